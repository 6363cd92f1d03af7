//! Gauge study through the daemon on two virtual benches (issue 21): 3
//! production parts x 2 repeats x 2 benches under a recipe. The study's
//! figures equal `qc::grr::anova` over the values the runs' verdicts give
//! through the public API, the parts' mean values lie at the virtual bench's
//! truth, and bad study requests are refused naming the field.
//!
//! The gauge study of the acceptance (10 parts x 3 repeats x 2
//! benches, both procedures) is in docs/qc.md, with the command that ran it.

use crate::common;

use common::{Api, Daemon};
use reqwest::Method;
use serde_json::{json, Value};
use springbench::physics::production::{part, Spread};
use springbench::qc::grr;
use std::time::{Duration, Instant};

/// The API as the station (jobs, reads).
fn station(d: &Daemon) -> Api {
    Api::with(d, OPERATOR)
}

const OPERATOR: &str = "station-secret-0123456789";
const ADMIN: &str = "engineer-secret-0123456789";

fn config() -> String {
    "[[auth.tokens]]\nname = \"station-1\"\ntoken = \"station-secret-0123456789\"\nrole = \"operator\"\n\
     [[auth.tokens]]\nname = \"qc-engineer\"\ntoken = \"engineer-secret-0123456789\"\nrole = \"admin\"\n\
     [[benches]]\nid = \"virtual-1\"\nseed = 1\n[[benches]]\nid = \"virtual-2\"\nseed = 1001\n"
        .into()
}

/// K(x) = sum k_i x^i of a part (N/m).
fn k_at(k: &[f64], x: f64) -> f64 {
    k.iter().rev().fold(0.0, |acc, c| acc * x + c)
}

