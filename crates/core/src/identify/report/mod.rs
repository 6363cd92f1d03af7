//! The result document of an identification (`Report`, the same JSON as
//! `springbench analyze --json` and the API) and its parts: the headline
//! values here, the validity of each ([`validity`]), the diagnostics
//! ([`diagnostics`]) and the sub-documents they fill ([`documents`]).
//! Types only (and the validity's judging of them): the pipeline that
//! computes them is `identify`'s, and nothing here imports it.

use serde::{Deserialize, Serialize};

pub mod diagnostics;
pub mod documents;
pub mod validity;

/// The result document (same JSON as `springbench analyze --json` and the API).
/// Field names are fixed by issues 2 and 5, with the unit in every name since
/// issue 12 (old names are read as aliases); more fields may be added.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Report {
    /// Small-signal fit of the pre-measurement; None when the set has no usable pre sweep.
    pub small_signal: Option<SmallSignal>,
    pub large_signal: LargeSignal,
    pub stiffness: Stiffness,
    pub model: Model,
    /// Human-readable warnings (one line each), e.g. "pre-measurement unreliable: ...".
    pub warnings: Vec<String>,
    /// Filled by `diagnose` (candidates, ladder, ...); None from a plain analysis.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        serialize_with = "diagnostics::sorted"
    )]
    #[schema(value_type = Object)]
    pub diagnostics: Option<diagnostics::Diagnostics>,
    /// Level series (a daemon job with two or more `levels_m`): K(x), R and
    /// the effects fitted jointly over all levels of the measurement's
    /// repeat, beside each level's own fit (`diagnose::series`). The same
    /// object in the document of every level of that repeat.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub series: Option<documents::SeriesFit>,
}

/// Small-signal parameters from the pre-measurement (SI), with standard errors.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SmallSignal {
    /// f0, k0 and R are null when not determined (`validity` says why and
    /// keeps the fit's number); never a non-finite number.
    pub f0_hz: Option<f64>,
    pub k0_n_per_m: Option<f64>,
    pub r_ns_per_m: Option<f64>,
    /// Quality factor sqrt(k0 m) / R; null when the fit found no positive
    /// damping (R <= 0: Q infinite or undefined), `q_null_reason` says so.
    /// Never a non-finite number.
    pub q: Option<f64>,
    /// Standard errors of the above (same units); `f0_se_hz` is null when
    /// the fitted k0 <= 0 (f0 = 0: its error is undefined), `q_se` with `q`
    /// or when it is undefined.
    pub f0_se_hz: Option<f64>,
    pub k0_se_n_per_m: f64,
    pub r_se_ns_per_m: f64,
    pub q_se: Option<f64>,
    /// Why `q` is null.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q_null_reason: Option<String>,
    /// Force per microphone volt A = Sd / mic sensitivity (N/V, i.e. m^2 Pa/V); None without a mic model.
    #[serde(default, alias = "area_per_mic_unit_m2_per_v")]
    pub force_per_mic_v_n_per_v: Option<f64>,
    /// Misfit of the linear resonator model against the measured transfer function (%).
    pub misfit_percent: f64,
    /// False when the pre-measurement is not the linear resonator it should be.
    pub reliable: bool,
    /// Effects in the small-signal model the values above come from (empty:
    /// the linear resonator). Filled by the diagnostics.
    #[serde(default, skip_serializing_if = "crate::effects::Effects::is_empty")]
    pub effects: crate::effects::Effects,
    /// Time (s from the start of the pre-measurement) k0 refers to, when the
    /// model lets the stiffness change over time (stiffness drift).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_time_s: Option<f64>,
    /// The linear resonator's values when the model above has effects
    /// (what a plain analysis reports), for comparison.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(no_recursion)]
    pub base: Option<Box<SmallSignal>>,
    /// The state of each headline value above (issue 22).
    #[serde(default)]
    pub validity: validity::SmallSignalValidity,
}

