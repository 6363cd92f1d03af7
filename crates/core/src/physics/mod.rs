//! Physics simulation of the pneumatic bench (the virtual bench). Pure: no I/O
//! (presets are compiled in with `include_str!`; reading a user's TOML file is
//! the caller's job).
//!
//! Layout: [`model`] (equations, RK4), [`production`] (production lots:
//! spread and defects). The bench around the model (sensors, the streaming
//! `Bench` device, the procedure, `simulate`, `truth.json`) is the
//! `springbench-bench` crate's.

pub mod ageing;
pub mod memory;
pub mod model;
pub mod production;
pub mod waveform;

pub use model::BenchParams;

use serde::{Deserialize, Serialize};

/// A suspension part as the virtual bench simulates it (all SI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartSpec {
    pub name: String,
    /// Moving mass: part plus inner clamp (kg).
    pub moving_mass_kg: f64,
    /// K(x) = sum k_i x^i (x in m, K in N/m).
    pub k_coeffs_si: Vec<f64>,
    /// Viscous mechanical resistance (N s/m).
    pub r_ns_per_m: f64,
    /// Effective area (m^2).
    pub ss_m2: f64,
    /// Physical effects beyond the basic force balance (hidden effects for tests).
    #[serde(default)]
    pub effects: crate::effects::Effects,
    /// Laser noise off this part's surface (m, standard deviation), when it
    /// is worse than the bench's (a dark or glossy surface); None: the bench's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_noise_m: Option<f64>,
    /// A second mechanical mode (a part of the moving mass on its own
    /// spring). Deliberately *not* an effect of the library
    /// (src/effects.rs): a part with it tests the diagnostics' report of
    /// structure outside the library. None: the part moves as one body.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub second_mode: Option<SecondMode>,
    /// Load-induced ageing (break-in and fatigue, `ageing.rs`); None: the
    /// part does not age. A bench ages it only when asked to carry its load.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ageing: Option<ageing::AgeingParams>,
}

/// A second mechanical mode: `mass_kg` of the moving mass (included in
/// `moving_mass_kg`, so the part weighs the same) hangs on a spring and a
/// damper that resonate at `f_hz` with quality factor `q` against a fixed
/// main body: `m2 x2'' = k2 (x - x2) + r2 (v - v2)`, the main body feels the
/// opposite force. Far below `f_hz` the part moves as one body.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SecondMode {
    pub mass_kg: f64,
    pub f_hz: f64,
    pub q: f64,
}

impl SecondMode {
    /// k2 (N/m) and r2 (N s/m).
    pub fn spring_damper(&self) -> (f64, f64) {
        let w = 2.0 * std::f64::consts::PI * self.f_hz;
        (self.mass_kg * w * w, self.mass_kg * w / self.q)
    }
}

impl PartSpec {
    /// One-line error naming the first implausible field.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |n: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{n} must be a positive number, got {v}"))
            }
        };
        pos("moving_mass_kg", self.moving_mass_kg)?;
        pos("ss_m2", self.ss_m2)?;
        if !self.r_ns_per_m.is_finite() || self.r_ns_per_m < 0.0 {
            return Err(format!("r_ns_per_m must be >= 0, got {}", self.r_ns_per_m));
        }
        if self.k_coeffs_si.is_empty() {
            return Err("k_coeffs_si must hold at least k0".into());
        }
        if self.k_coeffs_si.len() > 12 {
            return Err(format!(
                "k_coeffs_si holds {} coefficients; at most 12 are supported",
                self.k_coeffs_si.len()
            ));
        }
        if let Some((i, v)) = self
            .k_coeffs_si
            .iter()
            .enumerate()
            .find(|(_, v)| !v.is_finite())
        {
            return Err(format!("k_coeffs_si[{i}] must be finite, got {v}"));
        }
        pos("k_coeffs_si[0] (k0)", self.k_coeffs_si[0])?;
        if let Some(n) = self.laser_noise_m {
            if !(n.is_finite() && (0.0..=1e-3).contains(&n)) {
                return Err(format!("laser_noise_m must be in [0, 1e-3] m, got {n}"));
            }
        }
        if let Some(m) = &self.second_mode {
            if !(m.mass_kg.is_finite() && m.mass_kg > 0.0 && m.mass_kg < 0.5 * self.moving_mass_kg)
            {
                return Err(format!(
                    "second_mode.mass_kg must be > 0 and below half the moving mass, got {}",
                    m.mass_kg
                ));
            }
            pos("second_mode.f_hz", m.f_hz)?;
            pos("second_mode.q", m.q)?;
        }
        if let Some(a) = &self.ageing {
            a.validate(self.k_coeffs_si[0])?;
        }
        self.effects.validate()?;
        Ok(())
    }

    /// K(x) (N/m).
    pub fn stiffness_n_per_m(&self, x_m: f64) -> f64 {
        self.k_coeffs_si
            .iter()
            .rev()
            .fold(0.0, |acc, &c| acc * x_m + c)
    }

    /// Small-signal resonance sqrt(k0/m) / 2 pi (Hz).
    pub fn f0_hz(&self) -> f64 {
        (self.k_coeffs_si[0] / self.moving_mass_kg).sqrt() / (2.0 * std::f64::consts::PI)
    }

    /// Q = sqrt(k0 m) / R.
    pub fn q(&self) -> f64 {
        (self.k_coeffs_si[0] * self.moving_mass_kg).sqrt() / self.r_ns_per_m
    }
}

