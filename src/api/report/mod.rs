//! The printable report of a measurement over the API (issue 23), for a
//! part's traveller document: one self-contained HTML page (inline styles
//! and SVG plots, no script, no other request) with a print stylesheet for
//! A4 and Letter. It holds what the UI's report view (`#/report/ID`) holds:
//! part identity, the verdict with every judged parameter and its limits,
//! the parameters with units, uncertainties and validity, K(x), C(x), F(x)
//! over the valid range and Keff(Xpeak) of the job, and the traceability
//! (software version, recipe hash, calibration record). The numbers come
//! from the fit chosen as the measurement's headline, else its own result.

mod format;
mod longterm;
mod plots;
mod table;

use super::problem::{ApiResult, Problem};
use super::AppState;
use crate::store::{FitReads, MeasurementReads, PartReads, VerdictReads};
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use format::{display, esc, f, limits, sig};
use plots::{big, plots};
use serde_json::Value;
use std::fmt::Write;
use table::parameter_table;

const STYLE: &str = "body{font-family:'DejaVu Sans',Arial,sans-serif;font-size:11px;color:#1b2430;margin:0 auto;max-width:190mm}\
h1{font-size:17px;margin:0 0 2px}h2{font-size:13px;margin:10px 0 3px;border-bottom:1px solid #ccd}\
table{border-collapse:collapse;width:100%}td,th{text-align:left;padding:1px 4px;vertical-align:top}\
th{color:#555;font-weight:600}tr.fail td{color:#b3261e;font-weight:600}.num{font-variant-numeric:tabular-nums}\
.two{display:grid;grid-template-columns:1fr 1fr;gap:0 14px}.plots{display:grid;grid-template-columns:1fr 1fr;gap:4px 10px}\
.plots svg{width:100%;height:auto}.word{font-size:16px;font-weight:800;padding:0 6px;border-radius:3px}\
.pass{background:#137333;color:#fff}.fail-w{background:#b3261e;color:#fff}.invalid{background:#f2a900}\
.marked td:last-child{color:#8a5a00;font-weight:600}.muted{color:#5d6b7a}.mono{font-family:'DejaVu Sans Mono',monospace}section{break-inside:avoid}\
@page{margin:11mm 10mm}@media print{*{-webkit-print-color-adjust:exact;print-color-adjust:exact}}";

