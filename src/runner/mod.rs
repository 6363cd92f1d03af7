//! Runner: one task owns each bench, takes its queued jobs (priority, then
//! FIFO), runs the measurement procedure on a blocking thread, fits the
//! result with the identification core and stores each finished repeat's
//! recordings and measurements in one transaction as soon as it is done;
//! the job's end (state, verdicts, MES messages) is one more transaction. Job state changes and step progress become stored events;
//! live decimated samples are broadcast only.
//!
//! States: queued -> running -> succeeded | failed | cancelled | interrupted.
//! A job still `running` at start (crash, kill -9) is marked `interrupted`
//! and never re-run. At shutdown the running job is aborted (the bench ramps
//! its drive down), then marked `interrupted`.

pub mod events;
pub mod hardware;
pub mod job;
mod series;

use crate::bench::Bench;
use crate::config::{BenchConfig, BenchKind, Config};
use crate::identify::{self, AnalyzeOptions};
use crate::physics::PartSpec;
use crate::procedure::{self, Observer, ProcedureConfig, ProcedureError, Step};
use crate::recording::{Meta, RecordingSet};
use crate::store::RecipeReads;
use crate::store::{Job, JobState, NewMeasurement, NewRecording, Store, StoreResult};
pub use events::EventBus;
pub use job::{FieldError, JobSpec};
use serde::Serialize;
use serde_json::{json, Value};
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
}

