//! [`HardwareBench`]: the [`Bench`] of a real (or emulated) bench. It turns
//! the drive into DAC numbers, plays it through the [`AudioIo`] output while
//! capturing microphone, loopback and analog laser on one input converter,
//! checks every captured block against the limits, and aligns the channels
//! with the drive by the latency measured from the loopback.
//!
//! Safety: the drive limit is enforced where samples are produced
//! ([`DriveSource`]); the displacement limit, the laser range and the drive
//! actually applied (loopback) are checked on every captured block; any limit,
//! stream error or a missing loopback stops the sweep with
//! [`BenchError::Fault`] after the drive was ramped to zero.

use super::latency::{estimate_latency, LatencyEstimate};
use super::serial_rig::SerialRig;
use crate::audio::drive::DriveSource;
use crate::audio::{AudioError, AudioIo};
use crate::laser::LaserIdentity;
use crate::settings::{HardwareConfig, LaserConfig};
use crate::{Bench, BenchError, Block, Control, Limits};
use serde::Serialize;
use springbench_core::recording::Signals;

/// Captured frames handed to the observer at a time (10 ms at 48 kHz).
pub const BLOCK_LEN: usize = 480;
/// Below this normalised correlation the loopback does not show the drive.
pub const MIN_LOOPBACK_CORRELATION: f64 = 0.98;
/// Applied drive (loopback) beyond the limit by this factor is a fault.
pub const DRIVE_LIMIT_MARGIN: f64 = 1.05;

/// What a sweep measured about the bench itself (stored with the measurement).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunInfo {
    /// Frames of the sweep.
    pub frames: usize,
    /// Output-to-input latency measured from the loopback (s).
    pub latency_s: f64,
    pub latency_samples: f64,
    /// Normalised correlation of loopback and drive at that latency.
    pub loopback_correlation: f64,
    /// Loopback amplitude / played amplitude (1 when gain and divider are right).
    pub loopback_gain: f64,
    /// Samples clamped to the drive limit where they were produced.
    pub drive_clamped_samples: u64,
    /// Largest applied drive seen on the loopback (V).
    pub peak_drive_v: f64,
    /// Serial laser: how its samples were put on the audio clock (method,
    /// validity and reason, offset, clock ratio, residual, sensor identity).
    /// `None` with an analog laser (one converter clock).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment: Option<serde_json::Value>,
}

/// The channels of one capture, in SI, on the input clock.
#[derive(Debug, Default, Clone)]
pub struct Capture {
    pub microphone_v: Vec<f64>,
    /// Amplifier output from the loopback (V).
    pub drive_v: Vec<f64>,
    /// Analog laser (m); empty with a serial laser.
    pub displacement_m: Vec<f64>,
}

impl Capture {
    pub fn len(&self) -> usize {
        self.drive_v.len()
    }
    pub fn is_empty(&self) -> bool {
        self.drive_v.is_empty()
    }
}

pub struct HardwareBench {
    pub id: String,
    pub hw: HardwareConfig,
    pub limits: Limits,
    audio: Box<dyn AudioIo>,
    /// Latency (samples) used to hand blocks to the observer before this sweep's own is measured.
    last_latency: usize,
    runs: Vec<RunInfo>,
    /// The serial laser, when `hw.laser` is `kind = "serial"`.
    serial: Option<SerialRig>,
    /// Input-clock epoch and frame position of the last capture's first frame.
    clock: (u32, u64),
    /// Captures started (the epoch when the device does not say).
    captures: u32,
    /// What the last run captured before a fault ended it (drive time).
    fault_signals: Option<Signals>,
}

impl HardwareBench {
    pub fn new(id: &str, hw: HardwareConfig, limits: Limits, audio: Box<dyn AudioIo>) -> Self {
        HardwareBench {
            id: id.to_string(),
            hw,
            limits,
            audio,
            last_latency: 0,
            runs: Vec::new(),
            serial: None,
            clock: (0, 0),
            captures: 0,
            fault_signals: None,
        }
    }

