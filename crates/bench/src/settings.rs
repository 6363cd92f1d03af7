//! Configuration of a hardware (or emulated hardware) bench: devices, channel
//! map, calibration, laser and, for the emulated bench, the emulator. Plain
//! data read from the bench's `[benches.hardware]` TOML table; always compiled
//! (the configuration parses without the `hardware` feature, the daemon then
//! refuses to start such a bench with a one-line reason).

use crate::Limits;
use serde::{Deserialize, Serialize};

/// `[benches.hardware]`: one output device plays the drive; one input device
/// captures microphone, loopback and (analog laser) displacement on one clock.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HardwareConfig {
    /// Output device name as `springbench devices` lists it (ALSA PCM name).
    #[serde(default = "default_out")]
    pub output_device: String,
    /// Input device name (one converter for microphone, loopback, analog laser).
    #[serde(default = "default_in")]
    pub input_device: String,
    #[serde(default = "default_fs")]
    pub sample_rate_hz: u32,
    /// Frames per device buffer (cpal `BufferSize::Fixed`); also the capture block.
    #[serde(default = "default_buffer")]
    pub buffer_frames: u32,
    /// Channels opened on the output device; the drive goes to `channels.drive`, the others stay silent.
    #[serde(default = "default_out_ch")]
    pub output_channels: u16,
    /// Channels opened on the input device.
    #[serde(default = "default_in_ch")]
    pub input_channels: u16,
    #[serde(default)]
    pub channels: ChannelMap,
    pub calibration: Calibration,
    #[serde(default)]
    pub laser: LaserConfig,
    /// Largest output-to-input latency searched in the loopback (s).
    #[serde(default = "default_max_latency")]
    pub max_latency_s: f64,
    /// Length of the drive ramp-down after a fault, limit or cancel (s); at most 0.05.
    #[serde(default = "default_ramp")]
    pub ramp_down_s: f64,
}

fn default_out() -> String {
    "default".into()
}
fn default_in() -> String {
    "default".into()
}
fn default_fs() -> u32 {
    48000
}
fn default_buffer() -> u32 {
    480
}
fn default_out_ch() -> u16 {
    2
}
fn default_in_ch() -> u16 {
    4
}
fn default_max_latency() -> f64 {
    0.1
}
fn default_ramp() -> f64 {
    0.01
}

/// Channel indices (0-based) on the output and input devices.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChannelMap {
    /// Output channel of the drive.
    pub drive: u16,
    /// Input channel of the microphone.
    pub microphone: u16,
    /// Input channel of the amplifier-output loopback (through the divider).
    pub loopback: u16,
    /// Input channel of the analog laser output (DC-coupled), when the laser is analog.
    pub laser: u16,
}

impl Default for ChannelMap {
    fn default() -> Self {
        ChannelMap {
            drive: 0,
            microphone: 0,
            loopback: 1,
            laser: 2,
        }
    }
}

/// `[benches.hardware.calibration]`: what turns converter numbers into SI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// DAC output (V peak) at digital full scale.
    pub dac_full_scale_v: f64,
    /// Amplifier voltage gain (V/V): amplifier output = gain * DAC output.
    pub amplifier_gain: f64,
    /// ADC input (V peak) at digital full scale, all input channels.
    pub adc_full_scale_v: f64,
    /// Loopback divider ratio (V at the ADC per V of amplifier output), e.g. 0.01 for 100:1.
    pub loopback_divider: f64,
    /// Microphone sensitivity including its preamplifier (V/Pa).
    pub mic_sensitivity_v_per_pa: f64,
    /// Date of the microphone calibration (ISO 8601, e.g. "2026-10-01").
    pub mic_calibrated_on: String,
}