/// The study's document once every run has ended.
async fn study_done(d: &Daemon, id: &str, within: Duration) -> Value {
    let t = Instant::now();
    loop {
        let v = station(d).get(&format!("/api/v1/gauge-studies/{id}")).await;
        if v["state"] == "done" {
            return v;
        }
        assert!(t.elapsed() < within, "study {id} did not end: {v}");
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gauge_study_on_two_virtual_benches() {
    // A third bench whose laser reads 2 % long: out of calibration.
    let d = Daemon::start(&format!(
        "{}[[benches]]\nid = \"virtual-off\"\nseed = 4001\n[benches.virtual]\nlaser_gain_error = 0.02\n",
        config()
    ));
    let nominal = springbench::physics::preset("spider_4in").unwrap();
    let k0 = nominal.k_coeffs_si[0];
    let k4 = k_at(&nominal.k_coeffs_si, 0.004);
    let recipe = json!({
        "name": "spider-4in",
        "part_kind": "spider",
        "procedure": {"levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0", "lower": 0.9 * k0, "upper": 1.1 * k0},
            {"name": "k_at_4mm", "quantity": "k_at_x", "x_m": 0.004, "lower": 0.9 * k4, "upper": 1.1 * k4},
            {"name": "keff", "quantity": "keff"},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ]
    });
    let (s, v) = Api::with(&d, ADMIN)
        .exchange(Method::POST, "/api/v1/recipes", Some(&recipe))
        .await;
    assert_eq!(s, 201, "{v}");

    // Bad requests: one field named each.
    let parts: Vec<Value> = (0..3u64)
        .map(|i| json!({"serial": format!("G-{i}"), "production": {"preset": "spider_4in", "seed": 700 + i}}))
        .collect();
    let post = |body: Value| {
        let api = station(&d);
        async move {
            api.exchange(Method::POST, "/api/v1/gauge-studies", Some(&body))
                .await
        }
    };
    for (body, field) in [
        (
            json!({"recipe": "spider-4in", "parts": parts, "repeats": 1}),
            "repeats",
        ),
        (
            json!({"recipe": "spider-4in", "parts": parts[..1], "repeats": 2}),
            "parts",
        ),
        (
            json!({"recipe": "spider-4in", "parts": [parts[0], parts[0]], "repeats": 2}),
            "parts[1].serial",
        ),
        (
            json!({"recipe": "spider-4in", "parts": parts, "repeats": 2, "benches": ["nope"]}),
            "benches[0]",
        ),
        (
            json!({"recipe": "spider-4in", "parts": parts, "repeats": 2, "job": {"part": {}}}),
            "job.part",
        ),
        (
            json!({"recipe": "no-such", "parts": parts, "repeats": 2}),
            "recipe",
        ),
        (
            json!({"recipe": "spider-4in", "parts": parts, "repeats": 2, "extra": 1}),
            "extra",
        ),
    ] {
        let (s, v) = post(body).await;
        assert_eq!(s, 422, "{field}: {v}");
        let named = v["errors"]
            .as_array()
            .into_iter()
            .flatten()
            .any(|e| e["field"] == field)
            || v.to_string().contains(&format!("\"{field}\""));
        assert!(named, "{field} not named: {v}");
    }
    let (s, _) = Api::with(&d, OPERATOR)
        .exchange(Method::GET, "/api/v1/gauge-studies/nope", None)
        .await;
    assert_eq!(s, 404);

    // The study.
    let (s, study) = post(json!({"recipe": "spider-4in", "parts": parts, "repeats": 2,
                                 "benches": ["virtual-1", "virtual-2"]}))
    .await;
    assert_eq!(s, 201, "{study}");
    assert_eq!(study["runs_total"], 12);
    assert_eq!(study["benches"], json!(["virtual-1", "virtual-2"]));
    let id = study["id"].as_str().unwrap().to_string();
    let study = study_done(&d, &id, Duration::from_secs(900)).await;
    assert_eq!(study["not_computed"], json!([]), "{study}");

    // Independent values: each run's job verdict through the public API.
    // values[name][part][bench][repeat]
    let benches = ["virtual-1", "virtual-2"];
    let mut values = std::collections::HashMap::<String, Vec<Vec<Vec<f64>>>>::new();
    for run in study["runs"].as_array().unwrap() {
        let job = run["job_id"].as_str().unwrap();
        let v = station(&d)
            .get(&format!("/api/v1/jobs/{job}/verdict"))
            .await;
        let p = run["part_index"].as_u64().unwrap() as usize;
        let b = benches.iter().position(|x| *x == run["bench_id"]).unwrap();
        let r = run["repeat"].as_u64().unwrap() as usize;
        let m = &v["measurements"][0]["detail"]["parameters"];
        for param in m.as_array().unwrap() {
            let name = param["name"].as_str().unwrap().to_string();
            let grid = values
                .entry(name)
                .or_insert_with(|| vec![vec![vec![f64::NAN; 2]; 2]; 3]);
            grid[p][b][r] = param["value"].as_f64().unwrap();
        }
    }
    for q in study["quantities"].as_array().unwrap() {
        let name = q["quantity"].as_str().unwrap();
        let tol = q["tolerance"].as_f64();
        let want = grr::anova(name, q["unit"].as_str().unwrap(), &values[name], tol).unwrap();
        for f in ["ev_sd", "av_sd", "grr_sd", "pv_sd", "tv_sd"] {
            let got = q[f].as_f64().unwrap();
            let w = serde_json::to_value(&want).unwrap()[f].as_f64().unwrap();
            assert!(
                (got - w).abs() <= 1e-9 * w.abs().max(1e-12),
                "{name} {f}: {got} vs {w}"
            );
        }
        assert_eq!(q["ndc"], serde_json::to_value(want.ndc).unwrap());
        eprintln!(
            "{name}: EV {:.4e} AV {:.4e} GRR {:.4e} PV {:.4e} {}; %GRR of tolerance {:?}, ndc {:?}",
            want.ev_sd,
            want.av_sd,
            want.grr_sd,
            want.pv_sd,
            want.unit,
            want.grr_percent_of_tolerance,
            want.ndc
        );
    }
    let names: Vec<&str> = study["quantities"]
        .as_array()
        .unwrap()
        .iter()
        .map(|q| q["quantity"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["k0", "k_at_4mm", "keff", "model_error"]);
    // Issue 35: the one-sided limit (model error <= 5 %) is judged as AIAG
    // judges a one-sided characteristic: 3 GRR against the distance from
    // the mean to the limit, not against the total variation (which read
    // 100 %, ndc 0, "not acceptable" for parts of one kind).
    let me = &study["quantities"][3];
    assert_eq!(me["limits"], "upper", "{me}");
    assert_eq!(me["one_sided_limit"], 5.0, "{me}");
    let all: Vec<f64> = values["model_error"]
        .iter()
        .flatten()
        .flatten()
        .copied()
        .collect();
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    assert!(mean > 0.0 && mean < 5.0, "{mean}");
    let dist = me["limit_distance"].as_f64().unwrap();
    assert!(
        (dist - (5.0 - mean)).abs() < 1e-9,
        "{dist} vs {}",
        5.0 - mean
    );
    let grr_me = me["grr_sd"].as_f64().unwrap();
    let pct = me["grr_percent_of_limit_distance"].as_f64().unwrap();
    assert!(
        (pct - 100.0 * 3.0 * grr_me / (5.0 - mean)).abs() < 1e-9 * pct.max(1.0),
        "{me}"
    );
    let class = if pct < 10.0 {
        "acceptable"
    } else if pct <= 30.0 {
        "conditionally_acceptable"
    } else {
        "not_acceptable"
    };
    assert_eq!(me["acceptance"], class, "{me}");
    assert!(me["grr_percent_of_tolerance"].is_null(), "{me}");
    eprintln!("model_error: mean {mean:.3} %, GRR {grr_me:.4} %, {pct:.2} % of the distance to 5 %: {class}");
    // 3 parts on 2 benches: AIAG's 10 parts are missing, said so, once per quantity.
    for q in study["quantities"].as_array().unwrap() {
        let w = q["warnings"].to_string();
        assert!(w.contains("3 parts") && w.contains("at least 10"), "{q}");
        assert!(!w.contains("bench:"), "2 benches are enough: {q}");
    }
    assert_eq!(study["quantities"][0]["limits"], "two_sided");
    assert_eq!(study["quantities"][2]["limits"], "none");
    // Tolerance: USL - LSL of the recipe; keff has no limits.
    let tol = study["quantities"][0]["tolerance"].as_f64().unwrap();
    assert!((tol - 0.2 * k0).abs() < 1e-9 * k0);
    assert!(study["quantities"][2]["tolerance"].is_null());

    // Each part's mean over benches and repeats lies at the truth, within
    // the bounds tests/it/trust_virtual.rs holds the virtual bench's results
    // to (k0 3 %, K(x) 1 %).
    for (i, _) in parts.iter().enumerate() {
        let truth = part(&nominal, &Spread::default(), 700 + i as u64, None);
        for (name, want, bound) in [
            ("k0", truth.k_coeffs_si[0], 0.03),
            ("k_at_4mm", k_at(&truth.k_coeffs_si, 0.004), 0.01),
        ] {
            let v: Vec<f64> = values[name][i].iter().flatten().copied().collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            eprintln!(
                "part {i} {name}: mean {mean:.2} truth {want:.2} ({:+.3} %)",
                100.0 * (mean / want - 1.0)
            );
            assert!(
                (mean / want - 1.0).abs() < bound,
                "part {i} {name}: mean {mean:.1} truth {want:.1}"
            );
        }
    }

    bench_calibration_from_the_study_parts(&d).await;
}

/// Bench calibration (decision 0049) from the study's 3 parts as golden
/// units: virtual-2 differs from virtual-1 only in noise (e and dm about 0,
/// in calibration); virtual-off's laser reads 2 % long, beyond the 1 %
/// bound: out of calibration, and a part measured there is `invalid`, never
/// corrected silently. Every verdict names the calibration it was judged
/// with, or that there is none.
async fn bench_calibration_from_the_study_parts(d: &Daemon) {
    let serials: Vec<String> = (0..3).map(|i| format!("G-{i}")).collect();
    let job = |serial: &str, seed: u64, bench: &str| {
        json!({"part": {"serial": serial}, "recipe": "spider-4in", "bench": bench,
               "production": {"preset": "spider_4in", "seed": seed}})
    };
    // Too few golden units, an unknown bench, units not measured there or
    // not with the procedure.
    for (body, field) in [
        (
            json!({"bench": "virtual-2", "reference_bench": "virtual-1", "serials": serials[..2]}),
            "serials",
        ),
        (
            json!({"bench": "nope", "reference_bench": "virtual-1", "serials": serials}),
            "bench",
        ),
        (
            json!({"bench": "virtual-off", "reference_bench": "virtual-1", "serials": serials}),
            "serials",
        ),
        // Measured with the full procedure only: no production calibration.
        (
            json!({"bench": "virtual-2", "reference_bench": "virtual-1", "serials": serials,
                   "procedure": "production"}),
            "serials",
        ),
    ] {
        let (s, v) = Api::with(d, ADMIN)
            .exchange(
                Method::POST,
                "/api/v1/recipes/spider-4in/bench-calibrations",
                Some(&body),
            )
            .await;
        assert_eq!(s, 422, "{field}: {v}");
        assert!(
            v.to_string().contains(&format!("\"{field}\"")),
            "{field}: {v}"
        );
    }
    // The operator may not change how a bench is judged.
    let (s, _) = Api::with(d, OPERATOR)
        .exchange(
            Method::POST,
            "/api/v1/recipes/spider-4in/bench-calibrations",
            Some(
                &json!({"bench": "virtual-2", "reference_bench": "virtual-1", "serials": serials}),
            ),
        )
        .await;
    assert_eq!(s, 403);

    let cal = calibrate(d, "virtual-2", "virtual-1", &serials, None).await;
    let k = &cal["calibration"];
    eprintln!("virtual-2: {k}");
    assert_eq!(cal["state"], "in_calibration", "{cal}");
    // Noise only: e and dm at 0 within 5 % of the acceptance study's bench
    // differences (0.2 %, 0.05 g).
    assert!(k["laser_gain_error"].as_f64().unwrap().abs() < 1e-4, "{k}");
    assert!(k["clamp_mass_kg"].as_f64().unwrap().abs() < 2.5e-6, "{k}");

    run_jobs(
        d,
        (0..3)
            .map(|i| job(&serials[i], 700 + i as u64, "virtual-off"))
            .collect(),
    )
    .await;
    let off = calibrate(d, "virtual-off", "virtual-1", &serials, None).await;
    let e = off["calibration"]["laser_gain_error"].as_f64().unwrap();
    eprintln!(
        "virtual-off: laser {:+.4} %, problems {}",
        100.0 * e,
        off["calibration"]["problems"]
    );
    assert_eq!(off["state"], "out_of_calibration", "{off}");
    assert!((e - 0.02).abs() < 0.001, "{e}");
    assert!(
        off["calibration"]["problems"][0]
            .as_str()
            .unwrap()
            .contains("laser"),
        "{off}"
    );

    // One more measurement on each bench: its verdict's traceability.
    let ids = run_jobs(
        d,
        ["virtual-1", "virtual-2", "virtual-off"]
            .iter()
            .map(|b| job("G-0", 700, b))
            .collect(),
    )
    .await;
    let verdict =
        |id: String| async move { station(d).get(&format!("/api/v1/jobs/{id}/verdict")).await };
    let v1 = verdict(ids[0].clone()).await;
    assert_eq!(
        v1["measurements"][0]["traceability"]["bench_calibration"]["state"], "none",
        "{v1}"
    );
    let v2 = verdict(ids[1].clone()).await;
    let t = &v2["measurements"][0]["traceability"]["bench_calibration"];
    assert_eq!(t["id"], cal["id"], "{v2}");
    assert_eq!(t["state"], "in_calibration");
    assert_eq!(t["procedure"], "full");
    assert_eq!(v2["measurements"][0]["verdict"], "pass", "{v2}");
    let v3 = verdict(ids[2].clone()).await;
    assert_eq!(
        v3["measurements"][0]["traceability"]["bench_calibration"]["id"], off["id"],
        "{v3}"
    );
    assert_eq!(v3["verdict"], "invalid", "{v3}");
    assert!(v3.to_string().contains("bench_out_of_calibration"), "{v3}");
    let list = station(d)
        .get("/api/v1/recipes/spider-4in/bench-calibrations")
        .await;
    assert_eq!(list["items"].as_array().unwrap().len(), 2, "{list}");

    // Golden units measured with repeats calibrate with every repeat: each
    // unit's estimate is the mean over its (reference, bench) result pairs
    // (before, only the first repeat's result was read, the others unseen).
    // A job takes its repeats from the recipe: a version with 2.
    let mut r = station(d).get("/api/v1/recipes/spider-4in").await["recipe"].clone();
    r["procedure"]["repeats"] = json!(2);
    let (s, v) = Api::with(d, ADMIN)
        .exchange(Method::PUT, "/api/v1/recipes/spider-4in", Some(&r))
        .await;
    assert!(s == 200 || s == 201, "{s} {v}");
    run_jobs(
        d,
        (0..3)
            .map(|i| job(&serials[i], 700 + i as u64, "virtual-2"))
            .collect(),
    )
    .await;
    let cal = calibrate(d, "virtual-2", "virtual-1", &serials, None).await;
    assert_eq!(cal["state"], "in_calibration", "{cal}");
    let units = cal["calibration"]["units"].as_array().unwrap();
    assert_eq!(units.len(), 3, "{cal}");
    for u in units {
        assert_eq!(
            u["pairs"], 2,
            "one reference result, two repeats on the bench: {cal}"
        );
    }
    let k = &cal["calibration"];
    assert!(k["laser_gain_error"].as_f64().unwrap().abs() < 1e-4, "{k}");
}

/// Submits `bodies` as jobs and waits until each has succeeded.
async fn run_jobs(d: &Daemon, bodies: Vec<Value>) -> Vec<String> {
    let mut ids = vec![];
    for body in bodies {
        let (s, v) = Api::with(d, OPERATOR)
            .exchange(Method::POST, "/api/v1/jobs", Some(&body))
            .await;
        assert_eq!(s, 202, "{v}");
        ids.push(v["id"].as_str().unwrap().to_string());
    }
    for id in &ids {
        let t = Instant::now();
        loop {
            let j = station(d).get(&format!("/api/v1/jobs/{id}")).await;
            if common::terminal(j["state"].as_str().unwrap()) {
                assert_eq!(j["state"], "succeeded", "{j}");
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(900), "job {id}");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
    ids
}

/// Calibrates `bench` against `reference` from the golden units `serials`
/// (as the QC engineer); the stored calibration.
async fn calibrate(
    d: &Daemon,
    bench: &str,
    reference: &str,
    serials: &[String],
    procedure: Option<&str>,
) -> Value {
    let mut body = json!({"bench": bench, "reference_bench": reference, "serials": serials});
    if let Some(p) = procedure {
        body["procedure"] = json!(p);
    }
    let (s, v) = Api::with(d, ADMIN)
        .exchange(
            Method::POST,
            "/api/v1/recipes/spider-4in/bench-calibrations",
            Some(&body),
        )
        .await;
    assert_eq!(s, 201, "{v}");
    v
}

/// The acceptance gauge study of issue 21 (docs/qc.md, "Acceptance study"):
/// 10 spider_4in parts x 3 repeats x 2 virtual benches, full and production
/// procedure, under limits of +-10 % of the golden mean; twice: on two
/// benches that differ only in their noise (reproducibility about 0), and on
/// two that differ as two real benches do (laser sensitivity +-0.2 %, inner
/// clamp +-0.05 g; decision 0038). Minutes of CPU: `#[ignore]`.
/// `cargo test --test it -- --ignored --nocapture gauge::acceptance`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "acceptance study: 240 runs, minutes; docs/qc.md gives the command and figures"]
async fn acceptance_study_full_against_production() {
    const GAIN: f64 = 0.002;
    const CLAMP_KG: f64 = 0.00005;
    let cfg = format!(
        "{}[[benches]]\nid = \"virtual-3\"\nseed = 2001\n[benches.virtual]\nlaser_gain_error = {GAIN}\nclamp_mass_kg = {CLAMP_KG}\n\
         [[benches]]\nid = \"virtual-4\"\nseed = 3001\n[benches.virtual]\nlaser_gain_error = {}\nclamp_mass_kg = {}\n",
        config(),
        -GAIN,
        -CLAMP_KG
    );
    let d = Daemon::start(&cfg);
    let recipe = json!({
        "name": "spider-4in",
        "part_kind": "spider",
        "procedure": {"mode": "production", "levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0"},
            {"name": "keff", "quantity": "keff"},
            {"name": "k_at_4mm", "quantity": "k_at_x", "x_m": 0.004}
        ]
    });
    let (s, v) = Api::with(&d, ADMIN)
        .exchange(Method::POST, "/api/v1/recipes", Some(&recipe))
        .await;
    assert_eq!(s, 201, "{v}");

    // Golden units on virtual-1 (no reference yet: the full procedure),
    // limits of +-10 % of their mean, approved: the golden reference.
    let golden = |bench: &str, procedure: &str| -> Vec<Value> {
        (0..5u64)
            .map(|i| json!({"part": {"serial": format!("GU-{i}")}, "recipe": "spider-4in", "bench": bench,
                            "procedure": procedure, "production": {"preset": "spider_4in", "seed": 100 + i}}))
            .collect()
    };
    run_jobs(&d, golden("virtual-1", "full")).await;
    let serials: Vec<String> = (0..5).map(|i| format!("GU-{i}")).collect();
    let (s, p) = Api::with(&d, OPERATOR)
        .exchange(
            Method::POST,
            "/api/v1/recipes/spider-4in/limit-proposals",
            Some(&json!({"serials": serials, "method": "tolerance", "tolerance_percent": 10.0})),
        )
        .await;
    assert_eq!(s, 201, "{p}");
    let path = format!(
        "/api/v1/limit-proposals/{}/approve",
        p["id"].as_str().unwrap()
    );
    let (s, v) = Api::with(&d, ADMIN)
        .exchange(Method::POST, &path, None)
        .await;
    assert_eq!(s, 201, "{v}");

    // Bench calibration (decision 0049): the same golden units on every
    // other bench with the full procedure, and on every bench with the
    // production one; each bench calibrated against virtual-1 for each
    // procedure, virtual-1 against itself (the reference: e = 0, s = 1).
    let mut golden_jobs = vec![];
    for b in ["virtual-2", "virtual-3", "virtual-4"] {
        golden_jobs.extend(golden(b, "full"));
    }
    for b in ["virtual-1", "virtual-2", "virtual-3", "virtual-4"] {
        golden_jobs.extend(golden(b, "production"));
    }
    run_jobs(&d, golden_jobs).await;
    // Truth: the bench reads (1 + e) x; its clamp adds dm.
    for (procedure, (bench, e, dm)) in [
        ("virtual-1", 0.0, 0.0),
        ("virtual-2", 0.0, 0.0),
        ("virtual-3", GAIN, CLAMP_KG),
        ("virtual-4", -GAIN, -CLAMP_KG),
    ]
    .iter()
    .flat_map(|b| ["full", "production"].map(|p| (p, *b)))
    {
        let cal = calibrate(&d, bench, "virtual-1", &serials, Some(procedure)).await;
        let k = &cal["calibration"];
        let (ge, gdm) = (
            k["laser_gain_error"].as_f64().unwrap(),
            k["clamp_mass_kg"].as_f64().unwrap(),
        );
        eprintln!(
            "{bench} {procedure}: laser {:+.4} % (truth {:+.4} %, sd {:.4} %), clamp {:+.2} mg (truth {:+.2} mg), k scale {:.6}, K(x) scale {:.6}",
            100.0 * ge,
            100.0 * e,
            100.0 * k["laser_gain_error_sd"].as_f64().unwrap(),
            1e6 * gdm,
            1e6 * dm,
            k["k_scale"].as_f64().unwrap(),
            k["kx_scale"].as_f64().unwrap()
        );
        assert_eq!(cal["state"], "in_calibration", "{cal}");
        // The truth within the estimate's 99.8 % two-sided interval (7.2
        // standard errors: Student t, 4 degrees of freedom, from the spread
        // of the 5 units' single estimates), and the estimate resolves a
        // tenth of the study's laser difference.
        let n = 5f64.sqrt();
        let se_e = k["laser_gain_error_sd"].as_f64().unwrap() / n;
        let se_dm = 0.05 * k["kx_scale_sd"].as_f64().unwrap() / n;
        eprintln!(
            "    standard errors: laser {:.4} %, clamp {:.2} mg",
            100.0 * se_e,
            1e6 * se_dm
        );
        assert!(se_e <= 0.1 * GAIN, "{bench} {procedure}: {k}");
        assert!(
            (ge - e).abs() <= 7.2 * se_e + 1e-12,
            "{bench} {procedure}: e {ge} vs {e}"
        );
        assert!(
            (gdm - dm).abs() <= 7.2 * se_dm + 1e-12,
            "{bench} {procedure}: dm {gdm} vs {dm}"
        );
    }

    // Four studies: (identical | different benches) x (full | production).
    let parts: Vec<Value> = (0..10u64)
        .map(|i| json!({"serial": format!("S-{i:02}"), "production": {"preset": "spider_4in", "seed": 800 + i}}))
        .collect();
    let cases = [
        ("identical", ["virtual-1", "virtual-2"], "full"),
        ("identical", ["virtual-1", "virtual-2"], "production"),
        ("different", ["virtual-3", "virtual-4"], "full"),
        ("different", ["virtual-3", "virtual-4"], "production"),
    ];
    let mut studies = vec![];
    for (_, benches, procedure) in &cases {
        let body = json!({"recipe": "spider-4in", "parts": parts, "repeats": 3,
                          "benches": benches, "job": {"procedure": procedure}});
        let (s, v) = Api::with(&d, OPERATOR)
            .exchange(Method::POST, "/api/v1/gauge-studies", Some(&body))
            .await;
        assert_eq!(s, 201, "{v}");
        assert_eq!(v["runs_total"], 60);
        studies.push(v["id"].as_str().unwrap().to_string());
    }
    let t = Instant::now();
    let mut results = vec![];
    for id in &studies {
        results.push(study_done(&d, id, Duration::from_secs(3600)).await);
    }
    eprintln!("studies done after {:.0} s", t.elapsed().as_secs_f64());

    let q = |r: &Value, name: &str| -> Value {
        r["quantities"]
            .as_array()
            .unwrap()
            .iter()
            .find(|q| q["quantity"] == name)
            .unwrap_or_else(|| panic!("{name} not computed: {r}"))
            .clone()
    };
    eprintln!("| benches | procedure | quantity | EV | AV | GRR | PV | %GRR of +-10 % | ndc | acceptance |");
    for ((benches, _, procedure), r) in cases.iter().zip(&results) {
        assert_eq!(r["not_computed"], json!([]), "{r}");
        for name in ["k0", "keff", "k_at_4mm"] {
            let v = q(r, name);
            eprintln!(
                "| {benches} | {procedure} | {name} | {:.3} | {:.3} | {:.3} | {:.1} | {:.2} % | {} | {} |",
                v["ev_sd"].as_f64().unwrap(),
                v["av_sd"].as_f64().unwrap(),
                v["grr_sd"].as_f64().unwrap(),
                v["pv_sd"].as_f64().unwrap(),
                v["grr_percent_of_tolerance"].as_f64().unwrap(),
                v["ndc"],
                v["acceptance"]
            );
        }
    }
    // Every production run measured with the short procedure (no fall-back
    // on these good parts), every full run with the full one; each run's k0
    // by bench, read through the public API.
    let mut k0_by_bench = std::collections::HashMap::<String, Vec<f64>>::new();
    let mut bench_time = std::collections::HashMap::<&str, Vec<f64>>::new();
    for ((_, _, procedure), r) in cases.iter().zip(&results) {
        for run in r["runs"].as_array().unwrap() {
            assert_eq!(run["state"], "succeeded", "{run}");
            let job = run["job_id"].as_str().unwrap();
            let j = station(&d).get(&format!("/api/v1/jobs/{job}")).await;
            assert_eq!(j["warnings"], json!([]), "{job} fell back: {j}");
            let log = j["log"].to_string();
            assert!(
                log.contains(&format!("procedure {procedure}: bench time")),
                "{log}"
            );
            bench_time
                .entry(procedure)
                .or_default()
                .push(j["bench_time_s"].as_f64().unwrap());
            let v = station(&d)
                .get(&format!("/api/v1/jobs/{job}/verdict"))
                .await;
            // Traceability: the bench's calibration the values were judged with.
            let t = &v["measurements"][0]["traceability"]["bench_calibration"];
            assert_eq!(t["state"], "in_calibration", "{v}");
            assert_eq!(t["procedure"], *procedure, "{v}");
            assert_eq!(t["reference_bench_id"], "virtual-1", "{v}");
            let k0 = v["measurements"][0]["detail"]["parameters"]
                .as_array()
                .unwrap()
                .iter()
                .find(|p| p["name"] == "k0")
                .unwrap()["value"]
                .as_f64()
                .unwrap();
            k0_by_bench
                .entry(format!("{procedure} {}", run["bench_id"].as_str().unwrap()))
                .or_default()
                .push(k0);
        }
    }
    for (procedure, t) in &bench_time {
        let mut t = t.clone();
        t.sort_by(f64::total_cmp);
        eprintln!(
            "{procedure}: bench time median {:.2} s, max {:.2} s over {} runs",
            t[t.len() / 2],
            t[t.len() - 1],
            t.len()
        );
    }

    // The criterion, per quantity and bench pair: production %GRR
    // at most 1.5x the full procedure's and below 10 % of the tolerance.
    // Every bench calibrated from the golden units (decision 0049); the
    // ratios are printed and docs/qc.md states where 1.5x holds.
    let pgrr = |i: usize, name: &str| {
        q(&results[i], name)["grr_percent_of_tolerance"]
            .as_f64()
            .unwrap()
    };
    for pair in [0, 2] {
        for name in ["k0", "keff", "k_at_4mm"] {
            let (full, prod) = (pgrr(pair, name), pgrr(pair + 1, name));
            eprintln!(
                "{} {name}: %GRR full {full:.3} production {prod:.3} ratio {:.2}",
                cases[pair].0,
                prod / full
            );
        }
    }
    for (i, case) in cases.iter().enumerate() {
        for name in ["k0", "keff", "k_at_4mm"] {
            assert!(pgrr(i, name) < 10.0, "{case:?} {name}: {}", pgrr(i, name));
        }
    }
    // The ratio on the benches that differ as real ones do, where decision
    // 0076 judges it (on the noise-only pair K(4 mm) is the sweep length's
    // 1/sqrt(T) limit, about 2x; printed above).
    for name in ["k0", "keff", "k_at_4mm"] {
        let (full, prod) = (pgrr(2, name), pgrr(3, name));
        assert!(
            prod <= 1.5 * full,
            "{:?} {name}: production %GRR {prod:.4} over 1.5x the full procedure's {full:.4}",
            cases[2]
        );
    }
    // Known truth of the different benches: as measured, a clamp heavier by
    // dm reads k0 m / (m + dm), virtual-3 against virtual-4 (m - dm) / (m +
    // dm) = 0.998 (docs/qc.md, "before"); corrected by the benches'
    // calibrations the ratio is 1 within a tenth of that difference.
    let m = 0.05;
    let raw = (m - CLAMP_KG) / (m + CLAMP_KG);
    for procedure in ["full", "production"] {
        let mean = |b: &str| {
            let v = &k0_by_bench[&format!("{procedure} {b}")];
            v.iter().sum::<f64>() / v.len() as f64
        };
        let (same, got) = (
            mean("virtual-1") / mean("virtual-2"),
            mean("virtual-3") / mean("virtual-4"),
        );
        eprintln!(
            "{procedure}: corrected k0 virtual-1 / virtual-2 {same:.5}; virtual-3 / virtual-4 {got:.5} (as measured the clamps give {raw:.5})"
        );
        assert!((same - 1.0).abs() < 2e-4, "{procedure}: {same}");
        assert!((got - 1.0).abs() < 0.1 * (1.0 - raw), "{procedure}: {got}");
    }
}
