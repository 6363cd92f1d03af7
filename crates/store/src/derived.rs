//! Derived documents of a fit (diagnostics JSON, SVG plots), stored once.

use super::{now, Store, StoreResult};
use sqlx::Row;

/// One stored answer: HTTP status, content type, body.
#[derive(Debug, Clone, PartialEq)]
pub struct Derived {
    pub name: String,
    pub status: u16,
    pub content_type: String,
    pub body: Vec<u8>,
}

impl Store {
    /// The stored answer `name` of a measurement's fit (`fit_id` "" = its own).
    pub async fn get_derived(
        &self,
        measurement_id: &str,
        fit_id: &str,
        name: &str,
    ) -> StoreResult<Option<Derived>> {
        let row = sqlx::query(
            "SELECT status, content_type, body FROM derived \
             WHERE measurement_id = ? AND fit_id = ? AND name = ?",
        )
        .bind(measurement_id.to_string())
        .bind(fit_id.to_string())
        .bind(name.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| Derived {
            name: name.to_string(),
            status: r.get::<i64, _>(0) as u16,
            content_type: r.get(1),
            body: r.get(2),
        }))
    }

    /// Keeps all derived answers of one computation in one transaction (a
    /// concurrent identical computation keeps the first).
    pub async fn put_derived(
        &self,
        measurement_id: &str,
        fit_id: &str,
        items: &[Derived],
    ) -> StoreResult<()> {
        let mut tx = self.begin_write().await?;
        let t = now();
        for d in items {
            sqlx::query(
                "INSERT OR IGNORE INTO derived (measurement_id, fit_id, name, status, content_type, body, software_version, created_at) \
                 VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            )
            .bind(measurement_id.to_string())
            .bind(fit_id.to_string())
            .bind(d.name.clone())
            .bind(d.status as i64)
            .bind(d.content_type.clone())
            .bind(d.body.clone())
            .bind(springbench_core::VERSION)
            .bind(t.clone())
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }
}
