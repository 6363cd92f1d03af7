//! The diagnostics engine on force-balance data: the linear-in-parameters
//! force balance
//!
//! `m a = s mic + c - sum_i k_i x^(i+1) - R v - (effect terms)`
//!
//! (`s` the force per microphone volt, `c` an offset), candidate effects with
//! their regressors and hyper-parameter searches, ranking by blocked
//! cross-validation and a block-robust Wald test, identifiability by variance
//! inflation, and the forward-selection ladder.

mod design;
mod fit;
mod options;
mod rank;
mod result;

pub use crate::identify::documents::{CandidateResult, LadderStep};
pub use design::Prepared;
pub use options::{EngineOptions, Term, MODEL_ERROR_RESOLUTION};
pub use result::{fundamental_range_hz, CreepTauFree, EngineResult, FittedModel};

use crate::diagnose::spectrum;
use crate::effects::EffectId;
use crate::identify::ForceBalanceData;
use design::{Built, Spec};
use fit::{describe, forced_hyper, model_error, pct, residual};
use rank::{choose_order, rank};

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
    let mut memory_noise_percent = f64::INFINITY;
    // The residual, modelled force and spectrum of `built` while it is the
    // model of the step (the final model's when the ladder stops there),
    // and the base model's spectrum (the first step's).
    let mut current: Option<(Vec<f64>, Vec<f64>, spectrum::ResidualSpectrum)> = None;
    let mut base_spectrum = None;
    let mut skipped: Vec<String> = Vec::new();
    for _ in 0..opts.max_steps {
        // Noise floor of this step's residual (never rising along the ladder:
        // a big missing effect can only lift the estimate).
        let fit = built.gram.fit();
        let (res, modelled) = residual(&p, &built, &fit.beta);
        let sp = spectrum::residual_spectrum(&res, p.fs(), 0.5);
        noise_percent = noise_percent.min(100.0 * sp.noise_variance.sqrt() / p.rms_y);
        memory_noise_percent =
            memory_noise_percent.min(100.0 * noise_share_variance(&res, &sp).sqrt() / p.rms_y);
        if base_spectrum.is_none() {
            base_spectrum = Some(sp.clone());
        }
        current = Some((res, modelled, sp));
        let ranked = rank(&p, &built, opts, noise_percent, memory_noise_percent);
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
    // Backward check (issue 33, decision 0118): an effect the ladder added
    // that is no longer significant (block-robust Wald test at alpha, no
    // Bonferroni: only a clearly idle term goes) once the effects added
    // after it are in stood in for them; it leaves the model, the least
    // significant first (a strong reversible softening of a 3" spider
    // entered after a drift that only mimicked it).
    while opts.ladder && !built.spec.effects.is_empty() {
        let mut worst: Option<(usize, f64)> = None;
        for (i, &(e, h)) in built.spec.effects.iter().enumerate() {
            let cols = design::effect_ids(e, h);
            if opts.forced.contains(&e) || cols.is_empty() {
                continue;
            }
            let mut spec = built.spec.clone();
            spec.effects.remove(i);
            let gram = Built::new(&p, spec).with(&p, false, &cols, true);
            let fit = gram.fit();
            let (pv, _) = fit::wald_last(&gram, &fit.beta, cols.len());
            if pv >= opts.alpha && worst.is_none_or(|w| pv > w.1) {
                worst = Some((i, pv));
            }
        }
        let Some((i, pv)) = worst else { break };
        let mut spec = built.spec.clone();
        let (e, _) = spec.effects.remove(i);
        skipped.push(format!(
            "the ladder removed {e} again: not significant once the effects added after it were in (p {pv:.2})"
        ));
        built = Built::new(&p, spec);
        current = None;
    }
    let (model, beta) = describe(&p, &built, opts.folds);
    let creep_tau_free = creep_tau_free(&p, &built, opts.folds);
    // The fit of the same Gram gives the same coefficients: the step's
    // residual and spectrum are the final model's.
    let (res, modelled, spectrum) = current.unwrap_or_else(|| {
        let (res, modelled) = residual(&p, &built, &beta);
        let sp = spectrum::residual_spectrum(&res, p.fs(), 0.5);
        (res, modelled, sp)
    });
    let base_spectrum =
        base_spectrum.unwrap_or_else(|| spectrum::residual_spectrum(&base_res, p.fs(), 0.5));
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
        creep_tau_free,
    })
}

