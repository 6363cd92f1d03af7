//! What only the center answers: SPC of a recipe across stations and per
//! station (the station as a subgroup) and yield per station and day, both
//! as SQL aggregates over an index range (never the rows themselves); a
//! station's measurements in keyset pages; the audit trail of corrections
//! (`Corrections`, as a station's store answers it);
//! the center's recipes (written here, pulled by the stations).

use crate::ingest::apply_correction;
use crate::reads::{meas_from_row, meas_select, recipe_cols, recipe_from_row};
use crate::PgStore;
use serde::Serialize;
use springbench_core::qc::spc::{capability, Spc, D2};
use springbench_store::corrections::{AuditEntry, Corrections};
use springbench_store::fleet::Correction;
use springbench_store::qc::{RecipeExpect, RecipeWrite};
use springbench_store::results::MeasurementInfo;
use springbench_store::{now, StoreResult};
use sqlx::Row;

/// What [`PgStore::spc`] computes: parameter `parameter` (its `unit`, its
/// limits) of recipe `recipe` (any version) over its newest `last`
/// measurement verdicts, or those made in [since, until); every station
/// together, or (`per_station`) each station as a subgroup of the same window.
#[derive(Debug, Clone, Default)]
pub struct SpcQuery<'a> {
    pub recipe: &'a str,
    pub parameter: &'a str,
    pub unit: &'a str,
    pub lower: Option<f64>,
    pub upper: Option<f64>,
    pub since: Option<&'a str>,
    pub until: Option<&'a str>,
    pub last: Option<i64>,
    pub per_station: bool,
}

/// The SPC of one subgroup: a station, or (None) every station together.
/// `spc` is `core::qc::spc::Spc` as `compute` defines it, computed by
/// PostgreSQL (one point per part and job and level, its repeats
/// averaged; sigma the sample standard deviation; sigma_within the mean
/// moving range / d2 in time order), without the points themselves.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct SpcGroup {
    pub station_id: Option<String>,
    pub spc: Spc,
}

/// Job verdicts of a recipe on one station and one day (UTC).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct YieldDay {
    pub station_id: Option<String>,
    /// `YYYY-MM-DD` (UTC).
    pub day: String,
    pub passed: i64,
    pub failed: i64,
    pub invalid: i64,
    pub no_limits: i64,
    /// passed / (passed + failed); None without either.
    pub yield_fraction: Option<f64>,
}

fn summary(r: Option<&sqlx::postgres::PgRow>, q: &SpcQuery<'_>) -> Spc {
    let get = |c: &str| -> Option<f64> { r.and_then(|r| r.try_get(c).ok().flatten()) };
    let count = |c: &str| -> usize {
        r.and_then(|r| r.try_get::<Option<i64>, _>(c).ok().flatten())
            .unwrap_or(0) as usize
    };
    let (mean, sigma) = (get("mean"), get("sigma"));
    let sigma_within = get("mr").map(|m| m / D2);
    let (passed, failed) = (count("passed"), count("failed"));
    let cap = |s: Option<f64>| match (mean, s) {
        (Some(m), Some(s)) => capability(q.lower, q.upper, m, s),
        _ => (None, None),
    };
    let (cp, cpk) = cap(sigma_within);
    let (pp, ppk) = cap(sigma);
    let limit = |k: f64| mean.zip(sigma_within).map(|(m, s)| m + k * s);
    Spc {
        parameter: q.parameter.to_string(),
        unit: q.unit.to_string(),
        n: count("n"),
        mean,
        sigma,
        sigma_within,
        lower: q.lower,
        upper: q.upper,
        cp,
        cpk,
        pp,
        ppk,
        yield_fraction: (passed + failed > 0).then(|| passed as f64 / (passed + failed) as f64),
        passed,
        failed,
        invalid: count("invalid"),
        center_line: mean,
        ucl: limit(3.0),
        lcl: limit(-3.0),
        points: Vec::new(),
        // no chart points at the fleet's figures: no rule is read
        rules: Vec::new(),
    }
}

