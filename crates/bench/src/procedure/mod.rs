//! The standard measurement procedure as steps with parameters (data), run on
//! any [`Bench`]: (1) pre-measurement: wide-band low-level sweep with a level
//! check, (2) resonance search with rising sweeps, (3) narrow rising sweep
//! through the large-signal resonance, per target Xpeak. The fit (4) is done
//! by the caller with [`springbench_core::identify`].
//!
//! The production procedure ([`run_production`], `production.rs`) replaces
//! (1)-(3) by a short pre-measurement and one short narrow sweep per level at
//! what golden units established, and falls back to [`run`] when the part is
//! too far from them.
//!
//! Used by `springbench simulate` and by the daemon's runner alike.
//! CONTRACT (owned by the virtual-bench work): types and `run` signature are
//! shared with the daemon; change them only together.

use serde::{Deserialize, Serialize};
use springbench_core::recording::Signals;

/// Parameters of the whole procedure (stored with each measurement: its
/// type lives in the core, `springbench_core::job::ProcedureConfig`).
pub use springbench_core::job::ProcedureConfig;

/// Which step is running.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    PreMeasurement,
    ResonanceSearch,
    NarrowSweep,
    Fit,
}

/// Everything the procedure measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The small-signal sweep that was kept (after the level check).
    pub pre: Signals,
    /// The stimulus of `pre`.
    pub pre_sweep: SweepSpec,
    /// Small-signal resonance read off the pre-measurement (peak of |X/Mic|, Hz).
    pub f0_hz: f64,
    /// Quality of the drive-to-displacement response |X/U| around the
    /// resonance in the pre-measurement (its peak frequency over its
    /// half-power bandwidth): with the exciter and the box it differs from
    /// the part's Q, and it sets how far a short sweep builds up the
    /// resonance. None when the sweep did not reach both half-power points.
    pub pre_q_drive_to_x: Option<f64>,
    /// One narrow sweep per requested level, in the order of `levels_m`,
    /// except those the observer took as they finished
    /// ([`Observer::narrow_finished`]).
    pub narrow: Vec<NarrowSweep>,
    /// Stimulus time a real bench would need for all sweeps played, searches included (s).
    pub bench_time_s: f64,
    /// Human-readable log of the decisions taken (levels, resonances found).
    pub log: Vec<String>,
    /// Set when the production procedure ran (None: the full procedure was asked for).
    pub production: Option<ProductionRun>,
}

/// How a production run went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProductionRun {
    /// Why the part fell back to the full procedure (one line); None when the
    /// short procedure measured it.
    pub fallback: Option<String>,
    /// Bench time spent in the short procedure before a fall-back (s); the
    /// whole run's is `Outcome::bench_time_s`.
    pub short_bench_time_s: f64,
}

#[derive(Debug, Clone)]
pub struct NarrowSweep {
    pub target_xpeak_m: f64,
    /// Drive amplitude used (V).
    pub drive_v: f64,
    pub f_start_hz: f64,
    pub f_end_hz: f64,
    /// The complete stimulus.
    pub sweep: SweepSpec,
    /// Large-signal resonance found in the sweep (peak of |X/Mic| of the fundamental, Hz).
    pub resonance_hz: f64,
    /// Largest |x| of the sweep (m).
    pub xpeak_m: f64,
    pub signals: Signals,
    /// Set when the target was not reached within the limits: both figures
    /// and which limit held the level down (one line, for the result and the job).
    pub warning: Option<String>,
}

/// Receives progress while the procedure runs. Default methods ignore everything.
pub trait Observer {
    /// A step started or progressed; `progress` is the fraction of the whole procedure done (0..1),
    /// `eta_s` the estimated bench time left (s).
    fn progress(&mut self, _step: Step, _progress: f64, _eta_s: f64) {}
    /// Live samples during a sweep (for decimated streaming).
    fn samples(&mut self, _step: Step, _block: crate::Block<'_>) {}
    /// Polled between blocks; true aborts the procedure (cancel, shutdown).
    fn cancelled(&self) -> bool {
        false
    }
    /// The narrow sweep of level `index` (of `levels_m`) is final; levels
    /// come in order, each once. The default keeps it in
    /// [`Outcome::narrow`]. An observer that stores each level as it
    /// finishes takes it (answers `Ok(None)`): a long level series then holds
    /// one level's samples at a time, and what was measured survives a cancel
    /// or a crash. `bench` played it (its run records); an error ends the
    /// procedure with it.
    fn narrow_finished(
        &mut self,
        _bench: &dyn crate::Bench,
        _pre: &PreMeasured<'_>,
        _index: usize,
        sweep: NarrowSweep,
    ) -> Result<Option<NarrowSweep>, ProcedureError> {
        Ok(Some(sweep))
    }
}

/// The kept pre-measurement, as each level's narrow sweep is handed out.
pub struct PreMeasured<'a> {
    pub signals: &'a Signals,
    pub sweep: &'a SweepSpec,
    /// Small-signal resonance (Hz), as [`Outcome::f0_hz`].
    pub f0_hz: f64,
    /// As [`Outcome::pre_q_drive_to_x`].
    pub q_drive_to_x: Option<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum ProcedureError {
    #[error("cancelled")]
    Cancelled,
    #[error("invalid procedure configuration: {0}")]
    Invalid(String),
    #[error("bench: {0}")]
    Bench(#[from] crate::BenchError),
    #[error("{0}")]
    Failed(String),
}

pub mod break_in;
pub mod memory;
pub mod pace;
pub mod production;
mod run;
pub mod sweep;
pub mod waveform;
pub use break_in::{break_in, hold_at_resonance, BreakIn, BreakInDone};
pub use production::run_production;
pub use run::run;
pub use sweep::SweepSpec;
