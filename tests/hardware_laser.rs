//! The serial laser through the real code: the emulator on a pseudo-terminal
//! speaks each protocol with its own clock (4 kHz, +150 ppm, 3 ms offset,
//! 16 ms USB chunks, paced by the wall clock), `SerialLaser` opens the pty
//! by path and reads it on its thread, and the alignment puts the samples
//! on the audio clock of the simulated microphone. Faults are made for real:
//! garbage bytes on the line, a closed pty, an out-of-range flag, silence.
//!
//! `cargo test --features hardware --test hardware_laser -- --nocapture`
//! prints the measured figures (alignment, fault latencies) for docs/hardware.md.
#![cfg(feature = "hardware")]

use springbench::bench::align::{AlignConfig, AudioCapture, JobAligner, LaserTrack};
use springbench::bench::laser::emulator::{
    DisplacementFeed, EmulatorConfig, LaserEmulator, Pacing, TrajectoryFeed,
};
use springbench::bench::laser::serial::SerialLaser;
use springbench::bench::laser::{
    ascii_lines::AsciiLinesConfig, keyence::KeyenceConfig, optoncdt::OptoncdtConfig, LaserError,
    LaserFaultKind, LaserSample, LaserSource, ProtocolConfig, SampleClock, SerialLaserConfig,
};
use springbench::bench::simulate::simulate;
use springbench::bench::simulate::SimulateOptions;
use springbench::physics::preset;
use std::time::{Duration, Instant};

const PPM: f64 = 150.0;
const OFFSET_S: f64 = 3e-3;
const RATE_HZ: f64 = 4000.0;

fn emu_cfg(protocol: ProtocolConfig, pacing: Pacing) -> EmulatorConfig {
    EmulatorConfig {
        protocol,
        rate_hz: RATE_HZ,
        ppm: PPM,
        offset_s: OFFSET_S,
        jitter_s: 0.0,
        noise_m: 0.0,
        chunk_s: 0.016,
        pacing,
        model: "ILD1420-40 (emulated)".into(),
        serial: "EMU-0001".into(),
        seed: 7,
    }
}

fn laser_cfg(port: &str, protocol: ProtocolConfig, rate_hz: f64) -> SerialLaserConfig {
    SerialLaserConfig {
        port: port.into(),
        baud: 921_600,
        rate_hz,
        protocol,
        model: "configured model".into(),
        serial: "configured serial".into(),
        stall_timeout_s: 0.05,
    }
}

fn opto() -> ProtocolConfig {
    ProtocolConfig::Optoncdt(OptoncdtConfig {
        range_m: 0.04,
        counter: true,
        invert: false,
    })
}

fn ascii() -> ProtocolConfig {
    ProtocolConfig::AsciiLines(AsciiLinesConfig::default())
}

