//! Transfer function from a sweep (full-record H1 estimate with band coherence).

use super::Spectrum;
use realfft::num_complex::Complex64;

/// `H(f) = S_yx / S_xx` (output over input) with the magnitude-squared coherence.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferFunction {
    pub freq_hz: Vec<f64>,
    pub h: Vec<Complex64>,
    pub coherence: Vec<f64>,
    /// Input power per bin (|X|^2, arbitrary units), to judge where the input has energy.
    pub input_power: Vec<f64>,
}

/// Transfer function of a whole record (a sweep that starts and ends at rest):
/// the cross- and auto-spectra of the full-record FFTs are summed over bands of
/// `band_hz` (H1 = sum Y X* / sum |X|^2 and the coherence over the band). For a
/// deterministic sweep this has none of the bias that windowed segments
/// (Welch) give near a sharp resonance; noise and distortion lower the coherence.
/// Both spectra must have the same FFT size and rate. Bands up to `max_hz`.
pub fn transfer_function(
    input: &Spectrum,
    output: &Spectrum,
    band_hz: f64,
    max_hz: f64,
) -> TransferFunction {
    assert_eq!(input.n_fft, output.n_fft, "spectra of equal size");
    let kmax = (max_hz / input.df_hz()).ceil().max(1.0) as usize + 1;
    let nb = input.bins.len().min(output.bins.len()).min(kmax);
    let per = ((band_hz / input.df_hz()).round() as usize).max(1);
    let mut tf = TransferFunction {
        freq_hz: Vec::with_capacity(nb / per + 1),
        h: Vec::with_capacity(nb / per + 1),
        coherence: Vec::with_capacity(nb / per + 1),
        input_power: Vec::with_capacity(nb / per + 1),
    };
    let mut k = 1;
    while k + per <= nb {
        let (mut sxx, mut syy) = (0.0, 0.0);
        let mut syx = Complex64::new(0.0, 0.0);
        for i in k..k + per {
            let (x, y) = (input.bins[i], output.bins[i]);
            sxx += x.norm_sqr();
            syy += y.norm_sqr();
            syx += y * x.conj();
        }
        tf.freq_hz
            .push(input.freq_hz(k) + 0.5 * (per - 1) as f64 * input.df_hz());
        tf.h.push(if sxx > 0.0 {
            syx / sxx
        } else {
            Complex64::new(0.0, 0.0)
        });
        tf.coherence.push(if sxx * syy > 0.0 {
            syx.norm_sqr() / (sxx * syy)
        } else {
            0.0
        });
        tf.input_power.push(sxx / per as f64);
        k += per;
    }
    tf
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Exact response of m x'' + r x' + k x = f to a sampled input (bilinear-free:
    /// the ODE is integrated by RK4 with the input interpolated linearly).
    fn oscillator(f: &[f64], fs: f64, m: f64, r: f64, k: f64) -> Vec<f64> {
        let h = 1.0 / fs;
        let (mut x, mut v) = (0.0f64, 0.0f64);
        let mut out = Vec::with_capacity(f.len());
        let acc = |x: f64, v: f64, u: f64| (u - r * v - k * x) / m;
        for i in 0..f.len() {
            out.push(x);
            let u0 = f[i];
            let u1 = if i + 1 < f.len() { f[i + 1] } else { u0 };
            let um = 0.5 * (u0 + u1);
            let (k1x, k1v) = (v, acc(x, v, u0));
            let (k2x, k2v) = (
                v + 0.5 * h * k1v,
                acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v, um),
            );
            let (k3x, k3v) = (
                v + 0.5 * h * k2v,
                acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v, um),
            );
            let (k4x, k4v) = (v + h * k3v, acc(x + h * k3x, v + h * k3v, u1));
            x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
            v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
        out
    }

    #[test]
    fn second_order_system_from_a_sweep() {
        let fs = 4000.0;
        let (m, r, k) = (0.05, 1.8, 2400.0);
        let dur = 20.0;
        // The record ends with 1 s of rest so that the response has died away.
        let n = ((dur + 1.0) * fs) as usize;
        let (f1, f2) = (5.0f64, 200.0f64);
        let l = dur / (f2 / f1).ln();
        let f: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                if t < dur {
                    (2.0 * PI * f1 * l * ((t / l).exp() - 1.0)).sin()
                } else {
                    0.0
                }
            })
            .collect();
        let x = oscillator(&f, fs, m, r, k);
        let sf = Spectrum::new(&f, fs, 0);
        let sx = Spectrum::new(&x, fs, 0);
        let tf = transfer_function(&sf, &sx, 0.1, 200.0);
        let mut checked = 0;
        for (i, &fr) in tf.freq_hz.iter().enumerate() {
            if !(10.0..=150.0).contains(&fr) {
                continue;
            }
            let w = 2.0 * PI * fr;
            // The RK4 reference sees the input interpolated linearly between
            // samples: a triangle kernel, sinc^2(f / fs) in frequency.
            let sinc = (PI * fr / fs).sin() / (PI * fr / fs);
            let exact = sinc * sinc / Complex64::new(k - w * w * m, w * r);
            let rel = (tf.h[i] - exact).norm() / exact.norm();
            assert!(rel < 5e-4, "f {fr}: {rel}");
            assert!(tf.coherence[i] > 0.999, "f {fr}: {}", tf.coherence[i]);
            checked += 1;
        }
        assert!(checked > 200);
    }
}