/// `[benches.hardware.laser]`: how the displacement reaches the bench.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LaserConfig {
    /// Analog output sampled on the input device (channel `channels.laser`, DC-coupled).
    Analog {
        /// Displacement per volt at the ADC input (m/V).
        scale_m_per_v: f64,
        /// Displacement at 0 V (m); the reading at rest is subtracted per job anyway.
        #[serde(default)]
        offset_m: f64,
        /// Measuring range: |x| beyond it is out of range (a bench fault).
        range_m: f64,
        /// Sensor model and serial (analog sensors cannot be asked).
        #[serde(default)]
        model: String,
        #[serde(default)]
        serial: String,
    },
    /// A laser on a serial line (port, baud, protocol, rate); its samples are
    /// put on the audio clock per job ([`crate::align`]). On an
    /// emulated bench `port` is not opened: the bench emulator opens a
    /// pseudo-terminal and its laser emulator speaks the protocol there.
    Serial(crate::laser::SerialLaserConfig),
}

impl Default for LaserConfig {
    fn default() -> Self {
        LaserConfig::Analog {
            scale_m_per_v: 0.005,
            offset_m: 0.0,
            range_m: 0.025,
            model: String::new(),
            serial: String::new(),
        }
    }
}

impl LaserConfig {
    /// Largest |x| the sensor measures (m): beyond it is out of range (a
    /// bench fault). A serial sensor with an unknown range flags out-of-range
    /// samples itself: infinite here.
    pub fn range_m(&self) -> f64 {
        use crate::laser::ProtocolConfig as P;
        match self {
            LaserConfig::Analog { range_m, .. } => *range_m,
            // Serial sensors report x from the middle of their span.
            LaserConfig::Serial(c) => match &c.protocol {
                P::Optoncdt(p) => p.range_m / 2.0,
                P::Keyence(p) => p.range_m.map_or(f64::INFINITY, |r| r / 2.0),
                P::AsciiLines(p) => p.range_m.map_or(f64::INFINITY, |r| r / 2.0),
            },
        }
    }
}

/// `[benches.emulator]` of a `kind = "emulated"` bench: the physics behind the
/// same device interfaces (tests, trying the hardware path by hand).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Output-to-input latency of the emulated audio device (s): half in the
    /// output buffer (before the DAC), half after the ADC.
    #[serde(default = "default_emu_latency")]
    pub latency_s: f64,
    /// Microphone noise (Pa RMS) and laser noise (m RMS) of the emulated sensors.
    #[serde(default = "default_mic_noise")]
    pub mic_noise_pa: f64,
    #[serde(default = "default_laser_noise")]
    pub laser_noise_m: f64,
    /// Directory for a trace of every emulated run (what the DAC played, the fault instant).
    #[serde(default)]
    pub trace_dir: Option<std::path::PathBuf>,
    /// Faults injected on purpose (tests and demonstrations).
    #[serde(default)]
    pub faults: Vec<FaultPlan>,
    /// The laser emulator behind a `kind = "serial"` laser: its own clock.
    #[serde(default)]
    pub serial_laser: SerialLaserEmulation,
    /// Deliver the captured blocks in real time (the wall clock paces the
    /// emulated converter), as a real interface does; otherwise as fast as
    /// the CPU runs the physics.
    #[serde(default)]
    pub paced: bool,
}

/// `[benches.emulator.serial_laser]`: the emulated serial sensor's clock and
/// line (it speaks the configured protocol on a pseudo-terminal).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SerialLaserEmulation {
    /// Clock error of the sensor (ppm, + = fast).
    pub ppm: f64,
    /// Input-clock time of the sensor's sample 0 (s).
    pub offset_s: f64,
    /// Sampling-instant jitter (s RMS).
    pub jitter_s: f64,
    /// Bytes leave in chunks of this much sensor time (s), like a USB-serial adapter's latency timer.
    pub chunk_s: f64,
    /// What the sensor says about itself (protocols with an identity command).
    pub model: String,
    pub serial: String,
}

impl Default for SerialLaserEmulation {
    fn default() -> Self {
        SerialLaserEmulation {
            ppm: 150.0,
            offset_s: 0.003,
            jitter_s: 2e-6,
            chunk_s: 0.016,
            model: "ILD1420-40 (emulated)".into(),
            serial: "EMU-LASER-1".into(),
        }
    }
}

