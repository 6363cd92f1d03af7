//! Instruction-count budgets of the hot paths (issue 38): each benchmark runs
//! once under Valgrind's callgrind through `gungraun`, whose counts do not move
//! with the machine's load as wall times do. `.ci/budgets` runs them and
//! compares every count with `benches/budgets.baseline` (more than 10 %
//! above it fails CI); docs/performance.md ("Instruction budgets") says how
//! to update a baseline. Inputs are kept small enough for Valgrind (about
//! 50x slower than native): the whole step stays under 3 minutes.
//!
//! Setup (reading files, simulating the recordings a benchmark analyses,
//! opening a database) runs before the counted call and is not counted.
//!
//! Run: `cargo bench --profile dev --bench budgets` (needs `valgrind` and
//! `gungraun-runner` of the same version as the `gungraun` library).
use gungraun::{library_benchmark, library_benchmark_group, main, LibraryBenchmarkConfig};
use springbench::bench::long_term::{run_accelerated, LongTermPlan};
use springbench::bench::simulate::{simulate, SimulateOptions};
use springbench::bench::virtual_bench::VirtualBench;
use springbench::diagnose::{diagnose, DiagnoseOptions};
use springbench::identify::{analyze, AnalyzeOptions, Method, Report};
use springbench::physics::{preset, PartSpec};
use springbench::procedure::{self, Observer, ProcedureConfig};
use springbench::qc::cfx::{job_messages, JobFacts, TestedMeasurement};
use springbench::qc::production::{GoldenLevel, GoldenReference, DEFAULT_MAX_F0_DEVIATION_PERCENT};
use springbench::qc::spc::{self, SpcPoint};
use springbench::qc::{ParamOutcome, ParamResult, Verdict, VerdictKind};
use springbench::recording::{Meta, RecordingSet, RecordingSetFiles};
use springbench::store::fleet::{
    ItemBody, JobVerdictsItem, MeasurementItem, RecordingItem, ReplicationItem, VerdictItem,
};
use std::hint::black_box;

/// Rayon's pool as this one thread: the analysis splits its independent
/// halves with `rayon::join` (two cores, a shorter wall time), and callgrind
/// counts only the benchmark function's own thread. With the benchmark's
/// thread as the pool's only worker, every join runs both halves on it, one
/// after the other: the count is the whole work, the same every run. Called
/// by each setup (one process per benchmark), outside the count.
fn pool_on_this_thread() {
    // a second call (production_set's spider()) finds it built
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .use_current_thread()
        .build_global();
    assert_eq!(
        rayon::current_thread_index(),
        Some(0),
        "rayon's pool must be this thread alone, or the count misses the other threads' work"
    );
    assert_eq!(rayon::current_num_threads(), 1);
}

/// A reference recording set (16.5 s pre-measurement + 10.5 s main sweep,
/// 48 kHz, 3 channels), as `springbench analyze DIR` reads it.
fn reference_set(name: &str) -> RecordingSet {
    pool_on_this_thread();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings")
        .join(name);
    RecordingSet::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
}

struct Quiet;
impl Observer for Quiet {}

/// The full procedure with short sweeps (4 s pre-measurement, 2 s narrow
/// sweep instead of 16 s and 10 s): every step of it (pre-measurement and
/// its level check, resonance search, narrow sweep at the level) at about a
/// quarter of the bench time, so that one run stays a few seconds under
/// Valgrind.
fn short_full_procedure() -> SimulateOptions {
    SimulateOptions {
        procedure: ProcedureConfig {
            pre_duration_s: 4.0,
            narrow_duration_s: 2.0,
            ..ProcedureConfig::default()
        },
        ..SimulateOptions::default()
    }
}

fn spider() -> PartSpec {
    pool_on_this_thread();
    preset("spider_4in").expect("preset spider_4in")
}

