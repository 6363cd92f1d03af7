//! Linear least squares on well-scaled columns (normal equations + Cholesky,
//! one step of iterative refinement), with standard errors and residual.

use nalgebra::{DMatrix, DVector};

/// Result of [`lstsq`].
#[derive(Debug, Clone, PartialEq)]
pub struct Lstsq {
    /// Fitted coefficients, one per column, in the units of the columns given.
    pub coefficients: Vec<f64>,
    /// Standard errors of the coefficients (from the residual variance; the
    /// samples are taken as independent).
    pub standard_errors: Vec<f64>,
    /// Covariance of the coefficients, row-major p x p.
    pub covariance: Vec<f64>,
    /// Residual `y - A c` (same length as `y`).
    pub residual: Vec<f64>,
    /// Sum of squared residuals.
    pub rss: f64,
    /// Degrees of freedom (rows - columns).
    pub dof: usize,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LstsqError {
    #[error("least squares: {0}")]
    Shape(String),
    #[error("least squares: the columns are linearly dependent (or zero)")]
    RankDeficient,
    #[error("least squares: non-finite input")]
    NonFinite,
}

/// Solves `min |y - sum_j c_j columns[j]|^2`.
///
/// Each column is scaled to unit norm before the normal equations are formed,
/// so columns of very different magnitude (x in m next to x^5) are fine as long
/// as they are not nearly collinear after scaling (use x/xmax powers, not raw
/// powers on [0, 1] of high degree).
pub fn lstsq(columns: &[&[f64]], y: &[f64]) -> Result<Lstsq, LstsqError> {
    let p = columns.len();
    let n = y.len();
    check_shape(columns, y)?;
    let scale = column_scales(columns)?;
    let mut g = DMatrix::<f64>::zeros(p, p);
    for i in 0..p {
        for j in 0..=i {
            let s = dot(columns[i], columns[j]) * scale[i] * scale[j];
            g[(i, j)] = s;
            g[(j, i)] = s;
        }
    }
    let chol = g.clone().cholesky().ok_or(LstsqError::RankDeficient)?;
    // Reject near-singular systems: the smallest pivot relative to the largest.
    let l = chol.l_dirty();
    let (mut dmin, mut dmax) = (f64::INFINITY, 0.0f64);
    for i in 0..p {
        dmin = dmin.min(l[(i, i)].abs());
        dmax = dmax.max(l[(i, i)].abs());
    }
    if dmin.is_nan() || dmin <= 1e-7 * dmax {
        return Err(LstsqError::RankDeficient);
    }
    let rhs = |r: &[f64]| DVector::from_iterator(p, (0..p).map(|j| dot(columns[j], r) * scale[j]));
    let mut c = chol.solve(&rhs(y));
    let mut residual = vec![0.0; n];
    let compute_residual = |c: &DVector<f64>, res: &mut [f64]| {
        res.copy_from_slice(y);
        for j in 0..p {
            let cj = c[j] * scale[j];
            for (r, a) in res.iter_mut().zip(columns[j]) {
                *r -= cj * a;
            }
        }
    };
    compute_residual(&c, &mut residual);
    // One step of iterative refinement.
    let dc = chol.solve(&rhs(&residual));
    c += dc;
    compute_residual(&c, &mut residual);
    let rss: f64 = residual.iter().map(|r| r * r).sum();
    let dof = n - p;
    let sigma2 = rss / dof as f64;
    let ginv = chol.inverse();
    let mut covariance = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            covariance[i * p + j] = ginv[(i, j)] * sigma2 * scale[i] * scale[j];
        }
    }
    let coefficients: Vec<f64> = (0..p).map(|j| c[j] * scale[j]).collect();
    let standard_errors = (0..p)
        .map(|j| covariance[j * p + j].max(0.0).sqrt())
        .collect();
    Ok(Lstsq {
        coefficients,
        standard_errors,
        covariance,
        residual,
        rss,
        dof,
    })
}

fn check_shape(columns: &[&[f64]], y: &[f64]) -> Result<(), LstsqError> {
    let (p, n) = (columns.len(), y.len());
    if p == 0 {
        return Err(LstsqError::Shape("no columns".into()));
    }
    if columns.iter().any(|c| c.len() != n) {
        return Err(LstsqError::Shape("columns and y differ in length".into()));
    }
    if n <= p {
        return Err(LstsqError::Shape(format!(
            "{n} rows are too few for {p} unknowns"
        )));
    }
    if !all_finite(y) || !columns.iter().all(|c| all_finite(c)) {
        return Err(LstsqError::NonFinite);
    }
    Ok(())
}

/// Every value finite: blocks without an early exit, so that the test
/// vectorises (the small-signal fit's ~60 least squares of ~4 000 rows
/// checked value by value cost 8 M instructions).
fn all_finite(x: &[f64]) -> bool {
    x.chunks(256)
        .all(|b| b.iter().fold(true, |ok, v| ok & v.is_finite()))
}

