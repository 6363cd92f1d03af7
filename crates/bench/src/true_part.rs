//! The true load of an emulated part that ages (issue 32, decision 0135),
//! shared between the bench emulator, which ages the part with it sample
//! by sample (`physics::ageing::AgeingStep`, as the virtual bench does),
//! and the long-term test's runner, which hands it to the emulator when it
//! opens the bench, reads it at every interval (the emulated part's truth)
//! and stores it with the test's state, so that a test resumed after a
//! restart of the daemon hands it on to the new emulator.
//!
//! Not behind the `hardware` feature: the runner holds one either way. A
//! real bench has no such thing (its part ages by itself, its truth is
//! unknown).

use std::sync::{Arc, Mutex};

/// The load an emulated part has truly taken (J), shared.
#[derive(Debug, Clone, Default)]
pub struct TrueLoad(Arc<Mutex<f64>>);

impl TrueLoad {
    /// A part that has taken `load_j` (J) before (0: a new part).
    pub fn new(load_j: f64) -> TrueLoad {
        TrueLoad(Arc::new(Mutex::new(load_j.max(0.0))))
    }

    /// The load so far (J).
    pub fn get(&self) -> f64 {
        *self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn set(&self, load_j: f64) {
        *self.0.lock().unwrap_or_else(|p| p.into_inner()) = load_j;
    }
}