impl PgStore {
    /// SPC in SQL aggregates ([`SpcQuery`]): one group (station None), or
    /// one per station by id. Voided measurements are left out.
    pub async fn spc(&self, q: &SpcQuery<'_>) -> StoreResult<Vec<SpcGroup>> {
        let rows = if q.since.is_none() && q.until.is_none() {
            self.spc_newest(q).await?
        } else {
            self.spc_time_window(q).await?
        };
        let mut out: Vec<SpcGroup> = rows
            .iter()
            .map(|r| SpcGroup {
                station_id: r.get("g"),
                spc: summary(Some(r), q),
            })
            .collect();
        if out.is_empty() && !q.per_station {
            out.push(SpcGroup {
                station_id: None,
                spc: summary(None, q),
            });
        }
        Ok(out)
    }

    /// The newest `last` verdicts (every one without `last`) from the SPC
    /// points the ingest keeps (migration 0270): the window is the seqs from
    /// its oldest verdict's on, so its points are one index range in time
    /// order (the moving range needs no sort across stations); a point that
    /// began before the window (its first repeats outside) is recomputed
    /// from the verdicts inside it, as `core::qc::spc` takes a window.
    async fn spc_newest(&self, q: &SpcQuery<'_>) -> StoreResult<Vec<sqlx::postgres::PgRow>> {
        let lo: i64 = match q.last {
            None => 0,
            Some(n) if n <= 0 => i64::MAX,
            Some(n) => sqlx::query_scalar(
                "SELECT seq FROM qc_verdicts \
                 WHERE recipe_name = $1 AND measurement_id IS NOT NULL AND NOT voided \
                 ORDER BY seq DESC OFFSET $2 LIMIT 1",
            )
            .bind(q.recipe)
            .bind(n - 1)
            .fetch_optional(&self.pool)
            .await?
            .unwrap_or(0),
        };
        // Across stations: one group, the points in index order (a merge of
        // the range and the few partial points); per station: a sort.
        macro_rules! newest {
            ($g:literal, $g_v:literal, $over:literal) => {
                concat!(
                    "WITH pts AS ( \
                       (SELECT ", $g, " AS g, first_seq, value_sum / n AS value, \
                               CASE WHEN any_fail THEN 'fail' ELSE min_verdict END AS verdict \
                        FROM spc_points WHERE recipe_name = $1 AND parameter = $2 AND first_seq >= $3 \
                        ORDER BY first_seq) \
                       UNION ALL \
                       (SELECT ", $g_v, " AS g, MIN(v.seq), AVG(x.value), \
                               CASE WHEN bool_or(v.verdict = 'fail') THEN 'fail' ELSE MIN(v.verdict) END \
                        FROM spc_points s JOIN qc_verdicts v ON v.job_id = s.job_id AND v.recipe_name = $1 \
                             AND v.station_id IS NOT DISTINCT FROM s.station_id \
                             AND v.level_index IS NOT DISTINCT FROM s.level_index AND v.seq >= $3 \
                             AND v.measurement_id IS NOT NULL AND NOT v.voided AND v.verdict <> 'invalid' \
                        JOIN verdict_values x ON x.verdict_seq = v.seq AND x.parameter = $2 \
                        WHERE s.recipe_name = $1 AND s.parameter = $2 AND s.last_seq >= $3 \
                          AND s.last_seq > s.first_seq AND s.first_seq < $3 \
                        GROUP BY v.station_id, v.job_id, v.level_index ORDER BY 2) \
                       ORDER BY 2), \
                     d AS (SELECT g, value, verdict, value - LAG(value) OVER (", $over, " ORDER BY first_seq) AS step FROM pts), \
                     s AS ( \
                       SELECT g, COUNT(*) AS n, AVG(value) AS mean, STDDEV_SAMP(value) AS sigma, AVG(ABS(step)) AS mr, \
                              COUNT(*) FILTER (WHERE verdict = 'pass') AS passed, \
                              COUNT(*) FILTER (WHERE verdict = 'fail') AS failed FROM d GROUP BY g), \
                     inv AS ( \
                       SELECT ", $g, " AS g, COUNT(*) AS invalid FROM qc_verdicts \
                       WHERE recipe_name = $1 AND measurement_id IS NOT NULL AND NOT voided AND verdict = 'invalid' \
                         AND seq >= $3 GROUP BY 1), \
                     k AS (SELECT g FROM s UNION SELECT g FROM inv) \
                     SELECT k.g, s.n, s.mean, s.sigma, s.mr, s.passed, s.failed, inv.invalid \
                     FROM k LEFT JOIN s ON s.g IS NOT DISTINCT FROM k.g LEFT JOIN inv ON inv.g IS NOT DISTINCT FROM k.g \
                     ORDER BY 1 NULLS FIRST"
                )
            };
        }
        let sql = if q.per_station {
            newest!("station_id", "v.station_id", "PARTITION BY g")
        } else {
            newest!("NULL::text", "NULL::text", "")
        };
        Ok(sqlx::query(sql)
            .bind(q.recipe)
            .bind(q.parameter)
            .bind(lo)
            .fetch_all(&self.pool)
            .await?)
    }

