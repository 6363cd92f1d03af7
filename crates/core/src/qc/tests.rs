use super::limits::{propose, GoldenUnit, ProposalOptions, Spread, GOLDEN_KX_POINTS};
use super::spc::{compute, SpcPoint};
use super::verdict::judge_values;
use super::*;
use crate::identify::{LargeSignal, Method, Model, Report, SmallSignal, Stiffness};

/// A result document with K(x) = k0 + k1 x + k2 x^2 measured over +-8 mm.
fn report(k0: f64, k1: f64, k2: f64, q: f64) -> Report {
    Report {
        small_signal: Some(SmallSignal {
            f0_hz: Some(35.0),
            k0_n_per_m: Some(k0),
            r_ns_per_m: Some((k0 * 0.05f64).sqrt() / q),
            q: Some(q),
            reliable: true,
            misfit_percent: 0.5,
            ..Default::default()
        }),
        large_signal: LargeSignal {
            keff_n_per_m: k0 * 1.5,
            xpeak_m: 0.008,
            ..Default::default()
        },
        stiffness: Stiffness {
            coefficients_n_per_m_pow_i_plus_1: vec![k0, k1, k2],
            valid_range_m: [-0.008, 0.008],
            ..Default::default()
        },
        model: Model {
            residual_percent: 1.0,
            noise_floor_percent: 0.5,
            model_error_percent: 0.8,
            ..Default::default()
        },
        ..Default::default()
    }
}

fn facts(r: Report) -> RunFacts {
    RunFacts {
        report: Some(r),
        target_xpeak_m: Some(0.008),
        level_index: 0,
        drive_v: Some(20.0),
        max_drive_v: Some(100.0),
        ..Default::default()
    }
}

fn param(name: &str, q: Quantity, x_m: Option<f64>, lo: Option<f64>, hi: Option<f64>) -> ParamSpec {
    ParamSpec {
        name: name.into(),
        quantity: q,
        x_m,
        effect: None,
        effect_parameter: None,
        level_index: None,
        lower: lo,
        upper: hi,
        from_golden: None,
    }
}

fn recipe() -> Recipe {
    Recipe {
        name: "spider-4in".into(),
        part_kind: Some("spider".into()),
        description: None,
        procedure: ProcedureSettings {
            levels_m: vec![0.008],
            method: Method::TwoSignal,
            order: Some(4),
            repeats: 1,
            moving_mass_kg: Some(0.05),
            mode: Default::default(),
            golden: None,
        },
        parameters: vec![
            param("k0", Quantity::K0, None, Some(2300.0), Some(2500.0)),
            param("q", Quantity::Q, None, Some(5.0), Some(7.0)),
            param(
                "k_at_4mm",
                Quantity::KAtX,
                Some(0.004),
                Some(2700.0),
                Some(3100.0),
            ),
            param(
                "asym_4mm",
                Quantity::KAsymmetry,
                Some(0.004),
                Some(0.8),
                Some(1.0),
            ),
            param("model_error", Quantity::ModelError, None, None, Some(5.0)),
        ],
        validity: Validity::default(),
        kx_mask: None,
    }
}

#[test]
fn k_of_x_and_asymmetry_follow_the_polynomial() {
    let r = report(2400.0, 1.2e5, 3.6e7, 6.0);
    let x = 0.004;
    let kp = 2400.0 + 1.2e5 * x + 3.6e7 * x * x; // 2880
    let km = 2400.0 - 1.2e5 * x + 3.6e7 * x * x; // 1920
    assert!((k_of_x(&r, x) - kp).abs() < 1e-9);
    let v = judge(&recipe(), &facts(r));
    let asym = v.parameters.iter().find(|p| p.name == "asym_4mm").unwrap();
    assert!((asym.value - km / kp).abs() < 1e-12, "{}", asym.value);
    assert_eq!(asym.unit, "1");
}

