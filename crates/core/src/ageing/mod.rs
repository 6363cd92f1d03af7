//! The ageing law of a suspension part (issue 32, decisions 0110, 0111):
//! K(0) against the accumulated load, fitted from intermittent measurements
//! of a long-term test, with a fast break-in and a slow fatigue term:
//!
//! `K(0, c) = K_∞ + A_b exp(-c/τ_b) + A_f exp(-c/τ_f)`, `τ_b < τ_f`,
//!
//! `c` the load coordinate: the accumulated load (J, `physics::ageing`) when
//! every interval knows it, else the elapsed time under a constant stimulus
//! (s; the load grows in proportion to it). The fit is a variable
//! projection: for each pair (τ_b, τ_f) of a logarithmic grid the three
//! amplitudes are a linear least-squares problem; the best pair starts a
//! Levenberg-Marquardt refinement of all five parameters; the standard
//! errors are `s² (JᵀJ)⁻¹` with `s²` the residual variance (decision 0111
//! says why this is written here rather than taken from a crate).
//!
//! Pure: plain data in, plain data out.

pub mod series;

use crate::identify::validity::{HeadlineValidity, State};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// A value with its standard error (same unit as the field's name says).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Estimate {
    pub value: f64,
    pub se: f64,
}

/// The fitted law in the units of its load coordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct LawFit {
    /// [K_∞, A_b, τ_b, A_f, τ_f].
    pub theta: [f64; 5],
    /// Covariance of `theta`.
    pub cov: [[f64; 5]; 5],
    /// Residual standard deviation (the unit of the fitted values).
    pub residual_sd: f64,
    pub n: usize,
    /// Largest load coordinate of the data.
    pub c_max: f64,
    /// Whether the data support the law (reasons `; `-joined).
    pub validity: HeadlineValidity,
}

fn model(t: &[f64; 5], c: f64) -> f64 {
    t[0] + t[1] * (-c / t[2]).exp() + t[3] * (-c / t[4]).exp()
}

/// ∂model/∂theta at c.
fn gradient(t: &[f64; 5], c: f64) -> [f64; 5] {
    let eb = (-c / t[2]).exp();
    let ef = (-c / t[4]).exp();
    [
        1.0,
        eb,
        t[1] * eb * c / (t[2] * t[2]),
        ef,
        t[3] * ef * c / (t[4] * t[4]),
    ]
}

/// Amplitudes [K_∞, A, B] of `y ≈ K + A e^{-c/τb} + B e^{-c/τf}` and the RSS.
fn project(c: &[f64], y: &[f64], tb: f64, tf: f64) -> Option<([f64; 3], f64)> {
    let mut ata = Matrix3::<f64>::zeros();
    let mut aty = Vector3::<f64>::zeros();
    for (&ci, &yi) in c.iter().zip(y) {
        let r = Vector3::new(1.0, (-ci / tb).exp(), (-ci / tf).exp());
        ata += r * r.transpose();
        aty += r * yi;
    }
    let sol = ata.cholesky()?.solve(&aty);
    let a = [sol[0], sol[1], sol[2]];
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let t = [a[0], a[1], tb, a[2], tf];
    let rss = c
        .iter()
        .zip(y)
        .map(|(&ci, &yi)| (yi - model(&t, ci)).powi(2))
        .sum();
    Some((a, rss))
}

/// Fewest intervals a fit of the five parameters takes (and a residual).
pub const MIN_POINTS: usize = 7;

