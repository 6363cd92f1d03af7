//! Model diagnostics: compare model and measurement, rank candidate effects, model ladder, SVG plots. Pure.
//!
//! CONTRACT shared with the CLI and the daemon (owned by the diagnostics work):
//! `DiagnoseOptions`, `Diagnosis`, `diagnose`, `plot_names`, `plot`.

pub mod engine;
pub mod headline;
pub mod memory;
pub mod neighbours;
pub mod regress;
pub mod series;
pub mod spectrum;
pub mod stats;
pub mod studies;
pub mod svg;
pub mod synth;
pub mod unexplained;

use crate::effects::EffectId;
use crate::identify::diagnostics::{Ambiguity, SmallSignalComparison};
use crate::identify::{AnalyzeOptions, ForceBalanceData, Report};
use crate::recording::RecordingSet;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnoseOptions {
    pub analyze: AnalyzeOptions,
    /// Effects in the model (`--effects a,b`, or the body of a fit request).
    #[serde(default)]
    pub effects: Vec<EffectId>,
    /// True: fit exactly `effects` (the ladder's suggestions are reported,
    /// not added). False ("auto"): the ladder adds what the data demand.
    #[serde(default)]
    pub exact: bool,
}

/// The diagnosis: the analysis report with `model` refitted with the chosen
/// effects and `diagnostics` filled (candidates, ladder, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    pub report: Report,
}

#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Analyze(#[from] crate::identify::AnalyzeError),
}

