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

#[cfg(test)]
mod tests {
    use crate::virtual_bench::VirtualBench;
    use crate::{Bench, Control};
    use springbench_core::physics::ageing::AgeingParams;
    use springbench_core::physics::waveform::{self, LoopLoad};
    use springbench_core::physics::{preset, BenchParams, PartSpec};

    fn part(k_lost: [f64; 2]) -> PartSpec {
        let mut p = preset("spider_3in").unwrap();
        p.ageing = Some(AgeingParams {
            break_in_k_n_per_m: k_lost[0],
            break_in_load_j: 50.0,
            fatigue_k_n_per_m: k_lost[1],
            fatigue_load_j: 2000.0,
            width_m: 0.004,
            collapse: None,
        });
        p
    }

    /// The load the virtual bench accrues sample by sample playing `drive`.
    fn played(vb: &mut VirtualBench, drive: &[f64]) -> f64 {
        let e0 = vb.ageing_load_j().unwrap();
        vb.run(drive, &mut |_| Control::Continue).unwrap();
        vb.ageing_load_j().unwrap() - e0
    }

    #[test]
    fn a_noise_loops_accelerated_load_is_the_sample_by_sample_load() {
        // Known truth: the virtual bench's own sample-by-sample load (the
        // load measure accrued after every sample, its sensors and all) of
        // the noise loop played 20 times at one gain, on a hardening part
        // whose stiffness does not depend on the load (ageing parameters
        // that remove nothing): the accelerated path's rate times 20 s.
        let p = part([0.0, 0.0]);
        let b = BenchParams::default();
        let w = waveform::noise_loop(b.sample_rate_hz, [20.0, 200.0], 1.0, waveform::NOISE_SEED)
            .unwrap();
        let r = waveform::level(&p, &b, 0.0, &w, 0.0015, 1.0, 100.0);
        assert!((r.x_rms_m / 0.0015 - 1.0).abs() < 0.02, "{r:?}");
        // The bench starts from rest: 20 loops less 10 loops is 10 steady loops.
        let loops = |n: usize| -> Vec<f64> {
            (0..n)
                .flat_map(|_| w.iter().map(|u| r.gain_v * u))
                .collect()
        };
        let sim = played(
            &mut VirtualBench::new(p.clone(), 3).with_ageing(0.0),
            &loops(20),
        ) - played(
            &mut VirtualBench::new(p.clone(), 3).with_ageing(0.0),
            &loops(10),
        );
        let acc = r.load_rate_w * 10.0;
        let rel = acc / sim - 1.0;
        println!("constant part: sample by sample {sim} J, accelerated {acc} J ({rel:+.6})");
        assert!(rel.abs() < 1e-4, "{sim} {acc}");
        // The accelerated path levels at the target and scales the rate to it (∝ level²).
        let mut l = LoopLoad::new(w.clone());
        let mut vb = VirtualBench::new(p, 3).with_ageing(0.0);
        let e = vb.apply_loop_load(&mut l, 0.0015, 10.0);
        let want = acc * (0.0015 / r.x_rms_m).powi(2);
        println!("levelled at the target: {e} J, scaled {want} J");
        assert!((e / want - 1.0).abs() < 2e-3, "{e} {want}");
        assert_eq!(l.evaluations, 1);
    }

    #[test]
    fn an_ageing_parts_accelerated_noise_load_follows_the_sample_by_sample_load() {
        // The part breaks in (200 N/m over 50 J) while the noise is held at
        // 1.5 mm RMS. Sample by sample: 60 s of the loop in one run, each
        // 1-s loop's gain levelled for 1.5 mm on the part as the
        // accelerated path has it then (its load at that time). When the
        // accelerated load is right, the run's own load agrees with it.
        let p = part([200.0, 500.0]);
        let b = BenchParams::default();
        let w = waveform::noise_loop(b.sample_rate_hz, [20.0, 200.0], 1.0, waveform::NOISE_SEED)
            .unwrap();
        let mut l = LoopLoad::new(w.clone());
        let mut va = VirtualBench::new(p.clone(), 5).with_ageing(0.0);
        let mut drive = Vec::with_capacity(60 * w.len());
        let mut g = 1.0;
        for _ in 0..60 {
            let e = va.ageing_load_j().unwrap();
            let r = waveform::level(&p, &b, e, &w, 0.0015, g, 100.0);
            g = r.gain_v;
            // Levelled within 2 %; the accelerated rate is scaled to the
            // target (∝ level²), the drive here to the target (∝ level).
            let exact = g * 0.0015 / r.x_rms_m;
            drive.extend(w.iter().map(|u| exact * u));
            va.apply_loop_load(&mut l, 0.0015, 1.0);
        }
        let acc = va.ageing_load_j().unwrap();
        let sim = played(
            &mut VirtualBench::new(p.clone(), 5).with_ageing(0.0),
            &drive,
        );
        let rel = acc / sim - 1.0;
        let k0 = |e: f64| p.ageing.unwrap().k0_n_per_m(p.k_coeffs_si[0], e);
        println!(
            "ageing part: sample by sample {sim} J, accelerated {acc} J ({rel:+.4}), {} evaluations, K(0) {} -> {} N/m",
            l.evaluations,
            k0(0.0),
            k0(acc)
        );
        assert!(k0(acc) < k0(0.0) - 50.0);
        assert!(rel.abs() < 5e-3, "{sim} {acc}");
    }
}
