//! Load of the center (issue 20): N results put into PostgreSQL through the
//! replication ingest (`CenterIngest::ingest`, the same upsert a station's
//! batch takes), then the latencies of the fleet's questions. Not part of
//! `cargo test`; the figures go into docs/fleet.md.
//!
//! ```text
//! .ci/pg start /tmp/sb-load 55440          # prints the URL
//! cargo run -p springbench-store-pg --example load -- \
//!     --url 'postgres://sb@localhost:55440/postgres?host=/tmp/sb-load' \
//!     --results 1000000 --stations 50 --batch 200 --writers 4
//! .ci/pg stop /tmp/sb-load
//! ```
//!
//! Each result is a measurement with its recordings' reference (hash and
//! length, bytes kept on the station), a result document and a verdict with
//! six judged parameters, as a station sends it; parts get 2 measurements
//! (a job of two repeats). `--measure-only` skips the load and measures an
//! already loaded database.

use serde_json::json;
use springbench_store::fleet::{
    CenterIngest, ItemBody, JobVerdictsItem, MeasurementItem, RecordingItem, ReplicationItem,
    VerdictItem,
};
use springbench_store::results::{MeasurementReads, PartReads};
use springbench_store_pg::{PgStore, SpcQuery};
use std::time::{Duration, Instant};

struct Args {
    url: String,
    results: usize,
    stations: usize,
    batch: usize,
    writers: usize,
    measure_only: bool,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        url: String::new(),
        results: 1_000_000,
        stations: 50,
        batch: 200,
        writers: 4,
        measure_only: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut num = |name: &str| -> Result<usize, String> {
            it.next()
                .and_then(|v| v.parse().ok())
                .filter(|v| *v > 0)
                .ok_or_else(|| format!("{name}: a positive whole number"))
        };
        match k.as_str() {
            "--url" => a.url = it.next().ok_or("--url: the PostgreSQL URL")?,
            "--results" => a.results = num("--results")?,
            "--stations" => a.stations = num("--stations")?,
            "--batch" => a.batch = num("--batch")?,
            "--writers" => a.writers = num("--writers")?,
            "--measure-only" => a.measure_only = true,
            other => return Err(format!("unknown argument '{other}'")),
        }
    }
    if a.url.is_empty() {
        return Err("--url is required".into());
    }
    Ok(a)
}

const PARAMS: [&str; 6] = [
    "keff_n_per_m",
    "k0_n_per_m",
    "resonance_hz",
    "q_factor",
    "r_ns_per_m",
    "kx_asymmetry",
];

fn station_of(part: usize, stations: usize) -> String {
    format!("line-{:02}", part % stations)
}

fn serial_of(part: usize, stations: usize) -> String {
    format!("S{:02}-{part:09}", part % stations)
}

/// Result `i` of the fleet: part `i / 2` (a job of two repeats) on station
/// `part % stations`; its outbox seq: 3 items per part (two measurements,
/// the job's verdict).
fn item(i: usize, stations: usize) -> ReplicationItem {
    let job = i / 2;
    let station = station_of(job, stations);
    let serial = serial_of(job, stations);
    let seq = (3 * (job / stations) + i % 2 + 1) as i64;
    let id = format!("m-{i:09}");
    // one result every 1.7 s of fleet time from 2021-01-01
    let t = chrono::DateTime::parse_from_rfc3339("2021-01-01T00:00:00Z").unwrap()
        + chrono::Duration::milliseconds(i as i64 * 1700);
    let t = t
        .with_timezone(&chrono::Utc)
        .to_rfc3339_opts(chrono::SecondsFormat::Millis, true);
    let x = ((i as u64).wrapping_mul(2654435761) % 10_000) as f64 / 10_000.0;
    let keff = 1000.0 + (x - 0.5) * 120.0;
    let verdict = if i % 97 == 13 {
        "invalid"
    } else if (950.0..=1050.0).contains(&keff) {
        "pass"
    } else {
        "fail"
    };
    let values = [
        keff,
        keff * 1.2,
        31.5 + x,
        2.1 + x / 10.0,
        0.8 + x,
        x / 50.0,
    ];
    let parameters: Vec<_> = if verdict == "invalid" {
        vec![]
    } else {
        PARAMS
            .iter()
            .zip(values)
            .map(|(p, v)| json!({"name": p, "value": v, "lower": v * 0.9, "upper": v * 1.1, "result": "pass"}))
            .collect()
    };
    let rec = |kind: &str, n: usize| RecordingItem {
        kind: kind.into(),
        sample_rate_hz: 48_000.0,
        frames: 480_000,
        channel_scale: None,
        sha256: format!("{:064x}", (i as u128) * 4 + n as u128),
        byte_len: 2_100_000,
        bytes: None,
    };
    let m = MeasurementItem {
        id: id.clone(),
        part_serial: serial.clone(),
        part_kind: Some("spider-80".into()),
        part_notes: None,
        job_id: Some(format!("j-{job:09}")),
        source: "bench".into(),
        bench_id: Some("bench-1".into()),
        config: json!({"target_xpeak_m": 0.002, "repeats": 2, "levels_m": [0.002]}),
        meta: json!({"id": id, "sample_rate_hz": 48000, "station": station}),
        result: Some(json!({
            "large_signal": {"keff_n_per_m": keff, "xpeak_m": 0.002, "resonance_hz": 31.5 + x,
                             "validity": {"keff_n_per_m": {"state": "valid"}}},
            "small_signal": {"k0_n_per_m": keff * 1.2, "k0_se_n_per_m": 3.1, "misfit_percent": 0.4,
                             "reliable": true, "q_factor": 2.1 + x, "r_ns_per_m": 0.8 + x},
            "stiffness": {"coefficients_n_per_m_pow_i_plus_1": [keff, 1.2e4, -3.0e6, 4.1e9, 1.0e11]},
        })),
        analysis_error: None,
        target_xpeak_m: Some(0.002),
        repeat_index: Some((i % 2) as i64),
        level_index: Some(0),
        pre: rec("pre", 0),
        main: rec("main", 1),
        calibration: None,
        verdicts: vec![VerdictItem {
            id: format!("v-{i:09}"),
            job_id: Some(format!("j-{job:09}")),
            measurement_id: Some(id),
            part_serial: serial,
            recipe_name: format!("spider-80-{}", i % 5),
            recipe_version: 3,
            recipe_sha256: "ab".repeat(32),
            verdict: verdict.into(),
            detail: json!({"verdict": verdict, "failures": [], "invalid_reasons": [], "parameters": parameters}),
            trace: json!({"software_version": "0.9.0", "bench": "bench-1", "recipe": {"name": "spider-80", "version": 3},
                          "submitted_by": "mes", "sensors": {"laser": "optoNCDT 1420-10"}}),
            created_at: t.clone(),
        }],
        software_version: "0.9.0".into(),
        created_at: t,
    };
    ReplicationItem {
        seq,
        body: ItemBody::Measurement(Box::new(m)),
    }
}

