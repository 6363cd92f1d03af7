//! Synthetic recordings with exact answers: a polynomial spring driven by a
//! known force, solved by a small RK4 here (independent of the physics
//! module), the microphone being the force over a known scale.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use springbench::identify::{analyze, force_balance_data, AnalyzeOptions, Method};
use springbench::recording::{Meta, RecordingSet, Signals};
use std::f64::consts::PI;

const M: f64 = 0.04;
const R: f64 = 1.5;
const K: [f64; 5] = [2000.0, 8.0e4, 3.0e7, -3.0e8, 1.0e11];
/// Force per microphone volt (N/V).
const SCALE: f64 = 0.2;
const FS: f64 = 8000.0;

fn k_of(x: f64) -> f64 {
    K.iter().rev().fold(0.0, |a, c| a * x + c)
}

/// Log sweep force f1 -> f2 over `dur` s with 0.2 s half-cosine fades, then 0.5 s rest.
fn force(t: f64, f1: f64, f2: f64, dur: f64, amp: f64) -> f64 {
    if t >= dur {
        return 0.0;
    }
    let l = dur / (f2 / f1).ln();
    let fade = 0.2;
    let env = if t < fade {
        0.5 * (1.0 - (PI * t / fade).cos())
    } else if t > dur - fade {
        0.5 * (1.0 - (PI * (dur - t) / fade).cos())
    } else {
        1.0
    };
    amp * env * (2.0 * PI * f1 * l * ((t / l).exp() - 1.0)).sin()
}

thread_local! {
    /// The part's damping R (N s/m) in this test's thread.
    static DAMPING: std::cell::Cell<f64> = const { std::cell::Cell::new(R) };
}

