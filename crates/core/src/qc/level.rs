//! One level of a measurement, from its sweeps to what is stored and judged:
//! the analysis the job needs, the Keff at the level's target, the verdict,
//! and the finiteness check before the store. The runner calls it for every
//! level of every repeat; it was the runner's own code (issue 37: the science
//! lives in the core).

use super::{judge_calibrated, BenchCalibration, Recipe, RunFacts, Verdict};
use crate::diagnose::{diagnose, DiagnoseOptions};
use crate::identify::{self, AnalyzeOptions, ForceBalanceData, Report, Sweeps};
use crate::recording::{Meta, RecordingSet};

/// What the level is, beyond its sweeps.
pub struct Level<'a> {
    /// The level's sweeps; `meta` describes them (the diagnostics take a whole set).
    pub sweeps: Sweeps<'a>,
    pub meta: &'a Meta,
    pub opts: &'a AnalyzeOptions,
    /// Index of the level in the job's series, and its target Xpeak (m).
    pub level_index: usize,
    pub target_xpeak_m: f64,
    /// The bench's warning about these sweeps (added to the report).
    pub warning: Option<String>,
    /// Why the sweeps must not be fitted at all (a serial laser's samples
    /// not on the audio clock): the level is stored with this reason and
    /// judged without a result.
    pub not_fitted: Option<String>,
    /// The job measures several levels: keep each level's force-balance
    /// data for the joint fit of the series.
    pub keep_force_balance: bool,
    /// The recipe the level is judged by, and the bench's calibration under it.
    pub recipe: Option<&'a Recipe>,
    pub bench_cal: Option<&'a BenchCalibration>,
    /// Drive of the narrow sweep, its limit, and the pre-measurement's drive
    /// and drive-to-displacement Q (V, V, V, 1).
    pub drive_v: f64,
    pub max_drive_v: f64,
    pub pre_drive_v: f64,
    pub pre_q_drive_to_x: Option<f64>,
}

/// What became of the level.
#[derive(Debug)]
pub struct LevelOutcome {
    /// The result to store; None when the analysis failed, the sweeps were
    /// not fitted, or the result held a non-finite number.
    pub report: Option<Report>,
    /// Why there is no result.
    pub analysis_error: Option<String>,
    /// The level's force-balance data (kept only when asked and when there is a result).
    pub force_balance: Option<ForceBalanceData>,
    /// The verdict under the recipe (None without a recipe).
    pub verdict: Option<Verdict>,
    /// Lines for the job's log, untagged (the caller says which repeat).
    pub log: Vec<String>,
}

/// Analyses and judges one level (see the module's documentation).
///
/// A recipe that judges an effect's size gets the diagnostics' fitted
/// effects (the diagnosis' report, its `diagnostics` member dropped);
/// otherwise the plain analysis. The verdict judges the report as analysed,
/// before the finiteness check: a result refused for a NaN is still judged
/// by QC's own rules, and stored without a result, the reason kept.
pub fn measure_level(l: Level<'_>) -> LevelOutcome {
    let mut log = vec![];
    let level = format!("level {} ({} m)", l.level_index + 1, l.target_xpeak_m);
    let mut fb = None;
    let analysed = if let Some(why) = &l.not_fitted {
        // Never a fit of a displacement not on the audio clock.
        log.push(format!("{level} not fitted: {why}"));
        Err(why.clone())
    } else if l.recipe.is_some_and(|r| r.needs_diagnostics()) {
        let dopts = DiagnoseOptions {
            analyze: l.opts.clone(),
            effects: vec![],
            ..Default::default()
        };
        // (the diagnostics take a whole set: a copy of the pre-measurement
        // for this level's analysis only)
        let set = RecordingSet {
            meta: l.meta.clone(),
            pre: l.sweeps.pre.clone(),
            main: l.sweeps.main.clone(),
        };
        if l.keep_force_balance {
            fb = identify::force_balance_data(&set, l.opts).ok();
        }
        diagnose(&set, &dopts)
            .map(|d| Report {
                diagnostics: None,
                ..d.report
            })
            .map_err(|e| e.to_string())
    } else if l.keep_force_balance {
        identify::analyze_sweeps_with_force_balance(l.sweeps, l.opts)
            .map(|(rep, d)| {
                fb = Some(d);
                rep
            })
            .map_err(|e| e.to_string())
    } else {
        identify::analyze_sweeps(l.sweeps, l.opts).map_err(|e| e.to_string())
    }
    .map(|mut rep| {
        rep.warnings.extend(l.warning.iter().cloned());
        // The Keff QC judges, beside the one measured at the reached Xpeak.
        super::set_keff_at_target(&mut rep, Some(l.target_xpeak_m));
        rep
    });
    let verdict = l.recipe.map(|r| {
        let facts = RunFacts {
            report: analysed.as_ref().ok().cloned(),
            analysis_error: analysed.as_ref().err().cloned(),
            target_xpeak_m: Some(l.target_xpeak_m),
            level_index: l.level_index,
            drive_v: Some(l.drive_v),
            max_drive_v: Some(l.max_drive_v),
            pre_drive_v: Some(l.pre_drive_v),
            pre_q_drive_to_x: l.pre_q_drive_to_x,
        };
        judge_calibrated(r, &facts, l.bench_cal)
    });
    let (report, analysis_error) = match analysed {
        Ok(rep) => match storable(rep) {
            Ok(rep) => (Some(rep), None),
            Err(e) => {
                log.push(format!("analysis of {level}: {e}"));
                (None, Some(e))
            }
        },
        Err(e) if l.not_fitted.is_some() => (None, Some(e)),
        Err(e) => {
            log.push(format!("analysis of {level} failed: {e}"));
            (None, Some(e))
        }
    };
    LevelOutcome {
        force_balance: fb.filter(|_| report.is_some()),
        report,
        analysis_error,
        verdict,
        log,
    }
}

/// A result as it may be stored: never with a non-finite number written as
/// null (issue 11); such a result is refused, the reason kept
/// (`result refused: ...`). The runner's levels and the import use it.
pub fn storable(report: Report) -> Result<Report, String> {
    match crate::finite::check(&report) {
        Ok(()) => Ok(report),
        Err(e) => Err(format!("result refused: {e}")),
    }
}
