//! Speed of the virtual bench (issue 3: at least 100x real time for a 48 kHz,
//! 3-channel bench). Figures go into docs/performance.md.
//!
//! `cargo bench --bench simulate`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use springbench::bench::simulate::simulate;
use springbench::bench::simulate::SimulateOptions;
use springbench::bench::virtual_bench::VirtualBench;
use springbench::bench::{Bench, Control};
use springbench::physics::preset;
use springbench::procedure::SweepSpec;
use std::hint::black_box;

fn streaming(c: &mut Criterion) {
    let fs = 48000.0;
    // One second of a large-signal rising sweep through the resonance.
    let drive = SweepSpec::new(30.0, 60.0, 1.0, 50.0).samples(fs);
    let mut g = c.benchmark_group("virtual_bench");
    g.throughput(Throughput::Elements(drive.len() as u64));
    g.sample_size(20);
    for name in ["spider_4in", "cone_18in"] {
        let part = preset(name).unwrap();
        let mut vb = VirtualBench::new(part.clone(), 1);
        g.bench_function(format!("run_1s_3ch/{name}"), |b| {
            b.iter(|| {
                let s = vb
                    .run(black_box(&drive), &mut |_| Control::Continue)
                    .unwrap();
                black_box(s.displacement_m[1000])
            })
        });
        let mut fx = part.clone();
        fx.effects = serde_json::from_str(
            r#"{"coulomb_friction": {"force_n": 0.1}, "creep": {"k_n_per_m": 200, "tau_s": 0.05},
                "quadratic_damping": {"coeff_ns2_per_m2": 2}, "channel_delay": {"delay_s": 0.0002}}"#,
        )
        .unwrap();
        let mut vb = VirtualBench::new(fx, 1);
        g.bench_function(format!("run_1s_3ch_effects/{name}"), |b| {
            b.iter(|| {
                let s = vb
                    .run(black_box(&drive), &mut |_| Control::Continue)
                    .unwrap();
                black_box(s.displacement_m[1000])
            })
        });
    }
    g.finish();
    let mut g = c.benchmark_group("procedure");
    g.sample_size(10);
    let part = preset("spider_4in").unwrap();
    g.bench_function("simulate_recording_set/spider_4in", |b| {
        b.iter(|| black_box(simulate(&part, 1, &SimulateOptions::default()).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, streaming);
criterion_main!(benches);