/// The report page of a measurement.
pub async fn html(st: &AppState, id: &str) -> ApiResult<String> {
    let (info, result, _) = st
        .store
        .get_measurement(id)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", id))?;
    let choice = st.store.headline_choice(id).await?;
    let mut doc = result.unwrap_or(Value::Null);
    let mut source = "the measurement\u{2019}s own fit".to_string();
    if let Some(c) = choice.as_ref().filter(|c| c.fit_id.is_some()) {
        if let Some(fit) = st
            .store
            .list_fits(id)
            .await?
            .into_iter()
            .find(|x| Some(&x.id) == c.fit_id.as_ref())
        {
            source = format!(
                "fit {} chosen by {} at {}",
                fit.id,
                c.chosen_by.as_deref().unwrap_or("open access"),
                c.chosen_at
            );
            doc = fit.result;
        }
    }
    let verdict = st
        .store
        .measurement_verdict(id)
        .await?
        .map(crate::store::qc::VerdictRow::shown);
    let part = st.store.get_part(&info.part_serial).await?;
    let mut levels = vec![];
    if let Some(job) = &info.job_id {
        for m in st
            .store
            .list_measurements(None, Some(job), None, 200)
            .await?
        {
            if let (Some(x), Some(k)) = (f(&m.summary["xpeak_m"]), f(&m.summary["keff_n_per_m"])) {
                levels.push((x, k));
            }
        }
    }
    if levels.is_empty() {
        if let (Some(x), Some(k)) = (
            f(&doc["large_signal"]["xpeak_m"]),
            f(&doc["large_signal"]["keff_n_per_m"]),
        ) {
            levels.push((x, k));
        }
    }
    levels.sort_by(|a, b| a.0.total_cmp(&b.0));

    let mut s = String::new();
    let serial = esc(&info.part_serial);
    let _ = write!(
        s,
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Report {serial} {}</title><style>{STYLE}</style></head><body>",
        esc(&info.id)
    );
    let _ = write!(
        s,
        "<h1>Suspension test report: part {serial}</h1><p class=\"muted\">Springbench {}, made {}</p>",
        esc(crate::VERSION),
        esc(&crate::store::now())
    );
    // Identity and verdict side by side.
    let kind = part
        .as_ref()
        .and_then(|p| p.kind.clone())
        .unwrap_or_else(|| "not given".into());
    let target = info
        .target_xpeak_m
        .map(|x| format!("{:.3} mm", x * 1e3))
        .unwrap_or_else(|| "\u{2013}".into());
    let _ = write!(
        s,
        "<div class=\"two\"><section id=\"identity\"><h2>Part and measurement</h2><table>\
         <tr><th>part</th><td class=\"mono\">{serial}</td></tr><tr><th>kind</th><td>{}</td></tr>\
         <tr><th>measurement</th><td class=\"mono\">{}</td></tr><tr><th>measured</th><td>{}{} ({})</td></tr>\
         <tr><th>target Xpeak</th><td>{target}</td></tr><tr><th>result from</th><td>{}</td></tr></table></section>",
        esc(&kind),
        esc(&info.id),
        esc(&info.created_at),
        info.bench_id
            .as_deref()
            .map(|b| format!(" on {}", esc(b)))
            .unwrap_or_default(),
        esc(&info.source),
        esc(&source)
    );
    s.push_str("<section id=\"verdict\"><h2>Verdict and limits</h2>");
    match &verdict {
        None => s.push_str("<p class=\"muted\">Not judged: measured without a QC recipe.</p>"),
        Some(v) => {
            let (word, cls) = match v.verdict.as_str() {
                "pass" => ("PASS", "pass"),
                "fail" => ("FAIL", "fail-w"),
                "invalid" => ("INVALID", "invalid"),
                _ => ("NO LIMITS", ""),
            };
            let _ = write!(
                s,
                "<p><span class=\"word {cls}\">{word}</span> recipe {} version {}</p>",
                esc(&v.recipe_name),
                v.recipe_version
            );
            let detail = v.verdict_detail();
            if let Err(e) = &detail {
                // Another software version's, or damaged: said, never a
                // table that looks complete.
                let _ = write!(
                    s,
                    "<p>The verdict's detail does not read here: {}</p>",
                    esc(e)
                );
            }
            let detail = detail.ok();
            for r in detail.iter().flat_map(|d| &d.invalid_reasons) {
                let _ = write!(
                    s,
                    "<p>{}: {}</p>",
                    esc(r.code.replace('_', " ").as_str()),
                    esc(&r.detail)
                );
            }
            s.push_str(
                "<table><tr><th>parameter</th><th>value</th><th>limits</th><th>result</th></tr>",
            );
            for p in detail.iter().flat_map(|d| &d.parameters) {
                let unit = p.unit.as_str();
                let (du, k) = display(unit);
                let name = match (p.name.as_str(), p.x_m) {
                    ("kx_mask", Some(x)) => format!("K(x) mask at {:.3} mm", x * 1e3),
                    (n, _) => n.to_string(),
                };
                let result = match p.result {
                    crate::qc::ParamResult::Pass => "pass",
                    crate::qc::ParamResult::Fail => "fail",
                    crate::qc::ParamResult::NotJudged => "not_judged",
                };
                // An invalid measurement is never judged: its values are
                // shown as measured, marked so (issue 35).
                let shown = match (v.verdict.as_str(), result) {
                    ("invalid", _) => "as measured, not judged",
                    (_, "not_judged") => "no limits",
                    (_, r) => r,
                };
                let _ = write!(
                    s,
                    "<tr class=\"{}\"><td>{}</td><td class=\"num\">{} {}</td><td>{}</td><td>{}</td></tr>",
                    esc(result),
                    esc(&name),
                    sig(p.value * k, 5),
                    esc(du),
                    esc(&limits(p.lower, p.upper, unit)),
                    esc(shown)
                );
            }
            s.push_str("</table>");
        }
    }
    s.push_str("</section></div>");
    s.push_str(&parameter_table(&doc));
    s.push_str("<section id=\"plots\"><h2>Curves over the measured (valid) range</h2><div class=\"plots\">");
    for p in plots(&doc, &levels) {
        s.push_str(&big(&p));
    }
    s.push_str("</div></section>");
    // Traceability.
    let trace = verdict.as_ref().map(|v| &v.traceability);
    let cal = trace
        .map(|t| &t["calibration"])
        .filter(|c| !c.is_null())
        .map(|c| c.to_string())
        .unwrap_or_else(|| "none (virtual bench or import)".into());
    let _ = write!(
        s,
        "<section id=\"traceability\"><h2>Traceability</h2><table>\
         <tr><th>software (measurement)</th><td>{}</td></tr>\
         <tr><th>recipe</th><td>{}</td></tr><tr><th>recipe hash (SHA-256)</th><td class=\"mono\">{}</td></tr>\
         <tr><th>calibration record</th><td>{}</td></tr><tr><th>bench</th><td>{}</td></tr>\
         <tr><th>job</th><td class=\"mono\">{}</td></tr><tr><th>submitted by</th><td>{}</td></tr></table></section></body></html>",
        esc(&info.software_version),
        verdict
            .as_ref()
            .map(|v| format!("{} version {}", esc(&v.recipe_name), v.recipe_version))
            .unwrap_or_else(|| "none".into()),
        verdict
            .as_ref()
            .map(|v| esc(&v.recipe_sha256))
            .unwrap_or_else(|| "\u{2013}".into()),
        esc(&cal),
        esc(info.bench_id.as_deref().unwrap_or("\u{2013}")),
        esc(info.job_id.as_deref().unwrap_or("\u{2013}")),
        esc(trace
            .and_then(|t| t["submitted_by"].as_str())
            .unwrap_or("\u{2013}")),
    );
    Ok(s)
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}/report", tag = "measurements",
    summary = "The printable report of a measurement (HTML, A4 and Letter print stylesheet, inline SVG plots, no script): part identity, verdict and limits, parameters with units, uncertainties and validity, K(x), C(x), F(x), Keff(Xpeak), traceability; from the headline fit.",
    params(("id" = String, Path, description = "Measurement id")),
    responses(
        (status = 200, description = "The report", content_type = "text/html", body = String),
        (status = 404, description = "No such measurement")))]
