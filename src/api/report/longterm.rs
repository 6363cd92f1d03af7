//! The printable report of a long-term test (issue 32, decision 0131): the
//! same self-contained HTML page as a measurement's (inline styles and SVG
//! plots, no script, no other request, the print stylesheet for A4 and
//! Letter). It holds the part, the bench, the test's plan, its state and
//! what stopped it, the fitted ageing law with its parameters, standard
//! errors and state (a law that is not valid reads so on every number), the
//! prediction and its band, the K(x) family of the intervals, K(0), Keff
//! and f0 against test time with the law's curve and band, the intervals'
//! table with their ambient conditions, the events and the traceability.
//! The numbers come from the long-term document the API serves
//! (`Store::long_term_document`) and each interval's measurement, as the
//! series CSV reads them.

use super::format::{esc, sig, with_se};
use super::plots::{big, horner, CURVE_POINTS};
use super::STYLE;
use crate::api::problem::{ApiResult, Problem};
use crate::api::AppState;
use crate::diagnose::svg::{xy_chart, Curve};
use crate::identify::validity::{HeadlineValidity, State};
use crate::identify::Report;
use crate::store::longterm::{AmbientSource, LongTermInterval};
use crate::store::longterm_view::{spec_of, LongTermDocument};
use crate::store::MeasurementReads;
use springbench_core::ageing::series::{AgeingDocument, LawDoc};
use springbench_core::ageing::Estimate;
use std::fmt::Write;

const DASH: &str = "\u{2013}";

/// The state of a value as people read it: "valid", or the state in
/// capitals with its reason.
fn state_text(v: &HeadlineValidity) -> String {
    match v.state {
        State::Valid => "valid".into(),
        s => format!(
            "{}: {}",
            s.as_str().replace('_', " ").to_uppercase(),
            v.reason.as_deref().unwrap_or("no reason given")
        ),
    }
}

fn hours(s: f64) -> String {
    format!("{} h", sig(s / 3600.0, 5))
}

/// An estimate in a display unit (`scale` from SI), rounded to its error.
fn est(e: &Estimate, unit: &str, scale: f64) -> String {
    with_se(e.value * scale, Some(e.se * scale), unit)
}

/// Each interval's measurement report (None when it is not stored or does
/// not read), and the software version that made it.
type Measured = (Option<Report>, Option<String>);

/// The report page of long-term test `id`.
pub async fn html(st: &AppState, id: &str) -> ApiResult<String> {
    let doc = st
        .store
        .long_term_document(id)
        .await?
        .ok_or_else(|| Problem::not_found("long-term test", id))?;
    let mut measured: Vec<Measured> = vec![];
    for iv in &doc.intervals {
        measured.push(match st.store.get_measurement(&iv.measurement_id).await? {
            Some((info, r, _)) => (
                r.and_then(|r| serde_json::from_value::<Report>(r).ok()),
                Some(info.software_version),
            ),
            None => (None, None),
        });
    }
    Ok(page(&doc, &measured, &crate::store::now()))
}

/// The page of a long-term document and its intervals' measurements
/// (pure: the HTTP handler reads them, the tests give them).
pub(super) fn page(doc: &LongTermDocument, measured: &[Measured], made: &str) -> String {
    let j = &doc.job;
    let ad: Option<&AgeingDocument> = doc.state.as_ref().and_then(|s| s.document.as_ref());
    let mut s = String::new();
    let serial = esc(&j.part_serial);
    let _ = write!(
        s,
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Long-term test {serial} {}</title><style>{STYLE}</style></head><body>",
        esc(&j.id)
    );
    let _ = write!(
        s,
        "<h1>Long-term test report: part {serial}</h1><p class=\"muted\">Springbench {}, made {}{}</p>",
        esc(crate::VERSION),
        esc(made),
        doc.station_id
            .as_deref()
            .map(|st| format!(", the fleet center\u{2019}s copy from station {}", esc(st)))
            .unwrap_or_default()
    );
    s.push_str(&plan_section(doc));
    s.push_str(&law_section(ad));
    s.push_str(&plots_section(ad));
    s.push_str(&intervals_section(doc, measured));
    s.push_str(&events_section(doc));
    s.push_str(&trace_section(doc, measured));
    s.push_str("</body></html>");
    s
}

