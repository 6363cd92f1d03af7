-- Hardware benches: self-check calibration records, bench faults, and the
-- calibration record each measurement was made with.

-- One row per self-check: what it measured and the calibration (TOML) in effect.
CREATE TABLE calibrations (
    seq               INTEGER PRIMARY KEY AUTOINCREMENT,
    id                TEXT NOT NULL UNIQUE,
    bench_id          TEXT NOT NULL,
    job_id            TEXT REFERENCES jobs(id),
    passed            INTEGER NOT NULL CHECK (passed IN (0, 1)),
    calibration_json  TEXT NOT NULL,
    sensors_json      TEXT NOT NULL,
    result_json       TEXT NOT NULL,
    created_at        TEXT NOT NULL
);
CREATE INDEX calibrations_bench ON calibrations(bench_id, seq);

-- A fault keeps its bench `faulted` until a passing self-check clears it.
CREATE TABLE bench_faults (
    seq          INTEGER PRIMARY KEY AUTOINCREMENT,
    bench_id     TEXT NOT NULL,
    job_id       TEXT REFERENCES jobs(id),
    detail       TEXT NOT NULL,
    created_at   TEXT NOT NULL,
    cleared_by   TEXT REFERENCES calibrations(id),
    cleared_at   TEXT
);
CREATE INDEX bench_faults_open ON bench_faults(bench_id, cleared_by);

ALTER TABLE measurements ADD COLUMN calibration_id TEXT REFERENCES calibrations(id);
