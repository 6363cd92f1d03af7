//! One model, one set of numbers (issue 12): the headline K(x), R, k0, f0
//! and Q of a diagnosed report come from the model the diagnostics chose (or
//! were asked for); the base model's values stay beside them with the change
//! at the ends of the measured range. Pure.

use super::engine::{CreepTauFree, EngineResult, FittedModel, MODEL_ERROR_RESOLUTION};
use crate::identify::validity::{
    State, ACCURACY_F0, ACCURACY_K0, ACCURACY_K_OF_X, ACCURACY_Q, ACCURACY_R,
    ACCURACY_SMALL_SIGNAL_R,
};
use crate::identify::{
    large::describing_function_keff, LargeSignal, SmallSignal, Stiffness, StiffnessChange,
};

fn k_of(k: &[f64], x: f64) -> f64 {
    k.iter().rev().fold(0.0, |acc, c| acc * x + c)
}

/// Where C(x) = 1/K(x) first falls to 75 % of C(0) between 0 and `edge`
/// (K reaches K(0)/0.75); None when not reached inside the range.
fn xc_side(k: &[f64], edge: f64) -> Option<f64> {
    let k0 = k_of(k, 0.0);
    if k0.is_nan() || k0 <= 0.0 || edge == 0.0 {
        return None;
    }
    let target = k0 / 0.75;
    let steps = 2000;
    let mut prev = 0.0;
    for i in 1..=steps {
        let x = edge * i as f64 / steps as f64;
        if k_of(k, x) >= target {
            let (mut a, mut b) = (prev, x);
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                if k_of(k, m) >= target {
                    b = m;
                } else {
                    a = m;
                }
            }
            return Some(0.5 * (a + b));
        }
        prev = x;
    }
    None
}

/// `template` (the plain analysis's stiffness: method, valid range) with the
/// K(x) and R of `m`.
fn stiffness_of(template: &Stiffness, m: &FittedModel) -> Stiffness {
    let k = &m.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let [xlo, xhi] = template.valid_range_m;
    Stiffness {
        order: m.order,
        coefficients_n_per_mm_pow_i_plus_1: k
            .iter()
            .enumerate()
            .map(|(i, c)| c * 1e-3f64.powi(i as i32 + 1))
            .collect(),
        coefficients_n_per_m_pow_i_plus_1: k.clone(),
        coefficients_se_n_per_m_pow_i_plus_1: m
            .stiffness_coefficients_se_n_per_m_pow_i_plus_1
            .clone(),
        xc_m: [xc_side(k, xlo), xc_side(k, xhi)],
        r_ns_per_m: m.r_ns_per_m,
        r_se_ns_per_m: m.r_se_ns_per_m,
        force_per_mic_v_n_per_v: Some(m.force_per_mic_n_per_v),
        reference_time_s: m.reference_time_s,
        base: None,
        change_from_base: None,
        validity: Default::default(),
        ..template.clone()
    }
}

fn pct(a: f64, b: f64) -> f64 {
    if b != 0.0 {
        100.0 * (a / b - 1.0)
    } else {
        f64::NAN
    }
}

/// The headline stiffness of a diagnosed report: the chosen model's K(x) and
/// R; with effects in it, the base model's beside and the change.
pub fn stiffness(plain: &Stiffness, r: &EngineResult) -> Stiffness {
    let mut s = stiffness_of(plain, &r.model);
    if !r.model.effect_ids.is_empty() {
        let b = stiffness_of(plain, &r.base);
        let [xlo, xhi] = plain.valid_range_m;
        let (k, kb) = (
            &s.coefficients_n_per_m_pow_i_plus_1,
            &b.coefficients_n_per_m_pow_i_plus_1,
        );
        s.change_from_base = Some(StiffnessChange {
            k_at_range_ends_percent: [
                pct(k_of(k, xlo), k_of(kb, xlo)),
                pct(k_of(k, xhi), k_of(kb, xhi)),
            ],
            k0_percent: pct(k_of(k, 0.0), k_of(kb, 0.0)),
            r_percent: pct(s.r_ns_per_m, b.r_ns_per_m),
        });
        s.base = Some(Box::new(b));
    }
    s
}

