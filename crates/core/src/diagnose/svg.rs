//! Hand-written SVG plots of a diagnosis (no plotting crate). Each plot is
//! drawn from the `diagnostics` document alone, so the daemon can serve
//! stored diagnoses without the recordings.

use crate::identify::diagnostics::Diagnostics;
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

const W: f64 = 760.0;
const L: f64 = 84.0;
const R: f64 = 24.0;
const T: f64 = 44.0;
/// Height of one panel's plot area.
const PANEL_H: f64 = 300.0;
/// Gap between stacked panels (room for the upper panel's x tick labels).
const GAP: f64 = 26.0;
const COLORS: [&str; 6] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#555555",
];

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

/// Ticks of a log axis between 10^lo and 10^hi: (value, labelled). Labels at
/// 1-2-5 x 10^n (every 1..9 under 1.2 decades, only 10^n over 4 decades);
/// the other integer multiples get an unlabelled grid line.
fn log_ticks(lo: f64, hi: f64) -> Vec<(f64, bool)> {
    let decades = hi - lo;
    let labelled: &[f64] = if decades > 4.0 {
        &[1.0]
    } else if decades < 1.2 {
        &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    } else {
        &[1.0, 2.0, 5.0]
    };
    let mut out = Vec::new();
    for e in (lo.floor() as i32)..=(hi.ceil() as i32) {
        for m in 1..=9 {
            let v = m as f64 * 10f64.powi(e);
            let l = v.log10();
            if l >= lo - 1e-9 && l <= hi + 1e-9 {
                out.push((v, labelled.contains(&(m as f64))));
            }
        }
    }
    out
}

fn fmt_num(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        let e = a.log10().floor();
        let m = v / 10f64.powf(e);
        if (m - m.round()).abs() < 1e-6 {
            format!("{}e{}", m.round(), e)
        } else {
            format!("{m:.1}e{e}")
        }
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else {
        // Shortest of up to 4 decimals that shows the value.
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// One stacked panel of a figure (shares the x axis of the figure).
struct Panel<'a> {
    ylabel: &'a str,
    log_y: bool,
    series: Vec<Series>,
    /// Horizontal bands (lo, hi, label), e.g. +-noise.
    hbands: Vec<(f64, f64, String)>,
}

struct Chart<'a> {
    title: &'a str,
    xlabel: &'a str,
    log_x: bool,
    /// Shaded x ranges (lo, hi, label), e.g. harmonic bands.
    bands: Vec<(f64, f64, String)>,
    panels: Vec<Panel<'a>>,
}

fn ok_point(p: &(f64, f64), log_x: bool, log_y: bool) -> bool {
    p.0.is_finite() && p.1.is_finite() && (!log_x || p.0 > 0.0) && (!log_y || p.1 > 0.0)
}

/// Legend entries laid out in rows below the plots (never over the data).
fn legend_rows(names: &[(String, usize, bool)]) -> Vec<Vec<(String, usize, bool, f64)>> {
    let mut rows: Vec<Vec<(String, usize, bool, f64)>> = vec![vec![]];
    let mut x = L;
    for (name, color, dashed) in names {
        let w = 34.0 + 6.6 * name.chars().count() as f64 + 18.0;
        if x + w > W - R && !rows.last().map(|r| r.is_empty()).unwrap_or(true) {
            rows.push(vec![]);
            x = L;
        }
        rows.last_mut()
            .expect("a row")
            .push((name.clone(), *color, *dashed, x));
        x += w;
    }
    rows
}

