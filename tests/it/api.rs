//! The daemon over real HTTP and websocket: validation, problem documents,
//! idempotency, auth, events, import, job failure. (The measurement itself,
//! cancel while running and kill -9 are in tests/it/daemon.rs.)

use crate::common;

use common::{Api, Config, Daemon};
use futures_util::StreamExt;
use reqwest::Method;
use serde_json::{json, Value};
use springbench::recording::RecordingSetFiles;
use std::time::Duration;

#[tokio::test]
async fn health_ready_metrics_and_unknown_routes() {
    let d = Daemon::start("");
    let api = Api::new(&d);
    let h = api.get("/healthz").await;
    assert_eq!(h["status"], "ok");
    let r = api.get("/readyz").await;
    assert_eq!(r["benches"][0]["id"], "virtual-1");
    assert_eq!(r["benches"][0]["state"], "idle");
    let m = api.text("/metrics").await;
    assert!(m.contains("springbench_jobs{state=\"queued\"} 0"), "{m}");
    assert!(
        m.contains(
            "springbench_http_requests_total{method=\"GET\",route=\"/healthz\",status=\"200\"} 1"
        ),
        "{m}"
    );
    api.get_reply("/api/v1/nope").await.problem(404);
    api.send(
        api.builder(Method::DELETE, "/api/v1/jobs")
            .header("content-type", "application/json"),
    )
    .await
    .problem(405);
    let p = api
        .get_reply("/api/v1/jobs/does-not-exist")
        .await
        .problem(404);
    assert!(p["detail"].as_str().unwrap().contains("does-not-exist"));
    for (path, status) in [
        ("/api/v1/measurements/x", 404),
        ("/api/v1/parts/x", 404),
        ("/api/v1/jobs?state=finished", 422),
        ("/api/v1/jobs?limit=0", 422),
        ("/api/v1/jobs?limit=abc", 400),
    ] {
        api.get_reply(path).await.problem(status);
    }
    api.post_empty("/api/v1/jobs/x/cancel").await.problem(404);
    // A plain GET on the websocket route is refused with a problem document.
    let r = api.get_reply("/api/v1/events").await;
    assert!((400..500).contains(&r.status));
    assert_eq!(r.header("content-type"), "application/problem+json");
}

#[tokio::test]
async fn bad_job_requests_get_one_message_per_field() {
    let d = Daemon::start("");
    let api = Api::new(&d);
    let post = |body: String| {
        api.send(
            api.builder(Method::POST, "/api/v1/jobs")
                .header("content-type", "application/json")
                .body(body),
        )
    };
    let bad = json!({"part": {"serial": "SN-1"}, "moving_mass_kg": 0.0, "levels_m": [0.004, 0.5],
                     "method": "three-signal", "preset": "no-such-part", "wat": 1});
    let p = post(bad.to_string()).await.problem(422);
    let fields: Vec<&str> = p["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["field"].as_str().unwrap())
        .collect();
    for f in ["wat", "moving_mass_kg", "levels_m[1]", "method", "preset"] {
        assert!(fields.contains(&f), "{f} not in {fields:?}");
    }
    for e in p["errors"].as_array().unwrap() {
        assert!(!e["message"].as_str().unwrap().is_empty());
    }
    // NaN cannot be written in JSON; a string or a huge number is caught.
    let nan = r#"{"part": {"serial": "SN-1"}, "moving_mass_kg": "NaN"}"#;
    let p = post(nan.into()).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "moving_mass_kg");
    let huge = r#"{"part": {"serial": "SN-1"}, "moving_mass_kg": 1e400}"#;
    let p = post(huge.into()).await.problem(400);
    assert!(p["detail"].as_str().unwrap().contains("JSON"));
    // Beyond the bench's limits.
    let drive = json!({"part": {"serial": "S"}, "moving_mass_kg": 0.02,
                     "limits": {"max_drive_v": 1000.0}});
    let p = post(drive.to_string()).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "limits.max_drive_v");
    let far = json!({"part": {"serial": "S"}, "moving_mass_kg": 0.02, "target_xpeak_m": 0.05});
    let p = post(far.to_string()).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "target_xpeak_m");
    // Not JSON at all, missing part, oversize body.
    post("{not json".into()).await.problem(400);
    let p = post("{}".into()).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "part");
    // Oversize: the declared Content-Length alone is refused, before any of
    // the body is read. (Sent raw, headers only: a client still writing a
    // body the server will not read may see a broken pipe instead of the
    // answer, which made this test flaky under load.)
    let (status, headers, body) = common::raw(
        &d.addr(),
        format!(
            "POST /api/v1/jobs HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\nContent-Length: 1100000\r\nConnection: close\r\n\r\n{{",
            d.addr()
        )
        .as_bytes(),
    );
    assert_eq!(status, 413, "{headers}");
    assert!(
        headers
            .to_ascii_lowercase()
            .contains("application/problem+json"),
        "{headers}"
    );
    let p: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(p["status"], 413);
    // Nothing was stored.
    let jobs = api.get("/api/v1/jobs").await;
    assert_eq!(jobs["items"].as_array().unwrap().len(), 0);
}

