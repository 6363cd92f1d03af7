//! The parameter table of the printable report: every headline value with
//! its validity state (issue 22), as the result document states it.

use super::format::{esc, f, sig, with_se};
use serde_json::Value;
use std::fmt::Write;

/// The state of a headline value of a result document (issue 22):
/// `<section>.validity.<name>` as (state, reason, fit value); a document
/// from before the states: valid, or unreliable with an unreliable
/// small-signal fit. The same reading as the UI's `validityOf`.
pub(super) fn validity_of(
    doc: &Value,
    section: &str,
    name: &str,
) -> (String, Option<String>, Option<f64>) {
    let v = &doc[section]["validity"][name];
    if let Some(state) = v["state"].as_str() {
        return (
            state.to_string(),
            v["reason"].as_str().map(str::to_string),
            f(&v["fit_value"]),
        );
    }
    let ss = &doc["small_signal"];
    if section == "small_signal" && ss["reliable"].as_bool() == Some(false) {
        return (
            "unreliable".into(),
            Some(format!(
                "the small-signal fit is unreliable (misfit {} %)",
                sig(f(&ss["misfit_percent"]).unwrap_or(f64::NAN), 3)
            )),
            None,
        );
    }
    ("valid".into(), None, None)
}

/// "valid", or the state in capitals with its reason.
pub(super) fn state_text(state: &str, reason: Option<&str>) -> String {
    if state == "valid" {
        return "valid".into();
    }
    format!(
        "{}: {}",
        state.replace('_', " ").to_uppercase(),
        reason.unwrap_or("no reason given")
    )
}

/// One row of the parameter table: what people read, the value, its state,
/// and whether that state is not `valid` (shown marked).
pub(super) struct Row {
    name: String,
    value: String,
    validity: String,
    marked: bool,
}

