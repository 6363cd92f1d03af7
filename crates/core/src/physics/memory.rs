//! The material's memory (issue 33): a hysteretic element and a reversible
//! softening, both states that follow the part's displacement path rather
//! than the equations of motion (decisions 0115, 0116).
//!
//! - Hysteresis (`effects::Hysteresis`), Bouc-Wen with n = 1 and
//!   beta = gamma = 1/2: `F = k z`, `dz/dx = 1 - |z| / x_yield` while the
//!   motion loads the element (`v z > 0`), `dz/dx = 1` while it unloads. For
//!   a monotone piece of path the state has a closed form
//!   ([`hysteresis_step`]), so the simulation and the diagnostics' regressor
//!   compute the same z from the same x. Rate independent: the loop, and the
//!   loss per cycle, do not depend on frequency.
//! - Reversible softening (`effects::ReversibleSoftening`): `s` is the recent
//!   peak excursion, a peak hold whose memory decays with `tau_s`
//!   (`s <- max(|x|, s exp(-dt / tau_s))` once per sample, [`envelope_step`]).
//!   K near rest drops by `depth s`, K at the peaks (|x| >= s) stays:
//!   `F = -depth s x max(0, 1 - x^2 / s^2)`.
//!
//! The RK4 integrator holds both states fixed over a sample (their values at
//! its start) and evaluates the force exactly along the sample's path from
//! there; after the sample it advances them ([`Memory::advance`]). Parts
//! without either effect never touch this code: their simulation is bit for
//! bit what it was.

use crate::effects::{Effects, Hysteresis, ReversibleSoftening};

/// The hysteretic state after the displacement moves monotonically by `dx`
/// from a state `z` (m): exact for `dz/dx = 1 - |z|/x_yield` while loading,
/// `dz/dx = 1` while unloading (`dx z < 0`) until z crosses zero.
#[inline]
pub fn hysteresis_step(z: f64, dx: f64, x_yield_m: f64) -> f64 {
    if dx == 0.0 {
        return z;
    }
    let sg = dx.signum();
    let mut rest = dx;
    let mut z = z;
    if z * sg < 0.0 {
        // Unloading: elastic until z reaches zero.
        if (z + rest) * sg <= 0.0 {
            return z + rest;
        }
        rest += z;
        z = 0.0;
    }
    // Loading: w = |z| approaches x_yield exponentially in the path length.
    let w = z * sg;
    sg * (x_yield_m - (x_yield_m - w) * (-rest.abs() / x_yield_m).exp())
}

/// The softening envelope after one sample of `dt_s` that ends at `x`.
#[inline]
pub fn envelope_step(s: f64, x: f64, decay: f64) -> f64 {
    (s * decay).max(x.abs())
}

/// The per-sample decay factor of the envelope.
pub fn envelope_decay(dt_s: f64, tau_s: f64) -> f64 {
    (-dt_s / tau_s).exp()
}

/// The softening force (N, opposing like the suspension) at `x` with envelope `s`.
#[inline]
pub fn softening_force(depth_n_per_m2: f64, s: f64, x: f64) -> f64 {
    let s = s.max(x.abs());
    if s <= 0.0 {
        return 0.0;
    }
    let r = x / s;
    -depth_n_per_m2 * s * x * (1.0 - r * r).max(0.0)
}

/// The memory of one part in the simulation: its parameters and its states
/// at the start of the current sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Memory {
    pub hysteresis: Option<Hysteresis>,
    pub softening: Option<ReversibleSoftening>,
    /// Displacement at the start of the sample (m).
    pub x0_m: f64,
    /// Hysteretic state at the start of the sample (m).
    pub z_m: f64,
    /// Softening envelope at the start of the sample (m).
    pub s_m: f64,
    decay: f64,
}

impl Memory {
    /// None when the part has neither effect.
    pub fn new(fx: &Effects, sample_rate_hz: f64) -> Option<Memory> {
        if fx.hysteresis.is_none() && fx.reversible_softening.is_none() {
            return None;
        }
        Some(Memory {
            hysteresis: fx.hysteresis,
            softening: fx.reversible_softening,
            x0_m: 0.0,
            z_m: 0.0,
            s_m: 0.0,
            decay: fx
                .reversible_softening
                .map_or(1.0, |s| envelope_decay(1.0 / sample_rate_hz, s.tau_s)),
        })
    }

