//! The job's clock line `t(n) = A_e + B n` and its pieces: the tie points
//! (window delays), the line's covariance, one sweep's mapping.

/// The clock line of a job.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockLine {
    /// Audio time of device index 0 per epoch (s).
    pub offsets_s: Vec<(u32, f64)>,
    /// Audio time per device sample (s).
    pub period_s: f64,
    pub period_stderr_s: f64,
}

impl ClockLine {
    pub fn ratio_ppm(&self, nominal_rate_hz: f64) -> f64 {
        (1.0 / (self.period_s * nominal_rate_hz) - 1.0) * 1e6
    }
    pub(super) fn offset(&self, epoch: u32) -> Option<f64> {
        self.offsets_s
            .iter()
            .find(|(e, _)| *e == epoch)
            .map(|p| p.1)
    }
}

/// A delay estimate of one window: device index `n` was taken at audio time `t_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Tie {
    pub(super) epoch: u32,
    pub(super) sweep: u32,
    pub(super) n: f64,
    pub(super) t_s: f64,
    pub(super) sigma_s: f64,
}

#[derive(Debug, Clone)]
pub(super) struct LineCov {
    pub(super) n_ref: f64,
    /// Parameters: offsets (per epoch, in `line.offsets_s` order, at n_ref) then period.
    pub(super) cov: Vec<f64>,
    pub(super) p: usize,
}

/// Mapping of one sweep: t(n) = a + b n.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Map {
    pub(super) a: f64,
    pub(super) b: f64,
}

impl Map {
    pub(super) fn n_of(&self, t: f64) -> f64 {
        (t - self.a) / self.b
    }
}
