//! `springbench analyze DIR --diagnose`: model diagnostics on the command line
//! (owned by the diagnostics work; called from `cli::analyze` when `--diagnose` is given).
use super::analyze::AnalyzeArgs;
use crate::recording::RecordingSet;

/// Runs the diagnostics on `set` and prints them (table, or JSON with `--json`);
/// writes the SVG plots when `--plots DIR` is given.
pub fn run(_set: &RecordingSet, _args: &AnalyzeArgs) -> Result<(), String> {
    Err("diagnostics: not implemented yet".into())
}