/// The noise floor read by the residual's own estimator (decision 0141):
/// the time-domain mean square of `res` times the noise's share of its
/// Welch spectrum. The Welch sum weighs the samples by the overlapped Hann
/// windows and drops the tail past the last segment, so the floor it gives
/// differs from the mean square of the same noise by up to 0.9 % of the
/// variance (decision 0128); this one never exceeds the residual.
fn noise_share_variance(res: &[f64], sp: &spectrum::ResidualSpectrum) -> f64 {
    let welch: f64 = sp.psd.iter().sum();
    let mean_square = res.iter().map(|v| v * v).sum::<f64>() / res.len().max(1) as f64;
    if welch > 0.0 {
        mean_square * (sp.noise_psd.iter().sum::<f64>() / welch)
    } else {
        sp.noise_variance
    }
}

/// The chosen `model` (its order and effects) refitted with the
/// hyper-parameters of its searched effects (creep's and the softening's
/// tau, the yield excursion, friction's smoothing) found together: each in
/// turn searched on its grid and refined by golden section, as the ladder
/// does, but with every other effect of the model in, for `rounds` rounds.
/// The ladder searches an effect's hyper-parameter once, when it enters,
/// against the model of that step; two effects whose regressors overlap
/// (creep and a reversible softening on one part) keep the first one's
/// compromise. The added-mass study's attribution (decision 0122) needs
/// both causes at their own values.
pub fn refit_jointly(
    d: &ForceBalanceData,
    opts: &EngineOptions,
    model: &FittedModel,
    rounds: usize,
) -> Result<FittedModel, String> {
    let p = Prepared::new(d, opts.blocks)?;
    let mut spec = Spec {
        order: model.order,
        effects: model
            .effect_ids
            .iter()
            .map(|&e| (e, fit::hyper_of(&model.effects, e)))
            .collect(),
    };
    for _ in 0..rounds {
        for i in 0..spec.effects.len() {
            let e = spec.effects[i].0;
            if fit::hyper_grid(&p, e).is_none() {
                continue;
            }
            let mut without = spec.clone();
            without.effects.remove(i);
            let built = Built::new(&p, without);
            if let Some(h) = fit::evaluate(&p, &built, Term::Effect(e)).hyper {
                spec.effects[i].1 = h;
            }
        }
    }
    Ok(describe(&p, &Built::new(&p, spec), opts.folds).0)
}

/// The model of `built` with creep's time constant free, when it holds
/// creep: creep's column at tau is replaced by its columns at tau e^-h and
/// tau e^h, which span the column and its derivative in ln tau (the
/// Gauss-Newton linearisation of a free tau), so that the block-robust
/// standard errors of K(x) and R include what tau's uncertainty does to
/// them (decision 0072). The fit's own standard errors hold tau fixed at
/// the grid search's best.
fn creep_tau_free(p: &Prepared, built: &Built, folds: usize) -> Option<CreepTauFree> {
    let i = built
        .spec
        .effects
        .iter()
        .position(|(e, _)| *e == EffectId::Creep)?;
    let tau = built.spec.effects[i].1;
    let mut spec = built.spec.clone();
    spec.effects.remove(i);
    let h = CREEP_TAU_STEP;
    spec.effects.push((EffectId::Creep, tau * (-h).exp()));
    spec.effects.push((EffectId::Creep, tau * h.exp()));
    let model = describe(p, &Built::new(p, spec), folds).0;
    Some(CreepTauFree { tau_s: tau, model })
}

/// Step in ln tau of the two creep columns that span the derivative: a
/// tenth, well inside the tau grid's spacing (ln of its ratio 0.4-0.6), so
/// that the span is the linearisation's.
const CREEP_TAU_STEP: f64 = 0.1;
