-- Production QC (recipes, golden-unit limit proposals, verdicts) and the MES outbox.
-- All physical values SI; timestamps RFC 3339 UTC text.

-- Versioned recipes: a change is a new row (version + 1) with its content hash.
CREATE TABLE qc_recipes (
    seq          INTEGER PRIMARY KEY AUTOINCREMENT,
    name         TEXT NOT NULL,
    version      INTEGER NOT NULL,
    sha256       TEXT NOT NULL,
    body_json    TEXT NOT NULL,
    -- created | edited | limits_approved
    origin       TEXT NOT NULL,
    proposal_id  TEXT,
    retired      INTEGER NOT NULL DEFAULT 0,
    created_by   TEXT,
    created_at   TEXT NOT NULL,
    UNIQUE (name, version)
);

-- Limits proposed from golden units; an admin approves (a new recipe version) or rejects.
CREATE TABLE qc_limit_proposals (
    seq               INTEGER PRIMARY KEY AUTOINCREMENT,
    id                TEXT NOT NULL UNIQUE,
    recipe_name       TEXT NOT NULL,
    recipe_version    INTEGER NOT NULL,
    body_json         TEXT NOT NULL,
    state             TEXT NOT NULL CHECK (state IN ('proposed','approved','rejected')),
    created_by        TEXT,
    created_at        TEXT NOT NULL,
    decided_by        TEXT,
    decided_at        TEXT,
    approved_version  INTEGER
);

-- Verdicts: one per measurement judged and one per job (measurement_id NULL).
CREATE TABLE qc_verdicts (
    seq             INTEGER PRIMARY KEY AUTOINCREMENT,
    id              TEXT NOT NULL UNIQUE,
    job_id          TEXT REFERENCES jobs(id),
    measurement_id  TEXT REFERENCES measurements(id),
    part_serial     TEXT NOT NULL,
    recipe_name     TEXT NOT NULL,
    recipe_version  INTEGER NOT NULL,
    recipe_sha256   TEXT NOT NULL,
    verdict         TEXT NOT NULL CHECK (verdict IN ('pass','fail','invalid','no_limits')),
    detail_json     TEXT NOT NULL,
    trace_json      TEXT NOT NULL,
    created_at      TEXT NOT NULL
);
CREATE INDEX qc_verdicts_part ON qc_verdicts(part_serial, seq);
CREATE INDEX qc_verdicts_recipe ON qc_verdicts(recipe_name, seq);
CREATE INDEX qc_verdicts_job ON qc_verdicts(job_id);
CREATE INDEX qc_verdicts_measurement ON qc_verdicts(measurement_id);

-- MES messages (IPC-CFX JSON), written in the transaction of the result they announce.
CREATE TABLE mes_messages (
    seq           INTEGER PRIMARY KEY AUTOINCREMENT,
    unique_id     TEXT NOT NULL UNIQUE,
    message_name  TEXT NOT NULL,
    part_serial   TEXT NOT NULL,
    job_id        TEXT,
    body_json     TEXT NOT NULL,
    created_at    TEXT NOT NULL
);

-- One delivery per message and configured webhook; per (webhook, part) in seq order.
CREATE TABLE mes_deliveries (
    seq              INTEGER PRIMARY KEY AUTOINCREMENT,
    message_seq      INTEGER NOT NULL REFERENCES mes_messages(seq),
    webhook          TEXT NOT NULL,
    part_serial      TEXT NOT NULL,
    state            TEXT NOT NULL CHECK (state IN ('pending','delivered','failed','dropped')),
    attempts         INTEGER NOT NULL DEFAULT 0,
    next_attempt_at  TEXT NOT NULL,
    last_error       TEXT,
    delivered_at     TEXT,
    updated_at       TEXT NOT NULL
);
CREATE INDEX mes_deliveries_state ON mes_deliveries(state, seq);
CREATE INDEX mes_deliveries_order ON mes_deliveries(webhook, part_serial, state, seq);
