//! Acceptance of issue 2 on the independent reference recordings
//! (../shared/data/reference-recordings): K(x), k0, Keff, warnings.

use springbench::identify::{analyze, AnalyzeOptions, Method, Report};
use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;
use std::path::PathBuf;

fn dir(case: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings")
        .join(case)
}

struct Truth {
    k: Vec<f64>,
    k0: f64,
    resonance_hz: f64,
    x_range: [f64; 2],
}

fn truth(case: &str) -> Truth {
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir(case).join("truth.json")).unwrap())
            .unwrap();
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    Truth {
        k: t["k_coeffs_si"].as_array().unwrap().iter().map(f).collect(),
        k0: f(&t["k0"]),
        resonance_hz: f(&t["resonance_hz"]),
        x_range: [f(&t["x_range_m"][0]), f(&t["x_range_m"][1])],
    }
}

fn poly(k: &[f64], x: f64) -> f64 {
    k.iter().rev().fold(0.0, |a, c| a * x + c)
}

/// The part's own effective stiffness at the amplitude the report states:
/// first-harmonic describing function of the true K(x) x over one cycle of
/// x = c + X cos(theta) spanning the excursion at resonance (midpoint rule
/// on 4096 points). The truth's `resonance_hz` is read off a coarse
/// amplitude track (the displacement peak, which is not fR on a cone).
fn keff_truth(r: &Report, t: &Truth) -> f64 {
    let l = &r.large_signal;
    let (c, a) = (
        0.5 * (l.x_max_at_resonance_m + l.x_min_at_resonance_m),
        0.5 * (l.x_max_at_resonance_m - l.x_min_at_resonance_m),
    );
    let n = 4096;
    let mut first = 0.0;
    for j in 0..n {
        let th = 2.0 * std::f64::consts::PI * (j as f64 + 0.5) / n as f64;
        let x = c + a * th.cos();
        first += poly(&t.k, x) * x * th.cos() * 2.0 / n as f64;
    }
    first / a
}

/// RMS and max relative error of K(x) over the measured range (%).
fn k_errors(r: &Report, t: &Truth) -> (f64, f64) {
    let [lo, hi] = r.stiffness.valid_range_m;
    let n = 400;
    let (mut s2, mut mx) = (0.0f64, 0.0f64);
    for i in 0..=n {
        let x = lo + (hi - lo) * i as f64 / n as f64;
        let kt = poly(&t.k, x);
        let e = (poly(&r.stiffness.coefficients_n_per_m_pow_i_plus_1, x) - kt) / kt;
        s2 += e * e;
        mx = mx.max(e.abs());
    }
    (100.0 * (s2 / (n + 1) as f64).sqrt(), 100.0 * mx)
}

fn run(case: &str, method: Method) -> (Report, Truth) {
    let set = RecordingSet::read_dir(dir(case)).unwrap();
    let r = analyze(
        &set,
        &AnalyzeOptions {
            method,
            order: None,
        },
    )
    .unwrap();
    let t = truth(case);
    let (rms, mx) = k_errors(&r, &t);
    let ss = r.small_signal.as_ref().unwrap();
    let keff_t = keff_truth(&r, &t);
    eprintln!(
        "{case} {method:?}: K rms {rms:.3} % max {mx:.3} %, order {}, k0 {:+.3} % (misfit {:.2} %, reliable {}), Keff {:+.3} % (of the describing function), fR {:.3} vs truth's amplitude peak {:.3}, range [{:.3} {:.3}] vs [{:.3} {:.3}] mm, residual {:.3} % noise {:.3} %\n  warnings {:?}",
        r.stiffness.order,
        100.0 * (ss.k0_n_per_m.unwrap() / t.k0 - 1.0),
        ss.misfit_percent,
        ss.reliable,
        100.0 * (r.large_signal.keff_n_per_m / keff_t - 1.0),
        r.large_signal.resonance_hz,
        t.resonance_hz,
        1e3 * r.large_signal.x_min_m,
        1e3 * r.large_signal.x_max_m,
        1e3 * t.x_range[0],
        1e3 * t.x_range[1],
        r.model.residual_percent,
        r.model.noise_floor_percent,
        r.warnings
    );
    (r, t)
}

fn area_truth(case: &str) -> f64 {
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir(case).join("truth.json")).unwrap())
            .unwrap();
    t["ss_m2"].as_f64().unwrap() / t["mic_gain"].as_f64().unwrap()
}

