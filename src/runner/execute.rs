//! The procedure on the job's blocking thread: the bench made for the job,
//! the observer that reports progress and live samples and stores each
//! finished repeat, the fit of every level and the level series.

use super::*;
use crate::job::{
    HardwareRecord, MeasurementConfig, PreSweepSettings, ProcedureRun, RepeatEnded, SweepSettings,
};

pub(super) struct Done {
    pub(super) bench_time_s: f64,
    /// Wall time of the analyses (fits, judging) of the job's sweeps (s).
    pub(super) analysis_s: f64,
    /// Repeats measured, and those that fell back to the full procedure.
    pub(super) parts: u32,
    pub(super) fallbacks: u32,
    pub(super) log: Vec<String>,
    pub(super) warnings: Vec<String>,
    /// The job's measurements, stored as each level finished; kept without
    /// their result document.
    pub(super) measurements: Vec<NewMeasurement>,
    /// The result document of each measurement (index-aligned with
    /// `measurements`), typed: the series is attached to it when its repeat
    /// ends (and the stored result replaced), and the MES messages read it.
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
    Samples(super::JobEvent),
    /// A finished level's recordings and measurement, to be stored now (a
    /// cancel, a failure or a crash later keeps them; the job holds only
    /// their light results), or a finished repeat's completed documents;
    /// the reply carries the new recordings' ids, or why nothing was stored.
    Store(Batch, std::sync::mpsc::SyncSender<Result<Vec<i64>, String>>),
}

/// Recordings and the measurements that index into them (`pre`, `main`:
/// into `known`, recordings stored before, then `recordings`), and
/// replaced documents of stored measurements (id, config, result).
#[derive(Default)]
pub(super) struct Batch {
    pub(super) known: Vec<i64>,
    pub(super) recordings: Vec<NewRecording>,
    pub(super) measurements: Vec<NewMeasurement>,
    pub(super) updates: Vec<(String, MeasurementConfig, Option<identify::Report>)>,
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

    /// Has a finished level or repeat stored (waits for the store's
    /// answer: the new recordings' ids).
    fn store(&self, batch: Batch) -> Result<Vec<i64>, Stop> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let failed = |e: String| {
            Stop::Failed(JobProblem::new(
                ProblemKind::Storage,
                "Results not stored",
                format!("storing the measurements of a finished level failed: {e}"),
            ))
        };
        self.tx
            .send(Msg::Store(batch, tx))
            .map_err(|_| failed("the job's task is gone".into()))?;
        match rx.recv() {
            Ok(Ok(ids)) => Ok(ids),
            Ok(Err(e)) => Err(failed(e)),
            Err(_) => Err(failed("no answer from the store".into())),
        }
    }

    fn flush_samples(&mut self) {
        if self.buf_x.is_empty() {
            return;
        }
        let dt = self.decim as f64 / self.sample_rate_hz;
        let data = super::JobEvent::Samples {
            step: step_name(self.buf_step),
            t0_s: self.buf_t0,
            dt_s: dt,
            x_m: std::mem::take(&mut self.buf_x),
            microphone_v: std::mem::take(&mut self.buf_p),
        };
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
            hardware::open_bench(cfg, part, seed, job_seq, limits, None)
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
        ProcedureError::Invalid(m) => Stop::Failed(JobProblem::new(
            ProblemKind::ProcedureInvalid,
            "Procedure configuration refused",
            &m,
        )),
        ProcedureError::Bench(crate::bench::BenchError::Fault(m)) => Stop::Failed(JobProblem::new(
            ProblemKind::BenchFault,
            "Bench fault: the drive was ramped to zero",
            &m,
        )),
        ProcedureError::Bench(e) => Stop::Failed(JobProblem::new(
            ProblemKind::Bench,
            "Bench failed",
            e.to_string(),
        )),
        ProcedureError::Failed(m) => Stop::Failed(JobProblem::new(
            ProblemKind::Procedure,
            "Procedure failed",
            &m,
        )),
    }
}