/// A production measurement of spider_4in: the golden reference from one
/// unit measured by the (short) full procedure, then the production
/// procedure (1.5 s pre-measurement, 2 s narrow sweep) on another unit.
fn production_set() -> RecordingSet {
    pool_on_this_thread();
    let part = spider();
    let golden_unit = simulate(&part, 1, &short_full_procedure()).expect("golden unit");
    let r = analyze(&golden_unit.set, &AnalyzeOptions::default()).expect("golden analysis");
    let ss = r.small_signal.as_ref().expect("small signal");
    let narrow = &golden_unit.outcome.narrow[0];
    let golden = GoldenReference {
        units: 1,
        f0_hz: ss.f0_hz.expect("f0"),
        q: ss.q.expect("Q"),
        pre_drive_v: golden_unit.outcome.pre_sweep.amplitude_v,
        pre_q_drive_to_x: golden_unit.outcome.pre_q_drive_to_x,
        levels: vec![GoldenLevel {
            resonance_hz: r.large_signal.resonance_hz,
            drive_v: narrow.drive_v,
            xpeak_m: Some(r.large_signal.xpeak_m),
        }],
        max_f0_deviation_percent: DEFAULT_MAX_F0_DEVIATION_PERCENT,
    };
    let cfg = ProcedureConfig {
        moving_mass_kg: part.moving_mass_kg,
        ..ProcedureConfig::default()
    };
    let mut vb = VirtualBench::new(part.clone(), 2);
    let out = procedure::run_production(&mut vb, &cfg, Some(&golden), &mut Quiet)
        .expect("production procedure");
    assert!(
        out.production
            .as_ref()
            .is_some_and(|p| p.fallback.is_none()),
        "the production procedure fell back to the full one: {:?}",
        out.production
    );
    let mut meta = Meta::standard(part.moving_mass_kg, out.pre.sample_rate_hz);
    meta.channels.drive = Some(2);
    RecordingSet {
        meta,
        pre: out.pre,
        main: out.narrow[0].signals.clone(),
    }
}

#[library_benchmark]
#[bench::two_signal_p1(args = ("p1_spider", Method::TwoSignal), setup = with_set)]
#[bench::one_signal_p1(args = ("p1_spider", Method::OneSignal), setup = with_set)]
fn analyze_reference((set, method): (RecordingSet, Method)) -> Report {
    let opts = AnalyzeOptions {
        method,
        order: None,
    };
    black_box(analyze(black_box(&set), &opts).expect("analysis"))
}

fn with_set(name: &str, method: Method) -> (RecordingSet, Method) {
    (reference_set(name), method)
}

#[library_benchmark]
#[bench::p1(setup = reference_set, args = ("p1_spider"))]
fn diagnose_reference(set: RecordingSet) -> usize {
    let d = diagnose(black_box(&set), &DiagnoseOptions::default()).expect("diagnosis");
    black_box(d.report.warnings.len())
}

#[library_benchmark]
#[bench::spider_4in(setup = production_set)]
fn production_analysis(set: RecordingSet) -> Report {
    // As the runner analyses a production measurement (Two Signal, order 4).
    let opts = AnalyzeOptions {
        method: Method::TwoSignal,
        order: Some(4),
    };
    black_box(analyze(black_box(&set), &opts).expect("analysis"))
}

#[library_benchmark]
#[bench::spider_4in(setup = spider)]
fn simulate_full_procedure(part: PartSpec) -> usize {
    let s = simulate(black_box(&part), 1, &short_full_procedure()).expect("simulation");
    black_box(s.set.main.len())
}

/// 10^5 SPC points: 25 000 jobs of 4 repeats (averaged per part), values
/// spread around 2 500 N/m, a fail every 97th.
fn spc_points(n: usize) -> Vec<SpcPoint> {
    (0..n)
        .map(|i| SpcPoint {
            time: format!(
                "2026-11-28T{:02}:{:02}:{:02}.000Z",
                i / 3600 % 24,
                i / 60 % 60,
                i % 60
            ),
            part_serial: format!("P{:06}", i / 4),
            measurement_id: format!("m-{i}"),
            job_id: Some(format!("j-{}", i / 4)),
            level_index: Some(0),
            recipe_version: Some(1),
            value: 2500.0 + ((i * 7919) % 1000) as f64 * 0.1,
            repeats: 1,
            verdict: if i % 97 == 0 {
                VerdictKind::Fail
            } else {
                VerdictKind::Pass
            },
        })
        .collect()
}

#[library_benchmark]
#[bench::values_1e5(args = (100_000), setup = spc_points)]
fn spc_compute(points: Vec<SpcPoint>) -> usize {
    let s = spc::compute("keff", "N/m", Some(2400.0), Some(2700.0), points, 3);
    black_box(s.points.len())
}

