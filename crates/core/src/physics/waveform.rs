//! A drive waveform played at a level (issue 32, decision 0137): the
//! long-term test's stimuli other than the sine at resonance. Band-limited
//! noise is a generated loop ([`noise_loop`]); the level is the RMS of the
//! part's displacement, held closed-loop. The part's response to the loop
//! at a level, and the load it takes from it, come from the loop simulated
//! through the part's model ([`respond`]): the same model and the same load
//! measure (`E = ∫ |F_el(x) v| dt`, [`super::ageing`]) as the virtual
//! bench's sample-by-sample run. [`LoopLoad`] applies the stimulus
//! accelerated: the load's rate re-evaluated as the part ages.
//!
//! Pure: synchronous, no I/O.

use super::model::{idx, BenchParams, Integrator, Model};
use super::PartSpec;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;

/// Length of the generated noise loop (s): 0.25 Hz between its lines.
pub const NOISE_LOOP_S: f64 = 4.0;
/// The noise loop's seed: every test plays the same noise for a band.
pub const NOISE_SEED: u64 = 0x5EED_0137;
/// The peaks of Gaussian noise reach about this many times its RMS: a
/// noise's RMS level times it must stay within the displacement limit.
pub const CREST: f64 = 4.0;
/// The part settles into the loop over this much of its end played first (s).
const SETTLE_S: f64 = 2.0;
/// A level is met when the loop's RMS displacement is within this of it.
const LEVEL_TOL: f64 = 0.02;
/// The accelerated load's rate is evaluated again once the part's
/// stiffness has changed by this fraction of the new part's.
const PIECE_DRIFT: f64 = 0.005;