#[test]
fn pass_inside_the_limits_fail_names_every_failing_parameter() {
    let r = recipe();
    // k1 small: symmetric K(x): asymmetry 1.0 is at the upper limit (pass).
    let good = report(2400.0, 0.0, 3.0e7, 6.0); // K(4 mm) = 2880
    let v = judge(&r, &facts(good));
    assert_eq!(v.verdict, VerdictKind::Pass, "{v:?}");
    assert!(v.failures.is_empty());
    assert_eq!(v.parameters.len(), 5);
    let k0 = &v.parameters[0];
    assert_eq!(
        (k0.value, k0.lower, k0.upper, k0.unit.as_str()),
        (2400.0, Some(2300.0), Some(2500.0), "N/m")
    );

    // Stiff and over-damped: k0, K(4 mm) and Q fail, with their values and limits.
    let bad = report(2700.0, 0.0, 3.0e7, 4.0);
    let v = judge(&r, &facts(bad));
    assert_eq!(v.verdict, VerdictKind::Fail);
    let names: Vec<&str> = v.failures.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["k0", "q", "k_at_4mm"]);
    assert_eq!(v.failures[0].value, 2700.0);
    assert_eq!(v.failures[0].upper, Some(2500.0));
    assert_eq!(v.failures[1].value, 4.0);
    assert_eq!(v.failures[1].lower, Some(5.0));
    assert!((v.failures[2].value - (2700.0 + 3.0e7 * 16e-6)).abs() < 1e-9);
    assert!(v.invalid_reasons.is_empty());
}

#[test]
fn an_untrusted_measurement_is_invalid_never_pass() {
    let r = recipe();
    let good = report(2400.0, 0.0, 3.0e7, 6.0);
    // Target not reached at the drive limit: values inside the limits, still invalid.
    let mut f = facts(good.clone());
    f.report.as_mut().unwrap().large_signal.xpeak_m = 0.005;
    f.drive_v = Some(100.0);
    let v = judge(&r, &f);
    assert_eq!(v.verdict, VerdictKind::Invalid);
    assert_eq!(v.invalid_reasons[0].code, "target_not_reached");
    assert!(
        v.invalid_reasons[0].detail.contains("drive limit"),
        "{}",
        v.invalid_reasons[0].detail
    );
    assert!(v.failures.is_empty());

    // Noise floor above the bound.
    let mut f = facts(good.clone());
    f.report.as_mut().unwrap().model.noise_floor_percent = 7.0;
    assert_eq!(judge(&r, &f).invalid_reasons[0].code, "noise_high");
    // Model error above the validity bound (10 %), also above the limit (5 %): invalid wins.
    let mut f = facts(good.clone());
    f.report.as_mut().unwrap().model.model_error_percent = 12.0;
    let v = judge(&r, &f);
    assert_eq!(v.verdict, VerdictKind::Invalid);
    assert_eq!(v.invalid_reasons[0].code, "model_error_high");
    // Unreliable small-signal fit.
    let mut f = facts(good.clone());
    f.report
        .as_mut()
        .unwrap()
        .small_signal
        .as_mut()
        .unwrap()
        .reliable = false;
    assert_eq!(
        judge(&r, &f).invalid_reasons[0].code,
        "small_signal_unreliable"
    );
    // Clipping reported by the analysis.
    let mut f = facts(good.clone());
    f.report
        .as_mut()
        .unwrap()
        .warnings
        .push("microphone clipped in 12 samples".into());
    assert_eq!(judge(&r, &f).invalid_reasons[0].code, "clipping");
    // K(x) point outside the measured range.
    let mut f = facts(good.clone());
    f.report.as_mut().unwrap().stiffness.valid_range_m = [-0.003, 0.008];
    assert_eq!(
        judge(&r, &f).invalid_reasons[0].code,
        "outside_measured_range"
    );
    // No result at all.
    let f = RunFacts {
        analysis_error: Some("too short".into()),
        ..Default::default()
    };
    let v = judge(&r, &f);
    assert_eq!(v.verdict, VerdictKind::Invalid);
    assert!(v.invalid_reasons[0].detail.contains("too short"));
}

