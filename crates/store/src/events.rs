//! Events: an append-only log with sequence numbers (the websocket replays it).

use crate::{now, parse_json, Store, StoreResult};
use serde::Serialize;
use serde_json::Value;
use sqlx::Row;

#[derive(Debug, Clone, Serialize)]
pub struct Event {
    pub seq: i64,
    pub time: String,
    #[serde(rename = "type")]
    pub kind: String,
    pub job_id: Option<String>,
    pub data: Value,
}

impl Store {
    /// Appends an event; returns it with its sequence number.
    pub async fn append_event(
        &self,
        kind: &str,
        job_id: Option<&str>,
        data: &Value,
    ) -> StoreResult<Event> {
        let time = now();
        let row = sqlx::query(
            "INSERT INTO events (time, type, job_id, data_json) VALUES (?, ?, ?, ?) RETURNING seq",
        )
        .bind(time.clone())
        .bind(kind.to_string())
        .bind(job_id.map(str::to_string))
        .bind(data.to_string())
        .fetch_one(&mut *self.writer().await?)
        .await?;
        Ok(Event {
            seq: row.get(0),
            time,
            kind: kind.to_string(),
            job_id: job_id.map(str::to_string),
            data: data.clone(),
        })
    }

    pub async fn events_after(&self, after: i64, limit: i64) -> StoreResult<Vec<Event>> {
        let rows = sqlx::query(
            "SELECT seq, time, type, job_id, data_json FROM events WHERE seq > ? ORDER BY seq LIMIT ?",
        )
        .bind(after)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(Event {
                    seq: r.get(0),
                    time: r.get(1),
                    kind: r.get(2),
                    job_id: r.get(3),
                    data: parse_json(&r.get::<String, _>(4))?,
                })
            })
            .collect()
    }

    pub async fn last_event_seq(&self) -> StoreResult<i64> {
        let r = sqlx::query("SELECT COALESCE(MAX(seq), 0) FROM events")
            .fetch_one(&self.pool)
            .await?;
        Ok(r.get(0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[tokio::test]
    async fn events_have_increasing_sequence_numbers() {
        let s = Store::memory().await.unwrap();
        let a = s
            .append_event("job.state", Some("j"), &json!({"state": "queued"}))
            .await
            .unwrap();
        let b = s
            .append_event("job.progress", Some("j"), &json!({"progress": 0.1}))
            .await
            .unwrap();
        assert!(b.seq > a.seq);
        let after = s.events_after(a.seq, 10).await.unwrap();
        assert_eq!(after.len(), 1);
        assert_eq!(after[0].data["progress"], json!(0.1));
        assert_eq!(s.last_event_seq().await.unwrap(), b.seq);
    }

    /// A write waits its turn behind a writer that writes back to back (a
    /// running job's progress and events): SQLite's own busy handler polls
    /// with sleeps of up to 100 ms and hands the lock to whoever asks when it
    /// is free, nearly always the writer that just let it go. A job submitted
    /// while a bench streamed its progress waited up to 1.3 s for its write
    /// lock (fleet.rs's retired-recipe test lost its race so). Counted in
    /// the hammer's events committed between the probe's start and its own
    /// event, never in time: first come first served lets through at most
    /// the hammer's write in flight and the one it began meanwhile.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_write_is_not_starved_by_a_writer_that_writes_back_to_back() {
        use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
        use std::sync::Arc;
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).await.unwrap();
        let (writes, stop) = (
            Arc::new(AtomicU64::new(0)),
            Arc::new(AtomicBool::new(false)),
        );
        let hammer = {
            let (s, writes, stop) = (s.clone(), writes.clone(), stop.clone());
            tokio::spawn(async move {
                let data = json!({"step": "sweep", "progress": 0.5});
                while !stop.load(Ordering::SeqCst) {
                    s.append_event("job.progress", Some("j"), &data)
                        .await
                        .unwrap();
                    writes.fetch_add(1, Ordering::SeqCst);
                }
            })
        };
        while writes.load(Ordering::SeqCst) < 5 {
            tokio::task::yield_now().await;
        }
        let mut overtaken = vec![];
        for k in 0..50 {
            let before = s.last_event_seq().await.unwrap();
            let e = s
                .append_event("job.state", Some("probe"), &json!({"k": k}))
                .await
                .unwrap();
            overtaken.push(e.seq - before - 1);
        }
        stop.store(true, Ordering::SeqCst);
        hammer.await.unwrap();
        assert!(
            overtaken.iter().all(|&n| n <= 2),
            "the hammer's events committed while each probe waited: {overtaken:?}"
        );
    }
}
