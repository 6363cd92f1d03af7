//! The long-term test as a job (issue 32): on one bench, the full procedure
//! at intervals while a sine held at the part's current resonance ages the
//! part in between (the other benches keep working). Each interval is an
//! ordinary stored measurement linked to the test with its elapsed time and
//! the load taken; the test's state (intervals done, test clock, the part's
//! load) and the ageing law fitted so far (`ageing::series::analyse`, the
//! core code `springbench ageing` runs) are written in the same transaction
//! ([`crate::store::Store::insert_long_term_interval`]). A daemon killed
//! during the test finds the job `running` at its next start, puts it back
//! in the queue ([`requeue`]) and resumes after the last stored interval:
//! none lost or run twice, the load carried on.
//!
//! Virtual benches only: the stimulus between two measurements is applied
//! analytically (`physics::ageing::apply_sine`), faster than real time
//! unless the test asks for `accelerated: false` (then it is paced).
//! A failure limit (a change of K(0) beyond its bound, no resonance found)
//! stops the test, names the limit and stores the last 10 s of the signals.

use super::{new_id, JobEvent, Runner, Slot, Stop, CANCEL, COMMIT};
use crate::ageing as ageing_law;
use crate::ageing::series::{self, AgeingDocument};
use crate::bench::virtual_bench::VirtualBench;
use crate::bench::Bench;
use crate::config::{BenchConfig, BenchKind};
use crate::identify::{self, AnalyzeOptions, Report};
use crate::job::{
    Failure, HardwareRecord, Hold, JobProblem, LongTermSpec, MeasurementConfig, PartState,
    PreSweepSettings, ProblemKind, StimulusKind, SweepSettings,
};
use crate::physics::{ageing, waveform};
use crate::procedure::{self, Observer, ProcedureConfig, ProcedureError};
use crate::recording::{Meta, Signals};
use crate::store::hardware::CalibrationRecord;
use crate::store::longterm::{LongTermEventKind, NewInterval, PauseCause};
use crate::store::{Job, JobState, NewRecording, Store, StoreResult};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// Seconds of signals stored when a failure limit stops the test.
pub const LAST_SIGNALS_S: f64 = 10.0;
/// Test time of stimulus applied per step (s): the cancel is polled between steps.
const STIMULUS_STEP_S: f64 = 60.0;

enum Msg {
    /// A line for the job's log (the stimulus on a hardware or emulated bench).
    Log(String),
    Progress {
        progress: f64,
        eta_s: f64,
    },
    /// Paused (with the reason) or resumed (with why), at a test time (s).
    Paused {
        cause: PauseCause,
        paused: bool,
        detail: String,
        elapsed_s: f64,
        /// Stored as an event (false: the job's step only, for a pause
        /// stored before a stop of the daemon).
        record: bool,
    },
    Interval(
        Box<NewInterval>,
        std::sync::mpsc::SyncSender<Result<(), String>>,
    ),
    Failure(
        Box<Failure>,
        Option<(NewRecording, f64)>,
        std::sync::mpsc::SyncSender<Result<(), String>>,
    ),
    /// The last signals of a test a bench fault stopped.
    LastSignals(
        (NewRecording, f64),
        std::sync::mpsc::SyncSender<Result<(), String>>,
    ),
}

/// At the daemon's start: long-term tests still `running` (a crash, a kill,
/// a stop) go back to the queue and resume from their stored state.
pub(super) async fn requeue(store: &Store) -> StoreResult<Vec<String>> {
    let mut ids = vec![];
    for job in store.running_jobs().await? {
        if matches!(
            job.request.read(),
            Ok(crate::job::StoredRequest::LongTerm(_))
        ) && store.requeue_running(&job.id).await?
        {
            tracing::warn!(job = %job.id, "long-term test was running when the daemon stopped: resumes");
            ids.push(job.id);
        }
    }
    Ok(ids)
}

/// The user's pause as a running test sees it (decision 0130).
#[derive(Debug, Default)]
pub(super) struct PauseFlag {
    paused: bool,
    /// Who paused it, or who resumed it last (a token's name).
    by: Option<String>,
    /// The pause in effect is stored as an event already (before a restart
    /// of the daemon): not recorded twice.
    recorded: bool,
}

pub(super) type SharedPause = Arc<Mutex<PauseFlag>>;

/// Answer to a user's pause or resume of a long-term test.
pub enum PauseOutcome {
    /// Asked: the test pauses at its next step (or resumes).
    Done(Job),
    /// It was paused already (pause), or not paused (resume).
    Unchanged(Job),
    /// It has finished.
    Finished(Job),
    NotFound,
}

fn who(by: &Option<String>) -> String {
    match by {
        Some(b) if !b.is_empty() => format!("by {b}"),
        _ => "by the user".into(),
    }
}

struct Resume {
    index: usize,
    clock_s: f64,
    load_j: f64,
    /// The emulated part's true load then (J, decision 0135).
    true_load_j: Option<f64>,
    /// The finished intervals' (elapsed_s, load_j, result).
    done: Vec<series::Interval>,
    first_k0: Option<f64>,
}

/// Takes a running test's pause flag out of the runner's map when the test ends.
struct Unregister<'a>(
    &'a Mutex<std::collections::HashMap<String, SharedPause>>,
    String,
);

impl Drop for Unregister<'_> {
    fn drop(&mut self) {
        self.0.lock().unwrap().remove(&self.1);
    }
}

impl Runner {
    /// The user pauses (`pause`) or resumes long-term test `id` (`by`: the
    /// token's name). Stored with the test, so that it outlives a stop of
    /// the daemon; a running test stops its stimulus at its next step
    /// (decision 0130). A queued test starts paused.
    pub async fn pause_long_term(
        &self,
        id: &str,
        by: Option<String>,
        pause: bool,
    ) -> StoreResult<PauseOutcome> {
        let Some(job) = self.store.get_job(id).await? else {
            return Ok(PauseOutcome::NotFound);
        };
        if !matches!(
            job.request.read(),
            Ok(crate::job::StoredRequest::LongTerm(_))
        ) {
            return Ok(PauseOutcome::NotFound);
        }
        if job.state.is_terminal() {
            return Ok(PauseOutcome::Finished(job));
        }
        let changed = self
            .store
            .set_long_term_pause(id, pause.then_some(by.as_deref()))
            .await?;
        if !changed {
            return Ok(PauseOutcome::Unchanged(job));
        }
        if let Some(flag) = self.pauses.lock().unwrap().get(id) {
            let mut f = flag.lock().unwrap();
            f.paused = pause;
            f.by = by;
            if pause {
                f.recorded = false;
            }
        }
        tracing::info!(job = %id, "long-term test {} by the user", if pause { "paused" } else { "resumed" });
        Ok(PauseOutcome::Done(job))
    }

