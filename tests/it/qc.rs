//! Production QC through the daemon on the virtual bench: a recipe, golden
//! units, limits proposed and approved, production parts judged (good ones
//! pass, defective ones fail, unmeasurable ones are invalid and never pass),
//! SPC against an independent computation, traceability; and the MES outbox
//! surviving a receiver outage and a kill -9.
//!
//! Size: by default 5 golden units and 6 production parts (one good, three
//! defects, both kinds of unmeasurable part); `SPRINGBENCH_QC_FULL=1` runs the
//! acceptance lot of the issue: 8 golden units and 30 production parts (23
//! good, 5 defects, 2 unmeasurable). Two virtual benches run in parallel.

use crate::cfx_sdk;
use crate::common;

use common::{client, Api, Daemon};
use hmac::{Hmac, Mac};
use reqwest::Method;
use serde_json::{json, Value};
use sha2::Sha256;
use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The API as the station (jobs, reads).
fn station(d: &Daemon) -> Api {
    Api::with(d, STATION)
}

const STATION: &str = "station-secret-0123456789";
const ENGINEER: &str = "engineer-secret-0123456789";

fn tokens() -> &'static str {
    "[[auth.tokens]]\nname = \"station-1\"\ntoken = \"station-secret-0123456789\"\nrole = \"operator\"\n\
     [[auth.tokens]]\nname = \"qc-engineer\"\ntoken = \"engineer-secret-0123456789\"\nrole = \"admin\"\n"
}

fn benches() -> &'static str {
    "[[benches]]\nid = \"virtual-1\"\nseed = 1\n[[benches]]\nid = \"virtual-2\"\nseed = 1001\n"
}

fn recipe() -> Value {
    json!({
        "name": "spider-4in",
        "part_kind": "spider",
        "procedure": {"levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0"},
            {"name": "q", "quantity": "q"},
            {"name": "keff", "quantity": "keff"},
            {"name": "k_at_4mm", "quantity": "k_at_x", "x_m": 0.004},
            {"name": "asym_4mm", "quantity": "k_asymmetry", "x_m": 0.004},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0},
            {"name": "friction", "quantity": "effect_size", "effect": "coulomb_friction",
             "effect_parameter": "force_n", "upper": 0.1}
        ]
    })
}

