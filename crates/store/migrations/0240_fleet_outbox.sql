-- The fleet outbox (issue 20): what this station has still to send to the
-- fleet's center, one row per replication item (crates/store/src/fleet.rs), in
-- the station's own order. Triggers fill it inside the very transaction that
-- stores the event (a job's end with its measurements and verdicts, an
-- import, a correction): a committed result is in the outbox, a rolled-back
-- one is not, whatever code path wrote it. Rows are never deleted: `seq` is
-- the station's item sequence (1, 2, 3... without gaps, the order per part)
-- that the center checks for gaps; `delivered_at` marks what the center
-- acknowledged. A station without [fleet] fills it too (about 100 bytes per
-- measurement), so a station that joins a fleet later sends its history.
CREATE TABLE fleet_outbox (
    seq           INTEGER PRIMARY KEY AUTOINCREMENT,
    -- measurement: a finished measurement with its verdicts (at its job's
    -- end, or at once for an import); job_verdicts: the verdict of a whole
    -- job, after the job's measurements; correction: a row of `corrections`.
    kind          TEXT NOT NULL CHECK (kind IN ('measurement','job_verdicts','correction')),
    ref_id        TEXT NOT NULL,
    part_serial   TEXT NOT NULL,
    created_at    TEXT NOT NULL,
    delivered_at  TEXT,
    attempts      INTEGER NOT NULL DEFAULT 0,
    last_error    TEXT,
    last_attempt_at TEXT,
    -- the center answered and refused the item (last_error says why): later
    -- items of the same part wait behind it; retried at the worker's next start
    refused_at    TEXT
);
CREATE INDEX fleet_outbox_pending ON fleet_outbox(delivered_at, seq);

-- A job's end: its measurements (storage order), then the job's verdicts.
-- A job cancelled while queued ran nothing and sends nothing.
CREATE TRIGGER fleet_outbox_job_end AFTER UPDATE OF state ON jobs
WHEN NEW.state IN ('succeeded','failed','cancelled','interrupted')
 AND OLD.state IN ('queued','running')
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'measurement', m.id, m.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM measurements m WHERE m.job_id = NEW.id ORDER BY m.seq;
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'job_verdicts', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    WHERE OLD.state = 'running';
END;

-- A measurement without a job (an import) is finished when stored.
CREATE TRIGGER fleet_outbox_import AFTER INSERT ON measurements
WHEN NEW.job_id IS NULL
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    VALUES ('measurement', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'));
END;

-- Corrections with their audit trail: nothing is deleted; a correction is a
-- new row naming what it changed, from which value to which, why and by whom.
-- part_serial: the serial corrected (its old value); part_kind: the kind;
-- void_measurement: a measurement no longer counts (SPC, yield, the part's
-- verdict), its rows stay.
CREATE TABLE corrections (
    seq             INTEGER PRIMARY KEY AUTOINCREMENT,
    id              TEXT NOT NULL UNIQUE,
    kind            TEXT NOT NULL CHECK (kind IN ('part_serial','part_kind','void_measurement')),
    part_serial     TEXT NOT NULL,
    measurement_id  TEXT REFERENCES measurements(id),
    old_value       TEXT,
    new_value       TEXT,
    reason          TEXT NOT NULL CHECK (length(reason) > 0),
    made_by         TEXT,
    made_at         TEXT NOT NULL
);
CREATE INDEX corrections_part ON corrections(part_serial, seq);
CREATE UNIQUE INDEX corrections_one_void ON corrections(measurement_id) WHERE kind = 'void_measurement';

CREATE TRIGGER fleet_outbox_correction AFTER INSERT ON corrections
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    VALUES ('correction', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'));
END;