/// Reads samples until `until` (wall clock).
fn collect(laser: &mut SerialLaser, until: Instant) -> Vec<LaserSample> {
    let mut v = Vec::new();
    while Instant::now() < until {
        laser.poll(&mut v).unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
    laser.poll(&mut v).unwrap();
    v
}

/// A resting feed (x = 0.5 mm) for the fault tests.
fn rest() -> Box<dyn DisplacementFeed> {
    Box::new(TrajectoryFeed {
        start_s: 0.0,
        rate_hz: 1.0,
        x_m: vec![],
        rest_m: 0.5e-3,
    })
}

#[test]
fn streamed_protocols_are_aligned_to_the_audio_clock() {
    let part = preset("spider_4in").unwrap();
    let sim = simulate(&part, 3, &SimulateOptions::default()).unwrap();
    let pre = &sim.outcome.pre;
    let fs = pre.sample_rate_hz;
    let dur_s = pre.len() as f64 / fs;
    let epoch = Instant::now();
    let feed = || -> Box<dyn DisplacementFeed> {
        Box::new(TrajectoryFeed {
            start_s: 0.0,
            rate_hz: fs,
            x_m: pre.displacement_m.clone(),
            rest_m: 0.0,
        })
    };
    let mut runs = Vec::new();
    for protocol in [opto(), ascii()] {
        let emu = LaserEmulator::spawn(emu_cfg(protocol.clone(), Pacing::Wall { epoch }), feed())
            .unwrap();
        let mut laser = SerialLaser::open(&laser_cfg(emu.path(), protocol, RATE_HZ)).unwrap();
        laser.start(epoch).unwrap();
        runs.push((emu, laser));
    }
    let until = epoch + Duration::from_secs_f64(dur_s + 0.4);
    let handles: Vec<_> = runs
        .into_iter()
        .map(|(emu, mut laser)| {
            std::thread::spawn(move || {
                let s = collect(&mut laser, until);
                (emu, laser, s)
            })
        })
        .collect();
    for h in handles {
        let (_emu, laser, samples) = h.join().unwrap();
        let id = laser.identity().clone();
        let mut al = JobAligner::new(AlignConfig::default());
        let out = al.align(
            &AudioCapture {
                sample_rate_hz: fs,
                start_s: 0.0,
                audio_epoch: 0,
                host_start_s: 0.0,
                microphone: &pre.microphone_v,
                max_drive_hz: Some(sim.outcome.pre_sweep.f_end_hz),
            },
            &LaserTrack {
                nominal_rate_hz: laser.nominal_rate_hz(),
                clock: laser.clock(),
                samples: &samples,
            },
        );
        let r = &out.report;
        let e = (out
            .displacement_m
            .iter()
            .zip(&pre.displacement_m)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / pre.len() as f64)
            .sqrt();
        eprintln!(
            "{} ({:?}): {} samples, valid {} {:?}, ratio {:.2} ppm (+-{:.2}), offset {:.1} us, residual {:.2} us RMS (max {:.2}), x error {:.3} um RMS, identity {:?}",
            id.protocol,
            laser.clock(),
            samples.len(),
            r.valid,
            r.invalid_reason,
            r.ratio_ppm,
            r.ratio_stderr_ppm,
            r.offset_s * 1e6,
            r.residual_rms_s * 1e6,
            r.residual_max_s * 1e6,
            e * 1e6,
            id
        );
        assert!(r.valid, "{}: {:?}", id.protocol, r.invalid_reason);
        assert!(
            (r.ratio_ppm - PPM).abs() < 10.0,
            "{}: {} ppm",
            id.protocol,
            r.ratio_ppm
        );
        assert!(
            r.residual_rms_s < 10e-6,
            "{}: {}",
            id.protocol,
            r.residual_rms_s
        );
        // 16-bit over 40 mm and the truth's own 1 um noise: a few micrometres.
        assert!(e < 3e-6, "{}: x error {e}", id.protocol);
        if laser.clock() == SampleClock::DeviceCounter {
            assert!(
                (r.offset_s - OFFSET_S).abs() < 10e-6,
                "offset {}",
                r.offset_s
            );
            assert_eq!(id.model, "ILD1420-40 (emulated)");
            assert_eq!(id.serial, "EMU-0001");
            assert_eq!(id.range_m, Some(0.04));
            assert!(id.read_from_sensor);
        } else {
            assert_eq!(id.model, "configured model");
            assert!(!id.read_from_sensor);
        }
    }
}

#[test]
fn the_polled_protocol_reads_values_but_is_marked_invalid() {
    let protocol = ProtocolConfig::Keyence(KeyenceConfig {
        head: 1,
        unit_m: 1e-3,
        range_m: Some(0.02),
        invert: false,
    });
    let epoch = Instant::now();
    let emu =
        LaserEmulator::spawn(emu_cfg(protocol.clone(), Pacing::Wall { epoch }), rest()).unwrap();
    let mut laser = SerialLaser::open(&laser_cfg(emu.path(), protocol, 500.0)).unwrap();
    assert_eq!(laser.clock(), SampleClock::HostPoll);
    laser.start(epoch).unwrap();
    let samples = collect(&mut laser, epoch + Duration::from_millis(1500));
    assert!(samples.len() > 100, "{}", samples.len());
    for s in &samples {
        assert!((s.displacement_m - 0.5e-3).abs() < 1e-7, "{s:?}");
    }
    let mic = vec![0.0; 48_000];
    let out = JobAligner::new(AlignConfig::default()).align(
        &AudioCapture {
            sample_rate_hz: 48_000.0,
            start_s: 0.2,
            audio_epoch: 0,
            host_start_s: 0.2,
            microphone: &mic,
            max_drive_hz: Some(100.0),
        },
        &LaserTrack {
            nominal_rate_hz: 500.0,
            clock: laser.clock(),
            samples: &samples,
        },
    );
    assert!(!out.report.valid);
    let why = out.report.invalid_reason.unwrap();
    eprintln!("polled: {} samples in 1.5 s, invalid: {why}", samples.len());
    assert!(why.contains("no device clock"), "{why}");
}

/// Starts an optoNCDT stream at rest, lets it run 200 ms, applies `fault`,
/// and returns the error and the time from `fault` to the fault flag.
fn fault_case(
    fault: impl FnOnce(&LaserEmulator) -> Instant,
) -> (LaserError, Duration, Vec<LaserSample>) {
    let epoch = Instant::now();
    let emu = LaserEmulator::spawn(emu_cfg(opto(), Pacing::Wall { epoch }), rest()).unwrap();
    let mut laser = SerialLaser::open(&laser_cfg(emu.path(), opto(), RATE_HZ)).unwrap();
    laser.start(epoch).unwrap();
    let watch = laser.fault_watch();
    let mut samples = collect(&mut laser, Instant::now() + Duration::from_millis(200));
    assert!(samples.len() > 400, "{}", samples.len());
    assert_eq!(watch.fault(), None);
    let t0 = fault(&emu);
    let deadline = Instant::now() + Duration::from_secs(5);
    while watch.fault().is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_micros(100));
    }
    let dt = t0.elapsed();
    assert!(watch.fault().is_some(), "no fault flagged within 5 s");
    let err = loop {
        match laser.poll(&mut samples) {
            Err(e) => break e,
            Ok(()) => std::thread::sleep(Duration::from_millis(1)),
        }
    };
    assert_eq!(watch.fault(), Some(err.kind()));
    drop(emu);
    (err, dt, samples)
}

