//! Raw signals in the store: reading a recording back, the retention policy
//! (raw signals removed, results never), disk usage for `/metrics`.

use super::{now, Store, StoreError, StoreResult};
use serde::{Deserialize, Serialize};
use springbench_core::recording::ChannelScale;
use sqlx::Row;
use std::path::Path;

/// A stored recording as the store holds it ([`springbench_recording::codec`]).
#[derive(Debug, Clone)]
pub struct StoredRecording {
    /// FLAC or WAV bytes, standard layout; empty once pruned.
    pub bytes: Vec<u8>,
    /// Physical value of full scale per channel (`None`: float32 in physical units).
    pub channel_scale: Option<ChannelScale>,
    pub frames: i64,
    pub sample_rate_hz: f64,
    /// When the retention policy removed the raw signals.
    pub pruned_at: Option<String>,
}

/// A stored recording without its bytes ([`Store::recording_info`]); the
/// bytes are read in chunks by a [`BlobReader`].
#[derive(Debug, Clone)]
pub struct RecordingInfo {
    pub blob: super::blob::BlobRef,
    pub channel_scale: Option<ChannelScale>,
    pub frames: i64,
    pub sample_rate_hz: f64,
    pub pruned_at: Option<String>,
}

/// `std::io::Read` over a stored recording's bytes, one chunk of the blob
/// per call (SQLite incremental blob I/O on a pooled connection taken for
/// the call). Blocking: call it off the async workers (`spawn_blocking`);
/// wrap it in a `BufReader` (each call is a query).
pub struct BlobReader {
    store: Store,
    blob: super::blob::BlobRef,
    pos: u64,
    rt: tokio::runtime::Handle,
}

/// Largest read per call (one blob open, walk and read in SQLite).
const READ_CHUNK: usize = 1 << 20;

impl std::io::Read for BlobReader {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.pos >= self.blob.len || buf.is_empty() {
            return Ok(0);
        }
        let n = buf.len().min(READ_CHUNK);
        let (store, blob, pos) = (&self.store, &self.blob, self.pos);
        let got = self
            .rt
            .block_on(async move {
                let mut conn = store.pool.acquire().await?;
                super::blob::read_chunk(&mut conn, blob, pos, &mut buf[..n]).await
            })
            .map_err(std::io::Error::other)?;
        self.pos += got as u64;
        Ok(got)
    }
}

/// What one retention pass removed.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct RetentionReport {
    pub recordings_pruned: i64,
    pub bytes_freed: i64,
}

/// Recordings whose raw signals the policy lets go: not referenced by a
/// measurement that is among the last `?1` of its part or younger than `?2`.
macro_rules! prunable {
    () => {
        "WITH ranked AS ( \
       SELECT pre_recording_id AS pre, main_recording_id AS main, created_at, \
              ROW_NUMBER() OVER (PARTITION BY part_serial ORDER BY seq DESC) AS rn \
       FROM measurements), \
     keep AS ( \
       SELECT pre AS rid FROM ranked WHERE rn <= ?1 OR created_at >= ?2 \
       UNION SELECT main FROM ranked WHERE rn <= ?1 OR created_at >= ?2) \
     SELECT id FROM recordings WHERE pruned_at IS NULL AND id NOT IN (SELECT rid FROM keep)"
    };
}

/// The static SQL selecting `$cols` of a measurement's `pre` or `main`
/// recording (`r`, joined with its large-import blob `b`), by `$which`;
/// None for another name.
macro_rules! recording_select {
    ($which:expr, $cols:literal) => {{
        macro_rules! sel {
            ($col:literal) => {
                concat!(
                    "SELECT ",
                    $cols,
                    " FROM measurements m JOIN recordings r ON r.id = m.",
                    $col,
                    " LEFT JOIN recording_blobs b ON b.recording_id = r.id WHERE m.id = ?"
                )
            };
        }
        match $which {
            "pre" => Some(sel!("pre_recording_id")),
            "main" => Some(sel!("main_recording_id")),
            _ => None,
        }
    }};
}