/// Issue 35: an invalid measurement is never judged, not even per
/// parameter: its values stay as measured with their limits, each
/// `not_judged`, and no failures, whatever the values (a value inside its
/// limits and one outside), in the measurement's and the job's verdict.
#[test]
fn an_invalid_verdict_carries_no_pass_or_fail_per_parameter() {
    let r = recipe();
    // k0 2700 N/m is above its limit (fail), the rest inside; the target is not reached.
    let mut f = facts(report(2700.0, 0.0, 3.0e7, 6.0));
    f.report.as_mut().unwrap().large_signal.xpeak_m = 0.005;
    let v = judge(&r, &f);
    assert_eq!(v.verdict, VerdictKind::Invalid);
    assert!(v.parameters.len() >= 3, "{:?}", v.parameters);
    assert!(v.failures.is_empty());
    for p in &v.parameters {
        assert_eq!(p.result, ParamResult::NotJudged, "{}", p.name);
        assert!(p.value.is_finite() && (p.lower.is_some() || p.upper.is_some()));
    }
    let k0 = v.parameters.iter().find(|p| p.name == "k0").unwrap();
    assert_eq!(k0.value, 2700.0, "the value as measured");
    let pass = judge(&r, &facts(report(2400.0, 0.0, 3.0e7, 6.0)));
    assert_eq!(pass.verdict, VerdictKind::Pass);
    let job = combine(&[pass.clone(), v]);
    assert_eq!(job.verdict, VerdictKind::Invalid);
    assert!(job
        .parameters
        .iter()
        .all(|p| p.result == ParamResult::NotJudged));
    // A verdict stored before the rule, read back.
    let mut old = pass;
    old.verdict = VerdictKind::Invalid;
    assert!(never_judge_invalid(old)
        .parameters
        .iter()
        .all(|p| p.result == ParamResult::NotJudged));
}

#[test]
fn a_recipe_without_limits_gives_no_limits_and_the_hash_follows_the_content() {
    let mut r = recipe();
    for p in &mut r.parameters {
        p.lower = None;
        p.upper = None;
    }
    assert!(!r.has_limits());
    let v = judge(&r, &facts(report(2400.0, 0.0, 3.0e7, 6.0)));
    assert_eq!(v.verdict, VerdictKind::NoLimits);
    let h = r.sha256();
    assert_eq!(h.len(), 64);
    assert_eq!(r.clone().sha256(), h);
    r.parameters[0].upper = Some(2500.0);
    assert_ne!(r.sha256(), h);
}

#[test]
fn job_verdict_invalid_outranks_fail_outranks_pass() {
    let r = recipe();
    let pass = judge(&r, &facts(report(2400.0, 0.0, 3.0e7, 6.0)));
    let fail = judge(&r, &facts(report(2700.0, 0.0, 3.0e7, 6.0)));
    let invalid = invalid_job("hardware_fault", "laser out of range".into());
    assert_eq!(
        combine(&[pass.clone(), pass.clone()]).verdict,
        VerdictKind::Pass
    );
    assert_eq!(
        combine(&[pass.clone(), fail.clone()]).verdict,
        VerdictKind::Fail
    );
    assert_eq!(
        combine(&[fail, invalid.clone(), pass]).verdict,
        VerdictKind::Invalid
    );
    assert_eq!(combine(&[]).verdict, VerdictKind::Invalid);
}

#[test]
fn recipe_validation_names_each_bad_field() {
    let mut r = recipe();
    r.name = "a/b".into();
    r.procedure.levels_m = vec![0.0];
    r.parameters[2].x_m = None;
    r.parameters[0].lower = Some(3000.0);
    r.parameters
        .push(param("k0", Quantity::Keff, None, None, None));
    let mut fx = param("friction", Quantity::EffectSize, None, None, Some(0.05));
    fx.effect = Some("coulomb_friction".into());
    fx.effect_parameter = Some("force".into());
    r.parameters.push(fx);
    let e = r.validate().unwrap_err();
    let f: Vec<&str> = e.iter().map(|e| e.field.as_str()).collect();
    assert_eq!(
        f,
        [
            "name",
            "procedure.levels_m[0]",
            "parameters[0].lower",
            "parameters[2].x_m",
            "parameters[5].name",
            "parameters[6].effect_parameter"
        ]
    );
    assert!(recipe().validate().is_ok());
}

#[test]
fn effect_size_reads_the_fitted_effect_or_zero() {
    let mut r = recipe();
    let mut fx = param("friction", Quantity::EffectSize, None, None, Some(0.05));
    fx.effect = Some("coulomb_friction".into());
    fx.effect_parameter = Some("force_n".into());
    r.parameters = vec![fx];
    assert!(r.needs_diagnostics());
    let mut rep = report(2400.0, 0.0, 3.0e7, 6.0);
    let v = judge(&r, &facts(rep.clone()));
    assert_eq!((v.verdict, v.parameters[0].value), (VerdictKind::Pass, 0.0));
    assert_eq!(v.parameters[0].unit, "N");
    rep.model.effects.coulomb_friction = Some(crate::effects::CoulombFriction {
        force_n: 0.2,
        v_eps_m_per_s: 0.002,
    });
    let v = judge(&r, &facts(rep));
    assert_eq!(v.verdict, VerdictKind::Fail);
    assert_eq!(v.failures[0].value, 0.2);
}

