//! Physical effects beyond the basic force balance
//! `m x'' + R x' + K(x) x = Ss p`: ids, parameters and meanings shared by the
//! virtual bench (which simulates them) and the diagnostics (which fits them).
//!
//! Every effect is an extra force `F_e` on the part, opposing like the
//! suspension does: `m x'' = Ss p - R x' - K(x) x - F_e`, except
//! `channel_delay`, which acts on the microphone signal. Time `t` counts from
//! the first sample of the recording.
//!
//! JSON form (the same in `truth.json`, job bodies, part TOML and results):
//! `{"coulomb_friction": {"force_n": 0.15, "v_eps_m_per_s": 0.002}, "creep": {"k_n_per_m": 300, "tau_s": 0.05}}`.

use serde::{Deserialize, Serialize};

/// Identifier of an effect, as used in JSON and on the command line.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum EffectId {
    CoulombFriction,
    QuadraticDamping,
    DampingVsDisplacement,
    Creep,
    StiffnessDrift,
    ChannelDelay,
    Hysteresis,
    ReversibleSoftening,
}

impl EffectId {
    pub const ALL: [EffectId; 8] = [
        EffectId::CoulombFriction,
        EffectId::QuadraticDamping,
        EffectId::DampingVsDisplacement,
        EffectId::Creep,
        EffectId::StiffnessDrift,
        EffectId::ChannelDelay,
        EffectId::Hysteresis,
        EffectId::ReversibleSoftening,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            EffectId::CoulombFriction => "coulomb_friction",
            EffectId::QuadraticDamping => "quadratic_damping",
            EffectId::DampingVsDisplacement => "damping_vs_displacement",
            EffectId::Creep => "creep",
            EffectId::StiffnessDrift => "stiffness_drift",
            EffectId::ChannelDelay => "channel_delay",
            EffectId::Hysteresis => "hysteresis",
            EffectId::ReversibleSoftening => "reversible_softening",
        }
    }

    /// Parses an id; the error lists the known ids.
    pub fn parse(s: &str) -> Result<EffectId, String> {
        EffectId::ALL
            .into_iter()
            .find(|e| e.as_str() == s)
            .ok_or_else(|| {
                let known: Vec<&str> = EffectId::ALL.iter().map(|e| e.as_str()).collect();
                format!("unknown effect '{s}' (known: {})", known.join(", "))
            })
    }

    /// Names of the parameters, in SI with the unit in the name. The first
    /// ones are linear in the force balance; hyper-parameters (tau, eps,
    /// delay) are searched on a grid by the diagnostics.
    pub fn parameter_names(self) -> &'static [&'static str] {
        match self {
            EffectId::CoulombFriction => &["force_n", "v_eps_m_per_s"],
            EffectId::QuadraticDamping => &["coeff_ns2_per_m2"],
            EffectId::DampingVsDisplacement => &["r1_ns_per_m2", "r2_ns_per_m3"],
            EffectId::Creep => &["k_n_per_m", "tau_s"],
            EffectId::StiffnessDrift => &["dk0_dt_n_per_m_s"],
            EffectId::ChannelDelay => &["delay_s"],
            EffectId::Hysteresis => &["k_n_per_m", "x_yield_m"],
            EffectId::ReversibleSoftening => &["depth_n_per_m2", "tau_s"],
        }
    }

    /// The force law, one line.
    pub fn form(self) -> &'static str {
        match self {
            EffectId::CoulombFriction => "F = force_n * tanh(v / v_eps_m_per_s)",
            EffectId::QuadraticDamping => "F = coeff_ns2_per_m2 * v * |v|",
            EffectId::DampingVsDisplacement => "F = (r1_ns_per_m2 * x + r2_ns_per_m3 * x^2) * v",
            EffectId::Creep => "F = k_n_per_m * (x - xr), xr' = (x - xr) / tau_s",
            EffectId::StiffnessDrift => "F = dk0_dt_n_per_m_s * t * x",
            EffectId::ChannelDelay => "mic(t) = g * p(t - delay_s)",
            EffectId::Hysteresis => {
                "F = k_n_per_m * z, z' = v (1 - |z| / x_yield_m) while v z > 0, z' = v otherwise (Bouc-Wen, n = 1)"
            }
            EffectId::ReversibleSoftening => {
                "F = -depth_n_per_m2 * s * x * max(0, 1 - x^2 / s^2), s = max(|x|, s decaying with tau_s) (the recent excursion)"
            }
        }
    }

    /// One paragraph of physics: what the effect is and why it happens.
    pub fn explanation(self) -> &'static str {
        match self {
            EffectId::CoulombFriction => {
                "Dry (Coulomb) friction of the slide on its guide rod: a force of constant size opposing the \
                 motion, independent of speed. At small drive levels the slide sticks and the part does not move \
                 like a linear resonator; at large levels it adds a loss that does not grow with velocity."
            }
            EffectId::QuadraticDamping => {
                "Velocity-squared damping: air forced through the porous part or past the clamps turns turbulent \
                 at high speed, so the loss grows with v|v|. The apparent resistance R rises with amplitude."
            }
            EffectId::DampingVsDisplacement => {
                "Displacement-dependent damping: the material losses of the suspension change as it is stretched, \
                 so R depends on x (an odd term r1 x for asymmetric parts, an even term r2 x^2 for symmetric ones)."
            }
            EffectId::Creep => {
                "Creep (viscoelasticity) of the suspension material, modelled as a standard linear solid: a spring \
                 k in series with a dashpot k*tau, in parallel with K(x). The part is stiffer at high than at low \
                 frequencies, and the loss is not proportional to velocity."
            }
            EffectId::StiffnessDrift => {
                "Stiffness drift: K(0) changes during the measurement (break-in of a new part, warming, humidity), \
                 so the same displacement needs a different force at the end of the sweep than at the start."
            }
            EffectId::ChannelDelay => {
                "Channel delay: the microphone path is later than the laser path (different converters, filters \
                 or a laser with internal averaging), which shifts force against displacement in phase and looks \
                 like damping of the wrong size, different below and above resonance."
            }
            EffectId::Hysteresis => {
                "Hysteresis of rubber or impregnated fabric (plastic flow): a spring k in series with a slider \
                 that starts to yield softly at the excursion x_yield (Bouc-Wen with n = 1, elasto-plastic in \
                 the limit). The force-displacement loop does not depend on frequency; it gives odd harmonics \
                 even where the elastic K(x) is linear, and a stiffness that falls with amplitude."
            }
            EffectId::ReversibleSoftening => {
                "Reversible softening (paper section 6.1, Fig. 22): after a large excursion the part is softer \
                 between the excursion maxima. K(0) drops in proportion to the recent peak excursion s while K \
                 at the peaks stays; s decays with tau_s (seconds), so the part recovers when left alone. Keff \
                 and the resonance fall with rising level at small amplitude."
            }
        }
    }

    /// Where it shows in the comparison of model and measurement.
    pub fn signature(self) -> &'static str {
        match self {
            EffectId::CoulombFriction => "a step of the residual at v = 0 (residual against v, split by sign); the small-signal sweep sticks",
            EffectId::QuadraticDamping => "residual against v grows like v|v|; apparent R grows with amplitude",
            EffectId::DampingVsDisplacement => "residual depends on x and v together (residual against x differs for v > 0 and v < 0)",
            EffectId::Creep => "small-signal Hx deviates from 2nd order below resonance; residual in phase with a low-pass of x",
            EffectId::StiffnessDrift => "residual grows over time, in phase with x; K(0) differs between the start and end of the record",
            EffectId::ChannelDelay => "residual in phase with the derivative of the microphone signal; damping below and above resonance disagree",
            EffectId::Hysteresis => "H3 grows like X and lies in quadrature with the fundamental (a cubic K(x) term: like X^2, in phase; friction: falls with X); the loss per cycle does not depend on frequency",
            EffectId::ReversibleSoftening => "K(0) follows the recent excursion, not the clock: lower after the resonance's large excursion, recovering within seconds; K(0) falls with level in a level series",
        }
    }
}

