//! Small-signal fit of the pre-measurement: `X/Mic = A / (k0 - w^2 m + j w R)`
//! with the weighed mass m, linear in (k0, R, A) once multiplied out, fitted
//! on the full-record transfer function around the resonance, reweighted to
//! the output error (the displacement spectrum) in a few passes.

use super::prep::{check_signals, lowpass_for};
use super::{AnalyzeError, SmallSignal};
use crate::dsp::{self, Complex64, Spectrum};
use crate::recording::Signals;
use std::f64::consts::PI;

/// Misfit (%) above which the pre-measurement is not taken as a linear resonator.
pub const MISFIT_LIMIT_PERCENT: f64 = 10.0;
/// Mean coherence in the fit band below which the pre-measurement is unreliable.
pub const COHERENCE_LIMIT: f64 = 0.95;

/// The fit and what it was judged by.
#[derive(Debug, Clone)]
pub struct SmallFit {
    pub result: SmallSignal,
    pub warnings: Vec<String>,
}

pub fn fit(pre: &Signals, mass_kg: f64) -> Result<SmallFit, AnalyzeError> {
    check(pre)?;
    let (fs, fmax) = (pre.sample_rate_hz, max_hz(pre.sample_rate_hz));
    // Only the bins up to fmax are used.
    let (sx, sm) = (
        Spectrum::bands(&pre.displacement_m, fs, 64, fmax, None),
        Spectrum::bands(&pre.microphone_v, fs, 64, fmax, None),
    );
    fit_spectra(pre, mass_kg, &sx, &sm)
}

/// The checks [`fit`] makes before it transforms the pre-measurement.
pub fn check(pre: &Signals) -> Result<(), AnalyzeError> {
    check_signals(pre, "pre", 1.0)
}

/// Highest frequency of the fit's bins (Hz).
fn max_hz(fs: f64) -> f64 {
    lowpass_for(fs).pass_hz.min(0.45 * fs)
}

