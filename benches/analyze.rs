//! `identify::analyze` on the p1_spider reference set (files read once,
//! outside the timed loop, except `read_and_analyze`: the CLI's whole path
//! without process start). Run single-threaded: `cargo bench --bench analyze`.
use criterion::{criterion_group, criterion_main, Criterion};
use springbench::identify::{analyze, AnalyzeOptions, Method};
use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings/p1_spider");
    let set = RecordingSet::read_dir(dir).expect("reference recording p1_spider");
    let mut g = c.benchmark_group("analyze_p1");
    g.sample_size(30);
    for (name, method) in [
        ("two_signal", Method::TwoSignal),
        ("one_signal", Method::OneSignal),
    ] {
        let opts = AnalyzeOptions {
            method,
            order: None,
        };
        g.bench_function(name, |b| {
            b.iter(|| analyze(black_box(&set), &opts).unwrap())
        });
    }
    // The whole path of `springbench analyze DIR` without process start:
    // reading pre.wav, main.wav and meta.json (15 MB) plus the analysis.
    g.bench_function("read_and_analyze", |b| {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/reference-recordings/p1_spider");
        b.iter(|| {
            let set = RecordingSet::read_dir(&dir).unwrap();
            analyze(black_box(&set), &AnalyzeOptions::default()).unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
