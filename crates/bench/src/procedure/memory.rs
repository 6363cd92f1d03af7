//! The recovery measurement on any bench (issue 33, decision 0117): one
//! continuous drive (a large excitation, then small two-tone probes at the
//! plan's delays), so that the part's memory carries from the excitation to
//! the probes; the analysis is `springbench_core::diagnose::memory`.

use super::ProcedureError;
use crate::{Bench, Block, Control};
use springbench_core::diagnose::memory::{analyze_recovery, RecoveryPlan, RecoveryResult};
use springbench_core::recording::Signals;

/// Runs the plan on `bench` (within its drive limit) and analyses it.
pub fn run_recovery(
    bench: &mut dyn Bench,
    plan: &RecoveryPlan,
    mass_kg: f64,
    observer: &mut dyn FnMut(Block<'_>) -> Control,
) -> Result<(Signals, RecoveryResult), ProcedureError> {
    plan.validate().map_err(ProcedureError::Invalid)?;
    let limit = bench.limits().max_drive_v;
    let peak = plan.excitation_v.max(2.0 * plan.probe_v);
    if peak > limit {
        return Err(ProcedureError::Invalid(format!(
            "recovery drive {peak:.2} V peak exceeds the bench's limit of {limit:.2} V"
        )));
    }
    let (drive, _) = plan.drive(bench.sample_rate_hz());
    let signals = bench.run(&drive, observer)?;
    let result = analyze_recovery(plan, &signals, mass_kg).map_err(ProcedureError::Failed)?;
    Ok((signals, result))
}
