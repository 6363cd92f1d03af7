//! FFT-domain band limiting, differentiation and decimation of whole records.
//!
//! A record is padded to a power of two (the pad blends the last sample back to
//! the first with a half cosine, so the periodic extension has no step), its
//! real FFT is taken once, and band-limited derivatives are read back at a
//! lower rate by an inverse FFT of only the low bins (decimation in the
//! frequency domain: no aliasing, no filter delay).
//!
//! The analysis's long records (2^19-2^20 points) are transformed as complex
//! FFTs of at most [`SUB_FFT`] points ([`Spectrum::bands`]): the record's
//! even and odd samples packed into one complex sequence, split by decimation
//! in time into interleaved subsequences, each a small FFT, combined only at
//! the bins the analysis reads (the low band and a sample of the noise band).
//! Planning a 2^16 FFT costs 1.6 ms where a 2^19 one cost 16.5 ms, and the
//! buffers stay at 1 MB instead of tens (decision 0026).

use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;
use rustfft::FftPlanner;
use std::cell::RefCell;

/// Complex plans of [`Spectrum::bands`], shared by all threads: the plans
/// are immutable once made, and the two spectra of a sweep are transformed
/// on two threads at once, which planned the same 2^16-point FFT twice
/// (~10 M instructions each). The same plan, so the same numbers.
static CPLANNER: std::sync::LazyLock<std::sync::Mutex<FftPlanner<f64>>> =
    std::sync::LazyLock::new(|| std::sync::Mutex::new(FftPlanner::new()));

thread_local! {
    /// FFT plans of this thread: planning a 2^20 FFT (twiddles) costs about as
    /// much as running it, and `analyze` is called repeatedly on records of the
    /// same sizes (daemon, benchmark).
    static PLANNER: RefCell<RealFftPlanner<f64>> = RefCell::new(RealFftPlanner::new());
    /// Reused scratch and input buffers of the FFTs (multi-megabyte buffers
    /// allocated afresh cost page faults on every call).
    static SCRATCH: RefCell<(Vec<f64>, Vec<Complex64>)> = const { RefCell::new((Vec::new(), Vec::new())) };
    /// The reused sub-FFT and scratch buffers of [`Spectrum::bands`].
    static CBUF: RefCell<[Vec<Complex64>; 2]> = const { RefCell::new([Vec::new(), Vec::new()]) };
}

/// Frees this thread's FFT plans and buffers (about 10 MB after a 2^20-point
/// record), which are otherwise kept for the thread's next analysis: for a
/// caller that turns to other work first (the daemon before a level series'
/// joint fit). The next transform plans again; its numbers are the same.
pub fn release_thread_buffers() {
    PLANNER.with(|p| *p.borrow_mut() = RealFftPlanner::new());
    SCRATCH.with(|s| *s.borrow_mut() = (Vec::new(), Vec::new()));
    // (the shared complex plans: the 2^16 point one and its twiddles, ~3 MB)
    *CPLANNER.lock().unwrap_or_else(|e| e.into_inner()) = FftPlanner::new();
    CBUF.with(|b| *b.borrow_mut() = [Vec::new(), Vec::new()]);
}

/// Runs `f` with this thread's cached FFT planner (plans are kept between calls).
pub fn with_thread_planner<R>(f: impl FnOnce(&mut RealFftPlanner<f64>) -> R) -> R {
    PLANNER.with(|p| f(&mut p.borrow_mut()))
}

/// FFT size of a record of `len` samples padded by at least `min_pad`.
pub fn fft_len(len: usize, min_pad: usize) -> usize {
    (len + min_pad).max(2).next_power_of_two()
}

/// The record padded to `n_fft` samples: the samples, then a half-cosine
/// blend from the last sample back to the first (cos by rotation: the pad
/// can be 10^5 samples long); zeros for an empty record.
fn padded(signal: &[f64], n_fft: usize) -> impl Iterator<Item = f64> + '_ {
    let len = signal.len();
    let pad = n_fft.saturating_sub(len);
    let (a, b) = match (signal.last(), signal.first()) {
        (Some(&a), Some(&b)) => (a, b),
        _ => (0.0, 0.0),
    };
    let (sd, cd) = (std::f64::consts::PI / (pad + 1) as f64).sin_cos();
    let mut rot = (sd, cd);
    signal.iter().copied().chain((0..pad).map(move |_| {
        let (sn, cs) = rot;
        rot = (sn * cd + cs * sd, cs * cd - sn * sd);
        a + (b - a) * 0.5 * (1.0 - cs)
    }))
}

/// Length of the complex FFTs [`Spectrum::bands`] plans (2^16: planning
/// grows from 1.6 ms at 2^16 to 7 ms at 2^17 and 16.5 ms at 2^19 on this
/// machine, twiddle memory with it).
pub const SUB_FFT: usize = 1 << 16;

