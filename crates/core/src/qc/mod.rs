//! Production QC: recipes, limits from golden units, verdicts, SPC. Pure and
//! synchronous: plain data in, plain data out (no I/O, no clock, no logging).
//!
//! - [`Recipe`]: the procedure settings of a part type and the parameters
//!   judged, each with a unit and lower/upper limits; [`Recipe::sha256`] is the
//!   content hash that a verdict names.
//! - [`judge`]: the verdict of one measurement (`pass`, `fail` with every
//!   failing parameter, `invalid` when the measurement cannot be trusted,
//!   `no_limits` when the recipe has nothing to judge yet). An invalid
//!   measurement is never judged: its verdict is never `pass`.
//! - [`limits`]: limits proposed from golden units (mean +- k sigma or +- a
//!   tolerance, and a K(x) mask over the measured range).
//! - [`spc`]: n, mean, sigma, Cp, Cpk, Pp, Ppk, yield and control-chart data.

mod apply;
pub mod bench_cal;
pub mod cfx;
pub mod grr;
pub mod level;
pub mod limits;
pub mod lot;
pub mod production;
mod recipe;
pub mod spc;
pub mod trace;
mod verdict;

pub use bench_cal::{judge_calibrated, BenchCalibration, CalState};
pub use production::{GoldenLevel, GoldenReference, ProcedureMode};
pub use recipe::{
    FieldError, KxMask, ParamSpec, ProcedureSettings, Quantity, Recipe, Validity, KX_MASK,
    MAX_DESCRIPTION_CHARS, MAX_LIMIT, MAX_MASK_POINTS, MAX_PARAMETERS, MAX_PART_KIND_CHARS,
    MIN_LEVEL_M, MIN_MOVING_MASS_KG,
};
pub use trace::{AppliedCalibration, BenchCalibrationTrace, FleetTrace, VerdictTrace};
pub use verdict::{
    combine, finite_verdict, invalid_job, judge, k_of_x, keff_at_target, never_judge_invalid,
    set_keff_at_target, stiffness_coefficients, validity_problems, InvalidReason, ParamOutcome,
    ParamResult, RunFacts, Verdict, VerdictKind,
};

#[cfg(test)]
mod tests;
