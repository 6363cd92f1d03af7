//! Log sweeps (the stimulus of the reference recordings) and the
//! cycle-by-cycle fundamental that the procedure reads its decisions from.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// `u = V env(t) sin(2 pi f1 L (exp(t/L) - 1))`, `L = T/ln(f2/f1)`, half-cosine
/// fades in and out, silence after.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SweepSpec {
    pub f_start_hz: f64,
    pub f_end_hz: f64,
    pub duration_s: f64,
    pub amplitude_v: f64,
    pub fade_s: f64,
    pub silence_s: f64,
}

impl SweepSpec {
    /// A sweep with the reference recordings' fades (0.25 s) and silence (0.5 s).
    pub fn new(f_start_hz: f64, f_end_hz: f64, duration_s: f64, amplitude_v: f64) -> SweepSpec {
        SweepSpec {
            f_start_hz,
            f_end_hz,
            duration_s,
            amplitude_v,
            fade_s: 0.25,
            silence_s: 0.5,
        }
    }

    fn l(&self) -> f64 {
        self.duration_s / (self.f_end_hz / self.f_start_hz).ln()
    }

    /// Phase (rad) at time t.
    pub fn phase(&self, t: f64) -> f64 {
        let l = self.l();
        2.0 * PI * self.f_start_hz * l * ((t / l).exp() - 1.0)
    }

    /// Instantaneous frequency (Hz) at time t (within the sweep).
    pub fn freq_at(&self, t: f64) -> f64 {
        self.f_start_hz * (t.min(self.duration_s) / self.l()).exp()
    }

    /// Time (s) at which the sweep passes `f` Hz.
    pub fn time_at(&self, f_hz: f64) -> f64 {
        self.l() * (f_hz / self.f_start_hz).ln()
    }

    pub fn envelope(&self, t: f64) -> f64 {
        let tf = self.fade_s;
        let t_end = self.duration_s;
        if t < 0.0 || t > t_end {
            0.0
        } else if t < tf {
            0.5 * (1.0 - (PI * t / tf).cos())
        } else if t > t_end - tf {
            0.5 * (1.0 - (PI * (t_end - t) / tf).cos())
        } else {
            1.0
        }
    }

    pub fn value(&self, t: f64) -> f64 {
        self.amplitude_v * self.envelope(t) * self.phase(t).sin()
    }

    /// Total length including the silence (s).
    pub fn total_s(&self) -> f64 {
        self.duration_s + self.silence_s
    }

    /// The drive samples at `fs`.
    pub fn samples(&self, fs: f64) -> Vec<f64> {
        let n = (self.total_s() * fs).round() as usize;
        (0..n).map(|k| self.value(k as f64 / fs)).collect()
    }

    /// `[f_start, f_end, duration_s, drive_volts]` as in the reference truth.json.
    pub fn as_array(&self) -> [f64; 4] {
        [
            self.f_start_hz,
            self.f_end_hz,
            self.duration_s,
            self.amplitude_v,
        ]
    }

    /// Checks the numbers; one-line error.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.f_start_hz > 0.0 && self.f_end_hz > self.f_start_hz && self.f_end_hz.is_finite())
        {
            return Err(format!(
                "sweep needs 0 < f_start < f_end, got {} .. {} Hz",
                self.f_start_hz, self.f_end_hz
            ));
        }
        if !(self.duration_s > 2.0 * self.fade_s && self.duration_s.is_finite()) {
            return Err(format!(
                "sweep duration {} s is shorter than its fades",
                self.duration_s
            ));
        }
        if !(self.amplitude_v >= 0.0 && self.amplitude_v.is_finite()) {
            return Err(format!("sweep amplitude {} V is invalid", self.amplitude_v));
        }
        Ok(())
    }
}

/// Fundamental of one signal over one cycle of the sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct Cycle {
    /// Instantaneous frequency at the middle of the cycle (Hz).
    pub f_hz: f64,
    /// Time of the middle of the cycle (s).
    pub t_s: f64,
    /// Complex amplitude (re, im) of each signal at the sweep's phase.
    pub amp: Vec<(f64, f64)>,
}