/// Fits the law to (load coordinate, value) pairs; `None` when there are
/// fewer than [`MIN_POINTS`], a coordinate or value is not finite, or no
/// fit converged. The returned fit's `validity` says whether the data
/// support it.
pub fn fit_law(c: &[f64], y: &[f64]) -> Result<LawFit, String> {
    let n = c.len();
    if n != y.len() {
        return Err("load coordinates and values differ in number".into());
    }
    if n < MIN_POINTS {
        return Err(format!(
            "{n} intervals: the law's five parameters need at least {MIN_POINTS}"
        ));
    }
    if c.iter().chain(y).any(|v| !v.is_finite()) {
        return Err("a load or value is not a finite number".into());
    }
    let c_max = c.iter().cloned().fold(0.0f64, f64::max);
    let mut sorted: Vec<f64> = c.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let step = sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !(c_max > 0.0 && step.is_finite()) {
        return Err("the loads do not grow: no law to fit".into());
    }
    // Grid of (τ_b, τ_f), log-spaced from a fifth of the finest spacing to
    // 20 times the largest load.
    let lo = (step / 5.0).ln();
    let hi = (20.0 * c_max).ln();
    let g = 48;
    let tau = |i: usize| (lo + (hi - lo) * i as f64 / (g - 1) as f64).exp();
    let mut best: Option<([f64; 5], f64)> = None;
    for i in 0..g {
        for j in (i + 2)..g {
            let (tb, tf) = (tau(i), tau(j));
            if let Some((a, rss)) = project(c, y, tb, tf) {
                if best.as_ref().is_none_or(|(_, r)| rss < *r) {
                    best = Some(([a[0], a[1], tb, a[2], tf], rss));
                }
            }
        }
    }
    let (mut t, mut rss) = best.ok_or("no pair of load scales gave a fit")?;
    // Levenberg-Marquardt on all five; the scales in logarithms keep them positive.
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let mut j = DMatrix::<f64>::zeros(n, 5);
        let mut r = DVector::<f64>::zeros(n);
        for (k, (&ci, &yi)) in c.iter().zip(y).enumerate() {
            let gr = gradient(&t, ci);
            for (m, gv) in gr.iter().enumerate() {
                // d/d ln τ = τ d/dτ
                let s = if m == 2 || m == 4 { t[m] } else { 1.0 };
                j[(k, m)] = gv * s;
            }
            r[k] = yi - model(&t, ci);
        }
        let jtj = j.transpose() * &j;
        let jtr = j.transpose() * &r;
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj.clone();
            for d in 0..5 {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-300);
            }
            let Some(ch) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let dx = ch.solve(&jtr);
            let mut nt = t;
            for m in 0..5 {
                if m == 2 || m == 4 {
                    nt[m] = t[m] * dx[m].clamp(-5.0, 5.0).exp();
                } else {
                    nt[m] = t[m] + dx[m];
                }
            }
            let nrss: f64 = c
                .iter()
                .zip(y)
                .map(|(&ci, &yi)| (yi - model(&nt, ci)).powi(2))
                .sum();
            if nrss.is_finite() && nrss < rss {
                let rel = (rss - nrss) / rss.max(1e-300);
                t = nt;
                rss = nrss;
                lambda = (lambda / 3.0).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    // Keep the labels: break-in is the faster term.
    if t[2] > t[4] {
        t = [t[0], t[3], t[4], t[1], t[2]];
    }
    let dof = (n - 5) as f64;
    let s2 = rss / dof;
    let mut jtj = DMatrix::<f64>::zeros(5, 5);
    for &ci in c {
        let gr = DVector::from_row_slice(&gradient(&t, ci));
        jtj += &gr * gr.transpose();
    }
    let mut cov = [[f64::NAN; 5]; 5];
    let mut reasons = Vec::new();
    match jtj.clone().try_inverse() {
        Some(inv) if inv.iter().all(|v| v.is_finite()) => {
            for (a, row) in cov.iter_mut().enumerate() {
                for (b, v) in row.iter_mut().enumerate() {
                    *v = s2 * inv[(a, b)];
                }
            }
        }
        _ => reasons.push("the parameters are not separable from these data".to_string()),
    }
    let fit = LawFit {
        theta: t,
        cov,
        residual_sd: s2.sqrt(),
        n,
        c_max,
        validity: HeadlineValidity::default(),
    };
    let mut fit = fit;
    // What the data cannot support.
    let names = [
        "K_inf",
        "break-in change",
        "break-in scale",
        "fatigue change",
        "fatigue scale",
    ];
    if reasons.is_empty() {
        for (m, name) in names.iter().enumerate() {
            let se = fit.se(m);
            if !(se.is_finite() && se <= 0.3 * t[m].abs()) {
                reasons.push(format!(
                    "the {name} is uncertain by more than 30 % ({:.3e} ± {:.3e})",
                    t[m], se
                ));
            }
        }
    }
    if t[1] < 0.0 || t[3] < 0.0 {
        reasons.push("a term stiffens the part: this is not ageing".into());
    }
    if t[2] < 0.3 * step {
        reasons.push(format!(
            "break-in ({:.3e}) is faster than the intervals ({step:.3e}) resolve",
            t[2]
        ));
    }
    if t[4] > 3.0 * c_max {
        reasons.push(format!(
            "the fatigue scale ({:.3e}) lies beyond three times the largest load measured ({c_max:.3e})",
            t[4]
        ));
    }
    if t[4] < 3.0 * t[2] {
        reasons.push("break-in and fatigue are not separated (scales within a factor 3)".into());
    }
    if !reasons.is_empty() {
        fit.validity = HeadlineValidity {
            state: State::Unreliable,
            reason: Some(reasons.join("; ")),
            fit_value: None,
        };
    }
    Ok(fit)
}

