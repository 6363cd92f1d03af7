//! Runner: one task owns each bench, takes its queued jobs (priority, then
//! FIFO), runs the measurement procedure on a blocking thread, fits the
//! each level with the identification core as the procedure hands it out
//! and stores its recordings and measurement in one transaction at once
//! (the repeat's series result is written into them when the repeat ends);
//! the job's end (state, verdicts, MES messages) is one more transaction. Job state changes and step progress become stored events;
//! live decimated samples are broadcast only.
//!
//! States: queued -> running -> succeeded | failed | cancelled | interrupted.
//! A job still `running` at start (crash, kill -9) is marked `interrupted`
//! and never re-run. At shutdown the running job is aborted (the bench ramps
//! its drive down), then marked `interrupted`.

pub mod events;
mod execute;
#[cfg(test)]
mod guard;
pub mod hardware;
pub mod job;
mod longterm;
mod records;
mod series;
mod studies;

use crate::bench::Bench;
use crate::config::{BenchConfig, BenchKind, Config};
use crate::identify::{self, AnalyzeOptions};
use crate::job::{JobProblem, ProblemKind};
use crate::physics::PartSpec;
use crate::procedure::{self, Observer, ProcedureConfig, ProcedureError, Step};
use crate::recording::Meta;
use crate::store::RecipeReads;
use crate::store::{Doc, Job, JobState, NewMeasurement, NewRecording, Store, StoreResult};
pub use events::{EventBus, JobEvent};
use execute::*;
pub use job::{FieldError, JobSpec};
pub use longterm::PauseOutcome;
use serde::Serialize;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, Notify};
use tokio::task::JoinHandle;

/// Cancel flag of a running job: running, cancel requested, results being committed.
const RUN: u8 = 0;
const CANCEL: u8 = 1;
const COMMIT: u8 = 2;

/// What a bench is doing (for `/readyz`).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct BenchStatus {
    pub id: String,
    pub kind: BenchKind,
    /// "idle", "running", "faulted" (hardware: until a self-check passes) or "stopped".
    #[schema(value_type = String, pattern = "^(idle|running|faulted|stopped)$")]
    pub state: &'static str,
    pub job_id: Option<String>,
    /// The preset mounted when a job names none.
    pub preset: String,
    /// What faulted the bench, and when (state `faulted`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<hardware::FaultInfo>,
}

struct Slot {
    cfg: BenchConfig,
    notify: Notify,
    status: Mutex<BenchStatus>,
    /// Throughput of the finished jobs, by procedure (`full`, `production`).
    throughput: Mutex<std::collections::BTreeMap<&'static str, Throughput>>,
}

/// What a bench's finished jobs of one procedure took (for `/metrics`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Throughput {
    /// Parts measured (repeats of the procedure).
    pub parts: u64,
    /// Production runs that fell back to the full procedure.
    pub fallbacks: u64,
    /// Stimulus time played and captured (s).
    pub bench_time_s: f64,
    /// Fits and judging on the job's thread (s).
    pub analysis_s: f64,
    /// Wall time from the job's start to its end, storage included (s).
    pub wall_s: f64,
}

/// Result of a cancel request.
pub enum CancelOutcome {
    /// The job was queued and is now cancelled.
    Cancelled(Job),
    /// The job is running; the bench is told to stop (it becomes `cancelled`).
    Requested(Job),
    /// The job had already finished.
    Finished(Job),
    /// The job's results are being stored: too late to cancel.
    Finishing(Job),
    NotFound,
}