fn default_emu_latency() -> f64 {
    0.005
}
fn default_mic_noise() -> f64 {
    0.3
}
fn default_laser_noise() -> f64 {
    1e-6
}

impl Default for EmulatorConfig {
    fn default() -> Self {
        EmulatorConfig {
            latency_s: default_emu_latency(),
            mic_noise_pa: default_mic_noise(),
            laser_noise_m: default_laser_noise(),
            trace_dir: None,
            faults: vec![],
            serial_laser: SerialLaserEmulation::default(),
            paced: false,
        }
    }
}

/// One injected fault: in the job with sequence number `job_seq`, during its
/// `sweep`-th sweep (1 = the first), `at_s` seconds into the sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultPlan {
    pub kind: FaultKind,
    pub job_seq: i64,
    #[serde(default = "one")]
    pub sweep: u32,
    pub at_s: f64,
}

fn one() -> u32 {
    1
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// The audio device reports a stream error (as cpal's `DeviceNotAvailable`).
    AudioStreamError,
    /// The part slips in its clamp: the laser sees it move 30 mm outwards within 20 ms.
    PartSlips,
    /// The serial laser's adapter is unplugged: the laser emulator closes its pseudo-terminal.
    LaserUnplugged,
    /// The serial laser sends bytes that are no frame of its protocol.
    LaserGarbage,
}

/// The sensors' identities as a hardware bench stores them with every
/// calibration record and every measurement (`sensors`): the laser as
/// configured, the microphone's calibration, the converters. The bench
/// crate is the author of this document; the core and the store carry it
/// whole (they sit below this crate and cannot name its types), and the
/// runner compares the stored one with this one to decide whether a new
/// self-check is due.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SensorIdentities<'a> {
    pub laser: &'a LaserConfig,
    pub microphone: MicrophoneIdentity<'a>,
    pub input_device: &'a str,
    pub output_device: &'a str,
}

/// The measuring microphone's identity: its sensitivity and when it was calibrated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MicrophoneIdentity<'a> {
    pub sensitivity_v_per_pa: f64,
    pub calibrated_on: &'a str,
}

/// The document of a typed bench record. These types hold strings and
/// numbers only, which serde_json does not refuse; were it to, the record
/// would say `null` rather than the daemon stop.
fn document<T: Serialize>(t: &T) -> serde_json::Value {
    serde_json::to_value(t).unwrap_or_default()
}

impl BenchConfig {
    /// `sensors` of this bench's calibration records and measurements;
    /// `null` for a bench without a `[benches.hardware]` table.
    pub fn sensors_document(&self) -> serde_json::Value {
        self.hardware.as_ref().map_or(serde_json::Value::Null, |h| {
            document(&h.sensor_identities())
        })
    }

    /// `calibration` of this bench's calibration records and measurements:
    /// the `[benches.hardware.calibration]` in effect; `null` without one.
    pub fn calibration_document(&self) -> serde_json::Value {
        self.hardware
            .as_ref()
            .map_or(serde_json::Value::Null, |h| document(&h.calibration))
    }
}

