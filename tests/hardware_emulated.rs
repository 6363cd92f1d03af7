//! Issue 10 acceptance on the emulated bench, through the real daemon binary:
//! the hardware code path (drive production with the limit, capture, block
//! checks, loopback latency, alignment, calibration records, faults) against
//! the physics behind the emulated audio device.
#![cfg(feature = "hardware")]

mod common;

use common::{client, get, submit, terminal, wait_job, Daemon};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

/// RMS of K_fit(x) - K_true(x) over the valid range, relative to RMS K_true (%).
fn k_rms_error_percent(fit: &[f64], truth: &[f64], range: [f64; 2]) -> f64 {
    let k = |c: &[f64], x: f64| c.iter().rev().fold(0.0, |acc, ci| acc * x + ci);
    let n = 401;
    let (mut e2, mut t2) = (0.0, 0.0);
    for i in 0..n {
        let x = range[0] + (range[1] - range[0]) * i as f64 / (n - 1) as f64;
        e2 += (k(fit, x) - k(truth, x)).powi(2);
        t2 += k(truth, x).powi(2);
    }
    100.0 * (e2 / t2).sqrt()
}

/// An emulated bench with an analog laser; `faults` is TOML for `[[benches.emulator.faults]]`.
fn config(trace_dir: &Path, faults: &str) -> String {
    format!(
        r#"
[[benches]]
id = "emu-1"
kind = "emulated"
preset = "spider_4in"
seed = 7
limits = {{ max_displacement_m = 0.015, max_drive_v = 100.0 }}

[benches.hardware]
output_device = "emulated-out"
input_device = "emulated-in"
sample_rate_hz = 48000
buffer_frames = 480
output_channels = 2
input_channels = 4
channels = {{ drive = 0, microphone = 0, loopback = 1, laser = 2 }}

[benches.hardware.calibration]
dac_full_scale_v = 1.0
amplifier_gain = 100.0
adc_full_scale_v = 10.0
loopback_divider = 0.05
mic_sensitivity_v_per_pa = 0.0005
mic_calibrated_on = "2026-10-01"

[benches.hardware.laser]
kind = "analog"
scale_m_per_v = 0.005
range_m = 0.025
model = "emulated analog laser"
serial = "EMU-0001"

[benches.emulator]
latency_s = 0.005
trace_dir = "{}"
{faults}
"#,
        trace_dir.display()
    )
}

async fn self_check(c: &reqwest::Client, d: &Daemon) -> Value {
    let r = c
        .post(d.url("/api/v1/benches/emu-1/self-check"))
        .json(&json!({}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let id = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    wait_job(c, d, &id, Duration::from_secs(120), terminal).await
}

async fn bench_state(c: &reqwest::Client, d: &Daemon) -> Value {
    let b = get(c, d, "/api/v1/benches").await;
    b["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["id"] == "emu-1")
        .unwrap()
        .clone()
}

/// A spider job through the emulated bench with the analog laser: K(x)
/// within 0.5 % RMS, the 5 ms latency measured from the loopback, the
/// calibration record referenced by the measurement.
#[tokio::test]
async fn analog_laser_job_recovers_k_and_reports_latency_and_calibration() {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), ""));
    let c = client();
    let id = submit(
        &c,
        &d,
        json!({"part": {"serial": "SP-1", "kind": "spider"}}),
    )
    .await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let mid = j["measurement_ids"][0].as_str().unwrap();
    let m = get(&c, &d, &format!("/api/v1/measurements/{mid}")).await;
    let fit: Vec<f64> =
        serde_json::from_value(m["stiffness"]["coefficients_n_per_m_pow_i_plus_1"].clone())
            .unwrap();
    let range: [f64; 2] = serde_json::from_value(m["stiffness"]["valid_range_m"].clone()).unwrap();
    let truth = springbench::physics::preset("spider_4in")
        .unwrap()
        .k_coeffs_si;
    let err = k_rms_error_percent(&fit, &truth, range);
    let hw = &m["measurement"]["config"]["hardware"];
    println!(
        "analog laser: K(x) RMS error {err:.3} % over [{:.2}, {:.2}] mm; latency {} s; hardware {hw}",
        range[0] * 1e3,
        range[1] * 1e3,
        hw["latency_s"]
    );
    assert!(err < 0.5, "K(x) RMS error {err} %");
    let lat = hw["latency_s"].as_f64().expect("latency stored");
    assert!((lat - 0.005).abs() < 0.5 / 48000.0, "latency {lat}");
    assert!(
        hw["main_sweep"]["loopback_correlation"].as_f64().unwrap() > 0.999,
        "{hw}"
    );
    assert_eq!(hw["alignment"]["residual_s"], 0.0);
    // The calibration record exists, passed, and is the one referenced.
    let cal_id = hw["calibration_id"].as_str().unwrap();
    let cal = get(&c, &d, &format!("/api/v1/calibrations/{cal_id}")).await;
    assert_eq!(cal["passed"], true, "{cal}");
    let cl = cal["result"]["latency_s"].as_f64().unwrap();
    assert!((cl - 0.005).abs() < 0.5 / 48000.0, "{cal}");
    assert_eq!(cal["sensors"]["laser"]["serial"], "EMU-0001");
    assert_eq!(cal["sensors"]["microphone"]["calibrated_on"], "2026-10-01");
    // Noise floors as emulated: laser 1 um RMS, microphone 0.3 Pa RMS.
    let ln = cal["result"]["noise"]["laser_m"].as_f64().unwrap();
    assert!((ln - 1e-6).abs() < 0.2e-6, "laser noise {ln}");
    let mp = cal["result"]["mic_at_silence_pa"].as_f64().unwrap();
    assert!((mp - 0.3).abs() < 0.05, "mic at silence {mp}");
}

