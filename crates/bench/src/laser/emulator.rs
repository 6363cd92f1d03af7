//! A serial laser emulator on a pseudo-terminal (feature `hardware`): speaks
//! each protocol (answers identity and start/stop commands, streams or
//! answers polls) with its own clock, so the real open-by-path and reader
//! code ([`super::serial::SerialLaser`]) runs against it.
//!
//! The displacement comes from a [`DisplacementFeed`] in audio-clock time:
//! a precomputed trajectory ([`TrajectoryFeed`]) or a live ring that an
//! emulated audio device fills as its physics runs ([`SharedFeed`]). Device
//! sample `n` is taken at audio time `offset_s + n / (rate_hz (1 + ppm
//! 1e-6)) + jitter`; it is sent when the feed has reached that time (and, with
//! [`Pacing::Wall`], not before that time on the wall clock), in chunks of
//! `chunk_s` like a USB-serial adapter's latency timer.
//!
//! Faults on demand: garbage bytes, dropped samples, an out-of-range flag,
//! silence, and closing the pty (the reader then sees a hang-up).

use super::{optoncdt, ProtocolConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::collections::VecDeque;
use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::os::fd::{AsRawFd, BorrowedFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the feed has at an audio time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FeedValue {
    Value(f64),
    /// The producer has not reached this time yet: ask again later.
    NotYet,
}

/// Displacement (m) as a function of audio-clock time (s).
pub trait DisplacementFeed: Send {
    fn sample(&mut self, t_audio_s: f64) -> FeedValue;
    /// The latest audio time the feed can answer, if it is a live one (a
    /// polled sensor answers with the value "now").
    fn latest_s(&self) -> Option<f64> {
        None
    }
}

/// A precomputed trajectory: `x[k]` at audio time `start_s + k / rate_hz`,
/// `rest_m` outside it; always available.
#[derive(Debug, Clone)]
pub struct TrajectoryFeed {
    pub start_s: f64,
    pub rate_hz: f64,
    pub x_m: Vec<f64>,
    pub rest_m: f64,
}

impl DisplacementFeed for TrajectoryFeed {
    fn sample(&mut self, t: f64) -> FeedValue {
        FeedValue::Value(cubic(&self.x_m, (t - self.start_s) * self.rate_hz).unwrap_or(self.rest_m))
    }
}

/// Catmull-Rom value at fractional index `u`; `None` outside the samples.
fn cubic(x: &[f64], u: f64) -> Option<f64> {
    if x.is_empty() || !(u >= 0.0 && u <= (x.len() - 1) as f64) {
        return None;
    }
    let i = u.floor() as i64;
    let f = u - i as f64;
    let g = |k: i64| x[k.clamp(0, x.len() as i64 - 1) as usize];
    let (p0, p1, p2, p3) = (g(i - 1), g(i), g(i + 1), g(i + 2));
    Some(
        p1 + 0.5
            * f
            * (p2 - p0
                + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0))),
    )
}

/// A live feed: the emulated audio device pushes blocks of the simulated
/// displacement with the audio time of their first sample, continuously
/// (also between sweeps: a real input clock never stops), and the laser
/// emulator reads it at its own clock. Keeps the last `keep_s` seconds.
#[derive(Debug, Clone)]
pub struct SharedFeed {
    inner: Arc<Mutex<Ring>>,
}

#[derive(Debug)]
struct Ring {
    rate_hz: f64,
    /// Audio time of `x[0]`.
    start_s: f64,
    x: VecDeque<f64>,
    keep: usize,
}

impl SharedFeed {
    /// A feed at `rate_hz` (the audio rate) keeping `keep_s` seconds.
    pub fn new(rate_hz: f64, keep_s: f64) -> SharedFeed {
        SharedFeed {
            inner: Arc::new(Mutex::new(Ring {
                rate_hz,
                start_s: f64::NAN,
                x: VecDeque::new(),
                keep: (keep_s * rate_hz).ceil().max(8.0) as usize,
            })),
        }
    }

