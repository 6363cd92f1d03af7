//! Issue 32: parts that age, the ageing law, `springbench ageing`, break-in.
//!
//! The virtual part's break-in and fatigue are known (`aged_part`); a
//! long-term test on the virtual bench is accelerated
//! (`bench::long_term::run_accelerated`: each interval's measurement is
//! simulated sample by sample, the stimulus between two intervals applied
//! analytically), written as one recording set per interval and analysed by
//! the `springbench ageing` binary, as a user would.
//!
//! The full acceptance (10 h at 15-min intervals, then on to 20 h) is
//! `#[ignore]`d for CPU time (`cargo test --test it ageing:: -- --ignored`);
//! the always-on version runs 5 h at 15-min intervals.

use springbench::bench::long_term::{run_accelerated, LongTermPlan};
use springbench::bench::virtual_bench::VirtualBench;
use springbench::identify::{analyze, AnalyzeOptions};
use springbench::physics::ageing::AgeingParams;
use springbench::physics::PartSpec;
use springbench::procedure::{self, ProcedureConfig};
use springbench::recording::{Meta, RecordingSet, RecordingSetFiles};
use std::path::Path;
use std::process::Command;

/// The part's truth: spider_3in with the ageing of its preset.
fn aged_part() -> PartSpec {
    springbench::physics::preset("spider_3in").unwrap()
}

fn truth(p: &PartSpec) -> AgeingParams {
    p.ageing.expect("spider_3in has ageing parameters")
}

fn procedure_cfg() -> ProcedureConfig {
    ProcedureConfig {
        levels_m: vec![0.006],
        ..ProcedureConfig::default()
    }
}

/// Runs a long-term test, writes interval NNN/ per measurement under `dir`,
/// returns (elapsed_s, load_j, true k0) per interval.
fn run_test(dir: &Path, hours: f64, interval_s: f64, seed: u64) -> Vec<(f64, f64, f64)> {
    let part = aged_part();
    let mut vb = VirtualBench::new(part, seed).with_ageing(0.0);
    let plan = LongTermPlan {
        duration_s: hours * 3600.0,
        interval_s,
        stimulus_xpeak_m: STIMULUS_XPEAK_M,
        procedure: procedure_cfg(),
    };
    let mut rows = Vec::new();
    run_accelerated(&mut vb, &plan, &mut |m| {
        let sub = dir.join(format!("{:03}", m.index));
        m.set.write_dir(&sub).map_err(|e| e.to_string())?;
        rows.push((m.elapsed_s, m.load_j, m.k0_true_n_per_m));
        Ok(())
    })
    .unwrap();
    rows
}

const STIMULUS_XPEAK_M: f64 = 0.0053;

/// `springbench ageing --json --predict-s T DIR`, asserted to succeed.
pub(crate) fn ageing_json(dir: &Path, predict_s: f64) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_springbench"))
        .args(["ageing", "--json", "--predict-s"])
        .arg(predict_s.to_string())
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn within(name: &str, got: f64, want: f64, rel: f64) {
    assert!(
        (got / want - 1.0).abs() <= rel,
        "{name}: {got} against the truth {want} (more than {} %)",
        rel * 100.0
    );
}

/// The small-signal K(0) of the new part, measured on a bench that does not
/// age it: what the pre-measurement (about 1 mm) reads of a hardening part
/// is its stiffness there, not K(x = 0) (+3 % on spider_3in).
fn new_part_k0_small_signal(part: &PartSpec) -> f64 {
    let mut vb = VirtualBench::new(part.clone(), 99);
    repeated_k0(&mut vb, 1)[0]
}

