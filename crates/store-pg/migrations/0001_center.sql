-- The fleet's center on PostgreSQL (issue 20). The tables it shares with a
-- station's SQLite (crates/store/migrations/) have the same meaning and the
-- same column names: parts, recordings, measurements, fits, headline_choices,
-- qc_recipes, qc_verdicts. Timestamps stay RFC 3339 UTC text with
-- milliseconds, exactly as the station wrote them (they sort as text). JSON
-- documents are jsonb. The center adds: the station of every row, stations,
-- the items it holds per station (idempotency, gaps), the conflict log, the
-- audit trail of corrections, and one row per judged parameter value (SPC in
-- SQL).

CREATE TABLE stations (
    station_id         TEXT PRIMARY KEY,
    software_version   TEXT NOT NULL,
    contract_version   INTEGER NOT NULL,
    bench_states       JSONB NOT NULL,
    backlog_items      BIGINT NOT NULL,
    oldest_backlog_at  TEXT,
    sent_at            TEXT NOT NULL,
    first_contact_at   TEXT NOT NULL,
    last_contact_at    TEXT NOT NULL
);

CREATE TABLE parts (
    serial      TEXT PRIMARY KEY,
    kind        TEXT,
    notes       TEXT,
    created_at  TEXT NOT NULL,
    updated_at  TEXT NOT NULL,
    -- the station of the part's newest measurement
    station_id  TEXT
);

-- Raw signals, each distinct content once (a run's pre-measurement arrives
-- with every sweep). bytes NULL: a reference only, the station keeps them.
CREATE TABLE recordings (
    id                  BIGSERIAL PRIMARY KEY,
    sha256              TEXT NOT NULL UNIQUE,
    kind                TEXT NOT NULL CHECK (kind IN ('pre','main')),
    sample_rate_hz      DOUBLE PRECISION NOT NULL,
    frames              BIGINT NOT NULL,
    byte_len            BIGINT NOT NULL,
    wav                 BYTEA,
    channel_scale_json  TEXT,
    station_id          TEXT,
    created_at          TEXT NOT NULL
);

CREATE TABLE calibrations (
    station_id        TEXT NOT NULL,
    id                TEXT NOT NULL,
    bench_id          TEXT NOT NULL,
    job_id            TEXT,
    passed            BOOLEAN NOT NULL,
    calibration_json  JSONB NOT NULL,
    sensors_json      JSONB NOT NULL,
    result_json       JSONB NOT NULL,
    created_at        TEXT NOT NULL,
    PRIMARY KEY (station_id, id)
);

CREATE TABLE measurements (
    seq                BIGSERIAL PRIMARY KEY,
    id                 TEXT NOT NULL UNIQUE,
    station_id         TEXT,
    part_serial        TEXT NOT NULL REFERENCES parts(serial),
    -- the station's job (a reference: the queue stays on the station)
    job_id             TEXT,
    source             TEXT NOT NULL CHECK (source IN ('bench','import')),
    bench_id           TEXT,
    software_version   TEXT NOT NULL,
    config_json        JSONB NOT NULL,
    meta_json          JSONB NOT NULL,
    result_json        JSONB,
    analysis_error     TEXT,
    target_xpeak_m     DOUBLE PRECISION,
    repeat_index       BIGINT,
    level_index        BIGINT,
    pre_recording_id   BIGINT NOT NULL REFERENCES recordings(id),
    main_recording_id  BIGINT NOT NULL REFERENCES recordings(id),
    calibration_id     TEXT,
    created_at         TEXT NOT NULL,
    ingested_at        TEXT NOT NULL,
    -- the correction that voided it (it stays, out of SPC and yield)
    void_id            TEXT
);
CREATE INDEX measurements_part ON measurements (part_serial, seq);
CREATE INDEX measurements_job ON measurements (job_id, seq);
CREATE INDEX measurements_created ON measurements (created_at);
CREATE INDEX measurements_station ON measurements (station_id, seq);

CREATE TABLE fits (
    seq               BIGSERIAL PRIMARY KEY,
    id                TEXT NOT NULL UNIQUE,
    measurement_id    TEXT NOT NULL REFERENCES measurements(id),
    request_json      JSONB NOT NULL,
    result_json       JSONB NOT NULL,
    software_version  TEXT NOT NULL,
    created_at        TEXT NOT NULL
);
CREATE INDEX fits_measurement ON fits (measurement_id, seq);

CREATE TABLE headline_choices (
    seq             BIGSERIAL PRIMARY KEY,
    measurement_id  TEXT NOT NULL REFERENCES measurements(id),
    fit_id          TEXT REFERENCES fits(id),
    chosen_by       TEXT,
    chosen_at       TEXT NOT NULL
);
CREATE INDEX headline_choices_measurement ON headline_choices (measurement_id, seq);

