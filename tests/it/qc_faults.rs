//! The QC and MES paths under faults and hostile input (issue 24): a full
//! disk on a real tmpfs, a kill -9 during a QC job, stale approvals, role
//! checks per route, hostile MES receivers.
//!
//! The full-disk tests mount a tmpfs (root needed); where mounting is
//! refused they print why and pass without running.

use crate::common;

use common::{client, Api, Daemon, Tmpfs};
use reqwest::Method;
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Fills the file system of `dir` to the last byte; returns the filler file.
fn fill(dir: &Path) -> PathBuf {
    let p = dir.join("filler");
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&p)
        .expect("filler");
    let buf = vec![0x5au8; 1 << 16];
    for chunk in [1 << 16, 4096, 512, 1] {
        while let Ok(n) = f.write(&buf[..chunk]) {
            if n == 0 {
                break;
            }
        }
    }
    let free = springbench::store::health::free_bytes(dir).unwrap();
    assert!(free < 4096, "{free} bytes still free after filling");
    p
}

fn recipe(name: &str) -> Value {
    json!({
        "name": name,
        "part_kind": "spider",
        "procedure": {"levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0"},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ]
    })
}

fn qc_job(serial: &str, recipe: &str, seed: u64) -> Value {
    json!({"part": {"serial": serial, "kind": "spider"}, "recipe": recipe,
           "production": {"preset": "spider_4in", "seed": seed}})
}

const WEBHOOK: &str = "[[mes.webhooks]]\nname = \"mes\"\nurl = \"http://127.0.0.1:9/cfx\"\nsecret = \"0123456789abcdef0123\"\n";

async fn post(c: &reqwest::Client, d: &Daemon, path: &str, body: &Value) -> (u16, Value) {
    let r = c.post(d.url(path)).json(body).send().await.unwrap();
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

async fn wait_state(
    c: &reqwest::Client,
    d: &Daemon,
    id: &str,
    done: impl Fn(&str) -> bool,
) -> Value {
    common::wait_job(c, d, id, Duration::from_secs(300), done).await
}

/// The job's MES deliveries in the outbox (any state): (message name, UniqueID).
async fn job_outbox(c: &reqwest::Client, d: &Daemon, job: &str) -> Vec<(String, String)> {
    let mut out = vec![];
    for state in ["pending", "failed", "delivered"] {
        let o = common::get(c, d, &format!("/api/v1/outbox?state={state}&limit=500")).await;
        for m in o["items"].as_array().unwrap() {
            if m["job_id"] == job {
                let field = |k: &str| m[k].as_str().unwrap().to_string();
                out.push((field("message_name"), field("unique_id")));
            }
        }
    }
    out
}

/// The job's MES messages in the outbox, by message name (one per webhook delivery).
async fn job_messages(c: &reqwest::Client, d: &Daemon, job: &str) -> Vec<String> {
    let mut names: Vec<String> = job_outbox(c, d, job)
        .await
        .into_iter()
        .map(|m| m.0)
        .collect();
    names.sort();
    names
}

const THREE: [&str; 3] = [
    "CFX.Production.TestAndInspection.UnitsTested",
    "CFX.Production.WorkCompleted",
    "CFX.Production.WorkStarted",
];

/// A full disk must not poison the store's pool: a connection whose COMMIT
/// failed goes back inside its transaction, and later transactions on it
/// fail ("begin_with at non-zero transaction depth") after space returned.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_leaves_no_broken_connection_in_the_pool() {
    use springbench::store::qc::RecipeExpect::Any;
    let Some(fs) = Tmpfs::mount("6m") else { return };
    let store = springbench::store::Store::open(fs.path()).await.unwrap();
    let body = |i: usize| -> springbench::qc::Recipe {
        serde_json::from_value(
            json!({"name": "r", "description": format!("{i} {}", "x".repeat(50_000)),
            "procedure": {"levels_m": [0.004]}, "parameters": []}),
        )
        .unwrap()
    };
    for i in 0..5 {
        store
            .write_recipe("r", &format!("{i}"), &body(i), "created", None, Any)
            .await
            .unwrap();
    }
    let filler = fill(fs.path());
    let mut refused = 0;
    for i in 0..60 {
        if store
            .write_recipe("r", &format!("f{i}"), &body(i), "created", None, Any)
            .await
            .is_err()
        {
            refused += 1;
        }
    }
    assert!(
        refused > 0,
        "the full disk refused no write: the fault did not happen"
    );
    std::fs::remove_file(&filler).unwrap();
    let mut errors = vec![];
    for i in 0..40 {
        if let Err(e) = store
            .write_recipe("r", &format!("after{i}"), &body(i), "created", None, Any)
            .await
        {
            errors.push(e.to_string());
        }
    }
    assert!(
        errors.is_empty(),
        "{} of 40 writes failed after space returned: {errors:?}",
        errors.len()
    );
}

