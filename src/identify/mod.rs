//! Identification: small-signal fit (pre-measurement), large-signal results and
//! nonlinear stiffness K(x) (One Signal / Two Signal) from a recording set.
//! Pure and synchronous: no I/O, no logging.
//!
//! CONTRACT shared with the daemon: `analyze`, `AnalyzeOptions`, `Method`,
//! `Report` (Serialize + Deserialize + Clone; JSON field names fixed by issue 2).

use crate::recording::RecordingSet;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    #[default]
    TwoSignal,
    OneSignal,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AnalyzeOptions {
    pub method: Method,
    /// Highest power of K(x) = sum k_i x^i; chosen from the data when None.
    pub order: Option<usize>,
}

/// The result document (same JSON as `springbench analyze --json` and the API).
/// Field names are fixed by issues 2 and 5; more fields may be added (never renamed).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Small-signal fit of the pre-measurement; None when the set has no usable pre sweep.
    pub small_signal: Option<SmallSignal>,
    pub large_signal: LargeSignal,
    pub stiffness: Stiffness,
    pub model: Model,
    /// Human-readable warnings (one line each), e.g. "pre-measurement unreliable: ...".
    pub warnings: Vec<String>,
    /// Filled by `diagnose` (candidates, ladder, ...); None from a plain analysis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diagnostics: Option<serde_json::Value>,
}

/// Small-signal parameters from the pre-measurement (SI), with standard errors.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SmallSignal {
    pub f0_hz: f64,
    pub k0_n_per_m: f64,
    pub r_ns_per_m: f64,
    pub q: f64,
    /// Standard errors of the above (same units).
    pub f0_se_hz: f64,
    pub k0_se_n_per_m: f64,
    pub r_se_ns_per_m: f64,
    pub q_se: f64,
    /// Effective area per microphone unit: Sd / mic sensitivity (m^2 per V); None without a mic model.
    #[serde(default)]
    pub area_per_mic_unit_m2_per_v: Option<f64>,
    /// Misfit of the linear resonator model against the measured transfer function (%).
    pub misfit_percent: f64,
    /// False when the pre-measurement is not the linear resonator it should be.
    pub reliable: bool,
}

/// Large-signal results from the main (narrow) sweep (SI).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LargeSignal {
    pub resonance_hz: f64,
    pub keff_n_per_m: f64,
    pub ceff_m_per_n: f64,
    pub xpeak_m: f64,
    pub x_min_m: f64,
    pub x_max_m: f64,
    pub dc_m: f64,
    pub moving_mass_kg: f64,
    /// Harmonic amplitudes of x at resonance, fundamental first (m).
    #[serde(default)]
    pub harmonics_m: Vec<f64>,
}

/// Nonlinear stiffness K(x) = sum k_i x^i (x in m, K in N/m).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Stiffness {
    /// "two-signal" or "one-signal".
    pub method: String,
    pub order: usize,
    /// k_0..k_order in N/m^(i+1).
    pub coefficients: Vec<f64>,
    pub coefficients_se: Vec<f64>,
    /// Same coefficients in N/mm^(i+1) (x in mm, K in N/mm).
    #[serde(default)]
    pub coefficients_n_per_mm: Vec<f64>,
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
}

/// How well the force-balance model explains the measurement (issue 5 names).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
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

#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    #[error("{0}")]
    Invalid(String),
}

/// Analyses a recording set.
pub fn analyze(_set: &RecordingSet, _opts: &AnalyzeOptions) -> Result<Report, AnalyzeError> {
    Err(AnalyzeError::Invalid("analysis not implemented yet".into()))
}

/// Prepares the force-balance data of the main sweep of `set` (band limiting,
/// differentiation, alignment, analysed span). Shared by `analyze` and `diagnose`.
pub fn force_balance_data(
    _set: &RecordingSet,
    _opts: &AnalyzeOptions,
) -> Result<ForceBalanceData, AnalyzeError> {
    Err(AnalyzeError::Invalid(
        "force balance not implemented yet".into(),
    ))
}

/// The large-signal force-balance data, prepared once by the identification
/// and shared with [`crate::diagnose`] (which extends the same force balance
/// with candidate effects). All SI; every slice has the same length and covers
/// the analysed span of the main sweep (already band-limited, possibly decimated).
#[derive(Debug, Clone, PartialEq)]
pub struct ForceBalanceData {
    /// Sample rate of these slices (Hz).
    pub sample_rate_hz: f64,
    /// Time of the first sample, from the start of the main recording (s).
    pub t0_s: f64,
    /// Moving mass (kg).
    pub mass_kg: f64,
    /// Displacement (m), band-limited.
    pub x_m: Vec<f64>,
    /// Velocity (m/s).
    pub v_m_per_s: Vec<f64>,
    /// Acceleration (m/s^2).
    pub a_m_per_s2: Vec<f64>,
    /// Microphone (V), band-limited, aligned with x.
    pub mic_v: Vec<f64>,
    /// Standard deviation of the laser noise estimated from the data (m), for the noise floor.
    pub laser_noise_m: f64,
    /// Standard deviation of the microphone noise estimated from the data (V).
    pub mic_noise_v: f64,
}
