//! Issue 11 (hardening), HTTP side: each test makes one defect of the
//! issue's "Why" happen against the real daemon over real sockets.
//! Figures measured here are printed and kept in docs/http-hardening.md.

mod common;

use common::{client, problem, raw, read_response, rss_kb, Daemon};
use serde_json::{json, Value};
use std::io::{BufReader, Write};
use std::time::Duration;

fn post_raw(d: &Daemon, path: &str, headers: &str, body: &str) -> (u16, String, Value) {
    let req = format!(
        "POST {path} HTTP/1.1\r\nHost: {}\r\n{headers}Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        d.addr(),
        body.len()
    );
    let (s, h, b) = raw(&d.addr(), req.as_bytes());
    (s, h, serde_json::from_slice(&b).unwrap_or(Value::Null))
}

fn jobs_count(d: &Daemon) -> usize {
    let (s, _, b) = raw(
        &d.addr(),
        format!(
            "GET /api/v1/jobs HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            d.addr()
        )
        .as_bytes(),
    );
    assert_eq!(s, 200);
    let v: Value = serde_json::from_slice(&b).unwrap();
    v["items"].as_array().unwrap().len()
}

/// Cross-site requests a browser sends without a preflight (text/plain,
/// form-encoded, multipart, a foreign Origin) cannot start or cancel jobs.
#[test]
fn cross_site_posts_are_refused() {
    let d = Daemon::start("");
    let job = r#"{"part": {"serial": "SN-CSRF"}}"#;
    // text/plain with a foreign Origin (the issue's 202 on main)
    let (s, _, p) = post_raw(
        &d,
        "/api/v1/jobs",
        "Content-Type: text/plain\r\nOrigin: https://evil.example\r\n",
        job,
    );
    assert_eq!(s, 403, "{p}");
    assert_eq!(p["type"], "/problems/origin-not-allowed");
    // text/plain and form-encoded without an Origin (old browsers): no JSON, no token
    for ct in [
        "text/plain",
        "application/x-www-form-urlencoded",
        "multipart/form-data; boundary=x",
    ] {
        let (s, _, p) = post_raw(&d, "/api/v1/jobs", &format!("Content-Type: {ct}\r\n"), job);
        assert_eq!(s, 415, "{ct}: {p}");
        assert_eq!(p["type"], "/problems/unsupported-media-type");
    }
    let (s, _, _) = post_raw(&d, "/api/v1/jobs/x/cancel", "", "");
    assert_eq!(s, 415);
    // JSON from a foreign origin is refused too (the CORS preflight would be, too).
    let (s, _, _) = post_raw(
        &d,
        "/api/v1/jobs",
        "Content-Type: application/json\r\nOrigin: http://127.0.0.1:9999\r\n",
        job,
    );
    assert_eq!(s, 403);
    assert_eq!(jobs_count(&d), 0, "a refused request created a job");
    // The daemon's own origin (its web UI) with JSON is accepted.
    let (s, _, j) = post_raw(
        &d,
        "/api/v1/jobs",
        &format!(
            "Content-Type: application/json; charset=utf-8\r\nOrigin: http://{}\r\n",
            d.addr()
        ),
        job,
    );
    assert_eq!(s, 202, "{j}");
    assert_eq!(jobs_count(&d), 1);
}

/// DNS rebinding: a page on evil.example whose name resolves to 127.0.0.1
/// sends `Host: evil.example`; names must be configured to be accepted.
#[test]
fn foreign_host_is_refused_and_configured_names_are_accepted() {
    let d = Daemon::start(
        "[http]\nallowed_hosts = [\"bench-7.lab\"]\nallowed_origins = [\"https://mes.lab\"]",
    );
    let get = |host: &str, extra: &str| {
        raw(
            &d.addr(),
            format!(
                "GET /api/v1/jobs HTTP/1.1\r\nHost: {host}\r\n{extra}Connection: close\r\n\r\n"
            )
            .as_bytes(),
        )
    };
    let (s, _, b) = get("evil.example:8750", "");
    assert_eq!(s, 403);
    let p: Value = serde_json::from_slice(&b).unwrap();
    assert_eq!(p["type"], "/problems/host-not-allowed");
    assert!(p["detail"].as_str().unwrap().contains("evil.example"));
    for ok in ["bench-7.lab:8750", "localhost:8750", "127.0.0.1", "[::1]:1"] {
        assert_eq!(get(ok, "").0, 200, "{ok}");
    }
    // a listed origin may call the API; a websocket from a foreign origin may not
    assert_eq!(get("bench-7.lab", "Origin: https://mes.lab\r\n").0, 200);
    let (s, _, _) = raw(
        &d.addr(),
        format!(
            "GET /api/v1/events HTTP/1.1\r\nHost: {}\r\nOrigin: https://evil.example\r\nConnection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n",
            d.addr()
        )
        .as_bytes(),
    );
    assert_eq!(s, 403);
}