impl Runner {
    /// Marks jobs cut off by an earlier stop as interrupted and starts one task per bench.
    pub async fn start(
        store: Store,
        events: EventBus,
        cfg: &Config,
    ) -> StoreResult<(Arc<Runner>, Vec<JoinHandle<()>>)> {
        let known: Vec<String> = cfg.benches.iter().map(|b| b.id.clone()).collect();
        for id in store.fail_queued_on_unknown_benches(&known).await? {
            let problem = store.get_job(&id).await?.and_then(|j| j.problem);
            events
                .publish(
                    "job.state",
                    Some(&id),
                    json!({"state": "failed", "problem": problem}),
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
        });
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
                .publish("job.state", Some(id), json!({"state": "cancelled"}))
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
                let p = problem(
                    "storage",
                    "Results not stored",
                    &format!(
                        "the store could not write during the job ({e}); measure the part again"
                    ),
                );
                self.finish_failed_after(slot, &job, &p, None, &[], &[])
                    .await
            }
            ok => ok,
        };
        self.running.lock().unwrap().remove(&job.id);
        {
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
        res
    }

    async fn run_registered(
        &self,
        slot: &Slot,
        job: &Job,
        cancel: Arc<AtomicU8>,
    ) -> StoreResult<()> {
        if !self.store.start_job(&job.id).await? {
            return Ok(()); // cancelled meanwhile
        }
        {
            let mut st = slot.status.lock().unwrap();
            st.state = "running";
            st.job_id = Some(job.id.clone());
        }
        self.events
            .publish("job.state", Some(&job.id), json!({"state": "running"}))
            .await?;
        tracing::info!(job = %job.id, bench = %slot.cfg.id, part = %job.part_serial, "job started");

        let started = Instant::now();
        if hardware::is_self_check(job) {
            return self.run_self_check(slot, job, started).await;
        }
        let spec: Result<JobSpec, _> = serde_json::from_value(job.request.clone());
        // A hardware bench: faulted benches refuse, every measurement needs a calibration record.
        let calibration = match self.hardware_preflight(slot, job, &spec).await? {
            Ok(c) => c,
            Err(p) => return self.finish_failed(slot, job, p).await,
        };
        let started_at = self
            .store
            .get_job(&job.id)
            .await?
            .and_then(|j| j.started_at)
            .unwrap_or_else(crate::store::now);
        let recipe = match &spec {
            Ok(s) => match &s.recipe {
                Some(r) => Some(self.load_recipe(r).await?),
                None => None,
            },
            Err(_) => None,
        };
        let recipe_ok = recipe.clone().transpose();
        let outcome = match (spec.as_ref(), recipe_ok) {
            (Err(e), _) => Err(Stop::Failed(problem(
                "job-unreadable",
                "Job request unreadable",
                &format!("the stored request no longer parses: {e}"),
            ))),
            (Ok(_), Err(e)) => Err(Stop::Failed(problem("recipe", "Recipe not available", &e))),
            (Ok(spec), Ok(recipe)) => {
                let spec = spec.clone();
                let (tx, mut rx) = mpsc::unbounded_channel();
                let obs = JobObserver::new(tx, cancel.clone(), self.shutdown.clone(), spec.repeats);
                let bench_cfg = slot.cfg.clone();
                let seed = bench_cfg.seed.wrapping_add(job.seq as u64);
                let job_id = job.id.clone();
                let job_seq = job.seq;
                let cal = calibration.clone();
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
                    Err(e) => Err(Stop::Failed(problem(
                        "internal",
                        "Job crashed",
                        &format!("the measurement task ended abnormally: {e}"),
                    ))),
                }
            }
        };

        // From here on a cancel is too late (409); one that came during the
        // fit still wins, so a 202 always ends as `cancelled`.
        let cancelled_late = cancel.swap(COMMIT, Ordering::SeqCst) == CANCEL;
        let (state, prob, done) = match outcome {
            Ok(_) if cancelled_late => (JobState::Cancelled, None, None),
            Ok(done) => (JobState::Succeeded, None, Some(done)),
            Err(Stop::Aborted) if self.shutdown.load(Ordering::SeqCst) => (
                JobState::Interrupted,
                Some(problem(
                    "interrupted",
                    "Job interrupted",
                    "the daemon was stopped while this job was running; the bench was ramped down and the job was not re-run (submit it again)",
                )),
                None,
            ),
            Err(Stop::Aborted) => (JobState::Cancelled, None, None),
            Err(Stop::Failed(p)) => (JobState::Failed, Some(p), None),
        };
        if let Some(p) = prob.as_ref().filter(|p| hardware::is_bench_fault(p)) {
            self.fault_bench(slot, &job.id, p).await?;
        }
        let (bench_time, log, warnings, recs, meas, reports, verdicts) = match done {
            Some(d) => (
                Some(d.bench_time_s),
                d.log,
                d.warnings,
                d.recordings,
                d.measurements,
                d.reports,
                d.verdicts,
            ),
            None => (None, vec![], vec![], vec![], vec![], vec![], vec![]),
        };
        let records = self.job_records(
            &slot.cfg,
            job,
            spec.as_ref().ok(),
            recipe.and_then(|r| r.ok()).as_ref(),
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
        if let Err(e) = self
            .store
            .finish_job_qc(
                &job.id,
                state,
                prob.as_ref(),
                bench_time,
                &log,
                &warnings,
                recs,
                // stored as each repeat finished (Msg::Store)
                vec![],
                &records,
            )
            .await
        {
            // The results could not be written: do not leave the job running.
            tracing::error!(job = %job.id, "storing the results failed: {e}");
            let p = problem(
                "storage",
                "Results not stored",
                &format!("writing the results failed: {e}"),
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
                    "measurement.created",
                    Some(&job.id),
                    json!({"measurement_id": id, "part_serial": job.part_serial, "source": "bench"}),
                )
                .await?;
        }
        self.events
            .publish(
                "job.state",
                Some(&job.id),
                json!({"state": state.as_str(), "problem": prob, "bench_time_s": bench_time,
                       "measurement_ids": measurement_ids, "warnings": warnings, "verdict": job_verdict}),
            )
            .await?;
        Ok(())
    }

    /// The recipe version a job names; Err (a message) when it is gone or changed.
    async fn load_recipe(
        &self,
        r: &job::RecipeRef,
    ) -> StoreResult<Result<crate::qc::Recipe, String>> {
        let Some(row) = self.store.get_recipe(&r.name, Some(r.version)).await? else {
            return Ok(Err(format!(
                "recipe {} version {} is not stored",
                r.name, r.version
            )));
        };
        Ok(
            match serde_json::from_value::<crate::qc::Recipe>(row.recipe) {
                Ok(rec) if rec.sha256() == r.sha256 => Ok(rec),
                Ok(_) => Err(format!(
                    "recipe {} version {} does not have the hash {} any more",
                    r.name, r.version, r.sha256
                )),
                Err(e) => Err(format!(
                    "recipe {} version {} unreadable: {e}",
                    r.name, r.version
                )),
            },
        )
    }

    /// Verdicts (per measurement and for the job) with traceability, and the
    /// job's MES messages: written in the result transaction.
    #[allow(clippy::too_many_arguments)]
    fn job_records(
        &self,
        bench: &BenchConfig,
        job: &Job,
        spec: Option<&JobSpec>,
        _recipe: Option<&crate::qc::Recipe>,
        started_at: &str,
        state: JobState,
        prob: Option<&Value>,
        meas: &[NewMeasurement],
        reports: &[Option<identify::Report>],
        verdicts: Vec<(String, crate::qc::Verdict)>,
    ) -> crate::store::qc::JobRecords {
        use crate::qc::{combine, invalid_job, Verdict};
        let finished_at = crate::store::now();
        let mut rec = crate::store::qc::JobRecords {
            webhooks: self.mes.webhooks.iter().map(|w| w.name.clone()).collect(),
            ..Default::default()
        };
        let rref = spec.and_then(|s| s.recipe.clone());
        let job_verdict: Option<Verdict> = match (&rref, state) {
            (None, _) => None,
            (Some(_), JobState::Succeeded) => Some(combine(
                &verdicts.iter().map(|v| v.1.clone()).collect::<Vec<_>>(),
            )),
            (Some(_), JobState::Interrupted) => Some(invalid_job(
                "interrupted",
                prob.and_then(|p| p["detail"].as_str())
                    .unwrap_or("the job was interrupted")
                    .to_string(),
            )),
            (Some(_), JobState::Failed) => {
                let kind = prob
                    .and_then(|p| p["type"].as_str())
                    .unwrap_or("")
                    .to_string();
                let detail = prob
                    .and_then(|p| p["detail"].as_str())
                    .unwrap_or("the job failed")
                    .to_string();
                Some(invalid_job(
                    if kind.ends_with("/bench") {
                        "hardware_fault"
                    } else {
                        "job_failed"
                    },
                    detail,
                ))
            }
            (Some(_), _) => None,
        };
        if let (Some(r), Some(jv)) = (&rref, &job_verdict) {
            let trace = |m: Option<&NewMeasurement>| {
                json!({
                    "software_version": crate::VERSION,
                    "recipe": {"name": r.name, "version": r.version, "sha256": r.sha256},
                    "bench_id": bench.id,
                    "bench_kind": bench.kind,
                    "bench_description": m.and_then(|m| m.config.get("bench_description").cloned()),
                    // The virtual bench has no calibration record and no sensor identities;
                    // hardware benches put theirs here.
                    "calibration": Value::Null,
                    "sensors": [],
                    "submitted_by": spec.and_then(|s| s.submitted_by.clone()),
                    "job_created_at": job.created_at,
                    "job_started_at": started_at,
                    "judged_at": finished_at,
                    "measurement_id": m.map(|m| m.id.clone()),
                })
            };
            for (mid, v) in &verdicts {
                let m = meas.iter().find(|m| &m.id == mid);
                rec.verdicts.push(crate::store::qc::NewVerdict {
                    id: new_id(),
                    job_id: Some(job.id.clone()),
                    measurement_id: Some(mid.clone()),
                    part_serial: job.part_serial.clone(),
                    recipe_name: r.name.clone(),
                    recipe_version: r.version,
                    recipe_sha256: r.sha256.clone(),
                    verdict: v.verdict.as_str(),
                    detail: verdict_json(v),
                    trace: trace(m),
                });
            }
            rec.verdicts.push(crate::store::qc::NewVerdict {
                id: new_id(),
                job_id: Some(job.id.clone()),
                measurement_id: None,
                part_serial: job.part_serial.clone(),
                recipe_name: r.name.clone(),
                recipe_version: r.version,
                recipe_sha256: r.sha256.clone(),
                verdict: jv.verdict.as_str(),
                detail: verdict_json(jv),
                trace: trace(meas.first()),
            });
        }
        // MES messages of every job that ran (WorkStarted, UnitsTested, WorkCompleted).
        let tested = meas
            .iter()
            .zip(reports.iter().map(Some).chain(std::iter::repeat(None)))
            .map(|(m, rep)| {
                let values = rep
                    .and_then(|r| r.as_ref())
                    .map(crate::qc::cfx::tested_values)
                    .unwrap_or_default();
                crate::qc::cfx::TestedMeasurement {
                    measurement_id: m.id.clone(),
                    target_xpeak_m: m.target_xpeak_m,
                    level_index: m.level_index,
                    repeat_index: m.repeat_index,
                    verdict: verdicts.iter().find(|v| v.0 == m.id).map(|v| v.1.clone()),
                    values,
                }
            })
            .collect();
        let facts = crate::qc::cfx::JobFacts {
            job_id: job.id.clone(),
            part_serial: job.part_serial.clone(),
            source: format!("{}/{}", self.mes.source, bench.id),
            started_at: started_at.to_string(),
            finished_at: finished_at.clone(),
            state: state.as_str().to_string(),
            recipe: rref
                .as_ref()
                .map(|r| (format!("{}@{}", r.name, r.version), r.sha256.clone())),
            job_verdict,
            operator: spec.and_then(|s| s.submitted_by.clone()),
            measurements: tested,
        };
        for (uid, name, body) in
            crate::qc::cfx::job_messages(&facts, [new_id(), new_id(), new_id()])
        {
            rec.messages.push(crate::store::qc::NewMessage {
                unique_id: uid,
                message_name: name,
                part_serial: job.part_serial.clone(),
                job_id: Some(job.id.clone()),
                body,
            });
        }
        rec
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
                        "job.progress",
                        Some(job_id),
                        json!({"step": step, "progress": progress, "eta_s": eta_s}),
                    )
                    .await
                {
                    tracing::warn!(job = %job_id, "progress event not stored: {e}");
                }
            }
            Msg::Samples(data) => {
                self.events
                    .publish_live("job.samples", Some(job_id), data)
                    .await
            }
            Msg::Store(batch, reply) => {
                let r = self
                    .store
                    .insert_job_measurements(job_id, batch.recordings, batch.measurements)
                    .await
                    .map_err(|e| e.to_string());
                if let Err(e) = &r {
                    tracing::error!(job = %job_id, "storing a finished repeat failed: {e}");
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

/// An RFC 9457 problem document (as stored with a job).
pub fn problem(kind: &str, title: &str, detail: &str) -> Value {
    json!({"type": format!("/problems/{kind}"), "title": title, "status": 500, "detail": detail})
}

enum Stop {
    /// Cancel or shutdown: the bench was ramped down.
    Aborted,
    Failed(Value),
}

struct Done {
    bench_time_s: f64,
    log: Vec<String>,
    warnings: Vec<String>,
    recordings: Vec<NewRecording>,
    measurements: Vec<NewMeasurement>,
    /// The result document of each measurement (index-aligned with
    /// `measurements`), typed until the repeat is stored: the series is
    /// attached to it and the MES messages read it, then it is serialized
    /// once into the measurement's `result`.
    reports: Vec<Option<identify::Report>>,
    /// Verdict of each measurement under the job's recipe (by measurement id).
    verdicts: Vec<(String, crate::qc::Verdict)>,
}

enum Msg {
    Progress {
        step: Step,
        progress: f64,
        eta_s: f64,
    },
    Samples(Value),
    /// A finished repeat's recordings and measurements, to be stored now (a
    /// cancel, a failure or a crash later keeps them; the job holds only
    /// their light results); the reply says whether they were.
    Store(Batch, std::sync::mpsc::SyncSender<Result<(), String>>),
}

/// Recordings and the measurements that index into them (`pre`, `main`).
struct Batch {
    recordings: Vec<NewRecording>,
    measurements: Vec<NewMeasurement>,
}

/// Live samples: about this many per second of signal, in chunks of `CHUNK`.
const LIVE_RATE_HZ: f64 = 1000.0;
const CHUNK: usize = 100;

struct JobObserver {
    tx: mpsc::UnboundedSender<Msg>,
    cancel: Arc<AtomicU8>,
    shutdown: Arc<AtomicBool>,
    repeats: u32,
    repeat: u32,
    /// Fraction of a repeat taken by the procedure (the rest is the fit).
    proc_share: f64,
    last: Option<(Step, f64, Instant)>,
    sample_rate_hz: f64,
    decim: usize,
    buf_x: Vec<f32>,
    buf_p: Vec<f32>,
    buf_t0: f64,
    buf_step: Step,
}

impl JobObserver {
    fn new(
        tx: mpsc::UnboundedSender<Msg>,
        cancel: Arc<AtomicU8>,
        shutdown: Arc<AtomicBool>,
        repeats: u32,
    ) -> JobObserver {
        JobObserver {
            tx,
            cancel,
            shutdown,
            repeats: repeats.max(1),
            repeat: 0,
            proc_share: 0.95,
            last: None,
            sample_rate_hz: 48000.0,
            decim: 48,
            buf_x: Vec::new(),
            buf_p: Vec::new(),
            buf_t0: 0.0,
            buf_step: Step::PreMeasurement,
        }
    }

    fn set_sample_rate(&mut self, hz: f64) {
        self.sample_rate_hz = hz;
        self.decim = ((hz / LIVE_RATE_HZ).round() as usize).max(1);
    }

    fn overall(&self, p: f64) -> f64 {
        ((self.repeat as f64 + p.clamp(0.0, 1.0)) / self.repeats as f64).clamp(0.0, 1.0)
    }

    fn send_progress(&mut self, step: Step, progress: f64, eta_s: f64) {
        let now = Instant::now();
        let due = match self.last {
            None => true,
            Some((s, p, t)) => {
                s != step || (progress - p).abs() >= 0.01 || now - t >= Duration::from_millis(250)
            }
        };
        if due {
            self.last = Some((step, progress, now));
            let _ = self.tx.send(Msg::Progress {
                step,
                progress,
                eta_s: eta_s.max(0.0),
            });
        }
    }

    /// Has a finished repeat stored (waits for the store's answer).
    fn store(&self, batch: Batch) -> Result<(), Stop> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let failed = |e: String| {
            Stop::Failed(problem(
                "storage",
                "Results not stored",
                &format!("storing the measurements of a finished repeat failed: {e}"),
            ))
        };
        self.tx
            .send(Msg::Store(batch, tx))
            .map_err(|_| failed("the job's task is gone".into()))?;
        match rx.recv() {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(failed(e)),
            Err(_) => Err(failed("no answer from the store".into())),
        }
    }

    fn flush_samples(&mut self) {
        if self.buf_x.is_empty() {
            return;
        }
        let dt = self.decim as f64 / self.sample_rate_hz;
        let data = json!({"step": step_name(self.buf_step), "t0_s": self.buf_t0, "dt_s": dt,
                          "x_m": self.buf_x, "microphone_v": self.buf_p});
        self.buf_x.clear();
        self.buf_p.clear();
        let _ = self.tx.send(Msg::Samples(data));
    }
}

impl Observer for JobObserver {
    fn progress(&mut self, step: Step, progress: f64, eta_s: f64) {
        let p = self.overall(progress * self.proc_share);
        let left_repeats = (self.repeats - self.repeat - 1) as f64;
        // eta: this repeat's remainder plus the same procedure again per repeat left
        let per_repeat = if progress > 0.05 {
            eta_s / (1.0 - progress).max(1e-3)
        } else {
            eta_s
        };
        self.send_progress(step, p, eta_s + left_repeats * per_repeat);
    }

    fn samples(&mut self, step: Step, block: crate::bench::Block<'_>) {
        if block.start_sample == 0 || step != self.buf_step {
            self.flush_samples();
            self.buf_step = step;
        }
        let n = block.displacement_m.len().min(block.microphone_v.len());
        for i in 0..n {
            let k = block.start_sample + i;
            if k % self.decim == 0 {
                if self.buf_x.is_empty() {
                    self.buf_t0 = k as f64 / self.sample_rate_hz;
                }
                self.buf_x.push(block.displacement_m[i] as f32);
                self.buf_p.push(block.microphone_v[i] as f32);
                if self.buf_x.len() >= CHUNK {
                    self.flush_samples();
                }
            }
        }
    }

    fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed) == CANCEL || self.shutdown.load(Ordering::Relaxed)
    }
}