impl Store {
    /// A measurement's `pre` or `main` recording.
    pub async fn get_recording(
        &self,
        measurement_id: &str,
        which: &str,
    ) -> StoreResult<Option<StoredRecording>> {
        let sql = recording_select!(
            which,
            "COALESCE(b.bytes, r.wav) AS wav, r.channel_scale_json, r.frames, r.sample_rate_hz, r.pruned_at"
        );
        let row = self.recording_row(measurement_id, sql).await?;
        row.map(|r| {
            Ok(StoredRecording {
                bytes: r.get(0),
                channel_scale: scale_of(r.get(1))?,
                frames: r.get(2),
                sample_rate_hz: r.get(3),
                pruned_at: r.get(4),
            })
        })
        .transpose()
    }

    /// A measurement's `pre` or `main` recording without its bytes (their
    /// length only: SQLite does not load a blob for `length()`).
    pub async fn recording_info(
        &self,
        measurement_id: &str,
        which: &str,
    ) -> StoreResult<Option<RecordingInfo>> {
        let sql = recording_select!(
            which,
            "r.id, b.recording_id IS NOT NULL, COALESCE(length(b.bytes), length(r.wav)), \
             r.channel_scale_json, r.frames, r.sample_rate_hz, r.pruned_at"
        );
        let row = self.recording_row(measurement_id, sql).await?;
        row.map(|r| {
            Ok(RecordingInfo {
                blob: super::blob::BlobRef {
                    rowid: r.get(0),
                    in_blobs: r.get(1),
                    len: r.get::<i64, _>(2).max(0) as u64,
                },
                channel_scale: scale_of(r.get(3))?,
                frames: r.get(4),
                sample_rate_hz: r.get(5),
                pruned_at: r.get(6),
            })
        })
        .transpose()
    }

    /// The row `sql` (from [`recording_select!`]) selects for a measurement;
    /// None for an unknown `which` (`sql` None) or no row.
    async fn recording_row(
        &self,
        measurement_id: &str,
        sql: Option<&'static str>,
    ) -> StoreResult<Option<sqlx::sqlite::SqliteRow>> {
        let Some(sql) = sql else {
            return Ok(None);
        };
        Ok(sqlx::query(sql)
            .bind(measurement_id.to_string())
            .fetch_optional(&self.pool)
            .await?)
    }

    /// A reader of a stored recording's bytes (see [`BlobReader`]); call it
    /// inside the runtime, read it outside (`spawn_blocking`).
    pub fn blob_reader(&self, blob: super::blob::BlobRef) -> BlobReader {
        BlobReader {
            store: self.clone(),
            blob,
            pos: 0,
            rt: tokio::runtime::Handle::current(),
        }
    }

    /// Applies the retention policy once: the raw signals of recordings the
    /// policy does not keep are removed (the row, its frame count and the
    /// measurement stay; results, fits, jobs and configurations are never
    /// touched). Nothing happens when the policy sets no limit.
    pub async fn prune_raw(&self, policy: &Retention) -> StoreResult<RetentionReport> {
        if policy.raw_max_age_days.is_none() && policy.raw_keep_last_per_part.is_none() {
            return Ok(RetentionReport::default());
        }
        let cutoff = policy.raw_max_age_days.map(|d| {
            let ms = (d * 86_400_000.0).clamp(0.0, 1e15) as i64;
            (chrono::Utc::now() - chrono::Duration::milliseconds(ms))
                .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
        });
        let keep_last = policy.raw_keep_last_per_part.map(i64::from);
        let mut tx = self.begin_write().await?;
        let row = sqlx::query(concat!(
            "SELECT COUNT(*), COALESCE(SUM(length(wav) + COALESCE((SELECT length(bytes) FROM recording_blobs \
             WHERE recording_id = recordings.id), 0)), 0) FROM recordings WHERE id IN (",
            prunable!(),
            ")"
        ))
        .bind(keep_last)
        .bind(cutoff.clone())
        .fetch_one(&mut *tx)
        .await?;
        let report = RetentionReport {
            recordings_pruned: row.get(0),
            bytes_freed: row.get(1),
        };
        sqlx::query(concat!(
            "DELETE FROM recording_blobs WHERE recording_id IN (",
            prunable!(),
            ")"
        ))
        .bind(keep_last)
        .bind(cutoff.clone())
        .execute(&mut *tx)
        .await?;
        sqlx::query(concat!(
            "UPDATE recordings SET wav = X'', pruned_at = ?3 WHERE id IN (",
            prunable!(),
            ")"
        ))
        .bind(keep_last)
        .bind(cutoff)
        .bind(now())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(report)
    }

