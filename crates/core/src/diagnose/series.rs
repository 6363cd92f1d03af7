//! Level series (issue 12): K(x) and the effects fitted jointly over all
//! levels of a series (a job with several `levels_m`), so that effects that
//! change with amplitude separate from K(x): one K(x), one R, one set of
//! effects and one force scale for every level. Pure.
//!
//! The levels' force-balance data are put one after the other in time (the
//! order of the measurement) and run through the same engine as a single
//! level (candidates, ladder, block-robust errors); the per-level fits stay
//! beside for comparison.

use super::engine::{self, EngineOptions, EngineResult};
pub use crate::identify::documents::{JointFit, LevelFit, SeriesFit};
use crate::identify::ForceBalanceData;

/// The levels' data one after the other (same rate and mass required).
pub fn concat(levels: &[ForceBalanceData]) -> Result<ForceBalanceData, String> {
    let first = levels.first().ok_or("a series needs at least one level")?;
    let mut out = ForceBalanceData {
        x_m: Vec::new(),
        v_m_per_s: Vec::new(),
        a_m_per_s2: Vec::new(),
        mic_v: Vec::new(),
        ..first.clone()
    };
    let (mut lx, mut lm) = (0.0f64, 0.0f64);
    for (i, d) in levels.iter().enumerate() {
        if (d.sample_rate_hz - first.sample_rate_hz).abs() > 1e-9 * first.sample_rate_hz {
            return Err(format!(
                "level {} was prepared at {} Hz, level 1 at {} Hz: a series needs one rate",
                i + 1,
                d.sample_rate_hz,
                first.sample_rate_hz
            ));
        }
        if (d.mass_kg - first.mass_kg).abs() > 1e-12 {
            return Err(format!(
                "level {} has moving mass {} kg, level 1 {} kg: a series is one part",
                i + 1,
                d.mass_kg,
                first.mass_kg
            ));
        }
        out.x_m.extend_from_slice(&d.x_m);
        out.v_m_per_s.extend_from_slice(&d.v_m_per_s);
        out.a_m_per_s2.extend_from_slice(&d.a_m_per_s2);
        out.mic_v.extend_from_slice(&d.mic_v);
        lx = lx.max(d.laser_noise_m);
        lm = lm.max(d.mic_noise_v);
    }
    out.laser_noise_m = lx;
    out.mic_noise_v = lm;
    Ok(out)
}

fn range(d: &ForceBalanceData) -> [f64; 2] {
    d.x_m
        .iter()
        .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], &x| {
            [lo.min(x), hi.max(x)]
        })
}

fn level_fit(d: &ForceBalanceData, r: &EngineResult) -> LevelFit {
    let [lo, hi] = range(d);
    LevelFit {
        measurement_id: None,
        target_xpeak_m: None,
        x_abs_max_m: lo.abs().max(hi.abs()),
        range_m: [lo, hi],
        effects: r.model.effects,
        order: r.model.order,
        stiffness_coefficients_n_per_m_pow_i_plus_1: r
            .model
            .stiffness_coefficients_n_per_m_pow_i_plus_1
            .clone(),
        r_ns_per_m: r.model.r_ns_per_m,
        model_error_percent: r.model_error_percent,
    }
}

/// Fits every level alone and all levels jointly with the same options.
/// Takes the levels: they are dropped once joined, so that the joint fit
/// does not hold every sample twice.
pub fn fit_series(
    levels: Vec<ForceBalanceData>,
    opts: &EngineOptions,
) -> Result<SeriesFit, String> {
    let mut per = Vec::with_capacity(levels.len());
    for (i, d) in levels.iter().enumerate() {
        let r = engine::run(d, opts).map_err(|e| format!("level {}: {e}", i + 1))?;
        per.push(level_fit(d, &r));
    }
    let all = concat(&levels)?;
    drop(levels);
    let r = engine::run(&all, opts).map_err(|e| format!("joint fit: {e}"))?;
    let [lo, hi] = range(&all);
    let mut ambiguities = super::ambiguities(&all, &r, opts);
    let pairs = super::neighbours::check(&all, &r, opts);
    let mut candidates = r.candidates.clone();
    super::neighbours::apply(&pairs, &mut candidates, &mut ambiguities);
    Ok(SeriesFit {
        levels: per,
        joint: JointFit {
            effects: r.model.effects,
            order: r.model.order,
            stiffness_coefficients_n_per_m_pow_i_plus_1: r
                .model
                .stiffness_coefficients_n_per_m_pow_i_plus_1
                .clone(),
            stiffness_coefficients_se_n_per_m_pow_i_plus_1: r
                .model
                .stiffness_coefficients_se_n_per_m_pow_i_plus_1
                .clone(),
            reference_time_s: r.model.reference_time_s,
            r_ns_per_m: r.model.r_ns_per_m,
            r_se_ns_per_m: r.model.r_se_ns_per_m,
            valid_range_m: [lo, hi],
            model_error_percent: r.model_error_percent,
            noise_floor_percent: r.noise_floor_percent,
            ladder: r.ladder,
            candidates,
            ambiguities,
        },
    })
}

/// The series from recording sets (one per level, in the order measured).
pub fn fit_series_sets(
    sets: &[crate::recording::RecordingSet],
    opts: &EngineOptions,
) -> Result<SeriesFit, String> {
    let mut data = Vec::with_capacity(sets.len());
    for (i, s) in sets.iter().enumerate() {
        let (_, d) = crate::identify::analyze_with_force_balance(s, &Default::default())
            .map_err(|e| format!("level {}: {e}", i + 1))?;
        data.push(d);
    }
    fit_series(data, opts)
}