/// Builds the bench device for one job.
fn make_bench(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    job_seq: i64,
    limits: crate::bench::Limits,
) -> Result<Box<dyn Bench>, String> {
    match cfg.kind {
        BenchKind::Virtual => virtual_bench(&cfg.id, part, seed, limits),
        BenchKind::Hardware | BenchKind::Emulated => {
            hardware::open_bench(cfg, part, seed, job_seq, limits)
        }
    }
}

fn virtual_bench(
    id: &str,
    part: PartSpec,
    seed: u64,
    limits: crate::bench::Limits,
) -> Result<Box<dyn Bench>, String> {
    part.validate()?;
    let mut b = crate::bench::virtual_bench::VirtualBench::new(part, seed).with_limits(limits);
    b.id = id.to_string();
    Ok(Box::new(b))
}

fn procedure_stop(e: ProcedureError) -> Stop {
    match e {
        ProcedureError::Cancelled | ProcedureError::Bench(crate::bench::BenchError::Aborted) => {
            Stop::Aborted
        }
        ProcedureError::Invalid(m) => Stop::Failed(problem(
            "procedure-invalid",
            "Procedure configuration refused",
            &m,
        )),
        ProcedureError::Bench(crate::bench::BenchError::Fault(m)) => Stop::Failed(problem(
            hardware::BENCH_FAULT,
            "Bench fault: the drive was ramped to zero",
            &m,
        )),
        ProcedureError::Bench(e) => Stop::Failed(problem("bench", "Bench failed", &e.to_string())),
        ProcedureError::Failed(m) => Stop::Failed(problem("procedure", "Procedure failed", &m)),
    }
}

