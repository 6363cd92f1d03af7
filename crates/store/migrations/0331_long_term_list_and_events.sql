-- Issue 32: the station's long-term tests (the list of the web UI's page)
-- and what happened to each that its intervals do not say: a pause on a
-- full disk and its resumption, with the test clock (decision 0125).
CREATE TABLE long_term_tests (
    job_id TEXT PRIMARY KEY NOT NULL REFERENCES jobs(id),
    created_at TEXT NOT NULL
);
-- The tests submitted before this table (their request's tag is long_term).
INSERT OR IGNORE INTO long_term_tests (job_id, created_at)
    SELECT id, created_at FROM jobs WHERE json_extract(request_json, '$.type') = 'long_term';

CREATE TABLE long_term_events (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id TEXT NOT NULL REFERENCES jobs(id),
    -- paused (the disk is full) or resumed (space returned)
    kind TEXT NOT NULL CHECK (kind IN ('paused', 'resumed')),
    -- test time then (s)
    elapsed_s REAL NOT NULL,
    detail TEXT NOT NULL,
    at TEXT NOT NULL
);
CREATE INDEX long_term_events_job ON long_term_events(job_id, seq);