#[tokio::test]
async fn idempotent_resubmit_and_conflict() {
    let d = Daemon::start("");
    let api = Api::new(&d);
    let keyed = |body: &Value| {
        api.send(
            api.builder(Method::POST, "/api/v1/jobs")
                .header("Idempotency-Key", "qc1-0001")
                .json(body),
        )
    };
    let body = json!({"part": {"serial": "SN-7"}, "moving_mass_kg": 0.02, "priority": 3});
    let r1 = keyed(&body).await;
    let loc = r1.header("location").to_string();
    let j1 = r1.expect(202);
    assert_eq!(loc, format!("/api/v1/jobs/{}", j1["id"].as_str().unwrap()));
    assert_eq!(j1["state"], "queued");
    assert_eq!(j1["priority"], 3);
    // The same key and body: the same job, not a second one.
    let r2 = keyed(&body).await;
    assert_eq!(r2.header("idempotent-replayed"), "true");
    let j2 = r2.expect(200);
    assert_eq!(j2["id"], j1["id"]);
    // The same key with another body: 409.
    let other = json!({"part": {"serial": "SN-8"}, "moving_mass_kg": 0.02});
    let p = keyed(&other).await.problem(409);
    assert_eq!(p["job_id"], j1["id"]);
    let jobs = api.get("/api/v1/jobs").await;
    assert_eq!(jobs["items"].as_array().unwrap().len(), 1);
    // The part exists now.
    let part = api.get("/api/v1/parts/SN-7").await;
    assert_eq!(part["serial"], "SN-7");
}

