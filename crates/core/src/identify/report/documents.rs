//! Sub-documents of the result document that the diagnostics fill: the
//! ladder, the ranked candidates, a level series' joint fit, the effect
//! pairs the data cannot separate and a second mode of the pre-measurement.
//! They live here, beside [`super::Report`], so that the document does not
//! depend on the engine that computes them (`diagnose` depends on
//! `identify`, never the other way), and they import nothing of the
//! document above them (`diagnostics` uses them, not the reverse).

use crate::effects::Effects;
use serde::{Deserialize, Serialize};

/// One candidate, ranked against the model it would extend.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CandidateResult {
    pub effect: String,
    /// Reduction of the held-out model error (structured part) when added (%).
    pub error_reduction_percent: f64,
    /// Reduction of the held-out residual when added (%).
    pub residual_reduction_percent: f64,
    pub significant: bool,
    pub p_value: f64,
    /// Significance level after the Bonferroni correction this test was held to.
    pub alpha: f64,
    /// Fitted parameters (names of effects.rs, SI).
    pub parameters: serde_json::Value,
    /// Block-robust standard errors of the parameters.
    pub parameters_se: serde_json::Value,
    /// Largest variance inflation factor of the candidate's regressors.
    pub variance_inflation: f64,
    pub identifiable: bool,
    /// The model term the candidate is most collinear with.
    pub collinear_with: String,
    /// "cannot tell from this data ..." and the separating experiment, when not identifiable.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The memory effect or neighbour this candidate only stood in for: not
    /// significant once that one is in, which stays significant with this
    /// one in its place (decision 0120); it ranks below it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stands_in_for: Option<String>,
    pub cv_residual_percent: f64,
    #[serde(skip)]
    pub hyper: Option<f64>,
    #[serde(skip)]
    pub cv_sse: f64,
    /// Why the ladder does not add this candidate although it is
    /// significant (implausible parameters, a held-out gain that does not
    /// hold in most folds); None: it may be added.
    #[serde(skip)]
    pub not_added: Option<String>,
}

/// One step of the ladder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LadderStep {
    pub effects: Vec<String>,
    pub order: usize,
    pub residual_percent: f64,
    pub cv_residual_percent: f64,
    pub model_error_percent: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub added: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p_value: Option<f64>,
}

/// One level's own fit (the engine on that level alone).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LevelFit {
    /// The measurement of this level (daemon jobs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measurement_id: Option<String>,
    /// The level's target peak displacement (m), when it had one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_xpeak_m: Option<f64>,
    /// Largest |x| of the level's analysed data (m).
    pub x_abs_max_m: f64,
    /// Smallest and largest x of the level's analysed data (m).
    pub range_m: [f64; 2],
    pub effects: Effects,
    pub order: usize,
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    pub r_ns_per_m: f64,
    pub model_error_percent: f64,
}

/// The joint fit over all levels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JointFit {
    pub effects: Effects,
    pub order: usize,
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    pub stiffness_coefficients_se_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Time K(x) refers to (s from the start of the first level's analysed
    /// data) when stiffness drift is in the model.
    pub reference_time_s: Option<f64>,
    pub r_ns_per_m: f64,
    pub r_se_ns_per_m: f64,
    /// Union of the levels' ranges (m): where the joint K(x) holds.
    pub valid_range_m: [f64; 2],
    pub model_error_percent: f64,
    pub noise_floor_percent: f64,
    pub ladder: Vec<LadderStep>,
    /// Candidates ranked against the joint base model.
    pub candidates: Vec<CandidateResult>,
    /// Effect pairs the joint data still cannot separate (as
    /// `diagnostics.ambiguities`).
    pub ambiguities: Vec<Ambiguity>,
}

/// What a series fit returns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SeriesFit {
    pub levels: Vec<LevelFit>,
    pub joint: JointFit,
}

/// Two effects the data cannot separate, and the experiment that would.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Ambiguity {
    /// The effect the ladder added, then the one left out.
    pub effects: [String; 2],
    /// Share of the base model's held-out error each removes (%).
    pub error_reduction_percent: [f64; 2],
    /// p-value of the first once the second is in the model.
    pub p_value_of_first_after_second: Option<f64>,
    pub separating_experiment: String,
    pub note: String,
}

/// A resonance of the pre-measurement's transfer function X/Mic at a fixed
/// frequency of its own (a second mechanical mode: part of the moving mass
/// on its own spring), fitted over the whole excited band.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WideBandResonance {
    pub frequency_hz: f64,
    pub q: f64,
    /// The mass that moves on the mode's own spring (kg).
    pub mass_kg: f64,
    /// The band fitted (Hz).
    pub band_hz: [f64; 2],
    /// Relative misfit (%) of X over that band of the linear resonator,
    /// with creep added (best tau), and with the resonance added.
    pub misfit_linear_percent: f64,
    pub misfit_with_creep_percent: f64,
    pub misfit_with_resonance_percent: f64,
    /// The misfit the sensors' white noise alone would give (%).
    pub noise_misfit_percent: f64,
}
