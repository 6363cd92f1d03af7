//! Linear least squares in contiguous time blocks.
//!
//! The design is kept as per-block cross products (`X_b^T X_b`, `X_b^T y_b`,
//! `y_b^T y_b`), so that the full fit, the blocked cross-validation (folds are
//! runs of contiguous blocks) and the batch-means (block) covariance of the
//! coefficients all come from the same small matrices without touching the
//! samples again. Candidate columns are added by computing only their cross
//! products with the columns already there.

use nalgebra::{DMatrix, DVector};

/// Dot product of two equal-length slices (four accumulators, so it vectorises).
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut out = [0.0];
    dots(a, &[b], &mut out);
    out[0]
}

/// `out[j] = dot(z, others[j])` for every j, bit for bit: each product sum
/// runs in four lanes (`lane k` sums the products `4 i + k` in order),
/// reduced as `(s0 + s1) + (s2 + s3) + tail`. One pass over `z` serves up to
/// four columns at a time: their sums are independent chains, so the loop is
/// bound by throughput, not by the latency of one chain of additions.
pub fn dots(z: &[f64], others: &[&[f64]], out: &mut [f64]) {
    assert_eq!(others.len(), out.len(), "one output per column");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        for (o, r) in others.chunks(4).zip(out.chunks_mut(4)) {
            if o.iter().any(|c| c.len() != z.len()) {
                dots_scalar(z, o, r);
                continue;
            }
            // SAFETY: AVX is present (checked above); every column has z's length.
            unsafe {
                match o.len() {
                    1 => dots_avx::<1>(z, o, r),
                    2 => dots_avx::<2>(z, o, r),
                    3 => dots_avx::<3>(z, o, r),
                    _ => dots_avx::<4>(z, o, r),
                }
            }
        }
        return;
    }
    dots_scalar(z, others, out);
}

/// Lane sums and the tail of one product sum, reduced in the documented order.
fn reduce(s: [f64; 4], z: &[f64], c: &[f64], from: usize, n: usize) -> f64 {
    let mut tail = 0.0;
    for i in from..n {
        tail += z[i] * c[i];
    }
    (s[0] + s[1]) + (s[2] + s[3]) + tail
}

fn dots_scalar(z: &[f64], others: &[&[f64]], out: &mut [f64]) {
    for (c, o) in others.iter().zip(out.iter_mut()) {
        let n = z.len().min(c.len());
        let mut s = [0.0f64; 4];
        for i in (0..n / 4).map(|k| 4 * k) {
            for (l, sl) in s.iter_mut().enumerate() {
                *sl += z[i + l] * c[i + l];
            }
        }
        *o = reduce(s, z, c, 4 * (n / 4), n);
    }
}

/// `K` product sums in one pass, the four lanes of each in one AVX register
/// (multiply, then add: no fused multiply-add, so the rounding is the
/// scalar code's). Every column has the length of `z`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn dots_avx<const K: usize>(z: &[f64], others: &[&[f64]], out: &mut [f64]) {
    use std::arch::x86_64::*;
    let n = z.len();
    let chunks = n / 4;
    let zp = z.as_ptr();
    let cp: [*const f64; K] = std::array::from_fn(|j| others[j].as_ptr());
    let mut acc = [_mm256_setzero_pd(); K];
    for q in 0..chunks {
        let i = 4 * q;
        // SAFETY: i + 3 < n, the length of z and of every column.
        let zv = _mm256_loadu_pd(zp.add(i));
        for j in 0..K {
            let cv = _mm256_loadu_pd(cp[j].add(i));
            acc[j] = _mm256_add_pd(acc[j], _mm256_mul_pd(zv, cv));
        }
    }
    for j in 0..K {
        let mut s = [0.0f64; 4];
        _mm256_storeu_pd(s.as_mut_ptr(), acc[j]);
        out[j] = reduce(s, z, others[j], 4 * chunks, n);
    }
}

/// The hysteresis regressor at yield excursion `x_yield_m`: the Bouc-Wen
/// state z along the measured path (`physics::memory::hysteresis_step`,
/// the simulation's own law), starting relaxed (z = 0). Its coefficient is
/// minus the element's stiffness.
pub fn hysteresis_column(x: &[f64], x_yield_m: f64) -> Vec<f64> {
    use crate::physics::memory::hysteresis_step;
    let mut z = 0.0;
    let mut xp = x.first().copied().unwrap_or(0.0);
    x.iter()
        .map(|&xi| {
            z = hysteresis_step(z, xi - xp, x_yield_m);
            xp = xi;
            z
        })
        .collect()
}

