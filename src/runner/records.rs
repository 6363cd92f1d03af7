//! The job's end: the verdicts (per measurement and for the job) with their
//! traceability, the MES messages, and the paths that end a job `failed` or
//! `interrupted` once the store can write (each in one transaction).

use super::*;

impl Runner {
    /// The recipe version a job names; Err (a message) when it is gone or changed.
    pub(super) async fn load_recipe(
        &self,
        r: &job::RecipeRef,
    ) -> StoreResult<Result<crate::qc::Recipe, String>> {
        // A body the recipe type cannot read is this job's failure (named),
        // not the store's.
        let row = match self.store.get_recipe(&r.name, Some(r.version)).await {
            Err(crate::store::StoreError::Corrupt(why)) => return Ok(Err(why)),
            other => other?,
        };
        let Some(row) = row else {
            return Ok(Err(format!(
                "recipe {} version {} is not stored",
                r.name, r.version
            )));
        };
        // Retired (by the center, pulled by the fleet worker, or here): it no
        // longer judges. A station that could not reach the center cannot
        // know of a retirement; its verdicts say `offline` (job_records).
        if row.retired {
            return Ok(Err(format!(
                "recipe {} version {} is retired: it no longer judges (submit the job again: it takes the newest version held)",
                r.name, r.version
            )));
        }
        Ok(if row.recipe.sha256() == r.sha256 {
            Ok(row.recipe)
        } else {
            Err(format!(
                "recipe {} version {} does not have the hash {} any more",
                r.name, r.version, r.sha256
            ))
        })
    }

    /// Verdicts (per measurement and for the job) with traceability, and the
    /// job's MES messages: written in the result transaction.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn job_records(
        &self,
        bench: &BenchConfig,
        job: &Job,
        spec: Option<&JobSpec>,
        bench_cal: Option<&crate::qc::BenchCalibrationTrace>,
        started_at: &str,
        state: JobState,
        prob: Option<&JobProblem>,
        meas: &[NewMeasurement],
        reports: &[Option<identify::Report>],
        verdicts: Vec<(String, crate::qc::Verdict)>,
    ) -> crate::store::qc::JobRecords {
        use crate::qc::{combine, invalid_job, Verdict};
        let finished_at = crate::store::now();
        let mut rec = crate::store::qc::JobRecords {
            webhooks: self.mes.targets(),
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
                prob.map_or("the job was interrupted", |p| &p.detail)
                    .to_string(),
            )),
            (Some(_), JobState::Failed) => Some(match prob {
                Some(p) => invalid_job(p.invalid_reason(), p.detail.clone()),
                None => invalid_job("job_failed", "the job failed".to_string()),
            }),
            (Some(_), _) => None,
        };
        if let (Some(r), Some(jv)) = (&rref, &job_verdict) {
            let fleet = self.recipe_trace.get().map(|f| f());
            let trace = |m: Option<&NewMeasurement>| crate::qc::VerdictTrace {
                software_version: crate::VERSION.to_string(),
                recipe: r.clone(),
                bench_id: bench.id.clone(),
                bench_kind: bench.kind.as_str().to_string(),
                bench_description: m.and_then(|m| m.config.bench_description.clone()),
                // full or production, and a production run's fall-back with its reason
                procedure: m.and_then(|m| m.config.procedure_run.clone()),
                // The virtual bench has no calibration record and no sensor identities;
                // hardware benches put theirs in the measurement's configuration.
                calibration: None,
                sensors: vec![],
                // The bench calibration from golden units the values were
                // judged with (decision 0049), or that there is none.
                bench_calibration: bench_cal.cloned(),
                submitted_by: spec.and_then(|s| s.submitted_by.clone()),
                job_created_at: job.created_at.clone(),
                job_started_at: started_at.to_string(),
                judged_at: finished_at.clone(),
                measurement_id: m.map(|m| m.id.clone()),
                purpose: spec.map(|s| s.purpose).unwrap_or_default(),
                fleet: fleet.clone(),
            };
            let verdict = |mid: Option<&String>, v: &Verdict, m: Option<&NewMeasurement>| {
                crate::store::qc::NewVerdict::judged(
                    new_id(),
                    Some(job.id.clone()),
                    mid.cloned(),
                    job.part_serial.clone(),
                    r,
                    v,
                    &trace(m),
                )
            };
            for (mid, v) in &verdicts {
                let m = meas.iter().find(|m| &m.id == mid);
                rec.verdicts.push(verdict(Some(mid), v, m));
            }
            rec.verdicts.push(verdict(None, jv, meas.first()));
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
                    procedure: m.config.procedure_run.as_ref().map(|run| {
                        let mode = run.mode.as_str();
                        match run.ended.as_ref().and_then(|e| e.fallback.as_deref()) {
                            None => mode.to_string(),
                            Some(f) => format!("{mode} (fell back to the full procedure: {f})"),
                        }
                    }),
                    verdict: verdicts.iter().find(|v| v.0 == m.id).map(|v| v.1.clone()),
                    values,
                }
            })
            .collect();
        let facts = crate::qc::cfx::JobFacts {
            job_id: job.id.clone(),
            part_serial: job.part_serial.clone(),
            source: self.mes.handle_of(&bench.id),
            started_at: started_at.to_string(),
            finished_at: finished_at.clone(),
            state: state.as_str().to_string(),
            recipe: rref.clone(),
            job_verdict,
            operator: spec.and_then(|s| s.submitted_by.clone()),
            measurements: tested,
        };
        for (uid, name, body) in crate::qc::cfx::job_messages(&facts) {
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
}

