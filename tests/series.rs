//! Level series (issue 12): K(x) and the effects fitted jointly over all
//! levels of a series (`diagnose::series`), against the part's truth on the
//! virtual bench, beside each level's own fit. Three levels (3, 6, 9 mm
//! targets) of the 4" spider with an effect that changes with amplitude.
use springbench::diagnose::engine::EngineOptions;
use springbench::diagnose::series::{fit_series_sets, SeriesFit};
use springbench::diagnose::{diagnose, DiagnoseOptions};
use springbench::effects::*;
use springbench::physics::{preset, simulate, PartSpec, SimulateOptions};
use springbench::recording::RecordingSet;

fn k_of(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |a, k| a * x + k)
}

/// RMS of K_fit(x) - K_true(x) over `range` relative to RMS K_true (%).
fn k_rms(part: &PartSpec, coef: &[f64], range: [f64; 2]) -> f64 {
    let (mut se, mut st) = (0.0, 0.0);
    for i in 0..=100 {
        let x = range[0] + (range[1] - range[0]) * i as f64 / 100.0;
        let kt = part.stiffness_n_per_m(x);
        se += (k_of(coef, x) - kt).powi(2);
        st += kt * kt;
    }
    100.0 * (se / st).sqrt()
}

fn series(effects: Effects) -> (PartSpec, Vec<RecordingSet>, SeriesFit) {
    let mut part = preset("spider_4in").unwrap();
    part.effects = effects;
    let mut opts = SimulateOptions::default();
    opts.procedure.levels_m = vec![0.003, 0.006, 0.009];
    let sim = simulate(&part, 5, &opts).unwrap();
    let sets: Vec<RecordingSet> = sim
        .outcome
        .narrow
        .iter()
        .map(|n| RecordingSet {
            meta: sim.set.meta.clone(),
            pre: sim.set.pre.clone(),
            main: n.signals.clone(),
        })
        .collect();
    assert_eq!(sets.len(), 3);
    let s = fit_series_sets(&sets, &EngineOptions::default()).unwrap();
    (part, sets, s)
}

/// Prints and checks the K(x) errors; returns the joint error over the union.
fn k_errors(part: &PartSpec, s: &SeriesFit) -> f64 {
    let union = s.joint.valid_range_m;
    let joint = &s.joint.stiffness_coefficients_n_per_m_pow_i_plus_1;
    for (i, l) in s.levels.iter().enumerate() {
        let own = &l.stiffness_coefficients_n_per_m_pow_i_plus_1;
        let (e_own, e_joint, e_union) = (
            k_rms(part, own, l.range_m),
            k_rms(part, joint, l.range_m),
            k_rms(part, own, union),
        );
        eprintln!(
            "level {}: x {:.2}..{:.2} mm, effects {:?}; K(x) error over its range: own fit {e_own:.4} %, joint {e_joint:.4} %; own fit over the series' range {e_union:.3} %",
            i + 1,
            l.range_m[0] * 1e3,
            l.range_m[1] * 1e3,
            l.effects.ids()
        );
        // The joint K(x) holds on every level's range.
        assert!(e_joint <= 0.05, "level {}: {e_joint}", i + 1);
    }
    let e = k_rms(part, joint, union);
    eprintln!(
        "joint: x {:.2}..{:.2} mm, effects {:?}, K(x) error {e:.4} %, R {:.4} (true {:.4})",
        union[0] * 1e3,
        union[1] * 1e3,
        s.joint.effects,
        s.joint.r_ns_per_m,
        part.r_ns_per_m
    );
    assert!(e <= 0.05, "{e}");
    assert!((s.joint.r_ns_per_m / part.r_ns_per_m - 1.0).abs() < 0.01);
    e
}

#[test]
fn joint_fit_separates_quadratic_damping_from_friction_and_k() {
    let (part, sets, s) = series(Effects {
        quadratic_damping: Some(QuadraticDamping {
            coeff_ns2_per_m2: 1.0,
        }),
        ..Default::default()
    });
    k_errors(&part, &s);
    // The lowest level alone cannot tell v|v| damping from dry friction: the
    // pair is reported with the separating experiment (another level) ...
    let low = diagnose(&sets[0], &DiagnoseOptions::default()).unwrap();
    let amb = &low.report.diagnostics.as_ref().unwrap()["ambiguities"];
    eprintln!("3 mm level alone: ambiguities {amb}");
    let pair = amb
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["effects"] == serde_json::json!(["quadratic_damping", "coulomb_friction"]))
        .unwrap_or_else(|| panic!("no pair in {amb}"));
    assert!(pair["separating_experiment"]
        .as_str()
        .unwrap()
        .contains("second drive level"));
    // ... and the joint fit over the levels does: v|v| damping alone, its
    // coefficient within 1 %, no ambiguity left.
    eprintln!("joint ambiguities {:?}", s.joint.ambiguities);
    assert!(s.joint.ambiguities.is_empty());
    assert_eq!(s.joint.effects.ids(), vec![EffectId::QuadraticDamping]);
    let c = s.joint.effects.quadratic_damping.unwrap().coeff_ns2_per_m2;
    assert!((c - 1.0).abs() < 0.01, "{c}");
}

#[test]
fn joint_fit_with_friction() {
    let (part, _, s) = series(Effects {
        coulomb_friction: Some(CoulombFriction {
            force_n: 0.2,
            v_eps_m_per_s: 2e-3,
        }),
        ..Default::default()
    });
    k_errors(&part, &s);
    assert_eq!(s.joint.effects.ids(), vec![EffectId::CoulombFriction]);
    let f = s.joint.effects.coulomb_friction.unwrap().force_n;
    assert!((f / 0.2 - 1.0).abs() < 0.02, "{f}");
}
