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

pub mod cfx;
pub mod limits;
pub mod spc;

use crate::identify::{Method, Report};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Largest number of judged parameters of a recipe, and of K(x) mask points.
pub const MAX_PARAMETERS: usize = 64;
/// Longest `description` of a recipe (characters).
pub const MAX_DESCRIPTION_CHARS: usize = 4096;
/// Longest `part_kind` of a recipe (characters).
pub const MAX_PART_KIND_CHARS: usize = 64;
/// Largest magnitude of a limit or mask bound (SI units): anything beyond is
/// a typing error, and (U - L) / 6 sigma would overflow near 1.7e308.
pub const MAX_LIMIT: f64 = 1e12;
/// Smallest target level (m) and moving mass (kg) a recipe may name.
pub const MIN_LEVEL_M: f64 = 1e-5;
pub const MIN_MOVING_MASS_KG: f64 = 1e-4;
pub const MAX_MASK_POINTS: usize = 201;

/// Procedure settings of a recipe (what a job posted with `"recipe"` runs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProcedureSettings {
    /// Target peak displacement of each narrow sweep (m): one value, or a level series.
    pub levels_m: Vec<f64>,
    #[serde(default)]
    pub method: Method,
    /// K(x) order; chosen from the data when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
    #[serde(default = "one")]
    pub repeats: u32,
    /// Moving mass entered for the part type (kg); absent: the job's (on the
    /// virtual bench, the mounted part's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving_mass_kg: Option<f64>,
}

fn one() -> u32 {
    1
}

/// What a judged parameter measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    /// Small-signal stiffness k0 (N/m), from the pre-measurement.
    K0,
    /// Small-signal resonance f0 (Hz).
    F0,
    /// Small-signal Q (1).
    Q,
    /// Small-signal mechanical resistance R (N s/m).
    R,
    /// Effective stiffness Keff at the target level (N/m).
    Keff,
    /// K(x) at `x_m` (N/m).
    KAtX,
    /// K(-x)/K(x) at `x_m` (1).
    KAsymmetry,
    /// Model error of the force balance (%).
    ModelError,
    /// Size of an effect found significant by the diagnostics (`effect`,
    /// `effect_parameter`, e.g. coulomb_friction / force_n); 0 when the
    /// effect is not significant. Judging one runs the diagnostics.
    EffectSize,
}

impl Quantity {
    /// Where golden limits apply by default (sizes of faults get manual upper limits).
    pub fn golden_by_default(self) -> bool {
        !matches!(self, Quantity::ModelError | Quantity::EffectSize)
    }
}

/// One judged parameter. Limits are in the parameter's `unit` (SI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ParamSpec {
    /// Unique within the recipe, e.g. `k0`, `k_at_4mm`, `friction`.
    pub name: String,
    pub quantity: Quantity,
    /// Displacement of `k_at_x` and `k_asymmetry` (m, > 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<f64>,
    /// Effect id and parameter name of `effect_size` (see `crate::effects`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effect: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effect_parameter: Option<String>,
    /// Only judge the measurement of this level of the series (index into
    /// `levels_m`); absent: every level.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level_index: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lower: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub upper: Option<f64>,
    /// Whether golden-unit proposals set this parameter's limits (default:
    /// true except for model error and effect sizes, which take manual limits).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_golden: Option<bool>,
}

impl ParamSpec {
    /// Unit of the value and the limits.
    pub fn unit(&self) -> String {
        match self.quantity {
            Quantity::K0 | Quantity::Keff | Quantity::KAtX => "N/m".into(),
            Quantity::F0 => "Hz".into(),
            Quantity::Q | Quantity::KAsymmetry => "1".into(),
            Quantity::R => "N s/m".into(),
            Quantity::ModelError => "%".into(),
            Quantity::EffectSize => self
                .effect_parameter
                .as_deref()
                .map(unit_of_suffix)
                .unwrap_or_default(),
        }
    }

    pub fn from_golden(&self) -> bool {
        self.from_golden
            .unwrap_or_else(|| self.quantity.golden_by_default())
    }

    pub fn has_limits(&self) -> bool {
        self.lower.is_some() || self.upper.is_some()
    }
}

