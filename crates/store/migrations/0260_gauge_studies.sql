-- Gauge studies (issue 21): N parts x M repeats on one or more benches. The
-- row is written before its jobs; each run names the idempotency key its job
-- is submitted with, and its job id once submitted, so a study interrupted
-- while submitting can be read (runs without a job are shown as such).
CREATE TABLE gauge_studies (
    id            TEXT PRIMARY KEY,
    recipe_name   TEXT NOT NULL,
    -- The accepted request (JSON): parts, repeats, benches, procedure.
    request       TEXT NOT NULL,
    -- JSON array: {part_index, bench_id, repeat, idempotency_key, job_id}.
    runs          TEXT NOT NULL,
    created_by    TEXT,
    created_at    TEXT NOT NULL
);
CREATE INDEX gauge_studies_created ON gauge_studies(created_at);
