//! Gauge studies (station only): the plan of a study and its jobs. The
//! statistics are `core::qc::grr`; the values are the runs' verdicts.

use crate::{now, Store, StoreResult};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sqlx::Row;

/// A stored gauge study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GaugeStudyRow {
    pub id: String,
    pub recipe_name: String,
    pub request: Value,
    pub runs: Value,
    pub created_by: Option<String>,
    pub created_at: String,
}

impl Store {
    /// Stores a new study with its planned runs.
    pub async fn insert_gauge_study(
        &self,
        id: &str,
        recipe_name: &str,
        request: &Value,
        runs: &Value,
        created_by: Option<&str>,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO gauge_studies (id, recipe_name, request, runs, created_by, created_at) \
             VALUES (?, ?, ?, ?, ?, ?)",
        )
        .bind(id)
        .bind(recipe_name)
        .bind(request.to_string())
        .bind(runs.to_string())
        .bind(created_by)
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Replaces the runs of a study (their job ids once submitted).
    pub async fn update_gauge_runs(&self, id: &str, runs: &Value) -> StoreResult<()> {
        sqlx::query("UPDATE gauge_studies SET runs = ? WHERE id = ?")
            .bind(runs.to_string())
            .bind(id)
            .execute(&self.pool)
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
    let json = |c: &str| -> StoreResult<Value> {
        let s: String = r.try_get(c)?;
        serde_json::from_str(&s)
            .map_err(|e| crate::StoreError::Corrupt(format!("gauge_studies.{c}: {e}")))
    };
    Ok(GaugeStudyRow {
        id: r.try_get("id")?,
        recipe_name: r.try_get("recipe_name")?,
        request: json("request")?,
        runs: json("runs")?,
        created_by: r.try_get("created_by")?,
        created_at: r.try_get("created_at")?,
    })
}