    /// Runs (or resumes) long-term test `job` on `slot`'s bench.
    pub(super) async fn run_long_term(
        &self,
        slot: &Slot,
        job: &Job,
        spec: LongTermSpec,
        cancel: Arc<AtomicU8>,
    ) -> StoreResult<()> {
        // A hardware or emulated bench: a faulted bench refuses, the
        // intervals' measurements need the calibration record in effect.
        let calibration = match self.hardware_preflight(slot, job, &spec).await? {
            Ok(c) => c,
            Err(p) => return self.finish_failed(slot, job, p).await,
        };
        if slot.cfg.kind != BenchKind::Virtual && calibration.is_none() {
            let p = JobProblem::new(
                ProblemKind::Bench,
                "Bench not available",
                format!("bench '{}' has no calibration record", slot.cfg.id),
            );
            return self.finish_failed(slot, job, p).await;
        }
        // Listed among the station's tests (the API lists it at submit; again is no change).
        self.store.add_long_term_test(&job.id).await?;
        // The user's pause: registered before it is read, so that a pause
        // asked in between reaches the test either way. A test paused
        // before a stop of the daemon stays paused.
        let pause: SharedPause = Arc::default();
        self.pauses
            .lock()
            .unwrap()
            .insert(job.id.clone(), pause.clone());
        let _unregister = Unregister(&self.pauses, job.id.clone());
        if let Some(p) = self.store.long_term_pause(&job.id).await? {
            let recorded = self
                .store
                .long_term_events(&job.id)
                .await?
                .iter()
                .rev()
                .find(|e| e.cause == PauseCause::User)
                .is_some_and(|e| e.kind == LongTermEventKind::Paused);
            let mut f = pause.lock().unwrap();
            if !f.paused && f.by.is_none() {
                *f = PauseFlag {
                    paused: true,
                    by: p.by,
                    recorded,
                };
            }
        }
        let (resume, resumptions) = self.resume_point(&job.id).await?;
        let resumed_at = resume.index;
        // One line per resumption so far (the job's log is written at its end).
        let mut log: Vec<String> = resumptions
            .iter()
            .map(|r| {
                format!(
                    "resumed after interval {} at {} (load {:.1} J): the daemon had stopped",
                    r.intervals_done as i64 - 1,
                    r.at,
                    r.load_j
                )
            })
            .collect();
        if resumed_at > 0 {
            self.events
                .publish(
                    Some(&job.id),
                    &JobEvent::LongTermResumed {
                        intervals_done: resumed_at,
                        load_j: resume.load_j,
                    },
                )
                .await?;
        }
        // A WAV stimulus' file, read from the store once for the test.
        let wav = match self.wav_loop(&spec).await? {
            Ok(w) => w,
            Err(p) => return self.finish_failed(slot, job, p).await,
        };
        let (tx, mut rx) = mpsc::unbounded_channel();
        let bench_cfg = slot.cfg.clone();
        let shutdown = self.shutdown.clone();
        let flag = cancel.clone();
        let spec2 = spec.clone();
        let job_id = job.id.clone();
        let space = (self.store.clone(), self.min_free_bytes);
        let job_seq = job.seq;
        let user_pause = pause.clone();
        let mut handle = tokio::task::spawn_blocking(move || {
            let room = Room {
                store: &space.0,
                min_free_bytes: space.1,
                pause: &user_pause,
                tx: &tx,
            };
            let on = On {
                job_id: &job_id,
                job_seq,
                bench_cfg: &bench_cfg,
                calibration: calibration.as_ref(),
                wav: wav.as_ref(),
            };
            run_blocking(on, &spec2, resume, &tx, &flag, &shutdown, &room)
        });
        let res = loop {
            tokio::select! {
                msg = rx.recv() => match msg {
                    Some(Msg::Log(l)) => log.push(l),
                    Some(m) => self.on_long_term(&job.id, m).await,
                    None => break (&mut handle).await,
                },
                r = &mut handle => break r,
            }
        };
        while let Ok(m) = rx.try_recv() {
            match m {
                Msg::Log(l) => log.push(l),
                m => self.on_long_term(&job.id, m).await,
            }
        }
        let outcome = match res {
            Ok(r) => r,
            Err(e) => Err(Stop::Failed(JobProblem::new(
                ProblemKind::Internal,
                "Job crashed",
                format!("the long-term test's task ended abnormally: {e}"),
            ))),
        };
        let cancelled_late = cancel.swap(COMMIT, Ordering::SeqCst) == CANCEL;
        // The pauses and their ends, in the job's log (decision 0125).
        for e in self.store.long_term_events(&job.id).await? {
            log.push(match e.kind {
                LongTermEventKind::Paused => {
                    format!("paused at test time {:.0} s: {}", e.elapsed_s, e.detail)
                }
                LongTermEventKind::Resumed => {
                    format!("resumed at test time {:.0} s: {}", e.elapsed_s, e.detail)
                }
            });
        }
        let (state, problem) = match outcome {
            Ok(n) if !cancelled_late => {
                log.push(format!("{n} intervals measured"));
                (JobState::Succeeded, None)
            }
            Ok(_) => (JobState::Cancelled, None),
            Err(Stop::Aborted) if self.shutdown.load(Ordering::SeqCst) => {
                // Left running: the next start resumes it after its last stored interval.
                tracing::info!(job = %job.id, "daemon stopping: the long-term test resumes at the next start");
                self.settle(slot);
                return Ok(());
            }
            Err(Stop::Aborted) => (JobState::Cancelled, None),
            Err(Stop::Failed(p)) => (JobState::Failed, Some(p)),
        };
        // A fault of a hardware bench (a limit, the laser unplugged, a
        // stream error): the drive was ramped down, the bench is faulted
        // until a self-check passes, and the test stops with the reason;
        // its finished intervals are stored.
        if let Some(p) = problem
            .as_ref()
            .filter(|p| p.kind == ProblemKind::BenchFault)
        {
            log.push(format!("stopped by a bench fault: {}", p.detail));
            self.fault_bench(slot, &job.id, p).await?;
        }
        let commit = self.store.finish_job(
            &job.id,
            state,
            problem.as_ref(),
            None,
            &log,
            &[],
            vec![],
            vec![],
        );
        self.commit_settled(slot, &job.id, commit).await?;
        let measurement_ids = self
            .store
            .get_job(&job.id)
            .await?
            .map(|j| j.measurement_ids)
            .unwrap_or_default();
        self.events
            .publish(
                Some(&job.id),
                &JobEvent::LongTermEnded {
                    state,
                    problem,
                    measurement_ids,
                },
            )
            .await?;
        Ok(())
    }

    /// A WAV stimulus' loop (its sample rate and samples at unit RMS, read
    /// from the stored file; decision 0144); None for other kinds; Err: the
    /// file is gone or unusable (the test fails naming it).
    async fn wav_loop(
        &self,
        spec: &LongTermSpec,
    ) -> StoreResult<Result<Option<(u32, Vec<f64>)>, JobProblem>> {
        if spec.stimulus.kind != StimulusKind::Wav {
            return Ok(Ok(None));
        }
        let id = spec.stimulus.wav_id.as_deref().unwrap_or_default();
        let problem = |m: String| {
            JobProblem::new(
                ProblemKind::Bench,
                "Stimulus not made",
                format!("stimulus.wav_id: {m}"),
            )
        };
        let Some(bytes) = self.store.stimulus_bytes(id).await? else {
            return Ok(Err(problem(format!("no stimulus '{id}' on this station"))));
        };
        Ok(crate::recording::stimulus::decode(&bytes)
            .and_then(|d| {
                Ok((
                    d.sample_rate_hz,
                    crate::recording::stimulus::drive_loop(&d.samples)?,
                ))
            })
            .map(Some)
            .map_err(problem))
    }

