//! Residual spectrum and the noise floor estimated from it.
//!
//! The residual of a good model is sensor noise (broadband) plus model error,
//! which sits at the harmonics of the (swept) fundamental: narrow lines that
//! move with the sweep. Per short segment, a running low quantile over frequency
//! of the periodogram ignores the lines and follows the smooth noise
//! spectrum (for a periodogram bin of noise, the 20 % quantile is
//! -ln(0.8) = 0.223 x the mean). Summed
//! over frequency it gives the noise variance; averaged over segments, the
//! noise floor. The lines are never averaged across segments before the
//! quantile, so the sweep does not smear them into a broadband floor.

/// The running quantile taken over frequency: low, so that lines may cover
/// up to 80 % of the window without lifting the floor.
const QUANTILE: f64 = 0.2;
/// For a periodogram bin of noise (exponentially distributed), the
/// `QUANTILE` quantile is `-ln(1 - QUANTILE)` times the mean.
const QUANTILE_OF_MEAN: f64 = 0.223_143_551_314_209_7;

/// Welch spectrum of a signal and the noise floor under it.
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualSpectrum {
    /// Bin frequencies (Hz).
    pub freq_hz: Vec<f64>,
    /// Power spectral density of the residual (unit^2 / Hz), averaged over segments.
    pub psd: Vec<f64>,
    /// Estimated noise part of the PSD (unit^2 / Hz).
    pub noise_psd: Vec<f64>,
    /// Variance of the noise part (unit^2).
    pub noise_variance: f64,
}

/// Running lower quantile (fraction `QUANTILE`) over +-`half` bins: the
/// element of rank `floor(QUANTILE * len)` of each window (total order).
/// The window is kept sorted as it slides (one insertion and one removal
/// per bin) instead of selected afresh per bin.
fn running_quantile(p: &[f64], half: usize) -> Vec<f64> {
    let n = p.len();
    let mut out = vec![0.0; n];
    let mut win: Vec<f64> = Vec::with_capacity(2 * half + 2);
    let rank_of = |win: &[f64], v: f64| win.partition_point(|w| w.total_cmp(&v).is_lt());
    let (mut s, mut e) = (0, 0);
    for (i, o) in out.iter_mut().enumerate() {
        let (ns, ne) = (i.saturating_sub(half), (i + half + 1).min(n));
        while e < ne {
            let at = rank_of(&win, p[e]);
            win.insert(at, p[e]);
            e += 1;
        }
        while s < ns {
            let at = rank_of(&win, p[s]);
            win.remove(at);
            s += 1;
        }
        let m = ((win.len() as f64 * QUANTILE) as usize).min(win.len() - 1);
        *o = win[m];
    }
    out
}

/// Spectrum of `e` sampled at `fs_hz` with segments of about `segment_s`.
pub fn residual_spectrum(e: &[f64], fs_hz: f64, segment_s: f64) -> ResidualSpectrum {
    let n = e.len();
    let mut len = 256usize;
    while (len * 2) as f64 <= segment_s * fs_hz && len * 2 <= n {
        len *= 2;
    }
    if n < len {
        let var = e.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64;
        return ResidualSpectrum {
            freq_hz: vec![],
            psd: vec![],
            noise_psd: vec![],
            noise_variance: var,
        };
    }
    let window: Vec<f64> = (0..len)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / len as f64).cos())
        .collect();
    let w2: f64 = window.iter().map(|w| w * w).sum();
    let fft = crate::dsp::spectrum::with_thread_planner(|p| p.plan_fft_forward(len));
    let mut input = fft.make_input_vec();
    let mut output = fft.make_output_vec();
    let nb = len / 2 + 1;
    let mut psd = vec![0.0; nb];
    let mut noise = vec![0.0; nb];
    let hop = len / 2;
    let mut segments = 0usize;
    let mut start = 0;
    // Scale so that sum(psd) * df = variance (one-sided).
    let scale = 1.0 / (w2 * fs_hz);
    let half = (nb / 64).clamp(8, 40);
    let mut p = vec![0.0; nb];
    while start + len <= n {
        for i in 0..len {
            input[i] = e[start + i] * window[i];
        }
        if fft.process(&mut input, &mut output).is_err() {
            break;
        }
        for k in 0..nb {
            let one_sided = if k == 0 || k == nb - 1 { 1.0 } else { 2.0 };
            p[k] = output[k].norm_sqr() * scale * one_sided;
        }
        let med = running_quantile(&p, half);
        for k in 0..nb {
            psd[k] += p[k];
            noise[k] += med[k] / QUANTILE_OF_MEAN;
        }
        segments += 1;
        start += hop;
    }
    let df = fs_hz / len as f64;
    for k in 0..nb {
        psd[k] /= segments as f64;
        noise[k] = (noise[k] / segments as f64).min(psd[k]);
    }
    let noise_variance = noise.iter().sum::<f64>() * df;
    ResidualSpectrum {
        freq_hz: (0..nb).map(|k| k as f64 * df).collect(),
        psd,
        noise_psd: noise,
        noise_variance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn running_quantile_is_the_selected_rank_of_each_window() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let g = Normal::new(0.0f64, 1.0).unwrap();
        for (n, half) in [(1usize, 8usize), (5, 8), (40, 8), (513, 8), (300, 40)] {
            // Squares (as a periodogram) with repeated values.
            let p: Vec<f64> = (0..n)
                .map(|i| {
                    if i % 7 == 3 {
                        0.25
                    } else {
                        g.sample(&mut rng).powi(2_i32)
                    }
                })
                .collect();
            let got = running_quantile(&p, half);
            for i in 0..n {
                let mut w = p[i.saturating_sub(half)..(i + half + 1).min(n)].to_vec();
                let m = ((w.len() as f64 * QUANTILE) as usize).min(w.len() - 1);
                w.select_nth_unstable_by(m, |a, b| a.total_cmp(b));
                assert_eq!(got[i].to_bits(), w[m].to_bits(), "n {n} bin {i}");
            }
        }
    }

    #[test]
    fn noise_floor_of_noise_plus_swept_harmonics() {
        let fs = 8000.0;
        let n = 32000;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let g = Normal::new(0.0, 0.1).unwrap();
        // A swept fundamental 30-60 Hz with 5 harmonics, each of amplitude 1,
        // plus white noise of standard deviation 0.1 (variance 0.01).
        let dur = n as f64 / fs;
        let l = dur / 2f64.ln();
        let e: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                let ph = 2.0 * std::f64::consts::PI * 30.0 * l * ((t / l).exp() - 1.0);
                (1..=5).map(|h| (h as f64 * ph).sin()).sum::<f64>() + g.sample(&mut rng)
            })
            .collect();
        let s = residual_spectrum(&e, fs, 0.5);
        // The lines carry 2.5 units of variance, 250 x the noise: the floor still comes out within 15 %.
        let ratio = s.noise_variance / 0.01;
        assert!((ratio - 1.0).abs() < 0.15, "noise variance ratio {ratio}");
        let total: f64 = s.psd.iter().sum::<f64>() * s.freq_hz[1];
        assert!((total - 2.51).abs() < 0.1, "{total}");
    }
}
