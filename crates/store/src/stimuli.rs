//! Stimulus files uploaded to the station (issue 32, decision 0144): the
//! WAV files a long-term test plays, kept as sent and named by the SHA-256
//! of their bytes.

use crate::{now, Store, StoreResult};
use sqlx::Row;

/// What the daemon read from an uploaded WAV file (no samples).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct StimulusInfo {
    /// The SHA-256 of the file's bytes (64 hex digits): `stimulus.wav_id`.
    pub id: String,
    /// When it was first uploaded (RFC 3339 UTC).
    pub created_at: String,
    pub uploaded_by: Option<String>,
    /// The name the uploader gave (`?name=`), for people; not used.
    pub file_name: Option<String>,
    pub sample_rate_hz: u32,
    pub frames: u64,
    /// Length of one pass of the loop (s).
    pub duration_s: f64,
    /// Bits per sample and `int` or `float`.
    pub bits: u16,
    pub sample_format: String,
    /// RMS and peak of the samples (full scale = 1; the level played is set
    /// by the test's `excursion_rms_m`, not by these).
    pub rms_fs: f64,
    pub peak_fs: f64,
    /// Size of the file (bytes).
    pub size_bytes: u64,
}

/// An uploaded file to keep: its id and what was read from it (the store
/// stamps the time; duration and size follow from the row).
#[derive(Debug, Clone)]
pub struct NewStimulus<'a> {
    pub id: &'a str,
    pub uploaded_by: Option<&'a str>,
    pub file_name: Option<&'a str>,
    pub sample_rate_hz: u32,
    pub frames: u64,
    pub bits: u16,
    pub sample_format: &'a str,
    pub rms_fs: f64,
    pub peak_fs: f64,
}

fn info(r: &sqlx::sqlite::SqliteRow) -> StimulusInfo {
    let rate: i64 = r.get("sample_rate_hz");
    let frames: i64 = r.get("frames");
    let bits: i64 = r.get("bits");
    let size: i64 = r.get("size_bytes");
    StimulusInfo {
        id: r.get("id"),
        created_at: r.get("created_at"),
        uploaded_by: r.get("uploaded_by"),
        file_name: r.get("file_name"),
        sample_rate_hz: rate as u32,
        frames: frames as u64,
        duration_s: frames as f64 / rate as f64,
        bits: bits as u16,
        sample_format: r.get("sample_format"),
        rms_fs: r.get("rms_fs"),
        peak_fs: r.get("peak_fs"),
        size_bytes: size as u64,
    }
}

macro_rules! cols {
    () => {
        "id, created_at, uploaded_by, file_name, sample_rate_hz, frames, bits, \
         sample_format, rms_fs, peak_fs, length(bytes) AS size_bytes"
    };
}

impl Store {
    /// Keeps an uploaded file (`info` read from `bytes`); the same bytes
    /// again change nothing. Returns the stored info and whether it is new.
    pub async fn put_stimulus(
        &self,
        info: &NewStimulus<'_>,
        bytes: &[u8],
    ) -> StoreResult<(StimulusInfo, bool)> {
        let done = sqlx::query(
            "INSERT OR IGNORE INTO stimuli (id, created_at, uploaded_by, file_name, sample_rate_hz, \
             frames, bits, sample_format, rms_fs, peak_fs, bytes) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(info.id)
        .bind(now())
        .bind(info.uploaded_by)
        .bind(info.file_name)
        .bind(i64::from(info.sample_rate_hz))
        .bind(info.frames as i64)
        .bind(i64::from(info.bits))
        .bind(info.sample_format)
        .bind(info.rms_fs)
        .bind(info.peak_fs)
        .bind(bytes)
        .execute(&mut *self.writer().await?)
        .await?;
        let stored = self.stimulus(info.id).await?.ok_or_else(|| {
            crate::StoreError::Corrupt(format!("stimulus {} not found after storing it", info.id))
        })?;
        Ok((stored, done.rows_affected() == 1))
    }

    /// One stimulus' info (None: no such id).
    pub async fn stimulus(&self, id: &str) -> StoreResult<Option<StimulusInfo>> {
        let row = sqlx::query(concat!("SELECT ", cols!(), " FROM stimuli WHERE id = ?"))
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.as_ref().map(info))
    }

    /// The file's bytes as uploaded (None: no such id).
    pub async fn stimulus_bytes(&self, id: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(sqlx::query_scalar("SELECT bytes FROM stimuli WHERE id = ?")
            .bind(id)
            .fetch_optional(&self.pool)
            .await?)
    }

    /// The station's stimuli, newest first.
    pub async fn list_stimuli(&self, limit: i64) -> StoreResult<Vec<StimulusInfo>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            cols!(),
            " FROM stimuli ORDER BY created_at DESC, id LIMIT ?"
        ))
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(info).collect())
    }
}