    /// Attaches the serial laser (`hw.laser` of `kind = "serial"`).
    pub fn with_serial_laser(mut self, rig: SerialRig) -> Self {
        self.serial = Some(rig);
        self
    }

    /// What every sweep so far measured about the bench, oldest first.
    pub fn runs(&self) -> &[RunInfo] {
        &self.runs
    }

    fn fs(&self) -> f64 {
        self.hw.sample_rate_hz as f64
    }

    /// Amplifier output volts per DAC full-scale unit.
    fn volts_per_dac_unit(&self) -> f64 {
        self.hw.calibration.dac_full_scale_v * self.hw.calibration.amplifier_gain
    }

    /// Converts interleaved input frames to SI and appends them.
    fn convert(&self, frames: &[f32], cap: &mut Capture) {
        let nch = self.audio.input_channels().max(1);
        let c = &self.hw.calibration;
        let ch = self.hw.channels;
        let adc = c.adc_full_scale_v;
        for f in frames.chunks_exact(nch) {
            let get = |i: u16| f.get(i as usize).copied().unwrap_or(0.0) as f64 * adc;
            cap.microphone_v.push(get(ch.microphone));
            cap.drive_v.push(get(ch.loopback) / c.loopback_divider);
            match &self.hw.laser {
                LaserConfig::Analog {
                    scale_m_per_v,
                    offset_m,
                    ..
                } => cap
                    .displacement_m
                    .push(offset_m + scale_m_per_v * get(ch.laser)),
                // Filled from the serial laser after each block.
                LaserConfig::Serial(_) => {}
            }
        }
    }

    /// Safety checks of captured samples `from..` (on every block).
    fn check(&self, cap: &Capture, from: usize, max_drive_v: f64) -> Result<(), String> {
        let fs = self.fs();
        let range = self.hw.laser.range_m();
        let xlim = self.limits.max_displacement_m;
        for (k, &x) in cap.displacement_m.iter().enumerate().skip(from) {
            if !x.is_finite() || x.abs() >= range {
                return Err(format!(
                    "laser out of range: {x:.5} m at t = {:.3} s (range +-{range} m)",
                    k as f64 / fs
                ));
            }
            if x.abs() > xlim {
                return Err(format!(
                    "displacement limit exceeded: |x| = {:.5} m > {xlim} m at t = {:.3} s",
                    x.abs(),
                    k as f64 / fs
                ));
            }
        }
        for (k, &u) in cap.drive_v.iter().enumerate().skip(from) {
            if !u.is_finite() || u.abs() > max_drive_v * DRIVE_LIMIT_MARGIN {
                return Err(format!(
                    "drive limit exceeded at the amplifier output (loopback): {u:.2} V > {max_drive_v} V at t = {:.3} s; check amplifier_gain",
                    k as f64 / fs
                ));
            }
        }
        Ok(())
    }

