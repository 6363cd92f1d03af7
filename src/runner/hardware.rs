//! The runner's part for hardware (and emulated) benches: faulted state,
//! self-check jobs and calibration records, and what each measurement stores
//! about the bench it was made on (calibration record, sensors, latency,
//! alignment).

use super::{Runner, Slot};
use crate::bench::Bench;
use crate::config::{BenchConfig, BenchKind};
use crate::job::{JobProblem, ProblemKind};
use crate::physics::PartSpec;
use crate::store::hardware::{CalibrationRecord, SelfCheckResult};
use crate::store::{Job, JobState, StoreResult};
use serde::Serialize;
use std::time::Instant;

/// Why a bench is faulted.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FaultInfo {
    pub detail: String,
    pub job_id: Option<String>,
    pub since: String,
}

/// The job request of a self-check.
pub fn self_check_request(bench_id: &str) -> crate::job::StoredRequest {
    crate::job::StoredRequest::SelfCheck(crate::job::SelfCheck {
        bench: bench_id.to_string(),
    })
}

/// Part serial under which a bench's self-check jobs are stored.
pub fn self_check_serial(bench_id: &str) -> String {
    format!("selfcheck.{bench_id}")
}

/// Opens a hardware or emulated bench; `ageing`: the emulated part ages
/// with this true load (a long-term test's, decision 0135).
#[cfg(feature = "hardware")]
pub fn open_bench(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    job_seq: i64,
    limits: crate::bench::Limits,
    ageing: Option<crate::bench::true_part::TrueLoad>,
) -> Result<Box<dyn Bench>, String> {
    Ok(Box::new(crate::bench::hardware::open(
        cfg, part, seed, job_seq, limits, ageing,
    )?))
}

#[cfg(not(feature = "hardware"))]
pub fn open_bench(
    cfg: &BenchConfig,
    _part: PartSpec,
    _seed: u64,
    _job_seq: i64,
    _limits: crate::bench::Limits,
    _ageing: Option<crate::bench::true_part::TrueLoad>,
) -> Result<Box<dyn Bench>, String> {
    Err(format!(
        "bench '{}' needs the `hardware` feature, which this build lacks",
        cfg.id
    ))
}

/// Runs a self-check on its own blocking thread; Ok(result JSON, passed).
#[cfg(feature = "hardware")]
fn self_check_blocking(cfg: &BenchConfig, seq: i64) -> Result<SelfCheckResult, String> {
    let part = crate::physics::preset(&cfg.preset)?;
    let seed = cfg.seed.wrapping_add(seq as u64);
    let mut b = crate::bench::hardware::open(cfg, part, seed, seq, cfg.limits, None)?;
    match b.self_check() {
        Ok(sc) => Ok(SelfCheckResult::of(&sc)),
        Err(e) => Ok(SelfCheckResult::failed(e.to_string())),
    }
}

#[cfg(not(feature = "hardware"))]
fn self_check_blocking(cfg: &BenchConfig, _seq: i64) -> Result<SelfCheckResult, String> {
    Err(format!(
        "bench '{}' needs the `hardware` feature, which this build lacks",
        cfg.id
    ))
}

impl Runner {
    /// Marks the bench faulted (stored: it stays faulted across restarts).
    pub(super) async fn fault_bench(
        &self,
        slot: &Slot,
        job_id: &str,
        p: &JobProblem,
    ) -> StoreResult<()> {
        let detail = p.detail.clone();
        self.store
            .insert_bench_fault(&slot.cfg.id, Some(job_id), &detail)
            .await?;
        let info = FaultInfo {
            detail: detail.clone(),
            job_id: Some(job_id.to_string()),
            since: crate::store::now(),
        };
        {
            let mut st = slot.status.lock().unwrap();
            st.state = "faulted";
            st.fault = Some(info);
        }
        tracing::error!(bench = %slot.cfg.id, job = %job_id, "bench faulted: {detail}");
        self.events
            .publish(
                Some(job_id),
                &super::JobEvent::BenchFaulted {
                    bench_id: slot.cfg.id.clone(),
                    detail,
                },
            )
            .await?;
        Ok(())
    }