/// Unit from the name suffix of an effect parameter (`force_n` -> `N`).
fn unit_of_suffix(name: &str) -> String {
    const SUFFIXES: [(&str, &str); 8] = [
        ("_ns2_per_m2", "N s^2/m^2"),
        ("_ns_per_m3", "N s/m^3"),
        ("_ns_per_m2", "N s/m^2"),
        ("_n_per_m_s", "N/(m s)"),
        ("_n_per_m", "N/m"),
        ("_m_per_s", "m/s"),
        ("_n", "N"),
        ("_s", "s"),
    ];
    SUFFIXES
        .iter()
        .find(|(s, _)| name.ends_with(s))
        .map(|(_, u)| u.to_string())
        .unwrap_or_else(|| "1".into())
}

/// Bounds beyond which a measurement cannot be trusted (it is then `invalid`, never judged).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Validity {
    /// Measured Xpeak / target Xpeak below this: the target was not reached.
    pub min_xpeak_ratio: f64,
    /// Model error above this (%): the force balance does not explain the part.
    pub max_model_error_percent: f64,
    /// Noise floor of the force balance above this (%): too noisy to judge.
    pub max_noise_floor_percent: f64,
    /// An unreliable small-signal fit makes the measurement invalid.
    pub require_small_signal_reliable: bool,
    /// K(x) mask: fewer mask points inside the measured range than this fraction: invalid.
    pub min_mask_coverage: f64,
}

impl Default for Validity {
    fn default() -> Self {
        Validity {
            min_xpeak_ratio: 0.9,
            max_model_error_percent: 10.0,
            max_noise_floor_percent: 5.0,
            require_small_signal_reliable: true,
            min_mask_coverage: 0.5,
        }
    }
}

/// Band on K(x): at each `x_m`, K must lie within `[lower_n_per_m, upper_n_per_m]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct KxMask {
    pub x_m: Vec<f64>,
    pub lower_n_per_m: Vec<f64>,
    pub upper_n_per_m: Vec<f64>,
    /// Level of the series the mask applies to; absent: every level.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level_index: Option<usize>,
}

/// A recipe: what to run and what to judge for one part type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// 1-64 characters: letters, digits, `-`, `_`, `.`.
    pub name: String,
    /// At most 64 characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(max_length = 64)]
    pub part_kind: Option<String>,
    /// At most 4096 characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(max_length = 4096)]
    pub description: Option<String>,
    pub procedure: ProcedureSettings,
    pub parameters: Vec<ParamSpec>,
    #[serde(default)]
    pub validity: Validity,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kx_mask: Option<KxMask>,
}

/// One message per bad field (as the job validation does).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldError {
    pub field: String,
    pub message: String,
}

fn ferr(field: impl Into<String>, message: impl Into<String>) -> FieldError {
    FieldError {
        field: field.into(),
        message: message.into(),
    }
}

fn finite(v: f64) -> bool {
    v.is_finite()
}

