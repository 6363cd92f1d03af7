//! The memory's studies as jobs (issue 33, decision 0121): the recovery
//! measurement and the added-mass study on the job's bench. The added-mass
//! study measures the part, then waits in `awaiting_operator` with the
//! instruction until the operator confirms (`POST /api/v1/studies/{id}/confirm`),
//! then measures the part with the added mass. The science is core's
//! (`diagnose::studies`, `diagnose::memory`); this is the shell: the bench
//! thread, the wait, the store.

use super::events::StudyStep;
use super::execute::make_bench;
use super::{JobEvent, Runner, Slot, CANCEL, COMMIT};
use crate::diagnose::studies::{
    analyze_added_mass, attribute_added_mass, MassRun, Study, StudyPlan, StudyResult, StudyState,
};
use crate::identify::ForceBalanceData;
use crate::job::{JobProblem, ProblemKind};
use crate::store::{Job, JobState, StoreResult};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the wait for the operator looks at the study's row.
const CONFIRM_POLL: Duration = Duration::from_millis(100);

/// Why a study stopped early.
enum Halt {
    Failed(JobProblem),
    Aborted,
}

fn failed(kind: ProblemKind, title: &str, detail: impl Into<String>) -> Halt {
    Halt::Failed(JobProblem::new(kind, title, detail.into()))
}

/// One measurement of the part (the standard procedure at one level) and
/// its small- and large-signal values, with `mass_given_kg` as the fit's mass.
fn measure(
    slot_cfg: &crate::config::BenchConfig,
    part: crate::physics::PartSpec,
    seed: u64,
    job_seq: i64,
    mass_given_kg: f64,
    level_m: f64,
    stop: (Arc<AtomicU8>, Arc<AtomicBool>),
) -> Result<(MassRun, f64, ForceBalanceData), Halt> {
    let mut bench = make_bench(slot_cfg, part, seed, job_seq, slot_cfg.limits)
        .map_err(|e| failed(ProblemKind::Bench, "Bench not available", e))?;
    let cfg = crate::procedure::ProcedureConfig {
        moving_mass_kg: mass_given_kg,
        levels_m: vec![level_m],
        ..Default::default()
    };
    struct Obs(Arc<AtomicU8>, Arc<AtomicBool>);
    impl crate::procedure::Observer for Obs {
        fn cancelled(&self) -> bool {
            self.0.load(Ordering::Relaxed) == CANCEL || self.1.load(Ordering::Relaxed)
        }
    }
    let outcome = crate::procedure::run(bench.as_mut(), &cfg, &mut Obs(stop.0, stop.1)).map_err(
        |e| match e {
            crate::procedure::ProcedureError::Cancelled
            | crate::procedure::ProcedureError::Bench(crate::bench::BenchError::Aborted) => {
                Halt::Aborted
            }
            e => failed(ProblemKind::Procedure, "Procedure failed", e.to_string()),
        },
    )?;
    let narrow = outcome.narrow.first().ok_or_else(|| {
        failed(
            ProblemKind::Procedure,
            "Procedure failed",
            "no narrow sweep",
        )
    })?;
    let set = crate::recording::RecordingSet {
        meta: crate::recording::Meta::standard(mass_given_kg, bench.sample_rate_hz()),
        pre: outcome.pre.clone(),
        main: narrow.signals.clone(),
    };
    let bench_time_s = (outcome.pre.len() + narrow.signals.len()) as f64 / bench.sample_rate_hz();
    let (report, data) = crate::identify::analyze_with_force_balance(&set, &Default::default())
        .map_err(|e| failed(ProblemKind::Procedure, "Analysis failed", e.to_string()))?;
    let ss = report.small_signal.as_ref();
    let run = MassRun {
        mass_given_kg,
        f0_hz: ss.and_then(|s| s.f0_hz).unwrap_or(f64::NAN),
        k0_given_mass_n_per_m: ss.and_then(|s| s.k0_n_per_m).unwrap_or(f64::NAN),
        keff_n_per_m: report.large_signal.keff_n_per_m,
        resonance_hz: report.large_signal.resonance_hz,
        xpeak_m: report.large_signal.xpeak_m,
    };
    Ok((run, bench_time_s, data))
}

/// `f` on a blocking thread; a crash is the study's failure.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, Halt> + Send + 'static,
) -> Result<T, Halt> {
    tokio::task::spawn_blocking(f).await.unwrap_or_else(|e| {
        Err(failed(
            ProblemKind::Internal,
            "Study crashed",
            format!("the study's task ended abnormally: {e}"),
        ))
    })
}

