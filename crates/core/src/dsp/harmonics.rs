//! Per-period harmonic analysis along a sweep and resonance detection.

use nalgebra::{DMatrix, DVector};
use realfft::num_complex::Complex64;

/// Fractional sample positions of the upward zero crossings of `reference`
/// (a signal whose fundamental dominates, e.g. the drive, or the displacement
/// minus its mean). A hysteresis of `hysteresis` (in signal units) suppresses
/// crossings caused by noise; periods whose length differs by more than 30 %
/// from both neighbours are dropped.
pub fn period_marks(reference: &[f64], hysteresis: f64) -> Vec<f64> {
    let mut marks = Vec::new();
    let mut armed = false;
    // Blocks of 64 samples in which nothing changes the state are passed
    // over by a test that vectorises: unarmed, a block without a sample
    // below -hysteresis; armed, one without an upward zero crossing. The
    // others (about two a period) are walked sample by sample: the same
    // marks, bit for bit, as the walk over every sample.
    let n = reference.len();
    let mut start = 1;
    while start < n {
        let end = (start + 64).min(n);
        let (before, at) = (&reference[start - 1..end - 1], &reference[start..end]);
        let event = if armed {
            before
                .iter()
                .zip(at)
                .fold(false, |e, (&a, &b)| e | ((a < 0.0) & (b >= 0.0)))
        } else {
            at.iter().fold(false, |e, &b| e | (b < -hysteresis))
        };
        if event {
            for i in start..end {
                let (a, b) = (reference[i - 1], reference[i]);
                if b < -hysteresis {
                    armed = true;
                }
                if armed && a < 0.0 && b >= 0.0 {
                    // Walk back over the crossing for a linear interpolation.
                    let frac = if b != a { -a / (b - a) } else { 0.0 };
                    marks.push((i - 1) as f64 + frac);
                    armed = false;
                }
            }
        }
        start = end;
    }
    marks
}

/// One period of a signal: dc and complex harmonic amplitudes.
#[derive(Debug, Clone, PartialEq)]
pub struct PeriodHarmonics {
    /// Start and end of the period (fractional samples).
    pub start: f64,
    pub end: f64,
    /// Frequency of the period (Hz).
    pub freq_hz: f64,
    /// Mean over the period.
    pub dc: f64,
    /// Complex amplitude of harmonic h = 1..=H (index h-1), such that the
    /// signal is `dc + sum_h Re(c_h exp(j h theta))`, theta running from 0 to
    /// 2 pi over the period (a cubic in t that follows the local frequency).
    pub harmonics: Vec<Complex64>,
    /// Largest and smallest sample inside the period.
    pub max: f64,
    pub min: f64,
}

impl PeriodHarmonics {
    pub fn amplitude(&self, h: usize) -> f64 {
        self.harmonics.get(h - 1).map_or(0.0, |c| c.norm())
    }
    /// Centre of the period (fractional samples).
    pub fn centre(&self) -> f64 {
        0.5 * (self.start + self.end)
    }
}

/// Phase slope (rad/sample) at each mark: derivative of the parabola through
/// three neighbouring marks (phase 2 pi per mark), one-sided at the ends.
fn mark_slopes(marks: &[f64]) -> Vec<f64> {
    let two_pi = 2.0 * std::f64::consts::PI;
    let slope = |k: usize| -> f64 {
        if marks.len() < 3 {
            return two_pi / (marks[1] - marks[0]);
        }
        let lo = k.saturating_sub(1).min(marks.len() - 3);
        let t = [marks[lo], marks[lo + 1], marks[lo + 2]];
        let x = marks[k];
        let mut d = 0.0;
        for i in 0..3 {
            let mut li = 0.0;
            for j in 0..3 {
                if j == i {
                    continue;
                }
                let mut prod = 1.0 / (t[i] - t[j]);
                for l in 0..3 {
                    if l != i && l != j {
                        prod *= (x - t[l]) / (t[i] - t[l]);
                    }
                }
                li += prod;
            }
            d += two_pi * (lo + i) as f64 * li;
        }
        d
    };
    if marks.len() < 2 {
        return vec![0.0; marks.len()];
    }
    (0..marks.len()).map(slope).collect()
}

/// Cubic Hermite phase inside the period [ta, tb]: 0 -> 2 pi, with the local
/// frequency (slopes sa, sb) at both ends, so it follows the sweep.
fn hermite_phase(ta: f64, tb: f64, sa: f64, sb: f64, t: f64) -> f64 {
    let period = tb - ta;
    let u = (t - ta) / period;
    let (u2, u3) = (u * u, u * u * u);
    (u3 - 2.0 * u2 + u) * period * sa
        + (3.0 * u2 - 2.0 * u3) * 2.0 * std::f64::consts::PI
        + (u3 - u2) * period * sb
}

