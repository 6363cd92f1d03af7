//! The cpal code itself, against ALSA `file` PCMs (no sound card needed):
//! opening devices by name, the output's f32 -> S16_LE conversion by a
//! `plug` wrapper, fixed buffers, the loopback latency and channel map through
//! the real streams, the drive limit in the output file, and the error paths
//! (unknown device, a fault in the captured data).
#![cfg(feature = "hardware")]

use springbench::bench::hardware::cpal_io::CpalAudio;
use springbench::bench::hardware::HardwareBench;
use springbench::bench::settings::{Calibration, ChannelMap, HardwareConfig, LaserConfig};
use springbench::bench::{Bench, BenchError, Control, Limits};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

const FS: f64 = 48000.0;
/// Latency written into the prepared capture (samples).
const DELAY: usize = 137;

struct Files {
    dir: PathBuf,
}

/// ALSA reads its configuration once per process: one asoundrc for all tests,
/// and the tests take turns (the PCMs share files).
fn alsa() -> &'static Mutex<Files> {
    static F: OnceLock<Mutex<Files>> = OnceLock::new();
    F.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("springbench-alsa-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rc = format!(
            r#"
pcm.bench_out_file {{ type file slave.pcm "null" file "{d}/out.raw" format "raw" }}
pcm.bench_out {{
    type plug
    slave {{ pcm "bench_out_file" format S16_LE channels 2 rate 48000 }}
    hint {{ show on description "springbench test output (file)" }}
}}
pcm.bench_in {{
    type file slave.pcm "null" file "/dev/null" infile "{d}/in.raw" format "raw"
    hint {{ show on description "springbench test input (file)" }}
}}
"#,
            d = dir.display()
        );
        let path = dir.join("bench.asoundrc");
        std::fs::write(&path, rc).unwrap();
        // Before any ALSA call in this process.
        std::env::set_var(
            "ALSA_CONFIG_PATH",
            format!("/usr/share/alsa/alsa.conf:{}", path.display()),
        );
        Mutex::new(Files { dir })
    })
}

fn hw() -> HardwareConfig {
    HardwareConfig {
        output_device: "bench_out".into(),
        input_device: "bench_in".into(),
        sample_rate_hz: 48000,
        buffer_frames: 480,
        output_channels: 2,
        input_channels: 4,
        channels: ChannelMap {
            drive: 0,
            microphone: 0,
            loopback: 1,
            laser: 2,
        },
        calibration: Calibration {
            dac_full_scale_v: 1.0,
            amplifier_gain: 20.0,
            adc_full_scale_v: 10.0,
            loopback_divider: 0.1,
            mic_sensitivity_v_per_pa: 0.001,
            mic_calibrated_on: "2026-10-01".into(),
        },
        laser: LaserConfig::Analog {
            scale_m_per_v: 0.002,
            offset_m: 0.0,
            range_m: 0.02,
            model: String::new(),
            serial: String::new(),
        },
        max_latency_s: 0.05,
        ramp_down_s: 0.01,
    }
}

/// The drive: a 40 -> 400 Hz sweep, 16 V peak, 0.5 s (amplifier V).
fn drive() -> Vec<f64> {
    let n = (0.5 * FS) as usize;
    (0..n)
        .map(|k| {
            let t = k as f64 / FS;
            16.0 * (2.0 * std::f64::consts::PI * (40.0 * t + 360.0 * t * t)).sin()
        })
        .collect()
}

/// The prepared capture (f32 little-endian, 4 channels: cpal picks f32 on the
/// file PCM; a `plug` in front of a capturing `file` PCM drops a period now
/// and then, so the input is not wrapped): microphone a 1 kHz tone of
/// 0.5 V, the loopback the clamped drive `DELAY` samples late, the laser
/// `laser_v(k)`, channel 3 silent. Long enough that capture never runs dry.
fn write_capture(dir: &Path, drive_v: &[f64], limit_v: f64, laser_v: impl Fn(usize) -> f64) {
    let c = hw().calibration;
    let n = drive_v.len() + 20 * 48000;
    let mut bytes = Vec::with_capacity(n * 16);
    let q = |v: f64| (v / c.adc_full_scale_v).clamp(-1.0, 1.0) as f32;
    for k in 0..n {
        let mic = 0.5 * (2.0 * std::f64::consts::PI * 1000.0 * k as f64 / FS).sin();
        let u = if k >= DELAY && k - DELAY < drive_v.len() {
            drive_v[k - DELAY].clamp(-limit_v, limit_v)
        } else {
            0.0
        };
        for v in [mic, u * c.loopback_divider, laser_v(k), 0.0] {
            bytes.extend_from_slice(&q(v).to_le_bytes());
        }
    }
    std::fs::write(dir.join("in.raw"), bytes).unwrap();
    let _ = std::fs::remove_file(dir.join("out.raw"));
}

