//! Issue 32: the long-term test as a daemon job, over the REST API: one
//! bench runs it while the other keeps working; each interval an ordinary
//! measurement with `elapsed_s` and `load_j`; the ageing law stored with the
//! test; bad input named; cancel; a failure limit stops it with its last
//! signals; kill -9 of the daemon five times loses and repeats no interval.
//!
//! Accelerated on the virtual bench: each interval's measurement is
//! simulated sample by sample (~2-3 s wall in a debug build), the 15 min of
//! stimulus between two of them analytically.

use crate::common::{client, paused, post_status, problem, Daemon};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

const BENCHES: &str = "[[benches]]\nid = \"virtual-1\"\nseed = 7\npreset = \"spider_3in\"\n\
                       [[benches]]\nid = \"virtual-2\"\nseed = 1007\npreset = \"spider_3in\"\n";

fn test_body(serial: &str, intervals: usize) -> Value {
    json!({
        "measurement": {"part": {"serial": serial}, "bench": "virtual-1", "preset": "spider_3in",
                        "target_xpeak_m": 0.006},
        "duration_s": 900.0 * (intervals - 1) as f64,
        "interval_s": 900.0,
        "stimulus": {"excursion_m": 0.0053},
    })
}

async fn get(c: &reqwest::Client, d: &Daemon, path: &str) -> Value {
    let r = c.get(d.url(path)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "{path}");
    r.json().await.unwrap()
}

/// A test whose stimulus is `stim` is refused (422) with an error naming
/// `field`, its message containing `why` ("": any message).
async fn stimulus_refused(c: &reqwest::Client, d: &Daemon, stim: &Value, field: &str, why: &str) {
    let mut b = test_body("LT-STIMULUS-BAD", 3);
    b["stimulus"] = stim.clone();
    let r = c
        .post(d.url("/api/v1/long-term-tests"))
        .json(&b)
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    assert!(
        p["errors"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["field"] == field && e["message"].as_str().unwrap().contains(why)),
        "{stim}: {field} ({why}) not named: {p}"
    );
}