    /// (bytes of raw signals held, recordings held, recordings pruned).
    pub async fn raw_usage(&self) -> StoreResult<(i64, i64, i64)> {
        let r = sqlx::query(
            "SELECT COALESCE(SUM(length(wav)), 0) + (SELECT COALESCE(SUM(length(bytes)), 0) FROM recording_blobs), \
                    COALESCE(SUM(pruned_at IS NULL), 0), COALESCE(SUM(pruned_at IS NOT NULL), 0) \
             FROM recordings",
        )
        .fetch_one(&self.pool)
        .await?;
        Ok((r.get(0), r.get(1), r.get(2)))
    }
}

pub(crate) fn scale_of(json: Option<String>) -> StoreResult<Option<ChannelScale>> {
    json.map(|s| {
        serde_json::from_str(&s)
            .map_err(|e| StoreError::Corrupt(format!("stored channel scale unreadable: {e}")))
    })
    .transpose()
}

/// Bytes of the files under `dir` (the database, its WAL and anything else
/// kept there); unreadable entries count as 0.
pub fn dir_bytes(dir: &Path) -> u64 {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.flatten()
        .map(|e| match e.metadata() {
            Ok(m) if m.is_dir() => dir_bytes(&e.path()),
            Ok(m) => m.len(),
            Err(_) => 0,
        })
        .sum()
}

/// How long raw signals are kept (decision 0013). A recording is kept while
/// it is younger than `raw_max_age_days` **or** belongs to one of the last
/// `raw_keep_last_per_part` measurements of its part; an unset limit keeps
/// nothing by itself, both unset keep everything. Results, fits, verdicts,
/// jobs and configurations are always kept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Retention {
    pub raw_max_age_days: Option<f64>,
    pub raw_keep_last_per_part: Option<u32>,
    /// Seconds between two retention passes (the first runs at start).
    pub interval_s: f64,
}

