//! The diagnostics engine on force-balance data: the linear-in-parameters
//! force balance
//!
//! `m a = s mic + c - sum_i k_i x^(i+1) - R v - (effect terms)`
//!
//! (`s` the force per microphone volt, `c` an offset), candidate effects with
//! their regressors and hyper-parameter searches, ranking by blocked
//! cross-validation and a block-robust Wald test, identifiability by variance
//! inflation, and the forward-selection ladder.

use super::regress::{block_bounds, collinearity_r2, BlockGram};
use super::stats::{f_upper_p, t_two_sided_p};
use crate::effects::{
    ChannelDelay, CoulombFriction, Creep, DampingVsDisplacement, EffectId, Effects,
    QuadraticDamping, StiffnessDrift,
};
pub use crate::identify::documents::{CandidateResult, LadderStep};
use crate::identify::ForceBalanceData;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

/// Settings of the engine. The defaults are the documented design choices
/// (docs/diagnostics.md), not tuned to any data set.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineOptions {
    /// Highest power of K(x) in the base model; chosen from the data when None.
    pub order: Option<usize>,
    /// Effects forced into the model from the start.
    pub forced: Vec<EffectId>,
    /// Let the forward-selection ladder add effects to `forced` ("auto");
    /// false fits exactly `forced` and only reports what the ladder would add.
    pub ladder: bool,
    /// Number of contiguous time blocks (batch-means covariance).
    pub blocks: usize,
    /// Number of contiguous cross-validation folds (runs of blocks).
    pub folds: usize,
    /// Family-wise significance level per ladder step (Bonferroni over candidates).
    pub alpha: f64,
    /// Variance inflation above which a candidate cannot be told apart from the model.
    pub vif_limit: f64,
    /// Most effects the ladder adds.
    pub max_steps: usize,
    /// Practical relevance: a significant candidate must remove at least this
    /// share of the held-out model error (%).
    pub min_reduction_percent: f64,
    /// Highest K(x) power the order selection and `stiffness_order` may reach.
    pub max_order: usize,
}

impl Default for EngineOptions {
    fn default() -> Self {
        EngineOptions {
            order: None,
            forced: Vec::new(),
            ladder: true,
            blocks: 40,
            folds: 5,
            alpha: 0.01,
            vif_limit: 200.0,
            max_steps: 6,
            min_reduction_percent: 5.0,
            max_order: 10,
        }
    }
}

/// A candidate extension of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Term {
    Effect(EffectId),
    /// One more power of K(x) (not physics; guards against a too-low order).
    StiffnessOrder,
}

impl Term {
    pub fn name(self) -> &'static str {
        match self {
            Term::Effect(e) => e.as_str(),
            Term::StiffnessOrder => "stiffness_order",
        }
    }

    /// The experiment that separates this term from the model when this data cannot.
    pub fn separating_experiment(self) -> &'static str {
        match self {
            Term::Effect(EffectId::CoulombFriction) => {
                "a second drive level (dry friction does not grow with amplitude, viscous damping does)"
            }
            Term::Effect(EffectId::QuadraticDamping) => {
                "a second drive level (v|v| damping grows with amplitude, viscous damping does not)"
            }
            Term::Effect(EffectId::DampingVsDisplacement) => {
                "a second drive level or a larger excursion (damping that depends on x changes with it)"
            }
            Term::Effect(EffectId::Creep) => {
                "a wider frequency range (the small-signal sweep) or an added mass that moves the resonance"
            }
            Term::Effect(EffectId::StiffnessDrift) => {
                "a repeated measurement some minutes later (drift changes K(0) between runs)"
            }
            Term::Effect(EffectId::ChannelDelay) => {
                "an added mass (moves the resonance, so delay and damping separate)"
            }
            Term::StiffnessOrder => "a higher drive level (a larger displacement range)",
        }
    }
}

/// Fitted model: what is in it and how well it explains the data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedModel {
    pub order: usize,
    /// Effects in the model in the order they were added (forced first).
    pub effect_ids: Vec<EffectId>,
    pub effects: Effects,
    /// Standard errors of the effect parameters (same names), block-robust.
    pub effects_se: serde_json::Value,
    /// K(x) = sum k_i x^i (N/m, x in m) of this model; with stiffness
    /// drift in the model, K(x) at the start of the recording (`reference_time_s`).
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Block-robust standard errors of the coefficients (same units).
    #[serde(default)]
    pub stiffness_coefficients_se_n_per_m_pow_i_plus_1: Vec<f64>,
    /// Time (s from the start of the recording) K(x) refers to; None when
    /// nothing in the model changes K over time.
    #[serde(default)]
    pub reference_time_s: Option<f64>,
    pub r_ns_per_m: f64,
    #[serde(default)]
    pub r_se_ns_per_m: f64,
    pub force_per_mic_n_per_v: f64,
    pub residual_percent: f64,
    /// Residual of blocked cross-validation (held-out data).
    pub cv_residual_percent: f64,
    /// Block-robust covariance of the K(x) coefficients (row-major, same
    /// units as the coefficients): for derived figures such as Keff.
    #[serde(skip)]
    pub stiffness_covariance: Vec<Vec<f64>>,
    /// K(0) changes by this much per second (N/m/s) when stiffness drift is
    /// in the model (K(x) above holds at `reference_time_s`).
    #[serde(skip)]
    pub dk0_dt_n_per_m_s: f64,
}

/// Everything the engine found.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineResult {
    pub base: FittedModel,
    pub model: FittedModel,
    pub candidates: Vec<CandidateResult>,
    pub ladder: Vec<LadderStep>,
    pub noise_floor_percent: f64,
    pub model_error_percent: f64,
    pub base_model_error_percent: f64,
    /// Residual of the final and the base model (N), sample by sample.
    pub residual_n: Vec<f64>,
    pub base_residual_n: Vec<f64>,
    /// Modelled inertia force m a of the final model (N).
    pub modelled_force_n: Vec<f64>,
    pub spectrum: super::spectrum::ResidualSpectrum,
    /// Spectrum of the base model's residual.
    pub base_spectrum: super::spectrum::ResidualSpectrum,
    /// Order chosen for the base model and how.
    pub order_note: String,
    /// Significant candidates the ladder did not add, and why (one line each).
    pub skipped: Vec<String>,
}

/// Model specification: K order plus effects with their hyper-parameter.
#[derive(Debug, Clone, PartialEq)]
struct Spec {
    order: usize,
    effects: Vec<(EffectId, f64)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Mic,
    Intercept,
    K(usize),
    R,
    Eff(EffectId, usize),
}

impl Role {
    fn name(self) -> String {
        match self {
            Role::Mic => "the force scale (microphone)".into(),
            Role::Intercept => "the force offset".into(),
            Role::K(0) => "k0 (linear stiffness)".into(),
            Role::K(i) => format!("the x^{} term of K(x)", i),
            Role::R => "R (viscous damping)".into(),
            Role::Eff(e, _) => e.as_str().into(),
        }
    }
}

/// Data prepared for the engine.
pub struct Prepared<'a> {
    d: &'a ForceBalanceData,
    y: Vec<f64>,
    ones: Vec<f64>,
    /// x / x_scale in [-1, 1].
    u: Vec<f64>,
    x_scale: f64,
    v_max: f64,
    /// RMS(v) / RMS(x): a typical angular frequency of the motion (rad/s).
    omega_typ: f64,
    t_centered: Vec<f64>,
    bounds: Vec<(usize, usize)>,
    rms_y: f64,
    duration_s: f64,
    /// y . y per block.
    yy: Vec<f64>,
    /// Prefix sums of x (the creep columns' starting means).
    x_prefix: Vec<f64>,
    /// Model columns and the block cross products of every pair of columns
    /// used so far: each is computed once per data set, however many
    /// models, folds, candidates and grid points use it.
    cache: RefCell<Cache>,
}

/// A column of the design, named by what determines it (hyper-parameters
/// by their bits: the same value gives the same column, bit for bit), so
/// that its cross products are computed once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
enum Col {
    /// The microphone, shifted by the model's channel delay (s) if it has one.
    Mic(Option<u64>),
    /// The time derivative of that column (the linearised delay).
    DMic(Option<u64>),
    Ones,
    /// x P_i(x / x_scale), the i-th term of K(x).
    K(usize),
    V,
    /// Column k of an effect at hyper-parameter h.
    Eff(EffectId, usize, u64),
}

#[derive(Default)]
struct Cache {
    /// Columns of models (not of the hyper-parameter searches' trial points).
    cols: HashMap<Col, Rc<[f64]>>,
    /// Per block: a . b, keyed with a <= b (the product sum is symmetric bit for bit).
    cross: HashMap<(Col, Col), Box<[f64]>>,
    /// Per block: a . y.
    ycross: HashMap<Col, Box<[f64]>>,
    /// Trial columns computed ahead for a search (together is cheaper).
    staged: HashMap<Col, Rc<[f64]>>,
}

/// A column: kept in the cache or computed for one use.
enum ColData {
    Kept(Rc<[f64]>),
    Own(Vec<f64>),
}

