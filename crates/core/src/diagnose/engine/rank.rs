//! Ranking of the candidates against a model (cross-validation, test,
//! identifiability, relevance, plausibility) and the choice of the K(x) order.

use super::design::{Built, Col, Prepared, Role, Spec};
use super::fit::{
    describe, dmic_of, effect_params, effect_se, evaluate, model_error, pct, wald_last, Evaluated,
};
use super::options::{EngineOptions, Term, MODEL_ERROR_RESOLUTION};
use crate::diagnose::regress::collinearity_r2;
use crate::effects::EffectId;
use crate::identify::documents::CandidateResult;
use crate::identify::large::describing_function_keff;
use crate::identify::validity::{ACCURACY_K_OF_X, ACCURACY_R};

/// Ranks every candidate against `built`.
pub(super) fn rank(
    p: &Prepared,
    built: &Built,
    opts: &EngineOptions,
    noise_percent: f64,
    memory_noise_percent: f64,
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
                | Term::Effect(EffectId::Hysteresis)
                | Term::Effect(EffectId::ReversibleSoftening)
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
        // Practical relevance: the share of the structured (held-out) error
        // it removes. A memory effect on a sweep whose headline it weighs
        // is weighed against the floor read by the residual's own estimator
        // (decision 0141).
        let cut = |floor: f64| {
            let me_base = model_error(pct(p, base_cv), floor);
            let me_cand = model_error(pct(p, cv), floor);
            let reduction = if me_base > 0.0 {
                100.0 * (1.0 - me_cand / me_base)
            } else {
                0.0
            };
            (me_base, reduction)
        };
        let (spectrum_floor, spectrum_cut) = (noise_percent, cut(noise_percent));
        let own_floor = matches!(
            term,
            Term::Effect(EffectId::Hysteresis | EffectId::ReversibleSoftening)
        ) && opts.headline_relevance;
        let noise_percent = if own_floor {
            memory_noise_percent
        } else {
            noise_percent
        };
        let (me_base, reduction) = cut(noise_percent);
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
        // Where the record cannot weigh the model error (its estimate is
        // within the floor's resolution, decision 0128), a memory effect's
        // relevance is what leaving it out does to the headline (decision
        // 0140): K(x), R or Keff moved beyond its stated accuracy.
        let systematic = ev.p_value < alpha && cv < base_cv;
        let moved = match term {
            Term::Effect(e @ (EffectId::Hysteresis | EffectId::ReversibleSoftening))
                if systematic
                    && opts.headline_relevance
                    && reduction < opts.min_reduction_percent
                    && me_base <= MODEL_ERROR_RESOLUTION * noise_percent =>
            {
                headline_move(p, built, opts, e, ev.hyper).filter(|m| m.beyond())
            }
            _ => None,
        };
        let significant =
            systematic && (reduction >= opts.min_reduction_percent || moved.is_some());
        let not_added = match (&implausible, stable) {
            (Some(why), _) => Some(format!("implausible parameters ({why})")),
            (None, false) => Some(format!(
                "the held-out gain is not stable (lower held-out error in {folds_won} of {} folds)",
                opts.folds
            )),
            (None, true) => None,
        };
        // Relevant only against the residual's own floor: said, since the
        // document's figures use the spectrum's (decision 0141).
        let own_floor_note = (own_floor
            && significant
            && moved.is_none()
            && spectrum_cut.1 < opts.min_reduction_percent)
            .then(|| {
                format!(
                    "added because it removes {reduction:.1} % of the base model's held-out model error ({me_base:.3} %) against the noise floor read by the residual's own estimator ({noise_percent:.3} %: its mean square times the noise's share of its spectrum); against the spectrum's floor estimate ({:.3} %) the model error reads {:.3} % and cannot weigh it (decision 0141)",
                    spectrum_floor, spectrum_cut.0
                )
            });
        let note = match (identifiable, significant) {
            (true, true) if moved.is_some() => moved.map(|m| m.note(term, me_base, noise_percent)),
            (true, true) if own_floor_note.is_some() => own_floor_note,
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
            stands_in_for: None,
            cv_residual_percent: pct(p, cv),
            hyper: ev.hyper,
            cv_sse: cv,
            not_added,
        };
        out.push((term, ev, res));
    }
    out
}