    async fn resume_point(
        &self,
        job_id: &str,
    ) -> StoreResult<(Resume, Vec<crate::store::longterm::Resumption>)> {
        let Some(st) = self.store.long_term_state(job_id).await? else {
            let start = Resume {
                index: 0,
                clock_s: 0.0,
                load_j: 0.0,
                true_load_j: None,
                done: vec![],
                first_k0: None,
            };
            return Ok((start, vec![]));
        };
        let mut done = vec![];
        let mut first_k0 = None;
        for iv in self.store.long_term_intervals(job_id).await? {
            let report = match self.store.measurement_report(&iv.measurement_id).await {
                Ok(r) => r,
                // As before the store read it into its type: an interval
                // whose report does not read is left out of the fit.
                Err(crate::store::StoreError::Corrupt(_)) => None,
                Err(e) => return Err(e),
            };
            if let Some(report) = report {
                if iv.index == 0 {
                    first_k0 = k0_of(&report);
                }
                done.push(series::Interval {
                    elapsed_s: iv.elapsed_s,
                    load_j: Some(iv.load_j),
                    report,
                });
            }
        }
        let resume = Resume {
            index: st.intervals_done,
            clock_s: st.clock_s,
            load_j: st.load_j,
            true_load_j: st.part.true_load_j,
            done,
            first_k0,
        };
        Ok((resume, st.resumptions))
    }

    async fn on_long_term(&self, job_id: &str, m: Msg) {
        match m {
            Msg::Progress { progress, eta_s } => {
                if let Err(e) = self
                    .store
                    .set_progress(job_id, "long_term", progress, eta_s)
                    .await
                {
                    tracing::warn!(job = %job_id, "progress not stored: {e}");
                }
                let _ = self
                    .events
                    .publish(
                        Some(job_id),
                        &JobEvent::Progress {
                            step: "long_term",
                            progress,
                            eta_s,
                        },
                    )
                    .await;
            }
            Msg::Paused {
                cause,
                paused,
                detail,
                elapsed_s,
                record,
            } => {
                // The pause and its end stay with the test (its page, its log).
                let kind = if paused {
                    LongTermEventKind::Paused
                } else {
                    LongTermEventKind::Resumed
                };
                let stored = match record {
                    true => {
                        self.store
                            .add_long_term_event(job_id, kind, cause, elapsed_s, &detail)
                            .await
                    }
                    false => Ok(()),
                };
                if let Err(e) = stored {
                    tracing::warn!(job = %job_id, "pause event not stored: {e}");
                }
                let step = if paused {
                    format!("paused: {detail}")
                } else {
                    "long_term".to_string()
                };
                if paused {
                    tracing::warn!(job = %job_id, "long-term test paused: {detail}");
                } else {
                    tracing::info!(job = %job_id, "long-term test resumed: {detail}");
                }
                let stored = match self.store.get_job(job_id).await {
                    Ok(Some(j)) => {
                        self.store
                            .set_progress(job_id, &step, j.progress, j.eta_s.unwrap_or(0.0))
                            .await
                    }
                    Ok(None) => Ok(()),
                    Err(e) => Err(e),
                };
                if let Err(e) = stored {
                    tracing::warn!(job = %job_id, "pause not stored: {e}");
                }
            }
            Msg::Interval(iv, reply) => {
                let (index, mid) = (iv.index, iv.measurement.id.clone());
                let (elapsed_s, load_j) = (iv.elapsed_s, iv.load_j);
                let r = self
                    .store
                    .insert_long_term_interval(job_id, *iv)
                    .await
                    .map_err(|e| e.to_string());
                if r.is_ok() {
                    let _ = self
                        .events
                        .publish(
                            Some(job_id),
                            &JobEvent::LongTermInterval {
                                index,
                                measurement_id: mid,
                                elapsed_s,
                                load_j,
                            },
                        )
                        .await;
                }
                let _ = reply.send(r);
            }
            Msg::Log(_) => {}
            Msg::Failure(f, signals, reply) => {
                let r = self
                    .store
                    .set_long_term_failure(job_id, &f, signals)
                    .await
                    .map_err(|e| e.to_string());
                let _ = reply.send(r);
            }
            Msg::LastSignals(signals, reply) => {
                let r = self
                    .store
                    .set_long_term_last_signals(job_id, signals)
                    .await
                    .map_err(|e| e.to_string());
                let _ = reply.send(r);
            }
        }
    }
}

/// A report's K(x): coefficients (N/m^(i+1)) and valid range (m).
fn k_of(r: &Report) -> (Vec<f64>, [f64; 2]) {
    (
        r.stiffness.coefficients_n_per_m_pow_i_plus_1.clone(),
        r.stiffness.valid_range_m,
    )
}

fn k0_of(r: &Report) -> Option<f64> {
    r.small_signal.as_ref().and_then(|s| s.k0_n_per_m)
}

struct LtObserver<'a> {
    cancel: &'a AtomicU8,
    shutdown: &'a AtomicBool,
}

impl Observer for LtObserver<'_> {
    fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed) == CANCEL || self.shutdown.load(Ordering::Relaxed)
    }
}

fn send_and_wait(
    tx: &mpsc::UnboundedSender<Msg>,
    make: impl FnOnce(std::sync::mpsc::SyncSender<Result<(), String>>) -> Msg,
) -> Result<(), Stop> {
    let (rtx, rrx) = std::sync::mpsc::sync_channel(1);
    let failed = |e: String| {
        Stop::Failed(JobProblem::new(
            ProblemKind::Storage,
            "Results not stored",
            format!("storing a finished interval failed: {e}"),
        ))
    };
    tx.send(make(rtx))
        .map_err(|_| failed("the job's task is gone".into()))?;
    match rrx.recv() {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(failed(e)),
        Err(_) => Err(failed("no answer from the store".into())),
    }
}

/// The last `seconds` of `s`.
fn tail(s: &Signals, seconds: f64) -> Signals {
    let n = ((seconds * s.sample_rate_hz).round() as usize).min(s.len());
    let a = s.len() - n;
    Signals {
        sample_rate_hz: s.sample_rate_hz,
        displacement_m: s.displacement_m[a..].to_vec(),
        microphone_v: s.microphone_v[a..].to_vec(),
        drive_v: s.drive_v.as_ref().map(|d| d[a.min(d.len())..].to_vec()),
    }
}

fn failure_problem(f: &Failure) -> Stop {
    Stop::Failed(JobProblem::new(
        ProblemKind::FailureLimit,
        "Long-term test stopped by a failure limit",
        format!(
            "failure limit `{}` at interval {}: {}",
            f.limit, f.interval, f.detail
        ),
    ))
}

/// Where the test's results go, and the free space they need.
struct Room<'a> {
    store: &'a Store,
    min_free_bytes: u64,
    /// The user's pause (decision 0130).
    pause: &'a SharedPause,
    /// The test's messages to its job.
    tx: &'a mpsc::UnboundedSender<Msg>,
}