/// A QC job accepted with 202 whose results meet a full disk ends `failed`
/// (a stored reason), with an `invalid` verdict and its three MES messages,
/// once space returns; `/readyz` is not ready meanwhile; later submits work.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_meeting_a_full_disk_ends_failed_with_verdict_and_messages() {
    let Some(fs) = Tmpfs::mount("96m") else {
        return;
    };
    let logdir = tempfile::tempdir().unwrap();
    let log = logdir.path().join("daemon.log");
    let extra = format!("min_free_bytes = 1048576\n{WEBHOOK}");
    let d = Daemon::start_logged(fs.path(), &extra, Some(&log));
    let c = client();
    let (s, r) = post(&c, &d, "/api/v1/recipes", &recipe("disk")).await;
    assert_eq!(s, 201, "{r}");
    let (s, j) = post(&c, &d, "/api/v1/jobs", &qc_job("D-1", "disk", 7)).await;
    assert_eq!(s, 202, "{j}");
    let id = j["id"].as_str().unwrap().to_string();
    let j = wait_state(&c, &d, &id, |s| s != "queued").await;
    assert_eq!(j["state"], "running", "{j}");
    let filler = fill(&fs.path().join("data"));
    // The measurement runs on; its results then meet the full disk.
    let t = Instant::now();
    loop {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        if text.contains("storing the results failed") {
            break;
        }
        let j = common::get(&c, &d, &format!("/api/v1/jobs/{id}")).await;
        assert!(
            !common::terminal(j["state"].as_str().unwrap()),
            "the job ended before its results met the full disk: {j}"
        );
        assert!(
            t.elapsed() < Duration::from_secs(300),
            "no storage failure within 300 s"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let r = c.get(d.url("/readyz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 503, "ready while the disk is full");
    std::fs::remove_file(&filler).unwrap();

    let j = wait_state(&c, &d, &id, common::terminal).await;
    assert_eq!(j["state"], "failed", "{j}");
    assert_eq!(j["problem"]["type"], "/problems/storage", "{j}");
    let v = common::get(&c, &d, &format!("/api/v1/jobs/{id}/verdict")).await;
    assert_eq!(v["verdict"], "invalid", "{v}");
    assert_eq!(job_messages(&c, &d, &id).await, THREE);
    let r = c.get(d.url("/readyz")).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "not ready after space returned");

    // No broken connection left behind: every write after the fault works.
    let mut ids = vec![];
    for i in 0..12 {
        let mut body = recipe("disk");
        body["description"] = json!(format!("edit {i}"));
        let r = c
            .put(d.url("/api/v1/recipes/disk"))
            .json(&body)
            .send()
            .await
            .unwrap();
        let s = r.status().as_u16();
        assert!(s == 201, "PUT {i}: {s} {}", r.text().await.unwrap());
        let (s, j) = post(
            &c,
            &d,
            "/api/v1/jobs",
            &qc_job(&format!("D-{}", i + 2), "disk", 8 + i),
        )
        .await;
        // Accepted, or refused by admission (the queue's space), never a 500.
        match s {
            202 => ids.push(j["id"].as_str().unwrap().to_string()),
            503 if j["detail"]
                .as_str()
                .unwrap_or("")
                .contains("disk full for the queue") => {}
            _ => panic!("submit {i}: {s} {j}"),
        }
    }
    assert!(ids.len() >= 2, "{} of 12 submits accepted", ids.len());
    for id in ids.iter().take(2) {
        let j = wait_state(&c, &d, id, common::terminal).await;
        assert_eq!(j["state"], "succeeded", "{j}");
    }
    drop(d);
    drop(fs);
}

/// A kill -9 during a QC job: at restart the job ends `interrupted` with an
/// `invalid` verdict (reason `interrupted`) and its three MES messages.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_cut_off_by_kill_9_gets_its_verdict_and_messages_at_restart() {
    let mut d = Daemon::start(WEBHOOK);
    let c = client();
    let (s, r) = post(&c, &d, "/api/v1/recipes", &recipe("kill")).await;
    assert_eq!(s, 201, "{r}");
    let (s, j) = post(&c, &d, "/api/v1/jobs", &qc_job("K-1", "kill", 3)).await;
    assert_eq!(s, 202, "{j}");
    let id = j["id"].as_str().unwrap().to_string();
    let j = wait_state(&c, &d, &id, |s| s != "queued").await;
    assert_eq!(j["state"], "running", "{j}");
    d.kill9();
    let tmp = d.take_dir().unwrap();
    drop(d);
    let d = Daemon::start_in(tmp.path(), WEBHOOK);
    let j = common::get(&c, &d, &format!("/api/v1/jobs/{id}")).await;
    assert_eq!(j["state"], "interrupted", "{j}");
    let v = common::get(&c, &d, &format!("/api/v1/jobs/{id}/verdict")).await;
    assert_eq!(v["verdict"], "invalid", "{v}");
    assert_eq!(
        v["detail"]["invalid_reasons"][0]["code"], "interrupted",
        "{v}"
    );
    assert_eq!(job_messages(&c, &d, &id).await, THREE);
}

const VIEWER: &str = "viewer-secret-0123456789";
const OPERATOR: &str = "operator-secret-0123456789";
const ADMIN: &str = "admin-secret-0123456789";

fn tokens() -> String {
    [
        ("screen", VIEWER, "viewer"),
        ("station", OPERATOR, "operator"),
        ("engineer", ADMIN, "admin"),
    ]
    .iter()
    .map(|(n, t, r)| format!("[[auth.tokens]]\nname = \"{n}\"\ntoken = \"{t}\"\nrole = \"{r}\"\n"))
    .collect()
}

/// The API with `token`, or without one.
fn api(d: &Daemon, token: Option<&str>) -> Api {
    match token {
        Some(t) => Api::with(d, t),
        None => Api::new(d),
    }
}

/// The role each (method, route template) needs, written down here from the
/// documented policy (docs/http-hardening.md), independently of the daemon.
fn policy(method: &str, route: &str) -> Option<u8> {
    const VIEW: u8 = 1;
    const OPER: u8 = 2;
    const ADM: u8 = 3;
    if [
        "/healthz",
        "/readyz",
        "/api/v1/session",
        "/api/openapi.json",
    ]
    .contains(&route)
    {
        return None;
    }
    let admin_routes = [
        ("get", "/api/v1/config"),
        ("post", "/api/v1/recipes"),
        ("put", "/api/v1/recipes/{name}"),
        ("delete", "/api/v1/recipes/{name}"),
        ("post", "/api/v1/limit-proposals/{id}/approve"),
        ("post", "/api/v1/limit-proposals/{id}/reject"),
        ("post", "/api/v1/outbox/{id}/retry"),
        ("delete", "/api/v1/outbox/{id}"),
        // issue 20: corrections are an admin's; issue 21: how a bench is judged too
        ("post", "/api/v1/corrections"),
        ("post", "/api/v1/recipes/{name}/bench-calibrations"),
        // issue 36: publishing a station's local recipe to the center
        ("post", "/api/v1/recipes/{name}/publish"),
    ];
    Some(if admin_routes.contains(&(method, route)) {
        ADM
    } else if method == "get" {
        VIEW
    } else {
        OPER
    })
}

/// Every route of the OpenAPI document, with each role and without a token,
/// with path parameters named after route words: the role decides by the
/// route the request matched, never by the path's text.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_route_checks_the_role_of_its_matched_template() {
    let d = Daemon::start(&tokens());
    let c = client();
    let doc = common::get(&c, &d, "/api/openapi.json").await;
    let words = [
        "limit-proposals",
        "approve",
        "reject",
        "versions",
        "spc",
        "retry",
        "verdict",
        "cancel",
    ];
    let mut checked = 0;
    let mut wrong = vec![];
    let mut templates = vec![];
    for (route, item) in doc["paths"].as_object().unwrap() {
        for method in ["get", "post", "put", "delete"] {
            if item.get(method).is_none() || route == "/api/v1/events" {
                continue;
            }
            let need = policy(method, route);
            templates.push(format!("{method} {route}"));
            let paths: Vec<String> = if route.contains('{') {
                words
                    .iter()
                    .map(|w| {
                        route
                            .replace("{name}", w)
                            .replace("{id}", w)
                            .replace("{serial}", w)
                            .replace("{file}", w)
                            .replace("{version}", "1")
                            .replace("{index}", "0")
                    })
                    .collect()
            } else {
                vec![route.clone()]
            };
            for path in &paths {
                for (level, token) in [
                    (0u8, None),
                    (1, Some(VIEWER)),
                    (2, Some(OPERATOR)),
                    (3, Some(ADMIN)),
                ] {
                    let m = reqwest::Method::from_bytes(method.to_uppercase().as_bytes()).unwrap();
                    let (s, _) = api(&d, token).exchange(m, path, Some(&json!({}))).await;
                    let expect_refused = match need {
                        None => None,
                        Some(_) if level == 0 => Some(401),
                        Some(n) if level < n => Some(403),
                        Some(_) => None,
                    };
                    let ok = match expect_refused {
                        Some(code) => s == code,
                        None => s != 401 && s != 403,
                    };
                    checked += 1;
                    if !ok {
                        wrong.push(format!(
                            "{method} {path} as level {level}: {s}, expected {expect_refused:?}"
                        ));
                    }
                }
            }
        }
    }
    assert!(checked > 400, "{checked} requests");
    // The long-term test's writes (issue 32, decision 0130) are an operator's.
    for (m, t) in [
        (
            "put",
            "/api/v1/long-term-tests/{id}/intervals/{index}/ambient",
        ),
        ("post", "/api/v1/long-term-tests/{id}/pause"),
        ("post", "/api/v1/long-term-tests/{id}/resume"),
    ] {
        assert!(
            templates.contains(&format!("{m} {t}")),
            "{m} {t} not checked"
        );
        assert_eq!(policy(m, t), Some(2), "{m} {t}");
    }
    // Uploading a stimulus file (decision 0144) is an operator's, reading a viewer's.
    for (m, t, level) in [
        ("post", "/api/v1/stimuli", 2),
        ("get", "/api/v1/stimuli", 1),
        ("get", "/api/v1/stimuli/{id}", 1),
    ] {
        assert!(
            templates.contains(&format!("{m} {t}")),
            "{m} {t} not checked"
        );
        assert_eq!(policy(m, t), Some(level), "{m} {t}");
    }
    // Its printable report (decision 0131) is a viewer's.
    let t = "/api/v1/long-term-tests/{id}/report.html";
    assert!(
        templates.contains(&format!("get {t}")),
        "get {t} not checked"
    );
    assert_eq!(policy("get", t), Some(1));
    assert!(
        wrong.is_empty(),
        "{} of {checked} wrong:\n{}",
        wrong.len(),
        wrong.join("\n")
    );

    // The exploit of the issue: an operator creating a recipe named after a route word.
    for name in ["limit-proposals", "spc", "versions"] {
        let body = recipe(name);
        let path = format!("/api/v1/recipes/{name}");
        let (s, v) = api(&d, Some(OPERATOR))
            .exchange(Method::PUT, &path, Some(&body))
            .await;
        assert_eq!(s, 403, "operator PUT {path}: {v}");
        let (s, v) = api(&d, Some(ADMIN))
            .exchange(Method::PUT, &path, Some(&body))
            .await;
        assert_eq!(s, 201, "admin PUT {path}: {v}");
        assert_eq!(v["created_by"], "engineer");
        let (s, _) = api(&d, Some(OPERATOR))
            .exchange(Method::DELETE, &path, None)
            .await;
        assert_eq!(s, 403, "operator DELETE {path}");
    }
}