pub struct Runner {
    store: Store,
    events: EventBus,
    slots: HashMap<String, Arc<Slot>>,
    /// Cancel flags of the running jobs, by job id.
    running: Mutex<HashMap<String, Arc<AtomicU8>>>,
    shutdown: Arc<AtomicBool>,
    /// MES: CFX source and the webhooks each finished job's messages go to.
    mes: crate::mes::MesConfig,
    /// Wakes the MES delivery worker when messages were written.
    outbox: Arc<Notify>,
    /// A fleet station's recipe provenance for its verdicts' trace
    /// (`fleet::Link::recipe_trace`: `offline` when the station could not
    /// check its recipes with the center lately); unset without `[fleet]`.
    recipe_trace: std::sync::OnceLock<RecipeTrace>,
    /// `min_free_bytes`: a long-term test pauses below it (`longterm.rs`).
    min_free_bytes: u64,
    /// The user's pause of the running long-term tests, by job id (decision 0130).
    pauses: Mutex<HashMap<String, longterm::SharedPause>>,
}

/// See [`Runner::set_recipe_trace`].
pub type RecipeTrace = Arc<dyn Fn() -> crate::qc::FleetTrace + Send + Sync>;

/// What a measuring job has before its bench moves ([`Runner::preflight`]).
struct Preflight {
    /// A hardware bench's calibration record (None on a virtual bench).
    calibration: Option<crate::store::hardware::CalibrationRecord>,
    /// The job's start as stored.
    started_at: String,
    /// The job's recipe (None: it names none), or why it cannot be used.
    recipe: Result<Option<crate::qc::Recipe>, String>,
    /// The bench's calibration under the recipe (decision 0049).
    bench_cal: Option<crate::qc::BenchCalibration>,
    /// What the verdicts' trace says of it (None without a recipe).
    cal_trace: Option<crate::qc::BenchCalibrationTrace>,
}

impl Runner {
    /// Makes every verdict's trace carry what `f` gives (the fleet's recipe
    /// provenance, at the trace's top level). Set once.
    pub fn set_recipe_trace(&self, f: RecipeTrace) {
        let _ = self.recipe_trace.set(f);
    }

    /// Marks jobs cut off by an earlier stop as interrupted and starts one task per bench.
    pub async fn start(
        store: Store,
        events: EventBus,
        cfg: &Config,
    ) -> StoreResult<(Arc<Runner>, Vec<JoinHandle<()>>)> {
        map_large_buffers();
        let known: Vec<String> = cfg.benches.iter().map(|b| b.id.clone()).collect();
        for id in store.fail_queued_on_unknown_benches(&known).await? {
            let problem = store.get_job(&id).await?.and_then(|j| j.problem);
            events
                .publish(
                    Some(&id),
                    &JobEvent::Failed {
                        state: JobState::Failed,
                        problem,
                    },
                )
                .await?;
            tracing::warn!(job = %id, "queued job of a bench no longer configured: failed");
        }
        let slots: HashMap<String, Arc<Slot>> = cfg
            .benches
            .iter()
            .map(|b| {
                (
                    b.id.clone(),
                    Arc::new(Slot {
                        cfg: b.clone(),
                        notify: Notify::new(),
                        status: Mutex::new(BenchStatus {
                            id: b.id.clone(),
                            kind: b.kind,
                            state: "idle",
                            job_id: None,
                            preset: b.preset.clone(),
                            fault: None,
                        }),
                        throughput: Mutex::default(),
                    }),
                )
            })
            .collect();
        for f in store.open_bench_faults().await? {
            if let Some(slot) = slots.get(&f.bench_id) {
                let slot: &Arc<Slot> = slot;
                let mut st = slot.status.lock().unwrap();
                st.state = "faulted";
                st.fault = Some(hardware::FaultInfo {
                    detail: f.detail,
                    job_id: f.job_id,
                    since: f.created_at,
                });
            }
        }
        let runner = Arc::new(Runner {
            store,
            events,
            slots,
            running: Mutex::new(HashMap::new()),
            shutdown: Arc::new(AtomicBool::new(false)),
            mes: cfg.mes.clone(),
            outbox: Arc::new(Notify::new()),
            recipe_trace: std::sync::OnceLock::new(),
            min_free_bytes: cfg.min_free_bytes,
            pauses: Mutex::new(HashMap::new()),
        });
        longterm::requeue(&runner.store).await?;
        runner.end_interrupted(cfg).await?;
        let tasks = runner
            .slots
            .values()
            .map(|slot| {
                let r = runner.clone();
                let slot = slot.clone();
                tokio::spawn(async move { r.bench_loop(slot).await })
            })
            .collect();
        Ok((runner, tasks))
    }

