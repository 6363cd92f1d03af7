//! The experiments that tell the material's memory apart (issue 33,
//! decisions 0117, 0118): the recovery measurement (a large excitation, then
//! short small-signal probes at 0.5-30 s: the depth and time constant of the
//! reversible softening), and the added-mass study (the same part with two
//! clamping masses at two levels: the frequency-dependent share against the
//! amplitude-dependent one). Pure: the drive is made here, the recording
//! comes back as plain signals.
//!
//! The probes are analysed by the force balance at two tones per probe
//! (lock-in over whole periods): `s M_k = (K_i - m w_k^2 + j w_k R) X_k`,
//! with the force scale `s` and `R` shared by all probes and one K_i per
//! probe, one linear least-squares problem. The K_i against the probe
//! times give `K(t) = K_inf - depth exp(-t / tau)` (tau by a golden search,
//! K_inf and depth linear).

use crate::recording::Signals;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The recovery measurement's plan (SI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RecoveryPlan {
    /// The large excitation: a sine at this frequency (near the resonance).
    pub excitation_hz: f64,
    /// Its amplitude (V of drive).
    pub excitation_v: f64,
    /// Its duration (s), half-cosine fades of 0.1 s included.
    pub excitation_s: f64,
    /// Amplitude of each of the two probe tones (V of drive): small signal.
    pub probe_v: f64,
    /// Probe centres after the end of the excitation (s).
    pub delays_s: Vec<f64>,
}

/// The excitation's half-cosine fades (s).
pub const EXCITATION_FADE_S: f64 = 0.1;
/// Length of the analysed part of a probe (s): the tones are whole multiples of 1/it.
pub const PROBE_ANALYSIS_S: f64 = 0.2;
/// Lead-in of a probe before its analysed part (s): the part's transient settles.
pub const PROBE_LEAD_S: f64 = 0.2;

impl RecoveryPlan {
    /// The paper's plan: probes at 0.5, 1, 2, 5, 10 and 30 s.
    pub fn standard(excitation_hz: f64, excitation_v: f64, probe_v: f64) -> RecoveryPlan {
        RecoveryPlan {
            excitation_hz,
            excitation_v,
            excitation_s: 2.0,
            probe_v,
            delays_s: vec![0.5, 1.0, 2.0, 5.0, 10.0, 30.0],
        }
    }

