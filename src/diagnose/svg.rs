//! Hand-written SVG plots of a diagnosis (no plotting crate). Each plot is
//! drawn from the `diagnostics` document alone, so the daemon can serve
//! stored diagnoses without the recordings.

use serde_json::Value;
use std::fmt::Write;

pub const PLOT_NAMES: &[&str] = &[
    "model_vs_measurement",
    "residual_over_time",
    "residual_vs_x",
    "residual_vs_v",
    "residual_spectrum",
    "ladder",
    "small_signal",
];

const W: f64 = 720.0;
const H: f64 = 420.0;
const L: f64 = 80.0;
const R: f64 = 20.0;
const T: f64 = 40.0;
const B: f64 = 60.0;
const COLORS: [&str; 5] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];

struct Series {
    name: String,
    points: Vec<(f64, f64)>,
    dashed: bool,
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return vec![lo];
    }
    let raw = (hi - lo) / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + 1e-9 * step {
        out.push(if t.abs() < 1e-12 * step { 0.0 } else { t });
        t += step;
    }
    out
}

fn fmt_num(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.4}")
    }
}

struct Chart<'a> {
    title: &'a str,
    xlabel: &'a str,
    ylabel: &'a str,
    log_x: bool,
    log_y: bool,
    bands: Vec<(f64, f64, String)>,
}

fn line_chart(c: &Chart, series: &[Series]) -> String {
    let tx = |v: f64| if c.log_x { v.max(1e-300).log10() } else { v };
    let ty = |v: f64| if c.log_y { v.max(1e-300).log10() } else { v };
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .filter(|p| (!c.log_x || p.0 > 0.0) && (!c.log_y || p.1 > 0.0));
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        x0 = x0.min(tx(x));
        x1 = x1.max(tx(x));
        y0 = y0.min(ty(y));
        y1 = y1.max(ty(y));
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-300 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-300 {
        y1 = y0 + 1.0;
    }
    let pad = 0.05 * (y1 - y0);
    let (y0, y1) = (y0 - pad, y1 + pad);
    let px = |v: f64| L + (tx(v) - x0) / (x1 - x0) * (W - L - R);
    let py = |v: f64| H - B - (ty(v) - y0) / (y1 - y0) * (H - T - B);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(s, r#"<rect width="{W}" height="{H}" fill="white"/>"#);
    let _ = write!(
        s,
        r#"<text x="{}" y="24" text-anchor="middle" font-size="15">{}</text>"#,
        W / 2.0,
        esc(c.title)
    );
    for (lo, hi, label) in &c.bands {
        let (a, b) = (px(*lo).clamp(L, W - R), px(*hi).clamp(L, W - R));
        if b > a {
            let _ = write!(
                s,
                r##"<rect x="{a:.1}" y="{T}" width="{:.1}" height="{}" fill="#f0e0a0" opacity="0.5"/><text x="{a:.1}" y="{}" font-size="10" fill="#806000">{}</text>"##,
                b - a,
                H - T - B,
                T + 12.0,
                esc(label)
            );
        }
    }
    // Axes and ticks.
    let _ = write!(
        s,
        r#"<rect x="{L}" y="{T}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        W - L - R,
        H - T - B
    );
    let ticks = |lo: f64, hi: f64, log: bool| -> Vec<(f64, String)> {
        if log {
            nice_ticks(
                lo.floor(),
                hi.ceil(),
                ((hi - lo).ceil() as usize).clamp(1, 8),
            )
            .into_iter()
            .filter(|t| *t >= lo && *t <= hi)
            .map(|t| (10f64.powf(t), fmt_num(10f64.powf(t))))
            .collect()
        } else {
            nice_ticks(lo, hi, 6)
                .into_iter()
                .map(|t| (t, fmt_num(t)))
                .collect()
        }
    };
    for (v, label) in ticks(x0, x1, c.log_x) {
        let x = px(v);
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{T}" x2="{x:.1}" y2="{}" stroke="#e0e0e0"/><text x="{x:.1}" y="{}" text-anchor="middle">{label}</text>"##,
            H - B,
            H - B + 16.0
        );
    }
    for (v, label) in ticks(y0, y1, c.log_y) {
        let y = py(v);
        let _ = write!(
            s,
            r##"<line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#e0e0e0"/><text x="{}" y="{:.1}" text-anchor="end">{label}</text>"##,
            W - R,
            L - 6.0,
            y + 4.0
        );
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
        (L + W - R) / 2.0,
        H - 18.0,
        esc(c.xlabel)
    );
    let _ = write!(
        s,
        r#"<text x="18" y="{}" text-anchor="middle" transform="rotate(-90 18 {})">{}</text>"#,
        (T + H - B) / 2.0,
        (T + H - B) / 2.0,
        esc(c.ylabel)
    );
    for (i, se) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let mut d = String::new();
        let mut pen_down = false;
        for &(x, y) in &se.points {
            let ok =
                x.is_finite() && y.is_finite() && (!c.log_x || x > 0.0) && (!c.log_y || y > 0.0);
            if !ok {
                pen_down = false;
                continue;
            }
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if pen_down { "L" } else { "M" },
                px(x),
                py(y)
            );
            pen_down = true;
        }
        let dash = if se.dashed {
            r#" stroke-dasharray="6,4""#
        } else {
            ""
        };
        let _ = write!(
            s,
            r#"<path d="{d}" fill="none" stroke="{color}" stroke-width="1.5"{dash}/>"#
        );
        let ly = T + 16.0 + 16.0 * i as f64;
        let _ = write!(
            s,
            r#"<line x1="{}" y1="{ly}" x2="{}" y2="{ly}" stroke="{color}" stroke-width="2"{dash}/><text x="{}" y="{}">{}</text>"#,
            W - R - 200.0,
            W - R - 176.0,
            W - R - 170.0,
            ly + 4.0,
            esc(&se.name)
        );
    }
    s.push_str("</svg>\n");
    s
}