impl HardwareConfig {
    /// The sensors' identities as configured ([`SensorIdentities`]).
    pub fn sensor_identities(&self) -> SensorIdentities<'_> {
        SensorIdentities {
            laser: &self.laser,
            microphone: MicrophoneIdentity {
                sensitivity_v_per_pa: self.calibration.mic_sensitivity_v_per_pa,
                calibrated_on: &self.calibration.mic_calibrated_on,
            },
            input_device: &self.input_device,
            output_device: &self.output_device,
        }
    }

    /// One-line error naming the first implausible field.
    pub fn validate(&self, bench_id: &str) -> Result<(), String> {
        let e = |m: String| Err(format!("bench '{bench_id}': hardware.{m}"));
        let c = &self.calibration;
        for (n, v) in [
            ("calibration.dac_full_scale_v", c.dac_full_scale_v),
            ("calibration.amplifier_gain", c.amplifier_gain),
            ("calibration.adc_full_scale_v", c.adc_full_scale_v),
            ("calibration.loopback_divider", c.loopback_divider),
            (
                "calibration.mic_sensitivity_v_per_pa",
                c.mic_sensitivity_v_per_pa,
            ),
            ("max_latency_s", self.max_latency_s),
            ("ramp_down_s", self.ramp_down_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return e(format!("{n} must be a positive number, got {v}"));
            }
        }
        if self.ramp_down_s > 0.05 {
            return e(format!(
                "ramp_down_s must be at most 0.05 s (the drive must reach zero within 50 ms), got {}",
                self.ramp_down_s
            ));
        }
        if self.max_latency_s > 1.0 {
            return e(format!(
                "max_latency_s must be at most 1 s, got {}",
                self.max_latency_s
            ));
        }
        if !(8000..=384000).contains(&self.sample_rate_hz) {
            return e(format!(
                "sample_rate_hz must be 8000..=384000, got {}",
                self.sample_rate_hz
            ));
        }
        if !(16..=16384).contains(&self.buffer_frames) {
            return e(format!(
                "buffer_frames must be 16..=16384, got {}",
                self.buffer_frames
            ));
        }
        if self.channels.drive >= self.output_channels {
            return e(format!(
                "channels.drive = {} but the output has {} channels",
                self.channels.drive, self.output_channels
            ));
        }
        let mut used = vec![
            ("microphone", self.channels.microphone),
            ("loopback", self.channels.loopback),
        ];
        if matches!(self.laser, LaserConfig::Analog { .. }) {
            used.push(("laser", self.channels.laser));
        }
        for (i, (n, ch)) in used.iter().enumerate() {
            if *ch >= self.input_channels {
                return e(format!(
                    "channels.{n} = {ch} but the input has {} channels",
                    self.input_channels
                ));
            }
            if let Some((m, _)) = used[..i].iter().find(|(_, c)| c == ch) {
                return e(format!("channels.{n} and channels.{m} are both {ch}"));
            }
        }
        match &self.laser {
            LaserConfig::Analog {
                scale_m_per_v,
                offset_m,
                range_m,
                ..
            } => {
                if !(scale_m_per_v.is_finite() && *scale_m_per_v != 0.0) {
                    return e(format!(
                        "laser.scale_m_per_v must be finite and not 0, got {scale_m_per_v}"
                    ));
                }
                if !offset_m.is_finite() {
                    return e(format!("laser.offset_m must be finite, got {offset_m}"));
                }
                if !(range_m.is_finite() && *range_m > 0.0) {
                    return e(format!("laser.range_m must be > 0, got {range_m}"));
                }
            }
            LaserConfig::Serial(c) => {
                // SerialLaserConfig's messages start with "laser.".
                c.validate()
                    .map_err(|m| format!("bench '{bench_id}': hardware.{m}"))?;
            }
        }
        Ok(())
    }
}

impl EmulatorConfig {
    pub fn validate(&self, bench_id: &str) -> Result<(), String> {
        let e = |m: String| Err(format!("bench '{bench_id}': emulator.{m}"));
        if !(self.latency_s.is_finite() && (0.0..=0.5).contains(&self.latency_s)) {
            return e(format!(
                "latency_s must be in [0, 0.5] s, got {}",
                self.latency_s
            ));
        }
        for (n, v) in [
            ("mic_noise_pa", self.mic_noise_pa),
            ("laser_noise_m", self.laser_noise_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return e(format!("{n} must be >= 0, got {v}"));
            }
        }
        let sl = &self.serial_laser;
        if !(sl.ppm.is_finite() && sl.ppm.abs() <= 1000.0) {
            return e(format!(
                "serial_laser.ppm must be within +-1000, got {}",
                sl.ppm
            ));
        }
        for (n, v, hi) in [
            ("offset_s", sl.offset_s, 1.0),
            ("jitter_s", sl.jitter_s, 1e-3),
            ("chunk_s", sl.chunk_s, 0.1),
        ] {
            if !(v.is_finite() && (0.0..=hi).contains(&v)) {
                return e(format!("serial_laser.{n} must be in [0, {hi}], got {v}"));
            }
        }
        for f in &self.faults {
            if !(f.at_s.is_finite() && f.at_s >= 0.0) || f.sweep == 0 {
                return e(format!(
                    "faults: at_s must be >= 0 and sweep >= 1, got at_s = {}, sweep = {}",
                    f.at_s, f.sweep
                ));
            }
        }
        Ok(())
    }
}