    /// One-line error naming the first bad field.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |n: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("recovery.{n} must be a positive number, got {v}"))
            }
        };
        pos("excitation_hz", self.excitation_hz)?;
        pos("excitation_v", self.excitation_v)?;
        pos("probe_v", self.probe_v)?;
        if !(self.excitation_s.is_finite() && (0.5..=60.0).contains(&self.excitation_s)) {
            return Err(format!(
                "recovery.excitation_s must be 0.5..=60 s, got {}",
                self.excitation_s
            ));
        }
        if self.delays_s.len() < 3 || self.delays_s.len() > 20 {
            return Err(format!(
                "recovery.delays_s must hold 3..=20 delays, got {}",
                self.delays_s.len()
            ));
        }
        let (before, after) = (
            PROBE_LEAD_S + 0.5 * PROBE_ANALYSIS_S,
            0.5 * PROBE_ANALYSIS_S,
        );
        let mut prev_end = 0.1;
        for (i, &d) in self.delays_s.iter().enumerate() {
            if !(d.is_finite() && d <= 600.0) || d - before < prev_end - 1e-9 {
                return Err(format!(
                    "recovery.delays_s[{i}] = {d}: delays must rise, at most 600 s, each probe ({:.2} s, {before:.2} s before its delay) after the previous one ends and at least 0.1 s after the excitation",
                    before + after
                ));
            }
            prev_end = d + after;
        }
        Ok(())
    }

    /// The two probe tones (Hz) for a part resonating near `f_res_hz`:
    /// about 0.5 and 0.8 of it, whole multiples of 1 / [`PROBE_ANALYSIS_S`].
    pub fn probe_tones(&self) -> [f64; 2] {
        let step = 1.0 / PROBE_ANALYSIS_S;
        let at = |r: f64| ((r * self.excitation_hz / step).round().max(1.0)) * step;
        let (a, mut b) = (at(0.5), at(0.8));
        if b <= a {
            b = a + step;
        }
        [a, b]
    }

    /// The drive (V) at `fs` and the probes' analysed windows (start sample, end sample, centre time after the excitation in s).
    pub fn drive(&self, fs: f64) -> (Vec<f64>, Vec<(usize, usize, f64)>) {
        let ne = (self.excitation_s * fs).round() as usize;
        let last = self.delays_s.last().copied().unwrap_or(0.0);
        let total = ne + ((last + PROBE_ANALYSIS_S + 0.2) * fs).round() as usize;
        let mut u = vec![0.0; total];
        let fade = |t: f64, len: f64, f: f64| {
            if t < f {
                0.5 - 0.5 * (PI * t / f).cos()
            } else if t > len - f {
                0.5 - 0.5 * (PI * (len - t) / f).cos()
            } else {
                1.0
            }
        };
        for (i, v) in u.iter_mut().enumerate().take(ne) {
            let t = i as f64 / fs;
            *v = self.excitation_v
                * fade(t, self.excitation_s, EXCITATION_FADE_S)
                * (2.0 * PI * self.excitation_hz * t).sin();
        }
        let tones = self.probe_tones();
        let len = PROBE_LEAD_S + PROBE_ANALYSIS_S;
        let mut windows = Vec::new();
        for &d in &self.delays_s {
            let start = ne + ((d - PROBE_LEAD_S - 0.5 * PROBE_ANALYSIS_S) * fs).round() as usize;
            let n = (len * fs).round() as usize;
            for k in 0..n {
                let t = k as f64 / fs;
                let w = fade(t, len + 0.02, 0.04);
                u[start + k] =
                    self.probe_v * w * tones.iter().map(|f| (2.0 * PI * f * t).sin()).sum::<f64>();
            }
            let a0 = start + (PROBE_LEAD_S * fs).round() as usize;
            let a1 = a0 + (PROBE_ANALYSIS_S * fs).round() as usize;
            windows.push((a0, a1.min(start + n), d));
        }
        (u, windows)
    }
}

/// One probe's small-signal stiffness.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RecoveryPoint {
    /// Time of the probe's centre after the end of the excitation (s).
    pub t_s: f64,
    pub k_n_per_m: f64,
    /// Peak excursion during the probe (m).
    pub x_peak_m: f64,
}

/// What the recovery measurement found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RecoveryResult {
    pub points: Vec<RecoveryPoint>,
    /// Small-signal K(0) once recovered (N/m).
    pub k_recovered_n_per_m: f64,
    /// Drop of K(0) when the last full-size excursion ends (the start of the
    /// excitation's fade-out) (N/m), > 0 for a softening.
    pub depth_n_per_m: f64,
    /// The drop per metre of the excitation's peak excursion (N/m^2): the
    /// `reversible_softening` effect's `depth_n_per_m2`.
    pub depth_n_per_m2: f64,
    /// Time constant of the recovery (s).
    pub tau_s: f64,
    /// Standard errors of `depth_n_per_m`, `depth_n_per_m2` and `tau_s` (same
    /// units), from the recovery law's three-parameter fit to the points (its
    /// residual with n - 3 degrees of freedom, linearised at the fit); absent
    /// in results stored before they were computed, and when the points
    /// cannot give them (fewer than four, or a law without curvature).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_se_n_per_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_se_n_per_m2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tau_se_s: Option<f64>,
    /// Peak excursion of the excitation (m).
    pub excitation_peak_m: f64,
    /// RMS misfit of the recovery law to the points (N/m).
    pub misfit_n_per_m: f64,
    /// The drop is larger than five times the misfit and 0.5 % of K: the part softens
    /// reversibly (else depth and tau mean nothing).
    pub softening_found: bool,
    /// Shared force scale (N/V) and damping (N s/m) of the probes.
    pub force_per_mic_n_per_v: f64,
    pub r_ns_per_m: f64,
}

