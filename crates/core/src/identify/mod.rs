//! Identification: small-signal fit (pre-measurement), large-signal results and
//! nonlinear stiffness K(x) (One Signal / Two Signal) from a recording set.
//! Pure and synchronous: no I/O, no logging.
//!
//! CONTRACT shared with the daemon: `analyze`, `AnalyzeOptions`, `Method`,
//! `Report` (Serialize + Deserialize + Clone; JSON field names fixed by issue 2).
//!
//! This file is the pipeline; the result document's types are in
//! [`report`] (the report, its diagnostics, sub-documents and validity),
//! which depends on nothing else of `identify`.

use crate::recording::RecordingSet;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    #[default]
    TwoSignal,
    OneSignal,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AnalyzeOptions {
    pub method: Method,
    /// Highest power of K(x) = sum k_i x^i; chosen from the data when None.
    pub order: Option<usize>,
}

/// The standard error of f0 = sqrt(k0 / m) / (2 pi) from k0's relative
/// error: f0 rel_k / 2; None when it is undefined (k0 <= 0 gives f0 = 0 and
/// no relative error), never a NaN, which the store refuses with the whole
/// result.
pub fn f0_standard_error(f0_hz: f64, rel_k: f64) -> Option<f64> {
    let se = 0.5 * f0_hz * rel_k;
    (f0_hz > 0.0 && se.is_finite()).then_some(se)
}

/// Q = sqrt(k0 m) / R and its standard error from the relative errors of
/// k0 and R: (Q, its error, why Q is null). An undamped fit (R <= 0) has no
/// finite positive Q: null with the reason, never an infinity (which JSON
/// cannot carry and the store refuses, issue 11).
pub fn quality_factor(
    k0_n_per_m: f64,
    mass_kg: f64,
    r_ns_per_m: f64,
    rel_k: f64,
    rel_r: f64,
) -> (Option<f64>, Option<f64>, Option<String>) {
    let q = (k0_n_per_m.max(0.0) * mass_kg).sqrt() / r_ns_per_m;
    if !(r_ns_per_m > 0.0 && q.is_finite()) {
        return (
            None,
            None,
            Some(format!(
                "the fit found no damping (R = {r_ns_per_m:.3e} N s/m): Q = sqrt(k0 m) / R is infinite or undefined"
            )),
        );
    }
    let se = q * ((0.5 * rel_k).powi(2) + rel_r.powi(2)).sqrt();
    (Some(q), se.is_finite().then_some(se), None)
}

#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    #[error("{0}")]
    Invalid(String),
}

pub mod large;
mod prep;
pub mod report;
mod small;
mod stiffness;

pub use report::documents::WideBandResonance;
pub use report::{diagnostics, documents, validity};
pub use report::{LargeSignal, Model, Report, SmallSignal, Stiffness, StiffnessChange};
pub use small::{fit as small_signal_fit, SmallFit};
pub use small::{WideBand, COHERENCE_LIMIT, MISFIT_LIMIT_PERCENT};
pub use stiffness::{MAX_AUTO_ORDER, MAX_ORDER};

/// Relative variation of the microphone's fundamental over the One Signal span
/// above which the One Signal assumption (constant force at resonance) fails.
pub const ONE_SIGNAL_MIC_VARIATION_LIMIT: f64 = 0.2;

/// Analyses a recording set.
pub fn analyze(set: &RecordingSet, opts: &AnalyzeOptions) -> Result<Report, AnalyzeError> {
    analyze_sweeps(Sweeps::of(set), opts)
}

/// The two sweeps of a recording set and the moving mass, borrowed: a
/// caller that holds the pre-measurement once for many main sweeps (a level
/// series) analyses each level without copying it into a set.
#[derive(Debug, Clone, Copy)]
pub struct Sweeps<'a> {
    pub moving_mass_kg: f64,
    pub pre: &'a crate::recording::Signals,
    pub main: &'a crate::recording::Signals,
}

