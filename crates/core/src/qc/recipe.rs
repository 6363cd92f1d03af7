//! Recipes: the procedure settings of a part type and the parameters judged,
//! each with a unit and limits; their validation and content hash.

use super::production::{GoldenReference, ProcedureMode};
use crate::identify::Method;
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
    /// `full` (default) or `production`: the short procedure that uses
    /// `golden` (a job request's `procedure` overrides it per job).
    #[serde(default, skip_serializing_if = "ProcedureMode::is_full")]
    pub mode: ProcedureMode,
    /// What the golden units established (resonances, Q, drive levels),
    /// filled in by a limit proposal; the production procedure's reference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub golden: Option<GoldenReference>,
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

/// One message per bad field (the job request's type).
pub use crate::job::FieldError;

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
            e.push(FieldError::new(
                "name",
                "1-64 characters: letters, digits, '-', '_', '.'",
            ));
        }
        let p = &self.procedure;
        if p.levels_m.is_empty() || p.levels_m.len() > crate::job::MAX_LEVELS {
            e.push(FieldError::new(
                "procedure.levels_m",
                format!(
                    "give 1 to {} target peak displacements (m)",
                    crate::job::MAX_LEVELS
                ),
            ));
        }
        for (i, &l) in p.levels_m.iter().enumerate() {
            if !(finite(l) && (MIN_LEVEL_M..=0.1).contains(&l)) {
                e.push(FieldError::new(
                    format!("procedure.levels_m[{i}]"),
                    format!("must be in [{MIN_LEVEL_M}, 0.1] m, got {l}"),
                ));
            } else if i > 0 && l <= p.levels_m[i - 1] {
                e.push(FieldError::new(
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
            crate::job::check_chars(text.as_deref(), field, max, &mut e);
        }
        if let Some(o) = p.order {
            if !(1..=crate::job::MAX_ORDER).contains(&o) {
                e.push(FieldError::new(
                    "procedure.order",
                    format!("must be 1 to {}", crate::job::MAX_ORDER),
                ));
            }
        }
        if !(1..=crate::job::MAX_REPEATS).contains(&p.repeats) {
            e.push(FieldError::new(
                "procedure.repeats",
                format!("must be 1 to {}", crate::job::MAX_REPEATS),
            ));
        }
        if let Some(m) = p.moving_mass_kg {
            if !(finite(m) && (MIN_MOVING_MASS_KG..=10.0).contains(&m)) {
                e.push(FieldError::new(
                    "procedure.moving_mass_kg",
                    format!("must be in [{MIN_MOVING_MASS_KG}, 10] kg, got {m}"),
                ));
            }
        }
        if let Some(g) = &p.golden {
            if let Err(ge) = g.validate(p.levels_m.len()) {
                for (f, m) in ge {
                    e.push(FieldError::new(format!("procedure.golden.{f}"), m));
                }
            }
        }
        if self.parameters.len() > MAX_PARAMETERS {
            e.push(FieldError::new(
                "parameters",
                format!("at most {MAX_PARAMETERS} parameters"),
            ));
        }
        let mut names = std::collections::HashSet::new();
        for (i, ps) in self.parameters.iter().enumerate() {
            let f = |s: &str| format!("parameters[{i}].{s}");
            if !crate::job::valid_serial(&ps.name) {
                e.push(FieldError::new(
                    f("name"),
                    "1-64 characters: letters, digits, '-', '_', '.'",
                ));
            } else if !names.insert(ps.name.as_str()) || ps.name == KX_MASK {
                e.push(FieldError::new(
                    f("name"),
                    format!("'{}' is used twice or reserved", ps.name),
                ));
            }
            let needs_x = matches!(ps.quantity, Quantity::KAtX | Quantity::KAsymmetry);
            match ps.x_m {
                Some(x) if needs_x && !(finite(x) && x > 0.0 && x <= 0.1) => e.push(
                    FieldError::new(f("x_m"), format!("must be in (0, 0.1] m, got {x}")),
                ),
                None if needs_x => e.push(FieldError::new(
                    f("x_m"),
                    "required for k_at_x and k_asymmetry",
                )),
                Some(_) if !needs_x => {
                    e.push(FieldError::new(f("x_m"), "only for k_at_x and k_asymmetry"))
                }
                _ => {}
            }
            if ps.quantity == Quantity::EffectSize {
                match (&ps.effect, &ps.effect_parameter) {
                    (Some(eff), Some(par)) => match crate::effects::EffectId::parse(eff) {
                        Ok(id) if id.parameter_names().contains(&par.as_str()) => {}
                        Ok(id) => e.push(FieldError::new(
                            f("effect_parameter"),
                            format!(
                                "'{par}' is not a parameter of {eff} ({})",
                                id.parameter_names().join(", ")
                            ),
                        )),
                        Err(m) => e.push(FieldError::new(f("effect"), m)),
                    },
                    _ => e.push(FieldError::new(
                        f("effect"),
                        "effect_size needs effect and effect_parameter",
                    )),
                }
            } else if ps.effect.is_some() || ps.effect_parameter.is_some() {
                e.push(FieldError::new(f("effect"), "only for effect_size"));
            }
            if let Some(li) = ps.level_index {
                if li >= p.levels_m.len() {
                    e.push(FieldError::new(f("level_index"), "beyond the level series"));
                }
            }
            for (n, v) in [("lower", ps.lower), ("upper", ps.upper)] {
                if let Some(v) = v {
                    if !(finite(v) && v.abs() <= MAX_LIMIT) {
                        e.push(FieldError::new(
                            f(n),
                            format!("must be a finite number within +-{MAX_LIMIT:e}, got {v}"),
                        ));
                    }
                }
            }
            if let (Some(lo), Some(hi)) = (ps.lower, ps.upper) {
                if lo > hi {
                    e.push(FieldError::new(
                        f("lower"),
                        format!("lower {lo} is above upper {hi}"),
                    ));
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
                e.push(FieldError::new(
                    n,
                    format!("must be in [{lo}, {hi}], got {x}"),
                ));
            }
        }
        if let Some(m) = &self.kx_mask {
            let n = m.x_m.len();
            if n == 0 || n > MAX_MASK_POINTS {
                e.push(FieldError::new(
                    "kx_mask.x_m",
                    format!("1 to {MAX_MASK_POINTS} points"),
                ));
            }
            if m.lower_n_per_m.len() != n || m.upper_n_per_m.len() != n {
                e.push(FieldError::new(
                    "kx_mask",
                    "x_m, lower_n_per_m and upper_n_per_m must have the same length",
                ));
            }
            let all = m.x_m.iter().chain(&m.lower_n_per_m).chain(&m.upper_n_per_m);
            if all.clone().any(|v| !(finite(*v) && v.abs() <= MAX_LIMIT)) {
                e.push(FieldError::new(
                    "kx_mask",
                    format!("every value must be a finite number within +-{MAX_LIMIT:e}"),
                ));
            }
            for (i, &x) in m.x_m.iter().enumerate() {
                if !(finite(x) && x.abs() <= 0.1) {
                    e.push(FieldError::new(
                        format!("kx_mask.x_m[{i}]"),
                        format!("must be within +-0.1 m, got {x}"),
                    ));
                } else if i > 0 && x <= m.x_m[i - 1] {
                    e.push(FieldError::new(
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
                e.push(FieldError::new(
                    "kx_mask",
                    "a lower bound is above its upper bound",
                ));
            }
            if let Some(li) = m.level_index {
                if li >= p.levels_m.len() {
                    e.push(FieldError::new(
                        "kx_mask.level_index",
                        "beyond the level series",
                    ));
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