fn plan_section(doc: &LongTermDocument) -> String {
    let j = &doc.job;
    let spec = spec_of(j);
    let mut s = String::from(
        "<div class=\"two\"><section id=\"test\"><h2>Part, bench and plan</h2><table>",
    );
    let row = |s: &mut String, k: &str, v: String| {
        let _ = write!(s, "<tr><th>{k}</th><td>{v}</td></tr>");
    };
    row(
        &mut s,
        "part",
        format!("<span class=\"mono\">{}</span>", esc(&j.part_serial)),
    );
    if let Some(kind) = spec.and_then(|p| p.measurement.part.kind.as_deref()) {
        row(&mut s, "kind", esc(kind));
    }
    row(&mut s, "bench", esc(&j.bench_id));
    row(
        &mut s,
        "test",
        format!("<span class=\"mono\">{}</span>", esc(&j.id)),
    );
    if let Some(p) = spec {
        row(
            &mut s,
            "plan",
            format!(
                "{} long, a measurement every {} min ({} intervals)",
                hours(p.duration_s),
                sig(p.interval_s / 60.0, 5),
                doc.intervals_planned
            ),
        );
        let st = &p.stimulus;
        row(
            &mut s,
            "stimulus",
            format!(
                "{}{}",
                match st.kind {
                    crate::job::StimulusKind::Sine => format!(
                        "sine at the part\u{2019}s resonance, {} mm peak, held at its {}",
                        sig(st.start_level_m() * 1e3, 4),
                        match st.hold {
                            crate::job::Hold::Excursion => "excursion",
                            crate::job::Hold::Drive => "drive level",
                        }
                    ),
                    crate::job::StimulusKind::Wav => format!(
                        "WAV file {} as a loop, target {} mm RMS displacement",
                        st.wav_id.as_deref().unwrap_or("?"),
                        sig(st.start_level_m() * 1e3, 4)
                    ),
                    crate::job::StimulusKind::Noise => {
                        let [lo, hi] = st.band_hz.unwrap_or_default();
                        format!(
                            "band-limited noise, {} to {} Hz, target {} mm RMS displacement",
                            sig(lo, 4),
                            sig(hi, 4),
                            sig(st.start_level_m() * 1e3, 4)
                        )
                    }
                },
                match (st.on_s, st.off_s) {
                    (Some(on), Some(off)) =>
                        format!(", {} s on / {} s off", sig(on, 4), sig(off, 4)),
                    _ => String::new(),
                }
            ),
        );
        row(
            &mut s,
            "accelerated",
            if p.accelerated {
                "yes: the stimulus applied faster than real time on the virtual bench, each measurement simulated in full".into()
            } else {
                "no: real time".into()
            },
        );
        row(
            &mut s,
            "failure limits",
            format!(
                "K(0) change {} %, excursion growth {} %",
                sig(p.failure_limits.k0_change_percent, 4),
                sig(p.failure_limits.xpeak_runaway_percent, 4)
            ),
        );
    }
    s.push_str("</table></section><section id=\"state\"><h2>State</h2><table>");
    row(&mut s, "state", format!("<b>{}</b>", esc(j.state.as_str())));
    row(
        &mut s,
        "intervals",
        format!("{} of {}", doc.intervals.len(), doc.intervals_planned),
    );
    if let Some(st) = &doc.state {
        row(&mut s, "test time", hours(st.clock_s));
        row(
            &mut s,
            "load taken",
            format!("{} kJ", sig(st.load_j / 1e3, 5)),
        );
    }
    row(&mut s, "created", esc(&j.created_at));
    if let Some(t) = &j.finished_at {
        row(&mut s, "finished", esc(t));
    }
    if let Some(p) = &doc.user_pause {
        row(
            &mut s,
            "paused",
            format!(
                "by {} at {}",
                esc(p.by.as_deref().unwrap_or("open access")),
                esc(&p.at)
            ),
        );
    }
    if let Some(p) = &j.problem {
        let _ = write!(
            s,
            "<tr class=\"fail\"><th>problem</th><td id=\"problem\">{}: {}</td></tr>",
            esc(&p.title),
            esc(&p.detail)
        );
    }
    if let Some(f) = doc.state.as_ref().and_then(|s| s.failure.as_ref()) {
        let _ = write!(
            s,
            "<tr class=\"fail\"><th>failure</th><td id=\"failure\">limit <span class=\"mono\">{}</span> at interval {}{}: {}</td></tr>",
            esc(&f.limit),
            f.interval,
            f.at_s.map(|t| format!(" ({})", hours(t))).unwrap_or_default(),
            esc(&f.detail)
        );
    }
    s.push_str("</table></section></div>");
    s
}