    /// Plays `dac` (DAC units) and captures until `frames` frames are in or a
    /// check fails; `observer` sees blocks in drive time (latency `lat`).
    fn play_capture(
        &mut self,
        dac: Vec<f32>,
        frames: usize,
        observer: &mut dyn FnMut(&Capture, usize, usize) -> Control,
    ) -> Result<(Capture, u64), BenchError> {
        let fs = self.fs();
        let max_drive_v = self.limits.max_drive_v;
        let limit_dac = (max_drive_v / self.volts_per_dac_unit()) as f32;
        let ramp_len = ((self.hw.ramp_down_s * fs).round() as usize).max(1);
        let src = DriveSource::new(dac, limit_dac, ramp_len);
        let shared = src.shared();
        self.captures += 1;
        if let Some(rig) = self.serial.as_mut() {
            // Audio time is not known before the start: the collection stamps of
            // samples from before the sweep are refreshed by the first block.
            rig.begin_sweep(0.0).map_err(BenchError::Fault)?;
        }
        if let Err(e) = self.audio.start(src) {
            if let Some(rig) = self.serial.as_mut() {
                rig.end_sweep();
            }
            return Err(BenchError::Fault(format!("audio device: {e}")));
        }
        let (epoch, pos0) = self.audio.input_clock().unwrap_or((self.captures, 0));
        self.clock = (epoch, pos0);
        let mut cap = Capture::default();
        let mut buf = Vec::new();
        let mut outcome: Result<(), BenchError> = Ok(());
        while cap.len() < frames {
            buf.clear();
            if let Err(e) = self.audio.read(&mut buf) {
                outcome = Err(BenchError::Fault(match e {
                    AudioError::Stream(m) => {
                        format!("audio stream error during the sweep (the sweep is invalid): {m}")
                    }
                    e => format!("audio device: {e}"),
                }));
                break;
            }
            let from = cap.len();
            self.convert(&buf, &mut cap);
            if let Some(rig) = self.serial.as_mut() {
                let now_s = (pos0 + cap.len() as u64) as f64 / fs;
                if let Err(m) = rig.after_block(epoch, now_s) {
                    outcome = Err(BenchError::Fault(m));
                    break;
                }
                let len = cap.len();
                rig.fill(epoch, pos0 as f64 / fs, fs, &mut cap.displacement_m, len);
            }
            if let Err(m) = self.check(&cap, from, max_drive_v) {
                outcome = Err(BenchError::Fault(m));
                break;
            }
            if observer(&cap, from, cap.len()) == Control::Abort {
                outcome = Err(BenchError::Aborted);
                break;
            }
        }
        if outcome.is_err() {
            shared.abort();
        }
        // Let the ramp (or the played-out signal's silence) reach the output, then stop.
        self.audio
            .stop(self.hw.ramp_down_s + self.hw.max_latency_s + 0.25);
        if let Some(rig) = self.serial.as_mut() {
            if outcome.is_ok() {
                let end_s = (pos0 + cap.len() as u64) as f64 / fs;
                if let Err(m) = rig.finish(epoch, end_s) {
                    outcome = Err(BenchError::Fault(m));
                }
            }
            rig.end_sweep();
        }
        self.fault_signals = match &outcome {
            Err(BenchError::Fault(_)) => self.drive_time(&cap),
            _ => None,
        };
        outcome.map(|_| (cap, shared.clamped()))
    }

    /// A capture cut off by a fault, in drive time (shifted by the last
    /// measured latency), every channel to the length all have; None
    /// without a displacement (never zeros where nothing was measured).
    fn drive_time(&self, cap: &Capture) -> Option<Signals> {
        let l = self.last_latency;
        let n = cap
            .len()
            .min(cap.microphone_v.len())
            .min(cap.displacement_m.len());
        if n <= l {
            return None;
        }
        Some(Signals {
            sample_rate_hz: self.fs(),
            displacement_m: cap.displacement_m[l..n].to_vec(),
            microphone_v: cap.microphone_v[l..n].to_vec(),
            drive_v: Some(cap.drive_v[l..n].to_vec()),
        })
    }

    /// Latency of the loopback behind the digital drive; a fault when the loopback does not show it.
    fn latency(&self, drive_v: &[f64], cap: &Capture) -> Result<LatencyEstimate, BenchError> {
        let max_lag = (self.hw.max_latency_s * self.fs()).ceil() as usize;
        // Compare with what the producer actually played (the drive limit clamps).
        let lim = self.limits.max_drive_v;
        let played: Vec<f64> = drive_v.iter().map(|u| u.clamp(-lim, lim)).collect();
        match estimate_latency(&played, &cap.drive_v, max_lag) {
            Some(e) if e.correlation >= MIN_LOOPBACK_CORRELATION => Ok(e),
            Some(e) => Err(BenchError::Fault(format!(
                "the loopback does not show the drive (correlation {:.3} < {MIN_LOOPBACK_CORRELATION}): check the loopback wiring and channels.loopback; the sweep cannot be aligned",
                e.correlation
            ))),
            None => Err(BenchError::Fault(
                "the loopback channel is silent: check the amplifier, the divider and channels.loopback; the sweep cannot be aligned".into(),
            )),
        }
    }
}

impl Bench for HardwareBench {
    fn id(&self) -> &str {
        &self.id
    }

