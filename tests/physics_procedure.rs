//! The standard procedure on the virtual bench (issue 3): level check,
//! resonance search, narrow sweep; limits, bench time, cancel.

use springbench::physics::{preset, preset_names, simulate, SimulateOptions};

#[test]
fn procedure_on_every_preset() {
    for name in preset_names() {
        let part = preset(name).unwrap();
        let t0 = std::time::Instant::now();
        let sim = simulate(&part, 1, &SimulateOptions::default()).unwrap();
        let o = &sim.outcome;
        eprintln!("== {name} ({:.2} s wall)", t0.elapsed().as_secs_f64());
        for l in &o.log {
            eprintln!("   {l}");
        }
        let n = &o.narrow[0];
        assert!(
            o.bench_time_s <= 40.0,
            "{name}: bench time {}",
            o.bench_time_s
        );
        assert!(n.xpeak_m < 0.02);
    }
}