fn law_rows(l: &LawDoc) -> Vec<(&'static str, &'static str, String)> {
    let mut rows = vec![
        (
            "k_inf",
            "K\u{221e} (aged, the law\u{2019}s limit)",
            est(&l.k_inf_n_per_m, "N/mm", 1e-3),
        ),
        (
            "break_in_k",
            "break-in loss \u{394}K_b",
            est(&l.break_in_k_n_per_m, "N/mm", 1e-3),
        ),
    ];
    if let Some(e) = &l.break_in_load_j {
        rows.push((
            "break_in_load",
            "break-in load scale E_b",
            est(e, "kJ", 1e-3),
        ));
    }
    rows.push((
        "break_in_time",
        "break-in time scale",
        est(&l.break_in_time_s, "h", 1.0 / 3600.0),
    ));
    rows.push((
        "fatigue_k",
        "fatigue loss \u{394}K_f",
        est(&l.fatigue_k_n_per_m, "N/mm", 1e-3),
    ));
    if let Some(e) = &l.fatigue_load_j {
        rows.push(("fatigue_load", "fatigue load scale E_f", est(e, "kJ", 1e-3)));
    }
    rows.push((
        "fatigue_time",
        "fatigue time scale",
        est(&l.fatigue_time_s, "h", 1.0 / 3600.0),
    ));
    rows.push((
        "scatter",
        "scatter about the law (residual SD)",
        format!("{} N/mm", sig(l.residual_sd_n_per_m / 1e3, 3)),
    ));
    rows.push(("used", "intervals used", format!("{}", l.intervals_used)));
    rows
}

