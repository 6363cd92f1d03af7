//! FFT-domain band limiting, differentiation and decimation of whole records.
//!
//! A record is padded to a power of two (the pad blends the last sample back to
//! the first with a half cosine, so the periodic extension has no step), its
//! real FFT is taken once, and band-limited derivatives are read back at a
//! lower rate by an inverse FFT of only the low bins (decimation in the
//! frequency domain: no aliasing, no filter delay).

use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;
use std::cell::RefCell;

thread_local! {
    /// FFT plans of this thread: planning a 2^20 FFT (twiddles) costs about as
    /// much as running it, and `analyze` is called repeatedly on records of the
    /// same sizes (daemon, benchmark).
    static PLANNER: RefCell<RealFftPlanner<f64>> = RefCell::new(RealFftPlanner::new());
    /// Reused scratch and input buffers of the FFTs (multi-megabyte buffers
    /// allocated afresh cost page faults on every call).
    static SCRATCH: RefCell<(Vec<f64>, Vec<Complex64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
    /// Reused output of the forward FFTs whose callers keep only the low bins.
    static BINS: RefCell<Vec<Complex64>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's cached FFT planner (plans are kept between calls).
pub fn with_thread_planner<R>(f: impl FnOnce(&mut RealFftPlanner<f64>) -> R) -> R {
    PLANNER.with(|p| f(&mut p.borrow_mut()))
}

/// Sizes this thread's FFT buffers once for the largest record of a set
/// (`len` samples plus at least `min_pad`), before its first FFT: growing
/// them from the main sweep's size to the pre-measurement's copied and
/// page-faulted some 12 MB more per analysis.
pub fn reserve_for(len: usize, min_pad: usize) {
    let n_fft = (len + min_pad).max(2).next_power_of_two();
    let scratch_len = with_thread_planner(|p| p.plan_fft_forward(n_fft).get_scratch_len());
    SCRATCH.with(|sc| {
        let (buf, scratch) = &mut *sc.borrow_mut();
        if buf.capacity() < n_fft {
            *buf = Vec::with_capacity(n_fft);
        }
        if scratch.capacity() < scratch_len {
            *scratch = Vec::with_capacity(scratch_len);
        }
    });
}

/// Smooth low-pass: 1 up to `pass_hz`, raised-cosine to 0 at `stop_hz`, 0 above.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    pub pass_hz: f64,
    pub stop_hz: f64,
}

impl LowPass {
    pub fn gain(&self, f_hz: f64) -> f64 {
        if f_hz <= self.pass_hz {
            1.0
        } else if f_hz >= self.stop_hz {
            0.0
        } else {
            let u = (f_hz - self.pass_hz) / (self.stop_hz - self.pass_hz);
            0.5 * (1.0 + (std::f64::consts::PI * u).cos())
        }
    }
}

/// The real FFT of one padded record.
#[derive(Debug, Clone)]
pub struct Spectrum {
    pub sample_rate_hz: f64,
    /// Length of the original record.
    pub len: usize,
    /// FFT size (power of two, >= len).
    pub n_fft: usize,
    /// Bins 0..=n_fft/2.
    pub bins: Vec<Complex64>,
}

impl Spectrum {
    /// FFT of `signal` padded to a power of two with at least `min_pad` extra samples.
    pub fn new(signal: &[f64], sample_rate_hz: f64, min_pad: usize) -> Spectrum {
        let mut planner = RealFftPlanner::<f64>::new();
        Self::with_planner(signal, sample_rate_hz, min_pad, &mut planner)
    }

    pub fn with_planner(
        signal: &[f64],
        sample_rate_hz: f64,
        min_pad: usize,
        planner: &mut RealFftPlanner<f64>,
    ) -> Spectrum {
        let n_fft = (signal.len() + min_pad).max(2).next_power_of_two();
        let mut bins = vec![Complex64::new(0.0, 0.0); n_fft / 2 + 1];
        Self::forward(signal, n_fft, &mut bins, planner);
        Spectrum {
            sample_rate_hz,
            len: signal.len(),
            n_fft,
            bins,
        }
    }

    /// [`Spectrum::with_planner`] keeping only the bins up to `max_hz` (and
    /// two more): the same values, without holding (and page-faulting) the
    /// whole spectrum of a long record when only its low band is used.
    /// `white_noise_std` and the derivatives above `max_hz` are not
    /// available on it.
    pub fn low_band(
        signal: &[f64],
        sample_rate_hz: f64,
        min_pad: usize,
        max_hz: f64,
        planner: &mut RealFftPlanner<f64>,
    ) -> Spectrum {
        let n_fft = (signal.len() + min_pad).max(2).next_power_of_two();
        let df = sample_rate_hz / n_fft as f64;
        let keep = if max_hz.is_finite() && max_hz >= 0.0 {
            ((max_hz / df).ceil() as usize).saturating_add(3)
        } else {
            usize::MAX
        }
        .min(n_fft / 2 + 1);
        let bins = BINS.with(|b| {
            let out = &mut *b.borrow_mut();
            out.resize(n_fft / 2 + 1, Complex64::new(0.0, 0.0));
            Self::forward(signal, n_fft, out, planner);
            out[..keep].to_vec()
        });
        Spectrum {
            sample_rate_hz,
            len: signal.len(),
            n_fft,
            bins,
        }
    }

    /// The padded record's real FFT into `bins` (`n_fft / 2 + 1` long).
    fn forward(
        signal: &[f64],
        n_fft: usize,
        bins: &mut [Complex64],
        planner: &mut RealFftPlanner<f64>,
    ) {
        let len = signal.len();
        let fft = planner.plan_fft_forward(n_fft);
        SCRATCH.with(|sc| {
            let (buf, scratch) = &mut *sc.borrow_mut();
            buf.clear();
            buf.extend_from_slice(signal);
            let pad = n_fft - len;
            if pad > 0 && len > 0 {
                // Half-cosine blend from the last sample to the first (cos by
                // rotation: this pad can be 10^5 samples long).
                let (a, b) = (signal[len - 1], signal[0]);
                let (sd, cd) = (std::f64::consts::PI / (pad + 1) as f64).sin_cos();
                let (mut sn, mut cs) = (sd, cd);
                for _ in 0..pad {
                    buf.push(a + (b - a) * 0.5 * (1.0 - cs));
                    (sn, cs) = (sn * cd + cs * sd, cs * cd - sn * sd);
                }
            } else {
                buf.resize(n_fft, 0.0);
            }
            scratch.resize(fft.get_scratch_len(), Complex64::new(0.0, 0.0));
            fft.process_with_scratch(buf, bins, scratch)
                .expect("buffer sizes come from the plan");
        });
    }

    /// Frequency of bin `k` (Hz).
    pub fn freq_hz(&self, k: usize) -> f64 {
        k as f64 * self.sample_rate_hz / self.n_fft as f64
    }

    /// Bin spacing (Hz).
    pub fn df_hz(&self) -> f64 {
        self.sample_rate_hz / self.n_fft as f64
    }

    /// Largest power-of-two decimation that keeps `stop_hz` below 0.8 of the new Nyquist.
    pub fn max_decimation(&self, stop_hz: f64) -> usize {
        let mut d = 1;
        while self.n_fft % (2 * d) == 0
            && self.n_fft / (2 * d) >= 16
            && stop_hz <= 0.8 * self.sample_rate_hz / (2.0 * 2.0 * d as f64)
        {
            d *= 2;
        }
        d
    }

    /// The `order`-th time derivative (0, 1, 2, ...) of the band-limited record,
    /// sampled every `decim` samples (a power of two dividing the FFT size; the
    /// low-pass must end below the new Nyquist). Returns `ceil(len / decim)` samples.
    pub fn derivative(
        &self,
        lp: LowPass,
        order: u32,
        decim: usize,
        planner: &mut RealFftPlanner<f64>,
    ) -> Vec<f64> {
        assert!(
            decim.is_power_of_two() && self.n_fft % decim == 0 && self.n_fft / decim >= 2,
            "decimation must be a power of two dividing the FFT size"
        );
        let m = self.n_fft / decim;
        let inv = planner.plan_fft_inverse(m);
        let mut spec = inv.make_input_vec();
        let dw = 2.0 * std::f64::consts::PI * self.df_hz();
        let jpow = |w: f64| -> Complex64 {
            // (j w)^order
            let mag = w.powi(order as i32);
            match order % 4 {
                0 => Complex64::new(mag, 0.0),
                1 => Complex64::new(0.0, mag),
                2 => Complex64::new(-mag, 0.0),
                _ => Complex64::new(0.0, -mag),
            }
        };
        for (k, s) in spec.iter_mut().enumerate() {
            let g = lp.gain(self.freq_hz(k));
            *s = if g == 0.0 {
                Complex64::new(0.0, 0.0)
            } else {
                self.bins[k] * jpow(dw * k as f64) * (g / self.n_fft as f64)
            };
        }
        spec[0].im = 0.0;
        spec[m / 2] = Complex64::new(0.0, 0.0);
        let mut out = inv.make_output_vec();
        SCRATCH.with(|sc| {
            let scratch = &mut sc.borrow_mut().1;
            scratch.resize(inv.get_scratch_len(), Complex64::new(0.0, 0.0));
            inv.process_with_scratch(&mut spec, &mut out, scratch)
                .expect("buffer sizes come from the plan");
        });
        out.truncate(self.len.div_ceil(decim));
        out
    }

    /// Standard deviation of white noise estimated from the bins between
    /// `from_hz` and `to_hz` (assumed to hold noise only), as it would be at
    /// the full sample rate. None when the band holds no bins.
    pub fn white_noise_std(&self, from_hz: f64, to_hz: f64) -> Option<f64> {
        let k0 = (from_hz / self.df_hz()).ceil() as usize;
        let k1 = ((to_hz / self.df_hz()).floor() as usize).min(self.bins.len() - 1);
        if k1 <= k0 || self.len == 0 {
            return None;
        }
        // Median of |X|^2 (robust to stray tones); for complex Gaussian bins
        // the median of |X|^2 is ln 2 times the mean. E|X|^2 = len sigma^2.
        // At most ~32k bins (a stride through the band) are plenty for a median.
        let stride = ((k1 - k0 + 1) / 32_768).max(1);
        let mut p: Vec<f64> = self.bins[k0..=k1]
            .iter()
            .step_by(stride)
            .map(|c| c.norm_sqr())
            .collect();
        let mid = p.len() / 2;
        let (_, med, _) = p.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        let mean = *med / std::f64::consts::LN_2;
        Some((mean / self.len as f64).sqrt())
    }

    /// Standard deviation of the `order`-th derivative of white noise of
    /// standard deviation `sigma` after the low-pass `lp` (the noise that the
    /// band-limited derivative carries).
    pub fn filtered_noise_std(&self, sigma: f64, lp: LowPass, order: u32) -> f64 {
        // Discrete Parseval: var = sigma^2 * (2 / n_fft) * sum_k |G_k|^2 w_k^(2 order) (one-sided).
        let dw = 2.0 * std::f64::consts::PI * self.df_hz();
        let mut s = 0.0;
        for k in 0..self.bins.len() {
            let g = lp.gain(self.freq_hz(k));
            if g == 0.0 {
                break;
            }
            let w = (dw * k as f64).powi(order as i32);
            let two = if k == 0 { 1.0 } else { 2.0 };
            s += two * g * g * w * w;
        }
        sigma * (s / self.n_fft as f64).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn sine_through_the_differentiator() {
        // 37.3 Hz (not on a bin), 10 mm, 2 s at 48 kHz, decimated by 8.
        let fs = 48_000.0;
        let f = 37.3;
        let w = 2.0 * PI * f;
        let n = 96_000;
        // Fade in/out over 0.1 s so that the record starts and ends at rest.
        let env = |t: f64| {
            let tf = 0.1;
            let te = n as f64 / fs;
            if t < tf {
                0.5 * (1.0 - (PI * t / tf).cos())
            } else if t > te - tf {
                0.5 * (1.0 - (PI * (te - t) / tf).cos())
            } else {
                1.0
            }
        };
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                0.01 * env(t) * (w * t).sin()
            })
            .collect();
        let mut planner = RealFftPlanner::new();
        let s = Spectrum::with_planner(&x, fs, 0, &mut planner);
        let lp = LowPass {
            pass_hz: 800.0,
            stop_hz: 1200.0,
        };
        let d = s.max_decimation(lp.stop_hz);
        assert_eq!(d, 16, "1200 Hz is 0.8 of the Nyquist of 3 kHz");
        let x0 = s.derivative(lp, 0, d, &mut planner);
        let v = s.derivative(lp, 1, d, &mut planner);
        let a = s.derivative(lp, 2, d, &mut planner);
        assert_eq!(x0.len(), n / d);
        // Compare in the steady middle part.
        let mut err = [0.0f64; 3];
        for m in (n / d / 4)..(3 * n / d / 4) {
            let t = (m * d) as f64 / fs;
            err[0] = err[0].max((x0[m] - 0.01 * (w * t).sin()).abs() / 0.01);
            err[1] = err[1].max((v[m] - 0.01 * w * (w * t).cos()).abs() / (0.01 * w));
            err[2] = err[2].max((a[m] + 0.01 * w * w * (w * t).sin()).abs() / (0.01 * w * w));
        }
        assert!(err.iter().all(|e| *e < 1e-9), "{err:?}");
    }

    #[test]
    fn noise_estimates() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let sigma = 1e-6;
        let nd = Normal::new(0.0, sigma).unwrap();
        let fs = 48_000.0;
        let x: Vec<f64> = (0..200_000).map(|_| nd.sample(&mut rng)).collect();
        let mut planner = RealFftPlanner::new();
        let s = Spectrum::with_planner(&x, fs, 0, &mut planner);
        let est = s.white_noise_std(3000.0, 20000.0).unwrap();
        assert!((est / sigma - 1.0).abs() < 0.02, "{est}");
        // Predicted std of the band-limited second derivative vs the one measured.
        let lp = LowPass {
            pass_hz: 800.0,
            stop_hz: 1200.0,
        };
        let a = s.derivative(lp, 2, 8, &mut planner);
        let meas = (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
        let pred = s.filtered_noise_std(sigma, lp, 2);
        assert!((meas / pred - 1.0).abs() < 0.03, "{meas} vs {pred}");
    }
}