/// Keff of the chosen model over the excursion at resonance and its
/// block-robust standard error: the describing function is linear in the
/// K(x) coefficients, `Keff = sum_i c_i D_i` with `D_i` the describing
/// function of `x^i`, so `var(Keff) = D^T C D`. With stiffness drift, K(0)
/// is moved to the resonance period's time.
pub fn keff_of(m: &FittedModel, x_min_m: f64, x_max_m: f64, t_s: f64) -> (f64, f64) {
    let mut k = m.stiffness_coefficients_n_per_m_pow_i_plus_1.clone();
    if k.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    k[0] += m.dk0_dt_n_per_m_s * (t_s - m.reference_time_s.unwrap_or(t_s));
    let keff = describing_function_keff(&k, x_min_m, x_max_m);
    let d: Vec<f64> = (0..k.len())
        .map(|i| {
            let mut unit = vec![0.0; i + 1];
            unit[i] = 1.0;
            describing_function_keff(&unit, x_min_m, x_max_m)
        })
        .collect();
    let c = &m.stiffness_covariance;
    let mut var = 0.0;
    for (i, di) in d.iter().enumerate() {
        for (j, dj) in d.iter().enumerate() {
            var += di * dj * c.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0);
        }
    }
    (keff, var.max(0.0).sqrt())
}

/// The headline large-signal values of a diagnosed report: with effects in
/// the chosen model, Keff is the describing function of its K(x) over the
/// measured excursion at resonance (with its standard error) and fR the
/// frequency that Keff and the moving mass resonate at; the phase method's
/// values (which an effect such as a delayed microphone or creep biases)
/// stay beside in `base`. Without effects: the identification's values.
pub fn large_signal(plain: &LargeSignal, r: &EngineResult) -> LargeSignal {
    let m = &r.model;
    if m.effect_ids.is_empty() {
        return plain.clone();
    }
    let (keff, se) = keff_of(
        m,
        plain.x_min_at_resonance_m,
        plain.x_max_at_resonance_m,
        plain.resonance_time_s,
    );
    if !(keff.is_finite() && keff > 0.0 && plain.moving_mass_kg > 0.0) {
        return plain.clone();
    }
    let mut base = plain.clone();
    base.base = None;
    LargeSignal {
        resonance_hz: (keff / plain.moving_mass_kg).sqrt() / (2.0 * std::f64::consts::PI),
        keff_n_per_m: keff,
        ceff_m_per_n: 1.0 / keff,
        keff_from_k_of_x_n_per_m: keff,
        keff_se_n_per_m: Some(se),
        keff_method: Some("chosen_model".into()),
        base: Some(Box::new(base)),
        validity: Default::default(),
        ..plain.clone()
    }
}

