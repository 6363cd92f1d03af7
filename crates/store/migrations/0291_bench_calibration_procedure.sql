-- A bench calibration is per procedure too (decision 0049): the full
-- procedure's pre-measurement reaches its level on the laser's scale, the
-- production one drives the golden units' voltage, so a laser error moves
-- k0 differently in each. Rows of 0290 were estimated from the newest job
-- whatever its procedure; the golden runs were full-procedure runs.
ALTER TABLE bench_calibrations ADD COLUMN procedure TEXT NOT NULL DEFAULT 'full'
    CHECK (procedure IN ('full', 'production'));
CREATE INDEX bench_calibrations_procedure ON bench_calibrations(recipe_name, bench_id, procedure, seq);
