//! The material's memory (issue 33) on the virtual bench: the recovery
//! measurement gives back the softening's depth and time constant, the
//! hidden hysteresis and softening are found by the diagnostics, and a
//! confusable neighbour is never named confidently for them.
use springbench::bench::procedure::memory::run_recovery;
use springbench::bench::virtual_bench::VirtualBench;
use springbench::bench::Control;
use springbench::diagnose::memory::RecoveryPlan;
use springbench::effects::*;
use springbench::physics::{preset, PartSpec};

fn spider_with(effects: Effects) -> PartSpec {
    let mut part = preset("spider_4in").unwrap();
    part.effects = effects;
    part
}

fn softening(depth_n_per_m2: f64, tau_s: f64) -> Effects {
    Effects {
        reversible_softening: Some(ReversibleSoftening {
            depth_n_per_m2,
            tau_s,
        }),
        ..Default::default()
    }
}

/// The spider's resonance (35 Hz) driven to about 5 mm, probes of about 0.2 mm.
fn plan() -> RecoveryPlan {
    RecoveryPlan::standard(30.0, 50.0, 1.5)
}

#[test]
fn recovery_gives_back_depth_and_time_constant() {
    for (depth, tau, seed) in [(3.0e4, 2.0, 1u64), (1.5e4, 6.0, 2)] {
        let part = spider_with(softening(depth, tau));
        let mut bench = VirtualBench::new(part.clone(), seed);
        let (_, r) = run_recovery(&mut bench, &plan(), part.moving_mass_kg, &mut |_| {
            Control::Continue
        })
        .unwrap();
        eprintln!(
            "depth {depth:.3e} tau {tau}: {:?}",
            serde_json::to_string(&r).unwrap()
        );
        assert!(r.softening_found, "{r:?}");
        assert!(
            (r.depth_n_per_m2 / depth - 1.0).abs() <= 0.10,
            "depth {} vs {depth}",
            r.depth_n_per_m2
        );
        assert!(
            (r.tau_s / tau - 1.0).abs() <= 0.10,
            "tau {} vs {tau}",
            r.tau_s
        );
        // The recovered K(0) is the part's (small-signal, within 2 %).
        assert!((r.k_recovered_n_per_m / 2400.0 - 1.0).abs() < 0.02, "{r:?}");
    }
}

#[test]
fn recovery_finds_no_softening_on_a_part_without_it() {
    for effects in [
        Effects::default(),
        Effects {
            creep: Some(Creep {
                k_n_per_m: 400.0,
                tau_s: 0.02,
            }),
            ..Default::default()
        },
    ] {
        let part = spider_with(effects);
        let mut bench = VirtualBench::new(part.clone(), 5);
        let (_, r) = run_recovery(&mut bench, &plan(), part.moving_mass_kg, &mut |_| {
            Control::Continue
        })
        .unwrap();
        eprintln!("{:?}: {r:?}", part.effects);
        assert!(!r.softening_found, "{r:?}");
        assert!(r.depth_n_per_m.abs() < 0.01 * 2400.0, "{r:?}");
    }
}

/// A level series (3, 6, 9 mm) of a softening part: the joint fit names the
/// softening (K(0) falls with level), with its depth, and K(x) of the
/// elastic part within 1 % RMS.
#[test]
fn level_series_names_the_softening() {
    // The same level series as tests/it/series.rs (spider_4in, 3/6/9 mm, seed 5).
    let (part, _sets, s) = crate::series::series(softening(3.0e4, 2.0));
    let k0: Vec<f64> = s
        .levels
        .iter()
        .map(|l| l.stiffness_coefficients_n_per_m_pow_i_plus_1[0])
        .collect();
    eprintln!("per-level k0 {k0:?}; joint effects {:?}", s.joint.effects);
    let soft = s
        .joint
        .effects
        .reversible_softening
        .expect("the joint fit names the softening");
    assert!((soft.depth_n_per_m2 / 3.0e4 - 1.0).abs() <= 0.2, "{soft:?}");
    let k = &s.joint.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let [lo, hi] = s.joint.valid_range_m;
    let (mut se, mut st) = (0.0, 0.0);
    for i in 0..=100 {
        let x = lo + (hi - lo) * i as f64 / 100.0;
        let kt = part.stiffness_n_per_m(x);
        let kf = k.iter().rev().fold(0.0, |a, c| a * x + c);
        se += (kf - kt).powi(2);
        st += kt * kt;
    }
    let rms = 100.0 * (se / st).sqrt();
    eprintln!("joint K(x) {rms:.3} % RMS");
    assert!(rms <= 1.0, "{rms}");
}