/// The small-signal values of the model with effects (the engine on the
/// pre-measurement): reliable when k0 and R are positive and their
/// block-robust relative standard errors below 5 %.
fn small_signal_of_model(plain: &SmallSignal, pre: &EngineResult, mass_kg: f64) -> SmallSignal {
    let m = &pre.model;
    let k0 = m.stiffness_coefficients_n_per_m_pow_i_plus_1[0];
    let k0_se = m
        .stiffness_coefficients_se_n_per_m_pow_i_plus_1
        .first()
        .copied()
        .unwrap_or(0.0);
    let r = m.r_ns_per_m;
    let w0 = (k0.max(0.0) / mass_kg).sqrt();
    let f0 = w0 / (2.0 * std::f64::consts::PI);
    let rel_k = if k0 > 0.0 { k0_se / k0 } else { f64::NAN };
    let rel_r = if r > 0.0 {
        m.r_se_ns_per_m / r
    } else {
        f64::NAN
    };
    let (q, q_se, q_null_reason) = crate::identify::quality_factor(k0, mass_kg, r, rel_k, rel_r);
    let reliable = k0 > 0.0 && r > 0.0 && rel_k < 0.05 && rel_r < 0.05;
    let mut base = plain.clone();
    base.base = None;
    let mut s = SmallSignal {
        f0_hz: Some(f0),
        k0_n_per_m: Some(k0),
        r_ns_per_m: Some(r),
        q,
        f0_se_hz: crate::identify::f0_standard_error(f0, rel_k),
        k0_se_n_per_m: k0_se,
        r_se_ns_per_m: m.r_se_ns_per_m,
        q_se,
        q_null_reason,
        force_per_mic_v_n_per_v: Some(m.force_per_mic_n_per_v),
        misfit_percent: plain.misfit_percent,
        reliable,
        effects: m.effects,
        reference_time_s: m.reference_time_s,
        base: Some(Box::new(base)),
        validity: Default::default(),
    };
    crate::identify::validity::judge_small_signal(&mut s);
    s
}

/// The headline small-signal values: from the small-signal model with
/// effects when the diagnostics chose (or were asked for) any and that
/// model is reliable and physical (k0 and R positive, their block-robust
/// relative standard errors below 5 %), with the linear resonator's fit
/// beside; else the linear resonator's fit, and the reason the model with
/// effects was not taken (a warning).
pub fn small_signal(
    plain: &SmallSignal,
    pre: &EngineResult,
    mass_kg: f64,
) -> (SmallSignal, Option<String>) {
    if pre.model.effect_ids.is_empty() {
        return (plain.clone(), None);
    }
    let s = small_signal_of_model(plain, pre, mass_kg);
    if s.reliable {
        return (s, None);
    }
    let ids: Vec<&str> = pre.model.effect_ids.iter().map(|e| e.as_str()).collect();
    let m = &pre.model;
    let k0 = m.stiffness_coefficients_n_per_m_pow_i_plus_1[0];
    let mut linear = plain.clone();
    linear.validity.mark_all(
        crate::identify::validity::State::Unreliable,
        &format!(
            "the linear resonator holds none of {} that the diagnostics found, and the model with them is not reliable",
            ids.join(" + ")
        ),
    );
    (
        linear,
        Some(format!(
            "the small-signal model with {} is not reliable (k0 {k0:.1} ± {:.1} N/m, R {:.3} ± {:.3} N s/m): the small-signal values are the linear resonator's",
            ids.join(" + "),
            m.stiffness_coefficients_se_n_per_m_pow_i_plus_1
                .first()
                .copied()
                .unwrap_or(f64::NAN),
            m.r_ns_per_m,
            m.r_se_ns_per_m
        )),
    )
}

/// Half-width of a value's interval in standard errors (two: about 95 %)
/// that must lie within its stated accuracy for creep's tau not to matter.
pub const TAU_FREE_COVERAGE: f64 = 2.0;

/// True when [`TAU_FREE_COVERAGE`] relative standard errors `rel` exceed
/// the accuracy `acc`, or `rel` is not a number (no uncertainty known).
fn beyond(rel: f64, acc: f64) -> bool {
    rel.is_nan() || TAU_FREE_COVERAGE * rel > acc
}

/// RMS over `range` (201 points) of the standard error of K(x) from the
/// coefficients' covariance, relative to the RMS of K(x).
fn k_of_x_relative_se(m: &FittedModel, range: [f64; 2]) -> f64 {
    let k = &m.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let c = &m.stiffness_covariance;
    let (mut var, mut kk) = (0.0, 0.0);
    for i in 0..=200 {
        let x = range[0] + (range[1] - range[0]) * i as f64 / 200.0;
        let phi: Vec<f64> = (0..k.len()).map(|j| x.powi(j as i32)).collect();
        for (a, pa) in phi.iter().enumerate() {
            for (b, pb) in phi.iter().enumerate() {
                var += pa * pb * c.get(a).and_then(|r| r.get(b)).copied().unwrap_or(0.0);
            }
        }
        kk += k_of(k, x).powi(2);
    }
    if kk > 0.0 {
        (var.max(0.0) / kk).sqrt()
    } else {
        f64::NAN
    }
}

