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
/// spikes) it keeps only the values below the lower rank and above the upper
/// one in two bounded heaps, in one pass: no copy of the record, no sort
/// (sorting 768 000 samples to read two of them was a fifth of an analysis,
/// issue 38). Its cost grows with the number of values that enter a heap:
/// about n for a record that keeps setting new extremes, a few times the
/// heap's size for an oscillation.
pub fn quantile_pair(x: &[f64], p_lo: f64, p_hi: f64, min_n: usize) -> Option<(f64, f64)> {
    let n = x.iter().filter(|v| v.is_finite()).count();
    if n < min_n.max(1) {
        return None;
    }
    let rank = |p: f64| (((n - 1) as f64 * p).round() as usize).min(n - 1);
    let (r_lo, r_hi) = (rank(p_lo), rank(p_hi));
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
