//! The level series of a job's repeat (issue 12): after the levels are
//! measured and fitted one by one, K(x), R and the effects are fitted jointly
//! over all of them (`diagnose::series`), and the joint fit goes into the
//! result document of every level of that repeat (`series`). Runs on the
//! job's blocking thread.

use crate::diagnose::engine::EngineOptions;
use crate::diagnose::series::fit_series;
use crate::identify::{ForceBalanceData, Report};

/// One analysed level of a repeat.
pub struct Level {
    /// Index of its measurement in the job's list.
    pub measurement: usize,
    pub measurement_id: String,
    pub target_xpeak_m: f64,
    pub data: ForceBalanceData,
}

/// Fits the series of `levels` (the analysed levels of one repeat, in the
/// order measured) and puts it into the result documents `reports` (that
/// repeat's; `offset` is the job index of the first). Returns log lines; a
/// series that cannot be fitted leaves the results as they are.
pub fn attach(
    reports: &mut [Option<Report>],
    offset: usize,
    levels: Vec<Level>,
    order: Option<usize>,
) -> Vec<String> {
    if levels.len() < 2 {
        return vec![format!(
            "level series: {} of {} levels analysed, no joint fit (it needs two)",
            levels.len(),
            reports.len()
        )];
    }
    // moved, not copied: 16 levels' force-balance data are the series' largest part
    let (levels, data): (Vec<(usize, String, f64)>, Vec<ForceBalanceData>) = levels
        .into_iter()
        .map(|l| ((l.measurement, l.measurement_id, l.target_xpeak_m), l.data))
        .unzip();
    let opts = EngineOptions {
        order,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    // taken by the fit: the levels are dropped once joined into one record
    let mut fit = match fit_series(data, &opts) {
        Ok(f) => f,
        Err(e) => return vec![format!("level series: the joint fit failed: {e}")],
    };
    for (lf, l) in fit.levels.iter_mut().zip(&levels) {
        lf.measurement_id = Some(l.1.clone());
        lf.target_xpeak_m = Some(l.2);
    }
    if let Err(e) = crate::finite::check(&fit) {
        return vec![format!("level series: joint fit refused: {e}")];
    }
    for l in &levels {
        if let Some(Some(r)) = reports.get_mut(l.0 - offset) {
            r.series = Some(fit.clone());
        }
    }
    let j = &fit.joint;
    vec![format!(
        "level series: joint fit over {} levels ({:.2}..{:.2} mm): effects [{}], K(x) order {}, R {:.4} N s/m, model error {:.3} % ({:.2} s)",
        levels.len(),
        j.valid_range_m[0] * 1e3,
        j.valid_range_m[1] * 1e3,
        j.effects
            .ids()
            .iter()
            .map(|e| e.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        j.order,
        j.r_ns_per_m,
        j.model_error_percent,
        t.elapsed().as_secs_f64()
    )]
}