async fn submit(c: &reqwest::Client, d: &Daemon, body: &Value) -> String {
    let r = c
        .post(d.url("/api/v1/long-term-tests"))
        .json(body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let loc = r.headers()["location"].to_str().unwrap().to_string();
    let j: Value = r.json().await.unwrap();
    let id = j["id"].as_str().unwrap().to_string();
    assert_eq!(loc, format!("/api/v1/long-term-tests/{id}"));
    assert_eq!(j["request"]["type"], "long_term", "{j}");
    id
}

async fn wait_test(
    c: &reqwest::Client,
    d: &Daemon,
    id: &str,
    timeout: Duration,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let t = Instant::now();
    loop {
        let v = get(c, d, &format!("/api/v1/long-term-tests/{id}")).await;
        if done(&v) {
            return v;
        }
        assert!(t.elapsed() < timeout, "timed out: {v}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn terminal(v: &Value) -> bool {
    crate::common::terminal(v["job"]["state"].as_str().unwrap_or(""))
}

fn loads(v: &Value) -> Vec<f64> {
    v["intervals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| i["load_j"].as_f64().unwrap())
        .collect()
}

/// Indices 0..n, each once, and every interval an ordinary stored measurement.
async fn check_intervals(c: &reqwest::Client, d: &Daemon, v: &Value, n: usize) {
    let iv = v["intervals"].as_array().unwrap();
    let idx: Vec<u64> = iv.iter().map(|i| i["index"].as_u64().unwrap()).collect();
    assert_eq!(idx, (0..n as u64).collect::<Vec<_>>(), "{v}");
    for i in iv {
        let mid = i["measurement_id"].as_str().unwrap();
        let m = get(c, d, &format!("/api/v1/measurements/{mid}")).await;
        let meta = &m["measurement"]["meta"];
        assert_eq!(meta["elapsed_s"], i["elapsed_s"], "{m}");
        assert_eq!(meta["load_j"], i["load_j"]);
        assert_eq!(meta["accelerated"], true);
        assert_eq!(m["measurement"]["job_id"], v["job"]["id"]);
        assert!(m["small_signal"]["k0_n_per_m"].as_f64().unwrap() > 0.0);
        assert_eq!(
            i["elapsed_s"].as_f64().unwrap(),
            900.0 * i["index"].as_f64().unwrap()
        );
    }
    // The job lists every interval's measurement once.
    let mids: Vec<&str> = iv
        .iter()
        .map(|i| i["measurement_id"].as_str().unwrap())
        .collect();
    let job_mids: Vec<&str> = v["job"]["measurement_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    let mut a = mids.clone();
    let mut b = job_mids.clone();
    a.sort();
    b.sort();
    assert_eq!(a, b);
}

#[tokio::test]
async fn a_long_term_test_runs_as_a_job_while_the_other_bench_works() {
    let d = Daemon::start(BENCHES);
    let c = client();
    // Bad input: problem+json naming the field.
    for (patch, field) in [
        (
            json!({"interval_s": 1800.0, "duration_s": 900.0}),
            "interval_s",
        ),
        (
            json!({"stimulus": {"excursion_m": -0.001}}),
            "stimulus.excursion_m",
        ),
        (json!({"interval_s": 10.0}), "interval_s"),
        (
            json!({"stimulus": {"excursion_m": 0.005, "on_s": 60.0}}),
            "stimulus.off_s",
        ),
    ] {
        let mut body = test_body("LT-BAD", 3);
        for (k, v) in patch.as_object().unwrap() {
            body[k] = v.clone();
        }
        let r = c
            .post(d.url("/api/v1/long-term-tests"))
            .json(&body)
            .send()
            .await
            .unwrap();
        let p = problem(r, 422).await;
        let fields: Vec<&str> = p["errors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["field"].as_str().unwrap())
            .collect();
        assert!(fields.contains(&field), "{field} not named: {p}");
    }

    let n = 9;
    let id = submit(&c, &d, &test_body("LT-1", n)).await;
    // Running, with progress and the time left.
    let v = wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        v["intervals"].as_array().unwrap().len() >= 2 || terminal(v)
    })
    .await;
    assert_eq!(v["job"]["state"], "running", "{v}");
    assert_eq!(v["intervals_planned"], n);
    assert_eq!(v["accelerated"], true);
    let p = v["job"]["progress"].as_f64().unwrap();
    assert!(p > 0.0 && p < 1.0, "{v}");
    assert!(v["job"]["eta_s"].as_f64().unwrap() > 0.0, "{v}");
    // The other bench keeps working meanwhile.
    let r: Value = c
        .post(d.url("/api/v1/jobs"))
        .json(&json!({"part": {"serial": "SN-OTHER"}, "bench": "virtual-2"}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let other = r["id"].as_str().unwrap().to_string();
    let o = crate::common::wait_job(
        &c,
        &d,
        &other,
        Duration::from_secs(120),
        crate::common::terminal,
    )
    .await;
    assert_eq!(o["state"], "succeeded", "{o}");

    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    assert_eq!(v["job"]["progress"], 1.0);
    // The other job started before the test ended: they ran side by side.
    assert!(
        o["started_at"].as_str().unwrap() < v["job"]["finished_at"].as_str().unwrap(),
        "{o} {v}"
    );
    check_intervals(&c, &d, &v, n).await;
    // The load grows with every interval.
    let e = loads(&v);
    assert_eq!(e[0], 0.0);
    assert!(e.windows(2).all(|w| w[1] > w[0]), "{e:?}");
    // The fitted law is stored with the test, with standard errors.
    let doc = &v["state"]["document"];
    let law = &doc["law"];
    assert_eq!(law["axis"], "load_j", "{doc}");
    assert_eq!(law["intervals_used"], n);
    for k in ["k_inf_n_per_m", "break_in_k_n_per_m", "fatigue_k_n_per_m"] {
        assert!(law[k]["value"].as_f64().unwrap().is_finite(), "{law}");
        assert!(law[k]["se"].as_f64().unwrap() > 0.0, "{law}");
    }
    assert_eq!(doc["intervals"].as_array().unwrap().len(), n);
    assert_eq!(doc["prediction"]["elapsed_s"], 2.0 * 900.0 * (n - 1) as f64);
    // The part softened near rest: K(0) of the last interval below the first
    // by about the part's break-in (150 N/m) and some fatigue.
    let k0 = |i: usize| doc["intervals"][i]["k0_n_per_m"].as_f64().unwrap();
    let drop = k0(0) - k0(n - 1);
    assert!(
        drop > 150.0 && drop < 500.0,
        "K(0) fell by {drop} N/m: {doc}"
    );
    law_curves_follow_the_law_and_end_at_the_prediction(doc, n);
    assert_eq!(v["events"], json!([]), "no pause, resumption or failure");
    // The station's list of tests has it, finished, with its counts.
    let list = get(&c, &d, "/api/v1/long-term-tests").await;
    let item = list["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["job"]["id"] == json!(id))
        .unwrap_or_else(|| panic!("{id} not listed: {list}"));
    assert_eq!(item["intervals_done"], n);
    assert_eq!(item["intervals_planned"], n);
    assert_eq!(item["job"]["state"], "succeeded");
    assert_eq!(item["duration_s"], 900.0 * (n - 1) as f64);
    assert_eq!(item["law_validity"], law["validity"]);
    let r = c
        .get(d.url("/api/v1/long-term-tests?limit=0"))
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    assert_eq!(p["errors"][0]["field"], "limit", "{p}");
    offline_equals_online(&c, &d, &v).await;
    the_report_prints_the_documents_numbers(&c, &d, &v, n).await;
    // The series as CSV.
    let csv = c
        .get(d.url(&format!("/api/v1/long-term-tests/{id}/series.csv")))
        .send()
        .await
        .unwrap();
    assert_eq!(csv.status().as_u16(), 200);
    assert!(csv.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/csv"));
    let text = csv.text().await.unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), n + 1, "{text}");
    assert!(lines[0].starts_with("index,elapsed_s,load_j,k0_n_per_m"));
    let last: Vec<&str> = lines[n].split(',').collect();
    assert_eq!(last[1].parse::<f64>().unwrap(), 900.0 * (n - 1) as f64);
    assert_eq!(last[2].parse::<f64>().unwrap(), e[n - 1]);
    assert_eq!(last[3].parse::<f64>().unwrap(), k0(n - 1));
    // No failure: no last signals.
    assert!(v.get("last_signals").is_none(), "{v}");
    let r = c
        .get(d.url(&format!("/api/v1/long-term-tests/{id}/last-signals.wav")))
        .send()
        .await
        .unwrap();
    problem(r, 404).await;
    // An ordinary job is not a long-term test.
    let r = c
        .get(d.url(&format!("/api/v1/long-term-tests/{other}")))
        .send()
        .await
        .unwrap();
    problem(r, 404).await;
}

#[tokio::test]
async fn a_failure_limit_stops_the_test_names_it_and_keeps_the_last_signals() {
    let d = Daemon::start(BENCHES);
    let c = client();
    // spider_3in loses ~150 N/m (~10 %) of its K(0) to break-in in the
    // first interval: a 5 % limit is reached at interval 1.
    let mut body = test_body("LT-FAIL", 6);
    body["failure_limits"] = json!({"k0_change_percent": 5.0});
    let id = submit(&c, &d, &body).await;
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "failed", "{v}");
    let p = &v["job"]["problem"];
    assert_eq!(p["type"], "/problems/failure-limit", "{p}");
    assert!(
        p["detail"]
            .as_str()
            .unwrap()
            .contains("failure limit `k0_change_percent` at interval 1"),
        "{p}"
    );
    let f = &v["state"]["failure"];
    assert_eq!(f["limit"], "k0_change_percent", "{v}");
    assert_eq!(f["interval"], 1);
    assert!(f["value"].as_f64().unwrap() < -5.0, "{f}");
    assert_eq!(f["bound"], 5.0);
    assert_eq!(v["intervals"].as_array().unwrap().len(), 2);
    // The last 10 s of the signals, downloadable.
    let url = v["last_signals"].as_str().unwrap();
    let r = c.get(d.url(url)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let wav = r.bytes().await.unwrap();
    let h = hound::WavReader::new(std::io::Cursor::new(wav.to_vec())).unwrap();
    let spec = h.spec();
    let seconds = h.duration() as f64 / spec.sample_rate as f64;
    assert!((seconds - 10.0).abs() < 1e-3, "{seconds} s");
    assert!(spec.channels >= 2);
    // The printable report names the limit that stopped it, says there is
    // no law (two intervals), and prints both intervals' K(0).
    let id = v["job"]["id"].as_str().unwrap();
    let page = report_page(&c, &d, id).await;
    let failure = between(&page, "<td id=\"failure\">", "</td>");
    assert!(
        failure.contains("k0_change_percent") && failure.contains("at interval 1"),
        "{failure}"
    );
    assert!(between(&page, "<td id=\"problem\">", "</td>").contains("failure limit"));
    assert!(
        page.contains("<p id=\"no-law\" data-state=\"none\">No law"),
        "{page}"
    );
    assert!(!page.contains("id=\"law-table\""), "no law, no law table");
    assert!(page.contains("<tr data-kind=\"failure\" class=\"fail\">"));
    let ivs = v["state"]["document"]["intervals"].as_array().unwrap();
    for (k, iv) in ivs.iter().enumerate() {
        let row = between(&page, &format!("<tr data-index=\"{k}\">"), "</tr>");
        let mid = v["intervals"][k]["measurement_id"].as_str().unwrap();
        let cell = k0_cell(&c, &d, row, mid).await;
        printed_equals(
            cell,
            "N/mm",
            iv["k0_n_per_m"].as_f64().unwrap() / 1e3,
            &format!("K(0) of interval {k}"),
        );
    }
}

/// The K(0) cell of an interval's row without its state mark, which must be
/// the measurement's own state of K(0): none when valid, else " (STATE)".
async fn k0_cell<'a>(c: &reqwest::Client, d: &Daemon, row: &'a str, mid: &str) -> &'a str {
    let cell = between(row, "<td class=\"num k0\">", "</td>");
    let m = get(c, d, &format!("/api/v1/measurements/{mid}")).await;
    let state = m["small_signal"]["validity"]["k0_n_per_m"]["state"]
        .as_str()
        .unwrap();
    if state == "valid" {
        assert!(!cell.contains('('), "{cell}: K(0) is valid");
        cell
    } else {
        cell.strip_suffix(&format!(" ({})", state.replace('_', " ").to_uppercase()))
            .unwrap_or_else(|| panic!("{cell}: K(0) is {state}"))
    }
}

/// The text between `a` (its first occurrence) and the next `b`.
fn between<'a>(s: &'a str, a: &str, b: &str) -> &'a str {
    let i = s.find(a).unwrap_or_else(|| panic!("{a} not in the page")) + a.len();
    let j = s[i..].find(b).unwrap_or_else(|| panic!("no {b} after {a}"));
    &s[i..i + j]
}

/// A printed "value ± error unit" (rounded to the error: the value's last
/// printed digit is the error's second significant one) equals `want` to
/// half its last digit; returns the printed value and error.
fn printed_equals(cell: &str, unit: &str, want: f64, what: &str) -> (f64, f64) {
    let t = cell
        .strip_suffix(&format!(" {unit}"))
        .unwrap_or_else(|| panic!("{what}: '{cell}' does not end in {unit}"));
    let (v, e) = t
        .split_once(" \u{b1} ")
        .unwrap_or_else(|| panic!("{what}: '{cell}' has no \u{b1}"));
    let decimals = v.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
    assert_eq!(
        decimals,
        e.split_once('.').map_or(0, |(_, d)| d.len()) as i32,
        "{what}: '{cell}': the value to the error's place"
    );
    let (pv, pe): (f64, f64) = (v.parse().unwrap(), e.parse().unwrap());
    let half = 0.5 * 10f64.powi(-decimals) * (1.0 + 1e-9);
    assert!(
        (pv - want).abs() <= half,
        "{what}: printed {v}, the document's {want} (to {half})"
    );
    (pv, pe)
}

async fn report_page(c: &reqwest::Client, d: &Daemon, id: &str) -> String {
    let r = c
        .get(d.url(&format!("/api/v1/long-term-tests/{id}/report.html")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let ct = r.headers()["content-type"].to_str().unwrap().to_string();
    assert!(ct.starts_with("text/html"), "{ct}");
    let csp = r.headers()["content-security-policy"]
        .to_str()
        .unwrap()
        .to_string();
    assert_eq!(csp, "default-src 'none'; style-src 'unsafe-inline'");
    let page = r.text().await.unwrap();
    // Self-contained: nothing runs, nothing is loaded.
    assert!(!page.contains("<script") && !page.contains("src=\"") && !page.contains("href=\""));
    page
}

/// Issue 32, decision 0131: the printable report of a finished test prints
/// the numbers of the API's document (K(0) of each interval and the law's
/// stiffness parameters, each rounded to its standard error as printed), its
/// prediction, one K(x) curve per interval, the law's curve and band on the
/// time plots, every measurement id; an unknown test is a 404.
async fn the_report_prints_the_documents_numbers(
    c: &reqwest::Client,
    d: &Daemon,
    v: &Value,
    n: usize,
) {
    let id = v["job"]["id"].as_str().unwrap();
    let page = report_page(c, d, id).await;
    let doc = &v["state"]["document"];
    let f = |x: &Value| x.as_f64().unwrap();
    let ivs = doc["intervals"].as_array().unwrap();
    assert_eq!(ivs.len(), n);
    for (k, iv) in ivs.iter().enumerate() {
        let row = between(&page, &format!("<tr data-index=\"{k}\">"), "</tr>");
        let mid = v["intervals"][k]["measurement_id"].as_str().unwrap();
        let cell = k0_cell(c, d, row, mid).await;
        let (_, se) = printed_equals(
            cell,
            "N/mm",
            f(&iv["k0_n_per_m"]) / 1e3,
            &format!("K(0) of interval {k}"),
        );
        let want_se = f(&iv["k0_se_n_per_m"]) / 1e3;
        assert!(
            (se - want_se).abs() <= 0.05 * want_se,
            "interval {k}: se {se} vs {want_se}"
        );
        // Test time and load as the document says them.
        assert!(
            row.contains(&format!("{} h", f(&iv["elapsed_s"]) / 3600.0)),
            "{row}"
        );
        assert!(row.contains(mid), "{row}");
        assert!(
            between(&page, "<td class=\"mono\" id=\"measurement-ids\">", "</td>").contains(mid)
        );
    }
    // A marked value's reason is printed under the table.
    assert_eq!(
        page.contains("<p id=\"interval-reasons\""),
        between(&page, "<table id=\"interval-table\">", "</table>").contains(" (UNRELIABLE)"),
    );
    // The law: its state and its stiffness parameters, rounded to their errors.
    let law = &doc["law"];
    let state = law["validity"]["state"].as_str().unwrap();
    assert!(
        page.contains(&format!("<p id=\"law-state\" data-state=\"{state}\">")),
        "{page}"
    );
    for (key, field) in [
        ("k_inf", "k_inf_n_per_m"),
        ("break_in_k", "break_in_k_n_per_m"),
        ("fatigue_k", "fatigue_k_n_per_m"),
    ] {
        let row = between(&page, &format!("<tr id=\"law-{key}\""), "</tr>");
        let cell = between(row, "<td class=\"num\">", "</td>");
        let (_, se) = printed_equals(cell, "N/mm", f(&law[field]["value"]) / 1e3, field);
        let want_se = f(&law[field]["se"]) / 1e3;
        assert!(
            (se - want_se).abs() <= 0.05 * want_se,
            "{field}: se {se} vs {want_se}"
        );
        assert_eq!(row.contains("NOT VALID"), state != "valid", "{row}");
    }
    // The prediction and its band.
    let p = &doc["prediction"];
    printed_equals(
        between(&page, "<td class=\"num\" id=\"prediction-k0\">", "</td>"),
        "N/mm",
        f(&p["k0_n_per_m"]) / 1e3,
        "predicted K(0)",
    );
    let band = between(&page, "<td class=\"num\" id=\"prediction-band\">", "</td>");
    let (lo, hi) = band
        .strip_suffix(" N/mm")
        .unwrap()
        .split_once(" \u{2026} ")
        .unwrap();
    for (printed, want) in [
        (lo, f(&p["k0_band_n_per_m"][0])),
        (hi, f(&p["k0_band_n_per_m"][1])),
    ] {
        let x: f64 = printed.parse().unwrap();
        assert!(
            ((x - want / 1e3) / (want / 1e3)).abs() < 1e-4,
            "band {band} vs {p}"
        );
    }
    // One K(x) curve per interval; the time plots: the measured values, the
    // law and its band's two edges.
    let kx = between(&page, "<figure id=\"plot-kx\"", "</figure>");
    assert!(kx.starts_with(&format!(" data-curves=\"{n}\">")), "{kx}");
    assert_eq!(kx.matches("<path ").count(), n, "K(x) curves");
    for plot in ["plot-k0", "plot-keff", "plot-f0"] {
        let svg = between(&page, &format!("<figure id=\"{plot}\">"), "</figure>");
        assert_eq!(
            svg.matches("<path ").count(),
            4,
            "{plot}: measured, law, band low and high"
        );
        assert!(svg.contains("95 % band, low"), "{plot}");
    }
    assert!(page.contains(&format!(
        "<tr><th>test (job) id</th><td class=\"mono\">{id}</td></tr>"
    )));
    // An unknown test is a 404 problem naming it.
    let r = c
        .get(d.url("/api/v1/long-term-tests/nope/report.html"))
        .send()
        .await
        .unwrap();
    let p = problem(r, 404).await;
    assert!(p["detail"].as_str().unwrap().contains("nope"), "{p}");
}

#[tokio::test]
async fn cancel_stops_a_running_long_term_test() {
    let d = Daemon::start(BENCHES);
    let c = client();
    let id = submit(&c, &d, &test_body("LT-CANCEL", 40)).await;
    wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        !v["intervals"].as_array().unwrap().is_empty()
    })
    .await;
    let r = c
        .post(d.url(&format!("/api/v1/jobs/{id}/cancel")))
        .header("content-type", "application/json")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let v = wait_test(&c, &d, &id, Duration::from_secs(120), terminal).await;
    assert_eq!(v["job"]["state"], "cancelled", "{v}");
    let n = v["intervals"].as_array().unwrap().len();
    assert!(n < 40);
    check_intervals(&c, &d, &v, n).await;
}

/// The acceptance: kill -9 of the daemon five times during a test; 0
/// intervals lost or repeated, and the accumulated load continuous within
/// 1 % (against the same test run without a kill by a second daemon with
/// the same configuration).
#[tokio::test]
async fn kill_9_five_times_during_a_test_loses_and_repeats_no_interval() {
    // Killed after intervals 1 to 5 (each kill after one more stored
    // interval), then three intervals after the last resumption; 12
    // intervals and kills after 2, 4, ... 10 before the page's browser test
    // paid for its ~16 s with these ~8 simulated measurements.
    let n = 8;
    let mut d = Daemon::start(BENCHES);
    let tmp = d.take_dir().unwrap();
    let reference = Daemon::start(BENCHES);
    let c = client();
    let id = submit(&c, &d, &test_body("LT-K9", n)).await;
    let ref_id = submit(&c, &reference, &test_body("LT-K9", n)).await;
    let mut kills = 0;
    for after in [1, 2, 3, 4, 5] {
        let v = wait_test(&c, &d, &id, Duration::from_secs(300), |v| {
            v["intervals"].as_array().unwrap().len() >= after || terminal(v)
        })
        .await;
        assert_eq!(v["job"]["state"], "running", "{v}");
        d.kill9();
        kills += 1;
        d = Daemon::start_in(tmp.path(), BENCHES);
        // Resumed, not interrupted.
        let j = get(&c, &d, &format!("/api/v1/jobs/{id}")).await;
        assert!(
            matches!(j["state"].as_str(), Some("queued" | "running")),
            "{j}"
        );
    }
    assert_eq!(kills, 5);
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    check_intervals(&c, &d, &v, n).await;
    let resumed = v["job"]["log"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l.as_str().unwrap().starts_with("resumed after interval"))
        .count();
    assert_eq!(resumed, 5, "{v}");
    let res = v["state"]["resumptions"].as_array().unwrap();
    assert_eq!(res.len(), 5, "{v}");
    // Each resumption carried on from a stored interval, never behind one.
    for (r, after) in res.iter().zip([1, 2, 3, 4, 5]) {
        assert!(r["intervals_done"].as_u64().unwrap() >= after, "{r}");
    }
    // The test's events list each resumption, at the test time of the
    // interval it resumed after.
    let restarted: Vec<&Value> = v["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "restarted")
        .collect();
    assert_eq!(restarted.len(), 5, "{v}");
    for (e, r) in restarted.iter().zip(res) {
        let done = r["intervals_done"].as_u64().unwrap();
        assert_eq!(e["interval"], done, "{e}");
        assert_eq!(e["elapsed_s"], 900.0 * (done - 1) as f64, "{e}");
    }
    // The part's measurements: exactly one per interval.
    let ms = get(&c, &d, "/api/v1/parts/LT-K9/measurements?limit=100").await;
    assert_eq!(ms["items"].as_array().unwrap().len(), n);
    let r = wait_test(&c, &reference, &ref_id, Duration::from_secs(300), terminal).await;
    assert_eq!(r["job"]["state"], "succeeded", "{r}");
    let (e, e_ref) = (loads(&v), loads(&r));
    for (i, (a, b)) in e.iter().zip(&e_ref).enumerate().skip(1) {
        assert!(
            (a / b - 1.0).abs() <= 0.01,
            "interval {i}: load {a} J after five kills, {b} J without: {e:?} {e_ref:?}"
        );
    }
    let last = |v: &Value| v["state"]["load_j"].as_f64().unwrap();
    assert!((last(&v) / last(&r) - 1.0).abs() <= 0.01);
    println!(
        "kill -9 x5: loads {e:?}, reference {e_ref:?}; largest deviation {:.2e}",
        e.iter()
            .zip(&e_ref)
            .skip(1)
            .map(|(a, b)| (a / b - 1.0).abs())
            .fold(0.0, f64::max)
    );
    drop(d);
    drop(tmp);
}

/// spider_3in with its preset's ageing and a defect: past `onset_load_j`
/// the spider tears and `fraction` of its stiffness goes over the whole
/// stroke (`physics::ageing::Collapse`).
fn torn_part() -> springbench::physics::PartSpec {
    let mut p = springbench::physics::preset("spider_3in").unwrap();
    p.ageing.as_mut().unwrap().collapse = Some(springbench::physics::ageing::Collapse {
        onset_load_j: 12_000.0,
        load_scale_j: 6_000.0,
        fraction: 0.7,
    });
    p
}

fn torn_body(serial: &str, intervals: usize, hold: &str, limits: Value) -> Value {
    let mut body = test_body(serial, intervals);
    let m = body["measurement"].as_object_mut().unwrap();
    m.remove("preset");
    m.insert(
        "part_spec".into(),
        serde_json::to_value(torn_part()).unwrap(),
    );
    body["stimulus"]["hold"] = json!(hold);
    body["failure_limits"] = limits;
    body
}

/// The last signals of a failed test: (seconds, sample rate, displacement in m).
async fn last_signals(c: &reqwest::Client, d: &Daemon, v: &Value) -> (f64, f64, Vec<f64>) {
    let url = v["last_signals"].as_str().expect("last signals stored");
    let r = c.get(d.url(url)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let wav = r.bytes().await.unwrap();
    let mut h = hound::WavReader::new(std::io::Cursor::new(wav.to_vec())).unwrap();
    let spec = h.spec();
    assert_eq!(spec.sample_format, hound::SampleFormat::Float);
    let fs = spec.sample_rate as f64;
    let ch = spec.channels as usize;
    let x: Vec<f64> = h
        .samples::<f32>()
        .step_by(ch)
        .map(|s| s.unwrap() as f64)
        .collect();
    (x.len() as f64 / fs, fs, x)
}

/// Issue 32, failure: a part that tears during the test (a new defect, not
/// ageing: its stiffness collapses past a load) stops the test at the
/// interval whose true K(0) change crosses the bound, naming the limit.
#[tokio::test]
async fn a_part_that_collapses_stops_the_test_at_the_interval_its_truth_crosses_the_k0_limit() {
    let d = Daemon::start(BENCHES);
    let c = client();
    let bound = 40.0;
    let id = submit(
        &c,
        &d,
        &torn_body(
            "LT-TORN",
            12,
            "excursion",
            json!({"k0_change_percent": bound}),
        ),
    )
    .await;
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "failed", "{v}");
    let f = &v["state"]["failure"];
    assert_eq!(f["limit"], "k0_change_percent", "{v}");
    let at = f["interval"].as_u64().unwrap() as usize;
    assert!(v["job"]["problem"]["detail"]
        .as_str()
        .unwrap()
        .contains(&format!(
            "failure limit `k0_change_percent` at interval {at}"
        )));
    // The truth at each interval's load: the part's law with its tear.
    let part = torn_part();
    let a = part.ageing.unwrap();
    let k0_new = part.k_coeffs_si[0];
    let e = loads(&v);
    assert_eq!(e.len(), at + 1, "{v}");
    let truth: Vec<f64> = e
        .iter()
        .map(|&l| 100.0 * (a.k0_n_per_m(k0_new, l) / k0_new - 1.0))
        .collect();
    // The tear did it: the sound part's law alone stays far from the bound.
    let mut sound = a;
    sound.collapse = None;
    let sound_change = 100.0 * (sound.k0_n_per_m(k0_new, e[at]) / k0_new - 1.0);
    assert!(sound_change > -0.5 * bound, "{sound_change}");
    assert!(a.collapse_fraction(e[at]) > 0.1, "{e:?}");
    // Stopped at the first interval whose true change is beyond the bound.
    assert!(truth[at] < -bound, "{truth:?}");
    assert!(truth[..at].iter().all(|t| *t > -bound), "{truth:?}");
    // The measured change follows the truth within 3 points.
    let measured = f["value"].as_f64().unwrap();
    assert!(
        (measured - truth[at]).abs() < 3.0,
        "measured {measured:.1} %, true {:.1} %",
        truth[at]
    );
    assert_eq!(f["bound"], bound);
    let (secs, _, x) = last_signals(&c, &d, &v).await;
    assert!((secs - 10.0).abs() < 1e-3, "{secs}");
    assert!(x.iter().any(|x| x.abs() > 1e-3));
    println!(
        "collapse: stopped at interval {at} (load {:.0} J), K(0) {measured:+.1} % measured, {:+.1} % true; true changes {truth:?}",
        e[at], truth[at]
    );
}

/// Issue 32, failure: the same tear under a stimulus held at a drive level:
/// the excursion runs away; the test stops during the stimulus, names
/// `xpeak_runaway_percent`, and stores the last 10 s of that stimulus.
#[tokio::test]
async fn an_excursion_running_away_under_a_held_drive_stops_the_test_with_its_last_10_s() {
    use springbench::physics::ageing as law;
    let d = Daemon::start(BENCHES);
    let c = client();
    let id = submit(
        &c,
        &d,
        &torn_body("LT-RUN", 12, "drive", json!({"k0_change_percent": 90.0})),
    )
    .await;
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "failed", "{v}");
    let f = &v["state"]["failure"];
    assert_eq!(f["limit"], "xpeak_runaway_percent", "{v}");
    let bound = f["bound"].as_f64().unwrap();
    assert_eq!(bound, 30.0, "the default");
    let at = f["interval"].as_u64().unwrap() as usize;
    assert!(v["job"]["problem"]["detail"]
        .as_str()
        .unwrap()
        .contains(&format!(
            "failure limit `xpeak_runaway_percent` at interval {at}"
        )));
    // It stopped in the stimulus before interval `at`: that one was never measured.
    assert_eq!(v["intervals"].as_array().unwrap().len(), at, "{v}");
    let at_s = f["at_s"].as_f64().unwrap();
    assert!(
        at_s > 900.0 * (at - 1) as f64 && at_s <= 900.0 * at as f64,
        "{at_s}"
    );
    // The truth: the part held at the velocity amplitude 5.3 mm had at its resonance when new,
    // from the state after the last measurement, in the runner's 60 s steps.
    let part = torn_part();
    let x0 = 0.0053;
    let vel = law::velocity_at_excursion_m_per_s(&part, 0.0, x0);
    let st = &v["state"];
    let (mut t, mut e) = (
        st["clock_s"].as_f64().unwrap(),
        st["load_j"].as_f64().unwrap(),
    );
    let end = 900.0 * at as f64;
    let mut crossed = None;
    while t < end {
        let step = (end - t).min(60.0);
        e = law::apply_sine_at_velocity(&part, e, vel, step);
        t += step;
        let growth = 100.0 * (law::excursion_at_velocity_m(&part, e, vel) / x0 - 1.0);
        if growth > bound {
            crossed = Some((t, growth, e));
            break;
        }
    }
    let (t_true, growth_true, e_true) = crossed.expect("the truth crosses the bound");
    assert!((at_s - t_true).abs() < 1e-6, "{at_s} {t_true}");
    let growth = f["value"].as_f64().unwrap();
    assert!(
        (growth - growth_true).abs() < 1e-6,
        "{growth} {growth_true}"
    );
    // The tear did it: the sound part at that load would hardly have moved.
    let mut sound = part.clone();
    sound.ageing.as_mut().unwrap().collapse = None;
    let vs = law::velocity_at_excursion_m_per_s(&sound, 0.0, x0);
    let sound_growth = 100.0 * (law::excursion_at_velocity_m(&sound, e_true, vs) / x0 - 1.0);
    assert!(sound_growth < 10.0, "{sound_growth}");
    // The last 10 s: the stimulus then, simulated sample by sample: a sine
    // at the torn part's resonance at the runaway excursion.
    let (secs, fs, x) = last_signals(&c, &d, &v).await;
    assert!((secs - 10.0).abs() < 1e-3, "{secs}");
    let x_true = x0 * (1.0 + growth_true / 100.0);
    let tail = &x[x.len() / 2..];
    let peak = tail.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    // Its drive is levelled by probes on the upper branch, where the
    // excursion barely follows the drive: within 25 %, and beyond the bound.
    assert!(
        (peak / x_true - 1.0).abs() < 0.25,
        "{peak} against {x_true}"
    );
    assert!(peak > (1.0 + bound / 100.0) * x0, "{peak}");
    let ups = tail
        .windows(2)
        .filter(|w| w[0] < 0.0 && w[1] >= 0.0)
        .count();
    let f_meas = ups as f64 / (tail.len() as f64 / fs);
    let f_true = law::resonance_hz(&part, e_true, x_true);
    assert!((f_meas / f_true - 1.0).abs() < 0.02, "{f_meas} {f_true}");
    println!(
        "runaway: stopped at {at_s} s before interval {at}, excursion {:+.1} % ({:.2} mm; sound part {sound_growth:+.1} %), last 10 s peak {:.2} mm at {f_meas:.1} Hz (true {f_true:.1} Hz)",
        growth, 1e3 * x_true, 1e3 * peak
    );
}

/// Issue 32, offline equals online: the test's intervals exported through
/// the API (each measurement's meta and its pre.wav and main.wav, one
/// recording set per directory) and read by `springbench ageing DIR` give
/// the daemon's stored fit: the same intervals, law and prediction.
async fn offline_equals_online(c: &reqwest::Client, d: &Daemon, v: &Value) {
    let dir = tempfile::tempdir().unwrap();
    for i in v["intervals"].as_array().unwrap() {
        let mid = i["measurement_id"].as_str().unwrap();
        let sub = dir
            .path()
            .join(format!("{:03}", i["index"].as_u64().unwrap()));
        std::fs::create_dir_all(&sub).unwrap();
        let m = get(c, d, &format!("/api/v1/measurements/{mid}")).await;
        std::fs::write(
            sub.join("meta.json"),
            serde_json::to_vec(&m["measurement"]["meta"]).unwrap(),
        )
        .unwrap();
        for f in ["pre.wav", "main.wav"] {
            let r = c
                .get(d.url(&format!("/api/v1/measurements/{mid}/recordings/{f}")))
                .send()
                .await
                .unwrap();
            assert_eq!(r.status().as_u16(), 200, "{f}");
            std::fs::write(sub.join(f), r.bytes().await.unwrap()).unwrap();
        }
    }
    let online = &v["state"]["document"];
    let predict_s = online["prediction"]["elapsed_s"].as_f64().unwrap();
    let offline = crate::ageing::ageing_json(dir.path(), predict_s);
    let mut worst = (0.0f64, String::new());
    let mut cmp = |name: String, a: &Value, b: &Value| {
        let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
        let rel = if a == b { 0.0 } else { ((a - b) / b).abs() };
        if rel >= worst.0 {
            worst = (rel, format!("{name}: offline {a}, online {b}"));
        }
    };
    let (lo, ln) = (&offline["law"], &online["law"]);
    assert_eq!(lo["axis"], ln["axis"]);
    assert_eq!(lo["validity"], ln["validity"], "{lo} {ln}");
    assert_eq!(lo["intervals_used"], ln["intervals_used"]);
    for k in [
        "k_inf_n_per_m",
        "break_in_k_n_per_m",
        "fatigue_k_n_per_m",
        "break_in_load_j",
        "fatigue_load_j",
    ] {
        for p in ["value", "se"] {
            cmp(format!("law.{k}.{p}"), &lo[k][p], &ln[k][p]);
        }
    }
    for k in ["k0_n_per_m", "k0_se_n_per_m"] {
        cmp(
            format!("prediction.{k}"),
            &offline["prediction"][k],
            &online["prediction"][k],
        );
    }
    let (io, on) = (
        offline["intervals"].as_array().unwrap(),
        online["intervals"].as_array().unwrap(),
    );
    assert_eq!(io.len(), on.len());
    for (i, (a, b)) in io.iter().zip(on).enumerate() {
        assert_eq!(a["elapsed_s"], b["elapsed_s"]);
        assert_eq!(a["load_j"], b["load_j"]);
        cmp(
            format!("intervals[{i}].k0_n_per_m"),
            &a["k0_n_per_m"],
            &b["k0_n_per_m"],
        );
    }
    println!(
        "offline against online: largest relative difference {:.1e} ({})",
        worst.0, worst.1
    );
    assert!(worst.0 <= 1e-6, "{}", worst.1);
}

/// Issue 32, faults: a full disk during a test (a real tmpfs, filled below
/// `min_free_bytes`) pauses it with the reason in the job's `step`, and it
/// resumes when space returns: every interval measured once, none lost.
/// Needs root to mount; otherwise it says so and checks nothing.
#[tokio::test]
async fn a_full_disk_pauses_the_test_with_the_reason_and_it_resumes_when_space_returns() {
    use std::io::Write;
    let Some(fs) = crate::common::Tmpfs::mount("256m") else {
        return;
    };
    let mnt = fs.path().to_path_buf();
    let min_free = 40_000_000u64;
    let d = Daemon::start_in(&mnt, &format!("min_free_bytes = {min_free}\n{BENCHES}"));
    let c = client();
    let n = 5;
    let id = submit(&c, &d, &test_body("LT-DISK", n)).await;
    wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        !v["intervals"].as_array().unwrap().is_empty() || terminal(v)
    })
    .await;
    // Fill the disk to 10 MB short of the bound: room for the state, not for the test.
    let filler = mnt.join("filler");
    {
        let mut f = std::fs::File::create(&filler).unwrap();
        let block = vec![0u8; 1 << 20];
        loop {
            let st = nix_free(&mnt);
            if st + 10_000_000 < min_free {
                break;
            }
            f.write_all(&block).unwrap();
        }
        f.sync_all().unwrap();
    }
    let v = wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        v["job"]["step"]
            .as_str()
            .is_some_and(|s| s.starts_with("paused"))
            || terminal(v)
    })
    .await;
    assert_eq!(v["job"]["state"], "running", "{v}");
    let step = v["job"]["step"].as_str().unwrap();
    assert!(
        step.contains("disk full") && step.contains("min_free_bytes"),
        "{step}"
    );
    let held = v["intervals"].as_array().unwrap().len();
    assert!(held < n, "{v}");
    // Paused: no interval is measured while the disk stays full.
    tokio::time::sleep(Duration::from_secs(3)).await;
    let still = get(&c, &d, &format!("/api/v1/long-term-tests/{id}")).await;
    assert_eq!(
        still["intervals"].as_array().unwrap().len(),
        held,
        "{still}"
    );
    assert_eq!(still["job"]["state"], "running");
    // Space returns: it resumes and finishes, every interval once.
    std::fs::remove_file(&filler).unwrap();
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    check_intervals(&c, &d, &v, n).await;
    // The pause and its end stay with the test, in test time, and in the job's log.
    let paused_at = 900.0 * held as f64;
    let ev = v["events"].as_array().unwrap();
    let kinds: Vec<&str> = ev.iter().map(|e| e["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["paused", "resumed"], "{v}");
    assert_eq!(ev[0]["elapsed_s"], paused_at);
    assert_eq!(ev[1]["elapsed_s"], paused_at);
    assert!(
        ev[0]["detail"].as_str().unwrap().contains("disk full"),
        "{v}"
    );
    let log: Vec<&str> = v["job"]["log"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l.as_str().unwrap())
        .collect();
    let want = format!("paused at test time {paused_at:.0} s: ");
    assert!(
        log.iter()
            .any(|l| l.starts_with(&want) && l.contains("disk full")),
        "{log:?}"
    );
    assert!(
        log.contains(&format!("resumed at test time {paused_at:.0} s: space returned").as_str()),
        "{log:?}"
    );
    println!("full disk: paused after {held} intervals ({step}); resumed, {n} intervals");
    drop(d);
}

/// The document's curves (the page's plots): K(0)'s curve is the law
/// itself where the load is known (at the intervals), ends at the
/// prediction with its band, and f0's and Keff's fits follow the measured
/// values.
fn law_curves_follow_the_law_and_end_at_the_prediction(doc: &Value, n: usize) {
    let f = |v: &Value| v.as_f64().unwrap();
    let arr = |v: &Value| -> Vec<f64> { v.as_array().unwrap().iter().map(f).collect() };
    let law = &doc["law"];
    let p = |k: &str| f(&law[k]["value"]);
    let k0_law = |e: f64| {
        p("k_inf_n_per_m")
            + p("break_in_k_n_per_m") * (-e / p("break_in_load_j")).exp()
            + p("fatigue_k_n_per_m") * (-e / p("fatigue_load_j")).exp()
    };
    let cur = &doc["curves"];
    let t = arr(&cur["elapsed_s"]);
    let e = arr(&cur["load_j"]);
    assert_eq!(t.len(), 61);
    let t_pred = f(&doc["prediction"]["elapsed_s"]);
    assert_eq!(t[0], 0.0);
    assert_eq!(*t.last().unwrap(), t_pred);
    let curve = |q: &str| {
        cur["curves"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["quantity"] == q)
            .unwrap_or_else(|| panic!("no {q} curve: {cur}"))
            .clone()
    };
    let k0 = curve("k0_n_per_m");
    let (val, lo, hi) = (
        arr(&k0["value"]),
        arr(&k0["band_low"]),
        arr(&k0["band_high"]),
    );
    let rel = |a: f64, b: f64| ((a - b) / b).abs();
    let ivs = doc["intervals"].as_array().unwrap();
    let mut at_intervals = 0;
    for (k, &tk) in t.iter().enumerate() {
        if let Some(iv) = ivs.iter().find(|iv| f(&iv["elapsed_s"]) == tk) {
            // On an interval: its load exactly, and the law's value there.
            assert_eq!(e[k], f(&iv["load_j"]), "load at {tk} s");
            assert!(
                rel(val[k], k0_law(e[k])) < 1e-9,
                "{tk} s: {} vs {}",
                val[k],
                k0_law(e[k])
            );
            at_intervals += 1;
        }
        assert!(lo[k] < val[k] && val[k] < hi[k], "band at {tk} s");
    }
    assert!(at_intervals >= 3, "{at_intervals} grid points on intervals");
    // The load grows on beyond the last interval at the series' mean power.
    assert!(e.windows(2).all(|w| w[1] >= w[0]), "{e:?}");
    let pred = &doc["prediction"];
    assert!(rel(*val.last().unwrap(), f(&pred["k0_n_per_m"])) < 1e-9);
    assert!(rel(*e.last().unwrap(), f(&pred["load_j"])) < 1e-9);
    assert!(rel(*lo.last().unwrap(), f(&pred["k0_band_n_per_m"][0])) < 1e-9);
    assert!(rel(*hi.last().unwrap(), f(&pred["k0_band_n_per_m"][1])) < 1e-9);
    // f0 and Keff fitted on the law's scales: within 1 % of every measured value.
    for (q, key) in [("f0_hz", "f0_hz"), ("keff_n_per_m", "keff_n_per_m")] {
        let c = curve(q);
        let v = arr(&c["value"]);
        for iv in ivs.iter().take(n) {
            let ti = f(&iv["elapsed_s"]);
            if let Some(k) = t.iter().position(|&x| x == ti) {
                assert!(
                    rel(v[k], f(&iv[key])) < 0.01,
                    "{q} at {ti} s: {} vs {}",
                    v[k],
                    iv[key]
                );
            }
        }
    }
}

/// Free bytes of the file system holding `p` (statvfs through `df`).
fn nix_free(p: &std::path::Path) -> u64 {
    let out = std::process::Command::new("df")
        .args(["-B1", "--output=avail"])
        .arg(p)
        .output()
        .unwrap();
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .nth(1)
        .unwrap()
        .trim()
        .parse()
        .unwrap()
}

/// Ambient conditions (decision 0130): an emulated sensor with known
/// values (296.15 K + 0.4 K/h, 45 % − 1.5 %/h of test time) on virtual-1,
/// a hwmon sensor whose file is missing on virtual-2. Each interval
/// stores the sensor's values at its start with their source, in the
/// test's JSON and its CSV (units in the header); a failed reading leaves
/// them out and says why in the log. Entered by hand: 422s naming the
/// field, 404 for an interval not measured, and a value given replaces the
/// sensor's (source `hand`), the other kept.
#[tokio::test]
async fn ambient_conditions_come_from_the_benchs_sensor_or_by_hand() {
    let benches = "[[benches]]\nid = \"virtual-1\"\nseed = 7\npreset = \"spider_3in\"\n\
         [benches.ambient]\nkind = \"emulated\"\ntemperature_k = 296.15\ntemperature_k_per_h = 0.4\n\
         relative_humidity_percent = 45.0\nrelative_humidity_percent_per_h = -1.5\n\
         [[benches]]\nid = \"virtual-2\"\nseed = 1007\npreset = \"spider_3in\"\n\
         [benches.ambient]\nkind = \"hwmon\"\ntemperature_path = \"/nonexistent/temp1_input\"\n";
    let d = Daemon::start(benches);
    let c = client();
    let n = 3;
    let id = submit(&c, &d, &test_body("LT-AMB", n)).await;
    let mut other = test_body("LT-AMB-2", 2);
    other["measurement"]["bench"] = json!("virtual-2");
    let id2 = submit(&c, &d, &other).await;
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    let truth = |t_s: f64| (296.15 + 0.4 * t_s / 3600.0, 45.0 - 1.5 * t_s / 3600.0);
    for iv in v["intervals"].as_array().unwrap() {
        let (t, h) = truth(iv["elapsed_s"].as_f64().unwrap());
        assert!(
            (iv["temperature_k"].as_f64().unwrap() - t).abs() < 1e-9,
            "{iv}"
        );
        assert!(
            (iv["relative_humidity_percent"].as_f64().unwrap() - h).abs() < 1e-9,
            "{iv}"
        );
        assert_eq!(iv["temperature_source"], "sensor");
        assert_eq!(iv["humidity_source"], "sensor");
    }
    let csv = c
        .get(d.url(&format!("/api/v1/long-term-tests/{id}/series.csv")))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (ct, ch) = (col("temperature_k"), col("relative_humidity_percent"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), n);
    for (k, r) in rows.iter().enumerate() {
        let (t, h) = truth(900.0 * k as f64);
        assert!((r[ct].parse::<f64>().unwrap() - t).abs() < 1e-9, "{csv}");
        assert!((r[ch].parse::<f64>().unwrap() - h).abs() < 1e-9, "{csv}");
        assert_eq!(r[col("temperature_source")], "sensor");
    }
    // By hand: bad values are 422s naming the field; never stored.
    let url = |i: &str| {
        d.url(&format!(
            "/api/v1/long-term-tests/{id}/intervals/{i}/ambient"
        ))
    };
    for (body, field) in [
        (json!({"temperature_k": 23.0}), "temperature_k"),
        (json!({"temperature_k": "NaN"}), "temperature_k"),
        (
            json!({"relative_humidity_percent": 100.5}),
            "relative_humidity_percent",
        ),
        (
            json!({"relative_humidity_percent": -3.0}),
            "relative_humidity_percent",
        ),
        (json!({}), "temperature_k"),
        (json!({"temperature_c": 21.0}), "temperature_c"),
    ] {
        let r = c.put(url("1")).json(&body).send().await.unwrap();
        let p = problem(r, 422).await;
        let fields: Vec<&str> = p["errors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["field"].as_str().unwrap())
            .collect();
        assert!(fields.contains(&field), "{body}: {field} not named: {p}");
    }
    for i in ["9", "x"] {
        let r = c
            .put(url(i))
            .json(&json!({"temperature_k": 295.0}))
            .send()
            .await
            .unwrap();
        problem(r, 404).await;
    }
    let r = c
        .put(url("1"))
        .json(&json!({"temperature_k": 294.65}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let iv: Value = r.json().await.unwrap();
    assert_eq!(iv["index"], 1);
    assert_eq!(iv["temperature_k"], 294.65);
    assert_eq!(iv["temperature_source"], "hand");
    // The humidity not given stays the sensor's.
    assert!((iv["relative_humidity_percent"].as_f64().unwrap() - truth(900.0).1).abs() < 1e-9);
    assert_eq!(iv["humidity_source"], "sensor");
    let v = get(&c, &d, &format!("/api/v1/long-term-tests/{id}")).await;
    assert_eq!(v["intervals"][1]["temperature_k"], 294.65, "{v}");
    assert_eq!(v["intervals"][0]["temperature_source"], "sensor");
    // A sensor that cannot be read: no values, and the log says why.
    let v2 = wait_test(&c, &d, &id2, Duration::from_secs(300), terminal).await;
    assert_eq!(v2["job"]["state"], "succeeded", "{v2}");
    for iv in v2["intervals"].as_array().unwrap() {
        assert!(iv["temperature_k"].is_null(), "{iv}");
        assert!(iv["temperature_source"].is_null(), "{iv}");
    }
    let log = v2["job"]["log"].to_string();
    assert!(
        log.contains(
            "interval 0: no ambient conditions stored: ambient sensor /nonexistent/temp1_input"
        ),
        "{log}"
    );
    drop(d);
}

/// Pause and resume by the user (decision 0130): the pause holds (no
/// interval measured, the test clock, the load and the progress stand
/// still), outlives a kill -9 of the daemon (the resumed test stays
/// paused, its pause not recorded twice), resume continues with no
/// interval lost or repeated and the loads of the same test run without a
/// pause; cancel works while paused.
#[tokio::test]
async fn a_user_pause_holds_the_test_across_a_restart_and_resume_continues_it() {
    let n = 5;
    let mut d = Daemon::start(BENCHES);
    let tmp = d.take_dir().unwrap();
    let reference = Daemon::start(BENCHES);
    let c = client();
    let id = submit(&c, &d, &test_body("LT-P", n)).await;
    let ref_id = submit(&c, &reference, &test_body("LT-P", n)).await;
    let mut other = test_body("LT-P-C", 40);
    other["measurement"]["bench"] = json!("virtual-2");
    let id2 = submit(&c, &d, &other).await;
    let lt = |id: &str, what: &str| format!("/api/v1/long-term-tests/{id}/{what}");
    // Resuming a test not paused: 409; unknown tests: 404.
    assert_eq!(post_status(&c, &d, &lt(&id, "resume")).await, 409);
    assert_eq!(post_status(&c, &d, &lt("nope", "pause")).await, 404);
    wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        !v["intervals"].as_array().unwrap().is_empty() || terminal(v)
    })
    .await;
    assert_eq!(post_status(&c, &d, &lt(&id, "pause")).await, 202);
    assert_eq!(post_status(&c, &d, &lt(&id, "pause")).await, 409);
    let v = wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        paused(v) || terminal(v)
    })
    .await;
    assert_eq!(v["job"]["state"], "running", "{v}");
    assert!(v["user_pause"].is_object(), "{v}");
    let held = v["intervals"].as_array().unwrap().len();
    assert!(held < n, "{v}");
    let still = |a: &Value, b: &Value| {
        assert_eq!(
            a["intervals"], b["intervals"],
            "an interval measured while paused"
        );
        assert_eq!(
            a["state"]["clock_s"], b["state"]["clock_s"],
            "the test clock moved"
        );
        assert_eq!(a["state"]["load_j"], b["state"]["load_j"], "the load moved");
        assert_eq!(a["job"]["progress"], b["job"]["progress"]);
        assert!(paused(b), "{b}");
    };
    // The pause holds.
    tokio::time::sleep(Duration::from_secs(3)).await;
    let v2 = get(&c, &d, &format!("/api/v1/long-term-tests/{id}")).await;
    still(&v, &v2);
    // Cancel works while paused (the other bench's test).
    wait_test(&c, &d, &id2, Duration::from_secs(120), |v| {
        !v["intervals"].as_array().unwrap().is_empty() || terminal(v)
    })
    .await;
    assert_eq!(post_status(&c, &d, &lt(&id2, "pause")).await, 202);
    wait_test(&c, &d, &id2, Duration::from_secs(120), |v| {
        paused(v) || terminal(v)
    })
    .await;
    assert_eq!(
        post_status(&c, &d, &format!("/api/v1/jobs/{id2}/cancel")).await,
        202
    );
    let c2 = wait_test(&c, &d, &id2, Duration::from_secs(120), terminal).await;
    assert_eq!(c2["job"]["state"], "cancelled", "{c2}");
    assert!(c2["user_pause"].is_null(), "{c2}");
    assert_eq!(post_status(&c, &d, &lt(&id2, "resume")).await, 409);
    // kill -9 while paused: the test resumes paused, holds, and its pause
    // is one event.
    d.kill9();
    d = Daemon::start_in(tmp.path(), BENCHES);
    let v3 = wait_test(&c, &d, &id, Duration::from_secs(120), |v| {
        (paused(v) && v["job"]["state"] == "running") || terminal(v)
    })
    .await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let v4 = get(&c, &d, &format!("/api/v1/long-term-tests/{id}")).await;
    assert_eq!(v3["intervals"], v["intervals"], "{v3}");
    assert_eq!(v3["state"]["clock_s"], v["state"]["clock_s"]);
    still(&v3, &v4);
    let users = crate::common::user_events;
    // Paused at the next step: after the last measurement's end, before
    // the next interval's start (the stimulus between them is accelerated).
    let u = users(&v4);
    assert_eq!(u.len(), 1, "{v4}");
    assert_eq!(u[0].0, "paused");
    let clock = u[0].1;
    let last_end = v["state"]["clock_s"].as_f64().unwrap();
    assert!(
        clock >= last_end && clock <= 900.0 * held as f64,
        "paused at {clock} s, the last measurement ended at {last_end} s"
    );
    // Resumed: it finishes, every interval once, the loads those of the
    // test run without a pause.
    assert_eq!(post_status(&c, &d, &lt(&id, "resume")).await, 202);
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    check_intervals(&c, &d, &v, n).await;
    assert_eq!(
        users(&v),
        [
            ("paused".to_string(), clock),
            ("resumed".to_string(), clock)
        ],
        "{v}"
    );
    let log = v["job"]["log"].to_string();
    assert!(
        log.contains(&format!(
            "paused at test time {clock:.0} s: paused by the user"
        )) && log.contains(&format!(
            "resumed at test time {clock:.0} s: resumed by the user"
        )),
        "{log}"
    );
    let r = wait_test(&c, &reference, &ref_id, Duration::from_secs(300), terminal).await;
    let (e, e_ref) = (loads(&v), loads(&r));
    for (a, b) in e.iter().zip(&e_ref).skip(1) {
        assert!((a / b - 1.0).abs() <= 1e-9, "{e:?} against {e_ref:?}");
    }
    println!(
        "user pause: held after {held} intervals at test time {clock} s across a kill -9; loads {e:?}, without a pause {e_ref:?}"
    );
    drop(d);
    drop(tmp);
}

