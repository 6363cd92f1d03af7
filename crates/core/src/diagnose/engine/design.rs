//! The design of the force balance on the data: its columns (K(x) terms,
//! damping, effect regressors, the shifted microphone), computed once and
//! kept with their block cross products, and a model built on them.

use crate::diagnose::regress::{self, block_bounds, BlockGram};
use crate::effects::EffectId;
use crate::identify::ForceBalanceData;
use nalgebra::{DMatrix, DVector};
use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

/// Model specification: K order plus effects with their hyper-parameter.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Spec {
    pub(super) order: usize,
    pub(super) effects: Vec<(EffectId, f64)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Role {
    Mic,
    Intercept,
    K(usize),
    R,
    Eff(EffectId, usize),
}

impl Role {
    pub(super) fn name(self) -> String {
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
    pub(super) d: &'a ForceBalanceData,
    pub(super) y: Vec<f64>,
    /// x / x_scale in [-1, 1].
    u: Vec<f64>,
    pub(super) x_scale: f64,
    pub(super) v_max: f64,
    /// RMS(v) / RMS(x): a typical angular frequency of the motion (rad/s).
    pub(super) omega_typ: f64,
    t_centered: Vec<f64>,
    bounds: Vec<(usize, usize)>,
    pub(super) rms_y: f64,
    pub(super) duration_s: f64,
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
pub(super) enum Col {
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
pub(super) fn effect_ids(e: EffectId, h: f64) -> Vec<Col> {
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
pub(super) fn legendre_monomials(order: usize) -> Vec<Vec<f64>> {
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
    // Straight into the K columns: rows then columns held both at once
    // (twice the columns' memory).
    let mut cols: [Vec<f64>; K] = std::array::from_fn(|_| Vec::with_capacity(x.len()));
    for &xi in x {
        for j in 0..K {
            cols[j].push(xi - xr[j]);
            xr[j] += alpha[j] * (xi - xr[j]);
        }
    }
    cols.into()
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
            u: d.x_m.iter().map(|x| x / x_scale).collect(),
            x_scale,
            v_max,
            omega_typ,
            t_centered: (0..n).map(|i| i as f64 / fs - t_mid).collect(),
            yy: bounds
                .iter()
                .map(|&(s, e)| regress::dot(&y[s..e], &y[s..e]))
                .collect(),
            bounds,
            rms_y,
            duration_s: n as f64 / fs,
            y,
            cache: RefCell::new(Cache::default()),
            x_prefix: prefix_sums(&d.x_m),
        })
    }

    pub(super) fn fs(&self) -> f64 {
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
            EffectId::Hysteresis => vec![regress::hysteresis_column(x, h)],
            EffectId::ReversibleSoftening => {
                vec![regress::softening_column(x, self.fs(), h)]
            }
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
            // made when first used and kept in the cache (a copy of a kept
            // vector of ones held it twice)
            Col::Ones => vec![1.0; self.d.x_m.len()],
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
    pub(super) fn stage_creep(&self, built: &Built, grid: &[f64]) {
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

    pub(super) fn unstage(&self) {
        self.cache.borrow_mut().staged.clear();
    }

    /// A model column, computed once and kept.
    pub(super) fn column(&self, c: Col) -> Rc<[f64]> {
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
                    regress::dots(&z[s..e], &o, &mut out);
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
            .map(|(blk, &(s, e))| regress::Block {
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
pub(super) struct Built {
    pub(super) spec: Spec,
    pub(super) ids: Vec<Col>,
    pub(super) roles: Vec<Role>,
    pub(super) gram: BlockGram,
}

impl Built {
    pub(super) fn new(p: &Prepared, spec: Spec) -> Built {
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
    pub(super) fn with(&self, p: &Prepared, drop_mic: bool, new: &[Col], trial: bool) -> BlockGram {
        let mut ids: Vec<Col> = self.ids[usize::from(drop_mic)..].to_vec();
        ids.extend_from_slice(new);
        p.gram(&ids, if trial { new } else { &[] })
    }
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
