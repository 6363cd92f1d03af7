//! The material's memory (issue 33) on the virtual bench: the recovery
//! measurement gives back the softening's depth and time constant, the
//! hidden hysteresis and softening are found by the diagnostics, and a
//! confusable neighbour is never named confidently for them.
use springbench::bench::procedure::memory::run_recovery;
use springbench::bench::virtual_bench::VirtualBench;
use springbench::bench::Control;
use springbench::diagnose::engine::Term;
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
/// first (the final ranking the document shows, after the ladder's backward
/// check and the neighbours' check) and significant, its parameter within
/// 20 %, the model error down by at least half, the headline K(x) within
/// 1 % RMS of the elastic truth.
///
/// The model error is measured on the record's noise-free twin (decision
/// 0123): the same part and drive with the sensors' noise off, the base
/// model and the model the diagnostics chose each fitted to it. On a noisy
/// record the reported model error, sqrt(residual^2 - noise floor^2), is
/// resolved only down to 4-12 % of the noise floor (a clean part reads
/// 0.31 % on the 18" cone's 7.4 % floor), and a weak effect's whole share
/// lies below that; the noisy figures are printed beside it.
/// Always on: one preset per effect (`matrix_subset`); the full matrix:
/// `cargo test --release --test it -- --ignored --nocapture memory::matrix_full`.
fn matrix(presets: &[&str], strengths: &[usize], seeds: u64) {
    use springbench::bench::simulate::{simulate, simulate_recording_set, SimulateOptions};
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    use springbench::identify::validity::State::Unreliable;
    let mut failures = Vec::new();
    let mut quiet = SimulateOptions::default();
    quiet.bench.laser.noise_m = 0.0;
    quiet.bench.microphone.noise_pa = 0.0;
    for name in presets {
        let nominal = preset(name).unwrap();
        let k0 = nominal.k_coeffs_si[0];
        for id in [EffectId::Hysteresis, EffectId::ReversibleSoftening] {
            for &strength in strengths {
                // The noise-free twin's model error per model (the seed only draws the noise).
                let mut twin: Option<springbench::identify::ForceBalanceData> = None;
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
                    let twin = twin.get_or_insert_with(|| {
                        let set = simulate(&part, 900, &quiet).unwrap().set;
                        springbench::identify::analyze_for_diagnosis(&set, &Default::default())
                            .unwrap()
                            .1
                    });
                    // The base model and the chosen one (its yield excursion
                    // or tau as found on the noisy record), refitted to the
                    // twin: there the residual is the model error (a clean
                    // part leaves 0.0005-0.006 %).
                    let twin_error = |m: &serde_json::Value| {
                        let model = serde_json::from_value(serde_json::json!({
                            "order": m["order"], "effect_ids": m["effects"],
                            "effects": m["parameters"], "effects_se": {},
                            "stiffness_coefficients_n_per_m_pow_i_plus_1": [],
                            "r_ns_per_m": 0.0, "force_per_mic_n_per_v": 0.0,
                            "residual_percent": 0.0, "cv_residual_percent": 0.0
                        }))
                        .unwrap();
                        springbench::diagnose::engine::refit_jointly(
                            twin,
                            &Default::default(),
                            &model,
                            0,
                        )
                        .unwrap()
                        .residual_percent
                    };
                    let (twin_base, twin_final) = (
                        twin_error(&diag["base_model"]),
                        twin_error(&diag["final_model"]),
                    );
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
                        "{name} {id} x{f} seed {seed}: first {} sig {} cut {:.1} % (model error {base_me:.3} -> {me:.3} %; noise-free twin {twin_base:.3} -> {twin_final:.3} %), {param} {:+.1} %, K(x) {k_rms:.2} % RMS, K(x) state {:?}",
                        c["effect"],
                        c["significant"],
                        c["error_reduction_percent"].as_f64().unwrap_or(f64::NAN),
                        100.0 * (got / truth - 1.0),
                        s.validity.k_of_x
                    );
                    eprintln!("{line}");
                    // The record cannot weigh it (decision 0123): said, with
                    // the experiment, and the headline values marked.
                    let cannot_tell = c["effect"] == id.as_str()
                        && c["significant"] == false
                        && c["note"]
                            .as_str()
                            .is_some_and(|n| n.starts_with("cannot tell whether"))
                        && d.report.warnings.iter().any(|w| {
                            w.starts_with("cannot tell whether")
                                && w.contains(Term::Effect(id).separating_experiment())
                        })
                        && s.validity.k_of_x.state == Unreliable
                        && d.report.large_signal.validity.keff_n_per_m.state == Unreliable;
                    if cannot_tell {
                        eprintln!("  cannot tell (named, with its experiment): {line}");
                        continue;
                    }
                    let ok = c["effect"] == id.as_str()
                        && c["significant"] == true
                        && (got / truth - 1.0).abs() <= 0.2
                        && twin_final <= 0.5 * twin_base
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

/// spider_4in at the larger strength; the full matrix (60 of 60 since
/// decision 0141) is in docs/diagnostics.md; its hardest cases (the 18"
/// cone's hysteresis with seed 902) are always-on tests below.
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

/// The 18" cone's hysteresis (x_yield 1 mm) with seed 902, whose noise
/// floor the spectrum's estimator puts above the base model's held-out
/// residual (decisions 0123, 0128, 0140, 0141): the block test finds it
/// (p about 1e-47 and 1e-42, the first candidate), but with that floor the
/// model error reads 0 and the 5 % relevance rule cannot be met. Weighed
/// against the floor read by the residual's own estimator (the mean square
/// times the noise's share of the spectrum), it removes 7.8 % and 30.9 %
/// of the held-out model error and is added.
/// - k = 0.06 x k0: before (decision 0140) "cannot tell whether hysteresis
///   matters", nothing added, K(x) 0.42 % RMS from the elastic truth and
///   `unreliable`; now added, k within 2 % of the truth, K(x) 0.01 % RMS.
/// - k = 0.15 x k0: added since decision 0140 (by the headline it moves),
///   now by the 5 % rule; K(x) 0.15 % RMS, `valid`, k within 20 %.
fn hysteresis_of_seed_902_is_added(f: f64, k_rms_max: f64) {
    use springbench::bench::simulate::simulate_recording_set;
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    use springbench::identify::validity::State::Valid;
    let mut part = preset("cone_18in").unwrap();
    let k = f * part.k_coeffs_si[0];
    part.effects = hysteresis(k, 1e-3);
    let set = simulate_recording_set(&part, 902).unwrap();
    let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
    let diag = d.report.diagnostics.as_ref().unwrap();
    let first = &diag.candidates[0];
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
    let k_rms = (se / st).sqrt();
    let got = first.parameters["k_n_per_m"].as_f64().unwrap();
    eprintln!(
        "x{f}: first {} significant {} p {:.1e} k {got:.1} ({:+.1} %) K(x) {:.2} % RMS {:?} note {:?}; model {:?}; warnings {:#?}",
        first.effect,
        first.significant,
        first.p_value,
        100.0 * (got / k - 1.0),
        100.0 * k_rms,
        s.validity.k_of_x.state,
        first.note,
        diag.final_model.effects,
        d.report.warnings
    );
    assert_eq!(first.effect, "hysteresis");
    assert!(first.significant && first.p_value < first.alpha * 1e-6);
    assert_eq!(diag.final_model.effects, vec![EffectId::Hysteresis]);
    assert!(first
        .note
        .as_deref()
        .is_some_and(|n| n.starts_with("added because it removes")));
    assert!((got / k - 1.0).abs() <= 0.2, "{got} against {k}");
    assert!(k_rms <= k_rms_max, "{k_rms}");
    assert_eq!(s.validity.k_of_x.state, Valid);
    assert!(!d
        .report
        .warnings
        .iter()
        .any(|w| w.starts_with("cannot tell whether")));
}

#[test]
fn a_weak_hysteresis_is_weighed_against_the_floor_the_residual_is_read_by() {
    hysteresis_of_seed_902_is_added(0.06, 0.001);
}

#[test]
fn a_strong_hysteresis_the_spectrums_floor_cannot_weigh_is_added() {
    hysteresis_of_seed_902_is_added(0.15, 0.002);
}

/// A hysteresis within the floor's resolution (decisions 0123, 0128): the
/// 18" cone with k = 0.06 x k0, x_yield 1 mm, seed 904. Its whole share is
/// 0.05 % of the residual's variance, below what the floor estimate
/// resolves (a clean record's model error reads up to 13 % of the floor);
/// the block test finds it (p about 1e-43) but it removes 4.3 % of the
/// held-out model error (0.60 % over a floor of 7.24 %), under the 5 %
/// rule, and is not added. The floor lies below the residual here, so
/// decision 0123's trigger (floor not below the residual) missed it: before,
/// nothing said so and K(x), Keff and fR were `valid`; now the document
/// says "cannot tell whether hysteresis matters" with the separating
/// experiment and marks them (its share is several % of Keff).
#[test]
fn a_hysteresis_within_the_floors_resolution_is_cannot_tell() {
    use springbench::bench::simulate::simulate_recording_set;
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    use springbench::identify::validity::State::Unreliable;
    let mut part = preset("cone_18in").unwrap();
    part.effects = hysteresis(0.06 * part.k_coeffs_si[0], 1e-3);
    let set = simulate_recording_set(&part, 904).unwrap();
    let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
    let diag = d.report.diagnostics.as_ref().unwrap();
    let first = &diag.candidates[0];
    eprintln!(
        "first {} p {:.1e} alpha {:.1e} cut {:.1} % note {:?}; model {:?}; warnings {:#?}",
        first.effect,
        first.p_value,
        first.alpha,
        first.error_reduction_percent,
        first.note,
        diag.final_model.effects,
        d.report.warnings
    );
    assert_eq!(first.effect, "hysteresis");
    assert!(!first.significant && first.p_value < first.alpha * 1e-6);
    assert!(diag.final_model.effects.is_empty());
    let experiment = Term::Effect(EffectId::Hysteresis).separating_experiment();
    let note = first.note.as_deref().unwrap();
    assert!(
        note.starts_with("cannot tell whether hysteresis matters") && note.contains(experiment),
        "{note}"
    );
    assert!(d
        .report
        .warnings
        .iter()
        .any(|w| note.starts_with(w.as_str())));
    assert_eq!(d.report.stiffness.validity.k_of_x.state, Unreliable);
    assert_eq!(
        d.report.large_signal.validity.keff_n_per_m.state,
        Unreliable
    );
    assert_eq!(
        d.report.large_signal.validity.resonance_hz.state,
        Unreliable
    );
}

/// Softening against drift (decisions 0118, 0120): on the 3" spider a
/// strong softening's envelope grows with the clock over the sweep, and
/// `stiffness_drift` alone removes as much of the base model's error as the
/// softening (44 % against 41 % at tau 2 s). The ladder took the drift
/// first; once the softening is in, the drift is idle and leaves the model
/// again (before the backward check the final model held both). The drift
/// is never named with confidence: it ranks below the softening, marked as
/// having only stood in for it, and no warning says the part misses it
/// (before decision 0120 it was the first candidate, "the base model misses
/// stiffness_drift: the diagnostics added it"). Also with a softening that
/// recovers slower than the record (tau 30 s: the envelope is the sweep's).
#[test]
fn softening_is_named_and_drift_never_with_confidence() {
    use springbench::bench::simulate::simulate_recording_set;
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    for (depth, tau) in [(4.5e4, 2.0), (1.8e4, 30.0)] {
        let mut part = preset("spider_3in").unwrap();
        part.effects = softening(depth, tau);
        let set = simulate_recording_set(&part, 900).unwrap();
        let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
        let ids = d.report.model.effects.ids();
        let diag = d.report.diagnostics.as_ref().unwrap();
        let first = &diag.candidates[0];
        let drift = diag
            .candidates
            .iter()
            .find(|c| c.effect == "stiffness_drift")
            .unwrap();
        eprintln!(
            "depth {depth} tau {tau}: model {ids:?}, first {} ({:.1} %), drift cut {:.1} % stands in for {:?}; warnings {:#?}",
            first.effect, first.error_reduction_percent, drift.error_reduction_percent, drift.stands_in_for, d.report.warnings
        );
        assert_eq!(ids, vec![EffectId::ReversibleSoftening]);
        let got = d.report.model.effects.reversible_softening.unwrap();
        assert!((got.depth_n_per_m2 / depth - 1.0).abs() <= 0.2, "{got:?}");
        assert_eq!(first.effect, "reversible_softening");
        assert!(first.significant && first.stands_in_for.is_none());
        // The drift fits much of the same structure, and the document says
        // it only stood in for the softening.
        assert!(drift.significant && drift.error_reduction_percent >= 30.0);
        assert_eq!(drift.stands_in_for.as_deref(), Some("reversible_softening"));
        assert!(drift
            .note
            .as_deref()
            .unwrap()
            .contains("the data name reversible_softening"));
        assert!(
            !d.report
                .warnings
                .iter()
                .any(|w| w.contains("misses stiffness_drift")),
            "{:#?}",
            d.report.warnings
        );
    }
}

fn hysteresis(k_n_per_m: f64, x_yield_m: f64) -> Effects {
    Effects {
        hysteresis: Some(Hysteresis {
            k_n_per_m,
            x_yield_m,
        }),
        ..Default::default()
    }
}

/// The diagnosis of a 4" spider with `effects` measured at `levels_m`
/// (one level: the single-sweep diagnosis; the joint fit of a series
/// otherwise, returned as its ambiguities and the joint model's effects).
fn diagnose_at(
    effects: Effects,
    levels_m: Vec<f64>,
) -> (
    Vec<EffectId>,
    Vec<springbench::identify::diagnostics::Ambiguity>,
    Vec<String>,
) {
    use springbench::bench::simulate::{simulate, SimulateOptions};
    use springbench::diagnose::{diagnose, DiagnoseOptions};
    let part = spider_with(effects);
    let mut opts = SimulateOptions::default();
    opts.procedure.levels_m = levels_m;
    let sim = simulate(&part, 900, &opts).unwrap();
    if sim.outcome.narrow.len() > 1 {
        let sets: Vec<springbench::recording::RecordingSet> = sim
            .outcome
            .narrow
            .iter()
            .map(|n| springbench::recording::RecordingSet {
                meta: sim.set.meta.clone(),
                pre: sim.set.pre.clone(),
                main: n.signals.clone(),
            })
            .collect();
        let s = springbench::diagnose::series::fit_series_sets(&sets, &Default::default()).unwrap();
        return (s.joint.effects.ids(), s.joint.ambiguities, vec![]);
    }
    let d = diagnose(&sim.set, &DiagnoseOptions::default()).unwrap();
    let diag = d.report.diagnostics.unwrap();
    // The engine's chosen model (the headline's may leave stand-ins out).
    (
        diag.final_model.effects,
        diag.ambiguities,
        d.report.warnings,
    )
}

/// Hysteresis against its neighbours (decision 0120). Where one sweep
/// cannot separate them the diagnostics say so, name both and the
/// separating experiment, instead of naming one with confidence:
/// - a yield excursion of 0.02 mm at an 8 mm sweep: the element is a dry
///   friction force but for 0.02 mm after each reversal (each removes
///   17-18 % of the base model's error);
/// - a yield excursion of 20 mm, beyond the sweep's 8 mm: a thin loop that
///   creep (tau 80 ms) also draws, both mostly a stiffness (variance
///   inflation 488 and 721).
///
/// The same part with the separating experiment, a level series (3, 6,
/// 9 mm): the joint fit names hysteresis, not creep (at 3 mm alone the
/// ladder takes creep and v|v| damping). A hysteresis whose loop the sweep
/// resolves (0.3 mm) is named without any ambiguity.
#[test]
fn hysteresis_cannot_tell_and_the_separating_experiment() {
    let experiment = Term::Effect(EffectId::Hysteresis).separating_experiment();
    for (xy, other) in [(2e-5, "coulomb_friction"), (2e-2, "creep")] {
        let (chosen, amb, warnings) = diagnose_at(hysteresis(1000.0, xy), vec![0.008]);
        eprintln!("x_yield {xy}: chosen {chosen:?}; {amb:#?}");
        let a = amb
            .iter()
            .find(|a| {
                a.effects.contains(&"hysteresis".to_string())
                    && a.effects.contains(&other.to_string())
            })
            .unwrap_or_else(|| panic!("no cannot-tell for hysteresis/{other}: {amb:#?}"));
        assert!(a.note.starts_with("cannot tell"), "{}", a.note);
        assert_eq!(a.separating_experiment, experiment);
        assert!(warnings.iter().any(|w| w == &a.note));
    }
    // The separating experiment on the 20 mm part: a level series.
    let (joint, amb, _) = diagnose_at(hysteresis(1000.0, 2e-2), vec![0.003, 0.006, 0.009]);
    eprintln!("level series: joint {joint:?}; {amb:#?}");
    assert!(joint.contains(&EffectId::Hysteresis), "{joint:?}");
    assert!(!joint.contains(&EffectId::Creep), "{joint:?}");
    // A loop the sweep resolves: named, nothing ambiguous about it.
    let (chosen, amb, _) = diagnose_at(hysteresis(300.0, 3e-4), vec![0.008]);
    eprintln!("x_yield 0.3 mm: chosen {chosen:?}; {amb:#?}");
    assert_eq!(chosen, vec![EffectId::Hysteresis]);
    assert!(
        amb.iter()
            .all(|a| !a.effects.contains(&"hysteresis".to_string())),
        "{amb:#?}"
    );
}

/// The added-mass study as a daemon job (decision 0121), on the virtual
/// bench's spider_4in (moving mass 0.050 kg, k0 2400 N/m) weighed 10 % light
/// (0.045 kg): a bad request names its fields; the study measures the part,
/// waits in `awaiting_operator` with the instruction until the operator
/// confirms (a second confirmation is 409), measures the part with 20 g
/// added to the simulated slide, and derives the moving mass within 3 %
/// (measured +1.8 %), k0 within 4 % of K(0) (measured +3.2 %: the
/// pre-measurement's 1 mm already bends the hardening K(x), +1.4 % in the
/// single measurement with the true mass) and the weighing's error within
/// 2 points (measured -11.6 % for -10 %).
#[tokio::test]
async fn added_mass_study_job_derives_the_moving_mass() {
    use crate::common::{client, problem, terminal, wait_job, Daemon};
    use serde_json::{json, Value};
    let d = Daemon::start("");
    let c = client();
    // Bad input: problem+json naming each field.
    let r = c
        .post(d.url("/api/v1/studies"))
        .json(
            &json!({"bench": "virtual-1", "part_serial": "SN-M", "moving_mass_kg": -1.0,
            "plan": {"added_mass": {"added_mass_kg": 0.0, "level_m": 0.004}}}),
        )
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    let fields: Vec<&str> = p["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["field"].as_str().unwrap())
        .collect();
    assert_eq!(
        fields,
        ["moving_mass_kg", "plan.added_mass.added_mass_kg"],
        "{p}"
    );
    let r = c
        .post(d.url("/api/v1/studies"))
        .json(
            &json!({"bench": "nope", "part_serial": "SN-M", "moving_mass_kg": 0.05,
            "plan": {"added_mass": {"added_mass_kg": 0.02, "level_m": 0.004}}}),
        )
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "bench", "{p}");

    let r = c
        .post(d.url("/api/v1/studies"))
        .json(
            &json!({"bench": "virtual-1", "part_serial": "SN-M", "preset": "spider_4in",
            "moving_mass_kg": 0.045,
            "plan": {"added_mass": {"added_mass_kg": 0.02, "level_m": 0.004}}}),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let v: Value = r.json().await.unwrap();
    let id = v["id"].as_str().unwrap().to_string();
    let study = |c: reqwest::Client, path: String| async move {
        c.get(path)
            .send()
            .await
            .unwrap()
            .json::<Value>()
            .await
            .unwrap()
    };
    let url = d.url(&format!("/api/v1/studies/{id}"));
    let t = std::time::Instant::now();
    let waiting = loop {
        let s = study(c.clone(), url.clone()).await;
        if s["state"] == "awaiting_operator" || t.elapsed().as_secs() > 300 {
            break s;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    };
    assert_eq!(waiting["state"], "awaiting_operator", "{waiting}");
    assert_eq!(waiting["job_state"], "running");
    assert!(
        waiting["instruction"]
            .as_str()
            .unwrap()
            .starts_with("add 20.0 g to the slide"),
        "{waiting}"
    );
    // It waits: still there a moment later.
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    assert_eq!(
        study(c.clone(), url.clone()).await["state"],
        "awaiting_operator"
    );
    let confirm = d.url(&format!("/api/v1/studies/{id}/confirm"));
    let r = c.post(&confirm).json(&json!({})).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let r = c.post(&confirm).json(&json!({})).send().await.unwrap();
    let p = problem(r, 409).await;
    assert!(
        p["detail"]
            .as_str()
            .unwrap()
            .contains("is confirmed, not awaiting_operator"),
        "{p}"
    );
    let j = wait_job(&c, &d, &id, std::time::Duration::from_secs(300), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let s = study(c.clone(), url.clone()).await;
    eprintln!("{s:#}");
    assert_eq!(s["state"], "succeeded");
    let r = &s["result"];
    assert_eq!(r["kind"], "added_mass");
    let m = r["moving_mass_derived_kg"].as_f64().unwrap();
    let k0 = r["k0_derived_n_per_m"].as_f64().unwrap();
    let werr = r["weighed_mass_error_percent"].as_f64().unwrap();
    eprintln!("derived mass {m:.5} kg (truth 0.05), k0 {k0:.1} N/m (truth 2400), weighing {werr:+.2} % (truth -10 %)");
    assert!((m / 0.05 - 1.0).abs() <= 0.03, "{m}");
    assert!((k0 / 2400.0 - 1.0).abs() <= 0.04, "{k0}");
    assert!((werr + 10.0).abs() <= 2.0, "{werr}");
    // The attribution (decision 0122) of a part without a memory: neither
    // cause, both shares exactly 0.
    let a = &r["attribution"];
    eprintln!("attribution: {a}");
    assert_eq!(a["frequency_dependent_n_per_m"], 0.0, "{a}");
    assert_eq!(a["amplitude_dependent_n_per_m"], 0.0, "{a}");
    assert!(
        a["effects"].get("creep").is_none() && a["effects"].get("reversible_softening").is_none(),
        "{a}"
    );
    // An unknown study: 404.
    let r = c.get(d.url("/api/v1/studies/nope")).send().await.unwrap();
    problem(r, 404).await;
}

/// A study killed (kill -9) while it waits for the operator: after the
/// restart its job is `interrupted` (never re-run silently), and the study
/// says so too: `failed`, no instruction left, and a confirmation is a 409
/// (it was `awaiting_operator` for a job that no longer runs, and a
/// confirmation was accepted).
#[tokio::test]
async fn a_study_killed_while_it_waits_ends_with_its_job() {
    use crate::common::{Api, Daemon};
    use serde_json::json;
    use std::time::Duration;
    let mut d = Daemon::start("");
    let tmp = d.take_dir().unwrap();
    let a = Api::new(&d);
    let body = json!({"bench": "virtual-1", "part_serial": "SN-K", "preset": "spider_4in",
        "moving_mass_kg": 0.05, "plan": {"added_mass": {"added_mass_kg": 0.02, "level_m": 0.004}}});
    let id = a.post("/api/v1/studies", &body).await.expect(202)["id"]
        .as_str()
        .unwrap()
        .to_string();
    let study = format!("/api/v1/studies/{id}");
    let waiting = a
        .poll(&study, Duration::from_secs(300), |s| {
            s["state"] == "awaiting_operator"
        })
        .await;
    assert_eq!(waiting["job_state"], "running", "{waiting}");
    d.kill9();
    drop(d);
    let d = Daemon::start_in(tmp.path(), "");
    let a = Api::new(&d);
    let j = a.get(&format!("/api/v1/jobs/{id}")).await;
    assert_eq!(j["state"], "interrupted", "{j}");
    let s = a.get(&study).await;
    assert_eq!(
        (&s["state"], &s["job_state"], &s["instruction"]),
        (&json!("failed"), &json!("interrupted"), &json!(null)),
        "{s}"
    );
    let p = a.post_empty(&format!("{study}/confirm")).await.problem(409);
    assert!(
        p["detail"]
            .as_str()
            .unwrap()
            .contains("not awaiting_operator"),
        "{p}"
    );
}

/// One run of the added-mass study on the virtual bench: `part` with
/// `added_kg` on its slide, the standard procedure at `level_m`, the fit
/// given the true mass.
fn added_mass_run(
    part: &PartSpec,
    added_kg: f64,
    level_m: f64,
    seed: u64,
) -> springbench::diagnose::studies::AttributionRun {
    use springbench::procedure::{run, Observer, ProcedureConfig};
    struct Quiet;
    impl Observer for Quiet {}
    let mut part = part.clone();
    part.moving_mass_kg += added_kg;
    let mut bench = VirtualBench::new(part.clone(), seed);
    let cfg = ProcedureConfig {
        moving_mass_kg: part.moving_mass_kg,
        levels_m: vec![level_m],
        ..Default::default()
    };
    let out = run(&mut bench, &cfg, &mut Quiet).unwrap();
    let set = springbench::recording::RecordingSet {
        meta: springbench::recording::Meta::standard(part.moving_mass_kg, 48000.0),
        pre: out.pre,
        main: out.narrow[0].signals.clone(),
    };
    let (report, data) =
        springbench::identify::analyze_with_force_balance(&set, &Default::default()).unwrap();
    springbench::diagnose::studies::AttributionRun {
        data,
        resonance_hz: report.large_signal.resonance_hz,
        xpeak_m: report.large_signal.xpeak_m,
    }
}

/// The added-mass study's attribution (issue 33 acceptance: "on a part
/// with creep and softening together, each is attributed to the right
/// cause"; decision 0122). spider_4in (50 g, 35 Hz) measured at 6 mm, then
/// with 20 g added (the resonance falls by a sixth); creep 400 N/m with
/// tau 5 ms (omega tau about 1.2 at the resonance: where its stiffness
/// changes most with frequency) and a reversible softening of 3e4 N/m^2
/// (K(0) 180 N/m lower after 6 mm) with tau 2 s. The truth of each share
/// is the part's law where the study measured: creep's stored stiffness
/// `k w^2 tau^2 / (1 + w^2 tau^2)` at the second resonance minus at the
/// first, the softening's `-depth Xpeak`. Tolerance 20 %: the for
/// a recovered effect parameter. Each share is also a parameter product
/// (k and tau, depth and Xpeak), so the parameters are checked at 20 % too.
/// A part with one of them gets a zero share for the other.
#[test]
fn added_mass_study_attributes_creep_and_softening_to_their_causes() {
    use springbench::diagnose::studies::attribute_memory;
    let creep = Creep {
        k_n_per_m: 400.0,
        tau_s: 0.005,
    };
    let soft = ReversibleSoftening {
        depth_n_per_m2: 3.0e4,
        tau_s: 2.0,
    };
    let storage = |f: f64| {
        let u = (2.0 * std::f64::consts::PI * f * creep.tau_s).powi(2);
        creep.k_n_per_m * u / (1.0 + u)
    };
    let cases = [
        ("creep and softening", Some(creep), Some(soft)),
        ("creep alone", Some(creep), None),
        ("softening alone", None, Some(soft)),
    ];
    let mut failures = Vec::new();
    for (name, c, s) in cases {
        let part = spider_with(Effects {
            creep: c,
            reversible_softening: s,
            ..Default::default()
        });
        let runs = [
            added_mass_run(&part, 0.0, 0.006, 7),
            added_mass_run(&part, 0.02, 0.006, 8),
        ];
        let a = attribute_memory(&runs, &Default::default()).unwrap();
        let [f1, f2] = a.resonances_hz;
        let want_f = if c.is_some() {
            storage(f2) - storage(f1)
        } else {
            0.0
        };
        let want_a = s.map_or(0.0, |s| -s.depth_n_per_m2 * a.xpeak_m);
        eprintln!(
            "{name}: frequency-dependent {:+.1} N/m (truth {want_f:+.1}, {f1:.2} -> {f2:.2} Hz), amplitude-dependent {:+.1} N/m (truth {want_a:+.1} at {:.2} mm); effects {}; model error {:.3} %",
            a.frequency_dependent_n_per_m,
            a.amplitude_dependent_n_per_m,
            a.xpeak_m * 1e3,
            serde_json::to_string(&a.effects).unwrap(),
            a.model_error_percent
        );
        let near = |got: f64, want: f64| {
            if want == 0.0 {
                got == 0.0
            } else {
                (got / want - 1.0).abs() <= 0.2
            }
        };
        let mut ok = near(a.frequency_dependent_n_per_m, want_f)
            && near(a.amplitude_dependent_n_per_m, want_a)
            && a.effects.creep.is_some() == c.is_some()
            && a.effects.reversible_softening.is_some() == s.is_some();
        if let (Some(t), Some(g)) = (c, a.effects.creep) {
            ok &= near(g.k_n_per_m, t.k_n_per_m) && near(g.tau_s, t.tau_s);
        }
        if let (Some(t), Some(g)) = (s, a.effects.reversible_softening) {
            ok &= near(g.depth_n_per_m2, t.depth_n_per_m2);
        }
        if !ok {
            failures.push(format!("{name}: {a:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The recovery study as a daemon job (issue 33 acceptance: "the time
/// constant and depth within 10 % on the virtual bench"). The bench's
/// configuration mounts the softening on every part
/// (`[benches.virtual.part_effects.reversible_softening]`, the smallest
/// typed way a daemon's virtual bench carries a material's memory): spider_4in
/// with 3e4 N/m^2 and tau 2 s, the plan of the core test (30 Hz at 50 V,
/// probes at 1.5 V, 0.5-30 s). A bad plan is a 422 naming the field; a
/// bad part effect in the configuration stops the daemon's start-up with
/// the field named (tested in `springbench-bench`'s settings).
#[tokio::test]
async fn recovery_study_job_gives_back_depth_and_time_constant() {
    use crate::common::{client, get, problem, terminal, wait_job, Daemon};
    use serde_json::{json, Value};
    let d = Daemon::start(
        "[[benches]]\nid = \"virtual-soft\"\npreset = \"spider_4in\"\nseed = 11\n\
         [benches.virtual.part_effects.reversible_softening]\ndepth_n_per_m2 = 30000.0\ntau_s = 2.0\n",
    );
    let c = client();
    let mut plan = serde_json::to_value(plan()).unwrap();
    let body = |plan: &Value| {
        json!({"bench": "virtual-soft", "part_serial": "SN-R", "moving_mass_kg": 0.05,
            "plan": {"recovery": plan}})
    };
    let mut bad = plan.clone();
    bad["delays_s"] = json!([0.5]);
    let r = c
        .post(d.url("/api/v1/studies"))
        .json(&body(&bad))
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "plan.recovery.delays_s", "{p}");
    plan["excitation_s"] = json!(2.0);
    let r = c
        .post(d.url("/api/v1/studies"))
        .json(&body(&plan))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["kind"], "recovery", "{v}");
    let id = v["id"].as_str().unwrap().to_string();
    let j = wait_job(&c, &d, &id, std::time::Duration::from_secs(300), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let s = get(&c, &d, &format!("/api/v1/studies/{id}")).await;
    assert_eq!(s["state"], "succeeded", "{s}");
    let r = &s["result"];
    assert_eq!(r["kind"], "recovery", "{s}");
    let depth = r["depth_n_per_m2"].as_f64().unwrap();
    let tau = r["tau_s"].as_f64().unwrap();
    eprintln!(
        "daemon recovery: depth {depth:.4e} N/m^2 (truth 3e4, {:+.1} %), tau {tau:.3} s (truth 2, {:+.1} %), probes {}",
        100.0 * (depth / 3e4 - 1.0),
        100.0 * (tau / 2.0 - 1.0),
        r["points"].as_array().map_or(0, |p| p.len())
    );
    assert_eq!(r["softening_found"], true, "{r}");
    assert!((depth / 3e4 - 1.0).abs() <= 0.10, "{depth}");
    assert!((tau / 2.0 - 1.0).abs() <= 0.10, "{tau}");
}

/// The added-mass study job on a part with creep and softening together
/// (decision 0122, the daemon's path: the derived mass, not the true one,
/// scales the two runs). The bench mounts spider_4in with creep 400 N/m,
/// 5 ms and a softening of 3e4 N/m^2, 2 s; 6 mm, 20 g added, weighed right.
/// Each share within 20 % of the part's law at the measured resonances and
/// excursion, as the core test.
#[tokio::test]
#[ignore = "13.8 s (daemon, two runs, up to 4 joint fits): figures in decision 0122; run by hand: cargo test --test it -- --ignored added_mass_study_job_attributes"]
async fn added_mass_study_job_attributes_creep_and_softening() {
    use crate::common::{Api, Daemon};
    use serde_json::json;
    use std::time::Duration;
    let d = Daemon::start(
        "[[benches]]\nid = \"virtual-mem\"\npreset = \"spider_4in\"\nseed = 21\n\
         [benches.virtual.part_effects.creep]\nk_n_per_m = 400.0\ntau_s = 0.005\n\
         [benches.virtual.part_effects.reversible_softening]\ndepth_n_per_m2 = 30000.0\ntau_s = 2.0\n",
    );
    let a = Api::new(&d);
    let body = json!({"bench": "virtual-mem", "part_serial": "SN-CS",
        "moving_mass_kg": 0.05, "plan": {"added_mass": {"added_mass_kg": 0.02, "level_m": 0.006}}});
    let id = a.post("/api/v1/studies", &body).await.expect(202)["id"]
        .as_str()
        .unwrap()
        .to_string();
    let study = format!("/api/v1/studies/{id}");
    a.poll(&study, Duration::from_secs(300), |s| {
        s["state"] == "awaiting_operator"
    })
    .await;
    a.post_empty(&format!("{study}/confirm")).await.expect(200);
    let s = a
        .poll(&study, Duration::from_secs(300), |s| {
            s["state"] == "succeeded" || s["state"] == "failed"
        })
        .await;
    assert_eq!(s["state"], "succeeded", "{s}");
    let r = &s["result"];
    let at = &r["attribution"];
    let f = |k: &str| at[k].as_f64().unwrap();
    let (f1, f2) = (
        at["resonances_hz"][0].as_f64().unwrap(),
        at["resonances_hz"][1].as_f64().unwrap(),
    );
    let storage = |f: f64| {
        let u = (2.0 * std::f64::consts::PI * f * 0.005f64).powi(2);
        400.0 * u / (1.0 + u)
    };
    let (want_f, want_a) = (storage(f2) - storage(f1), -3e4 * f("xpeak_m"));
    eprintln!(
        "daemon attribution: derived mass {:.5} kg, corrected {:.5} kg; frequency-dependent {:+.1} N/m (truth {want_f:+.1}), amplitude-dependent {:+.1} N/m (truth {want_a:+.1}); {}",
        r["moving_mass_derived_kg"].as_f64().unwrap(),
        f("moving_mass_kg"),
        f("frequency_dependent_n_per_m"),
        f("amplitude_dependent_n_per_m"),
        at["effects"]
    );
    // The mass the runs were fitted with, corrected for creep: the part's.
    assert!((f("moving_mass_kg") / 0.05 - 1.0).abs() <= 0.01, "{at}");
    assert!(
        (f("frequency_dependent_n_per_m") / want_f - 1.0).abs() <= 0.2,
        "{at}"
    );
    assert!(
        (f("amplitude_dependent_n_per_m") / want_a - 1.0).abs() <= 0.2,
        "{at}"
    );
}
