-- Measured at 830 532 results (docs/fleet.md): SPC over a recipe's newest
-- 100 000 verdicts took 2.1 s because the planner joined the window to
-- verdict_values by a sequential scan of the whole table (it grows with
-- every recipe, not with the window); stations() took 0.5 s because it
-- counted every station's items on each call.

-- A recipe's judged values of one parameter are an index range: the SPC
-- window's values are read from it, from the window's oldest verdict on.
ALTER TABLE verdict_values ADD COLUMN recipe_name TEXT;
UPDATE verdict_values x SET recipe_name = v.recipe_name FROM qc_verdicts v WHERE v.seq = x.verdict_seq;
ALTER TABLE verdict_values ALTER COLUMN recipe_name SET NOT NULL;
CREATE INDEX verdict_values_recipe ON verdict_values (recipe_name, parameter, verdict_seq) INCLUDE (value);

-- What the center holds of each station's stream, kept by the ingest in
-- the batch's transaction: items held, distinct outbox seqs, the highest.
ALTER TABLE stations
    ADD COLUMN items BIGINT NOT NULL DEFAULT 0,
    ADD COLUMN distinct_seqs BIGINT NOT NULL DEFAULT 0,
    ADD COLUMN last_seq BIGINT;
UPDATE stations s SET items = i.items, distinct_seqs = i.distinct_seqs, last_seq = i.last_seq
FROM (SELECT station_id, COUNT(*) AS items, COUNT(DISTINCT seq) AS distinct_seqs, MAX(seq) AS last_seq
      FROM station_items GROUP BY station_id) i
WHERE i.station_id = s.station_id;
