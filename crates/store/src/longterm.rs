//! The long-term test's own rows (issue 32): its state, written with each
//! finished interval's measurement in one transaction (a daemon killed
//! during the test resumes where it stopped), the interval index, the
//! stored fit of the ageing law, the failure and the last signals.

use crate::measurements::{insert_measurement_rows, insert_results};
use crate::results::{NewMeasurement, NewRecording};
use crate::{now, Store, StoreError, StoreResult};
use serde::Serialize;
use springbench_core::ageing::series::AgeingDocument;
use springbench_core::job::{Failure, PartState};
use sqlx::Row;

/// Where a long-term test stands after its last finished interval.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LongTermState {
    /// Intervals finished (the next one's index).
    pub intervals_done: usize,
    /// Test time at the end of the last measurement (s).
    pub clock_s: f64,
    /// The part's accumulated load then (J).
    pub load_j: f64,
    pub part: PartState,
    /// The ageing law fitted over the intervals so far.
    pub document: Option<AgeingDocument>,
    /// The failure limit that stopped the test.
    pub failure: Option<Failure>,
    /// Each time the test was resumed after a crash, a kill or a stop.
    pub resumptions: Vec<Resumption>,
    pub updated_at: String,
}

/// A resumption of a test cut off by a crash, a kill or a stop.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct Resumption {
    /// When the daemon put it back in the queue.
    pub at: String,
    /// Intervals stored then (the next one is run next).
    pub intervals_done: usize,
    /// The part's load then (J).
    pub load_j: f64,
}

/// One finished interval: an ordinary stored measurement linked to the test.
// Deserialize: read back at the fleet's center from the station's document (decision 0134).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct LongTermInterval {
    pub index: usize,
    pub measurement_id: String,
    /// Test time at the measurement's start (s).
    pub elapsed_s: f64,
    /// The load the part had taken then (J).
    pub load_j: f64,
    /// Run faster than real time (virtual bench).
    pub accelerated: bool,
    pub created_at: String,
    /// Air temperature at the interval (K), when known.
    pub temperature_k: Option<f64>,
    /// Where it came from.
    pub temperature_source: Option<AmbientSource>,
    /// Relative humidity at the interval (%), when known.
    pub relative_humidity_percent: Option<f64>,
    pub humidity_source: Option<AmbientSource>,
}

/// Where an interval's ambient value came from (decision 0130).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum AmbientSource {
    /// The bench's configured sensor, read at the interval's start.
    Sensor,
    /// Entered by hand (it replaces the sensor's).
    Hand,
}

impl AmbientSource {
    pub fn as_str(self) -> &'static str {
        match self {
            AmbientSource::Sensor => "sensor",
            AmbientSource::Hand => "hand",
        }
    }

    fn parse(s: Option<String>) -> StoreResult<Option<AmbientSource>> {
        match s.as_deref() {
            None => Ok(None),
            Some("sensor") => Ok(Some(AmbientSource::Sensor)),
            Some("hand") => Ok(Some(AmbientSource::Hand)),
            Some(k) => Err(StoreError::Corrupt(format!("ambient source '{k}'"))),
        }
    }
}

/// What happened to a test between its intervals (decision 0125).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LongTermEventKind {
    /// The disk was full: the test waits before its next interval.
    Paused,
    /// Space returned: the test goes on.
    Resumed,
}

impl LongTermEventKind {
    fn as_str(self) -> &'static str {
        match self {
            LongTermEventKind::Paused => "paused",
            LongTermEventKind::Resumed => "resumed",
        }
    }
}

/// What paused a test (decision 0130).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PauseCause {
    /// The disk was full (decision 0125): the test resumes by itself.
    Disk,
    /// A user paused it (`POST .../pause`); a user resumes it.
    User,
}

impl PauseCause {
    fn as_str(self) -> &'static str {
        match self {
            PauseCause::Disk => "disk",
            PauseCause::User => "user",
        }
    }
}

/// The user's pause of a test in effect.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct UserPause {
    /// When it was asked for (RFC 3339).
    pub at: String,
    /// Who asked (the token's name; absent without authentication).
    pub by: Option<String>,
}