#[test]
fn golden_limits_are_mean_plus_minus_k_sigma_and_a_mask() {
    let mut r = recipe();
    for p in &mut r.parameters {
        if p.from_golden() {
            p.lower = None;
            p.upper = None;
        }
    }
    // k0 of the golden units 2380..2420 (mean 2400, sample sigma sqrt(250)).
    let k0s = [2380.0, 2390.0, 2400.0, 2410.0, 2420.0];
    let golden: Vec<GoldenUnit> = k0s
        .iter()
        .enumerate()
        .map(|(i, &k0)| GoldenUnit {
            serial: format!("G-{i}"),
            measurements: vec![facts(report(k0, 0.0, 3.0e7, 6.0))],
        })
        .collect();
    let opts = ProposalOptions {
        spread: Spread::KSigma { k: 3.0 },
        mask_points: 5,
        mask_range_fraction: 0.5,
    };
    let p = propose(&r, &golden, &opts).unwrap();
    let k0 = p.parameters.iter().find(|s| s.name == "k0").unwrap();
    let sigma = 250f64.sqrt();
    assert!((k0.mean - 2400.0).abs() < 1e-9 && (k0.sigma - sigma).abs() < 1e-9);
    assert!((k0.lower.unwrap() - (2400.0 - 3.0 * sigma)).abs() < 1e-9);
    assert!((k0.upper.unwrap() - (2400.0 + 3.0 * sigma)).abs() < 1e-9);
    // Manual limits (model error) are kept, not proposed.
    assert!(p.parameters.iter().all(|s| s.name != "model_error"));
    assert_eq!(p.recipe.parameters[4].upper, Some(5.0));
    // Mask over half of the common range +-8 mm: +-4 mm, K(x) = k0 + 3e7 x^2.
    let m = p.kx_mask.as_ref().unwrap();
    assert_eq!(m.x_m, vec![-0.004, -0.002, 0.0, 0.002, 0.004]);
    let mid = 2400.0 + 3.0e7 * 16e-6;
    assert!((0.5 * (m.lower_n_per_m[4] + m.upper_n_per_m[4]) - mid).abs() < 1e-6);
    assert!((0.5 * (m.upper_n_per_m[4] - m.lower_n_per_m[4]) - 3.0 * sigma).abs() < 1e-6);
    // The golden units' own K(x) over their whole common range +-8 mm: at
    // x = 8 mm the units' K are k0 + 3e7 * 64e-6 = k0 + 1920.
    let g = p.golden_kx.as_ref().unwrap();
    assert_eq!(
        (g.n, g.level_index, g.x_m.len()),
        (5, None, GOLDEN_KX_POINTS)
    );
    assert_eq!((g.x_m[0], g.x_m[GOLDEN_KX_POINTS - 1]), (-0.008, 0.008));
    let e = GOLDEN_KX_POINTS - 1;
    assert!((g.min_n_per_m[e] - (2380.0 + 1920.0)).abs() < 1e-6);
    assert!((g.max_n_per_m[e] - (2420.0 + 1920.0)).abs() < 1e-6);
    assert!((g.mean_n_per_m[e] - (2400.0 + 1920.0)).abs() < 1e-6);
    assert!((g.sigma_n_per_m[e] - sigma).abs() < 1e-6);
    assert!((g.mean_n_per_m[20] - 2400.0).abs() < 1e-6, "x = 0");
    // The approved recipe judges a golden unit pass and a stiff part fail on k0 and the mask.
    assert_eq!(
        judge(&p.recipe, &golden[2].measurements[0]).verdict,
        VerdictKind::Pass
    );
    let v = judge(&p.recipe, &facts(report(2500.0, 0.0, 3.0e7, 6.0)));
    let names: Vec<&str> = v.failures.iter().map(|f| f.name.as_str()).collect();
    assert!(
        names.contains(&"k0") && names.contains(&KX_MASK),
        "{names:?}"
    );

    // Tolerance: +- 10 % of the mean.
    let opts_t = ProposalOptions {
        spread: Spread::Tolerance {
            tolerance_percent: 10.0,
        },
        mask_points: 0,
        mask_range_fraction: 0.9,
    };
    let p = propose(&r, &golden, &opts_t).unwrap();
    let k0 = p.parameters.iter().find(|s| s.name == "k0").unwrap();
    assert!((k0.upper.unwrap() - 2640.0).abs() < 1e-9);
    assert!(p.kx_mask.is_none());

    // Four golden units are too few; an invalid golden unit is refused by serial.
    assert!(propose(&r, &golden[..4], &opts)
        .unwrap_err()
        .contains("at least 5"));
    let mut g = golden.clone();
    g[1].measurements[0]
        .report
        .as_mut()
        .unwrap()
        .model
        .noise_floor_percent = 9.0;
    assert!(propose(&r, &g, &opts).unwrap_err().contains("G-1"));
}

