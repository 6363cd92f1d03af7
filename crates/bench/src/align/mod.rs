//! Clock alignment: puts the samples of a serial laser (its own clock, device
//! index `n`) on the audio time base of the microphone. Pure: no I/O, no
//! clock; the hardware bench calls it after each sweep with what it captured.
//!
//! Model: the laser sample with device index `n` was taken at audio time
//! `t(n) = A_e + B n`, with one offset `A_e` per audio clock epoch (a
//! continuous run of the input stream) and one period `B = 1 / (f_nom (1 +
//! ppm 1e-6))` per job (`ppm > 0`: the laser clock runs fast).
//!
//! Estimator (docs/decisions/0010-clock-alignment.md): the microphone (box
//! pressure, audio clock) drives the part, `Ss p = m x'' + R x' + K(x) x`. A
//! time error `d` of `x` adds `d * d/dt(m x'' + R x' + K(x) x)` to the
//! residual: for a sine at `w` a damping change `(K - m w^2) d` that a
//! constant `R` cannot absorb over a sweep covering a band. Per sweep, a
//! Gauss-Newton iteration fits the force balance (`m, R, k_0..k_4` and a
//! constant, all linear) jointly with a line `d(t)`, re-resampling `x` each
//! time; then the delay is estimated in windows (tie points `(n, t)`), and a
//! weighted line through the tie points of all sweeps of the job gives `A_e`,
//! `B`; the scatter of the tie points about that line is the reported
//! residual. Arrival times are used only to seed a coarse search (+-50 ms).
//!
//! The output displacement is the laser resampled at the audio sample
//! instants with a windowed-sinc (Kaiser) interpolator ([`SincKernel`]).

mod dense;
mod grid;
mod job;
mod line;
mod sinc;
mod sweep;

pub use job::JobAligner;
pub use line::ClockLine;
pub use sinc::SincKernel;
pub use sweep::{AlignConfig, AlignedSweep, AlignmentReport, AudioCapture, LaserTrack};

#[cfg(test)]
mod tests;
