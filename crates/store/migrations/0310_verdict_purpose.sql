-- The pool of each verdict (issue 35, decision 0100): why the part was
-- measured (production, golden_unit, bench_calibration, gauge_study,
-- repeat, engineering), as its trace says. A verdict stored before purposes
-- existed has none in its trace and reads as production, as it was counted
-- then. SPC and yield select production only, by this index.
ALTER TABLE qc_verdicts ADD COLUMN purpose TEXT
    GENERATED ALWAYS AS (COALESCE(json_extract(trace_json, '$.purpose'), 'production')) VIRTUAL;
CREATE INDEX qc_verdicts_recipe_purpose ON qc_verdicts(recipe_name, purpose, seq);