#[test]
fn spc_matches_the_closed_form() {
    let vals = [1.0, 2.0, 3.0, 4.0, 5.0];
    let pts: Vec<SpcPoint> = vals
        .iter()
        .enumerate()
        .map(|(i, &v)| SpcPoint {
            recipe_version: None,
            time: format!("2026-01-01T00:00:0{i}Z"),
            part_serial: format!("S{i}"),
            measurement_id: format!("m{i}"),
            job_id: Some(format!("j{i}")),
            level_index: Some(0),
            value: v,
            repeats: 1,
            verdict: if v < 5.0 {
                VerdictKind::Pass
            } else {
                VerdictKind::Fail
            },
        })
        .collect();
    let s = compute("x", "1", Some(0.0), Some(6.0), pts, 2);
    let sigma = 2.5f64.sqrt();
    let sw = 1.0 / 1.128; // average moving range 1
    assert_eq!(s.n, 5);
    assert!((s.mean.unwrap() - 3.0).abs() < 1e-12);
    assert!((s.sigma.unwrap() - sigma).abs() < 1e-12);
    assert!((s.sigma_within.unwrap() - sw).abs() < 1e-12);
    assert!((s.cp.unwrap() - 6.0 / (6.0 * sw)).abs() < 1e-12);
    assert!((s.cpk.unwrap() - 3.0 / (3.0 * sw)).abs() < 1e-12);
    assert!((s.pp.unwrap() - 6.0 / (6.0 * sigma)).abs() < 1e-12);
    assert!((s.ppk.unwrap() - 3.0 / (3.0 * sigma)).abs() < 1e-12);
    assert!((s.yield_fraction.unwrap() - 0.8).abs() < 1e-12);
    assert_eq!((s.passed, s.failed, s.invalid), (4, 1, 2));
    assert!((s.ucl.unwrap() - (3.0 + 3.0 * sw)).abs() < 1e-12);
    // One-sided: Cpk from the upper limit only, no Cp.
    let s1 = compute("x", "1", None, Some(6.0), s.points.clone(), 0);
    assert!(s1.cp.is_none());
    assert!((s1.cpk.unwrap() - 3.0 / (3.0 * sw)).abs() < 1e-12);
    let csv = super::spc::to_csv(&s);
    assert_eq!(csv.lines().count(), 6);
    assert!(
        csv.lines().nth(5).unwrap().contains(",5,fail,0,6,3,"),
        "{csv}"
    );
    // Repeats: one point per job, the mean of its repeats (three repeats of
    // each part: the moving ranges are between the parts' means).
    let reps: Vec<SpcPoint> = s
        .points
        .iter()
        .flat_map(|p| {
            [-0.3, 0.1, 0.2].map(|d| SpcPoint {
                recipe_version: None,
                value: p.value + d,
                ..p.clone()
            })
        })
        .collect();
    let r = compute("x", "1", Some(0.0), Some(6.0), reps, 0);
    assert_eq!(r.n, 5);
    assert!(r.points.iter().all(|p| p.repeats == 3));
    assert!((r.mean.unwrap() - 3.0).abs() < 1e-12);
    assert!((r.sigma_within.unwrap() - sw).abs() < 1e-12);
    assert!((r.cpk.unwrap() - s.cpk.unwrap()).abs() < 1e-12);
    // Empty window: no NaN anywhere.
    let e = compute("x", "1", Some(0.0), Some(6.0), vec![], 0);
    assert!(e.mean.is_none() && e.cpk.is_none() && e.yield_fraction.is_none());
}

