//! The `diagnostics` document of the result (`Report::diagnostics`), typed:
//! what the engine tested and chose on the main sweep and on the
//! pre-measurement, what stays unexplained, the effect pairs the data cannot
//! separate, a level series' joint fit, and the comparison data the plots
//! draw. Built once by `diagnose`, amended through its fields, never patched
//! as JSON.
//!
//! On the wire the document keeps the key order it always had: members
//! sorted by name (it was a `serde_json::Value`, whose maps are sorted), so
//! stored and printed documents stay byte-identical. [`Report`] serializes
//! it through [`sorted`].
//!
//! [`Report`]: super::Report

pub use super::documents::Ambiguity;
use super::documents::{CandidateResult, LadderStep, SeriesFit, WideBandResonance};
use crate::effects::{EffectId, Effects};
use serde::{Deserialize, Serialize, Serializer};

/// The whole `diagnostics` document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnostics {
    /// Candidates ranked against the base model of the main sweep.
    pub candidates: Vec<CandidateResult>,
    pub ladder: Vec<LadderStep>,
    pub base_model: ModelSummary,
    pub final_model: ModelSummary,
    pub noise_floor_percent: f64,
    /// Order chosen for the base model and how.
    pub order_note: String,
    pub method: MethodNotes,
    pub comparison: Comparison,
    /// Effect pairs this data cannot separate.
    pub ambiguities: Vec<Ambiguity>,
    /// The same engine on the pre-measurement, when it was fitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub small_signal_model: Option<SmallSignalModel>,
    pub unexplained: Unexplained,
    /// A level series' joint fit (`analyze --series`, series jobs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub series: Option<SeriesFit>,
}

/// A fitted model as the document shows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelSummary {
    pub effects: Vec<EffectId>,
    pub parameters: Effects,
    pub parameters_se: serde_json::Value,
    pub order: usize,
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    pub r_ns_per_m: f64,
    pub force_per_mic_n_per_v: f64,
    pub residual_percent: f64,
    pub cv_residual_percent: f64,
    pub model_error_percent: f64,
}

impl ModelSummary {
    pub fn new(m: &FittedModel, model_error_percent: f64) -> Self {
        ModelSummary {
            effects: m.effect_ids.clone(),
            parameters: m.effects,
            parameters_se: m.effects_se.clone(),
            order: m.order,
            stiffness_coefficients_n_per_m_pow_i_plus_1: m
                .stiffness_coefficients_n_per_m_pow_i_plus_1
                .clone(),
            r_ns_per_m: m.r_ns_per_m,
            force_per_mic_n_per_v: m.force_per_mic_n_per_v,
            residual_percent: m.residual_percent,
            cv_residual_percent: m.cv_residual_percent,
            model_error_percent,
        }
    }
}

/// How the candidates were tested (fixed text).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodNotes {
    pub cross_validation: String,
    pub test: String,
    pub identifiability: String,
    pub relevance: String,
    pub model_error: String,
}

impl Default for MethodNotes {
    fn default() -> Self {
        MethodNotes {
            cross_validation: "blocked, 5 contiguous folds of 8 time blocks each".into(),
            test: "Wald test with batch-means (40 contiguous blocks) covariance, Bonferroni over candidates; hyper-parameter searches count 5 times".into(),
            identifiability: "variance inflation of the candidate's regressors against the model's; above 200 and not significant: cannot tell from this data".into(),
            relevance: "a significant candidate removes at least 5 % of the held-out model error (noise floor of the step's residual)".into(),
            model_error: "sqrt(residual^2 - noise_floor^2), residual on held-out blocks for candidates and ladder".into(),
        }
    }
}

/// The small-signal model: the engine on the pre-measurement (no plot data).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SmallSignalModel {
    pub candidates: Vec<CandidateResult>,
    pub ladder: Vec<LadderStep>,
    pub base_model: FittedModel,
    pub final_model: FittedModel,
    pub noise_floor_percent: f64,
    pub model_error_percent: f64,
    pub base_model_error_percent: f64,
    /// What the small-signal model leaves, when it misses structure.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unexplained: Option<Unexplained>,
}

/// Fitted model: what is in it and how well it explains the data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedModel {
    pub order: usize,
    /// Effects in the model in the order they were added (forced first).
    pub effect_ids: Vec<EffectId>,
    pub effects: Effects,
    /// Standard errors of the effect parameters (same names), block-robust.
    pub effects_se: serde_json::Value,
    /// K(x) = sum k_i x^i (N/m, x in m) of this model; with stiffness
    /// drift in the model, K(x) at the start of the recording (`reference_time_s`).
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Block-robust standard errors of the coefficients (same units).
    #[serde(default)]
    pub stiffness_coefficients_se_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Time (s from the start of the recording) K(x) refers to; None when
    /// nothing in the model changes K over time.
    #[serde(default)]
    pub reference_time_s: Option<f64>,
    pub r_ns_per_m: f64,
    #[serde(default)]
    pub r_se_ns_per_m: f64,
    pub force_per_mic_n_per_v: f64,
    pub residual_percent: f64,
    /// Residual of blocked cross-validation (held-out data).
    pub cv_residual_percent: f64,
    /// Block-robust covariance of the K(x) coefficients (row-major, same
    /// units as the coefficients): for derived figures such as Keff.
    #[serde(skip)]
    pub stiffness_covariance: Vec<Vec<f64>>,
    /// K(0) changes by this much per second (N/m/s) when stiffness drift is
    /// in the model (K(x) above holds at `reference_time_s`).
    #[serde(skip)]
    pub dk0_dt_n_per_m_s: f64,
}