/// The reversible-softening regressor at recovery time `tau_s`:
/// `s x max(0, 1 - x^2/s^2)` (sign: a softening force) with `s` the peak
/// envelope of the measured x (`physics::memory::envelope_step`), started at
/// |x[0]|. Its coefficient is minus the depth (N/m per m of envelope).
pub fn softening_column(x: &[f64], fs: f64, tau_s: f64) -> Vec<f64> {
    use crate::physics::memory::{envelope_decay, envelope_step, softening_force};
    let decay = envelope_decay(1.0 / fs, tau_s);
    let mut s = 0.0;
    x.iter()
        .map(|&xi| {
            s = envelope_step(s, xi, decay);
            softening_force(1.0, s, xi)
        })
        .collect()
}

/// Cross products of one block.
#[derive(Debug, Clone)]
pub struct Block {
    pub g: DMatrix<f64>,
    pub c: DVector<f64>,
    pub yy: f64,
    pub n: usize,
}

/// Cross products of a design, per contiguous block of samples.
#[derive(Debug, Clone)]
pub struct BlockGram {
    pub p: usize,
    pub blocks: Vec<Block>,
}

/// Result of a least-squares fit.
#[derive(Debug, Clone)]
pub struct Fit {
    pub beta: DVector<f64>,
    /// Residual sum of squares over all samples.
    pub sse: f64,
    pub n: usize,
}

/// Splits `n` samples into `count` contiguous blocks (start, end).
pub fn block_bounds(n: usize, count: usize) -> Vec<(usize, usize)> {
    let count = count.clamp(1, n.max(1));
    (0..count)
        .map(|b| (b * n / count, (b + 1) * n / count))
        .collect()
}

impl BlockGram {
    /// Builds the block cross products of `cols` against `y`.
    pub fn build(cols: &[&[f64]], y: &[f64], bounds: &[(usize, usize)]) -> BlockGram {
        let p = cols.len();
        let mut buf = vec![0.0; p + 1];
        let blocks = bounds
            .iter()
            .map(|&(s, e)| {
                let mut g = DMatrix::zeros(p, p);
                let mut c = DVector::zeros(p);
                for i in 0..p {
                    // Column i against columns i..p and y in one pass.
                    let mut rest: Vec<&[f64]> = cols[i..].iter().map(|col| &col[s..e]).collect();
                    rest.push(&y[s..e]);
                    let out = &mut buf[..rest.len()];
                    dots(&cols[i][s..e], &rest, out);
                    for (k, &v) in out[..p - i].iter().enumerate() {
                        g[(i, i + k)] = v;
                        g[(i + k, i)] = v;
                    }
                    c[i] = out[p - i];
                }
                Block {
                    g,
                    c,
                    yy: dot(&y[s..e], &y[s..e]),
                    n: e - s,
                }
            })
            .collect();
        BlockGram { p, blocks }
    }

    /// The design with column `drop` removed (if any) and `new_cols` appended
    /// at the end. `base_cols` are the columns this Gram was built from.
    pub fn augment(
        &self,
        base_cols: &[&[f64]],
        drop: Option<usize>,
        new_cols: &[&[f64]],
        y: &[f64],
        bounds: &[(usize, usize)],
    ) -> BlockGram {
        let keep: Vec<usize> = (0..self.p).filter(|&i| Some(i) != drop).collect();
        let pk = keep.len();
        let q = new_cols.len();
        let p = pk + q;
        let blocks = self
            .blocks
            .iter()
            .zip(bounds)
            .map(|(blk, &(s, e))| {
                let mut g = DMatrix::zeros(p, p);
                let mut c = DVector::zeros(p);
                for (a, &i) in keep.iter().enumerate() {
                    for (b, &j) in keep.iter().enumerate() {
                        g[(a, b)] = blk.g[(i, j)];
                    }
                    c[a] = blk.c[i];
                }
                for (u, z) in new_cols.iter().enumerate() {
                    // The new column against the kept ones, the new ones
                    // from itself on, and y, in one pass.
                    let zi = pk + u;
                    let mut other: Vec<&[f64]> =
                        keep.iter().map(|&i| &base_cols[i][s..e]).collect();
                    other.extend(new_cols[u..].iter().map(|z2| &z2[s..e]));
                    other.push(&y[s..e]);
                    let mut out = vec![0.0; other.len()];
                    dots(&z[s..e], &other, &mut out);
                    for (a, &v) in out[..pk].iter().enumerate() {
                        g[(zi, a)] = v;
                        g[(a, zi)] = v;
                    }
                    for (w, &v) in out[pk..pk + q - u].iter().enumerate() {
                        g[(zi, zi + w)] = v;
                        g[(zi + w, zi)] = v;
                    }
                    c[zi] = out[pk + q - u];
                }
                Block {
                    g,
                    c,
                    yy: blk.yy,
                    n: blk.n,
                }
            })
            .collect();
        BlockGram { p, blocks }
    }