/// Which kind of device a bench is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum BenchKind {
    /// The physics simulation ([`crate::virtual_bench::VirtualBench`]).
    Virtual,
    /// A real bench: audio devices through cpal, a laser (feature `hardware`).
    Hardware,
    /// The hardware code path against the bench emulator (physics behind the
    /// device interfaces; feature `hardware`).
    Emulated,
}

impl BenchKind {
    /// Its name, as in the configuration and the API.
    pub fn as_str(self) -> &'static str {
        match self {
            BenchKind::Virtual => "virtual",
            BenchKind::Hardware => "hardware",
            BenchKind::Emulated => "emulated",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// Stable identifier, used in job requests (`bench`) and stored with measurements.
    pub id: String,
    #[serde(default = "default_kind")]
    pub kind: BenchKind,
    /// Virtual bench: the preset part mounted when a job names none.
    #[serde(default = "default_preset")]
    pub preset: String,
    /// Virtual bench: noise seed of the first job (incremented per run).
    #[serde(default)]
    pub seed: u64,
    /// Hard limits; a job may ask for tighter ones, never for wider ones.
    #[serde(default = "default_limits")]
    pub limits: Limits,
    /// Hardware and emulated benches: devices, channels, calibration, laser.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hardware: Option<crate::settings::HardwareConfig>,
    /// Emulated bench: latency, noise, injected faults.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub emulator: Option<crate::settings::EmulatorConfig>,
    /// Virtual bench (`[benches.virtual]`): real-time pacing and the ways
    /// this bench differs from its neighbours (calibration, clamp).
    #[serde(default, rename = "virtual", skip_serializing_if = "Option::is_none")]
    pub virtual_: Option<VirtualConfig>,
    /// `[benches.ambient]`: the sensor of the air around the bench, read at
    /// every interval of a long-term test (issue 32, decision 0130).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient: Option<AmbientSensor>,
}

/// `[benches.ambient]`: where a bench's ambient conditions (air temperature
/// and relative humidity) come from. Read at the start of every interval of
/// a long-term test; a reading that fails or is out of range is left out of
/// the interval (the job's log says why), never stored as a guess.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum AmbientSensor {
    /// An emulated sensor (virtual and emulated benches): known values, each
    /// drifting linearly with the test time, so that a test knows the truth:
    /// T(t) = `temperature_k` + `temperature_k_per_h` · t/3600 s.
    Emulated {
        /// Air temperature at test time 0 (K).
        temperature_k: f64,
        /// Its drift (K per hour of test time).
        #[serde(default)]
        temperature_k_per_h: f64,
        /// Relative humidity at test time 0 (%).
        relative_humidity_percent: f64,
        /// Its drift (% per hour of test time).
        #[serde(default)]
        relative_humidity_percent_per_h: f64,
    },
    /// A Linux hwmon sensor (e.g. an SHT3x or HTU21 on I²C): `temp*_input`
    /// in millidegrees Celsius, `humidity*_input` in milli-percent.
    Hwmon {
        /// E.g. `/sys/class/hwmon/hwmon2/temp1_input`.
        temperature_path: std::path::PathBuf,
        /// E.g. `/sys/class/hwmon/hwmon2/humidity1_input` (absent: no humidity).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        humidity_path: Option<std::path::PathBuf>,
    },
}

