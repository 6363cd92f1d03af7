//! [`EmulatedAudio`]: an audio device whose output drives the project's
//! physics and whose input captures what the bench's sensors would deliver:
//! microphone, the amplifier-output loopback through the divider, and the
//! analog laser, on one clock, `latency_s` after the output produced the drive
//! (half before the DAC, half after the ADC). Unpaced (as fast as the CPU).
//!
//! Faults are injected for real where a device would show them: a stream
//! error from `read`, a part slipping in its clamp (the laser sees it), and
//! every run can leave a trace of what the DAC played (`trace_dir`), which the
//! tests use to measure how fast the drive reached zero.
//!
//! A long-term test's emulated part ages ([`EmulatedAudio::with_ageing`],
//! decision 0135): sample by sample with its true load, as the virtual
//! bench's part does.

use crate::audio::{AudioError, AudioIo, DriveSource};
use crate::settings::{
    Calibration, ChannelMap, EmulatorConfig, FaultKind, FaultPlan, HardwareConfig, LaserConfig,
};
use crate::true_part::TrueLoad;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use springbench_core::physics::ageing::AgeingStep;
use springbench_core::physics::model::{idx, BenchParams, Integrator, Model};
use springbench_core::physics::PartSpec;
use std::collections::VecDeque;

/// How far the part slips in its clamp in a `part_slips` fault (m), and how fast (s).
pub const SLIP_M: f64 = 0.03;
pub const SLIP_TIME_S: f64 = 0.02;

/// Receives the true displacement (m) at every DAC sample, in blocks, with
/// the input-clock time (s) of the block's first sample: the time at which
/// the emulated input converter samples that instant (the clock runs on
/// across sweeps, so a serial laser emulator sees one continuous trajectory).
pub type DisplacementTap = Box<dyn FnMut(f64, &[f64]) + Send>;

/// Called when an injected laser fault ([`FaultKind::LaserUnplugged`],
/// [`FaultKind::LaserGarbage`]) is due: the serial laser emulator acts on it.
pub type LaserFaultHook = Box<dyn FnMut(FaultKind) + Send>;

/// A physics-backed audio device.
pub struct EmulatedAudio {
    fs: f64,
    block: usize,
    in_channels: usize,
    map: ChannelMap,
    cal: Calibration,
    laser: LaserConfig,
    emu: EmulatorConfig,
    part: PartSpec,
    bench: BenchParams,
    /// Job sequence number (selects the injected faults) and the bench's displacement limit (for the trace).
    job_seq: i64,
    limit_m: f64,
    out_lat: usize,
    in_lat: usize,
    seed: u64,
    sweep: u32,
    run: Option<Run>,
    /// Receives the true displacement (m) at every DAC sample (serial laser emulators).
    tap: Option<DisplacementTap>,
    laser_fault_hook: Option<LaserFaultHook>,
    /// DAC samples stepped since the device was made (all runs): the emulated converter clock.
    clock_k: u64,
    /// The part ages (its `ageing` parameters) with this true load, carried
    /// from run to run ([`Self::with_ageing`]); None: it stays as it is.
    ageing: Option<TrueLoad>,
}

/// State of one started stream pair.
struct Run {
    drive: DriveSource,
    sim: Integrator,
    rng: ChaCha8Rng,
    dac_line: VecDeque<f32>,
    adc_line: VecDeque<f32>,
    /// Last DAC sample (amplifier V) and the number played.
    u_prev: f64,
    dac_k: usize,
    /// Captured frames handed out.
    adc_k: usize,
    fault: Option<(FaultKind, usize)>,
    stream_error_sent: bool,
    /// DAC output (amplifier V) of the whole run, and the first sample beyond the limit.
    played_v: Vec<f32>,
    event_sample: Option<usize>,
    /// First DAC sample produced after the bench asked for the ramp-down.
    abort_sample: Option<usize>,
    x_tap: Vec<f64>,
    /// True |x| at every DAC sample of the run (m), for the trace.
    x_abs_m: Vec<f32>,
    /// Converter clock (`clock_k`) of the first sample in `x_tap`.
    x_tap_k: u64,
    /// Converter clock at the run's first sample.
    clock_k0: u64,
    /// Wall-clock start (paced runs) and, after every captured block, (Unix
    /// time in s, DAC samples played): lets a test put a wall-clock event
    /// (a cancel request) on the emulated output.
    started: std::time::Instant,
    clock_log: Vec<(f64, usize)>,
    /// The part's ageing over this run (its load counted sample by sample).
    ageing: Option<AgeingStep>,
}