/// A job the procedure cannot do (a displacement limit below the 1 mm the
/// pre-measurement needs) fails with a problem document; the events tell the whole story in order,
/// and cancelling the finished job gives 409.
#[tokio::test]
async fn impossible_job_fails_with_a_problem_and_events() {
    let d = Daemon::start("");
    let api = Api::new(&d);
    let (mut ws, _) = tokio_tungstenite::connect_async(d.ws_url("/api/v1/events?after=0"))
        .await
        .expect("websocket");
    let small = json!({"part": {"serial": "SN-9", "kind": "spider"}, "target_xpeak_m": 0.0005,
                      "limits": {"max_displacement_m": 0.0008}});
    let id = api.submit(&small).await;
    let j = api.finished_within(&id, Duration::from_secs(120)).await;
    assert_eq!(j["state"], "failed", "{j}");
    let p = &j["problem"];
    assert!(p["type"].as_str().unwrap().starts_with("/problems/"), "{j}");
    assert!(!p["detail"].as_str().unwrap().is_empty());
    assert!(j["finished_at"].is_string());
    assert_eq!(j["measurement_ids"].as_array().unwrap().len(), 0);

    // Events: queued, running, (progress...), failed, with increasing seq.
    let mut states = vec![];
    let mut last_seq = 0;
    while states.last().map(String::as_str) != Some("failed") {
        let m = tokio::time::timeout(Duration::from_secs(30), ws.next())
            .await
            .expect("an event within 30 s")
            .unwrap()
            .unwrap();
        let e: Value = serde_json::from_str(m.to_text().unwrap()).unwrap();
        if e["live"] == true {
            continue;
        }
        let seq = e["seq"].as_i64().unwrap();
        assert!(seq > last_seq, "seq {seq} after {last_seq}");
        last_seq = seq;
        assert_eq!(e["job_id"], id.as_str());
        if e["type"] == "job.state" {
            states.push(e["data"]["state"].as_str().unwrap().to_string());
        }
    }
    assert_eq!(states, ["queued", "running", "failed"]);

    // Resume after the first event: the replay starts right after it.
    let (mut ws2, _) = tokio_tungstenite::connect_async(d.ws_url("/api/v1/events?after=1"))
        .await
        .unwrap();
    let m = tokio::time::timeout(Duration::from_secs(10), ws2.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let e: Value = serde_json::from_str(m.to_text().unwrap()).unwrap();
    assert_eq!(e["seq"], 2);
    assert_eq!(e["data"]["state"], "running");

    let cancel = format!("/api/v1/jobs/{id}/cancel");
    let p = api.post_empty(&cancel).await.problem(409);
    assert_eq!(p["state"], "failed");
    let m = api.text("/metrics").await;
    assert!(m.contains("springbench_jobs{state=\"failed\"} 1"), "{m}");
}

#[tokio::test]
async fn bearer_tokens_and_roles() {
    let (v, o, a) = (
        "viewer-token-0123456789",
        "operator-token-0123456789",
        "admin-token-0123456789",
    );
    let cfg = Config::new()
        .token("mes", v, springbench::config::Role::Viewer)
        .token("qc", o, springbench::config::Role::Operator)
        .token("lab", a, springbench::config::Role::Admin);
    let d = Daemon::start(&cfg.text());
    let open = Api::new(&d);
    let job = json!({"part": {"serial": "SN-A"}, "moving_mass_kg": 0.02});
    // Open routes.
    assert_eq!(open.get_reply("/healthz").await.status, 200);
    assert_eq!(open.get_reply("/readyz").await.status, 200);
    // No token, unknown token: 401 with a challenge.
    let r = open.get_reply("/api/v1/jobs").await;
    assert!(r.header("www-authenticate").starts_with("Bearer"));
    r.problem(401);
    let nope = open.token("nope-nope-nope-nope");
    nope.get_reply("/api/v1/jobs").await.problem(401);
    // Viewer reads, may not submit or read the configuration.
    let viewer = open.token(v);
    assert_eq!(viewer.get_reply("/api/v1/jobs").await.status, 200);
    assert_eq!(viewer.get_reply("/metrics").await.status, 200);
    viewer.post("/api/v1/jobs", &job).await.problem(403);
    viewer.get_reply("/api/v1/config").await.problem(403);
    // Operator submits and cancels.
    let operator = open.token(o);
    assert_eq!(operator.post("/api/v1/jobs", &job).await.status, 202);
    operator.get_reply("/api/v1/config").await.problem(403);
    // Admin reads the configuration, without the secrets.
    let cfg = open.token(a).text("/api/v1/config").await;
    assert!(
        cfg.contains("virtual-1") && !cfg.contains("0123456789"),
        "{cfg}"
    );
    // Websocket: token as a query parameter.
    assert!(tokio_tungstenite::connect_async(d.ws_url("/api/v1/events"))
        .await
        .is_err());
    let ok =
        tokio_tungstenite::connect_async(d.ws_url(&format!("/api/v1/events?after=0&token={v}")))
            .await;
    assert!(ok.is_ok());
}

/// A multipart upload of meta, pre and main (what an import sends).
fn upload(meta: Vec<u8>, pre: Vec<u8>, main: Vec<u8>) -> reqwest::multipart::Form {
    let part = |bytes: Vec<u8>, name: &str| {
        reqwest::multipart::Part::bytes(bytes).file_name(name.to_string())
    };
    reqwest::multipart::Form::new()
        .part("meta", part(meta, "meta.json"))
        .part("pre", part(pre, "pre.wav"))
        .part("main", part(main, "main.wav"))
}

#[tokio::test]
async fn import_stores_the_recordings_and_refuses_bad_uploads() {
    let d = Daemon::start("");
    let api = Api::with(&d, "any-value-in-open-access");
    let dir = common::reference_dir("p1_spider");
    let meta = std::fs::read(dir.join("meta.json")).unwrap();
    let pre = std::fs::read(dir.join("pre.wav")).unwrap();
    let main = std::fs::read(dir.join("main.wav")).unwrap();
    let form = |meta: Vec<u8>, pre: Vec<u8>, main: Vec<u8>| {
        upload(meta, pre, main)
            .text("serial", "REF-P1")
            .text("kind", "spider")
    };
    let import = |form: reqwest::multipart::Form| {
        api.send(
            api.builder(Method::POST, "/api/v1/measurements")
                .multipart(form),
        )
    };
    let doc = import(form(meta.clone(), pre.clone(), main.clone()))
        .await
        .expect(201);
    let id = doc["measurement"]["id"].as_str().unwrap().to_string();
    assert_eq!(doc["measurement"]["source"], "import");
    assert_eq!(doc["measurement"]["part_serial"], "REF-P1");
    // The stored recording reads back with the same samples (float32 as sent).
    let wav = api
        .builder(
            Method::GET,
            &format!("/api/v1/measurements/{id}/recordings/main.wav"),
        )
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let set = springbench::recording::RecordingSet::read_dir(&dir).unwrap();
    let meta_std = springbench::recording::Meta::standard(0.05, 48000.0);
    let back =
        springbench::recording::read_signals(std::io::Cursor::new(&wav[..]), &meta_std).unwrap();
    assert_eq!(back.len(), set.main.len());
    let max_err = back
        .displacement_m
        .iter()
        .zip(&set.main.displacement_m)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(max_err <= 1e-9, "{max_err}");
    let other = format!("/api/v1/measurements/{id}/recordings/other.wav");
    api.get_reply(&other).await.problem(404);
    // Listed under the part.
    let l = api.get("/api/v1/parts/REF-P1/measurements").await;
    assert_eq!(l["items"][0]["id"], id.as_str());

    // Broken uploads: a WAV that is not one, a missing field, too large.
    let not_wav = form(meta.clone(), b"RIFF nonsense".to_vec(), main.clone());
    let p = import(not_wav).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "pre");
    let meta_only = reqwest::multipart::Form::new()
        .part("meta", reqwest::multipart::Part::bytes(meta.clone()))
        .text("serial", "X");
    let p = import(meta_only).await.problem(422);
    let f: Vec<_> = p["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["field"].as_str().unwrap())
        .collect();
    assert_eq!(f, ["pre", "main"]);
    let l = api.get("/api/v1/measurements").await;
    assert_eq!(l["items"].as_array().unwrap().len(), 1);

    // Fits and diagnostics on the stored recordings: a bad request is refused
    // before any work; a valid one either fits or says why it cannot.
    let api = Api::new(&d);
    let fits = format!("/api/v1/measurements/{id}/fits");
    let warp = json!({"effects": ["warp_drive"]});
    let p = api.post(&fits, &warp).await.problem(422);
    assert_eq!(p["errors"][0]["field"], "effects[0]");
    let nope = "/api/v1/measurements/nope/fits";
    api.post(nope, &json!({})).await.problem(404);
    let svg = format!("/api/v1/measurements/{id}/plots/nonsense.svg");
    api.get_reply(&svg).await.problem(404);
}

/// The declared length is checked before the body is read, so the client
/// sends the headers only (sending the whole body races with the server's
/// close after its early 413 and can end in a connection reset).
#[test]
fn oversize_upload_is_413() {
    use std::io::{Read, Write};
    let d = Daemon::start("max_upload_bytes = 100000");
    let mut s = std::net::TcpStream::connect(d.addr()).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    write!(
        s,
        "POST /api/v1/measurements HTTP/1.1\r\nHost: {}\r\nAuthorization: Bearer any-value-in-open-access\r\nContent-Type: multipart/form-data; boundary=x\r\nContent-Length: 150000\r\nConnection: close\r\n\r\n--x\r\n",
        d.addr()
    )
    .unwrap();
    let mut answer = String::new();
    let _ = s.read_to_string(&mut answer);
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    assert!(answer.contains("100000"), "{answer}");
}

/// Issue 5 over the API: fits of stored recordings are kept, diagnostics and
/// SVG plots are served (p2_spider_friction has a hidden Coulomb friction).
#[tokio::test]
async fn fits_diagnostics_and_plots_of_an_imported_set() {
    let d = Daemon::start("");
    let api = Api::with(&d, "any-value-in-open-access");
    let dir = common::reference_dir("p2_spider_friction");
    let file = |name: &str| std::fs::read(dir.join(name)).unwrap();
    let form =
        upload(file("meta.json"), file("pre.wav"), file("main.wav")).text("serial", "REF-P2");
    let r = api
        .builder(Method::POST, "/api/v1/measurements")
        .multipart(form);
    let doc = api.send(r).await.expect(201);
    let id = doc["measurement"]["id"].as_str().unwrap().to_string();
    assert!(doc["measurement"]["analysis_error"].is_null(), "{doc}");
    assert!(
        doc["stiffness"]["coefficients_n_per_m_pow_i_plus_1"]
            .as_array()
            .unwrap()
            .len()
            >= 2
    );

    let api = Api::new(&d);
    let diag = api
        .get(&format!("/api/v1/measurements/{id}/diagnostics"))
        .await;
    let cands = diag["diagnostics"]["candidates"]
        .as_array()
        .expect("candidates");
    assert_eq!(cands[0]["effect"], "coulomb_friction", "{diag}");
    let plots = diag["plots"].as_array().unwrap();
    assert!(!plots.is_empty());
    let svg = api.get_reply(plots[0].as_str().unwrap()).await;
    assert_eq!(svg.header("content-type"), "image/svg+xml");
    assert!(svg.text.contains("<svg"));

    // The base model (first ladder step) misses the friction.
    let base_error = diag["diagnostics"]["ladder"][0]["model_error_percent"]
        .as_f64()
        .unwrap();
    // Two fits, both kept; with friction forced in, the model carries its
    // force and explains more than the base model.
    let path = format!("/api/v1/measurements/{id}/fits");
    let mut fits_made = vec![];
    for (effects, order) in [
        (json!(["coulomb_friction"]), json!(null)),
        (json!(["coulomb_friction"]), json!(5)),
    ] {
        let body = json!({"effects": effects, "order": order});
        let f = api.post(&path, &body).await.expect(201);
        let model = &f["result"]["model"];
        assert!(model["effects"]["coulomb_friction"].is_object(), "{model}");
        let e = model["model_error_percent"].as_f64().unwrap();
        assert!(e < base_error, "fit {e} % vs base {base_error} %");
        assert_eq!(f["request"]["effects"], effects);
        fits_made.push(f["id"].as_str().unwrap().to_string());
    }
    let fits = api.get(&path).await;
    let ids: Vec<_> = fits["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["id"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(ids, fits_made);
}

#[test]
fn bad_configuration_is_one_line_and_a_non_zero_exit() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("bad.toml");
    for (text, want) in [
        ("bnid = \"x\"", "bnid"),
        (
            "[[benches]]\nid = \"b\"\npreset = \"no_such_part\"",
            "no_such_part",
        ),
        ("bind = \"nonsense\"", "bind address"),
    ] {
        std::fs::write(&cfg, text).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_springbench"))
            .args(["serve", "--config"])
            .arg(&cfg)
            .arg("--data-dir")
            .arg(dir.path().join("data"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(want), "{err}");
        assert!(!err.contains("panicked"));
    }
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_springbench"))
        .args(["serve", "--config", "/nonexistent/springbench.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/springbench.toml"));
}
