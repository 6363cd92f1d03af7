-- The memory's studies (issue 33, decision 0121): one row per study job,
-- its own state beside the job's (the job stays `running` while the study
-- waits for the operator), the operator's instruction, and the result
-- (core::diagnose::studies::AddedMassResult or diagnose::memory::RecoveryResult,
-- JSON, SI units in every member's name).
CREATE TABLE studies (
    job_id       TEXT PRIMARY KEY REFERENCES jobs(id),
    kind         TEXT NOT NULL CHECK (kind IN ('added_mass', 'recovery')),
    state        TEXT NOT NULL CHECK (state IN ('measuring', 'awaiting_operator', 'confirmed', 'succeeded', 'failed')),
    instruction  TEXT,
    result_json  TEXT,
    confirmed_by TEXT,
    updated_at   TEXT NOT NULL
);