/// Removes the fundamental (cos and sin of the period phase, fitted per period
/// between consecutive marks) from signals of one record. Samples outside the
/// periods are left unchanged. What remains is dc, harmonics and noise: the
/// part of a force balance that a purely sinusoidal drive force does not enter.
/// The phase is computed once and reused for every signal.
#[derive(Debug, Clone)]
pub struct FundamentalRemover {
    /// (first sample, end sample, inverse 2x2 Gram [a, b, c] of [cos, sin]) per period.
    periods: Vec<(usize, usize, [f64; 3])>,
    cos: Vec<f64>,
    sin: Vec<f64>,
}

impl FundamentalRemover {
    pub fn new(len: usize, marks: &[f64]) -> FundamentalRemover {
        let slopes = mark_slopes(marks);
        let (mut cos, mut sin) = (vec![0.0; len], vec![0.0; len]);
        let mut periods = Vec::with_capacity(marks.len());
        for k in 0..marks.len().saturating_sub(1) {
            let (ta, tb) = (marks[k], marks[k + 1]);
            let i0 = ta.ceil().max(0.0) as usize;
            let i1 = (tb.ceil().max(0.0) as usize).min(len);
            if i1 <= i0 + 4 {
                continue;
            }
            let (mut gcc, mut gcs, mut gss) = (0.0, 0.0, 0.0);
            for i in i0..i1 {
                let (sn, cs) = hermite_phase(ta, tb, slopes[k], slopes[k + 1], i as f64).sin_cos();
                cos[i] = cs;
                sin[i] = sn;
                gcc += cs * cs;
                gcs += cs * sn;
                gss += sn * sn;
            }
            let det = gcc * gss - gcs * gcs;
            if det > 0.0 {
                periods.push((i0, i1, [gss / det, -gcs / det, gcc / det]));
            }
        }
        FundamentalRemover { periods, cos, sin }
    }

    pub fn apply(&self, signal: &[f64]) -> Vec<f64> {
        let mut out = signal.to_vec();
        for &(i0, i1, [a, b, c]) in &self.periods {
            let i1 = i1.min(signal.len());
            if i1 <= i0 {
                continue;
            }
            let (cs, sn) = (&self.cos[i0..i1], &self.sin[i0..i1]);
            let y = &signal[i0..i1];
            let rc = super::lstsq::dot(cs, y);
            let rs = super::lstsq::dot(sn, y);
            let (pc, ps) = (a * rc + b * rs, b * rc + c * rs);
            for ((o, cv), sv) in out[i0..i1].iter_mut().zip(cs).zip(sn) {
                *o -= pc * cv + ps * sv;
            }
        }
        out
    }
}

/// `signal` with its fundamental removed per period (see [`FundamentalRemover`]).
pub fn remove_fundamental_per_period(signal: &[f64], marks: &[f64]) -> Vec<f64> {
    FundamentalRemover::new(signal.len(), marks).apply(signal)
}

/// Least-squares fit of dc + `n_harm` harmonics to `signal` over each period
/// given by consecutive `marks` (fractional samples in the signal's own rate).
pub fn harmonics_per_period(
    signal: &[f64],
    marks: &[f64],
    sample_rate_hz: f64,
    n_harm: usize,
) -> Vec<PeriodHarmonics> {
    harmonics_per_period_of(&[signal], marks, sample_rate_hz, n_harm)
        .pop()
        .unwrap_or_default()
}

