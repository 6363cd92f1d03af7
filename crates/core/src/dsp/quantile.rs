//! Order statistics of a record without sorting it.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// An `f64` ordered by [`f64::total_cmp`] (finite values only here).
#[derive(Debug, Clone, Copy)]
struct Total(f64);

impl PartialEq for Total {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Total {}
impl PartialOrd for Total {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Total {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The quantiles `p_lo` and `p_hi` (0 <= p_lo <= p_hi <= 1) of the finite
/// values of `x`, each the value at rank `round((n - 1) p)` of the values
/// sorted by [`f64::total_cmp`] (n: the number of finite values), exactly
/// as indexing the sorted copy would give; None when fewer than `min_n`
/// values are finite.
///
/// For quantiles near the ends (a signal's excursion without its noise
/// spikes) a sample of about 4 000 values sets two thresholds a little
/// inside each rank; one pass keeps the values beyond them (about 0.5 % of
/// the record), and the ranks are selected among those: no copy of the
/// record, no sort (sorting 792 000 samples to read two of them was a
/// fifth of an analysis, issue 38). When the sample misleads (a threshold
/// that leaves the rank outside what it kept, or keeps too much, as for a
/// central quantile), the values are streamed through two bounded heaps
/// instead; both ways give the same value.
pub fn quantile_pair(x: &[f64], p_lo: f64, p_hi: f64, min_n: usize) -> Option<(f64, f64)> {
    let n = x.iter().filter(|v| v.is_finite()).count();
    if n < min_n.max(1) {
        return None;
    }
    let rank = |p: f64| (((n - 1) as f64 * p).round() as usize).min(n - 1);
    let (r_lo, r_hi) = (rank(p_lo), rank(p_hi));
    by_thresholds(x, n, r_lo, r_hi).or_else(|| by_heaps(x, n, r_lo, r_hi))
}

/// Values drawn for the thresholds of [`by_thresholds`].
const SAMPLE: usize = 4096;

/// The values at ranks `r_lo` and `r_hi` (of `n` finite values) from the
/// values beyond two thresholds read off a sample; None when the sample's
/// thresholds do not hold the ranks or would keep more than n / 16 values.
fn by_thresholds(x: &[f64], n: usize, r_lo: usize, r_hi: usize) -> Option<(f64, f64)> {
    if n < 4 * SAMPLE {
        return None;
    }
    // A spread sample: one value from each of SAMPLE equal stretches, at a
    // position that varies from stretch to stretch (a fixed stride could
    // follow a periodic signal's phase).
    let stretch = x.len() / SAMPLE;
    let mut sample: Vec<f64> = (0..SAMPLE)
        .map(|j| x[j * stretch + (j.wrapping_mul(7919) % stretch)])
        .filter(|v| v.is_finite())
        .collect();
    if sample.len() < SAMPLE / 2 {
        return None;
    }
    sample.sort_unstable_by(f64::total_cmp);
    let m = sample.len() as f64;
    // Where each rank falls in the sample, moved outwards by four standard
    // deviations of that count and eight values: the threshold lies beyond
    // the rank unless the sample is very unlike the record.
    let below = |r: usize| {
        let e = m * (r + 1) as f64 / n as f64;
        (e + 4.0 * e.sqrt() + 8.0).ceil() as usize
    };
    let (j_lo, j_hi) = (below(r_lo), below(n - 1 - r_hi));
    if j_lo >= sample.len() || j_hi >= sample.len() {
        return None;
    }
    let t_lo = sample[j_lo];
    let t_hi = sample[sample.len() - 1 - j_hi];
    let cap = n / 16;
    let (mut low, mut high) = (
        Vec::with_capacity(2 * j_lo * n / SAMPLE),
        Vec::with_capacity(2 * j_hi * n / SAMPLE),
    );
    for block in x.chunks(64) {
        // A block whose values all lie strictly between the thresholds
        // (nearly every block of a record) keeps none of them: tested as a
        // whole, by comparisons that vectorise (a NaN fails both, and a
        // value equal to a threshold, -0.0 against 0.0 included, fails one,
        // so such blocks are walked value by value, as every block was).
        if block
            .iter()
            .fold(true, |inside, &v| inside & (v > t_lo) & (v < t_hi))
        {
            continue;
        }
        for &v in block {
            // Non-finite values are not counted; NaN and the infinities sort
            // beyond every finite threshold, so they are checked only here.
            if v.total_cmp(&t_lo) != Ordering::Greater && v.is_finite() {
                low.push(v);
            }
            if v.total_cmp(&t_hi) != Ordering::Less && v.is_finite() {
                high.push(v);
            }
            if low.len() > cap || high.len() > cap {
                return None;
            }
        }
    }
    // Every finite value at or below t_lo is in `low`, every other one is
    // above all of them: the rank r_lo of the record is the rank r_lo of
    // `low` when `low` reaches it. The same from the top for r_hi.
    let from_top = n - 1 - r_hi;
    if low.len() <= r_lo || high.len() <= from_top {
        return None;
    }
    let (_, lo, _) = low.select_nth_unstable_by(r_lo, f64::total_cmp);
    let (_, hi, _) = high.select_nth_unstable_by(from_top, |a, b| b.total_cmp(a));
    Some((*lo, *hi))
}

/// The values at ranks `r_lo` and `r_hi` (of `n` finite values) by two
/// bounded heaps in one pass: the values below the lower rank and above the
/// upper one. Its cost grows with the number of values that enter a heap:
/// about n for a record that keeps setting new extremes.
fn by_heaps(x: &[f64], n: usize, r_lo: usize, r_hi: usize) -> Option<(f64, f64)> {
    // The r_lo + 1 smallest values (a max-heap: its top is the answer) and
    // the n - r_hi largest (a min-heap through Reverse).
    let (k_lo, k_hi) = (r_lo + 1, n - r_hi);
    let mut low: BinaryHeap<Total> = BinaryHeap::with_capacity(k_lo);
    let mut high: BinaryHeap<std::cmp::Reverse<Total>> = BinaryHeap::with_capacity(k_hi);
    for &v in x.iter().filter(|v| v.is_finite()) {
        let t = Total(v);
        if low.len() < k_lo {
            low.push(t);
        } else if let Some(mut top) = low.peek_mut() {
            if t < *top {
                *top = t;
            }
        }
        if high.len() < k_hi {
            high.push(std::cmp::Reverse(t));
        } else if let Some(mut top) = high.peek_mut() {
            if t > top.0 {
                top.0 = t;
            }
        }
    }
    Some((low.peek()?.0, high.peek()?.0 .0))
}

/// The largest |x| of a record (0 for an empty one; NaN is passed over),
/// in four lanes so that the pass vectorises: the same value as a fold with
/// `f64::max`.
pub fn max_abs(x: &[f64]) -> f64 {
    let mut m = [0.0f64; 4];
    let chunks = x.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for i in 0..4 {
            let a = c[i].abs();
            m[i] = if a > m[i] { a } else { m[i] };
        }
    }
    m.into_iter()
        .chain(rest.iter().map(|v| v.abs()))
        .fold(0.0f64, f64::max)
}

#[cfg(test)]
mod tests {
    use super::quantile_pair;

