//! Large-signal resonance fR and effective stiffness Keff(Xpeak) of the main
//! sweep (paper eqs. 13-16), from the force balance `m x'' + R x' + K(x) x = F`
//! with F = Ss p, i.e. the microphone: the resonance is where the
//! fundamental of the displacement lags the fundamental of the driving force
//! (the box pressure) by 90 degrees, `Keff = (2 pi fR)^2 m`. Neither the
//! exciter drive nor the displacement peak alone: the box's air spring makes
//! the pressure fall where the part moves most (large cones), and damping
//! moves the displacement peak below the resonance (low Q).

use super::prep::Prepared;
use realfft::num_complex::Complex64;
use std::f64::consts::PI;

/// The large-signal resonance found along the sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct Resonance {
    /// Frequency where X lags F by 90 degrees (Hz).
    pub fr_hz: f64,
    /// Fractional index into the per-period harmonics of the crossing.
    pub pos: f64,
    /// Index of the period whose centre is nearest to the crossing.
    pub index: usize,
    /// Frequency of the largest fundamental displacement (Hz).
    pub displacement_peak_hz: f64,
    /// Index of the period of the largest fundamental displacement.
    pub displacement_peak_index: usize,
}

/// Periods averaged (each side) when smoothing X1/F1 along the sweep.
const SMOOTH: usize = 2;

/// The complex ratio X1 / Mic1 of the fundamentals per period, oriented so
/// that it is F-proportional (positive real part well below resonance).
fn ratios(p: &Prepared) -> Vec<Complex64> {
    p.px.iter()
        .zip(&p.pm)
        .map(|(x, m)| {
            let (cx, cm) = (x.harmonics[0], m.harmonics[0]);
            if cm.norm() > 0.0 {
                cx / cm
            } else {
                Complex64::new(0.0, 0.0)
            }
        })
        .collect()
}

/// Finds fR on a prepared main sweep. None when the phase of X/F never
/// crosses -90 degrees inside the analysed part of the sweep.
pub fn find(p: &Prepared) -> Option<Resonance> {
    let n = p.px.len();
    let amp: Vec<f64> = p.px.iter().map(|q| q.amplitude(1)).collect();
    let (ipk, _) = amp.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    let h = ratios(p);
    // Smoothed ratio (complex mean of unit phasors weighted by |X1|).
    let hs: Vec<Complex64> = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(SMOOTH), (i + SMOOTH + 1).min(n));
            h[a..b]
                .iter()
                .zip(&amp[a..b])
                .map(|(c, w)| {
                    if c.norm() > 0.0 {
                        c / c.norm() * *w
                    } else {
                        *c
                    }
                })
                .sum()
        })
        .collect();
    // Usable periods: displacement fundamental at least 10 % of its peak.
    let thr = 0.1 * amp[ipk];
    let first = amp.iter().position(|&a| a >= thr)?;
    let last = amp.iter().rposition(|&a| a >= thr)?;
    // Orientation from the first usable periods (stiffness-controlled side).
    let head = (first..=last).take(((last - first) / 10).max(3));
    let mut orient = Complex64::new(0.0, 0.0);
    for i in head {
        orient += hs[i];
    }
    let sign = if orient.re < 0.0 { -1.0 } else { 1.0 };
    // Unwrapped phase of sign * X/F from the first usable period on.
    let mut phase = vec![f64::NAN; n];
    let mut prev = (sign * hs[first]).arg();
    for i in first..=last {
        let mut ph = (sign * hs[i]).arg();
        while ph - prev > PI {
            ph -= 2.0 * PI;
        }
        while ph - prev < -PI {
            ph += 2.0 * PI;
        }
        phase[i] = ph;
        prev = ph;
    }
    // Down-crossings of -90 degrees; the one with the largest displacement wins.
    let target = -0.5 * PI;
    let mut best: Option<(f64, f64)> = None; // (pos, amplitude)
    for i in first..last {
        let (a, b) = (phase[i], phase[i + 1]);
        if a > target && b <= target {
            let t = (a - target) / (a - b);
            let pos = i as f64 + t;
            let w = amp[i] * (1.0 - t) + amp[i + 1] * t;
            if best.is_none_or(|(_, bw)| w > bw) {
                best = Some((pos, w));
            }
        }
    }
    let (pos, _) = best?;
    let fr_hz = freq_at(p, pos);
    let index = (pos.round() as usize).min(n - 1);
    Some(Resonance {
        fr_hz,
        pos,
        index,
        displacement_peak_hz: p.px[ipk].freq_hz,
        displacement_peak_index: ipk,
    })
}

/// Frequency (Hz) at a fractional period index.
pub fn freq_at(p: &Prepared, pos: f64) -> f64 {
    let i = (pos.floor().max(0.0) as usize).min(p.px.len() - 1);
    let j = (i + 1).min(p.px.len() - 1);
    let t = pos - i as f64;
    p.px[i].freq_hz * (1.0 - t) + p.px[j].freq_hz * t
}

/// Effective stiffness of a restoring force `K(x) x` over the excursion
/// `x = c + X cos(theta)` (c, X from `[x_min, x_max]`): the first-harmonic
/// describing function `(1/(pi X)) int_0^{2 pi} K(x) x cos(theta) dtheta`
/// (Gauss-Chebyshev, exact for polynomials up to degree 2 * 64 - 1).
pub fn describing_function_keff(k: &[f64], x_min: f64, x_max: f64) -> f64 {
    let (c, a) = (0.5 * (x_max + x_min), 0.5 * (x_max - x_min));
    if a <= 0.0 {
        return f64::NAN;
    }
    let n = 128;
    let mut s = 0.0;
    for j in 0..n {
        let th = 2.0 * PI * (j as f64 + 0.5) / n as f64;
        let x = c + a * th.cos();
        let kx = k.iter().rev().fold(0.0, |acc, ci| acc * x + ci);
        s += kx * x * th.cos();
    }
    2.0 * s / (n as f64 * a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn describing_function_of_a_cubic_spring() {
        // K(x) = k0 + k2 x^2, symmetric: Keff = k0 + 3/4 k2 X^2.
        let (k0, k2, x) = (1500.0, 4e6, 0.01);
        let got = describing_function_keff(&[k0, 0.0, k2], -x, x);
        assert!((got - (k0 + 0.75 * k2 * x * x)).abs() < 1e-9 * got);
        // Linear spring with an offset: Keff = k0 for any c (F(x) = k0 x).
        let got = describing_function_keff(&[k0], -0.002, 0.008);
        assert!((got - k0).abs() < 1e-9 * k0);
        // K(x) = k0 + k1 x around c: F = k0 x + k1 x^2, first harmonic of
        // k1 (c + X cos)^2 is 2 k1 c X: Keff = k0 + 2 k1 c.
        let (k1, lo, hi) = (3e4, -0.004, 0.008);
        let c = 0.5 * (lo + hi);
        let got = describing_function_keff(&[k0, k1], lo, hi);
        assert!((got - (k0 + 2.0 * k1 * c)).abs() < 1e-9 * k0);
    }
}
