//! The fleet acceptance test (issue 20): three station daemons (virtual
//! benches) and one fleet daemon on one real PostgreSQL (a private server
//! from Debian's packages, `.ci/pg`). Each station runs a QC lot of 20 jobs
//! with repeated idempotency keys while other tasks poll. Each station
//! posts its items to the fleet daemon (the only writer of the center's
//! database, decision 0105) with its own token, through its own TCP proxy
//! (in this test); mid-run one station's proxy is cut for 30 s
//! (every connection through it closed, every new one closed at once: the
//! center unreachable from that station alone) while the two others keep
//! delivering, then restored. Afterwards every measurement and verdict is
//! in the center exactly once, each part's measurements in its station's
//! order, each station's item sequence without gaps, and the fleet's SPC
//! equals what the stations' own values give.
//!
//! Beside it: the fleet role serving the web UI and a station's reads from
//! the center (the same values as at the station, the station in every
//! row), in HTTP and in a browser.
//!
//! Without PostgreSQL binaries the test prints why it skips;
//! `SPRINGBENCH_PG_TESTS=require` (set by `.ci/run`) makes that a failure.

use crate::browser;
use crate::common;
use crate::contract_check;

use browser::Browser;
use common::{Api, Config, Daemon};
use reqwest::Method;
use serde_json::{json, Value};
use springbench::config::Role;
use springbench::qc::spc::{compute, SpcPoint};
use springbench_store_pg::test_server::{can_start_private, TestServer};
use springbench_store_pg::PgStore;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::AbortHandle;

const JOBS: usize = 20;
const MINUTE: Duration = Duration::from_secs(60);

/// A station's secret at the center (its `[fleet] token`, the center's
/// `[[stations]]` entry).
fn station_token(id: &str) -> String {
    format!("tok-{id}-9f2c71ab04d8e6")
}

/// A center (the fleet role) on database `url` that knows the stations
/// `ids`, with `more` configuration (tokens, other stations).
fn center(url: &str, ids: &[&str], more: Config) -> Daemon {
    let mut cfg = more.top(&format!("database = \"{url}\"\nbenches = []"));
    for id in ids {
        cfg = cfg.toml(&format!(
            "[[stations]]\nstation_id = \"{id}\"\ntoken = \"{}\"",
            station_token(id)
        ));
    }
    Daemon::start(&cfg.text())
}

/// A station `id` of the center at `center_url` (its own token), sending
/// recordings as `recordings` (`full` or `reference`), with more `[fleet]`
/// keys `fleet`; its virtual bench's first noise seed is `seed`. The TOML.
fn station_config(center_url: &str, id: &str, recordings: &str, fleet: &str, seed: u64) -> String {
    Config::new()
        .bench("virtual-1", seed)
        .toml(&format!(
            "[fleet]\ncenter = \"{center_url}\"\nstation_id = \"{id}\"\ntoken = \"{}\"\nrecordings = \"{recordings}\"\n{fleet}",
            station_token(id)
        ))
        .text()
}

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

/// A job of the recipe for part `serial`.
fn job(serial: &str) -> Value {
    json!({"part": {"serial": serial, "kind": "spider"}, "recipe": RECIPE})
}

/// The center holds the recipe; the stations pull it.
async fn center_holds_the_recipe(url: &str) {
    center_holds(url, &recipe()).await;
}

/// The center at `url` holds `recipe` (version 1, created by `qc-engineer`),
/// written to its database.
pub(crate) async fn center_holds(url: &str, recipe: &Value) {
    let center = PgStore::connect(url).await.unwrap();
    let r: springbench::qc::Recipe = serde_json::from_value(recipe.clone()).unwrap();
    center
        .write_recipe(
            &r.name,
            &r.sha256(),
            &r,
            "created",
            Some("qc-engineer"),
            springbench::store::qc::RecipeExpect::Absent,
        )
        .await
        .unwrap();
    center.close().await;
}

/// Waits until the station holds version `version` of recipe `name` as
/// `check` wants it; that row.
async fn station_recipe(
    station: &Api,
    name: &str,
    version: i64,
    check: impl Fn(&Value) -> bool,
) -> Value {
    let path = format!("/api/v1/recipes/{name}/versions/{version}");
    station.poll(&path, MINUTE, check).await
}

/// Every listed item of a paged listing (`cursor`), oldest first (the
/// listings serve the newest first).
async fn oldest_first(api: &Api, path: &str) -> Vec<Value> {
    let mut out = api.all_pages(path, "cursor", "next_cursor").await;
    out.reverse();
    out
}

/// One station's way to the center: a TCP port on loopback forwarding to
/// the fleet daemon. Cut, it closes every connection through it
/// and every new one as soon as it is accepted; restored, it forwards again.
struct Proxy {
    port: u16,
    cut: Arc<AtomicBool>,
    links: Arc<Mutex<Vec<AbortHandle>>>,
    accept: AbortHandle,
}

