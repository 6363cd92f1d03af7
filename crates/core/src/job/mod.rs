//! The job specification's bounds: what a job request, a recipe and the
//! runner all check against (one definition, below every user of it).

/// Largest number of levels of a level series, and of repeats.
pub const MAX_LEVELS: usize = 16;
pub const MAX_REPEATS: u32 = 10;
/// Lightest moving mass accepted (kg): 0.1 g. Lighter values are typos, and
/// the fit divides by the mass (1e-300 kg overflowed into stored infinities).
pub const MIN_MOVING_MASS_KG: f64 = 1e-4;
/// Highest K(x) order a job may ask for.
pub const MAX_ORDER: usize = 12;

/// A valid part serial: 1-64 characters of letters, digits, `-`, `_`, `.`,
/// starting with a letter or digit (it appears in URLs,
/// `/api/v1/parts/{serial}`, where `.` and `..` would be path segments).
pub fn valid_serial(s: &str) -> bool {
    s.len() <= 64
        && s.starts_with(|c: char| c.is_ascii_alphanumeric())
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

/// The rule of [`valid_serial`] in words (problem documents, CLI).
pub const SERIAL_RULE: &str =
    "1-64 characters: letters, digits, '-', '_', '.', starting with a letter or digit";

/// Smallest target peak displacement (m): 10 µm. The laser's noise is a few
/// µm at full bandwidth (docs/method-notes.md), so a smaller target measures
/// noise; 1e-300 m was accepted and fitted before.
pub const MIN_TARGET_XPEAK_M: f64 = 1e-5;

pub mod long_term;
mod measurement;
mod parse;
mod problem;
mod request;
mod spec;
mod stored;

pub use long_term::{
    Ambient, AmbientRequest, Failure, FailureLimits, Hold, LevelStep, LongTermRequest,
    LongTermSpec, PartState, Stimulus, StimulusKind,
};
pub use measurement::{
    HardwareRecord, MeasurementConfig, PreSweepSettings, ProcedureConfig, ProcedureRun,
    RepeatEnded, SweepSettings,
};
pub use parse::{bad_char, check_chars, parse_lenient, FieldError};
pub use problem::{JobProblem, ProblemKind};
pub use request::{JobLimits, JobRequest};
pub use spec::{
    production_part, Admission, BenchOffer, JobPart, JobProduction, JobSpec, Limits, ProcedureMode,
    Purpose, RecipeOrigin, RecipeRef, RecipeSource,
};
pub use stored::{SelfCheck, StoredRequest};