/// [`harmonics_per_period`] of several signals of one length on the same
/// periods: the basis and its Gram matrix are built and factored once (the
/// displacement and the microphone of a sweep share them). Each result is
/// the one [`harmonics_per_period`] gives for that signal alone.
pub fn harmonics_per_period_of(
    signals: &[&[f64]],
    marks: &[f64],
    sample_rate_hz: f64,
    n_harm: usize,
) -> Vec<Vec<PeriodHarmonics>> {
    let len = signals.first().map_or(0, |s| s.len());
    if signals.iter().any(|s| s.len() != len) {
        return signals
            .iter()
            .map(|s| harmonics_per_period(s, marks, sample_rate_hz, n_harm))
            .collect();
    }
    let p = 1 + 2 * n_harm;
    let cap = marks.len().saturating_sub(1);
    let mut out: Vec<Vec<PeriodHarmonics>> =
        signals.iter().map(|_| Vec::with_capacity(cap)).collect();
    // Lower triangle of the Gram matrix, row by row, and one right-hand side
    // and extremes per signal.
    let mut g = vec![0.0; p * p];
    let mut rs = vec![vec![0.0; p]; signals.len()];
    let mut ext = vec![(f64::NEG_INFINITY, f64::INFINITY); signals.len()];
    let mut basis = vec![0.0; p];
    let slopes = mark_slopes(marks);
    for k in 0..cap {
        let (ta, tb) = (marks[k], marks[k + 1]);
        let (sa, sb) = (slopes[k], slopes[k + 1]);
        let i0 = ta.ceil().max(0.0) as usize;
        let i1 = (tb.ceil() as usize).min(len);
        if i1 <= i0 + p {
            continue;
        }
        let period = tb - ta;
        g.fill(0.0);
        for r in rs.iter_mut() {
            r.fill(0.0);
        }
        ext.fill((f64::NEG_INFINITY, f64::INFINITY));
        for i in i0..i1 {
            let th = hermite_phase(ta, tb, sa, sb, i as f64);
            basis[0] = 1.0;
            // cos/sin of h theta by the angle-addition recurrence.
            let (s1, c1) = th.sin_cos();
            let (mut sh, mut ch) = (s1, c1);
            for h in 1..=n_harm {
                basis[2 * h - 1] = ch;
                basis[2 * h] = sh;
                (sh, ch) = (sh * c1 + ch * s1, ch * c1 - sh * s1);
            }
            // Whole rows (they vectorise; the upper triangle is not read):
            // each entry sums the same products in the same order.
            for (row, &ba) in g.chunks_exact_mut(p).zip(&basis) {
                for (gab, bb) in row.iter_mut().zip(&basis) {
                    *gab += ba * bb;
                }
            }
            for ((sig, r), (mx, mn)) in signals.iter().zip(rs.iter_mut()).zip(ext.iter_mut()) {
                let s = sig[i];
                for (ra, ba) in r.iter_mut().zip(&basis) {
                    *ra += ba * s;
                }
                *mx = mx.max(s);
                *mn = mn.min(s);
            }
        }
        let gm = DMatrix::<f64>::from_fn(
            p,
            p,
            |a, b| if b <= a { g[a * p + b] } else { g[b * p + a] },
        );
        let Some(ch) = gm.cholesky() else {
            continue;
        };
        for ((o, r), &(mx, mn)) in out.iter_mut().zip(&rs).zip(&ext) {
            let c = ch.solve(&DVector::from_column_slice(r));
            o.push(PeriodHarmonics {
                start: ta,
                end: tb,
                freq_hz: sample_rate_hz / period,
                dc: c[0],
                // a cos + b sin = Re((a - j b) e^{j theta})
                harmonics: (1..=n_harm)
                    .map(|h| Complex64::new(c[2 * h - 1], -c[2 * h]))
                    .collect(),
                max: mx,
                min: mn,
            });
        }
    }
    out
}