    /// Verdicts made in [since, until) (the newest `last` of them): not a
    /// range of seqs (the stations' clocks interleave), so the window's
    /// verdicts are joined to their values and their points formed here.
    async fn spc_time_window(&self, q: &SpcQuery<'_>) -> StoreResult<Vec<sqlx::postgres::PgRow>> {
        // A point's verdict: `fail` when a repeat failed, else its first
        // repeat's (core::qc::spc). The repeats of one job and level share
        // the recipe version, so without a failure they are all `pass` or
        // all `no_limits` and MIN gives the first's; an ordered array_agg
        // per point cost a sort per point (a quarter of the time at 10^5).
        let rows = sqlx::query(
            "WITH w AS ( \
               SELECT seq, station_id, job_id, level_index, verdict FROM qc_verdicts \
               WHERE recipe_name = $1 AND measurement_id IS NOT NULL AND NOT voided \
                 AND ($3::text IS NULL OR created_at >= $3) AND ($4::text IS NULL OR created_at < $4) \
               ORDER BY seq DESC LIMIT $5), \
             vals AS ( \
               SELECT verdict_seq, value FROM verdict_values \
               WHERE recipe_name = $1 AND parameter = $2 AND verdict_seq >= (SELECT MIN(seq) FROM w)), \
             pts AS ( \
               SELECT CASE WHEN $6 THEN w.station_id END AS g, MIN(w.seq) AS first_seq, AVG(x.value) AS value, \
                      CASE WHEN bool_or(w.verdict = 'fail') THEN 'fail' ELSE MIN(w.verdict) END AS verdict \
               FROM w JOIN vals x ON x.verdict_seq = w.seq \
               WHERE w.verdict <> 'invalid' \
               GROUP BY 1, w.station_id, COALESCE(w.job_id, 'seq:' || w.seq::text), w.level_index), \
             d AS ( \
               SELECT g, value, verdict, value - LAG(value) OVER (PARTITION BY g ORDER BY first_seq) AS step FROM pts), \
             s AS ( \
               SELECT g, COUNT(*) AS n, AVG(value) AS mean, STDDEV_SAMP(value) AS sigma, AVG(ABS(step)) AS mr, \
                      COUNT(*) FILTER (WHERE verdict = 'pass') AS passed, \
                      COUNT(*) FILTER (WHERE verdict = 'fail') AS failed FROM d GROUP BY g), \
             inv AS ( \
               SELECT CASE WHEN $6 THEN station_id END AS g, COUNT(*) AS invalid FROM w \
               WHERE verdict = 'invalid' GROUP BY 1), \
             k AS (SELECT g FROM s UNION SELECT g FROM inv) \
             SELECT k.g, s.n, s.mean, s.sigma, s.mr, s.passed, s.failed, inv.invalid \
             FROM k LEFT JOIN s ON s.g IS NOT DISTINCT FROM k.g LEFT JOIN inv ON inv.g IS NOT DISTINCT FROM k.g \
             ORDER BY 1 NULLS FIRST",
        )
        .bind(q.recipe)
        .bind(q.parameter)
        .bind(q.since)
        .bind(q.until)
        .bind(q.last)
        .bind(q.per_station)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows)
    }

    /// Yield of recipe `recipe` per station and day (UTC) over its job
    /// verdicts made in [since, until), oldest day first.
    pub async fn yield_per_day(
        &self,
        recipe: &str,
        since: &str,
        until: &str,
    ) -> StoreResult<Vec<YieldDay>> {
        let rows = sqlx::query(
            "SELECT station_id, substr(created_at, 1, 10) AS day, \
             COUNT(*) FILTER (WHERE verdict = 'pass') AS passed, COUNT(*) FILTER (WHERE verdict = 'fail') AS failed, \
             COUNT(*) FILTER (WHERE verdict = 'invalid') AS invalid, COUNT(*) FILTER (WHERE verdict = 'no_limits') AS no_limits \
             FROM qc_verdicts WHERE recipe_name = $1 AND measurement_id IS NULL AND NOT voided \
             AND created_at >= $2 AND created_at < $3 GROUP BY 1, 2 ORDER BY 2, 1",
        )
        .bind(recipe)
        .bind(since)
        .bind(until)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows
            .iter()
            .map(|r| {
                let (passed, failed): (i64, i64) = (r.get("passed"), r.get("failed"));
                YieldDay {
                    station_id: r.get("station_id"),
                    day: r.get("day"),
                    passed,
                    failed,
                    invalid: r.get("invalid"),
                    no_limits: r.get("no_limits"),
                    yield_fraction: (passed + failed > 0)
                        .then(|| passed as f64 / (passed + failed) as f64),
                }
            })
            .collect())
    }

    /// A station's measurements, newest first, in keyset pages (`before_seq`).
    pub async fn station_measurements(
        &self,
        station: &str,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<MeasurementInfo>> {
        let rows = sqlx::query(concat!(
            meas_select!(),
            " FROM measurements m WHERE m.station_id = $1 AND ($2::bigint IS NULL OR m.seq < $2) \
             ORDER BY m.seq DESC LIMIT $3"
        ))
        .bind(station)
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(meas_from_row).collect()
    }

    /// Stores a new version of a recipe at the center (version = last + 1,
    /// or 1) when the stored one is what the caller saw; two writers of one
    /// name are serialised (a transaction-scoped advisory lock on the name).
    pub async fn write_recipe(
        &self,
        name: &str,
        sha256: &str,
        body: &springbench_core::qc::Recipe,
        origin: &str,
        created_by: Option<&str>,
        expect: RecipeExpect,
    ) -> StoreResult<RecipeWrite> {
        let mut tx = self.pool.begin().await?;
        sqlx::query("SELECT pg_advisory_xact_lock(hashtext('qc_recipes:' || $1))")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let cur: Option<(i64, bool)> = sqlx::query_as(
            "SELECT version, retired FROM qc_recipes WHERE name = $1 ORDER BY version DESC LIMIT 1",
        )
        .bind(name)
        .fetch_optional(&mut *tx)
        .await?;
        let ok = match expect {
            RecipeExpect::Any => true,
            RecipeExpect::Absent => cur.is_none(),
            RecipeExpect::Version(v) => cur.map(|c| c.0) == Some(v),
        };
        if !ok {
            return Ok(RecipeWrite::Conflict(cur));
        }
        let row = sqlx::query(concat!(
            "INSERT INTO qc_recipes (name, version, sha256, body_json, origin, created_by, created_at) \
             VALUES ($1, $2, $3, $4::jsonb, $5, $6, $7) RETURNING ",
            recipe_cols!()
        ))
        .bind(name)
        .bind(cur.map_or(1, |c| c.0 + 1))
        .bind(sha256)
        .bind(springbench_store::json_text(body))
        .bind(origin)
        .bind(created_by)
        .bind(now())
        .fetch_one(&mut *tx)
        .await?;
        let stored = recipe_from_row(&row)?;
        tx.commit().await?;
        Ok(RecipeWrite::Stored(Box::new(stored)))
    }

    /// Retires one version of a recipe, or (None) every version: stations
    /// stop judging with it once they pulled the flag. False when unknown.
    pub async fn retire_recipe(&self, name: &str, version: Option<i64>) -> StoreResult<bool> {
        let r = sqlx::query(
            "UPDATE qc_recipes SET retired = true WHERE name = $1 AND ($2::bigint IS NULL OR version = $2)",
        )
        .bind(name)
        .bind(version)
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() > 0)
    }

    /// Keeps a fit of a stored measurement made at the center (an engineer's
    /// refit), as a station's `Store::insert_fit` does.
    pub async fn insert_fit(
        &self,
        id: &str,
        measurement_id: &str,
        request: &serde_json::Value,
        result: &serde_json::Value,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO fits (id, measurement_id, request_json, result_json, software_version, created_at) \
             VALUES ($1, $2, $3::jsonb, $4::jsonb, $5, $6)",
        )
        .bind(id)
        .bind(measurement_id)
        .bind(request.to_string())
        .bind(result.to_string())
        .bind(springbench_core::VERSION)
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Records who chose which fit (None: the measurement's own result) for
    /// a measurement's headline; every choice is kept.
    pub async fn choose_headline(
        &self,
        measurement_id: &str,
        fit_id: Option<&str>,
        chosen_by: Option<&str>,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO headline_choices (measurement_id, fit_id, chosen_by, chosen_at) VALUES ($1, $2, $3, $4)",
        )
        .bind(measurement_id)
        .bind(fit_id)
        .bind(chosen_by)
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }
}

