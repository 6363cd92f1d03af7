//! Nonlinear stiffness K(x) = sum k_i x^i from the force balance
//! `m x'' = s mic - R x' - K(x) x` (Two Signal: s, R, k_i unknown) or
//! `m x'' = -R' x' - K(x) x` around the resonance (One Signal).

use super::prep::Prepared;
use super::{AnalyzeError, Method};
use crate::dsp;
use rayon::prelude::*;

/// Highest order tried when the order is chosen from the data.
pub const MAX_AUTO_ORDER: usize = 8;
/// Highest order accepted from the user.
pub const MAX_ORDER: usize = 12;

#[derive(Debug, Clone)]
pub struct KFit {
    pub order: usize,
    /// k_0..k_order (N/m^(i+1)) and their standard errors.
    pub k: Vec<f64>,
    pub k_se: Vec<f64>,
    pub r_ns_per_m: f64,
    /// Force per microphone volt (Two Signal) and its standard error.
    pub scale_n_per_v: Option<(f64, f64)>,
    /// Residual force (N) over the span, and RMS of m x''.
    pub residual_n: Vec<f64>,
    pub rms_ma_n: f64,
    /// RMS of the fitted target (m x'', without its fundamental for One Signal).
    pub rms_target_n: f64,
    /// BIC per order tried (order, bic), when chosen from the data.
    pub bic: Vec<(usize, f64)>,
}

impl KFit {
    pub fn k_of_x(&self, x: f64) -> f64 {
        self.k.iter().rev().fold(0.0, |acc, c| acc * x + c)
    }
    /// dK/dx.
    pub fn dk_dx(&self, x: f64) -> f64 {
        self.k
            .iter()
            .enumerate()
            .skip(1)
            .rev()
            .fold(0.0, |acc, (i, c)| acc * x + i as f64 * c)
    }
    pub fn residual_percent(&self) -> f64 {
        let n = self.residual_n.len().max(1) as f64;
        let rms = (self.residual_n.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        100.0 * rms / self.rms_ma_n
    }
}

/// Target m x'' and the columns [mic (Two Signal)], x', x (x/xs)^i for i = 0..=max_order.
/// One Signal: the fundamental is removed per period from everything (the drive
/// force is taken as a pure, slowly varying sinusoid at the fundamental, so only
/// dc and harmonics balance without it).
fn design(
    p: &Prepared,
    method: Method,
    span: (usize, usize),
    max_order: usize,
    xs: f64,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let (s0, s1) = span;
    let x = &p.x[s0..s1];
    let mut y: Vec<f64> = p.a[s0..s1].iter().map(|a| p.mass_kg * a).collect();
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(max_order + 3);
    if method == Method::TwoSignal {
        cols.push(p.mic[s0..s1].to_vec());
    }
    cols.push(p.v[s0..s1].to_vec());
    let mut cur: Vec<f64> = x.to_vec();
    for _ in 0..=max_order {
        let next: Vec<f64> = cur.iter().zip(x).map(|(c, x)| c * x / xs).collect();
        cols.push(std::mem::replace(&mut cur, next));
    }
    if method == Method::OneSignal {
        let marks: Vec<f64> = p
            .marks
            .iter()
            .map(|m| m - s0 as f64)
            .filter(|m| *m >= -1.0 && *m <= (s1 - s0) as f64 + 1.0)
            .collect();
        let rm = dsp::harmonics::FundamentalRemover::new(s1 - s0, &marks);
        y = rm.apply(&y);
        for c in cols.iter_mut() {
            *c = rm.apply(c);
        }
    }
    (y, cols)
}

/// The Two Signal design (`design`) passed through the same linear filter,
/// a first-order low-pass at `fc_hz` run forward and backward (gain
/// 1 / (1 + (f / fc)^2)), for the coefficients' least squares: a generalised
/// least squares that whitens the laser's noise. The force balance is
/// linear in the coefficients, so filtering the target and every column
/// alike keeps it exact; but the laser's white noise, differentiated twice
/// in m x'', grows as f^4 up to the analysis low-pass (1.2 kHz), far above
/// the part's motion, and an unweighted fit spends its variance on it (a
/// spider_4in part's Keff at the target scattered 6-8x more, decision
/// 0069). Above the resonance m x'' dominates the force balance and with it
/// this noise, so the filter's corner is the displacement peak's frequency
/// (the laser noise's share of the residual becomes about white). The
/// columns are filtered over the whole record around the span (4 time
/// constants on each side, where the record has them), so the span's edges
/// carry no start-up transient. The residual and what it states (model
/// error, order choice) stay those of the unfiltered balance.
fn whitened(
    p: &Prepared,
    span: (usize, usize),
    max_order: usize,
    xs: f64,
    fc_hz: f64,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let (s0, s1) = span;
    let tau = p.fs_hz / (2.0 * std::f64::consts::PI * fc_hz);
    let pad = ((4.0 * tau) as usize).min(s0).min(p.x.len() - s1);
    let padded = (s0 - pad, s1 + pad);
    let (mut y, mut cols) = design(p, Method::TwoSignal, padded, max_order, xs);
    let alpha = (-1.0 / tau).exp();
    let smooth = |c: &mut Vec<f64>| {
        let mut st = 0.0;
        for v in c.iter_mut() {
            st = alpha * st + (1.0 - alpha) * *v;
            *v = st;
        }
        st = 0.0;
        for v in c.iter_mut().rev() {
            st = alpha * st + (1.0 - alpha) * *v;
            *v = st;
        }
        c.drain(..pad);
        c.truncate(s1 - s0);
    };
    smooth(&mut y);
    cols.iter_mut().for_each(smooth);
    (y, cols)
}

/// The least-squares design of the coefficients: the whitened one (Two
/// Signal with a displacement peak inside the record) or the plain one.
fn coefficient_design(
    p: &Prepared,
    method: Method,
    span: (usize, usize),
    max_order: usize,
    xs: f64,
) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let fc = super::large::freq_at(p, p.res_pos);
    (method == Method::TwoSignal && fc.is_finite() && fc > 0.0 && fc < 0.5 * p.fs_hz)
        .then(|| whitened(p, span, max_order, xs, fc))
}