/// Runs a job on its own blocking thread: procedure per repeat, then the fit per narrow sweep.
// Each argument is one thing the blocking thread owns or borrows for the job's duration.
#[allow(clippy::too_many_arguments)]
fn execute(
    job_id: &str,
    job_seq: i64,
    spec: &JobSpec,
    bench_cfg: &BenchConfig,
    seed: u64,
    calibration: Option<&crate::store::hardware::CalibrationRecord>,
    recipe: Option<&crate::qc::Recipe>,
    obs: &mut JobObserver,
) -> Result<Done, Stop> {
    let part = job::mounted_part(spec, bench_cfg)
        .map_err(|e| Stop::Failed(problem("part", "Part not available", &e)))?;
    let mut bench = make_bench(bench_cfg, part, seed, job_seq, spec.limits)
        .map_err(|e| Stop::Failed(problem("bench", "Bench not available", &e)))?;
    obs.set_sample_rate(bench.sample_rate_hz());
    let pcfg = ProcedureConfig {
        moving_mass_kg: spec.moving_mass_kg,
        levels_m: spec.levels_m.clone(),
        ..ProcedureConfig::default()
    };
    let opts = AnalyzeOptions {
        method: spec.method,
        order: spec.order,
    };
    let config = json!({"procedure": pcfg, "analysis": opts, "limits": spec.limits,
                        "bench": bench_cfg.id, "seed": seed, "bench_description": bench.describe()});
    let mut done = Done {
        bench_time_s: 0.0,
        log: vec![],
        warnings: vec![],
        recordings: vec![],
        measurements: vec![],
        reports: vec![],
        verdicts: vec![],
    };
    for r in 0..spec.repeats {
        obs.repeat = r;
        let runs_before = bench.run_records().len();
        let outcome = procedure::run(bench.as_mut(), &pcfg, obs).map_err(procedure_stop)?;
        if obs.cancelled() {
            return Err(Stop::Aborted);
        }
        done.bench_time_s += outcome.bench_time_s;
        if spec.repeats > 1 {
            done.log
                .extend(outcome.log.iter().map(|l| format!("repeat {}: {l}", r + 1)));
        } else {
            done.log.extend(outcome.log.iter().cloned());
        }
        let pre_index = done.recordings.len();
        let res = bench.resolution();
        done.recordings
            .push(recording("pre", &outcome.pre, res.as_ref())?);
        let n = outcome.narrow.len().max(1);
        // A level series (two or more levels) ends with the joint fit over
        // its levels (`series`): each analysed level's force-balance data.
        let want_series = outcome.narrow.len() >= 2;
        let first_measurement = done.measurements.len();
        let mut series_in: Vec<series::Level> = vec![];
        for (li, sweep) in outcome.narrow.iter().enumerate() {
            let fit_p = obs.proc_share + (1.0 - obs.proc_share) * li as f64 / n as f64;
            let p = obs.overall(fit_p);
            obs.send_progress(Step::Fit, p, 0.0);
            let mut meta = Meta::standard(spec.moving_mass_kg, outcome.pre.sample_rate_hz);
            meta.channels.drive = outcome.pre.drive_v.as_ref().map(|_| 2);
            let set = RecordingSet {
                meta,
                pre: outcome.pre.clone(),
                main: sweep.signals.clone(),
            };
            if let Some(w) = &sweep.warning {
                done.warnings.push(if spec.repeats > 1 {
                    format!("repeat {}: {w}", r + 1)
                } else {
                    w.clone()
                });
            }
            let hw_record = calibration.map(|c| {
                hardware::measurement_record(
                    c,
                    &bench.run_records()[runs_before..],
                    outcome.pre.len(),
                    sweep.signals.len(),
                    li,
                )
            });
            let not_aligned = hw_record.as_ref().and_then(hardware::alignment_invalid);
            let mut fb = None;
            let analysed = if let Some(why) = &not_aligned {
                // Never a fit of a displacement not on the audio clock.
                done.log.push(format!(
                    "level {} ({} m) not fitted: {why}",
                    li + 1,
                    sweep.target_xpeak_m
                ));
                Err(why.clone())
            } else if recipe.is_some_and(|r| r.needs_diagnostics()) {
                // Judging an effect's size needs the diagnostics' fitted effects.
                let dopts = crate::diagnose::DiagnoseOptions {
                    analyze: opts.clone(),
                    effects: vec![],
                    ..Default::default()
                };
                if want_series {
                    fb = identify::force_balance_data(&set, &opts).ok();
                }
                crate::diagnose::diagnose(&set, &dopts)
                    .map(|d| identify::Report {
                        diagnostics: None,
                        ..d.report
                    })
                    .map_err(|e| e.to_string())
            } else if want_series {
                identify::analyze_with_force_balance(&set, &opts)
                    .map(|(rep, d)| {
                        fb = Some(d);
                        rep
                    })
                    .map_err(|e| e.to_string())
            } else {
                identify::analyze(&set, &opts).map_err(|e| e.to_string())
            }
            .map(|mut rep| {
                rep.warnings.extend(sweep.warning.iter().cloned());
                // The Keff QC judges, beside the one measured at the reached Xpeak.
                crate::qc::set_keff_at_target(&mut rep, Some(sweep.target_xpeak_m));
                rep
            });
            let mid = new_id();
            if let Some(r) = recipe {
                let facts = crate::qc::RunFacts {
                    report: analysed.as_ref().ok().cloned(),
                    analysis_error: analysed.as_ref().err().cloned(),
                    target_xpeak_m: Some(sweep.target_xpeak_m),
                    level_index: li,
                    drive_v: Some(sweep.drive_v),
                    max_drive_v: Some(spec.limits.max_drive_v),
                };
                done.verdicts
                    .push((mid.clone(), crate::qc::judge(r, &facts)));
            }
            let (report, analysis_error) = match analysed {
                // Never stored with a non-finite number written as null
                // (issue 11): the result is refused, the reason kept. QC has
                // judged the report above with its own rules.
                Ok(rep) => match crate::finite::check(&rep) {
                    Ok(()) => (Some(rep), None),
                    Err(e) => {
                        let e = format!("result refused: {e}");
                        done.log.push(format!(
                            "analysis of level {} ({} m): {e}",
                            li + 1,
                            sweep.target_xpeak_m
                        ));
                        (None, Some(e))
                    }
                },
                Err(e) if not_aligned.is_some() => (None, Some(e)),
                Err(e) => {
                    done.log.push(format!(
                        "analysis of level {} ({} m) failed: {e}",
                        li + 1,
                        sweep.target_xpeak_m
                    ));
                    (None, Some(e))
                }
            };
            if let (Some(data), Some(_)) = (fb, &report) {
                series_in.push(series::Level {
                    measurement: done.measurements.len(),
                    measurement_id: mid.clone(),
                    target_xpeak_m: sweep.target_xpeak_m,
                    data,
                });
            }
            let main_index = done.recordings.len();
            done.recordings
                .push(recording("main", &sweep.signals, res.as_ref())?);
            let mut cfg_m = config.clone();
            cfg_m["narrow_sweep"] = json!({"drive_v": sweep.drive_v, "f_start_hz": sweep.f_start_hz,
                                           "f_end_hz": sweep.f_end_hz});
            if let Some(h) = hw_record {
                cfg_m["hardware"] = h;
            }
            done.measurements.push(NewMeasurement {
                id: mid,
                part_serial: spec.part.serial.clone(),
                job_id: Some(job_id.to_string()),
                source: "bench",
                bench_id: Some(bench_cfg.id.clone()),
                config: cfg_m,
                meta: serde_json::to_value(&set.meta).unwrap_or(Value::Null),
                // serialized once the repeat is complete (below)
                result: None,
                analysis_error,
                target_xpeak_m: Some(sweep.target_xpeak_m),
                repeat_index: Some(r as i64),
                level_index: Some(li as i64),
                pre: pre_index,
                main: main_index,
            });
            done.reports.push(report);
        }
        if want_series {
            obs.send_progress(Step::Fit, obs.overall(0.99), 0.0);
            let log = series::attach(
                &mut done.reports[first_measurement..],
                first_measurement,
                series_in,
                spec.order,
            );
            done.log.extend(log.into_iter().map(|l| {
                if spec.repeats > 1 {
                    format!("repeat {}: {l}", r + 1)
                } else {
                    l
                }
            }));
        }
        obs.flush_samples();
        // The repeat's recordings and measurements go to the store now: a
        // series of 16 levels x 10 repeats no longer holds every recording
        // until the end, and what is measured is kept.
        for (m, rep) in done.measurements[first_measurement..]
            .iter_mut()
            .zip(&done.reports[first_measurement..])
        {
            // checked finite above (and the series before it was attached)
            m.result = rep.as_ref().and_then(|r| serde_json::to_value(r).ok());
        }
        let batch = Batch {
            recordings: std::mem::take(&mut done.recordings),
            measurements: done.measurements[first_measurement..].to_vec(),
        };
        obs.store(batch)?;
    }
    Ok(done)
}

