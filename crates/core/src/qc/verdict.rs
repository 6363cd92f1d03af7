//! Verdicts: one measurement judged against a recipe (`pass`, `fail`,
//! `invalid`, `no_limits`), the validity checks that come first, and a
//! job's verdict from its measurements'.

use super::recipe::{Quantity, Recipe, KX_MASK};
use crate::identify::Report;
use serde::{Deserialize, Serialize};

/// Overall verdict. `invalid` outranks everything: a measurement that cannot
/// be trusted is never judged.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum VerdictKind {
    Pass,
    /// Valid measurement, but the recipe has no limits yet (golden units).
    NoLimits,
    Fail,
    Invalid,
}

impl VerdictKind {
    pub fn as_str(self) -> &'static str {
        match self {
            VerdictKind::Pass => "pass",
            VerdictKind::NoLimits => "no_limits",
            VerdictKind::Fail => "fail",
            VerdictKind::Invalid => "invalid",
        }
    }
}

/// Result of one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ParamResult {
    Pass,
    Fail,
    /// Not judged: no limits set for it, or the measurement is `invalid`
    /// (its value is shown as measured, never as pass or fail; issue 35).
    NotJudged,
}

/// One parameter's value against its limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ParamOutcome {
    pub name: String,
    pub quantity: Option<Quantity>,
    pub unit: String,
    pub value: f64,
    pub lower: Option<f64>,
    pub upper: Option<f64>,
    pub result: ParamResult,
    /// The displacement judged (K(x) points, the mask's worst point), m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<f64>,
}

/// Why a measurement cannot be trusted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct InvalidReason {
    /// `analysis_failed`, `target_not_reached`, `small_signal_unreliable`,
    /// `model_error_high`, `noise_high`, `clipping`, `alignment`,
    /// `outside_measured_range`, `mask_coverage`, `job_failed`, `hardware_fault`,
    /// `interrupted`, `non_finite_value`, `value_not_determined` (a judged
    /// value whose state in the result is `not_determined`, issue 22).
    pub code: String,
    pub detail: String,
}

fn reason(code: &str, detail: String) -> InvalidReason {
    InvalidReason {
        code: code.into(),
        detail,
    }
}

/// The verdict of one measurement (or, combined, of a job).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Verdict {
    pub verdict: VerdictKind,
    /// The failing parameters (value and limits), when `fail`.
    pub failures: Vec<ParamOutcome>,
    /// Why the measurement cannot be trusted, when `invalid`.
    pub invalid_reasons: Vec<InvalidReason>,
    /// Every parameter's value, limits and result (empty when `invalid`
    /// before any value could be read).
    pub parameters: Vec<ParamOutcome>,
}

/// What the judge needs besides the result document: how the run went.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunFacts {
    /// The measurement's result; None when the analysis failed.
    pub report: Option<Report>,
    pub analysis_error: Option<String>,
    /// Target Xpeak of this narrow sweep (m).
    pub target_xpeak_m: Option<f64>,
    /// Level index in the series.
    pub level_index: usize,
    /// Drive of the narrow sweep and the drive limit (V).
    pub drive_v: Option<f64>,
    pub max_drive_v: Option<f64>,
    /// Drive of the pre-measurement (V): with `drive_v` the production
    /// procedure's reference (`qc::production`).
    pub pre_drive_v: Option<f64>,
    /// Quality of the pre-measurement's drive-to-displacement response |X/U|
    /// around the resonance (`procedure::Outcome::pre_q_drive_to_x`).
    pub pre_q_drive_to_x: Option<f64>,
}

/// K(x) from the result's polynomial (x in m, K in N/m).
pub fn k_of_x(report: &Report, x_m: f64) -> f64 {
    stiffness_coefficients(report)
        .iter()
        .rev()
        .fold(0.0, |acc, &c| acc * x_m + c)
}

/// The SI coefficients k_0..k_n of K(x) in a result (N/m^(i+1)).
pub fn stiffness_coefficients(report: &Report) -> &[f64] {
    &report.stiffness.coefficients_n_per_m_pow_i_plus_1
}

