//! The procedure on the job's blocking thread: the bench made for the job,
//! the observer that reports progress and live samples and stores each
//! finished repeat, the fit of every level and the level series.

use super::*;

pub(super) struct Done {
    pub(super) bench_time_s: f64,
    /// Wall time of the analyses (fits, judging) of the job's sweeps (s).
    pub(super) analysis_s: f64,
    /// Repeats measured, and those that fell back to the full procedure.
    pub(super) parts: u32,
    pub(super) fallbacks: u32,
    pub(super) log: Vec<String>,
    pub(super) warnings: Vec<String>,
    pub(super) recordings: Vec<NewRecording>,
    pub(super) measurements: Vec<NewMeasurement>,
    /// The result document of each measurement (index-aligned with
    /// `measurements`), typed until the repeat is stored: the series is
    /// attached to it and the MES messages read it, then it is serialized
    /// once into the measurement's `result`.
    pub(super) reports: Vec<Option<identify::Report>>,
    /// Verdict of each measurement under the job's recipe (by measurement id).
    pub(super) verdicts: Vec<(String, crate::qc::Verdict)>,
}

pub(super) enum Msg {
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
pub(super) struct Batch {
    pub(super) recordings: Vec<NewRecording>,
    pub(super) measurements: Vec<NewMeasurement>,
}

/// Live samples: about this many per second of signal, in chunks of `CHUNK`.
const LIVE_RATE_HZ: f64 = 1000.0;
const CHUNK: usize = 100;

pub(super) struct JobObserver {
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
    pub(super) fn new(
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
pub(super) fn make_bench(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    job_seq: i64,
    limits: crate::bench::Limits,
) -> Result<Box<dyn Bench>, String> {
    match cfg.kind {
        BenchKind::Virtual => virtual_bench(cfg, part, seed, limits),
        BenchKind::Hardware | BenchKind::Emulated => {
            hardware::open_bench(cfg, part, seed, job_seq, limits)
        }
    }
}

pub(super) fn virtual_bench(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    limits: crate::bench::Limits,
) -> Result<Box<dyn Bench>, String> {
    part.validate()?;
    let v = cfg.virtual_.unwrap_or_default();
    let mut b = crate::bench::virtual_bench::VirtualBench::new(part, seed)
        .with_limits(limits)
        .with_config(&v);
    b.id = cfg.id.clone();
    Ok(if v.paced {
        Box::new(crate::bench::procedure::pace::Paced::new(b))
    } else {
        Box::new(b)
    })
}

pub(super) fn procedure_stop(e: ProcedureError) -> Stop {
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
pub(super) fn execute(
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
    // The production procedure's reference: the golden units of the recipe.
    let golden = recipe.and_then(|r| r.procedure.golden.as_ref());
    let config = json!({"procedure": pcfg, "procedure_mode": spec.procedure.as_str(),
                        "analysis": opts, "limits": spec.limits,
                        "bench": bench_cfg.id, "seed": seed, "bench_description": bench.describe()});
    let mut done = Done {
        bench_time_s: 0.0,
        analysis_s: 0.0,
        parts: 0,
        fallbacks: 0,
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
        let outcome = match spec.procedure {
            crate::job::ProcedureMode::Full => procedure::run(bench.as_mut(), &pcfg, obs),
            crate::job::ProcedureMode::Production => {
                procedure::run_production(bench.as_mut(), &pcfg, golden, obs)
            }
        }
        .map_err(procedure_stop)?;
        if obs.cancelled() {
            return Err(Stop::Aborted);
        }
        let analysis_started = Instant::now();
        done.bench_time_s += outcome.bench_time_s;
        done.parts += 1;
        // What ran, for the result and the verdict's traceability.
        let procedure_run = json!({
            "mode": spec.procedure.as_str(),
            "fallback": outcome.production.as_ref().and_then(|p| p.fallback.clone()),
            "bench_time_s": outcome.bench_time_s,
        });
        if let Some(why) = outcome
            .production
            .as_ref()
            .and_then(|p| p.fallback.as_ref())
        {
            done.fallbacks += 1;
            let w = format!("production procedure fell back to the full procedure: {why}");
            done.warnings.push(if spec.repeats > 1 {
                format!("repeat {}: {w}", r + 1)
            } else {
                w
            });
        }
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
                    pre_drive_v: Some(outcome.pre_sweep.amplitude_v),
                    pre_q_drive_to_x: outcome.pre_q_drive_to_x,
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
            cfg_m["procedure_run"] = procedure_run.clone();
            cfg_m["narrow_sweep"] = json!({"drive_v": sweep.drive_v, "f_start_hz": sweep.f_start_hz,
                                           "f_end_hz": sweep.f_end_hz,
                                           "duration_s": sweep.sweep.duration_s});
            cfg_m["pre_sweep"] = json!({"drive_v": outcome.pre_sweep.amplitude_v,
                                        "f_start_hz": outcome.pre_sweep.f_start_hz,
                                        "f_end_hz": outcome.pre_sweep.f_end_hz,
                                        "duration_s": outcome.pre_sweep.duration_s,
                                        "q_drive_to_x": outcome.pre_q_drive_to_x});
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
        let analysis_s = analysis_started.elapsed().as_secs_f64();
        done.analysis_s += analysis_s;
        done.log.push(format!(
            "{}procedure {}: bench time {:.2} s, analysis {analysis_s:.2} s",
            if spec.repeats > 1 {
                format!("repeat {}: ", r + 1)
            } else {
                String::new()
            },
            spec.procedure.as_str(),
            outcome.bench_time_s
        ));
        for m in &mut done.measurements[first_measurement..] {
            m.config["procedure_run"]["analysis_s"] = json!(analysis_s);
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
pub(super) fn recording(
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
