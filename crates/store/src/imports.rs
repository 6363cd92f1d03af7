//! Imports with an idempotency key (migration `0190_import_idempotency.sql`).

use super::measurements::insert_measurement_rows;
use super::{now, NewMeasurement, Store, StoreResult};
use springbench_core::recording::ChannelScale;
use sqlx::Row;
use std::path::Path;

/// A recording to store whose bytes (FLAC or WAV, standard layout) are in a
/// file: written into the database in chunks ([`super::blob`]).
pub struct RecordingFile<'a> {
    pub kind: &'static str,
    pub sample_rate_hz: f64,
    pub frames: i64,
    pub path: &'a Path,
    pub channel_scale: ChannelScale,
}

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
        recordings: Vec<RecordingFile<'_>>,
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
        let mut tx = self.begin_write().await?;
        let mid = measurement.id.clone();
        let mut rec_ids = vec![];
        for r in recordings {
            let len = std::fs::metadata(r.path)
                .map_err(|e| super::StoreError::Corrupt(format!("recording file: {e}")))?
                .len() as i64;
            let row = sqlx::query(
                "INSERT INTO recordings (kind, sample_rate_hz, frames, wav, channel_scale_json, created_at) \
                 VALUES (?, ?, ?, X'', ?, ?) RETURNING id",
            )
            .bind(r.kind)
            .bind(r.sample_rate_hz)
            .bind(r.frames)
            .bind(serde_json::to_string(&r.channel_scale).unwrap_or_default())
            .bind(now())
            .fetch_one(&mut *tx)
            .await?;
            let id: i64 = row.get(0);
            sqlx::query(
                "INSERT INTO recording_blobs (recording_id, bytes) VALUES (?, zeroblob(?))",
            )
            .bind(id)
            .bind(len)
            .execute(&mut *tx)
            .await?;
            super::blob::fill_recording(&mut tx, id, r.path).await?;
            rec_ids.push(id);
        }
        insert_measurement_rows(&mut tx, vec![measurement], &rec_ids).await?;
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