impl Room<'_> {
    /// Waits while the disk is below `min_free_bytes`: the test pauses with
    /// the reason (the job's `step`) and resumes when space returns.
    fn wait_for_space(
        &self,
        tx: &mpsc::UnboundedSender<Msg>,
        obs: &LtObserver<'_>,
        elapsed_s: f64,
    ) -> Result<(), Stop> {
        let mut paused = false;
        while let Err(e) = self.store.check_space(self.min_free_bytes) {
            if !paused {
                let _ = tx.send(Msg::Paused {
                    cause: PauseCause::Disk,
                    paused: true,
                    detail: e.to_string(),
                    elapsed_s,
                    record: true,
                });
                paused = true;
            }
            if obs.cancelled() {
                return Err(Stop::Aborted);
            }
            std::thread::sleep(Duration::from_millis(500));
        }
        if paused {
            let _ = tx.send(Msg::Paused {
                cause: PauseCause::Disk,
                paused: false,
                detail: "space returned".into(),
                elapsed_s,
                record: true,
            });
        }
        Ok(())
    }

    /// Holds the test while the user's pause is in effect (decision 0130):
    /// nothing is played, the test clock and the load stand still. The
    /// pause and its end are events at test time `elapsed_s`; a cancel
    /// (or the daemon stopping) ends the wait.
    fn hold_while_paused(
        &self,
        tx: &mpsc::UnboundedSender<Msg>,
        obs: &LtObserver<'_>,
        elapsed_s: f64,
    ) -> Result<(), Stop> {
        {
            let mut f = self.pause.lock().unwrap();
            if !f.paused {
                return Ok(());
            }
            // The job's step says it; the event is stored once (not again
            // for a pause stored before a stop of the daemon).
            let _ = tx.send(Msg::Paused {
                cause: PauseCause::User,
                paused: true,
                detail: format!("paused {}", who(&f.by)),
                elapsed_s,
                record: !f.recorded,
            });
            f.recorded = true;
        }
        loop {
            if obs.cancelled() {
                return Err(Stop::Aborted);
            }
            let by = {
                let f = self.pause.lock().unwrap();
                (!f.paused).then(|| f.by.clone())
            };
            if let Some(by) = by {
                let _ = tx.send(Msg::Paused {
                    cause: PauseCause::User,
                    paused: false,
                    detail: format!("resumed {}", who(&by)),
                    elapsed_s,
                    record: true,
                });
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The user's pause is in effect.
    fn paused(&self) -> bool {
        self.pause.lock().unwrap().paused
    }
}

/// The job and the bench a test runs on.
struct On<'a> {
    job_id: &'a str,
    job_seq: i64,
    bench_cfg: &'a BenchConfig,
    /// The calibration record in effect (hardware and emulated benches).
    calibration: Option<&'a CalibrationRecord>,
    /// A WAV stimulus' file (decision 0144): its sample rate and unit-RMS loop.
    wav: Option<&'a (u32, Vec<f64>)>,
}

/// A hardware or emulated bench, opened once for the test (a virtual bench
/// is made anew for each interval from the stored load instead).
struct Device<'a> {
    bench: Box<dyn Bench>,
    calibration: &'a CalibrationRecord,
    /// The bench runs in real time (real devices, a paced emulator): the
    /// stimulus' idle time is waited for, not skipped.
    paced: bool,
    /// The part's last measured K(x) (coefficients, valid range): the
    /// load is measured with it.
    k: Option<(Vec<f64>, [f64; 2])>,
    /// An emulated bench: the load its part has truly taken, which the
    /// emulator ages it with (decision 0135); None on a real bench.
    true_load: Option<crate::bench::true_part::TrueLoad>,
    /// A WAV stimulus' file: its sample rate and unit-RMS loop (decision 0144).
    wav: Option<&'a (u32, Vec<f64>)>,
}