fn effect_value(report: &Report, effect: &str, parameter: &str) -> f64 {
    let v = serde_json::to_value(report.model.effects).unwrap_or_default();
    v.get(effect)
        .and_then(|e| e.get(parameter))
        .and_then(|p| p.as_f64())
        .unwrap_or(0.0)
}

fn judge_value(
    name: &str,
    q: Option<Quantity>,
    unit: String,
    value: f64,
    lo: Option<f64>,
    hi: Option<f64>,
    x_m: Option<f64>,
) -> ParamOutcome {
    let result = if lo.is_none() && hi.is_none() {
        ParamResult::NotJudged
    } else if lo.is_some_and(|l| value < l) || hi.is_some_and(|h| value > h) || !value.is_finite() {
        ParamResult::Fail
    } else {
        ParamResult::Pass
    };
    ParamOutcome {
        name: name.to_string(),
        quantity: q,
        unit,
        value,
        lower: lo,
        upper: hi,
        result,
        x_m,
    }
}

/// Validity checks of a measurement against the recipe's bounds.
pub fn validity_problems(recipe: &Recipe, facts: &RunFacts) -> Vec<InvalidReason> {
    let v = &recipe.validity;
    let mut out = Vec::new();
    let Some(r) = &facts.report else {
        out.push(reason(
            "analysis_failed",
            format!(
                "the analysis failed: {}",
                facts.analysis_error.as_deref().unwrap_or("no result")
            ),
        ));
        return out;
    };
    if let Some(t) = facts.target_xpeak_m {
        let x = r.large_signal.xpeak_m;
        if !(x.is_finite() && x >= v.min_xpeak_ratio * t) {
            let at_limit = match (facts.drive_v, facts.max_drive_v) {
                (Some(d), Some(m)) if d >= 0.999 * m => {
                    format!(" at the drive limit ({d:.3} V of {m:.3} V)")
                }
                (Some(d), _) => format!(" at {d:.3} V"),
                _ => String::new(),
            };
            out.push(reason(
                "target_not_reached",
                format!(
                    "Xpeak {:.3} mm is below {:.0} % of the target {:.3} mm{at_limit}",
                    x * 1e3,
                    100.0 * v.min_xpeak_ratio,
                    t * 1e3
                ),
            ));
        }
    }
    match &r.small_signal {
        None if v.require_small_signal_reliable => out.push(reason(
            "small_signal_unreliable",
            "no small-signal fit".into(),
        )),
        Some(s) if v.require_small_signal_reliable && !s.reliable => out.push(reason(
            "small_signal_unreliable",
            format!(
                "the small-signal fit is unreliable (misfit {:.2} %)",
                s.misfit_percent
            ),
        )),
        _ => {}
    }
    let m = &r.model;
    if !(m.model_error_percent.is_finite() && m.model_error_percent <= v.max_model_error_percent) {
        out.push(reason(
            "model_error_high",
            format!(
                "model error {:.2} % is above the recipe's bound {:.2} %",
                m.model_error_percent, v.max_model_error_percent
            ),
        ));
    }
    if !(m.noise_floor_percent.is_finite() && m.noise_floor_percent <= v.max_noise_floor_percent) {
        out.push(reason(
            "noise_high",
            format!(
                "noise floor {:.2} % is above the recipe's bound {:.2} %",
                m.noise_floor_percent, v.max_noise_floor_percent
            ),
        ));
    }
    for w in &r.warnings {
        let l = w.to_lowercase();
        if l.contains("clip") || l.contains("saturat") || l.contains("out of range") {
            out.push(reason("clipping", w.clone()));
        } else if l.contains("align") {
            out.push(reason("alignment", w.clone()));
        } else if l.contains("not reached")
            && facts.target_xpeak_m.is_some()
            && !out.iter().any(|o| o.code == "target_not_reached")
        {
            out.push(reason("target_not_reached", w.clone()));
        }
    }
    out
}

