//! Beyond the library (issue 12): when the structured error after the
//! ladder stays clearly above the noise, describe what is left — its
//! harmonic orders (even, odd), how it depends on x, v, the direction of
//! motion, the acceleration, and time (= frequency along a sweep) — and name
//! the experiment that would tell more. Pure.
//!
//! Every description is a block-robust least-squares fit of the final
//! residual on a group of probe columns (never added to the model): its
//! share of the structured residual and its Wald test with the batch-means
//! covariance of the engine (docs/decisions/0014-trust-model.md).

use super::regress::{block_bounds, BlockGram};
use super::stats::f_upper_p;
use crate::identify::ForceBalanceData;

/// Structure is "clearly above the noise" when the model error left by the
/// ladder is at least this fraction of the noise floor (the residual RMS
/// then exceeds the noise by sqrt(1 + 0.3^2) - 1 = 4.4 %). A model with the
/// right effects leaves 0.00-0.15 x the noise floor on the virtual bench
/// (24 parts: every library effect and none, several seeds;
/// docs/diagnostics.md), so 0.3 is twice the largest seen (decision 0019).
pub const NOISE_RATIO: f64 = 0.3;
/// A probe describes the structure when it explains at least this share of
/// the structured residual variance (%).
pub const MIN_SHARE_PERCENT: f64 = 10.0;
/// Family-wise significance of the probe tests (Bonferroni over probes).
pub const ALPHA: f64 = 0.01;
/// Harmonic orders of the motion's phase examined.
pub const HARMONICS: usize = 6;

pub use crate::identify::diagnostics::{Probe, Unexplained};

/// The experiment that tells a resonance at a fixed frequency from a change
/// over time (a log sweep moves both together).
pub const FALLING_SWEEP: &str = "a falling sweep or a second sweep rate (a resonance at a fixed frequency stays where it is, a change over time moves with the sweep)";

/// Adds a second mode's resonance found in the pre-measurement: the
/// structure is outside the library (present), its signature and the
/// experiment that would tell come first.
pub fn add_resonance(u: &mut Unexplained, r: crate::identify::WideBandResonance) {
    let what = format!(
        "a resonance at a fixed frequency of {:.1} Hz (Q {:.1}, {:.1} g moving on its own spring) in the pre-measurement's transfer function over {:.0}-{:.0} Hz (misfit {:.1} % linear, {:.1} % with creep, {:.1} % with the resonance): a second mechanical mode, outside the effect library",
        r.frequency_hz,
        r.q,
        r.mass_kg * 1e3,
        r.band_hz[0],
        r.band_hz[1],
        r.misfit_linear_percent,
        r.misfit_with_creep_percent,
        r.misfit_with_resonance_percent
    );
    u.signature = if u.present {
        format!("{}; {what}", u.signature)
    } else {
        format!("an effect outside the library: {what}")
    };
    u.short = format!("a resonance at {:.1} Hz, a second mode", r.frequency_hz);
    u.present = true;
    u.experiments.retain(|e| e != FALLING_SWEEP);
    u.experiments.insert(0, FALLING_SWEEP.to_string());
    u.resonance = Some(r);
}

fn moving_mean(v: &[f64], w: usize) -> Vec<f64> {
    let n = v.len();
    let h = w / 2;
    let mut pre = vec![0.0; n + 1];
    for i in 0..n {
        pre[i + 1] = pre[i] + v[i];
    }
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(h), (i + h + 1).min(n));
            (pre[b] - pre[a]) / (b - a) as f64
        })
        .collect()
}

fn bins(key: &[f64], nb: usize) -> Vec<usize> {
    let (lo, hi) = key
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let w = ((hi - lo) / nb as f64).max(f64::MIN_POSITIVE);
    key.iter()
        .map(|&k| (((k - lo) / w) as usize).min(nb - 1))
        .collect()
}

/// Indicator columns of `groups` (one per group value < k).
fn indicators(groups: &[usize], k: usize, weight: impl Fn(usize) -> f64) -> Vec<Vec<f64>> {
    let mut cols = vec![vec![0.0; groups.len()]; k];
    for (i, &g) in groups.iter().enumerate() {
        cols[g][i] = weight(i);
    }
    cols.retain(|c| c.iter().filter(|v| **v != 0.0).count() >= 20);
    cols
}