impl<'a> Sweeps<'a> {
    pub fn of(set: &'a RecordingSet) -> Sweeps<'a> {
        Sweeps {
            moving_mass_kg: set.meta.moving_mass_kg,
            pre: &set.pre,
            main: &set.main,
        }
    }
}

/// [`analyze`] of borrowed sweeps.
pub fn analyze_sweeps(s: Sweeps<'_>, opts: &AnalyzeOptions) -> Result<Report, AnalyzeError> {
    let (p, (fitted, excursion)) = prepare_and_fit(s.pre, s.main, s.moving_mass_kg, opts);
    let (p, kf) = p?;
    let (mut r, creep) = analyze_prepared(excursion, &p, opts, fitted, kf)?;
    validity::judge_plain(&mut r, creep.as_deref());
    Ok(r)
}

/// The main sweep's preparation and its K(x) fit, and the small-signal fit
/// of the pre-measurement with its excursion ([`pre_excursion`]):
/// independent of each other and about equal in cost, so they run side by
/// side on the two cores (rayon's pool, whose threads keep their FFT plans
/// between calls). The K(x) fit needs only the prepared main sweep: it runs
/// right after the preparation, beside the small-signal fit, instead of
/// alone after both (decision 0094). Given owned signals (`S = Signals`,
/// [`analyze_owned`]), each half drops its sweep's raw channels as soon as
/// it has read them, so the K(x) fit's designs reuse the main sweep's
/// memory instead of fresh pages; borrowed (`S = &Signals`) they stay the
/// caller's. The same arithmetic as one after the other: the numbers are
/// bit for bit the same.
#[allow(clippy::type_complexity)]
fn prepare_and_fit<S: Sweep>(
    pre: S,
    main: S,
    mass_kg: f64,
    opts: &AnalyzeOptions,
) -> (
    Result<(prep::Prepared, Result<stiffness::KFit, AnalyzeError>), AnalyzeError>,
    (Result<small::SmallFit, AnalyzeError>, Option<(f64, f64)>),
) {
    rayon::join(
        move || {
            let p = prep::prepare_sweep(main.borrow(), mass_kg, "main");
            drop(main);
            let p = p?;
            let kf = fit_stiffness(&p, opts);
            Ok((p, kf))
        },
        move || small_fit_and_excursion(pre, mass_kg),
    )
}

/// The small-signal fit of the pre-measurement ([`small::fit`]) and its
/// excursion ([`pre_excursion`]). The excursion's quantiles are a pass over
/// the displacement that the fit does not need: they run beside the
/// pre-measurement's spectra (a task the other core takes when it is
/// free), not alone after the fit (decision 0133). After both, an owned
/// sweep drops its displacement and microphone (12.7 MB for a 16.5 s
/// record): the fit reads only their spectra, and the drive. A failed
/// check gives no excursion, which nothing reads then (the analysis
/// reports the fit's error first).
fn small_fit_and_excursion<S: Sweep>(
    pre: S,
    mass_kg: f64,
) -> (Result<small::SmallFit, AnalyzeError>, Option<(f64, f64)>) {
    let signals: &crate::recording::Signals = pre.borrow();
    if let Err(e) = small::check(signals) {
        return (Err(e), None);
    }
    let ((sx, sm), excursion) = rayon::join(
        || small::spectra(signals),
        || pre_excursion(&signals.displacement_m),
    );
    let pre = pre.drive_only();
    (
        small::fit_spectra(pre.borrow(), mass_kg, &sx, &sm),
        excursion,
    )
}

/// A sweep the analysis borrows (`&Signals`: the caller keeps it) or owns
/// (`Signals`: the analysis frees its channels once it has read them).
trait Sweep: std::borrow::Borrow<crate::recording::Signals> + Send + Sized {
    /// The sweep without its displacement and microphone when owned (their
    /// memory freed), as it is when borrowed: only for what reads the
    /// sample rate and the drive (`small::fit_spectra`).
    fn drive_only(self) -> Self;
}

impl Sweep for crate::recording::Signals {
    fn drive_only(mut self) -> Self {
        self.displacement_m = Vec::new();
        self.microphone_v = Vec::new();
        self
    }
}

impl Sweep for &crate::recording::Signals {
    fn drive_only(self) -> Self {
        self
    }
}

/// [`analyze`] of a set the caller gives away (the CLI): the same report,
/// with each sweep's raw channels freed as soon as the analysis has read
/// them ([`prepare_and_fit`]), which lowers the process's peak memory.
pub fn analyze_owned(set: RecordingSet, opts: &AnalyzeOptions) -> Result<Report, AnalyzeError> {
    let RecordingSet { meta, pre, main } = set;
    let (p, (fitted, excursion)) = prepare_and_fit(pre, main, meta.moving_mass_kg, opts);
    let (p, kf) = p?;
    let (mut r, creep) = analyze_prepared(excursion, &p, opts, fitted, kf)?;
    validity::judge_plain(&mut r, creep.as_deref());
    Ok(r)
}

/// The K(x) fit of a prepared main sweep as [`analyze_prepared`] takes it
/// (over the analysed span, One Signal as Two Signal).
fn fit_stiffness(
    p: &prep::Prepared,
    opts: &AnalyzeOptions,
) -> Result<stiffness::KFit, AnalyzeError> {
    stiffness::fit(p, opts.method, p.span, opts.order)
}

/// [`analyze`] and [`force_balance_data`] from one preparation of the main
/// sweep (the diagnostics need both; preparing twice doubled their cost).
pub fn analyze_with_force_balance(
    set: &RecordingSet,
    opts: &AnalyzeOptions,
) -> Result<(Report, ForceBalanceData), AnalyzeError> {
    analyze_sweeps_with_force_balance(Sweeps::of(set), opts)
}

/// [`analyze_with_force_balance`] of borrowed sweeps.
pub fn analyze_sweeps_with_force_balance(
    s: Sweeps<'_>,
    opts: &AnalyzeOptions,
) -> Result<(Report, ForceBalanceData), AnalyzeError> {
    let (p, (fitted, excursion)) = prepare_and_fit(s.pre, s.main, s.moving_mass_kg, opts);
    let (p, kf) = p?;
    let (mut report, creep) = analyze_prepared(excursion, &p, opts, fitted, kf)?;
    validity::judge_plain(&mut report, creep.as_deref());
    Ok((report, force_balance_of(&p, false)))
}

/// The pre-measurement's spectra, transformed once for the diagnostics: the
/// small-signal fit, the pre-measurement's force balance and the comparison
/// plot each took its own two 2^20-point FFTs before.
#[derive(Debug, Clone)]
pub struct PreSpectra {
    sx: crate::dsp::Spectrum,
    sm: crate::dsp::Spectrum,
}

impl PreSpectra {
    /// [`pre_force_balance_data`] from these spectra.
    pub fn force_balance_data(&self, set: &RecordingSet) -> Result<ForceBalanceData, AnalyzeError> {
        let p = prep::prepare_shared(&set.pre, set.meta.moving_mass_kg, "pre", &self.sx, &self.sm)?;
        Ok(force_balance_of(&p, true))
    }

