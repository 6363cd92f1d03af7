//! Model diagnostics: compare model and measurement, rank candidate effects, model ladder, SVG plots. Pure.
//!
//! CONTRACT shared with the CLI and the daemon (owned by the diagnostics work):
//! `DiagnoseOptions`, `Diagnosis`, `diagnose`, `plot_names`, `plot`.

pub mod engine;
pub mod regress;
pub mod spectrum;
pub mod stats;
pub mod synth;

use crate::effects::EffectId;
use crate::identify::{AnalyzeOptions, Report};
use crate::recording::RecordingSet;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnoseOptions {
    pub analyze: AnalyzeOptions,
    /// Effects forced into the model (`--effects a,b`, or the body of a fit request).
    #[serde(default)]
    pub effects: Vec<EffectId>,
}

/// The diagnosis: the analysis report with `model` refitted with the chosen
/// effects and `diagnostics` filled (candidates, ladder, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    pub report: Report,
}

#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Analyze(#[from] crate::identify::AnalyzeError),
}

/// Runs the diagnostics on a recording set.
pub fn diagnose(_set: &RecordingSet, _opts: &DiagnoseOptions) -> Result<Diagnosis, DiagnoseError> {
    Err(DiagnoseError::Invalid(
        "diagnostics not implemented yet".into(),
    ))
}

/// Names of the SVG plots (`{name}.svg`).
pub fn plot_names() -> &'static [&'static str] {
    &[]
}

/// Renders one SVG plot of a diagnosis; None for an unknown name.
pub fn plot(_set: &RecordingSet, _diagnosis: &Diagnosis, _name: &str) -> Option<String> {
    None
}
