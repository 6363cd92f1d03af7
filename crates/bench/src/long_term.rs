//! A long-term test on a virtual bench whose part ages (issue 32),
//! accelerated: at every interval the standard procedure is simulated
//! sample by sample (its own sweeps add their load), and the stimulus
//! between two intervals (a sine held at the part's current resonance at a
//! peak displacement) is applied analytically
//! (`physics::ageing::apply_sine`): ten hours of stimulus take seconds.
//! Each interval's recording set says `elapsed_s`, `load_j` and
//! `accelerated: true` in its meta.json.

use crate::procedure::{self, ProcedureConfig};
use crate::virtual_bench::VirtualBench;
use springbench_core::recording::{Meta, RecordingSet};

/// What the test does.
#[derive(Debug, Clone, PartialEq)]
pub struct LongTermPlan {
    /// Length of the test (s).
    pub duration_s: f64,
    /// Time between the starts of two measurements (s).
    pub interval_s: f64,
    /// Peak displacement of the sine stimulus held at resonance (m).
    pub stimulus_xpeak_m: f64,
    /// The measurement at each interval.
    pub procedure: ProcedureConfig,
}

impl LongTermPlan {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.interval_s.is_finite() && self.interval_s >= 60.0) {
            return Err(format!(
                "interval_s must be at least 60 s (a measurement takes about 40 s), got {}",
                self.interval_s
            ));
        }
        if !(self.duration_s.is_finite() && self.duration_s >= self.interval_s) {
            return Err(format!(
                "duration_s must be at least one interval, got {}",
                self.duration_s
            ));
        }
        if !(self.stimulus_xpeak_m.is_finite() && self.stimulus_xpeak_m >= 0.0) {
            return Err(format!(
                "stimulus_xpeak_m must be >= 0 m, got {}",
                self.stimulus_xpeak_m
            ));
        }
        Ok(())
    }

    /// Number of measurements (one at the start and one per interval).
    pub fn intervals(&self) -> usize {
        (self.duration_s / self.interval_s + 1e-9).floor() as usize + 1
    }
}

/// One interval's measurement.
#[derive(Debug, Clone)]
pub struct IntervalMeasured {
    pub index: usize,
    /// Time of the measurement's start since the start of the test (s).
    pub elapsed_s: f64,
    /// Load the part had taken when the measurement started (J).
    pub load_j: f64,
    /// The part's K(0) then (N/m): the truth the fit is judged against.
    pub k0_true_n_per_m: f64,
    /// Pre-measurement and first narrow sweep, meta with elapsed_s, load_j, accelerated.
    pub set: RecordingSet,
    /// Bench time of the measurement (s).
    pub bench_time_s: f64,
}

/// Runs the plan on `vb` (which must age its part: [`VirtualBench::with_ageing`]);
/// `on_interval` receives each measurement as it is made.
pub fn run_accelerated(
    vb: &mut VirtualBench,
    plan: &LongTermPlan,
    on_interval: &mut dyn FnMut(IntervalMeasured) -> Result<(), String>,
) -> Result<(), String> {
    plan.validate()?;
    if vb.ageing_load_j().is_none() {
        return Err("the virtual bench does not age its part (with_ageing)".into());
    }
    let mut cfg = plan.procedure.clone();
    cfg.moving_mass_kg = vb.part.moving_mass_kg;
    struct Quiet;
    impl procedure::Observer for Quiet {}
    let n = plan.intervals();
    for index in 0..n {
        let elapsed_s = index as f64 * plan.interval_s;
        let load_j = vb.ageing_load_j().unwrap_or(0.0);
        let k0_true_n_per_m = vb.k0_now_n_per_m();
        let out = procedure::run(vb, &cfg, &mut Quiet).map_err(|e| e.to_string())?;
        let first = out
            .narrow
            .first()
            .ok_or("the procedure made no narrow sweep")?;
        let mut meta = Meta::standard(vb.part.moving_mass_kg, vb.bench.sample_rate_hz);
        meta.long_term = springbench_core::recording::LongTermStamp {
            accelerated: Some(true),
            elapsed_s: Some(elapsed_s),
            load_j: Some(load_j),
            ..Default::default()
        };
        meta.extra.insert(
            "source".into(),
            serde_json::json!(format!(
                "springbench long-term test (virtual, accelerated), part '{}', interval {index}",
                vb.part.name
            )),
        );
        let set = RecordingSet {
            meta,
            pre: out.pre.clone(),
            main: first.signals.clone(),
        };
        on_interval(IntervalMeasured {
            index,
            elapsed_s,
            load_j,
            k0_true_n_per_m,
            set,
            bench_time_s: out.bench_time_s,
        })?;
        if index + 1 < n {
            let rest = (plan.interval_s - out.bench_time_s).max(0.0);
            vb.apply_sine_load(plan.stimulus_xpeak_m, rest);
        }
    }
    Ok(())
}