/// Runs a job on its own blocking thread: the procedure per repeat; each
/// level is fitted, judged and stored as its narrow sweep finishes
/// ([`Repeat`]), the level series once the repeat's last level is in.
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
    bench_cal: Option<&crate::qc::BenchCalibration>,
    obs: &mut JobObserver,
) -> Result<Done, Stop> {
    let part = job::mounted_part(spec, bench_cfg)
        .map_err(|e| Stop::Failed(JobProblem::new(ProblemKind::Part, "Part not available", &e)))?;
    let mut bench = make_bench(bench_cfg, part, seed, job_seq, spec.limits).map_err(|e| {
        Stop::Failed(JobProblem::new(
            ProblemKind::Bench,
            "Bench not available",
            &e,
        ))
    })?;
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
    // The short sweeps do not reveal the effects the diagnostics size (the
    // full procedure found 0.25 N of friction on 5 of 5 parts, production
    // on 0; docs/qc.md): a recipe that judges an effect size gets the full
    // procedure, said as a fall-back in the result and the traceability.
    let effect_judged = recipe.is_some_and(|r| r.needs_diagnostics());
    // What every measurement of the job was made with; each level adds its
    // sweeps (and a hardware bench's record), each repeat what ran.
    let config = MeasurementConfig {
        analysis: Some(opts.clone()),
        procedure: Some(pcfg.clone()),
        procedure_mode: Some(spec.procedure),
        procedure_run: None,
        limits: Some(spec.limits),
        bench: Some(bench_cfg.id.clone()),
        bench_description: Some(bench.describe()),
        seed: Some(seed),
        narrow_sweep: None,
        pre_sweep: None,
        hardware: None,
        other: Default::default(),
    };
    let mut done = Done {
        bench_time_s: 0.0,
        analysis_s: 0.0,
        parts: 0,
        fallbacks: 0,
        log: vec![],
        warnings: vec![],
        measurements: vec![],
        reports: vec![],
        verdicts: vec![],
    };
    let tagged = |r: u32, l: String| {
        if spec.repeats > 1 {
            format!("repeat {}: {l}", r + 1)
        } else {
            l
        }
    };
    for r in 0..spec.repeats {
        obs.repeat = r;
        let first_measurement = done.measurements.len();
        let mut rep = Repeat {
            obs: &mut *obs,
            job_id,
            spec,
            bench_id: &bench_cfg.id,
            calibration,
            recipe,
            bench_cal,
            opts: &opts,
            config: &config,
            repeat: r,
            runs_before: bench.run_records().len(),
            want_series: spec.levels_m.len() >= 2,
            done: &mut done,
            pre_id: None,
            series_in: vec![],
            log: vec![],
            analysis_s: 0.0,
            stop: None,
        };
        let outcome = match spec.procedure {
            crate::job::ProcedureMode::Full => procedure::run(bench.as_mut(), &pcfg, &mut rep),
            crate::job::ProcedureMode::Production if effect_judged => {
                procedure::production::run_full_instead(
                    bench.as_mut(),
                    &pcfg,
                    &mut rep,
                    "the recipe judges an effect size, which the production procedure's short sweeps do not reveal (docs/qc.md, Effect sizes)".into(),
                )
            }
            crate::job::ProcedureMode::Production => {
                procedure::run_production(bench.as_mut(), &pcfg, golden, &mut rep)
            }
        };
        let Repeat {
            stop,
            series_in,
            log: level_log,
            analysis_s: levels_analysis_s,
            ..
        } = rep;
        if let Some(stop) = stop {
            return Err(stop);
        }
        // The pre-measurement (stored with the first level) is dropped
        // here, not held through the joint fit (19 MB at 48 kHz).
        let procedure::Outcome {
            narrow,
            bench_time_s,
            log,
            production,
            ..
        } = outcome.map_err(procedure_stop)?;
        if obs.cancelled() {
            return Err(Stop::Aborted);
        }
        if !narrow.is_empty() {
            return Err(Stop::Failed(JobProblem::new(
                ProblemKind::Procedure,
                "Procedure failed",
                "the procedure kept narrow sweeps it did not hand out",
            )));
        }
        let analysis_started = Instant::now();
        done.bench_time_s += bench_time_s;
        done.parts += 1;
        if let Some(why) = production.as_ref().and_then(|p| p.fallback.as_ref()) {
            done.fallbacks += 1;
            let w = format!("production procedure fell back to the full procedure: {why}");
            done.warnings.push(tagged(r, w));
        }
        done.log.extend(log.iter().map(|l| tagged(r, l.clone())));
        done.log.extend(level_log);
        if spec.levels_m.len() >= 2 {
            // A level series (two or more levels) ends with the joint fit
            // over its levels (`series`): each analysed level's force-balance data.
            obs.send_progress(Step::Fit, obs.overall(0.99), 0.0);
            // The levels' FFT plans and buffers are not the joint fit's.
            crate::dsp::spectrum::release_thread_buffers();
            let log = series::attach(
                &mut done.reports[first_measurement..],
                first_measurement,
                series_in,
                spec.order,
            );
            done.log.extend(log.into_iter().map(|l| tagged(r, l)));
        }
        let analysis_s = levels_analysis_s + analysis_started.elapsed().as_secs_f64();
        done.analysis_s += analysis_s;
        done.log.push(tagged(
            r,
            format!(
                "procedure {}: bench time {:.2} s, analysis {analysis_s:.2} s",
                spec.procedure.as_str(),
                bench_time_s
            ),
        ));
        // What ran, for the result and the verdict's traceability; the
        // levels were stored as they finished, their documents are completed now.
        let procedure_run = ProcedureRun {
            mode: spec.procedure,
            ended: Some(RepeatEnded {
                fallback: production.as_ref().and_then(|p| p.fallback.clone()),
                bench_time_s,
                analysis_s,
            }),
        };
        let mut updates = vec![];
        for (m, rep) in done.measurements[first_measurement..]
            .iter_mut()
            .zip(&done.reports[first_measurement..])
        {
            m.config.procedure_run = Some(procedure_run.clone());
            // checked finite when fitted (and the series before it was attached)
            updates.push((m.id.clone(), m.config.clone(), rep.clone()));
        }
        obs.flush_samples();
        obs.store(Batch {
            updates,
            ..Batch::default()
        })?;
        give_back_freed_memory();
    }
    Ok(done)
}

