//! Production parts with manufacturing spread: a nominal preset, relative
//! standard deviations of K(x) coefficients, mass and R, and a seed give one
//! part of a production lot; an optional defect makes it a bad one. Pure.

use super::PartSpec;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// Relative standard deviations of one production lot (1 sigma).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Spread {
    /// Of k0 (the whole K(x) curve scales with it).
    pub k0_rel: f64,
    /// Of each higher coefficient k1.. on its own (the shape).
    pub k_shape_rel: f64,
    pub mass_rel: f64,
    /// Of R (and so of Q).
    pub r_rel: f64,
    /// Of the material's memory (issue 33): the hysteretic stiffness and the
    /// softening depth of a nominal part that has them (drawn after the
    /// others, so a lot without them is the same as before).
    pub memory_rel: f64,
    /// Of each ageing parameter on its own (break-in and fatigue amounts and
    /// loads; `ageing.rs`), for parts that have them.
    pub ageing_rel: f64,
}

impl Default for Spread {
    fn default() -> Self {
        Spread {
            k0_rel: 0.015,
            k_shape_rel: 0.03,
            mass_rel: 0.005,
            r_rel: 0.03,
            memory_rel: 0.1,
            ageing_rel: 0.1,
        }
    }
}

/// What can be wrong with a produced part (or with its surface for the laser).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Defect {
    /// K(x) 30 % stiffer throughout (too much impregnation).
    Stiff,
    /// K(x) 30 % softer throughout.
    Soft,
    /// Strong asymmetry: k1 times 3 (off-centre corrugation).
    Asymmetric,
    /// Progressive hardening: k2 and k4 times 2.5 (hardens early).
    Hardening,
    /// R times 2 (Q halved): a rubbing or glued part.
    Damped,
    /// Coulomb friction of 0.25 N (the part rubs on the clamp).
    Friction,
    /// A dark surface: laser noise 60 um instead of the bench's (measurement not trustworthy).
    DarkSurface,
}

impl Defect {
    pub const ALL: [Defect; 7] = [
        Defect::Stiff,
        Defect::Soft,
        Defect::Asymmetric,
        Defect::Hardening,
        Defect::Damped,
        Defect::Friction,
        Defect::DarkSurface,
    ];
}

/// One produced part: nominal with the lot's spread drawn from `seed`, then the defect.
pub fn part(nominal: &PartSpec, spread: &Spread, seed: u64, defect: Option<Defect>) -> PartSpec {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_9a27_0000_0000);
    let mut g = |s: f64| 1.0 + s * rng.sample::<f64, _>(StandardNormal);
    let mut p = nominal.clone();
    let scale = g(spread.k0_rel);
    for (i, k) in p.k_coeffs_si.iter_mut().enumerate() {
        *k *= scale;
        if i > 0 {
            *k *= g(spread.k_shape_rel);
        }
    }
    p.moving_mass_kg *= g(spread.mass_rel);
    p.r_ns_per_m *= g(spread.r_rel);
    if let Some(h) = &mut p.effects.hysteresis {
        h.k_n_per_m *= g(spread.memory_rel).max(0.0);
    }
    if let Some(s) = &mut p.effects.reversible_softening {
        s.depth_n_per_m2 *= g(spread.memory_rel).max(0.0);
    }
    // Drawn after the others: a lot's parts keep their K(x), mass and R.
    if let Some(a) = p.ageing.as_mut() {
        a.break_in_k_n_per_m *= g(spread.ageing_rel).max(0.0);
        a.break_in_load_j *= g(spread.ageing_rel).max(0.1);
        a.fatigue_k_n_per_m *= g(spread.ageing_rel).max(0.0);
        a.fatigue_load_j *= g(spread.ageing_rel).max(0.1);
    }
    p.name = format!("{} lot part {seed}", nominal.name);
    match defect {
        None => {}
        Some(Defect::Stiff) => scale_stiffness(&mut p, 1.3),
        Some(Defect::Soft) => scale_stiffness(&mut p, 0.7),
        Some(Defect::Asymmetric) => {
            if let Some(k1) = p.k_coeffs_si.get_mut(1) {
                *k1 *= 3.0;
            }
        }
        Some(Defect::Hardening) => {
            for i in [2, 4] {
                if let Some(k) = p.k_coeffs_si.get_mut(i) {
                    *k *= 2.5;
                }
            }
        }
        Some(Defect::Damped) => p.r_ns_per_m *= 2.0,
        Some(Defect::Friction) => {
            p.effects.coulomb_friction = Some(crate::effects::CoulombFriction {
                force_n: 0.25,
                v_eps_m_per_s: 2e-3,
            })
        }
        Some(Defect::DarkSurface) => p.laser_noise_m = Some(60e-6),
    }
    if let Some(d) = defect {
        p.name = format!(
            "{} ({})",
            p.name,
            serde_json::to_value(d)
                .unwrap_or_default()
                .as_str()
                .unwrap_or("")
        );
    }
    p
}

