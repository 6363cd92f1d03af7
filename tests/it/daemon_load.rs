//! Bounded load test: 200 concurrent clients poll a job and list
//! measurements, and 10 more read the diagnostics and a plot of a
//! measurement, while jobs run on the virtual bench. Zero errors asserted;
//! latency percentiles and the daemon's peak VmRSS are printed
//! (docs/performance.md has the figures of a 30 s run).
//! SPRINGBENCH_LOAD_SECS (default 5), SPRINGBENCH_LOAD_CLIENTS (default 200),
//! SPRINGBENCH_LOAD_DIAG_CLIENTS (default 10).

use crate::common;

use common::{terminal, wait_job, Daemon};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_hundred_clients_poll_while_jobs_run() {
    let secs = env_or("SPRINGBENCH_LOAD_SECS", 5);
    let clients = env_or("SPRINGBENCH_LOAD_CLIENTS", 200) as usize;
    let diag_clients = env_or("SPRINGBENCH_LOAD_DIAG_CLIENTS", 10) as usize;
    let d = Arc::new(Daemon::start(""));
    let c = common::client();
    // One finished measurement so the listing has rows.
    let submit = |c: reqwest::Client, d: Arc<Daemon>, repeats: u32| async move {
        common::submit(
            &c,
            &d,
            json!({"part": {"serial": "SN-LOAD"}, "repeats": repeats}),
        )
        .await
    };
    let first = submit(c.clone(), d.clone(), 1).await;
    let j = wait_job(&c, &d, &first, Duration::from_secs(120), terminal).await;
    assert_eq!(j["state"], "succeeded");
    let meas = j["measurement_ids"][0].as_str().unwrap().to_string();
    let rss_start = common::rss_kb(d.pid());
    let rss_peak = Arc::new(std::sync::atomic::AtomicU64::new(rss_start));
    let sampler = {
        let (peak, pid) = (rss_peak.clone(), d.pid());
        std::thread::spawn(move || {
            let end = Instant::now() + Duration::from_secs(secs + 5);
            while Instant::now() < end {
                peak.fetch_max(common::rss_kb(pid), Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };

    // Keep the bench busy for the whole test.
    let stop = Arc::new(AtomicBool::new(false));
    let feeder = {
        let (c, d, stop) = (c.clone(), d.clone(), stop.clone());
        tokio::spawn(async move {
            let mut ids = vec![];
            while !stop.load(Ordering::Relaxed) {
                let id = submit(c.clone(), d.clone(), 10).await;
                wait_job(&c, &d, &id, Duration::from_secs(600), |s| {
                    terminal(s) || stop.load(Ordering::Relaxed)
                })
                .await;
                ids.push(id);
            }
            ids
        })
    };
    let deadline = Instant::now() + Duration::from_secs(secs);
    let mut tasks = vec![];
    for k in 0..clients + diag_clients {
        let d = d.clone();
        let first = first.clone();
        let meas = meas.clone();
        tasks.push(tokio::spawn(async move {
            let c = reqwest::Client::builder()
                .timeout(Duration::from_secs(30))
                .build()
                .unwrap();
            let mut lat = vec![];
            let mut errors = vec![];
            let mut i = k;
            while Instant::now() < deadline {
                let url = if k >= clients {
                    if i % 2 == 0 {
                        d.url(&format!("/api/v1/measurements/{meas}/diagnostics"))
                    } else {
                        d.url(&format!(
                            "/api/v1/measurements/{meas}/plots/residual_spectrum.svg"
                        ))
                    }
                } else if i % 2 == 0 {
                    d.url(&format!("/api/v1/jobs/{first}"))
                } else {
                    d.url("/api/v1/measurements?limit=20")
                };
                i += 1;
                let t = Instant::now();
                match c.get(&url).send().await {
                    Ok(r) if r.status().is_success() => match r.bytes().await {
                        Ok(_) => lat.push(t.elapsed().as_secs_f64()),
                        Err(e) => errors.push(format!("{url}: body {e}")),
                    },
                    Ok(r) => errors.push(format!("{url}: {}", r.status())),
                    Err(e) => errors.push(format!("{url}: {e}")),
                }
            }
            (lat, errors)
        }));
    }
    let mut lat = vec![];
    let mut errors = vec![];
    for t in tasks {
        let (l, e) = t.await.unwrap();
        lat.extend(l);
        errors.extend(e);
    }
    // A job was running during the load.
    let jobs: Value = c
        .get(d.url("/api/v1/jobs?state=running"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let busy = !jobs["items"].as_array().unwrap().is_empty();
    stop.store(true, Ordering::Relaxed);
    let fed = feeder.await.unwrap();

    sampler.join().unwrap();
    let peak = rss_peak.load(Ordering::Relaxed);
    lat.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let q = |p: f64| lat[((lat.len() - 1) as f64 * p).round() as usize] * 1e3;
    println!(
        "load: {clients} clients + {diag_clients} on diagnostics, {secs} s, {} requests ({:.0}/s), errors {}, latency ms p50 {:.1} p90 {:.1} p99 {:.1} max {:.1}; jobs started during the load {}; daemon VmRSS {rss_start} kB at start, peak {peak} kB",
        lat.len(),
        lat.len() as f64 / secs as f64,
        errors.len(),
        q(0.5),
        q(0.9),
        q(0.99),
        q(1.0),
        fed.len()
    );
    assert!(
        errors.is_empty(),
        "{} errors, first: {:?}",
        errors.len(),
        &errors[..errors.len().min(5)]
    );
    assert!(lat.len() >= clients, "only {} requests", lat.len());
    assert!(busy, "no job was running at the end of the load");
}
