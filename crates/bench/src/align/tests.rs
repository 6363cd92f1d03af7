//! Alignment against the project's physics: a simulated job (pre-measurement
//! and narrow sweep of `spider_4in`), its displacement sampled by a laser
//! with its own clock (4 kHz, +150 ppm, 3 ms offset, 16 ms USB chunks), the
//! microphone on the audio clock; the alignment must recover the clock and
//! put x back where it was, well enough for K(x) within 0.5 % RMS.

use super::*;
use crate::laser::{LaserSample, SampleClock};
use crate::simulate::{simulate, SimulateOptions, Simulation};
use springbench_core::physics::preset;
use std::sync::OnceLock;

/// The emulated laser clock: sample `n` is taken at audio time `offset + n / (rate (1 + ppm))`.
#[derive(Clone, Copy)]
struct Clock {
    rate_hz: f64,
    ppm: f64,
    offset_s: f64,
}

impl Clock {
    fn t(&self, n: u64) -> f64 {
        self.offset_s + n as f64 / (self.rate_hz * (1.0 + self.ppm * 1e-6))
    }
    fn n_at(&self, t: f64) -> f64 {
        (t - self.offset_s) * self.rate_hz * (1.0 + self.ppm * 1e-6)
    }
}

const CLOCK: Clock = Clock {
    rate_hz: 4000.0,
    ppm: 150.0,
    offset_s: 3e-3,
};
/// Where the narrow sweep starts on the audio clock (after the pre-measurement).
const NARROW_START_S: f64 = 40.0;

fn sim() -> &'static Simulation {
    static SIM: OnceLock<Simulation> = OnceLock::new();
    SIM.get_or_init(|| {
        simulate(
            &preset("spider_4in").unwrap(),
            1,
            &SimulateOptions::default(),
        )
        .unwrap()
    })
}

/// Cubic (Catmull-Rom) value of `x` (rate `fs`, first sample at `start_s`) at audio time `t`.
fn at(x: &[f64], fs: f64, start_s: f64, t: f64) -> f64 {
    let u = (t - start_s) * fs;
    let i = u.floor() as i64;
    let f = u - i as f64;
    let g = |k: i64| x[k.clamp(0, x.len() as i64 - 1) as usize];
    let (p0, p1, p2, p3) = (g(i - 1), g(i), g(i + 1), g(i + 2));
    p1 + 0.5
        * f
        * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3 + f * (3.0 * (p1 - p2) + p3 - p0)))
}

/// The laser's samples of the displacement `x` of a sweep starting at audio
/// time `start_s`, from 0.3 s before to 0.3 s after it (at rest outside),
/// quantised to 16 bits over 40 mm, arriving in 16 ms USB chunks.
fn laser_samples(x: &[f64], fs: f64, start_s: f64, clock: Clock) -> Vec<LaserSample> {
    let end_s = start_s + x.len() as f64 / fs;
    let n0 = clock.n_at(start_s - 0.3).ceil().max(0.0) as u64;
    let n1 = clock.n_at(end_s + 0.3).floor() as u64;
    let q = 0.04 / 65536.0;
    (n0..=n1)
        .map(|n| {
            let t = clock.t(n);
            let v = if t < start_s || t > end_s {
                0.0
            } else {
                at(x, fs, start_s, t)
            };
            LaserSample {
                index: n,
                host_time_s: (t / 0.016).ceil() * 0.016 + 0.002,
                displacement_m: (v / q).round() * q,
            }
        })
        .collect()
}

fn capture<'a>(mic: &'a [f64], fs: f64, start_s: f64, f_max: f64) -> AudioCapture<'a> {
    AudioCapture {
        sample_rate_hz: fs,
        start_s,
        audio_epoch: 0,
        host_start_s: start_s,
        microphone: mic,
        max_drive_hz: Some(f_max),
    }
}

fn track(samples: &[LaserSample]) -> LaserTrack<'_> {
    LaserTrack {
        nominal_rate_hz: CLOCK.rate_hz,
        clock: SampleClock::DeviceCounter,
        samples,
    }
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

