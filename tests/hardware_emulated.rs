//! Issue 10 acceptance on the emulated bench, through the real daemon binary:
//! the hardware code path (drive production with the limit, capture, block
//! checks, loopback latency, alignment, calibration records, faults) against
//! the physics behind the emulated audio device.
#![cfg(feature = "hardware")]

#[path = "it/common/mod.rs"]
mod common;
#[path = "it/common/hardware.rs"]
mod hw;

use common::{client, get, paused, post_status, submit, terminal, wait_job, Daemon};
use hw::k_rms_error_percent;
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

/// An emulated bench with the analog laser; `faults` is TOML for `[[benches.emulator.faults]]`.
fn config(trace_dir: &Path, faults: &str) -> String {
    hw::config(trace_dir, hw::ANALOG_LASER, faults)
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
    // An analog sensor cannot be asked: its identity is the configuration's.
    let li = &cal["result"]["laser"];
    assert_eq!(li["protocol"], "analog", "{cal}");
    assert_eq!(li["model"], "emulated analog laser", "{cal}");
    assert_eq!(li["serial"], "EMU-0001", "{cal}");
    assert_eq!(li["read_from_sensor"], false, "{cal}");
    assert_eq!(cal["sensors"]["microphone"]["calibrated_on"], "2026-10-01");
    // Noise floors as emulated: laser 1 um RMS, microphone 0.3 Pa RMS.
    let ln = cal["result"]["noise"]["laser_m"].as_f64().unwrap();
    assert!((ln - 1e-6).abs() < 0.2e-6, "laser noise {ln}");
    let mp = cal["result"]["mic_at_silence_pa"].as_f64().unwrap();
    assert!((mp - 0.3).abs() < 0.05, "mic at silence {mp}");
}

async fn fault_scenario(faults: &str, expect_in_detail: &str) {
    let traces = tempfile::tempdir().unwrap();
    hw::fault_scenario(
        &config(traces.path(), faults),
        traces.path(),
        expect_in_detail,
    )
    .await;
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

/// A cancel during a sweep on a bench paced in real time: the drive on the
/// emulated output reaches zero within 50 ms of the moment the cancel request
/// was sent (put on the output by the trace's wall-clock log of the blocks),
/// the job is cancelled, the bench is not faulted.
#[tokio::test]
async fn cancel_during_a_sweep_ramps_the_drive_down_within_50_ms() {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), "paced = true\n"));
    let c = client();
    let sc = hw::self_check(&c, &d).await;
    assert_eq!(sc["state"], "succeeded", "{sc}");
    let id = submit(&c, &d, json!({"part": {"serial": "SP-C"}})).await;
    wait_job(&c, &d, &id, Duration::from_secs(60), |s| s != "queued").await;
    // 3 s into the 16 s pre-measurement sweep (paced: wall time is audio time).
    tokio::time::sleep(Duration::from_secs(3)).await;
    let t_cancel = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let r = c
        .post(d.url(&format!("/api/v1/jobs/{id}/cancel")))
        .header("content-type", "application/json")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let j = wait_job(&c, &d, &id, Duration::from_secs(60), terminal).await;
    assert_eq!(j["state"], "cancelled", "{j}");
    // The sweep that was playing: the last trace of job 2.
    let last_sweep = (1..100)
        .take_while(|k| traces.path().join(format!("run-2-{k}.json")).exists())
        .last()
        .expect("a trace of job 2");
    let tr: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(traces.path().join(format!("run-2-{last_sweep}.json"))).unwrap(),
    )
    .unwrap();
    assert_eq!(tr["paced"], true);
    let fs = tr["sample_rate_hz"].as_f64().unwrap();
    // DAC samples played when the request was sent (the log's last block before it).
    let clock: Vec<(f64, u64)> = serde_json::from_value(tr["clock"].clone()).unwrap();
    let event = clock
        .iter()
        .take_while(|(t, _)| *t <= t_cancel)
        .last()
        .map_or(0, |p| p.1) as f64;
    let last = tr["last_nonzero_drive_sample"].as_u64().unwrap() as f64;
    let to_zero_s = (last - event) / fs;
    println!(
        "cancel: drive zero {:.1} ms after the request was sent (sweep {last_sweep}, event at {:.3} s of the sweep, peak {} V)",
        to_zero_s * 1e3,
        event / fs,
        tr["peak_drive_v"]
    );
    assert!(
        last > event,
        "the drive was already off at the cancel: {tr}"
    );
    assert!(
        to_zero_s <= 0.05,
        "drive zero {to_zero_s} s after the cancel"
    );
    assert_eq!(hw::bench_state(&c, &d).await["state"], "idle");
    assert_eq!(get(&c, &d, "/healthz").await["status"], "ok");
}