/// Level stepping (decision 0132), against known truth: the load of a
/// stepped test equals the sum of the loads of each step's level run alone
/// for the step's duration. spider_3in without ageing: its load rate then
/// depends on the level alone (not on the load taken), and each interval's
/// measurement is the same on the same bench (its seed is the bench's plus
/// the interval's index), so the stepped test's load after its 4 mm then its
/// 6 mm interval is the 4 mm test's after its first interval plus what the
/// 6 mm test's second interval added, to the rounding of the sums (1e-9).
/// A step inside an interval (at 1350 s) splits the interval's stimulus at
/// its time: each level's part of the stimulus at that level's load per
/// second, to 1e-9 too. Bad steps are named; the document keeps them.
#[tokio::test]
async fn level_steps_load_the_part_as_each_level_alone() {
    let d = Daemon::start(BENCHES);
    let c = client();
    let mut part = springbench::physics::preset("spider_3in").unwrap();
    part.ageing = None;
    let body = |serial: &str, stimulus: Value| {
        let mut b = test_body(serial, 3);
        let m = b["measurement"].as_object_mut().unwrap();
        m.remove("preset");
        m.insert("part_spec".into(), serde_json::to_value(&part).unwrap());
        b["stimulus"] = stimulus;
        b
    };
    // Bad steps: one message each, naming the field.
    let r = c
        .post(d.url("/api/v1/long-term-tests"))
        .json(&body(
            "LT-STEP-BAD",
            json!({"excursion_m": 0.004, "steps": [{"from_s": 1200.0, "excursion_m": 0.006},
                {"from_s": 600.0, "excursion_m": 0.02}, {"from_s": -1.0, "excursion_m": 0.004}]}),
        ))
        .send()
        .await
        .unwrap();
    let p = problem(r, 422).await;
    let fields: Vec<&str> = p["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["field"].as_str().unwrap())
        .collect();
    for f in [
        "stimulus.steps[1].from_s",
        "stimulus.steps[1].excursion_m",
        "stimulus.steps[2].from_s",
    ] {
        assert!(fields.contains(&f), "{f} not in {p}");
    }
    let ids = [
        submit(&c, &d, &body("LT-STEP-A", json!({"excursion_m": 0.004}))).await,
        submit(&c, &d, &body("LT-STEP-B", json!({"excursion_m": 0.006}))).await,
        submit(
            &c,
            &d,
            &body(
                "LT-STEP-S",
                json!({"excursion_m": 0.004, "steps": [{"from_s": 900.0, "excursion_m": 0.006}]}),
            ),
        )
        .await,
        submit(
            &c,
            &d,
            &body(
                "LT-STEP-M",
                json!({"excursion_m": 0.004, "steps": [{"from_s": 1350.0, "excursion_m": 0.006}]}),
            ),
        )
        .await,
    ];
    let mut l = vec![];
    let mut docs = vec![];
    for id in &ids {
        let v = wait_test(&c, &d, id, Duration::from_secs(600), terminal).await;
        assert_eq!(v["job"]["state"], "succeeded", "{v}");
        l.push(loads(&v));
        docs.push(v);
    }
    let (a, b, s, m) = (&l[0], &l[1], &l[2], &l[3]);
    // The same first interval (4 mm) for A, S and M.
    assert_eq!(s[1], a[1]);
    assert_eq!(m[1], a[1]);
    let truth = a[1] + (b[2] - b[1]);
    let rel = (s[2] - truth).abs() / truth;
    eprintln!(
        "level steps: A(4 mm) {a:?}, B(6 mm) {b:?}, stepped at 900 s {s:?}, truth {truth:.3} J (rel {rel:.2e}), stepped at 1350 s {m:?}"
    );
    assert!(rel < 1e-9, "stepped {} J, truth {truth} J", s[2]);
    // The 6 mm level puts on more load per second than the 4 mm one; a step
    // inside the interval gives between the two.
    assert!(b[2] - b[1] > a[2] - a[1]);
    assert!(m[2] > a[2] && m[2] < s[2], "{m:?}");
    // Inside the interval: the stimulus runs from the measurement's end
    // (900 s + its bench time) to 1800 s, at 4 mm up to 1350 s and at 6 mm
    // after. Each level's load per second from its test alone: the same
    // split of the sums.
    let bench_time_s = docs[0]["state"]["clock_s"].as_f64().unwrap() - 1800.0;
    assert!(
        (20.0..120.0).contains(&bench_time_s),
        "a measurement's bench time {bench_time_s} s"
    );
    for v in &docs {
        assert_eq!(v["state"]["clock_s"], docs[0]["state"]["clock_s"]);
    }
    let on_s = 900.0 - bench_time_s;
    let truth_m =
        a[1] + (a[2] - a[1]) * (450.0 - bench_time_s) / on_s + (b[2] - b[1]) * 450.0 / on_s;
    let rel_m = (m[2] - truth_m).abs() / truth_m;
    eprintln!(
        "stepped at 1350 s: {} J, truth {truth_m:.3} J (rel {rel_m:.2e})",
        m[2]
    );
    assert!(
        rel_m < 1e-9,
        "stepped at 1350 s {} J, truth {truth_m} J",
        m[2]
    );
    // The document keeps the steps (the page shows them from it).
    assert_eq!(
        docs[2]["job"]["request"]["stimulus"]["steps"],
        json!([{"from_s": 900.0, "excursion_m": 0.006}]),
        "{}",
        docs[2]["job"]["request"]
    );
    assert!(docs[0]["job"]["request"]["stimulus"].get("steps").is_none());
    drop(d);
}

/// Decision 0146: the virtual bench's accelerated sine within its drive
/// limit. On a part 400 times stiffer than spider_3in (no ageing table: a
/// constant load rate) 100 V holds the 5.3 mm sine at the excursion
/// `physics::ageing::sine_reach_m` gives (5 µm); the test says so in its log
/// and the load by its second interval is that excursion's rate times the
/// stimulus' time (the interval less a measurement's bench time); on
/// spider_3in itself the sine reaches its 5.3 mm, its load is that level's
/// and the log says nothing of the drive.
#[tokio::test]
async fn the_sine_held_short_by_the_drive_limit_says_so_and_loads_the_part_as_reached() {
    use springbench::physics::{ageing, model::BenchParams};
    let d = Daemon::start(BENCHES);
    let c = client();
    let mut part = springbench::physics::preset("spider_3in").unwrap();
    part.ageing = None;
    let mut stiff = part.clone();
    stiff.k_coeffs_si.iter_mut().for_each(|k| *k *= 400.0);
    let run = |serial: &str, p: &springbench::physics::PartSpec| {
        let mut b = test_body(serial, 2);
        let m = b["measurement"].as_object_mut().unwrap();
        m.remove("preset");
        m.insert("part_spec".into(), serde_json::to_value(p).unwrap());
        b
    };
    let x = 0.0053;
    let reach = ageing::sine_reach_m(&stiff, &BenchParams::default(), 100.0, 0.0, x);
    let mut on = vec![];
    let mut logs = vec![];
    for (serial, p, rate) in [
        (
            "LT-SINE-STIFF",
            &stiff,
            ageing::sine_power_w(&stiff, 0.0, reach),
        ),
        ("LT-SINE-SOFT", &part, ageing::sine_power_w(&part, 0.0, x)),
    ] {
        let id = submit(&c, &d, &run(serial, p)).await;
        let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
        assert_eq!(v["job"]["state"], "succeeded", "{v}");
        on.push(loads(&v)[1] / rate);
        logs.push(v["job"]["log"].to_string());
    }
    println!("reached {:.4} mm; stimulus time {on:?} s", 1e3 * reach);
    assert!(reach > 0.0 && reach < 1e-5, "{reach}");
    assert!(
        logs[0].contains(&format!(
            "the sine reaches {:.3} mm of its 5.300 mm at the drive limit (100 V",
            1e3 * reach
        )),
        "{}",
        logs[0]
    );
    assert!(!logs[1].contains("drive limit"), "{}", logs[1]);
    // The stimulus' time, 900 s less the first measurement's bench time
    // (the parts' procedures differ by a few seconds): at the target's rate
    // the stiff part's load would give about 10^9 s.
    for t in &on {
        assert!(*t > 800.0 && *t < 900.0, "{on:?}");
    }
}

/// Issue 32, decision 0137: band-limited noise as the stimulus, its level
/// the RMS displacement. On the ageing spider_3in the test runs end to end
/// (intervals stored as measurements, the load growing, K(0) falling, the
/// report naming the noise). Known truth on the part without its ageing
/// table (its load rate constant): the load a noise test has taken by its
/// second interval is the noise loop's rate (`physics::waveform`, the loop
/// simulated through the part's model) times the stimulus' time, the same
/// time a sine test's load gives with the sine's analytic rate
/// (`ageing::sine_power_w`): 900 s less the first measurement's bench time.
#[tokio::test]
async fn a_noise_stimulus_ages_the_part_at_the_loops_load_rate() {
    use springbench::physics::{ageing, waveform, BenchParams};
    let d = Daemon::start(BENCHES);
    let c = client();
    // 20-100 Hz around the resonance: 1.5 mm RMS within the 100 V limit.
    let noise = json!({"kind": "noise", "band_hz": [20.0, 100.0], "excursion_rms_m": 0.0015});
    // Bad noise fields: named.
    for (stim, field) in [
        (
            json!({"kind": "noise", "excursion_rms_m": 0.0015}),
            "stimulus.band_hz",
        ),
        (
            json!({"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": 0.006}),
            "stimulus.excursion_rms_m",
        ),
        (
            json!({"kind": "noise", "band_hz": [20.0, 200.0], "excursion_m": 0.0015}),
            "stimulus.excursion_m",
        ),
        (
            json!({"kind": "noise", "band_hz": [300.0, 200.0], "excursion_rms_m": 0.0015}),
            "stimulus.band_hz",
        ),
    ] {
        stimulus_refused(&c, &d, &stim, field, "").await;
    }
    let n = 4;
    let mut b = test_body("LT-NOISE", n);
    b["stimulus"] = noise.clone();
    let id = submit(&c, &d, &b).await;
    let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
    assert_eq!(v["job"]["state"], "succeeded", "{v}");
    check_intervals(&c, &d, &v, n).await;
    let stim = &v["job"]["request"]["stimulus"];
    for k in ["kind", "band_hz", "excursion_rms_m"] {
        assert_eq!(stim[k], noise[k], "{stim}");
    }
    assert!(stim.get("excursion_m").is_none(), "{stim}");
    let e = loads(&v);
    assert!(e.windows(2).all(|w| w[1] > w[0]), "{e:?}");
    let doc = &v["state"]["document"];
    let k0 = |i: usize| doc["intervals"][i]["k0_n_per_m"].as_f64().unwrap();
    // K(0) fell as the part's law says at those loads (the fitted K(0)
    // carries the pre-measurement's bending, +50 N/m, at both ends).
    let sp = springbench::physics::preset("spider_3in").unwrap();
    let law = sp.ageing.unwrap();
    let truth =
        law.k0_n_per_m(sp.k_coeffs_si[0], e[0]) - law.k0_n_per_m(sp.k_coeffs_si[0], e[n - 1]);
    let fell = k0(0) - k0(n - 1);
    println!("noise at 1.5 mm RMS: loads {e:?} J, K(0) fell {fell} N/m, the law {truth} N/m");
    assert!(truth > 40.0 && (fell - truth).abs() < 5.0, "{fell} {truth}");
    let page = report_page(&c, &d, &id).await;
    assert!(
        page.contains("band-limited noise, 20 to 100 Hz, target 1.5 mm RMS displacement"),
        "{page}"
    );
    assert!(!v["job"]["log"].to_string().contains("drive limit"), "{v}");

    // The part without ageing: a constant rate.
    let mut part = springbench::physics::preset("spider_3in").unwrap();
    part.ageing = None;
    let run = |serial: &str, stimulus: Value| {
        let mut b = test_body(serial, 2);
        let m = b["measurement"].as_object_mut().unwrap();
        m.remove("preset");
        m.insert("part_spec".into(), serde_json::to_value(&part).unwrap());
        b["stimulus"] = stimulus;
        b
    };
    let a = submit(&c, &d, &run("LT-NOISE-C", noise.clone())).await;
    let s = submit(&c, &d, &run("LT-SINE-C", json!({"excursion_m": 0.0053}))).await;
    let mut on = vec![];
    for (id, rate) in [
        (a, {
            let bench = BenchParams::default();
            let w = waveform::noise_loop(
                bench.sample_rate_hz,
                [20.0, 100.0],
                waveform::NOISE_LOOP_S,
                waveform::NOISE_SEED,
            )
            .unwrap();
            let mut l = waveform::LoopLoad::new(w);
            // A part without ageing takes the load at one rate: 1 s of it.
            l.apply(&part, &bench, 100.0, 0.0, 0.0015, 1.0)
        }),
        (s, ageing::sine_power_w(&part, 0.0, 0.0053)),
    ] {
        let v = wait_test(&c, &d, &id, Duration::from_secs(300), terminal).await;
        assert_eq!(v["job"]["state"], "succeeded", "{v}");
        let e = loads(&v);
        on.push(e[1] / rate);
    }
    println!("stimulus time: noise {} s, sine {} s", on[0], on[1]);
    // 20-200 Hz needs more than 100 V for 1.5 mm RMS: the test says what it reaches.
    let mut wide = noise.clone();
    wide["band_hz"] = json!([20.0, 200.0]);
    let w = submit(&c, &d, &run("LT-NOISE-W", wide)).await;
    let v = wait_test(&c, &d, &w, Duration::from_secs(300), terminal).await;
    let log = v["job"]["log"].to_string();
    assert!(
        log.contains("the noise reaches 1.06")
            && log.contains("of its 1.500 mm at the drive limit (100 V"),
        "{log}"
    );
    assert!(on[1] > 800.0 && on[1] < 900.0, "{on:?}");
    assert!((on[0] / on[1] - 1.0).abs() < 1e-6, "{on:?}");
}

/// A mono WAV file of `samples` at `fs` (32-bit float, or 16-bit int).
fn wav_bytes(samples: &[f64], fs: u32, channels: u16, float: bool) -> Vec<u8> {
    let spec = hound::WavSpec {
        channels,
        sample_rate: fs,
        bits_per_sample: if float { 32 } else { 16 },
        sample_format: if float {
            hound::SampleFormat::Float
        } else {
            hound::SampleFormat::Int
        },
    };
    let mut cur = std::io::Cursor::new(Vec::new());
    {
        let mut w = hound::WavWriter::new(&mut cur, spec).unwrap();
        for &v in samples {
            for _ in 0..channels {
                if float {
                    w.write_sample(v as f32).unwrap();
                } else {
                    w.write_sample((v * 32767.0).round() as i16).unwrap();
                }
            }
        }
        w.finalize().unwrap();
    }
    cur.into_inner()
}

async fn upload(c: &reqwest::Client, d: &Daemon, bytes: Vec<u8>, query: &str) -> reqwest::Response {
    c.post(d.url(&format!("/api/v1/stimuli{query}")))
        .header("content-type", "audio/wav")
        // Not JSON: a bearer header (any value with open access) is the cross-site guard's proof.
        .bearer_auth("open-access")
        .body(bytes)
        .send()
        .await
        .unwrap()
}

/// Issue 32, decision 0144: a WAV file as the stimulus. Uploaded once
/// (named by the SHA-256 of its bytes; the same bytes again are the same
/// stimulus), refused with the reason when it cannot be played, and played
/// as a loop held at an RMS displacement like the noise. Known truth: the
/// noise loop written to a WAV file (32-bit float) and played as a file
/// loads the part without ageing as the noise test does, to the float's
/// rounding.
#[tokio::test]
async fn a_wav_stimulus_plays_its_file_as_a_loop() {
    use sha2::Digest;
    use springbench::physics::{waveform, BenchParams};
    let d = Daemon::start(BENCHES);
    let c = client();
    let fs = BenchParams::default().sample_rate_hz;
    let wave = waveform::noise_loop(
        fs,
        [20.0, 200.0],
        waveform::NOISE_LOOP_S,
        waveform::NOISE_SEED,
    )
    .unwrap();
    let bytes = wav_bytes(&wave, fs as u32, 1, true);
    let sha: String = sha2::Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let r = upload(&c, &d, bytes.clone(), "?name=noise-20-200.wav").await;
    assert_eq!(r.status(), 201);
    assert_eq!(
        r.headers()["location"].to_str().unwrap(),
        format!("/api/v1/stimuli/{sha}")
    );
    let info: Value = r.json().await.unwrap();
    assert_eq!(info["id"], sha);
    assert_eq!(info["frames"], wave.len());
    assert_eq!(info["sample_rate_hz"], 48000);
    assert_eq!(info["duration_s"], 4.0);
    assert_eq!(
        (info["bits"].as_u64(), info["sample_format"].as_str()),
        (Some(32), Some("float"))
    );
    assert_eq!(info["file_name"], "noise-20-200.wav");
    assert_eq!(info["size_bytes"], bytes.len());
    let rms = info["rms_fs"].as_f64().unwrap();
    let peak = wave.iter().fold(0.0f64, |p, v| p.max(v.abs()));
    assert!((rms - 1.0).abs() < 1e-6, "{info}");
    assert!(
        (info["peak_fs"].as_f64().unwrap() / peak - 1.0).abs() < 1e-6,
        "{info}"
    );
    // The same bytes again: the same stimulus, 200.
    let r = upload(&c, &d, bytes.clone(), "").await;
    assert_eq!(r.status(), 200);
    let again: Value = r.json().await.unwrap();
    assert_eq!(
        (again["id"].clone(), again["created_at"].clone()),
        (sha.clone().into(), info["created_at"].clone())
    );
    assert_eq!(get(&c, &d, &format!("/api/v1/stimuli/{sha}")).await, info);
    let list = get(&c, &d, "/api/v1/stimuli").await;
    assert_eq!(list["items"].as_array().unwrap().len(), 1);

    // Files that cannot be played: a 422 naming the body and the reason.
    let mut nan = wave.clone();
    nan[1000] = f64::NAN;
    let short = &wave[..48000];
    for (body, why) in [
        (vec![], "the body is empty"),
        (b"RIFF\x04\x00\x00\x00WAVE".to_vec(), "not a WAV file"),
        (wav_bytes(&wave, 48000, 2, true), "2 channels"),
        (
            wav_bytes(short, 48000, 1, true),
            "a stimulus loop lasts 2 to 600 s",
        ),
        (
            wav_bytes(&nan, 48000, 1, true),
            "sample 1000 is not a finite number",
        ),
        (
            wav_bytes(&vec![0.25; 192000], 48000, 1, false),
            "the file is silent",
        ),
    ] {
        let p = problem(upload(&c, &d, body, "").await, 422).await;
        assert_eq!(p["errors"][0]["field"], "body", "{p}");
        assert!(
            p["errors"][0]["message"].as_str().unwrap().contains(why),
            "{why}: {p}"
        );
    }
    let p = problem(upload(&c, &d, bytes.clone(), "?name=a%0Ab").await, 422).await;
    assert_eq!(p["errors"][0]["field"], "name", "{p}");
    // Larger than 32 MiB: the declared length is refused before the body is
    // read (headers only: sending the body races the server's early close).
    let addr = d.addr().to_string();
    let answer = tokio::task::spawn_blocking(move || {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(&addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        write!(
            s,
            "POST /api/v1/stimuli HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer open-access\r\nContent-Type: audio/wav\r\nContent-Length: {}\r\nConnection: close\r\n\r\nRIFF",
            33 * 1024 * 1024
        )
        .unwrap();
        let mut answer = String::new();
        let _ = s.read_to_string(&mut answer);
        answer
    })
    .await
    .unwrap();
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    assert!(
        answer.contains("application/problem+json") && answer.contains("33554432 bytes"),
        "{answer}"
    );
    assert_eq!(
        get(&c, &d, "/api/v1/stimuli").await["items"]
            .as_array()
            .unwrap()
            .len(),
        1,
        "nothing refused was stored"
    );
    // A 44.1 kHz file is stored, but a virtual bench (48 kHz) refuses to play it.
    let r = upload(&c, &d, wav_bytes(&wave[..96000], 44100, 1, false), "").await;
    assert_eq!(r.status(), 201);
    let id441 = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();

    // A test's WAV fields: named.
    for (stim, field, why) in [
        (
            json!({"kind": "wav", "excursion_rms_m": 0.0015}),
            "stimulus.wav_id",
            "required",
        ),
        (
            json!({"kind": "wav", "wav_id": "NOISE", "excursion_rms_m": 0.0015}),
            "stimulus.wav_id",
            "64 lowercase hex",
        ),
        (
            json!({"kind": "wav", "wav_id": "0".repeat(64), "excursion_rms_m": 0.0015}),
            "stimulus.wav_id",
            "no stimulus",
        ),
        (
            json!({"kind": "wav", "wav_id": id441, "excursion_rms_m": 0.0015}),
            "stimulus.wav_id",
            "44100 Hz",
        ),
        (
            json!({"kind": "wav", "wav_id": sha, "band_hz": [20.0, 200.0], "excursion_rms_m": 0.0015}),
            "stimulus.band_hz",
            "not a field",
        ),
        (
            json!({"kind": "wav", "wav_id": sha, "excursion_m": 0.0015}),
            "stimulus.excursion_m",
            "not a field",
        ),
        (
            json!({"excursion_m": 0.005, "wav_id": sha}),
            "stimulus.wav_id",
            "not a field",
        ),
    ] {
        stimulus_refused(&c, &d, &stim, field, why).await;
    }

    // Played: the same load as the noise it holds.
    let mut part = springbench::physics::preset("spider_3in").unwrap();
    part.ageing = None;
    let run = |serial: &str, stimulus: Value| {
        let mut b = test_body(serial, 2);
        let m = b["measurement"].as_object_mut().unwrap();
        m.remove("preset");
        m.insert("part_spec".into(), serde_json::to_value(&part).unwrap());
        b["stimulus"] = stimulus;
        b
    };
    let wav_stim = json!({"kind": "wav", "wav_id": sha, "excursion_rms_m": 0.0015});
    let w = submit(&c, &d, &run("LT-WAV", wav_stim.clone())).await;
    let n = submit(
        &c,
        &d,
        &run(
            "LT-WAV-NOISE",
            json!({"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": 0.0015}),
        ),
    )
    .await;
    let mut e = vec![];
    for id in [&w, &n] {
        let v = wait_test(&c, &d, id, Duration::from_secs(300), terminal).await;
        assert_eq!(v["job"]["state"], "succeeded", "{v}");
        e.push(loads(&v));
    }
    let rel = (e[0][1] / e[1][1] - 1.0).abs();
    println!(
        "WAV of the noise loop: {} J, the noise: {} J (rel {rel:.2e})",
        e[0][1], e[1][1]
    );
    assert!(e[0][1] > 0.0 && rel < 1e-5, "{e:?}");
    let v = wait_test(&c, &d, &w, Duration::from_secs(5), terminal).await;
    for k in ["kind", "wav_id", "excursion_rms_m"] {
        assert_eq!(v["job"]["request"]["stimulus"][k], wav_stim[k], "{k}");
    }
    let page = report_page(&c, &d, &w).await;
    assert!(
        page.contains(&format!(
            "WAV file {sha} as a loop, target 1.5 mm RMS displacement"
        )),
        "{page}"
    );
    drop(d);
}
