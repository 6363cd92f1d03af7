//! Gauge studies (station only): the plan of a study and its jobs. The
//! statistics are `core::qc::grr`; the values are the runs' verdicts.

use crate::{now, Store, StoreResult};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use springbench_core::qc::grr::{GaugeRun, GaugeStudyRequest};
use sqlx::Row;

/// A stored gauge study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaugeStudyRow {
    pub id: String,
    pub recipe_name: String,
    /// The study as requested, read into its type at the store's edge.
    pub request: GaugeStudyRequest,
    /// Its planned runs, with their job ids once submitted.
    pub runs: Vec<GaugeRun>,
    pub created_by: Option<String>,
    pub created_at: String,
}

impl Store {
    /// Stores a new study with its planned runs.
    pub async fn insert_gauge_study(
        &self,
        id: &str,
        request: &GaugeStudyRequest,
        runs: &[GaugeRun],
        created_by: Option<&str>,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO gauge_studies (id, recipe_name, request, runs, created_by, created_at) \
             VALUES (?, ?, ?, ?, ?, ?)",
        )
        .bind(id)
        .bind(&request.recipe)
        .bind(crate::json_text(request))
        .bind(crate::json_text(&runs))
        .bind(created_by)
        .bind(now())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// Replaces the runs of a study (their job ids once submitted).
    pub async fn update_gauge_runs(&self, id: &str, runs: &[GaugeRun]) -> StoreResult<()> {
        sqlx::query("UPDATE gauge_studies SET runs = ? WHERE id = ?")
            .bind(crate::json_text(&runs))
            .bind(id)
            .execute(&mut *self.writer().await?)
            .await?;
        Ok(())
    }

    pub async fn get_gauge_study(&self, id: &str) -> StoreResult<Option<GaugeStudyRow>> {
        let row = sqlx::query(
            "SELECT id, recipe_name, request, runs, created_by, created_at \
             FROM gauge_studies WHERE id = ?",
        )
        .bind(id)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| from_row(&r)).transpose()
    }

    /// The newest `limit` studies, newest first.
    pub async fn list_gauge_studies(&self, limit: i64) -> StoreResult<Vec<GaugeStudyRow>> {
        let rows = sqlx::query(
            "SELECT id, recipe_name, request, runs, created_by, created_at \
             FROM gauge_studies ORDER BY created_at DESC, id DESC LIMIT ?",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(from_row).collect()
    }
}

fn from_row(r: &sqlx::sqlite::SqliteRow) -> StoreResult<GaugeStudyRow> {
    fn json<T: serde::de::DeserializeOwned>(
        r: &sqlx::sqlite::SqliteRow,
        c: &str,
    ) -> StoreResult<T> {
        let s: String = r.try_get(c)?;
        serde_json::from_str(&s)
            .map_err(|e| crate::StoreError::Corrupt(format!("gauge_studies.{c}: {e}")))
    }
    Ok(GaugeStudyRow {
        id: r.try_get("id")?,
        recipe_name: r.try_get("recipe_name")?,
        request: json(r, "request")?,
        runs: json(r, "runs")?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
    })
}

/// A stored bench calibration (issue 21, decision 0049).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchCalibrationRow {
    pub id: String,
    pub recipe_name: String,
    pub bench_id: String,
    /// `full` or `production`: the procedure it was measured with and corrects.
    pub procedure: String,
    pub state: String,
    /// The calibration, read into its type at the store's edge.
    #[serde(serialize_with = "crate::sorted")]
    pub calibration: springbench_core::qc::BenchCalibration,
    pub created_by: Option<String>,
    pub created_at: String,
}