/// The test on the job's blocking thread; Ok(intervals measured in all).
fn run_blocking(
    on: On<'_>,
    spec: &LongTermSpec,
    resume: Resume,
    tx: &mpsc::UnboundedSender<Msg>,
    cancel: &AtomicU8,
    shutdown: &AtomicBool,
    room: &Room<'_>,
) -> Result<usize, Stop> {
    let (job_id, bench_cfg, wav) = (on.job_id, on.bench_cfg, on.wav);
    let m = &spec.measurement;
    let part = super::job::mounted_part(m, bench_cfg)
        .map_err(|e| Stop::Failed(JobProblem::new(ProblemKind::Part, "Part not available", &e)))?;
    part.validate()
        .map_err(|e| Stop::Failed(JobProblem::new(ProblemKind::Part, "Part not available", &e)))?;
    let mut device = match (bench_cfg.kind, on.calibration) {
        (BenchKind::Virtual, _) => None,
        (_, None) => {
            return Err(Stop::Failed(JobProblem::new(
                ProblemKind::Bench,
                "Bench not available",
                "no calibration record",
            )))
        }
        (kind, Some(calibration)) => {
            let seed = bench_cfg.seed.wrapping_add(on.job_seq as u64);
            // The emulated part ages from the true load stored with the
            // test's state (0: a new part); a real part ages by itself.
            let true_load = (kind == BenchKind::Emulated)
                .then(|| crate::bench::true_part::TrueLoad::new(resume.true_load_j.unwrap_or(0.0)));
            let bench = super::hardware::open_bench(
                bench_cfg,
                part.clone(),
                seed,
                on.job_seq,
                m.limits,
                true_load.clone(),
            )
            .map_err(|e| {
                Stop::Failed(JobProblem::new(
                    ProblemKind::Bench,
                    "Bench not available",
                    &e,
                ))
            })?;
            let paced =
                kind == BenchKind::Hardware || bench_cfg.emulator.as_ref().is_some_and(|e| e.paced);
            // The last measured K(x) of a resumed test.
            let k = resume.done.last().map(|iv| k_of(&iv.report));
            Some(Device {
                bench,
                calibration,
                paced,
                k,
                true_load,
                wav,
            })
        }
    };
    let vcfg = bench_cfg.virtual_.unwrap_or_default();
    let n = spec.intervals();
    let pcfg = ProcedureConfig {
        moving_mass_kg: m.moving_mass_kg,
        levels_m: m.levels_m.clone(),
        ..ProcedureConfig::default()
    };
    let opts = AnalyzeOptions {
        method: m.method,
        order: m.order,
    };
    let mut obs = LtObserver { cancel, shutdown };
    let Resume {
        index: start,
        mut clock_s,
        mut load_j,
        true_load_j: _,
        mut done,
        mut first_k0,
    } = resume;
    let started = Instant::now();
    let progress = |i: usize, elapsed_test_s: f64, per_interval_wall_s: Option<f64>| {
        let p = (elapsed_test_s / spec.duration_s).clamp(0.0, 1.0);
        let left_test_s = (spec.duration_s - elapsed_test_s).max(0.0);
        // Accelerated: what the intervals left take at this pace; else the test time left.
        let eta_s = match per_interval_wall_s {
            Some(w) if spec.accelerated => w * (n - i) as f64,
            _ => left_test_s,
        };
        let _ = tx.send(Msg::Progress { progress: p, eta_s });
    };
    // A stimulus held at a drive level keeps the velocity amplitude at the
    // resonance that its level's excursion had on the new part (each level
    // step its own drive level, decision 0132).
    let held_velocity = |x: f64| {
        (spec.stimulus.hold == Hold::Drive).then(|| {
            let mut new_part = part.clone();
            new_part.moving_mass_kg += vcfg.clamp_mass_kg;
            ageing::velocity_at_excursion_m_per_s(&new_part, 0.0, x)
        })
    };
    // A noise's loop and its load's rate, kept over the intervals.
    let mut noise: Option<waveform::LoopLoad> = None;
    // Whether the drive limit holds the stimulus below its level (said when it changes).
    let mut held_short = false;
    for index in start..n {
        if obs.cancelled() {
            return Err(Stop::Aborted);
        }
        let seed = bench_cfg.seed.wrapping_add(index as u64);
        // The bench is made anew for each interval from the part's state: a
        // resumed test carries on from the stored load alone.
        let mut vb = VirtualBench::new(part.clone(), seed)
            .with_limits(m.limits)
            .with_config(&vcfg)
            .with_ageing(load_j);
        vb.id = bench_cfg.id.clone();
        let t_start = index as f64 * spec.interval_s;
        // The stimulus up to this interval's start, from the last measurement's end.
        let mut t = clock_s.min(t_start);
        // A test paused by the user (a paused test resumed after a stop of
        // the daemon too) holds here, its clock and load standing still.
        room.hold_while_paused(tx, &obs, t)?;
        if let Some(d) = device.as_mut() {
            // Played through the bench, under its safety rules.
            let mut report = |t_now: f64| progress(index, t_now, None);
            load_j += device_stimulus(d, &pcfg, spec, (t, t_start), &obs, room, &mut report)
                .map_err(|s| keep_fault_signals(d, s, tx))?;
            t = t_start;
        }
        while t < t_start {
            if obs.cancelled() {
                return Err(Stop::Aborted);
            }
            // The user's pause stops the stimulus at the next step.
            room.hold_while_paused(tx, &obs, t)?;
            // A step ends at a level change (decision 0132): each piece
            // holds one level, the load accrues at that level's excursion.
            let mut end = (t + STIMULUS_STEP_S).min(t_start);
            if let Some(c) = spec.stimulus.next_change_s(t) {
                end = end.min(c);
            }
            let step = end - t;
            let level_m = spec.stimulus.excursion_at_m(t);
            let on = spec.stimulus.on_time_s(t, end);
            let held = held_velocity(level_m);
            match (spec.stimulus.kind, held) {
                // Noise: the loop's load rate on the part as it is, held
                // at its RMS displacement (decision 0137).
                (StimulusKind::Noise | StimulusKind::Wav, _) => {
                    let l = match noise.as_mut() {
                        Some(l) => l,
                        None => noise.insert(waveform::LoopLoad::new(loop_wave(
                            &spec.stimulus,
                            vb.bench.sample_rate_hz,
                            wav,
                        )?)),
                    };
                    vb.apply_loop_load(l, level_m, on);
                    // Never a level that looks met when it is not: the
                    // drive limit holding the noise below its target is said.
                    let short = l.last().filter(|r| r.x_rms_m < 0.98 * level_m);
                    if short.is_some() != held_short {
                        held_short = short.is_some();
                        let _ = tx.send(Msg::Log(match short {
                            Some(r) => format!(
                                "test time {t:.0} s: the {} reaches {:.3} mm RMS of its {:.3} mm at the drive limit ({} V at its peak)",
                                loop_name(spec.stimulus.kind),
                                1e3 * r.x_rms_m,
                                1e3 * level_m,
                                m.limits.max_drive_v
                            ),
                            None => format!(
                                "test time {t:.0} s: the {} reaches its {:.3} mm RMS",
                                loop_name(spec.stimulus.kind),
                                1e3 * level_m
                            ),
                        }));
                    }
                }
                (StimulusKind::Sine, None) => {
                    // The same for the sine (at its peak excursion).
                    let reach = vb.apply_sine_load(level_m, on).reach_m;
                    let short = reach < 0.98 * level_m;
                    if short != held_short {
                        held_short = short;
                        let _ = tx.send(Msg::Log(if short {
                            format!(
                                "test time {t:.0} s: the sine reaches {:.3} mm of its {:.3} mm at the drive limit ({} V at its peak)",
                                1e3 * reach,
                                1e3 * level_m,
                                m.limits.max_drive_v
                            )
                        } else {
                            format!("test time {t:.0} s: the sine reaches its {:.3} mm", 1e3 * level_m)
                        }));
                    }
                }
                (StimulusKind::Sine, Some(v)) => {
                    vb.apply_sine_load_at_velocity(v, on);
                }
            }
            if !spec.accelerated {
                pace(step, &obs);
            }
            t = end;
            if let (Some(v), true) = (held, on > 0.0 && level_m > 0.0) {
                let load = vb.ageing_load_j().unwrap_or(load_j);
                let x = ageing::excursion_at_velocity_m(&vb.part, load, v);
                let growth = 100.0 * (x / level_m - 1.0);
                let bound = spec.failure_limits.xpeak_runaway_percent;
                if growth > bound {
                    let f = Failure {
                        limit: "xpeak_runaway_percent".into(),
                        interval: index,
                        at_s: Some(t),
                        value: Some(growth),
                        bound: Some(bound),
                        detail: format!(
                            "the stimulus' peak displacement ran away to {:.2} mm at {:.0} s, {growth:+.1} % over its level's {:.2} mm on the new part, beyond +{bound} %",
                            1e3 * x,
                            t,
                            1e3 * level_m
                        ),
                    };
                    let last = stimulus_signals(&mut vb, load, x, &obs)?;
                    let secs = last.len() as f64 / last.sample_rate_hz;
                    let res = crate::bench::Bench::resolution(&vb);
                    let rec = super::execute::recording("main", &last, res.as_ref())?;
                    send_and_wait(tx, |r| {
                        Msg::Failure(Box::new(f.clone()), Some((rec, secs)), r)
                    })?;
                    return Err(failure_problem(&f));
                }
            }
            let per =
                (index > start).then(|| started.elapsed().as_secs_f64() / (index - start) as f64);
            progress(index, t, per);
        }
        // The interval's results need room: a full disk pauses the test here.
        room.wait_for_space(tx, &obs, t_start)?;
        room.hold_while_paused(tx, &obs, t_start)?;
        // The air around the bench, from its configured sensor (decision
        // 0130): a reading that fails is left out of the interval, and said.
        let ambient = match &bench_cfg.ambient {
            None => crate::job::Ambient::default(),
            Some(sensor) => sensor.read(t_start).unwrap_or_else(|e| {
                let _ = tx.send(Msg::Log(format!(
                    "interval {index}: no ambient conditions stored: {e}"
                )));
                crate::job::Ambient::default()
            }),
        };
        // A device's load is measured (the stimulus' just added); a virtual part's simulated.
        let load_at_start = match device {
            Some(_) => load_j,
            None => vb.ageing_load_j().unwrap_or(load_j),
        };
        // The part's truth: the virtual bench's, the emulator's (its part
        // aged at its own true load); none on a real bench.
        let true_load_at_start = match device.as_ref() {
            Some(d) => d.true_load.as_ref().map(|t| t.get()),
            None => Some(load_at_start),
        };
        let k0_true = match (bench_cfg.kind, true_load_at_start) {
            (BenchKind::Virtual, _) => Some(vb.k0_now_n_per_m()),
            (BenchKind::Emulated, Some(e)) => part
                .k_coeffs_si
                .first()
                .map(|&k0| part.ageing.map_or(k0, |a| a.k0_n_per_m(k0, e))),
            _ => None,
        };
        if let (BenchKind::Emulated, Some(e), Some(k)) =
            (bench_cfg.kind, true_load_at_start, k0_true)
        {
            let _ = tx.send(Msg::Log(format!(
                "interval {index}: the emulated part's truth at the measurement's start: load {e:.1} J, K(0) {k:.1} N/m (measured load {load_at_start:.1} J)"
            )));
        }
        let wall = Instant::now();
        let runs_before = device.as_ref().map_or(0, |d| d.bench.run_records().len());
        let bench: &mut dyn Bench = match device.as_mut() {
            Some(d) => d.bench.as_mut(),
            None => &mut vb,
        };
        let out = match procedure::run(bench, &pcfg, &mut obs) {
            Ok(o) => o,
            Err(ProcedureError::Cancelled)
            | Err(ProcedureError::Bench(crate::bench::BenchError::Aborted)) => {
                return Err(Stop::Aborted)
            }
            Err(ProcedureError::Failed(why)) if why.contains("resonance") => {
                let f = Failure {
                    limit: "no_resonance".into(),
                    interval: index,
                    at_s: None,
                    value: None,
                    bound: None,
                    detail: format!("the procedure found no resonance: {why}"),
                };
                if index > 0 {
                    send_and_wait(tx, |r| Msg::Failure(Box::new(f.clone()), None, r))?;
                }
                return Err(failure_problem(&f));
            }
            Err(e) => {
                let stop = super::execute::procedure_stop(e);
                return Err(match device.as_mut() {
                    Some(d) => keep_fault_signals(d, stop, tx),
                    None => stop,
                });
            }
        };
        if !spec.accelerated && device.is_none() {
            pace(out.bench_time_s - wall.elapsed().as_secs_f64(), &obs);
        }
        let first = out.narrow.first().ok_or_else(|| {
            Stop::Failed(JobProblem::new(
                ProblemKind::Procedure,
                "Procedure failed",
                "the procedure made no narrow sweep",
            ))
        })?;
        let mut meta = Meta::standard(m.moving_mass_kg, out.pre.sample_rate_hz);
        meta.long_term = crate::recording::LongTermStamp {
            accelerated: Some(spec.accelerated),
            elapsed_s: Some(t_start),
            load_j: Some(load_at_start),
            long_term_interval: Some(index as u32),
            long_term_test: Some(job_id.to_string()),
        };
        // What a hardware bench stores about itself; never a fit of a
        // displacement not on the audio clock.
        let hw_record = device.as_ref().map(|d| {
            HardwareRecord::of_level(
                &d.calibration.id,
                &d.calibration.calibration,
                &d.calibration.sensors,
                &d.bench.run_records()[runs_before..],
                out.pre.len(),
                first.signals.len(),
                0,
            )
        });
        let not_aligned = hw_record
            .as_ref()
            .and_then(HardwareRecord::alignment_invalid);
        let analysed = match &not_aligned {
            Some(why) => Err(why.clone()),
            None => identify::analyze_sweeps(
                identify::Sweeps {
                    moving_mass_kg: m.moving_mass_kg,
                    pre: &out.pre,
                    main: &first.signals,
                },
                &opts,
            )
            .map_err(|e| e.to_string()),
        }
        .and_then(|r| {
            crate::finite::check(&r)
                .map(|()| r)
                .map_err(|e| format!("result refused: {e}"))
        });
        let (report, analysis_error) = match analysed {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(e)),
        };
        let config = MeasurementConfig {
            analysis: Some(opts.clone()),
            procedure: Some(pcfg.clone()),
            procedure_mode: Some(m.procedure),
            procedure_run: None,
            limits: Some(m.limits),
            bench: Some(bench_cfg.id.clone()),
            bench_description: Some(match device.as_ref() {
                Some(d) => d.bench.describe(),
                None => vb.describe(),
            }),
            seed: Some(seed),
            narrow_sweep: Some(SweepSettings {
                drive_v: first.drive_v,
                f_start_hz: first.f_start_hz,
                f_end_hz: first.f_end_hz,
                duration_s: Some(first.sweep.duration_s),
            }),
            pre_sweep: Some(PreSweepSettings {
                sweep: SweepSettings {
                    drive_v: out.pre_sweep.amplitude_v,
                    f_start_hz: out.pre_sweep.f_start_hz,
                    f_end_hz: out.pre_sweep.f_end_hz,
                    duration_s: Some(out.pre_sweep.duration_s),
                },
                q_drive_to_x: out.pre_q_drive_to_x,
            }),
            hardware: hw_record,
            other: Default::default(),
        };
        let res = match device.as_ref() {
            Some(d) => d.bench.resolution(),
            None => vb.resolution(),
        };
        let recordings = vec![
            super::execute::recording("pre", &out.pre, res.as_ref())?,
            super::execute::recording("main", &first.signals, res.as_ref())?,
        ];
        let measurement = crate::store::NewMeasurement {
            id: new_id(),
            part_serial: m.part.serial.clone(),
            job_id: Some(job_id.to_string()),
            source: "bench",
            bench_id: Some(bench_cfg.id.clone()),
            config,
            meta: crate::store::Doc::Made(meta),
            result: report.clone().map(crate::store::Doc::Made),
            analysis_error,
            target_xpeak_m: m.levels_m.first().copied(),
            repeat_index: Some(0),
            level_index: Some(0),
            pre: 0,
            main: 1,
        };
        let k0 = report.as_ref().and_then(k0_of);
        if index == 0 {
            first_k0 = k0;
        }
        if let Some(r) = report.clone() {
            done.push(series::Interval {
                elapsed_s: t_start,
                load_j: Some(load_at_start),
                report: r,
            });
        }
        let document: Option<AgeingDocument> = Some(series::analyse(&done, Some(spec.predict_s)))
            .filter(|d| crate::finite::check(d).is_ok());
        load_j = match device.as_mut() {
            // The measurement's own load, measured with the K(x) it found.
            Some(d) => {
                if let Some(r) = report.as_ref().filter(|r| !k_of(r).0.is_empty()) {
                    d.k = Some(k_of(r));
                }
                let fs = out.pre.sample_rate_hz;
                let sweeps = std::iter::once(&out.pre).chain(out.narrow.iter().map(|n| &n.signals));
                load_at_start
                    + d.k.as_ref().map_or(0.0, |(c, r)| {
                        sweeps
                            .map(|s| {
                                ageing_law::load_from_displacement_j(&s.displacement_m, fs, c, *r)
                            })
                            .sum()
                    })
            }
            None => vb.ageing_load_j().unwrap_or(load_at_start),
        };
        clock_s = t_start + out.bench_time_s;
        let iv = NewInterval {
            index,
            elapsed_s: t_start,
            load_j: load_at_start,
            accelerated: spec.accelerated,
            recordings,
            measurement,
            clock_s,
            part: PartState {
                load_j,
                k0_true_n_per_m: k0_true,
                true_load_j: match device.as_ref() {
                    Some(d) => d.true_load.as_ref().map(|t| t.get()),
                    None => Some(load_j),
                },
            },
            document,
            ambient,
        };
        send_and_wait(tx, |r| Msg::Interval(Box::new(iv), r))?;
        // The failure limits, on what this interval measured.
        let f0 = report
            .as_ref()
            .and_then(|r| r.small_signal.as_ref())
            .and_then(|s| s.f0_hz);
        let failure = if k0.is_none() || f0.is_none() {
            Some(Failure {
                limit: "no_resonance".into(),
                interval: index,
                at_s: None,
                value: None,
                bound: None,
                detail: "the measurement determined no small-signal resonance (f0, K(0))".into(),
            })
        } else {
            match (first_k0, k0) {
                (Some(a), Some(b)) if a > 0.0 => {
                    let change = 100.0 * (b / a - 1.0);
                    let bound = spec.failure_limits.k0_change_percent;
                    (change.abs() > bound).then(|| Failure {
                        limit: "k0_change_percent".into(),
                        interval: index,
                        at_s: None,
                        value: Some(change),
                        bound: Some(bound),
                        detail: format!(
                            "K(0) changed by {change:+.1} % from the first interval ({a:.1} → {b:.1} N/m), beyond ±{bound} %"
                        ),
                    })
                }
                _ => None,
            }
        };
        if let Some(f) = failure {
            let last = tail(&first.signals, LAST_SIGNALS_S);
            let secs = last.len() as f64 / last.sample_rate_hz;
            let rec = super::execute::recording("main", &last, res.as_ref())?;
            send_and_wait(tx, |r| {
                Msg::Failure(Box::new(f.clone()), Some((rec, secs)), r)
            })?;
            return Err(failure_problem(&f));
        }
        let per = started.elapsed().as_secs_f64() / (index + 1 - start) as f64;
        progress(index + 1, clock_s.min(spec.duration_s), Some(per));
    }
    Ok(n)
}