impl EmulatedAudio {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        hw: &HardwareConfig,
        emu: &EmulatorConfig,
        part: PartSpec,
        seed: u64,
        job_seq: i64,
        limit_m: f64,
    ) -> EmulatedAudio {
        let fs = hw.sample_rate_hz as f64;
        let lat = (emu.latency_s * fs).round() as usize;
        let bench = BenchParams {
            sample_rate_hz: fs,
            ..BenchParams::default()
        };
        EmulatedAudio {
            fs,
            block: hw.buffer_frames as usize,
            in_channels: hw.input_channels as usize,
            map: hw.channels,
            cal: hw.calibration.clone(),
            laser: hw.laser.clone(),
            emu: emu.clone(),
            part,
            bench,
            job_seq,
            limit_m,
            out_lat: lat / 2,
            in_lat: lat - lat / 2,
            seed,
            sweep: 0,
            run: None,
            tap: None,
            laser_fault_hook: None,
            clock_k: 0,
            ageing: None,
        }
    }

    /// Ages the mounted part as the virtual bench does
    /// (`VirtualBench::with_ageing`): every sample adds its load
    /// `|F_el(x) v| / fs` to `load`, K(x) near rest falls with it, and the
    /// state carries over from one run to the next. `load` is shared: the
    /// caller reads the part's true load from it (and may hand it to the
    /// next emulator of the same part, decision 0135).
    pub fn with_ageing(mut self, load: TrueLoad) -> EmulatedAudio {
        self.ageing = Some(load);
        self
    }

    /// Hands the part's load so far to the shared [`TrueLoad`].
    fn publish_load(&self) {
        if let (Some(t), Some(a)) = (
            &self.ageing,
            self.run.as_ref().and_then(|r| r.ageing.as_ref()),
        ) {
            t.set(a.load_j());
        }
    }

    /// Hands the true displacement at every DAC sample to `tap` (e.g. a serial laser emulator).
    pub fn set_displacement_tap(&mut self, tap: DisplacementTap) {
        self.tap = Some(tap);
    }

    /// Lets `hook` act on the injected laser faults when they are due.
    pub fn set_laser_fault_hook(&mut self, hook: LaserFaultHook) {
        self.laser_fault_hook = Some(hook);
    }

    /// Hands the displacement stepped so far to the tap.
    fn flush_tap(&mut self) {
        let (Some(tap), Some(run)) = (self.tap.as_mut(), self.run.as_mut()) else {
            return;
        };
        if !run.x_tap.is_empty() {
            tap(
                (run.x_tap_k + self.in_lat as u64) as f64 / self.fs,
                &run.x_tap,
            );
            run.x_tap_k += run.x_tap.len() as u64;
            run.x_tap.clear();
        }
    }

    /// Output-to-input latency in samples.
    pub fn latency_samples(&self) -> usize {
        self.out_lat + self.in_lat
    }

    /// One DAC sample through the physics and the sensors into the ADC line.
    fn step(&mut self) {
        let run = self.run.as_mut().expect("started");
        // Output buffer: produced now, played out_lat samples later.
        if run.abort_sample.is_none() && run.drive.shared().aborted() {
            run.abort_sample = Some(run.dac_k + run.dac_line.len());
        }
        run.dac_line.push_back(run.drive.next_sample());
        let dac = run.dac_line.pop_front().unwrap_or(0.0) as f64;
        let u = dac * self.cal.dac_full_scale_v * self.cal.amplifier_gain;
        let k = run.dac_k;
        if k > 0 {
            run.sim.step(run.u_prev, u);
            if let Some(a) = run.ageing.as_mut() {
                a.after_step(&mut run.sim, self.fs);
            }
        }
        run.u_prev = u;
        run.dac_k += 1;
        self.clock_k += 1;
        run.played_v.push(u as f32);
        let mut x = run.sim.state[idx::X];
        if let Some((FaultKind::PartSlips, at)) = run.fault {
            if k >= at {
                x += SLIP_M * ((k - at) as f64 / (SLIP_TIME_S * self.fs)).min(1.0);
            }
        }
        run.x_abs_m.push(run.sim.state[idx::X].abs() as f32);
        if run.event_sample.is_none() && x.abs() > self.limit_m {
            run.event_sample = Some(k);
        }
        if let Some((kind @ (FaultKind::LaserUnplugged | FaultKind::LaserGarbage), at)) = run.fault
        {
            if k == at {
                run.event_sample = Some(k);
                if let Some(h) = self.laser_fault_hook.as_mut() {
                    h(kind);
                }
            }
        }
        if self.tap.is_some() {
            run.x_tap.push(x);
        }
        let p = run.sim.state[idx::P];
        let adc = self.cal.adc_full_scale_v;
        let q = |v: f64| (v / adc).clamp(-1.0, 1.0) as f32;
        let mic = (p + self.emu.mic_noise_pa * run.rng.sample::<f64, _>(StandardNormal))
            * self.cal.mic_sensitivity_v_per_pa;
        let mut frame = vec![0.0f32; self.in_channels];
        let mut put = |ch: u16, v: f32| {
            if let Some(s) = frame.get_mut(ch as usize) {
                *s = v;
            }
        };
        put(self.map.microphone, q(mic));
        put(self.map.loopback, q(u * self.cal.loopback_divider));
        match &self.laser {
            LaserConfig::Analog {
                scale_m_per_v,
                offset_m,
                range_m,
                ..
            } => {
                let xm = x + self.emu.laser_noise_m * run.rng.sample::<f64, _>(StandardNormal);
                // Beyond its range the sensor's output sits just past the range end.
                let xr = xm.clamp(-1.02 * range_m, 1.02 * range_m);
                put(self.map.laser, q((xr - offset_m) / scale_m_per_v));
            }
            // The serial laser emulator samples x through the tap.
            LaserConfig::Serial(_) => {}
        }
        run.adc_line.extend(frame);
    }

    fn write_trace(&self, run: &Run) {
        let Some(dir) = &self.emu.trace_dir else {
            return;
        };
        let last_nonzero = run.played_v.iter().rposition(|u| u.abs() > 1e-6);
        let first_nonzero = run.played_v.iter().position(|u| u.abs() > 1e-6);
        let peak = |a: usize, b: usize| {
            run.x_abs_m
                .get(a..b.min(run.x_abs_m.len()))
                .map_or(0.0, |s| s.iter().fold(0.0f32, |m, x| m.max(*x)))
        };
        // The second half of the drive's span but its last 0.3 s: a held
        // chunk's steady sine, after its glide, before its fade.
        let held = first_nonzero.zip(last_nonzero).map(|(a, b)| {
            let end = b.saturating_sub((0.3 * self.fs) as usize);
            peak((a + b) / 2, end.max((a + b) / 2))
        });
        let fault_sample = run.fault.map(|(_, s)| s);
        let event = match run.fault {
            Some((
                FaultKind::PartSlips | FaultKind::LaserUnplugged | FaultKind::LaserGarbage,
                _,
            )) => run.event_sample,
            Some((FaultKind::AudioStreamError, s)) if run.stream_error_sent => Some(s),
            _ => None,
        };
        // The drive's last 2 ms before it reached zero: a ramp fades it, a cut ends it at level.
        let tail_peak = last_nonzero.map(|l| {
            let a = l.saturating_sub((0.002 * self.fs) as usize);
            run.played_v[a..=l]
                .iter()
                .fold(0.0f32, |m, u| m.max(u.abs()))
        });
        let doc = serde_json::json!({
            "job_seq": self.job_seq,
            "sweep": self.sweep,
            "sample_rate_hz": self.fs,
            "frames_played": run.played_v.len(),
            "fault": run.fault.map(|(k, _)| k),
            "fault_sample": fault_sample,
            "event_sample": event,
            "last_nonzero_drive_sample": last_nonzero,
            // From the first to the last nonzero drive sample (s).
            "drive_span_s": first_nonzero.zip(last_nonzero).map(|(a, b)| (b - a) as f64 / self.fs),
            // The part's true largest excursion in the run (m).
            "x_true_peak_m": peak(0, run.x_abs_m.len()),
            "x_true_peak_held_m": held,
            // Its true load after the run (J), when it ages.
            "true_load_j": run.ageing.as_ref().map(AgeingStep::load_j),
            "abort_sample": run.abort_sample,
            "last_2ms_peak_drive_v": tail_peak,
            "peak_drive_v": run.played_v.iter().fold(0.0f32, |a, u| a.max(u.abs())),
            "latency_samples": self.latency_samples(),
            "paced": self.emu.paced,
            "clock": run.clock_log,
        });
        let _ = std::fs::create_dir_all(dir);
        let path = dir.join(format!("run-{}-{}.json", self.job_seq, self.sweep));
        let _ = std::fs::write(path, doc.to_string());
    }
}

