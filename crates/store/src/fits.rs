//! Fits of a stored measurement and the choice of the one that supplies its
//! headline figures (who, when; every choice kept).

use crate::results::{Fit, FitReads, HeadlineChoice};
use crate::{now, parse_json, Store, StoreResult};
use serde_json::Value;
use sqlx::Row;

impl Store {
    /// Keeps a fit of a stored measurement (effects, order, the refitted report).
    pub async fn insert_fit(
        &self,
        id: &str,
        measurement_id: &str,
        request: &Value,
        result: &Value,
    ) -> StoreResult<Fit> {
        let t = now();
        sqlx::query(
            "INSERT INTO fits (id, measurement_id, request_json, result_json, software_version, created_at) \
             VALUES (?, ?, ?, ?, ?, ?)",
        )
        .bind(id.to_string())
        .bind(measurement_id.to_string())
        .bind(request.to_string())
        .bind(result.to_string())
        .bind(springbench_core::VERSION)
        .bind(t.clone())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(Fit {
            id: id.to_string(),
            measurement_id: measurement_id.to_string(),
            request: request.clone(),
            result: result.clone(),
            software_version: springbench_core::VERSION.to_string(),
            created_at: t,
        })
    }

    /// Records who chose which fit (None: the measurement's own result) to
    /// supply the measurement's headline; every choice is kept.
    pub async fn choose_headline(
        &self,
        measurement_id: &str,
        fit_id: Option<&str>,
        chosen_by: Option<&str>,
    ) -> StoreResult<HeadlineChoice> {
        let t = now();
        sqlx::query(
            "INSERT INTO headline_choices (measurement_id, fit_id, chosen_by, chosen_at) VALUES (?, ?, ?, ?)",
        )
        .bind(measurement_id.to_string())
        .bind(fit_id.map(str::to_string))
        .bind(chosen_by.map(str::to_string))
        .bind(t.clone())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(HeadlineChoice {
            fit_id: fit_id.map(str::to_string),
            chosen_by: chosen_by.map(str::to_string),
            chosen_at: t,
        })
    }
}

impl FitReads for Store {
    async fn list_fits(&self, measurement_id: &str) -> StoreResult<Vec<Fit>> {
        let rows = sqlx::query(
            "SELECT id, measurement_id, request_json, result_json, software_version, created_at \
             FROM fits WHERE measurement_id = ? ORDER BY seq",
        )
        .bind(measurement_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(Fit {
                    id: r.get(0),
                    measurement_id: r.get(1),
                    request: parse_json(&r.get::<String, _>(2))?,
                    result: parse_json(&r.get::<String, _>(3))?,
                    software_version: r.get(4),
                    created_at: r.get(5),
                })
            })
            .collect()
    }

    async fn headline_choice(&self, measurement_id: &str) -> StoreResult<Option<HeadlineChoice>> {
        let row = sqlx::query(
            "SELECT fit_id, chosen_by, chosen_at FROM headline_choices \
             WHERE measurement_id = ? ORDER BY seq DESC LIMIT 1",
        )
        .bind(measurement_id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| HeadlineChoice {
            fit_id: r.get(0),
            chosen_by: r.get(1),
            chosen_at: r.get(2),
        }))
    }
}