impl std::ops::Deref for ColData {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        match self {
            ColData::Kept(c) => c,
            ColData::Own(c) => c,
        }
    }
}

/// Number of columns of an effect.
fn effect_width(e: EffectId) -> usize {
    match e {
        EffectId::DampingVsDisplacement => 2,
        EffectId::ChannelDelay => 0,
        _ => 1,
    }
}

/// The columns of an effect at hyper-parameter `h`.
fn effect_ids(e: EffectId, h: f64) -> Vec<Col> {
    (0..effect_width(e))
        .map(|k| Col::Eff(e, k, h.to_bits()))
        .collect()
}

fn legendre_cols(x: &[f64], u: &[f64], order: usize) -> Vec<Vec<f64>> {
    // x * P_i(u), i = 0..=order.
    let n = x.len();
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(order + 1);
    let mut p_prev = vec![1.0; n];
    let mut p_cur = u.to_vec();
    cols.push(x.to_vec());
    if order >= 1 {
        cols.push((0..n).map(|t| x[t] * p_cur[t]).collect());
    }
    for i in 1..order {
        let fi = i as f64;
        let p_next: Vec<f64> = (0..n)
            .map(|t| ((2.0 * fi + 1.0) * u[t] * p_cur[t] - fi * p_prev[t]) / (fi + 1.0))
            .collect();
        cols.push((0..n).map(|t| x[t] * p_next[t]).collect());
        p_prev = std::mem::replace(&mut p_cur, p_next);
    }
    cols
}

/// Monomial coefficients (in u) of the Legendre polynomials P_0..P_order.
fn legendre_monomials(order: usize) -> Vec<Vec<f64>> {
    let mut out: Vec<Vec<f64>> = vec![vec![1.0]];
    if order >= 1 {
        out.push(vec![0.0, 1.0]);
    }
    for i in 1..order {
        let fi = i as f64;
        let mut next = vec![0.0; i + 2];
        for (j, &c) in out[i].iter().enumerate() {
            next[j + 1] += (2.0 * fi + 1.0) * c / (fi + 1.0);
        }
        for (j, &c) in out[i - 1].iter().enumerate() {
            next[j] -= fi * c / (fi + 1.0);
        }
        out.push(next);
    }
    out
}

/// The relaxed position the creep low-pass starts from (see [`creep_columns`]).
fn creep_start(x: &[f64], fs: f64, tau: f64, starts_at_rest: bool) -> f64 {
    if starts_at_rest || x.is_empty() {
        x.first().copied().unwrap_or(0.0)
    } else {
        let m = ((5.0 * tau).max(1.0) * fs).ceil() as usize;
        let w = &x[..m.clamp(1, x.len())];
        w.iter().sum::<f64>() / w.len() as f64
    }
}

/// One creep column the plain way (the reference of the tests).
#[cfg(test)]
fn creep_column_alone(x: &[f64], fs: f64, tau: f64, starts_at_rest: bool) -> Vec<f64> {
    let alpha = 1.0 - (-1.0 / (fs * tau)).exp();
    let mut xr = creep_start(x, fs, tau, starts_at_rest);
    x.iter()
        .map(|&xi| {
            let out = xi - xr;
            xr += alpha * (xi - xr);
            out
        })
        .collect()
}

/// `x[..m].iter().sum()` for every m (index m), bit for bit: the same
/// additions from the same start, left to right.
fn prefix_sums(x: &[f64]) -> Vec<f64> {
    let mut s: f64 = std::iter::empty::<f64>().sum();
    let mut out = Vec::with_capacity(x.len() + 1);
    out.push(s);
    for &v in x {
        s += v;
        out.push(s);
    }
    out
}

/// Creep columns: x - xr, xr the first-order low-pass of x with time
/// constant tau (exact for a piecewise constant input): the relaxed
/// position of the creep model. A span that starts at rest starts xr at
/// x[0]; one that starts mid-oscillation (the main sweep) at the mean of x
/// over its first max(5 tau, 1 s), the low-pass's own estimate of the
/// relaxed position: started at x[0] there, the false start transient was
/// absorbed by a too short tau and K(x) took the missing creep stiffness
/// (up to 1.5 % off).
///
/// Several time constants in one pass over x: their recursions are
/// independent chains, each column computed exactly as alone. `prefix`:
/// [`prefix_sums`] of x, for the starting means.
fn creep_columns(
    x: &[f64],
    fs: f64,
    taus: &[f64],
    starts_at_rest: bool,
    prefix: Option<&[f64]>,
) -> Vec<Vec<f64>> {
    let start = |tau: f64| match prefix {
        Some(pre) if !starts_at_rest && !x.is_empty() => {
            let m = ((5.0 * tau).max(1.0) * fs).ceil() as usize;
            let m = m.clamp(1, x.len());
            pre[m] / m as f64
        }
        _ => creep_start(x, fs, tau, starts_at_rest),
    };
    let mut cols: Vec<Vec<f64>> = Vec::with_capacity(taus.len());
    let mut rest = taus;
    while !rest.is_empty() {
        let k = rest.len().min(4);
        let (group, tail) = rest.split_at(k);
        rest = tail;
        let alpha: Vec<f64> = group
            .iter()
            .map(|&tau| 1.0 - (-1.0 / (fs * tau)).exp())
            .collect();
        let xr: Vec<f64> = group.iter().map(|&tau| start(tau)).collect();
        match k {
            1 => cols.extend(creep_chains::<1>(x, &alpha, &xr)),
            2 => cols.extend(creep_chains::<2>(x, &alpha, &xr)),
            3 => cols.extend(creep_chains::<3>(x, &alpha, &xr)),
            _ => cols.extend(creep_chains::<4>(x, &alpha, &xr)),
        }
    }
    cols
}

/// K creep recursions side by side (registers, not memory, between samples).
fn creep_chains<const K: usize>(x: &[f64], alpha: &[f64], xr0: &[f64]) -> Vec<Vec<f64>> {
    let alpha: [f64; K] = std::array::from_fn(|j| alpha[j]);
    let mut xr: [f64; K] = std::array::from_fn(|j| xr0[j]);
    let mut rows = vec![[0.0f64; K]; x.len()];
    for (row, &xi) in rows.iter_mut().zip(x) {
        for j in 0..K {
            row[j] = xi - xr[j];
            xr[j] += alpha[j] * (xi - xr[j]);
        }
    }
    (0..K)
        .map(|j| rows.iter().map(|r| r[j]).collect())
        .collect()
}

/// mic(t + d) by 4-point Lagrange interpolation (d in seconds, any sign).
fn shifted(mic: &[f64], fs: f64, d: f64) -> Vec<f64> {
    let n = mic.len() as isize;
    let s = d * fs;
    let k = s.floor();
    let f = s - k;
    let k = k as isize;
    let at = |i: isize| mic[i.clamp(0, n - 1) as usize];
    let (c0, c1, c2, c3) = (
        -f * (f - 1.0) * (f - 2.0) / 6.0,
        (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0,
        -(f + 1.0) * f * (f - 2.0) / 2.0,
        (f + 1.0) * f * (f - 1.0) / 6.0,
    );
    let edge = |i: isize| {
        let j = i + k;
        c0 * at(j - 1) + c1 * at(j) + c2 * at(j + 1) + c3 * at(j + 2)
    };
    // Inside [1 - k, n - 2 - k) all four taps lie in the record: no clamping.
    let lo = (1 - k).clamp(0, n);
    let hi = (n - 2 - k).clamp(lo, n);
    let mut out = Vec::with_capacity(n as usize);
    out.extend((0..lo).map(edge));
    if hi > lo {
        let first = (lo + k - 1) as usize;
        out.extend(
            mic[first..first + (hi - lo) as usize + 3]
                .windows(4)
                .map(|w| c0 * w[0] + c1 * w[1] + c2 * w[2] + c3 * w[3]),
        );
    }
    out.extend((hi..n).map(edge));
    out
}

fn derivative(sig: &[f64], fs: f64) -> Vec<f64> {
    let n = sig.len();
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            if b > a {
                (sig[b] - sig[a]) * fs / (b - a) as f64
            } else {
                0.0
            }
        })
        .collect()
}