#[test]
fn garbage_on_the_line_is_a_typed_fault() {
    let (e, dt, _) = fault_case(|emu| {
        emu.inject_garbage();
        Instant::now()
    });
    eprintln!(
        "garbage: {e} flagged {:.1} ms after the request (16 ms chunks)",
        dt.as_secs_f64() * 1e3
    );
    assert!(matches!(e, LaserError::Garbage(_)), "{e}");
}

#[test]
fn a_closed_pty_is_a_typed_fault() {
    let (e, dt, _) = fault_case(|emu| {
        emu.close();
        let t = Instant::now();
        while emu.closed_at().is_none() {
            std::thread::sleep(Duration::from_micros(50));
        }
        emu.closed_at().unwrap_or(t)
    });
    eprintln!(
        "closed pty: {e} flagged {:.2} ms after the close",
        dt.as_secs_f64() * 1e3
    );
    assert_eq!(e.kind(), LaserFaultKind::Eof, "{e}");
}

#[test]
fn out_of_range_and_silence_are_typed_faults() {
    let (e, dt, _) = fault_case(|emu| {
        emu.out_of_range();
        Instant::now()
    });
    eprintln!(
        "out of range: {e} flagged {:.1} ms after the request",
        dt.as_secs_f64() * 1e3
    );
    assert!(
        matches!(e, LaserError::OutOfRange { code: 262_075, .. }),
        "{e}"
    );

    let (e, dt, _) = fault_case(|emu| {
        emu.go_silent();
        Instant::now()
    });
    eprintln!(
        "silence: {e} flagged {:.1} ms after the sensor stopped",
        dt.as_secs_f64() * 1e3
    );
    assert_eq!(e.kind(), LaserFaultKind::Stalled, "{e}");
}

#[test]
fn dropped_samples_show_as_index_gaps() {
    let epoch = Instant::now();
    let emu = LaserEmulator::spawn(emu_cfg(opto(), Pacing::Wall { epoch }), rest()).unwrap();
    let mut laser = SerialLaser::open(&laser_cfg(emu.path(), opto(), RATE_HZ)).unwrap();
    laser.start(epoch).unwrap();
    let mut s = collect(&mut laser, Instant::now() + Duration::from_millis(100));
    emu.drop_samples(5);
    s.extend(collect(
        &mut laser,
        Instant::now() + Duration::from_millis(100),
    ));
    let gaps: Vec<u64> = s
        .windows(2)
        .map(|w| w[1].index - w[0].index)
        .filter(|&d| d != 1)
        .collect();
    assert_eq!(gaps, vec![6], "index steps other than 1");
}

#[test]
fn a_missing_port_is_a_one_line_open_error() {
    let e = SerialLaser::open(&laser_cfg(
        "/dev/does-not-exist-springbench",
        opto(),
        RATE_HZ,
    ))
    .err()
    .unwrap();
    assert!(matches!(e, LaserError::Open { .. }), "{e}");
    assert!(!e.to_string().contains('\n'));
}