    pub fn events(&self) -> &EventBus {
        &self.events
    }

    /// The notifier of the MES delivery worker (see [`crate::mes::start`]).
    pub fn outbox_wake(&self) -> Arc<Notify> {
        self.outbox.clone()
    }

    /// A job was queued on `bench_id`.
    pub fn wake(&self, bench_id: &str) {
        if let Some(s) = self.slots.get(bench_id) {
            s.notify.notify_one();
        }
    }

    pub fn bench_statuses(&self) -> Vec<BenchStatus> {
        let mut v: Vec<_> = self
            .slots
            .values()
            .map(|s| s.status.lock().unwrap().clone())
            .collect();
        v.sort_by(|a, b| a.id.cmp(&b.id));
        v
    }

    /// Throughput per bench and procedure of the jobs finished since the start.
    pub fn throughput(&self) -> Vec<(String, &'static str, Throughput)> {
        let mut v = vec![];
        for s in self.slots.values() {
            for (mode, t) in s.throughput.lock().unwrap().iter() {
                v.push((s.cfg.id.clone(), *mode, *t));
            }
        }
        v.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        v
    }

    /// Stops taking jobs; the running ones are aborted (and become interrupted).
    pub fn shutdown(&self) {
        self.shutdown.store(true, Ordering::SeqCst);
        for s in self.slots.values() {
            s.notify.notify_one();
        }
    }

    pub async fn cancel(&self, id: &str) -> StoreResult<CancelOutcome> {
        if self.store.cancel_queued(id).await? {
            self.events
                .publish(
                    Some(id),
                    &JobEvent::State {
                        state: JobState::Cancelled,
                    },
                )
                .await?;
            return Ok(match self.store.get_job(id).await? {
                Some(j) => CancelOutcome::Cancelled(j),
                None => CancelOutcome::NotFound,
            });
        }
        let flag = self.running.lock().unwrap().get(id).cloned();
        let Some(job) = self.store.get_job(id).await? else {
            return Ok(CancelOutcome::NotFound);
        };
        if let Some(flag) = flag {
            if !job.state.is_terminal() {
                return Ok(
                    match flag.compare_exchange(RUN, CANCEL, Ordering::SeqCst, Ordering::SeqCst) {
                        Ok(_) | Err(CANCEL) => CancelOutcome::Requested(job),
                        Err(_) => CancelOutcome::Finishing(job),
                    },
                );
            }
        }
        Ok(CancelOutcome::Finished(job))
    }