impl std::fmt::Display for EffectId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Dry friction of the slide, smoothed: `F = force_n tanh(v / v_eps_m_per_s)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CoulombFriction {
    pub force_n: f64,
    /// Smoothing velocity (m/s); `v_eps` is accepted as in the reference recordings' truth.json.
    #[serde(default = "default_v_eps", alias = "v_eps")]
    pub v_eps_m_per_s: f64,
}

fn default_v_eps() -> f64 {
    2e-3
}

/// `F = coeff_ns2_per_m2 v |v|`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct QuadraticDamping {
    pub coeff_ns2_per_m2: f64,
}

/// `F = (r1_ns_per_m2 x + r2_ns_per_m3 x^2) v`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DampingVsDisplacement {
    #[serde(default)]
    pub r1_ns_per_m2: f64,
    #[serde(default)]
    pub r2_ns_per_m3: f64,
}

/// Standard linear solid: `F = k_n_per_m (x - xr)`, `xr' = (x - xr) / tau_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Creep {
    pub k_n_per_m: f64,
    pub tau_s: f64,
}

/// `F = dk0_dt_n_per_m_s t x` (K(0) changes linearly with time).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StiffnessDrift {
    pub dk0_dt_n_per_m_s: f64,
}

/// Microphone later than the laser by `delay_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ChannelDelay {
    pub delay_s: f64,
}