impl AmbientSensor {
    /// One-line error naming the field.
    pub fn validate(&self, id: &str, kind: BenchKind) -> Result<(), String> {
        match self {
            AmbientSensor::Emulated {
                temperature_k,
                temperature_k_per_h,
                relative_humidity_percent,
                relative_humidity_percent_per_h,
            } => {
                if kind == BenchKind::Hardware {
                    return Err(format!(
                        "bench '{id}': ambient.kind = \"emulated\" is for virtual and emulated benches; a hardware bench reads a real sensor (\"hwmon\")"
                    ));
                }
                let a = springbench_core::job::Ambient {
                    temperature_k: Some(*temperature_k),
                    relative_humidity_percent: Some(*relative_humidity_percent),
                };
                if let Some(e) = a.check().first() {
                    return Err(format!("bench '{id}': ambient.{}: {}", e.field, e.message));
                }
                for (name, v) in [
                    ("temperature_k_per_h", temperature_k_per_h),
                    (
                        "relative_humidity_percent_per_h",
                        relative_humidity_percent_per_h,
                    ),
                ] {
                    if !v.is_finite() {
                        return Err(format!(
                            "bench '{id}': ambient.{name} must be a finite number, got {v}"
                        ));
                    }
                }
                Ok(())
            }
            AmbientSensor::Hwmon {
                temperature_path,
                humidity_path,
            } => {
                for p in std::iter::once(temperature_path).chain(humidity_path.iter()) {
                    if p.as_os_str().is_empty() {
                        return Err(format!("bench '{id}': ambient: an empty sensor path"));
                    }
                }
                Ok(())
            }
        }
    }

    /// The ambient conditions at test time `elapsed_s` (s), checked (within
    /// `Ambient::check`'s ranges), or why not.
    pub fn read(&self, elapsed_s: f64) -> Result<springbench_core::job::Ambient, String> {
        let a = match self {
            AmbientSensor::Emulated {
                temperature_k,
                temperature_k_per_h,
                relative_humidity_percent,
                relative_humidity_percent_per_h,
            } => {
                let h = elapsed_s / 3600.0;
                springbench_core::job::Ambient {
                    temperature_k: Some(temperature_k + temperature_k_per_h * h),
                    relative_humidity_percent: Some(
                        relative_humidity_percent + relative_humidity_percent_per_h * h,
                    ),
                }
            }
            AmbientSensor::Hwmon {
                temperature_path,
                humidity_path,
            } => {
                let milli = |p: &std::path::Path| -> Result<f64, String> {
                    let s = std::fs::read_to_string(p)
                        .map_err(|e| format!("ambient sensor {}: {e}", p.display()))?;
                    s.trim().parse::<f64>().map(|v| v / 1000.0).map_err(|_| {
                        format!(
                            "ambient sensor {}: not a number: {:?}",
                            p.display(),
                            s.trim()
                        )
                    })
                };
                springbench_core::job::Ambient {
                    temperature_k: Some(milli(temperature_path)? + 273.15),
                    relative_humidity_percent: humidity_path.as_deref().map(milli).transpose()?,
                }
            }
        };
        match a.check().first() {
            Some(e) => Err(format!("ambient sensor: {}: {}", e.field, e.message)),
            None => Ok(a),
        }
    }
}

/// `[benches.virtual]` of a `kind = "virtual"` bench. Two real benches of one
/// station never read a part alike: their lasers' sensitivities are
/// calibrated to a tolerance, their inner clamps do not weigh the same. A
/// virtual bench takes such a difference here so that a gauge study across
/// virtual benches sees a reproducibility (AV) that is not trivially 0
/// (decision 0038).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VirtualConfig {
    /// Hand each captured block on no earlier than a converter at the
    /// bench's sample rate would (the wall time a real bench takes:
    /// throughput figures); otherwise as fast as the CPU computes.
    pub paced: bool,
    /// Relative error of the laser's sensitivity: the bench reads
    /// (1 + error) x. E.g. 0.002: 0.2 % high. At most 0.05 in size.
    pub laser_gain_error: f64,
    /// Mass this bench's inner clamp adds to every mounted part beyond the
    /// part's own moving mass (kg; negative: lighter). The recipe's moving
    /// mass does not know it. At most 0.01 kg in size.
    pub clamp_mass_kg: f64,
    /// Effects every part mounted on this bench carries beyond its own
    /// (`[benches.virtual.part_effects.reversible_softening]`
    /// `depth_n_per_m2 = 3e4`, `tau_s = 2.0`): a material's memory for the
    /// recovery study of a daemon (issue 33), hidden effects for a
    /// demonstration. One given here replaces the part's of its kind.
    #[serde(skip_serializing_if = "springbench_core::effects::Effects::is_empty")]
    pub part_effects: springbench_core::effects::Effects,
}

