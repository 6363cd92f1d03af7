//! The offline path: the standard procedure on a [`VirtualBench`], giving the
//! recording set `analyze` reads, the procedure's outcome and the truth.

use crate::truth;
use crate::virtual_bench::VirtualBench;
use springbench_core::physics::{BenchParams, PartSpec};

/// Fast offline path: runs the standard procedure on a [`VirtualBench`] with
/// `part` and returns the recording set (pre + first narrow sweep) that
/// `analyze` reads. Used by `simulate`, the tests and the diagnostics suite.
pub fn simulate_recording_set(
    part: &PartSpec,
    seed: u64,
) -> Result<springbench_core::recording::RecordingSet, String> {
    simulate(part, seed, &SimulateOptions::default()).map(|s| s.set)
}

/// Options of [`simulate`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimulateOptions {
    pub bench: BenchParams,
    pub procedure: crate::procedure::ProcedureConfig,
    /// Limits of the virtual bench; None: its defaults.
    pub limits: Option<crate::Limits>,
}

/// Result of [`simulate`].
#[derive(Debug, Clone)]
pub struct Simulation {
    pub set: springbench_core::recording::RecordingSet,
    pub outcome: crate::procedure::Outcome,
    /// What the simulation used (the `truth.json` document).
    pub truth: serde_json::Value,
}

/// Runs the standard procedure on a virtual bench with `part` (the moving
/// mass of the procedure is the part's) and returns the recording set, the
/// procedure outcome and the truth.
pub fn simulate(part: &PartSpec, seed: u64, opts: &SimulateOptions) -> Result<Simulation, String> {
    part.validate()?;
    opts.bench.validate()?;
    let mut vb = VirtualBench::new(part.clone(), seed).with_bench(opts.bench);
    if let Some(l) = opts.limits {
        vb = vb.with_limits(l);
    }
    let mut cfg = opts.procedure.clone();
    cfg.moving_mass_kg = part.moving_mass_kg;
    struct Quiet;
    impl crate::procedure::Observer for Quiet {}
    let outcome = crate::procedure::run(&mut vb, &cfg, &mut Quiet).map_err(|e| e.to_string())?;
    let first = outcome
        .narrow
        .first()
        .ok_or("the procedure made no narrow sweep")?;
    let mut meta =
        springbench_core::recording::Meta::standard(part.moving_mass_kg, opts.bench.sample_rate_hz);
    meta.extra.insert(
        "source".into(),
        serde_json::json!(format!(
            "springbench simulate (part '{}', seed {seed})",
            part.name
        )),
    );
    let set = springbench_core::recording::RecordingSet {
        meta,
        pre: outcome.pre.clone(),
        main: first.signals.clone(),
    };
    let truth = truth::truth_json(part, &opts.bench, seed, &outcome);
    Ok(Simulation {
        set,
        outcome,
        truth,
    })
}
