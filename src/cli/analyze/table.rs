//! The result document as the `analyze` command's table.
use crate::identify::validity::HeadlineValidity;
use crate::identify::Report;

/// A state as the tables and pages write it: "NOT DETERMINED", "UNRELIABLE"...
fn state_word(v: &HeadlineValidity) -> String {
    v.state.as_str().replace('_', " ").to_uppercase()
}

/// The readable table: SI and the conventional units of the field.
pub fn table(r: &Report) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let mm = |m: f64| m * 1e3;
    // Every headline value with its state (issue 22): a value that is not
    // valid carries its state in brackets and its reason below the table.
    let mut notes: Vec<String> = Vec::new();
    let mut tag = |what: &str, v: &HeadlineValidity| -> String {
        if v.is_valid() {
            return String::new();
        }
        let mut note = format!(
            "{what} {}: {}",
            state_word(v),
            v.reason.as_deref().unwrap_or("-")
        );
        if let Some(f) = v.fit_value {
            note.push_str(&format!(" (the fit gave {f:.6e})"));
        }
        notes.push(note);
        format!("   [{}]", state_word(v))
    };
    let num = |v: Option<f64>, prec: usize| {
        v.map_or("not determined".to_string(), |x| format!("{x:.prec$}"))
    };
    // A number the document still carries for a value `not_determined`
    // (the large-signal ones are plain numbers) is not shown as measured:
    // the note below the table gives the fit's number as a diagnostic.
    let shown = |x: f64, v: &HeadlineValidity| {
        (v.state != crate::identify::validity::State::NotDetermined).then_some(x)
    };
    let nd_fit = |v: &HeadlineValidity, x: f64| HeadlineValidity {
        fit_value: v.fit_value.or(Some(x).filter(|x| x.is_finite())),
        ..v.clone()
    };
    if let Some(s) = &r.small_signal {
        let _ = writeln!(
            o,
            "Small signal (pre-measurement){}",
            if s.reliable { "" } else { "  ** UNRELIABLE **" }
        );
        let sv = &s.validity;
        let _ = writeln!(
            o,
            "  f0      {:>10} Hz         ± {}{}",
            num(s.f0_hz, 3),
            s.f0_se_hz
                .map_or("undefined (k0 <= 0)".to_string(), |v| format!("{v:.3}")),
            tag("f0", &sv.f0_hz)
        );
        let _ = writeln!(
            o,
            "  k0      {:>10} N/m        ± {:.1}   ({} N/mm){}",
            num(s.k0_n_per_m, 1),
            s.k0_se_n_per_m,
            num(s.k0_n_per_m.map(|k| k * 1e-3), 4),
            tag("k0", &sv.k0_n_per_m)
        );
        let _ = writeln!(
            o,
            "  R       {:>10} N s/m      ± {:.4}{}",
            num(s.r_ns_per_m, 4),
            s.r_se_ns_per_m,
            tag("small-signal R", &sv.r_ns_per_m)
        );
        match (s.q, s.q_se) {
            (Some(q), Some(se)) => {
                let _ = writeln!(
                    o,
                    "  Q       {q:>10.3}            ± {se:.3}{}",
                    tag("Q", &sv.q)
                );
            }
            (Some(q), None) => {
                let _ = writeln!(o, "  Q       {q:>10.3}{}", tag("Q", &sv.q));
            }
            (None, _) => {
                let _ = writeln!(
                    o,
                    "  Q       {:>10}            ({}){}",
                    "-",
                    s.q_null_reason.as_deref().unwrap_or("undefined"),
                    tag("Q", &sv.q)
                );
            }
        }
        if let Some(a) = s.force_per_mic_v_n_per_v {
            let _ = writeln!(o, "  Ss/mic  {a:>10.5} N/V (m^2 Pa/V)");
        }
        let _ = writeln!(o, "  misfit  {:>10.2} %", s.misfit_percent);
    }
    let l = &r.large_signal;
    let _ = writeln!(
        o,
        "Large signal (main sweep), m = {:.4} kg",
        l.moving_mass_kg
    );
    let from_model = l.keff_method.as_deref() == Some("chosen_model");
    let lv = &l.validity;
    let _ = writeln!(
        o,
        "  fR      {:>10} Hz   ({}){}",
        num(shown(l.resonance_hz, &lv.resonance_hz), 3),
        if from_model {
            "Keff of the chosen model's K(x) resonating with m"
        } else {
            "x lags the force by 90 degrees"
        },
        tag("fR", &nd_fit(&lv.resonance_hz, l.resonance_hz))
    );
    let keff = shown(l.keff_n_per_m, &lv.keff_n_per_m);
    let _ = writeln!(
        o,
        "  Keff    {:>10} N/m{}   ({} N/mm) @ Xpeak = {:.3} mm{}",
        num(keff, 1),
        l.keff_se_n_per_m
            .filter(|_| keff.is_some())
            .map_or(String::new(), |se| format!(" ± {se:.1}")),
        num(keff.map(|k| k * 1e-3), 4),
        mm(l.xpeak_m),
        tag("Keff", &nd_fit(&lv.keff_n_per_m, l.keff_n_per_m))
    );
    if let Some(xt) = l.target_xpeak_m {
        let st = l
            .validity
            .keff_at_target_n_per_m
            .clone()
            .unwrap_or_default();
        let _ = writeln!(
            o,
            "  Keff at the target Xpeak {:.3} mm: {} N/m{}",
            mm(xt),
            num(l.keff_at_target_n_per_m, 1),
            tag("Keff at the target", &st)
        );
    }
    if let Some(b) = &l.base {
        let _ = writeln!(
            o,
            "  base (phase method, no effects): fR {:.3} Hz, Keff {:.1} N/m",
            b.resonance_hz, b.keff_n_per_m
        );
    }
    // Ceff is 1/Keff: it has Keff's state (its reason is Keff's note).
    let ceff = shown(l.ceff_m_per_n, &lv.keff_n_per_m);
    let _ = writeln!(
        o,
        "  Ceff    {:>10} m/N ({} mm/N){}",
        ceff.map_or("not determined".to_string(), |c| format!("{c:.4e}")),
        num(ceff.map(|c| c * 1e3), 4),
        if lv.keff_n_per_m.is_valid() {
            String::new()
        } else {
            format!("   [{}, as Keff]", state_word(&lv.keff_n_per_m))
        }
    );
    let _ = writeln!(
        o,
        "  x at resonance {:.3} .. {:.3} mm; Keff of the fitted K(x) there {:.1} N/m",
        mm(l.x_min_at_resonance_m),
        mm(l.x_max_at_resonance_m),
        l.keff_from_k_of_x_n_per_m
    );
    let _ = writeln!(
        o,
        "  displacement peak {:.3} Hz{}",
        l.displacement_peak_hz,
        l.displacement_peak_note
            .as_ref()
            .map_or(String::new(), |n| format!("\n    ({n})"))
    );
    let _ = writeln!(
        o,
        "  x range {:>10.3} .. {:.3} mm, dc at resonance {:.3} mm",
        mm(l.x_min_m),
        mm(l.x_max_m),
        mm(l.dc_m)
    );
    let h: Vec<String> = l
        .harmonics_m
        .iter()
        .map(|a| format!("{:.4}", mm(*a)))
        .collect();
    let _ = writeln!(o, "  harmonics of x at resonance (mm): {}", h.join(" "));
    let k = &r.stiffness;
    let _ = writeln!(
        o,
        "Stiffness K(x) = sum k_i x^i ({}, order {}), {} x in [{:.3}, {:.3}] mm{}",
        k.method,
        k.order,
        if k.validity.k_of_x.state == crate::identify::validity::State::NotDetermined {
            "NOT DETERMINED: the fit's coefficients below are a diagnostic, not a measurement, for"
        } else {
            "valid for"
        },
        mm(k.valid_range_m[0]),
        mm(k.valid_range_m[1]),
        tag("K(x)", &k.validity.k_of_x)
    );
    for i in 0..k.coefficients_n_per_m_pow_i_plus_1.len() {
        let _ = writeln!(
            o,
            "  k{i:<2} {:>14.6e} N/m^{:<2} ± {:.2e}   = {:>12.6e} N/mm^{}",
            k.coefficients_n_per_m_pow_i_plus_1[i],
            i + 1,
            k.coefficients_se_n_per_m_pow_i_plus_1
                .get(i)
                .copied()
                .unwrap_or(f64::NAN),
            k.coefficients_n_per_mm_pow_i_plus_1
                .get(i)
                .copied()
                .unwrap_or(f64::NAN),
            i + 1
        );
    }
    let _ = writeln!(
        o,
        "  R  {:>10} N s/m{}",
        num(shown(k.r_ns_per_m, &k.validity.r_ns_per_m), 4),
        tag("R", &nd_fit(&k.validity.r_ns_per_m, k.r_ns_per_m))
    );
    if let Some(s) = k.force_per_mic_v_n_per_v {
        let _ = writeln!(o, "  force per mic volt {s:.5} N/V");
    }
    let xc = |v: Option<f64>| v.map_or("not reached".to_string(), |x| format!("{:.3} mm", mm(x)));
    let _ = writeln!(
        o,
        "  XC (C = 75 % of C(0)): {} / {}",
        xc(k.xc_m[0]),
        xc(k.xc_m[1])
    );
    let _ = writeln!(
        o,
        "  {:>9} {:>10} {:>11} {:>10} {:>12}",
        "x [mm]", "K [N/mm]", "C [mm/N]", "F [N]", "dF/dx [N/mm]"
    );
    let n = 8;
    for i in 0..=n {
        let x =
            k.valid_range_m[0] + (k.valid_range_m[1] - k.valid_range_m[0]) * i as f64 / n as f64;
        let kx: f64 = k
            .coefficients_n_per_m_pow_i_plus_1
            .iter()
            .rev()
            .fold(0.0, |a, c| a * x + c);
        // dF/dx = d(K(x) x)/dx = sum (i+1) k_i x^i
        let inc: f64 = k
            .coefficients_n_per_m_pow_i_plus_1
            .iter()
            .enumerate()
            .rev()
            .fold(0.0, |a, (i, c)| a * x + (i + 1) as f64 * c);
        let _ = writeln!(
            o,
            "  {:>9.3} {:>10.4} {:>11.4} {:>10.4} {:>12.4}",
            mm(x),
            kx * 1e-3,
            1e3 / kx,
            kx * x,
            inc * 1e-3
        );
    }
    let m = &r.model;
    let _ = writeln!(
        o,
        "Model: residual {:.3} %, noise floor {:.3} %, model error {:.3} %",
        m.residual_percent, m.noise_floor_percent, m.model_error_percent
    );
    for n in &notes {
        let _ = writeln!(o, "STATE: {n}");
    }
    for w in &r.warnings {
        let _ = writeln!(o, "WARNING: {w}");
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::validity::State;

    /// Issue 22: a large-signal value `not_determined` (a plain number in
    /// the document: R, Keff, fR) shows no number on its line; the fit's
    /// number only in the state note, named as the fit's (before: R printed
    /// as -0.4000 N s/m with the tag beside it).
    #[test]
    fn a_value_not_determined_shows_no_number() {
        let mut r = Report::default();
        r.stiffness.coefficients_n_per_m_pow_i_plus_1 = vec![2400.0];
        r.stiffness.valid_range_m = [-0.001, 0.001];
        r.stiffness.r_ns_per_m = -0.4;
        r.large_signal.keff_n_per_m = 2512.5;
        crate::identify::validity::judge(&mut r);
        r.large_signal
            .validity
            .keff_n_per_m
            .mark(State::NotDetermined, "test: Keff not determined");
        assert_eq!(r.stiffness.validity.r_ns_per_m.state, State::NotDetermined);
        let t = table(&r);
        let line = |p: &str| {
            t.lines()
                .find(|l| l.trim_start().starts_with(p))
                .unwrap()
                .to_string()
        };
        let rl = line("R ");
        assert!(
            rl.contains("not determined") && !rl.contains("-0.4"),
            "{rl}"
        );
        assert!(rl.contains("[NOT DETERMINED]"), "{rl}");
        let kl = line("Keff ");
        assert!(
            kl.contains("not determined") && !kl.contains("2512"),
            "{kl}"
        );
        assert!(t.contains("the fit gave -4.000000e-1"), "{t}");
        assert!(t.contains("the fit gave 2.512500e3"), "{t}");
        // Ceff is 1/Keff: no number either, and Keff's state.
        let cl = line("Ceff ");
        assert!(cl.contains("not determined"), "{cl}");
        assert!(cl.contains("[NOT DETERMINED, as Keff]"), "{cl}");
    }

    /// Ceff beside an unreliable Keff carries the same state (issue 22:
    /// before, Ceff printed as a plain number under an UNRELIABLE Keff).
    #[test]
    fn ceff_has_keffs_state() {
        let mut r = Report::default();
        r.stiffness.coefficients_n_per_m_pow_i_plus_1 = vec![2400.0];
        r.stiffness.valid_range_m = [-0.001, 0.001];
        r.large_signal.keff_n_per_m = 2500.0;
        r.large_signal.ceff_m_per_n = 4e-4;
        crate::identify::validity::judge(&mut r);
        r.large_signal
            .validity
            .keff_n_per_m
            .mark(State::Unreliable, "test: noise floor");
        let t = table(&r);
        let cl = t
            .lines()
            .find(|l| l.trim_start().starts_with("Ceff "))
            .unwrap();
        assert!(cl.contains("4.0000e-4 m/N (0.4000 mm/N)"), "{cl}");
        assert!(cl.contains("[UNRELIABLE, as Keff]"), "{cl}");
    }
}