impl AudioIo for EmulatedAudio {
    fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    fn input_channels(&self) -> usize {
        self.in_channels
    }

    fn start(&mut self, drive: DriveSource) -> Result<(), AudioError> {
        self.part.validate().map_err(AudioError::Open)?;
        self.sweep += 1;
        let sweep = self.sweep;
        let fault = self
            .emu
            .faults
            .iter()
            .find(|f: &&FaultPlan| f.job_seq == self.job_seq && f.sweep == sweep)
            .map(|f| (f.kind, (f.at_s * self.fs).round() as usize));
        let mut sim = Integrator::new(Model::new(&self.part, &self.bench), self.fs, 1);
        let ageing = self
            .ageing
            .as_ref()
            .map(|t| AgeingStep::start(self.part.ageing, t.get(), &mut sim.model));
        let rng = ChaCha8Rng::seed_from_u64(
            self.seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(sweep as u64),
        );
        self.run = Some(Run {
            drive,
            sim,
            rng,
            dac_line: VecDeque::from(vec![0.0; self.out_lat]),
            adc_line: VecDeque::from(vec![0.0; self.in_lat * self.in_channels]),
            u_prev: 0.0,
            dac_k: 0,
            adc_k: 0,
            fault,
            stream_error_sent: false,
            played_v: Vec::new(),
            event_sample: None,
            abort_sample: None,
            x_tap: Vec::new(),
            x_abs_m: Vec::new(),
            x_tap_k: self.clock_k,
            clock_k0: self.clock_k,
            started: std::time::Instant::now(),
            clock_log: Vec::new(),
            ageing,
        });
        Ok(())
    }