/// The last seconds of a stimulus whose excursion ran away, simulated on the
/// virtual bench at the part's state then (the accelerated stimulus has no
/// signals of its own): a sine at the part's resonance at `xpeak_m`
/// (`physics::ageing::resonance_hz`), its drive levelled by four short
/// probes within the bench's drive limit. Each run glides up into the
/// frequency from 70 % of it, as `procedure::break_in` does: a hardening
/// part then stays on the upper branch of its response, whose excursion
/// barely follows the drive near the backbone, so the level is approached,
/// not met (within ~20 % of `xpeak_m`, above it, for the torn spider_3in).
fn stimulus_signals(
    vb: &mut VirtualBench,
    load_j: f64,
    xpeak_m: f64,
    obs: &LtObserver<'_>,
) -> Result<Signals, Stop> {
    use crate::bench::{Bench, Control};
    const GLIDE_S: f64 = 1.5;
    let f_hz = ageing::resonance_hz(&vb.part, load_j, xpeak_m);
    let fs = vb.bench.sample_rate_hz;
    let max_v = vb.limits.max_drive_v;
    // Runs `hold_s` at f_hz after the glide; returns the held part.
    let mut play = |v: f64, hold_s: f64| {
        let (ng, nh) = ((GLIDE_S * fs) as usize, (hold_s * fs).round() as usize);
        let mut phase = 0.0f64;
        let drive: Vec<f64> = (0..ng + nh)
            .map(|k| {
                let (f, g) = if k < ng {
                    let u = k as f64 / ng as f64;
                    (f_hz * (0.7 + 0.3 * u), u.min(0.2) / 0.2)
                } else {
                    (f_hz, 1.0)
                };
                phase += 2.0 * std::f64::consts::PI * f / fs;
                g * v * phase.sin()
            })
            .collect();
        vb.run(&drive, &mut |_| {
            if obs.cancelled() {
                Control::Abort
            } else {
                Control::Continue
            }
        })
        .map(|s| tail(&s, hold_s))
        .map_err(|e| match e {
            crate::bench::BenchError::Aborted => Stop::Aborted,
            e => Stop::Failed(JobProblem::new(
                ProblemKind::Bench,
                "Last signals not recorded",
                format!("the stimulus' last seconds on the virtual bench: {e}"),
            )),
        })
    };
    let peak = |s: &Signals| {
        let h = s.displacement_m.len() / 2;
        s.displacement_m[h..]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()))
    };
    let mut v = 1.0f64;
    for _ in 0..4 {
        let x = peak(&play(v, 1.0)?);
        if x > 0.0 {
            v = (v * xpeak_m / x).min(max_v);
        }
    }
    play(v, LAST_SIGNALS_S)
}

