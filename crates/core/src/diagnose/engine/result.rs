//! What the engine found: the fitted models, the candidates and the ladder,
//! and the `diagnostics` document with the comparison data the plots draw.

use crate::diagnose::spectrum;
use crate::identify::diagnostics::{
    ByDirection, Comparison, Detail, Diagnostics, Envelope, MethodNotes, ModelSummary,
    ResidualSpectrumPlot, ResidualVsV, ResidualVsX, SmallSignalModel, Unexplained,
};
use crate::identify::documents::{CandidateResult, LadderStep};
use crate::identify::ForceBalanceData;

pub use crate::identify::diagnostics::FittedModel;

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
    pub spectrum: spectrum::ResidualSpectrum,
    /// Spectrum of the base model's residual.
    pub base_spectrum: spectrum::ResidualSpectrum,
    /// Order chosen for the base model and how.
    pub order_note: String,
    /// Significant candidates the ladder did not add, and why (one line each).
    pub skipped: Vec<String>,
    /// With creep in the model: the model with its tau free.
    pub creep_tau_free: Option<CreepTauFree>,
}

/// The model with creep's time constant free (`engine::run`).
#[derive(Debug, Clone, PartialEq)]
pub struct CreepTauFree {
    /// Creep's tau of the model (s).
    pub tau_s: f64,
    /// K(x), R and their block-robust standard errors with tau free (its
    /// effect parameters are not creep's: two columns share them).
    pub model: FittedModel,
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

    /// The `diagnostics` document of this result: the ranked candidates,
    /// the ladder, both models and the comparison data the plots draw. The
    /// ambiguities, the small-signal model and what stays unexplained are
    /// filled in by `diagnose::diagnose`.
    pub fn diagnostics(&self, d: &ForceBalanceData, unexplained: Unexplained) -> Diagnostics {
        Diagnostics {
            candidates: self.candidates.clone(),
            ladder: self.ladder.clone(),
            base_model: ModelSummary::new(&self.base, self.base_model_error_percent),
            final_model: ModelSummary::new(&self.model, self.model_error_percent),
            noise_floor_percent: self.noise_floor_percent,
            order_note: self.order_note.clone(),
            method: MethodNotes::default(),
            comparison: comparison(self, d),
            ambiguities: vec![],
            small_signal_model: None,
            unexplained,
            series: None,
        }
    }

    /// The small-signal model's part of the document (no plot data).
    pub fn small_signal_model(&self) -> SmallSignalModel {
        SmallSignalModel {
            candidates: self.candidates.clone(),
            ladder: self.ladder.clone(),
            base_model: self.base.clone(),
            final_model: self.model.clone(),
            noise_floor_percent: self.noise_floor_percent,
            model_error_percent: self.model_error_percent,
            base_model_error_percent: self.base_model_error_percent,
            unexplained: None,
        }
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

fn comparison(r: &EngineResult, d: &ForceBalanceData) -> Comparison {
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
    let detail = Detail {
        t_s: idx.iter().map(|&i| d.t0_s + i as f64 / fs).collect(),
        x_m: idx.iter().map(|&i| d.x_m[i]).collect(),
        measured_force_n: idx.iter().map(|&i| y[i]).collect(),
        modelled_force_n: idx.iter().map(|&i| r.modelled_force_n[i]).collect(),
        base_modelled_force_n: idx.iter().map(|&i| y[i] - r.base_residual_n[i]).collect(),
    };
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
    let vs_x = |res: &[f64]| ByDirection {
        positive_v_n: mean_by_bins(&d.x_m, res, |i| v[i] > 0.0, xlo, xhi, nb),
        negative_v_n: mean_by_bins(&d.x_m, res, |i| v[i] <= 0.0, xlo, xhi, nb),
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
    Comparison {
        detail,
        envelope: Envelope {
            t_s: env_t,
            measured_rms_n: env_m,
            residual_rms_n: env_r,
            base_residual_rms_n: env_b,
        },
        noise_rms_n,
        residual_vs_x: ResidualVsX {
            x_m: centres(xlo, xhi),
            final_model: vs_x(&r.residual_n),
            base: vs_x(&r.base_residual_n),
            positive_v_count: counts(&d.x_m, &|i| v[i] > 0.0, xlo, xhi),
            negative_v_count: counts(&d.x_m, &|i| v[i] <= 0.0, xlo, xhi),
        },
        residual_vs_v: ResidualVsV {
            v_m_per_s: centres(vlo, vhi),
            final_n: vs_v(&r.residual_n),
            base_n: vs_v(&r.base_residual_n),
            count: counts(v, &|_| true, vlo, vhi),
        },
        spectrum: ResidualSpectrumPlot {
            freq_hz: f_out,
            psd_n2_per_hz: p_out,
            base_psd_n2_per_hz: b_out
                .into_iter()
                .map(|v| v.is_finite().then_some(v))
                .collect(),
            noise_psd_n2_per_hz: n_out,
            harmonic_bands_hz: bands,
        },
        small_signal: None,
    }
}