impl VirtualConfig {
    /// One-line error naming the field.
    pub fn validate(&self, id: &str) -> Result<(), String> {
        if !self.laser_gain_error.is_finite() || self.laser_gain_error.abs() > 0.05 {
            return Err(format!(
                "bench '{id}': virtual.laser_gain_error must be a number within +-0.05, got {}",
                self.laser_gain_error
            ));
        }
        if !self.clamp_mass_kg.is_finite() || self.clamp_mass_kg.abs() > 0.01 {
            return Err(format!(
                "bench '{id}': virtual.clamp_mass_kg must be a number within +-0.01 kg, got {}",
                self.clamp_mass_kg
            ));
        }
        self.part_effects
            .validate()
            .map_err(|e| format!("bench '{id}': virtual.part_{e}"))?;
        Ok(())
    }
}

impl BenchConfig {
    /// The `hardware` / `emulator` tables fit the kind, and the build can run it.
    pub fn validate_devices(&self) -> Result<(), String> {
        let id = &self.id;
        match (self.kind, &self.hardware) {
            (BenchKind::Virtual, Some(_)) => {
                return Err(format!(
                    "bench '{id}': a [benches.hardware] table needs kind = \"hardware\" or \"emulated\""
                ))
            }
            (BenchKind::Hardware | BenchKind::Emulated, None) => {
                return Err(format!(
                    "bench '{id}': kind = \"hardware\"/\"emulated\" needs a [benches.hardware] table (devices, calibration)"
                ))
            }
            (_, Some(h)) => h.validate(id)?,
            _ => {}
        }
        match (self.kind, &self.emulator) {
            (BenchKind::Emulated, Some(e)) => e.validate(id)?,
            (BenchKind::Emulated, None) => {}
            (_, Some(_)) => {
                return Err(format!(
                    "bench '{id}': a [benches.emulator] table needs kind = \"emulated\""
                ))
            }
            _ => {}
        }
        if let Some(a) = &self.ambient {
            a.validate(id, self.kind)?;
        }
        match (self.kind, &self.virtual_) {
            (BenchKind::Virtual, Some(v)) => v.validate(id)?,
            (_, Some(_)) => {
                return Err(format!(
                    "bench '{id}': a [benches.virtual] table needs kind = \"virtual\""
                ))
            }
            _ => {}
        }
        if self.kind != BenchKind::Virtual && !cfg!(feature = "hardware") {
            return Err(format!(
                "bench '{id}': this springbench was built without the `hardware` feature (cargo build --features hardware)"
            ));
        }
        Ok(())
    }
}

fn default_kind() -> BenchKind {
    BenchKind::Virtual
}
pub fn default_preset() -> String {
    DEFAULT_PRESET.to_string()
}
pub fn default_limits() -> Limits {
    Limits {
        max_displacement_m: 0.015,
        max_drive_v: 100.0,
    }
}