/// A recording as the store keeps it: at the bench's resolution (FLAC, bit
/// for bit what was captured), or float32 WAV when the bench declares none.
fn recording(
    kind: &'static str,
    s: &crate::recording::Signals,
    res: Option<&crate::recording::codec::Resolution>,
) -> Result<NewRecording, Stop> {
    let stored = crate::recording::codec::encode_capture(s, res).map_err(|e| {
        Stop::Failed(problem(
            "recording",
            "Recording could not be stored losslessly",
            &e.to_string(),
        ))
    })?;
    Ok(NewRecording {
        kind,
        sample_rate_hz: s.sample_rate_hz,
        frames: s.len() as i64,
        stored,
    })
}

/// A fresh id (UUID v4, text).
pub fn new_id() -> String {
    uuid::Uuid::new_v4().to_string()
}

impl Runner {
    async fn finish_failed(&self, slot: &Slot, job: &Job, p: Value) -> StoreResult<()> {
        self.finish_failed_after(slot, job, &p, None, &[], &[])
            .await
    }

    /// Ends a running job `failed` with problem `p`, keeping what the bench
    /// did before (its time, log and warnings), with its verdict (`invalid`
    /// under a recipe) and its MES messages, and announces it. The one way
    /// every runner path fails a job. While the store cannot write (full
    /// disk), tried again until it can (or the daemon stops: the restart
    /// then ends the job `interrupted`).
    async fn finish_failed_after(
        &self,
        slot: &Slot,
        job: &Job,
        p: &Value,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
    ) -> StoreResult<()> {
        let ended = self
            .end_running_until_stored(
                &slot.cfg,
                job,
                JobState::Failed,
                p,
                bench_time_s,
                log,
                warnings,
            )
            .await?;
        if ended {
            let _ = self
                .events
                .publish(
                    "job.state",
                    Some(&job.id),
                    json!({"state": "failed", "problem": p}),
                )
                .await
                .map_err(|e| tracing::warn!(job = %job.id, "job.state event not stored: {e}"));
        }
        Ok(())
    }

