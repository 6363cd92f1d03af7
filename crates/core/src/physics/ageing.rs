//! Load-induced ageing of a suspension part (issue 32, decision 0110): the
//! stiffness near rest falls with the load the part has taken, a fast
//! break-in term and a slow fatigue term; the stiffness at large excursion
//! barely changes (paper §6.2, Fig. 23).
//!
//! The law (SI):
//! - load `E = ∫ |F_el(x) v| dt` (J): the elastic energy moved through the
//!   suspension, `F_el = K(x) x` its restoring force, `v` its velocity. Over one
//!   cycle of an oscillation between `-X-` and `X+` it is `2 (U(X+) + U(-X-))`,
//!   `U` the stored elastic energy at the peak: four times the peak energy of
//!   a symmetric stroke. Under a constant stimulus it grows in proportion to
//!   time; it is the sample-domain form of the apparent power `F v` the
//!   suspension carries, accumulated.
//! - stiffness `K(x, E) = K_new(x) - L(E) w(x)` with the lost stiffness
//!   `L(E) = ΔK_b (1 - exp(-E/E_b)) + ΔK_f (1 - exp(-E/E_f))` and the shape
//!   `w(x) = exp(-(x/x_w)^4)`: flat near rest (the impregnated material),
//!   nothing left beyond about 1.6 `x_w` (the geometry). So
//!   `K(0, E) = K_∞ + ΔK_b exp(-E/E_b) + ΔK_f exp(-E/E_f)`,
//!   `K_∞ = k0 - ΔK_b - ΔK_f`.
//!
//! Pure: the parameters ([`AgeingParams`], a part's `[ageing]` table), the
//! lost stiffness at a load, the load of a sine (the accelerated load phase
//! of a long-term test, [`apply_sine`]).

use serde::{Deserialize, Serialize};

/// A part's ageing parameters (`[ageing]` in a part's TOML).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AgeingParams {
    /// Stiffness at rest that break-in removes (N/m): ΔK_b.
    pub break_in_k_n_per_m: f64,
    /// Load over which break-in falls by 1/e (J): E_b.
    pub break_in_load_j: f64,
    /// Stiffness at rest that fatigue removes (N/m): ΔK_f.
    pub fatigue_k_n_per_m: f64,
    /// Load over which fatigue falls by 1/e (J): E_f (much larger than E_b).
    pub fatigue_load_j: f64,
    /// Half-width of the softened zone around rest (m): x_w in
    /// w(x) = exp(-(x/x_w)^4).
    pub width_m: f64,
}

impl AgeingParams {
    /// One-line error naming the first implausible field; `k0_n_per_m` is
    /// the new part's stiffness at rest (the aged part must stay stiff).
    pub fn validate(&self, k0_n_per_m: f64) -> Result<(), String> {
        for (n, v) in [
            ("ageing.break_in_k_n_per_m", self.break_in_k_n_per_m),
            ("ageing.fatigue_k_n_per_m", self.fatigue_k_n_per_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{n} must be >= 0, got {v}"));
            }
        }
        for (n, v) in [
            ("ageing.break_in_load_j", self.break_in_load_j),
            ("ageing.fatigue_load_j", self.fatigue_load_j),
            ("ageing.width_m", self.width_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{n} must be a positive number, got {v}"));
            }
        }
        let lost = self.break_in_k_n_per_m + self.fatigue_k_n_per_m;
        if lost > 0.9 * k0_n_per_m {
            return Err(format!(
                "ageing.break_in_k_n_per_m + ageing.fatigue_k_n_per_m ({lost}) must stay below 90 % of k0 ({k0_n_per_m})"
            ));
        }
        Ok(())
    }

    /// Stiffness at rest lost after the load `load_j` (N/m): L(E).
    pub fn lost_k_n_per_m(&self, load_j: f64) -> f64 {
        let e = load_j.max(0.0);
        self.break_in_k_n_per_m * (1.0 - (-e / self.break_in_load_j).exp())
            + self.fatigue_k_n_per_m * (1.0 - (-e / self.fatigue_load_j).exp())
    }

