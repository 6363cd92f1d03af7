-- Issue 32, decision 0130: a long-term test paused by the user. The pause
-- asked for is a column of the test (it outlives a stop of the daemon: a
-- test resumed after a kill -9 stays paused); the pause and its end as
-- they happened are events, now with their cause: the disk ('disk', the
-- automatic pause of decision 0125) or the user ('user').
ALTER TABLE long_term_tests ADD COLUMN paused_at TEXT;
ALTER TABLE long_term_tests ADD COLUMN paused_by TEXT;
ALTER TABLE long_term_events ADD COLUMN cause TEXT NOT NULL DEFAULT 'disk'
    CHECK (cause IN ('disk', 'user'));