    /// [`Store::end_running_job`] with the job's records, tried again every
    /// few seconds while the store cannot write. False when the job was not
    /// running (never started, or ended before).
    #[allow(clippy::too_many_arguments)]
    async fn end_running_until_stored(
        &self,
        bench: &BenchConfig,
        job: &Job,
        state: JobState,
        p: &Value,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
    ) -> StoreResult<bool> {
        let spec: Option<JobSpec> = serde_json::from_value(job.request.clone()).ok();
        let mut wait = Duration::from_millis(250);
        loop {
            let started_at = job.started_at.clone().unwrap_or_else(crate::store::now);
            let records = self.job_records(
                bench,
                job,
                spec.as_ref(),
                None,
                &started_at,
                state,
                Some(p),
                &[],
                &[],
                vec![],
            );
            match self
                .store
                .end_running_job(
                    &job.id,
                    state,
                    Some(p),
                    bench_time_s,
                    log,
                    warnings,
                    &records,
                )
                .await
            {
                Ok(ended) => {
                    if ended && !records.messages.is_empty() && !records.webhooks.is_empty() {
                        self.outbox.notify_one();
                    }
                    return Ok(ended);
                }
                Err(e) if self.shutdown.load(Ordering::SeqCst) => return Err(e),
                Err(e) => {
                    tracing::error!(job = %job.id, "ending the job {} failed, trying again: {e}", state.as_str());
                    tokio::time::sleep(wait).await;
                    wait = (wait * 2).min(Duration::from_secs(2));
                }
            }
        }
    }