    /// The envelope's decay per sample at this sample rate.
    pub fn set_sample_rate(&mut self, sample_rate_hz: f64) {
        if let Some(s) = &self.softening {
            self.decay = envelope_decay(1.0 / sample_rate_hz, s.tau_s);
        }
    }

    /// Force of both elements at displacement `x` inside the current sample.
    #[inline]
    pub fn force(&self, x: f64) -> f64 {
        let mut f = 0.0;
        if let Some(h) = &self.hysteresis {
            f += h.k_n_per_m * hysteresis_step(self.z_m, x - self.x0_m, h.x_yield_m);
        }
        if let Some(s) = &self.softening {
            f += softening_force(s.depth_n_per_m2, self.s_m, x);
        }
        f
    }

    /// The states at the end of the sample, which ended at `x`.
    #[inline]
    pub fn advance(&mut self, x: f64) {
        if let Some(h) = &self.hysteresis {
            self.z_m = hysteresis_step(self.z_m, x - self.x0_m, h.x_yield_m);
        }
        if self.softening.is_some() {
            self.s_m = envelope_step(self.s_m, x, self.decay);
        }
        self.x0_m = x;
    }

    /// K(0) now, less the elastic K(0): the softening's share (N/m, <= 0).
    pub fn k0_shift_n_per_m(&self) -> f64 {
        self.softening.map_or(0.0, |s| -s.depth_n_per_m2 * self.s_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hysteresis_small_loop_is_elastic_and_large_one_saturates() {
        let xy = 1e-3;
        // Path additivity: two half steps equal one step (closed form).
        let a = hysteresis_step(hysteresis_step(0.0, 0.4e-3, xy), 0.4e-3, xy);
        let b = hysteresis_step(0.0, 0.8e-3, xy);
        assert!((a - b).abs() < 1e-15, "{a} {b}");
        // First loading: z = xy (1 - exp(-x/xy)).
        assert!((b - xy * (1.0 - (-0.8f64).exp())).abs() < 1e-15);
        // Far out it saturates at x_yield; unloading is elastic.
        let z = hysteresis_step(0.0, 20e-3, xy);
        assert!((z - xy).abs() < 1e-10);
        assert!((hysteresis_step(z, -0.5e-3, xy) - 0.5e-3).abs() < 1e-10);
        // Reversal through zero goes on loading the other way.
        let z2 = hysteresis_step(z, -20e-3, xy);
        assert!((z2 + xy).abs() < 1e-10);
    }

    #[test]
    fn loop_area_grows_like_x_cubed_at_small_amplitude() {
        // Energy lost per cycle: a Rayleigh-like loop, area ~ X^3 / x_yield.
        let xy = 1e-3;
        let area = |amp: f64| {
            let n = 4000;
            let (mut z, mut xp, mut w) = (0.0, 0.0, 0.0);
            for cycle in 0..3 {
                for i in 1..=n {
                    let x = amp * (2.0 * std::f64::consts::PI * i as f64 / n as f64).sin();
                    let zn = hysteresis_step(z, x - xp, xy);
                    if cycle == 2 {
                        w += 0.5 * (z + zn) * (x - xp);
                    }
                    z = zn;
                    xp = x;
                }
            }
            w
        };
        let (a1, a2) = (area(0.05e-3), area(0.1e-3));
        assert!(a1 > 0.0);
        let ratio = a2 / a1;
        assert!((ratio - 8.0).abs() < 0.4, "area ratio {ratio}");
    }

    #[test]
    fn softening_keeps_the_peaks_and_recovers() {
        let (d, s) = (3e4, 5e-3);
        assert_eq!(softening_force(d, s, s), 0.0);
        assert_eq!(softening_force(d, s, -2.0 * s), 0.0);
        // Near rest: K drops by depth * s.
        let x = 1e-6;
        assert!((softening_force(d, s, x) / x + d * s).abs() < 1e-3);
        // Recovery: the envelope decays with tau.
        let fs = 1000.0;
        let decay = envelope_decay(1.0 / fs, 2.0);
        let mut e = s;
        for _ in 0..2000 {
            e = envelope_step(e, 0.0, decay);
        }
        assert!((e / s - (-1.0f64).exp()).abs() < 1e-9);
    }
}