impl Runner {
    /// Runs a study job to its end (the job's and the study's state stored).
    pub(super) async fn run_study(
        &self,
        slot: &Slot,
        job: &Job,
        study: Study,
        cancel: Arc<AtomicU8>,
        started: Instant,
    ) -> StoreResult<()> {
        let kind = study.kind();
        self.store
            .set_study_state(&job.id, kind, StudyState::Measuring, None)
            .await?;
        let mut log = Vec::new();
        let res = self
            .study_result(slot, job, &study, &cancel, &mut log)
            .await?;
        // From here on a cancel is too late (409); one that came before
        // still wins, so a 202 always ends as `cancelled` (as a measurement
        // job: `Runner::record`).
        let cancelled_late = cancel.swap(COMMIT, Ordering::SeqCst) == CANCEL;
        let stopped = match res {
            Ok(_) if cancelled_late => Some(JobState::Cancelled),
            Err(Halt::Aborted) if self.shutdown.load(Ordering::SeqCst) => {
                Some(JobState::Interrupted)
            }
            Err(Halt::Aborted) => Some(JobState::Cancelled),
            _ => None,
        };
        if let Some(state) = stopped {
            // Cancelled by the user, or cut off by the shutdown: the job
            // says which (a cancelled study used to end `failed`).
            self.store.finish_study(&job.id, kind, None).await?;
            let p = (state == JobState::Interrupted).then(|| {
                JobProblem::new(
                    ProblemKind::Interrupted,
                    "Job interrupted",
                    "the daemon was stopped while this study was running; the bench was ramped down and the study was not re-run (submit it again)",
                )
            });
            let commit =
                self.store
                    .finish_job(&job.id, state, p.as_ref(), None, &log, &[], vec![], vec![]);
            self.commit_settled(slot, &job.id, commit).await?;
            tracing::info!(job = %job.id, bench = %slot.cfg.id, "{kind} study {}", state.as_str());
            self.events
                .publish(Some(&job.id), &JobEvent::Failed { state, problem: p })
                .await?;
            return Ok(());
        }
        match res {
            Ok((result, bench_time_s)) => {
                self.store
                    .finish_study(&job.id, kind, Some(&result))
                    .await?;
                let commit = self.store.finish_job(
                    &job.id,
                    JobState::Succeeded,
                    None,
                    Some(bench_time_s),
                    &log,
                    &[],
                    vec![],
                    vec![],
                );
                self.commit_settled(slot, &job.id, commit).await?;
                tracing::info!(job = %job.id, bench = %slot.cfg.id, wall_s = started.elapsed().as_secs_f64(), "{kind} study done");
                self.events
                    .publish(
                        Some(&job.id),
                        &JobEvent::StudySucceeded {
                            state: JobState::Succeeded,
                            study: kind,
                        },
                    )
                    .await?;
                Ok(())
            }
            Err(h) => {
                self.store.finish_study(&job.id, kind, None).await?;
                let p = match h {
                    Halt::Failed(p) => p,
                    // Handled above; kept for the match.
                    Halt::Aborted => JobProblem::new(
                        ProblemKind::Other("cancelled".into()),
                        "Study stopped",
                        "the study was cancelled or the daemon stopped before it ended",
                    ),
                };
                self.finish_failed_after(slot, job, &p, None, &log, &[])
                    .await
            }
        }
    }

