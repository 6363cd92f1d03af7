-- Issue 32: the long-term test as a job. Its state is written with each
-- finished interval, in the transaction that stores the interval's
-- measurement, so that a daemon killed during the test resumes where it
-- stopped: no finished interval lost or run twice, the load carried on.
CREATE TABLE long_term_state (
    job_id TEXT PRIMARY KEY NOT NULL REFERENCES jobs(id),
    -- intervals finished (the next one's index)
    intervals_done INTEGER NOT NULL,
    -- test time at the end of the last measurement (s)
    clock_s REAL NOT NULL,
    -- the part's accumulated load then (J)
    load_j REAL NOT NULL,
    -- the virtual bench's part state (JSON)
    part_state_json TEXT NOT NULL,
    -- the ageing document (the law's fit) over the intervals so far (JSON)
    document_json TEXT,
    -- the failure limit that stopped the test (JSON), if one did
    failure_json TEXT,
    -- each resumption after a crash, a kill or a stop (JSON list)
    resumptions_json TEXT NOT NULL DEFAULT '[]',
    updated_at TEXT NOT NULL
);

CREATE TABLE long_term_intervals (
    job_id TEXT NOT NULL REFERENCES jobs(id),
    idx INTEGER NOT NULL,
    measurement_id TEXT NOT NULL REFERENCES measurements(id),
    -- test time at the measurement's start (s)
    elapsed_s REAL NOT NULL,
    -- the load the part had taken then (J)
    load_j REAL NOT NULL,
    accelerated INTEGER NOT NULL,
    created_at TEXT NOT NULL,
    PRIMARY KEY (job_id, idx)
);

-- The last seconds of the signals before a failure limit stopped a test.
CREATE TABLE long_term_signals (
    job_id TEXT PRIMARY KEY NOT NULL REFERENCES jobs(id),
    recording_id INTEGER NOT NULL REFERENCES recordings(id),
    duration_s REAL NOT NULL,
    created_at TEXT NOT NULL
);