/// The parameter rows of a result document, each headline value with its
/// state; a `not_determined` value shows no number, the fit's own number in
/// a row named as a diagnostic (the UI's export.js `parameters`).
pub(super) fn parameter_rows(doc: &Value) -> Vec<Row> {
    let mut out = vec![];
    let plain = |out: &mut Vec<Row>,
                 name: &str,
                 v: &Value,
                 se: &Value,
                 unit: &str,
                 scale: f64,
                 valid: &str| {
        if let Some(x) = f(v) {
            out.push(Row {
                name: name.to_string(),
                value: with_se(x * scale, f(se).map(|s| s * scale), unit),
                validity: valid.to_string(),
                marked: false,
            });
        }
    };
    // A headline value with its state (`section.validity.key`).
    let headline = |out: &mut Vec<Row>,
                    name: &str,
                    section: &str,
                    key: &str,
                    se: &Value,
                    unit: &str,
                    scale: f64| {
        let v = &doc[section][key];
        let (state, reason, fit_value) = validity_of(doc, section, key);
        let text = state_text(&state, reason.as_deref());
        if state == "not_determined" {
            out.push(Row {
                name: name.to_string(),
                value: "not determined".into(),
                validity: text,
                marked: true,
            });
            if let Some(x) = fit_value.or_else(|| f(v)) {
                out.push(Row {
                    name: format!("{name}: fit value (diagnostic, not a measurement)"),
                    value: with_se(x * scale, None, unit),
                    validity: "diagnostic".into(),
                    marked: false,
                });
            }
        } else if let Some(x) = f(v) {
            out.push(Row {
                name: name.to_string(),
                value: with_se(x * scale, f(se).map(|s| s * scale), unit),
                marked: state != "valid",
                validity: text,
            });
        }
    };
    let ss = &doc["small_signal"];
    if ss.is_object() {
        headline(
            &mut out,
            "resonance f0 (small signal)",
            "small_signal",
            "f0_hz",
            &ss["f0_se_hz"],
            "Hz",
            1.0,
        );
        headline(
            &mut out,
            "stiffness k0 (small signal)",
            "small_signal",
            "k0_n_per_m",
            &ss["k0_se_n_per_m"],
            "N/mm",
            1e-3,
        );
        headline(
            &mut out,
            "mechanical resistance R (small signal)",
            "small_signal",
            "r_ns_per_m",
            &ss["r_se_ns_per_m"],
            "N\u{b7}s/m",
            1.0,
        );
        headline(
            &mut out,
            "quality factor Q (small signal)",
            "small_signal",
            "q",
            &ss["q_se"],
            "",
            1.0,
        );
        if f(&ss["q"]).is_none() && !out.iter().any(|r| r.name.starts_with("quality factor Q")) {
            out.push(Row {
                name: "quality factor Q (small signal)".into(),
                value: "not determined".into(),
                validity: state_text("not_determined", ss["q_null_reason"].as_str()),
                marked: true,
            });
        }
    }
    let ls = &doc["large_signal"];
    headline(
        &mut out,
        "effective stiffness Keff at Xpeak",
        "large_signal",
        "keff_n_per_m",
        &ls["keff_se_n_per_m"],
        "N/mm",
        1e-3,
    );
    if f(&ls["target_xpeak_m"]).is_some() {
        headline(
            &mut out,
            "Keff at the target Xpeak (judged by QC)",
            "large_signal",
            "keff_at_target_n_per_m",
            &Value::Null,
            "N/mm",
            1e-3,
        );
    }
    plain(
        &mut out,
        "peak displacement Xpeak",
        &ls["xpeak_m"],
        &Value::Null,
        "mm",
        1e3,
        "valid",
    );
    headline(
        &mut out,
        "resonance (large signal)",
        "large_signal",
        "resonance_hz",
        &Value::Null,
        "Hz",
        1.0,
    );
    plain(
        &mut out,
        "moving mass",
        &ls["moving_mass_kg"],
        &Value::Null,
        "g",
        1e3,
        "entered",
    );
    let st = &doc["stiffness"];
    let vr = &st["valid_range_m"];
    let range = format!(
        "valid for {:.3} .. {:.3} mm",
        f(&vr[0]).unwrap_or(f64::NAN) * 1e3,
        f(&vr[1]).unwrap_or(f64::NAN) * 1e3
    );
    let (kstate, kreason, _) = validity_of(doc, "stiffness", "k_of_x");
    let kvalid = if kstate == "valid" {
        range
    } else {
        format!("{} ({range})", state_text(&kstate, kreason.as_deref()))
    };
    // A K(x) not determined: its coefficients are the fit's, named so.
    let kname = if kstate == "not_determined" {
        "K(x) fit coefficient (diagnostic, not a measurement)"
    } else {
        "K(x) coefficient"
    };
    if let Some(c) = st["coefficients_n_per_m_pow_i_plus_1"].as_array() {
        for (i, k) in c.iter().enumerate() {
            let unit = if i == 0 {
                "N/mm".to_string()
            } else {
                format!("N/mm^{}", i + 1)
            };
            let n = out.len();
            plain(
                &mut out,
                &format!("{kname} k{i}"),
                k,
                &st["coefficients_se_n_per_m_pow_i_plus_1"][i],
                &unit,
                1e-3f64.powi(i as i32 + 1),
                &kvalid,
            );
            if let Some(r) = out.get_mut(n) {
                r.marked = kstate != "valid";
            }
        }
    }
    headline(
        &mut out,
        "mechanical resistance R (large signal)",
        "stiffness",
        "r_ns_per_m",
        &st["r_se_ns_per_m"],
        "N\u{b7}s/m",
        1.0,
    );
    let m = &doc["model"];
    plain(
        &mut out,
        "model error",
        &m["model_error_percent"],
        &Value::Null,
        "%",
        1.0,
        "valid",
    );
    plain(
        &mut out,
        "noise floor",
        &m["noise_floor_percent"],
        &Value::Null,
        "%",
        1.0,
        "valid",
    );
    out
}

/// The parameters section: every row with its state, a value not valid
/// marked.
pub(super) fn parameter_table(doc: &Value) -> String {
    let mut s = String::from("<section id=\"parameters\"><h2>Parameters</h2><table><tr><th>parameter</th><th>value \u{b1} standard error</th><th>validity</th></tr>");
    for r in parameter_rows(doc) {
        let _ = write!(
            s,
            "<tr{}><td>{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            if r.marked { " class=\"marked\"" } else { "" },
            esc(&r.name),
            esc(&r.value),
            esc(&r.validity)
        );
    }
    s.push_str("</table></section>");
    s
}