/// Issue 21 on the emulated hardware bench: the production procedure against
/// the full one through the hardware code path (drive, capture, block
/// checks, alignment). 5 golden units (spider_4in production parts, seeds
/// 100-104, full procedure) give the recipe's limits (+-10 % of their mean)
/// and golden reference; then 3 lot parts (seeds 800-802) are measured with
/// each procedure on the same emulated bench. Asserted as on the virtual
/// bench (tests/it/production.rs): the same verdict, no fall-back, k0, Keff at
/// target and K(4 mm) (`k_at_half`) within 1 % of the full procedure's. 11 jobs, 14 s of
/// wall time (the emulator is not paced), `#[ignore]` to keep CI's time
/// (issue 19):
/// `cargo test --features hardware --test hardware_emulated -- --ignored --nocapture production`
/// (figures in docs/qc.md).
#[tokio::test]
#[ignore = "11 jobs, 14 s; docs/qc.md gives the command and figures"]
async fn production_procedure_agrees_with_the_full_one_on_the_emulated_bench() {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), ""));
    let c = client();
    let recipe = json!({
        "name": "spider-4in",
        "part_kind": "spider",
        "procedure": {"mode": "production", "levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": common::production_equivalence_parameters(0.004)
    });
    let post = |path: &'static str, body: Value| {
        let (c, d) = (&c, &d);
        async move {
            let r = c.post(d.url(path)).json(&body).send().await.unwrap();
            (
                r.status().as_u16(),
                r.json::<Value>().await.unwrap_or(Value::Null),
            )
        }
    };
    let (s, v) = post("/api/v1/recipes", recipe).await;
    assert_eq!(s, 201, "{v}");
    let job = |serial: String, seed: u64, procedure: &str| {
        json!({"part": {"serial": serial}, "recipe": "spider-4in", "procedure": procedure,
               "production": {"preset": "spider_4in", "seed": seed}})
    };
    let run = |body: Value| {
        let (c, d) = (&c, &d);
        async move {
            let id = submit(c, d, body).await;
            let j = wait_job(c, d, &id, Duration::from_secs(900), terminal).await;
            assert_eq!(j["state"], "succeeded", "{j}");
            let v = get(c, d, &format!("/api/v1/jobs/{id}/verdict")).await;
            (j, v)
        }
    };
    let serials: Vec<String> = (0..5).map(|i| format!("GU-{i}")).collect();
    for (i, s) in serials.iter().enumerate() {
        run(job(s.clone(), 100 + i as u64, "full")).await;
    }
    let (s, p) = post(
        "/api/v1/recipes/spider-4in/limit-proposals",
        json!({"serials": serials, "method": "tolerance", "tolerance_percent": 10.0}),
    )
    .await;
    assert_eq!(s, 201, "{p}");
    let path = format!(
        "/api/v1/limit-proposals/{}/approve",
        p["id"].as_str().unwrap()
    );
    let r = c.post(d.url(&path)).json(&json!({})).send().await.unwrap();
    let (s, v) = (
        r.status().as_u16(),
        r.json::<Value>().await.unwrap_or(Value::Null),
    );
    assert_eq!(s, 201, "{v}");
    let values = |v: &Value| -> Vec<(String, f64)> {
        v["measurements"][0]["detail"]["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                (
                    p["name"].as_str().unwrap().to_string(),
                    p["value"].as_f64().unwrap_or(f64::NAN),
                )
            })
            .collect()
    };
    for seed in 800..803u64 {
        let serial = format!("LOT-{seed}");
        let (jf, vf) = run(job(serial.clone(), seed, "full")).await;
        let (jp, vp) = run(job(serial.clone(), seed, "production")).await;
        let tp = &vp["measurements"][0]["traceability"]["procedure"];
        assert!(tp["fallback"].is_null(), "{serial} fell back: {tp}");
        let (full, prod) = (values(&vf), values(&vp));
        let dev: Vec<String> = full
            .iter()
            .zip(&prod)
            .map(|((n, f), (_, p))| {
                if n == "model_error" {
                    format!("{n} {:+.3} pt", p - f)
                } else {
                    format!("{n} {:+.3} %", 100.0 * (p / f - 1.0))
                }
            })
            .collect();
        println!(
            "{serial}: bench time full {:.2} s, production {:.2} s; verdict full {} production {}; production - full: {}",
            jf["bench_time_s"].as_f64().unwrap(),
            jp["bench_time_s"].as_f64().unwrap(),
            vf["measurements"][0]["verdict"],
            vp["measurements"][0]["verdict"],
            dev.join(", ")
        );
        assert_eq!(
            vf["measurements"][0]["verdict"], vp["measurements"][0]["verdict"],
            "{serial}: {vf} {vp}"
        );
        for ((n, f), (_, p)) in full.iter().zip(&prod) {
            if ["k0", "keff", "k_at_half"].contains(&n.as_str()) {
                assert!(
                    (p / f - 1.0).abs() <= 0.01,
                    "{serial} {n}: full {f} production {p}"
                );
            }
        }
    }
}

