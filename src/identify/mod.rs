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
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Report {}

#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    #[error("{0}")]
    Invalid(String),
}

/// Analyses a recording set.
pub fn analyze(_set: &RecordingSet, _opts: &AnalyzeOptions) -> Result<Report, AnalyzeError> {
    Err(AnalyzeError::Invalid("analysis not implemented yet".into()))
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