/// The reason a value is marked when creep's tau trades against it, with
/// the experiment that separates them: creep's corner below the resonance
/// `f_res_hz` (creep nearly a constant stiffness there): a
/// pre-measurement from below the corner; above it (creep a damping that
/// falls with frequency, R a constant one): an added mass.
fn tau_reason(what: &str, c: &CreepTauFree, rel_se: f64, accuracy: f64, f_res_hz: f64) -> String {
    let corner = 1.0 / (2.0 * std::f64::consts::PI * c.tau_s);
    let experiment = if corner < f_res_hz {
        format!("a pre-measurement from below creep's corner ({corner:.1} Hz), or an added mass that moves the resonance, would separate them")
    } else {
        "an added mass that moves the resonance (creep's damping changes with frequency, R does not) would separate them".to_string()
    };
    format!(
        "creep's time constant trades against {what} in this sweep: with tau free (best {:.1} ms, corner {corner:.1} Hz) {what} is uncertain by +-{:.1} % ({TAU_FREE_COVERAGE} standard errors), more than its stated accuracy of {:.1} %; {experiment}",
        c.tau_s * 1e3,
        100.0 * TAU_FREE_COVERAGE * rel_se,
        100.0 * accuracy,
    )
}

/// Marks K(x) and R of the main sweep `unreliable` when the chosen model
/// holds creep and, with creep's tau free, their uncertainty is wider than
/// their stated accuracy (decision 0072): a tau the sweep cannot pin down
/// trades against K(x) (creep's corner below the band: creep is a
/// constant stiffness there) or R (above it: a damping). Keff follows K(x).
pub fn mark_creep_tau_main(s: &mut Stiffness, r: &EngineResult, f_res_hz: f64) {
    let Some(c) = r.creep_tau_free.as_ref().filter(|_| {
        r.model
            .effect_ids
            .contains(&crate::effects::EffectId::Creep)
    }) else {
        return;
    };
    let exp = f_res_hz;
    let rel_k = k_of_x_relative_se(&c.model, s.valid_range_m);
    if beyond(rel_k, ACCURACY_K_OF_X) {
        let why = tau_reason("K(x)", c, rel_k, ACCURACY_K_OF_X, exp);
        s.validity.k_of_x.mark(State::Unreliable, &why);
    }
    let rel_r = c.model.r_se_ns_per_m / c.model.r_ns_per_m.abs();
    if beyond(rel_r, ACCURACY_R) {
        let why = tau_reason("R", c, rel_r, ACCURACY_R, exp);
        s.validity.r_ns_per_m.mark(State::Unreliable, &why);
    }
}

/// Creep's stored stiffness `kc (w tau)^2 / (1 + (w tau)^2)` at `f_hz`
/// (0 without creep): the part of the dynamic stiffness there that relaxes
/// at rest.
fn creep_stored_n_per_m(c: Option<crate::effects::Creep>, f_hz: f64) -> f64 {
    let w = 2.0 * std::f64::consts::PI * f_hz;
    c.map_or(0.0, |c| {
        let wt2 = (w * c.tau_s).powi(2);
        c.k_n_per_m * wt2 / (1.0 + wt2)
    })
}

