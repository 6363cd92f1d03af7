//! `springbench analyze`: output on a good set, one-line errors (exit != 0, no
//! panic) on bad input.

use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;
use std::path::{Path, PathBuf};
use std::process::Command;

fn p1() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/reference-recordings/p1_spider")
}

fn analyze(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_springbench"))
        .arg("analyze")
        .arg(dir)
        .args(extra)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Writes a modified copy of p1 and expects one error line containing `needle`.
fn expect_error(modify: impl FnOnce(&mut RecordingSet, &Path), needle: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let mut set = RecordingSet::read_dir(p1()).unwrap();
    modify(&mut set, tmp.path());
    if !tmp.path().join("meta.json").exists() {
        set.write_dir(tmp.path()).unwrap();
    }
    let (code, stdout, stderr) = analyze(tmp.path(), &[]);
    assert_ne!(code, 0, "{needle}: {stdout}");
    assert_ne!(code, 101, "{needle}: panicked: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{needle}: {stderr}");
    assert!(stderr.contains(needle), "expected '{needle}' in: {stderr}");
}

#[test]
fn json_and_table_on_a_good_set() {
    let (code, stdout, stderr) = analyze(&p1(), &["--json"]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let k0 = v["stiffness"]["coefficients_n_per_m_pow_i_plus_1"][0]
        .as_f64()
        .unwrap();
    assert!((k0 / 2400.0 - 1.0).abs() < 0.005, "{k0}");
    assert_eq!(v["stiffness"]["method"], "two-signal");
    for f in ["f0_hz", "k0_n_per_m", "r_ns_per_m", "q"] {
        assert!(v["small_signal"][f].is_f64(), "{f}");
    }
    for f in [
        "resonance_hz",
        "keff_n_per_m",
        "xpeak_m",
        "x_min_m",
        "x_max_m",
        "dc_m",
    ] {
        assert!(v["large_signal"][f].is_f64(), "{f}");
    }
    assert!(v["model"]["residual_percent"].is_f64());
    assert!(v["warnings"].as_array().unwrap().is_empty());

    let (code, stdout, _) = analyze(&p1(), &["--method", "one-signal", "--order", "4"]);
    assert_eq!(code, 0);
    assert!(
        stdout.contains("Keff") && stdout.contains("N/mm"),
        "{stdout}"
    );
    assert!(stdout.contains("one-signal, order 4"), "{stdout}");
}

#[test]
fn bad_arguments() {
    let (code, _, stderr) = analyze(&p1(), &["--method", "three-signal"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("unknown --method"), "{stderr}");
    let (code, _, stderr) = analyze(&p1(), &["--order", "40"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("--order 40"), "{stderr}");
}

#[test]
fn missing_file() {
    expect_error(
        |set, dir| {
            set.write_dir(dir).unwrap();
            std::fs::remove_file(dir.join("pre.wav")).unwrap();
        },
        "pre.wav",
    );
}

#[test]
fn missing_channel() {
    expect_error(
        |set, dir| {
            set.write_dir(dir).unwrap();
            let meta = r#"{"moving_mass_kg":0.05,"sample_rate_hz":48000,"channels":{"displacement":0,"microphone":3}}"#;
            std::fs::write(dir.join("meta.json"), meta).unwrap();
        },
        "channel 3",
    );
}

#[test]
fn nan_sample() {
    expect_error(
        |set, _| set.main.microphone_v[1000] = f64::NAN,
        "non-finite",
    );
}

#[test]
fn mass_not_positive() {
    expect_error(|set, _| set.meta.moving_mass_kg = 0.0, "moving_mass_kg");
}

#[test]
fn too_short() {
    expect_error(
        |set, _| {
            let n = 12_000;
            set.main.displacement_m.truncate(n);
            set.main.microphone_v.truncate(n);
            set.main.drive_v.as_mut().unwrap().truncate(n);
        },
        "too short",
    );
}

#[test]
fn clipped_laser() {
    expect_error(
        |set, _| {
            for x in set.main.displacement_m.iter_mut() {
                *x = x.clamp(-6e-3, 6e-3);
            }
        },
        "clipped",
    );
}

#[test]
fn no_resonance_inside_the_sweep() {
    // The first 4 s of the sweep only: the amplitude is still rising at the end.
    expect_error(
        |set, _| {
            let n = 4 * 48_000;
            set.main.displacement_m.truncate(n);
            set.main.microphone_v.truncate(n);
            set.main.drive_v.as_mut().unwrap().truncate(n);
        },
        "no resonance",
    );
}

/// Issue 12: flags that would do nothing and unknown effects are refused with
/// one line and exit 2, before the set is read.
#[test]
fn flags_that_do_nothing_and_unknown_effects_are_refused() {
    let cases: [(&[&str], &str); 4] = [
        (
            &["--effects", "creep"],
            "--effects only acts with --diagnose",
        ),
        (
            &["--plots", "/tmp/never-written"],
            "--plots only acts with --diagnose",
        ),
        (
            &["--diagnose", "--effects", "creep,wobble"],
            "unknown effect 'wobble'",
        ),
        (&["--effects", "wobble"], "unknown effect 'wobble'"),
    ];
    for (args, needle) in cases {
        let (code, stdout, stderr) = analyze(&p1(), args);
        assert_eq!(code, 2, "{args:?}: {stdout}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
    }
    assert!(!Path::new("/tmp/never-written").exists());
}

/// `--diagnose` keeps the tables of the plain analysis (small signal, Keff, K(x)).
#[test]
fn diagnose_keeps_the_main_tables() {
    let (code, stdout, stderr) = analyze(&p1(), &["--diagnose"]);
    assert_eq!(code, 0, "{stderr}");
    for needle in [
        "Small signal (pre-measurement)",
        "  Keff ",
        "Stiffness K(x) = sum k_i x^i",
        "  k0 ",
        "candidates (held-out error reduction",
        "ladder:",
    ] {
        assert!(stdout.contains(needle), "'{needle}' missing in:\n{stdout}");
    }
}

/// Issue 22, same state everywhere: on a part whose drive hit its limit at
/// 1 % of the target (spider_4in on the virtual bench), every headline
/// value that `analyze --json` marks carries the same state and reason in
/// the table (`[STATE]` on its line, `STATE: <value> <STATE>: <reason>`
/// below), and a `not_determined` one shows no number.
#[test]
fn the_table_shows_the_states_of_the_json() {
    use springbench::bench::simulate::{simulate, SimulateOptions};
    let part = springbench::physics::preset("spider_4in").unwrap();
    let mut l = springbench::bench::virtual_bench::DEFAULT_LIMITS;
    l.max_drive_v = 0.5; // about 1 % of the 50 V the 8 mm target takes
    let opts = SimulateOptions {
        limits: Some(l),
        ..Default::default()
    };
    let sim = simulate(&part, 7, &opts).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    sim.set.write_dir(tmp.path()).unwrap();
    let (code, json, stderr) = analyze(tmp.path(), &["--json"]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let (code, table, stderr) = analyze(tmp.path(), &[]);
    assert_eq!(code, 0, "{stderr}");
    let fields = [
        ("f0", "small_signal", "f0_hz"),
        ("k0", "small_signal", "k0_n_per_m"),
        ("small-signal R", "small_signal", "r_ns_per_m"),
        ("Q", "small_signal", "q"),
        ("fR", "large_signal", "resonance_hz"),
        ("Keff", "large_signal", "keff_n_per_m"),
        ("K(x)", "stiffness", "k_of_x"),
        ("R", "stiffness", "r_ns_per_m"),
    ];
    let mut marked = 0;
    for (label, section, key) in fields {
        let s = &v[section]["validity"][key];
        let state = s["state"]
            .as_str()
            .unwrap_or_else(|| panic!("{label}: {s}"));
        let word = state.replace('_', " ").to_uppercase();
        let note = format!("STATE: {label} {word}: ");
        if state == "valid" {
            assert!(!table.contains(&note), "{label} valid in the JSON: {table}");
            continue;
        }
        marked += 1;
        let line = table
            .lines()
            .find(|l| l.starts_with(&note))
            .unwrap_or_else(|| panic!("no '{note}' in {table}"));
        assert!(line.contains(s["reason"].as_str().unwrap()), "{line}");
    }
    eprintln!("{table}");
    assert!(
        marked >= 3,
        "a drive-limited part marks its large-signal values: {table}"
    );
}