impl Runner {
    /// The job's `WorkStarted`, written with its start (decision 0096); the
    /// same message (UniqueID) its end writes again is kept once.
    pub(super) fn start_records(
        &self,
        bench: &BenchConfig,
        job: &Job,
        started_at: &str,
    ) -> crate::store::qc::JobRecords {
        let spec = job.request.measure();
        let facts = crate::qc::cfx::JobFacts {
            job_id: job.id.clone(),
            part_serial: job.part_serial.clone(),
            source: self.mes.handle_of(&bench.id),
            started_at: started_at.to_string(),
            finished_at: started_at.to_string(),
            state: "running".into(),
            recipe: spec.and_then(|s| s.recipe.clone()),
            job_verdict: None,
            operator: spec.and_then(|s| s.submitted_by.clone()),
            measurements: vec![],
        };
        let (unique_id, message_name, body) = crate::qc::cfx::work_started(&facts);
        crate::store::qc::JobRecords {
            webhooks: self.mes.targets(),
            messages: vec![crate::store::qc::NewMessage {
                unique_id,
                message_name,
                part_serial: job.part_serial.clone(),
                job_id: Some(job.id.clone()),
                body,
            }],
            ..Default::default()
        }
    }

    pub(super) async fn finish_failed(
        &self,
        slot: &Slot,
        job: &Job,
        p: JobProblem,
    ) -> StoreResult<()> {
        self.finish_failed_after(slot, job, &p, None, &[], &[])
            .await
    }

    /// Ends a running job `failed` with problem `p`, keeping what the bench
    /// did before (its time, log and warnings), with its verdict (`invalid`
    /// under a recipe) and its MES messages, and announces it. The one way
    /// every runner path fails a job. While the store cannot write (full
    /// disk), tried again until it can (or the daemon stops: the restart
    /// then ends the job `interrupted`).
    pub(super) async fn finish_failed_after(
        &self,
        slot: &Slot,
        job: &Job,
        p: &JobProblem,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
    ) -> StoreResult<()> {
        let ended = self
            .end_running_until_stored(slot, job, JobState::Failed, p, bench_time_s, log, warnings)
            .await?;
        if ended {
            let _ = self
                .events
                .publish(
                    Some(&job.id),
                    &JobEvent::Failed {
                        state: JobState::Failed,
                        problem: Some(p.clone()),
                    },
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
    pub(super) async fn end_running_until_stored(
        &self,
        slot: &Slot,
        job: &Job,
        state: JobState,
        p: &JobProblem,
        bench_time_s: Option<f64>,
        log: &[String],
        warnings: &[String],
    ) -> StoreResult<bool> {
        let spec = job.request.measure();
        let bench = &slot.cfg;
        let mut wait = Duration::from_millis(250);
        loop {
            let started_at = job.started_at.clone().unwrap_or_else(crate::store::now);
            let records = self.job_records(
                bench,
                job,
                spec,
                None,
                &started_at,
                state,
                Some(p),
                &[],
                &[],
                vec![],
            );
            let commit = self.store.end_running_job(
                &job.id,
                state,
                Some(p),
                bench_time_s,
                log,
                warnings,
                &records,
            );
            match self.commit_settled(slot, &job.id, commit).await {
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
    pub(super) async fn end_interrupted(&self, cfg: &Config) -> StoreResult<()> {
        let p = Store::interrupted_problem();
        for job in self.store.running_jobs().await? {
            let bench = cfg
                .benches
                .iter()
                .find(|b| b.id == job.bench_id)
                .cloned()
                // A bench no longer configured: its id, the defaults of the rest.
                .unwrap_or_else(|| BenchConfig {
                    id: job.bench_id.clone(),
                    kind: BenchKind::Virtual,
                    preset: crate::bench::settings::default_preset(),
                    seed: 0,
                    limits: crate::bench::settings::default_limits(),
                    hardware: None,
                    emulator: None,
                    virtual_: None,
                    ambient: None,
                });
            let spec = job.request.measure();
            let started_at = job.started_at.clone().unwrap_or_else(crate::store::now);
            let state = JobState::Interrupted;
            let records = self.job_records(
                &bench,
                &job,
                spec,
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
                    Some(&job.id),
                    &JobEvent::Interrupted {
                        state: JobState::Interrupted,
                        problem: p.clone(),
                        verdict,
                    },
                )
                .await?;
            tracing::warn!(job = %job.id, "job was running when the daemon stopped: marked interrupted");
        }
        Ok(())
    }
}

/// What a verdict's traceability says about the bench calibration it was
/// judged with (`None`: the bench has none for the recipe; `cal`: its
/// figures, None when its document did not read).
pub fn calibration_trace(
    row: Option<&crate::store::BenchCalibrationRow>,
    cal: Option<&crate::qc::BenchCalibration>,
) -> crate::qc::BenchCalibrationTrace {
    match row {
        None => crate::qc::BenchCalibrationTrace::none(),
        Some(r) => crate::qc::BenchCalibrationTrace::applied(
            &r.id,
            &r.state,
            &r.procedure,
            &r.created_at,
            cal,
        ),
    }
}
