//! Time of `analyze --diagnose` on a reference recording set (reading the
//! files excluded): the whole `diagnose` (identification + force balance +
//! candidates + ladder + comparison data), and the engine alone on the
//! prepared force-balance data. Figures go into docs/performance.md.
use criterion::{criterion_group, criterion_main, Criterion};
use springbench::diagnose::{diagnose, diagnose_data, engine::EngineOptions, DiagnoseOptions};
use springbench::identify::{force_balance_data, AnalyzeOptions};
use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;

fn bench(c: &mut Criterion) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings");
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    for case in ["p1_spider", "p2_spider_friction"] {
        let Ok(set) = RecordingSet::read_dir(dir.join(case)) else {
            eprintln!("reference recordings not found; skipping {case}");
            continue;
        };
        g.bench_function(format!("diagnose_{case}"), |b| {
            b.iter(|| diagnose(&set, &DiagnoseOptions::default()).unwrap())
        });
        let data = force_balance_data(&set, &AnalyzeOptions::default()).unwrap();
        g.bench_function(format!("engine_{case}"), |b| {
            b.iter(|| diagnose_data(&data, &EngineOptions::default()).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