    fn sample_rate_hz(&self) -> f64 {
        self.fs()
    }

    fn limits(&self) -> Limits {
        self.limits
    }

    fn take_fault_signals(&mut self) -> Option<Signals> {
        self.fault_signals.take()
    }

    fn run_records(&self) -> Vec<serde_json::Value> {
        self.runs
            .iter()
            .map(|r| serde_json::to_value(r).unwrap_or_default())
            .collect()
    }

    fn describe(&self) -> String {
        format!(
            "hardware bench at {} Hz: {}; laser {}",
            self.hw.sample_rate_hz,
            self.audio.describe(),
            match &self.hw.laser {
                LaserConfig::Analog { model, serial, .. } =>
                    format!("analog {model} {serial}").trim_end().to_string(),
                LaserConfig::Serial(c) => match &self.serial {
                    Some(r) => {
                        let id = r.identity();
                        format!(
                            "serial {} on {} ({} Hz): {} {}",
                            id.protocol, c.port, c.rate_hz, id.model, id.serial
                        )
                        .trim_end()
                        .to_string()
                    }
                    None => format!("serial on {} (not open)", c.port),
                },
            }
        )
    }

    fn run(
        &mut self,
        drive_v: &[f64],
        observer: &mut dyn FnMut(Block<'_>) -> Control,
    ) -> Result<Signals, BenchError> {
        if let Some(i) = drive_v.iter().position(|u| !u.is_finite()) {
            return Err(BenchError::Device(format!(
                "drive sample {i} is not finite"
            )));
        }
        let n = drive_v.len();
        let fs = self.fs();
        let tail = (self.hw.max_latency_s * fs).ceil() as usize + self.hw.buffer_frames as usize;
        let vpu = self.volts_per_dac_unit();
        let mut dac: Vec<f32> = drive_v.iter().map(|u| (u / vpu) as f32).collect();
        dac.resize(n + tail, 0.0);
        // Blocks go to the observer in drive time, shifted by the last measured latency.
        let lat = self.last_latency;
        let mut delivered = 0usize;
        let mut obs = |cap: &Capture, _from: usize, have: usize| -> Control {
            while delivered < n {
                let end = (delivered + BLOCK_LEN).min(n);
                if have < end + lat {
                    break;
                }
                let (a, b) = (delivered + lat, end + lat);
                let xs: &[f64] = if cap.displacement_m.is_empty() {
                    &[]
                } else {
                    &cap.displacement_m[a..b]
                };
                let ctl = observer(Block {
                    start_sample: delivered,
                    displacement_m: xs,
                    microphone_v: &cap.microphone_v[a..b],
                    drive_v: &cap.drive_v[a..b],
                });
                delivered = end;
                if ctl == Control::Abort {
                    return Control::Abort;
                }
            }
            Control::Continue
        };
        let (cap, clamped) = self.play_capture(dac, n + tail, &mut obs)?;
        let est = self.latency(drive_v, &cap)?;
        let l = est.latency_samples.round().max(0.0) as usize;
        self.last_latency = l;
        let seg = |v: &[f64]| -> Vec<f64> {
            let mut s = v[l.min(v.len())..(l + n).min(v.len())].to_vec();
            s.resize(n, 0.0);
            s
        };
        let mut signals = Signals {
            sample_rate_hz: fs,
            displacement_m: seg(&cap.displacement_m),
            microphone_v: seg(&cap.microphone_v),
            drive_v: Some(seg(&cap.drive_v)),
        };
        let (epoch, pos0) = self.clock;
        let alignment = self.serial.as_mut().map(|rig| {
            let start_s = (pos0 + l as u64) as f64 / fs;
            let al = rig.align(epoch, start_s, fs, &signals.microphone_v);
            signals.displacement_m = al.displacement_m;
            alignment_record(&al.report, rig.identity())
        });
        self.runs.push(RunInfo {
            frames: n,
            latency_s: est.latency_samples / fs,
            latency_samples: est.latency_samples,
            loopback_correlation: est.correlation,
            loopback_gain: est.gain,
            drive_clamped_samples: clamped,
            peak_drive_v: cap.drive_v.iter().fold(0.0f64, |a, u| a.max(u.abs())),
            alignment,
        });
        Ok(signals)
    }
}

/// What a measurement stores about a serial laser's alignment (JSON; finite
/// numbers only: an unknown figure is null).
fn alignment_record(
    r: &crate::align::AlignmentReport,
    id: &crate::laser::LaserIdentity,
) -> serde_json::Value {
    let f = |v: f64| v.is_finite().then_some(v);
    let method = match r.clock {
        crate::laser::SampleClock::DeviceCounter => "device counter + force balance",
        crate::laser::SampleClock::DeviceStream => "counted stream + force balance",
        crate::laser::SampleClock::HostPoll => "none (host poll times)",
    };
    serde_json::json!({
        "method": method,
        "valid": r.valid,
        "invalid_reason": r.invalid_reason,
        "offset_s": f(r.offset_s),
        "clock_ppm": f(r.ratio_ppm),
        "clock_ppm_stderr": f(r.ratio_stderr_ppm),
        "residual_s": f(r.residual_rms_s),
        "residual_max_s": f(r.residual_max_s),
        "line_stderr_s": f(r.line_stderr_s),
        "windows": r.windows,
        "job_windows": r.job_windows,
        "dropped_samples": r.dropped_samples,
        "fit_residual": f(r.fit_residual),
        "nominal_rate_hz": r.nominal_rate_hz,
        "sensor": id,
    })
}

/// Root mean square about the mean, and the mean.
fn rms_mean(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let r = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt();
    (r, m)
}

/// Self-check thresholds.
pub const SELF_CHECK_SILENCE_S: f64 = 0.5;
pub const SELF_CHECK_CHIRP_S: f64 = 0.5;
/// Largest accepted loopback gain error (fraction): amplifier gain and divider as configured.
pub const MAX_LOOPBACK_GAIN_ERROR: f64 = 0.1;
/// Largest accepted laser noise at rest (m RMS) and microphone noise at silence (Pa RMS).
pub const MAX_LASER_NOISE_M: f64 = 20e-6;
pub const MAX_MIC_NOISE_PA: f64 = 5.0;

/// What a self-check measured; `passed` when every check held.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SelfCheck {
    pub passed: bool,
    /// One line per failed check.
    pub failures: Vec<String>,
    pub latency_s: Option<f64>,
    pub loopback_correlation: Option<f64>,
    pub loopback_gain: Option<f64>,
    /// Noise floor (RMS about the mean) of every input channel at rest.
    pub noise: NoiseFloor,
    /// Mean laser reading with the drive silent (m).
    pub laser_at_rest_m: f64,
    /// Microphone at silence: RMS (Pa).
    pub mic_at_silence_pa: f64,
    /// Sample rate and the devices used.
    pub sample_rate_hz: f64,
    pub devices: String,
    /// The laser as identified at the self-check: model, serial and range
    /// read from the sensor where its protocol allows, else the configuration's.
    pub laser: LaserIdentity,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseFloor {
    pub microphone_v: f64,
    pub loopback_v: f64,
    pub laser_m: f64,
}

impl HardwareBench {
    /// Bench self-check: silence (noise floor of every channel, laser at rest,
    /// microphone at silence), then a short low-level chirp (latency and
    /// loopback gain). Device faults and limits are errors, as in a sweep.
    pub fn self_check(&mut self) -> Result<SelfCheck, BenchError> {
        let fs = self.fs();
        let ns = (SELF_CHECK_SILENCE_S * fs) as usize;
        let (silence, _) =
            self.play_capture(vec![0.0; ns], ns, &mut |_, _, _| Control::Continue)?;
        // Skip the first 10 % (device start-up).
        let skip = ns / 10;
        let (mic_v, _) = rms_mean(&silence.microphone_v[skip..]);
        let (loop_v, _) = rms_mean(&silence.drive_v[skip..]);
        let (laser_m, rest_m) = if silence.displacement_m.is_empty() {
            (0.0, 0.0)
        } else {
            rms_mean(&silence.displacement_m[skip..])
        };
        let mic_pa = mic_v / self.hw.calibration.mic_sensitivity_v_per_pa;
        let mut failures = Vec::new();
        let range = self.hw.laser.range_m();
        if rest_m.abs() + self.limits.max_displacement_m >= range {
            failures.push(format!(
                "laser at rest reads {rest_m:.5} m: with the displacement limit of {} m the part would leave the laser range (+-{range} m); adjust the laser position or laser.offset_m",
                self.limits.max_displacement_m
            ));
        }
        if laser_m > MAX_LASER_NOISE_M {
            failures.push(format!(
                "laser noise at rest {laser_m:.2e} m RMS > {MAX_LASER_NOISE_M:.0e} m"
            ));
        }
        if mic_pa > MAX_MIC_NOISE_PA {
            failures.push(format!(
                "microphone at silence {mic_pa:.2} Pa RMS > {MAX_MIC_NOISE_PA} Pa"
            ));
        }
        // Chirp 100 Hz -> 2 kHz with 10 ms fades, at a tenth of the drive limit (at most 1 V).
        let nc = (SELF_CHECK_CHIRP_S * fs) as usize;
        let amp = (self.limits.max_drive_v / 10.0).min(1.0);
        let (f1, f2) = (100.0f64, 2000.0f64);
        let rate = (f2 / f1).ln() / SELF_CHECK_CHIRP_S;
        let fade = (0.01 * fs) as usize;
        let chirp: Vec<f64> = (0..nc)
            .map(|k| {
                let t = k as f64 / fs;
                let ph = 2.0 * std::f64::consts::PI * f1 * ((rate * t).exp() - 1.0) / rate;
                let w = (k.min(nc - 1 - k) as f64 / fade as f64).min(1.0);
                amp * w * ph.sin()
            })
            .collect();
        let (mut lat, mut corr, mut gain) = (None, None, None);
        match self.run(&chirp, &mut |_| Control::Continue) {
            Ok(_) => {
                let r = self.runs.pop().expect("a run was recorded");
                lat = Some(r.latency_s);
                corr = Some(r.loopback_correlation);
                gain = Some(r.loopback_gain);
                if (r.loopback_gain - 1.0).abs() > MAX_LOOPBACK_GAIN_ERROR {
                    failures.push(format!(
                        "loopback gain {:.3} (1 expected): amplifier_gain or loopback_divider does not match the bench",
                        r.loopback_gain
                    ));
                }
            }
            Err(BenchError::Fault(m)) => failures.push(m),
            Err(e) => return Err(e),
        }
        Ok(SelfCheck {
            passed: failures.is_empty(),
            failures,
            latency_s: lat,
            loopback_correlation: corr,
            loopback_gain: gain,
            noise: NoiseFloor {
                microphone_v: mic_v,
                loopback_v: loop_v,
                laser_m,
            },
            laser_at_rest_m: rest_m,
            mic_at_silence_pa: mic_pa,
            sample_rate_hz: fs,
            devices: self.audio.describe(),
            laser: self.laser_identity(),
        })
    }

    /// The laser's identity: what a serial sensor answered at start, or for
    /// an analog sensor (which cannot be asked) the configured model/serial.
    fn laser_identity(&self) -> LaserIdentity {
        match (&self.serial, &self.hw.laser) {
            (Some(rig), _) => rig.identity().clone(),
            (None, LaserConfig::Analog { model, serial, .. }) => LaserIdentity {
                protocol: "analog".into(),
                model: model.clone(),
                serial: serial.clone(),
                firmware: String::new(),
                range_m: Some(self.hw.laser.range_m()),
                read_from_sensor: false,
            },
            (None, LaserConfig::Serial(c)) => LaserIdentity {
                protocol: "serial (not open)".into(),
                model: c.model.clone(),
                serial: c.serial.clone(),
                firmware: String::new(),
                range_m: None,
                read_from_sensor: false,
            },
        }
    }
}