fn nums(v: &Value) -> Vec<f64> {
    v.as_array()
        .map(|a| a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
        .unwrap_or_default()
}

fn zip(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    x.iter().copied().zip(y.iter().copied()).collect()
}

fn series(name: &str, x: &[f64], y: &[f64], dashed: bool) -> Series {
    Series {
        name: name.into(),
        points: zip(x, y),
        dashed,
    }
}

fn ladder_chart(d: &Value) -> String {
    let steps = d["ladder"].as_array().cloned().unwrap_or_default();
    let nf = d["noise_floor_percent"].as_f64().unwrap_or(0.0);
    let vals: Vec<(String, f64, f64)> = steps
        .iter()
        .map(|s| {
            let eff: Vec<String> = s["effects"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|e| e.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default();
            let label = match s["added"].as_str() {
                Some(a) => format!("+ {a}"),
                None if eff.is_empty() => "base model".into(),
                None => format!("base + {}", eff.join(", ")),
            };
            (
                label,
                s["model_error_percent"].as_f64().unwrap_or(0.0),
                s["cv_residual_percent"].as_f64().unwrap_or(0.0),
            )
        })
        .collect();
    let ymax = vals
        .iter()
        .map(|v| v.2.max(v.1))
        .fold(nf, f64::max)
        .max(1e-9)
        * 1.15;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12"><rect width="{W}" height="{H}" fill="white"/>"#
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="24" text-anchor="middle" font-size="15">Model ladder: error at each step (held-out data)</text>"#,
        W / 2.0
    );
    let _ = write!(
        s,
        r#"<rect x="{L}" y="{T}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        W - L - R,
        H - T - B
    );
    let py = |v: f64| H - B - v / ymax * (H - T - B);
    for t in nice_ticks(0.0, ymax, 5) {
        let _ = write!(
            s,
            r##"<line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#e0e0e0"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
            W - R,
            L - 6.0,
            py(t) + 4.0,
            fmt_num(t),
            y = py(t)
        );
    }
    let n = vals.len().max(1) as f64;
    let slot = (W - L - R) / n;
    for (i, (label, me, res)) in vals.iter().enumerate() {
        let x = L + slot * i as f64;
        let bw = slot * 0.35;
        let _ = write!(
            s,
            r##"<rect x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{}"/><rect x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{}"/><text x="{:.1}" y="{}" text-anchor="middle">{}</text><text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="10">{:.2} %</text>"##,
            x + slot * 0.12,
            py(*me),
            H - B - py(*me),
            COLORS[1],
            x + slot * 0.12 + bw,
            py(*res),
            H - B - py(*res),
            COLORS[0],
            x + slot / 2.0,
            H - B + 16.0,
            esc(label),
            x + slot * 0.12 + bw / 2.0,
            py(*me) - 4.0,
            me
        );
    }
    let _ = write!(
        s,
        r##"<line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="black" stroke-dasharray="6,4"/><text x="{}" y="{:.1}" text-anchor="end">noise floor {nf:.2} %</text>"##,
        W - R,
        W - R - 4.0,
        py(nf) - 4.0,
        y = py(nf)
    );
    let _ = write!(
        s,
        r##"<rect x="{}" y="{}" width="12" height="10" fill="{}"/><text x="{}" y="{}">model error (%)</text><rect x="{}" y="{}" width="12" height="10" fill="{}"/><text x="{}" y="{}">residual (%)</text>"##,
        L + 10.0,
        H - 30.0,
        COLORS[1],
        L + 26.0,
        H - 21.0,
        L + 160.0,
        H - 30.0,
        COLORS[0],
        L + 176.0,
        H - 21.0
    );
    s.push_str("</svg>\n");
    s
}

/// Renders the plot `name` from a diagnostics document.
pub fn render(d: &Value, name: &str) -> Option<String> {
    let c = &d["comparison"];
    match name {
        "model_vs_measurement" => {
            let det = &c["detail"];
            let t = nums(&det["t_s"]);
            Some(line_chart(
                &Chart {
                    title: "Force balance: measured m x'' against the models (largest excursion)",
                    xlabel: "time (s)",
                    ylabel: "force (N)",
                    log_x: false,
                    log_y: false,
                    bands: vec![],
                },
                &[
                    series("measured m x''", &t, &nums(&det["measured_force_n"]), false),
                    series("final model", &t, &nums(&det["modelled_force_n"]), true),
                    series("base model", &t, &nums(&det["base_modelled_force_n"]), true),
                ],
            ))
        }
        "residual_over_time" => {
            let e = &c["envelope"];
            let t = nums(&e["t_s"]);
            Some(line_chart(
                &Chart {
                    title: "Residual over time (RMS per segment)",
                    xlabel: "time (s)",
                    ylabel: "force (N RMS)",
                    log_x: false,
                    log_y: true,
                    bands: vec![],
                },
                &[
                    series("measured m x''", &t, &nums(&e["measured_rms_n"]), false),
                    series(
                        "residual, base model",
                        &t,
                        &nums(&e["base_residual_rms_n"]),
                        false,
                    ),
                    series(
                        "residual, final model",
                        &t,
                        &nums(&e["residual_rms_n"]),
                        false,
                    ),
                ],
            ))
        }
        "residual_vs_x" => {
            let r = &c["residual_vs_x"];
            let x: Vec<f64> = nums(&r["x_m"]).iter().map(|v| v * 1e3).collect();
            Some(line_chart(
                &Chart {
                    title: "Mean residual against displacement, split by the sign of v",
                    xlabel: "x (mm)",
                    ylabel: "mean residual force (N)",
                    log_x: false,
                    log_y: false,
                    bands: vec![],
                },
                &[
                    series("base, v > 0", &x, &nums(&r["base"]["positive_v_n"]), false),
                    series("base, v < 0", &x, &nums(&r["base"]["negative_v_n"]), false),
                    series("final, v > 0", &x, &nums(&r["final"]["positive_v_n"]), true),
                    series("final, v < 0", &x, &nums(&r["final"]["negative_v_n"]), true),
                ],
            ))
        }
        "residual_vs_v" => {
            let r = &c["residual_vs_v"];
            let v = nums(&r["v_m_per_s"]);
            Some(line_chart(
                &Chart {
                    title: "Mean residual against velocity",
                    xlabel: "v (m/s)",
                    ylabel: "mean residual force (N)",
                    log_x: false,
                    log_y: false,
                    bands: vec![],
                },
                &[
                    series("base model", &v, &nums(&r["base_n"]), false),
                    series("final model", &v, &nums(&r["final_n"]), false),
                ],
            ))
        }
        "residual_spectrum" => {
            let sp = &c["spectrum"];
            let f = nums(&sp["freq_hz"]);
            let bands = sp["harmonic_bands_hz"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .enumerate()
                        .map(|(i, b)| {
                            (
                                b[0].as_f64().unwrap_or(0.0),
                                b[1].as_f64().unwrap_or(0.0),
                                format!("{}", i + 1),
                            )
                        })
                        .collect()
                })
                .unwrap_or_default();
            Some(line_chart(
                &Chart {
                    title: "Residual spectrum (final model); shaded: harmonics of the swept fundamental",
                    xlabel: "frequency (Hz)",
                    ylabel: "PSD (N^2/Hz)",
                    log_x: true,
                    log_y: true,
                    bands,
                },
                &[
                    series("residual", &f, &nums(&sp["psd_n2_per_hz"]), false),
                    series("noise floor", &f, &nums(&sp["noise_psd_n2_per_hz"]), true),
                ],
            ))
        }
        "ladder" => Some(ladder_chart(d)),
        "small_signal" => {
            let ss = c.get("small_signal")?;
            let f = nums(&ss["freq_hz"]);
            Some(line_chart(
                &Chart {
                    title: "Small signal: |X/Mic| of the pre-measurement against the resonator fit",
                    xlabel: "frequency (Hz)",
                    ylabel: "|Hx| (m/V)",
                    log_x: true,
                    log_y: true,
                    bands: vec![],
                },
                &[
                    series("measured", &f, &nums(&ss["measured_abs_m_per_v"]), false),
                    series("linear fit", &f, &nums(&ss["fit_abs_m_per_v"]), true),
                ],
            ))
        }
        _ => None,
    }
}