/// Points of the sub-FFT inputs held at once (4 MiB): a 2^20-point record's
/// eight subsequences are transformed four at a time, so that each of the
/// two threads holds 4 MiB instead of 8 (fresh pages cost about as much to
/// zero as the analysis reads: docs/performance.md, session 20).
const SUB_GROUP: usize = 1 << 18;

/// Complex FFTs of `subs` sequences of `l` points each, in place on this
/// thread's plan and buffers, in groups of at most [`SUB_GROUP`] points from
/// the last sequence to the first: for each group `rs` (descending),
/// `fill(z, rs)` writes the inputs of sequences `rs` (sequence `r` at
/// `[(r - rs.start) * l, ...)`), then `read(acc, spectra, rs)` takes their
/// spectra, laid out the same way, and carries `acc` to the next group.
fn sub_ffts<A>(
    l: usize,
    subs: usize,
    mut fill: impl FnMut(&mut [Complex64], std::ops::Range<usize>),
    init: A,
    mut read: impl FnMut(A, &[Complex64], std::ops::Range<usize>) -> A,
) -> A {
    let fft = CPLANNER
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .plan_fft_forward(l);
    let group = (SUB_GROUP / l.max(1)).clamp(1, subs.max(1));
    CBUF.with(|b| {
        let [input, scratch] = &mut *b.borrow_mut();
        let zero = Complex64::new(0.0, 0.0);
        input.resize(l * group, zero);
        scratch.resize(fft.get_inplace_scratch_len(), zero);
        let mut acc = init;
        let mut end = subs;
        while end > 0 {
            let rs = end.saturating_sub(group)..end;
            let z = &mut input[..l * rs.len()];
            fill(z, rs.clone());
            fft.process_with_scratch(z, scratch);
            acc = read(acc, z, rs.clone());
            end = rs.start;
        }
        acc
    })
}

/// `exp(-2 pi i k / n)` at each of `ks`, as one product of two directly
/// computed values (a table of the first 1024 and the block's base, cached
/// while `ks` ascend): rounding-level, without a `sincos` per bin.
fn twiddles(n: usize, ks: &[usize]) -> Vec<Complex64> {
    const B: usize = 1024;
    let w = |k: usize| {
        let (s, c) = (-2.0 * std::f64::consts::PI * (k % n) as f64 / n as f64).sin_cos();
        Complex64::new(c, s)
    };
    let table: Vec<Complex64> = (0..B).map(w).collect();
    let mut block = (0usize, Complex64::new(1.0, 0.0));
    ks.iter()
        .map(|&k| {
            let k = k % n;
            if k < B {
                return table[k];
            }
            if block.0 != k / B {
                block = (k / B, w(k - k % B));
            }
            block.1 * table[k % B]
        })
        .collect()
}