/// Complex amplitude of `sig` at `f_hz` (lock-in with a Hann window, which
/// keeps the probe's own settling resonance out of the tones).
fn phasor(sig: &[f64], fs: f64, f_hz: f64) -> (f64, f64) {
    let n = sig.len() as f64;
    let (mut re, mut im, mut wsum) = (0.0, 0.0, 0.0);
    for (i, &s) in sig.iter().enumerate() {
        let w = 0.5 - 0.5 * (2.0 * PI * (i as f64 + 0.5) / n).cos();
        let ph = 2.0 * PI * f_hz * i as f64 / fs;
        re += w * s * ph.cos();
        im -= w * s * ph.sin();
        wsum += w;
    }
    (2.0 * re / wsum, 2.0 * im / wsum)
}

/// `K(t) = k_inf - depth exp(-t/tau)` at a fixed tau: (k_inf, depth, sse).
fn exp_fit(pts: &[(f64, f64)], tau: f64) -> (f64, f64, f64) {
    let n = pts.len() as f64;
    let e: Vec<f64> = pts.iter().map(|(t, _)| (-t / tau).exp()).collect();
    let (se, see) = (e.iter().sum::<f64>(), e.iter().map(|v| v * v).sum::<f64>());
    let sk: f64 = pts.iter().map(|p| p.1).sum();
    let sek: f64 = pts.iter().zip(&e).map(|(p, e)| p.1 * e).sum();
    let det = n * see - se * se;
    if det.abs() < 1e-300 {
        let k = sk / n;
        return (k, 0.0, pts.iter().map(|p| (p.1 - k).powi(2)).sum());
    }
    // k = a + b e, a = k_inf, b = -depth
    let a = (see * sk - se * sek) / det;
    let b = (n * sek - se * sk) / det;
    let sse = pts
        .iter()
        .zip(&e)
        .map(|(p, e)| (p.1 - a - b * e).powi(2))
        .sum();
    (a, -b, sse)
}

/// Standard errors of (depth, tau) of `K(t) = k_inf - depth exp(-t/tau)`
/// fitted to `pts` with residual sum of squares `sse`: sqrt of the diagonal
/// of s^2 (J^T J)^-1, s^2 = sse / (n - 3), J the law's Jacobian in
/// (k_inf, depth, tau) at the fit. None when n <= 3 or J^T J is singular.
fn exp_fit_se(pts: &[(f64, f64)], depth: f64, tau: f64, sse: f64) -> Option<(f64, f64)> {
    let n = pts.len();
    if n <= 3 || !tau.is_finite() || tau <= 0.0 {
        return None;
    }
    let mut jtj = nalgebra::Matrix3::<f64>::zeros();
    for &(t, _) in pts {
        let e = (-t / tau).exp();
        let j = nalgebra::Vector3::new(1.0, -e, -depth * e * t / (tau * tau));
        jtj += j * j.transpose();
    }
    let cov = jtj.try_inverse()? * (sse / (n - 3) as f64);
    let (vd, vt) = (cov[(1, 1)], cov[(2, 2)]);
    (vd.is_finite() && vt.is_finite() && vd >= 0.0 && vt >= 0.0).then(|| (vd.sqrt(), vt.sqrt()))
}

