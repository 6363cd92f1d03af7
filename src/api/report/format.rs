//! Number and text formatting of the printable report: HTML escaping,
//! significant digits, a value rounded to its uncertainty, display units and
//! limits as people read them.

use serde_json::Value;

pub(super) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

pub(super) fn f(v: &Value) -> Option<f64> {
    v.as_f64().filter(|x| x.is_finite())
}

/// A value with `digits` significant digits.
pub(super) fn sig(v: f64, digits: usize) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-4..1e6).contains(&a) {
        return format!("{:.*e}", digits.saturating_sub(1), v);
    }
    let place = digits as i32 - 1 - a.log10().floor() as i32;
    let t = format!("{:.*}", place.max(0) as usize, v);
    if t.contains('.') {
        t.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        t
    }
}

/// A value rounded to its uncertainty (the standard error to two
/// significant digits, the value to the same place), the unit after the +-.
pub(super) fn with_se(v: f64, se: Option<f64>, unit: &str) -> String {
    let u = if unit.is_empty() {
        String::new()
    } else {
        format!(" {unit}")
    };
    match se.map(f64::abs).filter(|s| s.is_finite() && *s > 0.0) {
        Some(s) if (1e-4..1e6).contains(&v.abs().max(s)) => {
            let place = s.log10().floor() as i32 - 1;
            let d = (-place).max(0) as usize;
            let r = |x: f64| {
                if place > 0 {
                    let k = 10f64.powi(place);
                    format!("{}", (x / k).round() * k)
                } else {
                    format!("{x:.d$}")
                }
            };
            format!("{} \u{b1} {}{u}", r(v), r(s))
        }
        Some(s) => format!("{v:.3e} \u{b1} {s:.1e}{u}"),
        None => format!("{}{u}", sig(v, 4)),
    }
}

/// SI unit -> (display unit, scale).
pub(super) fn display(unit: &str) -> (&str, f64) {
    match unit {
        "N/m" => ("N/mm", 1e-3),
        "m" => ("mm", 1e3),
        "N s/m" => ("N\u{b7}s/m", 1.0),
        "1" => ("", 1.0),
        u => (u, 1.0),
    }
}

pub(super) fn limits(lower: Option<f64>, upper: Option<f64>, unit: &str) -> String {
    let (u, k) = display(unit);
    let u = if u.is_empty() {
        String::new()
    } else {
        format!(" {u}")
    };
    match (lower, upper) {
        (Some(l), Some(h)) => format!("{} \u{2026} {}{u}", sig(l * k, 4), sig(h * k, 4)),
        (None, Some(h)) => format!("\u{2264} {}{u}", sig(h * k, 4)),
        (Some(l), None) => format!("\u{2265} {}{u}", sig(l * k, 4)),
        (None, None) => "no limits".into(),
    }
}