fn bench(limits: Limits) -> HardwareBench {
    let hw = hw();
    let audio = CpalAudio::open(&hw).expect("open the file PCMs by name");
    HardwareBench::new("alsa-file", hw, limits, Box::new(audio))
}

#[test]
fn a_sweep_through_cpal_and_alsa_file_pcms() {
    let files = alsa().lock().unwrap_or_else(|e| e.into_inner());
    let d = drive();
    // The drive limit (15 V) is below the sweep's 16 V peak: the output must be clamped.
    let limits = Limits {
        max_displacement_m: 0.01,
        max_drive_v: 15.0,
    };
    write_capture(&files.dir, &d, limits.max_drive_v, |_| 1.25);
    let mut b = bench(limits);
    assert!(b.describe().contains("bench_out"), "{}", b.describe());
    let mut blocks = 0;
    let s = b
        .run(&d, &mut |_| {
            blocks += 1;
            Control::Continue
        })
        .expect("the sweep runs");
    assert_eq!(s.len(), d.len());
    assert!(blocks >= d.len() / 480, "{blocks} blocks");
    // Latency found from the loopback through the real stream and the S32 conversion.
    let r = b.runs()[0].clone();
    println!("alsa file PCMs: {r:?}");
    assert!((r.latency_samples - DELAY as f64).abs() < 0.05, "{r:?}");
    assert!(r.loopback_correlation > 0.999_999, "{r:?}");
    assert!((r.loopback_gain - 1.0).abs() < 0.02, "{r:?}");
    assert!(r.drive_clamped_samples > 0, "{r:?}");
    // Channels in SI and aligned: drive = clamped digital drive, laser 1.25 V * 2 mm/V, microphone 1 kHz.
    let u = s.drive_v.as_ref().unwrap();
    for k in (0..d.len()).step_by(97) {
        assert!(
            (u[k] - d[k].clamp(-15.0, 15.0)).abs() < 1e-5,
            "drive {k}: {} vs {}",
            u[k],
            d[k]
        );
        assert!((s.displacement_m[k] - 0.0025).abs() < 1e-8, "laser {k}");
        let mic = 0.5 * (2.0 * std::f64::consts::PI * 1000.0 * (k + DELAY) as f64 / FS).sin();
        assert!((s.microphone_v[k] - mic).abs() < 1e-6, "mic {k}");
    }
    // What the output device got: S16_LE stereo, drive on channel 0 in DAC units, clamped to 15 V / 20 = 0.75.
    let out = std::fs::read(files.dir.join("out.raw")).unwrap();
    let frames: Vec<(i16, i16)> = out
        .chunks_exact(4)
        .map(|c| {
            (
                i16::from_le_bytes([c[0], c[1]]),
                i16::from_le_bytes([c[2], c[3]]),
            )
        })
        .collect();
    assert!(frames.len() >= d.len(), "{} frames written", frames.len());
    let peak = frames.iter().map(|f| f.0.unsigned_abs()).max().unwrap();
    assert!(
        (peak as f64 / 32768.0 - 0.75).abs() < 1e-3,
        "output peak {peak}"
    );
    assert!(frames.iter().all(|f| f.1 == 0), "channel 1 stays silent");
    for k in (0..d.len()).step_by(101) {
        let want = (d[k].clamp(-15.0, 15.0) / 20.0 * 32768.0).clamp(-32768.0, 32767.0);
        assert!(
            (frames[k].0 as f64 - want).abs() <= 1.5,
            "out {k}: {} vs {want}",
            frames[k].0
        );
    }
}

#[test]
fn the_laser_out_of_range_in_the_capture_faults_the_sweep() {
    let files = alsa().lock().unwrap_or_else(|e| e.into_inner());
    let d = drive();
    let limits = Limits {
        max_displacement_m: 0.01,
        max_drive_v: 100.0,
    };
    // 0.2 s in, the laser output jumps to 11 V: beyond the ADC, beyond the range.
    write_capture(&files.dir, &d, 100.0, |k| if k > 9600 { 11.0 } else { 0.0 });
    let mut b = bench(limits);
    let e = b.run(&d, &mut |_| Control::Continue).unwrap_err();
    match e {
        BenchError::Fault(m) => assert!(m.contains("laser out of range"), "{m}"),
        e => panic!("expected a fault, got {e}"),
    }
}

#[test]
fn an_unknown_device_is_refused_by_name() {
    let _files = alsa().lock().unwrap_or_else(|e| e.into_inner());
    let mut h = hw();
    h.input_device = "no_such_pcm".into();
    let e = CpalAudio::open(&h).err().expect("refused");
    let m = e.to_string();
    assert!(m.contains("no_such_pcm"), "{m}");
}