/// Bench time a held stimulus spends finding the resonance at its level
/// before it holds (s): the probe and at most three search sweeps.
const HOLD_SEARCH_S: f64 = 12.0;
/// Longest hold of one call (s): the resonance is searched again after it.
const HOLD_MAX_S: f64 = 3600.0;

/// The stimulus on a hardware or emulated bench over test times `span`:
/// the sine held at the part's resonance at the stimulus' level (`excursion_m`, then each
/// level step's from its `from_s`: a step ends the hold and the resonance is searched again)
/// (`procedure::hold_at_resonance`, the break-in's hold) played through the
/// bench, so that the bench's safety rules hold for it as for a
/// measurement: the drive clamped to the limit where it is produced and
/// checked on the loopback, the displacement limit and the laser checked
/// on every block, and any fault (a limit, the laser unplugged, a stream
/// error) ramps the drive down and stops the test (`Stop::Failed` with a
/// bench-fault problem). On/off cycled when asked; the off time, and the
/// time the hold could not fill, pass idle (waited for on a bench that runs
/// in real time). Returns the load it put on the part, measured from the
/// displacement with the last measured K(x) (J).
/// What a hold on a hardware or emulated bench has played so far: the load
/// measured from the laser with the part's last K(x) (J), the loopback's
/// peak (V), the seconds played from test time `t0_s`.
struct Played {
    k: Option<(Vec<f64>, [f64; 2])>,
    fs: f64,
    t0_s: f64,
    load_j: f64,
    peak_v: f64,
    played_s: f64,
}

impl Played {
    fn new(k: Option<(Vec<f64>, [f64; 2])>, fs: f64, t0_s: f64) -> Played {
        Played {
            k,
            fs,
            t0_s,
            load_j: 0.0,
            peak_v: 0.0,
            played_s: 0.0,
        }
    }

    /// One chunk played: its load, its drive's peak, the test's progress.
    fn chunk(&mut self, sig: &Signals, report: &mut dyn FnMut(f64)) {
        if let Some((c, r)) = &self.k {
            self.load_j +=
                ageing_law::load_from_displacement_j(&sig.displacement_m, self.fs, c, *r);
        }
        if let Some(u) = &sig.drive_v {
            self.peak_v = u.iter().fold(self.peak_v, |a, v| a.max(v.abs()));
        }
        self.played_s += sig.len() as f64 / self.fs;
        report(self.t0_s + self.played_s);
    }

    /// The hold's error as the test's stop, saying when in the test it came.
    fn stop(&self, e: ProcedureError) -> Stop {
        match super::execute::procedure_stop(e) {
            Stop::Failed(mut p) => {
                p.detail = format!(
                    "during the stimulus at test time {:.0} s: {}",
                    self.t0_s + self.played_s,
                    p.detail
                );
                Stop::Failed(p)
            }
            s => s,
        }
    }
}