impl LawFit {
    /// Standard error of parameter `m` (NaN when undetermined).
    pub fn se(&self, m: usize) -> f64 {
        self.cov[m][m].max(0.0).sqrt()
    }

    /// The law's value at `c`.
    pub fn value(&self, c: f64) -> f64 {
        model(&self.theta, c)
    }

    /// The law's value at `c` and its standard error (delta method).
    pub fn predict(&self, c: f64) -> (f64, f64) {
        let g = gradient(&self.theta, c);
        let mut var = 0.0;
        for a in 0..5 {
            for b in 0..5 {
                var += g[a] * self.cov[a][b] * g[b];
            }
        }
        (model(&self.theta, c), var.max(0.0).sqrt())
    }

    /// The fitted law's value at the start (the new part).
    pub fn initial(&self) -> f64 {
        self.theta[0] + self.theta[1] + self.theta[3]
    }
}

/// Another quantity's course (f0, Keff, K at an excursion) on the load
/// scales of the K(0) law: three amplitudes by linear least squares.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Track {
    /// What it is, with its unit (e.g. `keff_n_per_m`, `k_at_x_n_per_m`).
    pub quantity: String,
    /// Excursion the stiffness belongs to (m), for K at an excursion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_m: Option<f64>,
    /// The fitted law's value at the start and at the last interval (the
    /// quantity's unit).
    pub initial: f64,
    pub last: f64,
    /// Change from the start to the last interval (%), with its standard error.
    pub change_percent: Estimate,
    /// Change by break-in and by fatigue so far (%).
    pub break_in_change_percent: f64,
    pub fatigue_change_percent: f64,
    pub validity: HeadlineValidity,
}

/// A quantity fitted on the K(0) law's scales: its three amplitudes, their
/// covariance and the residual variance (for its curve and band).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackFit {
    /// [K_∞, A_b, A_f] in the quantity's unit.
    pub amplitudes: [f64; 3],
    /// Covariance of the amplitudes.
    pub cov: [[f64; 3]; 3],
    /// Residual variance about the fit.
    pub s2: f64,
    tb: f64,
    tf: f64,
}

impl TrackFit {
    fn row(&self, c: f64) -> Vector3<f64> {
        Vector3::new(1.0, (-c / self.tb).exp(), (-c / self.tf).exp())
    }

    /// The fitted value at load coordinate `c` and its standard error.
    pub fn predict(&self, c: f64) -> (f64, f64) {
        let r = self.row(c);
        let a = Vector3::from(self.amplitudes);
        let cov = Matrix3::from_fn(|i, j| self.cov[i][j]);
        (r.dot(&a), (r.transpose() * cov * r)[(0, 0)].max(0.0).sqrt())
    }
}

/// Fits `y` against `c` on the law's two scales (three linear amplitudes);
/// None with fewer than 4 points, a non-finite one or a singular system.
pub fn fit_track(c: &[f64], y: &[f64], law: &LawFit) -> Option<TrackFit> {
    let n = c.len();
    if n < 4 || n != y.len() || c.iter().chain(y).any(|v| !v.is_finite()) {
        return None;
    }
    let (tb, tf) = (law.theta[2], law.theta[4]);
    let (a, rss) = project(c, y, tb, tf)?;
    let s2 = rss / (n - 3) as f64;
    let mut ata = Matrix3::<f64>::zeros();
    for &ci in c {
        let r = Vector3::new(1.0, (-ci / tb).exp(), (-ci / tf).exp());
        ata += r * r.transpose();
    }
    let inv = ata.try_inverse()? * s2;
    Some(TrackFit {
        amplitudes: a,
        cov: std::array::from_fn(|i| std::array::from_fn(|j| inv[(i, j)])),
        s2,
        tb,
        tf,
    })
}

