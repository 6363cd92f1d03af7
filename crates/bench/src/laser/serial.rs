//! [`SerialLaser`]: a [`LaserSource`] on a serial port (feature `hardware`).
//!
//! The port is opened by path with tokio-serial's builder (`serialport`
//! underneath, no libudev) and read by a dedicated blocking thread with a
//! 1 ms read timeout, so a closed port, a garbage frame or an out-of-range
//! flag reaches the [`FaultWatch`] within about a millisecond of the bytes
//! (or the hang-up) arriving; a silent sensor after `stall_timeout_s`.

use super::{
    CounterUnwrapper, FaultWatch, LaserError, LaserIdentity, LaserProtocol, LaserSample,
    LaserSource, Reading, SampleClock, SerialLaserConfig,
};
use std::io::{ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

type Port = Box<dyn tokio_serial::SerialPort>;

/// What the reader thread shares with the bench.
#[derive(Default)]
struct Shared {
    samples: Vec<LaserSample>,
    fault: Option<LaserError>,
}

/// A serial laser.
pub struct SerialLaser {
    cfg: SerialLaserConfig,
    identity: LaserIdentity,
    clock: SampleClock,
    port: Option<Port>,
    protocol: Option<Box<dyn LaserProtocol>>,
    shared: Arc<Mutex<Shared>>,
    watch: FaultWatch,
    stop: Arc<AtomicBool>,
    /// The silence watch is on (see [`LaserSource::arm`]).
    armed: Arc<AtomicBool>,
    thread: Option<JoinHandle<(Port, Box<dyn LaserProtocol>)>>,
}

fn io_err(e: std::io::Error, samples: u64) -> LaserError {
    match e.kind() {
        ErrorKind::UnexpectedEof | ErrorKind::BrokenPipe | ErrorKind::ConnectionReset => {
            LaserError::Eof { samples }
        }
        // A pty whose master closed answers EIO.
        _ if e.raw_os_error() == Some(5) => LaserError::Eof { samples },
        _ => LaserError::Io(e.to_string()),
    }
}

impl SerialLaser {
    /// Opens the port, configures it and reads the identity (where the
    /// protocol has a command for it; otherwise the configured one).
    pub fn open(cfg: &SerialLaserConfig) -> Result<SerialLaser, LaserError> {
        cfg.validate().map_err(|reason| LaserError::Open {
            port: cfg.port.clone(),
            reason,
        })?;
        let mut port = tokio_serial::new(&cfg.port, cfg.baud)
            .timeout(Duration::from_millis(1))
            .open()
            .map_err(|e| LaserError::Open {
                port: cfg.port.clone(),
                reason: e.to_string(),
            })?;
        let mut protocol = cfg.protocol.build();
        let mut identity = LaserIdentity {
            protocol: protocol.name().to_string(),
            model: cfg.model.clone(),
            serial: cfg.serial.clone(),
            firmware: String::new(),
            range_m: None,
            read_from_sensor: false,
        };
        if let Some(req) = protocol.identity_request() {
            if let Some(stop) = protocol.stop_request() {
                port.write_all(&stop).map_err(|e| io_err(e, 0))?;
                drain(&mut port, Duration::from_millis(20));
            }
            port.write_all(&req).map_err(|e| io_err(e, 0))?;
            let deadline = Instant::now() + Duration::from_millis(500);
            let mut reply = Vec::new();
            let mut buf = [0u8; 256];
            loop {
                match port.read(&mut buf) {
                    Ok(0) => return Err(LaserError::Eof { samples: 0 }),
                    Ok(n) => reply.extend_from_slice(&buf[..n]),
                    Err(e)
                        if e.kind() == ErrorKind::TimedOut || e.kind() == ErrorKind::WouldBlock => {
                    }
                    Err(e) => return Err(io_err(e, 0)),
                }
                match protocol.parse_identity(&reply) {
                    Ok(Some(id)) => {
                        identity = LaserIdentity {
                            model: if id.model.is_empty() {
                                identity.model
                            } else {
                                id.model
                            },
                            serial: if id.serial.is_empty() {
                                identity.serial
                            } else {
                                id.serial
                            },
                            ..id
                        };
                        break;
                    }
                    Ok(None) => {}
                    Err(e) => return Err(LaserError::Identity(e.reason)),
                }
                if Instant::now() > deadline {
                    return Err(LaserError::Identity(format!(
                        "no complete answer within 500 ms ({} bytes)",
                        reply.len()
                    )));
                }
            }
        }
        if identity.range_m.is_none() {
            identity.range_m = match &cfg.protocol {
                super::ProtocolConfig::Optoncdt(c) => Some(c.range_m),
                super::ProtocolConfig::Keyence(c) => c.range_m,
                super::ProtocolConfig::AsciiLines(c) => c.range_m,
            };
        }
        // Scale with the range the sensor reported.
        if let (super::ProtocolConfig::Optoncdt(c), Some(r)) = (&cfg.protocol, identity.range_m) {
            let mut c = c.clone();
            c.range_m = r;
            protocol = Box::new(super::optoncdt::Optoncdt::new(c));
        }
        Ok(SerialLaser {
            cfg: cfg.clone(),
            clock: protocol.clock(),
            identity,
            port: Some(port),
            protocol: Some(protocol),
            shared: Arc::default(),
            watch: FaultWatch::new(),
            stop: Arc::new(AtomicBool::new(false)),
            armed: Arc::new(AtomicBool::new(true)),
            thread: None,
        })
    }

    fn join(&mut self) {
        if let Some(t) = self.thread.take() {
            self.stop.store(true, Ordering::Release);
            if let Ok((port, proto)) = t.join() {
                self.port = Some(port);
                self.protocol = Some(proto);
            }
        }
    }
}

fn drain(port: &mut Port, d: Duration) {
    let end = Instant::now() + d;
    let mut buf = [0u8; 256];
    while Instant::now() < end {
        if !matches!(port.read(&mut buf), Ok(n) if n > 0) {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

impl LaserSource for SerialLaser {
    fn identity(&self) -> &LaserIdentity {
        &self.identity
    }
    fn nominal_rate_hz(&self) -> f64 {
        self.cfg.rate_hz
    }
    fn clock(&self) -> SampleClock {
        self.clock
    }
    fn fault_watch(&self) -> FaultWatch {
        self.watch.clone()
    }

    fn start(&mut self, epoch: Instant) -> Result<(), LaserError> {
        self.join();
        let (Some(mut port), Some(mut proto)) = (self.port.take(), self.protocol.take()) else {
            return Err(LaserError::NotStarted);
        };
        proto.reset();
        *self.shared.lock().unwrap_or_else(|e| e.into_inner()) = Shared::default();
        self.watch.clear();
        self.stop.store(false, Ordering::Release);
        if let Some(req) = proto.start_request() {
            if let Err(e) = port.write_all(&req) {
                let e = io_err(e, 0);
                self.port = Some(port);
                self.protocol = Some(proto);
                self.watch.raise(e.kind());
                return Err(e);
            }
        }
        let shared = self.shared.clone();
        let watch = self.watch.clone();
        let stop = self.stop.clone();
        let armed = self.armed.clone();
        let rate = self.cfg.rate_hz;
        let stall = Duration::from_secs_f64(self.cfg.stall_timeout_s);
        let thread = std::thread::Builder::new()
            .name("laser-reader".into())
            .spawn(move || {
                let r = read_loop(
                    &mut port,
                    proto.as_mut(),
                    epoch,
                    rate,
                    stall,
                    &shared,
                    &stop,
                    &armed,
                );
                if let Err(e) = r {
                    watch.raise(e.kind());
                    shared.lock().unwrap_or_else(|e| e.into_inner()).fault = Some(e);
                }
                if let Some(req) = proto.stop_request() {
                    let _ = port.write_all(&req);
                }
                (port, proto)
            })
            .map_err(|e| LaserError::Io(format!("reader thread: {e}")))?;
        self.thread = Some(thread);
        Ok(())
    }

    fn poll(&mut self, out: &mut Vec<LaserSample>) -> Result<(), LaserError> {
        if self.thread.is_none() {
            return Err(LaserError::NotStarted);
        }
        let mut s = self.shared.lock().unwrap_or_else(|e| e.into_inner());
        out.append(&mut s.samples);
        match &s.fault {
            Some(e) => Err(e.clone()),
            None => Ok(()),
        }
    }

    fn stop(&mut self) {
        self.join();
    }

    fn arm(&mut self, armed: bool) {
        self.armed.store(armed, Ordering::Release);
    }
}

impl Drop for SerialLaser {
    fn drop(&mut self) {
        self.join();
    }
}

/// The reader thread: feeds bytes to the protocol, numbers the samples,
/// polls (polled protocols), watches for silence (when armed).
#[allow(clippy::too_many_arguments)]
fn read_loop(
    port: &mut Port,
    proto: &mut dyn LaserProtocol,
    epoch: Instant,
    rate_hz: f64,
    stall: Duration,
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
    armed: &AtomicBool,
) -> Result<(), LaserError> {
    let clock = proto.clock();
    let bits = proto.counter_bits();
    let poll_req = proto.poll_request();
    let poll_period = Duration::from_secs_f64(1.0 / rate_hz);
    let mut unwrap = CounterUnwrapper::default();
    let mut count: u64 = 0;
    let mut buf = [0u8; 4096];
    let mut readings = Vec::new();
    let mut last_value = Instant::now();
    let mut next_poll = Instant::now();
    let mut poll_sent: Option<Instant> = None;
    let mut batch = Vec::new();
    let mut was_armed = true;
    while !stop.load(Ordering::Acquire) {
        // Polled: one request in flight, at the configured rate.
        if let Some(req) = &poll_req {
            let now = Instant::now();
            if poll_sent.is_none() && now >= next_poll {
                port.write_all(req).map_err(|e| io_err(e, count))?;
                poll_sent = Some(now);
                next_poll += poll_period;
                if next_poll < now {
                    next_poll = now + poll_period;
                }
            }
        }
        let n = match port.read(&mut buf) {
            Ok(0) => return Err(LaserError::Eof { samples: count }),
            Ok(n) => n,
            Err(e) if e.kind() == ErrorKind::TimedOut || e.kind() == ErrorKind::WouldBlock => 0,
            Err(e) => return Err(io_err(e, count)),
        };
        let arrived = Instant::now();
        if n > 0 {
            readings.clear();
            let parsed = proto.feed(&buf[..n], &mut readings);
            for r in readings.drain(..) {
                let host_time_s = match (clock, poll_sent.take()) {
                    (SampleClock::HostPoll, Some(t)) => {
                        t.saturating_duration_since(epoch).as_secs_f64()
                    }
                    _ => arrived.saturating_duration_since(epoch).as_secs_f64(),
                };
                let index = |counter: Option<u32>, unwrap: &mut CounterUnwrapper, count: u64| match (
                    counter, bits,
                ) {
                    (Some(c), Some(b)) => unwrap.unwrap(c, b),
                    _ => count,
                };
                match r {
                    Reading::Value {
                        displacement_m,
                        counter,
                    } => {
                        let i = index(counter, &mut unwrap, count);
                        count += 1;
                        last_value = arrived;
                        batch.push(LaserSample {
                            index: i,
                            host_time_s,
                            displacement_m,
                        });
                    }
                    Reading::OutOfRange { code, counter } => {
                        let i = index(counter, &mut unwrap, count);
                        flush(shared, &mut batch);
                        return Err(LaserError::OutOfRange { index: i, code });
                    }
                    Reading::DeviceError { code } => {
                        flush(shared, &mut batch);
                        return Err(LaserError::DeviceError { code });
                    }
                }
            }
            flush(shared, &mut batch);
            parsed?;
        }
        // Silence: a streamed sensor that stopped, or an unanswered poll.
        let is_armed = armed.load(Ordering::Acquire);
        if is_armed && !was_armed {
            last_value = arrived;
            if poll_sent.is_some() {
                poll_sent = Some(arrived);
            }
        }
        was_armed = is_armed;
        let silent = arrived.saturating_duration_since(last_value);
        let poll_late = poll_sent.is_some_and(|t| arrived.saturating_duration_since(t) > stall);
        if !is_armed {
            if poll_late {
                // Unwatched: ask again rather than wait forever.
                poll_sent = None;
            }
            continue;
        }
        if silent > stall.max(poll_period * 3) || poll_late {
            return Err(LaserError::Stalled {
                silent_ms: silent.as_secs_f64() * 1e3,
            });
        }
    }
    Ok(())
}

fn flush(shared: &Mutex<Shared>, batch: &mut Vec<LaserSample>) {
    if !batch.is_empty() {
        shared
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .samples
            .append(batch);
    }
}