/// Runs one fault scenario: the faulted job fails with a bench-fault problem,
/// the drive reached zero within 50 ms of the event on the emulated output,
/// the bench is faulted (and refuses jobs), /healthz answers, and after a
/// passing self-check a job succeeds.
async fn fault_scenario(faults: &str, expect_in_detail: &str) {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), faults));
    let c = client();
    // Job 1: a self-check, so that job 2 is the first measurement.
    let sc = self_check(&c, &d).await;
    assert_eq!(sc["state"], "succeeded", "{sc}");
    let id = submit(&c, &d, json!({"part": {"serial": "SP-F"}})).await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "failed", "{j}");
    assert_eq!(j["problem"]["type"], "/problems/bench-fault", "{j}");
    let detail = j["problem"]["detail"].as_str().unwrap();
    assert!(detail.contains(expect_in_detail), "{detail}");
    // Measured on the emulated output: the drive was on at the event and zero within 50 ms.
    let tr: Value =
        serde_json::from_str(&std::fs::read_to_string(traces.path().join("run-2-2.json")).unwrap())
            .unwrap();
    let fs = tr["sample_rate_hz"].as_f64().unwrap();
    let event = tr["event_sample"].as_u64().expect("event recorded") as f64;
    let last = tr["last_nonzero_drive_sample"].as_u64().unwrap() as f64;
    let to_zero_s = (last - event) / fs;
    println!(
        "{expect_in_detail}: drive zero {:.1} ms after the event; trace {tr}",
        to_zero_s * 1e3
    );
    assert!(last > event, "the drive was already off at the event: {tr}");
    assert!(
        to_zero_s <= 0.05,
        "drive reached zero {to_zero_s} s after the event"
    );
    // The bench is faulted and says why; the daemon is healthy.
    let b = bench_state(&c, &d).await;
    assert_eq!(b["state"], "faulted", "{b}");
    assert!(
        b["fault"]["detail"]
            .as_str()
            .unwrap()
            .contains(expect_in_detail),
        "{b}"
    );
    let h = get(&c, &d, "/healthz").await;
    assert_eq!(h["status"], "ok");
    let r = get(&c, &d, "/readyz").await;
    assert!(r["benches"].to_string().contains("faulted"), "{r}");
    // A job on the faulted bench fails at once, naming the fault.
    let id = submit(&c, &d, json!({"part": {"serial": "SP-F"}})).await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(60), terminal).await;
    assert_eq!(j["state"], "failed", "{j}");
    assert!(
        j["problem"]["detail"]
            .as_str()
            .unwrap()
            .contains("self-check"),
        "{j}"
    );
    // A passing self-check clears it; the next job succeeds.
    let sc = self_check(&c, &d).await;
    assert_eq!(sc["state"], "succeeded", "{sc}");
    assert_eq!(bench_state(&c, &d).await["state"], "idle");
    let id = submit(&c, &d, json!({"part": {"serial": "SP-F"}})).await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
}

#[tokio::test]
async fn audio_stream_error_faults_the_bench_and_ramps_the_drive_down() {
    fault_scenario(
        "[[benches.emulator.faults]]\nkind = \"audio_stream_error\"\njob_seq = 2\nsweep = 2\nat_s = 3.0\n",
        "audio stream error",
    )
    .await;
}

#[tokio::test]
async fn displacement_limit_faults_the_bench_and_ramps_the_drive_down() {
    fault_scenario(
        "[[benches.emulator.faults]]\nkind = \"part_slips\"\njob_seq = 2\nsweep = 2\nat_s = 3.0\n",
        "displacement limit exceeded",
    )
    .await;
}
