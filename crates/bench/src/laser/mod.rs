//! Laser displacement sensors on a serial line: the protocols (pure frame
//! parsers, always compiled, unit-tested and fuzzable) and the source seam the
//! hardware bench reads samples from.
//!
//! Layers:
//! - [`LaserProtocol`]: one sensor family's commands (identity, start, stop,
//!   poll) and an incremental parser `bytes -> Reading`s. Pure: no I/O, never
//!   panics on any input. Implementations: [`optoncdt`] (Micro-Epsilon
//!   optoNCDT-style binary RS422 stream), [`keyence`] (Keyence LK-G-style
//!   polled ASCII), [`ascii_lines`] (one value per line, streamed).
//! - [`LaserSource`]: what a bench uses: identity, nominal rate, `start`, a
//!   non-blocking `poll` of the samples received so far (device index and
//!   displacement), typed faults. The serial implementation is
//!   `serial::SerialLaser` (feature `hardware`); it runs the protocol on its own
//!   reader thread.
//! - The samples are put on the audio time base by [`crate::align`]
//!   (never from their arrival times).
//!
//! Adding a protocol: one module implementing [`LaserProtocol`] plus one arm in
//! [`ProtocolConfig`] / [`ProtocolConfig::build`]; see docs/hardware.md.

pub mod ascii_lines;
pub mod keyence;
pub mod optoncdt;

#[cfg(feature = "hardware")]
pub mod emulator;
#[cfg(feature = "hardware")]
pub mod serial;

use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

/// What a sensor says about itself (read at start where the protocol allows,
/// otherwise taken from the configuration); stored with every measurement.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LaserIdentity {
    /// Protocol name as configured (`optoncdt`, `keyence`, `ascii_lines`).
    pub protocol: String,
    /// Sensor model, e.g. `ILD1420-10`; empty when neither the sensor nor the configuration says.
    pub model: String,
    /// Serial number; empty when unknown.
    pub serial: String,
    /// Firmware version; empty when unknown.
    #[serde(default)]
    pub firmware: String,
    /// Measuring range (m, full span); `None` when unknown.
    pub range_m: Option<f64>,
    /// True when model/serial/range were read from the sensor, false when they come from the configuration.
    pub read_from_sensor: bool,
}

/// Where a sample's time comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleClock {
    /// The sensor numbers its samples (measurement counter): the index is the
    /// device's, lost samples show as gaps.
    DeviceCounter,
    /// The sensor streams at its own rate without a counter: the index counts
    /// the values received (a lost value would shift the time base undetected).
    DeviceStream,
    /// The host polls; a sample's only time is the host's poll time (no device
    /// clock: the alignment cannot be established to microseconds).
    HostPoll,
}

/// One item out of a protocol parser.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// A displacement (m, from the middle of the measuring range, positive
    /// away from the sensor as configured) with the device's counter if the
    /// frame carries one (raw, wraps at `2^counter_bits`).
    Value {
        displacement_m: f64,
        counter: Option<u32>,
    },
    /// The sensor flagged this sample out of its measuring range (no target,
    /// too near, too far).
    OutOfRange { code: u32, counter: Option<u32> },
    /// The sensor reported an error (a code it sent instead of a value, or an
    /// error reply to a command).
    DeviceError { code: String },
}

/// A frame the parser could not accept. Always a fault: the byte stream is
/// not what the configured protocol sends (wrong protocol or baud rate, line
/// noise, a sensor in another mode).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("garbage from the laser at byte {offset}: {reason}")]
pub struct FrameError {
    /// Offset of the offending byte in the bytes fed since the parser was made (or reset).
    pub offset: u64,
    pub reason: String,
}