fn fit_order(
    p: &Prepared,
    method: Method,
    span: (usize, usize),
    order: usize,
    xs: f64,
    (y, cols): &(Vec<f64>, Vec<Vec<f64>>),
    nl: &dsp::lstsq::NestedLstsq,
) -> Result<KFit, AnalyzeError> {
    let two = method == Method::TwoSignal;
    let off = usize::from(two);
    let np = off + 2 + order;
    let (coef, se) = nl
        .solve(np)
        .map_err(|e| AnalyzeError::Invalid(format!("stiffness fit failed: {e}")))?;
    let mut residual = y.clone();
    for (c, col) in coef.iter().zip(&cols[..np]) {
        for (r, a) in residual.iter_mut().zip(col) {
            *r -= c * a;
        }
    }
    let k: Vec<f64> = (0..=order)
        .map(|i| -coef[off + 1 + i] / xs.powi(i as i32))
        .collect();
    let k_se: Vec<f64> = (0..=order)
        .map(|i| se[off + 1 + i] / xs.powi(i as i32))
        .collect();
    // Relative figures always against the full m x'' (not the projected one).
    let rms_ma_n = p.mass_kg
        * (p.a[span.0..span.1].iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
    Ok(KFit {
        order,
        k,
        k_se,
        r_ns_per_m: -coef[off],
        scale_n_per_v: two.then(|| (coef[0], se[0])),
        residual_n: residual,
        rms_ma_n,
        rms_target_n: (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt(),
        bic: Vec::new(),
    })
}

fn nested(d: &(Vec<f64>, Vec<Vec<f64>>)) -> Result<dsp::lstsq::NestedLstsq, AnalyzeError> {
    let refs: Vec<&[f64]> = d.1.iter().map(|c| c.as_slice()).collect();
    dsp::lstsq::NestedLstsq::new(&refs, &d.0).map_err(stiffness_failed)
}

/// [`nested`] of a design nothing else reads (the whitened one): its
/// columns are freed as they are copied into the factorised matrix.
fn nested_owned((y, cols): Design) -> Result<dsp::lstsq::NestedLstsq, AnalyzeError> {
    dsp::lstsq::NestedLstsq::from_columns(cols, y).map_err(stiffness_failed)
}

fn stiffness_failed(e: dsp::lstsq::LstsqError) -> AnalyzeError {
    AnalyzeError::Invalid(format!("stiffness fit failed: {e}"))
}

/// A least-squares design: the target and its columns.
type Design = (Vec<f64>, Vec<Vec<f64>>);

/// The plain design (residuals, order choice) and the factorised design
/// of the coefficients (the whitened one when there is one, else the
/// plain one): the whitened design and its factorisation are built beside
/// the plain design on rayon's pool.
fn designs(
    p: &Prepared,
    method: Method,
    span: (usize, usize),
    max_order: usize,
    xs: f64,
) -> (Design, Result<dsp::lstsq::NestedLstsq, AnalyzeError>) {
    let (d, whitened) = rayon::join(
        || design(p, method, span, max_order, xs),
        || coefficient_design(p, method, span, max_order, xs).map(nested_owned),
    );
    let nl = whitened.unwrap_or_else(|| nested(&d));
    (d, nl)
}

/// Fits K(x) over `span`; the order is `order` or chosen by the Bayesian
/// information criterion on the effective number of independent samples
/// (the band-limited noise is correlated over fs / (2 f_stop) samples).
pub fn fit(
    p: &Prepared,
    method: Method,
    span: (usize, usize),
    order: Option<usize>,
) -> Result<KFit, AnalyzeError> {
    let xs = p.x[span.0..span.1]
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    if let Some(n) = order {
        if n > MAX_ORDER {
            return Err(AnalyzeError::Invalid(format!(
                "--order {n} is too high (at most {MAX_ORDER})"
            )));
        }
        let (d, nl) = designs(p, method, span, n, xs);
        return fit_order(p, method, span, n, xs, &d, &nl?);
    }
    let n = (span.1 - span.0) as f64;
    let n_eff = (n * 2.0 * p.lowpass.stop_hz / p.fs_hz).min(n);
    let mut best: Option<(f64, KFit)> = None;
    let mut bic = Vec::new();
    let (d, nl) = designs(p, method, span, MAX_AUTO_ORDER, xs);
    let (d, nl) = (d, nl?);
    // The orders' fits (their residuals over the span) are independent:
    // on rayon's pool, judged below in the orders' sequence.
    let fits: Vec<Result<KFit, AnalyzeError>> = (1..=MAX_AUTO_ORDER)
        .into_par_iter()
        .map(|ord| fit_order(p, method, span, ord, xs, &d, &nl))
        .collect();
    for (ord, f) in (1..=MAX_AUTO_ORDER).zip(fits) {
        let f = f?;
        // Residuals below 1e-5 of the target are numerical (float32 recordings,
        // band limiting), not structure that more terms should chase.
        let rss: f64 =
            f.residual_n.iter().map(|e| e * e).sum::<f64>() + n * (1e-5 * f.rms_target_n).powi(2);
        let params = (ord + 1 + 1 + usize::from(method == Method::TwoSignal)) as f64;
        let b = n_eff * (rss / n).max(f64::MIN_POSITIVE).ln() + params * n_eff.ln();
        bic.push((ord, b));
        if best.as_ref().is_none_or(|(bb, _)| b < *bb) {
            best = Some((b, f));
        }
    }
    let (_, mut f) = best.expect("at least one order");
    f.bic = bic;
    Ok(f)
}