impl Corrections for PgStore {
    async fn correct(&self, c: &Correction) -> StoreResult<bool> {
        // At the center: the audit row's station is None.
        let mut tx = self.pool.begin().await?;
        let done = apply_correction(&mut tx, None, c).await?;
        tx.commit().await?;
        Ok(done)
    }

    async fn audit_log(
        &self,
        part: Option<&str>,
        after_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<AuditEntry>> {
        let rows = sqlx::query(
            "SELECT * FROM corrections WHERE ($1::text IS NULL OR part_serial = $1 \
             OR (kind = 'part_serial' AND new_value = $1)) AND ($2::bigint IS NULL OR seq > $2) ORDER BY seq LIMIT $3",
        )
        .bind(part)
        .bind(after_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows
            .iter()
            .map(|r| AuditEntry {
                seq: r.get("seq"),
                station_id: r.get("station_id"),
                correction: Correction {
                    id: r.get("id"),
                    kind: r.get("kind"),
                    part_serial: r.get("part_serial"),
                    measurement_id: r.get("measurement_id"),
                    old_value: r.get("old_value"),
                    new_value: r.get("new_value"),
                    reason: r.get("reason"),
                    made_by: r.get("made_by"),
                    made_at: r.get("made_at"),
                },
                applied_at: r.get("applied_at"),
            })
            .collect())
    }

    async fn measurement_void(&self, id: &str) -> StoreResult<Option<String>> {
        let v: Option<Option<String>> =
            sqlx::query_scalar("SELECT void_id FROM measurements WHERE id = $1")
                .bind(id)
                .fetch_optional(&self.pool)
                .await?;
        Ok(v.flatten())
    }
}