    /// Runs the self-check and stores its calibration record; a pass clears the fault.
    async fn self_check(
        &self,
        slot: &Slot,
        job: &Job,
    ) -> StoreResult<Result<CalibrationRecord, JobProblem>> {
        let cfg = slot.cfg.clone();
        let seq = job.seq;
        let res = tokio::task::spawn_blocking(move || self_check_blocking(&cfg, seq)).await;
        let result = match res {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => SelfCheckResult::failed(e),
            Err(e) => SelfCheckResult::failed(format!("self-check crashed: {e}")),
        };
        let passed = result.passed;
        let rec = CalibrationRecord {
            id: super::new_id(),
            bench_id: slot.cfg.id.clone(),
            job_id: Some(job.id.clone()),
            passed,
            calibration: slot.cfg.calibration_document(),
            sensors: slot.cfg.sensors_document(),
            result,
            created_at: crate::store::now(),
        };
        self.store.insert_calibration(&rec).await?;
        if passed {
            let mut st = slot.status.lock().unwrap();
            st.fault = None;
            if st.state == "faulted" {
                st.state = "running";
            }
            return Ok(Ok(rec));
        }
        let failures = &rec.result.failures;
        let p = JobProblem::new(
            ProblemKind::BenchFault,
            "Bench self-check failed",
            format!(
                "self-check of bench '{}' failed (calibration record {}): {}",
                slot.cfg.id,
                rec.id,
                failures.join("; ")
            ),
        );
        self.fault_bench(slot, &job.id, &p).await?;
        Ok(Err(p))
    }

    /// A self-check job: run, store the record, finish the job.
    pub(super) async fn run_self_check(
        &self,
        slot: &Slot,
        job: &Job,
        started: Instant,
    ) -> StoreResult<()> {
        if slot.cfg.kind == BenchKind::Virtual {
            let p = JobProblem::new(
                ProblemKind::SelfCheckUnsupported,
                "Self-check needs a hardware bench",
                format!("bench '{}' is virtual", slot.cfg.id),
            );
            return self.finish_failed(slot, job, p).await;
        }
        match self.self_check(slot, job).await? {
            Ok(rec) => {
                let log = vec![format!(
                    "self-check passed: calibration record {} (latency {} s)",
                    rec.id,
                    rec.result
                        .latency_s
                        .map_or("null".to_string(), |l| l.to_string())
                )];
                let commit = self.store.finish_job(
                    &job.id,
                    JobState::Succeeded,
                    None,
                    None,
                    &log,
                    &[],
                    vec![],
                    vec![],
                );
                self.commit_settled(slot, &job.id, commit).await?;
                tracing::info!(job = %job.id, bench = %slot.cfg.id, wall_s = started.elapsed().as_secs_f64(), "self-check passed");
                self.events
                    .publish(
                        Some(&job.id),
                        &super::JobEvent::SelfCheckPassed {
                            state: JobState::Succeeded,
                            calibration_id: rec.id.clone(),
                        },
                    )
                    .await?;
                Ok(())
            }
            Err(p) => self.finish_failed(slot, job, p).await,
        }
    }

    /// Before a measurement on a hardware bench: a faulted bench refuses; the
    /// calibration record in effect (a self-check is run first when the newest
    /// passing one was made with another calibration, or there is none).
    pub(super) async fn hardware_preflight<T>(
        &self,
        slot: &Slot,
        job: &Job,
        _spec: &T,
    ) -> StoreResult<Result<Option<CalibrationRecord>, JobProblem>> {
        if slot.cfg.kind == BenchKind::Virtual {
            return Ok(Ok(None));
        }
        let fault = slot.status.lock().unwrap().fault.clone();
        if let Some(f) = fault {
            return Ok(Err(JobProblem::new(ProblemKind::BenchFault,
                "Bench is faulted",
                format!(
                    "bench '{}' is faulted since {} ({}); run a self-check: POST /api/v1/benches/{}/self-check",
                    slot.cfg.id, f.since, f.detail, slot.cfg.id
                ),
            )));
        }
        if let Some(c) = self.store.latest_calibration(&slot.cfg.id).await? {
            if c.calibration == slot.cfg.calibration_document()
                && c.sensors == slot.cfg.sensors_document()
            {
                return Ok(Ok(Some(c)));
            }
        }
        Ok(self.self_check(slot, job).await?.map(Some))
    }
}