/// Checks the fitted law against the part's truth.
fn check_law(doc: &serde_json::Value, part: &PartSpec, rel: f64) {
    let t = truth(part);
    let law = &doc["law"];
    assert_eq!(law["axis"], "load_j", "{law}");
    assert_eq!(law["validity"]["state"], "valid", "{law}");
    let v = |k: &str| law[k]["value"].as_f64().unwrap();
    within(
        "break-in ΔK",
        v("break_in_k_n_per_m"),
        t.break_in_k_n_per_m,
        rel,
    );
    within(
        "break-in load",
        v("break_in_load_j"),
        t.break_in_load_j,
        rel,
    );
    within(
        "fatigue ΔK",
        v("fatigue_k_n_per_m"),
        t.fatigue_k_n_per_m,
        rel,
    );
    within("fatigue load", v("fatigue_load_j"), t.fatigue_load_j, rel);
    // K_∞ as the small-signal measurement reads it.
    let k_inf = new_part_k0_small_signal(part) - t.break_in_k_n_per_m - t.fatigue_k_n_per_m;
    within("K_inf", v("k_inf_n_per_m"), k_inf, rel);
    // Every parameter has a standard error.
    for k in [
        "k_inf_n_per_m",
        "break_in_k_n_per_m",
        "fatigue_k_n_per_m",
        "break_in_load_j",
        "fatigue_load_j",
    ] {
        assert!(law[k]["se"].as_f64().unwrap() > 0.0, "{k}: {law}");
    }
}

fn check_large_excursion(doc: &serde_json::Value) {
    let le = &doc["large_excursion"];
    assert_eq!(le["below_2_percent"], true, "{le}");
    for c in le["change_percent"].as_array().unwrap() {
        assert!(c.as_f64().unwrap().abs() < 2.0, "{le}");
    }
    assert!(le["statement"].as_str().unwrap().contains("both below 2 %"));
}

#[test]
fn a_five_hour_test_at_15_min_intervals_recovers_the_parts_ageing() {
    let dir = tempfile::tempdir().unwrap();
    let rows = run_test(dir.path(), 5.0, 900.0, 11);
    assert_eq!(rows.len(), 21);
    let doc = ageing_json(dir.path(), 7.5 * 3600.0);
    let part = aged_part();
    // Half the acceptance's load (half a fatigue scale): looser than its 10 %.
    check_law(&doc, &part, 0.15);
    check_large_excursion(&doc);
    let iv = doc["intervals"].as_array().unwrap();
    assert_eq!(iv.len(), 21);
    let offset = iv[0]["k0_n_per_m"].as_f64().unwrap() - rows[0].2;
    for (i, (e, load, k0)) in iv.iter().zip(&rows) {
        assert_eq!(i["elapsed_s"].as_f64().unwrap(), *e);
        assert_eq!(i["load_j"].as_f64().unwrap(), *load);
        // The interval follows the part's K(0) (less the small-signal offset).
        let got = i["k0_n_per_m"].as_f64().unwrap() - offset;
        within("interval k0", got, *k0, 0.02);
    }
    // Accelerated: every interval says so.
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("020/meta.json")).unwrap())
            .unwrap();
    assert_eq!(meta["accelerated"], true);
    let p = &doc["prediction"];
    assert_eq!(p["elapsed_s"].as_f64().unwrap(), 7.5 * 3600.0);
    assert_eq!(p["validity"]["state"], "extrapolated", "{p}");
    let band = p["k0_band_n_per_m"].as_array().unwrap();
    let k = p["k0_n_per_m"].as_f64().unwrap();
    assert!(band[0].as_f64().unwrap() < k && k < band[1].as_f64().unwrap());
}