/// One description of the remaining structure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Probe {
    /// `harmonic_1`..`harmonic_6`, `function_of_x`, `function_of_v`,
    /// `x_with_direction`, `acceleration`, `x_along_the_sweep`, `v_along_the_sweep`.
    pub name: String,
    /// Share of the structured residual variance this probe explains (%).
    pub share_percent: f64,
    pub p_value: f64,
    pub significant: bool,
}

/// What the model leaves unexplained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unexplained {
    /// True when the model error stays above `diagnose::unexplained::NOISE_RATIO`
    /// x the noise floor: the model misses structure (the probes describe it
    /// when they can).
    pub present: bool,
    pub model_error_percent: f64,
    pub noise_floor_percent: f64,
    /// Harmonic orders of the fundamental that carry the structure.
    pub harmonic_orders: Vec<usize>,
    /// "even", "odd", "both" or "none".
    pub parity: String,
    pub probes: Vec<Probe>,
    /// One sentence: what the structure looks like.
    pub signature: String,
    /// Experiments that would tell more.
    pub experiments: Vec<String>,
    /// Effects in the chosen models (main and small-signal) whose
    /// parameters may stand in for the unexplained structure: reported, not
    /// claimed as measured. Empty when nothing is unexplained.
    #[serde(default)]
    pub parameters_not_claimed: Vec<String>,
    /// A resonance at a fixed frequency of its own in the pre-measurement's
    /// wide-band transfer function (a second mechanical mode), when found.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resonance: Option<WideBandResonance>,
    /// A few words for the states' reasons ("model error 1.2 % over a
    /// noise floor of 1.5 %", "a resonance at 74 Hz").
    #[serde(skip)]
    pub short: String,
}

/// The data the diagnostics plots draw: measured against modelled force.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    /// 0.12 s around the largest displacement.
    pub detail: Detail,
    /// RMS per bucket over the whole record.
    pub envelope: Envelope,
    /// RMS of the noise in the force balance (N).
    pub noise_rms_n: f64,
    pub residual_vs_x: ResidualVsX,
    pub residual_vs_v: ResidualVsV,
    pub spectrum: ResidualSpectrumPlot,
    /// The pre-measurement's transfer function against the linear
    /// resonator's fit, when there is one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub small_signal: Option<SmallSignalComparison>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detail {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub measured_force_n: Vec<f64>,
    pub modelled_force_n: Vec<f64>,
    pub base_modelled_force_n: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    pub t_s: Vec<f64>,
    pub measured_rms_n: Vec<f64>,
    pub residual_rms_n: Vec<f64>,
    pub base_residual_rms_n: Vec<f64>,
}

/// Mean residual per x bin, split by the direction of motion (N); None
/// where a bin holds fewer than 20 samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ByDirection {
    pub positive_v_n: Vec<Option<f64>>,
    pub negative_v_n: Vec<Option<f64>>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualVsX {
    /// Bin centres (m).
    pub x_m: Vec<f64>,
    #[serde(rename = "final")]
    pub final_model: ByDirection,
    pub base: ByDirection,
    /// Samples per bin.
    pub positive_v_count: Vec<f64>,
    pub negative_v_count: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualVsV {
    /// Bin centres (m/s).
    pub v_m_per_s: Vec<f64>,
    pub final_n: Vec<Option<f64>>,
    pub base_n: Vec<Option<f64>>,
    pub count: Vec<f64>,
}

/// The residual's power spectral density on about 300 log-spaced points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualSpectrumPlot {
    pub freq_hz: Vec<f64>,
    pub psd_n2_per_hz: Vec<f64>,
    pub base_psd_n2_per_hz: Vec<Option<f64>>,
    pub noise_psd_n2_per_hz: Vec<f64>,
    /// The bands the first ten harmonics sweep through (Hz).
    pub harmonic_bands_hz: Vec<[f64; 2]>,
}

/// `Hx = X / Mic` of the pre-measurement against the linear resonator's fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SmallSignalComparison {
    pub freq_hz: Vec<f64>,
    pub measured_abs_m_per_v: Vec<f64>,
    pub fit_abs_m_per_v: Vec<f64>,
    pub coherence: Vec<f64>,
    pub reliable: bool,
    pub misfit_percent: f64,
}

/// Serializes the document with its members sorted by name at every depth,
/// as it has always been written (see the module's documentation).
pub fn sorted<S: Serializer>(d: &Option<Diagnostics>, s: S) -> Result<S::Ok, S::Error> {
    use serde::ser::Error;
    serde_json::to_value(d)
        .map_err(S::Error::custom)?
        .serialize(s)
}
