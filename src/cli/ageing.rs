//! `springbench ageing DIR [--json] [--predict-s T]`: offline analysis of a
//! long-term test. DIR holds one recording set per subdirectory, each
//! meta.json with `elapsed_s` (and `load_j` when the load is known; without
//! it the law is fitted against time, the load growing in proportion to it
//! under a constant stimulus). Each interval is analysed as `analyze` does,
//! then the ageing law is fitted (`core::ageing::series`, the same code as
//! the daemon's long-term test).
use crate::ageing::series::{analyse, AgeingDocument, Interval};
use crate::identify::{analyze, AnalyzeOptions};
use crate::recording::{RecordingSet, RecordingSetFiles};
use std::path::PathBuf;

#[derive(clap::Args, Debug, Default)]
pub struct AgeingArgs {
    /// Directory with one recording set per subdirectory.
    pub dir: PathBuf,
    /// Print the ageing document as JSON.
    #[arg(long)]
    pub json: bool,
    /// Predict K(0) and f0 at this elapsed time (s) under the series' stimulus.
    #[arg(long)]
    pub predict_s: Option<f64>,
}

/// Reads and analyses every interval of `dir` (subdirectories in name order).
pub fn read_series(dir: &std::path::Path) -> Result<Vec<Interval>, String> {
    let mut subs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    subs.sort();
    if subs.is_empty() {
        return Err(format!(
            "{}: no subdirectories (one recording set per interval expected)",
            dir.display()
        ));
    }
    let mut out = Vec::with_capacity(subs.len());
    for sub in subs {
        let set = RecordingSet::read_dir(&sub).map_err(|e| e.to_string())?;
        let num = |k: &str, v: Option<f64>| -> Result<Option<f64>, String> {
            match v {
                Some(x) if !(x.is_finite() && x >= 0.0) => Err(format!(
                    "{}/meta.json: {k} must be a number >= 0, got {x}",
                    sub.display()
                )),
                v => Ok(v),
            }
        };
        let stamp = &set.meta.long_term;
        let elapsed_s = num("elapsed_s", stamp.elapsed_s)?
            .ok_or_else(|| format!("{}/meta.json: elapsed_s is missing", sub.display()))?;
        let load_j = num("load_j", stamp.load_j)?;
        let report = analyze(&set, &AnalyzeOptions::default())
            .map_err(|e| format!("{}: {e}", sub.display()))?;
        out.push(Interval {
            elapsed_s,
            load_j,
            report,
        });
    }
    Ok(out)
}

pub fn run(args: AgeingArgs) -> Result<(), String> {
    if let Some(t) = args.predict_s {
        if !(t.is_finite() && t >= 0.0) {
            return Err(format!(
                "--predict-s must be a number of seconds >= 0, got {t}"
            ));
        }
    }
    let series = read_series(&args.dir)?;
    let doc = analyse(&series, args.predict_s);
    if args.json {
        let text = serde_json::to_string_pretty(&doc).map_err(|e| e.to_string())?;
        println!("{text}");
    } else {
        print!("{}", table(&doc));
    }
    Ok(())
}

fn state(v: &crate::identify::validity::HeadlineValidity) -> String {
    let s = serde_json::to_value(v.state)
        .ok()
        .and_then(|v| v.as_str().map(String::from))
        .unwrap_or_default();
    match &v.reason {
        Some(r) => format!("{s} ({r})"),
        None => s,
    }
}

/// The document for people.
pub fn table(d: &AgeingDocument) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:>10} {:>12} {:>12} {:>9} {:>12}",
        "elapsed h", "load kJ", "K(0) N/mm", "f0 Hz", "Keff N/mm"
    );
    for i in &d.intervals {
        let _ = writeln!(
            s,
            "{:>10.2} {:>12} {:>12} {:>9} {:>12.4}",
            i.elapsed_s / 3600.0,
            i.load_j.map_or("-".into(), |e| format!("{:.3}", e / 1e3)),
            i.k0_n_per_m
                .map_or("-".into(), |k| format!("{:.4}", k / 1e3)),
            i.f0_hz.map_or("-".into(), |f| format!("{f:.2}")),
            i.keff_n_per_m / 1e3
        );
    }
    match &d.law {
        None => {
            let _ = writeln!(
                s,
                "law: not fitted: {}",
                d.problem.as_deref().unwrap_or("no reason given")
            );
        }
        Some(l) => {
            let _ = writeln!(
                s,
                "law K(0) = K_inf + A_b exp(-c/c_b) + A_f exp(-c/c_f), c = {}: {}",
                l.axis,
                state(&l.validity)
            );
            let _ = writeln!(
                s,
                "  K_inf {:.4} ± {:.4} N/mm, break-in {:.4} ± {:.4} N/mm, fatigue {:.4} ± {:.4} N/mm",
                l.k_inf_n_per_m.value / 1e3,
                l.k_inf_n_per_m.se / 1e3,
                l.break_in_k_n_per_m.value / 1e3,
                l.break_in_k_n_per_m.se / 1e3,
                l.fatigue_k_n_per_m.value / 1e3,
                l.fatigue_k_n_per_m.se / 1e3
            );
            if let (Some(b), Some(f)) = (l.break_in_load_j, l.fatigue_load_j) {
                let _ = writeln!(
                    s,
                    "  break-in load {:.4} ± {:.4} kJ, fatigue load {:.2} ± {:.2} kJ",
                    b.value / 1e3,
                    b.se / 1e3,
                    f.value / 1e3,
                    f.se / 1e3
                );
            }
            let _ = writeln!(
                s,
                "  break-in time {:.3} ± {:.3} h, fatigue time {:.2} ± {:.2} h (this stimulus)",
                l.break_in_time_s.value / 3600.0,
                l.break_in_time_s.se / 3600.0,
                l.fatigue_time_s.value / 3600.0,
                l.fatigue_time_s.se / 3600.0
            );
        }
    }
    if let Some(c) = &d.characteristics {
        let _ = writeln!(
            s,
            "break-in: {:.1} % of K(0), 95 % done after {:.2} h; fatigue: {:.1} % of K(0), {:.2} %/h after break-in",
            c.break_in_loss_percent,
            c.break_in_95_time_s / 3600.0,
            c.fatigue_loss_percent,
            c.fatigue_rate_percent_per_h
        );
    }
    if let Some(l) = &d.large_excursion {
        let _ = writeln!(s, "{}", l.statement);
    }
    if let Some(p) = &d.prediction {
        let _ = writeln!(
            s,
            "prediction at {:.2} h: K(0) {:.4} ± {:.4} N/mm (95 % band {:.4} .. {:.4}), f0 {:.2} ± {:.2} Hz: {}",
            p.elapsed_s / 3600.0,
            p.k0_n_per_m / 1e3,
            p.k0_se_n_per_m / 1e3,
            p.k0_band_n_per_m[0] / 1e3,
            p.k0_band_n_per_m[1] / 1e3,
            p.f0_hz,
            p.f0_se_hz,
            state(&p.validity)
        );
    }
    s
}
