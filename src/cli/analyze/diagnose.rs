//! `springbench analyze DIR --diagnose`: model diagnostics on the command line
//! (called from [`super::run`] when `--diagnose` is given).
use super::args::AnalyzeArgs;
use crate::diagnose::{diagnose, plot, plot_names, DiagnoseOptions, Diagnosis};
use crate::effects::EffectId;
use crate::identify::{AnalyzeOptions, Method};
use crate::recording::{RecordingSet, RecordingSetFiles};
use std::fmt::Write;

/// The diagnose options of the command-line arguments; one-line error.
pub fn options(args: &AnalyzeArgs) -> Result<DiagnoseOptions, String> {
    let method = match args.method.as_str() {
        "two-signal" => Method::TwoSignal,
        "one-signal" => Method::OneSignal,
        m => {
            return Err(format!(
                "unknown method '{m}' (known: two-signal, one-signal)"
            ))
        }
    };
    let mut effects = Vec::new();
    // `--effects a,b` fits exactly that model; `--effects auto` (or none)
    // lets the ladder choose.
    let names: Vec<&str> = args
        .effects
        .iter()
        .map(|e| e.trim())
        .filter(|e| !e.is_empty())
        .collect();
    let auto = names.is_empty() || names == ["auto"];
    for e in names.into_iter().filter(|e| *e != "auto") {
        let id = EffectId::parse(e)?;
        if !effects.contains(&id) {
            effects.push(id);
        }
    }
    if args.order == Some(0) {
        return Err("--order must be at least 1".into());
    }
    Ok(DiagnoseOptions {
        analyze: AnalyzeOptions {
            method,
            order: args.order,
        },
        effects,
        exact: !auto,
    })
}

/// Runs the diagnostics on `set` and prints them (table, or JSON with `--json`);
/// writes the SVG plots when `--plots DIR` is given.
pub fn run(set: &RecordingSet, args: &AnalyzeArgs) -> Result<(), String> {
    let opts = options(args)?;
    let mut diagnosis = diagnose(set, &opts).map_err(|e| e.to_string())?;
    let series = if args.series.is_empty() {
        None
    } else {
        let mut sets = vec![set.clone()];
        for dir in &args.series {
            sets.push(RecordingSet::read_dir(dir).map_err(|e| format!("--series: {e}"))?);
        }
        let eopts = crate::diagnose::engine::EngineOptions {
            order: opts.analyze.order,
            forced: opts.effects.clone(),
            ladder: !opts.exact,
            ..Default::default()
        };
        let s = crate::diagnose::series::fit_series_sets(&sets, &eopts)?;
        if let Some(d) = diagnosis.report.diagnostics.as_mut() {
            d.series = Some(s.clone());
        }
        Some(s)
    };
    if let Some(dir) = &args.plots {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        for name in plot_names() {
            if let Some(svg) = plot(set, &diagnosis, name) {
                let path = dir.join(format!("{name}.svg"));
                std::fs::write(&path, svg).map_err(|e| format!("{}: {e}", path.display()))?;
            }
        }
    }
    if args.json {
        let text = serde_json::to_string_pretty(&diagnosis.report).map_err(|e| e.to_string())?;
        println!("{text}");
    } else {
        // The main tables of the analysis first (small signal, Keff, K(x)),
        // then the diagnostics.
        print!("{}", super::table::table(&diagnosis.report));
        print!("\nDiagnostics\n{}", table(&diagnosis));
        if let Some(s) = &series {
            print!("\n{}", series_table(s));
        }
    }
    Ok(())
}