/// Runs jobs one after the other and returns their documents (each terminal).
async fn run_all(c: &reqwest::Client, d: &Daemon, bodies: &[Value]) -> Vec<Value> {
    let mut ids = vec![];
    for b in bodies {
        let (s, j) = post(c, d, "/api/v1/jobs", b).await;
        assert_eq!(s, 202, "{j}");
        ids.push(j["id"].as_str().unwrap().to_string());
    }
    let mut out = vec![];
    for id in ids {
        out.push(wait_state(c, d, &id, common::terminal).await);
    }
    out
}

/// A limit proposal is approved only when it was made on the current
/// version of a live recipe: a stale one would undo the engineer's later
/// edits, one of a retired recipe would revive it. Recipe names are unique
/// under concurrency; PUT honours If-Match.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stale_and_retired_approvals_are_refused() {
    let d = Daemon::start("");
    let c = client();
    // Ten concurrent creations of one name: one 201, nine 409.
    let mut tasks = vec![];
    for _ in 0..10 {
        let c = c.clone();
        let url = d.url("/api/v1/recipes");
        tasks.push(tokio::spawn(async move {
            c.post(url)
                .json(&recipe("appr"))
                .send()
                .await
                .unwrap()
                .status()
                .as_u16()
        }));
    }
    let mut codes = vec![];
    for t in tasks {
        codes.push(t.await.unwrap());
    }
    codes.sort();
    assert_eq!(codes, [201, 409, 409, 409, 409, 409, 409, 409, 409, 409]);
    let v = common::get(&c, &d, "/api/v1/recipes/appr/versions").await;
    assert_eq!(v["items"].as_array().unwrap().len(), 1, "{v}");

    let golden: Vec<Value> = (0..5)
        .map(|i| qc_job(&format!("G-{i}"), "appr", 200 + i))
        .collect();
    for j in run_all(&c, &d, &golden).await {
        assert_eq!(j["state"], "succeeded", "{j}");
    }
    let serials: Vec<String> = (0..5).map(|i| format!("G-{i}")).collect();
    let propose = json!({"serials": serials, "method": "k_sigma", "k": 6.0});
    let (s, p1) = post(&c, &d, "/api/v1/recipes/appr/limit-proposals", &propose).await;
    assert_eq!(s, 201, "{p1}");
    assert_eq!(p1["recipe_version"], 1);

    // If-Match: a PUT made on an older version is refused (412).
    let r = c.get(d.url("/api/v1/recipes/appr")).send().await.unwrap();
    let etag1 = r.headers()["etag"].to_str().unwrap().to_string();
    let mut v2 = recipe("appr");
    v2["parameters"][1]["upper"] = json!(2.0);
    v2["parameters"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "f0", "quantity": "f0"}));
    let put_v1 = |body: &Value| {
        let api = Api::new(&d);
        let r = api
            .builder(Method::PUT, "/api/v1/recipes/appr")
            .header("if-match", etag1.as_str())
            .json(body);
        async move { api.send(r).await }
    };
    let r2 = put_v1(&v2).await;
    let (s, h, r2) = (r2.status, r2.headers, r2.body);
    assert_eq!(s, 201, "{r2}");
    assert_eq!(r2["version"], 2);
    assert_ne!(h["etag"].to_str().unwrap(), etag1);
    let mut v3 = v2.clone();
    v3["description"] = json!("made on version 1");
    let r = put_v1(&v3).await;
    let (s, r) = (r.status, r.body);
    assert_eq!(s, 412, "{r}");

    // The proposal made on v1 is stale now: 409, the recipe stays at v2.
    let approve = |id: &str| format!("/api/v1/limit-proposals/{id}/approve");
    let (s, r) = post(&c, &d, &approve(p1["id"].as_str().unwrap()), &json!({})).await;
    assert_eq!(s, 409, "{r}");
    assert_eq!(r["type"], "/problems/proposal-stale", "{r}");
    let cur = common::get(&c, &d, "/api/v1/recipes/appr").await;
    assert_eq!(cur["version"], 2);
    assert_eq!(cur["recipe"]["parameters"][1]["upper"], 2.0);
    assert!(cur["recipe"]["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .any(|p| p["name"] == "f0"));

    // A proposal on v2, then the recipe retired: 409, it stays retired.
    let (s, p2) = post(&c, &d, "/api/v1/recipes/appr/limit-proposals", &propose).await;
    assert_eq!(s, 201, "{p2}");
    assert_eq!(p2["recipe_version"], 2);
    let (s, r) = api(&d, None)
        .exchange(Method::DELETE, "/api/v1/recipes/appr", None)
        .await;
    assert_eq!(s, 204, "{r}");
    let (s, r) = post(&c, &d, &approve(p2["id"].as_str().unwrap()), &json!({})).await;
    assert_eq!(s, 409, "{r}");
    let cur = common::get(&c, &d, "/api/v1/recipes/appr").await;
    assert_eq!(cur["version"], 2);
    assert_eq!(cur["retired"], true);

    // Revived (v3): a proposal on v3 is approved (v4 with its limits).
    let (s, r) = api(&d, None)
        .exchange(Method::PUT, "/api/v1/recipes/appr", Some(&v3))
        .await;
    assert_eq!(s, 201, "{r}");
    assert_eq!(r["version"], 3);
    let (s, p3) = post(&c, &d, "/api/v1/recipes/appr/limit-proposals", &propose).await;
    assert_eq!(s, 201, "{p3}");
    let (s, r) = post(&c, &d, &approve(p3["id"].as_str().unwrap()), &json!({})).await;
    assert_eq!(s, 201, "{r}");
    assert_eq!(r["version"], 4);
    assert_eq!(r["recipe"]["description"], "made on version 1");
}

/// What a test receiver saw: (method, path, UniqueID header).
type Seen = std::sync::Arc<std::sync::Mutex<Vec<(String, String, String)>>>;

#[derive(Clone, Copy)]
enum Receiver {
    /// 200 to everything.
    Healthy,
    /// 303 to a POST (Location /other), 200 to anything else.
    Redirect,
    /// Accepts connections, never answers.
    Hang,
}

/// A raw HTTP/1.1 receiver on an ephemeral port; returns its URL and what it saw.
async fn receiver(kind: Receiver) -> (String, Seen) {
    receiver_on(kind, None).await
}

/// [`receiver`] behind TLS with `tls` (an `https://` URL), or plain.
async fn receiver_on(
    kind: Receiver,
    tls: Option<std::sync::Arc<rustls::ServerConfig>>,
) -> (String, Seen) {
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let scheme = if tls.is_some() { "https" } else { "http" };
    let url = format!("{scheme}://{}/cfx", l.local_addr().unwrap());
    let seen: Seen = Default::default();
    let s2 = seen.clone();
    tokio::spawn(async move {
        let mut held = vec![];
        loop {
            let Ok((sock, _)) = l.accept().await else {
                return;
            };
            if let Receiver::Hang = kind {
                held.push(sock);
                continue;
            }
            let seen = s2.clone();
            match &tls {
                None => {
                    tokio::spawn(answer(sock, kind, seen));
                }
                Some(cfg) => {
                    let acceptor = tokio_rustls::TlsAcceptor::from(cfg.clone());
                    tokio::spawn(async move {
                        // a refused handshake (an untrusting client) ends here
                        if let Ok(s) = acceptor.accept(sock).await {
                            answer(s, kind, seen).await;
                        }
                    });
                }
            }
        }
    });
    (url, seen)
}

/// Answers the requests of one connection as `kind` says, noting each.
async fn answer<S>(sock: S, kind: Receiver, seen: Seen)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
    let mut r = BufReader::new(sock);
    loop {
        let mut line = String::new();
        if r.read_line(&mut line).await.unwrap_or(0) == 0 {
            return;
        }
        let mut parts = line.split_whitespace();
        let (method, path) = (
            parts.next().unwrap_or("").to_string(),
            parts.next().unwrap_or("").to_string(),
        );
        let (mut len, mut uid) = (0usize, String::new());
        loop {
            let mut h = String::new();
            if r.read_line(&mut h).await.unwrap_or(0) == 0 {
                return;
            }
            let h = h.trim_end();
            if h.is_empty() {
                break;
            }
            if let Some((k, v)) = h.split_once(':') {
                match k.trim().to_ascii_lowercase().as_str() {
                    "content-length" => len = v.trim().parse().unwrap_or(0),
                    "x-springbench-unique-id" => uid = v.trim().to_string(),
                    _ => {}
                }
            }
        }
        let mut body = vec![0u8; len];
        if r.read_exact(&mut body).await.is_err() {
            return;
        }
        let answer: &[u8] = match (kind, method.as_str()) {
            (Receiver::Redirect, "POST") => {
                b"HTTP/1.1 303 See Other\r\nLocation: /other\r\nContent-Length: 0\r\n\r\n"
            }
            _ => b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\n\r\n",
        };
        seen.lock().unwrap().push((method, path, uid));
        if r.get_mut().write_all(answer).await.is_err() || r.get_mut().flush().await.is_err() {
            return;
        }
    }
}