/// One sensor family's protocol: commands and an incremental frame parser.
///
/// Implementations are pure (no I/O, no clock) and must never panic, whatever
/// bytes they are fed; errors are values. A parser keeps its partial frame
/// between calls to [`LaserProtocol::feed`], so bytes may arrive in chunks of
/// any size.
pub trait LaserProtocol: Send {
    /// Short name as used in the configuration (`optoncdt`, ...).
    fn name(&self) -> &'static str;
    /// Where the samples' time comes from.
    fn clock(&self) -> SampleClock;
    /// Width of the device counter in bits (it wraps at `2^bits`), if frames carry one.
    fn counter_bits(&self) -> Option<u32>;
    /// Bytes that ask the sensor for its identity, if the protocol has such a command.
    fn identity_request(&self) -> Option<Vec<u8>>;
    /// Parses the reply to [`LaserProtocol::identity_request`] accumulated so far:
    /// `Ok(None)` = incomplete, wait for more bytes.
    fn parse_identity(&self, reply: &[u8]) -> Result<Option<LaserIdentity>, FrameError>;
    /// Bytes that start the value stream (streamed protocols); `None` if the
    /// sensor streams by itself or is polled.
    fn start_request(&self) -> Option<Vec<u8>>;
    /// Bytes that stop the value stream, if any.
    fn stop_request(&self) -> Option<Vec<u8>>;
    /// Bytes that ask for one value (polled protocols only).
    fn poll_request(&self) -> Option<Vec<u8>>;
    /// Feeds received bytes; complete readings are appended to `out`. On a
    /// garbage frame, the readings before it are in `out` and the error is
    /// returned; the parser is then in an undefined-but-safe state (call
    /// [`LaserProtocol::reset`] before reusing it).
    fn feed(&mut self, bytes: &[u8], out: &mut Vec<Reading>) -> Result<(), FrameError>;
    /// Forgets any partial frame (after a restart of the stream).
    fn reset(&mut self);
}

/// The protocol of a serial laser, as configured (`[benches.hardware.laser]`
/// with `kind = "serial"`, field `protocol`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "name", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProtocolConfig {
    /// Micro-Epsilon optoNCDT-style binary stream.
    Optoncdt(optoncdt::OptoncdtConfig),
    /// Keyence LK-G-style polled ASCII.
    Keyence(keyence::KeyenceConfig),
    /// One value per line, streamed.
    AsciiLines(ascii_lines::AsciiLinesConfig),
}

impl ProtocolConfig {
    /// A fresh parser for this configuration.
    pub fn build(&self) -> Box<dyn LaserProtocol> {
        match self {
            ProtocolConfig::Optoncdt(c) => Box::new(optoncdt::Optoncdt::new(c.clone())),
            ProtocolConfig::Keyence(c) => Box::new(keyence::Keyence::new(c.clone())),
            ProtocolConfig::AsciiLines(c) => Box::new(ascii_lines::AsciiLines::new(c.clone())),
        }
    }

    /// One-line error naming the first implausible field.
    pub fn validate(&self) -> Result<(), String> {
        match self {
            ProtocolConfig::Optoncdt(c) => c.validate(),
            ProtocolConfig::Keyence(c) => c.validate(),
            ProtocolConfig::AsciiLines(c) => c.validate(),
        }
    }
}

/// A serial laser as configured: port, line settings, protocol, identity fallback.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialLaserConfig {
    /// Device path, e.g. `/dev/ttyUSB0` (as `springbench devices` lists it).
    pub port: String,
    /// Line speed (baud, 8N1).
    pub baud: u32,
    /// Nominal sample rate of the sensor (streamed) or the poll rate (polled) (Hz).
    pub rate_hz: f64,
    pub protocol: ProtocolConfig,
    /// Model and serial when the protocol cannot ask the sensor.
    #[serde(default)]
    pub model: String,
    #[serde(default)]
    pub serial: String,
    /// A streamed sensor that sends nothing for this long is a fault (s); default 0.05.
    #[serde(default = "default_stall_s")]
    pub stall_timeout_s: f64,
}

fn default_stall_s() -> f64 {
    0.05
}