    /// A resonance at a fixed frequency of its own in the pre-measurement's
    /// transfer function over the whole excited band (a second mechanical
    /// mode), when it explains it far better than the linear resonator
    /// and than creep (`small::wide_band_resonance`).
    pub fn wide_band_resonance(&self, set: &RecordingSet) -> Option<WideBandResonance> {
        let m = set.meta.moving_mass_kg;
        small::wide_band(&set.pre, m, &self.sx, &self.sm, true, None)?.resonance(m)
    }

    /// Displacement and microphone spectra of the whole pre-measurement
    /// (FFT size: the record plus at least 64 samples, to a power of two).
    pub fn spectra(&self) -> (&crate::dsp::Spectrum, &crate::dsp::Spectrum) {
        (&self.sx, &self.sm)
    }
}

/// [`analyze_with_force_balance`] plus the pre-measurement's spectra (the
/// same report: the small-signal fit runs on those spectra).
pub fn analyze_for_diagnosis(
    set: &RecordingSet,
    opts: &AnalyzeOptions,
) -> Result<(Report, ForceBalanceData, PreSpectra), AnalyzeError> {
    let (p, pre_spectra) = rayon::join(
        || prep::prepare(set).map(|p| (p, pre_excursion(&set.pre.displacement_m))),
        || small::check(&set.pre).map(|()| prep::spectra(&set.pre)),
    );
    let (p, excursion) = p?;
    let (sx, sm) = pre_spectra?;
    // The diagnostics fit creep themselves: the plain analysis's mark for it
    // is not theirs.
    let fitted = small::fit_spectra(&set.pre, p.mass_kg, &sx, &sm);
    let kf = fit_stiffness(&p, opts);
    let (report, _) = analyze_prepared(excursion, &p, opts, fitted, kf)?;
    Ok((report, force_balance_of(&p, false), PreSpectra { sx, sm }))
}

/// The report of a prepared main sweep, its K(x) fit ([`fit_stiffness`])
/// and the small-signal fit of its pre-measurement (`pre_excursion`: the
/// pre-measurement's, by [`pre_excursion`]). A failed small-signal fit is
/// reported before a failed K(x) fit, as when the K(x) fit ran after it.
fn analyze_prepared(
    pre_excursion: Option<(f64, f64)>,
    p: &prep::Prepared,
    opts: &AnalyzeOptions,
    fitted: Result<small::SmallFit, AnalyzeError>,
    kf: Result<stiffness::KFit, AnalyzeError>,
) -> Result<(Report, Option<String>), AnalyzeError> {
    let mut warnings = Vec::new();

    let (mut small_signal, creep) = match fitted {
        Ok(f) => {
            warnings.extend(f.warnings);
            (Some(f.result), f.creep)
        }
        Err(e) => return Err(e),
    };

    let span = match opts.method {
        Method::TwoSignal => p.span,
        Method::OneSignal => {
            let (_, variation) = one_signal_span(p);
            if variation > ONE_SIGNAL_MIC_VARIATION_LIMIT {
                warnings.push(format!(
                    "one-signal assumption fails: the microphone's fundamental varies by {:.0} % (> {:.0} %) around the resonance, so the driving force is not constant; use two-signal",
                    100.0 * variation,
                    100.0 * ONE_SIGNAL_MIC_VARIATION_LIMIT
                ));
            }
            p.span
        }
    };
    let kf = kf?;
    if opts.order.is_none() && kf.order == MAX_AUTO_ORDER {
        warnings.push(format!(
            "stiffness order reached the automatic limit {MAX_AUTO_ORDER}: the polynomial may not describe K(x) well"
        ));
    }
    if let (Some(ss), Some((s, _))) = (&small_signal, kf.scale_n_per_v) {
        if let Some(a) = ss.force_per_mic_v_n_per_v {
            if ss.reliable && ((s - a) / a).abs() > 0.1 {
                warnings.push(format!(
                    "microphone scale differs between pre-measurement ({a:.4} N/V) and main sweep ({s:.4} N/V)"
                ));
            }
        }
    }
    let large_signal = large_signal(p, &kf, &mut warnings)?;
    if let Some(ss) = small_signal.as_mut() {
        mark_pre_level_bend(ss, pre_excursion, &kf.k);
    }
    let (xlo, xhi) = extremes(&p.x[span.0..span.1]);
    let k0 = kf.k_of_x(0.0);
    let xc = [xc_side(&kf, k0, xlo), xc_side(&kf, k0, xhi)];
    let mut stiffness_validity = validity::StiffnessValidity::default();
    let (keff, keff_kx) = (
        large_signal.keff_n_per_m,
        large_signal.keff_from_k_of_x_n_per_m,
    );
    if keff_kx.is_finite() && ((keff / keff_kx) - 1.0).abs() > KEFF_CROSS_CHECK_LIMIT {
        stiffness_validity.k_of_x.mark(
            validity::State::Unreliable,
            &cross_check_reason(keff, keff_kx),
        );
    }
    let stiffness = Stiffness {
        method: match opts.method {
            Method::TwoSignal => "two-signal".into(),
            Method::OneSignal => "one-signal".into(),
        },
        order: kf.order,
        coefficients_n_per_mm_pow_i_plus_1: kf
            .k
            .iter()
            .enumerate()
            .map(|(i, k)| k * 1e-3f64.powi(i as i32 + 1))
            .collect(),
        coefficients_n_per_m_pow_i_plus_1: kf.k.clone(),
        coefficients_se_n_per_m_pow_i_plus_1: kf.k_se.clone(),
        valid_range_m: [xlo, xhi],
        xc_m: xc,
        r_ns_per_m: kf.r_ns_per_m,
        force_per_mic_v_n_per_v: kf.scale_n_per_v.map(|s| s.0),
        validity: stiffness_validity,
        ..Default::default()
    };

    // Noise floor of the force balance: what the sensor noise puts into e.
    let xs = &p.x[span.0..span.1];
    let mean_kinc2 = xs
        .iter()
        .map(|&x| (kf.k_of_x(x) + x * kf.dk_dx(x)).powi(2))
        .sum::<f64>()
        / xs.len() as f64;
    let s = kf.scale_n_per_v.map_or(0.0, |s| s.0);
    let noise_n = ((p.mass_kg * p.noise_a_m_per_s2).powi(2)
        + (s * p.noise_mic_v).powi(2)
        + (kf.r_ns_per_m * p.noise_v_m_per_s).powi(2)
        + mean_kinc2 * p.noise_x_m.powi(2))
    .sqrt();
    let residual_percent = kf.residual_percent();
    let noise_floor_percent = 100.0 * noise_n / kf.rms_ma_n;
    let model = Model {
        effects: Default::default(),
        residual_percent,
        noise_floor_percent,
        model_error_percent: (residual_percent.powi(2) - noise_floor_percent.powi(2))
            .max(0.0)
            .sqrt(),
    };
    Ok((
        Report {
            small_signal,
            large_signal,
            stiffness,
            model,
            warnings,
            diagnostics: None,
            series: None,
        },
        creep,
    ))
}

/// How far K(x) may bend over the pre-measurement's excursion before the
/// small-signal k0 and f0 (a linear resonator fitted at that level) are no
/// longer the part's stiffness at rest within k0's stated accuracy (3 %,
/// docs/diagnostics.md "Bad parts"; f0 half of it).
pub const PRE_LEVEL_BEND_LIMIT: f64 = 0.03;

/// Marks k0 and f0 `unreliable` when the main sweep's K(x) shows that the
/// pre-measurement's level already bends the stiffness by more than
/// [`PRE_LEVEL_BEND_LIMIT`]: the linear resonator then measures Keff at that
/// level, not k0 (a strongly hardening spider at 1.5 mm: +3.3 %, issue 22).
fn mark_pre_level_bend(ss: &mut SmallSignal, pre_excursion: Option<(f64, f64)>, k: &[f64]) {
    let Some((lo, hi)) = pre_excursion else {
        return;
    };
    let k0 = k.first().copied().unwrap_or(f64::NAN);
    let keff = large::describing_function_keff(k, lo, hi);
    let bend = keff / k0 - 1.0;
    if !(bend.is_finite() && k0 > 0.0) || bend.abs() <= PRE_LEVEL_BEND_LIMIT {
        return;
    }
    let why = format!(
        "the pre-measurement's excursion {:.2} .. {:.2} mm already bends K(x) of the main sweep by {:+.1} % (Keff there against K(0)): the linear resonator measures the stiffness at that level, not at rest; measure the pre-measurement at a lower level",
        lo * 1e3,
        hi * 1e3,
        100.0 * bend
    );
    ss.validity
        .k0_n_per_m
        .mark(validity::State::Unreliable, &why);
    ss.validity.f0_hz.mark(validity::State::Unreliable, &why);
}

/// The pre-measurement's excursion (m) that [`mark_pre_level_bend`] judges:
/// its 0.1 % and 99.9 % quantiles, so that a laser's noise spikes do not
/// widen it (the resonance holds the peak for many periods). None for fewer
/// than 1000 finite samples.
fn pre_excursion(pre_x_m: &[f64]) -> Option<(f64, f64)> {
    crate::dsp::quantile_pair(pre_x_m, 0.001, 0.999, 1000)
}

/// Prepares the force-balance data of the main sweep of `set` (band limiting,
/// differentiation, alignment, analysed span). Shared by `analyze` and `diagnose`.
pub fn force_balance_data(
    set: &RecordingSet,
    _opts: &AnalyzeOptions,
) -> Result<ForceBalanceData, AnalyzeError> {
    let p = prep::prepare(set)?;
    Ok(force_balance_of(&p, false))
}

/// Xpeak (m) of a main sweep as the analysis reads it (`LargeSignal::xpeak_m`:
/// the larger extreme of the band-limited displacement in the period at the
/// resonance, where x lags the force by 90 degrees). A procedure that checks
/// the level it reached with this measure accepts the sweeps the analysis
/// accepts; the raw samples' largest |x| lies where the upper branch ends,
/// past that period (a cone_6in `hardening` part: 5.62 mm against 5.37 mm).
pub fn sweep_xpeak_m(main: &crate::recording::Signals, mass_kg: f64) -> Result<f64, AnalyzeError> {
    let p = prep::prepare_sweep(main, mass_kg, "main")?;
    let (i, _) = resonance_period(&p)
        .ok_or_else(|| AnalyzeError::Invalid("main: no resonance inside the sweep".into()))?;
    Ok(p.px[i].max.max(-p.px[i].min))
}

/// Half the peak-to-peak excursion of a main sweep in the period at its
/// resonance (m): how far it reached on both sides of the centre Keff at a
/// target is read around (the production procedure's level check, issue 35).
pub fn sweep_reach_m(main: &crate::recording::Signals, mass_kg: f64) -> Result<f64, AnalyzeError> {
    let p = prep::prepare_sweep(main, mass_kg, "main")?;
    let (i, _) = resonance_period(&p)
        .ok_or_else(|| AnalyzeError::Invalid("main: no resonance inside the sweep".into()))?;
    Ok(0.5 * (p.px[i].max - p.px[i].min))
}

/// The period the large-signal values are read at: where x lags the force by
/// 90 degrees (with fR), else the displacement peak when it lies inside the
/// sweep (fR None).
fn resonance_period(p: &prep::Prepared) -> Option<(usize, Option<f64>)> {
    match large::find(p) {
        Some(r) => Some((r.index, Some(r.fr_hz))),
        None if p.disp_peak_inside => Some((p.res_index, None)),
        None => None,
    }
}

/// The force-balance data of the pre-measurement, prepared like the main
/// sweep (its span: where the displacement's fundamental exceeds 10 % of its
/// peak). The diagnostics fit the small-signal model with effects on it.
pub fn pre_force_balance_data(set: &RecordingSet) -> Result<ForceBalanceData, AnalyzeError> {
    let p = prep::prepare_sweep(&set.pre, set.meta.moving_mass_kg, "pre")?;
    Ok(force_balance_of(&p, true))
}

/// The analysed span of a prepared main sweep (the same for both methods).
fn force_balance_of(p: &prep::Prepared, starts_at_rest: bool) -> ForceBalanceData {
    let (s0, s1) = p.span;
    ForceBalanceData {
        sample_rate_hz: p.fs_hz,
        t0_s: s0 as f64 / p.fs_hz,
        mass_kg: p.mass_kg,
        x_m: p.x[s0..s1].to_vec(),
        v_m_per_s: p.v[s0..s1].to_vec(),
        a_m_per_s2: p.a[s0..s1].to_vec(),
        mic_v: p.mic[s0..s1].to_vec(),
        laser_noise_m: p.noise_x_m,
        mic_noise_v: p.noise_mic_v,
        starts_at_rest,
    }
}

/// Relative difference between Keff from the phase and from the fitted K(x)
/// above which the result says that an assumption of the force balance fails.
pub const KEFF_CROSS_CHECK_LIMIT: f64 = 0.03;

/// fR, Keff(Xpeak) and the excursion at resonance (see [`large`]).
fn large_signal(
    p: &prep::Prepared,
    kf: &stiffness::KFit,
    warnings: &mut Vec<String>,
) -> Result<LargeSignal, AnalyzeError> {
    let m = p.mass_kg;
    let w2m = |f: f64| (2.0 * std::f64::consts::PI * f).powi(2) * m;
    let peak_hz = large::freq_at(p, p.res_pos);
    let mut states = validity::LargeSignalValidity::default();
    let mut mark = |why: &str| {
        states.resonance_hz.mark(validity::State::Unreliable, why);
        states.keff_n_per_m.mark(validity::State::Unreliable, why);
    };
    let (ri, fr) = match resonance_period(p) {
        Some((i, Some(fr))) => (i, fr),
        Some((i, None)) => {
            warnings.push(format!(
                "the displacement never lags the driving force (microphone) by 90 degrees inside the sweep: fR = {peak_hz:.2} Hz is the displacement peak, which lies below the resonance of a damped part and is moved by the box's air spring"
            ));
            mark("the displacement never lags the force by 90 degrees inside the sweep: fR is the displacement peak");
            (i, peak_hz)
        }
        None => {
            return Err(AnalyzeError::Invalid(
                "main: no resonance inside the sweep (the displacement neither peaks nor lags the driving force by 90 degrees inside it)"
                    .into(),
            ))
        }
    };
    let n = p.px.len();
    if ri < 2 || ri + 2 >= n {
        warnings.push(format!(
            "the resonance ({fr:.2} Hz) lies at an end of the sweep: sweep from further below to further above it"
        ));
        mark("the resonance lies at an end of the sweep");
    }
    let period = &p.px[ri];
    let (xlo, xhi) = (period.min, period.max);
    let keff = w2m(fr);
    let keff_kx = large::describing_function_keff(&kf.k, xlo, xhi);
    if keff_kx.is_finite() && ((keff / keff_kx) - 1.0).abs() > KEFF_CROSS_CHECK_LIMIT {
        warnings.push(format!(
            "Keff from the resonance ({keff:.1} N/m) and from the fitted K(x) over the same excursion ({keff_kx:.1} N/m) differ by {:.1} % (> {:.0} %): the fitted K(x) or the force balance is off (an effect outside the model, see --diagnose; a delayed microphone; or a failed One Signal assumption)",
            100.0 * (keff / keff_kx - 1.0),
            100.0 * KEFF_CROSS_CHECK_LIMIT
        ));
        mark(&cross_check_reason(keff, keff_kx));
    }
    let note = ((peak_hz / fr - 1.0).abs() > 0.005).then(|| {
        let mic = |i: usize| p.pm[i].amplitude(1);
        let change = mic(p.res_index) / mic(ri) - 1.0;
        let q = (keff * m).sqrt() / kf.r_ns_per_m;
        if change.abs() > 0.05 {
            format!(
                "the displacement peaks at {peak_hz:.2} Hz, not at fR {fr:.2} Hz: the driving force (box pressure) there is {:.0} % {} than at fR, because the box's air spring takes part (large effective area); fR is where x lags the force by 90 degrees",
                100.0 * change.abs(),
                if change < 0.0 { "lower" } else { "higher" }
            )
        } else {
            let ideal = (1.0 - 0.5 / (q * q)).max(0.0).sqrt();
            format!(
                "the displacement peaks at {peak_hz:.2} Hz, {:.1} % {} fR {fr:.2} Hz: a damped resonator (Q = {q:.1}) driven by a constant force peaks at {ideal:.3} fR; fR is where x lags the force by 90 degrees",
                100.0 * (peak_hz / fr - 1.0).abs(),
                if peak_hz < fr { "below" } else { "above" }
            )
        }
    });
    let (x_min, x_max) = extremes(&p.x[p.span.0..p.span.1]);
    Ok(LargeSignal {
        resonance_hz: fr,
        keff_n_per_m: keff,
        ceff_m_per_n: 1.0 / keff,
        xpeak_m: xhi.max(-xlo),
        x_min_m: x_min,
        x_max_m: x_max,
        dc_m: period.dc,
        moving_mass_kg: m,
        harmonics_m: period.harmonics.iter().map(|c| c.norm()).collect(),
        x_min_at_resonance_m: xlo,
        x_max_at_resonance_m: xhi,
        keff_from_k_of_x_n_per_m: keff_kx,
        displacement_peak_hz: peak_hz,
        displacement_peak_note: note,
        resonance_time_s: 0.5 * (period.start + period.end) / p.fs_hz,
        keff_se_n_per_m: None,
        keff_method: Some("phase".into()),
        target_xpeak_m: None,
        keff_at_target_n_per_m: None,
        base: None,
        validity: states,
    })
}

/// Why Keff and K(x) are unreliable when they disagree by more than
/// [`KEFF_CROSS_CHECK_LIMIT`].
fn cross_check_reason(keff: f64, keff_kx: f64) -> String {
    format!(
        "Keff from the resonance and from the fitted K(x) over the same excursion differ by {:.1} % (> {:.0} %): an effect outside the model (see the diagnostics), a delayed microphone or a failed One Signal assumption",
        100.0 * (keff / keff_kx - 1.0),
        100.0 * KEFF_CROSS_CHECK_LIMIT
    )
}

/// Minimum and maximum of a sampled band-limited signal, refined by a parabola
/// through the extreme sample and its neighbours.
fn extremes(x: &[f64]) -> (f64, f64) {
    let refine = |i: usize| -> f64 {
        if i == 0 || i + 1 >= x.len() {
            return x[i];
        }
        let (a, b, c) = (x[i - 1], x[i], x[i + 1]);
        let den = a - 2.0 * b + c;
        if den == 0.0 {
            return b;
        }
        let off = (0.5 * (a - c) / den).clamp(-0.5, 0.5);
        b - 0.25 * (a - c) * off
    };
    let (mut imin, mut imax) = (0, 0);
    for (i, &v) in x.iter().enumerate() {
        if v < x[imin] {
            imin = i;
        }
        if v > x[imax] {
            imax = i;
        }
    }
    (refine(imin), refine(imax))
}

/// The periods around the resonance (from where the fundamental of x first
/// reaches 70 % of its peak up to the resonance period) and the relative
/// variation of the microphone's fundamental over them: One Signal needs a
/// drive force that does not change over the resonance.
fn one_signal_span(p: &prep::Prepared) -> ((usize, usize), f64) {
    let ri = p.res_index;
    let peak = p.px[ri].amplitude(1);
    let mut lo = ri;
    while lo > 0 && p.px[lo - 1].amplitude(1) >= 0.7 * peak {
        lo -= 1;
    }
    let hi = (ri + 1).min(p.px.len() - 1);
    let lo = lo.min(hi.saturating_sub(10));
    let mics: Vec<f64> = p.pm[lo..=hi].iter().map(|q| q.amplitude(1)).collect();
    let (mn, mx) = mics
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
    let mean = mics.iter().sum::<f64>() / mics.len() as f64;
    let variation = if mean > 0.0 { (mx - mn) / mean } else { 0.0 };
    let s0 = p.px[lo].start.ceil().max(0.0) as usize;
    let s1 = (p.px[hi].end.floor() as usize).min(p.x.len());
    ((s0, s1), variation)
}

/// Where C(x) = 1/K(x) first falls to 75 % of C(0) between 0 and `edge`.
fn xc_side(kf: &stiffness::KFit, k0: f64, edge: f64) -> Option<f64> {
    if k0.is_nan() || k0 <= 0.0 || edge == 0.0 {
        return None;
    }
    let target = k0 / 0.75;
    let steps = 2000;
    let mut prev = 0.0;
    for i in 1..=steps {
        let x = edge * i as f64 / steps as f64;
        if kf.k_of_x(x) >= target {
            // Bisection between prev and x.
            let (mut a, mut b) = (prev, x);
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                if kf.k_of_x(m) >= target {
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

/// The large-signal force-balance data, prepared once by the identification
/// and shared with [`crate::diagnose`] (which extends the same force balance
/// with candidate effects). All SI; every slice has the same length and covers
/// the analysed span of the main sweep (already band-limited, possibly decimated).
#[derive(Debug, Clone, PartialEq)]
pub struct ForceBalanceData {
    /// Sample rate of these slices (Hz).
    pub sample_rate_hz: f64,
    /// Time of the first sample, from the start of the main recording (s).
    pub t0_s: f64,
    /// Moving mass (kg).
    pub mass_kg: f64,
    /// Displacement (m), band-limited.
    pub x_m: Vec<f64>,
    /// Velocity (m/s).
    pub v_m_per_s: Vec<f64>,
    /// Acceleration (m/s^2).
    pub a_m_per_s2: Vec<f64>,
    /// Microphone (V), band-limited, aligned with x.
    pub mic_v: Vec<f64>,
    /// Standard deviation of the laser noise estimated from the data (m), for the noise floor.
    pub laser_noise_m: f64,
    /// Standard deviation of the microphone noise estimated from the data (V).
    pub mic_noise_v: f64,
    /// True when the span starts with the part at rest, or near it (the
    /// pre-measurement's slow start, a simulation from rest): a state
    /// variable such as creep's relaxed position starts at x[0]. False for a
    /// span that starts mid-oscillation (the main sweep).
    pub starts_at_rest: bool,
}

#[cfg(test)]
mod f0_se_tests {
    use super::f0_standard_error;

    #[test]
    fn f0_error_follows_k0_and_is_null_without_a_stiffness() {
        // k0 = 2500 N/m, m = 20 g: f0 = sqrt(2500 / 0.02) / 2 pi = 56.27 Hz;
        // 1 % on k0 is 0.5 % on f0.
        let f0 = (2500.0f64 / 0.02).sqrt() / (2.0 * std::f64::consts::PI);
        let se = f0_standard_error(f0, 0.01).unwrap();
        assert!(
            (se - 0.005 * f0).abs() < 1e-12 && (se - 0.28135).abs() < 1e-4,
            "{se}"
        );
        // k0 <= 0: f0 is 0 and rel_k NaN (k0 = 0) or negative; no error, no NaN.
        assert_eq!(f0_standard_error(0.0, f64::NAN), None);
        assert_eq!(f0_standard_error(0.0, -0.3), None);
    }
}