/// One repeat of a job as the procedure runs it: each level's narrow sweep
/// is fitted, judged and stored (recordings, measurement) the moment the
/// procedure hands it out, and its samples are dropped. A series of 16
/// levels holds one level's samples at a time, and a cancel or a crash keeps
/// every finished level.
struct Repeat<'a> {
    obs: &'a mut JobObserver,
    job_id: &'a str,
    spec: &'a JobSpec,
    bench_id: &'a str,
    calibration: Option<&'a crate::store::hardware::CalibrationRecord>,
    recipe: Option<&'a crate::qc::Recipe>,
    /// The bench's calibration under the recipe: the verdicts judge the
    /// corrected values (decision 0049); the stored result stays as measured.
    bench_cal: Option<&'a crate::qc::BenchCalibration>,
    opts: &'a AnalyzeOptions,
    config: &'a MeasurementConfig,
    repeat: u32,
    /// The bench's run records before this repeat (hardware traceability).
    runs_before: usize,
    want_series: bool,
    done: &'a mut Done,
    /// Id of this repeat's stored pre-measurement recording.
    pre_id: Option<i64>,
    series_in: Vec<series::Level>,
    log: Vec<String>,
    /// Wall time of the level analyses (s).
    analysis_s: f64,
    /// Why the job must stop (storing failed).
    stop: Option<Stop>,
}