#[test]
fn keff_is_judged_at_the_target_amplitude_not_the_reached_one() {
    // K(x) = k0 + k2 x^2: the describing function at amplitude X is
    // k0 + 3/4 k2 X^2 (exact), whatever Xpeak the level control reached.
    let (k0, k2) = (2400.0, 3.0e7);
    let mut r = report(k0, 0.0, k2, 6.0);
    r.large_signal.xpeak_m = 0.0075;
    r.large_signal.x_min_at_resonance_m = -0.0075;
    r.large_signal.x_max_at_resonance_m = 0.0075;
    let want = |x: f64| k0 + 0.75 * k2 * x * x;
    let got = keff_at_target(&r, Some(0.008));
    assert!((got - want(0.008)).abs() < 1e-9 * want(0.008), "{got}");
    // A part that reached 8.0 mm instead gives the same figure.
    r.large_signal.xpeak_m = 0.008;
    assert!((keff_at_target(&r, Some(0.008)) - got).abs() < 1e-9 * got);
    // A centre offset c: x = c + X cos(theta) gives k0 + k2 (3 c^2 + 3/4 X^2).
    r.large_signal.x_min_at_resonance_m = -0.007;
    r.large_signal.x_max_at_resonance_m = 0.009;
    let c: f64 = 0.001;
    let w = k0 + k2 * (3.0 * c * c + 0.75 * 0.008 * 0.008);
    assert!((keff_at_target(&r, Some(0.008)) - w).abs() < 1e-9 * w);
    // Without a target: the measured Keff.
    assert_eq!(keff_at_target(&r, None), r.large_signal.keff_n_per_m);
}

#[test]
fn keff_at_target_is_put_beside_the_measured_keff() {
    // K(x) = k0 + k1 x + k2 x^2 + k3 x^3 around a centre c, amplitude X: the
    // first harmonic of K(x) x over x = c + X cos(theta) gives
    // Keff = k0 + 2 k1 c + k2 (3 c^2 + 3/4 X^2) + k3 (4 c^3 + 3 c X^2).
    let (k0, k1, k2, k3) = (2400.0, -4.0e4, 3.0e7, 2.0e8);
    let mut r = report(k0, k1, k2, 6.0);
    r.stiffness.coefficients_n_per_m_pow_i_plus_1 = vec![k0, k1, k2, k3];
    r.large_signal.xpeak_m = 0.0085;
    r.large_signal.x_min_at_resonance_m = -0.0075;
    r.large_signal.x_max_at_resonance_m = 0.0085;
    let (c, x) = (0.0005f64, 0.008f64);
    let want = k0
        + 2.0 * k1 * c
        + k2 * (3.0 * c * c + 0.75 * x * x)
        + k3 * (4.0 * c.powi(3) + 3.0 * c * x * x);
    let measured = r.large_signal.keff_n_per_m;
    set_keff_at_target(&mut r, Some(x));
    let got = r.large_signal.keff_at_target_n_per_m.unwrap();
    assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
    assert_eq!(r.large_signal.target_xpeak_m, Some(x));
    // The number QC judges, and the measured Keff left as it was.
    assert_eq!(got, keff_at_target(&r, Some(x)));
    assert_eq!(r.large_signal.keff_n_per_m, measured);
    // Serialized with the unit in the name.
    let v = serde_json::to_value(&r).unwrap();
    assert_eq!(
        v["large_signal"]["keff_at_target_n_per_m"],
        serde_json::json!(got)
    );
    assert_eq!(v["large_signal"]["target_xpeak_m"], serde_json::json!(x));
    // No target: nothing added (and nothing in the JSON).
    let mut r2 = report(k0, k1, k2, 6.0);
    set_keff_at_target(&mut r2, None);
    assert!(r2.large_signal.keff_at_target_n_per_m.is_none());
    let v = serde_json::to_value(&r2).unwrap();
    assert!(v["large_signal"].get("keff_at_target_n_per_m").is_none());
    // No fitted K(x): the target is stated, no Keff invented.
    r2.stiffness.coefficients_n_per_m_pow_i_plus_1.clear();
    set_keff_at_target(&mut r2, Some(x));
    assert_eq!(r2.large_signal.target_xpeak_m, Some(x));
    assert!(r2.large_signal.keff_at_target_n_per_m.is_none());
}