/// Marks K(x) of the main sweep `unreliable` when the two sweeps' fits of
/// the same creep disagree about its stored stiffness at the resonance
/// (decision 0129). With creep's corner below the main sweep's band, the
/// main sweep sees creep nearly as a constant stiffness: the headline K(x)
/// is its stiffness at the resonance less creep's stored stiffness there,
/// and that split rests on the little creep changes across the band. The
/// pre-measurement (from 5 Hz, nearer the corner) fits the same creep
/// (forced into its model); where the small-signal values take that
/// model (`pre_creep`; not where it stands in for a spider's harmonics)
/// it is a second estimate of the stored stiffness at the same frequency,
/// and K(x) near 0 moves by their difference. K(x) is
/// uncertain by that difference (relative to K(x)'s RMS over the range)
/// plus two standard errors with tau free; beyond K(x)'s accuracy it is
/// marked (the tau-free standard errors alone see one sweep's noise, not
/// the bias of its split). Keff follows K(x) (`validity::judge`).
pub fn mark_creep_two_sweeps(
    s: &mut Stiffness,
    main: &EngineResult,
    pre_creep: Option<crate::effects::Creep>,
    f_res_hz: f64,
) {
    let Some(c) = main.creep_tau_free.as_ref() else {
        return;
    };
    let (Some(main_creep), Some(pre_creep)) = (main.model.effects.creep, pre_creep) else {
        return;
    };
    let rel_se = k_of_x_relative_se(&c.model, s.valid_range_m);
    if beyond(rel_se, ACCURACY_K_OF_X) {
        // Marked with tau free already (mark_creep_tau_main).
        return;
    }
    let k = &main.model.stiffness_coefficients_n_per_m_pow_i_plus_1;
    let range = s.valid_range_m;
    let mut kk = 0.0;
    for i in 0..=200 {
        let x = range[0] + (range[1] - range[0]) * i as f64 / 200.0;
        kk += k_of(k, x).powi(2);
    }
    let k_rms = (kk / 201.0).sqrt();
    let stored_main = creep_stored_n_per_m(Some(main_creep), f_res_hz);
    let stored_pre = creep_stored_n_per_m(Some(pre_creep), f_res_hz);
    let rel_split = (stored_main - stored_pre).abs() / k_rms;
    let total = rel_split + TAU_FREE_COVERAGE * rel_se;
    if k_rms.is_nan() || k_rms <= 0.0 || total.is_nan() || total <= ACCURACY_K_OF_X {
        return;
    }
    let corner = 1.0 / (2.0 * std::f64::consts::PI * main_creep.tau_s);
    let why = format!(
        "the two sweeps' fits of creep place its stored stiffness at the resonance ({f_res_hz:.1} Hz) at {stored_main:.1} N/m (main sweep, tau {:.1} ms) and {stored_pre:.1} N/m (pre-measurement, tau {:.1} ms): K(x) is the main sweep's stiffness there less creep's, uncertain by their difference ({:.2} % of K(x)) plus {TAU_FREE_COVERAGE} standard errors with tau free ({:.2} %), more than its stated accuracy of {:.1} %; a pre-measurement from below creep's corner ({corner:.1} Hz), or an added mass that moves the resonance, would separate them",
        main_creep.tau_s * 1e3,
        pre_creep.tau_s * 1e3,
        100.0 * rel_split,
        100.0 * TAU_FREE_COVERAGE * rel_se,
        100.0 * ACCURACY_K_OF_X,
    );
    s.validity.k_of_x.mark(State::Unreliable, &why);
}