/// Share of the structured residual variance `cols` explain, and the
/// block-robust Wald test of all their coefficients.
fn test_probe(
    cols: &[Vec<f64>],
    e: &[f64],
    bounds: &[(usize, usize)],
    structured_sse: f64,
) -> (f64, f64) {
    if cols.is_empty() {
        return (0.0, 1.0);
    }
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let gram = BlockGram::build(&refs, e, bounds);
    let fit = gram.fit();
    let sse0: f64 = e.iter().map(|v| v * v).sum();
    let share = 100.0 * ((sse0 - fit.sse) / structured_sse.max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    let cov = gram.block_covariance(&fit.beta);
    let q = cols.len();
    let nb = bounds.len() as f64;
    if nb <= q as f64 + 1.0 {
        return (share, 1.0);
    }
    let inv = super::regress::inverse_spd(&cov);
    let w = (fit.beta.transpose() * inv * &fit.beta)[(0, 0)];
    let qf = q as f64;
    let f = w * (nb - qf) / (qf * (nb - 1.0));
    (share, f_upper_p(f, qf, nb - qf))
}

/// Describes the residual `e` (N) of the final model on `d`.
pub fn describe(
    d: &ForceBalanceData,
    e: &[f64],
    model_error_percent: f64,
    noise_floor_percent: f64,
) -> Unexplained {
    let n = e.len().min(d.x_m.len());
    let e = &e[..n];
    let fs = d.sample_rate_hz;
    let (x, v, a) = (&d.x_m[..n], &d.v_m_per_s[..n], &d.a_m_per_s2[..n]);
    let rms_y = d.mass_kg * (a.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt();
    let me_n = model_error_percent / 100.0 * rms_y;
    let structured_sse = n as f64 * me_n * me_n;
    let bounds = block_bounds(n, 40);
    let mean_x = x.iter().sum::<f64>() / n.max(1) as f64;
    let xc: Vec<f64> = x.iter().map(|v| v - mean_x).collect();
    // Local angular frequency (one typical period of averaging) and the
    // phase of the motion: cos = x/A, sin = -v/(w A).
    let rms = |s: &[f64]| (s.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt();
    let w_typ = rms(v) / rms(&xc).max(f64::MIN_POSITIVE);
    let win = ((2.0 * std::f64::consts::PI / w_typ.max(1e-9)) * fs).round() as usize;
    let xx = moving_mean(&xc.iter().map(|v| v * v).collect::<Vec<_>>(), win.max(3));
    let vv = moving_mean(&v.iter().map(|v| v * v).collect::<Vec<_>>(), win.max(3));
    let (mut cs, mut sn) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        let w = (vv[i] / xx[i].max(f64::MIN_POSITIVE)).sqrt().max(1e-9);
        let amp = (xc[i] * xc[i] + (v[i] / w).powi(2))
            .sqrt()
            .max(f64::MIN_POSITIVE);
        cs[i] = xc[i] / amp;
        sn[i] = -v[i] / (w * amp);
    }
    let mut probes = Vec::new();
    let n_probes = (HARMONICS + 6) as f64;
    let alpha = ALPHA / n_probes;
    let mut push = |name: String, cols: Vec<Vec<f64>>| {
        let (share, p) = test_probe(&cols, e, &bounds, structured_sse);
        probes.push(Probe {
            name,
            share_percent: share,
            p_value: p,
            significant: p < alpha && share >= MIN_SHARE_PERCENT,
        });
    };
    // Harmonic h: cos(h theta), sin(h theta) by the Chebyshev recurrences.
    let (mut c_prev, mut s_prev) = (vec![1.0; n], vec![0.0; n]);
    let (mut c_cur, mut s_cur) = (cs.clone(), sn.clone());
    for h in 1..=HARMONICS {
        push(format!("harmonic_{h}"), vec![c_cur.clone(), s_cur.clone()]);
        let c_next: Vec<f64> = (0..n).map(|i| 2.0 * cs[i] * c_cur[i] - c_prev[i]).collect();
        let s_next: Vec<f64> = (0..n).map(|i| 2.0 * cs[i] * s_cur[i] - s_prev[i]).collect();
        c_prev = std::mem::replace(&mut c_cur, c_next);
        s_prev = std::mem::replace(&mut s_cur, s_next);
    }
    let nb = 12;
    let bx = bins(x, nb);
    let bv = bins(v, nb);
    push("function_of_x".into(), indicators(&bx, nb, |_| 1.0));
    push("function_of_v".into(), indicators(&bv, nb, |_| 1.0));
    push(
        "x_with_direction".into(),
        indicators(&bx, nb, |i| v[i].signum()),
    );
    push("acceleration".into(), vec![a.to_vec()]);
    let segs = 8;
    let bt: Vec<usize> = (0..n).map(|i| i * segs / n.max(1)).collect();
    push("x_along_the_sweep".into(), indicators(&bt, segs, |i| x[i]));
    push("v_along_the_sweep".into(), indicators(&bt, segs, |i| v[i]));

    let harmonic_orders: Vec<usize> = probes
        .iter()
        .filter(|p| p.significant && p.name.starts_with("harmonic_"))
        .filter_map(|p| p.name["harmonic_".len()..].parse().ok())
        .collect();
    let (even, odd) = (
        harmonic_orders.iter().any(|h| h % 2 == 0),
        harmonic_orders.iter().any(|h| h % 2 == 1),
    );
    let parity = match (even, odd) {
        (true, true) => "both",
        (true, false) => "even",
        (false, true) => "odd",
        (false, false) => "none",
    }
    .to_string();
    let above = model_error_percent >= NOISE_RATIO * noise_floor_percent;
    let present = above;
    let sig = |name: &str| {
        probes
            .iter()
            .find(|p| p.name == name)
            .filter(|p| p.significant)
            .map(|p| p.share_percent)
    };
    let mut parts = Vec::new();
    if !harmonic_orders.is_empty() {
        parts.push(format!(
            "at harmonic orders {:?} of the motion ({} orders{})",
            harmonic_orders,
            parity,
            if parity == "even" {
                ": asymmetric in x"
            } else if parity == "odd" {
                ": symmetric in x"
            } else {
                ""
            }
        ));
    }
    let mut experiments: Vec<String> = Vec::new();
    fn add_to(list: &mut Vec<String>, s: &str) {
        if !list.iter().any(|e| e == s) {
            list.push(s.to_string());
        }
    }
    let mut add = |s: &str| add_to(&mut experiments, s);
    if let Some(s) = sig("function_of_x") {
        parts.push(format!(
            "{s:.0} % a function of x alone (a force-displacement shape K(x) x does not follow)"
        ));
        add("another drive level (a shape in x stays, an amplitude effect moves)");
    }
    if let Some(s) = sig("function_of_v") {
        parts.push(format!(
            "{s:.0} % a function of v alone (a damping law outside the library)"
        ));
        add("another drive level (a damping law in v changes with the velocity range)");
    }
    if let Some(s) = sig("x_with_direction") {
        parts.push(format!(
            "{s:.0} % depends on x and the direction of motion (a loop: hysteresis)"
        ));
        add("another drive level and a slower sweep (rate-independent hysteresis keeps its loop when slower)");
    }
    if let Some(s) = sig("acceleration") {
        parts.push(format!(
            "{s:.0} % in phase with the acceleration (a mass that moves with the part but is not the weighed one: a second mode above the band, or a wrong mass)"
        ));
        add("an added mass (a wrong mass scales with it, a second mode does not)");
    }
    let tx = sig("x_along_the_sweep");
    let tv = sig("v_along_the_sweep");
    if tx.is_some() || tv.is_some() {
        parts.push(format!(
            "changes along the sweep (stiffness-like {:.0} %, damping-like {:.0} %): time and frequency move together in a sweep",
            tx.unwrap_or(0.0),
            tv.unwrap_or(0.0)
        ));
        add(FALLING_SWEEP);
        add("a repeated run (a change over time differs between runs)");
        add("the small-signal transfer function over a wider band (a second mechanical mode shows as a resonance of its own)");
    }
    if experiments.is_empty() && present {
        experiments.push("another drive level and an added mass".into());
    }
    if parts.is_empty() && present {
        parts.push(
            "no probe (harmonic order, x, v, direction, acceleration, time along the sweep) describes it alone".into(),
        );
    }
    let signature = if !present {
        format!(
            "no structure beyond the noise: model error {model_error_percent:.3} % < {NOISE_RATIO} x noise floor {noise_floor_percent:.3} %"
        )
    } else {
        format!(
            "an effect outside the library: model error {model_error_percent:.3} % over a noise floor of {noise_floor_percent:.3} %, {}",
            parts.join("; ")
        )
    };
    Unexplained {
        present,
        model_error_percent,
        noise_floor_percent,
        harmonic_orders,
        parity,
        probes,
        signature,
        experiments,
        parameters_not_claimed: Vec::new(),
        resonance: None,
        short: format!(
            "model error {model_error_percent:.2} % over a noise floor of {noise_floor_percent:.2} %"
        ),
    }
}
