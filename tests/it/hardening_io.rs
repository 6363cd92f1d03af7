//! Issue 11, the I/O part: imports honour `Idempotency-Key`, inputs that
//! would overflow on storage are refused at the door per field, large
//! imports and downloads stay within a memory bound (daemon VmRSS/VmHWM).

use crate::common;

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

/// A PCM 24-bit, 3-channel WAV of `frames` frames at 48 kHz written
/// directly (a sweep plus a few hundred LSB of noise per channel, like the
/// bench's converter sees it).
fn write_pcm24(path: &std::path::Path, frames: usize) {
    use std::io::Write;
    let data = frames * 9;
    let mut h = Vec::with_capacity(44);
    h.extend_from_slice(b"RIFF");
    h.extend_from_slice(&(36 + data as u32).to_le_bytes());
    h.extend_from_slice(b"WAVEfmt ");
    h.extend_from_slice(&16u32.to_le_bytes());
    h.extend_from_slice(&1u16.to_le_bytes());
    h.extend_from_slice(&3u16.to_le_bytes());
    h.extend_from_slice(&48000u32.to_le_bytes());
    h.extend_from_slice(&(48000u32 * 9).to_le_bytes());
    h.extend_from_slice(&9u16.to_le_bytes());
    h.extend_from_slice(&24u16.to_le_bytes());
    h.extend_from_slice(b"data");
    h.extend_from_slice(&(data as u32).to_le_bytes());
    let mut w = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(path).unwrap());
    w.write_all(&h).unwrap();
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut phase = 0.0f64;
    let mut buf = Vec::with_capacity(9 * 4096);
    for k in 0..frames {
        // 20 Hz -> 200 Hz over the file
        let f = 20.0 + 180.0 * k as f64 / frames as f64;
        phase += 2.0 * std::f64::consts::PI * f / 48000.0;
        let s = phase.sin();
        for amp in [3.0e6, 1.0e6, 2.0e6] {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let noise = (seed % 1024) as f64 - 512.0;
            let c = (amp * s + noise) as i32;
            buf.extend_from_slice(&c.to_le_bytes()[..3]);
        }
        if buf.len() >= 9 * 4096 {
            w.write_all(&buf).unwrap();
            buf.clear();
        }
    }
    w.write_all(&buf).unwrap();
    w.flush().unwrap();
}

/// Peak VmRSS of `pid` while `f` runs: VmHWM after resetting it through
/// /proc/PID/clear_refs (root), and a 10 ms sampler besides.
async fn peak_during<F: std::future::Future>(pid: u32, f: F) -> (u64, u64, F::Output) {
    let _ = std::fs::write(format!("/proc/{pid}/clear_refs"), "5");
    let start = common::status_kb(pid, "VmRSS:");
    let sampler = common::RssSampler::start(pid, std::time::Duration::from_millis(10));
    let out = f.await;
    (start, sampler.peak_kb(), out)
}