/// The joint fit over a level series beside each level's own fit.
pub fn series_table(s: &crate::diagnose::series::SeriesFit) -> String {
    let mut o = String::new();
    let ids = |e: &crate::effects::Effects| {
        let v: Vec<&str> = e.ids().iter().map(|i| i.as_str()).collect();
        if v.is_empty() {
            "-".to_string()
        } else {
            v.join(" + ")
        }
    };
    let k = |c: &[f64], x: f64| c.iter().rev().fold(0.0, |a, k| a * x + k);
    let _ = writeln!(o, "Level series: one K(x), R and effects over all levels");
    let _ = writeln!(
        o,
        "  {:<8} {:>16} {:>10} {:>10} {:>10} {:>10}  effects",
        "", "range mm", "K(-x) N/m", "K(0) N/m", "K(+x) N/m", "R N s/m"
    );
    let j = &s.joint;
    let mut row = |label: &str, range: [f64; 2], c: &[f64], r: f64, effects: &str| {
        let _ = writeln!(
            o,
            "  {label:<8} {:>7.3} .. {:<6.3} {:>10.1} {:>10.1} {:>10.1} {:>10.4}  {effects}",
            range[0] * 1e3,
            range[1] * 1e3,
            k(c, range[0]),
            k(c, 0.0),
            k(c, range[1]),
            r,
        );
    };
    for (i, l) in s.levels.iter().enumerate() {
        row(
            &format!("level {}", i + 1),
            l.range_m,
            &l.stiffness_coefficients_n_per_m_pow_i_plus_1,
            l.r_ns_per_m,
            &ids(&l.effects),
        );
    }
    row(
        "joint",
        j.valid_range_m,
        &j.stiffness_coefficients_n_per_m_pow_i_plus_1,
        j.r_ns_per_m,
        &ids(&j.effects),
    );
    let _ = writeln!(
        o,
        "  joint model error {:.3} % (noise floor {:.3} %), order {}",
        j.model_error_percent, j.noise_floor_percent, j.order
    );
    o
}

/// The readable table of a diagnosis.
pub fn table(diagnosis: &Diagnosis) -> String {
    let r = &diagnosis.report;
    let mut s = String::new();
    let m = &r.model;
    let effects: Vec<&str> = m.effects.ids().iter().map(|e| e.as_str()).collect();
    let _ = writeln!(
        s,
        "model: {}",
        if effects.is_empty() {
            "base (K(x), R, force scale)".to_string()
        } else {
            format!("base + {}", effects.join(" + "))
        }
    );
    let _ = writeln!(
        s,
        "  residual {:.3} %   noise floor {:.3} %   model error {:.3} %",
        m.residual_percent, m.noise_floor_percent, m.model_error_percent
    );
    let Some(d) = &r.diagnostics else {
        return s;
    };
    let fm = &d.final_model;
    let mut ids = fm.parameters.ids();
    ids.sort_by_key(|id| id.as_str());
    for id in ids {
        let se = &fm.parameters_se[id.as_str()];
        let mut parts = Vec::new();
        for (k, v) in fm.parameters.parameters(id).unwrap_or_default() {
            match se[k].as_f64() {
                Some(e) => parts.push(format!("{k} = {v:.4e} +- {e:.1e}")),
                None => parts.push(format!("{k} = {v:.4e}")),
            }
        }
        let _ = writeln!(s, "  {}: {}", id.as_str(), parts.join(", "));
    }
    let _ = writeln!(s, "\ncandidates (held-out error reduction, best first):");
    let _ = writeln!(
        s,
        "  {:<25} {:>10} {:>11} {:>10} {:>8}  parameters",
        "effect", "reduction", "significant", "p", "VIF"
    );
    for c in &d.candidates {
        let _ = writeln!(
            s,
            "  {:<25} {:>9.1}% {:>11} {:>10.1e} {:>8.1}  {}",
            c.effect,
            c.error_reduction_percent,
            if c.significant { "yes" } else { "no" },
            c.p_value,
            c.variance_inflation,
            c.parameters
        );
        if let Some(note) = &c.note {
            let _ = writeln!(s, "      {note}");
        }
    }
    let _ = writeln!(s, "\nladder:");
    let _ = writeln!(
        s,
        "  {:<50} {:>10} {:>13}",
        "effects", "residual", "model error"
    );
    for st in &d.ladder {
        let _ = writeln!(
            s,
            "  {:<50} {:>9.3}% {:>12.3}%",
            if st.effects.is_empty() {
                "base".to_string()
            } else {
                st.effects.join(", ")
            },
            st.cv_residual_percent,
            st.model_error_percent
        );
    }
    // The warnings are printed with the analysis tables (cli::analyze::table).
    s
}