    /// Appends a block whose first sample is at audio time `start_s`. Blocks
    /// must follow each other (a block that does not continue the previous
    /// one restarts the ring).
    pub fn push(&self, start_s: f64, x_m: &[f64]) {
        let mut r = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let end = r.start_s + r.x.len() as f64 / r.rate_hz;
        if !(r.start_s.is_finite() && ((start_s - end) * r.rate_hz).abs() < 0.5) {
            r.x.clear();
            r.start_s = start_s;
        }
        r.x.extend(x_m.iter().copied());
        let over = r.x.len().saturating_sub(r.keep);
        if over > 0 {
            r.x.drain(..over);
            r.start_s += over as f64 / r.rate_hz;
        }
    }
}

impl DisplacementFeed for SharedFeed {
    fn sample(&mut self, t: f64) -> FeedValue {
        let r = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if !r.start_s.is_finite() || r.x.is_empty() {
            return FeedValue::NotYet;
        }
        let u = (t - r.start_s) * r.rate_hz;
        // Two samples of look-ahead for the cubic.
        if u > r.x.len() as f64 - 3.0 {
            return FeedValue::NotYet;
        }
        let i = u.floor().max(0.0) as usize;
        let lo = i.saturating_sub(1);
        let hi = (i + 3).min(r.x.len());
        let seg: Vec<f64> = r.x.range(lo..hi).copied().collect();
        FeedValue::Value(cubic(&seg, u - lo as f64).unwrap_or(r.x[0]))
    }

    fn latest_s(&self) -> Option<f64> {
        let r = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        (r.start_s.is_finite() && r.x.len() >= 4)
            .then(|| r.start_s + (r.x.len() - 3) as f64 / r.rate_hz)
    }
}

/// When samples leave the emulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// As soon as the feed has them (tests with a precomputed trajectory).
    Unpaced,
    /// Not before `epoch + t_audio` on the wall clock (audio time = wall time since `epoch`).
    Wall { epoch: Instant },
}

/// The emulated sensor.
#[derive(Debug, Clone)]
pub struct EmulatorConfig {
    pub protocol: ProtocolConfig,
    pub rate_hz: f64,
    /// Clock error (ppm, + = fast) and audio time of sample 0 (s).
    pub ppm: f64,
    pub offset_s: f64,
    /// Sampling-instant jitter (s RMS).
    pub jitter_s: f64,
    /// Measurement noise (m RMS).
    pub noise_m: f64,
    /// Bytes are written in chunks of this much device time (s), as a USB-serial latency timer does.
    pub chunk_s: f64,
    pub pacing: Pacing,
    /// What `GETINFO` answers (optoNCDT).
    pub model: String,
    pub serial: String,
    pub seed: u64,
}

impl EmulatorConfig {
    /// Audio time of device sample `n`.
    pub fn t_of(&self, n: u64) -> f64 {
        self.offset_s + n as f64 / (self.rate_hz * (1.0 + self.ppm * 1e-6))
    }
}

/// Faults requested from outside, acted on by the emulator thread.
#[derive(Debug, Default)]
struct Faults {
    garbage: AtomicBool,
    out_of_range: AtomicBool,
    silence: AtomicBool,
    close: AtomicBool,
    drop_samples: AtomicU64,
}

/// A running emulator. Dropping it closes the pty.
pub struct LaserEmulator {
    path: String,
    faults: Arc<Faults>,
    sent: Arc<AtomicU64>,
    closed_at: Arc<Mutex<Option<Instant>>>,
    thread: Option<JoinHandle<()>>,
}

