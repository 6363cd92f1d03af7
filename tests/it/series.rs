//! Level series (issue 12): K(x) and the effects fitted jointly over all
//! levels of a series (`diagnose::series`), against the part's truth on the
//! virtual bench, beside each level's own fit. Three levels (3, 6, 9 mm
//! targets) of the 4" spider with an effect that changes with amplitude.
use crate::common;

use common::{client, get, submit, terminal, wait_job, Daemon};
use serde_json::{json, Value};
use springbench::bench::simulate::simulate;
use springbench::bench::simulate::SimulateOptions;
use springbench::diagnose::engine::EngineOptions;
use springbench::diagnose::series::{fit_series_sets, SeriesFit};
use springbench::diagnose::{diagnose, DiagnoseOptions};
use springbench::effects::*;
use springbench::identify::validity::ACCURACY_K_OF_X;
use springbench::physics::{preset, PartSpec};
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

pub(crate) fn series(effects: Effects) -> (PartSpec, Vec<RecordingSet>, SeriesFit) {
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
    let amb = serde_json::to_value(&low.report.diagnostics).unwrap()["ambiguities"].clone();
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

/// K(x) coefficients (N/m^(i+1)) of a JSON array.
fn coefs(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("no coefficients: {v}"))
        .iter()
        .map(|c| c.as_f64().unwrap())
        .collect()
}

fn range_of(v: &Value) -> [f64; 2] {
    [v[0].as_f64().unwrap(), v[1].as_f64().unwrap()]
}

/// A daemon job with three levels ends with the joint fit in the result
/// document of each level (`series`), against the part's truth: the joint
/// K(x) holds over the whole series' range, where the lowest level's own
/// fit (and its plain headline K(x)) does not.
#[tokio::test]
async fn daemon_job_with_levels_ends_with_the_joint_fit() {
    let d = Daemon::start("");
    let c = client();
    let mut part = preset("spider_4in").unwrap();
    part.effects = Effects {
        coulomb_friction: Some(CoulombFriction {
            force_n: 0.2,
            v_eps_m_per_s: 2e-3,
        }),
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let id = submit(
        &c,
        &d,
        json!({"part": {"serial": "SN-SERIES"}, "part_spec": part,
               "levels_m": [0.003, 0.006, 0.009]}),
    )
    .await;
    let j = wait_job(&c, &d, &id, std::time::Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    eprintln!(
        "job: {:.1} s wall; log {}",
        t.elapsed().as_secs_f64(),
        j["log"]
    );
    let ids: Vec<String> = j["measurement_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    assert_eq!(ids.len(), 3);
    let docs: Vec<Value> = {
        let mut v = vec![];
        for m in &ids {
            v.push(get(&c, &d, &format!("/api/v1/measurements/{m}")).await);
        }
        v
    };
    // The same joint fit in every level's document, naming the levels.
    let s = &docs[0]["series"];
    assert!(s.is_object(), "no series in {}", docs[0]);
    for doc in &docs[1..] {
        assert_eq!(&doc["series"], s);
    }
    let levels = s["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 3);
    for (i, l) in levels.iter().enumerate() {
        assert_eq!(l["measurement_id"], json!(ids[i]));
        assert_eq!(
            l["target_xpeak_m"],
            docs[i]["measurement"]["target_xpeak_m"]
        );
    }
    let joint = &s["joint"];
    let union = range_of(&joint["valid_range_m"]);
    let e_joint = k_rms(
        &part,
        &coefs(&joint["stiffness_coefficients_n_per_m_pow_i_plus_1"]),
        union,
    );
    // The lowest level alone: its own fit in the series (engine, effects
    // chosen by its ladder) and its document's headline (plain analysis).
    let low = &levels[0];
    let low_range = range_of(&low["range_m"]);
    let own = coefs(&low["stiffness_coefficients_n_per_m_pow_i_plus_1"]);
    let headline = coefs(&docs[0]["stiffness"]["coefficients_n_per_m_pow_i_plus_1"]);
    let (e_own_union, e_own_range) = (k_rms(&part, &own, union), k_rms(&part, &own, low_range));
    let e_joint_low = k_rms(
        &part,
        &coefs(&joint["stiffness_coefficients_n_per_m_pow_i_plus_1"]),
        low_range,
    );
    let (e_head_union, e_head_range) = (
        k_rms(&part, &headline, union),
        k_rms(&part, &headline, low_range),
    );
    eprintln!(
        "series over {:.2}..{:.2} mm, joint effects {}, R {} (true {}): K(x) RMS error over the series' range: joint {e_joint:.4} %, lowest level's own fit {e_own_union:.3} %, its headline (plain) {e_head_union:.3} %; over the lowest level's range ({:.2}..{:.2} mm): joint {e_joint_low:.4} %, own {e_own_range:.4} %, headline {e_head_range:.4} %",
        union[0] * 1e3,
        union[1] * 1e3,
        joint["effects"],
        joint["r_ns_per_m"],
        part.r_ns_per_m,
        low_range[0] * 1e3,
        low_range[1] * 1e3,
    );
    assert!(e_joint <= 0.05, "{e_joint}");
    // Beyond its range the lowest level's own K(x) is an extrapolation, the
    // joint K(x) a fit to data there. How far off the extrapolation is
    // depends on whether that level's own ladder resolved the friction:
    // 5.1 % at 2.98 mm of 3, 0.030 % at 3.29 mm (issue 35's level control
    // reaches the target on both sides), both of an order-4 fit of an order-4
    // truth; no ratio of the two follows from the physics, so only the order
    // is asserted. The plain headline, which has no friction term, stays
    // beyond the stated K(x) accuracy over the series' range.
    assert!(e_own_union > e_joint, "{e_own_union} vs {e_joint}");
    assert!(
        e_head_union > 100.0 * ACCURACY_K_OF_X,
        "headline {e_head_union} % over the series' range"
    );
    assert!(
        joint["effects"]["coulomb_friction"].is_object(),
        "{}",
        joint["effects"]
    );
    let f = joint["effects"]["coulomb_friction"]["force_n"]
        .as_f64()
        .unwrap();
    assert!((f / 0.2 - 1.0).abs() < 0.02, "{f}");
    let r = joint["r_ns_per_m"].as_f64().unwrap();
    assert!((r / part.r_ns_per_m - 1.0).abs() < 0.01, "{r}");
    // Keff at the level's target beside the one at the reached Xpeak.
    for doc in &docs {
        let ls = &doc["large_signal"];
        assert_eq!(ls["target_xpeak_m"], doc["measurement"]["target_xpeak_m"]);
        assert!(ls["keff_at_target_n_per_m"].as_f64().unwrap() > 0.0, "{ls}");
    }
}