impl<'a> Prepared<'a> {
    pub fn new(d: &'a ForceBalanceData, blocks: usize) -> Result<Prepared<'a>, String> {
        let n = d.x_m.len();
        if n < 400 {
            return Err(format!(
                "force-balance data too short for diagnostics: {n} samples (need at least 400)"
            ));
        }
        if d.v_m_per_s.len() != n || d.a_m_per_s2.len() != n || d.mic_v.len() != n {
            return Err("force-balance data: signals of different length".into());
        }
        let positive = |v: f64| v > 0.0 && v.is_finite();
        if !positive(d.mass_kg) || !positive(d.sample_rate_hz) {
            return Err("force-balance data: mass and sample rate must be positive".into());
        }
        let all = [&d.x_m, &d.v_m_per_s, &d.a_m_per_s2, &d.mic_v];
        if all.iter().any(|s| s.iter().any(|v| !v.is_finite())) {
            return Err("force-balance data contains NaN or infinite samples".into());
        }
        let x_scale = d.x_m.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let v_max = d.v_m_per_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if x_scale <= 0.0 || v_max <= 0.0 {
            return Err("force-balance data: the part does not move".into());
        }
        let rms = |s: &[f64]| (s.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let omega_typ = rms(&d.v_m_per_s) / rms(&d.x_m).max(f64::MIN_POSITIVE);
        let y: Vec<f64> = d.a_m_per_s2.iter().map(|a| d.mass_kg * a).collect();
        let rms_y = (y.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let fs = d.sample_rate_hz;
        let t_mid = (n as f64 - 1.0) / 2.0 / fs;
        let bounds = block_bounds(n, blocks.max(4));
        Ok(Prepared {
            d,
            ones: vec![1.0; n],
            u: d.x_m.iter().map(|x| x / x_scale).collect(),
            x_scale,
            v_max,
            omega_typ,
            t_centered: (0..n).map(|i| i as f64 / fs - t_mid).collect(),
            yy: bounds
                .iter()
                .map(|&(s, e)| super::regress::dot(&y[s..e], &y[s..e]))
                .collect(),
            bounds,
            rms_y,
            duration_s: n as f64 / fs,
            y,
            cache: RefCell::new(Cache::default()),
            x_prefix: prefix_sums(&d.x_m),
        })
    }

    fn fs(&self) -> f64 {
        self.d.sample_rate_hz
    }

    /// Columns of one effect at hyper-parameter `h` (none for channel delay).
    fn effect_cols(&self, e: EffectId, h: f64) -> Vec<Vec<f64>> {
        let (x, v) = (&self.d.x_m, &self.d.v_m_per_s);
        match e {
            EffectId::CoulombFriction => vec![v.iter().map(|v| (v / h).tanh()).collect()],
            EffectId::QuadraticDamping => vec![v.iter().map(|v| v * v.abs()).collect()],
            EffectId::DampingVsDisplacement => vec![
                x.iter().zip(v).map(|(x, v)| x * v).collect(),
                x.iter().zip(v).map(|(x, v)| x * x * v).collect(),
            ],
            EffectId::Creep => creep_columns(
                x,
                self.fs(),
                &[h],
                self.d.starts_at_rest,
                Some(&self.x_prefix),
            ),
            EffectId::StiffnessDrift => {
                vec![x.iter().zip(&self.t_centered).map(|(x, t)| x * t).collect()]
            }
            EffectId::ChannelDelay => vec![],
        }
    }

    /// The design of `spec`: its columns in order and their roles.
    fn design(&self, spec: &Spec) -> (Vec<Col>, Vec<Role>) {
        let delay = spec
            .effects
            .iter()
            .find(|(e, _)| *e == EffectId::ChannelDelay)
            .map(|&(_, d)| d.to_bits());
        let mut ids = vec![Col::Mic(delay), Col::Ones];
        let mut roles = vec![Role::Mic, Role::Intercept];
        for i in 0..=spec.order {
            ids.push(Col::K(i));
            roles.push(Role::K(i));
        }
        ids.push(Col::V);
        roles.push(Role::R);
        for &(e, h) in &spec.effects {
            for (k, c) in effect_ids(e, h).into_iter().enumerate() {
                ids.push(c);
                roles.push(Role::Eff(e, k));
            }
        }
        (ids, roles)
    }

    /// Computes a column (the K(x) terms: all up to it, kept).
    fn compute(&self, c: Col) -> Vec<f64> {
        match c {
            Col::Mic(None) => self.d.mic_v.clone(),
            Col::Mic(Some(d)) => shifted(&self.d.mic_v, self.fs(), f64::from_bits(d)),
            Col::DMic(m) => derivative(&self.column(Col::Mic(m)), self.fs()),
            Col::Ones => self.ones.clone(),
            Col::V => self.d.v_m_per_s.clone(),
            Col::K(i) => {
                let mut cols = legendre_cols(&self.d.x_m, &self.u, i);
                let last = cols.pop().expect("order >= 0");
                let mut cache = self.cache.borrow_mut();
                for (j, col) in cols.into_iter().enumerate() {
                    cache.cols.entry(Col::K(j)).or_insert_with(|| col.into());
                }
                last
            }
            Col::Eff(e, k, h) => self.effect_cols(e, f64::from_bits(h)).swap_remove(k),
        }
    }

    /// True when every cross product of `col` with the columns of `built`
    /// (and with y) is known.
    fn knows(&self, built: &Built, col: Col) -> bool {
        let cache = self.cache.borrow();
        let key = |a: Col, b: Col| if a <= b { (a, b) } else { (b, a) };
        cache.ycross.contains_key(&col)
            && cache.cross.contains_key(&(col, col))
            && built
                .ids
                .iter()
                .all(|&b| cache.cross.contains_key(&key(col, b)))
    }

    /// Stages the creep columns of a grid whose products with `built` are
    /// not all known (the recursions of all time constants in one pass).
    fn stage_creep(&self, built: &Built, grid: &[f64]) {
        let taus: Vec<f64> = grid
            .iter()
            .copied()
            .filter(|&h| !self.knows(built, Col::Eff(EffectId::Creep, 0, h.to_bits())))
            .collect();
        if taus.len() < 2 {
            return;
        }
        let cols = creep_columns(
            &self.d.x_m,
            self.fs(),
            &taus,
            self.d.starts_at_rest,
            Some(&self.x_prefix),
        );
        let mut cache = self.cache.borrow_mut();
        for (tau, col) in taus.iter().zip(cols) {
            cache
                .staged
                .insert(Col::Eff(EffectId::Creep, 0, tau.to_bits()), col.into());
        }
    }

    fn unstage(&self) {
        self.cache.borrow_mut().staged.clear();
    }

    /// A model column, computed once and kept.
    fn column(&self, c: Col) -> Rc<[f64]> {
        if let Some(col) = self.cache.borrow().cols.get(&c) {
            return col.clone();
        }
        let col: Rc<[f64]> = self.compute(c).into();
        self.cache.borrow_mut().cols.insert(c, col.clone());
        col
    }

    /// Block Gram of the design `ids` (in this order). Cross products not
    /// yet known are computed and kept; the columns in `trial` (a
    /// hyper-parameter search's trial points) are computed for this use
    /// only, and only when one of their products is missing.
    fn gram(&self, ids: &[Col], trial: &[Col]) -> BlockGram {
        let p = ids.len();
        let key = |a: Col, b: Col| if a <= b { (a, b) } else { (b, a) };
        // Missing products, by row: (row, partner columns, y too).
        let todo: Vec<(usize, Vec<Col>, bool)> = {
            let cache = self.cache.borrow();
            (0..p)
                .filter_map(|i| {
                    let partners: Vec<Col> = ids[i..]
                        .iter()
                        .copied()
                        .filter(|&b| !cache.cross.contains_key(&key(ids[i], b)))
                        .collect();
                    let y = !cache.ycross.contains_key(&ids[i]);
                    (!partners.is_empty() || y).then_some((i, partners, y))
                })
                .collect()
        };
        if !todo.is_empty() {
            let mut data: HashMap<Col, ColData> = HashMap::new();
            let fetch = |c: Col, data: &mut HashMap<Col, ColData>| {
                data.entry(c).or_insert_with(|| {
                    let kept = {
                        let cache = self.cache.borrow();
                        cache.cols.get(&c).or_else(|| cache.staged.get(&c)).cloned()
                    };
                    match kept {
                        Some(col) => ColData::Kept(col),
                        None if trial.contains(&c) => ColData::Own(self.compute(c)),
                        None => ColData::Kept(self.column(c)),
                    }
                });
            };
            for (i, partners, _) in &todo {
                fetch(ids[*i], &mut data);
                for &b in partners {
                    fetch(b, &mut data);
                }
            }
            let nb = self.bounds.len();
            for (i, partners, y) in todo {
                let a = ids[i];
                let z: &[f64] = &data[&a];
                let mut others: Vec<&[f64]> = partners.iter().map(|b| &*data[b]).collect();
                if y {
                    others.push(&self.y);
                }
                let mut per = vec![vec![0.0; nb]; others.len()];
                let mut out = vec![0.0; others.len()];
                for (blk, &(s, e)) in self.bounds.iter().enumerate() {
                    let o: Vec<&[f64]> = others.iter().map(|c| &c[s..e]).collect();
                    super::regress::dots(&z[s..e], &o, &mut out);
                    for (pk, &v) in per.iter_mut().zip(&out) {
                        pk[blk] = v;
                    }
                }
                let mut cache = self.cache.borrow_mut();
                let mut per = per.into_iter();
                for &b in &partners {
                    let v = per.next().expect("one per partner");
                    cache.cross.insert(key(a, b), v.into());
                }
                if y {
                    cache.ycross.insert(a, per.next().expect("and y").into());
                }
            }
        }
        let cache = self.cache.borrow();
        let cross: Vec<Vec<&[f64]>> = (0..p)
            .map(|i| {
                (0..p)
                    .map(|j| &*cache.cross[&key(ids[i], ids[j])])
                    .collect()
            })
            .collect();
        let ycross: Vec<&[f64]> = ids.iter().map(|c| &*cache.ycross[c]).collect();
        let blocks = self
            .bounds
            .iter()
            .enumerate()
            .map(|(blk, &(s, e))| super::regress::Block {
                g: DMatrix::from_fn(p, p, |i, j| cross[i][j][blk]),
                c: DVector::from_fn(p, |i, _| ycross[i][blk]),
                yy: self.yy[blk],
                n: e - s,
            })
            .collect();
        BlockGram { p, blocks }
    }
}

/// A model built on the data: its columns and block Gram.
struct Built {
    spec: Spec,
    ids: Vec<Col>,
    roles: Vec<Role>,
    gram: BlockGram,
}

impl Built {
    fn new(p: &Prepared, spec: Spec) -> Built {
        let (ids, roles) = p.design(&spec);
        let gram = p.gram(&ids, &[]);
        Built {
            spec,
            ids,
            roles,
            gram,
        }
    }

    /// Gram with columns `new` added (and the mic column replaced for a
    /// delay); `trial` names those of a search's trial points (not kept).
    fn with(&self, p: &Prepared, drop_mic: bool, new: &[Col], trial: bool) -> BlockGram {
        let mut ids: Vec<Col> = self.ids[usize::from(drop_mic)..].to_vec();
        ids.extend_from_slice(new);
        p.gram(&ids, if trial { new } else { &[] })
    }
}

fn golden_min(mut lo: f64, mut hi: f64, iters: usize, mut f: impl FnMut(f64) -> f64) -> (f64, f64) {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let mut a = hi - g * (hi - lo);
    let mut b = lo + g * (hi - lo);
    let mut fa = f(a);
    let mut fb = f(b);
    for _ in 0..iters {
        if fa < fb {
            hi = b;
            b = a;
            fb = fa;
            a = hi - g * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + g * (hi - lo);
            fb = f(b);
        }
    }
    if fa < fb {
        (a, fa)
    } else {
        (b, fb)
    }
}

/// The linearised delay column of a model: the derivative of its microphone column.
fn dmic_of(built: &Built) -> Col {
    match built.ids[0] {
        Col::Mic(d) => Col::DMic(d),
        other => unreachable!("the first column is the microphone, not {other:?}"),
    }
}

/// Block-robust Wald test of the last `q` coefficients of a fit of `gram`.
fn wald_last(gram: &BlockGram, beta: &DVector<f64>, q: usize) -> (f64, Vec<f64>) {
    let p = gram.p;
    let cov = gram.block_covariance(beta);
    let nb = gram.blocks.len() as f64;
    let se: Vec<f64> = (p - q..p).map(|i| cov[(i, i)].max(0.0).sqrt()).collect();
    let pval = if q == 1 {
        let t = beta[p - 1] / se[0];
        if se[0] > 0.0 {
            t_two_sided_p(t, nb - 1.0)
        } else {
            1.0
        }
    } else {
        let sub = cov.view((p - q, p - q), (q, q)).clone_owned();
        let g = beta.rows(p - q, q).clone_owned();
        let inv = super::regress::inverse_spd(&sub);
        let w = (g.transpose() * inv * &g)[(0, 0)];
        let qf = q as f64;
        let f = w * (nb - qf) / (qf * (nb - 1.0));
        f_upper_p(f, qf, nb - qf)
    };
    (pval, se)
}

/// Percent of RMS(m a) of a sum of squared errors.
fn pct(p: &Prepared, sse: f64) -> f64 {
    100.0 * (sse / p.y.len() as f64).sqrt() / p.rms_y
}

fn model_error(res: f64, noise: f64) -> f64 {
    (res * res - noise * noise).max(0.0).sqrt()
}

struct Evaluated {
    hyper: Option<f64>,
    gram: BlockGram,
    q: usize,
    drop_mic: bool,
    /// p-value and standard errors of the test (for delay: of the linearised column).
    p_value: f64,
    se: Vec<f64>,
    beta: DVector<f64>,
}

fn hyper_grid(p: &Prepared, e: EffectId) -> Option<Vec<f64>> {
    let logspace = |lo: f64, hi: f64, n: usize| -> Vec<f64> {
        (0..n)
            .map(|i| (lo.ln() + (hi.ln() - lo.ln()) * i as f64 / (n - 1) as f64).exp())
            .collect()
    };
    match e {
        EffectId::CoulombFriction => Some(logspace(p.v_max * 3e-4, p.v_max, 15)),
        // Below omega tau = 0.5 the creep column is mostly the high-passed
        // laser noise (and a damping force): no creep is measurable there.
        EffectId::Creep => {
            let lo = (0.5 / p.omega_typ).max(2.0 / p.fs());
            Some(logspace(lo, (p.duration_s / 2.0).max(2.0 * lo), 15))
        }
        _ => None,
    }
}

fn evaluate(p: &Prepared, built: &Built, term: Term) -> Evaluated {
    match term {
        Term::StiffnessOrder => {
            let order = built.spec.order + 1;
            let gram = built.with(p, false, &[Col::K(order)], false);
            let fit = gram.fit();
            let (p_value, se) = wald_last(&gram, &fit.beta, 1);
            Evaluated {
                hyper: None,
                gram,
                q: 1,
                drop_mic: false,
                p_value,
                se,
                beta: fit.beta,
            }
        }
        Term::Effect(EffectId::ChannelDelay) => {
            // Test: the linearised column d * s * mic'(t) added to the model.
            let dmic = dmic_of(built);
            let lin = built.with(p, false, &[dmic], false);
            let lfit = lin.fit();
            let (p_value, lse) = wald_last(&lin, &lfit.beta, 1);
            let s = lfit.beta[0];
            let d0 = if s != 0.0 {
                lfit.beta[lin.p - 1] / s
            } else {
                0.0
            };
            let current = built
                .spec
                .effects
                .iter()
                .find(|(e, _)| *e == EffectId::ChannelDelay)
                .map_or(0.0, |x| x.1);
            // Refine the delay with the exact shift around the linear estimate.
            let w = d0.abs().max(2.0 / p.fs());
            let shifted_mic = |d: f64| Col::Mic(Some((current + d).to_bits()));
            let sse_at = |d: f64| built.with(p, true, &[shifted_mic(d)], true).fit().sse;
            let (d_best, _) = golden_min(d0 - w, d0 + w, 18, sse_at);
            let gram = built.with(p, true, &[shifted_mic(d_best)], true);
            let fit = gram.fit();
            let se_d = if s != 0.0 { lse[0] / s.abs() } else { f64::NAN };
            Evaluated {
                hyper: Some(current + d_best),
                gram,
                q: 0,
                drop_mic: true,
                p_value,
                se: vec![se_d],
                beta: fit.beta,
            }
        }
        Term::Effect(e) => {
            let (hyper, cols) = match hyper_grid(p, e) {
                None => (None, effect_ids(e, 0.0)),
                Some(grid) => {
                    let sse_at = |h: f64| built.with(p, false, &effect_ids(e, h), true).fit().sse;
                    if e == EffectId::Creep {
                        p.stage_creep(built, &grid);
                    }
                    let sses: Vec<f64> = grid.iter().map(|&h| sse_at(h)).collect();
                    p.unstage();
                    let (ib, _) = sses
                        .iter()
                        .enumerate()
                        .min_by(|a, b| a.1.total_cmp(b.1))
                        .expect("grid not empty");
                    let lo = grid[ib.saturating_sub(1)].ln();
                    let hi = grid[(ib + 1).min(grid.len() - 1)].ln();
                    let (lh, sse) = golden_min(lo, hi, 14, |l| sse_at(l.exp()));
                    let h = if sse < sses[ib] { lh.exp() } else { grid[ib] };
                    (Some(h), effect_ids(e, h))
                }
            };
            let q = cols.len();
            let gram = built.with(p, false, &cols, hyper.is_some());
            let fit = gram.fit();
            let (p_value, se) = wald_last(&gram, &fit.beta, q);
            Evaluated {
                hyper,
                gram,
                q,
                drop_mic: false,
                p_value,
                se,
                beta: fit.beta,
            }
        }
    }
}

fn effect_params(e: EffectId, h: f64, coef: &[f64]) -> serde_json::Value {
    use serde_json::json;
    match e {
        EffectId::CoulombFriction => json!({"force_n": -coef[0], "v_eps_m_per_s": h}),
        EffectId::QuadraticDamping => json!({"coeff_ns2_per_m2": -coef[0]}),
        EffectId::DampingVsDisplacement => {
            json!({"r1_ns_per_m2": -coef[0], "r2_ns_per_m3": -coef[1]})
        }
        EffectId::Creep => json!({"k_n_per_m": -coef[0], "tau_s": h}),
        EffectId::StiffnessDrift => json!({"dk0_dt_n_per_m_s": -coef[0]}),
        EffectId::ChannelDelay => json!({"delay_s": h}),
    }
}

fn effect_se(e: EffectId, se: &[f64]) -> serde_json::Value {
    use serde_json::json;
    match e {
        EffectId::CoulombFriction => json!({"force_n": se[0]}),
        EffectId::QuadraticDamping => json!({"coeff_ns2_per_m2": se[0]}),
        EffectId::DampingVsDisplacement => json!({"r1_ns_per_m2": se[0], "r2_ns_per_m3": se[1]}),
        EffectId::Creep => json!({"k_n_per_m": se[0]}),
        EffectId::StiffnessDrift => json!({"dk0_dt_n_per_m_s": se[0]}),
        EffectId::ChannelDelay => json!({"delay_s": se[0]}),
    }
}

fn set_effect(effects: &mut Effects, e: EffectId, params: &serde_json::Value) {
    let g = |k: &str| params.get(k).and_then(|v| v.as_f64()).unwrap_or(0.0);
    match e {
        EffectId::CoulombFriction => {
            effects.coulomb_friction = Some(CoulombFriction {
                force_n: g("force_n"),
                v_eps_m_per_s: g("v_eps_m_per_s"),
            })
        }
        EffectId::QuadraticDamping => {
            effects.quadratic_damping = Some(QuadraticDamping {
                coeff_ns2_per_m2: g("coeff_ns2_per_m2"),
            })
        }
        EffectId::DampingVsDisplacement => {
            effects.damping_vs_displacement = Some(DampingVsDisplacement {
                r1_ns_per_m2: g("r1_ns_per_m2"),
                r2_ns_per_m3: g("r2_ns_per_m3"),
            })
        }
        EffectId::Creep => {
            effects.creep = Some(Creep {
                k_n_per_m: g("k_n_per_m"),
                tau_s: g("tau_s"),
            })
        }
        EffectId::StiffnessDrift => {
            effects.stiffness_drift = Some(StiffnessDrift {
                dk0_dt_n_per_m_s: g("dk0_dt_n_per_m_s"),
            })
        }
        EffectId::ChannelDelay => {
            effects.channel_delay = Some(ChannelDelay {
                delay_s: g("delay_s"),
            })
        }
    }
}

/// Default hyper-parameter of a forced effect: searched like a candidate.
fn forced_hyper(p: &Prepared, built: &Built, e: EffectId) -> f64 {
    evaluate(p, built, Term::Effect(e)).hyper.unwrap_or(0.0)
}

/// Fits `spec` fully and describes it.
fn describe(p: &Prepared, built: &Built, folds: usize) -> (FittedModel, DVector<f64>) {
    let fit = built.gram.fit();
    let cov = built.gram.block_covariance(&fit.beta);
    let mut effects = Effects::default();
    let mut se_map = serde_json::Map::new();
    let (mut r, mut s) = (0.0, 0.0);
    for (i, role) in built.roles.iter().enumerate() {
        match *role {
            Role::Mic => s = fit.beta[i],
            Role::R => r = -fit.beta[i],
            _ => {}
        }
    }
    for &(e, h) in &built.spec.effects {
        let idx: Vec<usize> = built
            .roles
            .iter()
            .enumerate()
            .filter(|(_, r)| matches!(r, Role::Eff(id, _) if *id == e))
            .map(|(i, _)| i)
            .collect();
        let coef: Vec<f64> = idx.iter().map(|&i| fit.beta[i]).collect();
        let se: Vec<f64> = idx.iter().map(|&i| cov[(i, i)].max(0.0).sqrt()).collect();
        let params = effect_params(e, h, &coef);
        set_effect(&mut effects, e, &params);
        if !se.is_empty() {
            se_map.insert(e.as_str().into(), effect_se(e, &se));
        }
    }
    // K(x) = sum_i b_i P_i(u), u = x / xs  ->  monomial coefficients in x,
    // as one linear map T of the fitted coefficients (so the standard errors
    // follow from the block covariance: diag(T C T^T)).
    let mono = legendre_monomials(built.spec.order);
    let np = fit.beta.len();
    let mut t_map = nalgebra::DMatrix::<f64>::zeros(built.spec.order + 1, np);
    for (col, role) in built.roles.iter().enumerate() {
        if let Role::K(i) = *role {
            for (j, c) in mono[i].iter().enumerate() {
                t_map[(j, col)] -= c / p.x_scale.powi(j as i32);
            }
        }
    }
    // Stiffness drift: the column x (t - t_mid) moves K(0) linearly in time;
    // K(x) is stated at the start of the recording (t = 0).
    let mut reference_time_s = None;
    if let Some(col) = built
        .roles
        .iter()
        .position(|r| *r == Role::Eff(EffectId::StiffnessDrift, 0))
    {
        let t_mid_abs = p.d.t0_s + (p.y.len() as f64 - 1.0) / 2.0 / p.fs();
        // K0(t) = K0_mid + slope (t - t_mid_abs), slope = -beta_d.
        t_map[(0, col)] += t_mid_abs;
        reference_time_s = Some(0.0);
    }
    let k: Vec<f64> = (&t_map * &fit.beta).iter().copied().collect();
    let k_cov = &t_map * &cov * t_map.transpose();
    let k_se: Vec<f64> = (0..k.len())
        .map(|j| k_cov[(j, j)].max(0.0).sqrt())
        .collect();
    let r_se = built
        .roles
        .iter()
        .position(|r| *r == Role::R)
        .map_or(0.0, |i| cov[(i, i)].max(0.0).sqrt());
    let model = FittedModel {
        order: built.spec.order,
        effect_ids: built.spec.effects.iter().map(|e| e.0).collect(),
        effects,
        effects_se: serde_json::Value::Object(se_map),
        stiffness_coefficients_n_per_m_pow_i_plus_1: k,
        stiffness_coefficients_se_n_per_m_pow_i_plus_1: k_se,
        reference_time_s,
        r_ns_per_m: r,
        r_se_ns_per_m: r_se,
        force_per_mic_n_per_v: s,
        residual_percent: pct(p, fit.sse),
        cv_residual_percent: pct(p, built.gram.cv_sse(folds)),
        stiffness_covariance: (0..k_cov.nrows())
            .map(|i| (0..k_cov.ncols()).map(|j| k_cov[(i, j)]).collect())
            .collect(),
        dk0_dt_n_per_m_s: effects.stiffness_drift.map_or(0.0, |d| d.dk0_dt_n_per_m_s),
    };
    (model, fit.beta)
}

fn residual(p: &Prepared, built: &Built, beta: &DVector<f64>) -> (Vec<f64>, Vec<f64>) {
    let n = p.y.len();
    let mut model = vec![0.0; n];
    for (&c, b) in built.ids.iter().zip(beta.iter()) {
        for (m, v) in model.iter_mut().zip(p.column(c).iter()) {
            *m += b * v;
        }
    }
    let res = p.y.iter().zip(&model).map(|(y, m)| y - m).collect();
    (res, model)
}

/// Ranks every candidate against `built`.
fn rank(
    p: &Prepared,
    built: &Built,
    opts: &EngineOptions,
    noise_percent: f64,
) -> Vec<(Term, Evaluated, CandidateResult)> {
    let mut terms: Vec<Term> = EffectId::ALL
        .into_iter()
        .filter(|e| !built.spec.effects.iter().any(|(x, _)| x == e))
        .map(Term::Effect)
        .collect();
    if built.spec.order < opts.max_order {
        terms.push(Term::StiffnessOrder);
    }
    let n_tests = terms.len().max(1) as f64;
    let base_cv = built.gram.cv_sse(opts.folds);
    let intercept = built.roles.iter().position(|r| *r == Role::Intercept);
    let mut out = Vec::new();
    for term in terms {
        let ev = evaluate(p, built, term);
        // Hyper-parameter searches test many shapes: count them as 4 tests more.
        let searched = matches!(
            term,
            Term::Effect(EffectId::CoulombFriction)
                | Term::Effect(EffectId::Creep)
                | Term::Effect(EffectId::ChannelDelay)
        );
        let alpha = opts.alpha / n_tests / if searched { 5.0 } else { 1.0 };
        let cv = ev.gram.cv_sse(opts.folds);
        // Identifiability: variance inflation of the new regressors against the model's.
        let total = ev.gram.total().g;
        let pk = ev.gram.p - ev.q;
        let (mut vif, mut with) = (1.0f64, String::new());
        let (check, others): (Vec<usize>, Vec<usize>) = if ev.drop_mic {
            // The shifted microphone against the rest, with the linear-delay column.
            (vec![], vec![])
        } else {
            ((pk..ev.gram.p).collect(), (0..pk).collect())
        };
        for &j in &check {
            let r2 = collinearity_r2(&total, j, &others, intercept);
            let v = 1.0 / (1.0 - r2).max(1e-12);
            if v >= vif {
                vif = v;
                // The single model term most correlated with this regressor.
                let mut best = (0.0, String::new());
                for &o in &others {
                    if Some(o) == intercept {
                        continue;
                    }
                    let r2o = collinearity_r2(&total, j, &[o, intercept.unwrap_or(o)], intercept);
                    if r2o > best.0 {
                        best = (r2o, built.roles[o].name());
                    }
                }
                with = best.1;
            }
        }
        if ev.drop_mic {
            // The delay's linear column d s mic' against the model (mic' is
            // close to a damping force near resonance).
            let lin = built.with(p, false, &[dmic_of(built)], false);
            let g = lin.total().g;
            let j = lin.p - 1;
            let r2 = collinearity_r2(&g, j, &(0..j).collect::<Vec<_>>(), intercept);
            vif = 1.0 / (1.0 - r2).max(1e-12);
            with = Role::R.name();
        }
        let identifiable = vif <= opts.vif_limit;
        let (params, se) = match term {
            Term::Effect(e) => {
                let coef: Vec<f64> = (pk..ev.gram.p).map(|i| ev.beta[i]).collect();
                (
                    effect_params(e, ev.hyper.unwrap_or(0.0), &coef),
                    effect_se(e, &ev.se),
                )
            }
            Term::StiffnessOrder => {
                let power = built.spec.order + 1;
                (serde_json::json!({ "order": power }), serde_json::json!({}))
            }
        };
        // Practical relevance: the share of the structured (held-out) error it removes.
        let me_base = model_error(pct(p, base_cv), noise_percent);
        let me_cand = model_error(pct(p, cv), noise_percent);
        let reduction = if me_base > 0.0 {
            100.0 * (1.0 - me_cand / me_base)
        } else {
            0.0
        };
        // An effect enters only with plausible parameters and a held-out
        // gain that holds in most folds, not one fold's luck (issue 22).
        let implausible = match term {
            Term::Effect(e) => implausible(p, built, &ev, e, &params),
            Term::StiffnessOrder => None,
        };
        let folds_won = {
            let (b, c) = (
                built.gram.cv_sse_folds(opts.folds),
                ev.gram.cv_sse_folds(opts.folds),
            );
            b.iter().zip(&c).filter(|(b, c)| c < b).count()
        };
        let stable = 2 * folds_won > opts.folds;
        let significant =
            ev.p_value < alpha && cv < base_cv && reduction >= opts.min_reduction_percent;
        let not_added = match (&implausible, stable) {
            (Some(why), _) => Some(format!("implausible parameters ({why})")),
            (None, false) => Some(format!(
                "the held-out gain is not stable (lower held-out error in {folds_won} of {} folds)",
                opts.folds
            )),
            (None, true) => None,
        };
        let note = match (identifiable, significant) {
            (true, _) => None,
            (false, false) => Some(format!(
                "cannot tell from this data: {} is collinear with {} (variance inflation {:.0}); to separate them: {}",
                term.name(),
                with,
                vif,
                term.separating_experiment()
            )),
            (false, true) => Some(format!(
                "{} is strongly collinear with {} (variance inflation {:.0}); this data still separates it, confirm with {}",
                term.name(),
                with,
                vif,
                term.separating_experiment()
            )),
        };
        let res = CandidateResult {
            effect: term.name().into(),
            error_reduction_percent: reduction,
            residual_reduction_percent: 100.0 * (1.0 - (cv / base_cv).sqrt()),
            significant,
            p_value: ev.p_value,
            alpha,
            parameters: params,
            parameters_se: se,
            variance_inflation: vif,
            identifiable,
            collinear_with: with,
            note,
            cv_residual_percent: pct(p, cv),
            hyper: ev.hyper,
            cv_sse: cv,
            not_added,
        };
        out.push((term, ev, res));
    }
    out
}

/// True for a number above zero (false for NaN).
fn is_positive(v: f64) -> bool {
    v > 0.0
}

/// Why a candidate's fitted parameters are not physical for a suspension
/// part on the bench (None: plausible). Friction, v|v| damping and creep
/// are positive; damping that depends on x keeps the total damping
/// positive over the measured range; drift moves K(0) by less than half
/// over the record; a channel delay is shorter than a quarter of a typical
/// period.
fn implausible(
    p: &Prepared,
    built: &Built,
    ev: &Evaluated,
    e: EffectId,
    params: &serde_json::Value,
) -> Option<String> {
    let g = |k: &str| params.get(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
    let r_model = built
        .roles
        .iter()
        .position(|r| *r == Role::R)
        .filter(|_| !ev.drop_mic)
        .map_or(f64::NAN, |i| -ev.beta[i]);
    let k_scale = p.d.mass_kg * p.omega_typ * p.omega_typ;
    match e {
        EffectId::CoulombFriction if !is_positive(g("force_n")) => {
            Some(format!("friction force {:.3e} N <= 0", g("force_n")))
        }
        EffectId::QuadraticDamping if !is_positive(g("coeff_ns2_per_m2")) => Some(format!(
            "v|v| damping {:.3e} N s^2/m^2 <= 0",
            g("coeff_ns2_per_m2")
        )),
        EffectId::Creep if !is_positive(g("k_n_per_m")) => {
            Some(format!("creep stiffness {:.3e} N/m <= 0", g("k_n_per_m")))
        }
        EffectId::DampingVsDisplacement if r_model.is_finite() => {
            let (r1, r2) = (g("r1_ns_per_m2"), g("r2_ns_per_m3"));
            let (lo, hi) =
                p.d.x_m
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            let rmin = [lo, hi, 0.0]
                .iter()
                .map(|x| r_model + r1 * x + r2 * x * x)
                .fold(f64::INFINITY, f64::min);
            (!is_positive(rmin)).then(|| {
                format!("the total damping R + r1 x + r2 x^2 falls to {rmin:.3e} N s/m <= 0 inside the range")
            })
        }
        EffectId::StiffnessDrift => {
            let change = (g("dk0_dt_n_per_m_s") * p.duration_s).abs();
            (!is_positive(0.5 * k_scale - change)).then(|| {
                format!(
                    "drift moves K(0) by {change:.3e} N/m over the record, more than half the stiffness ({k_scale:.3e} N/m)"
                )
            })
        }
        EffectId::ChannelDelay => {
            let quarter = 0.25 * 2.0 * std::f64::consts::PI / p.omega_typ;
            (!is_positive(quarter - g("delay_s").abs())).then(|| {
                format!(
                    "delay {:.3e} s is not shorter than a quarter period ({quarter:.3e} s)",
                    g("delay_s")
                )
            })
        }
        _ => None,
    }
}

fn choose_order(p: &Prepared, forced: &[(EffectId, f64)], opts: &EngineOptions) -> (usize, String) {
    if let Some(o) = opts.order {
        return (o.min(opts.max_order), format!("order {o} as given"));
    }
    // Smallest order after which neither of the next two powers is significant.
    let mut order = 1;
    let alpha = opts.alpha / 2.0;
    while order < opts.max_order {
        let built = Built::new(
            p,
            Spec {
                order,
                effects: forced.to_vec(),
            },
        );
        let base_cv = built.gram.cv_sse(opts.folds);
        let mut grew = None;
        for extra in 1..=2usize {
            if order + extra > opts.max_order {
                break;
            }
            let new: Vec<Col> = (order + 1..order + 1 + extra).map(Col::K).collect();
            let gram = built.with(p, false, &new, false);
            let fit = gram.fit();
            let (pv, _) = wald_last(&gram, &fit.beta, extra);
            if pv < alpha && gram.cv_sse(opts.folds) < base_cv {
                grew = Some(order + extra);
                break;
            }
        }
        match grew {
            Some(o) => order = o,
            None => break,
        }
    }
    (
        order,
        format!("order {order} chosen from the data (blocked CV and block-robust test)"),
    )
}

/// Runs the whole engine on prepared data.
pub fn run(d: &ForceBalanceData, opts: &EngineOptions) -> Result<EngineResult, String> {
    let p = Prepared::new(d, opts.blocks)?;
    // Forced effects: their hyper-parameters are searched against the K-only model.
    let mut forced: Vec<(EffectId, f64)> = Vec::new();
    let mut forced_ids = opts.forced.clone();
    forced_ids.dedup();
    let (order0, _) = choose_order(&p, &[], opts);
    for &e in &forced_ids {
        if forced.iter().any(|f| f.0 == e) {
            continue;
        }
        let built = Built::new(
            &p,
            Spec {
                order: order0,
                effects: forced.clone(),
            },
        );
        forced.push((e, forced_hyper(&p, &built, e)));
    }
    let (order, order_note) = choose_order(&p, &forced, opts);
    let mut built = Built::new(
        &p,
        Spec {
            order,
            effects: forced.clone(),
        },
    );
    let (base, base_beta) = describe(&p, &built, opts.folds);
    let (base_res, _) = residual(&p, &built, &base_beta);
    let mut ladder = vec![LadderStep {
        effects: forced.iter().map(|e| e.0.as_str().to_string()).collect(),
        order,
        residual_percent: base.residual_percent,
        cv_residual_percent: base.cv_residual_percent,
        model_error_percent: 0.0,
        added: None,
        p_value: None,
    }];
    let mut candidates: Option<Vec<CandidateResult>> = None;
    let mut ladder_names: Vec<String> = ladder[0].effects.clone();
    let mut noise_percent = f64::INFINITY;
    // The residual, modelled force and spectrum of `built` while it is the
    // model of the step (the final model's when the ladder stops there),
    // and the base model's spectrum (the first step's).
    let mut current: Option<(Vec<f64>, Vec<f64>, super::spectrum::ResidualSpectrum)> = None;
    let mut base_spectrum = None;
    let mut skipped: Vec<String> = Vec::new();
    for _ in 0..opts.max_steps {
        // Noise floor of this step's residual (never rising along the ladder:
        // a big missing effect can only lift the estimate).
        let fit = built.gram.fit();
        let (res, modelled) = residual(&p, &built, &fit.beta);
        let sp = super::spectrum::residual_spectrum(&res, p.fs(), 0.5);
        noise_percent = noise_percent.min(100.0 * sp.noise_variance.sqrt() / p.rms_y);
        if base_spectrum.is_none() {
            base_spectrum = Some(sp.clone());
        }
        current = Some((res, modelled, sp));
        let ranked = rank(&p, &built, opts, noise_percent);
        let best = ranked
            .iter()
            .filter(|r| r.2.significant && r.2.not_added.is_none())
            .min_by(|a, b| a.2.cv_sse.total_cmp(&b.2.cv_sse))
            .map(|r| (r.0, r.1.hyper, r.2.p_value, r.2.cv_sse));
        // A significant candidate that ranked better but may not enter
        // (issue 22): said, so that the choice is traceable.
        for r in ranked.iter().filter(|r| r.2.significant) {
            if let (Some(why), true) = (&r.2.not_added, best.is_none_or(|b| r.2.cv_sse < b.3)) {
                if opts.ladder {
                    skipped.push(format!("the ladder did not add {}: {why}", r.2.effect));
                }
            }
        }
        let best = best.map(|b| (b.0, b.1, b.2));
        if candidates.is_none() {
            candidates = Some(ranked.iter().map(|r| r.2.clone()).collect());
        }
        if !opts.ladder {
            // An explicit model: the candidates are reported, never added.
            break;
        }
        let Some((term, hyper, pv)) = best else { break };
        let mut spec = built.spec.clone();
        match term {
            Term::StiffnessOrder => spec.order += 1,
            Term::Effect(e) => spec.effects.push((e, hyper.unwrap_or(0.0))),
        }
        built = Built::new(&p, spec);
        current = None;
        let fit = built.gram.fit();
        ladder_names.push(term.name().into());
        ladder.push(LadderStep {
            effects: ladder_names.clone(),
            order: built.spec.order,
            residual_percent: pct(&p, fit.sse),
            cv_residual_percent: pct(&p, built.gram.cv_sse(opts.folds)),
            model_error_percent: 0.0,
            added: Some(term.name().into()),
            p_value: Some(pv),
        });
    }
    let (model, beta) = describe(&p, &built, opts.folds);
    // The fit of the same Gram gives the same coefficients: the step's
    // residual and spectrum are the final model's.
    let (res, modelled, spectrum) = current.unwrap_or_else(|| {
        let (res, modelled) = residual(&p, &built, &beta);
        let sp = super::spectrum::residual_spectrum(&res, p.fs(), 0.5);
        (res, modelled, sp)
    });
    let base_spectrum =
        base_spectrum.unwrap_or_else(|| super::spectrum::residual_spectrum(&base_res, p.fs(), 0.5));
    let noise_floor_percent = 100.0 * spectrum.noise_variance.sqrt() / p.rms_y;
    // Every model-error figure of the document is one formula: the in-sample
    // residual against the final model's noise floor (held-out figures are
    // reported as such: cv_residual_percent, error_reduction_percent).
    for step in &mut ladder {
        step.model_error_percent = model_error(step.residual_percent, noise_floor_percent);
    }
    // Reported reductions use the final model's noise floor (the cleanest
    // residual); the decisions above used each step's own estimate.
    let base_me = model_error(base.cv_residual_percent, noise_floor_percent);
    let mut candidates = candidates.unwrap_or_default();
    for c in &mut candidates {
        let me = model_error(c.cv_residual_percent, noise_floor_percent);
        c.error_reduction_percent = if base_me > 0.0 {
            100.0 * (1.0 - me / base_me)
        } else {
            0.0
        };
    }
    candidates.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(a.cv_sse.total_cmp(&b.cv_sse))
    });
    Ok(EngineResult {
        skipped,
        model_error_percent: model_error(model.residual_percent, noise_floor_percent),
        base_model_error_percent: model_error(base.residual_percent, noise_floor_percent),
        base,
        model,
        candidates,
        ladder,
        noise_floor_percent,
        residual_n: res,
        base_residual_n: base_res,
        modelled_force_n: modelled,
        spectrum,
        base_spectrum,
        order_note,
    })
}

impl EngineResult {
    /// The refitted model in the identification's report form.
    pub fn report_model(&self) -> crate::identify::Model {
        crate::identify::Model {
            effects: self.model.effects,
            residual_percent: self.model.residual_percent,
            noise_floor_percent: self.noise_floor_percent,
            model_error_percent: self.model_error_percent,
        }
    }

    /// The `diagnostics` document (issue 5 names plus the comparison data the plots draw).
    pub fn diagnostics_json(&self, d: &ForceBalanceData) -> serde_json::Value {
        use serde_json::json;
        let describe = |m: &FittedModel, me: f64| {
            json!({
                "effects": m.effect_ids.iter().map(|e| e.as_str()).collect::<Vec<_>>(),
                "parameters": m.effects,
                "parameters_se": m.effects_se,
                "order": m.order,
                "stiffness_coefficients_n_per_m_pow_i_plus_1": m.stiffness_coefficients_n_per_m_pow_i_plus_1,
                "r_ns_per_m": m.r_ns_per_m,
                "force_per_mic_n_per_v": m.force_per_mic_n_per_v,
                "residual_percent": m.residual_percent,
                "cv_residual_percent": m.cv_residual_percent,
                "model_error_percent": me,
            })
        };
        json!({
            "candidates": self.candidates,
            "ladder": self.ladder,
            "base_model": describe(&self.base, self.base_model_error_percent),
            "final_model": describe(&self.model, self.model_error_percent),
            "noise_floor_percent": self.noise_floor_percent,
            "order_note": self.order_note,
            "method": {
                "cross_validation": "blocked, 5 contiguous folds of 8 time blocks each",
                "test": "Wald test with batch-means (40 contiguous blocks) covariance, Bonferroni over candidates; hyper-parameter searches count 5 times",
                "identifiability": "variance inflation of the candidate's regressors against the model's; above 200 and not significant: cannot tell from this data",
                "relevance": "a significant candidate removes at least 5 % of the held-out model error (noise floor of the step's residual)",
                "model_error": "sqrt(residual^2 - noise_floor^2), residual on held-out blocks for candidates and ladder",
            },
            "comparison": comparison(self, d),
        })
    }
}

fn mean_by_bins(
    key: &[f64],
    val: &[f64],
    mask: impl Fn(usize) -> bool,
    lo: f64,
    hi: f64,
    nb: usize,
) -> Vec<Option<f64>> {
    let mut sum = vec![0.0; nb];
    let mut cnt = vec![0usize; nb];
    let w = (hi - lo) / nb as f64;
    for (i, (&k, &v)) in key.iter().zip(val).enumerate() {
        if !mask(i) || w <= 0.0 {
            continue;
        }
        let b = (((k - lo) / w) as usize).min(nb - 1);
        sum[b] += v;
        cnt[b] += 1;
    }
    sum.iter()
        .zip(&cnt)
        .map(|(s, &c)| (c >= 20).then(|| s / c as f64))
        .collect()
}

/// Range of the fundamental frequency (Hz) from the upward zero crossings of x.
pub fn fundamental_range_hz(x: &[f64], fs: f64) -> Option<(f64, f64)> {
    let mean = x.iter().sum::<f64>() / x.len().max(1) as f64;
    let amp = x.iter().fold(0.0f64, |m, v| m.max((v - mean).abs()));
    let mut crossings = Vec::new();
    let mut armed = false;
    for i in 1..x.len() {
        let (a, b) = (x[i - 1] - mean, x[i] - mean);
        if b < -0.2 * amp {
            armed = true;
        }
        if armed && a < 0.0 && b >= 0.0 {
            crossings.push(i as f64 - 1.0 + a / (a - b));
            armed = false;
        }
    }
    let mut f: Vec<f64> = crossings.windows(2).map(|w| fs / (w[1] - w[0])).collect();
    if f.len() < 4 {
        return None;
    }
    f.sort_by(|a, b| a.total_cmp(b));
    Some((f[f.len() / 20], f[f.len() - 1 - f.len() / 20]))
}

fn comparison(r: &EngineResult, d: &ForceBalanceData) -> serde_json::Value {
    use serde_json::json;
    let n = d.x_m.len();
    let fs = d.sample_rate_hz;
    let y: Vec<f64> = d.a_m_per_s2.iter().map(|a| a * d.mass_kg).collect();
    // Detail: 0.12 s around the largest displacement.
    let imax = (0..n)
        .max_by(|&a, &b| d.x_m[a].abs().total_cmp(&d.x_m[b].abs()))
        .unwrap_or(0);
    let half = ((0.06 * fs) as usize).max(1);
    let (s, e) = (imax.saturating_sub(half), (imax + half).min(n));
    let step = ((e - s) / 600).max(1);
    let idx: Vec<usize> = (s..e).step_by(step).collect();
    let detail = json!({
        "t_s": idx.iter().map(|&i| d.t0_s + i as f64 / fs).collect::<Vec<_>>(),
        "x_m": idx.iter().map(|&i| d.x_m[i]).collect::<Vec<_>>(),
        "measured_force_n": idx.iter().map(|&i| y[i]).collect::<Vec<_>>(),
        "modelled_force_n": idx.iter().map(|&i| r.modelled_force_n[i]).collect::<Vec<_>>(),
        "base_modelled_force_n": idx.iter().map(|&i| y[i] - r.base_residual_n[i]).collect::<Vec<_>>(),
    });
    // Envelope: RMS per bucket over the whole record.
    let buckets = 200.min(n);
    let rms = |sig: &[f64], a: usize, b: usize| {
        (sig[a..b].iter().map(|v| v * v).sum::<f64>() / (b - a).max(1) as f64).sqrt()
    };
    let mut env_t = Vec::new();
    let (mut env_m, mut env_r, mut env_b) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..buckets {
        let (a, b) = (k * n / buckets, (k + 1) * n / buckets);
        if b <= a {
            continue;
        }
        env_t.push(d.t0_s + (a + b) as f64 / 2.0 / fs);
        env_m.push(rms(&y, a, b));
        env_r.push(rms(&r.residual_n, a, b));
        env_b.push(rms(&r.base_residual_n, a, b));
    }
    let nb = 24;
    let (xlo, xhi) = d
        .x_m
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let (vlo, vhi) = d
        .v_m_per_s
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let centres = |lo: f64, hi: f64| -> Vec<f64> {
        (0..nb)
            .map(|b| lo + (b as f64 + 0.5) * (hi - lo) / nb as f64)
            .collect()
    };
    let v = &d.v_m_per_s;
    let vs_x = |res: &[f64]| {
        json!({
            "positive_v_n": mean_by_bins(&d.x_m, res, |i| v[i] > 0.0, xlo, xhi, nb),
            "negative_v_n": mean_by_bins(&d.x_m, res, |i| v[i] <= 0.0, xlo, xhi, nb),
        })
    };
    let vs_v = |res: &[f64]| mean_by_bins(v, res, |_| true, vlo, vhi, nb);
    // Samples per bin: a bin mean of white noise of RMS sigma scatters by sigma / sqrt(count).
    let counts = |key: &[f64], mask: &dyn Fn(usize) -> bool, lo: f64, hi: f64| -> Vec<f64> {
        let w = (hi - lo) / nb as f64;
        let mut c = vec![0.0; nb];
        for (i, &k) in key.iter().enumerate() {
            if mask(i) && w > 0.0 {
                c[(((k - lo) / w) as usize).min(nb - 1)] += 1.0;
            }
        }
        c
    };
    let noise_rms_n = r.spectrum.noise_variance.max(0.0).sqrt();
    // The base model's residual spectrum on the same bins as the final one.
    let base_sp = &r.base_spectrum;
    // Spectrum on about 300 log-spaced points.
    let sp = &r.spectrum;
    let (mut f_out, mut p_out, mut n_out, mut b_out) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    if sp.freq_hz.len() > 2 {
        let f1 = sp.freq_hz[1];
        let f2 = *sp.freq_hz.last().expect("non-empty");
        let pts = 300;
        let mut k = 1;
        for j in 1..=pts {
            let edge = f1 * (f2 / f1).powf(j as f64 / pts as f64);
            let start = k;
            while k < sp.freq_hz.len() && sp.freq_hz[k] <= edge {
                k += 1;
            }
            if k > start {
                let m = (k - start) as f64;
                f_out.push(sp.freq_hz[start..k].iter().sum::<f64>() / m);
                p_out.push(sp.psd[start..k].iter().sum::<f64>() / m);
                n_out.push(sp.noise_psd[start..k].iter().sum::<f64>() / m);
                b_out.push(if base_sp.psd.len() == sp.psd.len() {
                    base_sp.psd[start..k].iter().sum::<f64>() / m
                } else {
                    f64::NAN
                });
            }
        }
    }
    let bands: Vec<[f64; 2]> = match fundamental_range_hz(&d.x_m, fs) {
        Some((lo, hi)) => (1..=10).map(|h| [h as f64 * lo, h as f64 * hi]).collect(),
        None => vec![],
    };
    json!({
        "detail": detail,
        "envelope": {"t_s": env_t, "measured_rms_n": env_m, "residual_rms_n": env_r, "base_residual_rms_n": env_b},
        "noise_rms_n": noise_rms_n,
        "residual_vs_x": {"x_m": centres(xlo, xhi), "final": vs_x(&r.residual_n), "base": vs_x(&r.base_residual_n),
            "positive_v_count": counts(&d.x_m, &|i| v[i] > 0.0, xlo, xhi),
            "negative_v_count": counts(&d.x_m, &|i| v[i] <= 0.0, xlo, xhi)},
        "residual_vs_v": {"v_m_per_s": centres(vlo, vhi), "final_n": vs_v(&r.residual_n), "base_n": vs_v(&r.base_residual_n),
            "count": counts(v, &|_| true, vlo, vhi)},
        "spectrum": {"freq_hz": f_out, "psd_n2_per_hz": p_out, "base_psd_n2_per_hz": b_out.into_iter().map(|v| v.is_finite().then_some(v)).collect::<Vec<_>>(),
            "noise_psd_n2_per_hz": n_out, "harmonic_bands_hz": bands},
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legendre_monomials_match_recurrence() {
        let m = legendre_monomials(4);
        // P_4 = (35 u^4 - 30 u^2 + 3) / 8
        let want = [3.0 / 8.0, 0.0, -30.0 / 8.0, 0.0, 35.0 / 8.0];
        for (a, b) in m[4].iter().zip(want) {
            assert!((a - b).abs() < 1e-12);
        }
        let x = [0.3, -0.7];
        let u = [0.3, -0.7];
        let cols = legendre_cols(&x, &u, 4);
        let p4 = |u: f64| (35.0 * u.powi(4) - 30.0 * u * u + 3.0) / 8.0;
        assert!((cols[4][1] - (-0.7) * p4(-0.7)).abs() < 1e-12);
    }

    #[test]
    fn creep_columns_together_equal_each_alone() {
        let fs: f64 = 3000.0;
        let x: Vec<f64> = (0..5000)
            .map(|i| (2.0 * 3.1 * 7.0 * i as f64 / fs).sin() * 1e-3 + 1e-5 * (i % 13) as f64)
            .collect();
        let taus: Vec<f64> = (0..11).map(|k| 1e-3 * 2f64.powi(k)).collect();
        let pre = prefix_sums(&x);
        for m in [1, 2, 17, 4999, 5000] {
            assert_eq!(pre[m].to_bits(), x[..m].iter().sum::<f64>().to_bits());
        }
        for (rest, prefix) in [(true, None), (false, None), (false, Some(pre.as_slice()))] {
            let all = creep_columns(&x, fs, &taus, rest, prefix);
            for (tau, col) in taus.iter().zip(&all) {
                let alone = creep_column_alone(&x, fs, *tau, rest);
                assert!(col
                    .iter()
                    .zip(&alone)
                    .all(|(a, b)| a.to_bits() == b.to_bits()));
            }
        }
    }

    #[test]
    fn shift_without_clamps_inside_equals_the_clamped_formula() {
        let fs: f64 = 3000.0;
        let mic: Vec<f64> = (0..50)
            .map(|i| ((i * 37 % 11) as f64 - 5.0) / 3.0)
            .collect();
        let n = mic.len() as isize;
        for d in [0.0f64, 1e-5, -1e-5, 2.7e-3, -2.7e-3, 0.02, -0.02, 0.5, -0.5] {
            let s = d * fs;
            let k = s.floor();
            let f = s - k;
            let k = k as isize;
            let at = |i: isize| mic[i.clamp(0, n - 1) as usize];
            let c = [
                -f * (f - 1.0) * (f - 2.0) / 6.0,
                (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0,
                -(f + 1.0) * f * (f - 2.0) / 2.0,
                (f + 1.0) * f * (f - 1.0) / 6.0,
            ];
            let want: Vec<f64> = (0..n)
                .map(|i| {
                    let j = i + k;
                    c[0] * at(j - 1) + c[1] * at(j) + c[2] * at(j + 1) + c[3] * at(j + 2)
                })
                .collect();
            let got = shifted(&mic, fs, d);
            assert_eq!(got.len(), want.len());
            assert!(
                got.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "d {d}"
            );
        }
    }

    #[test]
    fn shift_interpolates_a_sine_exactly_enough() {
        let fs = 8000.0;
        let s: Vec<f64> = (0..800)
            .map(|i| (2.0 * 3.1 * 50.0 * i as f64 / fs).sin())
            .collect();
        let d = 3.3e-4;
        let sh = shifted(&s, fs, d);
        for (i, v) in sh.iter().enumerate().take(790).skip(10) {
            let want = (2.0 * 3.1 * 50.0 * (i as f64 / fs + d)).sin();
            assert!((v - want).abs() < 1e-6);
        }
    }
}