/// The recovery-of-the-law matrix (issue 33 acceptance): every preset, each
/// memory effect at two strengths, 3 noise seeds: the hidden effect ranked
/// first and significant, its parameter within 20 %, the model error down
/// by at least half, the headline K(x) within 1 % RMS of the elastic truth.
/// Always on: one preset per effect (`matrix_subset`); the full matrix:
/// `cargo test --release --test memory -- --ignored --nocapture matrix_full`.
fn matrix(presets: &[&str], strengths: &[usize], seeds: u64) {
    use springbench::bench::simulate::simulate_recording_set;
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    let mut failures = Vec::new();
    for name in presets {
        let nominal = preset(name).unwrap();
        let k0 = nominal.k_coeffs_si[0];
        for id in [EffectId::Hysteresis, EffectId::ReversibleSoftening] {
            for &strength in strengths {
                for seed in 0..seeds {
                    let f = [0.06, 0.15][strength];
                    let mut part = nominal.clone();
                    let (param, truth) = match id {
                        EffectId::Hysteresis => {
                            part.effects.hysteresis = Some(Hysteresis {
                                k_n_per_m: f * k0,
                                x_yield_m: 1e-3,
                            });
                            ("k_n_per_m", f * k0)
                        }
                        _ => {
                            // K(0) drops by f at a 5 mm excursion.
                            part.effects.reversible_softening = Some(ReversibleSoftening {
                                depth_n_per_m2: f * k0 / 5e-3,
                                tau_s: 2.0,
                            });
                            ("depth_n_per_m2", f * k0 / 5e-3)
                        }
                    };
                    let set = simulate_recording_set(&part, 900 + seed).unwrap();
                    let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
                    let diag =
                        serde_json::to_value(d.report.diagnostics.as_ref().unwrap()).unwrap();
                    let c = &diag["candidates"][0];
                    let base_me = diag["base_model"]["model_error_percent"].as_f64().unwrap();
                    let me = d.report.model.model_error_percent;
                    let got = c["parameters"][param].as_f64().unwrap_or(f64::NAN);
                    let s = &d.report.stiffness;
                    let [lo, hi] = s.valid_range_m;
                    let (mut se, mut st) = (0.0, 0.0);
                    for i in 0..=100 {
                        let x = lo + (hi - lo) * i as f64 / 100.0;
                        let kt = part.stiffness_n_per_m(x);
                        let kf = s
                            .coefficients_n_per_m_pow_i_plus_1
                            .iter()
                            .rev()
                            .fold(0.0, |a, c| a * x + c);
                        se += (kf - kt).powi(2);
                        st += kt * kt;
                    }
                    let k_rms = 100.0 * (se / st).sqrt();
                    let line = format!(
                        "{name} {id} x{f} seed {seed}: first {} sig {} cut {:.1} % (model error {base_me:.3} -> {me:.3} %), {param} {:+.1} %, K(x) {k_rms:.2} % RMS, K(x) state {:?}",
                        c["effect"],
                        c["significant"],
                        c["error_reduction_percent"].as_f64().unwrap_or(f64::NAN),
                        100.0 * (got / truth - 1.0),
                        s.validity.k_of_x
                    );
                    eprintln!("{line}");
                    let ok = c["effect"] == id.as_str()
                        && c["significant"] == true
                        && (got / truth - 1.0).abs() <= 0.2
                        && me <= 0.5 * base_me
                        && k_rms <= 1.0;
                    if !ok {
                        failures.push(line);
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// spider_4in at the larger strength; the open cases of the full matrix
/// (the 3" spider's softening ranks `stiffness_drift` first) are listed in
/// docs/diagnostics.md.
#[test]
fn matrix_subset() {
    matrix(&["spider_4in"], &[1], 1);
}

#[test]
#[ignore = "full matrix: 5 presets x 2 effects x 2 strengths x 3 seeds"]
fn matrix_full() {
    matrix(
        &[
            "spider_3in",
            "spider_4in",
            "cone_6in",
            "cone_18in",
            "passive_radiator",
        ],
        &[0, 1],
        3,
    );
}

/// Softening against drift (decision 0118): on the 3" spider a strong
/// softening's envelope grows with the clock over the sweep, and the ladder
/// adds `stiffness_drift` before the softening; once the softening is in,
/// the drift is idle and leaves the model again (before the backward check
/// the final model held both: drift 0.16 +- 0.10 N/m/s).
#[test]
fn softening_not_left_beside_a_drift_that_mimicked_it() {
    use springbench::bench::simulate::simulate_recording_set;
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    let mut part = preset("spider_3in").unwrap();
    part.effects = softening(0.15 * 1500.0 / 5e-3, 2.0);
    let set = simulate_recording_set(&part, 900).unwrap();
    let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
    let ids = d.report.model.effects.ids();
    eprintln!("{ids:?} {:?}", d.report.model.effects);
    assert_eq!(ids, vec![EffectId::ReversibleSoftening]);
    let got = d.report.model.effects.reversible_softening.unwrap();
    assert!((got.depth_n_per_m2 / 4.5e4 - 1.0).abs() <= 0.2, "{got:?}");
}