/// Runs the diagnostics on a recording set: the identification's report
/// with `model` refitted (base model plus the effects the ladder adds, or
/// the forced ones) and `diagnostics` filled.
pub fn diagnose(set: &RecordingSet, opts: &DiagnoseOptions) -> Result<Diagnosis, DiagnoseError> {
    let mut warnings = Vec::new();
    let (mut report, data, pre_spectra) =
        crate::identify::analyze_for_diagnosis(set, &opts.analyze)?;
    // A measurement that fails validity (its noise floor far above the
    // bench's: a drive limit far below the target, a dark surface) gets no
    // effect added: the ladder would fit the noise's structure (issue 22).
    let failed = crate::identify::validity::noise_problem(report.model.noise_floor_percent);
    let mut engine_opts = engine::EngineOptions {
        order: opts.analyze.order,
        forced: opts.effects.clone(),
        ladder: !opts.exact,
        ..Default::default()
    };
    if let (Some(why), true) = (&failed, engine_opts.ladder) {
        engine_opts.ladder = false;
        warnings.push(format!(
            "the diagnostics added no effect: {why}; the candidates are ranked and reported only"
        ));
    }
    let result = diagnose_data(&data, &engine_opts).map_err(DiagnoseError::Invalid)?;
    warnings.extend(result.skipped.iter().cloned());
    // Beyond the library: what the chosen model leaves, described; and a
    // resonance of its own in the pre-measurement's wide band (a second mode).
    let mut unexplained = unexplained::describe(
        &data,
        &result.residual_n,
        result.model_error_percent,
        result.noise_floor_percent,
    );
    // A second mode is linear: only a pre-measurement that is a clean
    // linear system around its resonance (the linear resonator's fit
    // reliable) is searched (a sticking part's misfit is not a mode).
    let linear_pre = report.small_signal.as_ref().is_some_and(|s| s.reliable);
    if let Some(res) = linear_pre
        .then(|| pre_spectra.wide_band_resonance(set))
        .flatten()
    {
        unexplained::add_resonance(&mut unexplained, res);
    }
    // Effects the ladder added while structure stays unexplained only stand
    // in for it: they do not enter the headline model (the forced ones do).
    let stand_ins: Vec<EffectId> = if unexplained.present && !opts.exact {
        result
            .model
            .effect_ids
            .iter()
            .copied()
            .filter(|e| !opts.effects.contains(e))
            .collect()
    } else {
        Vec::new()
    };
    let claimed = if stand_ins.is_empty() {
        result.clone()
    } else {
        warnings.push(format!(
            "the headline values come from the model without {}: the model still misses structure, which they only stand in for",
            stand_ins.iter().map(|e| e.as_str()).collect::<Vec<_>>().join(", ")
        ));
        engine::EngineResult {
            model: result.base.clone(),
            model_error_percent: result.base_model_error_percent,
            // (the final model's, not the base model's)
            creep_tau_free: None,
            ..result.clone()
        }
    };
    report.model = claimed.report_model();
    // One model, one set of numbers: the headline K(x) and R are the chosen
    // model's (the engine's force balance is the Two Signal one).
    if opts.analyze.method == crate::identify::Method::TwoSignal {
        report.stiffness = headline::stiffness(&report.stiffness, &claimed);
        headline::mark_creep_tau_main(
            &mut report.stiffness,
            &claimed,
            report.large_signal.resonance_hz,
        );
        report.large_signal = headline::large_signal(&report.large_signal, &claimed);
        headline::mark_memory(&mut report.stiffness, &mut report.large_signal, &claimed);
    } else if !claimed.model.effect_ids.is_empty() {
        warnings.push(
            "the effects were fitted with the two-signal force balance; K(x) above is the one-signal fit without them"
                .into(),
        );
    }
    if unexplained.present {
        warnings.push(unexplained.signature.clone());
        if !unexplained.experiments.is_empty() {
            warnings.push(format!(
                "to tell more about the unexplained structure: {}",
                unexplained.experiments.join("; or ")
            ));
        }
        let why = format!(
            "the model misses structure outside the effect library ({})",
            unexplained.short
        );
        let v = &mut report.stiffness.validity;
        v.k_of_x
            .mark(crate::identify::validity::State::Unreliable, &why);
        v.r_ns_per_m
            .mark(crate::identify::validity::State::Unreliable, &why);
        let l = &mut report.large_signal.validity;
        l.resonance_hz
            .mark(crate::identify::validity::State::Unreliable, &why);
        l.keff_n_per_m
            .mark(crate::identify::validity::State::Unreliable, &why);
    }
    let mut ambiguities = ambiguities(&data, &result, &engine_opts);
    // The memory against its neighbours (decision 0120): named only where
    // the data separate them, else "cannot tell" with the experiment.
    let pairs = neighbours::check(&data, &result, &engine_opts);
    let mut small_signal_model = None;
    // The small-signal model: the same engine on the pre-measurement (creep,
    // friction and delay show below resonance), k0, f0 and Q from its choice.
    if let Some(plain) = report.small_signal.clone() {
        // The part is the same in both sweeps: the effects of the headline
        // model are in the small-signal model from the start (a log sweep
        // alone confounds time and frequency: drift and creep look alike
        // there), the ladder may add more.
        let mut pre_opts = engine_opts.clone();
        pre_opts.headline_relevance = false;
        for e in claimed.model.effect_ids.iter() {
            if !pre_opts.forced.contains(e) {
                pre_opts.forced.push(*e);
            }
        }
        // A part with structure outside the library (a second mode): an
        // effect the pre-measurement's ladder added would stand in for it
        // as the main sweep's did (issue 22: stiffness drift entered the
        // small-signal model of a spider with a 77 Hz mode, seed 401).
        if unexplained.present {
            pre_opts.ladder = false;
        }
        match pre_spectra
            .force_balance_data(set)
            .map_err(|e| e.to_string())
            .and_then(|d| engine::run(&d, &pre_opts).map(|r| (d, r)))
        {
            Ok((pre_data, pre)) => {
                let pre_unexplained = unexplained::describe(
                    &pre_data,
                    &pre.residual_n,
                    pre.model_error_percent,
                    pre.noise_floor_percent,
                );
                let (mut ss, not_taken) = if pre_unexplained.present
                    && !pre.model.effect_ids.is_empty()
                {
                    // Its effects would stand in for what it misses.
                    let ids: Vec<&str> = pre.model.effect_ids.iter().map(|e| e.as_str()).collect();
                    let mut linear = plain.clone();
                    let why = format!(
                        "the small-signal model with {} still misses structure ({}), so its values are not taken; the linear resonator holds none of these effects",
                        ids.join(" + "),
                        pre_unexplained.short
                    );
                    linear
                        .validity
                        .mark_all(crate::identify::validity::State::Unreliable, &why);
                    (linear, Some(format!("{why}: the small-signal values are the linear resonator's")))
                } else {
                    let (mut ss, not_taken) =
                        headline::small_signal(&plain, &pre, set.meta.moving_mass_kg);
                    headline::mark_creep_tau_small(&mut ss, &pre);
                    (ss, not_taken)
                };
                warnings.extend(not_taken);
                if unexplained.present {
                    ss.validity.mark_all(
                        crate::identify::validity::State::Unreliable,
                        &format!(
                            "the part has structure outside the effect library ({})",
                            unexplained.short
                        ),
                    );
                }
                if !ss.effects.is_empty() {
                    let ids: Vec<&str> = ss.effects.ids().iter().map(|e| e.as_str()).collect();
                    let k0 = |s: &crate::identify::SmallSignal| {
                        s.k0_n_per_m
                            .map_or("not determined".to_string(), |k| format!("{k:.1} N/m"))
                    };
                    warnings.push(format!(
                        "small-signal values from the model with {} (the linear resonator's fit is in small_signal.base: k0 {} there, {} here)",
                        ids.join(" + "),
                        k0(&plain),
                        k0(&ss)
                    ));
                }
                // The same creep fitted on both sweeps (decision 0129): the
                // pre-measurement's, where the small-signal values take it.
                if opts.analyze.method == crate::identify::Method::TwoSignal {
                    headline::mark_creep_two_sweeps(
                        &mut report.stiffness,
                        &claimed,
                        ss.effects.creep,
                        report.large_signal.resonance_hz,
                    );
                }
                report.small_signal = Some(ss);
                let mut sm = pre.small_signal_model();
                if pre_unexplained.present {
                    sm.unexplained = Some(pre_unexplained);
                }
                small_signal_model = Some(sm);
            }
            Err(e) => warnings.push(format!(
                "small-signal model with effects not fitted ({e}); small-signal values are the linear resonator's"
            )),
        }
    }
    // Effects fitted while structure stays unexplained may stand in for it:
    // their parameters are reported, not claimed as measured.
    if unexplained.present {
        let mut ids: Vec<String> = result
            .model
            .effect_ids
            .iter()
            .map(|e| e.as_str().to_string())
            .collect();
        if let Some(ss) = &report.small_signal {
            for e in ss.effects.ids() {
                if !ids.iter().any(|i| i == e.as_str()) {
                    ids.push(e.as_str().to_string());
                }
            }
        }
        if !ids.is_empty() {
            warnings.push(format!(
                "the model still misses structure, so the parameters of {} may stand in for it: not claimed as measured",
                ids.join(", ")
            ));
        }
        unexplained.parameters_not_claimed = ids;
    }
    let mut diagnostics = result.diagnostics(&data, unexplained);
    warnings.extend(neighbours::apply(
        &pairs,
        &mut diagnostics.candidates,
        &mut ambiguities,
    ));
    // A memory the record finds systematic but cannot weigh (decision 0123).
    if engine_opts.ladder && opts.analyze.method == crate::identify::Method::TwoSignal {
        warnings.extend(headline::mark_unweighed_memory(
            &mut diagnostics.candidates,
            &result,
            &mut report.stiffness,
            &mut report.large_signal,
        ));
    }
    diagnostics.ambiguities = ambiguities;
    diagnostics.small_signal_model = small_signal_model;
    diagnostics.comparison.small_signal = small_signal_comparison(set, &report, &pre_spectra);
    report.diagnostics = Some(diagnostics);
    // The ladder's steps that stayed in the model (one it removed again
    // has its own warning above).
    let kept =
        |e: &str| EffectId::parse(e).map_or(true, |id| result.model.effect_ids.contains(&id));
    for step in result.ladder.iter().skip(1) {
        if let Some(added) = step.added.as_deref().filter(|a| kept(a)) {
            warnings.push(format!(
                "the base model misses {added}: the diagnostics added it (model error {:.3} % after it)",
                step.model_error_percent
            ));
        }
    }
    report.warnings.extend(warnings);
    crate::identify::validity::judge(&mut report);
    Ok(Diagnosis { report })
}