/// Preset mounted on the default virtual bench.
pub const DEFAULT_PRESET: &str = "spider_4in";

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn bench(laser: &str) -> BenchConfig {
        toml::from_str(&format!(
            r#"
id = "hw-1"
kind = "hardware"
[hardware]
output_device = "hw:1,0"
input_device = "hw:2,0"
[hardware.calibration]
dac_full_scale_v = 1.0
amplifier_gain = 100.0
adc_full_scale_v = 10.0
loopback_divider = 0.05
mic_sensitivity_v_per_pa = 0.0005
mic_calibrated_on = "2026-10-01"
{laser}
"#
        ))
        .unwrap()
    }

    /// The typed documents are the ones earlier versions wrote with `json!`
    /// in the runner, member for member: a stored self-check of an earlier
    /// version still matches the configuration after an upgrade (no forced
    /// self-check), and the fleet's records keep their shape.
    #[test]
    fn sensor_and_calibration_documents_keep_the_stored_shape() {
        for laser in [
            "",
            "[hardware.laser]\nkind = \"serial\"\nport = \"/dev/ttyUSB0\"\nbaud = 115200\nrate_hz = 2000.0\n\
             protocol = { name = \"keyence\", range_m = 0.02 }\nmodel = \"LK-G32\"\nserial = \"K-7\"\n",
        ] {
            let b = bench(laser);
            let h = b.hardware.as_ref().unwrap();
            let before = json!({
                "laser": h.laser,
                "microphone": {"sensitivity_v_per_pa": h.calibration.mic_sensitivity_v_per_pa,
                               "calibrated_on": h.calibration.mic_calibrated_on},
                "input_device": h.input_device, "output_device": h.output_device,
            });
            assert_eq!(b.sensors_document(), before);
            assert_eq!(
                b.sensors_document().to_string(),
                before.to_string(),
                "same text, member order included"
            );
            assert_eq!(b.sensors_document()["microphone"]["calibrated_on"], "2026-10-01");
            assert_eq!(
                b.calibration_document(),
                serde_json::to_value(&h.calibration).unwrap()
            );
            assert_eq!(b.calibration_document()["amplifier_gain"], 100.0);
        }
        let mut v = bench("");
        v.hardware = None;
        assert_eq!(v.sensors_document(), serde_json::Value::Null);
        assert_eq!(v.calibration_document(), serde_json::Value::Null);
    }

    #[test]
    fn an_ambient_sensor_reads_its_known_values_or_says_why_not() {
        let b: BenchConfig = toml::from_str(
            "id = \"v\"\n[ambient]\nkind = \"emulated\"\ntemperature_k = 296.15\ntemperature_k_per_h = 0.5\nrelative_humidity_percent = 40.0\nrelative_humidity_percent_per_h = -1.0\n",
        )
        .unwrap();
        b.validate_devices().unwrap();
        let a = b.ambient.as_ref().unwrap().read(7200.0).unwrap();
        assert_eq!(a.temperature_k, Some(297.15));
        assert_eq!(a.relative_humidity_percent, Some(38.0));
        // Drifted out of range: refused, not stored.
        assert!(b.ambient.as_ref().unwrap().read(3600.0 * 41.0).is_err());
        let dir = std::env::temp_dir().join(format!("sb-hwmon-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("temp1_input"), "23450\n").unwrap();
        std::fs::write(dir.join("humidity1_input"), "41250\n").unwrap();
        let h = AmbientSensor::Hwmon {
            temperature_path: dir.join("temp1_input"),
            humidity_path: Some(dir.join("humidity1_input")),
        };
        let a = h.read(0.0).unwrap();
        assert!((a.temperature_k.unwrap() - 296.6).abs() < 1e-9);
        assert_eq!(a.relative_humidity_percent, Some(41.25));
        std::fs::write(dir.join("humidity1_input"), "garbage").unwrap();
        assert!(h.read(0.0).unwrap_err().contains("not a number"));
        std::fs::remove_dir_all(&dir).unwrap();
        let bad: BenchConfig = toml::from_str(
            "id = \"v\"\n[ambient]\nkind = \"emulated\"\ntemperature_k = 23.0\nrelative_humidity_percent = 40.0\n",
        )
        .unwrap();
        assert!(bad
            .validate_devices()
            .unwrap_err()
            .contains("ambient.temperature_k"));
    }
}
