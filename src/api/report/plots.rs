//! The report's four plots: K(x), C(x), F(x) over the valid range and Keff
//! against Xpeak of the job's levels, as inline SVG.

use super::format::f;
use crate::diagnose::svg::{xy_chart, Curve};
use serde_json::Value;

/// Points of each curve inside the valid range.
pub(super) const CURVE_POINTS: usize = 201;

pub(super) fn horner(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, k| acc * x + k)
}

pub(super) fn integral(c: &[f64], x: f64) -> f64 {
    x * c
        .iter()
        .enumerate()
        .rev()
        .fold(0.0, |acc, (i, k)| acc * x + k / (i as f64 + 1.0))
}

/// The four plots (K, C, F over the valid range in mm; Keff against Xpeak).
pub(super) fn plots(doc: &Value, levels: &[(f64, f64)]) -> Vec<String> {
    let st = &doc["stiffness"];
    let c: Vec<f64> = st["coefficients_n_per_m_pow_i_plus_1"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
        .unwrap_or_default();
    let (Some(lo), Some(hi)) = (f(&st["valid_range_m"][0]), f(&st["valid_range_m"][1])) else {
        return vec![];
    };
    if c.is_empty() || hi <= lo {
        return vec![];
    }
    let xs: Vec<f64> = (0..CURVE_POINTS)
        .map(|i| lo + (hi - lo) * i as f64 / (CURVE_POINTS - 1) as f64)
        .collect();
    let curve = |name: &str, g: &dyn Fn(f64) -> Option<f64>| -> Vec<Curve> {
        vec![(
            name.to_string(),
            xs.iter()
                .filter_map(|&x| g(x).map(|y| (x * 1e3, y)))
                .collect(),
            false,
        )]
    };
    let k = |x: f64| horner(&c, x);
    vec![
        xy_chart(
            "Stiffness K(x)",
            "displacement x (mm)",
            "K (N/mm)",
            vec![],
            curve("K(x)", &|x| Some(k(x) * 1e-3)),
        ),
        xy_chart(
            "Compliance C(x) = 1/K(x)",
            "displacement x (mm)",
            "C (mm/N)",
            vec![],
            curve("C(x)", &|x| (k(x) > 0.0).then(|| 1e3 / k(x))),
        ),
        xy_chart(
            "Restoring force F(x)",
            "displacement x (mm)",
            "F (N)",
            vec![],
            curve("F(x)", &|x| Some(integral(&c, x))),
        ),
        xy_chart(
            "Keff against Xpeak (the job's levels)",
            "Xpeak (mm)",
            "Keff (N/mm)",
            vec![],
            vec![if let [(x, k)] = levels {
                // One level: a short mark (a line needs two points).
                (
                    "Keff at Xpeak (one level)".into(),
                    vec![(x * 1e3 - 0.1, k * 1e-3), (x * 1e3 + 0.1, k * 1e-3)],
                    false,
                )
            } else {
                (
                    "Keff(Xpeak)".into(),
                    levels.iter().map(|(x, k)| (x * 1e3, k * 1e-3)).collect(),
                    false,
                )
            }],
        ),
    ]
}

/// A plot drawn 760 px wide and printed about 90 mm wide: larger type (the
/// layout leaves room for it), so the labels read at about 7 pt.
pub(super) fn big(svg: &str) -> String {
    svg.replacen("font-size=\"12\"", "font-size=\"19\"", 1)
        .replacen("font-size=\"15\"", "font-size=\"21\"", 1)
}
