//! Imports with an idempotency key (migration `0190_import_idempotency.sql`).

use super::{insert_results, now, NewMeasurement, NewRecording, Store, StoreResult};
use sqlx::Row;

/// What an import with a key stored (or found stored before).
#[derive(Debug, Clone, PartialEq)]
pub enum ImportInserted {
    New,
    /// The key was used before with the same fields: that measurement.
    Replayed(String),
    /// The key was used before with other fields: that measurement.
    Conflict(String),
}

impl Store {
    /// The measurement stored under an import key, with the fields' hash.
    pub async fn import_by_key(&self, key: &str) -> StoreResult<Option<(String, String)>> {
        let row = sqlx::query(
            "SELECT measurement_id, request_sha256 FROM import_keys WHERE idempotency_key = ?",
        )
        .bind(key.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| (r.get(0), r.get(1))))
    }

    /// [`Store::insert_measurements`] of one import, with its key (and the
    /// fields' SHA-256) in the same transaction: of two concurrent imports
    /// with one key, one stores and the other finds it.
    pub async fn insert_import(
        &self,
        part: (&str, Option<&str>, Option<&str>),
        recordings: Vec<NewRecording>,
        measurement: NewMeasurement,
        key: Option<(&str, &str)>,
    ) -> StoreResult<ImportInserted> {
        let decide = |found: Option<(String, String)>, sha: &str| match found {
            Some((m, s)) if s == sha => Some(ImportInserted::Replayed(m)),
            Some((m, _)) => Some(ImportInserted::Conflict(m)),
            None => None,
        };
        if let Some((k, sha)) = key {
            if let Some(x) = decide(self.import_by_key(k).await?, sha) {
                return Ok(x);
            }
        }
        self.upsert_part(part.0, part.1, part.2).await?;
        let mut tx = self.pool.begin().await?;
        let mid = measurement.id.clone();
        insert_results(&mut tx, recordings, vec![measurement]).await?;
        if let Some((k, sha)) = key {
            let r = sqlx::query(
                "INSERT INTO import_keys (idempotency_key, request_sha256, measurement_id, created_at) VALUES (?, ?, ?, ?)",
            )
            .bind(k.to_string())
            .bind(sha.to_string())
            .bind(mid)
            .bind(now())
            .execute(&mut *tx)
            .await;
            match r {
                Ok(_) => {}
                Err(sqlx::Error::Database(e)) if e.is_unique_violation() => {
                    // A concurrent import with this key won: nothing of ours is kept.
                    drop(tx);
                    return match decide(self.import_by_key(k).await?, sha) {
                        Some(x) => Ok(x),
                        None => Err(super::StoreError::Corrupt(format!(
                            "import key {k} vanished"
                        ))),
                    };
                }
                Err(e) => return Err(e.into()),
            }
        }
        tx.commit().await?;
        Ok(ImportInserted::New)
    }
}
