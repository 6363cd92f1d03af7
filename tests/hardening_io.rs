//! Issue 11, the I/O part: imports honour `Idempotency-Key`, inputs that
//! would overflow on storage are refused at the door per field, large
//! imports and downloads stay within a memory bound (daemon VmRSS/VmHWM).

mod common;

use common::{client, problem, Daemon};
use serde_json::{json, Value};

fn reference() -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let dir = common::reference_dir("p1_spider");
    (
        std::fs::read(dir.join("meta.json")).unwrap(),
        std::fs::read(dir.join("pre.wav")).unwrap(),
        std::fs::read(dir.join("main.wav")).unwrap(),
    )
}

fn form(meta: &[u8], pre: &[u8], main: &[u8], serial: &str) -> reqwest::multipart::Form {
    reqwest::multipart::Form::new()
        .part(
            "meta",
            reqwest::multipart::Part::bytes(meta.to_vec()).file_name("meta.json"),
        )
        .part(
            "pre",
            reqwest::multipart::Part::bytes(pre.to_vec()).file_name("pre.wav"),
        )
        .part(
            "main",
            reqwest::multipart::Part::bytes(main.to_vec()).file_name("main.wav"),
        )
        .text("serial", serial.to_string())
}

async fn import(
    c: &reqwest::Client,
    d: &Daemon,
    f: reqwest::multipart::Form,
    key: Option<&str>,
) -> reqwest::Response {
    let mut r = c
        .post(d.url("/api/v1/measurements"))
        .bearer_auth("open")
        .multipart(f);
    if let Some(k) = key {
        r = r.header("Idempotency-Key", k);
    }
    r.send().await.unwrap()
}

async fn count(c: &reqwest::Client, d: &Daemon) -> usize {
    common::get(c, d, "/api/v1/measurements?limit=100").await["items"]
        .as_array()
        .unwrap()
        .len()
}

/// A retried import (new multipart boundary, same fields) stores once; the
/// same key with other fields is a 409 naming the stored measurement;
/// concurrent retries store once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn import_retried_with_the_same_key_stores_once() {
    let d = Daemon::start("");
    let c = client();
    let (meta, pre, main) = reference();
    let r = import(&c, &d, form(&meta, &pre, &main, "SN-IDEM"), Some("imp-1")).await;
    assert_eq!(r.status().as_u16(), 201);
    assert!(r.headers().get("idempotent-replayed").is_none());
    let first: Value = r.json().await.unwrap();
    let id = first["measurement"]["id"].as_str().unwrap().to_string();

    let r = import(&c, &d, form(&meta, &pre, &main, "SN-IDEM"), Some("imp-1")).await;
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(r.headers()["idempotent-replayed"], "true");
    assert_eq!(
        r.headers()["location"].to_str().unwrap(),
        format!("/api/v1/measurements/{id}")
    );
    let again: Value = r.json().await.unwrap();
    assert_eq!(again["measurement"]["id"], id.as_str());
    assert_eq!(again["stiffness"], first["stiffness"]);
    assert_eq!(count(&c, &d).await, 1);

    // Same key, other fields (another serial): 409, nothing stored.
    let p = problem(
        import(&c, &d, form(&meta, &pre, &main, "SN-OTHER"), Some("imp-1")).await,
        409,
    )
    .await;
    assert_eq!(p["type"], "/problems/idempotency-conflict");
    assert_eq!(p["measurement_id"], id.as_str());
    assert_eq!(count(&c, &d).await, 1);

    // Three concurrent uploads with a new key: one measurement.
    let rs = futures_util::future::join_all((0..3).map(|_| {
        let (c, meta, pre, main) = (c.clone(), meta.clone(), pre.clone(), main.clone());
        let d = &d;
        async move {
            let r = import(&c, d, form(&meta, &pre, &main, "SN-IDEM"), Some("imp-2")).await;
            let s = r.status().as_u16();
            let v: Value = r.json().await.unwrap();
            (s, v["measurement"]["id"].as_str().unwrap().to_string())
        }
    }))
    .await;
    let mut st: Vec<u16> = rs.iter().map(|r| r.0).collect();
    st.sort();
    assert_eq!(st, [200, 200, 201], "{rs:?}");
    assert!(rs.iter().all(|r| r.1 == rs[0].1));
    assert_eq!(count(&c, &d).await, 2);

    // Without a key every upload stores (the documented behaviour).
    let r = import(&c, &d, form(&meta, &pre, &main, "SN-IDEM"), None).await;
    assert_eq!(r.status().as_u16(), 201);
    assert_eq!(count(&c, &d).await, 3);
    // A malformed key is a 400 problem (a small body: the answer comes
    // before the body is read, a large one would race with the close).
    let small = reqwest::multipart::Form::new().text("serial", "SN-IDEM");
    let p = problem(import(&c, &d, small, Some("")).await, 400).await;
    assert!(p["detail"].as_str().unwrap().contains("Idempotency-Key"));
}

/// Values that overflowed on storage (issue 11: stored as NaN/inf, the
/// measurement answered 500 for good) are refused at the door with the
/// field that is wrong; nothing is stored.
#[tokio::test]
async fn overflowing_inputs_are_refused_per_field() {
    let d = Daemon::start("");
    let c = client();
    let (meta, pre, main) = reference();
    let meta_v: Value = serde_json::from_slice(&meta).unwrap();
    let with = |f: &dyn Fn(&mut Value)| {
        let mut m = meta_v.clone();
        f(&mut m);
        serde_json::to_vec(&m).unwrap()
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (
            with(&|m| m["channel_scale"] = json!({"displacement": 1e300})),
            "meta.channel_scale.displacement",
        ),
        (
            with(&|m| m["channel_scale"] = json!({"microphone": 1e-300})),
            "meta.channel_scale.microphone",
        ),
        (
            with(&|m| m["moving_mass_kg"] = json!(1e-300)),
            "meta.moving_mass_kg",
        ),
        (
            with(&|m| m["moving_mass_kg"] = json!(1e300)),
            "meta.moving_mass_kg",
        ),
        (
            with(&|m| m["sample_rate_hz"] = json!(-48000)),
            "meta.sample_rate_hz",
        ),
    ];
    for (m, field) in cases {
        let p = problem(
            import(&c, &d, form(&m, &pre, &main, "SN-OVF"), None).await,
            422,
        )
        .await;
        assert_eq!(p["errors"][0]["field"], field, "{p}");
    }
    assert_eq!(count(&c, &d).await, 0);
    for (body, field) in [
        (
            json!({"part": {"serial": "SN-OVF"}, "moving_mass_kg": 1e-300}),
            "moving_mass_kg",
        ),
        (
            json!({"part": {"serial": "SN-OVF"}, "target_xpeak_m": 1e300}),
            "target_xpeak_m",
        ),
    ] {
        let r = c
            .post(d.url("/api/v1/jobs"))
            .json(&body)
            .send()
            .await
            .unwrap();
        let p = problem(r, 422).await;
        assert!(
            p["errors"]
                .as_array()
                .unwrap()
                .iter()
                .any(|e| e["field"] == field),
            "{p}"
        );
    }
    let jobs = common::get(&c, &d, "/api/v1/jobs").await;
    assert_eq!(jobs["items"].as_array().unwrap().len(), 0);
}