/// A lot of 30 parts, one job each with one measurement judged against a
/// recipe's four limits.
fn lot_facts(parts: usize) -> Vec<JobFacts> {
    let param = |name: &str, unit: &str, value: f64| ParamOutcome {
        name: name.into(),
        quantity: None,
        unit: unit.into(),
        value,
        lower: Some(0.9 * value),
        upper: Some(1.1 * value),
        result: ParamResult::Pass,
        x_m: None,
    };
    (0..parts)
        .map(|i| {
            let verdict = Verdict {
                verdict: VerdictKind::Pass,
                failures: vec![],
                invalid_reasons: vec![],
                parameters: vec![
                    param("k0", "N/m", 2500.0 + i as f64),
                    param("keff", "N/m", 2780.0 + i as f64),
                    param("xpeak", "m", 0.008),
                    param("resonance", "Hz", 37.5),
                ],
            };
            JobFacts {
                job_id: format!("job-{i:04}"),
                part_serial: format!("LOT7-{i:04}"),
                source: "springbench/line-1".into(),
                started_at: "2026-11-28T08:00:00.000Z".into(),
                finished_at: "2026-11-28T08:00:05.000Z".into(),
                state: "succeeded".into(),
                recipe: None,
                job_verdict: Some(verdict.clone()),
                operator: Some("op".into()),
                measurements: vec![TestedMeasurement {
                    measurement_id: format!("m-{i:04}"),
                    target_xpeak_m: Some(0.008),
                    level_index: Some(0),
                    repeat_index: Some(0),
                    procedure: None,
                    verdict: Some(verdict),
                    values: vec![],
                }],
            }
        })
        .collect()
}

#[library_benchmark]
#[bench::parts_30(args = (30), setup = lot_facts)]
fn cfx_lot_messages(lot: Vec<JobFacts>) -> usize {
    // As the outbox stores them: the three messages of every job as JSON text.
    let mut bytes = 0;
    for f in &lot {
        for (_, _, body) in job_messages(f) {
            bytes += serde_json::to_string(&body).expect("json").len();
        }
    }
    black_box(bytes)
}

/// A long-term test's first hour on the virtual bench (issue 32's
/// accelerated test, `bench::long_term::run_accelerated`): spider_3in aging
/// from new, measured at the start and the end of the hour with the short
/// full procedure at 6 mm, the hour's sine stimulus at 5.3 mm applied
/// between them. The ageing tests measure every 15 minutes with 16 s + 10 s
/// sweeps; under Valgrind that hour would take minutes, and its cost is the
/// measurements', which this counts (two, at a quarter of their length).
fn long_term_hour() -> (VirtualBench, LongTermPlan) {
    pool_on_this_thread();
    let part = preset("spider_3in").expect("preset spider_3in");
    assert!(part.ageing.is_some(), "spider_3in ages");
    let plan = LongTermPlan {
        duration_s: 3600.0,
        interval_s: 3600.0,
        stimulus_xpeak_m: 0.0053,
        procedure: ProcedureConfig {
            levels_m: vec![0.006],
            ..short_full_procedure().procedure
        },
    };
    (VirtualBench::new(part, 3).with_ageing(0.0), plan)
}

#[library_benchmark]
#[bench::spider_3in(setup = long_term_hour)]
fn long_term_test((mut vb, plan): (VirtualBench, LongTermPlan)) -> usize {
    let mut frames = 0;
    run_accelerated(&mut vb, black_box(&plan), &mut |m| {
        frames += m.set.pre.len() + m.set.main.len();
        Ok(())
    })
    .expect("long-term test");
    black_box(frames)
}

