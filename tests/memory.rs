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
        assert!((r.tau_s / tau - 1.0).abs() <= 0.10, "tau {} vs {tau}", r.tau_s);
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