/// Bins `ks` (each at most `n / 2`) of the real FFT of `signal` padded to
/// `n` samples (a power of two, at least 2): the even samples as the real
/// and the odd ones as the imaginary part of `z` (`m = n / 2` points), `z`
/// split into `m / l` interleaved subsequences of `l <= SUB_FFT` points, one
/// FFT each, `Z[k] = sum_r w_m^(r k) Z_r[k mod l]` summed only at the wanted
/// bins, then `X[k] = E[k] + w_n^k O[k]` with `E = (Z[k] + conj Z[m-k]) / 2`,
/// `O = (Z[k] - conj Z[m-k]) / 2i`.
fn real_fft_bins(signal: &[f64], n: usize, ks: &[usize]) -> Vec<Complex64> {
    let m = n / 2;
    let l = m.min(SUB_FFT);
    let subs = m / l;
    // Z[k] = sum_r w_m^(r k) Z_r[k mod l] at k and at m - k for every wanted
    // bin (w_m^(m-k) = conj w_m^k), by Horner's scheme over the subsequences.
    let step = twiddles(m, ks);
    let acc: Vec<Complex64> = sub_ffts(
        l,
        subs,
        |z, rs| {
            // z[c] = y[2c] + i y[2c+1] goes to subsequence c % subs, place
            // c / subs; this group holds subsequences `rs`. Where both
            // samples are the record's they are read directly; the rest (the
            // pad, whose values follow a recurrence) in order, once per group.
            // The record is read in order (its `subs` pairs of samples at
            // place q, of which this group's), not once per subsequence with
            // a stride: the same values in the same places.
            let full = signal.len() / 2;
            let inside = |r: usize| full.saturating_sub(r).div_ceil(subs).min(l);
            let g = rs.len();
            // places where every subsequence of the group has its samples
            // (and the record all `subs` pairs of the place)
            let common = inside(rs.end - 1).min(signal.len() / (2 * subs));
            for (q, pairs) in signal
                .chunks_exact(2 * subs)
                .take(common)
                .map(|c| &c[2 * rs.start..2 * rs.end])
                .enumerate()
            {
                for (j, p) in pairs.chunks_exact(2).enumerate().take(g) {
                    z[j * l + q] = Complex64::new(p[0], p[1]);
                }
            }
            for r in rs.clone() {
                let zr = &mut z[(r - rs.start) * l..][..l];
                for (q, o) in zr.iter_mut().enumerate().take(inside(r)).skip(common) {
                    let c = q * subs + r;
                    *o = Complex64::new(signal[2 * c], signal[2 * c + 1]);
                }
            }
            let mut y = padded(signal, n).skip(2 * full);
            for c in full..m {
                let re = y.next().unwrap_or(0.0);
                let im = y.next().unwrap_or(0.0);
                let r = c % subs;
                if rs.contains(&r) {
                    z[(r - rs.start) * l + c / subs] = Complex64::new(re, im);
                }
            }
        },
        Vec::with_capacity(2 * ks.len()),
        |mut acc, spectra, rs| {
            // Horner's scheme from the last subsequence to the first, across
            // the groups: the same operations in the same order as over all
            // subsequences at once.
            let first = acc.is_empty();
            for (b, (&k, &w)) in ks.iter().zip(&step).enumerate() {
                // Sub-FFT bins (l is a power of two).
                let (i, j) = ((k % m) & (l - 1), ((m - k % m) % m) & (l - 1));
                let wc = w.conj();
                let mut rows = rs.clone().rev();
                let (mut a, mut c) = if first {
                    let last = rows.next().map_or(0, |r| (r - rs.start) * l);
                    (spectra[last + i], spectra[last + j])
                } else {
                    (acc[2 * b], acc[2 * b + 1])
                };
                for r in rows {
                    let at = (r - rs.start) * l;
                    a = a * w + spectra[at + i];
                    c = c * wc + spectra[at + j];
                }
                if first {
                    acc.push(a);
                    acc.push(c);
                } else {
                    acc[2 * b] = a;
                    acc[2 * b + 1] = c;
                }
            }
            acc
        },
    );
    twiddles(n, ks)
        .into_iter()
        .zip(acc.chunks_exact(2))
        .map(|(w, z)| {
            let (zk, zc) = (z[0], z[1].conj());
            let d = zk - zc;
            (zk + zc) * 0.5 + w * Complex64::new(d.im, -d.re) * 0.5
        })
        .collect()
}

/// How many bins of an `n`-point real FFT with spacing `df_hz` hold the band
/// up to `max_hz` and three more (all of them for an infinite or negative
/// `max_hz`).
fn bins_up_to(max_hz: f64, df_hz: f64, n: usize) -> usize {
    if max_hz.is_finite() && max_hz >= 0.0 {
        ((max_hz / df_hz).ceil() as usize).saturating_add(3)
    } else {
        usize::MAX
    }
    .min(n / 2 + 1)
}

/// The bins of a noise band that [`Spectrum::white_noise_std`] takes its
/// median of: from `ceil(from / df)` to `floor(to / df)` (at most the last
/// bin), every `stride`-th so that at most ~32k are used.
fn noise_bins(
    from_hz: f64,
    to_hz: f64,
    df_hz: f64,
    last: usize,
) -> std::ops::RangeInclusive<usize> {
    let k0 = (from_hz / df_hz).ceil() as usize;
    let k1 = ((to_hz / df_hz).floor() as usize).min(last);
    k0..=k1
}

/// Every how many bins of `band` the noise median reads (at most ~32k bins).
fn noise_stride(band: &std::ops::RangeInclusive<usize>) -> usize {
    ((band.end().saturating_sub(*band.start()) + 1) / 32_768).max(1)
}

/// |X|^2 at the bins of a noise band, kept by [`Spectrum::bands`] for
/// [`Spectrum::white_noise_std`].
#[derive(Debug, Clone)]
pub struct NoiseSample {
    pub from_hz: f64,
    pub to_hz: f64,
    pub power: Vec<f64>,
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
    /// Bins 0..=n_fft/2, or only the low band of them.
    pub bins: Vec<Complex64>,
    /// |X|^2 sampled over a noise band above the low band, when only the low
    /// band is held ([`Spectrum::bands`]).
    pub noise: Option<NoiseSample>,
}