    async fn bench_loop(self: Arc<Self>, slot: Arc<Slot>) {
        loop {
            if self.shutdown.load(Ordering::SeqCst) {
                break;
            }
            match self.store.next_queued(&slot.cfg.id).await {
                Ok(Some(job)) => {
                    if let Err(e) = self.run_one(&slot, job).await {
                        tracing::error!(bench = %slot.cfg.id, "storing a job failed: {e}");
                        tokio::time::sleep(Duration::from_secs(1)).await;
                    }
                }
                Ok(None) => {
                    let _ =
                        tokio::time::timeout(Duration::from_secs(1), slot.notify.notified()).await;
                }
                Err(e) => {
                    tracing::error!(bench = %slot.cfg.id, "reading the queue failed: {e}");
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
        }
        slot.status.lock().unwrap().state = "stopped";
    }

    async fn run_one(&self, slot: &Slot, job: Job) -> StoreResult<()> {
        let flag = Arc::new(AtomicU8::new(RUN));
        self.running
            .lock()
            .unwrap()
            .insert(job.id.clone(), flag.clone());
        let res = match self.run_registered(slot, &job, flag).await {
            // A store error (full disk, lost file) anywhere after the job
            // started: it ends `failed` with its verdict and MES messages as
            // soon as the store can write, never `running` forever. A job
            // that never started stays queued and is taken again.
            Err(e) => {
                tracing::error!(job = %job.id, "the store failed during the job: {e}");
                let p = JobProblem::new(
                    ProblemKind::Storage,
                    "Results not stored",
                    format!(
                        "the store could not write during the job ({e}); measure the part again"
                    ),
                );
                self.finish_failed_after(slot, &job, &p, None, &[], &[])
                    .await
            }
            ok => ok,
        };
        self.running.lock().unwrap().remove(&job.id);
        self.settle(slot);
        res
    }

    /// The bench's state once its job has ended: `stopped` (shutdown),
    /// `faulted` or `idle`. Called before the job's end is stored, so that
    /// whoever sees the job ended also sees its bench settled (a client
    /// that read `succeeded` and then the bench read `running`: the CI
    /// failure of session 11's hardware_serial test).
    fn settle(&self, slot: &Slot) {
        let mut st = slot.status.lock().unwrap();
        st.state = if self.shutdown.load(Ordering::SeqCst) {
            "stopped"
        } else if st.fault.is_some() {
            "faulted"
        } else {
            "idle"
        };
        st.job_id = None;
    }

    /// Stores a job's end (`commit`) with its bench settled first; if the
    /// store fails, the bench is `running` the job again (see [`Self::unsettle`]).
    /// The one way each of the three places that end a job commits it.
    async fn commit_settled<T>(
        &self,
        slot: &Slot,
        job_id: &str,
        commit: impl std::future::Future<Output = StoreResult<T>>,
    ) -> StoreResult<T> {
        self.settle(slot);
        let r = commit.await;
        if r.is_err() {
            Self::unsettle(slot, job_id);
        }
        r
    }

    /// Back to `running` job `job_id` when storing its end failed: the
    /// bench takes no other job while the runner retries.
    fn unsettle(slot: &Slot, job_id: &str) {
        let mut st = slot.status.lock().unwrap();
        if st.state != "stopped" {
            st.state = "running";
        }
        st.job_id = Some(job_id.to_string());
    }

    async fn run_registered(
        &self,
        slot: &Slot,
        job: &Job,
        cancel: Arc<AtomicU8>,
    ) -> StoreResult<()> {
        // A measuring job announces its start to the MES (WorkStarted) in
        // the transaction that starts it.
        let started_at = crate::store::now();
        let announce = match job.request.read() {
            Ok(
                crate::job::StoredRequest::SelfCheck(_)
                | crate::job::StoredRequest::LongTerm(_)
                | crate::job::StoredRequest::Study(_),
            ) => Default::default(),
            _ => self.start_records(&slot.cfg, job, &started_at),
        };
        if !self
            .store
            .start_job_announced(&job.id, &started_at, &announce)
            .await?
        {
            return Ok(()); // cancelled meanwhile
        }
        if !announce.messages.is_empty() && !announce.webhooks.is_empty() {
            self.outbox.notify_one();
        }
        {
            let mut st = slot.status.lock().unwrap();
            st.state = "running";
            st.job_id = Some(job.id.clone());
        }
        self.events
            .publish(
                Some(&job.id),
                &JobEvent::State {
                    state: JobState::Running,
                },
            )
            .await?;
        tracing::info!(job = %job.id, bench = %slot.cfg.id, part = %job.part_serial, "job started");

        let started = Instant::now();
        let spec: Result<JobSpec, String> = match job.request.read() {
            Ok(crate::job::StoredRequest::SelfCheck(_)) => {
                return self.run_self_check(slot, job, started).await
            }
            Ok(crate::job::StoredRequest::LongTerm(t)) => {
                return self.run_long_term(slot, job, t.clone(), cancel).await
            }
            Ok(crate::job::StoredRequest::Study(s)) => {
                return self.run_study(slot, job, s.clone(), cancel, started).await
            }
            Ok(crate::job::StoredRequest::Measure(s)) => Ok(s.clone()),
            Err(e) => Err(e.to_string()),
        };
        let pf = match self.preflight(slot, job, &spec).await? {
            Ok(pf) => pf,
            Err(p) => return self.finish_failed(slot, job, p).await,
        };
        let outcome = self.measure(slot, job, &spec, &pf, &cancel).await;
        self.record(slot, job, &spec, pf, outcome, &cancel, started)
            .await
    }

    /// Before the bench moves: a hardware bench's calibration record (a
    /// faulted bench refuses), the job's start as stored, the recipe and
    /// the bench's calibration under it. A recipe or a calibration that
    /// cannot be read is the job's failure later, named (`measure`).
    async fn preflight(
        &self,
        slot: &Slot,
        job: &Job,
        spec: &Result<JobSpec, String>,
    ) -> StoreResult<Result<Preflight, JobProblem>> {
        // A hardware bench: faulted benches refuse, every measurement needs a calibration record.
        let calibration = match self.hardware_preflight(slot, job, spec).await? {
            Ok(c) => c,
            Err(p) => return Ok(Err(p)),
        };
        let started_at = self
            .store
            .get_job(&job.id)
            .await?
            .and_then(|j| j.started_at)
            .unwrap_or_else(crate::store::now);
        let recipe = match spec {
            Ok(s) => match &s.recipe {
                Some(r) => Some(self.load_recipe(r).await?),
                None => None,
            },
            Err(_) => None,
        };
        // The bench's calibration from golden units under the recipe (decision 0049).
        // The calibration of the procedure the job asks for (a production
        // job that falls back is still judged with it; docs/qc.md).
        // A calibration this version cannot read fails the job, named.
        let cal_read = match (recipe.as_ref().and_then(|r| r.as_ref().ok()), spec.as_ref()) {
            (Some(r), Ok(s)) => match self
                .store
                .latest_bench_calibration(&r.name, &slot.cfg.id, s.procedure.as_str())
                .await
            {
                Err(crate::store::StoreError::Corrupt(why)) => Err(why),
                other => Ok(other?),
            },
            _ => Ok(None),
        };
        let (cal_row, bench_cal) = match cal_read {
            Ok(row) => {
                let cal = row.as_ref().map(|c| c.calibration.clone());
                (row, Ok(cal))
            }
            Err(why) => (None, Err(why)),
        };
        let cal_trace = recipe.as_ref().is_some_and(|r| r.is_ok()).then(|| {
            records::calibration_trace(
                cal_row.as_ref(),
                bench_cal.as_ref().ok().and_then(|c| c.as_ref()),
            )
        });
        let recipe_ok = match bench_cal.clone() {
            Ok(_) => recipe.clone().transpose(),
            Err(e) => Err(e),
        };
        Ok(Ok(Preflight {
            calibration,
            started_at,
            recipe: recipe_ok,
            bench_cal: bench_cal.ok().flatten(),
            cal_trace,
        }))
    }

    /// The measurement on the bench's blocking thread ([`execute`]), its
    /// messages (progress, live samples, each finished repeat) handled here
    /// as they come.
    async fn measure(
        &self,
        slot: &Slot,
        job: &Job,
        spec: &Result<JobSpec, String>,
        pf: &Preflight,
        cancel: &Arc<AtomicU8>,
    ) -> Result<Done, Stop> {
        match (spec.as_ref(), pf.recipe.clone()) {
            (Err(e), _) => Err(Stop::Failed(JobProblem::new(
                ProblemKind::JobUnreadable,
                "Job request unreadable",
                format!("the stored request no longer parses: {e}"),
            ))),
            (Ok(_), Err(e)) => Err(Stop::Failed(JobProblem::new(
                ProblemKind::Recipe,
                "Recipe not available",
                &e,
            ))),
            (Ok(spec), Ok(recipe)) => {
                let spec = spec.clone();
                let (tx, mut rx) = mpsc::unbounded_channel();
                let obs = JobObserver::new(tx, cancel.clone(), self.shutdown.clone(), spec.repeats);
                let bench_cfg = slot.cfg.clone();
                let seed = bench_cfg.seed.wrapping_add(job.seq as u64);
                let job_id = job.id.clone();
                let job_seq = job.seq;
                let cal = pf.calibration.clone();
                let bench_cal = pf.bench_cal.clone();
                let mut handle = tokio::task::spawn_blocking(move || {
                    let mut obs = obs;
                    execute(
                        &job_id,
                        job_seq,
                        &spec,
                        &bench_cfg,
                        seed,
                        cal.as_ref(),
                        recipe.as_ref(),
                        bench_cal.as_ref(),
                        &mut obs,
                    )
                });
                let res = loop {
                    tokio::select! {
                        msg = rx.recv() => match msg {
                            Some(m) => self.on_message(&job.id, m).await,
                            None => break (&mut handle).await,
                        },
                        r = &mut handle => break r,
                    }
                };
                while let Ok(m) = rx.try_recv() {
                    self.on_message(&job.id, m).await;
                }
                match res {
                    Ok(r) => r,
                    Err(e) => Err(Stop::Failed(JobProblem::new(
                        ProblemKind::Internal,
                        "Job crashed",
                        format!("the measurement task ended abnormally: {e}"),
                    ))),
                }
            }
        }
    }

    /// After the measurement: the job's state, its records (verdicts, CFX
    /// messages, webhooks) committed with it, the bench's throughput, and
    /// the events.
    #[allow(clippy::too_many_arguments)]
    async fn record(
        &self,
        slot: &Slot,
        job: &Job,
        spec: &Result<JobSpec, String>,
        pf: Preflight,
        outcome: Result<Done, Stop>,
        cancel: &Arc<AtomicU8>,
        started: Instant,
    ) -> StoreResult<()> {
        let Preflight {
            calibration,
            started_at,
            cal_trace,
            ..
        } = pf;
        // From here on a cancel is too late (409); one that came during the
        // fit still wins, so a 202 always ends as `cancelled`.
        let cancelled_late = cancel.swap(COMMIT, Ordering::SeqCst) == CANCEL;
        let (state, prob, done) = match outcome {
            Ok(_) if cancelled_late => (JobState::Cancelled, None, None),
            Ok(done) => (JobState::Succeeded, None, Some(done)),
            Err(Stop::Aborted) if self.shutdown.load(Ordering::SeqCst) => (
                JobState::Interrupted,
                Some(JobProblem::new(ProblemKind::Interrupted,
                    "Job interrupted",
                    "the daemon was stopped while this job was running; the bench was ramped down and the job was not re-run (submit it again)",
                )),
                None,
            ),
            Err(Stop::Aborted) => (JobState::Cancelled, None, None),
            Err(Stop::Failed(p)) => (JobState::Failed, Some(p), None),
        };
        if let Some(p) = prob.as_ref().filter(|p| p.kind == ProblemKind::BenchFault) {
            self.fault_bench(slot, &job.id, p).await?;
        }
        if let (Some(d), Ok(sp)) = (&done, &spec) {
            let mut t = slot.throughput.lock().unwrap();
            let e = t.entry(sp.procedure.as_str()).or_default();
            e.parts += u64::from(d.parts);
            e.fallbacks += u64::from(d.fallbacks);
            e.bench_time_s += d.bench_time_s;
            e.analysis_s += d.analysis_s;
            e.wall_s += started.elapsed().as_secs_f64();
        }
        let (bench_time, log, warnings, meas, reports, verdicts) = match done {
            Some(d) => (
                Some(d.bench_time_s),
                d.log,
                d.warnings,
                d.measurements,
                d.reports,
                d.verdicts,
            ),
            None => (None, vec![], vec![], vec![], vec![], vec![]),
        };
        let records = self.job_records(
            &slot.cfg,
            job,
            spec.as_ref().ok(),
            cal_trace.as_ref(),
            &started_at,
            state,
            prob.as_ref(),
            &meas,
            &reports,
            verdicts,
        );
        let job_verdict = records
            .verdicts
            .iter()
            .find(|v| v.measurement_id.is_none())
            .map(|v| v.verdict);
        let new_measurements: Vec<String> = meas.iter().map(|m| m.id.clone()).collect();
        let commit = self.store.finish_job_qc(
            &job.id,
            state,
            prob.as_ref(),
            bench_time,
            &log,
            &warnings,
            // stored as each level finished (Msg::Store)
            vec![],
            vec![],
            &records,
        );
        if let Err(e) = self.commit_settled(slot, &job.id, commit).await {
            // The results could not be written: do not leave the job running.
            tracing::error!(job = %job.id, "storing the results failed: {e}");
            let p = JobProblem::new(
                ProblemKind::Storage,
                "Results not stored",
                format!("writing the results failed: {e}"),
            );
            return self
                .finish_failed_after(slot, job, &p, bench_time, &log, &warnings)
                .await;
        }
        if let (Some(c), JobState::Succeeded) = (&calibration, state) {
            self.store
                .set_measurement_calibration(&job.id, &c.id)
                .await?;
        }
        let measurement_ids = self
            .store
            .get_job(&job.id)
            .await?
            .map(|j| j.measurement_ids)
            .unwrap_or_default();
        tracing::info!(job = %job.id, state = state.as_str(), wall_s = started.elapsed().as_secs_f64(), "job finished");
        if !records.messages.is_empty() && !records.webhooks.is_empty() {
            self.outbox.notify_one();
        }
        for id in &new_measurements {
            self.events
                .publish(
                    Some(&job.id),
                    &JobEvent::MeasurementCreated {
                        measurement_id: id.clone(),
                        part_serial: job.part_serial.clone(),
                        source: "bench",
                    },
                )
                .await?;
        }
        self.events
            .publish(
                Some(&job.id),
                &JobEvent::Finished {
                    state,
                    problem: prob,
                    bench_time_s: bench_time,
                    measurement_ids,
                    warnings,
                    verdict: job_verdict,
                },
            )
            .await?;
        Ok(())
    }

    async fn on_message(&self, job_id: &str, m: Msg) {
        match m {
            Msg::Progress {
                step,
                progress,
                eta_s,
            } => {
                let step = step_name(step);
                if let Err(e) = self.store.set_progress(job_id, step, progress, eta_s).await {
                    tracing::warn!(job = %job_id, "progress not stored: {e}");
                }
                if let Err(e) = self
                    .events
                    .publish(
                        Some(job_id),
                        &JobEvent::Progress {
                            step,
                            progress,
                            eta_s,
                        },
                    )
                    .await
                {
                    tracing::warn!(job = %job_id, "progress event not stored: {e}");
                }
            }
            Msg::Samples(data) => self.events.publish_live(Some(job_id), &data).await,
            Msg::Store(batch, reply) => {
                let mut r = Ok(vec![]);
                if !batch.recordings.is_empty() || !batch.measurements.is_empty() {
                    r = self
                        .store
                        .insert_job_measurements(
                            job_id,
                            &batch.known,
                            batch.recordings,
                            batch.measurements,
                        )
                        .await;
                }
                if r.is_ok() && !batch.updates.is_empty() {
                    r = self
                        .store
                        .update_job_measurements(job_id, batch.updates)
                        .await
                        .map(|()| vec![]);
                }
                let r = r.map_err(|e| e.to_string());
                if let Err(e) = &r {
                    tracing::error!(job = %job_id, "storing finished measurements failed: {e}");
                }
                let _ = reply.send(r);
            }
        }
    }
}

pub fn step_name(s: Step) -> &'static str {
    match s {
        Step::PreMeasurement => "pre_measurement",
        Step::ResonanceSearch => "resonance_search",
        Step::NarrowSweep => "narrow_sweep",
        Step::Fit => "fit",
    }
}

pub(super) enum Stop {
    /// Cancel or shutdown: the bench was ramped down.
    Aborted,
    Failed(JobProblem),
}

/// A fresh id (UUID v4, text).
pub fn new_id() -> String {
    uuid::Uuid::new_v4().to_string()
}