pub(super) fn law_section(ad: Option<&AgeingDocument>) -> String {
    let mut s = String::from("<section id=\"law\"><h2>The fitted ageing law</h2>");
    let Some(l) = ad.and_then(|d| d.law.as_ref()) else {
        let why = match ad {
            Some(d) => format!(
                "No law: {}.",
                esc(d.problem.as_deref().unwrap_or("not fitted"))
            ),
            None => "No law: no interval is finished.".into(),
        };
        let _ = write!(
            s,
            "<p id=\"no-law\" data-state=\"none\">{why}</p></section>"
        );
        return s;
    };
    let d = ad.expect("a law is in a document");
    let valid = l.validity.state == State::Valid;
    let by_load = l.axis == "load_j";
    let _ = write!(
        s,
        "<p>K(0) = K\u{221e} + \u{394}K_b e^(\u{2212}E/E_b) + \u{394}K_f e^(\u{2212}E/E_f), fitted against {}. \
         Values rounded to their standard error (two significant digits of the error).</p>\
         <p id=\"law-state\" data-state=\"{}\">State of the law: <span class=\"word {}\">{}</span></p>",
        if by_load {
            "the accumulated load E"
        } else {
            "test time (the load unknown)"
        },
        l.validity.state.as_str(),
        if valid { "pass" } else { "invalid" },
        esc(&state_text(&l.validity)),
    );
    s.push_str("<table id=\"law-table\"><tr><th>parameter</th><th>value \u{b1} standard error</th><th>state</th></tr>");
    let word = if valid {
        "valid".to_string()
    } else {
        format!(
            "NOT VALID ({})",
            l.validity.state.as_str().replace('_', " ")
        )
    };
    for (key, name, value) in law_rows(l) {
        let _ = write!(
            s,
            "<tr id=\"law-{key}\"{}><td>{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            if valid { "" } else { " class=\"marked\"" },
            esc(name),
            esc(&value),
            esc(&word)
        );
    }
    s.push_str("</table>");
    if let Some(c) = &d.characteristics {
        let _ = write!(
            s,
            "<p id=\"characteristics\">Break-in {} % of the new part\u{2019}s K(0) ({} % of the whole loss), 95 % of it done after {}; fatigue {} %, at {} %/h after break-in{}{}.</p>",
            sig(c.break_in_loss_percent, 3),
            sig(100.0 * c.break_in_share, 3),
            hours(c.break_in_95_time_s),
            sig(c.fatigue_loss_percent, 3),
            sig(c.fatigue_rate_percent_per_h, 3),
            c.mean_power_w
                .map(|w| format!("; the stimulus\u{2019} mean load power {} W", sig(w, 4)))
                .unwrap_or_default(),
            if valid { "" } else { " (from a law that is not valid)" }
        );
    }
    if let Some(x) = &d.large_excursion {
        let _ = write!(s, "<p id=\"large-excursion\">{}</p>", esc(&x.statement));
    }
    if let Some(p) = &d.prediction {
        let pvalid = p.validity.state == State::Valid;
        let _ = write!(
            s,
            "<h2>Prediction at {}{}</h2><table id=\"prediction\" data-state=\"{}\">\
             <tr{m}><th>K(0)</th><td class=\"num\" id=\"prediction-k0\">{}</td></tr>\
             <tr{m}><th>95 % band of a measurement then</th><td class=\"num\" id=\"prediction-band\">{} \u{2026} {} N/mm</td></tr>\
             <tr{m}><th>f0</th><td class=\"num\">{}</td></tr>\
             <tr{m}><th>state</th><td>{}</td></tr></table>",
            hours(p.elapsed_s),
            p.load_j
                .map(|e| format!(" ({} kJ)", sig(e / 1e3, 5)))
                .unwrap_or_default(),
            p.validity.state.as_str(),
            esc(&with_se(p.k0_n_per_m / 1e3, Some(p.k0_se_n_per_m / 1e3), "N/mm")),
            sig(p.k0_band_n_per_m[0] / 1e3, 5),
            sig(p.k0_band_n_per_m[1] / 1e3, 5),
            esc(&with_se(p.f0_hz, Some(p.f0_se_hz), "Hz")),
            esc(&state_text(&p.validity)),
            m = if pvalid { "" } else { " class=\"marked\"" },
        );
    }
    s.push_str("</section>");
    s
}