/// Hysteresis (Bouc-Wen, n = 1): `F = k_n_per_m z`, `z' = v (1 - |z| / x_yield_m)`
/// while `v z > 0`, `z' = v` otherwise (physics: `physics::memory`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Hysteresis {
    pub k_n_per_m: f64,
    pub x_yield_m: f64,
}

/// Reversible softening: `F = -depth_n_per_m2 s x max(0, 1 - x^2 / s^2)` with
/// `s` the recent peak excursion, decaying with `tau_s` (physics: `physics::memory`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReversibleSoftening {
    pub depth_n_per_m2: f64,
    pub tau_s: f64,
}

/// A set of effects, at most one of each kind. Serialises as a JSON object
/// keyed by effect id; absent effects are omitted.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coulomb_friction: Option<CoulombFriction>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quadratic_damping: Option<QuadraticDamping>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping_vs_displacement: Option<DampingVsDisplacement>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub creep: Option<Creep>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness_drift: Option<StiffnessDrift>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel_delay: Option<ChannelDelay>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hysteresis: Option<Hysteresis>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reversible_softening: Option<ReversibleSoftening>,
}

impl Effects {
    /// The ids of the effects present.
    pub fn ids(&self) -> Vec<EffectId> {
        EffectId::ALL
            .into_iter()
            .filter(|&id| self.has(id))
            .collect()
    }

