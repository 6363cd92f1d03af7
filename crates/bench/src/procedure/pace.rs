//! [`Paced`]: any bench held to real time. The virtual bench computes a
//! sweep as fast as the CPU allows; wrapped, each captured block is handed on
//! no earlier than the moment its last sample would have left a converter
//! running at the bench's sample rate, so a procedure takes the wall time a
//! real bench would (throughput measurements). A bench that is already
//! paced by its device (hardware) gains nothing but also loses nothing.

use crate::{Bench, BenchError, Block, Control, Limits};
use springbench_core::recording::Signals;
use std::time::{Duration, Instant};

/// A bench whose sweeps take at least their signal's duration of wall time.
pub struct Paced<B: Bench> {
    pub inner: B,
}

impl<B: Bench> Paced<B> {
    pub fn new(inner: B) -> Paced<B> {
        Paced { inner }
    }
}

impl<B: Bench> Bench for Paced<B> {
    fn id(&self) -> &str {
        self.inner.id()
    }
    fn sample_rate_hz(&self) -> f64 {
        self.inner.sample_rate_hz()
    }
    fn limits(&self) -> Limits {
        self.inner.limits()
    }
    fn describe(&self) -> String {
        format!("{} (paced in real time)", self.inner.describe())
    }
    fn run_records(&self) -> Vec<serde_json::Value> {
        self.inner.run_records()
    }
    fn resolution(&self) -> Option<springbench_recording::codec::Resolution> {
        self.inner.resolution()
    }
    fn run(
        &mut self,
        drive_v: &[f64],
        observer: &mut dyn FnMut(Block<'_>) -> Control,
    ) -> Result<Signals, BenchError> {
        let fs = self.inner.sample_rate_hz();
        let start = Instant::now();
        let mut paced = |b: Block<'_>| {
            let due = (b.start_sample + b.displacement_m.len()) as f64 / fs;
            let now = start.elapsed().as_secs_f64();
            if due > now {
                std::thread::sleep(Duration::from_secs_f64(due - now));
            }
            observer(b)
        };
        let out = self.inner.run(drive_v, &mut paced);
        // The capture ends with the last block (an abort's ramp included).
        if let Ok(s) = &out {
            let due = s.len() as f64 / fs;
            let now = start.elapsed().as_secs_f64();
            if due > now {
                std::thread::sleep(Duration::from_secs_f64(due - now));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_bench::VirtualBench;

    #[test]
    fn a_paced_sweep_takes_its_duration() {
        let part = springbench_core::physics::preset("spider_4in").unwrap();
        let mut b = Paced::new(VirtualBench::new(part, 1));
        let fs = b.sample_rate_hz();
        let drive = vec![0.0; (0.3 * fs) as usize];
        let t = Instant::now();
        let s = b.run(&drive, &mut |_| Control::Continue).unwrap();
        assert_eq!(s.len(), drive.len());
        // never earlier than the signal's duration (a lower bound only: no timing upper bound)
        assert!(t.elapsed().as_secs_f64() >= 0.3);
    }
}