/// Keff at the recipe's target amplitude: the first-harmonic describing
/// function of the fitted K(x) over `c +- X_target` (c: the measured centre
/// of the excursion at resonance). The level control stops near, not at,
/// the target (it aims 8 % above it, with the excursion on both sides, so
/// that c +- X_target lies inside the measured range; issue 35), and the
/// Keff of a spider changes by about 10 % per 0.5 mm, so the Keff measured
/// at the reached Xpeak would judge the level control, not the part. Without a
/// target (or a fitted K(x)): the measured Keff.
pub fn keff_at_target(r: &crate::identify::Report, target_xpeak_m: Option<f64>) -> f64 {
    let ls = &r.large_signal;
    let k = &r.stiffness.coefficients_n_per_m_pow_i_plus_1;
    match target_xpeak_m {
        Some(xt) if xt > 0.0 && !k.is_empty() => {
            let c = 0.5 * (ls.x_min_at_resonance_m + ls.x_max_at_resonance_m);
            let c = if c.is_finite() { c } else { 0.0 };
            let v = crate::identify::large::describing_function_keff(k, c - xt, c + xt);
            if v.is_finite() {
                v
            } else {
                ls.keff_n_per_m
            }
        }
        _ => ls.keff_n_per_m,
    }
}

/// Puts the Keff QC judges beside the measured one: with a target level,
/// `large_signal.target_xpeak_m` and `large_signal.keff_at_target_n_per_m`
/// = [`keff_at_target`] (the same function, so an operator reads the
/// number QC judged). Nothing without a target or without a fitted K(x).
pub fn set_keff_at_target(r: &mut crate::identify::Report, target_xpeak_m: Option<f64>) {
    let Some(xt) = target_xpeak_m.filter(|x| x.is_finite() && *x > 0.0) else {
        return;
    };
    r.large_signal.target_xpeak_m = Some(xt);
    r.large_signal.keff_at_target_n_per_m =
        (!r.stiffness.coefficients_n_per_m_pow_i_plus_1.is_empty())
            .then(|| keff_at_target(r, Some(xt)))
            .filter(|v| v.is_finite());
    // Its state (extrapolated beyond the measured range, issue 22).
    crate::identify::validity::judge(r);
}

/// The state of the value QC judges for `q`, as the result document states
/// it: the small-signal values', K(x)'s, and for Keff that of Keff at the
/// target (with a target; [`set_keff_at_target`] states it the same way) or
/// of the measured Keff.
fn judged_validity(
    r: &crate::identify::Report,
    q: Quantity,
    target_xpeak_m: Option<f64>,
) -> Option<crate::identify::validity::HeadlineValidity> {
    let ss = r.small_signal.as_ref().map(|s| &s.validity);
    match q {
        Quantity::K0 => ss.map(|v| v.k0_n_per_m.clone()),
        Quantity::F0 => ss.map(|v| v.f0_hz.clone()),
        Quantity::Q => ss.map(|v| v.q.clone()),
        Quantity::R => ss.map(|v| v.r_ns_per_m.clone()),
        Quantity::Keff => match target_xpeak_m.filter(|x| x.is_finite() && *x > 0.0) {
            Some(xt) => {
                let mut c = r.clone();
                set_keff_at_target(&mut c, Some(xt));
                c.large_signal.validity.keff_at_target_n_per_m
            }
            None => Some(r.large_signal.validity.keff_n_per_m.clone()),
        },
        Quantity::KAtX | Quantity::KAsymmetry => Some(r.stiffness.validity.k_of_x.clone()),
        Quantity::ModelError | Quantity::EffectSize => None,
    }
}

/// The verdict of one measurement under a recipe.
pub fn judge(recipe: &Recipe, facts: &RunFacts) -> Verdict {
    finite_verdict(judge_values(recipe, facts))
}