impl SerialLaserConfig {
    /// One-line error naming the first implausible field.
    pub fn validate(&self) -> Result<(), String> {
        if self.port.trim().is_empty() {
            return Err("laser.port must name a serial device".into());
        }
        if !(300..=4_000_000).contains(&self.baud) {
            return Err(format!(
                "laser.baud must be 300..=4000000, got {}",
                self.baud
            ));
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 100_000.0) {
            return Err(format!(
                "laser.rate_hz must be in (0, 100000], got {}",
                self.rate_hz
            ));
        }
        if !(self.stall_timeout_s.is_finite() && (0.001..=10.0).contains(&self.stall_timeout_s)) {
            return Err(format!(
                "laser.stall_timeout_s must be in [0.001, 10] s, got {}",
                self.stall_timeout_s
            ));
        }
        self.protocol
            .validate()
            .map_err(|e| format!("laser.protocol: {e}"))
    }
}

/// One displacement sample from a [`LaserSource`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserSample {
    /// Device sample index: the unwrapped device counter ([`SampleClock::DeviceCounter`]),
    /// the count of values since `start` ([`SampleClock::DeviceStream`]), or the
    /// count of polls ([`SampleClock::HostPoll`]). Increases strictly; a jump
    /// of more than one is a dropout.
    pub index: u64,
    /// Host time (s since the `epoch` given to [`LaserSource::start`]) at which
    /// the bytes arrived (streamed) or the poll was sent (polled). Coarse
    /// (USB-serial adapters deliver in chunks of up to ~16 ms): only a seed for
    /// the alignment, never the time base.
    pub host_time_s: f64,
    /// Displacement (m).
    pub displacement_m: f64,
}

/// Kinds of laser faults, as a small number for [`FaultWatch`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LaserFaultKind {
    /// The port closed or hung up (unplugged adapter, closed pseudo-terminal).
    Eof,
    /// A read or write failed.
    Io,
    /// Bytes that are not frames of the configured protocol.
    Garbage,
    /// The sensor flagged a sample out of its measuring range.
    OutOfRange,
    /// The sensor reported an error.
    DeviceError,
    /// A streamed sensor went silent (no value for `stall_timeout_s`), or a poll was not answered.
    Stalled,
}

impl LaserFaultKind {
    fn code(self) -> u8 {
        match self {
            LaserFaultKind::Eof => 1,
            LaserFaultKind::Io => 2,
            LaserFaultKind::Garbage => 3,
            LaserFaultKind::OutOfRange => 4,
            LaserFaultKind::DeviceError => 5,
            LaserFaultKind::Stalled => 6,
        }
    }
    fn from_code(c: u8) -> Option<LaserFaultKind> {
        Some(match c {
            1 => LaserFaultKind::Eof,
            2 => LaserFaultKind::Io,
            3 => LaserFaultKind::Garbage,
            4 => LaserFaultKind::OutOfRange,
            5 => LaserFaultKind::DeviceError,
            6 => LaserFaultKind::Stalled,
            _ => return None,
        })
    }
}

/// A laser fault. Every fault is a safety event: the bench ramps the drive down.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LaserError {
    /// The port could not be opened or configured.
    #[error("laser: cannot open {port}: {reason}")]
    Open { port: String, reason: String },
    /// The identity query failed or was not answered.
    #[error("laser: identity: {0}")]
    Identity(String),
    #[error("laser: the serial port closed (unplugged?) after {samples} samples")]
    Eof { samples: u64 },
    #[error("laser: read/write error: {0}")]
    Io(String),
    #[error("laser: {0}")]
    Garbage(#[from] FrameError),
    /// `index` is the device index of the flagged sample (or of the last good one).
    #[error("laser: out of range (code {code}) at sample {index}")]
    OutOfRange { index: u64, code: u32 },
    #[error("laser: sensor error {code}")]
    DeviceError { code: String },
    #[error("laser: no value for {silent_ms:.0} ms")]
    Stalled { silent_ms: f64 },
    /// `start` was not called, or the source was stopped.
    #[error("laser: not started")]
    NotStarted,
}