/// Marks the small-signal values from the model with creep `unreliable`
/// when, with creep's tau free, their uncertainty is wider than their
/// stated accuracy (decision 0072); see [`mark_creep_tau_main`].
pub fn mark_creep_tau_small(s: &mut SmallSignal, pre: &EngineResult) {
    let Some(c) = pre.creep_tau_free.as_ref() else {
        return;
    };
    if s.effects.creep.is_none() {
        return;
    }
    let m = &c.model;
    let k0 = m.stiffness_coefficients_n_per_m_pow_i_plus_1[0];
    let rel_k = m
        .stiffness_coefficients_se_n_per_m_pow_i_plus_1
        .first()
        .map_or(f64::NAN, |se| se / k0.abs());
    let rel_r = m.r_se_ns_per_m / m.r_ns_per_m.abs();
    let rel_q = ((0.5 * rel_k).powi(2) + rel_r.powi(2)).sqrt();
    let exp = s.f0_hz.unwrap_or(f64::NAN);
    let v = &mut s.validity;
    for (what, rel, acc, state) in [
        ("k0", rel_k, ACCURACY_K0, &mut v.k0_n_per_m),
        ("f0", 0.5 * rel_k, ACCURACY_F0, &mut v.f0_hz),
        ("R", rel_r, ACCURACY_SMALL_SIGNAL_R, &mut v.r_ns_per_m),
        ("Q", rel_q, ACCURACY_Q, &mut v.q),
    ] {
        if beyond(rel, acc) {
            state.mark(State::Unreliable, &tau_reason(what, c, rel, acc, exp));
        }
    }
}

/// Accuracy stated for Keff and fR of a diagnosed report (decision 0119):
/// the relative change the part's memory may make before they are marked.
pub const ACCURACY_KEFF_MEMORY: f64 = 0.015;

/// Marks the headline values the part's memory makes uncertain (decision
/// 0119). The headline K(x) is the elastic one, without the hysteretic
/// element's and the softening's share; it is `unreliable` when, with them
/// in the model, its standard error is wider than its accuracy (the memory
/// trades against K(x) in this sweep). Keff and fR are those of the elastic
/// K(x): `unreliable` when the memory's share at the measured excursion
/// (the hysteretic stiffness, or the softening's drop of K(0) at the peak
/// excursion) exceeds their accuracy, with the experiment that measures it.
pub fn mark_memory(s: &mut Stiffness, l: &mut LargeSignal, r: &EngineResult) {
    let fx = &r.model.effects;
    if fx.hysteresis.is_none() && fx.reversible_softening.is_none() {
        return;
    }
    let rel_k = k_of_x_relative_se(&r.model, s.valid_range_m);
    let names: Vec<&str> = [
        fx.hysteresis.map(|_| "hysteresis"),
        fx.reversible_softening.map(|_| "reversible softening"),
    ]
    .into_iter()
    .flatten()
    .collect();
    let names = names.join(" and ");
    if beyond(rel_k, ACCURACY_K_OF_X) {
        s.validity.k_of_x.mark(
            State::Unreliable,
            &format!(
                "the part's memory ({names}) trades against K(x) in this sweep: K(x) is uncertain by +-{:.1} % ({TAU_FREE_COVERAGE} standard errors), more than its stated accuracy of {:.1} %; a level series or a recovery measurement separates them",
                100.0 * TAU_FREE_COVERAGE * rel_k,
                100.0 * ACCURACY_K_OF_X
            ),
        );
    }
    let x_peak = l
        .x_max_at_resonance_m
        .abs()
        .max(l.x_min_at_resonance_m.abs());
    let share = fx.hysteresis.map_or(0.0, |h| h.k_n_per_m)
        + fx.reversible_softening
            .map_or(0.0, |v| v.depth_n_per_m2 * x_peak);
    let keff = l.keff_n_per_m;
    if keff > 0.0 && share / keff > ACCURACY_KEFF_MEMORY {
        let why = format!(
            "Keff and fR are those of the elastic K(x): the part's memory ({names}) adds up to {:.1} % of Keff at this excursion that depends on the amplitude and the part's recent history; the recovery measurement and a level series measure it",
            100.0 * share / keff
        );
        l.validity.keff_n_per_m.mark(State::Unreliable, &why);
        l.validity.resonance_hz.mark(State::Unreliable, &why);
    }
}