/// 100 000 requests with distinct long method names (outside auth) must not
/// grow the metrics tables: labels come from a fixed set.
#[test]
fn bogus_methods_do_not_grow_memory() {
    let d = Daemon::start("");
    let addr = d.addr();
    let run = |from: usize, to: usize| {
        let threads: Vec<_> = (0..4)
            .map(|t| {
                let addr = addr.clone();
                std::thread::spawn(move || {
                    let s = std::net::TcpStream::connect(&addr).unwrap();
                    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
                    let mut w = std::io::BufWriter::new(s.try_clone().unwrap());
                    let n = (from + t..to).step_by(4).count();
                    // pipelined: one thread writes, this one reads
                    let writer = std::thread::spawn(move || {
                        let pad = "X".repeat(200);
                        for i in (from + t..to).step_by(4) {
                            write!(w, "M{i:07}{pad} /healthz HTTP/1.1\r\nHost: {addr}\r\n\r\n")
                                .unwrap();
                        }
                        w.flush().unwrap();
                    });
                    let mut r = BufReader::new(s);
                    let mut statuses = std::collections::BTreeMap::new();
                    for _ in 0..n {
                        let (s, _, _) = read_response(&mut r).expect("response");
                        *statuses.entry(s).or_insert(0u32) += 1;
                    }
                    writer.join().unwrap();
                    statuses
                })
            })
            .collect();
        let mut all = std::collections::BTreeMap::new();
        for t in threads {
            for (k, v) in t.join().unwrap() {
                *all.entry(k).or_insert(0u32) += v;
            }
        }
        all
    };
    // warm-up: the allocator and the runtime's threads reach their working size
    run(0, 5_000);
    let before = rss_kb(d.pid());
    let statuses = run(5_000, 105_000);
    let after = rss_kb(d.pid());
    // refused (415 here: not GET and no JSON; 405 on a daemon without the guard)
    let refused: u32 = statuses
        .iter()
        .filter(|(s, _)| (400..500).contains(*s))
        .map(|(_, n)| n)
        .sum();
    assert_eq!(refused, 100_000, "{statuses:?}");
    let (_, _, m) = raw(
        &d.addr(),
        format!(
            "GET /metrics HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            d.addr()
        )
        .as_bytes(),
    );
    let m = String::from_utf8(m).unwrap();
    let lines = m
        .lines()
        .filter(|l| l.starts_with("springbench_http_requests_total"))
        .count();
    println!(
        "bogus methods: RSS {before} kB before, {after} kB after 100 000 requests ({:+} kB); {lines} request-counter series; /metrics {} bytes",
        after as i64 - before as i64,
        m.len()
    );
    assert!(
        m.contains("method=\"other\",route=\"/healthz\",status=\"415\"} 105000"),
        "{m}"
    );
    assert!(lines < 10, "{lines} series");
    assert!(
        after < before + 10 * 1024,
        "memory grew from {before} kB to {after} kB"
    );
}

/// Path-decoding errors, the websocket's plain GET and `.`/`..` serials.
#[tokio::test]
async fn every_error_is_a_problem_document() {
    let d = Daemon::start("");
    let c = client();
    let p = problem(
        c.get(d.url("/api/v1/jobs/%ff%fe")).send().await.unwrap(),
        400,
    )
    .await;
    assert!(p["detail"].as_str().unwrap().contains("UTF-8"), "{p}");
    // RFC 6455 4.2.2 / the spec: a plain GET on the websocket answers 426.
    let r = c.get(d.url("/api/v1/events")).send().await.unwrap();
    assert_eq!(r.headers()["upgrade"], "websocket");
    problem(r, 426).await;
    for s in [".", "..", ".hidden", "-x"] {
        let p = problem(
            c.post(d.url("/api/v1/jobs"))
                .json(&json!({"part": {"serial": s}}))
                .send()
                .await
                .unwrap(),
            422,
        )
        .await;
        assert_eq!(p["errors"][0]["field"], "part.serial", "{s}: {p}");
    }
}

/// A websocket token is percent-decoded (a browser's URLSearchParams encodes `+`, `/`, `=`).
#[tokio::test]
async fn websocket_token_is_percent_decoded() {
    let secret = "a+b/c=d&e 0123456789";
    let d = Daemon::start(&format!(
        "[[auth.tokens]]\nname = \"ui\"\ntoken = \"{secret}\"\nrole = \"viewer\"\n"
    ));
    let enc: String = form_urlencoded::byte_serialize(secret.as_bytes()).collect();
    let (ws, _) =
        tokio_tungstenite::connect_async(d.ws_url(&format!("/api/v1/events?token={enc}")))
            .await
            .expect("websocket with a percent-encoded token");
    drop(ws);
    assert!(
        tokio_tungstenite::connect_async(d.ws_url("/api/v1/events?token=a%2Bb"))
            .await
            .is_err()
    );
}

/// The published example secrets do not start a daemon.
#[test]
fn published_example_tokens_do_not_start_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("s.toml");
    std::fs::write(
        &cfg,
        "bind = \"127.0.0.1:0\"\n[[auth.tokens]]\nname = \"mes\"\ntoken = \"change-me-viewer-0001\"\nrole = \"viewer\"\n",
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_springbench"))
        .args(["serve", "--config"])
        .arg(&cfg)
        .arg("--data-dir")
        .arg(dir.path().join("data"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("published example"), "{err}");
    // The shipped configuration starts as it is (loopback, no tokens).
    let shipped = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/springbench.toml"),
    )
    .unwrap();
    assert!(springbench::config::Config::parse(&shipped).is_ok());
}