    /// What the analysis computed before: sort the finite values, index.
    fn by_sorting(x: &[f64], p_lo: f64, p_hi: f64) -> (f64, f64) {
        let mut xs: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
        xs.sort_by(f64::total_cmp);
        let q = |p: f64| xs[((xs.len() - 1) as f64 * p).round() as usize];
        (q(p_lo), q(p_hi))
    }

    #[test]
    fn equals_the_sorted_copy_on_oscillations_ramps_and_ties() {
        let n = 20_000;
        let sweep: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / n as f64;
                (1.0 + 3.0 * t) * (40.0 * t * t * 6.0).sin() + 1e-3 * ((i * 7919) % 13) as f64
            })
            .collect();
        let falling: Vec<f64> = (0..n).map(|i| -(i as f64)).collect();
        let rising: Vec<f64> = (0..n).map(|i| i as f64 * 0.5).collect();
        let ties: Vec<f64> = (0..n).map(|i| ((i * 31) % 5) as f64 - 2.0).collect();
        let mut holes = sweep.clone();
        for i in (0..n).step_by(97) {
            holes[i] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][i % 3];
        }
        // -0.0 and 0.0 differ under total_cmp, as in the sort.
        let zeros: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 0.0 } else { -0.0 })
            .collect();
        for x in [&sweep, &falling, &rising, &ties, &holes, &zeros] {
            for (lo, hi) in [(0.001, 0.999), (0.0, 1.0), (0.25, 0.75), (0.5, 0.5)] {
                let (a, b) = quantile_pair(x, lo, hi, 1000).unwrap();
                let (c, d) = by_sorting(x, lo, hi);
                assert_eq!((a.to_bits(), b.to_bits()), (c.to_bits(), d.to_bits()));
            }
        }
        // Known values: the ramp 0, -1, ..., -19999 at ranks 20 and 19979.
        assert_eq!(
            quantile_pair(&falling, 0.001, 0.999, 1000),
            Some((-19979.0, -20.0))
        );
    }

    /// Records long enough for the thresholds (a sweep that grows, noise
    /// with spikes, a constant, a periodic signal whose period divides the
    /// sample's stretch): the value the sort gives, bit for bit, whichever
    /// of the two ways found it.
    #[test]
    fn long_records_equal_the_sorted_copy() {
        let n = 200_000;
        let growing: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / n as f64;
                t * (900.0 * t * t).sin() + 1e-4 * ((i * 7919) % 17) as f64
            })
            .collect();
        let mut spikes: Vec<f64> = (0..n)
            .map(|i| 1e-3 * (((i * 48271) % 2003) as f64 - 1001.0))
            .collect();
        for i in (0..n).step_by(5003) {
            spikes[i] = if i % 2 == 0 { 5.0 } else { -5.0 };
            spikes[i + 1] = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][i % 3];
        }
        let constant = vec![0.25; n];
        let stretch = n / super::SAMPLE;
        let periodic: Vec<f64> = (0..n)
            .map(|i| ((i % stretch) as f64 * 0.37).sin())
            .collect();
        // The thresholds hold the end ranks of the sweep and of the noise
        // (the fast way is taken there); a constant keeps too much.
        let ends = |x: &[f64]| {
            let n = x.iter().filter(|v| v.is_finite()).count();
            let r = |p: f64| ((n - 1) as f64 * p).round() as usize;
            super::by_thresholds(x, n, r(0.001), r(0.999))
        };
        assert!(ends(&growing).is_some() && ends(&spikes).is_some());
        assert_eq!(ends(&constant), None);
        for x in [&growing, &spikes, &constant, &periodic] {
            for (lo, hi) in [(0.001, 0.999), (0.0, 1.0), (0.01, 0.95), (0.5, 0.5)] {
                let (a, b) = quantile_pair(x, lo, hi, 1000).unwrap();
                let (c, d) = by_sorting(x, lo, hi);
                assert_eq!((a.to_bits(), b.to_bits()), (c.to_bits(), d.to_bits()));
            }
        }
    }

    #[test]
    fn max_abs_is_the_fold() {
        let x: Vec<f64> = (0..1003).map(|i| ((i * 37) % 101) as f64 - 60.5).collect();
        assert_eq!(super::max_abs(&x), 60.5);
        assert_eq!(super::max_abs(&x[..3]), 60.5);
        assert_eq!(super::max_abs(&[]), 0.0);
        assert_eq!(super::max_abs(&[f64::NAN, -2.0]), 2.0);
    }

    #[test]
    fn too_few_finite_values_give_none() {
        let x = vec![f64::NAN; 5000];
        assert_eq!(quantile_pair(&x, 0.001, 0.999, 1000), None);
        assert_eq!(quantile_pair(&[1.0; 999], 0.001, 0.999, 1000), None);
        assert_eq!(
            quantile_pair(&[1.0; 1000], 0.0, 1.0, 1000),
            Some((1.0, 1.0))
        );
    }
}
