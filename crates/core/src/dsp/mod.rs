//! Signal processing: band-limited differentiation, FFT helpers, transfer functions, harmonic analysis, least squares. Pure.
//!
//! - [`spectrum`]: FFT-domain low-pass, differentiation and decimation of whole records, noise estimates.
//! - [`tf`]: transfer function from a sweep with coherence (full-record H1, band-averaged).
//! - [`harmonics`]: per-period harmonic analysis along a sweep, resonance peak.
//! - [`lstsq`](mod@lstsq): least squares with standard errors (shared with the diagnostics).
//! - [`quantile`]: order statistics without sorting the record.

pub mod harmonics;
pub mod lstsq;
pub mod quantile;
pub mod spectrum;
pub mod tf;

pub use harmonics::{
    harmonics_per_period, harmonics_per_period_of, period_marks, resonance_peak, PeriodHarmonics,
};
pub use lstsq::{lstsq, Lstsq, LstsqError};
pub use quantile::{max_abs, quantile_pair};
pub use realfft::num_complex::Complex64;
pub use spectrum::{LowPass, Spectrum};
pub use tf::{transfer_function, TransferFunction};