    async fn study_result(
        &self,
        slot: &Slot,
        job: &Job,
        study: &Study,
        cancel: &Arc<AtomicU8>,
        log: &mut Vec<String>,
    ) -> StoreResult<Result<(StudyResult, f64), Halt>> {
        let bad = study.check();
        if !bad.is_empty() {
            let detail = bad
                .iter()
                .map(|e| format!("{}: {}", e.field, e.message))
                .collect::<Vec<_>>()
                .join("; ");
            return Ok(Err(failed(
                ProblemKind::JobUnreadable,
                "Study request refused",
                detail,
            )));
        }
        let name = study.preset.as_deref().unwrap_or(&slot.cfg.preset);
        let part = match crate::physics::preset(name) {
            Ok(p) => p,
            Err(e) => return Ok(Err(failed(ProblemKind::Part, "Part not available", e))),
        };
        let seed = slot.cfg.seed.wrapping_add(job.seq as u64);
        let stop = (cancel.clone(), self.shutdown.clone());
        let (cfg, seq, mass) = (slot.cfg.clone(), job.seq, study.moving_mass_kg);
        match &study.plan {
            StudyPlan::Recovery(plan) => {
                let (plan, stop) = (plan.clone(), stop.clone());
                let r: Result<(StudyResult, f64), Halt> = blocking(move || {
                    let mut bench = make_bench(&cfg, part, seed, seq, cfg.limits)
                        .map_err(|e| failed(ProblemKind::Bench, "Bench not available", e))?;
                    let fs = bench.sample_rate_hz();
                    let (signals, r) = crate::bench::procedure::memory::run_recovery(
                        bench.as_mut(),
                        &plan,
                        mass,
                        &mut |_| {
                            if stop.0.load(Ordering::Relaxed) == CANCEL
                                || stop.1.load(Ordering::Relaxed)
                            {
                                crate::bench::Control::Abort
                            } else {
                                crate::bench::Control::Continue
                            }
                        },
                    )
                    .map_err(|e| match e {
                        crate::procedure::ProcedureError::Cancelled
                        | crate::procedure::ProcedureError::Bench(
                            crate::bench::BenchError::Aborted,
                        ) => Halt::Aborted,
                        e => failed(
                            ProblemKind::Procedure,
                            "Recovery measurement failed",
                            e.to_string(),
                        ),
                    })?;
                    Ok((StudyResult::Recovery(r), signals.len() as f64 / fs))
                })
                .await;
                Ok(r)
            }
            StudyPlan::AddedMass(plan) => {
                let (level, added) = (plan.level_m, plan.added_mass_kg);
                let (c1, p1, s1) = (cfg.clone(), part.clone(), stop.clone());
                let first = blocking(move || measure(&c1, p1, seed, seq, mass, level, s1)).await;
                let (without, t1, d1) = match first {
                    Ok(r) => r,
                    Err(h) => return Ok(Err(h)),
                };
                log.push(format!(
                    "without the added mass: f0 {:.3} Hz, Keff {:.1} N/m at {:.2} mm",
                    without.f0_hz,
                    without.keff_n_per_m,
                    without.xpeak_m * 1e3
                ));
                let instruction = study
                    .instruction()
                    .unwrap_or_default()
                    .replace("{id}", &job.id);
                self.store
                    .set_study_state(
                        &job.id,
                        study.kind(),
                        StudyState::AwaitingOperator,
                        Some(&instruction),
                    )
                    .await?;
                self.store
                    .set_progress(&job.id, "awaiting_operator", 0.5, 0.0)
                    .await?;
                self.events
                    .publish(
                        Some(&job.id),
                        &JobEvent::StudyAwaitingOperator {
                            state: StudyStep::AwaitingOperator,
                            instruction: instruction.clone(),
                        },
                    )
                    .await?;
                // The wait: the operator's confirmation, a cancel or the shutdown.
                loop {
                    if cancel.load(Ordering::Relaxed) == CANCEL
                        || self.shutdown.load(Ordering::Relaxed)
                    {
                        return Ok(Err(Halt::Aborted));
                    }
                    let row = self.store.get_study(&job.id).await?;
                    if row.is_some_and(|r| r.state == StudyState::Confirmed) {
                        break;
                    }
                    tokio::time::sleep(CONFIRM_POLL).await;
                }
                log.push(format!(
                    "the operator confirmed {:.1} g on the slide",
                    added * 1e3
                ));
                self.store
                    .set_progress(&job.id, "added_mass", 0.5, 0.0)
                    .await?;
                self.events
                    .publish(
                        Some(&job.id),
                        &JobEvent::StudyStep {
                            state: StudyStep::Confirmed,
                        },
                    )
                    .await?;
                // On a virtual bench the mass is added to the simulated
                // slide; on hardware the operator has mounted it.
                let mut heavier = part;
                heavier.moving_mass_kg += added;
                let second = blocking(move || {
                    measure(
                        &cfg,
                        heavier,
                        seed.wrapping_add(1),
                        seq,
                        mass + added,
                        level,
                        stop,
                    )
                })
                .await;
                let (with_mass, t2, d2) = match second {
                    Ok(r) => r,
                    Err(h) => return Ok(Err(h)),
                };
                log.push(format!(
                    "with the added mass: f0 {:.3} Hz, Keff {:.1} N/m at {:.2} mm",
                    with_mass.f0_hz,
                    with_mass.keff_n_per_m,
                    with_mass.xpeak_m * 1e3
                ));
                let mut result = match analyze_added_mass(added, without, with_mass) {
                    Ok(r) => r,
                    Err(e) => {
                        return Ok(Err(failed(
                            ProblemKind::Procedure,
                            "Added-mass study failed",
                            e,
                        )))
                    }
                };
                // Which cause the changes go to (decision 0122): both runs
                // as one part, with the derived mass corrected for creep.
                let r0 = result.clone();
                match blocking(move || Ok(attribute_added_mass(&r0, [d1, d2], &Default::default())))
                    .await
                {
                    Ok(Ok(a)) => {
                        log.extend(a.notes.iter().cloned());
                        result.attribution = Some(Box::new(a));
                    }
                    Ok(Err(e)) => log.push(format!("no attribution: {e}")),
                    Err(h) => return Ok(Err(h)),
                }
                Ok(Ok((StudyResult::AddedMass(result), t1 + t2)))
            }
        }
    }
}
