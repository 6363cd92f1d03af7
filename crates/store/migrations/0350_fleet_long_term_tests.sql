-- Issue 32 (decision 0134): the fleet's center shows a station's long-term
-- tests, finished and running, read only. The outbox gains the kind
-- `long_term_test` (ref_id: the test's job id): the test's document as the
-- station's page shows it, sent whenever the test changes (submitted,
-- started, an interval finished, a user's pause asked or ended, a pause or
-- its end, an ambient value entered, its end). Each interval's measurement goes to the center when the
-- interval is stored, not only at the test's end (a test runs for hours).
--
-- SQLite cannot change a CHECK: the outbox is rebuilt with its rows, its
-- sequence and its index; its triggers are dropped first and made again.
DROP TRIGGER fleet_outbox_job_end;
DROP TRIGGER fleet_outbox_import;
DROP TRIGGER fleet_outbox_correction;

CREATE TABLE fleet_outbox_new (
    seq           INTEGER PRIMARY KEY AUTOINCREMENT,
    -- measurement: a finished measurement with its verdicts (at its job's
    -- end, at once for an import, at each stored interval of a long-term
    -- test); job_verdicts: the verdict of a whole job, after the job's
    -- measurements; correction: a row of `corrections`; long_term_test: the
    -- document of a long-term test as it stands when the item is sent.
    kind          TEXT NOT NULL CHECK (kind IN ('measurement','job_verdicts','correction','long_term_test')),
    ref_id        TEXT NOT NULL,
    part_serial   TEXT NOT NULL,
    created_at    TEXT NOT NULL,
    delivered_at  TEXT,
    attempts      INTEGER NOT NULL DEFAULT 0,
    last_error    TEXT,
    last_attempt_at TEXT,
    refused_at    TEXT
);
INSERT INTO fleet_outbox_new (seq, kind, ref_id, part_serial, created_at, delivered_at, attempts, last_error, last_attempt_at, refused_at)
    SELECT seq, kind, ref_id, part_serial, created_at, delivered_at, attempts, last_error, last_attempt_at, refused_at FROM fleet_outbox;
-- The station's event sequence carries on where it was (copying the rows
-- set the new table's sequence to their largest seq; a sequence is never
-- reused, so take the old one where it was higher); the rename moves it.
UPDATE sqlite_sequence SET seq = MAX(seq, COALESCE((SELECT s.seq FROM sqlite_sequence s WHERE s.name = 'fleet_outbox'), 0))
    WHERE name = 'fleet_outbox_new';
DROP TABLE fleet_outbox;
ALTER TABLE fleet_outbox_new RENAME TO fleet_outbox;
CREATE INDEX fleet_outbox_pending ON fleet_outbox(delivered_at, seq);

-- As 0240, except that a measurement already sent (a long-term test's
-- interval) is not sent again at its job's end.
CREATE TRIGGER fleet_outbox_job_end AFTER UPDATE OF state ON jobs
WHEN NEW.state IN ('succeeded','failed','cancelled','interrupted')
 AND OLD.state IN ('queued','running')
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'measurement', m.id, m.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM measurements m WHERE m.job_id = NEW.id
      AND NOT EXISTS (SELECT 1 FROM fleet_outbox o WHERE o.kind = 'measurement' AND o.ref_id = m.id)
    ORDER BY m.seq;
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'job_verdicts', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    WHERE OLD.state = 'running';
END;

CREATE TRIGGER fleet_outbox_import AFTER INSERT ON measurements
WHEN NEW.job_id IS NULL
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    VALUES ('measurement', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'));
END;

CREATE TRIGGER fleet_outbox_correction AFTER INSERT ON corrections
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    VALUES ('correction', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'));
END;

-- A long-term test submitted: the center lists it (queued).
CREATE TRIGGER fleet_outbox_long_term_submitted AFTER INSERT ON long_term_tests
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'long_term_test', NEW.job_id, j.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM jobs j WHERE j.id = NEW.job_id;
END;

-- Its job started, ended, was interrupted or put back in the queue. After
-- fleet_outbox_job_end (triggers of one event fire newest first in SQLite,
-- so the order is not relied on: the center shows the newest document).
CREATE TRIGGER fleet_outbox_long_term_state AFTER UPDATE OF state ON jobs
WHEN NEW.state <> OLD.state AND EXISTS (SELECT 1 FROM long_term_tests t WHERE t.job_id = NEW.id)
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    VALUES ('long_term_test', NEW.id, NEW.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now'));
END;

-- An interval stored: its measurement now, then the test's document.
CREATE TRIGGER fleet_outbox_long_term_interval AFTER INSERT ON long_term_intervals
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'measurement', m.id, m.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM measurements m WHERE m.id = NEW.measurement_id
      AND NOT EXISTS (SELECT 1 FROM fleet_outbox o WHERE o.kind = 'measurement' AND o.ref_id = m.id);
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'long_term_test', NEW.job_id, j.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM jobs j WHERE j.id = NEW.job_id;
END;

-- A value of an interval changed afterwards (ambient entered by hand).
CREATE TRIGGER fleet_outbox_long_term_interval_changed AFTER UPDATE ON long_term_intervals
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'long_term_test', NEW.job_id, j.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM jobs j WHERE j.id = NEW.job_id;
END;

-- A user asked for a pause or its end (migration 0333), before the test
-- stops or goes on (that is an event, below).
CREATE TRIGGER fleet_outbox_long_term_user_pause AFTER UPDATE OF paused_at ON long_term_tests
WHEN NEW.paused_at IS NOT OLD.paused_at
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'long_term_test', NEW.job_id, j.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM jobs j WHERE j.id = NEW.job_id;
END;

-- A pause or its end.
CREATE TRIGGER fleet_outbox_long_term_event AFTER INSERT ON long_term_events
BEGIN
    INSERT INTO fleet_outbox (kind, ref_id, part_serial, created_at)
    SELECT 'long_term_test', NEW.job_id, j.part_serial, strftime('%Y-%m-%dT%H:%M:%fZ', 'now')
    FROM jobs j WHERE j.id = NEW.job_id;
END;