/// Issue 11: a 200 MB import peaked at 1.17 GB. Now the recordings are
/// spooled to the data directory, stored block by block (FLAC encoded frame
/// by frame, written into SQLite in 1 MiB chunks) and not analysed above
/// `max_analysis_frames`: the daemon's resident memory grows by less than
/// 100 MB. Its download is streamed from the store: it grows VmRSS by less
/// than 32 MB (measured +14 MB: read buffers, one batch, and the pooled
/// connections' SQLite page caches, at most 8 x 2 MB for the whole daemon)
/// and every sample equals the imported one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_200_mb_import_stays_under_100_mb_of_extra_memory() {
    let d = Daemon::start("");
    // A hang guard, not a time limit: 200 MB through an unoptimised daemon
    // took over the common client's 60 s on the shared 2-core machine
    // while the one test binary ran heavier tests beside it.
    let c = reqwest::Client::builder()
        .timeout(std::time::Duration::from_secs(600))
        .build()
        .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let frames = 200_000_000 / 9;
    let (pre_p, main_p) = (tmp.path().join("pre.wav"), tmp.path().join("main.wav"));
    write_pcm24(&pre_p, 48_000);
    write_pcm24(&main_p, frames);
    let meta = json!({"moving_mass_kg": 0.005, "sample_rate_hz": 48000,
        "channels": {"displacement": 0, "microphone": 1, "drive": 2},
        "channel_scale": {"displacement": 0.02, "microphone": 10.0, "drive": 100.0}});
    let pre = std::fs::read(&pre_p).unwrap();
    let main = std::fs::read(&main_p).unwrap();
    let body_bytes = pre.len() + main.len();
    assert!(body_bytes > 200_000_000);
    let f = form(&serde_json::to_vec(&meta).unwrap(), &pre, &main, "SN-BIG");
    let pid = d.pid();
    let (start, peak, r) = peak_during(pid, import(&c, &d, f, Some("big-1"))).await;
    let status = r.status().as_u16();
    let doc: Value = r.json().await.unwrap();
    assert_eq!(status, 201, "{doc}");
    let id = doc["measurement"]["id"].as_str().unwrap().to_string();
    assert!(
        doc["measurement"]["analysis_error"]
            .as_str()
            .unwrap()
            .contains("max_analysis_frames"),
        "{doc}"
    );
    let db = std::fs::metadata(d.dir.join("data/springbench.db"))
        .map(|m| m.len())
        .unwrap_or(0)
        + std::fs::metadata(d.dir.join("data/springbench.db-wal"))
            .map(|m| m.len())
            .unwrap_or(0);
    println!(
        "import of {body_bytes} bytes ({frames} frames): VmRSS {start} kB -> peak {peak} kB (+{} MB); database + WAL {db} bytes",
        (peak - start) / 1024
    );
    // The spool is gone.
    let left: Vec<_> = std::fs::read_dir(d.dir.join("data/tmp"))
        .unwrap()
        .flatten()
        .collect();
    assert!(left.is_empty(), "{left:?}");

    // The download, streamed from the store in chunks (issue 11: the stored
    // blob was read whole, +173 MB): the float32 WAV of every frame, each
    // sample the imported code / 2^23 * full scale, compared as it arrives.
    let expect = |frame: usize, c: usize| {
        let fs = [0.02f64, 10.0, 100.0][c];
        let o = 44 + 9 * frame + 3 * c;
        let code = i32::from_le_bytes([0, main[o], main[o + 1], main[o + 2]]) >> 8;
        (code as f64 / (1u64 << 23) as f64 * fs) as f32
    };
    let (start2, peak2, got) = peak_during(pid, async {
        let mut r = c
            .get(d.url(&format!("/api/v1/measurements/{id}/recordings/main.wav")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200);
        assert_eq!(
            r.content_length(),
            Some(44 + frames as u64 * 12),
            "Content-Length"
        );
        let (mut n, mut frame, mut wrong) = (0usize, 0usize, 0usize);
        let mut first_wrong = None;
        let mut header: Option<Vec<u8>> = None;
        let mut pending = Vec::new();
        while let Some(chunk) = r.chunk().await.unwrap() {
            n += chunk.len();
            pending.extend_from_slice(&chunk);
            if header.is_none() {
                if pending.len() < 44 {
                    continue;
                }
                header = Some(pending.drain(..44).collect());
            }
            let whole = pending.len() / 12 * 12;
            for f in pending[..whole].chunks_exact(12) {
                for c in 0..3 {
                    let v = f32::from_le_bytes(f[4 * c..4 * c + 4].try_into().unwrap());
                    if frame >= frames || v != expect(frame, c) {
                        wrong += 1;
                        first_wrong.get_or_insert((frame, c, v));
                    }
                }
                frame += 1;
            }
            pending.drain(..whole);
        }
        (n, frame, wrong, first_wrong, header.unwrap_or_default())
    })
    .await;
    let (n, got_frames, wrong, first_wrong, header) = got;
    println!(
        "download of {n} bytes: VmRSS {start2} kB -> peak {peak2} kB (+{} MB)",
        (peak2 - start2) / 1024
    );
    assert_eq!(n, 44 + frames * 12);
    assert_eq!(&header[..4], b"RIFF");
    assert_eq!(
        u16::from_le_bytes([header[20], header[21]]),
        3,
        "IEEE float"
    );
    assert_eq!(u16::from_le_bytes([header[22], header[23]]), 3, "channels");
    assert_eq!(got_frames, frames);
    assert_eq!(
        wrong, 0,
        "first differing sample (frame, channel, value): {first_wrong:?}"
    );
    assert!(
        peak2 - start2 < 32 * 1024,
        "downloading the 200 MB import grew VmRSS by {} MB",
        (peak2 - start2) / 1024
    );
    assert!(
        peak - start < 100 * 1024,
        "a 200 MB import grew VmRSS by {} MB",
        (peak - start) / 1024
    );
}