/// The preset TOML format: the fields of [`PartSpec`] plus an optional description.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PartToml {
    name: String,
    #[serde(default)]
    #[allow(dead_code)]
    description: Option<String>,
    moving_mass_kg: f64,
    k_coeffs_si: Vec<f64>,
    r_ns_per_m: f64,
    ss_m2: f64,
    #[serde(default)]
    effects: crate::effects::Effects,
    #[serde(default)]
    second_mode: Option<SecondMode>,
    #[serde(default)]
    ageing: Option<ageing::AgeingParams>,
}

const PRESETS: [(&str, &str); 5] = [
    ("spider_3in", include_str!("../../presets/spider_3in.toml")),
    ("spider_4in", include_str!("../../presets/spider_4in.toml")),
    ("cone_6in", include_str!("../../presets/cone_6in.toml")),
    ("cone_18in", include_str!("../../presets/cone_18in.toml")),
    (
        "passive_radiator",
        include_str!("../../presets/passive_radiator.toml"),
    ),
];

/// Names of the built-in part presets.
pub fn preset_names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _)| *n).collect()
}

/// A built-in preset by name.
pub fn preset(name: &str) -> Result<PartSpec, String> {
    let (_, text) = PRESETS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
        format!(
            "unknown preset '{name}' (known: {})",
            preset_names().join(", ")
        )
    })?;
    parse_part_toml(text).map_err(|e| format!("preset '{name}': {e}"))
}

/// Parses a part description in the presets' TOML format; one-line error.
pub fn parse_part_toml(text: &str) -> Result<PartSpec, String> {
    let t: PartToml = toml::from_str(text).map_err(|e| {
        // toml's message spans several lines (with a source excerpt); keep one.
        let msg = e.message().trim().replace('\n', "; ");
        match e.span() {
            Some(s) => {
                let line = text[..s.start.min(text.len())].lines().count().max(1);
                format!("part TOML, line {line}: {msg}")
            }
            None => format!("part TOML: {msg}"),
        }
    })?;
    let p = PartSpec {
        name: t.name,
        moving_mass_kg: t.moving_mass_kg,
        k_coeffs_si: t.k_coeffs_si,
        r_ns_per_m: t.r_ns_per_m,
        ss_m2: t.ss_m2,
        effects: t.effects,
        laser_noise_m: None,
        second_mode: t.second_mode,
        ageing: t.ageing,
    };
    p.validate().map_err(|e| format!("part TOML: {e}"))?;
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_parse_and_are_plausible() {
        assert_eq!(preset_names().len(), 5);
        for name in preset_names() {
            let p = preset(name).unwrap();
            assert_eq!(p.name, name);
            // Typical magnitudes (method notes): f0 10-50 Hz, Q 2-15.
            assert!(
                (10.0..=50.0).contains(&p.f0_hz()),
                "{name}: f0 {}",
                p.f0_hz()
            );
            assert!((2.0..=15.0).contains(&p.q()), "{name}: Q {}", p.q());
            // Restoring force F = K(x) x strictly increasing over +-15 mm
            // (one equilibrium, no snap-through).
            let f = |x: f64| p.stiffness_n_per_m(x) * x;
            let mut last = f(-0.015);
            for i in 1..=300 {
                let x = -0.015 + 0.03 * i as f64 / 300.0;
                assert!(f(x) > last, "{name}: F(x) not increasing at {x}");
                last = f(x);
            }
        }
        assert!(preset("woofer").unwrap_err().contains("spider_4in"));
    }

    #[test]
    fn bad_part_toml_gives_clear_errors() {
        let ok = "name='a'\nmoving_mass_kg=0.05\nk_coeffs_si=[1000.0]\nr_ns_per_m=1\nss_m2=0.002\n";
        assert_eq!(parse_part_toml(ok).unwrap().k_coeffs_si, vec![1000.0]);
        let cases = [
            (ok.replace("0.05", "-0.05"), "moving_mass_kg"),
            (ok.replace("[1000.0]", "[]"), "k_coeffs_si"),
            (ok.replace("[1000.0]", "[-5.0]"), "k0"),
            (ok.replace("ss_m2=0.002", "ss_m2=0"), "ss_m2"),
            (ok.replace("r_ns_per_m=1", "r_ns=1"), "r_ns"),
            (
                format!("{ok}[effects.creep]\nk_n_per_m=100\ntau_s=-1\n"),
                "creep.tau_s",
            ),
            (format!("{ok}[effects.warp]\nx=1\n"), "warp"),
            ("name='a'\nmoving_mass_kg=\n".to_string(), "line 2"),
        ];
        for (text, want) in cases {
            let e = parse_part_toml(&text).unwrap_err();
            assert!(e.contains(want), "{want}: {e}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
        let with_fx = format!("{ok}[effects.coulomb_friction]\nforce_n=0.1\n");
        let p = parse_part_toml(&with_fx).unwrap();
        assert_eq!(p.effects.coulomb_friction.unwrap().v_eps_m_per_s, 2e-3);
    }
}