/// The K(x) family (one curve per interval over its own valid range) and
/// K(0), Keff, f0 against test time with the law's curve and band.
fn plots_section(ad: Option<&AgeingDocument>) -> String {
    let mut s =
        String::from("<section id=\"plots\"><h2>The part over time</h2><div class=\"plots\">");
    let Some(d) = ad.filter(|d| !d.intervals.is_empty()) else {
        s.push_str("<p class=\"muted\">No interval measured yet.</p></div></section>");
        return s;
    };
    let family: Vec<Curve> = d
        .intervals
        .iter()
        .map(|iv| {
            let [lo, hi] = iv.valid_range_m;
            let c = &iv.k_coefficients_n_per_m_pow_i_plus_1;
            let pts = (0..CURVE_POINTS)
                .map(|i| {
                    let x = lo + (hi - lo) * i as f64 / (CURVE_POINTS - 1) as f64;
                    (x * 1e3, horner(c, x) * 1e-3)
                })
                .collect();
            (hours(iv.elapsed_s), pts, false)
        })
        .collect();
    let _ = write!(
        s,
        "<figure id=\"plot-kx\" data-curves=\"{}\">{}</figure>",
        family.len(),
        big(&xy_chart(
            "K(x) over time (each interval over its valid range)",
            "displacement x (mm)",
            "K (N/mm)",
            vec![],
            family,
        ))
    );
    let law = d.law.as_ref();
    let valid = law.is_some_and(|l| l.validity.state == State::Valid);
    let word = match law {
        Some(l) if !valid => format!(
            " \u{2014} NOT VALID ({})",
            l.validity.state.as_str().replace('_', " ")
        ),
        _ => String::new(),
    };
    let h = |t: f64| t / 3600.0;
    for (id, q, title, unit, scale) in [
        ("plot-k0", "k0_n_per_m", "K(0) small-signal", "N/mm", 1e-3),
        ("plot-keff", "keff_n_per_m", "Keff at Xpeak", "N/mm", 1e-3),
        ("plot-f0", "f0_hz", "f0 small-signal", "Hz", 1.0),
    ] {
        let value = |iv: &springbench_core::ageing::series::IntervalValues| match q {
            "k0_n_per_m" => iv.k0_n_per_m,
            "keff_n_per_m" => Some(iv.keff_n_per_m),
            _ => iv.f0_hz,
        };
        let mut curves: Vec<Curve> = vec![(
            format!("measured {title}"),
            d.intervals
                .iter()
                .filter_map(|iv| value(iv).map(|v| (h(iv.elapsed_s), v * scale)))
                .collect(),
            false,
        )];
        if let Some((lc, c)) = d
            .curves
            .as_ref()
            .and_then(|lc| lc.curves.iter().find(|c| c.quantity == q).map(|c| (lc, c)))
        {
            let xs: Vec<f64> = lc.elapsed_s.iter().map(|t| h(*t)).collect();
            let line = |ys: &[f64]| -> Vec<(f64, f64)> {
                xs.iter().zip(ys).map(|(x, y)| (*x, y * scale)).collect()
            };
            curves.push((format!("fitted law{word}"), line(&c.value), !valid));
            curves.push((format!("95 % band, low{word}"), line(&c.band_low), true));
            curves.push((format!("95 % band, high{word}"), line(&c.band_high), true));
        }
        let _ = write!(
            s,
            "<figure id=\"{id}\">{}</figure>",
            big(&xy_chart(
                &format!("{title} against test time"),
                "test time (h)",
                &format!("{title} ({unit})"),
                vec![],
                curves,
            ))
        );
    }
    s.push_str("</div></section>");
    s
}

fn ambient(v: Option<f64>, src: Option<AmbientSource>, show: impl Fn(f64) -> String) -> String {
    match v {
        Some(x) if x.is_finite() => format!(
            "{} ({})",
            show(x),
            match src {
                Some(AmbientSource::Hand) => "by hand",
                Some(AmbientSource::Sensor) => "sensor",
                None => "source unknown",
            }
        ),
        _ => DASH.into(),
    }
}