#[test]
fn a_job_is_aligned_to_the_truth_and_k_of_x_survives() {
    let sim = sim();
    let out = &sim.outcome;
    let fs = out.pre.sample_rate_hz;
    let narrow = &out.narrow[0];
    let pre_laser = laser_samples(&out.pre.displacement_m, fs, 0.0, CLOCK);
    let nar_laser = laser_samples(&narrow.signals.displacement_m, fs, NARROW_START_S, CLOCK);
    let mut al = JobAligner::new(AlignConfig::default());
    let a = al.align(
        &capture(&out.pre.microphone_v, fs, 0.0, out.pre_sweep.f_end_hz),
        &track(&pre_laser),
    );
    let b = al.align(
        &capture(
            &narrow.signals.microphone_v,
            fs,
            NARROW_START_S,
            narrow.f_end_hz,
        ),
        &track(&nar_laser),
    );
    for (name, r) in [("pre", &a.report), ("narrow", &b.report)] {
        eprintln!(
            "{name}: valid {} ({:?}), offset {:.3} us, ratio {:.3} ppm (+-{:.3}), residual {:.3} us (max {:.3}), line se {:.3} us, windows {}/{}, fit {:.4}, iterations {}",
            r.valid,
            r.invalid_reason,
            r.offset_s * 1e6,
            r.ratio_ppm,
            r.ratio_stderr_ppm,
            r.residual_rms_s * 1e6,
            r.residual_max_s * 1e6,
            r.line_stderr_s * 1e6,
            r.windows,
            r.job_windows,
            r.fit_residual,
            r.iterations
        );
        assert!(r.valid, "{name}: {:?}", r.invalid_reason);
        assert!(
            (r.ratio_ppm - CLOCK.ppm).abs() < 10.0,
            "{name}: {} ppm",
            r.ratio_ppm
        );
        assert!(
            r.residual_rms_s < 10e-6,
            "{name}: residual {}",
            r.residual_rms_s
        );
        assert!(
            (r.offset_s - CLOCK.offset_s).abs() < 10e-6,
            "{name}: offset {}",
            r.offset_s
        );
    }
    // The aligned displacement is the simulated one (up to the laser's band and quantisation).
    for (name, x_al, x_true) in [
        ("pre", &a.displacement_m, &out.pre.displacement_m),
        ("narrow", &b.displacement_m, &narrow.signals.displacement_m),
    ] {
        let e = rms(x_al.iter().zip(x_true.iter()).map(|(p, q)| p - q));
        let s = rms(x_true.iter().copied());
        eprintln!(
            "{name}: x error {:.3} um RMS of {:.3} mm RMS",
            e * 1e6,
            s * 1e3
        );
        // The 48 kHz truth carries 1 um of white noise the 4 kHz laser cannot see.
        assert!(e < 1.5e-6, "{name}: x error {e}");
    }
    // K(x) through identify, with the aligned displacement.
    let mut set = sim.set.clone();
    set.pre.displacement_m = a.displacement_m.clone();
    set.main.displacement_m = b.displacement_m.clone();
    let r = springbench_core::identify::analyze(
        &set,
        &springbench_core::identify::AnalyzeOptions::default(),
    )
    .unwrap();
    let truth = &preset("spider_4in").unwrap().k_coeffs_si;
    let range = r.stiffness.valid_range_m;
    let k = |c: &[f64], x: f64| c.iter().rev().fold(0.0, |acc, &ci| acc * x + ci);
    let (mut se, mut st) = (0.0, 0.0);
    for i in 0..=400 {
        let x = range[0] + (range[1] - range[0]) * i as f64 / 400.0;
        se += (k(&r.stiffness.coefficients_n_per_m_pow_i_plus_1, x) - k(truth, x)).powi(2);
        st += k(truth, x).powi(2);
    }
    let e = (se / st).sqrt();
    eprintln!("K(x) through the serial laser: {:.3} % RMS", e * 100.0);
    assert!(e < 0.005, "K(x) {:.3} % RMS", e * 100.0);
}

#[test]
fn a_misaligned_laser_would_spoil_k_of_x() {
    // The control of the test above: the same job with the laser taken at its
    // nominal clock and zero offset (what arrival order gives) is far off.
    let sim = sim();
    let out = &sim.outcome;
    let fs = out.pre.sample_rate_hz;
    let narrow = &out.narrow[0];
    let nar_laser = laser_samples(&narrow.signals.displacement_m, fs, NARROW_START_S, CLOCK);
    let naive: Vec<f64> = (0..narrow.signals.len())
        .map(|k| {
            let n = (NARROW_START_S + k as f64 / fs) * CLOCK.rate_hz;
            let i = nar_laser
                .partition_point(|s| (s.index as f64) < n)
                .min(nar_laser.len() - 1);
            nar_laser[i].displacement_m
        })
        .collect();
    let e = rms(naive
        .iter()
        .zip(&narrow.signals.displacement_m)
        .map(|(p, q)| p - q));
    // 150 ppm over 40 s is 6 ms: tens of micrometres of error at least.
    assert!(e > 20e-6, "naive error {e}");
}