impl Observer for Repeat<'_> {
    fn progress(&mut self, step: Step, progress: f64, eta_s: f64) {
        self.obs.progress(step, progress, eta_s)
    }

    fn samples(&mut self, step: Step, block: crate::bench::Block<'_>) {
        self.obs.samples(step, block)
    }

    fn cancelled(&self) -> bool {
        self.obs.cancelled()
    }

    fn narrow_finished(
        &mut self,
        bench: &dyn Bench,
        pre: &procedure::PreMeasured<'_>,
        index: usize,
        sweep: procedure::NarrowSweep,
    ) -> Result<Option<procedure::NarrowSweep>, ProcedureError> {
        let t = Instant::now();
        let r = self.level(bench, pre, index, sweep);
        self.analysis_s += t.elapsed().as_secs_f64();
        match r {
            Ok(()) => Ok(None),
            Err(stop) => {
                let why = match &stop {
                    Stop::Failed(p) => p.detail.clone(),
                    Stop::Aborted => "aborted".into(),
                };
                self.stop = Some(stop);
                Err(ProcedureError::Failed(why))
            }
        }
    }
}

impl Repeat<'_> {
    fn tag(&self, l: String) -> String {
        if self.spec.repeats > 1 {
            format!("repeat {}: {l}", self.repeat + 1)
        } else {
            l
        }
    }

    /// Fits, judges and stores level `li`.
    fn level(
        &mut self,
        bench: &dyn Bench,
        pre: &procedure::PreMeasured<'_>,
        li: usize,
        sweep: procedure::NarrowSweep,
    ) -> Result<(), Stop> {
        let spec = self.spec;
        let opts = self.opts;
        let procedure::NarrowSweep {
            target_xpeak_m,
            drive_v,
            f_start_hz,
            f_end_hz,
            sweep: narrow_spec,
            signals,
            warning,
            ..
        } = sweep;
        let mut meta = Meta::standard(spec.moving_mass_kg, pre.signals.sample_rate_hz);
        meta.channels.drive = pre.signals.drive_v.as_ref().map(|_| 2);
        // The level's sweeps as the analysis reads them: the repeat's
        // pre-measurement borrowed, not copied into each level's set.
        let sweeps = identify::Sweeps {
            moving_mass_kg: meta.moving_mass_kg,
            pre: pre.signals,
            main: &signals,
        };
        if let Some(w) = &warning {
            let w = self.tag(w.clone());
            self.done.warnings.push(w);
        }
        let hw_record = self.calibration.map(|c| {
            HardwareRecord::of_level(
                &c.id,
                &c.calibration,
                &c.sensors,
                &bench.run_records()[self.runs_before..],
                pre.signals.len(),
                signals.len(),
                li,
            )
        });
        let not_aligned = hw_record
            .as_ref()
            .and_then(HardwareRecord::alignment_invalid);
        let out = crate::qc::level::measure_level(crate::qc::level::Level {
            sweeps,
            meta: &meta,
            opts,
            level_index: li,
            target_xpeak_m,
            warning,
            not_fitted: not_aligned,
            keep_force_balance: self.want_series,
            recipe: self.recipe,
            bench_cal: self.bench_cal,
            drive_v,
            max_drive_v: spec.limits.max_drive_v,
            pre_drive_v: pre.sweep.amplitude_v,
            pre_q_drive_to_x: pre.q_drive_to_x,
        });
        for l in out.log {
            let l = self.tag(l);
            self.log.push(l);
        }
        let mid = new_id();
        if let Some(v) = out.verdict {
            self.done.verdicts.push((mid.clone(), v));
        }
        let (report, analysis_error) = (out.report, out.analysis_error);
        if let Some(data) = out.force_balance {
            self.series_in.push(series::Level {
                measurement: self.done.measurements.len(),
                measurement_id: mid.clone(),
                target_xpeak_m,
                data,
            });
        }
        let res = bench.resolution();
        let known: Vec<i64> = self.pre_id.into_iter().collect();
        let mut recordings = vec![];
        if self.pre_id.is_none() {
            recordings.push(recording("pre", pre.signals, res.as_ref())?);
        }
        recordings.push(recording("main", &signals, res.as_ref())?);
        let cfg_m = MeasurementConfig {
            // completed with the bench and analysis time when the repeat ends
            procedure_run: Some(ProcedureRun {
                mode: spec.procedure,
                ended: None,
            }),
            narrow_sweep: Some(SweepSettings {
                drive_v,
                f_start_hz,
                f_end_hz,
                duration_s: Some(narrow_spec.duration_s),
            }),
            pre_sweep: Some(PreSweepSettings {
                sweep: SweepSettings {
                    drive_v: pre.sweep.amplitude_v,
                    f_start_hz: pre.sweep.f_start_hz,
                    f_end_hz: pre.sweep.f_end_hz,
                    duration_s: Some(pre.sweep.duration_s),
                },
                q_drive_to_x: pre.q_drive_to_x,
            }),
            hardware: hw_record,
            ..self.config.clone()
        };
        let mut m = NewMeasurement {
            id: mid,
            part_serial: spec.part.serial.clone(),
            job_id: Some(self.job_id.to_string()),
            source: "bench",
            bench_id: Some(self.bench_id.to_string()),
            config: cfg_m,
            meta: Doc::Made(meta),
            // checked finite above
            result: report.clone().map(Doc::Made),
            analysis_error,
            target_xpeak_m: Some(target_xpeak_m),
            repeat_index: Some(self.repeat as i64),
            level_index: Some(li as i64),
            pre: 0,
            main: known.len() + recordings.len() - 1,
        };
        drop(signals);
        self.obs.flush_samples();
        let ids = self.obs.store(Batch {
            known,
            recordings,
            measurements: vec![m.clone()],
            updates: vec![],
        })?;
        if self.pre_id.is_none() {
            self.pre_id = ids.first().copied();
        }
        // The job keeps the light part (the records and MES messages read it).
        m.result = None;
        self.done.measurements.push(m);
        self.done.reports.push(report);
        give_back_freed_memory();
        Ok(())
    }
}