impl Recipe {
    /// SHA-256 (hex) of the canonical JSON of the recipe (sorted keys): equal
    /// content, equal hash; any change of settings, parameters or limits changes it.
    pub fn sha256(&self) -> String {
        let v = serde_json::to_value(self).unwrap_or_default();
        let d = Sha256::digest(v.to_string().as_bytes());
        d.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// Whether anything can be judged (some limit or a mask).
    pub fn has_limits(&self) -> bool {
        self.kx_mask.is_some() || self.parameters.iter().any(|p| p.has_limits())
    }

    /// Checks what serde cannot: one message per bad field.
    pub fn validate(&self) -> Result<(), Vec<FieldError>> {
        let mut e = Vec::new();
        if !crate::job::valid_serial(&self.name) {
            e.push(ferr(
                "name",
                "1-64 characters: letters, digits, '-', '_', '.'",
            ));
        }
        let p = &self.procedure;
        if p.levels_m.is_empty() || p.levels_m.len() > crate::job::MAX_LEVELS {
            e.push(ferr(
                "procedure.levels_m",
                format!(
                    "give 1 to {} target peak displacements (m)",
                    crate::job::MAX_LEVELS
                ),
            ));
        }
        for (i, &l) in p.levels_m.iter().enumerate() {
            if !(finite(l) && (MIN_LEVEL_M..=0.1).contains(&l)) {
                e.push(ferr(
                    format!("procedure.levels_m[{i}]"),
                    format!("must be in [{MIN_LEVEL_M}, 0.1] m, got {l}"),
                ));
            } else if i > 0 && l <= p.levels_m[i - 1] {
                e.push(ferr(
                    format!("procedure.levels_m[{i}]"),
                    format!(
                        "must be above the level before it ({} m): levels rise, without repeats",
                        p.levels_m[i - 1]
                    ),
                ));
            }
        }
        for (field, text, max) in [
            ("description", &self.description, MAX_DESCRIPTION_CHARS),
            ("part_kind", &self.part_kind, MAX_PART_KIND_CHARS),
        ] {
            if text.as_ref().is_some_and(|t| t.chars().count() > max) {
                e.push(ferr(field, format!("at most {max} characters")));
            }
        }
        if let Some(o) = p.order {
            if !(1..=crate::job::MAX_ORDER).contains(&o) {
                e.push(ferr(
                    "procedure.order",
                    format!("must be 1 to {}", crate::job::MAX_ORDER),
                ));
            }
        }
        if !(1..=crate::job::MAX_REPEATS).contains(&p.repeats) {
            e.push(ferr(
                "procedure.repeats",
                format!("must be 1 to {}", crate::job::MAX_REPEATS),
            ));
        }
        if let Some(m) = p.moving_mass_kg {
            if !(finite(m) && (MIN_MOVING_MASS_KG..=10.0).contains(&m)) {
                e.push(ferr(
                    "procedure.moving_mass_kg",
                    format!("must be in [{MIN_MOVING_MASS_KG}, 10] kg, got {m}"),
                ));
            }
        }
        if self.parameters.len() > MAX_PARAMETERS {
            e.push(ferr(
                "parameters",
                format!("at most {MAX_PARAMETERS} parameters"),
            ));
        }
        let mut names = std::collections::HashSet::new();
        for (i, ps) in self.parameters.iter().enumerate() {
            let f = |s: &str| format!("parameters[{i}].{s}");
            if !crate::job::valid_serial(&ps.name) {
                e.push(ferr(
                    f("name"),
                    "1-64 characters: letters, digits, '-', '_', '.'",
                ));
            } else if !names.insert(ps.name.as_str()) || ps.name == KX_MASK {
                e.push(ferr(
                    f("name"),
                    format!("'{}' is used twice or reserved", ps.name),
                ));
            }
            let needs_x = matches!(ps.quantity, Quantity::KAtX | Quantity::KAsymmetry);
            match ps.x_m {
                Some(x) if needs_x && !(finite(x) && x > 0.0 && x <= 0.1) => {
                    e.push(ferr(f("x_m"), format!("must be in (0, 0.1] m, got {x}")))
                }
                None if needs_x => e.push(ferr(f("x_m"), "required for k_at_x and k_asymmetry")),
                Some(_) if !needs_x => e.push(ferr(f("x_m"), "only for k_at_x and k_asymmetry")),
                _ => {}
            }
            if ps.quantity == Quantity::EffectSize {
                match (&ps.effect, &ps.effect_parameter) {
                    (Some(eff), Some(par)) => match crate::effects::EffectId::parse(eff) {
                        Ok(id) if id.parameter_names().contains(&par.as_str()) => {}
                        Ok(id) => e.push(ferr(
                            f("effect_parameter"),
                            format!(
                                "'{par}' is not a parameter of {eff} ({})",
                                id.parameter_names().join(", ")
                            ),
                        )),
                        Err(m) => e.push(ferr(f("effect"), m)),
                    },
                    _ => e.push(ferr(
                        f("effect"),
                        "effect_size needs effect and effect_parameter",
                    )),
                }
            } else if ps.effect.is_some() || ps.effect_parameter.is_some() {
                e.push(ferr(f("effect"), "only for effect_size"));
            }
            if let Some(li) = ps.level_index {
                if li >= p.levels_m.len() {
                    e.push(ferr(f("level_index"), "beyond the level series"));
                }
            }
            for (n, v) in [("lower", ps.lower), ("upper", ps.upper)] {
                if let Some(v) = v {
                    if !(finite(v) && v.abs() <= MAX_LIMIT) {
                        e.push(ferr(
                            f(n),
                            format!("must be a finite number within +-{MAX_LIMIT:e}, got {v}"),
                        ));
                    }
                }
            }
            if let (Some(lo), Some(hi)) = (ps.lower, ps.upper) {
                if lo > hi {
                    e.push(ferr(f("lower"), format!("lower {lo} is above upper {hi}")));
                }
            }
        }
        let v = &self.validity;
        for (n, x, lo, hi) in [
            ("validity.min_xpeak_ratio", v.min_xpeak_ratio, 0.0, 1.0),
            (
                "validity.max_model_error_percent",
                v.max_model_error_percent,
                0.0,
                100.0,
            ),
            (
                "validity.max_noise_floor_percent",
                v.max_noise_floor_percent,
                0.0,
                100.0,
            ),
            ("validity.min_mask_coverage", v.min_mask_coverage, 0.0, 1.0),
        ] {
            if !(finite(x) && x >= lo && x <= hi) {
                e.push(ferr(n, format!("must be in [{lo}, {hi}], got {x}")));
            }
        }
        if let Some(m) = &self.kx_mask {
            let n = m.x_m.len();
            if n == 0 || n > MAX_MASK_POINTS {
                e.push(ferr(
                    "kx_mask.x_m",
                    format!("1 to {MAX_MASK_POINTS} points"),
                ));
            }
            if m.lower_n_per_m.len() != n || m.upper_n_per_m.len() != n {
                e.push(ferr(
                    "kx_mask",
                    "x_m, lower_n_per_m and upper_n_per_m must have the same length",
                ));
            }
            let all = m.x_m.iter().chain(&m.lower_n_per_m).chain(&m.upper_n_per_m);
            if all.clone().any(|v| !(finite(*v) && v.abs() <= MAX_LIMIT)) {
                e.push(ferr(
                    "kx_mask",
                    format!("every value must be a finite number within +-{MAX_LIMIT:e}"),
                ));
            }
            for (i, &x) in m.x_m.iter().enumerate() {
                if !(finite(x) && x.abs() <= 0.1) {
                    e.push(ferr(
                        format!("kx_mask.x_m[{i}]"),
                        format!("must be within +-0.1 m, got {x}"),
                    ));
                } else if i > 0 && x <= m.x_m[i - 1] {
                    e.push(ferr(
                        format!("kx_mask.x_m[{i}]"),
                        format!(
                            "must be above the point before it ({} m): x_m rises",
                            m.x_m[i - 1]
                        ),
                    ));
                }
            }
            if m.lower_n_per_m
                .iter()
                .zip(&m.upper_n_per_m)
                .any(|(a, b)| a > b)
            {
                e.push(ferr("kx_mask", "a lower bound is above its upper bound"));
            }
            if let Some(li) = m.level_index {
                if li >= p.levels_m.len() {
                    e.push(ferr("kx_mask.level_index", "beyond the level series"));
                }
            }
        }
        if e.is_empty() {
            Ok(())
        } else {
            Err(e)
        }
    }

    /// Whether judging needs the diagnostics (an effect size is judged).
    pub fn needs_diagnostics(&self) -> bool {
        self.parameters
            .iter()
            .any(|p| p.quantity == Quantity::EffectSize)
    }
}

/// Name of the K(x) mask in verdicts.
pub const KX_MASK: &str = "kx_mask";

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
    /// No limits set for it.
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
    /// `interrupted`, `non_finite_value`.
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
/// the target (a hardening spider jumps to about 7.5 mm for an 8 mm
/// target, and another part of the same lot to 7.9 mm), and the Keff of
/// such a part changes by about 10 % per 0.5 mm, so the Keff measured at the
/// reached Xpeak would judge the level control, not the part. Without a
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
        Ok(()) => v,
        Err(e) => invalid_job(
            "non_finite_value",
            format!("the measurement cannot be judged: the verdict held a {e}"),
        ),
    }
}

fn judge_values(recipe: &Recipe, facts: &RunFacts) -> Verdict {
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
    if let Some(m) = &recipe.kx_mask {
        if m.level_index.is_none_or(|li| li == facts.level_index) {
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
    out
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

#[cfg(test)]
mod tests;