/// Issue 11: a result with a non-finite stiffness coefficient (an
/// ill-conditioned fit; the store refuses such a result, QC judges it first)
/// against a K(x) mask was a `fail` whose value was stored as null. The
/// verdict is `invalid` and names the value; it passes the store's check.
#[test]
fn a_non_finite_value_makes_the_verdict_invalid_not_null() {
    let mut r = recipe();
    r.parameters.clear();
    r.kx_mask = Some(KxMask {
        x_m: vec![-0.004, 0.0, 0.004],
        lower_n_per_m: vec![1000.0; 3],
        upper_n_per_m: vec![1.0e5; 3],
        level_index: None,
    });
    let good = judge(&r, &facts(report(2400.0, 1.2e5, 3.6e7, 6.0)));
    assert_eq!(good.verdict, VerdictKind::Pass, "{good:?}");
    let mut rep = report(2400.0, 1.2e5, 3.6e7, 6.0);
    rep.stiffness.coefficients_n_per_m_pow_i_plus_1[2] = f64::NAN;
    let raw = judge_values(&r, &facts(rep.clone()));
    assert!(raw.parameters[0].value.is_nan(), "{raw:?}");
    let v = judge(&r, &facts(rep));
    assert_eq!(v.verdict, VerdictKind::Invalid, "{v:?}");
    assert_eq!(v.invalid_reasons[0].code, "non_finite_value");
    assert!(
        v.invalid_reasons[0]
            .detail
            .contains("NaN at failures[0].value"),
        "{v:?}"
    );
    let doc = crate::finite::to_value(&v).unwrap();
    assert_eq!(doc["verdict"], "invalid");
}

/// Issue 22: a part that reached 0.5 mm of an 8 mm target (a drive limit):
/// Keff at the target would be K(x) extrapolated 16 times past the measured
/// range, `not_determined` in the result. QC does not judge the fit's
/// number (before: `pass` or `fail` on it beside the invalid reasons): the
/// verdict is invalid with the reason, and no Keff parameter is judged.
#[test]
fn a_keff_at_target_not_determined_is_invalid_not_judged() {
    let mut r = report(2400.0, 0.0, 3.0e7, 6.0);
    r.stiffness.valid_range_m = [-0.0005, 0.0005];
    r.large_signal.xpeak_m = 0.0005;
    r.large_signal.x_min_at_resonance_m = -0.0005;
    r.large_signal.x_max_at_resonance_m = 0.0005;
    let mut rc = recipe();
    rc.parameters = vec![param("Keff", Quantity::Keff, None, Some(1.0), Some(1e12))];
    rc.kx_mask = None;
    rc.validity.min_xpeak_ratio = 0.0;
    let v = judge(&rc, &facts(r.clone()));
    assert_eq!(v.verdict, VerdictKind::Invalid, "{v:?}");
    assert!(v.parameters.iter().all(|p| p.name != "Keff"), "{v:?}");
    let why = v
        .invalid_reasons
        .iter()
        .find(|x| x.code == "value_not_determined")
        .unwrap_or_else(|| panic!("{v:?}"));
    assert!(why.detail.starts_with("Keff: not determined"), "{why:?}");
    assert!(why.detail.contains("measure at a level"), "{why:?}");
    // The same part measured to 7.8 mm: judged (and passes these limits).
    r.stiffness.valid_range_m = [-0.0078, 0.0078];
    r.large_signal.x_min_at_resonance_m = -0.0078;
    r.large_signal.x_max_at_resonance_m = 0.0078;
    let v = judge(&rc, &facts(r));
    assert_eq!(v.verdict, VerdictKind::Pass, "{v:?}");
}

/// Issue 22: k0 that the result marks `not_determined` (the fit gave
/// k0 <= 0; the headline is null) is invalid with the result's reason, not
/// an anonymous `analysis_failed`.
#[test]
fn a_small_signal_value_not_determined_names_its_reason() {
    let mut r = report(2400.0, 0.0, 3.0e7, 6.0);
    let ss = r.small_signal.as_mut().unwrap();
    ss.k0_n_per_m = Some(-5.0);
    crate::identify::validity::judge_small_signal(ss);
    let mut rc = recipe();
    rc.parameters = vec![param("k0", Quantity::K0, None, Some(1.0), Some(1e6))];
    rc.kx_mask = None;
    let v = judge(&rc, &facts(r));
    assert_eq!(v.verdict, VerdictKind::Invalid);
    let codes: Vec<&str> = v.invalid_reasons.iter().map(|x| x.code.as_str()).collect();
    assert_eq!(codes, ["value_not_determined"], "{v:?}");
    assert!(v.invalid_reasons[0]
        .detail
        .contains("no physical stiffness"));
}