    pub fn has(&self, id: EffectId) -> bool {
        match id {
            EffectId::CoulombFriction => self.coulomb_friction.is_some(),
            EffectId::QuadraticDamping => self.quadratic_damping.is_some(),
            EffectId::DampingVsDisplacement => self.damping_vs_displacement.is_some(),
            EffectId::Creep => self.creep.is_some(),
            EffectId::StiffnessDrift => self.stiffness_drift.is_some(),
            EffectId::ChannelDelay => self.channel_delay.is_some(),
            EffectId::Hysteresis => self.hysteresis.is_some(),
            EffectId::ReversibleSoftening => self.reversible_softening.is_some(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.ids().is_empty()
    }

    /// The parameters of effect `id` as (name, SI value), in the order of
    /// [`EffectId::parameter_names`]; None when the effect is absent.
    pub fn parameters(&self, id: EffectId) -> Option<Vec<(&'static str, f64)>> {
        let values = match id {
            EffectId::CoulombFriction => self
                .coulomb_friction
                .map(|e| vec![e.force_n, e.v_eps_m_per_s]),
            EffectId::QuadraticDamping => self.quadratic_damping.map(|e| vec![e.coeff_ns2_per_m2]),
            EffectId::DampingVsDisplacement => self
                .damping_vs_displacement
                .map(|e| vec![e.r1_ns_per_m2, e.r2_ns_per_m3]),
            EffectId::Creep => self.creep.map(|e| vec![e.k_n_per_m, e.tau_s]),
            EffectId::StiffnessDrift => self.stiffness_drift.map(|e| vec![e.dk0_dt_n_per_m_s]),
            EffectId::ChannelDelay => self.channel_delay.map(|e| vec![e.delay_s]),
            EffectId::Hysteresis => self.hysteresis.map(|e| vec![e.k_n_per_m, e.x_yield_m]),
            EffectId::ReversibleSoftening => self
                .reversible_softening
                .map(|e| vec![e.depth_n_per_m2, e.tau_s]),
        }?;
        Some(id.parameter_names().iter().copied().zip(values).collect())
    }

    /// These effects with each one `over` has replaced by `over`'s.
    pub fn overlaid_with(&self, over: &Effects) -> Effects {
        Effects {
            coulomb_friction: over.coulomb_friction.or(self.coulomb_friction),
            quadratic_damping: over.quadratic_damping.or(self.quadratic_damping),
            damping_vs_displacement: over
                .damping_vs_displacement
                .or(self.damping_vs_displacement),
            creep: over.creep.or(self.creep),
            stiffness_drift: over.stiffness_drift.or(self.stiffness_drift),
            channel_delay: over.channel_delay.or(self.channel_delay),
            hysteresis: over.hysteresis.or(self.hysteresis),
            reversible_softening: over.reversible_softening.or(self.reversible_softening),
        }
    }

    /// Checks that parameters are finite and physically possible; one-line error naming the field.
    pub fn validate(&self) -> Result<(), String> {
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("effects.{name} must be finite, got {v}"))
            }
        };
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("effects.{name} must be > 0, got {v}"))
            }
        };
        let non_negative = |name: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(format!("effects.{name} must be >= 0, got {v}"))
            }
        };
        if let Some(e) = &self.coulomb_friction {
            non_negative("coulomb_friction.force_n", e.force_n)?;
            positive("coulomb_friction.v_eps_m_per_s", e.v_eps_m_per_s)?;
        }
        if let Some(e) = &self.quadratic_damping {
            non_negative("quadratic_damping.coeff_ns2_per_m2", e.coeff_ns2_per_m2)?;
        }
        if let Some(e) = &self.damping_vs_displacement {
            finite("damping_vs_displacement.r1_ns_per_m2", e.r1_ns_per_m2)?;
            finite("damping_vs_displacement.r2_ns_per_m3", e.r2_ns_per_m3)?;
        }
        if let Some(e) = &self.creep {
            non_negative("creep.k_n_per_m", e.k_n_per_m)?;
            positive("creep.tau_s", e.tau_s)?;
        }
        if let Some(e) = &self.stiffness_drift {
            finite("stiffness_drift.dk0_dt_n_per_m_s", e.dk0_dt_n_per_m_s)?;
        }
        if let Some(e) = &self.hysteresis {
            non_negative("hysteresis.k_n_per_m", e.k_n_per_m)?;
            positive("hysteresis.x_yield_m", e.x_yield_m)?;
        }
        if let Some(e) = &self.reversible_softening {
            non_negative("reversible_softening.depth_n_per_m2", e.depth_n_per_m2)?;
            positive("reversible_softening.tau_s", e.tau_s)?;
        }
        if let Some(e) = &self.channel_delay {
            non_negative("channel_delay.delay_s", e.delay_s)?;
            if e.delay_s > 0.1 {
                return Err(format!(
                    "effects.channel_delay.delay_s must be at most 0.1 s, got {}",
                    e.delay_s
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_reference_truth_form_and_round_trips() {
        let e: Effects =
            serde_json::from_str(r#"{"coulomb_friction": {"force_n": 0.15, "v_eps": 0.002}}"#)
                .unwrap();
        assert_eq!(e.coulomb_friction.unwrap().force_n, 0.15);
        assert_eq!(e.coulomb_friction.unwrap().v_eps_m_per_s, 0.002);
        assert_eq!(e.ids(), vec![EffectId::CoulombFriction]);
        let back: Effects = serde_json::from_str(&serde_json::to_string(&e).unwrap()).unwrap();
        assert_eq!(back, e);
        assert!(serde_json::from_str::<Effects>(r#"{"unknown_effect": {}}"#).is_err());
        assert!(
            serde_json::from_str::<Effects>(r#"{"creep": {"k_n_per_m": 1, "tau": 2}}"#).is_err()
        );
    }

    #[test]
    fn ids_parse_and_validate() {
        for id in EffectId::ALL {
            assert_eq!(EffectId::parse(id.as_str()).unwrap(), id);
            assert_eq!(serde_json::to_value(id).unwrap(), id.as_str());
        }
        assert!(EffectId::parse("friction")
            .unwrap_err()
            .contains("coulomb_friction"));
        let e = Effects {
            creep: Some(Creep {
                k_n_per_m: 100.0,
                tau_s: 0.0,
            }),
            ..Default::default()
        };
        assert!(e.validate().unwrap_err().contains("creep.tau_s"));
    }
}
