//! SQLite storage (sqlx): parts, jobs, measurements, recordings, events.
//!
//! WAL journal with `synchronous = FULL`: a transaction that has committed
//! survives a crash or a power cut. Results are written in one transaction
//! (recordings, measurements, job state), so a finished result is either
//! entirely there or not at all. Queries are runtime-checked (`sqlx::query`),
//! the schema lives in `migrations/`.

mod derived;
pub mod health;
pub use derived::Derived;
pub mod hardware;

use serde::Serialize;
use serde_json::Value;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteRow,
    SqliteSynchronous,
};
use sqlx::Row;
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

mod blob;
pub use blob::BlobRef;
mod imports;
pub use imports::{ImportInserted, RecordingFile};
pub mod qc;
mod raw;
pub use raw::{dir_bytes, BlobReader, RecordingInfo, Retention, RetentionReport, StoredRecording};

macro_rules! job_select {
    () => {
        "SELECT j.seq, j.id, j.bench_id, j.part_serial, j.priority, j.state, j.step, j.progress, j.eta_s, \
     j.request_json, j.request_sha256, j.problem_json, j.bench_time_s, j.log_json, j.warnings_json, j.created_at, j.started_at, j.finished_at, \
     (SELECT json_group_array(m.id) FROM (SELECT id FROM measurements WHERE job_id = j.id ORDER BY seq) m) AS measurement_ids, \
     (SELECT v.verdict FROM qc_verdicts v WHERE v.job_id = j.id AND v.measurement_id IS NULL ORDER BY v.seq DESC LIMIT 1) AS verdict \
     FROM jobs j"
    };
}

macro_rules! meas_select {
    () => {
        "SELECT m.seq, m.id, m.part_serial, m.job_id, m.source, m.bench_id, m.software_version, \
     m.target_xpeak_m, m.repeat_index, m.level_index, m.analysis_error, m.created_at, m.config_json, \
     json_object('keff_n_per_m', json_extract(m.result_json, '$.large_signal.keff_n_per_m'), \
                 'xpeak_m', json_extract(m.result_json, '$.large_signal.xpeak_m'), \
                 'resonance_hz', json_extract(m.result_json, '$.large_signal.resonance_hz'), \
                 'k0_n_per_m', CASE WHEN json_extract(m.result_json, '$.small_signal.reliable') = 0 THEN NULL \
                                    ELSE json_extract(m.result_json, '$.small_signal.k0_n_per_m') END, \
                 'k0_null_reason', CASE WHEN json_extract(m.result_json, '$.small_signal.reliable') = 0 \
                                    THEN printf('small_signal.reliable is false (k0 %.1f +- %.1f N/m, misfit %.2f %%): not a plain number', \
                                         json_extract(m.result_json, '$.small_signal.k0_n_per_m'), \
                                         json_extract(m.result_json, '$.small_signal.k0_se_n_per_m'), \
                                         json_extract(m.result_json, '$.small_signal.misfit_percent')) END) AS summary"
    };
}

pub type StoreResult<T> = Result<T, StoreError>;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("database migration: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("{0}")]
    Corrupt(String),
}

/// Current time as RFC 3339 UTC with milliseconds.
pub fn now() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// Job states; the terminal ones never change again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
    Interrupted,
}

impl JobState {
    pub const ALL: [JobState; 6] = [
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Cancelled,
        JobState::Interrupted,
    ];
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
            JobState::Interrupted => "interrupted",
        }
    }
    pub fn parse(s: &str) -> Option<JobState> {
        JobState::ALL.into_iter().find(|j| j.as_str() == s)
    }
    pub fn is_terminal(self) -> bool {
        !matches!(self, JobState::Queued | JobState::Running)
    }
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Part {
    pub serial: String,
    pub kind: Option<String>,
    pub notes: Option<String>,
    pub created_at: String,
    pub updated_at: String,
    pub measurement_count: i64,
    /// The QC verdict of the part's newest job judged under a recipe (`pass`,
    /// `fail`, `invalid`, `no_limits`); null when no job was judged.
    #[schema(value_type = Option<springbench_core::qc::VerdictKind>)]
    pub verdict: Option<String>,
}

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Job {
    pub id: String,
    pub state: JobState,
    pub bench_id: String,
    pub part_serial: String,
    pub priority: i64,
    /// Current step while running (pre_measurement, resonance_search, narrow_sweep, fit).
    pub step: Option<String>,
    /// Fraction of the procedure done (0..1).
    pub progress: f64,
    /// Estimated bench time left (s), while running.
    pub eta_s: Option<f64>,
    /// The request as accepted (after defaults were filled in).
    pub request: Value,
    /// RFC 9457 problem document when the job failed or was interrupted.
    pub problem: Option<Value>,
    /// Stimulus time the procedure needed (s), once finished.
    pub bench_time_s: Option<f64>,
    /// Decisions the procedure took (levels, resonances found).
    pub log: Vec<String>,
    /// What the user must know about the execution, one line each (e.g. a
    /// target Xpeak not reached within the limits, with both figures).
    pub warnings: Vec<String>,
    pub measurement_ids: Vec<String>,
    /// The job's QC verdict (`pass`, `fail`, `invalid`, `no_limits`); null
    /// without a recipe or before the job has finished.
    #[schema(value_type = Option<springbench_core::qc::VerdictKind>)]
    pub verdict: Option<String>,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    #[serde(skip)]
    pub seq: i64,
    #[serde(skip)]
    pub request_sha256: String,
}