/// Cycle-by-cycle complex amplitude of the fundamental of each signal in
/// `signals` (lock-in on the sweep's phase, one full cycle per estimate;
/// within the fades and the sweep only).
pub fn cycles(spec: &SweepSpec, fs: f64, signals: &[&[f64]]) -> Vec<Cycle> {
    let n = signals.iter().map(|s| s.len()).min().unwrap_or(0);
    let n_sweep = ((spec.duration_s * fs) as usize).min(n);
    let mut out = Vec::new();
    let mut start = 0usize;
    let mut acc = vec![(0.0, 0.0); signals.len()];
    // Least squares of a cos + b sin over each cycle (exact for a pure
    // sinusoid at the sweep's phase, whatever the cycle's sample count).
    let (mut scc, mut sss, mut ssc) = (0.0, 0.0, 0.0);
    let mut cycle_idx = 0.0f64;
    for k in 0..n_sweep {
        let ph = spec.phase(k as f64 / fs);
        let (s, c) = ph.sin_cos();
        scc += c * c;
        sss += s * s;
        ssc += s * c;
        for (a, sig) in acc.iter_mut().zip(signals) {
            a.0 += sig[k] * c;
            a.1 += sig[k] * s;
        }
        let cyc = (ph / (2.0 * PI)).floor();
        if cyc > cycle_idx || k + 1 == n_sweep {
            let len = k + 1 - start;
            let det = scc * sss - ssc * ssc;
            if len > 4 && det > 1e-9 * (scc + sss).powi(2) {
                let t_mid = (start + k) as f64 * 0.5 / fs;
                out.push(Cycle {
                    f_hz: spec.freq_at(t_mid),
                    t_s: t_mid,
                    amp: acc
                        .iter()
                        .map(|&(xc, xs)| {
                            let a = (sss * xc - ssc * xs) / det;
                            let b = (scc * xs - ssc * xc) / det;
                            // x = Re(A e^{j ph}) = A.re cos - A.im sin
                            (a, -b)
                        })
                        .collect(),
                });
            }
            acc.iter_mut().for_each(|a| *a = (0.0, 0.0));
            (scc, sss, ssc) = (0.0, 0.0, 0.0);
            start = k + 1;
            cycle_idx = cyc;
        }
    }
    out
}

/// |a| of a complex pair.
pub fn abs(a: (f64, f64)) -> f64 {
    a.0.hypot(a.1)
}

/// a / b of complex pairs.
pub fn div(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let d = b.0 * b.0 + b.1 * b.1;
    ((a.0 * b.0 + a.1 * b.1) / d, (a.1 * b.0 - a.0 * b.1) / d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lock_in_recovers_amplitude_and_phase() {
        let spec = SweepSpec::new(10.0, 80.0, 4.0, 2.0);
        let fs = 8000.0;
        let u = spec.samples(fs);
        // y = 0.5 * u delayed by a quarter period at every frequency = 0.5 A cos-phase shift.
        let y: Vec<f64> = (0..u.len())
            .map(|k| {
                let t = k as f64 / fs;
                0.5 * spec.amplitude_v * spec.envelope(t) * (spec.phase(t) - PI / 2.0).sin()
            })
            .collect();
        let cyc = cycles(&spec, fs, &[&u, &y]);
        assert!(cyc.len() > 100);
        for c in cyc.iter().filter(|c| c.t_s > 0.3 && c.t_s < 3.7) {
            let h = div(c.amp[1], c.amp[0]);
            assert!((abs(h) - 0.5).abs() < 1e-3, "{h:?} at {}", c.f_hz);
            assert!((h.1.atan2(h.0) + PI / 2.0).abs() < 1e-2, "{h:?}");
        }
        assert!((spec.freq_at(spec.time_at(33.0)) - 33.0).abs() < 1e-9);
    }
}
