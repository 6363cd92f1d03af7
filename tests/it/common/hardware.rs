//! Shared scaffolding of the emulated-bench tests (tests/hardware_emulated.rs,
//! tests/hardware_serial.rs): the bench configuration with a chosen laser,
//! the K(x) error against the mounted part, self-check and bench-state
//! requests, and the fault scenario (faulted job, drive to zero on the
//! emulated output, bench faulted, daemon healthy, recovery by self-check).
//! Included with `#[path = "common/hardware.rs"] mod hw;` next to `mod common;`.
#![allow(dead_code)]

use super::common::{client, get, submit, terminal, wait_job, Daemon};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

/// The analog laser of the emulated bench.
pub const ANALOG_LASER: &str = r#"
[benches.hardware.laser]
kind = "analog"
scale_m_per_v = 0.005
range_m = 0.025
model = "emulated analog laser"
serial = "EMU-0001"
"#;

/// RMS of K_fit(x) - K_true(x) over the valid range, relative to RMS K_true (%).
pub fn k_rms_error_percent(fit: &[f64], truth: &[f64], range: [f64; 2]) -> f64 {
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

/// K(x) error of a measurement (GET /api/v1/measurements/ID) against the
/// `spider_4in` preset the emulator mounts (%), and the valid range (m).
pub fn k_error_of(m: &Value) -> (f64, [f64; 2]) {
    let fit: Vec<f64> =
        serde_json::from_value(m["stiffness"]["coefficients_n_per_m_pow_i_plus_1"].clone())
            .unwrap_or_else(|e| panic!("no stiffness ({e}): {m}"));
    let range: [f64; 2] = serde_json::from_value(m["stiffness"]["valid_range_m"].clone()).unwrap();
    let truth = springbench::physics::preset("spider_4in")
        .unwrap()
        .k_coeffs_si;
    (k_rms_error_percent(&fit, &truth, range), range)
}

/// An emulated bench `emu-1` with `laser` (a `[benches.hardware.laser]`
/// table) and `emulator` (extra lines of `[benches.emulator]`, then
/// `[[benches.emulator.faults]]` tables).
pub fn config(trace_dir: &Path, laser: &str, emulator: &str) -> String {
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
{laser}
[benches.emulator]
latency_s = 0.005
trace_dir = "{}"
{emulator}
"#,
        trace_dir.display()
    )
}

