//! Issue 24: what a level series holds in memory, counted by a global
//! allocator (bytes live on this thread and their peak), not sampled from
//! the process: a few seconds, in the default suite. The daemon's whole
//! 16-level x 10-repeat series is `a_16_by_10_series_stays_below_150_mb_and_keeps_its_levels`
//! in `tests/it/qc_faults.rs` (`#[ignore]`, minutes).

use springbench::bench::virtual_bench::VirtualBench;
use springbench::bench::{Bench, BenchError, Block, Control, Limits};
use springbench::identify::{self, AnalyzeOptions, ForceBalanceData};
use springbench::physics::preset;
use springbench::procedure::{
    run, NarrowSweep, Observer, PreMeasured, ProcedureConfig, ProcedureError,
};
use springbench::recording::Signals;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// Counts the bytes allocated and freed on each thread (a test runs on one).
struct Counting;

thread_local! {
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn add(d: isize) {
    // `try_with`: the thread's counters may be gone while it exits.
    let _ = LIVE.try_with(|l| {
        let v = l.get() + d;
        l.set(v);
        let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
    });
}

// SAFETY: every call is passed to the system allocator unchanged; the
// counters are thread-local cells that never allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = System.alloc(l);
        if !p.is_null() {
            add(l.size() as isize);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(l);
        if !p.is_null() {
            add(l.size() as isize);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l);
        add(-(l.size() as isize));
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        let q = System.realloc(p, l, new);
        if !q.is_null() {
            add(new as isize - l.size() as isize);
        }
        q
    }
}

#[global_allocator]
static A: Counting = Counting;

fn live() -> isize {
    LIVE.with(|l| l.get())
}

/// Starts a new peak at the bytes live now.
fn reset_peak() {
    let v = live();
    PEAK.with(|p| p.set(v));
}

fn peak() -> isize {
    PEAK.with(|p| p.get())
}

/// A bench that measures how much the heap grows while its longest sweep
/// is played: (the drive, growth in bytes), kept outside the measurement.
struct Metered {
    inner: VirtualBench,
    longest: Option<(Vec<f64>, isize)>,
}

impl Bench for Metered {
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
        self.inner.describe()
    }
    fn run(
        &mut self,
        drive_v: &[f64],
        observer: &mut dyn FnMut(Block<'_>) -> Control,
    ) -> Result<Signals, BenchError> {
        let base = live();
        reset_peak();
        let r = self.inner.run(drive_v, observer);
        let growth = peak() - base;
        if self
            .longest
            .as_ref()
            .is_none_or(|(d, _)| d.len() < drive_v.len())
        {
            self.longest = Some((drive_v.to_vec(), growth));
        }
        r
    }
}

/// Does what the runner does with each level (`src/runner/execute.rs`):
/// analyses it against the borrowed pre-measurement, keeps only its
/// force-balance data for the joint fit, drops its samples. Notes the bytes
/// live as each level is handed out and once it is analysed.
struct Levels {
    mass_kg: f64,
    kept: Vec<ForceBalanceData>,
    /// (live when handed out, live after, bytes of the kept data).
    at: Vec<(isize, isize, isize)>,
}

fn bytes(d: &ForceBalanceData) -> isize {
    8 * (d.x_m.capacity() + d.v_m_per_s.capacity() + d.a_m_per_s2.capacity() + d.mic_v.capacity())
        as isize
}

impl Observer for Levels {
    fn narrow_finished(
        &mut self,
        _bench: &dyn Bench,
        pre: &PreMeasured<'_>,
        _index: usize,
        sweep: NarrowSweep,
    ) -> Result<Option<NarrowSweep>, ProcedureError> {
        let before = live();
        let sweeps = identify::Sweeps {
            moving_mass_kg: self.mass_kg,
            pre: pre.signals,
            main: &sweep.signals,
        };
        let (_, fb) =
            identify::analyze_sweeps_with_force_balance(sweeps, &AnalyzeOptions::default())
                .map_err(|e| ProcedureError::Failed(e.to_string()))?;
        drop(sweep);
        // The FFT plans and buffers this thread keeps for its next analysis
        // are not the level's.
        springbench::dsp::spectrum::release_thread_buffers();
        let held = bytes(&fb);
        self.kept.reserve(1);
        self.kept.push(fb);
        self.at.push((before, live(), held));
        Ok(None)
    }
}

/// A sweep is held once while it is played: the procedure adds no copy of
/// its samples to the bench's own record (it copied every sweep before,
/// 38 MB for a 16 s pre-measurement at 48 kHz), and a finished level leaves
/// only its force-balance data behind.
#[test]
fn a_sweep_is_held_once_and_a_finished_level_leaves_only_its_force_balance_data() {
    let part = preset("spider_4in").unwrap();
    let cfg = ProcedureConfig {
        moving_mass_kg: part.moving_mass_kg,
        levels_m: vec![0.002, 0.004, 0.006],
        pre_duration_s: 4.0,
        narrow_duration_s: 3.0,
        ..ProcedureConfig::default()
    };
    let mut bench = Metered {
        inner: VirtualBench::new(part.clone(), 7),
        longest: None,
    };
    let mut obs = Levels {
        mass_kg: cfg.moving_mass_kg,
        kept: vec![],
        at: vec![],
    };
    let out = run(&mut bench, &cfg, &mut obs).expect("procedure");
    assert!(out.narrow.is_empty(), "every level was taken");
    assert_eq!(obs.kept.len(), 3);

    // The longest sweep (the pre-measurement) played by the bench alone, on
    // a fresh bench with the same drive: what the bench itself holds.
    let (drive, in_procedure) = bench.longest.take().unwrap();
    let mut alone = VirtualBench::new(part, 7);
    let base = live();
    reset_peak();
    let sig = alone.run(&drive, &mut |_| Control::Continue).unwrap();
    let bench_alone = peak() - base;
    drop(sig);
    let channel = 8 * drive.len() as isize;
    println!(
        "pre-measurement of {} samples: the heap grew by {:.1} MB while the procedure played it, {:.1} MB for the bench alone (one channel: {:.1} MB)",
        drive.len(),
        in_procedure as f64 / 1e6,
        bench_alone as f64 / 1e6,
        channel as f64 / 1e6
    );
    assert!(
        in_procedure - bench_alone < channel / 10,
        "the procedure held {} bytes more than the bench while playing {} samples",
        in_procedure - bench_alone,
        drive.len()
    );

    // Each finished level leaves its force-balance data and nothing of
    // its samples or its analysis.
    for w in obs.at.windows(2) {
        let ((_, after0, _), (_, after1, held1)) = (w[0], w[1]);
        println!(
            "level kept: {:.2} MB live more than after the level before, its force-balance data {:.2} MB",
            (after1 - after0) as f64 / 1e6,
            held1 as f64 / 1e6
        );
        assert!(
            after1 - after0 <= held1 + 64 * 1024,
            "a level left {} bytes, its force-balance data is {held1}",
            after1 - after0
        );
    }
}
