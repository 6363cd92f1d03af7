//! The diagnostics engine on force-balance data with known truth (a local
//! RK4 simulation, independent of the identification's signal processing).
use springbench::diagnose::engine::{run, EngineOptions};
use springbench::diagnose::synth::{force_balance, SynthSpec};
use springbench::effects::*;

fn show(r: &springbench::diagnose::engine::EngineResult) {
    eprintln!(
        "order {} res {:.3}% nf {:.3}% me {:.3}% (base me {:.3}%) {}",
        r.model.order,
        r.model.residual_percent,
        r.noise_floor_percent,
        r.model_error_percent,
        r.base_model_error_percent,
        r.order_note
    );
    for c in &r.candidates {
        eprintln!(
            "  {:24} red {:7.2}% sig {} p {:.2e} vif {:.1} {}",
            c.effect,
            c.error_reduction_percent,
            c.significant,
            c.p_value,
            c.variance_inflation,
            c.parameters
        );
    }
    for s in &r.ladder {
        eprintln!(
            "  ladder {:?} res {:.3} me {:.3}",
            s.effects, s.residual_percent, s.model_error_percent
        );
    }
}

#[test]
fn no_hidden_effect_nothing_significant() {
    let spec = SynthSpec::spider();
    let d = force_balance(&spec, 1);
    let r = run(&d, &EngineOptions::default()).unwrap();
    show(&r);
    assert!(r.candidates.iter().all(|c| !c.significant));
}

#[test]
fn coulomb_friction_found() {
    let mut spec = SynthSpec::spider();
    spec.effects.coulomb_friction = Some(CoulombFriction {
        force_n: 0.1,
        v_eps_m_per_s: 2e-3,
    });
    let d = force_balance(&spec, 2);
    let r = run(&d, &EngineOptions::default()).unwrap();
    show(&r);
    let c = &r.candidates[0];
    assert_eq!(c.effect, "coulomb_friction");
    assert!(c.significant && c.error_reduction_percent >= 50.0);
    let f = c.parameters["force_n"].as_f64().unwrap();
    assert!((f / 0.1 - 1.0).abs() < 0.2, "force {f}");
    assert_eq!(r.ladder[1].effects, vec!["coulomb_friction".to_string()]);
    assert!(r.model_error_percent <= 0.5 * r.base_model_error_percent);
}