fn check_clean_part(case: &str) {
    let (r, t) = run(case, Method::TwoSignal);
    let (rms, mx) = k_errors(&r, &t);
    assert!(rms < 0.5 && mx < 1.0, "{case}: K(x) rms {rms} % max {mx} %");
    let ss = r.small_signal.as_ref().unwrap();
    assert!(ss.reliable, "{case}: {:?}", r.warnings);
    assert!(
        (ss.k0_n_per_m.unwrap() / t.k0 - 1.0).abs() < 0.01,
        "{case}: k0 {:?}",
        ss.k0_n_per_m
    );
    let keff_t = keff_truth(&r, &t);
    let dk = r.large_signal.keff_n_per_m / keff_t - 1.0;
    assert!(dk.abs() < 0.015, "{case}: Keff {dk}");
    // The measured range is the truth's range (1 um laser noise, band-limited).
    assert!((r.large_signal.x_min_m - t.x_range[0]).abs() < 2e-5);
    assert!((r.large_signal.x_max_m - t.x_range[1]).abs() < 2e-5);
    assert_eq!(
        r.stiffness.valid_range_m,
        [r.large_signal.x_min_m, r.large_signal.x_max_m]
    );
    // The microphone force scale of both sweeps is the truth's Ss / mic gain.
    let a = area_truth(case);
    let s = r.stiffness.force_per_mic_v_n_per_v.unwrap();
    assert!((s / a - 1.0).abs() < 0.01, "{case}: main scale {s} vs {a}");
    let sa = ss.force_per_mic_v_n_per_v.unwrap();
    assert!((sa / a - 1.0).abs() < 0.02, "{case}: pre scale {sa} vs {a}");
    // The residual is sensor noise: noise floor explains it.
    assert!(r.model.model_error_percent < 0.5 * r.model.residual_percent.max(0.1));
    assert!(r.warnings.is_empty(), "{case}: {:?}", r.warnings);
}

#[test]
fn p1_spider_two_signal() {
    check_clean_part("p1_spider");
}

#[test]
fn p3_cone_two_signal() {
    check_clean_part("p3_cone");
}

#[test]
fn p2_friction_flags_small_signal_and_keeps_k() {
    let (r, t) = run("p2_spider_friction", Method::TwoSignal);
    let ss = r.small_signal.as_ref().unwrap();
    assert!(!ss.reliable);
    assert!(ss.misfit_percent > 10.0, "{}", ss.misfit_percent);
    assert!(r
        .warnings
        .iter()
        .any(|w| w.contains("pre-measurement unreliable")));
    let (rms, _) = k_errors(&r, &t);
    assert!(rms < 2.0, "K(x) rms {rms} %");
}

#[test]
fn one_signal_on_spider_is_close_and_quiet() {
    // The box is nearly a short circuit for a spider: the harmonic force of the
    // air spring (Ss^2 / CAB = 9 N/m against k0 = 2400 N/m) is the only error.
    let (r, t) = run("p1_spider", Method::OneSignal);
    let (rms, mx) = k_errors(&r, &t);
    assert!(rms < 1.0 && mx < 1.5, "rms {rms} % max {mx} %");
    assert!(
        !r.warnings.iter().any(|w| w.contains("one-signal")),
        "{:?}",
        r.warnings
    );
    assert_eq!(r.stiffness.method, "one-signal");
    assert!(r.stiffness.force_per_mic_v_n_per_v.is_none());
}

#[test]
fn one_signal_on_cone_warns() {
    let (r, _) = run("p3_cone", Method::OneSignal);
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("one-signal assumption fails")),
        "{:?}",
        r.warnings
    );
}

/// The CLI's analysis of a set it gives away (`analyze_owned`, which frees
/// each sweep's raw channels as soon as they are read, decision 0094) is
/// the borrowed analysis's report, field for field, for both methods (p2:
/// with its warnings and unreliable marks).
#[test]
fn owned_analysis_is_the_borrowed_one() {
    let set = RecordingSet::read_dir(dir("p2_spider_friction")).unwrap();
    for method in [Method::TwoSignal, Method::OneSignal] {
        let opts = AnalyzeOptions {
            method,
            ..Default::default()
        };
        let borrowed = serde_json::to_string(&analyze(&set, &opts).unwrap()).unwrap();
        let owned = springbench::identify::analyze_owned(set.clone(), &opts).unwrap();
        assert_eq!(
            serde_json::to_string(&owned).unwrap(),
            borrowed,
            "{method:?}"
        );
    }
}
