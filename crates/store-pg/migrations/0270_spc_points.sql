-- Measured at 10^6 results (docs/fleet.md): SPC over a recipe's newest
-- 100 000 verdicts took 1.0-1.2 s, most of it CPU spent joining the window's
-- verdicts to their values, averaging each point's repeats and sorting the
-- points for the moving range. The ingest now keeps one row per SPC point
-- and parameter (a point: one station's job and level of a recipe, its
-- repeats summed; core::qc::spc::per_part), ordered by the point's first
-- verdict: the window is one index-only range read in time order.
--
-- A point's key: its station, its job (a verdict without a job is a point
-- of its own) and its level, as a JSON array (no separator can clash).
CREATE FUNCTION spc_point_key(station_id TEXT, job_id TEXT, seq BIGINT, level_index BIGINT)
RETURNS TEXT LANGUAGE sql IMMUTABLE AS $$
    SELECT jsonb_build_array(station_id, COALESCE(job_id, 'seq:' || seq::text), level_index)::text
$$;

-- Derived from qc_verdicts (measurement verdicts, not voided, not invalid)
-- and verdict_values; a void recomputes the points it touches.
CREATE TABLE spc_points (
    recipe_name  TEXT NOT NULL,
    parameter    TEXT NOT NULL,
    point_key    TEXT NOT NULL,
    station_id   TEXT,
    job_id       TEXT,
    level_index  BIGINT,
    -- seq of the point's first and last verdict with this parameter
    first_seq    BIGINT NOT NULL,
    last_seq     BIGINT NOT NULL,
    -- its repeats: how many, the sum of their values
    n            BIGINT NOT NULL CHECK (n > 0),
    value_sum    DOUBLE PRECISION NOT NULL,
    -- the point's verdict: fail when a repeat failed, else MIN (they agree)
    any_fail     BOOLEAN NOT NULL,
    min_verdict  TEXT NOT NULL,
    PRIMARY KEY (recipe_name, parameter, point_key)
);

INSERT INTO spc_points
SELECT v.recipe_name, x.parameter, spc_point_key(v.station_id, v.job_id, v.seq, v.level_index),
       MIN(v.station_id), MIN(v.job_id), MIN(v.level_index), MIN(v.seq), MAX(v.seq), COUNT(*),
       SUM(x.value), bool_or(v.verdict = 'fail'), MIN(v.verdict)
FROM qc_verdicts v JOIN verdict_values x ON x.verdict_seq = v.seq
WHERE v.measurement_id IS NOT NULL AND NOT v.voided AND v.verdict <> 'invalid'
GROUP BY v.recipe_name, x.parameter, spc_point_key(v.station_id, v.job_id, v.seq, v.level_index);

-- The window: a recipe's points of one parameter from a seq on, in time order.
CREATE INDEX spc_points_window ON spc_points (recipe_name, parameter, first_seq)
    INCLUDE (station_id, n, value_sum, any_fail, min_verdict);
-- Points of several verdicts (only those can start before a window and end
-- in it): the window's first point may be a part of one.
CREATE INDEX spc_points_spanning ON spc_points (recipe_name, parameter, last_seq)
    INCLUDE (first_seq) WHERE last_seq > first_seq;
-- The window's invalid verdicts (about 1 in 100) without reading the others.
CREATE INDEX qc_verdicts_recipe_invalid ON qc_verdicts (recipe_name, seq) INCLUDE (station_id)
    WHERE measurement_id IS NOT NULL AND NOT voided AND verdict = 'invalid';