impl Proxy {
    async fn start(target: String) -> Proxy {
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
                let target = target.clone();
                let link = tokio::spawn(async move {
                    if let Ok(mut up) = TcpStream::connect(&target).await {
                        let _ = tokio::io::copy_bidirectional(&mut tcp, &mut up).await;
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
        format!("http://127.0.0.1:{}", self.port)
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
async fn center_items(fleet: &Api) -> BTreeMap<String, i64> {
    let v = fleet.get("/api/v1/fleet/stations").await;
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

/// The ids of a listing's items.
fn ids(items: &[Value]) -> Vec<&str> {
    items.iter().map(|x| x["id"].as_str().unwrap()).collect()
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
    center_holds_the_recipe(&url).await;
    let fleet = center(&url, &["line-1", "line-2", "line-3"], Config::new());
    let fa = Api::new(&fleet);
    let mut proxies = vec![];
    for _ in 0..3 {
        proxies.push(Proxy::start(fleet.addr()).await);
    }
    let stations: Vec<(String, Daemon)> = (1..=3)
        .map(|i| {
            let id = format!("line-{i}");
            let cfg = station_config(
                &proxies[i - 1].url(),
                &id,
                if i == 2 { "reference" } else { "full" },
                "retry_max_s = 2\nrecipe_poll_s = 5\nbatch_items = 7",
                1000 * i as u64,
            );
            (id, Daemon::start(&cfg))
        })
        .collect();
    let apis: Vec<Api> = stations.iter().map(|(_, d)| Api::new(d)).collect();
    // Each station runs the recipe it pulled from the center.
    for a in &apis {
        a.poll(&format!("/api/v1/recipes/{RECIPE}"), MINUTE, |_| true)
            .await;
    }

    // Concurrent polling while the lots run.
    let polling = Arc::new(AtomicBool::new(true));
    let mut pollers = vec![];
    for a in &apis {
        let (a, on) = (a.clone(), polling.clone());
        pollers.push(tokio::spawn(async move {
            let mut n = 0u64;
            while on.load(Ordering::SeqCst) {
                a.get("/api/v1/jobs?limit=50").await;
                n += 1;
                tokio::time::sleep(Duration::from_millis(25)).await;
            }
            n
        }));
    }

    // The lots: each job submitted twice with its idempotency key.
    let mut jobs: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for ((id, _), a) in stations.iter().zip(&apis) {
        for k in 0..JOBS {
            let body = json!({
                "part": {"serial": format!("{id}-P{k:02}"), "kind": "spider"},
                "recipe": RECIPE,
                "production": {"preset": "spider_4in", "seed": 7 * k as u64 + 1},
            });
            let key = format!("{id}-lot-{k}");
            let mut ids = vec![];
            for expect in [202, 200] {
                let r = a.builder(Method::POST, "/api/v1/jobs");
                let v = a
                    .send(r.header("Idempotency-Key", &key).json(&body))
                    .await
                    .expect(expect);
                ids.push(v["id"].as_str().unwrap().to_string());
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
        for a in &apis {
            let v = a.get("/api/v1/jobs?state=succeeded&limit=200").await;
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
    let a_cut = &apis[CUT];
    let pending = "springbench_fleet_backlog_items{state=\"pending\"}";
    let backlog_before = a_cut.metric(pending).await;
    let held_before = center_items(&fa).await;
    while outage.elapsed() < Duration::from_secs(30) {
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    // The cut station kept measuring: its backlog grew, its link is down,
    // and nothing of it reached the center; the two others stayed
    // connected and kept delivering.
    let held_after = center_items(&fa).await;
    assert!(
        a_cut.metric(pending).await > backlog_before,
        "{cut_id} measured nothing during the outage"
    );
    assert_eq!(a_cut.metric("springbench_fleet_connected").await, 0.0);
    assert_eq!(
        held_after.get(cut_id),
        held_before.get(cut_id),
        "{cut_id}: items reached the center through a cut link"
    );
    for (i, ((id, _), a)) in stations.iter().zip(&apis).enumerate() {
        if i != CUT {
            assert_eq!(a.metric("springbench_fleet_connected").await, 1.0, "{id}");
            assert!(
                held_after.get(id) > held_before.get(id),
                "{id} delivered nothing while {cut_id} was cut off: {held_before:?} -> {held_after:?}"
            );
        }
    }
    proxies[CUT].restore();

    // Every job ends; every station's outbox drains.
    for ((id, _), a) in stations.iter().zip(&apis) {
        for j in &jobs[id] {
            let v = a.finished_within(j, Duration::from_secs(1800)).await;
            assert_eq!(v["state"], "succeeded", "{j}: {v}");
        }
    }
    polling.store(false, Ordering::SeqCst);
    for p in pollers {
        assert!(p.await.unwrap() > 0);
    }
    for ((id, _), a) in stations.iter().zip(&apis) {
        let t0 = Instant::now();
        while a.metric(pending).await > 0.0 {
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
    let all_verdicts = fa
        .all_pages(
            &format!("/api/v1/fleet/recipes/{RECIPE}/verdicts?limit=10000"),
            "after",
            "next_after",
        )
        .await;
    let distinct: BTreeSet<&str> = ids(&all_verdicts).into_iter().collect();
    assert_eq!(
        distinct.len(),
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
    let st_list = fa.get("/api/v1/fleet/stations").await;
    for ((id, _), a) in stations.iter().zip(&apis) {
        let mine = oldest_first(a, "/api/v1/measurements?limit=7").await;
        assert_eq!(mine.len(), JOBS, "{id}: one measurement per job");
        let theirs = oldest_first(
            &fa,
            &format!("/api/v1/fleet/measurements?station={id}&limit=7"),
        )
        .await;
        let b = ids(&theirs);
        assert_eq!(
            ids(&mine),
            b,
            "{id}: the center holds each measurement once, in the station's order"
        );
        assert!(theirs.iter().all(|m| m["station_id"] == json!(id)));
        // line-2 sends references only: its WAV is the station's to serve.
        let wav = format!("/api/v1/measurements/{}/recordings/main.wav", b[0]);
        let r = fa.get_reply(&wav).await;
        if id == cut_id {
            let p = r.problem(404);
            assert_eq!(
                p["type"]
                    .as_str()
                    .map(|t| t.ends_with("recording-at-station")),
                Some(true),
                "{p}"
            );
            assert!(p["detail"].as_str().unwrap().contains(id.as_str()), "{p}");
        } else {
            assert_eq!(r.status, 200, "{wav}");
        }
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
            let p = fa.get(&format!("/api/v1/fleet/parts/{serial}")).await;
            let local = a.get(&format!("/api/v1/measurements?part={serial}")).await;
            assert_eq!(
                ids(p["measurements"].as_array().unwrap()),
                ids(local["items"].as_array().unwrap()),
                "{serial}"
            );
        }
        // No gaps: the center holds items 1..=last of the station's sequence.
        let last = a.metric("springbench_fleet_last_seq").await as i64;
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
        let f = fa
            .get(&format!(
                "/api/v1/fleet/recipes/{RECIPE}/spc?parameter={param}&last=100000"
            ))
            .await;
        let mut pooled: Vec<SpcPoint> = vec![];
        let mut invalid = 0;
        let (lower, upper) = (None, (param == "model_error").then_some(5.0));
        for ((id, _), a) in stations.iter().zip(&apis) {
            let own = a
                .get(&format!(
                    "/api/v1/recipes/{RECIPE}/spc?parameter={param}&last=100000"
                ))
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
    for (path, field) in [
        (
            format!("/api/v1/fleet/recipes/{RECIPE}/spc?parameter=keff&last=0"),
            "last",
        ),
        (
            "/api/v1/fleet/measurements?statoin=x".to_string(),
            "statoin",
        ),
    ] {
        let p = fa.get_reply(&path).await.problem(422);
        assert_eq!(p["errors"][0]["field"], field, "{p}");
    }
    center.close().await;
}

/// A recipe version retired while jobs that name it wait in the queue: they
/// are not judged with it (each fails naming the retirement), while the job
/// already running when it was retired keeps the version it started with.
/// (A retirement at the center reaches a station's SQLite the same way:
/// `Store::apply_center_recipes`; this path needs no PostgreSQL.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_jobs_of_a_retired_recipe_version_are_not_judged_with_it() {
    let d = Daemon::start(&Config::new().bench("virtual-1", 5).text());
    let a = Api::new(&d);
    a.create_recipe(&recipe()).await;
    let mut ids = vec![];
    for k in 0..3u64 {
        ids.push(
            a.submit(&json!({
                "part": {"serial": format!("R{k}"), "kind": "spider"},
                "recipe": RECIPE,
                "production": {"preset": "spider_4in", "seed": k + 1},
            }))
            .await,
        );
    }
    let r = a.builder(Method::DELETE, &format!("/api/v1/recipes/{RECIPE}"));
    let r = a.send(r.header("content-type", "application/json")).await;
    assert_eq!(r.status, 204, "{}", r.text);
    let mut judged_with_v1 = 0;
    for (k, id) in ids.iter().enumerate() {
        let j = a.finished(id).await;
        let v = a.get(&format!("/api/v1/jobs/{id}/verdict")).await;
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
    let body = json!({"part": {"serial": "R9"}, "recipe": RECIPE});
    let p = a.post("/api/v1/jobs", &body).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "recipe", "{p}");
}

/// Corrections over a station's API: admin only, a reason required, bad
/// fields named; a void keeps the measurement and takes it out of SPC; a
/// serial correction moves the measurement; the audit log reads them back
/// in order with who made them, and they wait in the fleet outbox.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn corrections_over_the_api_keep_an_audit_trail() {
    let d = Daemon::start(
        &Config::new()
            .token("mes", common::config::VIEWER, Role::Viewer)
            .token("qc", common::config::OPERATOR, Role::Operator)
            .token("lab", common::config::ADMIN, Role::Admin)
            .bench("virtual-1", 3)
            .text(),
    );
    let admin = Api::with(&d, common::config::ADMIN);
    let (operator, viewer) = (
        admin.token(common::config::OPERATOR),
        admin.token(common::config::VIEWER),
    );
    admin.create_recipe(&recipe()).await;
    let mut mids = vec![];
    for serial in ["C1", "C2"] {
        let id = operator.submit(&job(serial)).await;
        let j = viewer.finished(&id).await;
        assert_eq!(j["state"], "succeeded", "{j}");
        mids.push(j["measurement_ids"][0].as_str().unwrap().to_string());
    }
    let spc_ids = || async {
        let s = viewer
            .get(&format!(
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
    let path = "/api/v1/corrections";
    let void = json!({"kind": "void_measurement", "part_serial": "C1", "measurement_id": mids[0],
                      "reason": "clamp was not closed"});
    // Not an admin: refused; the audit log stays empty.
    for who in [&operator, &viewer] {
        assert_eq!(who.post(path, &void).await.status, 403);
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
        let p = admin.post(path, &body).await.problem(422);
        assert_eq!(p["errors"][0]["field"], field, "{p}");
    }
    assert!(viewer.get(path).await["items"]
        .as_array()
        .unwrap()
        .is_empty());
    // The void: the measurement stays, out of SPC; a second void conflicts.
    let v = admin.post(path, &void).await.expect(201);
    assert_eq!(
        (v["kind"].as_str(), v["made_by"].as_str()),
        (Some("void_measurement"), Some("lab"))
    );
    // The measurement stays readable and says that (and by which correction) it was voided.
    let m0 = viewer
        .get(&format!("/api/v1/measurements/{}", mids[0]))
        .await;
    assert_eq!(m0["measurement"]["void_correction_id"], v["id"], "{m0}");
    let m1 = viewer
        .get(&format!("/api/v1/measurements/{}", mids[1]))
        .await;
    assert_eq!(m1["measurement"]["void_correction_id"], Value::Null);
    assert_eq!(spc_ids().await, (vec![mids[1].clone()], 1));
    admin.post(path, &void).await.problem(409);
    // C2 was C3: the part and its measurement move, C2 stays (empty).
    let moved = json!({"kind": "part_serial", "part_serial": "C2", "new_value": "C3", "reason": "label misread"});
    admin.post(path, &moved).await.expect(201);
    let m = viewer
        .get(&format!("/api/v1/measurements/{}", mids[1]))
        .await;
    assert_eq!(m["measurement"]["part_serial"], "C3", "{m}");
    // The audit log: oldest first, by part, in pages.
    let log = viewer.get(path).await;
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
    let c3 = viewer.get("/api/v1/corrections?part=C3").await;
    assert_eq!(c3["items"].as_array().unwrap().len(), 1);
    let first = log["items"][0]["seq"].as_i64().unwrap();
    let page = viewer
        .get(&format!("/api/v1/corrections?after={first}&limit=1"))
        .await;
    assert_eq!(page["items"][0]["kind"], "part_serial");
    let bad = viewer.get_reply("/api/v1/corrections?limit=0").await;
    assert_eq!(bad.problem(422)["errors"][0]["field"], "limit");
}

/// A station (open access) that ran two jobs of the recipe and voided the
/// measurement of the second, everything at the center; and the fleet
/// daemon on the same database.
struct OneStation {
    /// The center's database.
    url: String,
    fleet: Daemon,
    station: Daemon,
    jobs: Vec<String>,
    /// The measurements of each job.
    mids: Vec<Vec<String>>,
    void_id: String,
}

const STATION: &str = "line-7";

async fn one_station_at_the_center(pg: &TestServer) -> OneStation {
    let url = pg.url();
    center_holds_the_recipe(&url).await;
    let fleet = center(&url, &[STATION], Config::new());
    let station = Daemon::start(&station_config(
        &fleet.base,
        STATION,
        "full",
        "retry_max_s = 1",
        7,
    ));
    let s = Api::new(&station);
    s.poll(&format!("/api/v1/recipes/{RECIPE}"), MINUTE, |_| true)
        .await;
    let (mut jobs, mut mids) = (vec![], vec![]);
    for serial in ["U1", "U2"] {
        let id = s.submit(&job(serial)).await;
        let j = s.finished(&id).await;
        assert_eq!(j["state"], "succeeded", "{j}");
        let m = s.get(&format!("/api/v1/measurements?job={id}")).await;
        mids.push(
            ids(m["items"].as_array().unwrap())
                .into_iter()
                .map(str::to_string)
                .collect::<Vec<_>>(),
        );
        jobs.push(id);
    }
    let void = json!({"kind": "void_measurement", "part_serial": "U2",
        "measurement_id": mids[1][0], "reason": "spider torn at the clamp"});
    let v = s.post("/api/v1/corrections", &void).await.expect(201);
    let void_id = v["id"].as_str().unwrap().to_string();
    // Replicated: both jobs' verdicts and the void (the station's last item).
    Api::new(&fleet)
        .poll(
            &format!("/api/v1/measurements/{}", mids[1][0]),
            MINUTE,
            |m| m["measurement"]["void_correction_id"] == json!(void_id),
        )
        .await;
    OneStation {
        url,
        fleet,
        station,
        jobs,
        mids,
        void_id,
    }
}

/// Takes every `station_id` out of `v`; returns how many named `station`
/// (and fails on another station's).
fn strip_station(v: &mut Value, station: &str) -> usize {
    match v {
        Value::Object(m) => {
            let mut n = 0;
            if let Some(s) = m.remove("station_id") {
                assert_eq!(s, json!(station));
                n += 1;
            }
            n + m
                .values_mut()
                .map(|x| strip_station(x, station))
                .sum::<usize>()
        }
        Value::Array(a) => a.iter_mut().map(|x| strip_station(x, station)).sum(),
        _ => 0,
    }
}

/// Takes the times out of every part row (an object with `measurement_count`).
fn without_part_times(v: &mut Value) {
    match v {
        Value::Object(m) => {
            if m.contains_key("measurement_count") {
                m.remove("created_at");
                m.remove("updated_at");
            }
            m.values_mut().for_each(without_part_times);
        }
        Value::Array(a) => a.iter_mut().for_each(without_part_times),
        _ => {}
    }
}

/// The fleet role serves a station's reads that the UI's parts,
/// measurement, compare and QC views use, from the center's store: every
/// answer equals the station's own, value for value, once the station of
/// each row is taken out; each listed row names its station; a void made
/// at the station reads the same at both; nothing that writes or runs a
/// bench is offered at the center.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_center_answers_the_stations_reads_with_the_stations_values() {
    if !can_start_private("center reads test") {
        return;
    }
    let pg = TestServer::start(55472).expect("a private PostgreSQL server");
    let o = one_station_at_the_center(&pg).await;
    let (st, fa) = (Api::new(&o.station), Api::new(&o.fleet));
    let (m1, m2) = (&o.mids[0][0], &o.mids[1][0]);
    let mut paths = vec![
        "/api/v1/parts".to_string(),
        "/api/v1/parts?limit=1".into(),
        "/api/v1/parts/U1".into(),
        "/api/v1/parts/U1/measurements".into(),
        "/api/v1/parts/U1/verdict".into(),
        "/api/v1/parts/U2/verdict".into(),
        "/api/v1/parts/U9".into(),
        format!("/api/v1/measurements?job={}", o.jobs[1]),
        "/api/v1/measurements?part=U1&limit=0".into(),
        "/api/v1/recipes".into(),
        format!("/api/v1/recipes/{RECIPE}"),
        format!("/api/v1/recipes/{RECIPE}/versions"),
        format!("/api/v1/recipes/{RECIPE}/versions/1"),
        format!("/api/v1/recipes/{RECIPE}/spc?parameter=keff&last=100"),
        format!("/api/v1/recipes/{RECIPE}/spc?parameter=nope"),
    ];
    for (j, ms) in o.jobs.iter().zip(&o.mids) {
        paths.push(format!("/api/v1/jobs/{j}/verdict"));
        for m in ms {
            paths.push(format!("/api/v1/measurements/{m}"));
            paths.push(format!("/api/v1/measurements/{m}/fits"));
        }
    }
    let mut named = 0;
    for p in &paths {
        let (a, b) = (st.get_reply(p).await, fa.get_reply(p).await);
        assert_eq!(a.status, b.status, "{p}");
        let status = a.status;
        assert!(!a.body.is_null() && !b.body.is_null(), "{p}: not JSON");
        let (mut a, mut b) = (a.body, b.body);
        if status >= 400 {
            // The same problem: status, type and the field it names.
            assert_eq!(
                (&a["type"], &a["errors"]),
                (&b["type"], &b["errors"]),
                "{p}"
            );
            continue;
        }
        // (A station's verdicts name it in their traceability.)
        let at_station = strip_station(&mut a, STATION);
        named += strip_station(&mut b, STATION) - at_station;
        // A part's times are its own at each: at the station from its first
        // job's submission, at the center from its oldest measurement.
        without_part_times(&mut a);
        without_part_times(&mut b);
        assert_eq!(a, b, "{p}: the center's answer differs from the station's");
    }
    // The recordings, sent in full: the same WAV, byte for byte.
    for file in ["pre.wav", "main.wav"] {
        let url = format!("/api/v1/measurements/{m1}/recordings/{file}");
        let wav = |a: &Api| {
            let r = a.builder(Method::GET, &url);
            async move { r.send().await.unwrap() }
        };
        let (a, b) = (wav(&st).await, wav(&fa).await);
        assert_eq!(
            (a.status().as_u16(), b.status().as_u16()),
            (200, 200),
            "{url}"
        );
        let (a, b) = (a.bytes().await.unwrap(), b.bytes().await.unwrap());
        assert!(
            a.len() > 100_000 && &a[..4] == b"RIFF",
            "{file}: {} bytes",
            a.len()
        );
        assert!(a == b, "{file} differs at the center");
    }
    // Each row a view lists names its station at the center.
    let rows = |v: &Value, k: &str| -> Vec<Value> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|x| x["station_id"].clone())
            .collect()
    };
    let parts = fa.get("/api/v1/parts").await;
    assert_eq!(rows(&parts, "items"), [json!(STATION), json!(STATION)]);
    let ms = fa.get("/api/v1/parts/U1/measurements").await;
    assert_eq!(rows(&ms, "items"), vec![json!(STATION); o.mids[0].len()]);
    let jv = fa.get(&format!("/api/v1/jobs/{}/verdict", o.jobs[0])).await;
    assert_eq!(jv["station_id"], STATION);
    assert!(named >= 10, "{named} rows named the station");
    // The figures themselves, at both: K(x), Keff, the verdict and its value.
    let doc = format!("/api/v1/measurements/{m1}");
    let (a, b) = (st.get(&doc).await, fa.get(&doc).await);
    let keff = a["large_signal"]["keff_n_per_m"].as_f64().unwrap();
    assert!(keff.is_finite() && keff > 0.0, "{keff}");
    assert_eq!(b["large_signal"]["keff_n_per_m"].as_f64(), Some(keff));
    let kx = a["stiffness"]["coefficients_n_per_m_pow_i_plus_1"].clone();
    assert!(kx.as_array().is_some_and(|k| k.len() >= 3), "{kx}");
    assert_eq!(b["stiffness"]["coefficients_n_per_m_pow_i_plus_1"], kx);
    let verdict = a["measurement"]["verdict"]["verdict"].clone();
    assert!(verdict == "pass" || verdict == "fail", "{verdict}");
    assert_eq!(b["measurement"]["verdict"]["verdict"], verdict);
    assert_eq!(b["measurement"]["verdict"]["station_id"], STATION);
    let judged = a["measurement"]["verdict"]["detail"]["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "keff")
        .unwrap()["value"]
        .as_f64()
        .unwrap();
    assert!(judged.is_finite() && judged > 0.0, "{judged}");
    // SPC leaves the voided U2 out at both: one point, the Keff U1 was judged by.
    let spc = fa
        .get(&format!("/api/v1/recipes/{RECIPE}/spc?parameter=keff"))
        .await;
    assert_eq!(
        (spc["n"].as_i64(), spc["mean"].as_f64()),
        (Some(1), Some(judged)),
        "{spc}"
    );
    // A station's chart reads up to 100 000 verdicts, the center's 10 000
    // (docs/fleet.md: 1.5 s for 8 000 there); the center says where to go.
    let wide = format!("/api/v1/recipes/{RECIPE}/spc?parameter=keff&last=10001");
    assert_eq!(st.get(&wide).await["n"], 1);
    let p = fa.get_reply(&wide).await.problem(422);
    assert!(
        p["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("/api/v1/fleet/recipes/"),
        "{p}"
    );
    let voided = fa.get(&format!("/api/v1/measurements/{m2}")).await;
    assert_eq!(
        voided["measurement"]["void_correction_id"],
        json!(o.void_id)
    );
    // The center offers no job, bench or write.
    assert_eq!(fa.get("/api/v1/session").await["daemon"], "center");
    assert_eq!(st.get("/api/v1/session").await["daemon"], "station");
    for p in [
        "/api/v1/jobs",
        "/api/v1/benches",
        "/api/v1/events",
        "/api/v1/gauge-studies",
    ] {
        fa.get_reply(p).await.problem(404);
    }
    let body = json!({"part": {"serial": "U3"}});
    fa.post("/api/v1/jobs", &body).await.problem(405);
    assert!(fa.text("/").await.contains("/ui/app.js"));
    fleet_role_contract(&o).await;
}

/// Every route of the fleet role (its `/api/v1/fleet/...` and the station's
/// reads it serves) against the OpenAPI document, strictly as
/// `tests/it/contract.rs` checks a station's: each answers a validated success
/// and, where it takes parameters, a 422 naming the bad one.
async fn fleet_role_contract(o: &OneStation) {
    let fa = Api::new(&o.fleet);
    let mut k = contract_check::Contract::new(
        serde_json::from_str(springbench::api::openapi::json()).unwrap(),
    );
    let (m1, m2, j1) = (&o.mids[0][0], &o.mids[1][0], &o.jobs[0]);
    let r = RECIPE;
    let f = "/api/v1/fleet";
    // Recipes authored at the center (decision 0106): a proposal of new
    // limits and its rejection, validated as the document says.
    let mut tighter = recipe();
    tighter["parameters"][1]["upper"] = json!(4.0);
    let route = "/api/v1/fleet/recipe-proposals";
    let mut posted = vec![];
    for body in [
        json!({"recipe": tighter, "base_version": 1, "note": "tighter"}),
        json!({"recipe": {"name": r}}),
    ] {
        let resp = fa.builder(Method::POST, route).json(&body).send().await;
        posted.push(k.take("post", route, resp.unwrap()).await);
    }
    assert_eq!(posted[0].0, 201, "{}", posted[0].1);
    assert_eq!(posted[0].1["kind"], "limits", "{}", posted[0].1);
    assert_eq!(posted[1].0, 422, "{}", posted[1].1);
    assert_eq!(
        posted[1].1["errors"][0]["field"], "recipe",
        "{}",
        posted[1].1
    );
    let pid = posted[0].1["id"].as_str().unwrap().to_string();
    #[rustfmt::skip]
    let cases: Vec<(&str, String, u16, Option<&str>)> = vec![
        ("/healthz", "/healthz".into(), 200, None),
        ("/api/v1/session", "/api/v1/session".into(), 200, None),
        ("/api/v1/fleet/stations", format!("{f}/stations"), 200, None),
        ("/api/v1/fleet/stations", format!("{f}/stations?x=1"), 422, Some("x")),
        ("/api/v1/fleet/parts", format!("{f}/parts"), 200, None),
        ("/api/v1/fleet/parts", format!("{f}/parts?limit=0"), 422, Some("limit")),
        ("/api/v1/fleet/parts/{serial}", format!("{f}/parts/U1"), 200, None),
        ("/api/v1/fleet/parts/{serial}", format!("{f}/parts/U9"), 404, None),
        ("/api/v1/fleet/measurements", format!("{f}/measurements?station={STATION}"), 200, None),
        ("/api/v1/fleet/measurements", format!("{f}/measurements?part=U1&job={j1}"), 200, None),
        ("/api/v1/fleet/measurements", format!("{f}/measurements?cursor=x"), 422, Some("cursor")),
        ("/api/v1/fleet/measurements", format!("{f}/measurements?station={STATION}&part=U1"), 422, Some("station")),
        ("/api/v1/fleet/measurements/{id}", format!("{f}/measurements/{m2}"), 200, None),
        ("/api/v1/fleet/measurements/{id}", format!("{f}/measurements/nope"), 404, None),
        ("/api/v1/fleet/recipes", format!("{f}/recipes"), 200, None),
        ("/api/v1/fleet/recipes", format!("{f}/recipes?x=1"), 422, Some("x")),
        ("/api/v1/fleet/recipes/{name}/verdicts", format!("{f}/recipes/{r}/verdicts"), 200, None),
        ("/api/v1/fleet/recipes/{name}/verdicts", format!("{f}/recipes/{r}/verdicts?last=0"), 422, Some("last")),
        ("/api/v1/fleet/recipe-proposals", format!("{f}/recipe-proposals?recipe={r}&state=proposed"), 200, None),
        ("/api/v1/fleet/recipe-proposals", format!("{f}/recipe-proposals?state=maybe"), 422, Some("state")),
        ("/api/v1/fleet/recipe-proposals/{id}", format!("{f}/recipe-proposals/{pid}"), 200, None),
        ("/api/v1/fleet/recipe-proposals/{id}", format!("{f}/recipe-proposals/nope"), 404, None),
        // Issue 36: last=1000000 took the center to 6.3 GB; capped at 10 000.
        ("/api/v1/fleet/recipes/{name}/verdicts", format!("{f}/recipes/{r}/verdicts?last=1000000"), 422, Some("last")),
        ("/api/v1/fleet/recipes/{name}/spc", format!("{f}/recipes/{r}/spc?parameter=keff"), 200, None),
        ("/api/v1/fleet/recipes/{name}/spc", format!("{f}/recipes/{r}/spc"), 422, Some("parameter")),
        ("/api/v1/fleet/recipes/{name}/spc", format!("{f}/recipes/nope/spc?parameter=keff"), 404, None),
        ("/api/v1/fleet/recipes/{name}/yield", format!("{f}/recipes/{r}/yield"), 200, None),
        ("/api/v1/fleet/recipes/{name}/yield", format!("{f}/recipes/{r}/yield?since=yesterday"), 422, Some("since")),
        ("/api/v1/fleet/audit", format!("{f}/audit?part=U2"), 200, None),
        ("/api/v1/fleet/audit", format!("{f}/audit?after=-1"), 422, Some("after")),
        ("/api/v1/fleet/refusals", format!("{f}/refusals"), 200, None),
        ("/api/v1/fleet/refusals", format!("{f}/refusals?limit=0"), 422, Some("limit")),
        ("/api/v1/parts", "/api/v1/parts".into(), 200, None),
        ("/api/v1/parts", "/api/v1/parts?limit=0".into(), 422, Some("limit")),
        ("/api/v1/parts/{serial}", "/api/v1/parts/U1".into(), 200, None),
        ("/api/v1/parts/{serial}", "/api/v1/parts/U9".into(), 404, None),
        ("/api/v1/parts/{serial}/measurements", "/api/v1/parts/U1/measurements".into(), 200, None),
        ("/api/v1/parts/{serial}/measurements", "/api/v1/parts/U1/measurements?limit=0".into(), 422, Some("limit")),
        ("/api/v1/parts/{serial}/verdict", "/api/v1/parts/U1/verdict".into(), 200, None),
        ("/api/v1/parts/{serial}/verdict", "/api/v1/parts/U2/verdict".into(), 404, None),
        ("/api/v1/measurements", format!("/api/v1/measurements?job={j1}"), 200, None),
        ("/api/v1/measurements", "/api/v1/measurements?since=x".into(), 422, Some("since")),
        ("/api/v1/measurements/{id}", format!("/api/v1/measurements/{m1}"), 200, None),
        ("/api/v1/measurements/{id}", format!("/api/v1/measurements/{m2}"), 200, None),
        ("/api/v1/measurements/{id}/fits", format!("/api/v1/measurements/{m1}/fits"), 200, None),
        ("/api/v1/measurements/{id}/recordings/{file}", format!("/api/v1/measurements/{m1}/recordings/main.wav"), 200, None),
        ("/api/v1/measurements/{id}/recordings/{file}", format!("/api/v1/measurements/{m1}/recordings/x.wav"), 404, None),
        ("/api/v1/jobs/{id}/verdict", format!("/api/v1/jobs/{j1}/verdict"), 200, None),
        ("/api/v1/recipes", "/api/v1/recipes".into(), 200, None),
        ("/api/v1/recipes/{name}", format!("/api/v1/recipes/{r}"), 200, None),
        ("/api/v1/recipes/{name}/versions", format!("/api/v1/recipes/{r}/versions"), 200, None),
        ("/api/v1/recipes/{name}/versions/{version}", format!("/api/v1/recipes/{r}/versions/1"), 200, None),
        ("/api/v1/recipes/{name}/versions/{version}", format!("/api/v1/recipes/{r}/versions/9"), 404, None),
        ("/api/v1/recipes/{name}/spc", format!("/api/v1/recipes/{r}/spc?parameter=keff"), 200, None),
        ("/api/v1/recipes/{name}/spc", format!("/api/v1/recipes/{r}/spc?parameter=keff&format=csv"), 200, None),
        ("/api/v1/recipes/{name}/spc", format!("/api/v1/recipes/{r}/spc?parameter=nope"), 422, Some("parameter")),
        ("/api/v1/recipes/{name}/spc", format!("/api/v1/recipes/{r}/spc?parameter=keff&last=10001"), 422, Some("last")),
    ];
    // The same center with tokens: every route needs one (a viewer's
    // does), but /healthz, /api/v1/session and the UI's pages.
    let guarded = Daemon::start(
        &Config::roles()
            .top(&format!("database = \"{}\"\nbenches = []", o.url))
            .text(),
    );
    let (anyone, viewer) = (
        Api::new(&guarded),
        Api::with(&guarded, common::config::VIEWER),
    );
    for (route, url, status, _) in &cases {
        let open = ["/healthz", "/api/v1/session"].contains(route);
        assert_eq!(
            anyone.get_reply(url).await.status,
            if open { 200 } else { 401 },
            "{url} without a token"
        );
        assert_eq!(
            viewer.get_reply(url).await.status,
            *status,
            "{url} as a viewer"
        );
    }
    for page in ["/", "/ui/app.js", "/ui/qc.js"] {
        assert_eq!(anyone.get_reply(page).await.status, 200, "{page}");
    }
    // Issue 36: a NUL or another control byte is a 400 without the
    // database's text (it was a 500 carrying it); /readyz and /metrics.
    for bad in [
        "/api/v1/fleet/parts/%00",
        "/api/v1/fleet/measurements?part=a%00b",
        "/api/v1/fleet/audit?part=%1b",
        "/api/v1/parts/%ff%fe",
    ] {
        let r = fa.get_reply(bad).await;
        assert_eq!(r.status, 400, "{bad}: {}", r.text);
        assert!(
            !r.text.contains("byte sequence") && !r.text.contains("database"),
            "{bad}: {}",
            r.text
        );
    }
    assert_eq!(fa.get_reply("/readyz").await.status, 200);
    let held = fa
        .metric(&format!(
            "springbench_center_station_items{{station=\"{STATION}\"}} "
        ))
        .await;
    assert!(held >= 4.0, "{held}");
    let s = viewer.get("/api/v1/session").await;
    assert_eq!(
        (&s["role"], &s["daemon"]),
        (&json!("viewer"), &json!("center"))
    );
    for (route, url, status, field) in cases {
        let resp = fa.builder(Method::GET, &url).send().await.unwrap();
        let (got, v) = k.take("get", route, resp).await;
        assert_eq!(got, status, "GET {url}: {v}");
        if let Some(field) = field {
            assert_eq!(v["errors"][0]["field"], field, "GET {url}: {v}");
        }
    }
    let fleet_routes = springbench::api::fleet::paths()
        .into_iter()
        .chain(springbench::api::fleet::station_paths())
        .chain(["/healthz"])
        // Checked against the document where a long-term test runs:
        // a_long_term_test_is_at_the_center_read_only_while_it_runs_and_after.
        .filter(|p| !p.starts_with("/api/v1/long-term-tests"));
    for p in fleet_routes {
        let seen = k.seen.get(&("get".to_string(), p.to_string()));
        assert!(
            seen.is_some_and(|st| st.iter().any(|s| *s < 300)),
            "the fleet role's GET {p}: no validated success"
        );
    }
}

/// The web UI on a center, in a browser: the parts, measurement, compare
/// and QC views show the station's data with the station named, the same
/// figures as the same views on the station, and no job or bench control.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ui_on_the_center_shows_the_stations_data() {
    if !can_start_private("center UI test") {
        return;
    }
    let _one = browser::ONE_AT_A_TIME.lock().await;
    let Some(mut b) = Browser::start().await else {
        return;
    };
    let pg = TestServer::start(55474).expect("a private PostgreSQL server");
    let o = one_station_at_the_center(&pg).await;
    let (m1, m2) = (&o.mids[0][0], &o.mids[1][0]);
    const T: Duration = Duration::from_secs(30);
    let (center, station) = (o.fleet.base.clone(), o.station.base.clone());
    // Parts: both, each with its station; no operator view.
    b.goto(&format!("{center}/#/parts")).await;
    b.wait_js(
        "document.querySelectorAll('#parts tr[data-serial]').length === 2",
        T,
        "the parts at the center",
    )
    .await;
    let cells = b
        .js(
            "return [...document.querySelectorAll('#parts td.station')].map((e) => e.textContent);",
            vec![],
        )
        .await;
    assert_eq!(cells, json!([STATION, STATION]));
    assert!(b.exists("#daemon-center").await);
    assert_eq!(
        b.js(
            "return document.querySelector('a[data-view=operator]').hidden;",
            vec![]
        )
        .await,
        json!(true)
    );
    b.assert_no_console_errors("on the center's parts view")
        .await;
    // A part: its measurements with their station, its verdict, no jobs table.
    b.goto(&format!("{center}/#/part/U1")).await;
    b.wait_js(
        "document.querySelector('#part-measurements td.station')",
        T,
        "U1's measurements",
    )
    .await;
    assert_eq!(b.text("#part-measurements td.station").await, STATION);
    assert!(b.exists("#part-jobs-center").await && !b.exists("#part-jobs").await);
    let verdict = b
        .js(
            "return document.querySelector('#part-verdict').dataset.verdict;",
            vec![],
        )
        .await;
    assert!(verdict == "pass" || verdict == "fail", "{verdict}");
    b.assert_no_console_errors("on the center's part view")
        .await;
    // A view's text at the station and at the center (the station named at the center only).
    async fn shown(b: &Browser, url: String, ready: &str, css: &str) -> Vec<String> {
        b.goto(&url).await;
        b.wait_js(ready, T, css).await;
        let v = b
            .js(
                &format!("return [...document.querySelectorAll('{css}')].map((e) => e.innerText);"),
                vec![],
            )
            .await;
        serde_json::from_value(v).unwrap()
    }
    let fig = "#figures, #coefficients, #measurement-verdict-parameters";
    let ready = "document.querySelector('#figures') && document.querySelector('#plot-kx canvas')";
    let at_station = shown(&b, format!("{station}/#/measurement/{m1}"), ready, fig).await;
    let at_center = shown(&b, format!("{center}/#/measurement/{m1}"), ready, fig).await;
    assert_eq!(at_station.len(), 3, "{at_station:?}");
    assert_eq!(
        at_center, at_station,
        "the measurement's figures differ at the center"
    );
    assert_eq!(b.text("#trace-station").await, STATION);
    assert!(b.text("#measurement-origin").await.contains(STATION));
    assert!(b.exists("#center-recordings").await && !b.exists("#open-diagnostics").await);
    assert!(!b.exists("#headline-base").await && !b.exists("#fit-list button").await);
    b.assert_no_console_errors("on the center's measurement view")
        .await;
    b.goto(&format!("{center}/#/measurement/{m2}")).await;
    b.wait_js(
        "document.querySelector('#measurement-void')",
        T,
        "the void at the center",
    )
    .await;
    // Compare: the same rows, the station beside the part at the center.
    let rows = "#compare-rows tr[data-measurement]";
    let ready = "document.querySelectorAll('#compare-rows tr[data-measurement]').length === 2 && document.querySelector('#plot-compare canvas')";
    let at_station = shown(
        &b,
        format!("{station}/#/compare?ids={m1},{m2}"),
        ready,
        rows,
    )
    .await;
    let at_center = shown(&b, format!("{center}/#/compare?ids={m1},{m2}"), ready, rows).await;
    let named = format!(" ({STATION})");
    assert!(
        at_center.iter().all(|r| r.contains(&named)),
        "{at_center:?}"
    );
    let at_center: Vec<String> = at_center
        .iter()
        .map(|r| r.replacen(&named, "", 1))
        .collect();
    assert_eq!(at_center, at_station);
    b.assert_no_console_errors("on the center's compare view")
        .await;
    // The measurement's printable report: the same parameters.
    let ready =
        "document.querySelector('#report-parameters') && document.querySelector('#report-kx svg')";
    let params = "#report-parameters";
    let at_station = shown(&b, format!("{station}/#/report/{m1}"), ready, params).await;
    let at_center = shown(&b, format!("{center}/#/report/{m1}"), ready, params).await;
    assert_eq!(
        at_center, at_station,
        "the report's parameters differ at the center"
    );
    b.assert_no_console_errors("on the center's printable report")
        .await;
    // QC: the recipe's SPC as at the station, and per station.
    let stats =
        "document.querySelector('#spc-stats') && document.querySelector('#spc-stats').dataset.n";
    let qc = format!("/#/qc/{RECIPE}?parameter=keff");
    let at_station = shown(&b, format!("{station}{qc}"), stats, "#spc-stats").await;
    b.goto(&format!("{center}{qc}")).await;
    b.wait_js(
        "document.querySelector('#spc-per-station tr[data-station]')",
        T,
        "SPC per station",
    )
    .await;
    let at_center = b
        .js(
            "return [document.querySelector('#spc-stats').innerText];",
            vec![],
        )
        .await;
    assert_eq!(at_center, json!(at_station), "SPC differs at the center");
    let n = b
        .js(
            "return document.querySelector('#spc-stats').dataset.n;",
            vec![],
        )
        .await;
    assert_eq!(n, json!("1"), "U2 is voided: one point");
    let per = b
        .js("return [...document.querySelectorAll('#spc-per-station tr[data-station]')].map((r) => [r.dataset.station, r.dataset.n]);", vec![])
        .await;
    assert_eq!(per, json!([[STATION, "1"]]));
    assert!(b.exists("#center-station-only").await && !b.exists("#gauge").await);
    b.screenshot("center-qc").await;
    b.assert_no_console_errors("on the center's QC view").await;
    // The operator view says why it is not here.
    b.goto(&format!("{center}/#/operator")).await;
    b.wait_js(
        "document.querySelector('#center-note')",
        T,
        "the center's note",
    )
    .await;
    b.assert_no_console_errors("on the center").await;
    b.quit().await;
}

/// Waits until the center holds measurement `id`; its document.
async fn at_center(fleet: &Api, id: &str, within: Duration) -> Value {
    let path = format!("/api/v1/fleet/measurements/{id}");
    fleet.poll(&path, within, |_| true).await
}

/// Issue 36's attacks (decision 0105), each of which went through before:
/// with everything in station B's configuration (it held the center's
/// database URL and owner role, now the center's HTTP URL and B's token),
/// B cannot delete, change or void A's data at the center; B's token
/// claiming A's id is refused and listed; a void of A's measurement forged
/// in B's own SQLite is refused, listed at the center with its reason,
/// parked at B with it, and B's next measurement still arrives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_station_cannot_write_as_another_and_a_refused_item_does_not_stop_it() {
    if !can_start_private("fleet identity test") {
        return;
    }
    let pg = TestServer::start(55475).expect("a private PostgreSQL server");
    let url = pg.url();
    center_holds_the_recipe(&url).await;
    let retired = format!(
        "[[stations]]\nstation_id = \"line-r\"\ntoken = \"{}\"\nretired = true",
        station_token("line-r")
    );
    let fleet = center(&url, &["line-a", "line-b"], Config::new().toml(&retired));
    let fa = Api::new(&fleet);
    let station = |id: &str, seed: u64| {
        let cfg = station_config(&fleet.base, id, "reference", "retry_max_s = 2", seed);
        (Daemon::start(&cfg), cfg)
    };
    let (a, _) = station("line-a", 11);
    let (b, b_cfg) = station("line-b", 12);
    let (sa, sb) = (Api::new(&a), Api::new(&b));
    for s in [&sa, &sb] {
        s.poll(&format!("/api/v1/recipes/{RECIPE}"), MINUTE, |_| true)
            .await;
    }
    let ma = sa.measured(&job("A-1")).await;
    let a_doc = at_center(&fa, &ma[0], MINUTE).await;
    assert_eq!(a_doc["measurement"]["station_id"], "line-a");

    // B's configuration holds no credential of the center's database: the
    // direct DELETE / UPDATE of before has nothing to connect with.
    assert!(!b_cfg.contains("postgres"), "{b_cfg}");
    let b_center = b_cfg
        .lines()
        .find_map(|l| l.strip_prefix("center = \""))
        .unwrap()
        .trim_end_matches('"');
    assert!(
        PgStore::connect(b_center).await.is_err(),
        "B's center URL opens the database"
    );
    // The readers' API writes nothing, with B's token or any.
    let as_b = fa.token(&station_token("line-b"));
    let a_path = format!("/api/v1/fleet/measurements/{}", ma[0]);
    for m in [Method::DELETE, Method::PUT, Method::PATCH] {
        let body = json!({"verdict": "fail"});
        let r = as_b.call(m.clone(), &a_path, Some(&body)).await;
        assert_eq!(r.status, 405, "{m}");
    }

    // B's token claiming A's id: refused, and the readers see it.
    let (hello, items) = ("/api/v1/fleet/ingest/hello", "/api/v1/fleet/ingest/items");
    let hello_of = |id: &str| {
        json!({"station_id": id, "software_version": "x", "bench_states": [],
            "backlog_items": 0, "sent_at": "2026-11-28T00:00:00.000Z"})
    };
    let p = as_b.post(hello, &hello_of("line-a")).await.expect(403);
    assert!(
        p["type"]
            .as_str()
            .unwrap_or("")
            .ends_with("station-mismatch"),
        "{p}"
    );
    let none_of_a = json!({"station_id": "line-a", "items": []});
    as_b.post(items, &none_of_a).await.expect(403);
    // No token, a reader's token: 401.
    let stranger = fa.token("not-a-station-token-0123");
    stranger.post(items, &none_of_a).await.expect(401);
    // A retired station's token: refused, with its history kept and the
    // attempt listed.
    let as_r = fa.token(&station_token("line-r"));
    let p = as_r.post(hello, &hello_of("line-r")).await.expect(403);
    assert!(
        p["type"]
            .as_str()
            .unwrap_or("")
            .ends_with("station-retired"),
        "{p}"
    );
    let retired = fa.get("/api/v1/fleet/refusals?station=line-r").await;
    assert!(
        retired["items"][0]["reason"]
            .as_str()
            .unwrap_or("")
            .contains("retired"),
        "{retired}"
    );
    let refusals = fa.get("/api/v1/fleet/refusals?station=line-a").await;
    let by_b: Vec<&Value> = refusals["items"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["credential_station"] == "line-b")
        .collect();
    assert!(!by_b.is_empty(), "{refusals}");
    assert!(by_b[0]["reason"]
        .as_str()
        .unwrap()
        .contains("claims station id 'line-a'"));
    let stations = fa.get("/api/v1/fleet/stations").await;
    let line_a = stations["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["station_id"] == "line-a")
        .unwrap();
    assert!(line_a["refused"].as_i64().unwrap() >= 2, "{line_a}");

    // B, as itself, posts corrections of A's data: refused one by one, with
    // their reasons, nothing changed at the center.
    let correction = |id: &str, kind: &str, m: Option<&str>, new: Option<&str>| {
        json!({"station_id": "line-b", "items": [{"seq": 900, "type": "correction", "id": id,
            "kind": kind, "part_serial": "A-1", "measurement_id": m, "old_value": null,
            "new_value": new, "reason": "forged", "made_by": "intruder",
            "made_at": "2026-11-28T00:00:00.000Z"}]})
    };
    let own_measurements = "its own measurements only";
    for (id, kind, m, new, why) in [
        (
            "forged-void",
            "void_measurement",
            Some(ma[0].as_str()),
            None,
            own_measurements,
        ),
        (
            "forged-move",
            "part_serial",
            Some(ma[0].as_str()),
            Some("B-STOLEN"),
            own_measurements,
        ),
        (
            "forged-kind",
            "part_kind",
            None,
            Some("woofer"),
            "its own parts only",
        ),
    ] {
        let r = as_b.post(items, &correction(id, kind, m, new)).await;
        let p = r.expect(422);
        assert!(p["detail"].as_str().unwrap().contains(why), "{id}: {p}");
    }
    let a_now = fa.get(&a_path).await;
    assert_eq!(a_now["void_correction_id"], Value::Null, "{a_now}");
    assert_eq!(a_now["measurement"]["part_serial"], "A-1");
    let part = fa.get("/api/v1/fleet/parts/A-1").await;
    assert_eq!(part["part"]["kind"], "spider", "{part}");

    // A void of A's measurement forged in B's own SQLite (as someone with
    // B's disk would): B's worker sends it, the center refuses it.
    {
        use sqlx::ConnectOptions;
        let mut db = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(b.dir.join("data").join("springbench.db"))
            .foreign_keys(false)
            .connect()
            .await
            .unwrap();
        sqlx::query(
            "INSERT INTO corrections (id, kind, part_serial, measurement_id, reason, made_by, made_at) \
             VALUES ('sqlite-forged-void', 'void_measurement', 'A-1', ?, 'forged in SQLite', 'intruder', \
             strftime('%Y-%m-%dT%H:%M:%fZ', 'now'))",
        )
        .bind(&ma[0])
        .execute(&mut db)
        .await
        .unwrap();
    }
    let forged = "correction:sqlite-forged-void";
    let r = fa
        .poll(
            "/api/v1/fleet/refusals?station=line-b",
            Duration::from_secs(30),
            |r| {
                r["items"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|x| x["item_id"] == forged)
            },
        )
        .await;
    let x = r["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|x| x["item_id"] == forged)
        .unwrap();
    assert!(
        x["reason"]
            .as_str()
            .unwrap()
            .contains("made by station line-a"),
        "{x}"
    );
    // Parked at B with its reason; B's next measurement still arrives
    // within 30 s of its end.
    let t0 = Instant::now();
    while sb
        .metric("springbench_fleet_backlog_items{state=\"refused\"}")
        .await
        < 1.0
    {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "not parked at the station"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let link = sb.get("/api/v1/fleet/link").await;
    let parked = &link["refused"][0];
    assert_eq!(parked["ref_id"], "sqlite-forged-void", "{link}");
    assert!(
        parked["last_error"]
            .as_str()
            .unwrap_or("")
            .contains("made by station line-a"),
        "{link}"
    );
    assert_eq!(link["stuck"], true, "{link}");
    assert_eq!(sb.metric("springbench_fleet_stuck").await, 1.0);
    let mb = sb.measured(&job("B-1")).await;
    at_center(&fa, &mb[0], Duration::from_secs(30)).await;
    let a_now = fa.get(&a_path).await;
    assert_eq!(a_now["void_correction_id"], Value::Null, "{a_now}");

    // Text the center could not store is refused at the station, before
    // its 202 / 201: a NUL byte in notes, an 8 000-character serial.
    let nul = json!({"part": {"serial": "B-2", "kind": "spider", "notes": "bad\u{0}byte"}, "recipe": RECIPE});
    let p = sb.post("/api/v1/jobs", &nul).await.problem(422);
    assert!(p.to_string().contains("part.notes"), "{p}");
    let long = json!({"kind": "part_serial", "part_serial": "B-1", "new_value": "S".repeat(8000),
        "reason": "label misread"});
    let p = sb.post("/api/v1/corrections", &long).await.problem(422);
    assert!(p.to_string().contains("new_value"), "{p}");
}

/// Issue 36's "recipes authored at the center" (decision 0106): an author
/// proposes a recipe at the center, an approver (not the author) approves
/// it; three stations take it, judge a job each with it, and each verdict's
/// traceability names the center's version, its hash and its approver, at
/// the station and at the center. Roles and bad input are refused with
/// the field named; new limits are a proposal of their own; a retirement
/// reaches the stations; a station's local recipe is marked local, is
/// published to the center and comes back as the center's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recipe_authored_at_the_center_is_judged_with_at_three_stations() {
    if !can_start_private("center recipes test") {
        return;
    }
    const NAME: &str = "spider-center";
    let pg = TestServer::start(55476).expect("a private PostgreSQL server");
    let ids = ["line-1", "line-2", "line-3"];
    // The center's readers: a viewer, a recipe author (operator), two
    // approvers (admin).
    let tokens = Config::new()
        .token("mes", "center-viewer-0123456789", Role::Viewer)
        .token("qe-author", "center-author-0123456789", Role::Operator)
        .token("qe-approver", "center-approver-0123456789", Role::Admin)
        .token("qe-lead", "center-lead-0123456789", Role::Admin);
    let fleet = center(&pg.url(), &ids, tokens);
    let anyone = Api::new(&fleet);
    let viewer = anyone.token("center-viewer-0123456789");
    let author = anyone.token("center-author-0123456789");
    let approver = anyone.token("center-approver-0123456789");
    let lead = anyone.token("center-lead-0123456789");
    let stations: Vec<Daemon> = ids
        .iter()
        .enumerate()
        .map(|(i, id)| {
            Daemon::start(&station_config(
                &fleet.base,
                id,
                "reference",
                "retry_max_s = 2\nrecipe_poll_s = 5",
                21 + i as u64,
            ))
        })
        .collect();
    let apis: Vec<Api> = stations.iter().map(Api::new).collect();
    let mut body = recipe();
    body["name"] = json!(NAME);
    let proposal = json!({"recipe": body, "note": "the 4-inch spider, line release"});
    let path = "/api/v1/fleet/recipe-proposals";

    // Roles: nobody without a token, not a viewer; bad fields are named.
    anyone.post(path, &proposal).await.expect(401);
    viewer.post(path, &proposal).await.expect(403);
    let mut bad = proposal.clone();
    bad["recipe"]["parameters"][1]["upper"] = json!("five");
    let p = author.post(path, &bad).await.expect(422);
    assert_eq!(p["errors"][0]["field"], "recipe.parameters[1].upper", "{p}");
    let mut bad = proposal.clone();
    bad["recipe"]["parameters"][1]["lower"] = json!(9.0);
    let p = author.post(path, &bad).await.expect(422);
    assert!(
        p["errors"][0]["field"]
            .as_str()
            .unwrap()
            .starts_with("recipe.parameters[1]"),
        "{p}"
    );
    let mut bad = proposal.clone();
    bad["note"] = json!("a\u{0}b");
    let p = author.post(path, &bad).await.expect(422);
    assert_eq!(p["errors"][0]["field"], "note", "{p}");

    // The author proposes; nothing reaches the stations until approved.
    let p = author.post(path, &proposal).await.expect(201);
    assert_eq!(
        (
            &p["state"],
            &p["kind"],
            &p["proposed_by"],
            &p["base_version"]
        ),
        (
            &json!("proposed"),
            &json!("create"),
            &json!("qe-author"),
            &Value::Null
        ),
        "{p}"
    );
    let id = p["id"].as_str().unwrap().to_string();
    let listed = viewer
        .get(&format!("{path}?recipe={NAME}&state=proposed"))
        .await;
    assert_eq!(listed["items"][0]["id"], json!(id), "{listed}");
    let held = anyone
        .token(&station_token("line-1"))
        .get("/api/v1/fleet/ingest/recipes")
        .await;
    assert!(
        held.as_array().unwrap().iter().all(|r| r["name"] != NAME),
        "{held}"
    );

    // The author may not approve (an approver's role), nor reject.
    let approve = format!("{path}/{id}/approve");
    author.post(&approve, &json!({})).await.expect(403);
    let p = approver.post(&approve, &json!({})).await.expect(201);
    let sha = p["sha256"].as_str().unwrap().to_string();
    assert_eq!(
        (
            &p["version"],
            &p["origin"],
            &p["approved_by"],
            &p["created_by"]
        ),
        (
            &json!(1),
            &json!("created"),
            &json!("qe-approver"),
            &json!("qe-author")
        ),
        "{p}"
    );
    let p = lead.post(&approve, &json!({})).await.expect(409);
    assert!(
        p["type"].as_str().unwrap().ends_with("proposal-decided"),
        "{p}"
    );

    // Each station takes it as the center's and judges a job with it.
    for a in &apis {
        let v = station_recipe(a, NAME, 1, |_| true).await;
        assert_eq!(
            (&v["source"], &v["approved_by"], &v["sha256"]),
            (&json!("center"), &json!("qe-approver"), &json!(sha)),
            "{v}"
        );
    }
    let jobs = futures_util::future::join_all(apis.iter().enumerate().map(|(i, a)| async move {
        let body = json!({"part": {"serial": format!("C-{i}"), "kind": "spider"}, "recipe": NAME});
        let id = a.submit(&body).await;
        let j = a.finished(&id).await;
        assert_eq!(j["state"], "succeeded", "{j}");
        id
    }))
    .await;
    let want_recipe = |t: &Value| {
        assert_eq!(t["recipe"]["name"], NAME, "{t}");
        assert_eq!(t["recipe"]["version"], 1, "{t}");
        assert_eq!(t["recipe"]["sha256"], json!(sha), "{t}");
        assert_eq!(t["recipe"]["origin"]["source"], "center", "{t}");
        assert_eq!(t["recipe"]["origin"]["approved_by"], "qe-approver", "{t}");
        assert_eq!(t["recipe"]["origin"]["proposal_id"], json!(id), "{t}");
    };
    for (a, job) in apis.iter().zip(&jobs) {
        let v = a.get(&format!("/api/v1/jobs/{job}/verdict")).await;
        assert!(
            ["pass", "fail"].contains(&v["verdict"].as_str().unwrap()),
            "{v}"
        );
        want_recipe(&v["traceability"]);
        for m in v["measurements"].as_array().unwrap() {
            want_recipe(&m["traceability"]);
        }
    }
    // At the center: every station's verdicts, each naming the version.
    let v = viewer
        .poll(
            &format!("/api/v1/fleet/recipes/{NAME}/verdicts?last=100"),
            MINUTE,
            |v| {
                let items = v["items"].as_array().cloned().unwrap_or_default();
                let lines: BTreeSet<&str> = items
                    .iter()
                    .filter_map(|x| x["station_id"].as_str())
                    .collect();
                lines.len() == 3
            },
        )
        .await;
    for v in v["items"].as_array().unwrap() {
        want_recipe(&v["traceability"]);
    }

    // New limits are a proposal of their own: kind limits, approved by
    // another approver than its author (an approver who proposed it is
    // refused: four eyes).
    let mut tighter = body.clone();
    tighter["parameters"][1]["upper"] = json!(3.0);
    let lim = json!({"recipe": tighter, "base_version": 1});
    let p = approver.post(path, &lim).await.expect(201);
    assert_eq!(p["kind"], "limits", "{p}");
    let lim_id = p["id"].as_str().unwrap().to_string();
    let lim_approve = format!("{path}/{lim_id}/approve");
    let p = approver.post(&lim_approve, &json!({})).await.expect(403);
    assert!(p["type"].as_str().unwrap().ends_with("own-proposal"), "{p}");
    // A stale base and a rejection without a reason are refused.
    let stale = json!({"recipe": body, "base_version": 7});
    author.post(path, &stale).await.expect(409);
    let r = lead
        .post(&format!("{path}/{lim_id}/reject"), &json!({}))
        .await;
    assert_eq!(r.expect(422)["errors"][0]["field"], "reason");
    let p = lead.post(&lim_approve, &json!({})).await.expect(201);
    assert_eq!(
        (&p["version"], &p["origin"], &p["approved_by"]),
        (&json!(2), &json!("limits_approved"), &json!("qe-lead")),
        "{p}"
    );
    for a in &apis {
        let v = station_recipe(a, NAME, 2, |_| true).await;
        assert_eq!(v["recipe"]["parameters"][1]["upper"], 3.0, "{v}");
    }

    // A station's own recipe is local; published, it is a proposal at the
    // center by that station; approved there, it comes back as the center's.
    let l1 = &apis[0];
    let mut local = recipe();
    local["name"] = json!("spider-line1");
    l1.create_recipe(&local).await;
    let v = station_recipe(l1, "spider-line1", 1, |_| true).await;
    assert_eq!(v["source"], "local", "{v}");
    let r = l1
        .post(&format!("/api/v1/recipes/{NAME}/publish"), &json!({}))
        .await;
    let p = r.problem(409);
    assert!(
        p["type"].as_str().unwrap().ends_with("recipe-not-local"),
        "{p}"
    );
    let note = json!({"note": "tried on line 1"});
    let r = l1.post("/api/v1/recipes/spider-line1/publish", &note).await;
    let p = r.expect(201);
    assert_eq!(
        (
            &p["proposed_by"],
            &p["station_id"],
            &p["station_version"],
            &p["kind"]
        ),
        (
            &json!("station:line-1"),
            &json!("line-1"),
            &json!(1),
            &json!("create")
        ),
        "{p}"
    );
    let pid = p["id"].as_str().unwrap();
    let p = approver
        .post(&format!("{path}/{pid}/approve"), &json!({}))
        .await
        .expect(201);
    assert_eq!(p["version"], 1, "{p}");
    for a in &apis {
        station_recipe(a, "spider-line1", 1, |v| v["source"] == "center").await;
    }

    // Retired at the center: retired at every station.
    let retire = format!("/api/v1/fleet/recipes/{NAME}/retire");
    author.post(&retire, &json!({})).await.expect(403);
    approver.post(&retire, &json!({})).await.expect(204);
    for a in &apis {
        station_recipe(a, NAME, 2, |v| v["retired"] == true).await;
    }
}

/// Issue 32 (decision 0134): a station's long-term test is at the center,
/// read only, while it runs and after: each interval's measurement arrives
/// when the interval is stored, the test's document follows each change,
/// and once the test has ended the center's copy is the station's document
/// value for value (with the station named), the list's line too, and the
/// series' CSV byte for byte from the center's copies of the measurements.
/// The last signals stay at the station (the center's 404 names it); the
/// center offers no write.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_long_term_test_is_at_the_center_read_only_while_it_runs_and_after() {
    if !can_start_private("center long-term test") {
        return;
    }
    let pg = TestServer::start(55477).expect("a private PostgreSQL server");
    let fleet = center(&pg.url(), &[STATION], Config::new());
    let station = Daemon::start(&station_config(
        &fleet.base,
        STATION,
        "full",
        "retry_max_s = 1",
        7,
    ));
    let (s, fa) = (Api::new(&station), Api::new(&fleet));
    // spider_3in loses ~10 % of its K(0) to break-in in its first interval:
    // a 5 % limit stops the test at interval 1, with its last signals.
    let body = json!({
        "measurement": {"part": {"serial": "LT-C1"}, "bench": "virtual-1", "preset": "spider_3in",
                        "target_xpeak_m": 0.006},
        "duration_s": 4.0 * 900.0, "interval_s": 900.0,
        "stimulus": {"excursion_m": 0.0053},
        "failure_limits": {"k0_change_percent": 5.0},
    });
    let id = s.post("/api/v1/long-term-tests", &body).await.expect(202)["id"]
        .as_str()
        .unwrap()
        .to_string();
    let doc_path = format!("/api/v1/long-term-tests/{id}");
    // Interval 0 at the center, and its measurement with it (sent when the
    // interval was stored, whether or not the test has ended by now).
    let first = fa
        .poll(&doc_path, 5 * MINUTE, |d| {
            d["intervals"].as_array().is_some_and(|i| !i.is_empty())
        })
        .await;
    assert_eq!(first["station_id"], STATION, "{first}");
    let m0 = first["intervals"][0]["measurement_id"].as_str().unwrap();
    let m = fa.get(&format!("/api/v1/measurements/{m0}")).await;
    assert_eq!(m["measurement"]["part_serial"], "LT-C1", "{m}");
    // The test ends at the station; the center's copy follows.
    let end = s
        .poll(&doc_path, 5 * MINUTE, |d| {
            common::terminal(d["job"]["state"].as_str().unwrap_or(""))
        })
        .await;
    assert_eq!(end["job"]["state"], "failed", "{end}");
    assert_eq!(end["intervals"].as_array().unwrap().len(), 2);
    let mut at_center = fa
        .poll(&doc_path, MINUTE, |d| {
            d["job"]["state"] == end["job"]["state"]
        })
        .await;
    let copy_seq = at_center["copy_seq"].as_i64().unwrap();
    assert!(copy_seq >= 6, "the copy of outbox item {copy_seq}");
    let o = at_center.as_object_mut().unwrap();
    for k in ["copy_seq", "copy_received_at"] {
        assert!(o.remove(k).is_some(), "{k}");
    }
    assert_eq!(o.remove("station_id"), Some(json!(STATION)));
    assert_eq!(
        at_center, end,
        "the center's copy differs from the station's"
    );
    // Both intervals' measurements, the K(0) of each the same as at the station.
    for iv in end["intervals"].as_array().unwrap() {
        let p = format!(
            "/api/v1/measurements/{}",
            iv["measurement_id"].as_str().unwrap()
        );
        let (a, b) = (s.get(&p).await, fa.get(&p).await);
        let k0 = &a["small_signal"]["k0_n_per_m"];
        assert!(k0.as_f64().is_some_and(|k| k > 1000.0), "{k0}");
        assert_eq!(&b["small_signal"]["k0_n_per_m"], k0);
    }
    // The list's line, and the series' CSV byte for byte.
    let mut line = fa.get("/api/v1/long-term-tests").await["items"][0].clone();
    let o = line.as_object_mut().unwrap();
    assert_eq!(o.remove("station_id"), Some(json!(STATION)));
    o.remove("copy_seq");
    o.remove("copy_received_at");
    assert_eq!(line, s.get("/api/v1/long-term-tests").await["items"][0]);
    let csv = format!("{doc_path}/series.csv");
    let (a, b) = (s.text(&csv).await, fa.text(&csv).await);
    assert_eq!(a.lines().count(), 3, "{a}");
    assert_eq!(a, b, "the series' CSV differs at the center");
    // The last signals: at the station; the center names it.
    let wav = end["last_signals"].as_str().unwrap();
    assert_eq!(s.get_reply(wav).await.status, 200);
    let p = fa.get_reply(wav).await.problem(404);
    assert_eq!(p["type"], "/problems/signals-at-station", "{p}");
    assert!(p["detail"].as_str().unwrap().contains(STATION), "{p}");
    // Every long-term route of the center against the OpenAPI document (the
    // station's schemas), as fleet_role_contract checks the others.
    let mut k = contract_check::Contract::new(
        serde_json::from_str(springbench::api::openapi::json()).unwrap(),
    );
    let lt = "/api/v1/long-term-tests";
    #[rustfmt::skip]
    let cases: Vec<(String, String, u16, Option<&str>)> = vec![
        (lt.into(), lt.into(), 200, None),
        (lt.into(), format!("{lt}?station={STATION}&limit=1"), 200, None),
        (lt.into(), format!("{lt}?limit=0"), 422, Some("limit")),
        (format!("{lt}/{{id}}"), doc_path.clone(), 200, None),
        (format!("{lt}/{{id}}"), format!("{lt}/nope"), 404, None),
        (format!("{lt}/{{id}}/series.csv"), csv.clone(), 200, None),
        (format!("{lt}/{{id}}/series.csv"), format!("{lt}/nope/series.csv"), 404, None),
        (format!("{lt}/{{id}}/last-signals.wav"), wav.to_string(), 404, None),
    ];
    for (route, url, status, field) in cases {
        let resp = fa.builder(Method::GET, &url).send().await.unwrap();
        let (got, v) = k.take("get", &route, resp).await;
        assert_eq!(got, status, "GET {url}: {v}");
        if let Some(field) = field {
            assert_eq!(v["errors"][0]["field"], field, "GET {url}: {v}");
        }
    }
    // Read only: no cancel at the center.
    fa.post_empty(&format!("/api/v1/jobs/{id}/cancel"))
        .await
        .problem(405);
    // The web UI at the center: the list names the station, the test's page
    // the station and its copy, with both intervals' K(x) and no cancel.
    let _one = browser::ONE_AT_A_TIME.lock().await;
    let Some(mut b) = Browser::start().await else {
        return;
    };
    const T: Duration = Duration::from_secs(30);
    b.goto(&format!("{}/#/long-term", fleet.base)).await;
    let row = format!("#lt-list tr[data-id=\"{id}\"]");
    b.wait_js(
        &format!("document.querySelector('{row}')"),
        T,
        "the test in the center's list",
    )
    .await;
    assert_eq!(b.text(&format!("{row} td.station")).await, STATION);
    b.goto(&format!("{}/#/long-term/{id}", fleet.base)).await;
    b.wait_js(
        "document.querySelector('#view').dataset.intervals === '2' && document.querySelector('#lt-station') && document.querySelector('#plot-lt-kx').dataset.curves === '2'",
        T,
        "the test's page at the center",
    )
    .await;
    assert!(b.text("#lt-station").await.contains(STATION));
    assert!(b.text("#lt-problem").await.contains("k0_change_percent"));
    assert!(
        !b.exists("#lt-cancel:not([hidden])").await,
        "no cancel at the center"
    );
    // The printable report is the station's route: not offered at the center.
    assert!(
        !b.exists("#lt-report:not([hidden])").await,
        "no report button at the center"
    );
    fa.get_reply(&format!("{doc_path}/report.html"))
        .await
        .problem(404);
    b.screenshot("center-long-term-test").await;
    b.assert_no_console_errors("on the center's long-term page")
        .await;
    b.quit().await;
}
