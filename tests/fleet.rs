//! The fleet acceptance test (issue 20): three station daemons (virtual
//! benches) and one fleet daemon on one real PostgreSQL (a private server
//! from Debian's packages, `.ci/pg`). Each station runs a QC lot of 20 jobs
//! with repeated idempotency keys while other tasks poll. Each station
//! reaches PostgreSQL through its own TCP proxy (in this test, in front of
//! the server's Unix socket); mid-run one station's proxy is cut for 30 s
//! (every connection through it closed, every new one closed at once: the
//! center unreachable from that station alone) while the two others keep
//! delivering, then restored. Afterwards every measurement and verdict is
//! in the center exactly once, each part's measurements in its station's
//! order, each station's item sequence without gaps, and the fleet's SPC
//! equals what the stations' own values give.
//!
//! Without PostgreSQL binaries the test prints why it skips;
//! `SPRINGBENCH_PG_TESTS=require` (set by `.ci/run`) makes that a failure.

mod common;

use common::{client, Daemon};
use serde_json::{json, Value};
use springbench::qc::spc::{compute, SpcPoint};
use springbench_store_pg::test_server::{can_start_private, TestServer};
use springbench_store_pg::PgStore;
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::{TcpListener, UnixStream};
use tokio::task::AbortHandle;

const JOBS: usize = 20;
const RECIPE: &str = "spider-4in";

fn recipe() -> Value {
    json!({
        "name": RECIPE,
        "part_kind": "spider",
        "procedure": {"levels_m": [0.004], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "keff", "quantity": "keff"},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ]
    })
}

async fn get(c: &reqwest::Client, base: &str, path: &str) -> Value {
    let r = c.get(format!("{base}{path}")).send().await.unwrap();
    let s = r.status().as_u16();
    let v: Value = r.json().await.unwrap_or(Value::Null);
    assert_eq!(s, 200, "{path}: {v}");
    v
}

/// A gauge of the station's `/metrics`.
async fn metric(c: &reqwest::Client, d: &Daemon, line: &str) -> f64 {
    let text = c
        .get(d.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    text.lines()
        .find_map(|l| {
            l.strip_prefix(line)
                .map(|v| v.trim().parse::<f64>().unwrap())
        })
        .unwrap_or_else(|| panic!("no {line} in /metrics"))
}

/// Every measurement of a station, oldest first (its storage order).
async fn station_measurements(c: &reqwest::Client, d: &Daemon) -> Vec<Value> {
    let mut out = vec![];
    let mut cursor: Option<String> = None;
    loop {
        let q = cursor
            .as_ref()
            .map_or(String::new(), |b| format!("&cursor={b}"));
        let page = get(c, &d.base, &format!("/api/v1/measurements?limit=7{q}")).await;
        out.extend(page["items"].as_array().unwrap().clone());
        match page["next_cursor"].as_str() {
            Some(b) => cursor = Some(b.to_string()),
            None => break,
        }
    }
    out.reverse();
    out
}

/// Every measurement of a station at the center, oldest first.
async fn center_measurements(c: &reqwest::Client, fleet: &Daemon, station: &str) -> Vec<Value> {
    let mut out = vec![];
    let mut cursor: Option<String> = None;
    loop {
        let q = cursor
            .as_ref()
            .map_or(String::new(), |b| format!("&cursor={b}"));
        let page = get(
            c,
            &fleet.base,
            &format!("/api/v1/fleet/measurements?station={station}&limit=7{q}"),
        )
        .await;
        out.extend(page["items"].as_array().unwrap().clone());
        match page["next_cursor"].as_str() {
            Some(b) => cursor = Some(b.to_string()),
            None => break,
        }
    }
    out.reverse();
    out
}

/// One station's way to the center: a TCP port on loopback forwarding to
/// the server's Unix socket. Cut, it closes every connection through it
/// and every new one as soon as it is accepted; restored, it forwards again.
struct Proxy {
    port: u16,
    cut: Arc<AtomicBool>,
    links: Arc<Mutex<Vec<AbortHandle>>>,
    accept: AbortHandle,
}

impl Proxy {
    async fn start(socket: PathBuf) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let port = listener.local_addr().unwrap().port();
        let cut = Arc::new(AtomicBool::new(false));
        let links: Arc<Mutex<Vec<AbortHandle>>> = Arc::default();
        let (c, l) = (cut.clone(), links.clone());
        let accept = tokio::spawn(async move {
            while let Ok((mut tcp, _)) = listener.accept().await {
                if c.load(Ordering::SeqCst) {
                    continue; // dropped: closed at once
                }
                let socket = socket.clone();
                let link = tokio::spawn(async move {
                    if let Ok(mut unix) = UnixStream::connect(&socket).await {
                        let _ = tokio::io::copy_bidirectional(&mut tcp, &mut unix).await;
                    }
                });
                let mut l = l.lock().unwrap();
                l.retain(|h| !h.is_finished());
                l.push(link.abort_handle());
            }
        })
        .abort_handle();
        Proxy {
            port,
            cut,
            links,
            accept,
        }
    }

    /// The URL a station uses to reach the center through this proxy.
    fn url(&self) -> String {
        format!("postgres://sb@127.0.0.1:{}/postgres", self.port)
    }

    fn cut(&self) {
        self.cut.store(true, Ordering::SeqCst);
        for h in self.links.lock().unwrap().drain(..) {
            h.abort();
        }
    }

    fn restore(&self) {
        self.cut.store(false, Ordering::SeqCst);
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.cut();
        self.accept.abort();
    }
}