/// A certificate authority of its own (self-signed, written as PEM to
/// `dir/name.pem`) and a server configuration for 127.0.0.1 signed by it.
fn test_ca(dir: &Path, name: &str) -> (PathBuf, std::sync::Arc<rustls::ServerConfig>) {
    let mut ca = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    ca.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    ca.distinguished_name
        .push(rcgen::DnType::CommonName, format!("{name} test CA"));
    let ca = rcgen::CertifiedIssuer::self_signed(ca, rcgen::KeyPair::generate().unwrap()).unwrap();
    let leaf_key = rcgen::KeyPair::generate().unwrap();
    let leaf = rcgen::CertificateParams::new(vec!["127.0.0.1".to_string()])
        .unwrap()
        .signed_by(&leaf_key, &ca)
        .unwrap();
    let pem = dir.join(format!("{name}.pem"));
    std::fs::write(&pem, ca.pem()).unwrap();
    let key = rustls::pki_types::PrivateKeyDer::Pkcs8(leaf_key.serialize_der().into());
    let cfg = rustls::ServerConfig::builder_with_provider(std::sync::Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_no_client_auth()
    .with_single_cert(vec![leaf.der().clone()], key)
    .unwrap();
    (pem, std::sync::Arc::new(cfg))
}

/// `https://` receivers: one whose certificate chains to the CA of the
/// webhook's `ca_file` gets every message (signed, over TLS); one whose
/// certificate comes from another CA is refused at the handshake: its
/// deliveries are failed attempts naming the certificate, and it never sees
/// a request. (Before, the daemon refused to start with an `https://` URL.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn https_receivers_are_checked_against_the_configured_ca() {
    let tmp = tempfile::tempdir().unwrap();
    let (ca_file, server) = test_ca(tmp.path(), "factory");
    let (_, stranger) = test_ca(tmp.path(), "stranger");
    let (good_url, good_seen) = receiver_on(Receiver::Healthy, Some(server)).await;
    let (bad_url, bad_seen) = receiver_on(Receiver::Healthy, Some(stranger)).await;
    let hooks = format!(
        "{}ca_file = \"{}\"\n{}ca_file = \"{}\"\n",
        webhook("tls", &good_url),
        ca_file.display(),
        webhook("untrusted", &bad_url),
        ca_file.display()
    );
    let d = Daemon::start(&format!(
        "[mes]\ninitial_backoff_s = 0.2\nmax_backoff_s = 0.5\n{hooks}"
    ));
    let c = client();
    let j = &run_all(&c, &d, &[plain_job("TLS-1")]).await[0];
    assert_eq!(j["state"], "succeeded", "{j}");
    let want = job_messages_all(&c, &d, j["id"].as_str().unwrap()).await;
    assert_eq!(want.len(), 3);
    let t = Instant::now();
    loop {
        let mut got: Vec<String> = good_seen
            .lock()
            .unwrap()
            .iter()
            .filter(|(m, p, _)| m == "POST" && p == "/cfx")
            .map(|x| x.2.clone())
            .collect();
        got.sort();
        got.dedup();
        if got == want {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the https receiver has {got:?} of {want:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // the untrusted receiver: failed attempts that say why, no request seen
    let t = Instant::now();
    loop {
        let o = common::get(&c, &d, "/api/v1/outbox?limit=500").await;
        let untrusted: Vec<Value> = o["items"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|i| i["webhook"] == "untrusted")
            .cloned()
            .collect();
        assert_eq!(untrusted.len(), 3, "{o}");
        assert!(untrusted.iter().all(|i| i["state"] != "delivered"), "{o}");
        // in order per part: the first message is retried, the others wait behind it
        let tried: Vec<&Value> = untrusted
            .iter()
            .filter(|i| i["attempts"].as_i64().unwrap_or(0) >= 1)
            .collect();
        if tried
            .iter()
            .any(|i| i["attempts"].as_i64().unwrap_or(0) >= 2)
        {
            for i in &tried {
                let e = i["last_error"].as_str().unwrap_or("");
                assert!(e.contains("certificate"), "{e}");
            }
            println!(
                "untrusted https receiver: {}",
                tried[0]["last_error"].as_str().unwrap()
            );
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "{o}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(bad_seen.lock().unwrap().is_empty());
}

fn webhook(name: &str, url: &str) -> String {
    format!("[[mes.webhooks]]\nname = \"{name}\"\nurl = \"{url}\"\nsecret = \"{name}-secret-0123456789\"\n")
}

fn plain_job(serial: &str) -> Value {
    json!({"part": {"serial": serial, "kind": "spider"}, "target_xpeak_m": 0.008,
           "production": {"preset": "spider_4in", "seed": 5}})
}

/// A receiver answering 303: the delivery is a failed attempt naming the
/// redirect, never `delivered`, and no body-less GET follows it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_redirecting_receiver_is_a_failed_attempt() {
    let (url, seen) = receiver(Receiver::Redirect).await;
    // credentials in the URL (userinfo and a query token) are secrets too
    let url = url.replacen("http://", "http://mes:pw-0123456789@", 1) + "?token=tk-0123456789";
    let d = Daemon::start(&format!(
        "[mes]\ninitial_backoff_s = 0.2\nmax_backoff_s = 0.5\n{}",
        webhook("mes", &url)
    ));
    let c = client();
    let j = &run_all(&c, &d, &[plain_job("R-1")]).await[0];
    assert_eq!(j["state"], "succeeded", "{j}");
    let t = Instant::now();
    loop {
        let posts = seen
            .lock()
            .unwrap()
            .iter()
            .filter(|s| s.0 == "POST")
            .count();
        if posts >= 3 {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the receiver saw {posts} POSTs"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let o = common::get(&c, &d, "/api/v1/outbox?state=delivered").await;
    assert_eq!(
        o["items"].as_array().unwrap().len(),
        0,
        "delivered by a redirect: {o}"
    );
    let o = common::get(&c, &d, "/api/v1/outbox").await;
    let first = &o["items"][0];
    assert!(
        first["last_error"].as_str().unwrap_or("").contains("303"),
        "{first}"
    );
    assert!(first["attempts"].as_i64().unwrap() >= 1, "{first}");
    let gets: Vec<_> = seen
        .lock()
        .unwrap()
        .iter()
        .filter(|s| s.0 != "POST")
        .cloned()
        .collect();
    assert!(gets.is_empty(), "the redirect was followed: {gets:?}");
    // Secrets of webhooks are redacted in the configuration's answer.
    let cfg = common::get(&c, &d, "/api/v1/config").await;
    assert_eq!(
        cfg["mes"]["webhooks"][0]["secret"], "<redacted>",
        "{}",
        cfg["mes"]
    );
    assert!(!cfg.to_string().contains("mes-secret-0123456789"));
    for secret in ["pw-0123456789", "tk-0123456789"] {
        assert!(!cfg.to_string().contains(secret), "{}", cfg["mes"]);
    }
    // the rest of the URL stays readable (which receiver it is)
    let shown = cfg["mes"]["webhooks"][0]["url"].as_str().unwrap();
    assert!(shown.ends_with("/cfx?redacted"), "{shown}");
}

/// One receiver that accepts connections and never answers, beside two
/// healthy ones: the healthy ones get every message within 10 s of the
/// last job's end (the hanging one only delays itself).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hanging_receiver_delays_only_itself() {
    let (hang, _) = receiver(Receiver::Hang).await;
    let (ok1, seen1) = receiver(Receiver::Healthy).await;
    let (ok2, seen2) = receiver(Receiver::Healthy).await;
    let d = Daemon::start(&format!(
        "[mes]\ntimeout_s = 60\n{}{}{}",
        webhook("hang", &hang),
        webhook("ok1", &ok1),
        webhook("ok2", &ok2)
    ));
    let c = client();
    let jobs: Vec<Value> = (0..4).map(|i| plain_job(&format!("H-{i}"))).collect();
    let done = run_all(&c, &d, &jobs).await;
    let ended = Instant::now();
    let mut want = vec![];
    for j in &done {
        assert_eq!(j["state"], "succeeded", "{j}");
        let id = j["id"].as_str().unwrap();
        want.extend(job_messages_all(&c, &d, id).await);
    }
    want.sort();
    assert_eq!(want.len(), 12);
    loop {
        let got = |s: &Seen| {
            let mut v: Vec<String> = s.lock().unwrap().iter().map(|x| x.2.clone()).collect();
            v.sort();
            v.dedup();
            v
        };
        let (g1, g2) = (got(&seen1), got(&seen2));
        if g1 == want && g2 == want {
            break;
        }
        assert!(
            ended.elapsed() < Duration::from_secs(10),
            "10 s after the last job: ok1 has {} and ok2 {} of {} messages",
            g1.len(),
            g2.len(),
            want.len()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The UniqueIDs of a job's messages (one per message, any webhook).
async fn job_messages_all(c: &reqwest::Client, d: &Daemon, job: &str) -> Vec<String> {
    let mut ids: Vec<String> = job_outbox(c, d, job)
        .await
        .into_iter()
        .map(|m| m.1)
        .collect();
    ids.sort();
    ids.dedup();
    ids
}

/// SPC with repeats: one point per part and job (the mean of its repeats),
/// against an independent computation from the stored measurement verdicts.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spc_takes_one_point_per_part_and_job() {
    let d = Daemon::start("");
    let c = client();
    let mut r = recipe("reps");
    r["procedure"]["repeats"] = json!(3);
    r["parameters"][0] = json!({"name": "k0", "quantity": "k0", "lower": 1000.0, "upper": 6000.0});
    let (s, v) = post(&c, &d, "/api/v1/recipes", &r).await;
    assert_eq!(s, 201, "{v}");
    let jobs: Vec<Value> = (0..5)
        .map(|i| qc_job(&format!("P-{i}"), "reps", 300 + i))
        .collect();
    let done = run_all(&c, &d, &jobs).await;
    let mut means = vec![];
    let mut all = vec![];
    for j in &done {
        assert_eq!(j["state"], "succeeded", "{j}");
        let v = common::get(
            &c,
            &d,
            &format!("/api/v1/jobs/{}/verdict", j["id"].as_str().unwrap()),
        )
        .await;
        let vals: Vec<f64> = v["measurements"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| {
                let p = m["detail"]["parameters"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .find(|p| p["name"] == "k0")
                    .unwrap();
                p["value"].as_f64().unwrap()
            })
            .collect();
        assert_eq!(vals.len(), 3, "{v}");
        all.extend(vals.iter().copied());
        means.push(vals.iter().sum::<f64>() / 3.0);
    }
    let spc = common::get(&c, &d, "/api/v1/recipes/reps/spc?parameter=k0&last=1000").await;
    assert_eq!(spc["n"], 5, "one point per part and job: {spc}");
    let n = means.len() as f64;
    let mean = means.iter().sum::<f64>() / n;
    let sd = (means.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let mr = means.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (n - 1.0);
    let sw = mr / 1.128;
    let (lo, hi) = (1000.0, 6000.0);
    let cpk = (hi - mean).min(mean - lo) / (3.0 * sw);
    let ppk = (hi - mean).min(mean - lo) / (3.0 * sd);
    let rel = |a: &Value, b: f64| (a.as_f64().unwrap() - b).abs() <= 1e-9 * b.abs();
    assert!(rel(&spc["mean"], mean), "mean {} vs {mean}", spc["mean"]);
    assert!(
        rel(&spc["sigma_within"], sw),
        "sigma_within {} vs {sw}",
        spc["sigma_within"]
    );
    assert!(rel(&spc["cpk"], cpk), "Cpk {} vs {cpk}", spc["cpk"]);
    assert!(rel(&spc["ppk"], ppk), "Ppk {} vs {ppk}", spc["ppk"]);
    for (p, m) in spc["points"].as_array().unwrap().iter().zip(&means) {
        assert_eq!(p["repeats"], 3);
        assert!(rel(&p["value"], *m));
    }
    assert_eq!(spc["unreadable_verdicts"], 0, "{spc}");
    assert!(spc.get("warnings").is_none(), "{spc}");
    // A verdict detail this version cannot read (as another software
    // version might have written it): P-0's three measurement verdicts are
    // left out, counted and named, not dropped without a word (they were).
    {
        use sqlx::ConnectOptions;
        let mut db = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(d.dir.join("data").join("springbench.db"))
            .connect()
            .await
            .unwrap();
        let r = sqlx::query(
            "UPDATE qc_verdicts SET detail_json = '{\"verdict\": \"pass\", \"values\": {}}' \
             WHERE part_serial = 'P-0' AND measurement_id IS NOT NULL",
        )
        .execute(&mut db)
        .await
        .unwrap();
        assert_eq!(r.rows_affected(), 3);
    }
    let spc = common::get(&c, &d, "/api/v1/recipes/reps/spc?parameter=k0&last=1000").await;
    assert_eq!(spc["n"], 4, "{spc}");
    assert_eq!(spc["unreadable_verdicts"], 3, "{spc}");
    let w = spc["warnings"].to_string();
    assert!(w.contains("3 verdict(s)") && w.contains("P-0"), "{spc}");
    let mean4 = means[1..].iter().sum::<f64>() / 4.0;
    assert!(rel(&spc["mean"], mean4), "mean {} vs {mean4}", spc["mean"]);
    let csv = c
        .get(d.url("/api/v1/recipes/reps/spc?parameter=k0&last=1000&format=csv"))
        .send()
        .await
        .unwrap();
    assert_eq!(
        csv.headers()["springbench-unreadable-verdicts"],
        "3",
        "{:?}",
        csv.headers()
    );
    println!(
        "SPC with 3 repeats of 5 parts: k0 mean {mean:.1} N/m, sigma_within {sw:.2} (per measurement it would read {:.2}), Cpk {cpk:.3}, Ppk {ppk:.3}",
        all.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (all.len() - 1) as f64 / 1.128
    );
}

/// A burst of 100 submits onto a small disk: the daemon acknowledges only
/// what the disk can keep (the queue's measurements counted) and refuses
/// the rest with 503; every acknowledged job ends `succeeded`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn admission_counts_the_space_queued_jobs_need() {
    let Some(fs) = Tmpfs::mount("48m") else {
        return;
    };
    let d = Daemon::start_in(fs.path(), "min_free_bytes = 1048576\n");
    let c = client();
    let (mut accepted, mut refused) = (vec![], 0);
    for i in 0..100 {
        let (s, j) = post(&c, &d, "/api/v1/jobs", &plain_job(&format!("B-{i}"))).await;
        match s {
            202 => accepted.push(j["id"].as_str().unwrap().to_string()),
            503 => refused += 1,
            _ => panic!("submit {i}: {s} {j}"),
        }
    }
    assert!(refused > 0, "100 jobs acknowledged on a 48 MB disk");
    assert!(!accepted.is_empty());
    for id in &accepted {
        let j = wait_state(&c, &d, id, common::terminal).await;
        assert_eq!(j["state"], "succeeded", "{j}");
    }
    let used = 48 * 1024 * 1024 - springbench::store::health::free_bytes(fs.path()).unwrap();
    println!(
        "burst of 100 on a 48 MB tmpfs: {} acknowledged and all succeeded, {refused} refused with 503; {used} bytes used",
        accepted.len()
    );
    drop(d);
    drop(fs);
}

/// Submits a 16-level x 10-repeat series and cancels it once its progress
/// reaches `cancel_at`; every measurement the job lists afterwards must be a
/// fitted level. Returns (measurements listed just before the cancel,
/// measurements kept, the daemon's peak resident memory in kB: the larger
/// of VmHWM and an RSS sampled every 50 ms).
async fn cancelled_series(d: &Daemon, cancel_at: f64) -> (usize, usize, u64) {
    let c = client();
    let levels: Vec<f64> = (0..16).map(|i| 0.001 + 0.0005 * i as f64).collect();
    let body = json!({"part": {"serial": "S-1", "kind": "spider"}, "levels_m": levels, "repeats": 10,
                      "production": {"preset": "spider_4in", "seed": 11}});
    let (s, j) = post(&c, d, "/api/v1/jobs", &body).await;
    assert_eq!(s, 202, "{j}");
    let id = j["id"].as_str().unwrap().to_string();
    let sampler = common::RssSampler::start(d.pid(), Duration::from_millis(50));
    let t = Instant::now();
    let listed = loop {
        let j = common::get(&c, d, &format!("/api/v1/jobs/{id}")).await;
        assert!(!common::terminal(j["state"].as_str().unwrap()), "{j}");
        if j["progress"].as_f64().unwrap() >= cancel_at {
            break j["measurement_ids"].as_array().unwrap().len();
        }
        assert!(
            t.elapsed() < Duration::from_secs(900),
            "{cancel_at} not reached: {j}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let (s, _) = post(&c, d, &format!("/api/v1/jobs/{id}/cancel"), &json!({})).await;
    assert_eq!(s, 202);
    let j = wait_state(&c, d, &id, common::terminal).await;
    let peak_kb = sampler.peak_kb();
    assert_eq!(j["state"], "cancelled", "{j}");
    let ids = j["measurement_ids"].as_array().unwrap();
    let mut seen = std::collections::HashSet::new();
    for m in ids {
        let m = common::get(
            &c,
            d,
            &format!("/api/v1/measurements/{}", m.as_str().unwrap()),
        )
        .await;
        assert!(
            m["large_signal"]["keff_n_per_m"].as_f64().unwrap() > 0.0,
            "{m}"
        );
        let r = &m["measurement"];
        let key = format!("{} {}", r["repeat_index"], r["level_index"]);
        assert!(
            r["level_index"].as_i64().is_some() && seen.insert(key.clone()),
            "level {key}: {r}"
        );
    }
    // A later level of a repeat names the pre-measurement stored with its first.
    if let Some(m) = ids.get(1) {
        let wav = common::get_bytes(
            &c,
            d,
            &format!(
                "/api/v1/measurements/{}/recordings/pre.wav",
                m.as_str().unwrap()
            ),
        )
        .await;
        assert!(wav.len() > 48_000 * 3 * 4, "{} bytes", wav.len());
    }
    (listed, ids.len(), peak_kb)
}

/// A level series keeps every level it finished: each level is stored as
/// its narrow sweep is fitted (listed while the job runs), so a cancel in
/// the middle of the first repeat keeps its first levels. (Before, a repeat
/// was stored only when all 16 levels were in: nothing was kept.) Cancelled
/// at 4 % (about 6 of the first repeat's 16 levels), a few seconds of work.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_series_keeps_its_finished_levels() {
    let d = Daemon::start("");
    let (listed, kept, peak_kb) = cancelled_series(&d, 0.04).await;
    println!(
        "16 levels x 10 repeats cancelled at 4 %: {kept} levels kept ({listed} listed while running); peak RSS {} MB",
        peak_kb / 1024
    );
    assert!(listed >= 3, "{listed} levels stored at 4 %");
    assert!(kept >= listed);
}

/// Issue 24's series: 16 levels x 10 repeats, cancelled at 30 %. The daemon
/// stays below 150 MB resident throughout (136 MB; it held every level's
/// samples until the repeat's end at first: 456-485 MB, then 230 MB with
/// each level stored as it finished, the joint fit's memory), and the
/// cancel keeps the finished levels. About 70 s; run with
/// `cargo test --test it -- --ignored qc_faults::a_16_by_10_series --nocapture`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "about 70 s: run on purpose (docs/qc.md, docs/performance.md)"]
async fn a_16_by_10_series_stays_below_150_mb_and_keeps_its_levels() {
    let d = Daemon::start("");
    let rss0 = common::rss_kb(d.pid());
    let (listed, kept, peak_kb) = cancelled_series(&d, 0.30).await;
    println!(
        "16 levels x 10 repeats cancelled at 30 %: {kept} levels kept ({listed} listed while running); RSS {} MB at start, {} MB at most",
        rss0 / 1024,
        peak_kb / 1024
    );
    assert!(listed >= 3 * 16, "{listed} levels stored at 30 %");
    assert!(kept >= listed);
    assert!(
        peak_kb < 150 * 1024,
        "peak resident memory {} MB",
        peak_kb / 1024
    );
}

/// A 422 naming `field` (and no error with an empty field).
fn names_field(status: u16, v: &Value, field: &str) -> Result<(), String> {
    let errors = v["errors"].as_array().cloned().unwrap_or_default();
    let fields: Vec<&str> = errors.iter().filter_map(|e| e["field"].as_str()).collect();
    if status == 422 && fields.contains(&field) && !fields.contains(&"") {
        Ok(())
    } else {
        Err(format!("{status}, fields {fields:?}, wanted {field}: {v}"))
    }
}

/// The "Low" list of the issue: each bad recipe, proposal and query is
/// refused with a per-field problem naming the field, parse errors too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_recipes_proposals_and_queries_name_their_field() {
    let d = Daemon::start("");
    let c = client();
    let with = |path: &str, v: Value| {
        let mut r = recipe("val");
        let ptr: Vec<&str> = path.split('/').collect();
        let mut cur = &mut r;
        for k in &ptr[..ptr.len() - 1] {
            cur = match k.parse::<usize>() {
                Ok(i) => &mut cur[i],
                Err(_) => &mut cur[*k],
            };
        }
        cur[ptr[ptr.len() - 1]] = v;
        r
    };
    let mask = |x: Vec<f64>| {
        let n = x.len();
        json!({"x_m": x, "lower_n_per_m": vec![1000.0; n], "upper_n_per_m": vec![5000.0; n]})
    };
    let cases: Vec<(&str, Value, &str)> = vec![
        (
            "duplicate levels",
            with("procedure/levels_m", json!([0.004, 0.004])),
            "procedure.levels_m[1]",
        ),
        (
            "decreasing levels",
            with("procedure/levels_m", json!([0.008, 0.004])),
            "procedure.levels_m[1]",
        ),
        (
            "a 1e-300 m level",
            with("procedure/levels_m", json!([1e-300])),
            "procedure.levels_m[0]",
        ),
        (
            "a 1e-300 kg mass",
            with("procedure/moving_mass_kg", json!(1e-300)),
            "procedure.moving_mass_kg",
        ),
        (
            "mask x_m of 1 m",
            with("kx_mask", mask(vec![0.0, 1.0])),
            "kx_mask.x_m[1]",
        ),
        (
            "unsorted mask x_m",
            with("kx_mask", mask(vec![0.002, -0.002])),
            "kx_mask.x_m[1]",
        ),
        (
            "a 20 000-character description",
            with("description", json!("d".repeat(20_000))),
            "description",
        ),
        (
            "a 100-character part kind",
            with("part_kind", json!("k".repeat(100))),
            "part_kind",
        ),
        (
            "an upper limit of 1.7e308",
            with("parameters/1/upper", json!(1.7e308)),
            "parameters[1].upper",
        ),
        (
            "a lower limit of -1.7e308",
            with("parameters/0/lower", json!(-1.7e308)),
            "parameters[0].lower",
        ),
        (
            "a level that is text (parse error)",
            with("procedure/levels_m", json!(["8 mm"])),
            "procedure.levels_m[0]",
        ),
        (
            "repeats that are text (parse error)",
            with("procedure/repeats", json!("ten")),
            "procedure.repeats",
        ),
    ];
    let mut wrong = vec![];
    for (what, body, field) in &cases {
        let (s, v) = post(&c, &d, "/api/v1/recipes", body).await;
        if let Err(e) = names_field(s, &v, field) {
            wrong.push(format!("POST recipe with {what}: {e}"));
        }
    }
    // Proposals: size cap, options, parse errors (the recipe exists).
    let (s, v) = post(&c, &d, "/api/v1/recipes", &recipe("valid")).await;
    assert_eq!(s, 201, "{v}");
    let many: Vec<String> = (0..95_000).map(|i| format!("S-{i}")).collect();
    let five: Vec<String> = (0..5).map(|i| format!("S-{i}")).collect();
    let proposals: Vec<(&str, Value, &str)> = vec![
        (
            "95 000 serials",
            json!({"serials": many, "method": "k_sigma", "k": 6.0}),
            "serials",
        ),
        (
            "k = -1",
            json!({"serials": five, "method": "k_sigma", "k": -1.0}),
            "k",
        ),
        (
            "mask_points = 1",
            json!({"serials": five, "method": "k_sigma", "k": 6.0, "mask_points": 1}),
            "mask_points",
        ),
        (
            "mask_range_fraction = 2",
            json!({"serials": five, "method": "k_sigma", "k": 6.0, "mask_range_fraction": 2.0}),
            "mask_range_fraction",
        ),
        (
            "a numeric serial (parse error)",
            json!({"serials": [1, 2], "method": "k_sigma", "k": 6.0}),
            "serials[0]",
        ),
    ];
    for (what, body, field) in &proposals {
        let (s, v) = post(&c, &d, "/api/v1/recipes/valid/limit-proposals", body).await;
        if let Err(e) = names_field(s, &v, field) {
            wrong.push(format!(
                "proposal with {what}: {}",
                e.chars().take(400).collect::<String>()
            ));
        }
    }
    let r = c
        .get(d.url("/api/v1/recipes/valid/spc?parameter=k0&format=xml"))
        .send()
        .await
        .unwrap();
    let s = r.status().as_u16();
    let v: Value = r.json().await.unwrap_or(Value::Null);
    if let Err(e) = names_field(s, &v, "format") {
        wrong.push(format!("SPC format=xml: {e}"));
    }
    assert!(
        wrong.is_empty(),
        "{} wrong:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

/// A golden unit that fails the recipe's current limits is left out of a
/// proposal (and named) unless the engineer keeps it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_golden_unit_is_left_out_unless_kept() {
    let d = Daemon::start("");
    let c = client();
    let r = with_k0_limits(recipe("gold"), 2000.0, 2800.0);
    let (s, v) = post(&c, &d, "/api/v1/recipes", &r).await;
    assert_eq!(s, 201, "{v}");
    let mut jobs: Vec<Value> = (0..5)
        .map(|i| qc_job(&format!("G-{i}"), "gold", 400 + i))
        .collect();
    let mut stiff = qc_job("G-stiff", "gold", 500);
    stiff["production"]["defect"] = json!("stiff");
    jobs.push(stiff);
    let done = run_all(&c, &d, &jobs).await;
    let verdicts: Vec<String> = done
        .iter()
        .map(|j| j["verdict"].as_str().unwrap_or("").to_string())
        .collect();
    assert_eq!(
        verdicts,
        ["pass", "pass", "pass", "pass", "pass", "fail"],
        "{done:?}"
    );
    let serials: Vec<String> = (0..5)
        .map(|i| format!("G-{i}"))
        .chain(["G-stiff".to_string()])
        .collect();
    let body = json!({"serials": serials, "method": "k_sigma", "k": 6.0});
    let (s, p) = post(&c, &d, "/api/v1/recipes/gold/limit-proposals", &body).await;
    assert_eq!(s, 201, "{p}");
    assert_eq!(
        p["proposal"]["serials"].as_array().unwrap().len(),
        5,
        "{}",
        p["proposal"]["serials"]
    );
    assert_eq!(
        p["proposal"]["left_out"][0]["serial"], "G-stiff",
        "{}",
        p["proposal"]
    );
    assert!(p["proposal"]["left_out"][0]["failures"][0]
        .as_str()
        .unwrap()
        .starts_with("k0 = "));
    let mut body = body;
    body["keep_failed"] = json!(["G-stiff"]);
    let (s, p) = post(&c, &d, "/api/v1/recipes/gold/limit-proposals", &body).await;
    assert_eq!(s, 201, "{p}");
    assert_eq!(p["proposal"]["serials"].as_array().unwrap().len(), 6);
    assert_eq!(p["proposal"]["kept_failed"][0]["serial"], "G-stiff");
}

fn with_k0_limits(mut r: Value, lo: f64, hi: f64) -> Value {
    r["parameters"][0] = json!({"name": "k0", "quantity": "k0", "lower": lo, "upper": hi});
    r
}

/// kill -9 during QC lots, 20 rounds: every job the API acknowledged ends
/// with a verdict and its three MES messages (no message twice).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_rounds_lose_no_verdict_and_no_message() {
    let c = client();
    let mut d = Daemon::start(WEBHOOK);
    let (s, r) = post(&c, &d, "/api/v1/recipes", &recipe("rounds")).await;
    assert_eq!(s, 201, "{r}");
    let tmp = d.take_dir().unwrap();
    let mut acked = vec![];
    for round in 0..20u64 {
        if round > 0 {
            d = Daemon::start_in(tmp.path(), WEBHOOK);
        }
        for k in 0..2 {
            let (s, j) = post(
                &c,
                &d,
                "/api/v1/jobs",
                &qc_job(&format!("L-{round}-{k}"), "rounds", 600 + 2 * round + k),
            )
            .await;
            if s == 202 {
                acked.push(j["id"].as_str().unwrap().to_string());
            }
        }
        // kills land before, during and after runs and their commits
        tokio::time::sleep(Duration::from_millis(150 + 173 * (round % 9))).await;
        d.kill9();
    }
    let d = Daemon::start_in(tmp.path(), WEBHOOK);
    assert!(acked.len() >= 30, "{} jobs acknowledged", acked.len());
    let mut states = std::collections::BTreeMap::new();
    for id in &acked {
        let j = wait_state(&c, &d, id, common::terminal).await;
        *states
            .entry(j["state"].as_str().unwrap().to_string())
            .or_insert(0) += 1;
        let r = c
            .get(d.url(&format!("/api/v1/jobs/{id}/verdict")))
            .send()
            .await
            .unwrap();
        assert_eq!(
            r.status().as_u16(),
            200,
            "job {id} ({}) has no verdict",
            j["state"]
        );
        assert_eq!(
            job_messages(&c, &d, id).await,
            THREE,
            "job {id} ({})",
            j["state"]
        );
        assert_eq!(
            job_messages_all(&c, &d, id).await.len(),
            3,
            "job {id}: UniqueIDs"
        );
    }
    println!("20 kill -9 rounds: {} jobs acknowledged, ends {states:?}; each with a verdict and 3 MES messages", acked.len());
}
