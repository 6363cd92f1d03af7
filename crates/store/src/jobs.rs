//! The job queue of this station: jobs from submission to their end (one
//! owner per bench, idempotency keys), the end written with the run's
//! results, verdicts and MES messages in one transaction.

use crate::measurements::{insert_measurement_rows, insert_results};
use crate::results::{NewMeasurement, NewRecording};
use crate::{now, parse_json, qc, Store, StoreError, StoreResult};
use serde::Serialize;
use serde_json::Value;
use springbench_core::job::{JobProblem, JobSpec, MeasurementConfig, ProblemKind, StoredRequest};
use sqlx::sqlite::SqliteRow;
use sqlx::Row;

macro_rules! job_select {
    () => {
        "SELECT j.seq, j.id, j.bench_id, j.part_serial, j.priority, j.state, j.step, j.progress, j.eta_s, \
     j.request_json, j.request_sha256, j.problem_json, j.bench_time_s, j.log_json, j.warnings_json, j.created_at, j.started_at, j.finished_at, \
     (SELECT json_group_array(m.id) FROM (SELECT id FROM measurements WHERE job_id = j.id ORDER BY seq) m) AS measurement_ids, \
     (SELECT v.verdict FROM qc_verdicts v WHERE v.job_id = j.id AND v.measurement_id IS NULL ORDER BY v.seq DESC LIMIT 1) AS verdict \
     FROM jobs j"
    };
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
    #[schema(value_type = Value)]
    pub request: JobRequestRow,
    /// RFC 9457 problem document when the job failed or was interrupted.
    #[schema(value_type = Option<Value>)]
    pub problem: Option<JobProblem>,
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

/// A job's request as read back from the queue: typed, or the stored
/// document of a request this version cannot read, with why (the runner
/// fails such a job; the API still shows what was stored).
// One per job read: a box would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum JobRequestRow {
    Read(StoredRequest),
    Unreadable { document: Value, error: String },
}

impl JobRequestRow {
    /// The typed request, or why the stored one cannot be read.
    pub fn read(&self) -> Result<&StoredRequest, &str> {
        match self {
            JobRequestRow::Read(r) => Ok(r),
            JobRequestRow::Unreadable { error, .. } => Err(error),
        }
    }

    /// The measurement the job asks for (None: another kind, or unreadable).
    pub fn measure(&self) -> Option<&JobSpec> {
        self.read().ok().and_then(StoredRequest::measure)
    }

    fn parse(text: &str) -> StoreResult<JobRequestRow> {
        let document = parse_json(text)?;
        Ok(match serde_json::from_value(document.clone()) {
            Ok(r) => JobRequestRow::Read(r),
            Err(e) => JobRequestRow::Unreadable {
                document,
                error: e.to_string(),
            },
        })
    }
}

/// As stored (serde_json's sorted members: the document the API always showed).
impl Serialize for JobRequestRow {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            JobRequestRow::Read(r) => serde_json::to_value(r)
                .map_err(serde::ser::Error::custom)?
                .serialize(s),
            JobRequestRow::Unreadable { document, .. } => document.serialize(s),
        }
    }
}

/// Result of an insert that honours an idempotency key.
pub enum Inserted {
    New(Job),
    /// The key was used before with the same body: the earlier job.
    Replayed(Job),
    /// The key was used before with another body.
    Conflict(Job),
}