pub async fn report(State(st): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    Ok(page_response(html(&st, &id).await?))
}

#[utoipa::path(get, path = "/api/v1/long-term-tests/{id}/report.html", tag = "jobs",
    summary = "The printable report of a long-term test (HTML, A4 and Letter print stylesheet, inline SVG plots, no script): part, bench, plan, state and failure, the fitted ageing law with standard errors and its state, the prediction and its band, the K(x) family, K(0), Keff and f0 against test time with the law's curve and band, the intervals with their ambient conditions, the events, traceability.",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 200, description = "The report", content_type = "text/html", body = String),
        (status = 404, description = "No such long-term test")))]
pub async fn long_term_report(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    Ok(page_response(longterm::html(&st, &id).await?))
}

/// A report page with its own policy: its styles only, nothing loaded,
/// nothing run.
fn page_response(body: String) -> Response {
    (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/html; charset=utf-8"),
            ),
            // Its own styles only; nothing is loaded, nothing runs.
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static("default-src 'none'; style-src 'unsafe-inline'"),
            ),
        ],
        body,
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::format::with_se;
    use super::*;

    #[test]
    fn values_are_rounded_to_their_uncertainty_with_the_unit_after_the_error() {
        assert_eq!(
            with_se(3.92149, Some(0.01234), "N/mm"),
            "3.921 \u{b1} 0.012 N/mm"
        );
        assert_eq!(
            with_se(2433.26, Some(0.26), "N/m"),
            "2433.26 \u{b1} 0.26 N/m"
        );
        assert_eq!(with_se(12345.0, Some(150.0), ""), "12350 \u{b1} 150");
        assert_eq!(with_se(5.99851, None, ""), "5.999");
        assert_eq!(limits(None, Some(0.1), "N"), "\u{2264} 0.1 N");
        assert_eq!(
            limits(Some(1000.0), Some(8000.0), "N/m"),
            "1 \u{2026} 8 N/mm"
        );
        assert_eq!(limits(Some(2.0), None, "1"), "\u{2265} 2");
    }

    /// Issue 22: the printable report shows each headline value's state as
    /// the result document states it (before: "valid" for every value, a
    /// null k0 and a null Keff at the target left out without a word).
    #[test]
    fn the_parameters_carry_the_states_of_the_result_document() {
        let why_k0 = "the fit gave k0 = -5.0000e0 N/m <= 0: no physical stiffness";
        let why_noise = "the measurement's noise floor is 93.0 % of the inertia force";
        let why_far = "Keff at the target 8.000 mm is judged over -8.0 .. 8.0 mm, 1500 % of the measured range's half-span beyond it";
        let doc = serde_json::json!({
            "small_signal": {
                "f0_hz": null, "k0_n_per_m": null, "r_ns_per_m": 1.2, "q": null,
                "k0_se_n_per_m": 3.0, "r_se_ns_per_m": 0.01, "misfit_percent": 2.0, "reliable": true,
                "validity": {
                    "f0_hz": {"state": "not_determined", "reason": why_k0},
                    "k0_n_per_m": {"state": "not_determined", "reason": why_k0, "fit_value": -5.0},
                    "r_ns_per_m": {"state": "valid"},
                    "q": {"state": "not_determined", "reason": why_k0}
                }
            },
            "large_signal": {
                "keff_n_per_m": 2500.0, "xpeak_m": 0.0005, "resonance_hz": 35.0,
                "moving_mass_kg": 0.05, "target_xpeak_m": 0.008, "keff_at_target_n_per_m": null,
                "validity": {
                    "resonance_hz": {"state": "unreliable", "reason": why_noise},
                    "keff_n_per_m": {"state": "unreliable", "reason": why_noise},
                    "keff_at_target_n_per_m": {"state": "not_determined", "reason": why_far}
                }
            },
            "stiffness": {
                "coefficients_n_per_m_pow_i_plus_1": [2400.0, 1.0e5],
                "valid_range_m": [-0.0005, 0.0005], "r_ns_per_m": -0.4,
                "validity": {
                    "k_of_x": {"state": "unreliable", "reason": why_noise},
                    "r_ns_per_m": {"state": "not_determined", "reason": "the fit gave R = -4.0000e-1 N s/m <= 0: no physical damping", "fit_value": -0.4}
                }
            },
            "model": {"model_error_percent": 10.0, "noise_floor_percent": 93.0}
        });
        let t = parameter_table(&doc);
        let row = |name: &str| -> String {
            let i = t
                .find(&format!("<td>{}</td>", esc(name)))
                .unwrap_or_else(|| panic!("{name} in {t}"));
            let j = t[..i].rfind("<tr").unwrap();
            let k = i + t[i..].find("</tr>").unwrap();
            t[j..k].to_string()
        };
        let k0 = row("stiffness k0 (small signal)");
        assert!(
            k0.contains("not determined")
                && k0.contains(&esc(&format!("NOT DETERMINED: {why_k0}"))),
            "{k0}"
        );
        assert!(k0.contains("class=\"marked\""), "{k0}");
        let fit = row("stiffness k0 (small signal): fit value (diagnostic, not a measurement)");
        assert!(fit.contains("-0.005 N/mm"), "{fit}");
        let kt = row("Keff at the target Xpeak (judged by QC)");
        assert!(
            kt.contains(&esc(&format!("NOT DETERMINED: {why_far}"))),
            "{kt}"
        );
        let keff = row("effective stiffness Keff at Xpeak");
        assert!(
            keff.contains("2.5 N/mm") && keff.contains(&esc(&format!("UNRELIABLE: {why_noise}"))),
            "{keff}"
        );
        let r = row("mechanical resistance R (large signal)");
        assert!(
            r.contains(">not determined<") && !r.contains("-0.4 "),
            "{r}"
        );
        let k = row("K(x) coefficient k0");
        assert!(
            k.contains("UNRELIABLE") && k.contains("class=\"marked\""),
            "{k}"
        );
        let rs = row("mechanical resistance R (small signal)");
        assert!(
            rs.contains("<td>valid</td>") && !rs.contains("marked"),
            "{rs}"
        );
    }
}
