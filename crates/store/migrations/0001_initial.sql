-- Springbench schema v1. All physical values SI; timestamps RFC 3339 UTC text.

CREATE TABLE parts (
    serial      TEXT PRIMARY KEY NOT NULL,
    kind        TEXT,
    notes       TEXT,
    created_at  TEXT NOT NULL,
    updated_at  TEXT NOT NULL
);

-- Job state (how the execution went), kept apart from the result (measurements).
CREATE TABLE jobs (
    seq              INTEGER PRIMARY KEY AUTOINCREMENT,
    id               TEXT NOT NULL UNIQUE,
    bench_id         TEXT NOT NULL,
    part_serial      TEXT NOT NULL REFERENCES parts(serial),
    priority         INTEGER NOT NULL DEFAULT 0,
    state            TEXT NOT NULL CHECK (state IN ('queued','running','succeeded','failed','cancelled','interrupted')),
    step             TEXT,
    progress         REAL NOT NULL DEFAULT 0,
    eta_s            REAL,
    request_json     TEXT NOT NULL,
    idempotency_key  TEXT UNIQUE,
    request_sha256   TEXT NOT NULL,
    problem_json     TEXT,
    bench_time_s     REAL,
    log_json         TEXT,
    created_at       TEXT NOT NULL,
    started_at       TEXT,
    finished_at      TEXT
);
CREATE INDEX jobs_queue ON jobs(bench_id, state, priority DESC, seq);
CREATE INDEX jobs_part ON jobs(part_serial, seq);
CREATE INDEX jobs_state ON jobs(state, seq);

-- Raw signals, float32 WAV (0 displacement m, 1 microphone V, 2 drive V), so any
-- measurement can be fitted again. A pre-measurement shared by the sweeps of one
-- run is stored once.
CREATE TABLE recordings (
    id              INTEGER PRIMARY KEY AUTOINCREMENT,
    kind            TEXT NOT NULL CHECK (kind IN ('pre','main')),
    sample_rate_hz  REAL NOT NULL,
    frames          INTEGER NOT NULL,
    wav             BLOB NOT NULL,
    created_at      TEXT NOT NULL
);

CREATE TABLE measurements (
    seq                INTEGER PRIMARY KEY AUTOINCREMENT,
    id                 TEXT NOT NULL UNIQUE,
    part_serial        TEXT NOT NULL REFERENCES parts(serial),
    job_id             TEXT REFERENCES jobs(id),
    source             TEXT NOT NULL CHECK (source IN ('bench','import')),
    bench_id           TEXT,
    software_version   TEXT NOT NULL,
    config_json        TEXT NOT NULL,
    meta_json          TEXT NOT NULL,
    result_json        TEXT,
    analysis_error     TEXT,
    target_xpeak_m     REAL,
    repeat_index       INTEGER,
    level_index        INTEGER,
    pre_recording_id   INTEGER NOT NULL REFERENCES recordings(id),
    main_recording_id  INTEGER NOT NULL REFERENCES recordings(id),
    created_at         TEXT NOT NULL
);
CREATE INDEX measurements_part ON measurements(part_serial, seq);
CREATE INDEX measurements_job ON measurements(job_id);

-- Append-only event stream; seq is the resume point of GET /api/v1/events?after=N.
CREATE TABLE events (
    seq          INTEGER PRIMARY KEY AUTOINCREMENT,
    time         TEXT NOT NULL,
    type         TEXT NOT NULL,
    job_id       TEXT,
    data_json    TEXT NOT NULL
);