fn intervals_section(doc: &LongTermDocument, measured: &[Measured]) -> String {
    let mut s = String::from(
        "<section id=\"intervals\"><h2>Intervals</h2><p class=\"muted\">K(0) rounded to its standard error (two significant digits of the error); f0, Keff and the load to 5 significant digits, Xpeak to 4; a value that is not valid is marked with its state.</p>\
         <table id=\"interval-table\"><tr><th>#</th><th>test time</th><th>load</th><th>K(0)</th><th>f0</th><th>Keff</th><th>Xpeak</th><th>air temperature</th><th>relative humidity</th><th>measurement</th></tr>",
    );
    // Why a value is marked: each distinct reason once, under the table.
    let reasons = std::cell::RefCell::new(std::collections::BTreeSet::<String>::new());
    let marked = |v: &HeadlineValidity, text: String| -> String {
        if v.state != State::Valid {
            reasons.borrow_mut().insert(state_text(v));
        }
        match v.state {
            State::Valid => text,
            State::NotDetermined => format!(
                "not determined ({})",
                esc(v.reason.as_deref().unwrap_or(""))
            ),
            st => format!("{text} ({})", st.as_str().replace('_', " ").to_uppercase()),
        }
    };
    for (iv, (r, _)) in doc
        .intervals
        .iter()
        .zip(measured.iter().chain(std::iter::repeat(&(None, None))))
    {
        let ss = r.as_ref().and_then(|r| r.small_signal.as_ref());
        let k0 = match ss {
            Some(ss) => marked(
                &ss.validity.k0_n_per_m,
                ss.k0_n_per_m
                    .map(|k| esc(&with_se(k / 1e3, Some(ss.k0_se_n_per_m / 1e3), "N/mm")))
                    .unwrap_or_else(|| DASH.into()),
            ),
            None => DASH.into(),
        };
        let f0 = match ss {
            Some(ss) => marked(
                &ss.validity.f0_hz,
                ss.f0_hz
                    .map(|f| format!("{} Hz", sig(f, 5)))
                    .unwrap_or_else(|| DASH.into()),
            ),
            None => DASH.into(),
        };
        let (keff, xpeak) = match r {
            Some(r) => (
                marked(
                    &r.large_signal.validity.keff_n_per_m,
                    format!("{} N/mm", sig(r.large_signal.keff_n_per_m / 1e3, 5)),
                ),
                format!("{} mm", sig(r.large_signal.xpeak_m * 1e3, 4)),
            ),
            None => (DASH.into(), DASH.into()),
        };
        let _ = write!(
            s,
            "<tr data-index=\"{}\"><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{} kJ</td><td class=\"num k0\">{k0}</td><td class=\"num\">{f0}</td><td class=\"num\">{keff}</td><td class=\"num\">{xpeak}</td><td>{}</td><td>{}</td><td class=\"mono\">{}</td></tr>",
            iv.index,
            iv.index,
            hours(iv.elapsed_s),
            sig(iv.load_j / 1e3, 5),
            esc(&ambient(iv.temperature_k, iv.temperature_source, |k| format!("{:.1} \u{b0}C", k - 273.15))),
            esc(&ambient(iv.relative_humidity_percent, iv.humidity_source, |h| format!("{h:.1} %"))),
            esc(&iv.measurement_id),
        );
    }
    s.push_str("</table>");
    let reasons = reasons.into_inner();
    if !reasons.is_empty() {
        s.push_str("<p id=\"interval-reasons\" class=\"muted\">Marked values, as their measurements state them:</p><ul>");
        for r in &reasons {
            let _ = write!(s, "<li>{}</li>", esc(r));
        }
        s.push_str("</ul>");
    }
    s.push_str("</section>");
    s
}

fn events_section(doc: &LongTermDocument) -> String {
    let mut s = String::from("<section id=\"events\"><h2>Events</h2>");
    if doc.events.is_empty() {
        s.push_str(
            "<p class=\"muted\" id=\"no-events\">No pause, resumption or failure.</p></section>",
        );
        return s;
    }
    s.push_str("<table><tr><th>test time</th><th>event</th><th>what</th><th>when</th></tr>");
    for e in &doc.events {
        let kind = serde_json::to_value(e.kind)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default();
        let cause = e
            .cause
            .and_then(|c| serde_json::to_value(c).ok())
            .and_then(|v| v.as_str().map(|c| format!(" ({c})")))
            .unwrap_or_default();
        let fail = matches!(kind.as_str(), "failure" | "stopped");
        let _ = write!(
            s,
            "<tr data-kind=\"{}\"{}><td class=\"num\">{}</td><td>{}{}</td><td>{}</td><td>{}</td></tr>",
            esc(&kind),
            if fail { " class=\"fail\"" } else { "" },
            e.elapsed_s.map(hours).unwrap_or_else(|| DASH.into()),
            esc(&kind),
            esc(&cause),
            esc(&e.detail),
            esc(e.at.as_deref().unwrap_or(DASH)),
        );
    }
    s.push_str("</table></section>");
    s
}