/// A measurement's listing entry (the result document itself is `result`).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct MeasurementInfo {
    pub id: String,
    pub part_serial: String,
    pub job_id: Option<String>,
    /// "bench" or "import".
    pub source: String,
    pub bench_id: Option<String>,
    pub software_version: String,
    pub target_xpeak_m: Option<f64>,
    pub repeat_index: Option<i64>,
    pub level_index: Option<i64>,
    /// Why the analysis failed (the recordings are kept and can be fitted again).
    pub analysis_error: Option<String>,
    pub created_at: String,
    /// Configuration used (procedure and analysis options).
    pub config: Value,
    /// Headline numbers from the result, for listings.
    pub summary: Value,
    #[serde(skip)]
    pub seq: i64,
}

/// A new measurement to store.
#[derive(Debug, Clone)]
pub struct NewMeasurement {
    pub id: String,
    pub part_serial: String,
    pub job_id: Option<String>,
    pub source: &'static str,
    pub bench_id: Option<String>,
    pub config: Value,
    pub meta: Value,
    pub result: Option<Value>,
    pub analysis_error: Option<String>,
    pub target_xpeak_m: Option<f64>,
    pub repeat_index: Option<i64>,
    pub level_index: Option<i64>,
    /// Index into the `recordings` list handed to the same call.
    pub pre: usize,
    pub main: usize,
}

/// A recording to store: FLAC (or WAV) bytes and their channel scale
/// ([`springbench_recording::codec`]).
#[derive(Debug, Clone)]
pub struct NewRecording {
    pub kind: &'static str,
    pub sample_rate_hz: f64,
    pub frames: i64,
    pub stored: springbench_recording::codec::Stored,
}

#[derive(Debug, Clone, Serialize)]
pub struct Event {
    pub seq: i64,
    pub time: String,
    #[serde(rename = "type")]
    pub kind: String,
    pub job_id: Option<String>,
    pub data: Value,
}

/// A fit of a stored measurement.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Fit {
    pub id: String,
    pub measurement_id: String,
    /// `{"effects": [...], "order": ..., "method": ...}` as accepted.
    pub request: Value,
    /// The refitted result document (with `model` and `diagnostics`).
    #[schema(value_type = springbench_core::identify::Report)]
    pub result: Value,
    pub software_version: String,
    pub created_at: String,
}

/// Which fit supplies a measurement's headline figures, chosen by whom and when.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct HeadlineChoice {
    /// The fit (`GET /api/v1/measurements/{id}/fits`); null: the measurement's own result.
    pub fit_id: Option<String>,
    /// The token name of who chose it (null with open access).
    pub chosen_by: Option<String>,
    pub chosen_at: String,
}

/// Result of an insert that honours an idempotency key.
pub enum Inserted {
    New(Job),
    /// The key was used before with the same body: the earlier job.
    Replayed(Job),
    /// The key was used before with another body.
    Conflict(Job),
}

#[derive(Clone)]
pub struct Store {
    pool: SqlitePool,
    /// The data directory (None in memory): free-space checks (health.rs).
    dir: Option<std::sync::Arc<std::path::PathBuf>>,
}

impl Store {
    /// Opens (creating if missing) `data_dir/springbench.db` and migrates it.
    pub async fn open(data_dir: &Path) -> StoreResult<Store> {
        std::fs::create_dir_all(data_dir).map_err(|e| {
            StoreError::Corrupt(format!("data directory {}: {e}", data_dir.display()))
        })?;
        let path = data_dir.join("springbench.db");
        let opts = SqliteConnectOptions::new()
            .filename(&path)
            .create_if_missing(false)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .foreign_keys(true)
            // Every write transaction starts with BEGIN IMMEDIATE (the write
            // lock first, waiting up to this timeout): a deferred transaction
            // that reads and then writes fails at once with "database is
            // locked" when another connection wrote in between (WAL snapshot
            // upgrade), whatever the timeout; seen approving a limit proposal
            // while jobs finished.
            .busy_timeout(Duration::from_secs(10));
        // Created here only: the pool never creates a file by itself, so a
        // lost database is not silently replaced by an empty one (health.rs).
        if !path.exists() {
            use sqlx::{ConnectOptions, Connection};
            opts.clone()
                .create_if_missing(true)
                .connect()
                .await?
                .close()
                .await?;
        }
        let guard = health::FileGuard::new(&path)
            .map_err(|e| StoreError::Corrupt(format!("database file {}: {e}", path.display())))?;
        let (g1, g2) = (guard.clone(), guard.clone());
        let pool = SqlitePoolOptions::new()
            .max_connections(8)
            .min_connections(1)
            .acquire_timeout(Duration::from_secs(5))
            .after_connect(move |_, _| {
                let g = g1.clone();
                Box::pin(async move { g.connect_check() })
            })
            .before_acquire(move |_, meta| {
                let g = g2.clone();
                Box::pin(async move { g.usable(meta.age) })
            })
            // A connection whose COMMIT or ROLLBACK failed (full disk, I/O
            // error) may still be inside its transaction: pooled again, the
            // next BEGIN fails with "begin_with at non-zero transaction
            // depth" or writes into the stale transaction. It is closed.
            .after_release(|conn, _| Box::pin(async move { health::reusable(conn).await }))
            .connect_with(opts.clone())
            .await?;
        sqlx::migrate!("./migrations").run(&pool).await?;
        health::spawn_watchdog(guard, opts, pool.clone());
        Ok(Store {
            pool,
            dir: Some(std::sync::Arc::new(data_dir.to_path_buf())),
        })
    }

