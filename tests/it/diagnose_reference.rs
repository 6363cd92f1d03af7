//! Diagnostics on the independent reference recordings (../shared/data/reference-recordings).
use springbench::diagnose::{diagnose, plot, plot_names, DiagnoseOptions};
use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;

const DIR: &str = "../shared/data/reference-recordings";

fn run(case: &str) -> Option<springbench::diagnose::Diagnosis> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(DIR)
        .join(case);
    let set = RecordingSet::read_dir(&path).ok()?;
    let d = diagnose(&set, &DiagnoseOptions::default()).unwrap();
    eprintln!(
        "{case}:\n{}",
        springbench::cli::analyze::diagnose::table(&d)
    );
    for name in plot_names() {
        let has_fit = d
            .report
            .small_signal
            .as_ref()
            .is_some_and(|s| s.force_per_mic_v_n_per_v.is_some());
        if *name == "small_signal" && !has_fit {
            continue;
        }
        let svg = plot(&set, &d, name).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        if std::env::var_os("SPRINGBENCH_WRITE_PLOTS").is_some() {
            let out = std::env::temp_dir().join(format!("{case}_{name}.svg"));
            std::fs::write(out, &svg).unwrap();
        }
    }
    Some(d)
}

#[test]
fn p2_friction_ranks_first_and_force_within_20_percent() {
    let Some(d) = run("p2_spider_friction") else {
        return;
    };
    let diag = serde_json::to_value(d.report.diagnostics.unwrap()).unwrap();
    let c = &diag["candidates"][0];
    assert_eq!(c["effect"], "coulomb_friction");
    assert_eq!(c["significant"], true);
    let f = c["parameters"]["force_n"].as_f64().unwrap();
    assert!((f / 0.15 - 1.0).abs() < 0.2, "force {f} N, truth 0.15 N");
    let fm = d.report.model.effects.coulomb_friction.unwrap().force_n;
    assert!((fm / 0.15 - 1.0).abs() < 0.2, "final model force {fm} N");
}

#[test]
fn p1_and_p3_show_nothing_significant() {
    for case in ["p1_spider", "p3_cone"] {
        let Some(d) = run(case) else { continue };
        let diag = serde_json::to_value(d.report.diagnostics.unwrap()).unwrap();
        for c in diag["candidates"].as_array().unwrap() {
            assert_eq!(c["significant"], false, "{case}: {c}");
        }
        assert!(d.report.model.effects.is_empty());
    }
}