/// Pairs of effects the data cannot separate: an effect A the ladder added
/// and a significant candidate B left out that removed nearly as much of the
/// base model's error (at least 80 % of it, held-out), and the swap test
/// fails: with B in the model instead of A, A is not significant either (so
/// neither is needed once the other is in). Each names the experiment that
/// would separate them.
pub fn ambiguities(
    d: &ForceBalanceData,
    r: &engine::EngineResult,
    opts: &engine::EngineOptions,
) -> Vec<Ambiguity> {
    let mut out = Vec::new();
    let find = |name: &str| r.candidates.iter().find(|c| c.effect == name);
    for added in r.ladder.iter().filter_map(|s| s.added.as_deref()) {
        let Some(a) = find(added) else { continue };
        for b in &r.candidates {
            let in_model = r.model.effect_ids.iter().any(|e| e.as_str() == b.effect);
            if b.effect == a.effect || in_model || !b.significant {
                continue;
            }
            if b.error_reduction_percent < 0.8 * a.error_reduction_percent {
                continue;
            }
            let (Ok(ea), Ok(eb)) = (EffectId::parse(&a.effect), EffectId::parse(&b.effect)) else {
                continue;
            };
            // Swap: the chosen model with B instead of A, A ranked against it.
            let mut forced: Vec<EffectId> = r
                .model
                .effect_ids
                .iter()
                .copied()
                .filter(|e| *e != ea)
                .collect();
            forced.push(eb);
            let swapped = engine::EngineOptions {
                forced,
                ladder: false,
                order: Some(r.model.order),
                ..opts.clone()
            };
            let a_after_b = engine::run(d, &swapped)
                .ok()
                .and_then(|s| s.candidates.into_iter().find(|c| c.effect == a.effect));
            if a_after_b.as_ref().is_some_and(|c| c.significant) {
                continue;
            }
            let exp = engine::Term::Effect(eb).separating_experiment();
            out.push(Ambiguity {
                note: format!(
                    "this data cannot separate {} from {} (they remove {:.0} % and {:.0} % of the base model's error, and neither is significant once the other is in); the ladder kept {}; to separate them: {}",
                    a.effect, b.effect, a.error_reduction_percent, b.error_reduction_percent, a.effect, exp
                ),
                effects: [a.effect.clone(), b.effect.clone()],
                error_reduction_percent: [a.error_reduction_percent, b.error_reduction_percent],
                p_value_of_first_after_second: a_after_b.map(|c| c.p_value),
                separating_experiment: exp.to_string(),
            });
        }
    }
    out
}