/// A memory effect the record cannot weigh (decisions 0123, 0128): the
/// block test finds it systematic (p below its corrected alpha), it lowers
/// the held-out error in most folds with plausible parameters, but the base
/// model's held-out model error is within the floor estimate's resolution
/// (`MODEL_ERROR_RESOLUTION`), so whether it removes 5 % of that error
/// (decision 0003) is decided by the estimator's scatter, not by the part.
/// The 18" cone's weak hysteresis (0.06 x k0, 0.05 % of the residual's
/// variance, p about 1e-43) is added in 5 of seeds 900-911; in 2 the floor
/// lies above the residual (decision 0123's case), in 5 it removes 1.8-4.3
/// % of the held-out model error, and those 5 said nothing, with K(x), Keff
/// and fR `valid`. Such a candidate gets a "cannot tell" note and a warning
/// with its separating experiment, and the values its share would move (its
/// share at the measured excursion above their accuracy) are marked
/// `unreliable`. The candidate is not added: the record cannot say that it
/// matters. Returns the warnings.
pub fn mark_unweighed_memory(
    candidates: &mut [crate::identify::documents::CandidateResult],
    r: &EngineResult,
    s: &mut Stiffness,
    l: &mut LargeSignal,
) -> Vec<String> {
    use crate::diagnose::engine::Term;
    use crate::effects::EffectId;
    let mut warnings = Vec::new();
    let base_cv = r.base.cv_residual_percent;
    let floor = r.noise_floor_percent;
    let base_me = (base_cv * base_cv - floor * floor).max(0.0).sqrt();
    // Only while the ladder added nothing: the base model is then the
    // chosen one, and its error is what the record cannot resolve.
    if !(r.model.effect_ids.is_empty() && base_me <= MODEL_ERROR_RESOLUTION * floor) {
        return warnings;
    }
    let x_peak = l
        .x_max_at_resonance_m
        .abs()
        .max(l.x_min_at_resonance_m.abs());
    for c in candidates.iter_mut() {
        let Some(id) = EffectId::parse(&c.effect)
            .ok()
            .filter(|e| matches!(e, EffectId::Hysteresis | EffectId::ReversibleSoftening))
        else {
            continue;
        };
        if c.significant
            || c.p_value >= c.alpha
            || c.cv_residual_percent >= base_cv
            || c.not_added.is_some()
        {
            continue;
        }
        let g = |k: &str| c.parameters.get(k).and_then(|v| v.as_f64()).unwrap_or(0.0);
        let share = match id {
            EffectId::Hysteresis => g("k_n_per_m"),
            _ => g("depth_n_per_m2") * x_peak,
        };
        let keff = l.keff_n_per_m;
        let rel = if keff > 0.0 { share / keff } else { 0.0 };
        let note = format!(
            "cannot tell whether {} matters with this data: it is systematic (p {:.1e}) and lowers the held-out error, but the base model's held-out model error ({base_me:.3} %) is within the resolution of the estimated noise floor ({floor:.3} %; about {:.0} % of it), so its share of the model error ({:.1} % removed) cannot be weighed; it would add {:.1} % of Keff at this excursion; to tell: {}",
            c.effect,
            c.p_value,
            100.0 * MODEL_ERROR_RESOLUTION,
            c.error_reduction_percent,
            100.0 * rel,
            Term::Effect(id).separating_experiment()
        );
        if rel > ACCURACY_K_OF_X {
            let why = format!(
                "the part may have {} this record cannot weigh (up to {:.1} % of Keff), which K(x), Keff and fR would then carry",
                c.effect,
                100.0 * rel
            );
            s.validity.k_of_x.mark(State::Unreliable, &why);
            l.validity.keff_n_per_m.mark(State::Unreliable, &why);
            l.validity.resonance_hz.mark(State::Unreliable, &why);
        }
        c.note = Some(match c.note.take() {
            Some(n) => format!("{note}; {n}"),
            None => note.clone(),
        });
        warnings.push(note);
    }
    warnings
}