impl Store {
    pub async fn insert_bench_calibration(&self, row: &BenchCalibrationRow) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO bench_calibrations (id, recipe_name, bench_id, procedure, state, calibration, created_by, created_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(&row.id)
        .bind(&row.recipe_name)
        .bind(&row.bench_id)
        .bind(&row.procedure)
        .bind(&row.state)
        .bind(crate::json_text(&row.calibration))
        .bind(&row.created_by)
        .bind(&row.created_at)
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// The calibration in effect for `recipe` on `bench` for measurements
    /// with `procedure`: the newest.
    pub async fn latest_bench_calibration(
        &self,
        recipe: &str,
        bench: &str,
        procedure: &str,
    ) -> StoreResult<Option<BenchCalibrationRow>> {
        let row = sqlx::query(
            "SELECT id, recipe_name, bench_id, procedure, state, calibration, created_by, created_at \
             FROM bench_calibrations WHERE recipe_name = ? AND bench_id = ? AND procedure = ? \
             ORDER BY seq DESC LIMIT 1",
        )
        .bind(recipe)
        .bind(bench)
        .bind(procedure)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| cal_from_row(&r)).transpose()
    }

    /// Every calibration of `recipe`, newest first.
    pub async fn list_bench_calibrations(
        &self,
        recipe: &str,
    ) -> StoreResult<Vec<BenchCalibrationRow>> {
        let rows = sqlx::query(
            "SELECT id, recipe_name, bench_id, procedure, state, calibration, created_by, created_at \
             FROM bench_calibrations WHERE recipe_name = ? ORDER BY seq DESC",
        )
        .bind(recipe)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(cal_from_row).collect()
    }

    /// The result documents of the first level (every repeat, oldest first)
    /// of the newest succeeded job of `serial` under `recipe` on `bench`
    /// measured with `procedure` (a production job that fell back does not
    /// count), whatever its verdict (a bench out of calibration judges its
    /// golden units `invalid`; they still calibrate it).
    pub async fn newest_results_on_bench(
        &self,
        recipe: &str,
        serial: &str,
        bench: &str,
        procedure: &str,
    ) -> StoreResult<Option<(String, Vec<Value>)>> {
        let Some(job) = sqlx::query(
            "SELECT v.job_id FROM qc_verdicts v JOIN jobs j ON j.id = v.job_id \
             WHERE v.recipe_name = ? AND v.part_serial = ? AND v.measurement_id IS NULL \
             AND j.bench_id = ? AND j.state = 'succeeded' AND EXISTS (SELECT 1 FROM measurements m \
             WHERE m.job_id = v.job_id AND json_extract(m.config_json, '$.procedure_mode') = ? \
             AND json_extract(m.config_json, '$.procedure_run.fallback') IS NULL) \
             ORDER BY v.seq DESC LIMIT 1",
        )
        .bind(recipe)
        .bind(serial)
        .bind(bench)
        .bind(procedure)
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        let job_id: String = job.get(0);
        let rows = sqlx::query(
            "SELECT result_json FROM measurements WHERE job_id = ? AND result_json IS NOT NULL \
             AND COALESCE(level_index, 0) = 0 ORDER BY seq",
        )
        .bind(&job_id)
        .fetch_all(&self.pool)
        .await?;
        let mut out = vec![];
        for r in rows {
            let s: String = r.try_get(0)?;
            out.push(serde_json::from_str(&s).map_err(|e| {
                crate::StoreError::Corrupt(format!("measurements.result_json: {e}"))
            })?);
        }
        Ok(Some((job_id, out)))
    }
}

fn cal_from_row(r: &sqlx::sqlite::SqliteRow) -> StoreResult<BenchCalibrationRow> {
    let s: String = r.try_get("calibration")?;
    Ok(BenchCalibrationRow {
        id: r.try_get("id")?,
        recipe_name: r.try_get("recipe_name")?,
        bench_id: r.try_get("bench_id")?,
        procedure: r.try_get("procedure")?,
        state: r.try_get("state")?,
        calibration: serde_json::from_str(&s).map_err(|e| {
            crate::StoreError::Corrupt(format!(
                "bench calibration {} unreadable: {e}",
                r.get::<String, _>("id")
            ))
        })?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
    })
}