/// A batch of the station's default size (`[fleet] batch_items` = 50): 40
/// finished measurements and the verdicts of 10 jobs of 4 measurements,
/// each measurement with its result document, one verdict and its two
/// recordings as references (`[fleet] recordings = "reference"`; with the
/// bytes the center also hashes them: SHA-256, linear in their size).
fn ingest_batch(items: usize) -> Vec<ReplicationItem> {
    let report = serde_json::to_value(Report::default()).expect("report json");
    let detail = serde_json::to_value(&lot_facts(1)[0].job_verdict).expect("verdict json");
    let verdict = |i: usize, measurement: Option<String>| VerdictItem {
        id: format!("v-{i:04}"),
        job_id: Some(format!("job-{:04}", i / 4)),
        measurement_id: measurement,
        part_serial: format!("LOT7-{:04}", i / 4),
        recipe_name: "spider-4in".into(),
        recipe_version: 3,
        recipe_sha256: "ab".repeat(32),
        verdict: "pass".into(),
        detail: detail.clone(),
        trace: serde_json::json!({
            "software_version": "0.1.0", "bench_id": "virtual-1",
            "recipe": {"name": "spider-4in", "version": 3}, "offline": false
        }),
        created_at: "2026-11-28T08:00:05.000Z".into(),
    };
    let recording = |kind: &str, frames: i64| RecordingItem {
        kind: kind.into(),
        sample_rate_hz: 48_000.0,
        frames,
        channel_scale: None,
        sha256: "cd".repeat(32),
        byte_len: 4 * frames,
        bytes: None,
    };
    let measurements = items * 4 / 5;
    (0..items)
        .map(|i| {
            let body = if i < measurements {
                let id = format!("m-{i:04}");
                ItemBody::Measurement(Box::new(MeasurementItem {
                    id: id.clone(),
                    part_serial: format!("LOT7-{:04}", i / 4),
                    part_kind: Some("spider_4in".into()),
                    part_notes: None,
                    job_id: Some(format!("job-{:04}", i / 4)),
                    source: "bench".into(),
                    bench_id: Some("virtual-1".into()),
                    config: serde_json::json!({
                        "analysis": {"method": "two-signal", "order": null},
                        "bench": "virtual-1", "seed": i,
                        "procedure": {"levels_m": [0.008], "pre_duration_s": 16.0, "narrow_duration_s": 10.0}
                    }),
                    meta: serde_json::json!({"moving_mass_kg": 0.0121, "sample_rate_hz": 48000.0}),
                    result: Some(report.clone()),
                    analysis_error: None,
                    target_xpeak_m: Some(0.008),
                    repeat_index: Some((i % 4) as i64),
                    level_index: Some(0),
                    pre: recording("pre", 792_000),
                    main: recording("main", 504_000),
                    calibration: None,
                    verdicts: vec![verdict(i, Some(id))],
                    software_version: "0.1.0".into(),
                    created_at: "2026-11-28T08:00:05.000Z".into(),
                }))
            } else {
                let job = i - measurements;
                let v = verdict(4 * job, None);
                ItemBody::JobVerdicts(JobVerdictsItem {
                    job_id: v.job_id.clone().unwrap_or_default(),
                    part_serial: v.part_serial.clone(),
                    verdicts: vec![v],
                })
            };
            ReplicationItem {
                seq: i as i64 + 1,
                body,
            }
        })
        .collect()
}

// The center's work on an ingest batch outside PostgreSQL
// (`PgStore::ingest` in crates/store-pg): per item its id and content
// hash, the checks that refuse a contradictory item (`to_finished`, each
// verdict's `to_new`), and the JSON texts bound to the SQL. The SQL runs
// in the PostgreSQL server, another process that callgrind does not count
// (docs/performance.md).
#[library_benchmark]
#[bench::items_50(args = (50), setup = ingest_batch)]
fn center_ingest_batch(items: Vec<ReplicationItem>) -> usize {
    let mut bytes = 0;
    for item in black_box(&items) {
        bytes += item.item_id().len() + item.content_sha256().len();
        match &item.body {
            ItemBody::Measurement(m) => {
                let f = m.to_finished().expect("a consistent measurement");
                bytes += m.config.to_string().len() + m.meta.to_string().len();
                bytes += m.result.as_ref().map_or(0, |r| r.to_string().len());
                for v in &f.verdicts {
                    bytes += v.detail.to_string().len() + v.trace.to_string().len();
                }
            }
            ItemBody::JobVerdicts(j) => {
                for v in &j.verdicts {
                    let v = v.to_new().expect("a known verdict");
                    bytes += v.detail.to_string().len() + v.trace.to_string().len();
                }
            }
            ItemBody::Correction(_) => {}
            ItemBody::LongTermTest(t) => {
                bytes += t.document.to_string().len() + t.summary.to_string().len();
            }
        }
    }
    black_box(bytes)
}

library_benchmark_group!(
    name = analysis;
    benchmarks = analyze_reference, diagnose_reference, production_analysis
);

library_benchmark_group!(
    name = procedures;
    benchmarks = simulate_full_procedure, long_term_test
);

library_benchmark_group!(
    name = quality;
    benchmarks = spc_compute, cfx_lot_messages
);

library_benchmark_group!(
    name = fleet;
    benchmarks = center_ingest_batch
);

main!(
    config = LibraryBenchmarkConfig::default();
    library_benchmark_groups = analysis, procedures, quality, fleet
);