    /// At start: every job still `running` was cut off by a crash or a kill.
    /// Each ends `interrupted` (never re-run silently) with its verdict
    /// (`invalid`, reason `interrupted`, under a recipe) and its MES messages.
    async fn end_interrupted(&self, cfg: &Config) -> StoreResult<()> {
        let p = Store::interrupted_problem();
        for job in self.store.running_jobs().await? {
            let bench = cfg
                .benches
                .iter()
                .find(|b| b.id == job.bench_id)
                .cloned()
                .or_else(|| serde_json::from_value(json!({"id": job.bench_id})).ok());
            let Some(bench) = bench else { continue };
            let spec: Option<JobSpec> = serde_json::from_value(job.request.clone()).ok();
            let started_at = job.started_at.clone().unwrap_or_else(crate::store::now);
            let state = JobState::Interrupted;
            let records = self.job_records(
                &bench,
                &job,
                spec.as_ref(),
                None,
                &started_at,
                state,
                Some(&p),
                &[],
                &[],
                vec![],
            );
            if !self
                .store
                .end_running_job(&job.id, state, Some(&p), None, &[], &[], &records)
                .await?
            {
                continue;
            }
            if !records.messages.is_empty() && !records.webhooks.is_empty() {
                self.outbox.notify_one();
            }
            let verdict = records
                .verdicts
                .iter()
                .find(|v| v.measurement_id.is_none())
                .map(|v| v.verdict);
            self.events
                .publish(
                    "job.state",
                    Some(&job.id),
                    json!({"state": "interrupted", "problem": p, "verdict": verdict}),
                )
                .await?;
            tracing::warn!(job = %job.id, "job was running when the daemon stopped: marked interrupted");
        }
        Ok(())
    }
}

/// A verdict as stored: through the store's finite check (issue 11; `judge`
/// already turns a non-finite verdict into an invalid one, this is the last
/// guard before the database).
fn verdict_json(v: &crate::qc::Verdict) -> Value {
    let v = crate::qc::finite_verdict(v.clone());
    crate::finite::to_value(&v).unwrap_or(Value::Null)
}