/// A pause or its end, with the test clock.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LongTermEvent {
    pub kind: LongTermEventKind,
    pub cause: PauseCause,
    /// Test time then (s).
    pub elapsed_s: f64,
    /// Why (the pause's reason).
    pub detail: String,
    pub at: String,
}

/// What one finished interval stores.
pub struct NewInterval {
    pub index: usize,
    pub elapsed_s: f64,
    pub load_j: f64,
    pub accelerated: bool,
    /// The interval's recordings (pre, main) and measurement (`pre`/`main` index them).
    pub recordings: Vec<NewRecording>,
    pub measurement: NewMeasurement,
    /// The test's state after it.
    pub clock_s: f64,
    pub part: PartState,
    pub document: Option<AgeingDocument>,
    /// The bench's sensor's reading at the interval's start (checked).
    pub ambient: springbench_core::job::Ambient,
}

fn to_json<T: Serialize>(v: &T) -> StoreResult<String> {
    // Never a stored NaN: a non-finite number is refused, not written as null.
    springbench_core::finite::to_value(v)
        .map(|v| v.to_string())
        .map_err(|e| StoreError::Invalid(e.to_string()))
}

fn from_json<T: serde::de::DeserializeOwned>(what: &str, s: &str) -> StoreResult<T> {
    serde_json::from_str(s).map_err(|e| StoreError::Corrupt(format!("{what} unreadable: {e}")))
}

impl Store {
    /// Stores a finished interval of running test `job_id` and the test's
    /// state after it, in one transaction. Refuses (nothing written) an
    /// interval that is not the next one: none is stored twice.
    pub async fn insert_long_term_interval(
        &self,
        job_id: &str,
        iv: NewInterval,
    ) -> StoreResult<()> {
        let part = to_json(&iv.part)?;
        let doc = iv.document.as_ref().map(to_json).transpose()?;
        let mut tx = self.begin_write().await?;
        crate::jobs::running_job(&mut tx, job_id).await?;
        let done: i64 = sqlx::query_scalar(
            "SELECT COALESCE((SELECT intervals_done FROM long_term_state WHERE job_id = ?), 0)",
        )
        .bind(job_id)
        .fetch_one(&mut *tx)
        .await?;
        if done != iv.index as i64 {
            return Err(StoreError::Invalid(format!(
                "interval {} of test {job_id}: {done} are stored, the next is {done}",
                iv.index
            )));
        }
        let mid = iv.measurement.id.clone();
        if let Some(e) = iv.ambient.check().first() {
            return Err(StoreError::Invalid(format!(
                "interval {} of test {job_id}: {}: {}",
                iv.index, e.field, e.message
            )));
        }
        let src = |v: Option<f64>| v.map(|_| AmbientSource::Sensor.as_str());
        let ids = insert_results(&mut tx, iv.recordings, vec![]).await?;
        insert_measurement_rows(&mut tx, vec![iv.measurement], &ids).await?;
        let t = now();
        sqlx::query(
            "INSERT INTO long_term_intervals (job_id, idx, measurement_id, elapsed_s, load_j, accelerated, created_at, \
             temperature_k, temperature_source, relative_humidity_percent, humidity_source) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(job_id)
        .bind(iv.index as i64)
        .bind(&mid)
        .bind(iv.elapsed_s)
        .bind(iv.load_j)
        .bind(iv.accelerated)
        .bind(&t)
        .bind(iv.ambient.temperature_k)
        .bind(src(iv.ambient.temperature_k))
        .bind(iv.ambient.relative_humidity_percent)
        .bind(src(iv.ambient.relative_humidity_percent))
        .execute(&mut *tx)
        .await?;
        sqlx::query(
            "INSERT INTO long_term_state (job_id, intervals_done, clock_s, load_j, part_state_json, document_json, updated_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(job_id) DO UPDATE SET intervals_done = excluded.intervals_done, \
             clock_s = excluded.clock_s, load_j = excluded.load_j, part_state_json = excluded.part_state_json, \
             document_json = excluded.document_json, updated_at = excluded.updated_at",
        )
        .bind(job_id)
        .bind(iv.index as i64 + 1)
        .bind(iv.clock_s)
        .bind(iv.part.load_j)
        .bind(part)
        .bind(doc)
        .bind(&t)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// The state of test `job_id` (None: no interval finished yet).
    pub async fn long_term_state(&self, job_id: &str) -> StoreResult<Option<LongTermState>> {
        let Some(r) = sqlx::query(
            "SELECT intervals_done, clock_s, load_j, part_state_json, document_json, failure_json, updated_at, \
             resumptions_json FROM long_term_state WHERE job_id = ?",
        )
        .bind(job_id)
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        Ok(Some(LongTermState {
            intervals_done: r.get::<i64, _>(0).max(0) as usize,
            clock_s: r.get(1),
            load_j: r.get(2),
            part: from_json("part state", &r.get::<String, _>(3))?,
            document: r
                .get::<Option<String>, _>(4)
                .map(|s| from_json("ageing document", &s))
                .transpose()?,
            failure: r
                .get::<Option<String>, _>(5)
                .map(|s| from_json("failure", &s))
                .transpose()?,
            updated_at: r.get(6),
            resumptions: from_json("resumptions", &r.get::<String, _>(7))?,
        }))
    }

    /// The finished intervals of test `job_id`, in order.
    pub async fn long_term_intervals(&self, job_id: &str) -> StoreResult<Vec<LongTermInterval>> {
        let rows = sqlx::query(
            "SELECT idx, measurement_id, elapsed_s, load_j, accelerated, created_at, \
             temperature_k, temperature_source, relative_humidity_percent, humidity_source \
             FROM long_term_intervals WHERE job_id = ? ORDER BY idx",
        )
        .bind(job_id)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(LongTermInterval {
                    index: r.get::<i64, _>(0).max(0) as usize,
                    measurement_id: r.get(1),
                    elapsed_s: r.get(2),
                    load_j: r.get(3),
                    accelerated: r.get(4),
                    created_at: r.get(5),
                    temperature_k: r.get(6),
                    temperature_source: AmbientSource::parse(r.get(7))?,
                    relative_humidity_percent: r.get(8),
                    humidity_source: AmbientSource::parse(r.get(9))?,
                })
            })
            .collect()
    }