/// Submits jobs and waits for all of them; returns the job documents in order.
async fn run_jobs(d: &Daemon, bodies: &[Value]) -> Vec<Value> {
    let mut ids = vec![];
    for b in bodies {
        let (s, v) = Api::with(d, STATION)
            .exchange(Method::POST, "/api/v1/jobs", Some(&b.clone()))
            .await;
        assert_eq!(s, 202, "{v}");
        ids.push(v["id"].as_str().unwrap().to_string());
    }
    let mut out = vec![];
    for id in ids {
        let t = Instant::now();
        loop {
            let j = station(d).get(&format!("/api/v1/jobs/{id}")).await;
            if common::terminal(j["state"].as_str().unwrap()) {
                out.push(j);
                break;
            }
            assert!(
                t.elapsed() < Duration::from_secs(600),
                "job {id} did not finish"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
    out
}

fn job(serial: &str, seed: u64, defect: Option<&str>) -> Value {
    let mut production = json!({"preset": "spider_4in", "seed": seed});
    if let Some(d) = defect {
        production["defect"] = json!(d);
    }
    json!({"part": {"serial": serial, "kind": "spider"}, "recipe": "spider-4in", "production": production})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn golden_units_limits_and_production_verdicts() {
    let full = std::env::var("SPRINGBENCH_QC_FULL").is_ok_and(|v| v == "1");
    // A webhook nobody answers: the lot's MES messages stay in the outbox,
    // read at the end as the CFX SDK reads them.
    let d = Daemon::start(&format!(
        "{}{}[mes]\nhandle = \"Acme.Line3.Springbench\"\nmax_backoff_s = 60.0\n\
         [[mes.webhooks]]\nname = \"mes\"\nurl = \"http://127.0.0.1:9/cfx\"\nsecret = \"{HOOK_SECRET}\"\n",
        tokens(),
        benches()
    ));
    let c = client();

    // Recipe: only an admin creates it; the station (operator) may not.
    let (s, _) = Api::with(&d, STATION)
        .exchange(Method::POST, "/api/v1/recipes", Some(&recipe()))
        .await;
    assert_eq!(s, 403);
    let (s, r) = Api::with(&d, ENGINEER)
        .exchange(Method::POST, "/api/v1/recipes", Some(&recipe()))
        .await;
    assert_eq!(s, 201, "{r}");
    assert_eq!(r["version"], 1);
    assert_eq!(r["created_by"], "qc-engineer");
    assert!(
        r["has_limits"].as_bool().unwrap(),
        "model error and friction have manual limits"
    );

    // Golden units: measured with the recipe, in their own pool (issue 35:
    // never counted as production); only the manual limits (model error,
    // friction) judge them.
    let n_golden = if full { 8 } else { 5 };
    let golden: Vec<Value> = (0..n_golden)
        .map(|i| {
            let mut b = job(&format!("G-{i:02}"), 100 + i as u64, None);
            b["purpose"] = json!("golden_unit");
            b
        })
        .collect();
    let done = run_jobs(&d, &golden).await;
    for j in &done {
        assert_eq!(j["state"], "succeeded", "{j}");
        assert_eq!(j["verdict"], "pass", "{}", j["id"]);
        assert_eq!(j["request"]["purpose"], "golden_unit", "{}", j["id"]);
    }
    let serials: Vec<String> = (0..n_golden).map(|i| format!("G-{i:02}")).collect();
    let (s, p) = Api::with(&d, STATION)
        .exchange(
            Method::POST,
            "/api/v1/recipes/spider-4in/limit-proposals",
            Some(&json!({"serials": serials, "method": "k_sigma", "k": 6.0})),
        )
        .await;
    assert_eq!(s, 201, "{p}");
    assert_eq!(p["state"], "proposed");
    let pid = p["id"].as_str().unwrap().to_string();
    // Statistics of k0 equal the golden values' own mean and sample sigma.
    let k0 = p["proposal"]["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|x| x["name"] == "k0")
        .unwrap()
        .clone();
    let vals: Vec<f64> = k0["values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(vals.len(), n_golden);
    let (m, sd) = mean_sd(&vals);
    assert!((k0["mean"].as_f64().unwrap() - m).abs() < 1e-9 * m);
    assert!((k0["upper"].as_f64().unwrap() - (m + 6.0 * sd)).abs() < 1e-9 * m);
    // Only an admin approves; approval is recorded and makes version 2.
    let path = format!("/api/v1/limit-proposals/{pid}/approve");
    let (s, _) = Api::with(&d, STATION)
        .exchange(Method::POST, &path, None)
        .await;
    assert_eq!(s, 403);
    let (s, v2) = Api::with(&d, ENGINEER)
        .exchange(Method::POST, &path, None)
        .await;
    assert_eq!(s, 201, "{v2}");
    assert_eq!(
        (v2["version"].as_i64(), v2["origin"].as_str()),
        (Some(2), Some("limits_approved"))
    );
    assert!(v2["has_limits"].as_bool().unwrap());
    let p = station(&d)
        .get(&format!("/api/v1/limit-proposals/{pid}"))
        .await;
    assert_eq!(
        (p["state"].as_str(), p["decided_by"].as_str()),
        (Some("approved"), Some("qc-engineer"))
    );
    let (s, _) = Api::with(&d, ENGINEER)
        .exchange(Method::POST, &path, None)
        .await;
    assert_eq!(s, 409, "approved twice");
    // The recipe's proposals, newest first (what the QC view lists).
    let list = station(&d)
        .get("/api/v1/recipes/spider-4in/limit-proposals")
        .await;
    let items = list["items"].as_array().unwrap();
    assert_eq!(items.len(), 1, "{list}");
    assert_eq!(
        (items[0]["id"].as_str(), items[0]["state"].as_str()),
        (Some(pid.as_str()), Some("approved"))
    );
    let (s, _) = Api::with(&d, STATION)
        .exchange(
            Method::GET,
            "/api/v1/recipes/no-such-recipe/limit-proposals",
            None,
        )
        .await;
    assert_eq!(s, 404);

    // Production: (serial, body, expected verdict, expected failing parameter or invalid reason).
    let mut lot: Vec<(String, Value, &str, &str)> = vec![];
    let n_good = if full { 23 } else { 1 };
    for i in 0..n_good {
        let s = format!("P-{i:02}");
        lot.push((s.clone(), job(&s, 500 + i as u64, None), "pass", ""));
    }
    let defects: &[(&str, &str)] = if full {
        &[
            ("stiff", "k0"),
            ("asymmetric", "asym_4mm"),
            ("hardening", "keff"),
            ("damped", "q"),
            ("friction", "friction"),
        ]
    } else {
        &[("stiff", "k0"), ("asymmetric", "asym_4mm"), ("damped", "q")]
    };
    for (i, (defect, param)) in defects.iter().enumerate() {
        let s = format!("D-{defect}");
        lot.push((
            s.clone(),
            job(&s, 700 + i as u64, Some(defect)),
            "fail",
            param,
        ));
    }
    // Unmeasurable: the amplifier limited to 0.3 V cannot reach 8 mm; a dark surface makes the laser noisy.
    let mut weak = job("U-drive", 801, None);
    weak["limits"] = json!({"max_drive_v": 0.3});
    lot.push(("U-drive".into(), weak, "invalid", "target_not_reached"));
    lot.push((
        "U-dark".into(),
        job("U-dark", 802, Some("dark_surface")),
        "invalid",
        "noise_high",
    ));

    let bodies: Vec<Value> = lot.iter().map(|l| l.1.clone()).collect();
    let done = run_jobs(&d, &bodies).await;
    let mut wrong = vec![];
    for ((serial, _, want, why), j) in lot.iter().zip(&done) {
        let v = station(&d)
            .get(&format!("/api/v1/parts/{serial}/verdict"))
            .await;
        let got = v["verdict"].as_str().unwrap().to_string();
        let detail = &v["detail"];
        let ok = got == *want
            && match *want {
                "fail" => detail["failures"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|f| f["name"] == *why),
                "invalid" => detail["invalid_reasons"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|r| r["code"] == *why),
                _ => true,
            };
        if !ok {
            wrong.push(format!(
                "{serial}: want {want} ({why}), got {got}: {detail}"
            ));
        }
        // Never pass on an invalid measurement.
        if !detail["invalid_reasons"].as_array().unwrap().is_empty() {
            assert_ne!(got, "pass", "{serial}");
        }
        assert_eq!(
            j["verdict"].as_str(),
            Some(got.as_str()),
            "job and part verdict agree"
        );
        // Traceability.
        let t = &v["traceability"];
        assert_eq!(t["recipe"]["version"], 2);
        assert_eq!(t["recipe"]["sha256"], v2["sha256"]);
        assert_eq!(t["submitted_by"], "station-1");
        assert_eq!(t["software_version"], env!("CARGO_PKG_VERSION"));
        assert!(t["bench_id"].as_str().unwrap().starts_with("virtual-"));
        assert!(
            t["calibration"].is_null(),
            "the virtual bench has no calibration record"
        );
        // Each failing parameter carries its value and limits.
        for f in detail["failures"].as_array().unwrap() {
            let (x, lo, hi) = (
                f["value"].as_f64().unwrap(),
                f["lower"].as_f64(),
                f["upper"].as_f64(),
            );
            assert!(
                lo.is_some_and(|l| x < l) || hi.is_some_and(|h| x > h),
                "{f}"
            );
        }
    }
    assert!(
        wrong.is_empty(),
        "{} wrong verdicts:\n{}",
        wrong.len(),
        wrong.join("\n")
    );

    // The measurement carries its verdict too.
    let mid = done[0]["measurement_ids"][0].as_str().unwrap();
    let m = station(&d)
        .get(&format!("/api/v1/measurements/{mid}"))
        .await;
    assert_eq!(m["measurement"]["verdict"]["verdict"], "pass");

    // SPC of k0 over the window: Cpk and Ppk equal an independent computation
    // on the stored k0 of the same measurements: the production parts' only
    // (the golden units are their own pool).
    let spc = station(&d)
        .get("/api/v1/recipes/spider-4in/spc?parameter=k0&last=1000")
        .await;
    assert_eq!(spc["purpose"], "production", "{spc}");
    let pts = spc["points"].as_array().unwrap();
    let mut values = vec![];
    for p in pts {
        let id = p["measurement_id"].as_str().unwrap();
        let m = station(&d).get(&format!("/api/v1/measurements/{id}")).await;
        values.push(m["small_signal"]["k0_n_per_m"].as_f64().unwrap());
    }
    // Production (pass/fail); the invalid ones have no value.
    assert_eq!(values.len(), lot.len() - 2);
    let lot_serials: HashSet<&str> = lot.iter().map(|l| l.0.as_str()).collect();
    for p in pts {
        let serial = p["part_serial"].as_str().unwrap_or_default();
        assert!(lot_serials.contains(serial), "not a production part: {p}");
    }
    assert_eq!(spc["invalid"], 2);
    let (lo, hi) = (
        spc["lower"].as_f64().unwrap(),
        spc["upper"].as_f64().unwrap(),
    );
    let (mean, sd) = mean_sd(&values);
    let mr =
        values.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (values.len() - 1) as f64;
    let sw = mr / 1.128;
    let cpk = ((hi - mean).min(mean - lo)) / (3.0 * sw);
    let ppk = ((hi - mean).min(mean - lo)) / (3.0 * sd);
    let rel = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1e-12);
    assert!(
        rel(spc["cpk"].as_f64().unwrap(), cpk),
        "Cpk {} vs {cpk}",
        spc["cpk"]
    );
    assert!(
        rel(spc["ppk"].as_f64().unwrap(), ppk),
        "Ppk {} vs {ppk}",
        spc["ppk"]
    );
    let fails = lot.iter().filter(|l| l.2 == "fail" && l.3 == "k0").count();
    assert_eq!(
        spc["failed"].as_u64().unwrap() as usize,
        lot.iter().filter(|l| l.2 == "fail").count()
    );
    assert!(fails >= 1);
    let csv = c
        .get(d.url("/api/v1/recipes/spider-4in/spc?parameter=k0&last=1000&format=csv"))
        .bearer_auth(STATION)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(csv.lines().count(), values.len() + 1);
    println!(
        "QC lot: {} golden, {} production; k0 mean {mean:.1} N/m, sigma {sd:.2}, Cpk {cpk:.3}, Ppk {ppk:.3}",
        n_golden,
        lot.len()
    );

    // Every MES message of the lot, strictly against the CFX SDK's shapes
    // (decision 0095): golden, pass, fail and invalid parts.
    let store = springbench::store::Store::open(&d.dir.join("data"))
        .await
        .unwrap();
    let items = store.list_outbox(None, 100_000).await.unwrap();
    let shapes = cfx_sdk::Shapes::load();
    let mut results: HashMap<String, usize> = HashMap::new();
    for m in &items {
        let errs = shapes.check(&m.body);
        assert!(errs.is_empty(), "{}: {errs:?}\n{}", m.message_name, m.body);
        assert!(m.body["Source"]
            .as_str()
            .unwrap()
            .starts_with("Acme.Line3.Springbench.virtual-"));
        if let Some(r) = m.body["MessageBody"]["TestedUnits"][0]["OverallResult"].as_str() {
            *results.entry(r.to_string()).or_default() += 1;
        }
    }
    let jobs = n_golden + lot.len();
    assert_eq!(items.len(), 3 * jobs, "three messages a job");
    // golden and good parts pass, defects fail, unmeasurable parts are errors
    assert_eq!(results.get("Error"), Some(&2), "{results:?}");
    assert!(
        results.get("Failed").is_some_and(|&n| n >= fails),
        "{results:?}"
    );
    if std::env::var_os("CFX_SDK_DIR").is_some() {
        let dir = tempfile::tempdir().unwrap();
        let msgs: std::collections::BTreeMap<String, Value> = items
            .iter()
            .enumerate()
            .map(|(i, m)| (format!("{i:04}.json"), m.body.clone()))
            .collect();
        cfx_sdk::write_messages(&dir.path().join("lot"), &msgs);
        let r = cfx_sdk::sdk_check(&dir.path().join("lot"), &dir.path().join("out.json")).unwrap();
        for (n, m) in &msgs {
            let x = &r["messages"][n];
            assert_eq!(
                (&x["from_json"], &x["strict"]),
                (&json!("ok"), &json!("ok")),
                "{n}: {x}"
            );
            let mut lost = vec![];
            cfx_sdk::lost_in_round_trip(m, &x["round_trip"], n, &mut lost);
            assert!(lost.is_empty(), "{lost:?}");
        }
    }
    println!(
        "CFX: {} messages of the lot read strictly ({results:?})",
        items.len()
    );
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

/// What the webhook receiver saw: (UniqueID, part serial, signature valid), in arrival order.
type Seen = Arc<Mutex<Vec<(String, String, bool)>>>;

const HOOK_SECRET: &str = "hook-secret-0123456789";

async fn receiver(port: u16, seen: Seen, refuse_first: usize) -> tokio::task::JoinHandle<()> {
    use axum::http::{HeaderMap, StatusCode};
    let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
        .await
        .unwrap();
    let count = Arc::new(Mutex::new(0usize));
    let app = axum::Router::new().route(
        "/cfx",
        axum::routing::post(move |headers: HeaderMap, body: axum::body::Bytes| {
            let seen = seen.clone();
            let count = count.clone();
            async move {
                {
                    let mut n = count.lock().unwrap();
                    *n += 1;
                    if *n <= refuse_first {
                        return StatusCode::SERVICE_UNAVAILABLE;
                    }
                }
                let sig = headers
                    .get("x-springbench-signature")
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or("")
                    .to_string();
                let mut mac = Hmac::<Sha256>::new_from_slice(HOOK_SECRET.as_bytes()).unwrap();
                mac.update(&body);
                let want: String = mac
                    .finalize()
                    .into_bytes()
                    .iter()
                    .map(|b| format!("{b:02x}"))
                    .collect();
                let v: Value = serde_json::from_slice(&body).unwrap();
                let body = &v["MessageBody"];
                let serial = body["PrimaryIdentifier"]
                    .as_str()
                    .or(body["TestedUnits"][0]["UnitIdentifier"].as_str())
                    .unwrap_or("")
                    .to_string();
                seen.lock().unwrap().push((
                    v["UniqueID"].as_str().unwrap().to_string(),
                    serial,
                    sig == format!("sha256={want}"),
                ));
                StatusCode::OK
            }
        }),
    );
    tokio::spawn(async move {
        let _ = axum::serve(listener, app).await;
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mes_outbox_survives_receiver_outage_and_kill_9() {
    // The receiver is down: its port is free while the jobs finish.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let cfg = format!(
        "{}{}[mes]\nsource = \"line-3\"\ninitial_backoff_s = 0.2\nmax_backoff_s = 1.0\n\
         [[mes.webhooks]]\nname = \"mes\"\nurl = \"http://127.0.0.1:{port}/cfx\"\nsecret = \"{HOOK_SECRET}\"\n",
        tokens(),
        benches()
    );
    let mut d = Daemon::start(&cfg);
    let c = client();
    // 10 jobs on 5 parts (two each: the order per part matters).
    let bodies: Vec<Value> = (0..10)
        .map(|i| json!({"part": {"serial": format!("M-{}", i % 5)}, "preset": "spider_4in", "target_xpeak_m": 0.006}))
        .collect();
    let done = run_jobs(&d, &bodies).await;
    assert!(done.iter().all(|j| j["state"] == "succeeded"));
    // Every bench measurement was announced on the event stream.
    let ob = station(&d).get("/api/v1/outbox?limit=500").await;
    assert_eq!(ob["pending"], 30, "{ob}");
    let expected: Vec<(String, String)> = ob["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| {
            (
                x["unique_id"].as_str().unwrap().to_string(),
                x["part_serial"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    // Each job's three messages, in this order (WorkStarted written when it started).
    let mut per_job: HashMap<String, Vec<String>> = HashMap::new();
    for x in ob["items"].as_array().unwrap() {
        per_job
            .entry(x["job_id"].as_str().unwrap().to_string())
            .or_default()
            .push(x["message_name"].as_str().unwrap().to_string());
    }
    assert_eq!(per_job.len(), 10);
    for names in per_job.values() {
        assert_eq!(
            names,
            &[
                "CFX.Production.WorkStarted",
                "CFX.Production.TestAndInspection.UnitsTested",
                "CFX.Production.WorkCompleted"
            ]
        );
    }
    let metrics = c
        .get(d.url("/metrics"))
        .bearer_auth(STATION)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains("springbench_mes_outbox_depth{state=\"pending\"} 30"),
        "{metrics}"
    );
    assert!(
        !metrics.contains("springbench_mes_delivery_failures_total 0\n"),
        "attempts failed while down"
    );
    // Killed with the messages pending.
    d.kill9();

    // The receiver comes back, refusing its first 5 requests (503); then the daemon.
    let seen: Seen = Arc::new(Mutex::new(vec![]));
    let rx = receiver(port, seen.clone(), 5).await;
    let dir = d.take_dir().unwrap();
    let d2 = Daemon::start_in(dir.path(), &cfg);
    let t = Instant::now();
    loop {
        let got: HashSet<String> = seen.lock().unwrap().iter().map(|s| s.0.clone()).collect();
        if expected.iter().all(|e| got.contains(&e.0)) {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "not every message arrived: {} of 30",
            got.len()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let seen = seen.lock().unwrap().clone();
    assert!(seen.iter().all(|s| s.2), "every signature valid");
    // Per part: first arrivals in the order the outbox holds them.
    let mut first: HashMap<String, Vec<String>> = HashMap::new();
    let mut got = HashSet::new();
    for (uid, serial, _) in &seen {
        if got.insert(uid.clone()) {
            first.entry(serial.clone()).or_default().push(uid.clone());
        }
    }
    for part in (0..5).map(|i| format!("M-{i}")) {
        let want: Vec<String> = expected
            .iter()
            .filter(|e| e.1 == part)
            .map(|e| e.0.clone())
            .collect();
        assert_eq!(want.len(), 6);
        assert_eq!(first.get(&part), Some(&want), "order of {part}");
    }
    // The receiver records a message before it answers 200, so the daemon
    // marks the last one delivered a moment after it was seen: wait for it.
    let t = Instant::now();
    let ob = loop {
        let ob = station(&d2).get("/api/v1/outbox").await;
        if ob["pending"] == 0 || t.elapsed() > Duration::from_secs(30) {
            break ob;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(
        (ob["pending"].as_i64(), ob["failed"].as_i64()),
        (Some(0), Some(0)),
        "{ob}"
    );
    println!(
        "MES: 30 messages, {} posts received (5 refused)",
        seen.len() + 5
    );
    rx.abort();
}

/// Issue 35: `GET` of an invalid verdict (the part's, the job's with its
/// measurements', the measurement's) carries no per-parameter result: the
/// values as measured, with their limits, each `not_judged`, no failures.
/// A verdict stored before this rule (its invalid parameters marked pass
/// or fail, written here into SQLite as it stood) reads the same.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn get_of_an_invalid_verdict_has_no_per_parameter_result() {
    let d = Daemon::start(tokens());
    // k0 inside wide limits (it would pass), K(6 mm) with a limit it would fail.
    let r = json!({
        "name": "never-judged",
        "part_kind": "spider",
        "procedure": {"levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0", "lower": 100.0, "upper": 100000.0},
            {"name": "k_at_6mm", "quantity": "k_at_x", "x_m": 0.006, "upper": 1.0}
        ]
    });
    let (s, v) = Api::with(&d, ENGINEER)
        .exchange(Method::POST, "/api/v1/recipes", Some(&r))
        .await;
    assert_eq!(s, 201, "{v}");
    // 20 V cannot drive a spider to 8 mm: target not reached, invalid.
    let body = json!({"part": {"serial": "SN-INV", "kind": "spider"}, "recipe": "never-judged",
                      "limits": {"max_drive_v": 20.0}});
    let job = run_jobs(&d, &[body]).await.remove(0);
    assert_eq!(job["verdict"], "invalid", "{job}");
    let id = job["id"].as_str().unwrap().to_string();
    let check = |what: &str, v: &Value| {
        assert_eq!(v["verdict"], "invalid", "{what}: {v}");
        let d = &v["detail"];
        assert_eq!(d["failures"], json!([]), "{what}: {v}");
        let ps = d["parameters"].as_array().unwrap();
        for p in ps {
            assert_eq!(p["result"], "not_judged", "{what}: {p}");
            assert!(
                p["value"].as_f64().is_some_and(f64::is_finite),
                "{what}: {p}"
            );
        }
        ps.len()
    };
    let check_all = |part: Value, jobv: Value, meas: Value| {
        let n = check("part", &part);
        assert_eq!(n, 2, "both values shown as measured: {part}");
        check("job", &jobv);
        let ms = jobv["measurements"].as_array().unwrap();
        assert!(!ms.is_empty());
        for m in ms {
            check("job's measurement", m);
        }
        check("measurement", &meas["measurement"]["verdict"]);
    };
    let mid = |jobv: &Value| {
        jobv["measurements"][0]["measurement_id"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let jobv = station(&d).get(&format!("/api/v1/jobs/{id}/verdict")).await;
    let m = mid(&jobv);
    check_all(
        station(&d).get("/api/v1/parts/SN-INV/verdict").await,
        jobv,
        station(&d).get(&format!("/api/v1/measurements/{m}")).await,
    );
    // As an older version stored it: k0 `pass`, K(6 mm) `fail`, a failure.
    {
        use sqlx::ConnectOptions;
        let mut db = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(d.dir.join("data").join("springbench.db"))
            .connect()
            .await
            .unwrap();
        let r = sqlx::query(
            "UPDATE qc_verdicts SET detail_json = json_set(detail_json, \
               '$.parameters[0].result', 'pass', '$.parameters[1].result', 'fail', \
               '$.failures', json_array(json_extract(detail_json, '$.parameters[1]'))) \
             WHERE part_serial = 'SN-INV'",
        )
        .execute(&mut db)
        .await
        .unwrap();
        assert!(r.rows_affected() >= 2);
    }
    let jobv = station(&d).get(&format!("/api/v1/jobs/{id}/verdict")).await;
    check_all(
        station(&d).get("/api/v1/parts/SN-INV/verdict").await,
        jobv,
        station(&d).get(&format!("/api/v1/measurements/{m}")).await,
    );
}

/// Issue 35: a faulted bench takes no part. The fault, as a hardware bench
/// stores it when its laser fails (a `bench_faults` row; it outlives a
/// restart), makes `POST /api/v1/jobs` on that bench a 409 problem naming
/// the fault and the self-check that clears it; nothing is queued; the
/// other bench still takes parts.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_on_a_faulted_bench_is_refused_with_a_problem_naming_the_fault() {
    let cfg = format!("{}{}", tokens(), benches());
    let (d, tmp) = common::with_bench_fault(&cfg, "virtual-2", common::LASER_LOST).await;
    let benches = station(&d).get("/api/v1/benches").await;
    let b2 = benches["items"]
        .as_array()
        .or(benches.as_array())
        .unwrap()
        .iter()
        .find(|b| b["id"] == "virtual-2")
        .cloned()
        .unwrap();
    assert_eq!(b2["state"], "faulted", "{benches}");
    let body = |bench: &str, serial: &str| json!({"part": {"serial": serial, "kind": "spider"}, "target_xpeak_m": 0.004, "bench": bench});
    let (s, p) = Api::with(&d, STATION)
        .exchange(
            Method::POST,
            "/api/v1/jobs",
            Some(&body("virtual-2", "SN-F2")),
        )
        .await;
    assert_eq!(s, 409, "{p}");
    assert_eq!(p["type"], "/problems/bench-faulted", "{p}");
    let detail = p["detail"].as_str().unwrap();
    assert!(
        detail.contains("virtual-2")
            && detail.contains("laser signal lost")
            && detail.contains("self-check"),
        "{detail}"
    );
    assert_eq!(
        p["fault"]["detail"], "laser signal lost: 0 valid frames in 0.5 s",
        "{p}"
    );
    let jobs = station(&d).get("/api/v1/jobs?limit=50").await;
    assert!(
        !jobs.to_string().contains("SN-F2"),
        "nothing queued: {jobs}"
    );
    let (s, v) = Api::with(&d, STATION)
        .exchange(
            Method::POST,
            "/api/v1/jobs",
            Some(&body("virtual-1", "SN-F1")),
        )
        .await;
    assert_eq!(s, 202, "{v}");
    drop(d);
    drop(tmp);
}

/// The messages the reference CFX SDK reads (issue 34, decision 0095): every
/// example job's messages (golden, pass, fail, invalid, production with a
/// fall-back, level series, cancelled, failed, interrupted, no recipe) and
/// the endpoint's own are read strictly against the SDK's shapes; they are
/// the messages the SDK itself read (tests/cfx_sdk/examples, sdk_check.json),
/// with every value, limit, unit and result back in its round trip. With
/// `CFX_SDK_DIR` set (a checkout of the SDK; mono installed), the SDK reads
/// them here and now; `CFX_FIXTURES=write` writes the examples anew.
#[test]
fn cfx_messages_are_read_by_the_reference_sdk() {
    let shapes = cfx_sdk::Shapes::load();
    let msgs = cfx_sdk::examples();
    let dir = cfx_sdk::dir().join("examples");
    if std::env::var("CFX_FIXTURES").as_deref() == Ok("write") {
        let _ = std::fs::remove_dir_all(&dir);
        cfx_sdk::write_messages(&dir, &msgs);
    }
    let mut bad = vec![];
    for (n, m) in &msgs {
        bad.extend(shapes.check(m).into_iter().map(|e| format!("{n}: {e}")));
    }
    assert!(
        bad.is_empty(),
        "{} problems the SDK's strict reading refuses:\n{}",
        bad.len(),
        bad.join("\n")
    );
    // The examples the SDK read are these messages.
    let stored: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        stored.len(),
        msgs.len(),
        "tests/cfx_sdk/examples: {stored:?}"
    );
    for (n, m) in &msgs {
        let s: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(n)).unwrap()).unwrap();
        assert_eq!(
            &s, m,
            "{n} is not what the SDK read: write the examples (CFX_FIXTURES=write) and let the SDK read them (tests/cfx_sdk/run.sh check)"
        );
    }
    // The strict check refuses whatever the SDK refused of the messages as
    // they were before issue 34 (tests/cfx_sdk/before, sdk_check_before.json).
    let before: Value = serde_json::from_str(
        &std::fs::read_to_string(cfx_sdk::dir().join("sdk_check_before.json")).unwrap(),
    )
    .unwrap();
    let mut refused = (0, 0);
    for (n, r) in before["messages"].as_object().unwrap() {
        let m: Value = serde_json::from_str(
            &std::fs::read_to_string(cfx_sdk::dir().join("before").join(n)).unwrap(),
        )
        .unwrap();
        let sdk_ok = r["from_json"] == "ok" && r["strict"] == "ok";
        let ours = shapes.check(&m);
        assert!(
            sdk_ok || !ours.is_empty(),
            "{n}: the SDK refused it ({r}), Shapes::check did not"
        );
        refused.0 += usize::from(!sdk_ok);
        refused.1 += usize::from(!ours.is_empty());
    }
    println!(
        "before issue 34: the SDK refused {} of {} messages, Shapes::check {}",
        refused.0,
        before["messages"].as_object().unwrap().len(),
        refused.1
    );
    let live = tempfile::tempdir().unwrap();
    let sdk = cfx_sdk::sdk_check(&dir, &live.path().join("sdk_check.json")).unwrap_or_else(|| {
        println!(
            "CFX_SDK_DIR not set: the SDK's reading as pinned in tests/cfx_sdk/sdk_check.json"
        );
        serde_json::from_str(
            &std::fs::read_to_string(cfx_sdk::dir().join("sdk_check.json")).unwrap(),
        )
        .unwrap()
    });
    let mut lost = vec![];
    for (n, m) in &msgs {
        let r = &sdk["messages"][n];
        assert_eq!(r["from_json"], "ok", "{n}: CFXEnvelope.FromJson: {r}");
        assert_eq!(r["strict"], "ok", "{n}: strict reading: {r}");
        cfx_sdk::lost_in_round_trip(m, &r["round_trip"], n, &mut lost);
    }
    assert!(
        lost.is_empty(),
        "lost in the SDK's round trip:\n{}",
        lost.join("\n")
    );
    let values = msgs
        .values()
        .flat_map(|m| {
            m["MessageBody"]["TestedUnits"][0]["Tests"]
                .as_array()
                .cloned()
                .unwrap_or_default()
        })
        .map(|t| t["Measurements"].as_array().map_or(0, Vec::len))
        .sum::<usize>();
    println!(
        "CFX: {} messages ({values} measured values) read by the SDK {}: FromJson, strict, round trip",
        msgs.len(),
        sdk["sdk_version"]
    );
}

/// `GET /api/v1/recipes/pools/lot.csv{query}` as rows by column name.
async fn lot_csv(d: &Daemon, query: &str) -> Vec<HashMap<String, String>> {
    let r = station(d)
        .builder(
            Method::GET,
            &format!("/api/v1/recipes/pools/lot.csv{query}"),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200, "lot.csv{query}");
    assert_eq!(r.headers()["content-type"], "text/csv; charset=utf-8");
    let text = r.text().await.unwrap();
    let mut rd = csv::Reader::from_reader(text.as_bytes());
    let h: Vec<String> = rd.headers().unwrap().iter().map(String::from).collect();
    rd.records()
        .map(|rec| {
            h.iter()
                .cloned()
                .zip(rec.unwrap().iter().map(String::from))
                .collect()
        })
        .collect()
}

/// Pools (issue 35, decision 0100): SPC and yield count production only.
/// Production parts, golden units and a gauge study's runs of known parts
/// under one recipe: the SPC figures of the recipe are those of the
/// production parts alone (computed here from their stored k0), while
/// `purpose=all` and each other pool count their own, and the gauge study
/// keeps its figures. Before pools, the gauge study's four soft runs and the
/// golden units were SPC points (n 11 instead of 5).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spc_and_yield_count_production_parts_only() {
    let d = Daemon::start(&format!("{}{}", tokens(), benches()));
    let k0 = springbench::physics::preset("spider_4in")
        .unwrap()
        .k_coeffs_si[0];
    let recipe = json!({
        "name": "pools",
        "part_kind": "spider",
        "procedure": {"levels_m": [0.004], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0", "lower": 0.85 * k0, "upper": 1.15 * k0},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ]
    });
    let (s, v) = Api::with(&d, ENGINEER)
        .exchange(Method::POST, "/api/v1/recipes", Some(&recipe))
        .await;
    assert_eq!(s, 201, "{v}");
    let part = |serial: &str, seed: u64, defect: Option<&str>, purpose: Option<&str>| {
        let mut production = json!({"preset": "spider_4in", "seed": seed});
        if let Some(d) = defect {
            production["defect"] = json!(d);
        }
        let mut b =
            json!({"part": {"serial": serial}, "recipe": "pools", "production": production});
        if let Some(p) = purpose {
            b["purpose"] = json!(p);
        }
        b
    };
    // Production: four good parts (one says so, three take the default) and
    // a stiff one (k0 30 % high: fails). Golden units: two soft parts
    // (k0 30 % low), so that counting them would move every figure.
    let production = [
        part("P-1", 11, None, Some("production")),
        part("P-2", 12, None, None),
        part("P-3", 13, None, None),
        part("P-4", 14, None, None),
        part("P-stiff", 15, Some("stiff"), None),
    ];
    let golden = [
        part("G-1", 21, Some("soft"), Some("golden_unit")),
        part("G-2", 22, Some("soft"), Some("golden_unit")),
    ];
    let bodies: Vec<Value> = production.iter().chain(&golden).cloned().collect();
    let done = run_jobs(&d, &bodies).await;
    for (j, b) in done.iter().zip(&bodies) {
        assert_eq!(j["state"], "succeeded", "{j}");
        let want = b["purpose"].as_str().unwrap_or("production");
        assert_eq!(j["request"]["purpose"], want, "{}", b["part"]["serial"]);
    }
    // A gauge study of two soft parts, twice each on one bench: four runs.
    let (s, study) = Api::with(&d, STATION).exchange(Method::POST, "/api/v1/gauge-studies", Some(&json!({"recipe": "pools", "repeats": 2, "benches": ["virtual-1"], "parts": [
            {"serial": "S-1", "production": {"preset": "spider_4in", "seed": 31, "defect": "soft"}},
            {"serial": "S-2", "production": {"preset": "spider_4in", "seed": 32, "defect": "soft"}}
        ]})))
    .await;
    assert_eq!(s, 201, "{study}");
    let sid = study["id"].as_str().unwrap();
    let t = Instant::now();
    let study = loop {
        let v = station(&d)
            .get(&format!("/api/v1/gauge-studies/{sid}"))
            .await;
        if v["state"] == "done" {
            break v;
        }
        assert!(t.elapsed() < Duration::from_secs(600), "study: {v}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    // The study keeps working: its runs are its own, with figures for k0.
    let runs = study["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    for r in runs {
        let j = station(&d)
            .get(&format!("/api/v1/jobs/{}", r["job_id"].as_str().unwrap()))
            .await;
        assert_eq!(j["request"]["purpose"], "gauge_study", "{j}");
    }
    assert!(
        study.to_string().contains("\"k0\""),
        "the study has its k0 figures: {study}"
    );

    // The production parts' k0 as stored, in job order.
    let mut values = vec![];
    for j in &done[..production.len()] {
        let mid = j["measurement_ids"][0].as_str().unwrap();
        let m = station(&d)
            .get(&format!("/api/v1/measurements/{mid}"))
            .await;
        values.push(m["small_signal"]["k0_n_per_m"].as_f64().unwrap());
    }
    let spc = station(&d)
        .get("/api/v1/recipes/pools/spc?parameter=k0&last=1000")
        .await;
    assert_eq!(spc["purpose"], "production");
    assert_eq!(
        (spc["n"].as_u64(), spc["invalid"].as_u64()),
        (Some(5), Some(0)),
        "{spc}"
    );
    let got: Vec<f64> = spc["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["value"].as_f64().unwrap())
        .collect();
    assert_eq!(got, values, "the points are the production parts' k0");
    for p in spc["points"].as_array().unwrap() {
        assert_eq!(p["recipe_version"], 1, "{p}");
    }
    let (mean, sd) = mean_sd(&values);
    let sw = values.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / 4.0 / 1.128;
    let (lo, hi) = (0.85 * k0, 1.15 * k0);
    let cpk = (hi - mean).min(mean - lo) / (3.0 * sw);
    let ppk = (hi - mean).min(mean - lo) / (3.0 * sd);
    let rel = |a: &Value, b: f64| {
        let a = a.as_f64().unwrap();
        assert!((a - b).abs() <= 1e-9 * b.abs(), "{a} vs {b}");
    };
    rel(&spc["mean"], mean);
    rel(&spc["sigma"], sd);
    rel(&spc["cpk"], cpk);
    rel(&spc["ppk"], ppk);
    assert_eq!(
        (spc["passed"].as_u64(), spc["failed"].as_u64()),
        (Some(4), Some(1))
    );
    rel(&spc["yield_fraction"], 0.8);
    // Western Electric signals of the production chart: those of its values.
    let signals = springbench::qc::spc::western_electric(&values, mean, sw);
    assert_eq!(spc["rules"], serde_json::to_value(&signals).unwrap());
    // The other pools, and all of them when asked.
    for (purpose, n) in [
        ("all", 11),
        ("golden_unit", 2),
        ("gauge_study", 4),
        ("engineering", 0),
    ] {
        let s = station(&d)
            .get(&format!(
                "/api/v1/recipes/pools/spc?parameter=k0&last=1000&purpose={purpose}"
            ))
            .await;
        // (a gauge run may be invalid: counted apart, without a value)
        let counted = s["n"].as_u64().unwrap() + s["invalid"].as_u64().unwrap();
        assert_eq!(counted, n, "{purpose}: {s}");
        assert_eq!(s["purpose"], purpose);
    }
    let (s, v) = Api::with(&d, STATION)
        .exchange(
            Method::GET,
            "/api/v1/recipes/pools/spc?parameter=k0&purpose=scrap",
            None,
        )
        .await;
    assert_eq!(s, 422, "{v}");
    assert!(v.to_string().contains("purpose"), "{v}");
    // The lot export: a row per production measurement, each value and
    // result as the API's verdict shows it (to 1e-9), with its trace.
    let rows = lot_csv(&d, "").await;
    assert_eq!(rows.len(), production.len());
    for j in &done[..production.len()] {
        let jid = j["id"].as_str().unwrap();
        let jv = station(&d)
            .get(&format!("/api/v1/jobs/{jid}/verdict"))
            .await;
        for m in jv["measurements"].as_array().unwrap() {
            let mid = m["measurement_id"].as_str().unwrap();
            let row = rows
                .iter()
                .find(|r| r["measurement_id"] == mid)
                .unwrap_or_else(|| panic!("measurement {mid} not in the lot"));
            assert_eq!(row["part_serial"], m["part_serial"].as_str().unwrap());
            assert_eq!(row["job_id"], jid);
            assert_eq!(row["verdict"], m["verdict"].as_str().unwrap());
            assert_eq!(row["recipe_version"], "1");
            assert_eq!(row["purpose"], "production");
            assert_eq!(
                row["bench_id"],
                m["traceability"]["bench_id"].as_str().unwrap()
            );
            let params = m["detail"]["parameters"].as_array().unwrap();
            assert!(!params.is_empty(), "{m}");
            for p in params {
                let (name, unit) = (p["name"].as_str().unwrap(), p["unit"].as_str().unwrap());
                let want = p["value"].as_f64().unwrap();
                let got: f64 = row[&format!("{name} [{unit}]")].parse().unwrap();
                assert!(
                    (got - want).abs() <= 1e-9 * want.abs(),
                    "{name}: {got} vs {want}"
                );
                assert_eq!(
                    row[&format!("{name} result")],
                    p["result"].as_str().unwrap()
                );
            }
        }
    }
    let all = lot_csv(&d, "?purpose=all").await;
    let count = |p: &str| all.iter().filter(|r| r["purpose"] == p).count();
    assert_eq!(
        (
            all.len(),
            count("production"),
            count("golden_unit"),
            count("gauge_study")
        ),
        (11, 5, 2, 4)
    );
    let (s, v) = station(&d)
        .exchange(
            Method::GET,
            "/api/v1/recipes/pools/lot.csv?since=yesterday",
            None,
        )
        .await;
    assert_eq!(s, 422, "{v}");
    assert!(v.to_string().contains("since"), "{v}");
    println!(
        "pools: production k0 mean {mean:.1} N/m, Cpk {cpk:.3}; all pools n 11, mean {}",
        station(&d)
            .get("/api/v1/recipes/pools/spc?parameter=k0&last=1000&purpose=all")
            .await["mean"]
    );
}