/// The small-signal transfer function `Hx = X / Mic` of the pre-measurement
/// against the identification's linear-resonator fit
/// `(Ss/g) / (k0 - w^2 m + j w R)`, magnitude (m/V). None without a fit.
fn small_signal_comparison(
    set: &RecordingSet,
    report: &Report,
    pre_spectra: &crate::identify::PreSpectra,
) -> Option<SmallSignalComparison> {
    let ss = report.small_signal.as_ref()?;
    let area = ss.force_per_mic_v_n_per_v?;
    let (k0, r) = (ss.k0_n_per_m?, ss.r_ns_per_m?);
    let pre = &set.pre;
    // The pre-measurement passed the small-signal fit's checks (finite
    // samples) before its spectra were taken.
    if pre.len() < 1024 {
        return None;
    }
    let fs = pre.sample_rate_hz;
    // The identification's spectra when their FFT size is this one's
    // (unpadded: it differs only when the record ends within 64 samples
    // of a power of two).
    let own;
    let (sx, sm) = if pre_spectra.spectra().0.n_fft == pre.len().max(2).next_power_of_two() {
        pre_spectra.spectra()
    } else {
        own = (
            crate::dsp::Spectrum::bands(&pre.displacement_m, fs, 0, 110.0, None),
            crate::dsp::Spectrum::bands(&pre.microphone_v, fs, 0, 110.0, None),
        );
        (&own.0, &own.1)
    };
    let tf = crate::dsp::transfer_function(sm, sx, 0.5, 110.0);
    let m = set.meta.moving_mass_kg;
    let (mut f, mut meas, mut fit, mut coh) = (vec![], vec![], vec![], vec![]);
    for (i, &fr) in tf.freq_hz.iter().enumerate() {
        if !(3.0..=110.0).contains(&fr) {
            continue;
        }
        let w = 2.0 * std::f64::consts::PI * fr;
        let den = crate::dsp::Complex64::new(k0 - w * w * m, w * r);
        f.push(fr);
        meas.push(tf.h[i].norm());
        fit.push(area.abs() / den.norm());
        coh.push(tf.coherence[i]);
    }
    Some(SmallSignalComparison {
        freq_hz: f,
        measured_abs_m_per_v: meas,
        fit_abs_m_per_v: fit,
        coherence: coh,
        reliable: ss.reliable,
        misfit_percent: ss.misfit_percent,
    })
}

/// The engine on force-balance data (no recording set needed).
pub fn diagnose_data(
    data: &ForceBalanceData,
    opts: &engine::EngineOptions,
) -> Result<engine::EngineResult, String> {
    engine::run(data, opts)
}

/// Names of the SVG plots (`{name}.svg`).
pub fn plot_names() -> &'static [&'static str] {
    svg::PLOT_NAMES
}

/// Renders one SVG plot of a diagnosis; None for an unknown name or a
/// diagnosis without diagnostics.
pub fn plot(_set: &RecordingSet, diagnosis: &Diagnosis, name: &str) -> Option<String> {
    svg::render(diagnosis.report.diagnostics.as_ref()?, name)
}