/// spider_4in (K(0) 2400 N/m) with strong, fast ageing: break-in 720 N/m
/// over 400 J, fatigue 480 N/m over 5 kJ (the preset's: 240 N/m over 3.2 kJ,
/// 1440 N/m over 320 kJ).
fn fast_ageing_part() -> springbench::physics::PartSpec {
    let mut p = springbench::physics::preset("spider_4in").unwrap();
    p.ageing = Some(springbench::physics::ageing::AgeingParams {
        break_in_k_n_per_m: 720.0,
        break_in_load_j: 400.0,
        fatigue_k_n_per_m: 480.0,
        fatigue_load_j: 5000.0,
        width_m: 0.003,
        collapse: None,
    });
    p
}

/// Issue 32 on the emulated bench (decision 0135): the emulator ages its
/// part sample by sample with its own true load, the virtual bench's law,
/// and carries it across runs and across a kill -9 of the daemon (the
/// runner stores the true load with the test's state and hands it to the
/// new emulator). A part with strong, fast ageing, 4 intervals of 60 s,
/// the stimulus 6 mm at the resonance, killed -9 after interval 1: the
/// measured K(0) falls at every interval and its change from interval 0
/// follows the part's true K(0) at the emulator's true load; the load
/// measured from the laser (`ageing::load_from_displacement_j` with the
/// last measured K(x)) agrees with the emulator's true load. Unpaced
/// emulator, analog laser.
#[tokio::test]
async fn the_emulated_part_ages_with_its_true_load_across_runs_and_a_restart() {
    let traces = tempfile::tempdir().unwrap();
    let cfg = config(traces.path(), "");
    let mut d = Daemon::start(&cfg);
    let tmp = d.take_dir().unwrap();
    let c = client();
    let part = fast_ageing_part();
    let a = part.ageing.unwrap();
    let k0_new = part.k_coeffs_si[0];
    let id = hw::submit_long_term(
        &c,
        &d,
        json!({"measurement": {"part": {"serial": "LT-AGE"}, "bench": "emu-1",
                               "part_spec": part, "target_xpeak_m": 0.004},
               "duration_s": 180.0, "interval_s": 60.0,
               "stimulus": {"excursion_m": 0.006}}),
    )
    .await;
    let path = format!("/api/v1/long-term-tests/{id}");
    // Killed -9 once interval 1 is stored (during the stimulus before interval 2).
    let t0 = std::time::Instant::now();
    let before = loop {
        let v = get(&c, &d, &path).await;
        if v["intervals"].as_array().unwrap().len() >= 2
            || common::terminal(v["job"]["state"].as_str().unwrap_or(""))
        {
            break v;
        }
        assert!(t0.elapsed() < Duration::from_secs(600), "timed out: {v}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    d.kill9();
    assert_eq!(before["job"]["state"], "running", "{before}");
    assert_eq!(before["intervals"].as_array().unwrap().len(), 2, "{before}");
    // The emulated part's truth after interval 1's measurement, as stored.
    let part1 = before["state"]["part"].clone();
    let true_load_1 = part1["true_load_j"].as_f64().expect("true load stored");
    let measured_load_1 = part1["load_j"].as_f64().unwrap();
    let k0_true_1 = part1["k0_true_n_per_m"].as_f64().unwrap();
    d = Daemon::start_in(tmp.path(), &cfg);
    let j = wait_job(&c, &d, &id, Duration::from_secs(600), terminal).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let t = get(&c, &d, &path).await;
    let doc = &t["state"]["document"];
    let k0 = hw::column(&doc["intervals"], "k0_n_per_m");
    let loads = hw::column(&t["intervals"], "load_j");
    // The truth at each interval's start: interval 0 the new part; 1 from
    // the state stored with it (its K(0) at the measurement's start, its
    // loads after it); 2 and 3 from the resumed daemon's log.
    let after = hw::truth_lines(&j);
    println!(
        "emulated ageing: measured K(0) {k0:?} N/m, loads {loads:?} J; before the kill: {part1}; after: {after:?}\nlog: {}",
        j["log"]
    );
    assert_eq!(k0.len(), 4, "{t}");
    assert_eq!(after.iter().map(|r| r.0).collect::<Vec<_>>(), [2, 3], "{j}");
    // The true load was carried across the restart: the resumed emulator's
    // part starts from the stored one, and the stimulus adds to it.
    assert!(after[0].1 > true_load_1, "{after:?} {part1}");
    let k0_true = [k0_new, k0_true_1, after[0].2, after[1].2];
    let true_loads_at_start = [0.0, f64::NAN, after[0].1, after[1].1];
    // The log's K(0) is the law's at the log's load (both to 0.1).
    for (i, (e, k)) in true_loads_at_start.iter().zip(&k0_true).enumerate() {
        if e.is_finite() {
            assert!(
                (a.k0_n_per_m(k0_new, *e) - k).abs() < 0.2,
                "interval {i}: K(0) true {k} at {e} J"
            );
        }
    }
    // The measured K(0) falls at every interval, and its change from
    // interval 0 follows the truth's.
    for i in 1..4 {
        assert!(k0[i] < k0[i - 1], "K(0) did not fall: {k0:?}");
        let measured = 100.0 * (k0[i] / k0[0] - 1.0);
        let truth = 100.0 * (k0_true[i] / k0_new - 1.0);
        println!("interval {i}: K(0) change {measured:+.2} % measured, {truth:+.2} % true");
        assert!(
            (measured - truth).abs() < 2.0,
            "interval {i}: K(0) change {measured:+.2} % measured, {truth:+.2} % true"
        );
    }
    // The measured load against the emulator's true load.
    let pairs = [
        (measured_load_1, true_load_1),
        (after[0].3, after[0].1),
        (after[1].3, after[1].1),
    ];
    // The measured load leaves out the measurements' resonance-search
    // sweeps (the procedure does not return them).
    for (m, e) in pairs {
        let dev = 100.0 * (m / e - 1.0);
        println!("load measured {m:.1} J, true {e:.1} J: {dev:+.2} %");
        assert!((-15.0..=2.0).contains(&dev), "measured {m} J, true {e} J");
    }
    let last = &t["state"]["part"];
    println!("final state {last}");
    assert!(last["true_load_j"].as_f64().unwrap() > after[1].1, "{last}");
}

/// Every run of job 2 with its wall-clock span (first and last captured
/// block, Unix s) from the emulator's traces.
fn runs_of_job_2(dir: &Path) -> Vec<(Value, f64, f64)> {
    hw::traces_of_job(dir, 2)
        .into_iter()
        .map(|r| {
            let clock = r["clock"].as_array().cloned().unwrap_or_default();
            let at = |v: Option<&Value>| v.and_then(|c| c[0].as_f64()).unwrap_or(f64::NAN);
            let (a, b) = (at(clock.first()), at(clock.last()));
            (r, a, b)
        })
        .collect()
}

fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// A daemon on the emulated bench (its traces in `traces`) running a test
/// of one 120-s interval, measurements at 4 mm, with `stimulus`; its id.
async fn one_interval_test(traces: &Path, serial: &str, stimulus: Value) -> (Daemon, String) {
    let d = Daemon::start(&config(traces, ""));
    let body = json!({"measurement": {"part": {"serial": serial}, "bench": "emu-1", "target_xpeak_m": 0.004},
                      "duration_s": 120.0, "interval_s": 120.0, "stimulus": stimulus});
    let id = hw::submit_long_term(&client(), &d, body).await;
    (d, id)
}

/// Polls the test until `done`.
async fn wait_test(
    c: &reqwest::Client,
    d: &Daemon,
    id: &str,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let t0 = std::time::Instant::now();
    loop {
        let v = get(c, d, &format!("/api/v1/long-term-tests/{id}")).await;
        if done(&v) || common::terminal(v["job"]["state"].as_str().unwrap_or("")) {
            return v;
        }
        assert!(t0.elapsed() < Duration::from_secs(600), "timed out: {v}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The user's pause on the emulated bench (decisions 0126, 0130): asked
/// while the stimulus holds its chunks, the hold stops at the end of the
/// chunk it plays (faded out, not ramped down by an abort), no run of the
/// bench starts while the test is paused (the emulator's traces, by wall
/// clock), the test clock, load and intervals stand still, and after the
/// resume the stimulus plays again and the test finishes with both
/// intervals; the pause and its end are the user's events at one test time.
/// Unpaced emulator, analog laser, ~10 s.
#[tokio::test]
async fn a_user_pause_on_the_emulated_bench_stops_the_hold_at_its_chunks_end() {
    let traces = tempfile::tempdir().unwrap();
    let (d, id) = one_interval_test(traces.path(), "LT-UP", json!({"excursion_m": 0.004})).await;
    let c = client();
    // In the hold's chunks: the probe and the search take at most 12 s of
    // test time after interval 0's measurement; 25 s later a chunk has ended.
    let v = wait_test(&c, &d, &id, |v| {
        let clock = v["state"]["clock_s"].as_f64().unwrap_or(f64::INFINITY);
        v["job"]["progress"].as_f64().unwrap_or(0.0) * 120.0 > clock + 25.0
    })
    .await;
    assert_eq!(v["job"]["state"], "running", "{v}");
    let lt = |what: &str| format!("/api/v1/long-term-tests/{id}/{what}");
    let asked = unix_now_s();
    assert_eq!(post_status(&c, &d, &lt("pause")).await, 202);
    let answered = unix_now_s();
    let held = wait_test(&c, &d, &id, paused).await;
    assert_eq!(held["job"]["state"], "running", "{held}");
    tokio::time::sleep(Duration::from_secs(2)).await;
    let still = get(&c, &d, &format!("/api/v1/long-term-tests/{id}")).await;
    for k in ["intervals", "state"] {
        assert_eq!(held[k], still[k], "{k} moved while paused");
    }
    assert_eq!(held["job"]["progress"], still["job"]["progress"]);
    assert!(paused(&still), "{still}");
    let resumed = unix_now_s();
    assert_eq!(post_status(&c, &d, &lt("resume")).await, 202);
    let t = wait_test(&c, &d, &id, |_| false).await;
    assert_eq!(t["job"]["state"], "succeeded", "{t}");
    let at: Vec<f64> = hw::column(&t["intervals"], "elapsed_s");
    assert_eq!(at, [0.0, 120.0], "{t}");
    // The events: the user's pause and its end at one test time, within the stimulus.
    let users = common::user_events(&t);
    assert_eq!(users.len(), 2, "{t}");
    assert_eq!(
        (users[0].0.as_str(), users[1].0.as_str()),
        ("paused", "resumed")
    );
    assert_eq!(users[0].1, users[1].1);
    let clock0 = v["state"]["clock_s"].as_f64().unwrap();
    assert!(
        users[0].1 > clock0 + 12.0 && users[0].1 < 120.0,
        "{users:?}"
    );
    // The emulated bench: the run playing when the pause was asked went to
    // its end, faded; none started until the resume; runs after it.
    let runs = runs_of_job_2(traces.path());
    for (r, a, b) in &runs {
        println!(
            "run {}: {a:.3} .. {b:.3}, span {} s, peak drive {} V, last 2 ms {} V, abort {}, x peak {} m",
            r["sweep"], r["drive_span_s"], r["peak_drive_v"], r["last_2ms_peak_drive_v"], r["abort_sample"], r["x_true_peak_m"]
        );
    }
    println!("pause asked {asked:.3}, answered {answered:.3}, resume asked {resumed:.3}; events {users:?}");
    let started_while_paused: Vec<_> = runs
        .iter()
        .filter(|(_, a, _)| *a > answered && *a < resumed)
        .collect();
    assert!(
        started_while_paused.is_empty(),
        "runs started while paused: {started_while_paused:?}"
    );
    let playing: Vec<_> = runs
        .iter()
        .filter(|(_, a, b)| *a <= answered && *b >= asked)
        .collect();
    assert!(playing.len() <= 1, "{playing:?}");
    for (r, _, _) in &playing {
        assert!(r["abort_sample"].is_null(), "the chunk was cut: {r}");
        let peak = r["peak_drive_v"].as_f64().unwrap();
        let tail = r["last_2ms_peak_drive_v"].as_f64().unwrap();
        assert!(tail < 0.1 * peak, "the chunk ended at level: {r}");
    }
    assert!(
        runs.iter().any(|(_, a, _)| *a > resumed),
        "nothing played after the resume"
    );
    let log = t["job"]["log"].to_string();
    assert_eq!(log.matches("stimulus from test time").count(), 2, "{log}");
}

/// A stepped stimulus on the emulated bench (decision 0132): the hold's
/// target changes at the step, the resonance searched again at the new
/// level; the part's true excursion in every held chunk (the emulator's
/// trace) is the level's within 10 %, each hold's mean within 5 %. 2 mm
/// until test time 70 s, 4 mm from then (at 5 mm spider_4in's hold is
/// jumpy: one chunk fell to 3.75 mm, the next held 5.93 mm).
/// Unpaced emulator, analog laser, ~10 s.
#[tokio::test]
async fn a_stepped_stimulus_on_the_emulated_bench_holds_each_levels_excursion() {
    let traces = tempfile::tempdir().unwrap();
    let stimulus = json!({"excursion_m": 0.002, "steps": [{"from_s": 70.0, "excursion_m": 0.004}]});
    let (d, id) = one_interval_test(traces.path(), "LT-ST", stimulus).await;
    let c = client();
    let t = wait_test(&c, &d, &id, |_| false).await;
    assert_eq!(t["job"]["state"], "succeeded", "{t}");
    let runs = hw::traces_of_job(traces.path(), 2);
    // The runs in groups, each begun by the 2-s probe at 0.5 V that starts
    // a measurement (its 16-s pre-measurement follows) and a hold (its
    // resonance search follows, then its chunks of 10 s).
    let span = |r: &Value| r["drive_span_s"].as_f64().unwrap();
    let mut groups: Vec<Vec<&Value>> = vec![];
    for r in &runs {
        println!(
            "run {}: span {:.3} s, peak drive {} V, x peak {} m, held {} m",
            r["sweep"],
            span(r),
            r["peak_drive_v"],
            r["x_true_peak_m"],
            r["x_true_peak_held_m"]
        );
        if r["peak_drive_v"] == 0.5 && (span(r) - 2.0).abs() < 0.01 || groups.is_empty() {
            groups.push(vec![]);
        }
        groups.last_mut().unwrap().push(r);
    }
    let is_measurement = |g: &Vec<&Value>| g.iter().any(|r| span(r) > 12.0);
    let holds: Vec<Vec<f64>> = groups
        .iter()
        .filter(|g| !is_measurement(g))
        .map(|g| {
            g.iter()
                .filter(|r| span(r) > 5.0)
                .map(|r| r["x_true_peak_held_m"].as_f64().unwrap())
                .collect()
        })
        .collect();
    println!(
        "held chunks' true peaks per hold: {holds:?}\nlog {}",
        t["job"]["log"]
    );
    assert_eq!(groups.len(), 4, "measurement, hold, hold, measurement");
    assert!(is_measurement(&groups[0]) && is_measurement(&groups[3]));
    // Each hold's chunks at its level: 2 mm before the step, 4 mm after.
    assert_eq!(holds.len(), 2, "{holds:?}");
    for (chunks, level) in holds.iter().zip([0.002, 0.004]) {
        assert!(!chunks.is_empty(), "{holds:?}");
        let mean = chunks.iter().sum::<f64>() / chunks.len() as f64;
        assert!((mean / level - 1.0).abs() < 0.05, "{holds:?}");
        for x in chunks {
            assert!(
                (x / level - 1.0).abs() < 0.1,
                "a chunk held {x} m at the level {level} m: {holds:?}"
            );
        }
    }
    // The step ended the first hold: the second began at its test time.
    let log = t["job"]["log"].to_string();
    assert!(
        log.contains("stimulus from test time 70 s:") && log.contains("(target 4.000 mm)"),
        "{log}"
    );
}

/// A two-interval long-term test (60 s apart) of `stimulus` on `emu-1`,
/// run to its end: its job, its test document, each run's peak drive from
/// the bench's traces, and the job's log lines that begin with `prefix`
/// (one per held stimulus). Asserts it succeeded with its three intervals.
async fn run_loop_test(
    c: &reqwest::Client,
    d: &Daemon,
    traces: &std::path::Path,
    serial: &str,
    stimulus: Value,
    prefix: &str,
) -> (Value, Value, Vec<f64>, Vec<String>) {
    let id = hw::submit_long_term(
        c,
        d,
        json!({"measurement": {"part": {"serial": serial}, "bench": "emu-1", "target_xpeak_m": 0.004},
               "duration_s": 120.0, "interval_s": 60.0, "stimulus": stimulus}),
    )
    .await;
    let j = wait_job(c, d, &id, Duration::from_secs(600), terminal).await;
    let t = get(c, d, &format!("/api/v1/long-term-tests/{id}")).await;
    let peaks: Vec<f64> = hw::traces_of_job(traces, 2)
        .iter()
        .map(|r| r["peak_drive_v"].as_f64().unwrap())
        .collect();
    let log: Vec<String> = j["log"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|l| l.as_str())
        .filter(|l| l.starts_with(prefix))
        .map(str::to_string)
        .collect();
    println!("job {j}\npeak drive per run {peaks:?}\n{log:#?}");
    assert_eq!(j["state"], "succeeded", "{j}");
    assert_eq!(t["intervals"].as_array().unwrap().len(), 3, "{t}");
    (j, t, peaks, log)
}

/// Issue 32, decision 0137: band-limited noise as a long-term test's
/// stimulus on the emulated bench, played through the hardware path in
/// faded chunks under the bench's safety rules. The drive limit (30 V) is
/// below what 1.5 mm RMS of 20-100 Hz needs on spider_4in: every run's
/// drive on the emulated output stays within it, the noise's chunks reach
/// it, and the job's log says the RMS displacement reached against its
/// target; the load measured from the laser grows with every interval.
/// Unpaced emulator, analog laser.
#[tokio::test]
async fn a_noise_stimulus_plays_under_the_drive_limit_on_the_emulated_bench() {
    let traces = tempfile::tempdir().unwrap();
    let cfg = config(traces.path(), "").replace("max_drive_v = 100.0", "max_drive_v = 30.0");
    let d = Daemon::start(&cfg);
    let c = client();
    let (j, t, peaks, log) = run_loop_test(
        &c,
        &d,
        traces.path(),
        "LT-NOISE-E",
        json!({"kind": "noise", "band_hz": [20.0, 100.0], "excursion_rms_m": 0.0015}),
        "noise stimulus",
    )
    .await;
    for p in &peaks {
        assert!(*p <= 30.0 + 1e-3, "beyond the drive limit: {peaks:?}");
    }
    assert!(
        peaks.iter().any(|p| *p > 29.0),
        "the limit never bound: {peaks:?}"
    );
    assert_eq!(log.len(), 2, "{j}");
    for l in &log {
        assert!(
            l.contains("(target 1.500 mm)") && l.contains("(limit 30 V)"),
            "{l}"
        );
        let x: f64 = l
            .split("RMS displacement ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(x > 0.3 && x < 1.5, "{l}");
    }
    let loads = hw::column(&t["intervals"], "load_j");
    assert!(loads.windows(2).all(|w| w[1] > w[0]), "{loads:?}");
}

/// Issue 32, decision 0144: a WAV file as a long-term test's stimulus on
/// the emulated bench, played as the noise is (the loop in faded chunks,
/// levelled on the measured RMS displacement, under the drive limit).
/// The file: 4 s of a 25 + 40 Hz two-tone at 48 kHz, 16 bit, uploaded
/// once. Unpaced emulator, analog laser.
#[tokio::test]
async fn a_wav_stimulus_plays_on_the_emulated_bench() {
    let traces = tempfile::tempdir().unwrap();
    let d = Daemon::start(&config(traces.path(), ""));
    let c = client();
    let wav = {
        let spec = hound::WavSpec {
            channels: 1,
            sample_rate: 48000,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut cur = std::io::Cursor::new(Vec::new());
        let mut w = hound::WavWriter::new(&mut cur, spec).unwrap();
        for i in 0..192000 {
            let t = i as f64 / 48000.0;
            let v = 0.4 * (2.0 * std::f64::consts::PI * 25.0 * t).sin()
                + 0.3 * (2.0 * std::f64::consts::PI * 40.0 * t).sin();
            w.write_sample((v * 32767.0) as i16).unwrap();
        }
        w.finalize().unwrap();
        cur.into_inner()
    };
    let r = c
        .post(d.url("/api/v1/stimuli"))
        .bearer_auth("open-access")
        .header("content-type", "audio/wav")
        .body(wav)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let wav_id = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let (j, t, peaks, log) = run_loop_test(
        &c,
        &d,
        traces.path(),
        "LT-WAV-E",
        json!({"kind": "wav", "wav_id": wav_id, "excursion_rms_m": 0.001}),
        "WAV file stimulus",
    )
    .await;
    for p in &peaks {
        assert!(*p <= 100.0 + 1e-3, "beyond the drive limit: {peaks:?}");
    }
    assert_eq!(log.len(), 2, "{j}");
    for l in &log {
        assert!(l.contains("(target 1.000 mm)"), "{l}");
        let x: f64 = l
            .split("RMS displacement ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!((x - 1.0).abs() < 0.1, "held {x} mm of 1 mm: {l}");
    }
    let loads = hw::column(&t["intervals"], "load_j");
    assert!(loads.windows(2).all(|w| w[1] > w[0]), "{loads:?}");
}