fn line_chart(c: &Chart) -> String {
    let tx = |v: f64| if c.log_x { v.max(1e-300).log10() } else { v };
    // The x range over every panel.
    let (mut x0, mut x1) = (f64::MAX, f64::MIN);
    for p in &c.panels {
        for se in &p.series {
            for pt in se.points.iter().filter(|pt| ok_point(pt, c.log_x, p.log_y)) {
                x0 = x0.min(tx(pt.0));
                x1 = x1.max(tx(pt.0));
            }
        }
    }
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    if x1 - x0 < 1e-300 {
        x1 = x0 + 1.0;
    }
    let px = |v: f64| L + (tx(v) - x0) / (x1 - x0) * (W - L - R);
    // Legend entries: one colour per series over the whole figure.
    let mut names = vec![];
    let mut k = 0;
    for p in &c.panels {
        for se in &p.series {
            names.push((se.name.clone(), k % COLORS.len(), se.dashed));
            k += 1;
        }
        for (_, _, label) in &p.hbands {
            names.push((label.clone(), usize::MAX, false));
        }
    }
    let rows = legend_rows(&names);
    let n = c.panels.len().max(1) as f64;
    let plots_h = n * PANEL_H + (n - 1.0) * GAP;
    let axis_bottom = T + plots_h;
    let legend_top = axis_bottom + 50.0;
    let h = legend_top + 18.0 * rows.len() as f64 + 8.0;
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(s, r#"<rect width="{W}" height="{h}" fill="white"/>"#);
    let _ = write!(
        s,
        r#"<text x="{}" y="24" text-anchor="middle" font-size="15">{}</text>"#,
        W / 2.0,
        esc(c.title)
    );
    let mut color_idx = 0;
    for (pi, p) in c.panels.iter().enumerate() {
        let top = T + pi as f64 * (PANEL_H + GAP);
        let bottom = top + PANEL_H;
        let ty = |v: f64| if p.log_y { v.max(1e-300).log10() } else { v };
        let (mut y0, mut y1) = (f64::MAX, f64::MIN);
        for se in &p.series {
            for pt in se.points.iter().filter(|pt| ok_point(pt, c.log_x, p.log_y)) {
                y0 = y0.min(ty(pt.1));
                y1 = y1.max(ty(pt.1));
            }
        }
        for (lo, hi, _) in &p.hbands {
            y0 = y0.min(ty(*lo));
            y1 = y1.max(ty(*hi));
        }
        if y0 > y1 {
            (y0, y1) = (0.0, 1.0);
        }
        if y1 - y0 < 1e-300 {
            y1 = y0 + 1.0;
        }
        let pad = 0.05 * (y1 - y0);
        let (y0, y1) = (y0 - pad, y1 + pad);
        let py = |v: f64| bottom - (ty(v) - y0) / (y1 - y0) * PANEL_H;
        for (lo, hi, label) in &c.bands {
            let (a, b) = (px(*lo).clamp(L, W - R), px(*hi).clamp(L, W - R));
            if b > a {
                let _ = write!(
                    s,
                    r##"<rect x="{a:.1}" y="{top}" width="{:.1}" height="{PANEL_H}" fill="#f0e0a0" opacity="0.5"/><text x="{:.1}" y="{}" font-size="10" fill="#806000" text-anchor="middle">{}</text>"##,
                    b - a,
                    (a + b) / 2.0,
                    top + 12.0,
                    esc(label)
                );
            }
        }
        for (lo, hi, _) in &p.hbands {
            let (a, b) = (py(*hi).clamp(top, bottom), py(*lo).clamp(top, bottom));
            if b > a {
                let _ = write!(
                    s,
                    r##"<rect x="{L}" y="{a:.1}" width="{}" height="{:.1}" fill="#2ca02c" opacity="0.15"/>"##,
                    W - L - R,
                    b - a
                );
            }
        }
        let _ = write!(
            s,
            r#"<rect x="{L}" y="{top}" width="{}" height="{PANEL_H}" fill="none" stroke="black"/>"#,
            W - L - R
        );
        // x ticks (labels under every panel: the panels share the axis).
        let xt: Vec<(f64, bool)> = if c.log_x {
            log_ticks(x0, x1)
        } else {
            nice_ticks(x0, x1, 7)
                .into_iter()
                .map(|t| (t, true))
                .collect()
        };
        for (v, labelled) in xt {
            let x = px(v);
            let stroke = if labelled { "#d8d8d8" } else { "#f0f0f0" };
            let _ = write!(
                s,
                r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{bottom}" stroke="{stroke}"/>"##
            );
            if labelled {
                let _ = write!(
                    s,
                    r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#,
                    bottom + 15.0,
                    fmt_num(v)
                );
            }
        }
        let yt: Vec<(f64, bool)> = if p.log_y {
            log_ticks(y0, y1)
        } else {
            nice_ticks(y0, y1, 6)
                .into_iter()
                .map(|t| (t, true))
                .collect()
        };
        for (v, labelled) in yt {
            let y = py(v);
            let stroke = if labelled { "#d8d8d8" } else { "#f0f0f0" };
            let _ = write!(
                s,
                r##"<line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="{stroke}"/>"##,
                W - R
            );
            if labelled {
                let _ = write!(
                    s,
                    r#"<text x="{}" y="{:.1}" text-anchor="end">{}</text>"#,
                    L - 6.0,
                    y + 4.0,
                    fmt_num(v)
                );
            }
        }
        let mid = (top + bottom) / 2.0;
        let _ = write!(
            s,
            r#"<text x="16" y="{mid}" text-anchor="middle" transform="rotate(-90 16 {mid})">{}</text>"#,
            esc(p.ylabel)
        );
        for se in &p.series {
            let color = COLORS[color_idx % COLORS.len()];
            color_idx += 1;
            let mut d = String::new();
            let mut pen_down = false;
            for pt in &se.points {
                if !ok_point(pt, c.log_x, p.log_y) {
                    pen_down = false;
                    continue;
                }
                let _ = write!(
                    d,
                    "{}{:.1},{:.1} ",
                    if pen_down { "L" } else { "M" },
                    px(pt.0),
                    py(pt.1)
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
        }
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
        (L + W - R) / 2.0,
        axis_bottom + 36.0,
        esc(c.xlabel)
    );
    for (ri, row) in rows.iter().enumerate() {
        let ly = legend_top + 18.0 * ri as f64;
        for (name, color, dashed, x) in row {
            if *color == usize::MAX {
                let _ = write!(
                    s,
                    r##"<rect x="{x}" y="{}" width="24" height="10" fill="#2ca02c" opacity="0.15"/>"##,
                    ly - 5.0
                );
            } else {
                let dash = if *dashed {
                    r#" stroke-dasharray="6,4""#
                } else {
                    ""
                };
                let _ = write!(
                    s,
                    r#"<line x1="{x}" y1="{ly}" x2="{}" y2="{ly}" stroke="{}" stroke-width="2"{dash}/>"#,
                    x + 24.0,
                    COLORS[*color]
                );
            }
            let _ = write!(
                s,
                r#"<text x="{}" y="{}">{}</text>"#,
                x + 30.0,
                ly + 4.0,
                esc(name)
            );
        }
    }
    s.push_str("</svg>\n");
    s
}

/// A one-panel chart.
fn single<'a>(
    title: &'a str,
    xlabel: &'a str,
    ylabel: &'a str,
    log: (bool, bool),
    bands: Vec<(f64, f64, String)>,
    series: Vec<Series>,
) -> String {
    line_chart(&Chart {
        title,
        xlabel,
        log_x: log.0,
        bands,
        panels: vec![Panel {
            ylabel,
            log_y: log.1,
            series,
            hbands: vec![],
        }],
    })
}

/// One curve of [`xy_chart`]: name, points (x, y), dashed.
pub type Curve = (String, Vec<(f64, f64)>, bool);

/// A one-panel line chart of curves (linear axes) with shaded x ranges
/// (lo, hi, label): the plots of the printable report (`api::report`).
pub fn xy_chart(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    bands: Vec<(f64, f64, String)>,
    curves: Vec<Curve>,
) -> String {
    single(
        title,
        xlabel,
        ylabel,
        (false, false),
        bands,
        curves
            .into_iter()
            .map(|(name, points, dashed)| Series {
                name,
                points,
                dashed,
            })
            .collect(),
    )
}

/// Bin means with empty bins as gaps (NaN is not drawn).
fn gaps(v: &[Option<f64>]) -> Vec<f64> {
    v.iter().map(|x| x.unwrap_or(f64::NAN)).collect()
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

fn ladder_chart(d: &Diagnostics) -> String {
    const H: f64 = 440.0;
    const B: f64 = 92.0;
    let nf = d.noise_floor_percent;
    let vals: Vec<(String, f64, f64)> = d
        .ladder
        .iter()
        .map(|s| {
            let label = match &s.added {
                Some(a) => format!("+ {a}"),
                None if s.effects.is_empty() => "base model".into(),
                None => format!("base + {}", s.effects.join(", ")),
            };
            (label, s.model_error_percent, s.cv_residual_percent)
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
        r#"<text x="{}" y="24" text-anchor="middle" font-size="15">Model ladder: error after each added effect (held-out data)</text>"#,
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
    let mid = (T + H - B) / 2.0;
    let _ = write!(
        s,
        r#"<text x="16" y="{mid}" text-anchor="middle" transform="rotate(-90 16 {mid})">% of RMS(m x''), the measured inertial force</text>"#
    );
    let n = vals.len().max(1) as f64;
    let slot = (W - L - R) / n;
    for (i, (label, me, res)) in vals.iter().enumerate() {
        let x = L + slot * i as f64;
        let bw = slot * 0.35;
        let _ = write!(
            s,
            r##"<rect x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{}"/><rect x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{}"/><text x="{:.1}" y="{}" text-anchor="middle">{}</text><text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="10">{:.2} %</text><text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="10">{:.2} %</text>"##,
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
            me,
            x + slot * 0.12 + bw * 1.5,
            py(*res) - 4.0,
            res
        );
    }
    let _ = write!(
        s,
        r##"<line x1="{L}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="black" stroke-dasharray="6,4"/>"##,
        W - R,
        y = py(nf)
    );
    // Legend below the axis.
    let ly = H - B + 44.0;
    let _ = write!(
        s,
        r##"<rect x="{L}" y="{}" width="12" height="10" fill="{}"/><text x="{}" y="{}">model error: residual that is not noise</text><rect x="{}" y="{}" width="12" height="10" fill="{}"/><text x="{}" y="{}">residual incl. noise</text><line x1="{}" y1="{ly}" x2="{}" y2="{ly}" stroke="black" stroke-dasharray="6,4"/><text x="{}" y="{}">noise floor {nf:.2} %</text>"##,
        ly - 5.0,
        COLORS[1],
        L + 16.0,
        ly + 4.0,
        L + 280.0,
        ly - 5.0,
        COLORS[0],
        L + 296.0,
        ly + 4.0,
        L + 440.0,
        L + 464.0,
        L + 470.0,
        ly + 4.0,
    );
    let _ = write!(
        s,
        r##"<text x="{L}" y="{}" font-size="11" fill="#555">model error = sqrt(residual^2 - noise floor^2), both on held-out blocks</text>"##,
        ly + 26.0
    );
    s.push_str("</svg>\n");
    s
}

/// Renders the plot `name` from a diagnostics document.
pub fn render(d: &Diagnostics, name: &str) -> Option<String> {
    let c = &d.comparison;
    match name {
        "model_vs_measurement" => {
            let det = &c.detail;
            let (t, meas) = (&det.t_s, &det.measured_force_n);
            let (fin, base) = (&det.modelled_force_n, &det.base_modelled_force_n);
            let diff = |m: &[f64]| -> Vec<f64> { meas.iter().zip(m).map(|(a, b)| a - b).collect() };
            let noise = Some(c.noise_rms_n).filter(|v| v.is_finite());
            Some(line_chart(&Chart {
                title: "Force balance at the largest excursion: measured m x'' against the models",
                xlabel: "time t (s)",
                log_x: false,
                bands: vec![],
                panels: vec![
                    Panel {
                        ylabel: "force (N)",
                        log_y: false,
                        series: vec![
                            series("measured m x''", t, meas, false),
                            series("final model", t, fin, true),
                            series("base model", t, base, true),
                        ],
                        hbands: vec![],
                    },
                    Panel {
                        ylabel: "residual force (N)",
                        log_y: false,
                        series: vec![
                            series("residual, base model", t, &diff(base), false),
                            series("residual, final model", t, &diff(fin), false),
                        ],
                        hbands: noise
                            .map(|n| vec![(-n, n, "+-1 noise RMS".to_string())])
                            .unwrap_or_default(),
                    },
                ],
            }))
        }
        "residual_over_time" => {
            let e = &c.envelope;
            let t = &e.t_s;
            Some(single(
                "Residual over the sweep (RMS per segment)",
                "time t (s)",
                "force, RMS per segment (N)",
                (false, true),
                vec![],
                vec![
                    series("measured m x''", t, &e.measured_rms_n, false),
                    series("residual, base model", t, &e.base_residual_rms_n, false),
                    series("residual, final model", t, &e.residual_rms_n, false),
                ],
            ))
        }
        "residual_vs_x" => {
            let r = &c.residual_vs_x;
            let x: Vec<f64> = r.x_m.iter().map(|v| v * 1e3).collect();
            Some(single(
                "Mean residual against displacement, split by the sign of v",
                "displacement x (mm)",
                "mean residual force (N)",
                (false, false),
                vec![],
                vec![
                    series("base, v > 0", &x, &gaps(&r.base.positive_v_n), false),
                    series("base, v < 0", &x, &gaps(&r.base.negative_v_n), false),
                    series("final, v > 0", &x, &gaps(&r.final_model.positive_v_n), true),
                    series("final, v < 0", &x, &gaps(&r.final_model.negative_v_n), true),
                ],
            ))
        }
        "residual_vs_v" => {
            let r = &c.residual_vs_v;
            let v = &r.v_m_per_s;
            Some(single(
                "Mean residual against velocity",
                "velocity v (m/s)",
                "mean residual force (N)",
                (false, false),
                vec![],
                vec![
                    series("base model", v, &gaps(&r.base_n), false),
                    series("final model", v, &gaps(&r.final_n), false),
                ],
            ))
        }
        "residual_spectrum" => {
            let sp = &c.spectrum;
            let f = &sp.freq_hz;
            let bands = sp
                .harmonic_bands_hz
                .iter()
                .enumerate()
                .map(|(i, b)| (b[0], b[1], format!("{}f", i + 1)))
                .collect();
            let mut s = vec![series("residual, final model", f, &sp.psd_n2_per_hz, false)];
            let base = gaps(&sp.base_psd_n2_per_hz);
            if base.iter().any(|v| v.is_finite()) {
                s.push(series("residual, base model", f, &base, false));
            }
            s.push(series("noise floor", f, &sp.noise_psd_n2_per_hz, true));
            Some(single(
                "Residual spectrum; shaded: harmonics 1f, 2f, ... of the swept fundamental",
                "frequency f (Hz)",
                "power spectral density (N^2/Hz)",
                (true, true),
                bands,
                s,
            ))
        }
        "ladder" => Some(ladder_chart(d)),
        "small_signal" => {
            let ss = c.small_signal.as_ref()?;
            let f = &ss.freq_hz;
            Some(single(
                "Small signal: |X/Mic| of the pre-measurement against the resonator fit",
                "frequency f (Hz)",
                "|Hx| = |X / Mic| (m/V)",
                (true, true),
                vec![],
                vec![
                    series("measured", f, &ss.measured_abs_m_per_v, false),
                    series("linear resonator fit", f, &ss.fit_abs_m_per_v, true),
                ],
            ))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_label_1_2_5_per_decade() {
        // 3 Hz .. 110 Hz (the small-signal plot): labels 5, 10, 20, 50, 100.
        let t = log_ticks(3f64.log10(), 110f64.log10());
        let labelled: Vec<f64> = t.iter().filter(|t| t.1).map(|t| t.0).collect();
        assert_eq!(labelled, vec![5.0, 10.0, 20.0, 50.0, 100.0]);
        // Unlabelled grid lines at the other multiples (30, 40 around an f0 of 35 Hz).
        assert!(t.contains(&(30.0, false)) && t.contains(&(40.0, false)));
        // Under 1.2 decades every multiple is labelled; over 4 only the decades.
        assert!(log_ticks(1.0, 1.9).iter().all(|t| t.1));
        let wide: Vec<f64> = log_ticks(-6.0, 0.0)
            .iter()
            .filter(|t| t.1)
            .map(|t| t.0)
            .collect();
        assert_eq!(wide.len(), 7);
    }

    #[test]
    fn numbers_are_short() {
        assert_eq!(fmt_num(20.0), "20");
        assert_eq!(fmt_num(0.5), "0.5");
        assert_eq!(fmt_num(2e-6), "2e-6");
        assert_eq!(fmt_num(0.0), "0");
        assert_eq!(fmt_num(1.25), "1.25");
    }

    #[test]
    fn legends_sit_below_the_plot_area() {
        let s: Vec<Series> = (0..6)
            .map(|i| {
                series(
                    &format!("a long series name {i}"),
                    &[1.0, 2.0],
                    &[1.0, 2.0],
                    false,
                )
            })
            .collect();
        let svg = single("t", "x (m)", "y (N)", (false, false), vec![], s);
        // Every legend text is below the x axis label, i.e. outside the data area.
        let axis_bottom = T + PANEL_H;
        let legend_y: Vec<f64> = svg
            .split("<text ")
            .filter(|t| t.contains(">a long series name"))
            .filter_map(|t| t.split("y=\"").nth(1)?.split('"').next()?.parse().ok())
            .collect();
        assert_eq!(legend_y.len(), 6);
        assert!(
            legend_y.iter().all(|y| *y > axis_bottom + 36.0),
            "{legend_y:?}"
        );
    }
}
