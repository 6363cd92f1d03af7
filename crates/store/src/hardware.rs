//! Hardware benches: calibration records (self-checks) and bench faults.

use super::{now, Store, StoreResult};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sqlx::Row;

/// A stored self-check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CalibrationRecord {
    pub id: String,
    pub bench_id: String,
    pub job_id: Option<String>,
    pub passed: bool,
    /// The `[benches.hardware.calibration]` in effect.
    pub calibration: Value,
    /// Sensor identities (laser model/serial/range, microphone calibration date).
    pub sensors: Value,
    /// What the self-check measured (latency, noise floors, rest readings, failures).
    #[serde(serialize_with = "crate::sorted")]
    #[schema(value_type = Object)]
    pub result: SelfCheckResult,
    pub created_at: String,
}

/// What a self-check found: its verdict, failures and loopback latency
/// typed (the runner reads them); the rest of the bench's report (noise
/// floors, rest readings, loopback figures) kept as the bench wrote it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct SelfCheckResult {
    #[serde(default)]
    pub passed: bool,
    /// One line per failed check.
    #[serde(default)]
    pub failures: Vec<String>,
    /// Loopback latency (s); absent when the check did not get that far.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latency_s: Option<f64>,
    #[serde(flatten)]
    pub measured: serde_json::Map<String, Value>,
}

impl SelfCheckResult {
    /// A self-check that could not run or failed before measuring.
    pub fn failed(why: impl Into<String>) -> Self {
        SelfCheckResult {
            passed: false,
            failures: vec![why.into()],
            ..Default::default()
        }
    }

    /// The stored text: keys sorted, as the record was always written.
    pub fn to_json(&self) -> String {
        crate::json_text(self)
    }

    /// The bench's own report (`bench::hardware::SelfCheck`), read into the
    /// typed members; a report that does not serialise as an object is a
    /// failed check naming why.
    pub fn of<T: Serialize>(report: &T) -> Self {
        serde_json::to_value(report)
            .and_then(serde_json::from_value)
            .unwrap_or_else(|e| Self::failed(format!("self-check report unreadable: {e}")))
    }
}

/// An open (not yet cleared) fault of a bench.
#[derive(Debug, Clone, Serialize)]
pub struct BenchFault {
    pub bench_id: String,
    pub job_id: Option<String>,
    pub detail: String,
    pub created_at: String,
}

fn calibration_row(r: &sqlx::sqlite::SqliteRow) -> CalibrationRecord {
    let j = |s: String| serde_json::from_str(&s).unwrap_or(Value::Null);
    CalibrationRecord {
        id: r.get("id"),
        bench_id: r.get("bench_id"),
        job_id: r.get("job_id"),
        passed: r.get::<i64, _>("passed") == 1,
        calibration: j(r.get("calibration_json")),
        sensors: j(r.get("sensors_json")),
        result: serde_json::from_str(&r.get::<String, _>("result_json")).unwrap_or_else(|e| {
            SelfCheckResult::failed(format!("stored self-check result unreadable: {e}"))
        }),
        created_at: r.get("created_at"),
    }
}

impl Store {
    /// Stores a self-check; a passing one clears the bench's open faults (one transaction).
    pub async fn insert_calibration(&self, rec: &CalibrationRecord) -> StoreResult<()> {
        let mut tx = self.begin_write().await?;
        sqlx::query(
            "INSERT INTO calibrations (id, bench_id, job_id, passed, calibration_json, sensors_json, result_json, created_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(&rec.id)
        .bind(&rec.bench_id)
        .bind(&rec.job_id)
        .bind(i64::from(rec.passed))
        .bind(rec.calibration.to_string())
        .bind(rec.sensors.to_string())
        .bind(rec.result.to_json())
        .bind(&rec.created_at)
        .execute(&mut *tx)
        .await?;
        if rec.passed {
            sqlx::query(
                "UPDATE bench_faults SET cleared_by = ?, cleared_at = ? WHERE bench_id = ? AND cleared_by IS NULL",
            )
            .bind(&rec.id)
            .bind(now())
            .bind(&rec.bench_id)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// The newest passing self-check of a bench.
    pub async fn latest_calibration(
        &self,
        bench_id: &str,
    ) -> StoreResult<Option<CalibrationRecord>> {
        let r = sqlx::query(
            "SELECT * FROM calibrations WHERE bench_id = ? AND passed = 1 ORDER BY seq DESC LIMIT 1",
        )
        .bind(bench_id)
        .fetch_optional(&self.pool)
        .await?;
        Ok(r.as_ref().map(calibration_row))
    }

    pub async fn get_calibration(&self, id: &str) -> StoreResult<Option<CalibrationRecord>> {
        let r = sqlx::query("SELECT * FROM calibrations WHERE id = ?")
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        Ok(r.as_ref().map(calibration_row))
    }

    pub async fn list_calibrations(&self, bench_id: &str) -> StoreResult<Vec<CalibrationRecord>> {
        let rows = sqlx::query(
            "SELECT * FROM calibrations WHERE bench_id = ? ORDER BY seq DESC LIMIT 100",
        )
        .bind(bench_id)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(calibration_row).collect())
    }

    pub async fn insert_bench_fault(
        &self,
        bench_id: &str,
        job_id: Option<&str>,
        detail: &str,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO bench_faults (bench_id, job_id, detail, created_at) VALUES (?, ?, ?, ?)",
        )
        .bind(bench_id)
        .bind(job_id)
        .bind(detail)
        .bind(now())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// The oldest open fault of each bench that has one.
    pub async fn open_bench_faults(&self) -> StoreResult<Vec<BenchFault>> {
        let rows = sqlx::query(
            "SELECT bench_id, job_id, detail, created_at FROM bench_faults WHERE cleared_by IS NULL ORDER BY seq",
        )
        .fetch_all(&self.pool)
        .await?;
        let mut out: Vec<BenchFault> = vec![];
        for r in rows {
            let b: String = r.get(0);
            if out.iter().any(|f| f.bench_id == b) {
                continue;
            }
            out.push(BenchFault {
                bench_id: b,
                job_id: r.get(1),
                detail: r.get(2),
                created_at: r.get(3),
            });
        }
        Ok(out)
    }

    /// Links the measurements of a job to the calibration record they were made with.
    pub async fn set_measurement_calibration(
        &self,
        job_id: &str,
        calibration_id: &str,
    ) -> StoreResult<()> {
        sqlx::query("UPDATE measurements SET calibration_id = ? WHERE job_id = ?")
            .bind(calibration_id)
            .bind(job_id)
            .execute(&mut *self.writer().await?)
            .await?;
        Ok(())
    }
}
