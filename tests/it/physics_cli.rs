//! `springbench simulate` end to end: files written, readable by the
//! recording module, truth.json consistent; bad input gives one line and exit != 0.

use springbench::recording::RecordingSetFiles;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_springbench"))
}

#[test]
fn simulate_writes_a_readable_recording_set_and_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("set");
    let o = bin()
        .args(["simulate", "--part", "spider_4in", "--seed", "7", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let set = springbench::recording::RecordingSet::read_dir(&out).unwrap();
    assert_eq!(set.meta.moving_mass_kg, 0.05);
    assert_eq!(set.pre.len(), 792000, "16 s + 0.5 s at 48 kHz");
    assert_eq!(set.main.len(), 504000, "10 s + 0.5 s");
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("truth.json")).unwrap()).unwrap();
    assert_eq!(truth["k0"], 2400.0);
    assert_eq!(truth["seed"], 7);
    let xpk = truth["xpeak_m"].as_f64().unwrap();
    let xmax = set
        .main
        .displacement_m
        .iter()
        .fold(0.0f64, |a, x| a.max(x.abs()));
    assert!((xpk - xmax).abs() < 1e-6, "{xpk} vs {xmax}");
    assert!(truth["bench_time_s"].as_f64().unwrap() <= 40.0);
    // Same seed, same files; another part from a TOML file.
    let toml = dir.path().join("p.toml");
    std::fs::write(
        &toml,
        "name = 'mine'\nmoving_mass_kg = 0.04\nk_coeffs_si = [2000.0, 0.0, 2.0e7]\nr_ns_per_m = 1.5\nss_m2 = 0.003\n",
    )
    .unwrap();
    let o = bin()
        .args(["simulate", "--part"])
        .arg(&toml)
        .arg("--out")
        .arg(dir.path().join("mine"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn simulate_bad_input_is_one_line_and_nonzero() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "name = 'x'\nmoving_mass_kg = -1\nk_coeffs_si = [1.0]\nr_ns_per_m = 1\nss_m2 = 0.01\n",
    )
    .unwrap();
    for (args, want) in [
        (vec!["--part", "woofer"], "neither a preset"),
        (vec!["--part", bad.to_str().unwrap()], "moving_mass_kg"),
        (vec!["--part", "spider_4in", "--xpeak-m=-3"], "xpeak"),
        (vec!["--part", "spider_4in", "--xpeak-m", "0.5"], "limit"),
    ] {
        let o = bin()
            .arg("simulate")
            .args(&args)
            .arg("--out")
            .arg(dir.path().join("o"))
            .output()
            .unwrap();
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(e.trim().lines().count(), 1, "{e}");
        assert!(e.contains(want), "{want}: {e}");
    }
}

/// Issue 12: the target not reached within the limits is printed with both figures.
#[test]
fn simulate_prints_a_target_not_reached() {
    let dir = tempfile::tempdir().unwrap();
    let o = bin()
        .args([
            "simulate",
            "--part",
            "spider_4in",
            "--max-drive-v",
            "20",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    let line = err
        .lines()
        .find(|l| {
            l.starts_with("WARNING: target Xpeak 8.000 mm not reached within the limits: reached ")
        })
        .unwrap_or_else(|| panic!("{err}"));
    assert!(line.contains("drive is at its limit of 20 V"), "{line}");
    let bad = bin()
        .args([
            "simulate",
            "--part",
            "spider_4in",
            "--max-drive-v=-1",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert_eq!(String::from_utf8_lossy(&bad.stderr).lines().count(), 1);
}
