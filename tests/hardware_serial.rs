//! Issue 10 acceptance for the serial laser, through the real daemon binary
//! on an emulated bench: the emulated audio closes the loop drive -> physics
//! -> microphone/loopback; a laser emulator on a pseudo-terminal samples the
//! same physics on its own clock (4 kHz, +150 ppm, 3 ms offset, 2 us RMS
//! jitter, 16 ms USB chunks) and speaks the configured protocol; the real
//! `SerialLaser` reads the pty by path; the samples are put on the audio
//! clock by the job's alignment and the measurement stores the sensor, the
//! clock ratio, the offset and the residual. Faults are made for real (the
//! pty closed, garbage bytes on the line) in the middle of a sweep.
//!
//! `cargo test --features hardware --test hardware_serial -- --nocapture`
//! prints the figures quoted in docs/hardware.md.
#![cfg(feature = "hardware")]

#[path = "it/common/mod.rs"]
mod common;
#[path = "it/common/hardware.rs"]
mod hw;

use common::{client, get, submit, terminal, wait_job, Daemon};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

const TRUE_PPM: f64 = 150.0;
const TRUE_OFFSET_S: f64 = 0.003;

/// `[benches.hardware.laser]` of a serial laser speaking `protocol` (TOML inline table).
fn serial_laser(protocol: &str, rate_hz: f64) -> String {
    format!(
        r#"
[benches.hardware.laser]
kind = "serial"
port = "emulator"
baud = 921600
rate_hz = {rate_hz:.1}
model = "configured model"
serial = "CFG-1"
# A loaded CI machine may not schedule the emulator for a while.
stall_timeout_s = 0.5
protocol = {protocol}
"#
    )
}

const OPTONCDT: &str = r#"{ name = "optoncdt", range_m = 0.04, counter = true }"#;
const ASCII: &str = r#"{ name = "ascii_lines", unit_m = 0.001 }"#;
const KEYENCE: &str = r#"{ name = "keyence", head = 1, unit_m = 0.001, range_m = 0.04 }"#;

fn config(trace_dir: &Path, laser: &str, faults: &str) -> String {
    hw::config(trace_dir, laser, faults)
}

/// Runs one spider job; returns (daemon, job, first measurement).
async fn job(laser: &str) -> (Daemon, Value, Value) {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), laser, ""));
    let c = client();
    let id = submit(
        &c,
        &d,
        json!({"part": {"serial": "SP-S", "kind": "spider"}}),
    )
    .await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(900), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let mid = j["measurement_ids"][0].as_str().unwrap();
    let m = get(&c, &d, &format!("/api/v1/measurements/{mid}")).await;
    (d, j, m)
}

/// A streamed protocol with a device clock: K(x) within 0.5 % RMS, the
/// residual below 10 us, the clock ratio within 10 ppm of the truth.
async fn streamed(name: &str, protocol: &str) {
    let (d, _j, m) = job(&serial_laser(protocol, 4000.0)).await;
    let hwr = &m["measurement"]["config"]["hardware"];
    let al = &hwr["alignment"];
    let (err, range) = hw::k_error_of(&m);
    println!(
        "{name}: K(x) RMS error {err:.3} % over [{:.2}, {:.2}] mm; clock {} ppm; offset {} s; residual {} s RMS (max {}); pre-measurement {}; sensor {}",
        range[0] * 1e3,
        range[1] * 1e3,
        al["clock_ppm"],
        al["offset_s"],
        al["residual_s"],
        al["residual_max_s"],
        hwr["pre_alignment"],
        al["sensor"]
    );
    assert_eq!(al["valid"], true, "{al}");
    assert!(err < 0.5, "{name}: K(x) RMS error {err} %");
    let ppm = al["clock_ppm"].as_f64().unwrap();
    assert!((ppm - TRUE_PPM).abs() < 10.0, "{name}: {ppm} ppm");
    let res = al["residual_s"].as_f64().unwrap();
    assert!(res < 10e-6, "{name}: residual {res} s");
    assert_eq!(al["sensor"]["protocol"], name);
    let lat = hwr["latency_s"].as_f64().unwrap();
    assert!((lat - 0.005).abs() < 0.5 / 48000.0, "latency {lat}");
    let offset = al["offset_s"].as_f64().expect("offset stored");
    if name == "optoncdt" {
        // The device counter numbers the samples from the emulator's sample 0.
        assert!((offset - TRUE_OFFSET_S).abs() < 10e-6, "offset {offset} s");
        assert_eq!(al["sensor"]["model"], "ILD1420-40 (emulated)");
        assert_eq!(al["sensor"]["read_from_sensor"], true);
    }
    // The calibration record the measurement references holds the laser as
    // the self-check identified it: from the sensor where it can answer.
    let cal_id = hwr["calibration_id"]
        .as_str()
        .expect("a calibration record");
    let cal = get(&client(), &d, &format!("/api/v1/calibrations/{cal_id}")).await;
    let li = &cal["result"]["laser"];
    assert_eq!(li, &al["sensor"], "{cal}");
    let from_sensor = name == "optoncdt";
    assert_eq!(li["read_from_sensor"], from_sensor, "{cal}");
    if !from_sensor {
        assert_eq!(li["model"], "configured model", "{cal}");
    }
}

#[tokio::test]
async fn optoncdt_with_counter_recovers_k_and_the_clock() {
    streamed("optoncdt", OPTONCDT).await;
}

#[tokio::test]
async fn streamed_ascii_recovers_k_and_the_clock() {
    streamed("ascii_lines", ASCII).await;
}

/// The polled protocol has no device clock: the measurement is stored but
/// marked invalid with the reason and not fitted (never a silently
/// misaligned fit).
#[tokio::test]
async fn polled_keyence_measurement_is_marked_invalid_and_not_fitted() {
    let (_d, j, m) = job(&serial_laser(KEYENCE, 1000.0)).await;
    let hwr = &m["measurement"]["config"]["hardware"];
    let al = &hwr["alignment"];
    println!("keyence: alignment {al}; measurement {}", m["measurement"]);
    assert_eq!(al["valid"], false, "{al}");
    assert!(
        al["invalid_reason"]
            .as_str()
            .unwrap()
            .contains("no device clock"),
        "{al}"
    );
    assert!(m["stiffness"].is_null(), "fitted anyway: {m}");
    let why = m["measurement"]["analysis_error"].as_str().unwrap();
    assert!(
        why.contains("alignment") && why.contains("no device clock"),
        "{why}"
    );
    assert!(j["log"].to_string().contains("not fitted"), "{j}");
}

#[tokio::test]
async fn laser_unplugged_mid_sweep_faults_the_bench_and_ramps_the_drive_down() {
    let traces = tempfile::tempdir().unwrap();
    let cfg = config(
        traces.path(),
        &serial_laser(OPTONCDT, 4000.0),
        "[[benches.emulator.faults]]\nkind = \"laser_unplugged\"\njob_seq = 2\nsweep = 2\nat_s = 3.0\n",
    );
    hw::fault_scenario(&cfg, traces.path(), "serial port closed").await;
}

#[tokio::test]
async fn garbage_from_the_laser_mid_sweep_faults_the_bench_and_ramps_the_drive_down() {
    let traces = tempfile::tempdir().unwrap();
    let cfg = config(
        traces.path(),
        &serial_laser(OPTONCDT, 4000.0),
        "[[benches.emulator.faults]]\nkind = \"laser_garbage\"\njob_seq = 2\nsweep = 2\nat_s = 3.0\n",
    );
    hw::fault_scenario(&cfg, traces.path(), "garbage from the laser").await;
}