/// A verdict is stored and sent to the MES as JSON, where a NaN or an
/// infinity would be written as `null` silently (issue 11): one with a
/// non-finite number (e.g. K(x) overflowing at a mask point) becomes an
/// `invalid` verdict (`non_finite_value`) that names the value, as
/// `store::finite` refuses a result document.
pub fn finite_verdict(v: Verdict) -> Verdict {
    match crate::finite::check(&v) {
        Ok(()) => never_judge_invalid(v),
        Err(e) => invalid_job(
            "non_finite_value",
            format!("the measurement cannot be judged: the verdict held a {e}"),
        ),
    }
}

/// An invalid measurement is never judged (ARCHITECTURE.md, issue 35): its
/// parameters keep their values and limits, as measured, but no result
/// (`not_judged`), and it lists no failures. Applied to every verdict the
/// judge, [`combine`] and [`finite_verdict`] return, and by the API to a
/// verdict stored before this rule (whose invalid parameters carried pass
/// or fail).
pub fn never_judge_invalid(mut v: Verdict) -> Verdict {
    if v.verdict == VerdictKind::Invalid {
        v.failures.clear();
        for p in &mut v.parameters {
            p.result = ParamResult::NotJudged;
        }
    }
    v
}

pub(super) fn judge_values(recipe: &Recipe, facts: &RunFacts) -> Verdict {
    let mut invalid = validity_problems(recipe, facts);
    let Some(r) = &facts.report else {
        return Verdict {
            verdict: VerdictKind::Invalid,
            failures: vec![],
            invalid_reasons: invalid,
            parameters: vec![],
        };
    };
    let (xlo, xhi) = (r.stiffness.valid_range_m[0], r.stiffness.valid_range_m[1]);
    let inside = |x: f64| x >= xlo - 1e-12 && x <= xhi + 1e-12;
    let mut params = Vec::new();
    for p in &recipe.parameters {
        if p.level_index.is_some_and(|li| li != facts.level_index) {
            continue;
        }
        let ss = r.small_signal.as_ref();
        // A value the result marks `not_determined` (unphysical, or Keff at
        // a target far outside the measured range) is no measurement: the
        // verdict is invalid with its reason, never pass or fail on the
        // fit's number (issue 22).
        if let Some(v) = judged_validity(r, p.quantity, facts.target_xpeak_m)
            .filter(|v| v.state == crate::identify::validity::State::NotDetermined)
        {
            invalid.push(reason(
                "value_not_determined",
                format!(
                    "{}: not determined: {}",
                    p.name,
                    v.reason.as_deref().unwrap_or("no reason given")
                ),
            ));
            continue;
        }
        let value = match p.quantity {
            Quantity::K0 => ss.and_then(|s| s.k0_n_per_m),
            Quantity::F0 => ss.and_then(|s| s.f0_hz),
            Quantity::Q => ss.and_then(|s| s.q),
            Quantity::R => ss.and_then(|s| s.r_ns_per_m),
            Quantity::Keff => Some(keff_at_target(r, facts.target_xpeak_m)),
            Quantity::KAtX | Quantity::KAsymmetry => {
                let x = p.x_m.unwrap_or(0.0);
                if !(inside(x) && inside(-x)) {
                    invalid.push(reason(
                        "outside_measured_range",
                        format!(
                            "{}: +-{:.3} mm is outside the measured range {:.3} .. {:.3} mm",
                            p.name,
                            x * 1e3,
                            xlo * 1e3,
                            xhi * 1e3
                        ),
                    ));
                }
                if p.quantity == Quantity::KAtX {
                    Some(k_of_x(r, x))
                } else {
                    Some(k_of_x(r, -x) / k_of_x(r, x))
                }
            }
            Quantity::ModelError => Some(r.model.model_error_percent),
            Quantity::EffectSize => Some(effect_value(
                r,
                p.effect.as_deref().unwrap_or(""),
                p.effect_parameter.as_deref().unwrap_or(""),
            )),
        };
        match value {
            Some(v) if v.is_finite() => params.push(judge_value(
                &p.name,
                Some(p.quantity),
                p.unit(),
                v,
                p.lower,
                p.upper,
                p.x_m,
            )),
            _ => invalid.push(reason(
                "analysis_failed",
                format!("{}: no finite value in the result", p.name),
            )),
        }
    }
    let kx = &r.stiffness.validity.k_of_x;
    if let Some(m) = &recipe.kx_mask {
        if kx.state == crate::identify::validity::State::NotDetermined
            && m.level_index.is_none_or(|li| li == facts.level_index)
        {
            invalid.push(reason(
                "value_not_determined",
                format!(
                    "{KX_MASK}: K(x) not determined: {}",
                    kx.reason.as_deref().unwrap_or("no reason given")
                ),
            ));
        } else if m.level_index.is_none_or(|li| li == facts.level_index) {
            let mut judged = 0usize;
            let mut worst: Option<(f64, ParamOutcome)> = None;
            for i in 0..m.x_m.len() {
                let x = m.x_m[i];
                if !inside(x) {
                    continue;
                }
                judged += 1;
                let (lo, hi) = (m.lower_n_per_m[i], m.upper_n_per_m[i]);
                let k = k_of_x(r, x);
                let half = (0.5 * (hi - lo)).max(1e-12);
                let excess = ((lo - k).max(k - hi)) / half; // <= 0 inside
                if worst.as_ref().is_none_or(|(e, _)| excess > *e) {
                    worst = Some((
                        excess,
                        judge_value(
                            KX_MASK,
                            Some(Quantity::KAtX),
                            "N/m".into(),
                            k,
                            Some(lo),
                            Some(hi),
                            Some(x),
                        ),
                    ));
                }
            }
            let coverage = judged as f64 / m.x_m.len().max(1) as f64;
            if coverage < recipe.validity.min_mask_coverage {
                invalid.push(reason(
                    "mask_coverage",
                    format!(
                        "only {judged} of {} K(x) mask points lie inside the measured range {:.3} .. {:.3} mm",
                        m.x_m.len(),
                        xlo * 1e3,
                        xhi * 1e3
                    ),
                ));
            }
            if let Some((_, o)) = worst {
                params.push(o);
            }
        }
    }
    let failures: Vec<ParamOutcome> = params
        .iter()
        .filter(|p| p.result == ParamResult::Fail)
        .cloned()
        .collect();
    let verdict = if !invalid.is_empty() {
        VerdictKind::Invalid
    } else if !failures.is_empty() {
        VerdictKind::Fail
    } else if params.iter().any(|p| p.result == ParamResult::Pass) {
        VerdictKind::Pass
    } else {
        VerdictKind::NoLimits
    };
    Verdict {
        verdict,
        failures: if verdict == VerdictKind::Fail {
            failures
        } else {
            vec![]
        },
        invalid_reasons: invalid,
        parameters: params,
    }
}