fn device_stimulus(
    d: &mut Device<'_>,
    pcfg: &ProcedureConfig,
    spec: &LongTermSpec,
    span: (f64, f64),
    obs: &LtObserver<'_>,
    room: &Room<'_>,
    report: &mut dyn FnMut(f64),
) -> Result<f64, Stop> {
    let tx = room.tx;
    let (mut t, to) = span;
    let max_drive_v = d.bench.limits().max_drive_v;
    let mut load_j = 0.0;
    // A noise's loop and where it stands (decision 0137).
    let (mut noise_wave, mut noise_phase): (Option<Vec<f64>>, usize) = (None, 0);
    while t < to - 1e-9 {
        if obs.cancelled() {
            return Err(Stop::Aborted);
        }
        // The user's pause: the hold below stopped at the end of a chunk
        // (faded out), nothing plays until it is resumed, then the
        // resonance is searched again.
        room.hold_while_paused(tx, obs, t)?;
        // The current phase of the on/off cycle and its end.
        let (on, end) = match (spec.stimulus.on_s, spec.stimulus.off_s) {
            (Some(on_s), Some(off_s)) if on_s + off_s > 0.0 => {
                let period = on_s + off_s;
                let phase = t - (t / period).floor() * period;
                if phase < on_s {
                    (true, (t - phase + on_s).min(to))
                } else {
                    (false, (t - phase + period).min(to))
                }
            }
            _ => (true, to),
        };
        // A level step ends the chunk: the hold's target is the level's
        // (decision 0132), the resonance searched again at the new level.
        let x = spec.stimulus.excursion_at_m(t);
        let end = spec.stimulus.next_change_s(t).map_or(end, |c| end.min(c));
        // A noise or a WAV file: a loop held at its RMS displacement.
        let noise = spec.stimulus.kind.is_loop();
        let hold_s = if noise {
            procedure::waveform::held_within_s(end - t).min(HOLD_MAX_S)
        } else {
            (end - t - HOLD_SEARCH_S).min(HOLD_MAX_S)
        };
        if noise && on && x > 0.0 && hold_s >= 1.0 {
            // Band-limited noise (decision 0137): the loop played in faded
            // chunks, levelled on the measured RMS displacement, under the
            // same limits and checks as the sine's hold.
            let fs = d.bench.sample_rate_hz();
            let wave = match &noise_wave {
                Some(w) => w,
                None => noise_wave.insert(loop_wave(&spec.stimulus, fs, d.wav)?),
            };
            let (mut p, t0) = (Played::new(d.k.clone(), fs, t), t);
            let r = procedure::waveform::hold_loop(
                d.bench.as_mut(),
                wave,
                &mut noise_phase,
                x,
                hold_s,
                &mut || obs.cancelled(),
                &mut || room.paused(),
                &mut |sig: &Signals| p.chunk(sig, report),
            );
            let done = r.map_err(|e| p.stop(e))?;
            let (e, peak_v) = (p.load_j, p.peak_v);
            load_j += e;
            let _ = tx.send(Msg::Log(format!(
                "{} stimulus from test time {t0:.0} s: {:.0} s held, RMS displacement {:.3} mm (target {:.3} mm), peak drive {:.2} V, peak drive on the loopback {:.2} V (limit {max_drive_v} V), load +{e:.1} J",
                loop_name(spec.stimulus.kind),
                done.held_s,
                1e3 * done.x_rms_m,
                1e3 * x,
                done.drive_peak_v,
                peak_v,
            )));
            t += done.bench_time_s;
            if room.paused() {
                report(t);
                continue;
            }
        } else if on && x > 0.0 && hold_s >= 1.0 {
            let fs = d.bench.sample_rate_hz();
            let (mut p, t0) = (Played::new(d.k.clone(), fs, t), t);
            let r = procedure::hold_at_resonance(
                d.bench.as_mut(),
                pcfg,
                &procedure::BreakIn {
                    duration_s: hold_s,
                    xpeak_m: x,
                },
                &mut || obs.cancelled(),
                &mut || room.paused(),
                &mut |sig: &Signals| p.chunk(sig, report),
            );
            let done = r.map_err(|e| p.stop(e))?;
            let (e, peak_v) = (p.load_j, p.peak_v);
            load_j += e;
            let _ = tx.send(Msg::Log(format!(
                "stimulus from test time {t0:.0} s: {:.0} s held at {:.2} Hz, mean peak displacement {:.3} mm (target {:.3} mm), drive {:.2} V, peak drive on the loopback {:.2} V (limit {max_drive_v} V), load +{e:.1} J",
                done.held_s,
                done.f_hz,
                1e3 * done.xpeak_m,
                1e3 * x,
                done.drive_v,
                peak_v,
            )));
            t += done.bench_time_s;
            if room.paused() {
                report(t);
                continue;
            }
        }
        // Off, or what the hold left of its phase: idle, drive silent.
        if t < end {
            if d.paced {
                // The user's pause stops the idle clock too.
                let waited = pace_unless(end - t, obs, &|| room.paused());
                if obs.cancelled() {
                    return Err(Stop::Aborted);
                }
                t = if room.paused() { t + waited } else { end };
            } else {
                t = end;
            }
        }
        report(t);
    }
    Ok(load_j)
}

/// A loop stimulus' name in the job's log.
fn loop_name(kind: StimulusKind) -> &'static str {
    if kind == StimulusKind::Wav {
        "WAV file"
    } else {
        "noise"
    }
}

/// A loop stimulus' loop at the bench's sample rate (the accelerated
/// load's on a virtual bench, the hold's on a hardware one): the noise's
/// (decision 0137) or the WAV file's (decision 0144), which must be at the
/// bench's rate (it is not resampled).
fn loop_wave(
    s: &crate::job::Stimulus,
    fs: f64,
    wav: Option<&(u32, Vec<f64>)>,
) -> Result<Vec<f64>, Stop> {
    if s.kind == StimulusKind::Wav {
        let Some((rate, wave)) = wav else {
            return Err(Stop::Failed(JobProblem::new(
                ProblemKind::Bench,
                "Stimulus not made",
                "the WAV stimulus' file was not read",
            )));
        };
        if f64::from(*rate) != fs {
            return Err(Stop::Failed(JobProblem::new(
                ProblemKind::Bench,
                "Stimulus not made",
                format!("stimulus.wav_id: the file runs at {rate} Hz, the bench at {fs} Hz (it is not resampled)"),
            )));
        }
        return Ok(wave.clone());
    }
    let band = s.band_hz.unwrap_or([0.0, 0.0]);
    waveform::noise_loop(fs, band, waveform::NOISE_LOOP_S, waveform::NOISE_SEED).ok_or_else(|| {
        Stop::Failed(JobProblem::new(
            ProblemKind::Bench,
            "Stimulus not made",
            format!("stimulus.band_hz {band:?} holds no line at {fs} Hz"),
        ))
    })
}

/// A bench fault on a hardware or emulated bench: the last seconds the
/// bench captured before it (the faulted run's, up to the fault and its
/// ramp) are stored as the test's last signals (issue 32: "on a failure
/// the last seconds of the signals are stored"); the stop is returned as
/// it was, and a failure to store them is only logged.
fn keep_fault_signals(d: &mut Device<'_>, stop: Stop, tx: &mpsc::UnboundedSender<Msg>) -> Stop {
    let Stop::Failed(p) = &stop else {
        return stop;
    };
    if p.kind != ProblemKind::BenchFault {
        return stop;
    }
    let Some(sig) = d.bench.take_fault_signals() else {
        return stop;
    };
    let last = tail(&sig, LAST_SIGNALS_S);
    let secs = last.len() as f64 / last.sample_rate_hz;
    let res = d.bench.resolution();
    let stored = super::execute::recording("main", &last, res.as_ref())
        .map_err(|_| "not encoded".to_string())
        .and_then(|rec| {
            send_and_wait(tx, |r| Msg::LastSignals((rec, secs), r))
                .map_err(|_| "not stored".to_string())
        });
    let _ = tx.send(Msg::Log(match stored {
        Ok(()) => format!("the last {secs:.2} s before the bench fault stored (last-signals.wav)"),
        Err(e) => format!("the last signals before the bench fault: {e}"),
    }));
    stop
}

/// Waits `seconds` of real time (a paced, not accelerated, test), polling the cancel.
fn pace(seconds: f64, obs: &LtObserver<'_>) {
    pace_unless(seconds, obs, &|| false);
}

/// [`pace`], also ended by `stop`; returns the seconds waited.
fn pace_unless(seconds: f64, obs: &LtObserver<'_>, stop: &dyn Fn() -> bool) -> f64 {
    let start = Instant::now();
    let until = start + Duration::from_secs_f64(seconds.max(0.0));
    while Instant::now() < until && !obs.cancelled() && !stop() {
        std::thread::sleep(Duration::from_millis(100).min(until - Instant::now()));
    }
    start.elapsed().as_secs_f64().min(seconds.max(0.0))
}