    /// Enters by hand the ambient conditions of finished interval `index` of
    /// test `job_id` (each value given replaces the stored one, its source
    /// `hand`). False when the test has no such interval.
    pub async fn set_long_term_ambient(
        &self,
        job_id: &str,
        index: usize,
        ambient: springbench_core::job::Ambient,
    ) -> StoreResult<bool> {
        if let Some(e) = ambient.check().first() {
            return Err(StoreError::Invalid(format!("{}: {}", e.field, e.message)));
        }
        let hand = AmbientSource::Hand.as_str();
        let r = sqlx::query(
            "UPDATE long_term_intervals SET \
             temperature_k = COALESCE(?1, temperature_k), \
             temperature_source = CASE WHEN ?1 IS NULL THEN temperature_source ELSE ?3 END, \
             relative_humidity_percent = COALESCE(?2, relative_humidity_percent), \
             humidity_source = CASE WHEN ?2 IS NULL THEN humidity_source ELSE ?3 END \
             WHERE job_id = ?4 AND idx = ?5",
        )
        .bind(ambient.temperature_k)
        .bind(ambient.relative_humidity_percent)
        .bind(hand)
        .bind(job_id)
        .bind(index as i64)
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Records the failure limit that stopped running test `job_id`, and the
    /// last seconds of its signals (a recording), in one transaction.
    pub async fn set_long_term_failure(
        &self,
        job_id: &str,
        failure: &Failure,
        signals: Option<(NewRecording, f64)>,
    ) -> StoreResult<()> {
        let f = to_json(failure)?;
        let mut tx = self.begin_write().await?;
        crate::jobs::running_job(&mut tx, job_id).await?;
        let t = now();
        let r = sqlx::query(
            "UPDATE long_term_state SET failure_json = ?, updated_at = ? WHERE job_id = ?",
        )
        .bind(f)
        .bind(&t)
        .bind(job_id)
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() != 1 {
            return Err(StoreError::Invalid(format!(
                "test {job_id} has no finished interval to fail after"
            )));
        }
        if let Some(signals) = signals {
            insert_last_signals(&mut tx, job_id, signals, &t).await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// Stores the last signals of a test stopped by something other than a
    /// failure limit (a bench fault on a hardware or emulated bench): the
    /// recording and its duration (s).
    pub async fn set_long_term_last_signals(
        &self,
        job_id: &str,
        signals: (NewRecording, f64),
    ) -> StoreResult<()> {
        let mut tx = self.begin_write().await?;
        crate::jobs::running_job(&mut tx, job_id).await?;
        insert_last_signals(&mut tx, job_id, signals, &now()).await?;
        tx.commit().await?;
        Ok(())
    }

    /// The recording of the last signals of a failed test: (recording id, duration s).
    pub async fn long_term_signals(&self, job_id: &str) -> StoreResult<Option<(i64, f64)>> {
        let r =
            sqlx::query("SELECT recording_id, duration_s FROM long_term_signals WHERE job_id = ?")
                .bind(job_id)
                .fetch_optional(&self.pool)
                .await?;
        Ok(r.map(|r| (r.get(0), r.get(1))))
    }

    /// The stored last signals of a failed test, without their bytes.
    pub async fn long_term_signals_info(
        &self,
        job_id: &str,
    ) -> StoreResult<Option<crate::RecordingInfo>> {
        let row = sqlx::query(
            "SELECT r.id, b.recording_id IS NOT NULL, COALESCE(length(b.bytes), length(r.wav)), \
             r.channel_scale_json, r.frames, r.sample_rate_hz, r.pruned_at \
             FROM long_term_signals s JOIN recordings r ON r.id = s.recording_id \
             LEFT JOIN recording_blobs b ON b.recording_id = r.id WHERE s.job_id = ?",
        )
        .bind(job_id)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| {
            Ok(crate::RecordingInfo {
                blob: crate::blob::BlobRef {
                    rowid: r.get(0),
                    in_blobs: r.get(1),
                    len: r.get::<i64, _>(2).max(0) as u64,
                },
                channel_scale: crate::raw::scale_of(r.get(3))?,
                frames: r.get(4),
                sample_rate_hz: r.get(5),
                pruned_at: r.get(6),
            })
        })
        .transpose()
    }

    /// A running job back to `queued` (a long-term test cut off by a crash
    /// or a stop, resumed from its stored state); false when it is not running.
    /// The resumption is recorded with the test's state (when an interval
    /// was stored), in the same transaction.
    pub async fn requeue_running(&self, job_id: &str) -> StoreResult<bool> {
        let mut tx = self.begin_write().await?;
        let r = sqlx::query(
            "UPDATE jobs SET state = 'queued', step = NULL, eta_s = NULL WHERE id = ? AND state = 'running'",
        )
        .bind(job_id)
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() != 1 {
            return Ok(false);
        }
        let row = sqlx::query(
            "SELECT intervals_done, load_j, resumptions_json FROM long_term_state WHERE job_id = ?",
        )
        .bind(job_id)
        .fetch_optional(&mut *tx)
        .await?;
        if let Some(row) = row {
            let mut list: Vec<Resumption> = from_json("resumptions", &row.get::<String, _>(2))?;
            list.push(Resumption {
                at: now(),
                intervals_done: row.get::<i64, _>(0).max(0) as usize,
                load_j: row.get(1),
            });
            sqlx::query("UPDATE long_term_state SET resumptions_json = ? WHERE job_id = ?")
                .bind(to_json(&list)?)
                .bind(job_id)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(true)
    }

    /// Lists `job_id` among the station's long-term tests (again: no change).
    pub async fn add_long_term_test(&self, job_id: &str) -> StoreResult<()> {
        sqlx::query(
            "INSERT OR IGNORE INTO long_term_tests (job_id, created_at) \
             SELECT id, created_at FROM jobs WHERE id = ?",
        )
        .bind(job_id)
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// The station's long-term tests, newest first (at most `limit`).
    pub async fn list_long_term_tests(&self, limit: i64) -> StoreResult<Vec<crate::Job>> {
        let ids: Vec<String> = sqlx::query_scalar(
            "SELECT job_id FROM long_term_tests ORDER BY created_at DESC, job_id LIMIT ?",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        let mut out = Vec::with_capacity(ids.len());
        for id in ids {
            if let Some(j) = self.get_job(&id).await? {
                out.push(j);
            }
        }
        Ok(out)
    }

    /// Pauses (`Some(by)`) or resumes (`None`) test `job_id` as the user
    /// asks; false when it already was paused, or not paused.
    pub async fn set_long_term_pause(
        &self,
        job_id: &str,
        pause: Option<Option<&str>>,
    ) -> StoreResult<bool> {
        self.add_long_term_test(job_id).await?;
        let r = match pause {
            Some(by) => {
                sqlx::query(
                    "UPDATE long_term_tests SET paused_at = ?, paused_by = ? WHERE job_id = ? AND paused_at IS NULL",
                )
                .bind(now())
                .bind(by)
                .bind(job_id)
                .execute(&mut *self.writer().await?)
                .await?
            }
            None => {
                sqlx::query(
                    "UPDATE long_term_tests SET paused_at = NULL, paused_by = NULL WHERE job_id = ? AND paused_at IS NOT NULL",
                )
                .bind(job_id)
                .execute(&mut *self.writer().await?)
                .await?
            }
        };
        Ok(r.rows_affected() == 1)
    }

    /// The user's pause of test `job_id` in effect, if any.
    pub async fn long_term_pause(&self, job_id: &str) -> StoreResult<Option<UserPause>> {
        let r = sqlx::query(
            "SELECT paused_at, paused_by FROM long_term_tests WHERE job_id = ? AND paused_at IS NOT NULL",
        )
        .bind(job_id)
        .fetch_optional(&self.pool)
        .await?;
        Ok(r.map(|r| UserPause {
            at: r.get(0),
            by: r.get(1),
        }))
    }

    /// Records a pause or its end of test `job_id`.
    pub async fn add_long_term_event(
        &self,
        job_id: &str,
        kind: LongTermEventKind,
        cause: PauseCause,
        elapsed_s: f64,
        detail: &str,
    ) -> StoreResult<()> {
        if !elapsed_s.is_finite() {
            return Err(StoreError::Invalid(format!(
                "long-term event of {job_id}: elapsed_s {elapsed_s} is not finite"
            )));
        }
        sqlx::query(
            "INSERT INTO long_term_events (job_id, kind, elapsed_s, detail, at, cause) VALUES (?, ?, ?, ?, ?, ?)",
        )
        .bind(job_id)
        .bind(kind.as_str())
        .bind(elapsed_s)
        .bind(detail)
        .bind(now())
        .bind(cause.as_str())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// The pauses and their ends of test `job_id` (the disk's and the user's), in order.
    pub async fn long_term_events(&self, job_id: &str) -> StoreResult<Vec<LongTermEvent>> {
        let rows = sqlx::query(
            "SELECT kind, elapsed_s, detail, at, cause FROM long_term_events WHERE job_id = ? ORDER BY seq",
        )
        .bind(job_id)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                let kind = match r.get::<String, _>(0).as_str() {
                    "paused" => LongTermEventKind::Paused,
                    "resumed" => LongTermEventKind::Resumed,
                    k => return Err(StoreError::Corrupt(format!("long-term event kind '{k}'"))),
                };
                let cause = match r.get::<String, _>(4).as_str() {
                    "disk" => PauseCause::Disk,
                    "user" => PauseCause::User,
                    c => return Err(StoreError::Corrupt(format!("long-term event cause '{c}'"))),
                };
                Ok(LongTermEvent {
                    kind,
                    cause,
                    elapsed_s: r.get(1),
                    detail: r.get(2),
                    at: r.get(3),
                })
            })
            .collect()
    }
}

/// A test's last signals: the recording, linked to the test (one per test).
async fn insert_last_signals(
    tx: &mut sqlx::SqliteConnection,
    job_id: &str,
    (rec, duration_s): (NewRecording, f64),
    at: &str,
) -> StoreResult<()> {
    let ids = insert_results(tx, vec![rec], vec![]).await?;
    sqlx::query(
        "INSERT OR REPLACE INTO long_term_signals (job_id, recording_id, duration_s, created_at) VALUES (?, ?, ?, ?)",
    )
    .bind(job_id)
    .bind(ids[0])
    .bind(duration_s)
    .bind(at)
    .execute(&mut *tx)
    .await?;
    Ok(())
}
