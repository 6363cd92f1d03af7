//! Measurement: the device seam, the benches behind it, and the procedure
//! that drives them.
//!
//! A bench plays an exciter drive signal and captures the laser displacement
//! and the microphone, block by block like an audio callback ([`Bench`]). The
//! virtual bench ([`virtual_bench`], the physics model of `springbench-core`
//! behind the device interface) and the hardware bench ([`hardware`], feature
//! `hardware`) implement the same trait, so the measurement [`procedure`]
//! does not know which one it drives; [`simulate`] runs it offline.
//!
//! Invariant: synchronous and blocking by design: the daemon runs a bench on
//! a blocking thread it owns; nothing here is async (the serial laser's
//! emulator runs its own small runtime on its own thread), nothing here
//! stores or serves. Depends on `springbench-core` and
//! `springbench-recording`, never on the store or the daemon.

use springbench_core::recording::Signals;

pub mod align;
#[cfg(feature = "hardware")]
pub mod audio;
#[cfg(feature = "hardware")]
pub mod emulator;
#[cfg(feature = "hardware")]
pub mod hardware;
pub mod laser;
pub mod long_term;
pub mod procedure;
pub mod settings;
pub mod simulate;
pub mod true_part;
pub mod truth;
pub mod virtual_bench;

/// Hard limits of a bench; a procedure never exceeds them (defined with the
/// job specification, which a job's tighter limits are part of).
pub use springbench_core::job::Limits;

/// One captured block, handed to the observer while a sweep runs.
#[derive(Debug, Clone, Copy)]
pub struct Block<'a> {
    /// Index of the first sample of the block within the sweep.
    pub start_sample: usize,
    pub displacement_m: &'a [f64],
    pub microphone_v: &'a [f64],
    pub drive_v: &'a [f64],
}

/// What the observer wants after a block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    Continue,
    /// Ramp the drive down and stop (cancel, shutdown, limit exceeded).
    Abort,
}

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("aborted")]
    Aborted,
    #[error("laser out of range at t = {t_s:.3} s")]
    LaserOutOfRange { t_s: f64 },
    #[error("device error: {0}")]
    Device(String),
    /// A hardware bench stopped for safety (limit, device error, laser fault):
    /// the drive was ramped to zero; the bench is faulted until a self-check passes.
    #[error("bench fault: {0}")]
    Fault(String),
}

/// A measurement bench: exciter output, microphone and laser input.
pub trait Bench: Send {
    /// Stable identifier (shown in /readyz and stored with measurements).
    fn id(&self) -> &str;
    fn sample_rate_hz(&self) -> f64;
    fn limits(&self) -> Limits;
    /// Plays `drive_v` (amplifier output, V) from rest and captures all
    /// channels for exactly `drive_v.len()` samples. `observer` sees every
    /// block as it is captured; `Control::Abort` ramps the drive down within
    /// a few milliseconds and returns `BenchError::Aborted`.
    fn run(
        &mut self,
        drive_v: &[f64],
        observer: &mut dyn FnMut(Block<'_>) -> Control,
    ) -> Result<Signals, BenchError>;
    /// Short human-readable description (preset, part, device names).
    fn describe(&self) -> String;
    /// What each sweep so far measured about the bench itself (hardware:
    /// latency, loopback, alignment), oldest first, each with its `frames`.
    fn run_records(&self) -> Vec<serde_json::Value> {
        Vec::new()
    }
    /// The resolution every captured sample is on (converter bits and full
    /// scale per channel); the store keeps recordings exactly at it (FLAC).
    /// `None`: unknown, stored as float32 WAV (decision 0013).
    fn resolution(&self) -> Option<springbench_recording::codec::Resolution> {
        None
    }
    /// What the last run captured before a fault ended it ([`BenchError::Fault`]),
    /// in drive time, handed out once; None when the last run did not
    /// fault or the bench keeps nothing (a long-term test stores its last
    /// seconds, issue 32).
    fn take_fault_signals(&mut self) -> Option<Signals> {
        None
    }
}