/// Items the center holds of each station (`/api/v1/fleet/stations`).
async fn center_items(c: &reqwest::Client, fleet: &Daemon) -> BTreeMap<String, i64> {
    let v = get(c, &fleet.base, "/api/v1/fleet/stations").await;
    v["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["station_id"].as_str().unwrap().to_string(),
                s["items"].as_i64().unwrap(),
            )
        })
        .collect()
}

fn close(a: &Value, b: &Value, what: &str) {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => assert!(
            (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1e-12),
            "{what}: {x} vs {y}"
        ),
        _ => assert_eq!(a, b, "{what}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn three_stations_one_center_outage_nothing_lost_nothing_doubled() {
    if !can_start_private("fleet acceptance test") {
        return;
    }
    let pg = TestServer::start(55471).expect("a private PostgreSQL server");
    let url = pg.url();
    // The center holds the recipe; the stations pull it.
    {
        let center = PgStore::connect(&url).await.unwrap();
        let r: springbench::qc::Recipe = serde_json::from_value(recipe()).unwrap();
        center
            .write_recipe(
                RECIPE,
                &r.sha256(),
                &recipe(),
                "created",
                Some("qc-engineer"),
                springbench::store::qc::RecipeExpect::Absent,
            )
            .await
            .unwrap();
        center.close().await;
    }
    let fleet = Daemon::start(&format!("database = \"{url}\"\nbenches = []"));
    let mut proxies = vec![];
    for _ in 0..3 {
        proxies.push(Proxy::start(pg.socket()).await);
    }
    let stations: Vec<(String, Daemon)> = (1..=3)
        .map(|i| {
            let id = format!("line-{i}");
            let center = proxies[i - 1].url();
            let d = Daemon::start(&format!(
                "[fleet]\ncenter = \"{center}\"\nstation_id = \"{id}\"\nrecordings = \"{}\"\nretry_max_s = 2\nrecipe_poll_s = 5\nbatch_items = 7\n\
                 [[benches]]\nid = \"virtual-1\"\nseed = {}\n",
                if i == 2 { "reference" } else { "full" },
                1000 * i
            ));
            (id, d)
        })
        .collect();
    let c = client();
    // Each station runs the recipe it pulled from the center.
    for (id, d) in &stations {
        let t0 = Instant::now();
        loop {
            let r = c
                .get(d.url(&format!("/api/v1/recipes/{RECIPE}")))
                .send()
                .await
                .unwrap();
            if r.status().as_u16() == 200 {
                break;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "{id} never got the recipe"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    // Concurrent polling while the lots run.
    let polling = Arc::new(AtomicBool::new(true));
    let mut pollers = vec![];
    for (_, d) in &stations {
        let (c, base, on) = (c.clone(), d.base.clone(), polling.clone());
        pollers.push(tokio::spawn(async move {
            let mut n = 0u64;
            while on.load(Ordering::SeqCst) {
                let r = c
                    .get(format!("{base}/api/v1/jobs?limit=50"))
                    .send()
                    .await
                    .unwrap();
                assert_eq!(r.status().as_u16(), 200);
                n += 1;
                tokio::time::sleep(Duration::from_millis(25)).await;
            }
            n
        }));
    }

    // The lots: each job submitted twice with its idempotency key.
    let mut jobs: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for (id, d) in &stations {
        for k in 0..JOBS {
            let body = json!({
                "part": {"serial": format!("{id}-P{k:02}"), "kind": "spider"},
                "recipe": RECIPE,
                "production": {"preset": "spider_4in", "seed": 7 * k as u64 + 1},
            });
            let key = format!("{id}-lot-{k}");
            let mut ids = vec![];
            for expect in [202, 200] {
                let r = c
                    .post(d.url("/api/v1/jobs"))
                    .header("Idempotency-Key", &key)
                    .json(&body)
                    .send()
                    .await
                    .unwrap();
                assert_eq!(r.status().as_u16(), expect, "{key}");
                ids.push(
                    r.json::<Value>().await.unwrap()["id"]
                        .as_str()
                        .unwrap()
                        .to_string(),
                );
            }
            assert_eq!(ids[0], ids[1], "a repeated key is the same job");
            jobs.entry(id.clone()).or_default().push(ids[0].clone());
        }
    }

    // Mid-run: once a third of the jobs are done, the center is cut off
    // from line-2 alone for 30 s.
    const CUT: usize = 1;
    let cut_id = &stations[CUT].0;
    let t0 = Instant::now();
    loop {
        let mut finished = 0;
        for (_, d) in &stations {
            let v = get(&c, &d.base, "/api/v1/jobs?state=succeeded&limit=200").await;
            finished += v["items"].as_array().unwrap().len();
        }
        if finished >= JOBS {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(1800),
            "the lots do not progress"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    proxies[CUT].cut();
    let outage = Instant::now();
    let d_cut = &stations[CUT].1;
    let pending = "springbench_fleet_backlog_items{state=\"pending\"}";
    let backlog_before = metric(&c, d_cut, pending).await;
    let held_before = center_items(&c, &fleet).await;
    while outage.elapsed() < Duration::from_secs(30) {
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    // The cut station kept measuring: its backlog grew, its link is down,
    // and nothing of it reached the center; the two others stayed
    // connected and kept delivering.
    let held_after = center_items(&c, &fleet).await;
    assert!(
        metric(&c, d_cut, pending).await > backlog_before,
        "{cut_id} measured nothing during the outage"
    );
    assert_eq!(metric(&c, d_cut, "springbench_fleet_connected").await, 0.0);
    assert_eq!(
        held_after.get(cut_id),
        held_before.get(cut_id),
        "{cut_id}: items reached the center through a cut link"
    );
    for (i, (id, d)) in stations.iter().enumerate() {
        if i != CUT {
            assert_eq!(
                metric(&c, d, "springbench_fleet_connected").await,
                1.0,
                "{id}"
            );
            assert!(
                held_after.get(id) > held_before.get(id),
                "{id} delivered nothing while {cut_id} was cut off: {held_before:?} -> {held_after:?}"
            );
        }
    }
    proxies[CUT].restore();

    // Every job ends; every station's outbox drains.
    for (id, d) in &stations {
        for j in &jobs[id] {
            let v = common::wait_job(&c, d, j, Duration::from_secs(1800), common::terminal).await;
            assert_eq!(v["state"], "succeeded", "{j}: {v}");
        }
    }
    polling.store(false, Ordering::SeqCst);
    for p in pollers {
        assert!(p.await.unwrap() > 0);
    }
    for (id, d) in &stations {
        let t0 = Instant::now();
        while metric(&c, d, "springbench_fleet_backlog_items{state=\"pending\"}").await > 0.0 {
            assert!(
                t0.elapsed() < Duration::from_secs(300),
                "{id}: the backlog does not drain"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }

    // Exactly once, station by station, in the station's order.
    let center = PgStore::connect(&url).await.unwrap();
    let mut total = 0usize;
    let all_verdicts = get(
        &c,
        &fleet.base,
        &format!("/api/v1/fleet/recipes/{RECIPE}/verdicts?last=1000000"),
    )
    .await;
    let all_verdicts = all_verdicts["items"].as_array().unwrap().clone();
    let ids: BTreeSet<&str> = all_verdicts
        .iter()
        .map(|v| v["id"].as_str().unwrap())
        .collect();
    assert_eq!(
        ids.len(),
        all_verdicts.len(),
        "a verdict twice at the center"
    );
    // A verdict says `offline` exactly when its station could not check its
    // recipes with the center (no recipe sync for two polls): some of the
    // cut station's, none of the others'.
    let mut offline: BTreeMap<String, usize> = BTreeMap::new();
    for v in &all_verdicts {
        let o = v["traceability"]["offline"]
            .as_bool()
            .unwrap_or_else(|| panic!("a verdict without `offline`: {v}"));
        *offline
            .entry(v["station_id"].as_str().unwrap().to_string())
            .or_default() += usize::from(o);
    }
    for (id, _) in &stations {
        let n = offline.get(id).copied().unwrap_or(0);
        if id == cut_id {
            assert!(n > 0, "{id} judged during its outage, none says offline");
        } else {
            assert_eq!(n, 0, "{id} never lost the center, yet judged offline");
        }
    }
    let st_list = get(&c, &fleet.base, "/api/v1/fleet/stations").await;
    for (id, d) in &stations {
        let mine = station_measurements(&c, d).await;
        assert_eq!(mine.len(), JOBS, "{id}: one measurement per job");
        let theirs = center_measurements(&c, &fleet, id).await;
        let a: Vec<&str> = mine.iter().map(|m| m["id"].as_str().unwrap()).collect();
        let b: Vec<&str> = theirs.iter().map(|m| m["id"].as_str().unwrap()).collect();
        assert_eq!(
            a, b,
            "{id}: the center holds each measurement once, in the station's order"
        );
        assert!(theirs.iter().all(|m| m["station_id"] == json!(id)));
        total += b.len();
        // Verdicts: one per measurement of this station, each once.
        let n = all_verdicts
            .iter()
            .filter(|v| v["station_id"] == json!(id))
            .count();
        assert_eq!(n, JOBS, "{id}: measurement verdicts at the center");
        // Per-part order: a part's history at the center is the station's.
        for m in mine.iter().take(3) {
            let serial = m["part_serial"].as_str().unwrap();
            let p = get(&c, &fleet.base, &format!("/api/v1/fleet/parts/{serial}")).await;
            let hist: Vec<&str> = p["measurements"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x["id"].as_str().unwrap())
                .collect();
            let local = get(&c, &d.base, &format!("/api/v1/measurements?part={serial}")).await;
            let local: Vec<&str> = local["items"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x["id"].as_str().unwrap())
                .collect();
            assert_eq!(hist, local, "{serial}");
        }
        // No gaps: the center holds items 1..=last of the station's sequence.
        let last = metric(&c, d, "springbench_fleet_last_seq").await as i64;
        let s = st_list["items"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["station_id"] == json!(id))
            .unwrap_or_else(|| panic!("{id} is not in the station list: {st_list}"));
        assert_eq!(s["last_seq"], json!(last), "{id}: {s}");
        assert_eq!(s["items"], json!(last), "{id}: {s}");
        assert_eq!(s["missing_items"], json!(0), "{id}: {s}");
        assert!(s["backlog_items"].as_i64().is_some_and(|b| b >= 0), "{s}");
        assert_eq!(s["bench_states"][0]["bench_id"], "virtual-1");
        // 20 measurements + 20 job verdict items.
        assert_eq!(last, 2 * JOBS as i64, "{id}");
    }
    let (_, meas, _, _) = center.counts().await.unwrap();
    assert_eq!(meas as usize, total, "nothing else at the center");

    // SPC: each station's subgroup is its own SPC; the fleet's is the
    // stations' values pooled (n, mean, sigma, Pp, Ppk and yield do not
    // depend on how the stations interleave; Cp/Cpk are per station).
    for param in ["keff", "model_error"] {
        let f = get(
            &c,
            &fleet.base,
            &format!("/api/v1/fleet/recipes/{RECIPE}/spc?parameter={param}&last=100000"),
        )
        .await;
        let mut pooled: Vec<SpcPoint> = vec![];
        let mut invalid = 0;
        let (lower, upper) = (None, (param == "model_error").then_some(5.0));
        for (id, d) in &stations {
            let own = get(
                &c,
                &d.base,
                &format!("/api/v1/recipes/{RECIPE}/spc?parameter={param}&last=100000"),
            )
            .await;
            let g = f["stations"]
                .as_array()
                .unwrap()
                .iter()
                .find(|g| g["station_id"] == json!(id))
                .unwrap_or_else(|| panic!("no subgroup {id}: {f}"));
            for k in [
                "n",
                "mean",
                "sigma",
                "sigma_within",
                "cp",
                "cpk",
                "pp",
                "ppk",
                "passed",
                "failed",
                "invalid",
            ] {
                close(&g["spc"][k], &own[k], &format!("{param} {id} {k}"));
            }
            invalid += own["invalid"].as_u64().unwrap() as usize;
            pooled.extend(serde_json::from_value::<Vec<SpcPoint>>(own["points"].clone()).unwrap());
        }
        let want = compute(param, "", lower, upper, pooled, invalid);
        let got = &f["fleet"];
        assert_eq!(got["n"], json!(want.n), "{param}: {got}");
        assert_eq!(want.n, 3 * JOBS, "{param}: one point per job");
        for (k, w) in [
            ("mean", want.mean),
            ("sigma", want.sigma),
            ("pp", want.pp),
            ("ppk", want.ppk),
            ("yield_fraction", want.yield_fraction),
        ] {
            close(&got[k], &json!(w), &format!("{param} fleet {k}"));
        }
    }

    // Bad query parameters are named.
    let r = c
        .get(fleet.url(&format!(
            "/api/v1/fleet/recipes/{RECIPE}/spc?parameter=keff&last=0"
        )))
        .send()
        .await
        .unwrap();
    let p = common::problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "last", "{p}");
    let r = c
        .get(fleet.url("/api/v1/fleet/measurements?statoin=x"))
        .send()
        .await
        .unwrap();
    let p = common::problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "statoin", "{p}");
    center.close().await;
}

/// A recipe version retired while jobs that name it wait in the queue: they
/// are not judged with it (each fails naming the retirement), while the job
/// already running when it was retired keeps the version it started with.
/// (A retirement at the center reaches a station's SQLite the same way:
/// `Store::apply_center_recipes`; this path needs no PostgreSQL.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_jobs_of_a_retired_recipe_version_are_not_judged_with_it() {
    let d = Daemon::start("[[benches]]\nid = \"virtual-1\"\nseed = 5\n");
    let c = client();
    let r = c
        .post(d.url("/api/v1/recipes"))
        .json(&recipe())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201, "{}", r.text().await.unwrap());
    let mut ids = vec![];
    for k in 0..3u64 {
        let r = c
            .post(d.url("/api/v1/jobs"))
            .json(&json!({
                "part": {"serial": format!("R{k}"), "kind": "spider"},
                "recipe": RECIPE,
                "production": {"preset": "spider_4in", "seed": k + 1},
            }))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 202);
        ids.push(
            r.json::<Value>().await.unwrap()["id"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    let r = c
        .delete(d.url(&format!("/api/v1/recipes/{RECIPE}")))
        .header("content-type", "application/json")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 204);
    let mut judged_with_v1 = 0;
    for (k, id) in ids.iter().enumerate() {
        let j = common::wait_job(&c, &d, id, Duration::from_secs(600), common::terminal).await;
        let v = get(&c, &d.base, &format!("/api/v1/jobs/{id}/verdict")).await;
        if j["state"] == "succeeded" {
            // Only the job that had started before the retirement.
            assert_eq!(k, 0, "job {k} judged with a retired version: {v}");
            assert_eq!(v["recipe_version"], 1, "{v}");
            judged_with_v1 += 1;
        } else {
            assert_eq!(j["state"], "failed", "{j}");
            let detail = j["problem"]["detail"].as_str().unwrap_or("");
            assert!(detail.contains("version 1 is retired"), "{j}");
            assert_eq!(v["verdict"], "invalid", "{v}");
            assert!(v["measurements"].as_array().unwrap().is_empty(), "{v}");
        }
    }
    assert!(judged_with_v1 <= 1);
    // A job submitted now is refused at once (nothing to judge with).
    let r = c
        .post(d.url("/api/v1/jobs"))
        .json(&json!({"part": {"serial": "R9"}, "recipe": RECIPE}))
        .send()
        .await
        .unwrap();
    let p = common::problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "recipe", "{p}");
}

const TOKENS: &str = r#"
[[auth.tokens]]
name = "mes"
token = "viewer-token-0123456789"
role = "viewer"
[[auth.tokens]]
name = "qc"
token = "operator-token-0123456789"
role = "operator"
[[auth.tokens]]
name = "lab"
token = "admin-token-0123456789"
role = "admin"
"#;

/// Corrections over a station's API: admin only, a reason required, bad
/// fields named; a void keeps the measurement and takes it out of SPC; a
/// serial correction moves the measurement; the audit log reads them back
/// in order with who made them, and they wait in the fleet outbox.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn corrections_over_the_api_keep_an_audit_trail() {
    let d = Daemon::start(&format!(
        "[[benches]]\nid = \"virtual-1\"\nseed = 3\n{TOKENS}"
    ));
    let c = client();
    let as_ = |tok: &'static str| move |r: reqwest::RequestBuilder| r.bearer_auth(tok);
    let (admin, operator, viewer) = (
        as_("admin-token-0123456789"),
        as_("operator-token-0123456789"),
        as_("viewer-token-0123456789"),
    );
    let r = admin(c.post(d.url("/api/v1/recipes")))
        .json(&recipe())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201, "{}", r.text().await.unwrap());
    let mut mids = vec![];
    for serial in ["C1", "C2"] {
        let r = operator(c.post(d.url("/api/v1/jobs")))
            .json(&json!({"part": {"serial": serial, "kind": "spider"}, "recipe": RECIPE}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 202);
        let id = r.json::<Value>().await.unwrap()["id"]
            .as_str()
            .unwrap()
            .to_string();
        let t = Instant::now();
        let j = loop {
            let j: Value = c
                .get(d.url(&format!("/api/v1/jobs/{id}")))
                .bearer_auth("viewer-token-0123456789")
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
            if common::terminal(j["state"].as_str().unwrap_or(""))
                || t.elapsed() > Duration::from_secs(600)
            {
                break j;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        assert_eq!(j["state"], "succeeded", "{j}");
        mids.push(j["measurement_ids"][0].as_str().unwrap().to_string());
    }
    let read = |path: String| {
        let (c, url) = (c.clone(), d.url(&path));
        async move {
            let r = c
                .get(url)
                .bearer_auth("viewer-token-0123456789")
                .send()
                .await
                .unwrap();
            assert_eq!(r.status().as_u16(), 200, "{path}");
            r.json::<Value>().await.unwrap()
        }
    };
    let spc_ids = || async {
        let s = read(format!(
            "/api/v1/recipes/{RECIPE}/spc?parameter=keff&last=100"
        ))
        .await;
        let ids: Vec<String> = s["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["measurement_id"].as_str().unwrap().to_string())
            .collect();
        (ids, s["n"].as_u64().unwrap())
    };
    assert_eq!(spc_ids().await, (mids.clone(), 2));
    let void = json!({"kind": "void_measurement", "part_serial": "C1", "measurement_id": mids[0],
                      "reason": "clamp was not closed"});
    // Not an admin: refused; the audit log stays empty.
    for who in [operator, viewer] {
        let r = who(c.post(d.url("/api/v1/corrections")))
            .json(&void)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 403);
    }
    // Bad fields, named.
    for (body, field) in [
        (
            json!({"kind": "void_measurement", "part_serial": "C1", "measurement_id": mids[0], "reason": " "}),
            "reason",
        ),
        (
            json!({"kind": "delete", "part_serial": "C1", "reason": "x"}),
            "kind",
        ),
        (
            json!({"kind": "void_measurement", "part_serial": "C2", "measurement_id": mids[0], "reason": "x"}),
            "measurement_id",
        ),
        (
            json!({"kind": "part_kind", "part_serial": "C9", "new_value": "cone", "reason": "x"}),
            "part_serial",
        ),
        (
            json!({"kind": "part_serial", "part_serial": "C2", "reason": "x"}),
            "new_value",
        ),
    ] {
        let r = admin(c.post(d.url("/api/v1/corrections")))
            .json(&body)
            .send()
            .await
            .unwrap();
        let p = common::problem(r, 422).await;
        assert_eq!(p["errors"][0]["field"], field, "{p}");
    }
    assert!(read("/api/v1/corrections".into()).await["items"]
        .as_array()
        .unwrap()
        .is_empty());
    // The void: the measurement stays, out of SPC; a second void conflicts.
    let r = admin(c.post(d.url("/api/v1/corrections")))
        .json(&void)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let v: Value = r.json().await.unwrap();
    assert_eq!(
        (v["kind"].as_str(), v["made_by"].as_str()),
        (Some("void_measurement"), Some("lab"))
    );
    read(format!("/api/v1/measurements/{}", mids[0])).await;
    assert_eq!(spc_ids().await, (vec![mids[1].clone()], 1));
    let r = admin(c.post(d.url("/api/v1/corrections")))
        .json(&void)
        .send()
        .await
        .unwrap();
    common::problem(r, 409).await;
    // C2 was C3: the part and its measurement move, C2 stays (empty).
    let r = admin(c.post(d.url("/api/v1/corrections")))
        .json(&json!({"kind": "part_serial", "part_serial": "C2", "new_value": "C3", "reason": "label misread"}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let m = read(format!("/api/v1/measurements/{}", mids[1])).await;
    assert_eq!(m["measurement"]["part_serial"], "C3", "{m}");
    // The audit log: oldest first, by part, in pages.
    let log = read("/api/v1/corrections".into()).await;
    let got: Vec<(&str, &str, Option<&str>, &str)> = log["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["kind"].as_str().unwrap(),
                e["part_serial"].as_str().unwrap(),
                e["old_value"].as_str(),
                e["reason"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            ("void_measurement", "C1", None, "clamp was not closed"),
            ("part_serial", "C2", Some("C2"), "label misread"),
        ]
    );
    let c3 = read("/api/v1/corrections?part=C3".into()).await;
    assert_eq!(c3["items"].as_array().unwrap().len(), 1);
    let first = log["items"][0]["seq"].as_i64().unwrap();
    let page = read(format!("/api/v1/corrections?after={first}&limit=1")).await;
    assert_eq!(page["items"][0]["kind"], "part_serial");
    let bad = c
        .get(d.url("/api/v1/corrections?limit=0"))
        .bearer_auth("viewer-token-0123456789")
        .send()
        .await
        .unwrap();
    assert_eq!(
        common::problem(bad, 422).await["errors"][0]["field"],
        "limit"
    );
}