    fn read(&mut self, out: &mut Vec<f32>) -> Result<(), AudioError> {
        let Some(run) = self.run.as_mut() else {
            return Err(AudioError::Stream("stream not started".into()));
        };
        if let Some((FaultKind::AudioStreamError, at)) = run.fault {
            if !run.stream_error_sent && run.adc_k + self.block > at {
                run.stream_error_sent = true;
                // Output keeps playing what it had (as a real output stream would) until stopped.
                return Err(AudioError::Stream(
                    "The requested device is no longer available (emulated unplug)".into(),
                ));
            }
        }
        if self.emu.paced {
            // A real device delivers the block when its last frame was converted.
            let due = run.started
                + std::time::Duration::from_secs_f64((run.adc_k + self.block) as f64 / self.fs);
            let now = std::time::Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        for _ in 0..self.block {
            self.step();
        }
        let run = self.run.as_mut().expect("started");
        let n = self.block * self.in_channels;
        out.extend(run.adc_line.drain(..n));
        run.adc_k += self.block;
        let unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        run.clock_log.push((unix_s, run.dac_k));
        self.flush_tap();
        self.publish_load();
        Ok(())
    }

    fn stop(&mut self, timeout_s: f64) {
        if self.run.is_none() {
            return;
        }
        // The output runs on until the ramp is through and out of the output buffer.
        let max = (timeout_s * self.fs) as usize;
        let (mut steps, mut silent_steps) = (0usize, 0usize);
        while steps < max {
            if self.run.as_ref().expect("started").drive.shared().silent() {
                silent_steps += 1;
                if silent_steps > self.out_lat {
                    break;
                }
            }
            self.step();
            steps += 1;
        }
        self.flush_tap();
        self.publish_load();
        let run = self.run.take().expect("started");
        self.write_trace(&run);
    }

    fn input_clock(&self) -> Option<(u32, u64)> {
        // One clock for the device's life: captured frame j of a run is
        // converter sample clock_k0 + j (the input line delays by in_lat what
        // the physics did in_lat samples before).
        self.run.as_ref().map(|r| (0, r.clock_k0))
    }

    fn describe(&self) -> String {
        format!(
            "emulated audio ({} Hz, latency {} samples, part '{}')",
            self.fs,
            self.latency_samples(),
            self.part.name
        )
    }
}
