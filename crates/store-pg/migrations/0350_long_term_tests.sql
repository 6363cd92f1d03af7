-- Issue 32 (decision 0134): the stations' long-term tests, read only at the
-- center. One row per test: the newest document its station sent (the
-- station's outbox item with the highest seq), served back as it came.
CREATE TABLE long_term_tests (
    job_id        TEXT PRIMARY KEY,
    station_id    TEXT NOT NULL,
    part_serial   TEXT NOT NULL,
    bench_id      TEXT NOT NULL,
    -- queued, running, succeeded, failed, cancelled, interrupted
    job_state     TEXT NOT NULL,
    -- when the test was submitted (the station's clock, RFC 3339 UTC)
    created_at    TEXT NOT NULL,
    -- the station's outbox seq of the document held
    item_seq      BIGINT NOT NULL,
    -- the station's GET /api/v1/long-term-tests/{id} and its list line (JSON text, as sent)
    document_json TEXT NOT NULL,
    summary_json  TEXT NOT NULL,
    -- the last signals before a failure limit stopped it are at the station
    last_signals_at_station BOOLEAN NOT NULL,
    -- the center's clock when the document arrived
    received_at   TEXT NOT NULL
);
CREATE INDEX long_term_tests_newest ON long_term_tests (created_at DESC, job_id);