/// 1 / norm of each column (RankDeficient for a zero column).
fn column_scales(columns: &[&[f64]]) -> Result<Vec<f64>, LstsqError> {
    columns
        .iter()
        .map(|c| {
            let s = dot(c, c).sqrt();
            if s > 0.0 {
                Ok(1.0 / s)
            } else {
                Err(LstsqError::RankDeficient)
            }
        })
        .collect()
}

/// Least squares of nested models by one Householder QR: the model with the
/// first `p` columns, for every `p`, from one factorisation (the order search
/// of a polynomial). QR keeps the accuracy that normal equations lose on
/// nearly collinear columns (e.g. powers of x after removing the fundamental).
#[derive(Debug, Clone)]
pub struct NestedLstsq {
    n: usize,
    scale: Vec<f64>,
    r: DMatrix<f64>,
    /// Q^T y (length n).
    qty: DVector<f64>,
}

impl NestedLstsq {
    pub fn new(columns: &[&[f64]], y: &[f64]) -> Result<NestedLstsq, LstsqError> {
        let p = columns.len();
        let n = y.len();
        check_shape(columns, y)?;
        let scale = column_scales(columns)?;
        let a = DMatrix::<f64>::from_fn(n, p, |i, j| columns[j][i] * scale[j]);
        let qr = a.qr();
        let mut qty = DVector::<f64>::from_column_slice(y);
        qr.q_tr_mul(&mut qty);
        let r = qr.r();
        Ok(NestedLstsq { n, scale, r, qty })
    }

    /// [`NestedLstsq::new`] of columns and a target the caller gives away:
    /// the same factorisation, bit for bit, with each column freed as soon
    /// as it is copied into the matrix and the target taken as `Q^T y`'s
    /// buffer, so that the design and its matrix are not held twice (the
    /// K(x) fit's whitened design: ~5 MB for a 10 s main sweep).
    pub fn from_columns(columns: Vec<Vec<f64>>, y: Vec<f64>) -> Result<NestedLstsq, LstsqError> {
        let p = columns.len();
        let n = y.len();
        let scale = {
            let refs: Vec<&[f64]> = columns.iter().map(|c| c.as_slice()).collect();
            check_shape(&refs, &y)?;
            column_scales(&refs)?
        };
        let mut data = Vec::with_capacity(n * p);
        for (c, s) in columns.into_iter().zip(&scale) {
            data.extend(c.iter().map(|v| v * s));
        }
        let qr = DMatrix::<f64>::from_vec(n, p, data).qr();
        let mut qty = DVector::<f64>::from_vec(y);
        qr.q_tr_mul(&mut qty);
        let r = qr.r();
        Ok(NestedLstsq { n, scale, r, qty })
    }

    /// Number of columns.
    pub fn columns(&self) -> usize {
        self.scale.len()
    }

    /// Residual sum of squares of the model with the first `p` columns.
    pub fn rss(&self, p: usize) -> f64 {
        self.qty.rows(p, self.n - p).norm_squared()
    }

    /// Coefficients and standard errors of the model with the first `p` columns.
    pub fn solve(&self, p: usize) -> Result<(Vec<f64>, Vec<f64>), LstsqError> {
        if p == 0 || p > self.columns() || p >= self.n {
            return Err(LstsqError::Shape(format!(
                "{p} columns out of {}",
                self.columns()
            )));
        }
        let r = self.r.view((0, 0), (p, p)).into_owned();
        let (mut dmin, mut dmax) = (f64::INFINITY, 0.0f64);
        for i in 0..p {
            dmin = dmin.min(r[(i, i)].abs());
            dmax = dmax.max(r[(i, i)].abs());
        }
        if dmin.is_nan() || dmin <= 1e-12 * dmax {
            return Err(LstsqError::RankDeficient);
        }
        let c = r
            .solve_upper_triangular(&self.qty.rows(0, p).into_owned())
            .ok_or(LstsqError::RankDeficient)?;
        let rinv = r
            .solve_upper_triangular(&DMatrix::<f64>::identity(p, p))
            .ok_or(LstsqError::RankDeficient)?;
        let sigma = (self.rss(p) / (self.n - p) as f64).sqrt();
        let coef = (0..p).map(|j| c[j] * self.scale[j]).collect();
        let se = (0..p)
            .map(|j| sigma * rinv.row(j).norm() * self.scale[j])
            .collect();
        Ok((coef, se))
    }
}

pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four accumulators: faster and slightly more accurate than one.
    let mut s = [0.0f64; 4];
    let n4 = a.len() / 4 * 4;
    for k in (0..n4).step_by(4) {
        s[0] += a[k] * b[k];
        s[1] += a[k + 1] * b[k + 1];
        s[2] += a[k + 2] * b[k + 2];
        s[3] += a[k + 3] * b[k + 3];
    }
    let mut t = (s[0] + s[1]) + (s[2] + s[3]);
    for k in n4..a.len() {
        t += a[k] * b[k];
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_polynomial_with_badly_scaled_columns() {
        // y = 3 + 2e3 x - 5e7 x^3 with x in +-10 mm: columns differ by 1e6 in size.
        let x: Vec<f64> = (0..2001).map(|i| (i as f64 - 1000.0) * 1e-5).collect();
        let c0 = vec![1.0; x.len()];
        let c3: Vec<f64> = x.iter().map(|v| v * v * v).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 + 2e3 * v - 5e7 * v * v * v).collect();
        let r = lstsq(&[&c0, &x, &c3], &y).unwrap();
        assert!((r.coefficients[0] - 3.0).abs() < 1e-12);
        assert!((r.coefficients[1] / 2e3 - 1.0).abs() < 1e-12);
        assert!((r.coefficients[2] / -5e7 - 1.0).abs() < 1e-12);
        assert!(r.rss < 1e-20);
    }

    #[test]
    fn standard_errors_match_theory() {
        // y = a + noise with known sigma: se(a) = sigma / sqrt(n), residual variance = sigma^2.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 40_000;
        let ones = vec![1.0; n];
        let t: Vec<f64> = (0..n).map(|i| i as f64 / n as f64 - 0.5).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|t| 1.5 + 0.2 * t + 0.1 * (rng.random::<f64>() - 0.5) * 12f64.sqrt())
            .collect();
        let r = lstsq(&[&ones, &t], &y).unwrap();
        let se_theory = 0.1 / (n as f64).sqrt();
        assert!((r.standard_errors[0] / se_theory - 1.0).abs() < 0.03);
        assert!((r.coefficients[0] - 1.5).abs() < 4.0 * se_theory);
        assert!((r.rss / r.dof as f64 / 0.01 - 1.0).abs() < 0.03);
    }

    #[test]
    fn nested_qr_matches_and_is_exact() {
        let x: Vec<f64> = (0..3001).map(|i| (i as f64 - 1500.0) * 1e-5).collect();
        let cols: Vec<Vec<f64>> = (0..8)
            .map(|k| x.iter().map(|v| v.powi(k)).collect())
            .collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 + 2e3 * v - 5e7 * v * v * v).collect();
        let nl = NestedLstsq::new(&refs, &y).unwrap();
        assert!(nl.rss(3) > 1e-6 * dot(&y, &y), "cubic term missing");
        for p in 4..=8 {
            let (c, _) = nl.solve(p).unwrap();
            assert!(
                (c[0] - 3.0).abs() < 1e-9 && (c[3] / -5e7 - 1.0).abs() < 1e-7,
                "{p}: {c:?}"
            );
            assert!(nl.rss(p) < 1e-18 * dot(&y, &y));
        }
        let full = lstsq(&refs[..4], &y).unwrap();
        let (c, _) = nl.solve(4).unwrap();
        for (a, b) in c.iter().zip(&full.coefficients) {
            assert!((a - b).abs() <= 1e-7 * b.abs().max(1.0));
        }
    }

    /// The owned constructor factorises the same matrix: the same bits.
    #[test]
    fn nested_from_owned_columns_is_the_same() {
        let x: Vec<f64> = (0..2501).map(|i| (i as f64 - 1200.0) * 1e-5).collect();
        let cols: Vec<Vec<f64>> = (0..6)
            .map(|k| {
                x.iter()
                    .map(|v| v.powi(k) + 1e-3 * (v * 1e3).sin())
                    .collect()
            })
            .collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let y: Vec<f64> = x.iter().map(|v| 1.0 + 7e2 * v - 3e6 * v * v).collect();
        let a = NestedLstsq::new(&refs, &y).unwrap();
        let b = NestedLstsq::from_columns(cols.clone(), y.clone()).unwrap();
        assert_eq!(a.scale, b.scale);
        assert_eq!(a.r, b.r);
        assert_eq!(a.qty, b.qty);
        for p in 1..=6 {
            assert_eq!(a.solve(p).unwrap(), b.solve(p).unwrap());
        }
        let mut bad = cols.clone();
        bad[3][7] = f64::NAN;
        assert_eq!(
            NestedLstsq::from_columns(bad, y.clone()).unwrap_err(),
            LstsqError::NonFinite
        );
        let mut zero = cols;
        zero[2].fill(0.0);
        assert_eq!(
            NestedLstsq::from_columns(zero, y).unwrap_err(),
            LstsqError::RankDeficient
        );
    }

    #[test]
    fn errors_instead_of_panics() {
        let a = vec![1.0, 2.0, 3.0];
        let b: Vec<f64> = a.iter().map(|v| 2.0 * v).collect();
        let y = vec![1.0, 1.0, 2.0];
        assert_eq!(lstsq(&[&a, &b], &y), Err(LstsqError::RankDeficient));
        assert!(matches!(lstsq(&[&a], &y[..2]), Err(LstsqError::Shape(_))));
        let nan = vec![1.0, f64::NAN, 3.0];
        assert_eq!(lstsq(&[&nan], &y), Err(LstsqError::NonFinite));
        assert!(matches!(lstsq(&[], &y), Err(LstsqError::Shape(_))));
    }
}