/// Fits `y` against `c` with the K(0) law's scales held.
pub fn track(
    quantity: &str,
    x_m: Option<f64>,
    c: &[f64],
    y: &[f64],
    law: &LawFit,
) -> Option<Track> {
    let fit = fit_track(c, y, law)?;
    let (a, tb, tf) = (fit.amplitudes, fit.tb, fit.tf);
    let inv = Matrix3::from_fn(|i, j| fit.cov[i][j]);
    let t = [a[0], a[1], tb, a[2], tf];
    let initial = a[0] + a[1] + a[2];
    let last = model(&t, law.c_max);
    // change = (last - initial)/initial; gradient in the amplitudes.
    let eb = (-law.c_max / tb).exp();
    let ef = (-law.c_max / tf).exp();
    let g_last = Vector3::new(1.0, eb, ef);
    let g_init = Vector3::new(1.0, 1.0, 1.0);
    let g = (g_last * initial - g_init * last) / (initial * initial);
    let se = (g.transpose() * inv * g)[(0, 0)].max(0.0).sqrt() * 100.0;
    let change = 100.0 * (last / initial - 1.0);
    let mut validity = HeadlineValidity::default();
    if !(se.is_finite() && initial.abs() > 0.0) {
        validity = HeadlineValidity {
            state: State::Unreliable,
            reason: Some("the change is not determined by these data".into()),
            fit_value: None,
        };
    }
    Some(Track {
        quantity: quantity.into(),
        x_m,
        initial,
        last,
        change_percent: Estimate {
            value: change,
            se: if se.is_finite() { se } else { 0.0 },
        },
        break_in_change_percent: 100.0 * a[1] * (eb - 1.0) / initial,
        fatigue_change_percent: 100.0 * a[2] * (ef - 1.0) / initial,
        validity,
    })
}

/// Length of the blocks the measured load is summed over (s): the
/// displacement is averaged over each (the mean takes the laser's noise out
/// of the differences; a sine loses ~(π f T)² of its load at the turning
/// points between blocks: 0.1 % at 40 Hz).
pub const LOAD_BLOCK_S: f64 = 0.00025;