    /// The new part's k0 after the load: K(0, E) (N/m).
    pub fn k0_n_per_m(&self, k0_new_n_per_m: f64, load_j: f64) -> f64 {
        k0_new_n_per_m - self.lost_k_n_per_m(load_j)
    }

    /// Fraction of break-in still to come after the load: exp(-E/E_b).
    pub fn break_in_remaining(&self, load_j: f64) -> f64 {
        (-load_j.max(0.0) / self.break_in_load_j).exp()
    }
}

/// w(x) = exp(-(x/x_w)^4) from `inv_width4` = 1/x_w^4.
#[inline]
pub fn shape(x_m: f64, inv_width4: f64) -> f64 {
    let u = x_m * x_m;
    (-(u * u * inv_width4)).exp()
}

/// The elastic restoring force of a part at a load (N): K(x, E) x.
pub fn elastic_force_n(part: &super::PartSpec, load_j: f64, x_m: f64) -> f64 {
    let mut k = part.stiffness_n_per_m(x_m);
    if let Some(a) = &part.ageing {
        k -= a.lost_k_n_per_m(load_j) * shape(x_m, a.width_m.powi(-4));
    }
    k * x_m
}

/// Elastic energy stored at `x_m` (J): ∫_0^x F_el dx (Simpson, 200 panels).
pub fn stored_energy_j(part: &super::PartSpec, load_j: f64, x_m: f64) -> f64 {
    let n = 200;
    let h = x_m / n as f64;
    let mut s = elastic_force_n(part, load_j, 0.0) + elastic_force_n(part, load_j, x_m);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        s += w * elastic_force_n(part, load_j, i as f64 * h);
    }
    s * h / 3.0
}

/// The load of one cycle of a symmetric oscillation of amplitude `xpeak_m` (J).
pub fn cycle_load_j(part: &super::PartSpec, load_j: f64, xpeak_m: f64) -> f64 {
    2.0 * (stored_energy_j(part, load_j, xpeak_m) + stored_energy_j(part, load_j, -xpeak_m))
}

/// Keff at amplitude `xpeak_m`: the first-harmonic describing function of the
/// elastic force over ±xpeak_m (N/m).
pub fn keff_n_per_m(part: &super::PartSpec, load_j: f64, xpeak_m: f64) -> f64 {
    let n = 256;
    let mut s = 0.0;
    for i in 0..n {
        let th = 2.0 * std::f64::consts::PI * (i as f64 + 0.5) / n as f64;
        s += elastic_force_n(part, load_j, xpeak_m * th.sin()) * th.sin();
    }
    2.0 * s / n as f64 / xpeak_m
}

/// The resonance at amplitude `xpeak_m` (Hz): sqrt(Keff/m) / 2 pi.
pub fn resonance_hz(part: &super::PartSpec, load_j: f64, xpeak_m: f64) -> f64 {
    (keff_n_per_m(part, load_j, xpeak_m).max(0.0) / part.moving_mass_kg).sqrt()
        / (2.0 * std::f64::consts::PI)
}

/// Load power of a sine held at the part's current resonance at `xpeak_m` (W).
pub fn sine_power_w(part: &super::PartSpec, load_j: f64, xpeak_m: f64) -> f64 {
    if xpeak_m <= 0.0 {
        return 0.0;
    }
    resonance_hz(part, load_j, xpeak_m) * cycle_load_j(part, load_j, xpeak_m)
}

