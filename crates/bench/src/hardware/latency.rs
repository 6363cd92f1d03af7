//! Output-to-input latency from the loopback channel: the lag that maximises
//! the cross-correlation of the drive as played (digital) with the drive as
//! captured (loopback), refined to a fraction of a sample by a parabola
//! through the peak. Pure: plain slices in, numbers out.

use realfft::RealFftPlanner;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LatencyEstimate {
    /// Lag of the captured loopback behind the played drive (samples, fractional).
    pub latency_samples: f64,
    /// Normalised correlation at the peak (1 = the loopback is the drive, scaled).
    pub correlation: f64,
    /// Captured / played amplitude at the peak lag (1 when the calibration is right).
    pub gain: f64,
}

/// Lag in `0..=max_lag` of `captured` behind `reference`. `None` when the
/// reference is silent or too short.
pub fn estimate_latency(
    reference: &[f64],
    captured: &[f64],
    max_lag: usize,
) -> Option<LatencyEstimate> {
    let e_ref: f64 = reference.iter().map(|v| v * v).sum();
    if reference.is_empty()
        || captured.is_empty()
        || e_ref.is_nan()
        || e_ref <= 0.0
        || !e_ref.is_finite()
    {
        return None;
    }
    let n = (reference.len() + captured.len()).next_power_of_two();
    let mut planner = RealFftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(n);
    let inv = planner.plan_fft_inverse(n);
    let mut a = vec![0.0; n];
    a[..reference.len()].copy_from_slice(reference);
    let mut b = vec![0.0; n];
    b[..captured.len()].copy_from_slice(captured);
    let mut fa = fwd.make_output_vec();
    let mut fb = fwd.make_output_vec();
    fwd.process(&mut a, &mut fa).ok()?;
    fwd.process(&mut b, &mut fb).ok()?;
    for (x, y) in fa.iter_mut().zip(&fb) {
        *x = x.conj() * y;
    }
    // The imaginary parts of DC and Nyquist must be zero for the inverse.
    fa[0].im = 0.0;
    if let Some(last) = fa.last_mut() {
        last.im = 0.0;
    }
    let mut c = vec![0.0; n];
    inv.process(&mut fa, &mut c).ok()?;
    let scale = 1.0 / n as f64;
    let max_lag = max_lag.min(captured.len().saturating_sub(1));
    // Energy of the captured window under the reference at each lag (prefix sums).
    let mut prefix = Vec::with_capacity(captured.len() + 1);
    prefix.push(0.0);
    for v in captured {
        prefix.push(prefix.last().unwrap() + v * v);
    }
    let window_energy = |lag: usize| {
        let hi = (lag + reference.len()).min(captured.len());
        prefix[hi] - prefix[lag.min(hi)]
    };
    let (mut best, mut best_v) = (0usize, f64::NEG_INFINITY);
    for (lag, &v) in c.iter().enumerate().take(max_lag + 1) {
        if v > best_v {
            best_v = v;
            best = lag;
        }
    }
    let peak = best_v * scale;
    let e_cap = window_energy(best);
    if peak.is_nan() || peak <= 0.0 || e_cap.is_nan() || e_cap <= 0.0 {
        return None;
    }
    let mut frac = 0.0;
    if best > 0 && best < max_lag {
        let (y0, y1, y2) = (c[best - 1], c[best], c[best + 1]);
        let den = y0 - 2.0 * y1 + y2;
        if den < 0.0 {
            frac = (0.5 * (y0 - y2) / den).clamp(-0.5, 0.5);
        }
    }
    Some(LatencyEstimate {
        latency_samples: best as f64 + frac,
        correlation: peak / (e_ref * e_cap).sqrt(),
        gain: peak / e_ref,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sweep(n: usize, fs: f64) -> Vec<f64> {
        (0..n)
            .map(|k| {
                let t = k as f64 / fs;
                (2.0 * std::f64::consts::PI * (20.0 * t + 200.0 * t * t)).sin()
            })
            .collect()
    }

    #[test]
    fn integer_latency_and_gain_are_found_exactly() {
        let fs = 48000.0;
        let d = sweep(24000, fs);
        let mut cap = vec![0.0; 240];
        cap.extend(d.iter().map(|v| 0.5 * v));
        cap.extend(vec![0.0; 4800]);
        let e = estimate_latency(&d, &cap, 4800).unwrap();
        assert!((e.latency_samples - 240.0).abs() < 1e-6, "{e:?}");
        assert!((e.gain - 0.5).abs() < 1e-9, "{e:?}");
        assert!(e.correlation > 0.999_999, "{e:?}");
    }

    #[test]
    fn fractional_latency_within_a_tenth_of_a_sample() {
        let fs = 48000.0;
        let n = 24000;
        let delay = 100.3;
        let d: Vec<f64> = (0..n)
            .map(|k| (2.0 * std::f64::consts::PI * 300.0 * k as f64 / fs).sin())
            .collect();
        let cap: Vec<f64> = (0..n + 400)
            .map(|k| {
                let t = k as f64 - delay;
                if t < 0.0 || t >= n as f64 {
                    0.0
                } else {
                    (2.0 * std::f64::consts::PI * 300.0 * t / fs).sin()
                }
            })
            .collect();
        let e = estimate_latency(&d, &cap, 400).unwrap();
        assert!((e.latency_samples - delay).abs() < 0.1, "{e:?}");
    }

    #[test]
    fn silence_and_unrelated_noise_are_told_apart() {
        let d = sweep(4800, 48000.0);
        assert!(estimate_latency(&vec![0.0; 100], &d, 10).is_none());
        assert!(estimate_latency(&d, &vec![0.0; 5000], 10).is_none());
        // A loopback of something else: correlation far below 1.
        let other: Vec<f64> = (0..5000)
            .map(|k| ((k * 7919) % 101) as f64 - 50.0)
            .collect();
        if let Some(e) = estimate_latency(&d, &other, 100) {
            assert!(e.correlation < 0.2, "{e:?}");
        }
    }
}