/// Minimum of `f` on [lo, hi] by golden-section search.
fn golden(mut lo: f64, mut hi: f64, iters: usize, f: impl Fn(f64) -> f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..iters {
        let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if f(a) < f(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    0.5 * (lo + hi)
}

/// The recovery law fitted to `pts`: tau searched from 0.05 s to `tau_max_s`
/// (a log grid, then golden section), k_inf and depth linear at each tau.
/// Returns (k_inf, depth, tau, sse).
fn recovery_law(pts: &[(f64, f64)], tau_max_s: f64) -> (f64, f64, f64, f64) {
    let (lo, hi) = (0.05f64.ln(), tau_max_s.ln());
    let grid: Vec<f64> = (0..40).map(|i| lo + (hi - lo) * i as f64 / 39.0).collect();
    let sse = |l: f64| exp_fit(pts, l.exp()).2;
    let ib = (0..grid.len())
        .min_by(|&i, &j| sse(grid[i]).total_cmp(&sse(grid[j])))
        .unwrap_or(0);
    let (a0, b0) = (
        grid[ib.saturating_sub(1)],
        grid[(ib + 1).min(grid.len() - 1)],
    );
    let tau = golden(a0, b0, 60, sse).exp();
    let (k_inf, depth, sse_v) = exp_fit(pts, tau);
    (k_inf, depth, tau, sse_v)
}

/// Analyses the recording of [`RecoveryPlan::drive`] (same sample rate).
pub fn analyze_recovery(
    plan: &RecoveryPlan,
    s: &Signals,
    mass_kg: f64,
) -> Result<RecoveryResult, String> {
    plan.validate()?;
    let fs = s.sample_rate_hz;
    let (_, windows) = plan.drive(fs);
    let need = windows.last().map_or(0, |w| w.1);
    if s.displacement_m.len() < need || s.microphone_v.len() < need {
        return Err(format!(
            "recovery recording too short: {} samples, the plan needs {need}",
            s.len()
        ));
    }
    if !(mass_kg.is_finite() && mass_kg > 0.0) {
        return Err(format!("moving mass must be positive, got {mass_kg}"));
    }
    let tones = plan.probe_tones();
    let np = windows.len();
    // Unknowns: K_1..K_np, R, s. Rows: re and im per probe and tone.
    let rows = 4 * np;
    let mut a = DMatrix::<f64>::zeros(rows, np + 2);
    let mut y = DVector::<f64>::zeros(rows);
    let mut peaks = Vec::with_capacity(np);
    for (i, &(w0, w1, _)) in windows.iter().enumerate() {
        let x = &s.displacement_m[w0..w1];
        let m = &s.microphone_v[w0..w1];
        peaks.push(x.iter().fold(0.0f64, |p, v| p.max(v.abs())));
        for (k, &f) in tones.iter().enumerate() {
            let w = 2.0 * PI * f;
            let (xr, xi) = phasor(x, fs, f);
            let (mr, mi) = phasor(m, fs, f);
            // K X + j w R X - s M = m w^2 X
            let r = 4 * i + 2 * k;
            a[(r, i)] = xr;
            a[(r + 1, i)] = xi;
            a[(r, np)] = -w * xi;
            a[(r + 1, np)] = w * xr;
            a[(r, np + 1)] = -mr;
            a[(r + 1, np + 1)] = -mi;
            y[r] = mass_kg * w * w * xr;
            y[r + 1] = mass_kg * w * w * xi;
        }
    }
    // Column scaling for the conditioning.
    let scale: Vec<f64> = (0..np + 2)
        .map(|j| {
            let n = a.column(j).norm();
            if n > 0.0 {
                1.0 / n
            } else {
                1.0
            }
        })
        .collect();
    for (j, sc) in scale.iter().enumerate() {
        a.column_mut(j).scale_mut(*sc);
    }
    let sol = a
        .clone()
        .svd(true, true)
        .solve(&y, 1e-12)
        .map_err(|e| format!("recovery fit failed: {e}"))?;
    let theta: Vec<f64> = sol.iter().zip(&scale).map(|(v, s)| v * s).collect();
    if theta.iter().any(|v| !v.is_finite()) {
        return Err("recovery fit gave no finite stiffness (is the part moving?)".into());
    }
    let points: Vec<RecoveryPoint> = windows
        .iter()
        .zip(&theta)
        .zip(&peaks)
        .map(|((w, &k), &p)| RecoveryPoint {
            t_s: w.2,
            k_n_per_m: k,
            x_peak_m: p,
        })
        .collect();
    // Time from the last full-size excursion (the start of the fade-out).
    let pts: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p.t_s + EXCITATION_FADE_S, p.k_n_per_m))
        .collect();
    let (k_inf, depth, tau, sse_v) =
        recovery_law(&pts, 10.0 * plan.delays_s.last().unwrap_or(&1.0));
    let misfit = (sse_v / pts.len() as f64).sqrt();
    let se = exp_fit_se(&pts, depth, tau, sse_v);
    // Peak excursion of the excitation's last second.
    let ne = (plan.excitation_s * fs).round() as usize;
    let from = ne.saturating_sub(fs as usize).min(s.len());
    let exc_peak = s.displacement_m[from..ne.min(s.len())]
        .iter()
        .fold(0.0f64, |p, v| p.max(v.abs()));
    Ok(RecoveryResult {
        k_recovered_n_per_m: k_inf,
        depth_n_per_m: depth,
        depth_n_per_m2: if exc_peak > 0.0 {
            depth / exc_peak
        } else {
            f64::NAN
        },
        tau_s: tau,
        depth_se_n_per_m: se.map(|s| s.0),
        depth_se_n_per_m2: se.filter(|_| exc_peak > 0.0).map(|s| s.0 / exc_peak),
        tau_se_s: se.map(|s| s.1),
        excitation_peak_m: exc_peak,
        misfit_n_per_m: misfit,
        softening_found: depth > 5.0 * misfit && depth > 5e-3 * k_inf.abs(),
        force_per_mic_n_per_v: theta[np + 1],
        r_ns_per_m: theta[np],
        points,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_checks_and_the_exponential_law_comes_back() {
        let p = RecoveryPlan::standard(30.0, 5.0, 0.2);
        p.validate().unwrap();
        let mut bad = p.clone();
        bad.delays_s = vec![0.5, 0.6, 2.0];
        assert!(bad.validate().unwrap_err().contains("delays_s[1]"));
        let pts: Vec<(f64, f64)> = p
            .delays_s
            .iter()
            .map(|&t| (t, 2400.0 - 300.0 * (-t / 3.0).exp()))
            .collect();
        let (k, d, sse) = exp_fit(&pts, 3.0);
        assert!((k - 2400.0).abs() < 1e-9 && (d - 300.0).abs() < 1e-9 && sse < 1e-12);
        let tones = p.probe_tones();
        assert_eq!(tones, [15.0, 25.0]);
    }

    /// The stated standard errors of depth and tau are the spread of the fit
    /// over noise: 2000 draws of the standard plan's six probes from a known
    /// law (2400 N/m recovered, 300 N/m deep, tau 2 s) with 3 N/m of Gaussian
    /// noise on each K; the fit's spread and the mean stated SE agree within
    /// 10 % (the draws' own sampling error of a standard deviation is ~1.6 %).
    #[test]
    fn the_recovery_laws_standard_errors_are_its_spread_over_noise() {
        use rand::{Rng, SeedableRng};
        let p = RecoveryPlan::standard(30.0, 5.0, 0.2);
        let (n, sd) = (2000, 3.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(33);
        let (mut depths, mut taus, mut se_d, mut se_t) = (vec![], vec![], 0.0, 0.0);
        for _ in 0..n {
            let pts: Vec<(f64, f64)> = p
                .delays_s
                .iter()
                .map(|&t| {
                    let z: f64 = rng.sample(rand_distr::StandardNormal);
                    (t, 2400.0 - 300.0 * (-t / 2.0).exp() + sd * z)
                })
                .collect();
            let (_, depth, tau, sse) = recovery_law(&pts, 300.0);
            let (sd_, st_) = exp_fit_se(&pts, depth, tau, sse).unwrap();
            depths.push(depth);
            taus.push(tau);
            se_d += sd_ / n as f64;
            se_t += st_ / n as f64;
        }
        let spread = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
        };
        let (sp_d, sp_t) = (spread(&depths), spread(&taus));
        eprintln!("depth: spread {sp_d:.3} N/m, stated {se_d:.3}; tau: spread {sp_t:.4} s, stated {se_t:.4}");
        assert!(
            (se_d / sp_d - 1.0).abs() < 0.10,
            "depth {se_d} against {sp_d}"
        );
        assert!(
            (se_t / sp_t - 1.0).abs() < 0.10,
            "tau {se_t} against {sp_t}"
        );
        // Exact points: no misfit, no error.
        let exact: Vec<(f64, f64)> = p
            .delays_s
            .iter()
            .map(|&t| (t, 2400.0 - 300.0 * (-t / 2.0).exp()))
            .collect();
        let (_, d, t, sse) = recovery_law(&exact, 300.0);
        assert!(
            (d - 300.0).abs() < 1e-3 && (t - 2.0).abs() < 1e-5,
            "{d} {t}"
        );
        let (a, b) = exp_fit_se(&exact, d, t, sse).unwrap();
        assert!(a < 1e-3 && b < 1e-5, "{a} {b}");
        assert_eq!(exp_fit_se(&exact[..3], d, t, sse), None);
    }
}
