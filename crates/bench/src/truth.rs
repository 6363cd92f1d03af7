//! `truth.json`: what a simulation used, in the form of the reference
//! recordings' truth.json (same field names where they exist) plus the
//! complete bench and the procedure's decisions.

use crate::procedure::Outcome;
use serde_json::{json, Value};
use springbench_core::physics::model::BenchParams;
use springbench_core::physics::PartSpec;

/// The truth document of one simulation.
pub fn truth_json(part: &PartSpec, bench: &BenchParams, seed: u64, outcome: &Outcome) -> Value {
    let main = outcome.narrow.first();
    let (x_lo, x_hi) = main
        .map(|n| {
            n.signals
                .displacement_m
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                })
        })
        .unwrap_or((0.0, 0.0));
    json!({
        "part": part.name,
        "seed": seed,
        "moving_mass_kg": part.moving_mass_kg,
        "k_coeffs_si": part.k_coeffs_si,
        "k0": part.k_coeffs_si[0],
        "f0_hz": part.f0_hz(),
        "q": part.q(),
        "R_ns_per_m": part.r_ns_per_m,
        "ss_m2": part.ss_m2,
        "effects": part.effects,
        "second_mode": part.second_mode,
        "mic_gain": bench.microphone.gain_v_per_pa,
        "mic_delay_s": bench.microphone.delay_s
            + part.effects.channel_delay.map(|c| c.delay_s).unwrap_or(0.0),
        "adiabatic": bench.box_.adiabatic,
        "pre_sweep": outcome.pre_sweep.as_array(),
        "main_sweep": main.map(|n| n.sweep.as_array()),
        "narrow_sweeps": outcome.narrow.iter().map(|n| json!({
            "target_xpeak_m": n.target_xpeak_m,
            "sweep": n.sweep.as_array(),
            "resonance_hz": n.resonance_hz,
            "xpeak_m": n.xpeak_m,
        })).collect::<Vec<_>>(),
        "resonance_hz": main.map(|n| n.resonance_hz),
        "xpeak_m": main.map(|n| n.xpeak_m),
        "x_range_m": [x_lo, x_hi],
        "x_range_note": "from the recorded (noisy) laser signal",
        "bench_time_s": outcome.bench_time_s,
        "procedure_log": outcome.log,
        "bench": bench,
    })
}