/// m x'' + R x' + K(x) x = F(t), RK4 with 4 steps per sample.
fn simulate(f1: f64, f2: f64, dur: f64, amp: f64, noise: Option<(u64, f64, f64)>) -> Signals {
    let n = ((dur + 0.5) * FS) as usize;
    let r = DAMPING.with(|d| d.get());
    let sub = 4;
    let h = 1.0 / (FS * sub as f64);
    let acc = |t: f64, x: f64, v: f64| (force(t, f1, f2, dur, amp) - r * v - k_of(x) * x) / M;
    let (mut x, mut v) = (0.0f64, 0.0f64);
    let mut sig = Signals {
        sample_rate_hz: FS,
        displacement_m: Vec::with_capacity(n),
        microphone_v: Vec::with_capacity(n),
        drive_v: Some(Vec::with_capacity(n)),
    };
    for i in 0..n {
        let t = i as f64 / FS;
        let f = force(t, f1, f2, dur, amp);
        sig.displacement_m.push(x);
        sig.microphone_v.push(f / SCALE);
        sig.drive_v.as_mut().unwrap().push(f / amp);
        for s in 0..sub {
            let t = t + s as f64 * h;
            let (k1x, k1v) = (v, acc(t, x, v));
            let (k2x, k2v) = (
                v + 0.5 * h * k1v,
                acc(t + 0.5 * h, x + 0.5 * h * k1x, v + 0.5 * h * k1v),
            );
            let (k3x, k3v) = (
                v + 0.5 * h * k2v,
                acc(t + 0.5 * h, x + 0.5 * h * k2x, v + 0.5 * h * k2v),
            );
            let (k4x, k4v) = (v + h * k3v, acc(t + h, x + h * k3x, v + h * k3v));
            x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
            v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
    }
    if let Some((seed, laser, mic)) = noise {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let (nl, nm) = (
            Normal::new(0.0, laser).unwrap(),
            Normal::new(0.0, mic).unwrap(),
        );
        for v in sig.displacement_m.iter_mut() {
            *v += nl.sample(&mut rng);
        }
        for v in sig.microphone_v.iter_mut() {
            *v += nm.sample(&mut rng);
        }
    }
    sig
}

fn set(noise: Option<(u64, f64, f64)>, drive: bool) -> RecordingSet {
    let mut pre = simulate(5.0, 100.0, 12.0, 0.005, noise);
    let mut main = simulate(30.0, 75.0, 8.0, 2.0, noise.map(|(s, l, m)| (s + 1, l, m)));
    if !drive {
        pre.drive_v = None;
        main.drive_v = None;
    }
    RecordingSet {
        meta: Meta::standard(M, FS),
        pre,
        main,
    }
}

/// RMS and max relative error of K(x) over the valid range (%).
fn k_errors(coef: &[f64], range: [f64; 2]) -> (f64, f64) {
    let (mut s2, mut mx) = (0.0f64, 0.0f64);
    let n = 200;
    for i in 0..=n {
        let x = range[0] + (range[1] - range[0]) * i as f64 / n as f64;
        let e = coef.iter().rev().fold(0.0, |a, c| a * x + c) / k_of(x) - 1.0;
        s2 += e * e;
        mx = mx.max(e.abs());
    }
    (100.0 * (s2 / (n + 1) as f64).sqrt(), 100.0 * mx)
}

#[test]
fn noise_free_polynomial_spring_is_recovered_exactly() {
    let s = set(None, true);
    let r = analyze(&s, &AnalyzeOptions::default()).unwrap();
    let (rms, mx) = k_errors(
        &r.stiffness.coefficients_n_per_m_pow_i_plus_1,
        r.stiffness.valid_range_m,
    );
    assert!(rms < 0.01 && mx < 0.02, "two signal: {rms} % / {mx} %");
    assert_eq!(
        r.stiffness.order, 4,
        "{:?}",
        r.stiffness.coefficients_n_per_m_pow_i_plus_1
    );
    let sc = r.stiffness.force_per_mic_v_n_per_v.unwrap();
    assert!((sc / SCALE - 1.0).abs() < 1e-4, "{sc}");
    assert!(
        (r.stiffness.r_ns_per_m / R - 1.0).abs() < 1e-3,
        "{}",
        r.stiffness.r_ns_per_m
    );
    // The range is the simulated one.
    let (lo, hi) = s
        .main
        .displacement_m
        .iter()
        .fold((0.0f64, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    assert!((r.stiffness.valid_range_m[0] / lo - 1.0).abs() < 1e-3);
    assert!((r.stiffness.valid_range_m[1] / hi - 1.0).abs() < 1e-3);
    assert!(
        r.model.residual_percent < 0.05,
        "{}",
        r.model.residual_percent
    );

    let ss = r.small_signal.as_ref().unwrap();
    assert!(ss.reliable && ss.misfit_percent < 0.5, "{ss:?}");
    assert!(
        (ss.k0_n_per_m.unwrap() / K[0] - 1.0).abs() < 1e-3,
        "{:?}",
        ss.k0_n_per_m
    );
    assert!(
        (ss.r_ns_per_m.unwrap() / R - 1.0).abs() < 5e-3,
        "{:?}",
        ss.r_ns_per_m
    );
    let f0 = (K[0] / M).sqrt() / (2.0 * PI);
    assert!((ss.f0_hz.unwrap() / f0 - 1.0).abs() < 5e-4);
    assert!((ss.q.unwrap() / ((K[0] * M).sqrt() / R) - 1.0).abs() < 5e-3);
    assert!((ss.force_per_mic_v_n_per_v.unwrap() / SCALE - 1.0).abs() < 1e-3);

    // Keff = wR^2 m is the stiffness at the resonance: compare with the force
    // balance at the fundamental there, K_eff = Keff(Xpeak) from K(x) by
    // harmonic balance (first Fourier coefficient of K(x) x over one cycle).
    let l = &r.large_signal;
    let x1 = l.harmonics_m[0];
    let dc = l.dc_m;
    let n = 2000;
    let mut c = 0.0;
    for i in 0..n {
        let th = 2.0 * PI * i as f64 / n as f64;
        let x = dc + x1 * th.cos();
        c += k_of(x) * x * th.cos();
    }
    let kfund = 2.0 * c / n as f64 / x1;
    assert!(
        (l.keff_n_per_m / kfund - 1.0).abs() < 0.03,
        "Keff {} vs {}",
        l.keff_n_per_m,
        kfund
    );
}

#[test]
#[ignore = "One Signal on noise-free data is 0.56 % RMS off with drive marks (0.08 % without): a systematic error of the harmonic-balance formulation, not conditioning (QR gives the same); not yet explained"]
fn one_signal_is_exact_when_the_force_has_no_harmonics() {
    let opts = AnalyzeOptions {
        method: Method::OneSignal,
        order: None,
    };
    for drive in [true, false] {
        // Without the drive channel the periods are found on the displacement.
        let s = set(None, drive);
        let r = analyze(&s, &opts).unwrap();
        let (rms, mx) = k_errors(
            &r.stiffness.coefficients_n_per_m_pow_i_plus_1,
            r.stiffness.valid_range_m,
        );
        eprintln!(
            "drive {drive}: one signal: {rms} % / {mx} % {:?} {:?}",
            r.stiffness.coefficients_n_per_m_pow_i_plus_1, r.stiffness.valid_range_m
        );
        assert!(
            rms < 0.05 && mx < 0.1,
            "drive {drive}: one signal: {rms} % / {mx} %"
        );
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    }
}

#[test]
fn sensor_noise_sets_the_floor() {
    // 1 um laser noise, mic noise 2 % of the pre-sweep force.
    let s = set(Some((11, 1e-6, 5e-4)), true);
    let r = analyze(&s, &AnalyzeOptions::default()).unwrap();
    let (rms, mx) = k_errors(
        &r.stiffness.coefficients_n_per_m_pow_i_plus_1,
        r.stiffness.valid_range_m,
    );
    assert!(rms < 0.1 && mx < 0.3, "{rms} % / {mx} %");
    // The residual is explained by the estimated noise within 10 %.
    let m = &r.model;
    assert!(
        (m.residual_percent / m.noise_floor_percent - 1.0).abs() < 0.1,
        "residual {} noise {}",
        m.residual_percent,
        m.noise_floor_percent
    );
    let fb = force_balance_data(&s, &AnalyzeOptions::default()).unwrap();
    assert_eq!(fb.mass_kg, M);
    assert!(fb.x_m.len() == fb.mic_v.len() && fb.a_m_per_s2.len() == fb.x_m.len());
    // Band-limited noise in x: 1 um white at 8 kHz through a 1.2 kHz low-pass.
    assert!(
        fb.laser_noise_m > 0.3e-6 && fb.laser_noise_m < 0.7e-6,
        "{}",
        fb.laser_noise_m
    );
}

/// Issue 11: a fit with R <= 0 has no finite positive Q = sqrt(k0 m) / R
/// (infinite or negative): Q and its error are null with the reason, never
/// an infinity, and the whole result passes the store's finite check.
#[test]
fn an_undamped_fit_has_q_null_with_a_reason() {
    // A pre-measurement whose fit finds no positive damping. A part with
    // R = 0 is not enough: the sweep through its resonance fits R = 0.02
    // N s/m (Q 452, finite); a microphone phase error, or here a simulated
    // R = -0.2 N s/m, fits R < 0. The main sweep is damped (an undamped one
    // never lags the force by 90 degrees: no fR).
    DAMPING.with(|d| d.set(-0.2));
    let pre = simulate(5.0, 100.0, 12.0, 0.005, None);
    DAMPING.with(|d| d.set(R));
    let main = simulate(30.0, 75.0, 8.0, 2.0, None);
    let s = RecordingSet {
        meta: Meta::standard(M, FS),
        pre,
        main,
    };
    let rep = analyze(&s, &AnalyzeOptions::default()).unwrap();
    let ss = rep.small_signal.as_ref().unwrap();
    println!(
        "undamped: R = {:?} +- {:e} N s/m, Q {:?}, reason {:?}",
        ss.r_ns_per_m, ss.r_se_ns_per_m, ss.q, ss.q_null_reason
    );
    // Issue 22: R <= 0 is not a headline value: null, the fit's number
    // kept as a diagnostic with the state and its reason.
    assert_eq!(ss.r_ns_per_m, None);
    let v = &ss.validity.r_ns_per_m;
    assert_eq!(
        v.state,
        springbench::identify::validity::State::NotDetermined
    );
    assert!(v.fit_value.unwrap() <= 0.0, "{v:?}");
    assert!(
        v.reason.as_deref().unwrap().contains("no physical damping"),
        "{v:?}"
    );
    assert_eq!(
        ss.validity.q.state,
        springbench::identify::validity::State::NotDetermined
    );
    assert_eq!((ss.q, ss.q_se), (None, None));
    assert!(ss.q_null_reason.as_deref().unwrap().contains("no damping"));
    let v = springbench::finite::to_value(&rep).expect("a finite result document");
    assert!(v["small_signal"]["q"].is_null());
    assert!(v["small_signal"]["q_se"].is_null());
    assert!(v["small_signal"]["q_null_reason"].is_string());
    // The document reads back as it was.
    let back: springbench::identify::Report = serde_json::from_value(v).unwrap();
    assert_eq!(back.small_signal.unwrap().q, None);
}