impl LaserError {
    /// The kind, for [`FaultWatch`] and for the bench's fault report.
    pub fn kind(&self) -> LaserFaultKind {
        match self {
            LaserError::Open { .. } | LaserError::Io(_) | LaserError::NotStarted => {
                LaserFaultKind::Io
            }
            LaserError::Identity(_) | LaserError::Stalled { .. } => LaserFaultKind::Stalled,
            LaserError::Eof { .. } => LaserFaultKind::Eof,
            LaserError::Garbage(_) => LaserFaultKind::Garbage,
            LaserError::OutOfRange { .. } => LaserFaultKind::OutOfRange,
            LaserError::DeviceError { .. } => LaserFaultKind::DeviceError,
        }
    }
}

/// A cheap, clonable view of a source's fault state, readable from any thread
/// without locks (e.g. inside the audio output callback, to start the
/// ramp-down the moment the reader thread sees a fault).
#[derive(Debug, Clone, Default)]
pub struct FaultWatch(Arc<AtomicU8>);

impl FaultWatch {
    pub fn new() -> FaultWatch {
        FaultWatch::default()
    }
    /// The first fault raised since the last [`FaultWatch::clear`], if any.
    pub fn fault(&self) -> Option<LaserFaultKind> {
        LaserFaultKind::from_code(self.0.load(Ordering::Acquire))
    }
    /// Records a fault (the first one wins).
    pub fn raise(&self, kind: LaserFaultKind) {
        let _ = self
            .0
            .compare_exchange(0, kind.code(), Ordering::AcqRel, Ordering::Acquire);
    }
    pub fn clear(&self) {
        self.0.store(0, Ordering::Release);
    }
}

/// A displacement sensor as the hardware bench sees it.
///
/// Contract:
/// - [`LaserSource::start`] opens the stream (streamed protocols) or starts
///   polling at `nominal_rate_hz` (polled ones) on the source's own thread.
///   Indices restart at the device's counter (or at 0 without one).
/// - [`LaserSource::poll`] never blocks: it moves every sample received since
///   the previous call into `out` (in index order) and returns the fault, if
///   one happened, *after* delivering the samples that preceded it. A fault
///   is sticky until the next `start`.
/// - Faults reach [`LaserSource::fault_watch`] as soon as the reader sees
///   them (a closed port, a garbage frame or an out-of-range flag within
///   milliseconds; a silent sensor after `stall_timeout_s`).
pub trait LaserSource: Send {
    /// Identity read at open (or configured).
    fn identity(&self) -> &LaserIdentity;
    /// Nominal sample rate (Hz): the sensor's rate, or the poll rate.
    fn nominal_rate_hz(&self) -> f64;
    fn clock(&self) -> SampleClock;
    /// Starts streaming/polling; `epoch` is the zero of the samples' `host_time_s`.
    fn start(&mut self, epoch: std::time::Instant) -> Result<(), LaserError>;
    /// Non-blocking: appends new samples to `out`; `Err` once a fault happened.
    fn poll(&mut self, out: &mut Vec<LaserSample>) -> Result<(), LaserError>;
    /// Lock-free fault flag shared with the reader thread.
    fn fault_watch(&self) -> FaultWatch;
    /// Stops streaming/polling (the port stays open; `start` again to resume).
    fn stop(&mut self);
    /// Arms (default after `start`) or disarms the silence watch: a bench
    /// disarms it between sweeps, when an emulated sensor has nothing to
    /// send; arming restarts the silence clock.
    fn arm(&mut self, _armed: bool) {}
}

/// Unwraps a device counter of `bits` bits into a monotonic index.
#[derive(Debug, Clone, Default)]
pub struct CounterUnwrapper {
    last: Option<u64>,
}

impl CounterUnwrapper {
    /// The unwrapped index of raw `counter` (wrapping at `2^bits`): the
    /// smallest index greater than the previous one with these low bits.
    pub fn unwrap(&mut self, counter: u32, bits: u32) -> u64 {
        let bits = bits.clamp(1, 32);
        let modulus = 1u64 << bits;
        let c = u64::from(counter) & (modulus - 1);
        let idx = match self.last {
            None => c,
            Some(last) => {
                let base = last - last % modulus;
                let mut i = base + c;
                if i <= last {
                    i += modulus;
                }
                i
            }
        };
        self.last = Some(idx);
        idx
    }
    pub fn reset(&mut self) {
        self.last = None;
    }
}

