//! Raw data that fits (issue 11, decision 0013): recordings stored as FLAC at
//! the resolution they were captured with, read back sample for sample, and
//! the data directory growth of the default job.

use crate::common;

use common::*;
use serde_json::json;
use springbench::bench::{Bench, Control};
use springbench::recording::codec::{self, Resolution};
use springbench::store::{NewMeasurement, NewRecording, Store};
use std::time::Duration;

/// A virtual bench capture goes through the store and comes back identical:
/// every sample the same `f64` and the same converter code.
#[tokio::test]
async fn a_capture_reads_back_from_the_store_sample_for_sample() {
    let part = springbench::physics::preset(springbench::bench::settings::DEFAULT_PRESET).unwrap();
    let mut bench = springbench::bench::virtual_bench::VirtualBench::new(part, 7);
    let res: Resolution = bench
        .resolution()
        .expect("the virtual bench declares its converter");
    assert_eq!(res.bits, 24);
    let sweep = springbench::procedure::sweep::SweepSpec::new(20.0, 200.0, 1.5, 20.0);
    let drive = sweep.samples(bench.sample_rate_hz());
    let captured = bench.run(&drive, &mut |_| Control::Continue).unwrap();
    // Captured samples are converter codes: not one is off the 24-bit grid.
    let codes = codec::codes(&captured, res.bits, &res.scale).expect("on the converter grid");
    let distinct_mic: std::collections::BTreeSet<i32> =
        codes.iter().skip(1).step_by(3).copied().collect();
    assert!(distinct_mic.len() > 1000, "a real signal, not a constant");

    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).await.unwrap();
    let stored = codec::encode_capture(&captured, Some(&res)).unwrap();
    assert!(stored.bytes.starts_with(b"fLaC"));
    let f32_bytes = captured.len() * 3 * 4;
    println!(
        "{} frames: FLAC {} bytes, float32 WAV {} bytes (ratio {:.2})",
        captured.len(),
        stored.bytes.len(),
        f32_bytes,
        f32_bytes as f64 / stored.bytes.len() as f64
    );
    let rec = |kind| NewRecording {
        kind,
        sample_rate_hz: captured.sample_rate_hz,
        frames: captured.len() as i64,
        stored: stored.clone(),
    };
    store
        .insert_measurements(
            ("SN-RAW", None, None),
            vec![rec("pre"), rec("main")],
            vec![NewMeasurement {
                id: "m-raw".into(),
                part_serial: "SN-RAW".into(),
                job_id: None,
                source: "import",
                bench_id: None,
                config: Default::default(),
                meta: springbench::store::Doc::Received(json!({"moving_mass_kg": 0.05})),
                result: None,
                analysis_error: Some("not analysed".into()),
                target_xpeak_m: None,
                repeat_index: None,
                level_index: None,
                pre: 0,
                main: 1,
            }],
        )
        .await
        .unwrap();
    store.close().await;
    let store = Store::open(dir.path()).await.unwrap();
    let back = store.get_recording("m-raw", "main").await.unwrap().unwrap();
    assert_eq!(back.frames as usize, captured.len());
    let read = codec::decode(&back.bytes, back.channel_scale.as_ref()).unwrap();
    assert_eq!(read, captured, "read back equals what was captured");
    let eq_bits = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    assert!(eq_bits(&read.displacement_m, &captured.displacement_m));
    assert!(eq_bits(&read.microphone_v, &captured.microphone_v));
    assert!(eq_bits(
        read.drive_v.as_ref().unwrap(),
        captured.drive_v.as_ref().unwrap()
    ));
    assert_eq!(codec::codes(&read, res.bits, &res.scale).unwrap(), codes);
}

/// The default job grows the data directory by at most 5 MB (it was about
/// 15 MB with float32 WAV), and the served WAV still reads.
#[tokio::test]
async fn the_default_job_grows_the_data_directory_by_at_most_5_mb() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let mut d = Daemon::start_in(tmp.path(), "");
    d.terminate();
    let before = springbench::store::dir_bytes(&data);

    let mut d = Daemon::start_in(tmp.path(), "");
    let c = client();
    let id = submit(&c, &d, json!({"part": {"serial": "SN-DISK"}})).await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let mid = j["measurement_ids"][0].as_str().unwrap().to_string();
    let mut wav_bytes = 0;
    for file in ["pre.wav", "main.wav"] {
        let r = c
            .get(d.url(&format!("/api/v1/measurements/{mid}/recordings/{file}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200);
        assert_eq!(r.headers()["content-type"], "audio/wav");
        let wav = r.bytes().await.unwrap();
        wav_bytes += wav.len();
        let meta = springbench::recording::Meta::standard(0.05, 48000.0);
        let s =
            springbench::recording::read_signals(std::io::Cursor::new(&wav[..]), &meta).unwrap();
        assert!(s.duration_s() > 1.0, "{file}");
    }
    let m = get_text(&c, &d, "/metrics").await;
    let metric = |name: &str| -> f64 {
        m.lines()
            .find_map(|l| l.strip_prefix(&format!("{name} ")))
            .unwrap_or_else(|| panic!("{name} missing in {m}"))
            .parse()
            .unwrap()
    };
    let rec_bytes = metric("springbench_recordings_bytes");
    assert!(metric("springbench_data_dir_bytes") > rec_bytes);
    assert!(
        m.contains("springbench_recordings{state=\"kept\"} 2"),
        "{m}"
    );
    d.terminate();
    let after = springbench::store::dir_bytes(&data);
    let growth = after.saturating_sub(before);
    println!(
        "default job: data directory {before} -> {after} bytes (+{growth}); raw signals {rec_bytes} bytes \
         stored, {wav_bytes} bytes as float32 WAV (ratio {:.2})",
        wav_bytes as f64 / rec_bytes
    );
    assert!(
        growth <= 5_000_000,
        "the default job grew the data directory by {growth} bytes"
    );
    // Not vacuous: the raw signals are stored.
    assert!(rec_bytes > 1e6, "{rec_bytes}");
}