    /// Sum over a set of blocks.
    fn sum(&self, which: impl Iterator<Item = usize>) -> Block {
        let mut g = DMatrix::zeros(self.p, self.p);
        let mut c = DVector::zeros(self.p);
        let mut yy = 0.0;
        let mut n = 0;
        for b in which {
            let blk = &self.blocks[b];
            g += &blk.g;
            c += &blk.c;
            yy += blk.yy;
            n += blk.n;
        }
        Block { g, c, yy, n }
    }

    pub fn total(&self) -> Block {
        self.sum(0..self.blocks.len())
    }

    /// Least-squares fit on all blocks.
    pub fn fit(&self) -> Fit {
        let t = self.total();
        let beta = solve_spd(&t.g, &t.c);
        let sse = (t.yy - 2.0 * beta.dot(&t.c) + (&t.g * &beta).dot(&beta)).max(0.0);
        Fit { beta, sse, n: t.n }
    }

    /// Held-out sum of squared errors of blocked cross-validation with
    /// `folds` contiguous folds (each a run of neighbouring blocks).
    pub fn cv_sse(&self, folds: usize) -> f64 {
        self.cv_sse_folds(folds).iter().sum()
    }

    /// The held-out sum of squared errors of each fold of [`Self::cv_sse`].
    pub fn cv_sse_folds(&self, folds: usize) -> Vec<f64> {
        let nb = self.blocks.len();
        let folds = folds.clamp(2, nb.max(2));
        let total = self.total();
        (0..folds)
            .map(|f| {
                let (s, e) = (f * nb / folds, (f + 1) * nb / folds);
                let test = self.sum(s..e);
                let g = &total.g - &test.g;
                let c = &total.c - &test.c;
                let beta = solve_spd(&g, &c);
                (test.yy - 2.0 * beta.dot(&test.c) + (&test.g * &beta).dot(&beta)).max(0.0)
            })
            .collect()
    }

    /// Batch-means (block) covariance of the coefficients at `beta`:
    /// `G^-1 (sum_b s_b s_b^T) G^-1 * B/(B-1)` with the block scores
    /// `s_b = X_b^T e_b`. Valid for residuals correlated over times shorter
    /// than a block; it does not assume independent samples.
    pub fn block_covariance(&self, beta: &DVector<f64>) -> DMatrix<f64> {
        let t = self.total();
        let mut s = DMatrix::zeros(self.p, self.p);
        for blk in &self.blocks {
            let sb = &blk.c - &blk.g * beta;
            s += &sb * sb.transpose();
        }
        let nb = self.blocks.len() as f64;
        if nb > 1.0 {
            s *= nb / (nb - 1.0);
        }
        let gi = inverse_spd(&t.g);
        &gi * s * &gi
    }
}

/// Solves the symmetric positive (semi)definite system `g x = c`, with
/// diagonal scaling; falls back to a pseudo-inverse when Cholesky fails.
/// Columns with a zero diagonal get a zero coefficient.
pub fn solve_spd(g: &DMatrix<f64>, c: &DVector<f64>) -> DVector<f64> {
    let inv = inverse_spd(g);
    &inv * c
}