/// The load after `duration_s` of a sine held at the part's current
/// resonance (it moves as the part softens) at `xpeak_m`, from `load_j`: the
/// accelerated load phase of a long-term test. The load's rate dE/dt =
/// f_R(E) · cycle load(E) is integrated with the midpoint rule in steps of at
/// most 10 s (the part changes over minutes, not seconds).
pub fn apply_sine(part: &super::PartSpec, load_j: f64, xpeak_m: f64, duration_s: f64) -> f64 {
    if part.ageing.is_none() || duration_s <= 0.0 || xpeak_m <= 0.0 {
        // A part without ageing parameters still takes load; its stiffness
        // does not depend on it, so one rate holds throughout.
        return load_j + sine_power_w(part, load_j, xpeak_m) * duration_s.max(0.0);
    }
    let steps = (duration_s / 10.0).ceil().max(1.0) as usize;
    let h = duration_s / steps as f64;
    let mut e = load_j;
    for _ in 0..steps {
        let p1 = sine_power_w(part, e, xpeak_m);
        let p2 = sine_power_w(part, e + 0.5 * h * p1, xpeak_m);
        e += h * p2;
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aged() -> super::super::PartSpec {
        let mut p = super::super::preset("spider_3in").unwrap();
        p.ageing = Some(AgeingParams {
            break_in_k_n_per_m: 200.0,
            break_in_load_j: 50.0,
            fatigue_k_n_per_m: 500.0,
            fatigue_load_j: 2000.0,
            width_m: 0.004,
        });
        p
    }

    #[test]
    fn k0_falls_by_both_terms_and_large_excursion_stays() {
        let p = aged();
        let a = p.ageing.unwrap();
        assert_eq!(a.k0_n_per_m(1500.0, 0.0), 1500.0);
        let e = 100.0;
        let want = 1500.0 - 200.0 * (1.0 - (-2.0f64).exp()) - 500.0 * (1.0 - (-0.05f64).exp());
        assert!((a.k0_n_per_m(1500.0, e) - want).abs() < 1e-9);
        // K(x) at 6.4 mm (0.8 of an 8 mm stroke): the loss is 0.14 % of it.
        let k = |x: f64, e: f64| elastic_force_n(&p, e, x) / x;
        let x = 0.0064;
        let rel = (k(x, 1e6) / k(x, 0.0) - 1.0).abs();
        assert!(rel < 0.002, "{rel}");
        assert!((k(1e-6, 1e6) - (1500.0 - 700.0)).abs() < 1.0);
    }

    #[test]
    fn cycle_load_is_four_peak_energies_of_a_linear_spring() {
        let mut p = super::super::preset("spider_3in").unwrap();
        p.k_coeffs_si = vec![1000.0];
        p.ageing = None;
        // U = k X^2 / 2; four of them per cycle.
        let x = 0.002;
        assert!((cycle_load_j(&p, 0.0, x) - 4.0 * 0.5 * 1000.0 * x * x).abs() < 1e-12);
        assert!((keff_n_per_m(&p, 0.0, x) - 1000.0).abs() < 1e-9);
        // A constant rate: load grows in proportion to time.
        let e = apply_sine(&p, 1.0, x, 3600.0);
        let f = (1000.0 / p.moving_mass_kg).sqrt() / (2.0 * std::f64::consts::PI);
        assert!((e - 1.0 - f * 0.008 * 3600.0).abs() < 1e-6);
    }

    #[test]
    fn accelerated_load_matches_small_steps() {
        // The midpoint rule in 10 s steps against 0.1 s steps.
        let p = aged();
        let coarse = apply_sine(&p, 0.0, 0.006, 600.0);
        let mut fine = 0.0;
        for _ in 0..6000 {
            fine += 0.1 * sine_power_w(&p, fine, 0.006);
        }
        assert!((coarse / fine - 1.0).abs() < 1e-3, "{coarse} {fine}");
    }

    #[test]
    fn bad_parameters_are_named() {
        let mut a = aged().ageing.unwrap();
        a.width_m = 0.0;
        assert!(a.validate(1500.0).unwrap_err().contains("width_m"));
        let mut a = aged().ageing.unwrap();
        a.fatigue_k_n_per_m = 1400.0;
        assert!(a.validate(1500.0).unwrap_err().contains("90 %"));
        assert!(aged().ageing.unwrap().validate(1500.0).is_ok());
    }
}