/// [`fit`] on the spectra of the checked pre-measurement (FFT padded by at
/// least 64 samples, as [`fit`] takes them; bins up to the low-pass at least).
pub fn fit_spectra(
    pre: &Signals,
    mass_kg: f64,
    sx: &Spectrum,
    sm: &Spectrum,
) -> Result<SmallFit, AnalyzeError> {
    let fs = pre.sample_rate_hz;
    let fmax = max_hz(fs);
    let tf = dsp::transfer_function(sm, sx, sx.df_hz(), fmax);
    // Where the stimulus has energy: the frequency range of the drive's periods
    // when the drive is recorded, else where the microphone has power.
    let drive_band = pre.drive_v.as_ref().and_then(|d| {
        let peak = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let marks = dsp::period_marks(d, 0.05 * peak);
        let f = marks.windows(2).map(|w| fs / (w[1] - w[0]));
        let (lo, hi) = f.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
        (marks.len() > 10 && hi > lo).then_some((lo, hi))
    });
    let excited: Vec<bool> = match drive_band {
        Some((lo, hi)) => tf.freq_hz.iter().map(|f| *f >= lo && *f <= hi).collect(),
        None => {
            let smooth = smooth_mean(&tf.input_power, (1.0 / sx.df_hz()).round() as usize);
            let pmax = smooth.iter().cloned().fold(0.0, f64::max);
            smooth.iter().map(|&p| p > 1e-2 * pmax).collect()
        }
    };
    // Coarse resonance: peak of |H| (1 Hz smoothed) over the excited band.
    let hs: Vec<f64> = tf.h.iter().map(|h| h.norm()).collect();
    let hs = smooth_mean(&hs, (1.0 / sx.df_hz()).round() as usize);
    let (mut kpk, mut hpk) = (None, 0.0);
    for k in 0..hs.len() {
        if excited[k] && tf.freq_hz[k] > 1.0 && hs[k] > hpk {
            hpk = hs[k];
            kpk = Some(k);
        }
    }
    let kpk = kpk
        .ok_or_else(|| AnalyzeError::Invalid("pre: the sweep excites no frequency band".into()))?;
    let fpk = tf.freq_hz[kpk];
    let (flo, fhi) = (fpk / 2.0, fpk * 2.0);
    let idx: Vec<usize> = (0..tf.freq_hz.len())
        .filter(|&k| excited[k] && tf.freq_hz[k] >= flo && tf.freq_hz[k] <= fhi)
        .collect();
    if idx.len() < 20 {
        return Err(AnalyzeError::Invalid(
            "pre: too little of the sweep around the resonance".into(),
        ));
    }
    let band = (tf.freq_hz[idx[0]], tf.freq_hz[*idx.last().unwrap()]);
    let xs: Vec<Complex64> = idx.iter().map(|&k| sx.bins[k + 1]).collect();
    let ms: Vec<Complex64> = idx.iter().map(|&k| sm.bins[k + 1]).collect();
    let ws: Vec<f64> = idx.iter().map(|&k| 2.0 * PI * tf.freq_hz[k]).collect();
    let n = idx.len();
    // Start: weights 1 / |w^2 m| (mass-line scale), then 1/|D| of the last fit.
    let mut wgt: Vec<f64> = ws.iter().map(|w| 1.0 / (w * w * mass_kg)).collect();
    let mut sol = None;
    for _ in 0..4 {
        let mut c_k = Vec::with_capacity(2 * n);
        let mut c_r = Vec::with_capacity(2 * n);
        let mut c_a = Vec::with_capacity(2 * n);
        let mut y = Vec::with_capacity(2 * n);
        for i in 0..n {
            let (x, m, w, g) = (xs[i], ms[i], ws[i], wgt[i]);
            let jwx = Complex64::new(0.0, w) * x;
            let t = x * (w * w * mass_kg);
            c_k.extend([g * x.re, g * x.im]);
            c_r.extend([g * jwx.re, g * jwx.im]);
            c_a.extend([-g * m.re, -g * m.im]);
            y.extend([g * t.re, g * t.im]);
        }
        let r = dsp::lstsq(&[&c_k, &c_r, &c_a], &y)
            .map_err(|e| AnalyzeError::Invalid(format!("pre: small-signal fit failed: {e}")))?;
        let (k0, rr) = (r.coefficients[0], r.coefficients[1]);
        for i in 0..n {
            let d = Complex64::new(k0 - ws[i] * ws[i] * mass_kg, ws[i] * rr).norm();
            wgt[i] = if d > 0.0 { 1.0 / d } else { 0.0 };
        }
        sol = Some(r);
    }
    let r = sol.expect("loop ran");
    let (k0, rr, aa) = (r.coefficients[0], r.coefficients[1], r.coefficients[2]);
    let (sk, sr) = (r.standard_errors[0], r.standard_errors[1]);
    // Misfit: displacement spectrum predicted from the microphone vs measured.
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n {
        let d = Complex64::new(k0 - ws[i] * ws[i] * mass_kg, ws[i] * rr);
        let pred = ms[i] * aa / d;
        num += (xs[i] - pred).norm_sqr();
        den += xs[i].norm_sqr();
    }
    let misfit_percent = 100.0 * (num / den.max(f64::MIN_POSITIVE)).sqrt();
    // Coherence over 1 Hz bands inside the fit band, weighted by input power.
    let tfc = dsp::transfer_function(sm, sx, 1.0, band.1);
    let (mut cs, mut ps) = (0.0, 0.0);
    for k in 0..tfc.freq_hz.len() {
        if tfc.freq_hz[k] >= band.0 && tfc.freq_hz[k] <= band.1 {
            cs += tfc.coherence[k] * tfc.input_power[k];
            ps += tfc.input_power[k];
        }
    }
    let mean_coherence = if ps > 0.0 { cs / ps } else { 0.0 };

    let mut warnings = Vec::new();
    let mut reliable = true;
    let physical = k0 > 0.0 && rr > 0.0 && aa.is_finite() && aa != 0.0;
    if !physical {
        reliable = false;
        warnings.push(format!(
            "pre-measurement unreliable: the fit is not a physical resonator (k0 {k0:.4} N/m, R {rr:.4} N s/m)"
        ));
    }
    if misfit_percent > MISFIT_LIMIT_PERCENT {
        reliable = false;
        warnings.push(format!(
            "pre-measurement unreliable: it is not a linear resonator (misfit {misfit_percent:.1} % > {MISFIT_LIMIT_PERCENT} %; dry friction sticking at this level, or the level is too high)"
        ));
    }
    if mean_coherence < COHERENCE_LIMIT {
        reliable = false;
        warnings.push(format!(
            "pre-measurement unreliable: low coherence {mean_coherence:.3} (< {COHERENCE_LIMIT}) around the resonance (noise or nonlinearity)"
        ));
    }
    let w0 = (k0.max(0.0) / mass_kg).sqrt();
    let f0 = w0 / (2.0 * PI);
    let rel_k = if k0 > 0.0 { sk / k0 } else { f64::NAN };
    let (q, q_se, q_null_reason) = super::quality_factor(k0, mass_kg, rr, rel_k, sr / rr);
    let result = SmallSignal {
        f0_hz: f0,
        k0_n_per_m: k0,
        r_ns_per_m: rr,
        q,
        f0_se_hz: super::f0_standard_error(f0, rel_k),
        k0_se_n_per_m: sk,
        r_se_ns_per_m: sr,
        q_se,
        q_null_reason,
        force_per_mic_v_n_per_v: Some(aa),
        misfit_percent,
        reliable,
        ..Default::default()
    };
    Ok(SmallFit { result, warnings })
}

fn smooth_mean(v: &[f64], w: usize) -> Vec<f64> {
    let h = w / 2;
    let mut pre = vec![0.0; v.len() + 1];
    for i in 0..v.len() {
        pre[i + 1] = pre[i] + v[i];
    }
    (0..v.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(h), (i + h + 1).min(v.len()));
            (pre[b] - pre[a]) / (b - a) as f64
        })
        .collect()
}