impl LaserEmulator {
    /// Opens a pseudo-terminal pair and starts the emulator on its master side.
    pub fn spawn(
        cfg: EmulatorConfig,
        feed: Box<dyn DisplacementFeed>,
    ) -> std::io::Result<LaserEmulator> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        // SerialStream::pair registers with the reactor: build it inside a runtime,
        // then keep plain duplicates of the descriptors.
        let (master, slave, path) = rt.block_on(async {
            let (m, s) = tokio_serial::SerialStream::pair().map_err(std::io::Error::other)?;
            use tokio_serial::SerialPort;
            let path = s
                .name()
                .ok_or_else(|| std::io::Error::other("pty without a name"))?;
            // SAFETY: the descriptor is open for the duration of this borrow.
            let fd = unsafe { BorrowedFd::borrow_raw(m.as_raw_fd()) }.try_clone_to_owned()?;
            // Our own slave descriptor keeps the pty up until the reader opens
            // it by path (with no slave open, the master reads EIO).
            // SAFETY: as above.
            let sfd = unsafe { BorrowedFd::borrow_raw(s.as_raw_fd()) }.try_clone_to_owned()?;
            Ok::<_, std::io::Error>((File::from(fd), sfd, path))
        })?;
        drop(rt);
        let faults = Arc::new(Faults::default());
        let sent = Arc::new(AtomicU64::new(0));
        let closed_at = Arc::new(Mutex::new(None));
        let (f2, s2, c2) = (faults.clone(), sent.clone(), closed_at.clone());
        let thread = std::thread::Builder::new()
            .name("laser-emulator".into())
            .spawn(move || {
                run(cfg, feed, master, f2, s2, c2);
                drop(slave);
            })?;
        Ok(LaserEmulator {
            path,
            faults,
            sent,
            closed_at,
            thread: Some(thread),
        })
    }

    /// Path of the slave side (`/dev/pts/N`): configure the laser's `port` with it.
    pub fn path(&self) -> &str {
        &self.path
    }
    /// Sends bytes that are no frame of the protocol, once.
    pub fn inject_garbage(&self) {
        self.faults.garbage.store(true, Ordering::Release);
    }
    /// Flags the next sample out of range.
    pub fn out_of_range(&self) {
        self.faults.out_of_range.store(true, Ordering::Release);
    }
    /// Skips the next `n` samples (the counter runs on).
    pub fn drop_samples(&self, n: u64) {
        self.faults.drop_samples.store(n, Ordering::Release);
    }
    /// Stops sending (a cable pulled on an RS422 line closes nothing).
    pub fn go_silent(&self) {
        self.faults.silence.store(true, Ordering::Release);
    }
    /// Closes the pty master, like an unplugged USB adapter.
    pub fn close(&self) {
        self.faults.close.store(true, Ordering::Release);
    }
    /// A handle that requests faults from another thread (e.g. an emulated
    /// audio device's fault plan).
    pub fn controls(&self) -> EmulatorControls {
        EmulatorControls(self.faults.clone())
    }
    /// Device samples sent so far.
    pub fn samples_sent(&self) -> u64 {
        self.sent.load(Ordering::Acquire)
    }
    /// When the emulator closed the pty (after [`LaserEmulator::close`]).
    pub fn closed_at(&self) -> Option<Instant> {
        *self.closed_at.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Requests faults of a running [`LaserEmulator`].
#[derive(Debug, Clone)]
pub struct EmulatorControls(Arc<Faults>);

impl EmulatorControls {
    /// As [`LaserEmulator::close`].
    pub fn close(&self) {
        self.0.close.store(true, Ordering::Release);
    }
    /// As [`LaserEmulator::inject_garbage`].
    pub fn inject_garbage(&self) {
        self.0.garbage.store(true, Ordering::Release);
    }
}

impl Drop for LaserEmulator {
    fn drop(&mut self) {
        self.faults.close.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn encode(cfg: &EmulatorConfig, n: u64, x: f64, oor: bool, out: &mut Vec<u8>) {
    match &cfg.protocol {
        ProtocolConfig::Optoncdt(c) => {
            let d = if c.invert { -x } else { x };
            let raw = if oor {
                optoncdt::CODE_NO_TARGET
            } else {
                optoncdt::raw_of_displacement(d, c.range_m)
            };
            out.extend_from_slice(&optoncdt::encode_value(raw, false));
            if c.counter {
                let cnt = (n % (1 << optoncdt::COUNTER_BITS)) as u32;
                out.extend_from_slice(&optoncdt::encode_value(cnt, true));
            }
        }
        ProtocolConfig::AsciiLines(c) => {
            let d = if c.invert { -x } else { x } / c.unit_m;
            let v = if oor {
                "OOR".to_string()
            } else {
                format!("{d:.6}")
            };
            match c.counter_bits {
                Some(b) => {
                    out.extend_from_slice(format!("{},{v}\n", n % (1u64 << b.min(63))).as_bytes())
                }
                None => out.extend_from_slice(format!("{v}\n").as_bytes()),
            }
        }
        ProtocolConfig::Keyence(c) => {
            let d = if c.invert { -x } else { x } / c.unit_m;
            let v = if oor {
                "+FFFFFFF".to_string()
            } else {
                format!("{d:+.4}")
            };
            out.extend_from_slice(format!("MS,OUT{:02},{v}\r", c.head).as_bytes());
        }
    }
}

/// Writes all of `bytes` to the non-blocking master, waiting while the pty's
/// buffer is full (the reader is slower than an unpaced emulator); gives up
/// on a close request or an error.
fn write_all(port: &mut File, mut bytes: &[u8], faults: &Faults) -> bool {
    while !bytes.is_empty() {
        if faults.close.load(Ordering::Acquire) {
            return false;
        }
        match port.write(bytes) {
            Ok(0) => return false,
            Ok(k) => bytes = &bytes[k..],
            Err(e) if e.kind() == ErrorKind::WouldBlock || e.kind() == ErrorKind::Interrupted => {
                std::thread::sleep(Duration::from_micros(200))
            }
            Err(_) => return false,
        }
    }
    true
}

fn run(
    cfg: EmulatorConfig,
    mut feed: Box<dyn DisplacementFeed>,
    mut port: File,
    faults: Arc<Faults>,
    sent: Arc<AtomicU64>,
    closed_at: Arc<Mutex<Option<Instant>>>,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let polled = matches!(cfg.protocol, ProtocolConfig::Keyence(_));
    // Streams that need no start command stream from the beginning.
    let mut streaming = match &cfg.protocol {
        ProtocolConfig::AsciiLines(c) => c.start_command.is_none(),
        _ => false,
    };
    let mut cmd = Vec::new();
    let mut n: u64 = 0;
    let mut out = Vec::new();
    let mut chunk_end_t = f64::NEG_INFINITY;
    let mut buf = [0u8; 256];
    let started = Instant::now();
    let close = |port: File| {
        drop(port);
        *closed_at.lock().unwrap_or_else(|e| e.into_inner()) = Some(Instant::now());
    };
    loop {
        if faults.close.load(Ordering::Acquire) {
            close(port);
            return;
        }
        // Commands (the master is non-blocking).
        match port.read(&mut buf) {
            Ok(k) if k > 0 => cmd.extend_from_slice(&buf[..k]),
            Ok(_) => {}
            Err(e) if e.kind() == ErrorKind::WouldBlock => {}
            Err(_) => {
                close(port);
                return;
            }
        }
        while let Some(end) = cmd.iter().position(|&b| b == b'\r' || b == b'\n') {
            let line: Vec<u8> = cmd.drain(..=end).collect();
            let text = String::from_utf8_lossy(&line).trim().to_string();
            if text.is_empty() {
                continue;
            }
            let reply: Option<Vec<u8>> = match (&cfg.protocol, text.as_str()) {
                (ProtocolConfig::Optoncdt(c), "GETINFO") => Some(
                    format!(
                        "GETINFO\r\nName:      {}\r\nSerial:    {}\r\nMeasuring range: {} mm\r\nVersion:   emulator\r\n->\r\n",
                        cfg.model,
                        cfg.serial,
                        c.range_m * 1e3
                    )
                    .into_bytes(),
                ),
                (ProtocolConfig::Optoncdt(_), "OUTPUT RS422") => {
                    streaming = true;
                    Some(b"->\r\n".to_vec())
                }
                (ProtocolConfig::Optoncdt(_), "OUTPUT NONE") => {
                    streaming = false;
                    Some(b"->\r\n".to_vec())
                }
                (ProtocolConfig::Optoncdt(_), _) => Some(b"E200 unknown command\r\n->\r\n".to_vec()),
                (ProtocolConfig::AsciiLines(c), t) => {
                    if c.start_command.as_deref() == Some(t) {
                        streaming = true;
                    } else if c.stop_command.as_deref() == Some(t) {
                        streaming = false;
                    }
                    None
                }
                (ProtocolConfig::Keyence(c), t) => {
                    if t == format!("MS,{:02}", c.head) {
                        // The value now: audio time from the wall clock or the feed.
                        let t_now = match cfg.pacing {
                            Pacing::Wall { epoch } => epoch.elapsed().as_secs_f64(),
                            Pacing::Unpaced => feed.latest_s().unwrap_or_else(|| cfg.t_of(n)),
                        };
                        let x = match feed.sample(t_now) {
                            FeedValue::Value(x) => x,
                            FeedValue::NotYet => 0.0,
                        } + cfg.noise_m * rng.sample::<f64, _>(StandardNormal);
                        let mut r = Vec::new();
                        encode(&cfg, n, x, faults.out_of_range.swap(false, Ordering::AcqRel), &mut r);
                        n += 1;
                        sent.store(n, Ordering::Release);
                        Some(r)
                    } else {
                        Some(format!("ER,{},02\r", t.split(',').next().unwrap_or("")).into_bytes())
                    }
                }
            };
            if let Some(r) = reply {
                if !write_all(&mut port, &r, &faults) {
                    close(port);
                    return;
                }
            }
        }
        if polled || !streaming || faults.silence.load(Ordering::Acquire) {
            std::thread::sleep(Duration::from_micros(500));
            continue;
        }
        // Stream: produce the samples of the next chunk.
        if chunk_end_t == f64::NEG_INFINITY {
            chunk_end_t = cfg.t_of(n);
        }
        chunk_end_t += cfg.chunk_s.max(1e-4);
        let mut waiting = false;
        while cfg.t_of(n) < chunk_end_t {
            let t = cfg.t_of(n) + cfg.jitter_s * rng.sample::<f64, _>(StandardNormal);
            let x = match feed.sample(t) {
                FeedValue::Value(x) => x,
                FeedValue::NotYet => {
                    waiting = true;
                    break;
                }
            };
            let skip = faults.drop_samples.load(Ordering::Acquire);
            if skip > 0 {
                faults.drop_samples.store(skip - 1, Ordering::Release);
            } else {
                let x = x + cfg.noise_m * rng.sample::<f64, _>(StandardNormal);
                encode(
                    &cfg,
                    n,
                    x,
                    faults.out_of_range.swap(false, Ordering::AcqRel),
                    &mut out,
                );
            }
            n += 1;
        }
        if faults.garbage.swap(false, Ordering::AcqRel) {
            out.extend_from_slice(b"\xff\xfe\x00garbage\xc3\x28");
        }
        if let Pacing::Wall { epoch } = cfg.pacing {
            let due = epoch + Duration::from_secs_f64(chunk_end_t.max(0.0));
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        if !out.is_empty() {
            if !write_all(&mut port, &out, &faults) {
                close(port);
                return;
            }
            out.clear();
            sent.store(n, Ordering::Release);
        }
        if waiting {
            chunk_end_t = cfg.t_of(n);
            std::thread::sleep(Duration::from_micros(500));
        }
        let _ = started;
    }
}