/// Has glibc map every allocation of 1 MiB or more on its own and unmap it
/// when freed. By default glibc raises that threshold to the size of the
/// largest block freed (up to 32 MiB), after which a job's multi-megabyte
/// signals, spectra and design columns come from its heaps, and what they
/// free between two trims stays resident: a 16-level series' joint fit held
/// about 50 MB above its live heap. The numbers do not change; each large
/// buffer costs its page faults, as after [`give_back_freed_memory`] anyway.
pub(super) fn map_large_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation thresholds.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

/// Returns the heap glibc keeps after a level's analysis (its signals,
/// spectra and fit buffers, tens of MB, freed but held by the allocator's
/// arenas) to the system, so that a long series does not keep its resident
/// memory at the peak of its largest level.
fn give_back_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free memory of glibc's heaps.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// A recording as the store keeps it: at the bench's resolution (FLAC, bit
/// for bit what was captured), or float32 WAV when the bench declares none.
pub(super) fn recording(
    kind: &'static str,
    s: &crate::recording::Signals,
    res: Option<&crate::recording::codec::Resolution>,
) -> Result<NewRecording, Stop> {
    let stored = crate::recording::codec::encode_capture(s, res).map_err(|e| {
        Stop::Failed(JobProblem::new(
            ProblemKind::Recording,
            "Recording could not be stored losslessly",
            e.to_string(),
        ))
    })?;
    Ok(NewRecording {
        kind,
        sample_rate_hz: s.sample_rate_hz,
        frames: s.len() as i64,
        stored,
    })
}