/// The verdict of a job from its measurements' verdicts: `invalid` if any is
/// invalid (or there are none), else `fail` if any fails, else `pass` (or
/// `no_limits`). Failures and reasons are collected, prefixed by the level.
pub fn combine(verdicts: &[Verdict]) -> Verdict {
    if verdicts.is_empty() {
        return invalid_job("job_failed", "the job produced no measurement".into());
    }
    let worst = verdicts
        .iter()
        .map(|v| v.verdict)
        .max()
        .unwrap_or(VerdictKind::Invalid);
    let mut out = Verdict {
        verdict: worst,
        failures: vec![],
        invalid_reasons: vec![],
        parameters: vec![],
    };
    for v in verdicts {
        if worst == VerdictKind::Fail {
            out.failures.extend(v.failures.iter().cloned());
        }
        out.invalid_reasons
            .extend(v.invalid_reasons.iter().cloned());
        out.parameters.extend(v.parameters.iter().cloned());
    }
    never_judge_invalid(out)
}

/// The verdict of a job that did not produce a trustworthy measurement
/// (bench fault, failed procedure).
pub fn invalid_job(code: &str, detail: String) -> Verdict {
    Verdict {
        verdict: VerdictKind::Invalid,
        failures: vec![],
        invalid_reasons: vec![reason(code, detail)],
        parameters: vec![],
    }
}