/// (Pseudo-)inverse of a symmetric positive semidefinite matrix, with diagonal scaling.
pub fn inverse_spd(g: &DMatrix<f64>) -> DMatrix<f64> {
    let p = g.nrows();
    let d: Vec<f64> = (0..p)
        .map(|i| {
            let v = g[(i, i)];
            if v > 0.0 && v.is_finite() {
                1.0 / v.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let mut gs = g.clone();
    for i in 0..p {
        for j in 0..p {
            gs[(i, j)] *= d[i] * d[j];
        }
    }
    for i in 0..p {
        if d[i] == 0.0 {
            gs[(i, i)] = 1.0;
        }
    }
    let inv_s = match nalgebra::Cholesky::new(gs.clone()) {
        Some(ch) => ch.inverse(),
        None => {
            let eig = nalgebra::SymmetricEigen::new(gs);
            let max = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
            let mut inv = DMatrix::zeros(p, p);
            for k in 0..p {
                let l = eig.eigenvalues[k];
                if l > max * 1e-13 {
                    let v = eig.eigenvectors.column(k);
                    inv += (v * v.transpose()) / l;
                }
            }
            inv
        }
    };
    let mut inv = inv_s;
    for i in 0..p {
        for j in 0..p {
            inv[(i, j)] *= d[i] * d[j];
        }
    }
    inv
}

/// R^2 of column `j` explained by the other columns of the (total) Gram
/// matrix `g`; centred when `intercept` names the column of ones among
/// `others`. Variance inflation factor = 1 / (1 - R^2).
pub fn collinearity_r2(
    g: &DMatrix<f64>,
    j: usize,
    others: &[usize],
    intercept: Option<usize>,
) -> f64 {
    if others.is_empty() || g[(j, j)] <= 0.0 {
        return 0.0;
    }
    let k = others.len();
    let mut go = DMatrix::zeros(k, k);
    let mut co = DVector::zeros(k);
    for (a, &i) in others.iter().enumerate() {
        for (b, &l) in others.iter().enumerate() {
            go[(a, b)] = g[(i, l)];
        }
        co[a] = g[(i, j)];
    }
    let beta = solve_spd(&go, &co);
    let explained = beta.dot(&co);
    let mean_part = match intercept {
        Some(k) if g[(k, k)] > 0.0 => g[(j, k)] * g[(j, k)] / g[(k, k)],
        _ => 0.0,
    };
    let total = g[(j, j)] - mean_part;
    if total <= 0.0 {
        return 1.0;
    }
    ((explained - mean_part) / total).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dots_match_the_four_lane_scalar_sum_bit_for_bit() {
        let col = |k: usize, n: usize| -> Vec<f64> {
            (0..n)
                .map(|i| ((i * 7919 + k * 104_729) % 1013) as f64 / 97.0 - 5.0 + 1e-9 * i as f64)
                .collect()
        };
        for n in [0, 1, 3, 4, 5, 17, 730, 733] {
            let z = col(0, n);
            let cols: Vec<Vec<f64>> = (1..=7).map(|k| col(k, n)).collect();
            for k in 1..=cols.len() {
                let refs: Vec<&[f64]> = cols[..k].iter().map(|c| c.as_slice()).collect();
                let mut fast = vec![0.0; k];
                let mut slow = vec![0.0; k];
                dots(&z, &refs, &mut fast);
                dots_scalar(&z, &refs, &mut slow);
                for j in 0..k {
                    assert_eq!(fast[j].to_bits(), slow[j].to_bits(), "n {n} k {k} j {j}");
                    assert_eq!(fast[j].to_bits(), dot(refs[j], &z).to_bits());
                }
            }
        }
    }

    #[test]
    fn fit_cv_and_covariance_match_direct_computation() {
        // y = 2 + 3 t - 0.5 t^2 + tiny deterministic "noise".
        let n = 1000;
        let t: Vec<f64> = (0..n).map(|i| i as f64 / n as f64).collect();
        let one = vec![1.0; n];
        let t2: Vec<f64> = t.iter().map(|v| v * v).collect();
        let y: Vec<f64> = (0..n)
            .map(|i| 2.0 + 3.0 * t[i] - 0.5 * t2[i] + 1e-3 * ((i * 7919 % 13) as f64 - 6.0))
            .collect();
        let bounds = block_bounds(n, 10);
        let bg = BlockGram::build(&[&one, &t], &y, &bounds);
        let full = bg.augment(&[&one, &t], None, &[&t2], &y, &bounds);
        let direct = BlockGram::build(&[&one, &t, &t2], &y, &bounds);
        let (f1, f2) = (full.fit(), direct.fit());
        assert!((f1.beta[0] - 2.0).abs() < 1e-3);
        assert!((f1.beta[1] - 3.0).abs() < 1e-2);
        assert!((f1.beta[2] + 0.5).abs() < 1e-2);
        assert!((f1.sse - f2.sse).abs() < 1e-12);
        // SSE equals the sum of squared residuals computed sample by sample.
        let sse: f64 = (0..n)
            .map(|i| {
                let e = y[i] - f2.beta[0] - f2.beta[1] * t[i] - f2.beta[2] * t2[i];
                e * e
            })
            .sum();
        assert!((sse - f2.sse).abs() < 1e-9 * sse.max(1e-12) + 1e-12);
        // Held-out error is larger than in-sample error, and the missing t^2
        // term costs on held-out data.
        assert!(full.cv_sse(5) > f1.sse);
        assert!(bg.cv_sse(5) > full.cv_sse(5));
        // Dropping a column: drop t^2 again gives back the base fit.
        let back = full.augment(&[&one, &t, &t2], Some(2), &[], &y, &bounds);
        assert!((back.fit().sse - bg.fit().sse).abs() < 1e-9);
        let cov = full.block_covariance(&f1.beta);
        assert!(cov[(2, 2)] > 0.0 && cov[(2, 2)].sqrt() < 0.01);
        // t^2 on [0, 1] is collinear with (1, t): centred R^2 = 15/16.
        let g = direct.total().g;
        let r2 = collinearity_r2(&g, 2, &[0, 1], Some(0));
        assert!((r2 - 0.9375).abs() < 2e-3, "{r2}");
    }
}