/// Periodic band-limited Gaussian noise of unit RMS: `len_s` at `fs`, every
/// line of the real FFT within `band_hz` (inclusive) an independent complex
/// Gaussian, nothing outside. It loops without a seam. None when the band
/// holds no line.
pub fn noise_loop(fs: f64, band_hz: [f64; 2], len_s: f64, seed: u64) -> Option<Vec<f64>> {
    let n = 2 * ((len_s * fs / 2.0).round() as usize);
    if n < 4 {
        return None;
    }
    let mut planner = RealFftPlanner::<f64>::new();
    let c2r = planner.plan_fft_inverse(n);
    let mut spec = c2r.make_input_vec();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut lines = 0;
    let last = spec.len() - 1;
    for (k, b) in spec.iter_mut().enumerate() {
        let f = k as f64 * fs / n as f64;
        if k > 0 && k < last && f >= band_hz[0] && f <= band_hz[1] {
            *b = Complex64::new(
                rng.sample::<f64, _>(StandardNormal),
                rng.sample::<f64, _>(StandardNormal),
            );
            lines += 1;
        }
    }
    if lines == 0 {
        return None;
    }
    let mut out = c2r.make_output_vec();
    c2r.process(&mut spec, &mut out).ok()?;
    let rms = (out.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    if !(rms.is_finite() && rms > 0.0) {
        return None;
    }
    out.iter_mut().for_each(|v| *v /= rms);
    Some(out)
}

/// A recorded drive (a WAV file's samples) as a loop: its mean removed (the
/// exciter holds no static pressure; a mean would only offset the part)
/// and scaled to unit RMS, so that a test's level sets the gain as for
/// [`noise_loop`]. None when nothing is left (silent, or not finite).
pub fn unit_loop(samples: &[f64]) -> Option<Vec<f64>> {
    if samples.is_empty() || samples.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = samples.len() as f64;
    let mean = samples.iter().sum::<f64>() / n;
    let rms = (samples.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    if !(rms.is_finite() && rms > 0.0) {
        return None;
    }
    Some(samples.iter().map(|v| (v - mean) / rms).collect())
}

/// The part's steady response to a loop played at a drive gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopResponse {
    /// The drive's gain: the drive is `gain_v` times the loop (V per unit).
    pub gain_v: f64,
    /// RMS and peak of the displacement over one loop (m).
    pub x_rms_m: f64,
    pub x_peak_m: f64,
    /// RMS of the velocity (m/s).
    pub v_rms_m_per_s: f64,
    /// The load's rate over the loop (W): Σ |F_el(x) v| / fs over one loop,
    /// divided by its length.
    pub load_rate_w: f64,
    /// Peak drive (V).
    pub drive_peak_v: f64,
}

/// The loop `wave` at `gain_v` through the part's model at load `load_j`
/// (its ageing loss and collapse then): the loop's last [`SETTLE_S`] played
/// first so that the part enters the measured loop as from the loop before,
/// then one loop measured. The load accrues as the virtual bench accrues it
/// (after each sample's step, `|F_el(x) v| / fs`).
pub fn respond(
    part: &PartSpec,
    bench: &BenchParams,
    load_j: f64,
    wave: &[f64],
    gain_v: f64,
) -> LoopResponse {
    let fs = bench.sample_rate_hz;
    let n = wave.len();
    let mut sim = Integrator::new(Model::new(part, bench), fs, bench.substeps);
    if let Some(a) = &part.ageing {
        sim.model.set_ageing_loss(a.lost_k_n_per_m(load_j));
        sim.model.set_ageing_collapse(a.collapse_fraction(load_j));
    }
    let settle = (SETTLE_S * fs) as usize;
    let u = |i: usize| gain_v * wave[(i + n * (settle / n + 1) - settle) % n];
    let (mut sx, mut sv, mut pk, mut e) = (0.0, 0.0, 0.0f64, 0.0);
    for i in 0..settle + n {
        sim.step(u(i), u(i + 1));
        if i >= settle {
            let (x, v) = (sim.state[idx::X], sim.state[idx::V]);
            sx += x * x;
            sv += v * v;
            pk = pk.max(x.abs());
            e += (sim.model.elastic_force(x) * v).abs() / fs;
        }
    }
    let nf = n.max(1) as f64;
    LoopResponse {
        gain_v,
        x_rms_m: (sx / nf).sqrt(),
        x_peak_m: pk,
        v_rms_m_per_s: (sv / nf).sqrt(),
        load_rate_w: e / (nf / fs),
        drive_peak_v: gain_v * wave.iter().fold(0.0f64, |m, v| m.max(v.abs())),
    }
}

/// The loop levelled for an RMS displacement `target_rms_m` at load
/// `load_j`, from the gain `gain0_v` (the last one found, or any guess):
/// the gain scaled by target/measured until within 2 %, at most eight
/// times, never beyond `max_drive_v` at the loop's peak. The answer is
/// the last response (its `x_rms_m` the level reached: below the target
/// when the drive limit held it).
pub fn level(
    part: &PartSpec,
    bench: &BenchParams,
    load_j: f64,
    wave: &[f64],
    target_rms_m: f64,
    gain0_v: f64,
    max_drive_v: f64,
) -> LoopResponse {
    let peak = wave.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
    let max_gain = max_drive_v / peak;
    let mut g = gain0_v.clamp(1e-9, max_gain);
    let mut r = respond(part, bench, load_j, wave, g);
    for _ in 0..8 {
        if r.x_rms_m <= 0.0 || (r.x_rms_m / target_rms_m - 1.0).abs() < LEVEL_TOL {
            break;
        }
        let ng = (g * (target_rms_m / r.x_rms_m).clamp(0.2, 5.0)).min(max_gain);
        if ng == g {
            break;
        }
        g = ng;
        r = respond(part, bench, load_j, wave, g);
    }
    r
}

/// The rate of the load (W) a stationary Gaussian displacement of RMS
/// `x_rms_m` with a velocity of RMS `v_rms_m_per_s` puts on the part at
/// load `load_j`: E|F_el(x) v| = E|F_el(x)| E|v| (x and v of a stationary
/// Gaussian process are independent), E|v| = √(2/π) σ_v, E|F_el(x)| by
/// quadrature over N(0, σ_x). On a linear part, (2/π) k σ_x σ_v.
pub fn gaussian_load_rate_w(part: &PartSpec, load_j: f64, x_rms_m: f64, v_rms_m_per_s: f64) -> f64 {
    if x_rms_m <= 0.0 || v_rms_m_per_s <= 0.0 {
        return 0.0;
    }
    // Simpson over ±8 σ.
    let n = 800;
    let (a, h) = (-8.0, 16.0 / n as f64);
    let mut s = 0.0;
    for i in 0..=n {
        let z = a + i as f64 * h;
        let w = if i == 0 || i == n {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let pdf = (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
        s += w * pdf * super::ageing::elastic_force_n(part, load_j, z * x_rms_m).abs();
    }
    let ef = s * h / 3.0;
    ef * (2.0 / std::f64::consts::PI).sqrt() * v_rms_m_per_s
}

/// The part's loss at a load as a fraction of the new part's stiffness at
/// rest: the collapse's fraction plus the lost stiffness over k0. The load
/// rate changes with it.
fn softening(part: &PartSpec, load_j: f64) -> f64 {
    match &part.ageing {
        None => 0.0,
        Some(a) => {
            a.collapse_fraction(load_j)
                + a.lost_k_n_per_m(load_j) / part.k_coeffs_si[0].abs().max(1e-9)
        }
    }
}

/// The load from `load_j` over which the part's softening grows by
/// [`PIECE_DRIFT`]; infinite when it never will.
fn piece_load_j(part: &PartSpec, load_j: f64) -> f64 {
    let s0 = softening(part, load_j);
    let drop = |de: f64| softening(part, load_j + de) - s0;
    let mut hi = 1e-3;
    while drop(hi) < PIECE_DRIFT {
        hi *= 2.0;
        if hi > 1e15 {
            return f64::INFINITY;
        }
    }
    let mut lo = 0.0;
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if drop(mid) < PIECE_DRIFT {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

/// A loop played at a level, applied accelerated (the virtual bench's
/// long-term test): the load grows at the rate of the loop levelled on the
/// part as it is. The rate is evaluated at the middle of a piece of load
/// over which the part softens by 0.5 % of its stiffness (the midpoint
/// rule in load) and kept while the part stays within the piece, so a
/// sound part's rate is evaluated once and an ageing part's about once per
/// 0.5 % it softens.
#[derive(Debug, Clone)]
pub struct LoopLoad {
    wave: Vec<f64>,
    /// The last gain found (the next levelling starts from it).
    gain_v: f64,
    /// The piece in use: its load from and to (J), the target RMS and the
    /// response levelled at its middle.
    piece: Option<(f64, f64, f64, LoopResponse)>,
    /// Responses evaluated (each one or more simulated loops).
    pub evaluations: usize,
}

impl LoopLoad {
    pub fn new(wave: Vec<f64>) -> LoopLoad {
        LoopLoad {
            wave,
            gain_v: 1.0,
            piece: None,
            evaluations: 0,
        }
    }

    /// The response of the piece the last [`Self::apply`] ended in.
    pub fn last(&self) -> Option<LoopResponse> {
        self.piece.map(|p| p.3)
    }

    /// The load after `duration_s` of the loop held at `target_rms_m` from
    /// `load_j` (J). The rate of a response that the drive limit held below
    /// its target is that of the level reached (what the bench would play).
    #[allow(clippy::too_many_arguments)]
    pub fn apply(
        &mut self,
        part: &PartSpec,
        bench: &BenchParams,
        max_drive_v: f64,
        load_j: f64,
        target_rms_m: f64,
        duration_s: f64,
    ) -> f64 {
        if duration_s <= 0.0 || target_rms_m <= 0.0 {
            return load_j;
        }
        let mut e = load_j;
        let mut left = duration_s;
        while left > 0.0 {
            let fresh = match self.piece {
                Some((lo, hi, t, _)) => !(e >= lo && e < hi && t == target_rms_m),
                None => true,
            };
            if fresh {
                let span = piece_load_j(part, e);
                let mid = if span.is_finite() { e + 0.5 * span } else { e };
                let r = level(
                    part,
                    bench,
                    mid,
                    &self.wave,
                    target_rms_m,
                    self.gain_v,
                    max_drive_v,
                );
                self.evaluations += 1;
                self.gain_v = r.gain_v;
                self.piece = Some((e, e + span, target_rms_m, r));
            }
            let (_, hi, _, r) = self.piece.expect("set above");
            // Within 2 % of the target: its rate scaled to the target (∝ level²).
            let rate = if (r.x_rms_m / target_rms_m - 1.0).abs() < LEVEL_TOL {
                r.load_rate_w * (target_rms_m / r.x_rms_m).powi(2)
            } else {
                r.load_rate_w
            };
            if !(rate.is_finite() && rate > 0.0) {
                break;
            }
            let to_end = (hi - e) / rate;
            if to_end >= left {
                e += rate * left;
                left = 0.0;
            } else {
                e = hi;
                left -= to_end;
            }
        }
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::ageing::aged;

    #[test]
    fn the_noise_loop_is_gaussian_in_its_band_and_loops() {
        let fs = 48000.0;
        let w = noise_loop(fs, [20.0, 200.0], NOISE_LOOP_S, NOISE_SEED).unwrap();
        assert_eq!(w.len(), 192000);
        let n = w.len() as f64;
        let mean = w.iter().sum::<f64>() / n;
        let rms = (w.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
        let kurt = w.iter().map(|v| v.powi(4)).sum::<f64>() / n;
        assert!(mean.abs() < 1e-12, "{mean}");
        assert!((rms - 1.0).abs() < 1e-12, "{rms}");
        // Gaussian: E z^4 = 3 (721 lines in the band: within 0.1).
        assert!((kurt - 3.0).abs() < 0.1, "{kurt}");
        // Nothing outside the band: the spectrum's power below 20 Hz and
        // above 200 Hz is rounding.
        let mut p = RealFftPlanner::<f64>::new();
        let r2c = p.plan_fft_forward(w.len());
        let mut buf = w.clone();
        let mut spec = r2c.make_output_vec();
        r2c.process(&mut buf, &mut spec).unwrap();
        let (mut inb, mut out) = (0.0, 0.0);
        for (k, c) in spec.iter().enumerate() {
            let f = k as f64 * fs / w.len() as f64;
            if (20.0..=200.0).contains(&f) {
                inb += c.norm_sqr();
            } else {
                out += c.norm_sqr();
            }
        }
        assert!(out / inb < 1e-20, "{out} {inb}");
        assert!(noise_loop(fs, [10.05, 10.2], NOISE_LOOP_S, 1).is_none());
    }

    fn linear() -> PartSpec {
        let mut p = crate::physics::preset("spider_3in").unwrap();
        p.k_coeffs_si = vec![1000.0];
        p.ageing = None;
        p
    }

    #[test]
    fn a_linear_part_takes_the_gaussian_load_rate() {
        // Known truth: x and v of a stationary Gaussian process are
        // independent, so E|k x v| = k E|x| E|v| = (2/π) k σ_x σ_v.
        let p = linear();
        let b = BenchParams::default();
        let w = noise_loop(b.sample_rate_hz, [20.0, 120.0], 16.0, NOISE_SEED).unwrap();
        let r = level(&p, &b, 0.0, &w, 0.001, 1.0, 100.0);
        assert!((r.x_rms_m / 0.001 - 1.0).abs() < 0.02, "{r:?}");
        let truth = 2.0 / std::f64::consts::PI * 1000.0 * r.x_rms_m * r.v_rms_m_per_s;
        let q = gaussian_load_rate_w(&p, 0.0, r.x_rms_m, r.v_rms_m_per_s);
        assert!((q / truth - 1.0).abs() < 1e-6, "{q} {truth}");
        let rel = r.load_rate_w / truth - 1.0;
        assert!(
            rel.abs() < 0.01,
            "simulated {} W, analytic {truth} W ({rel:+.4})",
            r.load_rate_w
        );
        println!(
            "linear part: simulated {} W, analytic {truth} W ({rel:+.4})",
            r.load_rate_w
        );
    }

    #[test]
    fn accelerated_loop_load_matches_finer_pieces() {
        // The midpoint in pieces of 0.5 % softening against one evaluation
        // per 0.05 %: the rate of the loop evaluated afresh in 10x smaller
        // pieces of load (the same level, the same loop).
        let p = aged();
        let b = BenchParams::default();
        let w = noise_loop(b.sample_rate_hz, [20.0, 200.0], 1.0, NOISE_SEED).unwrap();
        let mut acc = LoopLoad::new(w.clone());
        let coarse = acc.apply(&p, &b, 100.0, 0.0, 0.001, 600.0);
        // fine: explicit pieces of 0.05 % at their midpoints
        let (mut e, mut t, mut g) = (0.0f64, 0.0f64, 1.0);
        while t < 600.0 {
            let span = piece_load_j(&p, e) / 10.0;
            let r = level(&p, &b, e + 0.5 * span, &w, 0.001, g, 100.0);
            assert!((r.x_rms_m / 0.001 - 1.0).abs() < 0.02, "{r:?}");
            g = r.gain_v;
            let rate = r.load_rate_w * (0.001 / r.x_rms_m).powi(2);
            let dt = (span / rate).min(600.0 - t);
            e += rate * dt;
            t += dt;
            if e > 3000.0 {
                break;
            }
        }
        println!(
            "coarse {coarse} J ({} evaluations), fine {e} J",
            acc.evaluations
        );
        assert!((coarse / e - 1.0).abs() < 5e-3, "{coarse} {e}");
        assert!(acc.evaluations > 5, "{}", acc.evaluations);
    }
}