impl Store {
    /// The problem document of a job cut off by a crash, a kill or a stop.
    pub fn interrupted_problem() -> JobProblem {
        JobProblem::new(
            ProblemKind::Interrupted,
            "Job interrupted",
            "the daemon stopped while this job was running; it was not re-run (submit it again)",
        )
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
            let problem = problem_json(&JobProblem::new(
                ProblemKind::UnknownBench,
                "Bench no longer configured",
                format!(
                    "bench '{bench}' is not in the configuration any more; submit the job again"
                ),
            ));
            let done = sqlx::query(
                "UPDATE jobs SET state = 'failed', finished_at = ?, problem_json = ? \
                 WHERE state = 'queued' AND bench_id = ? RETURNING id",
            )
            .bind(now())
            .bind(problem)
            .bind(bench)
            .fetch_all(&mut *self.writer().await?)
            .await?;
            ids.extend(done.iter().map(|r| r.get::<String, _>(0)));
        }
        Ok(ids)
    }

    /// Inserts a queued job (creating the part), honouring the idempotency key.
    #[allow(clippy::too_many_arguments)]
    pub async fn insert_job(
        &self,
        id: &str,
        bench_id: &str,
        part: (&str, Option<&str>, Option<&str>),
        priority: i64,
        request: &StoredRequest,
        request_sha256: &str,
        idempotency_key: Option<&str>,
    ) -> StoreResult<Inserted> {
        if let Some(key) = idempotency_key {
            if let Some(j) = self.job_by_key(key).await? {
                return Ok(replay_or_conflict(j, request_sha256));
            }
        }
        let mut tx = self.begin_write().await?;
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
        .bind(request.to_json())
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
        .execute(&mut *self.writer().await?)
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
        .execute(&mut *self.writer().await?)
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
        .execute(&mut *self.writer().await?)
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
        problem: Option<&JobProblem>,
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
        problem: Option<&JobProblem>,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
        records: &qc::JobRecords,
    ) -> StoreResult<()> {
        let mut tx = self.begin_write().await?;
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
        .bind(problem.map(problem_json))
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
        problem: Option<&JobProblem>,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
        records: &qc::JobRecords,
    ) -> StoreResult<bool> {
        let mut tx = self.begin_write().await?;
        let r = sqlx::query(
            "UPDATE jobs SET state = ?, finished_at = ?, problem_json = ?, bench_time_s = ?, log_json = ?, warnings_json = ?, eta_s = NULL \
             WHERE id = ? AND state = 'running'",
        )
        .bind(state.as_str())
        .bind(now())
        .bind(problem.map(problem_json))
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
        // A study job (issue 33) ended here without its own end (a kill -9
        // while it measured or waited for the operator): the study ends
        // with it, so that it never waits for a confirmation nobody runs.
        sqlx::query(
            "UPDATE studies SET state = 'failed', instruction = NULL, updated_at = ? \
             WHERE job_id = ? AND state NOT IN ('succeeded', 'failed')",
        )
        .bind(now())
        .bind(id.to_string())
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(true)
    }

    /// Stores a running job's finished recordings and measurements (a
    /// level as it finishes) in one transaction; the job stays running. The
    /// measurements' `pre` and `main` index into `known` (recordings stored
    /// earlier, by id) followed by `recordings`. Answers the ids of
    /// `recordings`.
    pub async fn insert_job_measurements(
        &self,
        job_id: &str,
        known: &[i64],
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
    ) -> StoreResult<Vec<i64>> {
        let mut tx = self.begin_write().await?;
        running_job(&mut tx, job_id).await?;
        let new = insert_results(&mut tx, recordings, vec![]).await?;
        let ids: Vec<i64> = known.iter().chain(&new).copied().collect();
        insert_measurement_rows(&mut tx, measurements, &ids).await?;
        tx.commit().await?;
        Ok(new)
    }

    /// Replaces the configuration and result documents of a running job's
    /// stored measurements (a level series' joint fit, known once its last
    /// level is measured), in one transaction.
    pub async fn update_job_measurements(
        &self,
        job_id: &str,
        updates: Vec<(
            String,
            MeasurementConfig,
            Option<springbench_core::identify::Report>,
        )>,
    ) -> StoreResult<()> {
        let mut tx = self.begin_write().await?;
        running_job(&mut tx, job_id).await?;
        for (id, config, result) in updates {
            let r = sqlx::query(
                "UPDATE measurements SET config_json = ?, result_json = ? WHERE id = ? AND job_id = ?",
            )
            .bind(config.to_json())
            .bind(
                result
                    .and_then(|r| serde_json::to_value(r).ok())
                    .map(|v| v.to_string()),
            )
            .bind(&id)
            .bind(job_id.to_string())
            .execute(&mut *tx)
            .await?;
            if r.rows_affected() != 1 {
                return Err(StoreError::Corrupt(format!(
                    "measurement {id} of job {job_id} is not stored"
                )));
            }
        }
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
}

/// Refuses to add to a job that is not running.
pub(crate) async fn running_job(tx: &mut sqlx::SqliteConnection, job_id: &str) -> StoreResult<()> {
    let running: Option<i64> =
        sqlx::query_scalar("SELECT 1 FROM jobs WHERE id = ? AND state = 'running'")
            .bind(job_id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
    match running {
        Some(_) => Ok(()),
        None => Err(StoreError::Corrupt(format!("job {job_id} is not running"))),
    }
}

/// A problem as stored (the RFC 9457 document).
fn problem_json(p: &JobProblem) -> String {
    serde_json::to_string(p).unwrap_or_default()
}

fn replay_or_conflict(j: Job, sha: &str) -> Inserted {
    if j.request_sha256 == sha {
        Inserted::Replayed(j)
    } else {
        Inserted::Conflict(j)
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
        request: JobRequestRow::parse(&r.get::<String, _>("request_json"))?,
        request_sha256: r.get("request_sha256"),
        problem: r
            .get::<Option<String>, _>("problem_json")
            .map(|s| {
                serde_json::from_str(&s)
                    .map_err(|e| StoreError::Corrupt(format!("stored problem unreadable: {e}")))
            })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::{MeasurementReads, PartReads};
    use serde_json::json;

    fn self_check(bench: &str) -> StoredRequest {
        StoredRequest::SelfCheck(springbench_core::job::SelfCheck {
            bench: bench.into(),
        })
    }

    use crate::results::tiny_recording as rec;

    #[tokio::test]
    async fn job_lifecycle_and_results_round_trip() {
        let s = Store::memory().await.unwrap();
        let req = self_check("b1");
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
            config: serde_json::from_value(json!({"method": "two-signal"})).unwrap(),
            meta: crate::Doc::Received(json!({"moving_mass_kg": 0.05})),
            result: Some(crate::Doc::Received(
                json!({"large_signal": {"keff_n_per_m": 1234.5,
                "validity": {"keff_n_per_m": {"state": "unreliable", "reason": "noise"}}},
                "small_signal": {"k0_n_per_m": 1792.0, "k0_se_n_per_m": 210.0,
                                 "misfit_percent": 12.5, "reliable": false}}),
            )),
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
        // Its state beside it (issue 22): a list shows it with the value.
        assert_eq!(
            info.summary["keff_validity"],
            json!({"state": "unreliable", "reason": "noise"})
        );
        assert_eq!(info.summary["resonance_validity"], json!(null));
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
        let req = self_check("b1");
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
        assert_eq!(j.problem.unwrap().title, "Job interrupted");
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
        let req = self_check("b1");
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
        let p = b.problem.unwrap();
        assert_eq!(p.kind, ProblemKind::UnknownBench);
        assert!(p.detail.contains("gone"));
        assert_eq!(
            s.get_job("a").await.unwrap().unwrap().state,
            JobState::Queued
        );
    }
}