pub async fn self_check(c: &reqwest::Client, d: &Daemon) -> Value {
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

pub async fn bench_state(c: &reqwest::Client, d: &Daemon) -> Value {
    let b = get(c, d, "/api/v1/benches").await;
    b["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["id"] == "emu-1")
        .unwrap()
        .clone()
}

/// The drive on the emulated output from the event to zero (s), from the
/// trace of job `seq`'s sweep `sweep`; asserts the drive was on at the event.
pub fn drive_to_zero_s(trace_dir: &Path, seq: u32, sweep: u32) -> (f64, Value) {
    let path = trace_dir.join(format!("run-{seq}-{sweep}.json"));
    let tr: Value = serde_json::from_str(
        &std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .unwrap();
    let fs = tr["sample_rate_hz"].as_f64().unwrap();
    let event = tr["event_sample"].as_u64().expect("event recorded") as f64;
    let last = tr["last_nonzero_drive_sample"].as_u64().unwrap() as f64;
    assert!(last > event, "the drive was already off at the event: {tr}");
    ((last - event) / fs, tr)
}

/// Runs one fault scenario on a daemon configured by `cfg` whose fault is
/// planned for job 2, sweep 2: the faulted job fails with a bench-fault
/// problem naming `expect_in_detail`, the drive reached zero within 50 ms of
/// the event on the emulated output, the bench is faulted (and refuses
/// jobs), /healthz answers, and after a passing self-check a job succeeds.
pub async fn fault_scenario(cfg: &str, trace_dir: &Path, expect_in_detail: &str) {
    let d = Daemon::start(cfg);
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
    let (to_zero_s, tr) = drive_to_zero_s(trace_dir, 2, 2);
    println!(
        "{expect_in_detail}: drive zero {:.1} ms after the event; trace {tr}; problem: {detail}",
        to_zero_s * 1e3
    );
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
    // A job on the faulted bench is refused at submission (issue 35): a 409
    // problem that names the fault and the self-check that clears it.
    let r = c
        .post(d.url("/api/v1/jobs"))
        .json(&json!({"part": {"serial": "SP-F"}}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 409);
    let p: Value = r.json().await.unwrap();
    assert!(
        p["type"].as_str().unwrap().ends_with("bench-faulted"),
        "{p}"
    );
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains(expect_in_detail), "{p}");
    assert!(detail.contains("self-check"), "{p}");
    // A passing self-check clears it; the next job succeeds.
    let sc = self_check(&c, &d).await;
    assert_eq!(sc["state"], "succeeded", "{sc}");
    assert_eq!(bench_state(&c, &d).await["state"], "idle");
    let id = submit(&c, &d, json!({"part": {"serial": "SP-F"}})).await;
    let j = wait_job(&c, &d, &id, Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
}

/// `POST /api/v1/long-term-tests` with `body`: the answer, unread.
pub async fn post_long_term(c: &reqwest::Client, d: &Daemon, body: &Value) -> reqwest::Response {
    c.post(d.url("/api/v1/long-term-tests"))
        .json(body)
        .send()
        .await
        .unwrap()
}

/// Submits a long-term test on the emulated bench `emu-1` (after a
/// self-check, so that the test is job 2); returns its id.
pub async fn submit_long_term(c: &reqwest::Client, d: &Daemon, body: Value) -> String {
    let sc = self_check(c, d).await;
    assert_eq!(sc["state"], "succeeded", "{sc}");
    let r = post_long_term(c, d, &body).await;
    let status = r.status().as_u16();
    let v: Value = r.json().await.unwrap();
    assert_eq!(status, 202, "{v}");
    v["id"].as_str().unwrap().to_string()
}

/// Every emulated run of job `seq` (its traces), in order.
pub fn traces_of_job(dir: &Path, seq: u32) -> Vec<Value> {
    (1..10_000)
        .map(|k| dir.join(format!("run-{seq}-{k}.json")))
        .take_while(|p| p.exists())
        .map(|p| serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap())
        .collect()
}

/// The emulated part's truth at each interval's start from the job's log
/// lines "interval I: the emulated part's truth at the measurement's
/// start: load E J, K(0) K N/m (measured load M J)": (I, E, K, M).
pub fn truth_lines(job: &Value) -> Vec<(u64, f64, f64, f64)> {
    let num = |s: &str, after: &str| -> Option<f64> {
        s.split(after).nth(1)?.split(' ').next()?.parse().ok()
    };
    job["log"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|l| {
            let l = l.as_str()?;
            let rest = l.strip_prefix("interval ")?;
            if !l.contains("the emulated part's truth") {
                return None;
            }
            let i = rest.split(':').next()?.parse().ok()?;
            Some((
                i,
                num(l, "start: load ")?,
                num(l, "K(0) ")?,
                num(l, "(measured load ")?,
            ))
        })
        .collect()
}

/// `key` of every item of the array `items` (numbers).
pub fn column(items: &Value, key: &str) -> Vec<f64> {
    items
        .as_array()
        .unwrap()
        .iter()
        .map(|i| i[key].as_f64().unwrap())
        .collect()
}

/// The last signals of a stopped long-term test (its document `t`): the
/// WAV's channels (displacement m, microphone V, drive V, as stored) and
/// its sample rate.
pub async fn last_signals(c: &reqwest::Client, d: &Daemon, t: &Value) -> (Vec<Vec<f64>>, f64) {
    let url = t["last_signals"].as_str().expect("last signals stored");
    let r = c.get(d.url(url)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let wav = r.bytes().await.unwrap();
    let mut h = hound::WavReader::new(std::io::Cursor::new(wav.to_vec())).unwrap();
    let spec = h.spec();
    let ch = spec.channels as usize;
    let mut out = vec![Vec::new(); ch];
    for (k, s) in h.samples::<f32>().enumerate() {
        out[k % ch].push(s.unwrap() as f64);
    }
    (out, spec.sample_rate as f64)
}