impl Spectrum {
    /// The real FFT of `signal` padded to [`fft_len`]`(len, min_pad)`, held
    /// only where it is read: the bins up to `low_hz` (and three more), and
    /// |X|^2 over `noise_band` (Hz) as [`Spectrum::white_noise_std`] samples
    /// it. Computed with complex FFTs of at most [`SUB_FFT`] points; the
    /// values equal a whole real FFT's to rounding (~1e-15 of the largest bin).
    pub fn bands(
        signal: &[f64],
        sample_rate_hz: f64,
        min_pad: usize,
        low_hz: f64,
        noise_band: Option<(f64, f64)>,
    ) -> Spectrum {
        let n = fft_len(signal.len(), min_pad);
        let df = sample_rate_hz / n as f64;
        let keep = bins_up_to(low_hz, df, n);
        let noise_ks: Vec<usize> = match noise_band {
            Some((from, to)) if !signal.is_empty() => {
                let band = noise_bins(from, to, df, n / 2);
                if band.end() > band.start() {
                    let stride = noise_stride(&band);
                    band.step_by(stride).collect()
                } else {
                    Vec::new()
                }
            }
            _ => Vec::new(),
        };
        let ks: Vec<usize> = (0..keep).chain(noise_ks.iter().copied()).collect();
        let mut bins = real_fft_bins(signal, n, &ks);
        let noise = noise_band.map(|(from_hz, to_hz)| NoiseSample {
            from_hz,
            to_hz,
            power: bins[keep..].iter().map(|c| c.norm_sqr()).collect(),
        });
        bins.truncate(keep);
        Spectrum {
            sample_rate_hz,
            len: signal.len(),
            n_fft: n,
            bins,
            noise,
        }
    }

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
        let n_fft = fft_len(signal.len(), min_pad);
        let mut bins = vec![Complex64::new(0.0, 0.0); n_fft / 2 + 1];
        Self::forward(signal, n_fft, &mut bins, planner);
        Spectrum {
            sample_rate_hz,
            len: signal.len(),
            n_fft,
            bins,
            noise: None,
        }
    }

    /// The padded record's real FFT into `bins` (`n_fft / 2 + 1` long).
    fn forward(
        signal: &[f64],
        n_fft: usize,
        bins: &mut [Complex64],
        planner: &mut RealFftPlanner<f64>,
    ) {
        let fft = planner.plan_fft_forward(n_fft);
        SCRATCH.with(|sc| {
            let (buf, scratch) = &mut *sc.borrow_mut();
            buf.clear();
            buf.extend(padded(signal, n_fft));
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
        // Median of |X|^2 (robust to stray tones); for complex Gaussian bins
        // the median of |X|^2 is ln 2 times the mean. E|X|^2 = len sigma^2.
        // At most ~32k bins (a stride through the band) are plenty for a median.
        let mut p: Vec<f64> = match &self.noise {
            Some(s) if s.from_hz == from_hz && s.to_hz == to_hz => s.power.clone(),
            _ => {
                let band = noise_bins(from_hz, to_hz, self.df_hz(), self.n_fft / 2);
                if *band.end() >= self.bins.len() {
                    // Only a low band is held.
                    return None;
                }
                let stride = noise_stride(&band);
                self.bins[band]
                    .iter()
                    .step_by(stride)
                    .map(|c| c.norm_sqr())
                    .collect()
            }
        };
        if p.len() < 2 || self.len == 0 {
            return None;
        }
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

    #[test]
    fn bands_equal_a_whole_real_fft() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let nd = Normal::new(0.0, 1.0).unwrap();
        let fs = 48_000.0;
        // One sub-FFT (2^14 points), 4 and 8 subsequences of 2^16 (2^19 and
        // 2^20 padded; with a last place of the record only partly filled).
        for len in [20_000usize, 300_005, 792_000, 792_003] {
            let x: Vec<f64> = (0..len)
                .map(|i| (i as f64 * 0.003).sin() + 1e-3 * nd.sample(&mut rng))
                .collect();
            let whole = Spectrum::new(&x, fs, 64);
            let noise = (2400.0, 22_800.0);
            let part = Spectrum::bands(&x, fs, 64, 1200.0, Some(noise));
            assert_eq!(part.n_fft, whole.n_fft);
            assert_eq!(
                part.bins.len(),
                (1200.0 / whole.df_hz()).ceil() as usize + 3
            );
            let scale = whole.bins.iter().fold(0.0f64, |m, c| m.max(c.norm()));
            let worst = part
                .bins
                .iter()
                .zip(&whole.bins)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
            assert!(worst < 1e-13 * scale, "len {len}: {worst} of {scale}");
            let (a, b) = (
                part.white_noise_std(noise.0, noise.1).unwrap(),
                whole.white_noise_std(noise.0, noise.1).unwrap(),
            );
            assert!((a / b - 1.0).abs() < 1e-12, "len {len}: noise {a} vs {b}");
            // A band it does not hold is not estimated from the wrong bins.
            assert_eq!(part.white_noise_std(3000.0, 20_000.0), None);
        }
    }
}