/// Resonance found as the interior maximum of `magnitude` (one value per
/// period, along the sweep). Returns the index and a sub-period position from
/// a parabola through the peak and its neighbours. None when the maximum sits
/// within `edge` periods of either end, or the curve does not fall by at least
/// `min_drop` (relative) on both sides: no resonance inside the sweep.
pub fn resonance_peak(magnitude: &[f64], edge: usize, min_drop: f64) -> Option<(usize, f64)> {
    let n = magnitude.len();
    if n < 2 * edge + 3 {
        return None;
    }
    let (imax, &vmax) = magnitude
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    if imax < edge || imax + edge >= n || vmax.is_nan() || vmax <= 0.0 {
        return None;
    }
    let left_min = magnitude[..imax]
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    let right_min = magnitude[imax + 1..]
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    if left_min > (1.0 - min_drop) * vmax || right_min > (1.0 - min_drop) * vmax {
        return None;
    }
    let (a, b, c) = (magnitude[imax - 1], vmax, magnitude[imax + 1]);
    let den = a - 2.0 * b + c;
    let off = if den < 0.0 {
        (0.5 * (a - c) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some((imax, imax as f64 + off))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn harmonics_of_a_known_signal_along_a_sweep() {
        // Linear sweep 30 -> 60 Hz at 6 kHz, x = dc + A1 cos + A2 cos(2.) + A3 sin(3.)
        let fs = 6000.0;
        let n = 30_000;
        let (f1, f2) = (30.0, 60.0);
        let dur = n as f64 / fs;
        let phase = |t: f64| 2.0 * PI * (f1 * t + 0.5 * (f2 - f1) / dur * t * t);
        let drive: Vec<f64> = (0..n).map(|i| phase(i as f64 / fs).sin()).collect();
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let ph = phase(i as f64 / fs) - 0.7;
                -0.3e-3 + 5e-3 * ph.cos() + 0.4e-3 * (2.0 * ph).cos() + 0.1e-3 * (3.0 * ph).sin()
            })
            .collect();
        let marks = period_marks(&drive, 0.1);
        // about 45 Hz * 5 s periods
        assert!((marks.len() as f64 - 225.0).abs() < 3.0, "{}", marks.len());
        let per = harmonics_per_period(&x, &marks, fs, 4);
        assert_eq!(per.len(), marks.len() - 1);
        for p in &per {
            let t = p.centre() / fs;
            let f_true = f1 + (f2 - f1) * t / dur;
            assert!(
                (p.freq_hz / f_true - 1.0).abs() < 2e-3,
                "{} {}",
                p.freq_hz,
                f_true
            );
            assert!((p.dc + 0.3e-3).abs() < 1e-7, "{}", p.dc);
            assert!((p.amplitude(1) / 5e-3 - 1.0).abs() < 1e-5);
            assert!((p.amplitude(2) / 0.4e-3 - 1.0).abs() < 1e-3);
            assert!((p.amplitude(3) / 0.1e-3 - 1.0).abs() < 3e-3);
            assert!(p.amplitude(4) < 1e-7);
        }
        let mag: Vec<f64> = per.iter().map(|p| p.amplitude(1)).collect();
        assert!(resonance_peak(&mag, 3, 0.1).is_none(), "flat: no resonance");
    }

    /// The walk over every sample (the marks before the blocks were passed
    /// over): the same marks, bit for bit.
    fn marks_by_walking(reference: &[f64], hysteresis: f64) -> Vec<f64> {
        let mut marks = Vec::new();
        let mut armed = false;
        for i in 1..reference.len() {
            let (a, b) = (reference[i - 1], reference[i]);
            if b < -hysteresis {
                armed = true;
            }
            if armed && a < 0.0 && b >= 0.0 {
                let frac = if b != a { -a / (b - a) } else { 0.0 };
                marks.push((i - 1) as f64 + frac);
                armed = false;
            }
        }
        marks
    }

    #[test]
    fn marks_equal_the_walk_over_every_sample() {
        let n = 50_000;
        // a sweep from slow to fast periods (block edges at every phase),
        // noise around zero that the hysteresis must ignore, exact zeros,
        // NaN and infinities, and records shorter than a block
        let sweep: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / n as f64;
                (2.0 * PI * (3.0 + 400.0 * t) * t * 20.0).sin()
            })
            .collect();
        let noisy: Vec<f64> = sweep
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.2 * (((i * 48271) % 1009) as f64 / 1009.0 - 0.5))
            .collect();
        let mut holes = sweep.clone();
        for i in (0..n).step_by(611) {
            holes[i] = [f64::NAN, 0.0, -0.0, f64::INFINITY, f64::NEG_INFINITY][i % 5];
        }
        let square: Vec<f64> = (0..n)
            .map(|i| if (i / 97) % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        for x in [&sweep, &noisy, &holes, &square] {
            for h in [0.0, 0.05, 0.5, 2.0] {
                for len in [0, 1, 2, 63, 64, 65, 130, n] {
                    let r = &x[..len];
                    let (a, b) = (period_marks(r, h), marks_by_walking(r, h));
                    assert_eq!(a.len(), b.len(), "h {h}, len {len}");
                    assert!(a.iter().zip(&b).all(|(u, v)| u.to_bits() == v.to_bits()));
                }
            }
        }
        assert!(period_marks(&sweep, 0.05).len() > 1000);
    }

    #[test]
    fn resonance_peak_interior_only() {
        let peak: Vec<f64> = (0..50)
            .map(|i| 1.0 / (1.0 + ((i as f64 - 20.3) / 4.0).powi(2)))
            .collect();
        let (i, pos) = resonance_peak(&peak, 3, 0.2).unwrap();
        assert_eq!(i, 20);
        assert!((pos - 20.3).abs() < 0.05, "{pos}");
        let rising: Vec<f64> = (0..50).map(|i| i as f64).collect();
        assert!(resonance_peak(&rising, 3, 0.2).is_none());
        assert!(resonance_peak(&[], 3, 0.2).is_none());
    }
}