/// The load a bench's stimulus put on the part, measured from its
/// displacement `x_m` at `fs_hz` (J): the load measure of
/// `physics::ageing`, `E = ∫ |F_el(x) v| dt`, as `Σ |F_el(x̄) Δx|` over
/// blocks of [`LOAD_BLOCK_S`], with `F_el = K(x) x` and K(x) the part's last
/// measured stiffness polynomial (`k_coeffs`: N/m^(i+1), x in m) evaluated
/// within its valid range `range_m` (clamped beyond it). The hardware and
/// emulated benches' long-term test uses it: their part has no simulated
/// load. Non-finite samples are skipped.
pub fn load_from_displacement_j(
    x_m: &[f64],
    fs_hz: f64,
    k_coeffs: &[f64],
    range_m: [f64; 2],
) -> f64 {
    let n = ((LOAD_BLOCK_S * fs_hz).round() as usize).max(1);
    let (lo, hi) = (range_m[0].min(range_m[1]), range_m[0].max(range_m[1]));
    let force = |x: f64| {
        let xc = x.clamp(lo, hi);
        k_coeffs.iter().rev().fold(0.0, |a, &c| a * xc + c) * x
    };
    let means: Vec<f64> = x_m
        .chunks(n)
        .filter(|c| c.len() == n)
        .map(|c| c.iter().sum::<f64>() / n as f64)
        .filter(|m| m.is_finite())
        .collect();
    means
        .windows(2)
        .map(|w| (force(0.5 * (w[0] + w[1])) * (w[1] - w[0])).abs())
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn series(noise: f64, n: usize, step: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let t = [800.0, 200.0, 5000.0, 500.0, 150_000.0];
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c: Vec<f64> = (0..n).map(|i| i as f64 * step).collect();
        let y = c
            .iter()
            .map(|&ci| model(&t, ci) + noise * rng.sample::<f64, _>(StandardNormal))
            .collect();
        (c, y)
    }

    #[test]
    fn recovers_known_parameters_with_honest_errors() {
        let truth = [800.0, 200.0, 5000.0, 500.0, 150_000.0];
        let (c, y) = series(1.0, 41, 5000.0, 3);
        let f = fit_law(&c, &y).unwrap();
        assert_eq!(f.validity.state, State::Valid, "{:?}", f.validity);
        for (m, want) in truth.iter().enumerate() {
            let err = (f.theta[m] - want).abs();
            assert!(err < 0.05 * want, "{m}: {} vs {want}", f.theta[m]);
            // within four standard errors (an honest error, not a tiny one)
            assert!(err < 4.0 * f.se(m), "{m}: {err} > 4 se {}", f.se(m));
        }
        assert!((f.residual_sd - 1.0).abs() < 0.3);
        // Prediction at twice the load.
        let (p, se) = f.predict(400_000.0);
        let want = model(&truth, 400_000.0);
        assert!((p - want).abs() < 4.0 * se.max(1.0), "{p} {want} {se}");
    }

    #[test]
    fn data_that_cannot_support_the_law_are_marked() {
        // Loads far below the fatigue scale: a straight line, no curvature.
        let (c, y) = series(1.0, 12, 500.0, 4);
        let f = fit_law(&c, &y).unwrap();
        assert_eq!(f.validity.state, State::Unreliable);
        let why = f.validity.reason.unwrap();
        assert!(
            why.contains("uncertain by more than 30 %") || why.contains("not separable"),
            "{why}"
        );
        // Too few intervals.
        let (c, y) = series(1.0, 5, 5000.0, 5);
        assert!(fit_law(&c, &y).unwrap_err().contains("at least"));
        // Not finite.
        let (c, mut y) = series(1.0, 20, 5000.0, 5);
        y[3] = f64::NAN;
        assert!(fit_law(&c, &y).is_err());
    }

    #[test]
    fn a_track_on_the_law_scales_gives_its_change() {
        let (c, y) = series(0.5, 41, 5000.0, 6);
        let f = fit_law(&c, &y).unwrap();
        // A stiffness at large excursion that loses 1 % by fatigue only.
        let z: Vec<f64> = c
            .iter()
            .map(|&ci| 5000.0 - 50.0 * (1.0 - (-ci / 150_000.0).exp()))
            .collect();
        let t = track("k_at_x_n_per_m", Some(0.006), &c, &z, &f).unwrap();
        let want = -50.0 * (1.0 - (-200_000.0f64 / 150_000.0).exp()) / 50.0;
        assert!((t.change_percent.value - want).abs() < 0.05, "{:?}", t);
        assert!(t.break_in_change_percent.abs() < 0.05);
        // Its curve: the value at any load within 0.01 % of the truth, the
        // standard error small but not zero, and the band around it.
        let fit = fit_track(&c, &z, &f).unwrap();
        for cc in [0.0, 50_000.0, 200_000.0, 400_000.0] {
            let (v, se) = fit.predict(cc);
            let want = 5000.0 - 50.0 * (1.0 - (-cc / 150_000.0f64).exp());
            assert!((v - want).abs() < 0.5, "{cc}: {v} vs {want}");
            assert!(se.is_finite() && se < 0.5, "{cc}: se {se}");
        }
    }

    /// A sine of a linear spring: 2 (U(X) + U(-X)) = 2 K X^2 per cycle.
    #[test]
    fn measured_load_of_a_sine_is_four_peak_energies_per_cycle() {
        let (fs, f, xp, k) = (48_000.0, 40.0, 0.005, 1000.0);
        let x: Vec<f64> = (0..48_000)
            .map(|i| xp * (2.0 * std::f64::consts::PI * f * i as f64 / fs).sin())
            .collect();
        let e = super::load_from_displacement_j(&x, fs, &[k], [-0.01, 0.01]);
        let truth = f * 2.0 * k * xp * xp;
        assert!((e / truth - 1.0).abs() < 3e-3, "{e} J against {truth} J");
        // Beyond the valid range K is held at the range's end.
        let e2 = super::load_from_displacement_j(&x, fs, &[k, 0.0, 1e7], [-0.001, 0.001]);
        let k_end = k + 1e7 * 1e-6;
        assert!(
            (e2 / (f * 2.0 * k_end * xp * xp) - 1.0).abs() < 0.05,
            "{e2}"
        );
    }
}