/// Feeds `bytes` to a fresh parser of `config` in one go: the plain entry
/// point for fuzzing and tests (`fn(&[u8]) -> ...`).
pub fn parse_stream(config: &ProtocolConfig, bytes: &[u8]) -> Result<Vec<Reading>, FrameError> {
    let mut p = config.build();
    let mut out = Vec::new();
    p.feed(bytes, &mut out).map(|_| out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_unwraps_across_wraps_and_gaps() {
        let mut u = CounterUnwrapper::default();
        let bits = 18;
        let m = 1u32 << bits;
        assert_eq!(u.unwrap(m - 2, bits), u64::from(m - 2));
        assert_eq!(u.unwrap(m - 1, bits), u64::from(m - 1));
        assert_eq!(u.unwrap(0, bits), u64::from(m));
        // A gap of 5 across nothing special.
        assert_eq!(u.unwrap(6, bits), u64::from(m) + 6);
        // A repeated counter is not allowed to go back: it jumps a full wrap.
        assert_eq!(u.unwrap(6, bits), 2 * u64::from(m) + 6);
    }

    /// Random bytes, random chunkings, every protocol: never a panic, never a
    /// non-finite value (the fuzz harness drives the same entry points).
    #[test]
    fn parsers_never_panic_on_random_bytes() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(10);
        let configs = [
            ProtocolConfig::Optoncdt(optoncdt::OptoncdtConfig {
                range_m: 0.01,
                counter: true,
                invert: false,
            }),
            ProtocolConfig::Optoncdt(optoncdt::OptoncdtConfig {
                range_m: 0.01,
                counter: false,
                invert: true,
            }),
            ProtocolConfig::Keyence(keyence::KeyenceConfig {
                head: 1,
                unit_m: 1e-3,
                range_m: None,
                invert: false,
            }),
            ProtocolConfig::AsciiLines(ascii_lines::AsciiLinesConfig::default()),
            ProtocolConfig::AsciiLines(ascii_lines::AsciiLinesConfig {
                counter_bits: Some(16),
                ..ascii_lines::AsciiLinesConfig::default()
            }),
        ];
        // Alphabets: anything, ASCII-ish, marker-shaped bytes.
        let alphabet = |k: usize, r: &mut rand_chacha::ChaCha8Rng| -> u8 {
            match k {
                0 => r.random(),
                1 => {
                    let a = b"0123456789.,-+\r\nMSOUTERF; ";
                    a[r.random_range(0..a.len())]
                }
                _ => (r.random_range(0..3u8) << 6) | r.random_range(0..64u8),
            }
        };
        let mut values = 0;
        for round in 0..3000 {
            let len = rng.random_range(0..400);
            let k = round % 3;
            let bytes: Vec<u8> = (0..len).map(|_| alphabet(k, &mut rng)).collect();
            for cfg in &configs {
                let mut p = cfg.build();
                let mut out = Vec::new();
                let mut i = 0;
                while i < bytes.len() {
                    let n = rng.random_range(1..=32).min(bytes.len() - i);
                    if p.feed(&bytes[i..i + n], &mut out).is_err() {
                        break;
                    }
                    i += n;
                }
                for r in &out {
                    if let Reading::Value { displacement_m, .. } = r {
                        assert!(displacement_m.is_finite());
                        values += 1;
                    }
                }
                let _ = parse_stream(cfg, &bytes);
                let _ = p.parse_identity(&bytes);
            }
            let _ = optoncdt::parse_getinfo(&bytes);
        }
        // The marker-shaped alphabet does produce values (the loop reaches the decoder).
        assert!(values > 20, "{values}");
    }

    #[test]
    fn fault_watch_keeps_the_first_fault() {
        let w = FaultWatch::new();
        assert_eq!(w.fault(), None);
        let w2 = w.clone();
        w2.raise(LaserFaultKind::Garbage);
        w2.raise(LaserFaultKind::Eof);
        assert_eq!(w.fault(), Some(LaserFaultKind::Garbage));
        w.clear();
        assert_eq!(w2.fault(), None);
    }
}
