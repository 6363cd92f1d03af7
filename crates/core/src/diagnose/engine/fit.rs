//! One candidate term tried on a model (hyper-parameter search, block-robust
//! Wald test), and a model's full fit described: effect parameters, K(x)
//! coefficients with standard errors, residual.

use super::design::{effect_ids, legendre_monomials, Built, Col, Prepared, Role};
use super::options::Term;
use super::result::FittedModel;
use crate::diagnose::regress::{self, BlockGram};
use crate::diagnose::stats::{f_upper_p, t_two_sided_p};
use crate::effects::{
    ChannelDelay, CoulombFriction, Creep, DampingVsDisplacement, EffectId, Effects, Hysteresis,
    QuadraticDamping, ReversibleSoftening, StiffnessDrift,
};
use nalgebra::DVector;

pub(super) fn golden_min(
    mut lo: f64,
    mut hi: f64,
    iters: usize,
    mut f: impl FnMut(f64) -> f64,
) -> (f64, f64) {
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
pub(super) fn dmic_of(built: &Built) -> Col {
    match built.ids[0] {
        Col::Mic(d) => Col::DMic(d),
        other => unreachable!("the first column is the microphone, not {other:?}"),
    }
}

/// Block-robust Wald test of the last `q` coefficients of a fit of `gram`.
pub(super) fn wald_last(gram: &BlockGram, beta: &DVector<f64>, q: usize) -> (f64, Vec<f64>) {
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
        let inv = regress::inverse_spd(&sub);
        let w = (g.transpose() * inv * &g)[(0, 0)];
        let qf = q as f64;
        let f = w * (nb - qf) / (qf * (nb - 1.0));
        f_upper_p(f, qf, nb - qf)
    };
    (pval, se)
}

/// Percent of RMS(m a) of a sum of squared errors.
pub(super) fn pct(p: &Prepared, sse: f64) -> f64 {
    100.0 * (sse / p.y.len() as f64).sqrt() / p.rms_y
}

pub(super) fn model_error(res: f64, noise: f64) -> f64 {
    (res * res - noise * noise).max(0.0).sqrt()
}

pub(super) struct Evaluated {
    pub(super) hyper: Option<f64>,
    pub(super) gram: BlockGram,
    pub(super) q: usize,
    pub(super) drop_mic: bool,
    /// p-value and standard errors of the test (for delay: of the linearised column).
    pub(super) p_value: f64,
    pub(super) se: Vec<f64>,
    pub(super) beta: DVector<f64>,
}

pub(super) fn hyper_grid(p: &Prepared, e: EffectId) -> Option<Vec<f64>> {
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
        // Yield excursions from 1 % to twice the largest excursion: below,
        // the element is a friction force; above, a linear spring (k0).
        EffectId::Hysteresis => Some(logspace(p.x_scale * 0.01, p.x_scale * 2.0, 15)),
        // Recovery times from a few periods to far beyond the record (a
        // running maximum of the excursion).
        EffectId::ReversibleSoftening => {
            let lo = (20.0 / p.omega_typ).max(0.05);
            Some(logspace(lo, (20.0 * p.duration_s).max(2.0 * lo), 15))
        }
        _ => None,
    }
}

/// Creep time constants staged at once in a grid search (their recursions
/// run side by side in one pass): two full-length columns at a time, 7 MB
/// for a 16-level series.
const CREEP_STAGE: usize = 2;

pub(super) fn evaluate(p: &Prepared, built: &Built, term: Term) -> Evaluated {
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
                    // Creep's grid is staged a few time constants at a time
                    // (one pass of their recursions each): the whole grid at
                    // once held 15 full-length columns, 55 MB for a 16-level
                    // series. Each column is computed exactly as alone.
                    let chunk = if e == EffectId::Creep {
                        CREEP_STAGE
                    } else {
                        grid.len()
                    };
                    let mut sses: Vec<f64> = Vec::with_capacity(grid.len());
                    for hs in grid.chunks(chunk) {
                        if e == EffectId::Creep {
                            p.stage_creep(built, hs);
                        }
                        sses.extend(hs.iter().map(|&h| sse_at(h)));
                        p.unstage();
                    }
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

pub(super) fn effect_params(e: EffectId, h: f64, coef: &[f64]) -> serde_json::Value {
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
        EffectId::Hysteresis => json!({"k_n_per_m": -coef[0], "x_yield_m": h}),
        EffectId::ReversibleSoftening => json!({"depth_n_per_m2": -coef[0], "tau_s": h}),
    }
}

pub(super) fn effect_se(e: EffectId, se: &[f64]) -> serde_json::Value {
    use serde_json::json;
    match e {
        EffectId::CoulombFriction => json!({"force_n": se[0]}),
        EffectId::QuadraticDamping => json!({"coeff_ns2_per_m2": se[0]}),
        EffectId::DampingVsDisplacement => json!({"r1_ns_per_m2": se[0], "r2_ns_per_m3": se[1]}),
        EffectId::Creep => json!({"k_n_per_m": se[0]}),
        EffectId::StiffnessDrift => json!({"dk0_dt_n_per_m_s": se[0]}),
        EffectId::ChannelDelay => json!({"delay_s": se[0]}),
        EffectId::Hysteresis => json!({"k_n_per_m": se[0]}),
        EffectId::ReversibleSoftening => json!({"depth_n_per_m2": se[0]}),
    }
}

pub(super) fn set_effect(effects: &mut Effects, e: EffectId, params: &serde_json::Value) {
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
        EffectId::Hysteresis => {
            effects.hysteresis = Some(Hysteresis {
                k_n_per_m: g("k_n_per_m"),
                x_yield_m: g("x_yield_m"),
            })
        }
        EffectId::ReversibleSoftening => {
            effects.reversible_softening = Some(ReversibleSoftening {
                depth_n_per_m2: g("depth_n_per_m2"),
                tau_s: g("tau_s"),
            })
        }
    }
}

/// The hyper-parameter of effect `e` in `effects` (0 for an effect without one or not there).
pub(super) fn hyper_of(effects: &Effects, e: EffectId) -> f64 {
    match e {
        EffectId::CoulombFriction => effects.coulomb_friction.map(|f| f.v_eps_m_per_s),
        EffectId::Creep => effects.creep.map(|c| c.tau_s),
        EffectId::ChannelDelay => effects.channel_delay.map(|c| c.delay_s),
        EffectId::Hysteresis => effects.hysteresis.map(|h| h.x_yield_m),
        EffectId::ReversibleSoftening => effects.reversible_softening.map(|s| s.tau_s),
        EffectId::QuadraticDamping | EffectId::DampingVsDisplacement | EffectId::StiffnessDrift => {
            None
        }
    }
    .unwrap_or(0.0)
}

/// Default hyper-parameter of a forced effect: searched like a candidate.
pub(super) fn forced_hyper(p: &Prepared, built: &Built, e: EffectId) -> f64 {
    evaluate(p, built, Term::Effect(e)).hyper.unwrap_or(0.0)
}

/// Fits `spec` fully and describes it.
pub(super) fn describe(p: &Prepared, built: &Built, folds: usize) -> (FittedModel, DVector<f64>) {
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

pub(super) fn residual(p: &Prepared, built: &Built, beta: &DVector<f64>) -> (Vec<f64>, Vec<f64>) {
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
