//! The laser samples on a dense device-index grid, short gaps bridged.

use super::line::Map;
use crate::laser::LaserSample;

/// The laser samples on a dense index grid, short gaps bridged.
#[derive(Debug, Clone)]
pub(super) struct Dense {
    pub(super) n0: u64,
    pub(super) x: Vec<f64>,
    pub(super) dropped: u64,
    /// First gap longer than allowed: (index, length).
    pub(super) long_gap: Option<(u64, u64)>,
}

impl Dense {
    /// Samples with index in [n_lo, n_hi] (plus one either side).
    pub(super) fn new(
        samples: &[LaserSample],
        n_lo: f64,
        n_hi: f64,
        max_gap: u64,
    ) -> Result<Dense, String> {
        let lo = n_lo.max(0.0) as u64;
        let hi = if n_hi.is_finite() && n_hi >= 0.0 {
            n_hi as u64
        } else {
            0
        };
        let first = samples.partition_point(|s| s.index < lo).saturating_sub(1);
        let last = samples
            .partition_point(|s| s.index <= hi)
            .min(samples.len());
        let sel = &samples[first..last.max(first)];
        let sel: Vec<&LaserSample> = {
            let mut v: Vec<&LaserSample> = Vec::with_capacity(sel.len());
            for s in sel {
                if s.displacement_m.is_finite() && v.last().is_none_or(|l| s.index > l.index) {
                    v.push(s);
                }
            }
            v
        };
        let (Some(f), Some(l)) = (sel.first(), sel.last()) else {
            return Err("no laser samples during the sweep".into());
        };
        let span = l.index - f.index + 1;
        if span > 50_000_000 {
            return Err(format!("laser indices span {span} samples: counter jump"));
        }
        let mut x = Vec::with_capacity(span as usize);
        let mut dropped = 0;
        let mut long_gap = None;
        for w in sel.windows(2) {
            let (a, b) = (w[0], w[1]);
            x.push(a.displacement_m);
            let gap = b.index - a.index - 1;
            if gap > 0 {
                dropped += gap;
                if gap > max_gap && long_gap.is_none() {
                    long_gap = Some((a.index + 1, gap));
                }
                for i in 1..=gap {
                    let u = i as f64 / (gap + 1) as f64;
                    x.push(a.displacement_m + u * (b.displacement_m - a.displacement_m));
                }
            }
        }
        x.push(l.displacement_m);
        Ok(Dense {
            n0: f.index,
            x,
            dropped,
            long_gap,
        })
    }
    pub(super) fn n_first(&self) -> f64 {
        self.n0 as f64
    }
    pub(super) fn n_last(&self) -> f64 {
        (self.n0 + self.x.len() as u64 - 1) as f64
    }
}

pub(super) fn coverage_fraction(d: &Dense, map: Map, t0: f64, t1: f64) -> f64 {
    let (a, b) = (map.n_of(t0), map.n_of(t1));
    if b.is_nan() || a.is_nan() || b <= a {
        return 0.0;
    }
    let lo = a.max(d.n_first());
    let hi = b.min(d.n_last());
    ((hi - lo) / (b - a)).clamp(0.0, 1.0)
}
