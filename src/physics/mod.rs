//! Physics simulation of the pneumatic bench (the virtual bench). Pure: no I/O
//! (presets are compiled in with `include_str!`; reading a user's TOML file is
//! the caller's job).
//!
//! CONTRACT shared with the daemon (owned by the virtual-bench work):
//! `PartSpec`, `preset`, `preset_names`, `parse_part_toml`, `VirtualBench::new`.

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
}

/// Names of the built-in part presets.
pub fn preset_names() -> Vec<&'static str> {
    Vec::new()
}

/// A built-in preset by name.
pub fn preset(name: &str) -> Result<PartSpec, String> {
    Err(format!("unknown preset '{name}'"))
}

/// Parses a part description in the presets' TOML format.
pub fn parse_part_toml(_text: &str) -> Result<PartSpec, String> {
    Err("part TOML not implemented yet".into())
}

/// Fast offline path: runs the standard procedure on a [`VirtualBench`] with
/// `part` and returns the recording set (pre + first narrow sweep) that
/// `analyze` reads. Used by `simulate`, the tests and the diagnostics suite.
pub fn simulate_recording_set(
    _part: &PartSpec,
    _seed: u64,
) -> Result<crate::recording::RecordingSet, String> {
    Err("simulation not implemented yet".into())
}

/// The virtual bench: implements [`crate::bench::Bench`].
pub struct VirtualBench {
    pub part: PartSpec,
    pub seed: u64,
}

impl VirtualBench {
    pub fn new(part: PartSpec, seed: u64) -> VirtualBench {
        VirtualBench { part, seed }
    }
}