-- Recipes come from the center: a change is a new version with its hash.
-- retired: the version may no longer judge (stations pull the flag).
CREATE TABLE qc_recipes (
    seq          BIGSERIAL PRIMARY KEY,
    name         TEXT NOT NULL,
    version      BIGINT NOT NULL,
    sha256       TEXT NOT NULL,
    body_json    JSONB NOT NULL,
    origin       TEXT NOT NULL,
    proposal_id  TEXT,
    retired      BOOLEAN NOT NULL DEFAULT false,
    created_by   TEXT,
    created_at   TEXT NOT NULL,
    UNIQUE (name, version)
);

CREATE TABLE qc_verdicts (
    seq             BIGSERIAL PRIMARY KEY,
    id              TEXT NOT NULL UNIQUE,
    station_id      TEXT,
    job_id          TEXT,
    measurement_id  TEXT REFERENCES measurements(id),
    part_serial     TEXT NOT NULL,
    recipe_name     TEXT NOT NULL,
    recipe_version  BIGINT NOT NULL,
    recipe_sha256   TEXT NOT NULL,
    verdict         TEXT NOT NULL CHECK (verdict IN ('pass','fail','invalid','no_limits')),
    detail_json     JSONB NOT NULL,
    trace_json      JSONB NOT NULL,
    created_at      TEXT NOT NULL,
    -- the measurement's level in a series (SPC groups by it)
    level_index     BIGINT,
    voided          BOOLEAN NOT NULL DEFAULT false
);
CREATE INDEX qc_verdicts_part ON qc_verdicts (part_serial, seq);
CREATE INDEX qc_verdicts_job ON qc_verdicts (job_id);
CREATE INDEX qc_verdicts_measurement ON qc_verdicts (measurement_id);
-- SPC: a recipe's measurement verdicts, newest first, without visiting the table.
CREATE INDEX qc_verdicts_recipe ON qc_verdicts (recipe_name, seq)
    INCLUDE (verdict, job_id, level_index, station_id, created_at)
    WHERE measurement_id IS NOT NULL AND NOT voided;
-- Yield per station and day: job verdicts.
CREATE INDEX qc_verdicts_recipe_jobs ON qc_verdicts (recipe_name, created_at)
    INCLUDE (verdict, station_id)
    WHERE measurement_id IS NULL AND NOT voided;

-- One row per judged parameter of a measurement verdict (from its detail's
-- `parameters`): SPC aggregates these in SQL.
CREATE TABLE verdict_values (
    verdict_seq  BIGINT NOT NULL REFERENCES qc_verdicts(seq),
    parameter    TEXT NOT NULL,
    value        DOUBLE PRECISION NOT NULL,
    PRIMARY KEY (verdict_seq, parameter)
);

-- What the center holds of each station's stream: the idempotency key of
-- every item, its outbox seq and content hash.
CREATE TABLE station_items (
    item_id         TEXT PRIMARY KEY,
    station_id      TEXT NOT NULL,
    seq             BIGINT NOT NULL,
    content_sha256  TEXT NOT NULL,
    received_at     TEXT NOT NULL
);
CREATE INDEX station_items_seq ON station_items (station_id, seq);

-- Items refused as conflicts (same id, other content; an id of another
-- station): kept for an engineer, never applied.
CREATE TABLE ingest_conflicts (
    seq             BIGSERIAL PRIMARY KEY,
    station_id      TEXT NOT NULL,
    item_seq        BIGINT NOT NULL,
    item_id         TEXT NOT NULL,
    content_sha256  TEXT NOT NULL,
    reason          TEXT NOT NULL,
    item_json       JSONB NOT NULL,
    received_at     TEXT NOT NULL
);

-- The audit trail: corrections of a part's serial or kind and voids of a
-- measurement, made on a station (replicated) or at the center. Nothing is
-- deleted: the rows they change keep their history here (old and new value).
CREATE TABLE corrections (
    seq             BIGSERIAL PRIMARY KEY,
    id              TEXT NOT NULL UNIQUE,
    -- the station it was made on; NULL: at the center
    station_id      TEXT,
    kind            TEXT NOT NULL CHECK (kind IN ('part_serial','part_kind','void_measurement')),
    part_serial     TEXT NOT NULL,
    measurement_id  TEXT,
    old_value       TEXT,
    new_value       TEXT,
    reason          TEXT NOT NULL CHECK (length(reason) > 0),
    made_by         TEXT,
    made_at         TEXT NOT NULL,
    applied_at      TEXT NOT NULL
);
CREATE INDEX corrections_part ON corrections (part_serial, seq);
CREATE INDEX corrections_measurement ON corrections (measurement_id);