impl Default for Retention {
    fn default() -> Self {
        Retention {
            raw_max_age_days: None,
            raw_keep_last_per_part: None,
            interval_s: 3600.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::{FitReads, MeasurementReads};
    use crate::{NewMeasurement, NewRecording};
    use serde_json::json;

    fn rec(kind: &'static str, fill: u8) -> NewRecording {
        NewRecording {
            kind,
            sample_rate_hz: 48000.0,
            frames: 1000,
            stored: springbench_recording::codec::Stored {
                bytes: vec![fill; 1000],
                channel_scale: None,
            },
        }
    }

    fn meas(id: &str, serial: &str) -> NewMeasurement {
        NewMeasurement {
            id: id.into(),
            part_serial: serial.into(),
            job_id: None,
            source: "import",
            bench_id: None,
            config: serde_json::from_value(json!({"analysis": {"method": "two-signal"}})).unwrap(),
            meta: crate::Doc::Received(json!({"moving_mass_kg": 0.05})),
            result: Some(crate::Doc::Received(
                json!({"large_signal": {"keff_n_per_m": 1000.0}}),
            )),
            analysis_error: None,
            target_xpeak_m: None,
            repeat_index: None,
            level_index: None,
            pre: 0,
            main: 1,
        }
    }

    async fn setback(s: &Store, id: &str, days: f64) {
        let t = (chrono::Utc::now() - chrono::Duration::milliseconds((days * 86_400_000.0) as i64))
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, true);
        sqlx::query("UPDATE measurements SET created_at = ? WHERE id = ?")
            .bind(t)
            .bind(id.to_string())
            .execute(&s.pool)
            .await
            .unwrap();
    }

    #[tokio::test]
    async fn retention_removes_raw_signals_and_never_results() {
        let s = Store::memory().await.unwrap();
        // Part A: 4 measurements (a0 oldest); part B: 1, 40 days old.
        for i in 0..4u8 {
            s.insert_measurements(
                ("A", None, None),
                vec![rec("pre", i), rec("main", 10 + i)],
                vec![meas(&format!("a{i}"), "A")],
            )
            .await
            .unwrap();
        }
        s.insert_measurements(
            ("B", None, None),
            vec![rec("pre", 20), rec("main", 21)],
            vec![meas("b0", "B")],
        )
        .await
        .unwrap();
        s.insert_fit("f1", "a0", &json!({"effects": []}), &json!({"k": 1}))
            .await
            .unwrap();
        setback(&s, "a0", 40.0).await;
        setback(&s, "a1", 20.0).await;
        setback(&s, "b0", 40.0).await;
        assert_eq!(s.raw_usage().await.unwrap(), (10_000, 10, 0));

        // No limit configured: nothing goes.
        let none = Retention::default();
        assert_eq!(
            s.prune_raw(&none).await.unwrap(),
            RetentionReport::default()
        );

        // Keep the last 2 per part: a0 and a1 lose their raw signals.
        let last2 = Retention {
            raw_keep_last_per_part: Some(2),
            ..Retention::default()
        };
        let r = s.prune_raw(&last2).await.unwrap();
        assert_eq!(
            r,
            RetentionReport {
                recordings_pruned: 4,
                bytes_freed: 4000
            }
        );
        for (id, gone) in [
            ("a0", true),
            ("a1", true),
            ("a2", false),
            ("a3", false),
            ("b0", false),
        ] {
            for which in ["pre", "main"] {
                let rec = s.get_recording(id, which).await.unwrap().unwrap();
                assert_eq!(rec.pruned_at.is_some(), gone, "{id} {which}");
                assert_eq!(rec.bytes.is_empty(), gone, "{id} {which}");
                assert_eq!(rec.frames, 1000);
            }
        }
        // A second pass has nothing more to do.
        assert_eq!(s.prune_raw(&last2).await.unwrap().recordings_pruned, 0);

        // Keep 30 days or the last 1: b0 (40 days old, but the last of B) and
        // a2 (young) stay; nothing more goes.
        let both = Retention {
            raw_max_age_days: Some(30.0),
            raw_keep_last_per_part: Some(1),
            ..Retention::default()
        };
        let r = s.prune_raw(&both).await.unwrap();
        assert_eq!(r.recordings_pruned, 0);
        assert!(s
            .get_recording("b0", "pre")
            .await
            .unwrap()
            .unwrap()
            .pruned_at
            .is_none());
        // Only 30 days: b0 goes too.
        let age = Retention {
            raw_max_age_days: Some(30.0),
            ..Retention::default()
        };
        assert_eq!(s.prune_raw(&age).await.unwrap().recordings_pruned, 2);
        assert!(s
            .get_recording("b0", "main")
            .await
            .unwrap()
            .unwrap()
            .pruned_at
            .is_some());

        // Every result, fit, configuration and meta is still there.
        for id in ["a0", "a1", "a2", "a3", "b0"] {
            let (info, result, meta) = s.get_measurement(id).await.unwrap().unwrap();
            assert_eq!(
                result.unwrap()["large_signal"]["keff_n_per_m"],
                json!(1000.0)
            );
            assert_eq!(info.config["analysis"]["method"], json!("two-signal"));
            assert_eq!(meta["moving_mass_kg"], json!(0.05));
        }
        assert_eq!(s.list_fits("a0").await.unwrap().len(), 1);
        assert_eq!(s.counts().await.unwrap(), (2, 5));
        let (bytes, kept, pruned) = s.raw_usage().await.unwrap();
        assert_eq!((kept + pruned, bytes), (10, kept * 1000));
    }
}