/// The verdict of part `part`'s job (pass unless a repeat failed or was invalid).
fn job_verdict(part: usize, stations: usize) -> ReplicationItem {
    let v = |i: usize| match item(i, stations).body {
        ItemBody::Measurement(m) => m.verdicts[0].clone(),
        _ => unreachable!(),
    };
    let (a, b) = (v(2 * part), v(2 * part + 1));
    let verdict = if a.verdict == "invalid" || b.verdict == "invalid" {
        "invalid"
    } else if a.verdict == "fail" || b.verdict == "fail" {
        "fail"
    } else {
        "pass"
    };
    ReplicationItem {
        seq: (3 * (part / stations) + 3) as i64,
        body: ItemBody::JobVerdicts(JobVerdictsItem {
            job_id: format!("j-{part:09}"),
            part_serial: a.part_serial.clone(),
            verdicts: vec![VerdictItem {
                id: format!("vj-{part:09}"),
                measurement_id: None,
                verdict: verdict.into(),
                detail: json!({"verdict": verdict}),
                ..b
            }],
        }),
    }
}

fn stats(mut v: Vec<Duration>) -> String {
    v.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    format!(
        "median {:.1} ms, p95 {:.1} ms, max {:.1} ms ({} runs)",
        ms(v[v.len() / 2]),
        ms(v[(v.len() * 95 / 100).min(v.len() - 1)]),
        ms(v[v.len() - 1]),
        v.len()
    )
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("load: {e}");
            std::process::exit(2);
        }
    };
    let s = PgStore::connect(&a.url).await.unwrap_or_else(|e| {
        eprintln!("load: {e}");
        std::process::exit(1)
    });
    if !a.measure_only {
        let t0 = Instant::now();
        // Writers take rounds of `batch` items of each station (whole parts);
        // each station's seq grows without gaps, as an outbox's does.
        let parts_total = a.results / 2;
        let per_writer = parts_total.div_ceil(a.writers);
        let mut tasks = Vec::new();
        for w in 0..a.writers {
            let s = s.clone();
            let (stations, batch, total) = (a.stations, a.batch.div_ceil(3), parts_total);
            tasks.push(tokio::spawn(async move {
                let lo = w * per_writer;
                let hi = ((w + 1) * per_writer).min(total);
                let mut i = lo;
                let mut done = 0usize;
                let mut last_report = Instant::now();
                while i < hi {
                    let end = (i + batch * stations).min(hi);
                    // group this round by station
                    let mut by: std::collections::BTreeMap<String, Vec<ReplicationItem>> =
                        Default::default();
                    for p in i..end {
                        let q = by.entry(station_of(p, stations)).or_default();
                        q.push(item(2 * p, stations));
                        q.push(item(2 * p + 1, stations));
                        q.push(job_verdict(p, stations));
                    }
                    for (st, items) in by {
                        let r = s.ingest(&st, &items).await.expect("ingest");
                        assert_eq!(r.inserted as usize, items.len(), "a fresh database");
                        done += 2 * (items.len() / 3);
                    }
                    i = end;
                    if w == 0 && last_report.elapsed() > Duration::from_secs(30) {
                        eprintln!(
                            "writer 0: {done} results of {} in {:.0} s",
                            2 * (hi - lo),
                            t0.elapsed().as_secs_f64()
                        );
                        last_report = Instant::now();
                    }
                }
                done
            }));
        }
        let mut n = 0;
        for t in tasks {
            n += t.await.expect("writer");
        }
        let dt = t0.elapsed().as_secs_f64();
        println!(
            "ingest: {n} results in {dt:.1} s = {:.0} results/s ({} writers, batches of {})",
            n as f64 / dt,
            a.writers,
            a.batch
        );
    }
    let (parts, meas, verdicts, recs) = s.counts().await.unwrap();
    println!("rows: {parts} parts, {meas} measurements, {verdicts} verdicts, {recs} recordings");
    let size: Vec<(String, i64)> = sqlx::query_as(
        "SELECT relname::text, pg_total_relation_size(c.oid) FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace \
         WHERE n.nspname = current_schema() AND c.relkind = 'r' ORDER BY 2 DESC",
    )
    .fetch_all(&sqlx::PgPool::connect(&a.url).await.unwrap())
    .await
    .unwrap();
    let total: i64 = size.iter().map(|x| x.1).sum();
    println!("database: {:.2} GB", total as f64 / 1e9);
    for (t, b) in size.iter().take(6) {
        println!(
            "  {t}: {:.2} GB ({:.0} bytes per measurement)",
            *b as f64 / 1e9,
            *b as f64 / meas.max(1) as f64
        );
    }

    // SPC over the newest 100 000 verdicts of a recipe, across stations and per station.
    for per_station in [false, true] {
        let mut v = Vec::new();
        let mut n = 0;
        let mut first = None;
        for _ in 0..10 {
            let t = Instant::now();
            let g = s
                .spc(&SpcQuery {
                    recipe: "spider-80-1",
                    parameter: "keff_n_per_m",
                    unit: "N/m",
                    lower: Some(950.0),
                    upper: Some(1050.0),
                    last: Some(100_000),
                    per_station,
                    ..Default::default()
                })
                .await
                .unwrap();
            v.push(t.elapsed());
            n = g.iter().map(|g| g.spc.n).sum::<usize>();
            first = g.first().map(|g| g.spc.clone());
        }
        println!(
            "SPC last 100 000 verdicts of a recipe ({}; {n} points): {}",
            if per_station {
                "per station"
            } else {
                "all stations"
            },
            stats(v)
        );
        // The figures, to compare one way of computing them with another.
        if let Some(f) = first {
            println!(
                "  first group: n {} mean {:?} sigma {:?} sigma_within {:?} passed {} failed {} invalid {}",
                f.n, f.mean, f.sigma, f.sigma_within, f.passed, f.failed, f.invalid
            );
        }
    }
    // A part's history: its measurements, newest first, and the part.
    let mut v = Vec::new();
    for k in 0..50 {
        // a part that is there (a load stopped early holds ranges of parts)
        let after = serial_of((k * 7919) % (meas.max(2) as usize / 2), a.stations);
        let Some(serial) = s
            .list_parts(Some(&after), 1)
            .await
            .unwrap()
            .pop()
            .map(|p| p.serial)
        else {
            continue;
        };
        let t = Instant::now();
        let p = s.get_part(&serial).await.unwrap();
        let h = s
            .list_measurements(Some(&serial), None, None, 50)
            .await
            .unwrap();
        v.push(t.elapsed());
        assert!(p.is_some() && !h.is_empty(), "part {serial} is there");
    }
    println!("part history (part + its measurements): {}", stats(v));
    // A page of the parts listing deep in the keyset, and of a station's measurements.
    let mut v = Vec::new();
    for k in 0..20 {
        let after = serial_of((k * 7717) % (meas.max(2) as usize / 2), a.stations);
        let t = Instant::now();
        let page = s.list_parts(Some(&after), 50).await.unwrap();
        v.push(t.elapsed());
        assert!(!page.is_empty() || k > 0);
    }
    println!("parts page of 50 (keyset): {}", stats(v));
    let mut v = Vec::new();
    let mut before = None;
    for _ in 0..20 {
        let t = Instant::now();
        let page = s.station_measurements("line-07", before, 50).await.unwrap();
        v.push(t.elapsed());
        before = page.last().map(|m| m.seq);
    }
    println!(
        "a station's measurements, page of 50 (keyset): {}",
        stats(v)
    );
    let mut v = Vec::new();
    for _ in 0..10 {
        let t = Instant::now();
        s.yield_per_day("spider-80-1", "2021-01-01", "2021-03-01")
            .await
            .unwrap();
        v.push(t.elapsed());
    }
    println!(
        "yield per station and day, 2 months of a recipe: {}",
        stats(v)
    );
    let mut v = Vec::new();
    for _ in 0..10 {
        let t = Instant::now();
        s.stations().await.unwrap();
        v.push(t.elapsed());
    }
    println!("stations (last contact, items, gaps): {}", stats(v));
}