#[test]
fn polled_dropouts_and_foreign_signals_are_handled() {
    let sim = sim();
    let out = &sim.outcome;
    let fs = out.pre.sample_rate_hz;
    let mic = &out.pre.microphone_v;
    let cap = capture(mic, fs, 0.0, out.pre_sweep.f_end_hz);
    let laser = laser_samples(&out.pre.displacement_m, fs, 0.0, CLOCK);

    // Polled: invalid, with the reason.
    let r = JobAligner::new(AlignConfig::default()).align(
        &cap,
        &LaserTrack {
            nominal_rate_hz: 1000.0,
            clock: SampleClock::HostPoll,
            samples: &laser,
        },
    );
    assert!(!r.report.valid);
    assert!(r.report.invalid_reason.unwrap().contains("no device clock"));
    assert_eq!(r.displacement_m.len(), mic.len());

    // Short dropouts (3 samples every second) are bridged; the job stays valid.
    let dropped: Vec<LaserSample> = laser
        .iter()
        .filter(|s| !(1000..1003).contains(&(s.index % 4000)))
        .copied()
        .collect();
    let r = JobAligner::new(AlignConfig::default()).align(&cap, &track(&dropped));
    assert!(r.report.valid, "{:?}", r.report.invalid_reason);
    assert!(
        r.report.dropped_samples >= 45,
        "{}",
        r.report.dropped_samples
    );
    assert!((r.report.ratio_ppm - CLOCK.ppm).abs() < 10.0);

    // A long dropout (50 ms) is not bridged.
    let gap: Vec<LaserSample> = laser
        .iter()
        .filter(|s| !(20_000..20_200).contains(&s.index))
        .copied()
        .collect();
    let r = JobAligner::new(AlignConfig::default()).align(&cap, &track(&gap));
    assert!(!r.report.valid);
    assert!(r
        .report
        .invalid_reason
        .unwrap()
        .contains("dropout of 200 samples"));

    // A laser that looked at something else (the narrow sweep's motion)
    // does not follow this microphone: invalid, not a silent misfit.
    let other = laser_samples(&out.narrow[0].signals.displacement_m, fs, 0.0, CLOCK);
    let r = JobAligner::new(AlignConfig::default()).align(&cap, &track(&other));
    assert!(!r.report.valid, "{:?}", r.report);

    // No samples at all, and samples that end early.
    let r = JobAligner::new(AlignConfig::default()).align(&cap, &track(&[]));
    assert!(r
        .report
        .invalid_reason
        .unwrap()
        .contains("no laser samples"));
    let r = JobAligner::new(AlignConfig::default()).align(&cap, &track(&laser[..laser.len() / 2]));
    assert!(r.report.invalid_reason.unwrap().contains("cover"));
}

#[test]
fn the_sinc_kernel_interpolates_band_limited_signals() {
    let k = SincKernel::default();
    // A 1.2 kHz tone sampled at 4 kHz (0.3 of the rate), read between samples.
    let f = 0.3;
    let x: Vec<f64> = (0..400)
        .map(|n| (2.0 * std::f64::consts::PI * f * n as f64).sin())
        .collect();
    let mut worst = 0.0f64;
    for i in 0..1000 {
        let u = 100.0 + i as f64 * 0.1937;
        let want = (2.0 * std::f64::consts::PI * f * u).sin();
        worst = worst.max((k.eval(&x, u) - want).abs());
    }
    assert!(worst < 2e-3, "{worst}");
    // Slow content is exact to 1e-5; ends are held; never NaN.
    let y: Vec<f64> = (0..400).map(|n| (0.01 * n as f64).cos()).collect();
    for u in [50.5, 123.456, 300.999] {
        assert!((k.eval(&y, u) - (0.01 * u).cos()).abs() < 1e-5);
    }
    assert_eq!(k.eval(&y, -100.0), y[0]);
    assert_eq!(k.eval(&y, 1e9), y[399]);
    assert_eq!(k.eval(&y, f64::NAN), 0.0);
    assert_eq!(k.eval(&[], 3.0), 0.0);
}
