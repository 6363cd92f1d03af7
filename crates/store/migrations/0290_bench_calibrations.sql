-- Bench calibrations from golden units (issue 21, decision 0049): per recipe
-- and bench, the bench's laser sensitivity error and stiffness scale (clamp
-- mass) against the reference bench, estimated from the same golden units
-- measured on both. The newest row of a (recipe, bench) is in effect; every
-- verdict names the one it was judged with.
CREATE TABLE bench_calibrations (
    seq           INTEGER PRIMARY KEY AUTOINCREMENT,
    id            TEXT NOT NULL UNIQUE,
    recipe_name   TEXT NOT NULL,
    bench_id      TEXT NOT NULL,
    state         TEXT NOT NULL CHECK (state IN ('in_calibration', 'out_of_calibration')),
    -- core::qc::BenchCalibration (JSON): estimates, bounds' problems, units.
    calibration   TEXT NOT NULL,
    created_by    TEXT,
    created_at    TEXT NOT NULL
);
CREATE INDEX bench_calibrations_bench ON bench_calibrations(recipe_name, bench_id, seq);