fn trace_section(doc: &LongTermDocument, measured: &[Measured]) -> String {
    let j = &doc.job;
    let mut versions: Vec<&str> = measured.iter().filter_map(|m| m.1.as_deref()).collect();
    versions.sort_unstable();
    versions.dedup();
    let ids: Vec<String> = doc
        .intervals
        .iter()
        .map(|iv: &LongTermInterval| format!("{}: {}", iv.index, esc(&iv.measurement_id)))
        .collect();
    format!(
        "<section id=\"traceability\"><h2>Traceability</h2><table>\
         <tr><th>software (report)</th><td>{}</td></tr>\
         <tr><th>software (measurements)</th><td>{}</td></tr>\
         <tr><th>test (job) id</th><td class=\"mono\">{}</td></tr>\
         <tr><th>request hash (SHA-256)</th><td class=\"mono\">{}</td></tr>\
         <tr><th>measurement ids</th><td class=\"mono\" id=\"measurement-ids\">{}</td></tr></table></section>",
        esc(crate::VERSION),
        if versions.is_empty() {
            DASH.to_string()
        } else {
            esc(&versions.join(", "))
        },
        esc(&j.id),
        esc(&j.request_sha256),
        if ids.is_empty() {
            DASH.to_string()
        } else {
            ids.join("<br>")
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A law that is not valid reads so on every parameter, in its state
    /// line and on its prediction: never as a valid number.
    #[test]
    fn a_law_that_is_not_valid_reads_so_on_every_number() {
        let why = "the break-in scale is not resolved by the intervals";
        let e = |v: f64, se: f64| serde_json::json!({"value": v, "se": se});
        let bad = serde_json::json!({"state": "unreliable", "reason": why});
        let doc: AgeingDocument = serde_json::from_value(serde_json::json!({
            "intervals": [], "tracks": [],
            "law": {"axis": "load_j", "k_inf_n_per_m": e(1234.5678, 12.345),
                "break_in_k_n_per_m": e(150.0, 40.0), "fatigue_k_n_per_m": e(80.0, 30.0),
                "break_in_load_j": e(5000.0, 900.0), "fatigue_load_j": e(90000.0, 20000.0),
                "break_in_time_s": e(1800.0, 300.0), "fatigue_time_s": e(36000.0, 7200.0),
                "residual_sd_n_per_m": 3.0, "intervals_used": 7, "validity": bad},
            "prediction": {"elapsed_s": 7200.0, "k0_n_per_m": 1300.0, "k0_se_n_per_m": 20.0,
                "k0_band_n_per_m": [1250.0, 1350.0], "f0_hz": 30.0, "f0_se_hz": 0.2,
                "validity": bad}
        }))
        .unwrap();
        let s = law_section(Some(&doc));
        assert!(
            s.contains("<p id=\"law-state\" data-state=\"unreliable\">")
                && s.contains(&format!("UNRELIABLE: {why}")),
            "{s}"
        );
        let rows = s.matches("<tr id=\"law-").count();
        assert_eq!(rows, 9, "{s}");
        assert_eq!(
            s.matches("<td>NOT VALID (unreliable)</td>").count(),
            rows,
            "{s}"
        );
        assert_eq!(s.matches("class=\"marked\"").count(), rows + 4, "{s}");
        // K_inf rounded to its error: 1.234 5678 +- 0.012 345 N/mm.
        assert!(s.contains("1.235 \u{b1} 0.012 N/mm"), "{s}");
        assert!(s.contains("<table id=\"prediction\" data-state=\"unreliable\">"));
        assert!(!s.contains(">valid<"), "{s}");
        // The same law, valid: no mark.
        let mut ok = doc.clone();
        for v in [
            &mut ok.law.as_mut().unwrap().validity,
            &mut ok.prediction.as_mut().unwrap().validity,
        ] {
            *v = HeadlineValidity::default();
        }
        let s = law_section(Some(&ok));
        assert!(!s.contains("NOT VALID") && !s.contains("marked"), "{s}");
        assert_eq!(s.matches("<td>valid</td>").count(), 9 + 1, "{s}"); // and the prediction
                                                                       // No law: said, with the series' reason.
        let mut none = doc;
        none.law = None;
        none.prediction = None;
        none.problem = Some("7 intervals with K(0) are needed, 2 given".into());
        let s = law_section(Some(&none));
        assert!(
            s.contains("No law: 7 intervals with K(0) are needed, 2 given."),
            "{s}"
        );
    }
}