    /// An in-memory database (tests).
    pub async fn memory() -> StoreResult<Store> {
        let opts = SqliteConnectOptions::from_str("sqlite::memory:")?.foreign_keys(true);
        Store::with_options(opts, 1).await
    }

    async fn with_options(opts: SqliteConnectOptions, max: u32) -> StoreResult<Store> {
        let pool = SqlitePoolOptions::new()
            .max_connections(max)
            .min_connections(1)
            .connect_with(opts)
            .await?;
        sqlx::migrate!("./migrations").run(&pool).await?;
        Ok(Store { pool, dir: None })
    }

    pub async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await?;
        Ok(())
    }

    /// The problem document of a job cut off by a crash, a kill or a stop.
    pub fn interrupted_problem() -> Value {
        serde_json::json!({
            "type": "/problems/interrupted",
            "title": "Job interrupted",
            "status": 500,
            "detail": "the daemon stopped while this job was running; it was not re-run (submit it again)",
        })
    }

    /// At start: the jobs still `running` were cut off by a crash or a kill
    /// (the runner ends each one `interrupted` with its verdict and MES
    /// messages, [`Store::end_running_job`]; never re-run silently).
    pub async fn running_jobs(&self) -> StoreResult<Vec<Job>> {
        let rows = sqlx::query(concat!(
            job_select!(),
            " WHERE j.state = 'running' ORDER BY j.seq"
        ))
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(job_from_row).collect()
    }

    /// At start: queued jobs of benches that are no longer configured would
    /// wait forever; they fail with a problem naming the bench. Returns their ids.
    pub async fn fail_queued_on_unknown_benches(
        &self,
        known: &[String],
    ) -> StoreResult<Vec<String>> {
        let rows = sqlx::query("SELECT DISTINCT bench_id FROM jobs WHERE state = 'queued'")
            .fetch_all(&self.pool)
            .await?;
        let mut ids = vec![];
        for r in rows {
            let bench: String = r.get(0);
            if known.contains(&bench) {
                continue;
            }
            let problem = serde_json::json!({
                "type": "/problems/unknown-bench",
                "title": "Bench no longer configured",
                "status": 500,
                "detail": format!("bench '{bench}' is not in the configuration any more; submit the job again"),
            })
            .to_string();
            let done = sqlx::query(
                "UPDATE jobs SET state = 'failed', finished_at = ?, problem_json = ? \
                 WHERE state = 'queued' AND bench_id = ? RETURNING id",
            )
            .bind(now())
            .bind(problem)
            .bind(bench)
            .fetch_all(&self.pool)
            .await?;
            ids.extend(done.iter().map(|r| r.get::<String, _>(0)));
        }
        Ok(ids)
    }

    // ---- parts ----

    /// Creates the part if new; updates kind/notes when given.
    pub async fn upsert_part(
        &self,
        serial: &str,
        kind: Option<&str>,
        notes: Option<&str>,
    ) -> StoreResult<()> {
        let t = now();
        sqlx::query(
            "INSERT INTO parts (serial, kind, notes, created_at, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(serial) DO UPDATE SET kind = COALESCE(excluded.kind, parts.kind), \
             notes = COALESCE(excluded.notes, parts.notes), \
             updated_at = CASE WHEN excluded.kind IS NULL AND excluded.notes IS NULL THEN parts.updated_at ELSE excluded.updated_at END",
        )
        .bind(serial.to_string())
        .bind(kind.map(str::to_string))
        .bind(notes.map(str::to_string))
        .bind(t.clone())
        .bind(t)
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    pub async fn get_part(&self, serial: &str) -> StoreResult<Option<Part>> {
        let row = sqlx::query(
            "SELECT p.serial, p.kind, p.notes, p.created_at, p.updated_at, \
             (SELECT COUNT(*) FROM measurements m WHERE m.part_serial = p.serial), \
             (SELECT v.verdict FROM qc_verdicts v WHERE v.part_serial = p.serial AND v.measurement_id IS NULL ORDER BY v.seq DESC LIMIT 1) \
             FROM parts p WHERE p.serial = ?",
        )
        .bind(serial.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| part_from_row(&r)))
    }

    /// Parts ordered by serial; `after` is the last serial of the previous page.
    pub async fn list_parts(&self, after: Option<&str>, limit: i64) -> StoreResult<Vec<Part>> {
        let rows = sqlx::query(
            "SELECT p.serial, p.kind, p.notes, p.created_at, p.updated_at, \
             (SELECT COUNT(*) FROM measurements m WHERE m.part_serial = p.serial), \
             (SELECT v.verdict FROM qc_verdicts v WHERE v.part_serial = p.serial AND v.measurement_id IS NULL ORDER BY v.seq DESC LIMIT 1) \
             FROM parts p WHERE (? IS NULL OR p.serial > ?) ORDER BY p.serial LIMIT ?",
        )
        .bind(after.map(str::to_string))
        .bind(after.map(str::to_string))
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(part_from_row).collect())
    }

    // ---- jobs ----

    /// Inserts a queued job (creating the part), honouring the idempotency key.
    #[allow(clippy::too_many_arguments)]
    pub async fn insert_job(
        &self,
        id: &str,
        bench_id: &str,
        part: (&str, Option<&str>, Option<&str>),
        priority: i64,
        request: &Value,
        request_sha256: &str,
        idempotency_key: Option<&str>,
    ) -> StoreResult<Inserted> {
        if let Some(key) = idempotency_key {
            if let Some(j) = self.job_by_key(key).await? {
                return Ok(replay_or_conflict(j, request_sha256));
            }
        }
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        let t = now();
        sqlx::query(
            "INSERT INTO parts (serial, kind, notes, created_at, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(serial) DO UPDATE SET kind = COALESCE(excluded.kind, parts.kind), \
             notes = COALESCE(excluded.notes, parts.notes), updated_at = excluded.updated_at",
        )
        .bind(part.0.to_string())
        .bind(part.1.map(str::to_string))
        .bind(part.2.map(str::to_string))
        .bind(t.clone())
        .bind(t.clone())
        .execute(&mut *tx)
        .await?;
        let res = sqlx::query(
            "INSERT INTO jobs (id, bench_id, part_serial, priority, state, request_json, idempotency_key, request_sha256, created_at) \
             VALUES (?, ?, ?, ?, 'queued', ?, ?, ?, ?)",
        )
        .bind(id.to_string())
        .bind(bench_id.to_string())
        .bind(part.0.to_string())
        .bind(priority)
        .bind(request.to_string())
        .bind(idempotency_key.map(str::to_string))
        .bind(request_sha256.to_string())
        .bind(t)
        .execute(&mut *tx)
        .await;
        match res {
            Ok(_) => {
                tx.commit().await?;
            }
            Err(sqlx::Error::Database(e)) if e.is_unique_violation() => {
                // Two requests with the same key raced; the other one won.
                drop(tx);
                if let Some(key) = idempotency_key {
                    if let Some(j) = self.job_by_key(key).await? {
                        return Ok(replay_or_conflict(j, request_sha256));
                    }
                }
                return Err(StoreError::Corrupt(format!("duplicate job id {id}")));
            }
            Err(e) => return Err(e.into()),
        }
        let job = self
            .get_job(id)
            .await?
            .ok_or_else(|| StoreError::Corrupt(format!("job {id} vanished after insert")))?;
        Ok(Inserted::New(job))
    }

    async fn job_by_key(&self, key: &str) -> StoreResult<Option<Job>> {
        let row = sqlx::query(concat!(job_select!(), " WHERE j.idempotency_key = ?"))
            .bind(key.to_string())
            .fetch_optional(&self.pool)
            .await?;
        row.map(|r| job_from_row(&r)).transpose()
    }

    pub async fn get_job(&self, id: &str) -> StoreResult<Option<Job>> {
        let row = sqlx::query(concat!(job_select!(), " WHERE j.id = ?"))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        row.map(|r| job_from_row(&r)).transpose()
    }

    /// Jobs newest first; `before_seq` is the cursor of the previous page.
    pub async fn list_jobs(
        &self,
        state: Option<JobState>,
        part: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<Job>> {
        self.list_jobs_since(state, part, None, before_seq, limit)
            .await
    }

    /// [`Store::list_jobs`] of jobs created at or after `since` (RFC 3339 UTC, ms).
    pub async fn list_jobs_since(
        &self,
        state: Option<JobState>,
        part: Option<&str>,
        since: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<Job>> {
        let rows = sqlx::query(concat!(
            job_select!(),
            " WHERE (? IS NULL OR j.state = ?) AND (? IS NULL OR j.part_serial = ?) \
             AND (? IS NULL OR j.created_at >= ?) \
             AND (? IS NULL OR j.seq < ?) ORDER BY j.seq DESC LIMIT ?"
        ))
        .bind(state.map(|s| s.as_str()))
        .bind(state.map(|s| s.as_str()))
        .bind(part.map(str::to_string))
        .bind(part.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(before_seq)
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(job_from_row).collect()
    }

    /// The next job to run on a bench: highest priority first, then FIFO.
    pub async fn next_queued(&self, bench_id: &str) -> StoreResult<Option<Job>> {
        let row = sqlx::query(concat!(job_select!(), " WHERE j.bench_id = ? AND j.state = 'queued' ORDER BY j.priority DESC, j.seq ASC LIMIT 1"))
        .bind(bench_id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| job_from_row(&r)).transpose()
    }

    /// queued -> running; false when the job is no longer queued (cancelled meanwhile).
    pub async fn start_job(&self, id: &str) -> StoreResult<bool> {
        let r = sqlx::query(
            "UPDATE jobs SET state = 'running', started_at = ?, progress = 0 WHERE id = ? AND state = 'queued'",
        )
        .bind(now())
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    pub async fn set_progress(
        &self,
        id: &str,
        step: &str,
        progress: f64,
        eta_s: f64,
    ) -> StoreResult<()> {
        sqlx::query(
            "UPDATE jobs SET step = ?, progress = ?, eta_s = ? WHERE id = ? AND state = 'running'",
        )
        .bind(step.to_string())
        .bind(progress)
        .bind(eta_s)
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// queued -> cancelled; false when the job is not queued.
    pub async fn cancel_queued(&self, id: &str) -> StoreResult<bool> {
        let r = sqlx::query(
            "UPDATE jobs SET state = 'cancelled', finished_at = ? WHERE id = ? AND state = 'queued'",
        )
        .bind(now())
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// running -> a terminal state, with the measurements of the run, in one
    /// transaction (recordings, measurements, job row).
    #[allow(clippy::too_many_arguments)]
    pub async fn finish_job(
        &self,
        id: &str,
        state: JobState,
        problem: Option<&Value>,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
    ) -> StoreResult<()> {
        self.finish_job_qc(
            id,
            state,
            problem,
            bench_time_s,
            log,
            warnings,
            recordings,
            measurements,
            &qc::JobRecords::default(),
        )
        .await
    }

    /// [`Store::finish_job`] with the job's verdicts and MES outbox messages
    /// in the same transaction as its result.
    #[allow(clippy::too_many_arguments)]
    pub async fn finish_job_qc(
        &self,
        id: &str,
        state: JobState,
        problem: Option<&Value>,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
        records: &qc::JobRecords,
    ) -> StoreResult<()> {
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        let ids = insert_results(&mut tx, recordings, measurements).await?;
        let _ = ids;
        qc::insert_job_records(&mut tx, records).await?;
        let progress_done = if state == JobState::Succeeded {
            1.0
        } else {
            -1.0
        };
        sqlx::query(
            "UPDATE jobs SET state = ?, finished_at = ?, problem_json = ?, bench_time_s = ?, log_json = ?, warnings_json = ?, eta_s = NULL, \
             progress = CASE WHEN ? >= 0 THEN ? ELSE progress END WHERE id = ?",
        )
        .bind(state.as_str())
        .bind(now())
        .bind(problem.map(|p| p.to_string()))
        .bind(bench_time_s)
        .bind(serde_json::to_string(log).unwrap_or_else(|_| "[]".into()))
        .bind(serde_json::to_string(warnings).unwrap_or_else(|_| "[]".into()))
        .bind(progress_done)
        .bind(progress_done)
        .bind(id.to_string())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// running -> `state` (failed or interrupted, no results) with the job's
    /// verdicts and MES messages, in one transaction. False (nothing written)
    /// when the job is not running: it never started, or it ended meanwhile
    /// (a retry after a storage fault never overwrites a stored result).
    #[allow(clippy::too_many_arguments)]
    pub async fn end_running_job(
        &self,
        id: &str,
        state: JobState,
        problem: Option<&Value>,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
        records: &qc::JobRecords,
    ) -> StoreResult<bool> {
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(
            "UPDATE jobs SET state = ?, finished_at = ?, problem_json = ?, bench_time_s = ?, log_json = ?, warnings_json = ?, eta_s = NULL \
             WHERE id = ? AND state = 'running'",
        )
        .bind(state.as_str())
        .bind(now())
        .bind(problem.map(|p| p.to_string()))
        .bind(bench_time_s)
        .bind(serde_json::to_string(log).unwrap_or_else(|_| "[]".into()))
        .bind(serde_json::to_string(warnings).unwrap_or_else(|_| "[]".into()))
        .bind(id.to_string())
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() != 1 {
            return Ok(false);
        }
        qc::insert_job_records(&mut tx, records).await?;
        tx.commit().await?;
        Ok(true)
    }

    /// Stores a running job's finished recordings and measurements (one
    /// repeat) in one transaction; the job stays running.
    pub async fn insert_job_measurements(
        &self,
        job_id: &str,
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
    ) -> StoreResult<()> {
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        let running: Option<i64> =
            sqlx::query_scalar("SELECT 1 FROM jobs WHERE id = ? AND state = 'running'")
                .bind(job_id.to_string())
                .fetch_optional(&mut *tx)
                .await?;
        if running.is_none() {
            return Err(StoreError::Corrupt(format!("job {job_id} is not running")));
        }
        insert_results(&mut tx, recordings, measurements).await?;
        tx.commit().await?;
        Ok(())
    }

    /// Stores measurements without a job (multipart import), in one transaction.
    pub async fn insert_measurements(
        &self,
        part: (&str, Option<&str>, Option<&str>),
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
    ) -> StoreResult<()> {
        self.upsert_part(part.0, part.1, part.2).await?;
        let mut tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        insert_results(&mut tx, recordings, measurements).await?;
        tx.commit().await?;
        Ok(())
    }

    pub async fn job_counts(&self) -> StoreResult<Vec<(String, i64)>> {
        let rows = sqlx::query("SELECT state, COUNT(*) FROM jobs GROUP BY state")
            .fetch_all(&self.pool)
            .await?;
        Ok(rows
            .iter()
            .map(|r| (r.get::<String, _>(0), r.get::<i64, _>(1)))
            .collect())
    }

    pub async fn counts(&self) -> StoreResult<(i64, i64)> {
        let r =
            sqlx::query("SELECT (SELECT COUNT(*) FROM parts), (SELECT COUNT(*) FROM measurements)")
                .fetch_one(&self.pool)
                .await?;
        Ok((r.get(0), r.get(1)))
    }

    // ---- measurements ----

    pub async fn get_measurement(
        &self,
        id: &str,
    ) -> StoreResult<Option<(MeasurementInfo, Option<Value>, Value)>> {
        let row = sqlx::query(concat!(
            meas_select!(),
            ", m.result_json, m.meta_json FROM measurements m WHERE m.id = ?"
        ))
        .bind(id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        let Some(r) = row else { return Ok(None) };
        let info = meas_from_row(&r)?;
        let result = r
            .get::<Option<String>, _>("result_json")
            .map(|s| parse_json(&s))
            .transpose()?;
        let meta = parse_json(&r.get::<String, _>("meta_json"))?;
        Ok(Some((info, result, meta)))
    }

    /// Measurements newest first, optionally of one part or one job.
    pub async fn list_measurements(
        &self,
        part: Option<&str>,
        job: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<MeasurementInfo>> {
        self.list_measurements_since(part, job, None, before_seq, limit)
            .await
    }

    /// [`Store::list_measurements`] of measurements stored at or after `since` (RFC 3339 UTC, ms).
    pub async fn list_measurements_since(
        &self,
        part: Option<&str>,
        job: Option<&str>,
        since: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<MeasurementInfo>> {
        let rows = sqlx::query(concat!(
            meas_select!(),
            " FROM measurements m WHERE (? IS NULL OR m.part_serial = ?) \
             AND (? IS NULL OR m.job_id = ?) AND (? IS NULL OR m.created_at >= ?) \
             AND (? IS NULL OR m.seq < ?) ORDER BY m.seq DESC LIMIT ?"
        ))
        .bind(part.map(str::to_string))
        .bind(part.map(str::to_string))
        .bind(job.map(str::to_string))
        .bind(job.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(before_seq)
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(meas_from_row).collect()
    }

    // ---- fits ----

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
        .execute(&self.pool)
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

    /// The fits of a measurement, oldest first.
    pub async fn list_fits(&self, measurement_id: &str) -> StoreResult<Vec<Fit>> {
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
        .execute(&self.pool)
        .await?;
        Ok(HeadlineChoice {
            fit_id: fit_id.map(str::to_string),
            chosen_by: chosen_by.map(str::to_string),
            chosen_at: t,
        })
    }

    /// The newest headline choice of a measurement (None: never chosen).
    pub async fn headline_choice(
        &self,
        measurement_id: &str,
    ) -> StoreResult<Option<HeadlineChoice>> {
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

    // ---- events ----

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
        .fetch_one(&self.pool)
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

    /// Flushes the WAL into the database file (at shutdown).
    pub async fn close(&self) {
        let _ = sqlx::query("PRAGMA wal_checkpoint(TRUNCATE)")
            .execute(&self.pool)
            .await;
        self.pool.close().await;
    }
}

async fn insert_results(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    recordings: Vec<NewRecording>,
    measurements: Vec<NewMeasurement>,
) -> StoreResult<Vec<i64>> {
    let t = now();
    let mut rec_ids = Vec::with_capacity(recordings.len());
    for r in recordings {
        let row = sqlx::query(
            "INSERT INTO recordings (kind, sample_rate_hz, frames, wav, channel_scale_json, created_at) VALUES (?, ?, ?, ?, ?, ?) RETURNING id",
        )
        .bind(r.kind)
        .bind(r.sample_rate_hz)
        .bind(r.frames)
        .bind(r.stored.bytes)
        .bind(
            r.stored
                .channel_scale
                .map(|c| serde_json::to_string(&c).unwrap_or_default()),
        )
        .bind(t.clone())
        .fetch_one(&mut **tx)
        .await?;
        rec_ids.push(row.get::<i64, _>(0));
    }
    insert_measurement_rows(tx, measurements, &rec_ids).await?;
    Ok(rec_ids)
}

/// The measurement rows; `pre` / `main` index into `rec_ids`.
async fn insert_measurement_rows(
    tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
    measurements: Vec<NewMeasurement>,
    rec_ids: &[i64],
) -> StoreResult<()> {
    let t = now();
    for m in measurements {
        let pre = *rec_ids.get(m.pre).ok_or_else(|| {
            StoreError::Corrupt("measurement names a missing pre recording".into())
        })?;
        let main = *rec_ids.get(m.main).ok_or_else(|| {
            StoreError::Corrupt("measurement names a missing main recording".into())
        })?;
        sqlx::query(
            "INSERT INTO measurements (id, part_serial, job_id, source, bench_id, software_version, config_json, meta_json, \
             result_json, analysis_error, target_xpeak_m, repeat_index, level_index, pre_recording_id, main_recording_id, created_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(m.id)
        .bind(m.part_serial)
        .bind(m.job_id)
        .bind(m.source)
        .bind(m.bench_id)
        .bind(springbench_core::VERSION)
        .bind(m.config.to_string())
        .bind(m.meta.to_string())
        .bind(m.result.map(|v| v.to_string()))
        .bind(m.analysis_error)
        .bind(m.target_xpeak_m)
        .bind(m.repeat_index)
        .bind(m.level_index)
        .bind(pre)
        .bind(main)
        .bind(t.clone())
        .execute(&mut **tx)
        .await?;
    }
    Ok(())
}

fn replay_or_conflict(j: Job, sha: &str) -> Inserted {
    if j.request_sha256 == sha {
        Inserted::Replayed(j)
    } else {
        Inserted::Conflict(j)
    }
}

fn parse_json(s: &str) -> StoreResult<Value> {
    serde_json::from_str(s).map_err(|e| StoreError::Corrupt(format!("stored JSON unreadable: {e}")))
}

fn part_from_row(r: &SqliteRow) -> Part {
    Part {
        serial: r.get(0),
        kind: r.get(1),
        notes: r.get(2),
        created_at: r.get(3),
        updated_at: r.get(4),
        measurement_count: r.get(5),
        verdict: r.get(6),
    }
}

fn job_from_row(r: &SqliteRow) -> StoreResult<Job> {
    let state: String = r.get("state");
    let log = r
        .get::<Option<String>, _>("log_json")
        .map(|s| serde_json::from_str::<Vec<String>>(&s).unwrap_or_default())
        .unwrap_or_default();
    let warnings = r
        .get::<Option<String>, _>("warnings_json")
        .map(|s| serde_json::from_str::<Vec<String>>(&s).unwrap_or_default())
        .unwrap_or_default();
    let ids: Vec<String> = serde_json::from_str(&r.get::<String, _>("measurement_ids"))
        .map_err(|e| StoreError::Corrupt(e.to_string()))?;
    Ok(Job {
        seq: r.get("seq"),
        id: r.get("id"),
        state: JobState::parse(&state)
            .ok_or_else(|| StoreError::Corrupt(format!("unknown job state '{state}'")))?,
        bench_id: r.get("bench_id"),
        part_serial: r.get("part_serial"),
        priority: r.get("priority"),
        step: r.get("step"),
        progress: r.get("progress"),
        eta_s: r.get("eta_s"),
        request: parse_json(&r.get::<String, _>("request_json"))?,
        request_sha256: r.get("request_sha256"),
        problem: r
            .get::<Option<String>, _>("problem_json")
            .map(|s| parse_json(&s))
            .transpose()?,
        bench_time_s: r.get("bench_time_s"),
        log,
        warnings,
        measurement_ids: ids,
        verdict: r.get("verdict"),
        created_at: r.get("created_at"),
        started_at: r.get("started_at"),
        finished_at: r.get("finished_at"),
    })
}

fn meas_from_row(r: &SqliteRow) -> StoreResult<MeasurementInfo> {
    Ok(MeasurementInfo {
        seq: r.get("seq"),
        id: r.get("id"),
        part_serial: r.get("part_serial"),
        job_id: r.get("job_id"),
        source: r.get("source"),
        bench_id: r.get("bench_id"),
        software_version: r.get("software_version"),
        target_xpeak_m: r.get("target_xpeak_m"),
        repeat_index: r.get("repeat_index"),
        level_index: r.get("level_index"),
        analysis_error: r.get("analysis_error"),
        created_at: r.get("created_at"),
        config: parse_json(&r.get::<String, _>("config_json"))?,
        summary: parse_json(&r.get::<String, _>("summary"))?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn rec(kind: &'static str) -> NewRecording {
        NewRecording {
            kind,
            sample_rate_hz: 48000.0,
            frames: 3,
            stored: springbench_recording::codec::Stored {
                bytes: vec![1, 2, 3, kind.len() as u8],
                channel_scale: None,
            },
        }
    }

    #[tokio::test]
    async fn job_lifecycle_and_results_round_trip() {
        let s = Store::memory().await.unwrap();
        let req = json!({"part": {"serial": "SN-1"}});
        let Inserted::New(j) = s
            .insert_job(
                "j1",
                "b1",
                ("SN-1", Some("spider"), None),
                0,
                &req,
                "h1",
                Some("k1"),
            )
            .await
            .unwrap()
        else {
            panic!("expected a new job")
        };
        assert_eq!(j.state, JobState::Queued);
        // Same key, same body: the same job; another body: a conflict.
        assert!(matches!(
            s.insert_job("j2", "b1", ("SN-1", None, None), 0, &req, "h1", Some("k1")).await.unwrap(),
            Inserted::Replayed(ref r) if r.id == "j1"
        ));
        assert!(matches!(
            s.insert_job("j3", "b1", ("SN-1", None, None), 0, &req, "h2", Some("k1"))
                .await
                .unwrap(),
            Inserted::Conflict(_)
        ));
        assert!(s.get_job("j2").await.unwrap().is_none());

        assert_eq!(s.next_queued("b1").await.unwrap().unwrap().id, "j1");
        assert!(s.start_job("j1").await.unwrap());
        assert!(
            !s.start_job("j1").await.unwrap(),
            "a running job cannot start twice"
        );
        assert!(!s.cancel_queued("j1").await.unwrap());
        s.set_progress("j1", "narrow_sweep", 0.5, 12.0)
            .await
            .unwrap();
        let m = NewMeasurement {
            id: "m1".into(),
            part_serial: "SN-1".into(),
            job_id: Some("j1".into()),
            source: "bench",
            bench_id: Some("b1".into()),
            config: json!({"method": "two-signal"}),
            meta: json!({"moving_mass_kg": 0.05}),
            result: Some(json!({"large_signal": {"keff_n_per_m": 1234.5},
                "small_signal": {"k0_n_per_m": 1792.0, "k0_se_n_per_m": 210.0,
                                 "misfit_percent": 12.5, "reliable": false}})),
            analysis_error: None,
            target_xpeak_m: Some(0.008),
            repeat_index: Some(0),
            level_index: Some(0),
            pre: 0,
            main: 1,
        };
        s.finish_job(
            "j1",
            JobState::Succeeded,
            None,
            Some(31.5),
            &["ok".into()],
            &["target Xpeak 8.000 mm not reached".into()],
            vec![rec("pre"), rec("main")],
            vec![m],
        )
        .await
        .unwrap();
        let j = s.get_job("j1").await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Succeeded);
        assert_eq!(j.measurement_ids, vec!["m1".to_string()]);
        assert_eq!(j.bench_time_s, Some(31.5));
        assert_eq!(
            j.warnings,
            vec!["target Xpeak 8.000 mm not reached".to_string()]
        );
        assert_eq!(j.progress, 1.0);
        let (info, result, _) = s.get_measurement("m1").await.unwrap().unwrap();
        assert_eq!(info.summary["keff_n_per_m"], json!(1234.5));
        // An unreliable small-signal k0 is never a plain number in the summary.
        assert_eq!(info.summary["k0_n_per_m"], json!(null));
        assert_eq!(
            info.summary["k0_null_reason"],
            json!("small_signal.reliable is false (k0 1792.0 +- 210.0 N/m, misfit 12.50 %): not a plain number")
        );
        assert_eq!(
            result.unwrap()["large_signal"]["keff_n_per_m"],
            json!(1234.5)
        );
        assert_eq!(
            s.get_recording("m1", "main").await.unwrap().unwrap().bytes,
            vec![1, 2, 3, 4]
        );
        assert_eq!(
            s.get_recording("m1", "pre").await.unwrap().unwrap().bytes,
            vec![1, 2, 3, 3]
        );
        assert!(s.get_recording("m1", "other").await.unwrap().is_none());
        let p = s.get_part("SN-1").await.unwrap().unwrap();
        assert_eq!(
            (p.kind.as_deref(), p.measurement_count),
            (Some("spider"), 1)
        );
    }

    #[tokio::test]
    async fn queue_is_priority_then_fifo_and_running_jobs_become_interrupted() {
        let s = Store::memory().await.unwrap();
        let req = json!({});
        for (id, prio) in [("a", 0), ("b", 5), ("c", 0), ("d", 5)] {
            s.insert_job(id, "b1", ("P", None, None), prio, &req, id, None)
                .await
                .unwrap();
        }
        let mut order = vec![];
        while let Some(j) = s.next_queued("b1").await.unwrap() {
            assert!(s.start_job(&j.id).await.unwrap());
            order.push(j.id);
        }
        assert_eq!(order, ["b", "d", "a", "c"]);
        let running = s.running_jobs().await.unwrap();
        assert_eq!(running.len(), 4);
        for j in &running {
            let p = Store::interrupted_problem();
            let rec = qc::JobRecords::default();
            let ended =
                s.end_running_job(&j.id, JobState::Interrupted, Some(&p), None, &[], &[], &rec);
            assert!(ended.await.unwrap());
        }
        // ended once: a second end (a retry) writes nothing
        let p = Store::interrupted_problem();
        let rec = qc::JobRecords::default();
        let again = s.end_running_job("a", JobState::Failed, Some(&p), None, &[], &[], &rec);
        assert!(!again.await.unwrap());
        let j = s.get_job("a").await.unwrap().unwrap();
        assert_eq!(j.state, JobState::Interrupted);
        assert_eq!(j.problem.unwrap()["title"], json!("Job interrupted"));
        // pagination newest first
        let page = s.list_jobs(None, None, None, 2).await.unwrap();
        assert_eq!(
            page.iter().map(|j| j.id.as_str()).collect::<Vec<_>>(),
            ["d", "c"]
        );
        let page2 = s
            .list_jobs(None, None, Some(page[1].seq), 10)
            .await
            .unwrap();
        assert_eq!(
            page2.iter().map(|j| j.id.as_str()).collect::<Vec<_>>(),
            ["b", "a"]
        );
        assert!(s
            .list_jobs(Some(JobState::Queued), None, None, 10)
            .await
            .unwrap()
            .is_empty());
    }

    #[tokio::test]
    async fn queued_jobs_of_removed_benches_fail() {
        let s = Store::memory().await.unwrap();
        let req = json!({});
        for (id, bench) in [("a", "b1"), ("b", "gone"), ("c", "gone")] {
            s.insert_job(id, bench, ("P", None, None), 0, &req, id, None)
                .await
                .unwrap();
        }
        let mut ids = s
            .fail_queued_on_unknown_benches(&["b1".to_string()])
            .await
            .unwrap();
        ids.sort();
        assert_eq!(ids, ["b", "c"]);
        let b = s.get_job("b").await.unwrap().unwrap();
        assert_eq!(b.state, JobState::Failed);
        assert!(b.problem.unwrap()["detail"]
            .as_str()
            .unwrap()
            .contains("gone"));
        assert_eq!(
            s.get_job("a").await.unwrap().unwrap().state,
            JobState::Queued
        );
    }

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
}