/// K(x) scaled throughout; the stiffness ageing removes near rest with it.
fn scale_stiffness(p: &mut PartSpec, f: f64) {
    p.k_coeffs_si.iter_mut().for_each(|k| *k *= f);
    if let Some(a) = p.ageing.as_mut() {
        a.break_in_k_n_per_m *= f;
        a.fatigue_k_n_per_m *= f;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seed_gives_one_part_and_the_lot_has_the_spread() {
        let nominal = super::super::preset("spider_4in").unwrap();
        let s = Spread::default();
        assert_eq!(part(&nominal, &s, 3, None), part(&nominal, &s, 3, None));
        assert_ne!(part(&nominal, &s, 3, None), part(&nominal, &s, 4, None));
        // 2000 parts: the relative spread of k0 and mass is the configured one (within 5 %).
        let n = 2000;
        let rel = |f: &dyn Fn(&PartSpec) -> f64| {
            let v: Vec<f64> = (0..n).map(|i| f(&part(&nominal, &s, i, None))).collect();
            let (m, sd) = crate::qc::limits::mean_sigma(&v);
            (m, sd / m)
        };
        let (mk, sk) = rel(&|p| p.k_coeffs_si[0]);
        assert!((mk / 2400.0 - 1.0).abs() < 0.002, "{mk}");
        assert!((sk / s.k0_rel - 1.0).abs() < 0.05, "{sk}");
        let (_, sm) = rel(&|p| p.moving_mass_kg);
        assert!((sm / s.mass_rel - 1.0).abs() < 0.05, "{sm}");
        for p in (0..20).map(|i| part(&nominal, &s, i, None)) {
            p.validate().unwrap();
        }
        // The ageing parameters spread as configured.
        let (mb, sb) = rel(&|p| p.ageing.unwrap().break_in_load_j);
        let eb = nominal.ageing.unwrap().break_in_load_j;
        assert!((mb / eb - 1.0).abs() < 0.01, "{mb}");
        assert!((sb / s.ageing_rel - 1.0).abs() < 0.06, "{sb}");
    }

    #[test]
    fn the_memory_spreads_only_where_the_nominal_part_has_it() {
        let mut nominal = super::super::preset("spider_4in").unwrap();
        let s = Spread::default();
        let plain = part(&nominal, &s, 7, None);
        assert!(plain.effects.is_empty());
        nominal.effects.reversible_softening = Some(crate::effects::ReversibleSoftening {
            depth_n_per_m2: 3e4,
            tau_s: 2.0,
        });
        let with = part(&nominal, &s, 7, None);
        // The other draws are the same part's.
        assert_eq!(with.k_coeffs_si, plain.k_coeffs_si);
        assert_eq!(with.r_ns_per_m, plain.r_ns_per_m);
        let v: Vec<f64> = (0..2000)
            .map(|i| {
                part(&nominal, &s, i, None)
                    .effects
                    .reversible_softening
                    .unwrap()
                    .depth_n_per_m2
            })
            .collect();
        let (m, sd) = crate::qc::limits::mean_sigma(&v);
        assert!((m / 3e4 - 1.0).abs() < 0.01, "{m}");
        assert!((sd / m / s.memory_rel - 1.0).abs() < 0.06, "{sd}");
    }

    #[test]
    fn defects_change_what_they_say() {
        let nominal = super::super::preset("spider_4in").unwrap();
        let s = Spread::default();
        let good = part(&nominal, &s, 9, None);
        let stiff = part(&nominal, &s, 9, Some(Defect::Stiff));
        assert!((stiff.k_coeffs_si[0] / good.k_coeffs_si[0] - 1.3).abs() < 1e-12);
        let asym = part(&nominal, &s, 9, Some(Defect::Asymmetric));
        assert!((asym.k_coeffs_si[1] / good.k_coeffs_si[1] - 3.0).abs() < 1e-12);
        assert_eq!(asym.k_coeffs_si[0], good.k_coeffs_si[0]);
        let damped = part(&nominal, &s, 9, Some(Defect::Damped));
        assert!((damped.q() * 2.0 - good.q()).abs() < 1e-9);
        let dark = part(&nominal, &s, 9, Some(Defect::DarkSurface));
        assert_eq!(dark.laser_noise_m, Some(60e-6));
        assert_eq!(dark.k_coeffs_si, good.k_coeffs_si);
        for d in Defect::ALL {
            part(&nominal, &s, 9, Some(d)).validate().unwrap();
        }
    }
}