/// Large-signal results from the main (narrow) sweep (SI).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LargeSignal {
    /// fR: where the fundamental of x lags the driving force (Ss p, the
    /// microphone) by 90 degrees; the displacement peak when the phase never
    /// crosses (with a warning).
    pub resonance_hz: f64,
    /// Keff(Xpeak) = (2 pi fR)^2 m.
    pub keff_n_per_m: f64,
    pub ceff_m_per_n: f64,
    /// Largest |x| of the resonance period: the amplitude Keff belongs to.
    pub xpeak_m: f64,
    /// Smallest and largest x of the whole analysed sweep.
    pub x_min_m: f64,
    pub x_max_m: f64,
    /// Mean x of the resonance period.
    pub dc_m: f64,
    pub moving_mass_kg: f64,
    /// Harmonic amplitudes of x at resonance, fundamental first (m).
    #[serde(default)]
    pub harmonics_m: Vec<f64>,
    /// Smallest and largest x of the resonance period (the excursion of Keff).
    #[serde(default)]
    pub x_min_at_resonance_m: f64,
    #[serde(default)]
    pub x_max_at_resonance_m: f64,
    /// Cross-check of Keff: the first-harmonic describing function of the
    /// fitted restoring force K(x) x over the excursion at resonance.
    #[serde(default)]
    pub keff_from_k_of_x_n_per_m: f64,
    /// Frequency of the largest fundamental displacement of the sweep (Hz).
    #[serde(default)]
    pub displacement_peak_hz: f64,
    /// Why the displacement peak is not fR, when they differ by more than
    /// 0.5 % (box air spring, damping).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub displacement_peak_note: Option<String>,
    /// Time of the resonance period's centre (s from the start of the main
    /// recording): where stiffness drift is evaluated for Keff.
    #[serde(default)]
    pub resonance_time_s: f64,
    /// Block-robust standard error of Keff (N/m), when Keff comes from a
    /// fitted model (diagnostics with effects); None for the phase method.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keff_se_n_per_m: Option<f64>,
    /// How fR and Keff were found: "phase" (x lags the force by 90 degrees,
    /// model-free) or "chosen_model" (the describing function of the chosen
    /// model's K(x) over the excursion at resonance, fR = sqrt(Keff/m)/2 pi).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keff_method: Option<String>,
    /// The target peak displacement of the level this measurement was made
    /// for (m), when it had one (daemon jobs); the level control stops near,
    /// not at, it (`xpeak_m` is what was reached).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_xpeak_m: Option<f64>,
    /// Keff at the target amplitude (N/m): the first-harmonic describing
    /// function of the headline K(x) over c +- `target_xpeak_m` (c the
    /// measured centre of the excursion at resonance), the value QC judges
    /// as `keff` (`qc::keff_at_target`). `keff_n_per_m` is Keff at the
    /// reached Xpeak.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keff_at_target_n_per_m: Option<f64>,
    /// With effects in the chosen model: the identification's values (phase
    /// method, no effects) in the same layout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(no_recursion)]
    pub base: Option<Box<LargeSignal>>,
    /// The state of each headline value above (issue 22).
    #[serde(default)]
    pub validity: validity::LargeSignalValidity,
}

/// Nonlinear stiffness K(x) = sum k_i x^i (x in m, K in N/m).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Stiffness {
    /// "two-signal" or "one-signal".
    pub method: String,
    pub order: usize,
    /// k_0..k_order in N/m^(i+1).
    #[serde(alias = "coefficients")]
    pub coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Standard errors of k_0..k_order in N/m^(i+1).
    #[serde(alias = "coefficients_se")]
    pub coefficients_se_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Same coefficients in N/mm^(i+1) (x in mm, K in N/mm).
    #[serde(default, alias = "coefficients_n_per_mm")]
    pub coefficients_n_per_mm_pow_i_plus_1: Vec<f64>,
    /// The measured range; K(x) is not valid outside it.
    pub valid_range_m: [f64; 2],
    /// x where C(x) first falls to 75 % of C(0), per side; None when not reached inside the range.
    #[serde(default)]
    pub xc_m: [Option<f64>; 2],
    /// Fitted mechanical resistance of the force balance (N s/m).
    #[serde(default)]
    pub r_ns_per_m: f64,
    /// Force per microphone volt of the Two Signal method (N/V); None for One Signal.
    #[serde(default)]
    pub force_per_mic_v_n_per_v: Option<f64>,
    /// Standard error of `r_ns_per_m` (N s/m); 0 when not estimated.
    #[serde(default)]
    pub r_se_ns_per_m: f64,
    /// Time (s from the start of the main recording) K(x) refers to, when
    /// the model lets the stiffness change over time (stiffness drift).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_time_s: Option<f64>,
    /// The base model's K(x) and R when the model the values above come
    /// from has effects (chosen by the diagnostics or asked for).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(no_recursion)]
    pub base: Option<Box<Stiffness>>,
    /// Change from the base model to this one: K at both ends of the range,
    /// K(0) and R (%).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub change_from_base: Option<StiffnessChange>,
    /// The state of K(x) and R (issue 22).
    #[serde(default)]
    pub validity: validity::StiffnessValidity,
}

/// How much the headline K(x) and R differ from the base model's (%).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct StiffnessChange {
    /// 100 (K(x)/K_base(x) - 1) at the lower and upper end of the valid range.
    pub k_at_range_ends_percent: [f64; 2],
    pub k0_percent: f64,
    pub r_percent: f64,
}

/// How well the force-balance model explains the measurement (issue 5 names).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Model {
    /// Effects included in the fitted model, with their fitted parameters.
    #[serde(default)]
    pub effects: crate::effects::Effects,
    /// 100 RMS(e) / RMS(m x'') over the analysed span.
    pub residual_percent: f64,
    /// The part of the residual that sensor noise explains (estimated from the data).
    pub noise_floor_percent: f64,
    /// Structured part: sqrt(residual^2 - noise^2).
    pub model_error_percent: f64,
}