/// Western Electric rules 1-4 on a chart with centre 0 and sigma 1, each
/// pattern placed by hand: 3.2 beyond 3 sigma (rule 1 at 1); 3.2 and 2.5 two
/// of three beyond 2 sigma (rule 2 at 3); -1.5, -1.2, -1.1, -1.3 four of
/// five beyond 1 sigma below (rule 3 at 9, the first window holding four);
/// eight negative points from index 4 (rule 4 at 11). Index 10 (-0.4) ends a
/// window of four beyond 1 sigma too but is not itself beyond: no signal.
#[test]
fn western_electric_rules_flag_the_points_that_complete_each_pattern() {
    use crate::qc::spc::western_electric;
    let v = [
        0.0, 3.2, 0.0, 2.5, -0.5, -0.3, -1.5, -1.2, -1.1, -1.3, -0.4, -0.2,
    ];
    let got: Vec<(u8, usize, &str)> = western_electric(&v, 0.0, 1.0)
        .iter()
        .map(|r| {
            (
                r.rule,
                r.index,
                if r.side == "above" { "above" } else { "below" },
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            (1, 1, "above"),
            (2, 3, "above"),
            (3, 9, "below"),
            (4, 11, "below")
        ]
    );
    // Scaled and shifted: the same signals (the rules read z-scores).
    let w: Vec<f64> = v.iter().map(|x| 2400.0 + 50.0 * x).collect();
    assert_eq!(western_electric(&w, 2400.0, 50.0).len(), 4);
    // No sigma: no signal.
    assert!(western_electric(&v, 0.0, 0.0).is_empty());
}

/// One level from sweeps to what is stored and judged (`qc::level`, the
/// runner's code before): a level that must not be fitted is stored without
/// a result, its reason kept, logged and judged invalid; an analysis that
/// fails is logged and not judged without a recipe; a result holding a NaN
/// is refused with the reason, a finite one stored as it is.
#[test]
fn a_level_not_fitted_or_failed_is_stored_with_its_reason_and_judged() {
    use super::level::{measure_level, storable, Level};
    use crate::recording::{Meta, Signals};
    let empty = Signals {
        sample_rate_hz: 48000.0,
        displacement_m: vec![],
        microphone_v: vec![],
        drive_v: None,
    };
    let meta = Meta::standard(0.05, 48000.0);
    let opts = crate::identify::AnalyzeOptions::default();
    let r = recipe();
    let level = |not_fitted: Option<String>, judged: bool| Level {
        sweeps: crate::identify::Sweeps {
            moving_mass_kg: 0.05,
            pre: &empty,
            main: &empty,
        },
        meta: &meta,
        opts: &opts,
        level_index: 1,
        target_xpeak_m: 0.006,
        warning: None,
        not_fitted,
        keep_force_balance: true,
        recipe: judged.then_some(&r),
        bench_cal: None,
        drive_v: 2.0,
        max_drive_v: 10.0,
        pre_drive_v: 0.5,
        pre_q_drive_to_x: None,
    };
    let why = "laser samples not on the audio clock (residual 80 us)".to_string();
    let out = measure_level(level(Some(why.clone()), true));
    assert!(out.report.is_none() && out.force_balance.is_none());
    assert_eq!(out.analysis_error.as_deref(), Some(why.as_str()));
    assert_eq!(
        out.log,
        vec![format!("level 2 (0.006 m) not fitted: {why}")]
    );
    let v = out.verdict.expect("judged under the recipe");
    assert_eq!(v.verdict, VerdictKind::Invalid, "{v:?}");
    assert!(v.failures.is_empty() && v.parameters.is_empty(), "{v:?}");

    let out = measure_level(level(None, false));
    let e = out.analysis_error.expect("empty sweeps do not analyse");
    assert!(out.report.is_none() && out.verdict.is_none());
    assert_eq!(
        out.log,
        vec![format!("analysis of level 2 (0.006 m) failed: {e}")]
    );

    let good = report(2400.0, 1.2e5, 3.6e7, 6.0);
    assert_eq!(storable(good.clone()), Ok(good.clone()));
    let mut bad = good;
    bad.stiffness.coefficients_n_per_m_pow_i_plus_1[1] = f64::INFINITY;
    let e = storable(bad).unwrap_err();
    assert!(e.starts_with("result refused: "), "{e}");
    assert!(e.contains("stiffness"), "{e}");
}