/// The acceptance: 10 h at 15-min intervals (41 measurements), on to 20 h.
#[test]
#[ignore = "CPU: 81 simulated measurements; run with --release -- --ignored"]
fn acceptance_ten_hours_at_15_min_intervals_and_a_20_hour_prediction() {
    let all = tempfile::tempdir().unwrap();
    let first = tempfile::tempdir().unwrap();
    let t = std::time::Instant::now();
    let rows = run_test(all.path(), 20.0, 900.0, 21);
    let wall = t.elapsed().as_secs_f64();
    assert_eq!(rows.len(), 81);
    // The first 10 h alone.
    for i in 0..41 {
        let name = format!("{i:03}");
        copy_dir(&all.path().join(&name), &first.path().join(&name));
    }
    let t = std::time::Instant::now();
    let doc10 = ageing_json(first.path(), 72000.0);
    let analyse_s = t.elapsed().as_secs_f64();
    let part = aged_part();
    check_law(&doc10, &part, 0.10);
    check_large_excursion(&doc10);
    let doc20 = ageing_json(all.path(), 72000.0);
    let measured_20h = doc20["intervals"][80]["k0_n_per_m"].as_f64().unwrap();
    let predicted = doc10["prediction"]["k0_n_per_m"].as_f64().unwrap();
    within(
        "K(0) at 20 h predicted from 10 h",
        predicted,
        measured_20h,
        0.03,
    );
    let band = doc10["prediction"]["k0_band_n_per_m"].as_array().unwrap();
    println!(
        "acceptance: simulation of 81 intervals {wall:.0} s wall, analysis of 41 {analyse_s:.0} s; \
         law {}; K(0) at 20 h predicted {predicted:.1} N/m (band {band:?}), measured {measured_20h:.1} N/m, true {:.1} N/m; {}",
        doc10["law"],
        rows[80].2,
        doc10["large_excursion"]["statement"]
    );
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

/// K(0) of `n` measurements in a row of the part on `vb`.
fn repeated_k0(vb: &mut VirtualBench, n: usize) -> Vec<f64> {
    let mut cfg = procedure_cfg();
    cfg.moving_mass_kg = vb.part.moving_mass_kg;
    struct Quiet;
    impl procedure::Observer for Quiet {}
    (0..n)
        .map(|_| {
            let out = procedure::run(vb, &cfg, &mut Quiet).unwrap();
            let set = RecordingSet {
                meta: Meta::standard(vb.part.moving_mass_kg, 48000.0),
                pre: out.pre.clone(),
                main: out.narrow[0].signals.clone(),
            };
            let r = analyze(&set, &AnalyzeOptions::default()).unwrap();
            r.small_signal.unwrap().k0_n_per_m.unwrap()
        })
        .collect()
}

/// Drift of a series: the line through the twelve K(0) from the first to
/// the last measurement, relative to the first (%).
fn drift_percent(k: &[f64]) -> f64 {
    let n = k.len() as f64;
    let mx = (n - 1.0) / 2.0;
    let my = k.iter().sum::<f64>() / n;
    let sxy: f64 = k
        .iter()
        .enumerate()
        .map(|(i, y)| (i as f64 - mx) * (y - my))
        .sum();
    let sxx: f64 = (0..k.len()).map(|i| (i as f64 - mx).powi(2)).sum();
    let slope = sxy / sxx;
    100.0 * slope * (n - 1.0) / (my - slope * mx)
}

#[test]
fn break_in_removes_the_drift_of_repeated_measurements() {
    let part = aged_part();
    let mut fresh = VirtualBench::new(part.clone(), 31).with_ageing(0.0);
    let without = repeated_k0(&mut fresh, 12);
    let d0 = drift_percent(&without);
    let mut broken_in = VirtualBench::new(part.clone(), 32).with_ageing(0.0);
    let cfg = ProcedureConfig {
        moving_mass_kg: part.moving_mass_kg,
        ..procedure_cfg()
    };
    let done = procedure::break_in(
        &mut broken_in,
        &cfg,
        &procedure::BreakIn {
            duration_s: procedure::break_in::DEFAULT_DURATION_S,
            xpeak_m: 0.009,
        },
        &mut || false,
    )
    .unwrap();
    // The result states the break-in done: 5 min near the level.
    assert!((done.held_s - 300.0).abs() < 1e-6, "{done:?}");
    within("break-in level", done.xpeak_m, 0.009, 0.15);
    let with = repeated_k0(&mut broken_in, 12);
    let d1 = drift_percent(&with);
    println!("drift of 12 measurements: {d0:.3} % without, {d1:.3} % after break-in {done:?}");
    assert!(d0 < -1.0, "without break-in: {d0} % ({without:?})");
    assert!(d1.abs() <= 0.2, "after break-in: {d1} % ({with:?})");
}
