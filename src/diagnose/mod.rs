//! Model diagnostics: compare model and measurement, rank candidate effects, model ladder, SVG plots. Pure.
//!
//! CONTRACT shared with the CLI and the daemon (owned by the diagnostics work):
//! `DiagnoseOptions`, `Diagnosis`, `diagnose`, `plot_names`, `plot`.

pub mod engine;
pub mod regress;
pub mod spectrum;
pub mod stats;
pub mod svg;
pub mod synth;

use crate::effects::EffectId;
use crate::identify::{AnalyzeOptions, ForceBalanceData, Report};
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

/// Runs the diagnostics on a recording set: the identification's report
/// with `model` refitted (base model plus the effects the ladder adds, or
/// the forced ones) and `diagnostics` filled.
pub fn diagnose(set: &RecordingSet, opts: &DiagnoseOptions) -> Result<Diagnosis, DiagnoseError> {
    let mut warnings = Vec::new();
    let mut report = crate::identify::analyze(set, &opts.analyze)?;
    let data = crate::identify::force_balance_data(set, &opts.analyze)?;
    let engine_opts = engine::EngineOptions {
        order: opts.analyze.order,
        forced: opts.effects.clone(),
        ..Default::default()
    };
    let result = diagnose_data(&data, &engine_opts).map_err(DiagnoseError::Invalid)?;
    report.model = result.report_model();
    report.diagnostics = Some(result.diagnostics_json(&data));
    for step in result.ladder.iter().skip(1) {
        if let Some(added) = &step.added {
            warnings.push(format!(
                "the base model misses {added}: the diagnostics added it (model error {:.3} % after it)",
                step.model_error_percent
            ));
        }
    }
    report.warnings.extend(warnings);
    Ok(Diagnosis { report })
}

/// The engine on force-balance data (no recording set needed).
pub fn diagnose_data(
    data: &ForceBalanceData,
    opts: &engine::EngineOptions,
) -> Result<engine::EngineResult, String> {
    engine::run(data, opts)
}

/// Names of the SVG plots (`{name}.svg`).
pub fn plot_names() -> &'static [&'static str] {
    svg::PLOT_NAMES
}

/// Renders one SVG plot of a diagnosis; None for an unknown name or a
/// diagnosis without diagnostics.
pub fn plot(_set: &RecordingSet, diagnosis: &Diagnosis, name: &str) -> Option<String> {
    svg::render(diagnosis.report.diagnostics.as_ref()?, name)
}