/// What leaving a candidate out does to the headline values of the sweep
/// (decision 0140): the relative changes of K(x) (RMS over the measured
/// range), R and Keff (the describing function of K(x) over that range)
/// between the model with it and without it, each refitted.
#[derive(Debug, Clone, Copy)]
struct HeadlineMove {
    k_of_x: f64,
    r: f64,
    keff: f64,
}

impl HeadlineMove {
    /// One of them beyond its stated accuracy (Keff follows K(x)'s).
    fn beyond(&self) -> bool {
        self.k_of_x > ACCURACY_K_OF_X
            || self.r.abs() > ACCURACY_R
            || self.keff.abs() > ACCURACY_K_OF_X
    }

    fn note(&self, term: Term, me_base: f64, floor: f64) -> String {
        format!(
            "added because leaving it out moves the headline beyond its stated accuracy (K(x) {:.2} % RMS, R {:+.1} %, Keff {:+.2} %; accuracy {:.0} %, {:.0} %, {:.0} %): the base model's held-out model error ({me_base:.3} %) is within the resolution of the estimated noise floor ({floor:.3} %), so the share of it that {} removes cannot be weighed (decision 0140)",
            100.0 * self.k_of_x,
            100.0 * self.r,
            100.0 * self.keff,
            100.0 * ACCURACY_K_OF_X,
            100.0 * ACCURACY_R,
            100.0 * ACCURACY_K_OF_X,
            term.name()
        )
    }
}

fn headline_move(
    p: &Prepared,
    built: &Built,
    opts: &EngineOptions,
    e: EffectId,
    hyper: Option<f64>,
) -> Option<HeadlineMove> {
    let mut spec = built.spec.clone();
    spec.effects.push((e, hyper.unwrap_or(0.0)));
    let (without, _) = describe(p, built, opts.folds);
    let (with, _) = describe(p, &Built::new(p, spec), opts.folds);
    let (lo, hi) =
        p.d.x_m
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    let k_at = |k: &[f64], x: f64| k.iter().rev().fold(0.0, |a, c| a * x + c);
    let kb = &without.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let kw = &with.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let (mut d2, mut k2) = (0.0, 0.0);
    for i in 0..=100 {
        let x = lo + (hi - lo) * i as f64 / 100.0;
        d2 += (k_at(kw, x) - k_at(kb, x)).powi(2);
        k2 += k_at(kb, x).powi(2);
    }
    let keff = |k: &[f64]| describing_function_keff(k, lo, hi);
    let m = HeadlineMove {
        k_of_x: (d2 / k2).sqrt(),
        r: with.r_ns_per_m / without.r_ns_per_m - 1.0,
        keff: keff(kw) / keff(kb) - 1.0,
    };
    // A value that is not a number moves nothing (NaN compares false).
    Some(m).filter(|m| m.k_of_x.is_finite() && m.r.is_finite() && m.keff.is_finite())
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
        EffectId::Hysteresis if !is_positive(g("k_n_per_m")) => Some(format!(
            "hysteretic stiffness {:.3e} N/m <= 0",
            g("k_n_per_m")
        )),
        EffectId::Hysteresis if !is_positive(0.5 * k_scale - g("k_n_per_m")) => Some(format!(
            "hysteretic stiffness {:.3e} N/m above half the stiffness ({k_scale:.3e} N/m)",
            g("k_n_per_m")
        )),
        EffectId::ReversibleSoftening => {
            let drop = g("depth_n_per_m2") * p.x_scale;
            if !is_positive(g("depth_n_per_m2")) {
                Some(format!(
                    "softening depth {:.3e} N/m^2 <= 0 (the part stiffens after excursions)",
                    g("depth_n_per_m2")
                ))
            } else {
                (!is_positive(0.5 * k_scale - drop)).then(|| {
                    format!("softening drops K(0) by {drop:.3e} N/m, more than half the stiffness ({k_scale:.3e} N/m)")
                })
            }
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

pub(super) fn choose_order(
    p: &Prepared,
    forced: &[(EffectId, f64)],
    opts: &EngineOptions,
) -> (usize, String) {
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
