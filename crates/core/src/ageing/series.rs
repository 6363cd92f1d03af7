//! A long-term test's series: one analysed measurement per interval in,
//! the ageing document out (the law, the characteristics that separate
//! break-in from fatigue, the tracks of f0, Keff and K at large excursion,
//! a prediction). `springbench ageing` and the daemon's long-term test both
//! call [`analyse`].

use super::{fit_law, fit_track, track, Estimate, Track};
use crate::identify::validity::{HeadlineValidity, State};
use crate::identify::Report;
use serde::{Deserialize, Serialize};

/// One interval of a long-term test: when it was measured, the load the part
/// had taken, and the measurement's analysis.
#[derive(Debug, Clone)]
pub struct Interval {
    pub elapsed_s: f64,
    /// None when the series does not know it (then the law is fitted against time).
    pub load_j: Option<f64>,
    pub report: Report,
}

/// An interval's values as the document lists them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct IntervalValues {
    pub elapsed_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_j: Option<f64>,
    /// Small-signal stiffness at rest and its standard error; null when the
    /// measurement did not determine it (then the interval is left out of the law).
    pub k0_n_per_m: Option<f64>,
    pub k0_se_n_per_m: f64,
    pub f0_hz: Option<f64>,
    pub keff_n_per_m: f64,
    pub xpeak_m: f64,
    /// K(x) of the measurement at the two large excursions of the document
    /// (`large_excursion.x_m`), N/m.
    pub k_at_large_excursion_n_per_m: [f64; 2],
    /// The interval's K(x) polynomial (N/m^(i+1)) and its valid range (m),
    /// for the family of curves.
    pub k_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    pub valid_range_m: [f64; 2],
    /// The states of the measurement's own K(0), f0 and Keff (a value that
    /// is not `valid` is marked wherever the series is shown).
    #[serde(default)]
    pub validity: IntervalValidity,
}

/// The states of an interval's values, as its measurement gave them.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct IntervalValidity {
    pub k0_n_per_m: HeadlineValidity,
    pub f0_hz: HeadlineValidity,
    pub keff_n_per_m: HeadlineValidity,
}

/// The fitted law, named in the units of the series' load coordinate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LawDoc {
    /// "load_j": fitted against the accumulated load; "elapsed_s": against
    /// time (the series did not say its load).
    pub axis: String,
    pub k_inf_n_per_m: Estimate,
    pub break_in_k_n_per_m: Estimate,
    pub fatigue_k_n_per_m: Estimate,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub break_in_load_j: Option<Estimate>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fatigue_load_j: Option<Estimate>,
    /// The scales in time under the series' stimulus (its mean load power
    /// when the axis is the load).
    pub break_in_time_s: Estimate,
    pub fatigue_time_s: Estimate,
    pub residual_sd_n_per_m: f64,
    pub intervals_used: usize,
    pub validity: HeadlineValidity,
}

/// What separates break-in from fatigue.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Characteristics {
    /// K(0) of the new part and at the last interval, by the law (N/m).
    pub k0_initial_n_per_m: f64,
    pub k0_last_n_per_m: f64,
    /// Share of the stiffness lost in the end (K_∞ reached) that break-in removes (0..1).
    pub break_in_share: f64,
    /// Break-in's and fatigue's whole loss relative to the new part's K(0) (%).
    pub break_in_loss_percent: f64,
    pub fatigue_loss_percent: f64,
    /// Time under the series' stimulus after which 95 % of break-in is done (3 τ_b, s).
    pub break_in_95_time_s: f64,
    /// Fatigue's initial rate, after break-in (% of K(0) of the new part per hour).
    pub fatigue_rate_percent_per_h: f64,
    /// Mean load power of the stimulus over the series (W), when the load is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_power_w: Option<f64>,
}

/// K at ±0.8 of the largest excursion: the geometry, which ageing should leave alone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LargeExcursion {
    /// The two excursions (m): 0.8 of the smallest largest excursion of all intervals per side.
    pub x_m: [f64; 2],
    /// Change from the first to the last interval by the tracks (%).
    pub change_percent: [f64; 2],
    /// Both below 2 %.
    pub below_2_percent: bool,
    /// One sentence that says so.
    pub statement: String,
}

/// K(0) and f0 predicted at a time under the series' stimulus.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Prediction {
    pub elapsed_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_j: Option<f64>,
    pub k0_n_per_m: f64,
    /// Standard error of the law's value (N/m).
    pub k0_se_n_per_m: f64,
    /// Where a measurement at that time falls with 95 % probability: the
    /// law's uncertainty and the measurements' scatter about it (N/m).
    pub k0_band_n_per_m: [f64; 2],
    pub f0_hz: f64,
    pub f0_se_hz: f64,
    pub validity: HeadlineValidity,
}

/// A fitted law drawn over the test (for the page's plots): its value, the
/// standard error of that value, and the 95 % band where a measurement
/// falls (the law's uncertainty and the measurements' scatter about it:
/// `value ± 2 sqrt(se² + s²)`), at the times of [`LawCurves::elapsed_s`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Curve {
    /// What it is, with its unit: `k0_n_per_m` (the law), `f0_hz` or
    /// `keff_n_per_m` (fitted on the law's scales).
    pub quantity: String,
    pub value: Vec<f64>,
    pub se: Vec<f64>,
    pub band_low: Vec<f64>,
    pub band_high: Vec<f64>,
}

/// The fitted laws from the start to the later of the last interval and
/// the prediction's time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LawCurves {
    /// Test time of each point (s).
    pub elapsed_s: Vec<f64>,
    /// The load then (J): the intervals' loads interpolated, beyond the
    /// last one at the series' mean load power. Absent when the law is
    /// fitted against time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_j: Option<Vec<f64>>,
    pub curves: Vec<Curve>,
}

/// Points of each curve.
pub const CURVE_POINTS: usize = 61;

/// The document of a series (`springbench ageing --json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AgeingDocument {
    pub intervals: Vec<IntervalValues>,
    /// None when the law could not be fitted at all (`problem` says why).
    pub law: Option<LawDoc>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub characteristics: Option<Characteristics>,
    pub tracks: Vec<Track>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub large_excursion: Option<LargeExcursion>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prediction: Option<Prediction>,
    /// The laws of K(0), f0 and Keff drawn over the test with their bands.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curves: Option<LawCurves>,
    /// Why there is no law.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub problem: Option<String>,
}

fn k_at(coeffs: &[f64], x: f64) -> f64 {
    coeffs.iter().rev().fold(0.0, |a, &c| a * x + c)
}

/// Slope of y against x by least squares (a line with intercept).
fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    sxy / sxx
}

fn est(v: f64, se: f64) -> Estimate {
    Estimate {
        value: v,
        se: if se.is_finite() { se } else { 0.0 },
    }
}

/// Analyses a series; `predict_s`: the elapsed time to predict K(0) at.
pub fn analyse(intervals: &[Interval], predict_s: Option<f64>) -> AgeingDocument {
    let mut iv: Vec<&Interval> = intervals.iter().collect();
    iv.sort_by(|a, b| a.elapsed_s.total_cmp(&b.elapsed_s));
    // The large excursions: 0.8 of the smallest reach per side.
    let neg = iv
        .iter()
        .map(|i| i.report.stiffness.valid_range_m[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let pos = iv
        .iter()
        .map(|i| i.report.stiffness.valid_range_m[1])
        .fold(f64::INFINITY, f64::min);
    let x_large = [0.8 * neg.min(0.0), 0.8 * pos.max(0.0)];
    let values: Vec<IntervalValues> = iv
        .iter()
        .map(|i| {
            let r = &i.report;
            let ss = r.small_signal.as_ref();
            let c = &r.stiffness.coefficients_n_per_m_pow_i_plus_1;
            let k0_ok = ss.is_some_and(|s| s.validity.k0_n_per_m.state != State::NotDetermined);
            IntervalValues {
                elapsed_s: i.elapsed_s,
                load_j: i.load_j,
                k0_n_per_m: ss.and_then(|s| s.k0_n_per_m).filter(|_| k0_ok),
                k0_se_n_per_m: ss.map_or(0.0, |s| s.k0_se_n_per_m),
                f0_hz: ss.and_then(|s| s.f0_hz),
                keff_n_per_m: r.large_signal.keff_n_per_m,
                xpeak_m: r.large_signal.xpeak_m,
                k_at_large_excursion_n_per_m: [k_at(c, x_large[0]), k_at(c, x_large[1])],
                k_coefficients_n_per_m_pow_i_plus_1: c.clone(),
                valid_range_m: r.stiffness.valid_range_m,
                validity: IntervalValidity {
                    k0_n_per_m: ss.map_or_else(
                        || not_measured("no small-signal fit"),
                        |s| s.validity.k0_n_per_m.clone(),
                    ),
                    f0_hz: ss.map_or_else(
                        || not_measured("no small-signal fit"),
                        |s| s.validity.f0_hz.clone(),
                    ),
                    keff_n_per_m: r.large_signal.validity.keff_n_per_m.clone(),
                },
            }
        })
        .collect();
    let mut doc = AgeingDocument {
        intervals: values.clone(),
        law: None,
        characteristics: None,
        tracks: Vec::new(),
        large_excursion: None,
        prediction: None,
        curves: None,
        problem: None,
    };
    let used: Vec<&IntervalValues> = values.iter().filter(|v| v.k0_n_per_m.is_some()).collect();
    let by_load = !used.is_empty() && used.iter().all(|v| v.load_j.is_some());
    let coord = |v: &IntervalValues| {
        if by_load {
            v.load_j.unwrap_or(0.0)
        } else {
            v.elapsed_s
        }
    };
    let c: Vec<f64> = used.iter().map(|v| coord(v)).collect();
    let y: Vec<f64> = used.iter().filter_map(|v| v.k0_n_per_m).collect();
    let law = match fit_law(&c, &y) {
        Ok(l) => l,
        Err(e) => {
            doc.problem = Some(e);
            return doc;
        }
    };
    let t: Vec<f64> = used.iter().map(|v| v.elapsed_s).collect();
    // Load per second of the stimulus (1 when the axis is time).
    let power = if by_load && used.len() >= 2 {
        slope(&t, &c)
    } else {
        1.0
    };
    let power_ok = power.is_finite() && power > 0.0;
    let to_time = |e: Estimate| {
        if power_ok {
            est(e.value / power, e.se / power)
        } else {
            est(f64::NAN, f64::NAN)
        }
    };
    let th = law.theta;
    let p = |m: usize| est(th[m], law.se(m));
    let mut validity = law.validity.clone();
    if by_load && !power_ok {
        validity = HeadlineValidity {
            state: State::Unreliable,
            reason: Some("the load does not grow with time: no time scales".into()),
            fit_value: None,
        };
    }
    let break_in_time = if by_load { to_time(p(2)) } else { p(2) };
    let fatigue_time = if by_load { to_time(p(4)) } else { p(4) };
    let nan0 = |e: Estimate| {
        if e.value.is_finite() {
            e
        } else {
            est(0.0, 0.0)
        }
    };
    doc.law = Some(LawDoc {
        axis: if by_load { "load_j" } else { "elapsed_s" }.into(),
        k_inf_n_per_m: p(0),
        break_in_k_n_per_m: p(1),
        fatigue_k_n_per_m: p(3),
        break_in_load_j: by_load.then(|| p(2)),
        fatigue_load_j: by_load.then(|| p(4)),
        break_in_time_s: nan0(break_in_time),
        fatigue_time_s: nan0(fatigue_time),
        residual_sd_n_per_m: law.residual_sd,
        intervals_used: law.n,
        validity: validity.clone(),
    });
    let k_new = law.initial();
    let secs_per_coord = if by_load && power_ok {
        1.0 / power
    } else {
        1.0
    };
    doc.characteristics = Some(Characteristics {
        k0_initial_n_per_m: k_new,
        k0_last_n_per_m: law.value(law.c_max),
        break_in_share: th[1] / (th[1] + th[3]),
        break_in_loss_percent: 100.0 * th[1] / k_new,
        fatigue_loss_percent: 100.0 * th[3] / k_new,
        break_in_95_time_s: 3.0 * th[2] * secs_per_coord,
        fatigue_rate_percent_per_h: 100.0 * th[3] / th[4] / k_new * 3600.0 / secs_per_coord,
        mean_power_w: (by_load && power_ok).then_some(power),
    });
    // Tracks on the law's scales.
    let all_c: Vec<f64> = values.iter().map(coord).collect();
    let mass = iv
        .first()
        .map(|i| i.report.large_signal.moving_mass_kg)
        .unwrap_or(0.0);
    let f0: Vec<(f64, f64)> = values
        .iter()
        .filter_map(|v| v.f0_hz.map(|f| (coord(v), f)))
        .collect();
    let (fc, fy): (Vec<f64>, Vec<f64>) = f0.into_iter().unzip();
    if let Some(tr) = track("f0_hz", None, &fc, &fy, &law) {
        doc.tracks.push(tr);
    }
    let keff: Vec<f64> = values.iter().map(|v| v.keff_n_per_m).collect();
    if let Some(tr) = track("keff_n_per_m", None, &all_c, &keff, &law) {
        doc.tracks.push(tr);
    }
    let mut change = [f64::NAN; 2];
    for (side, x) in x_large.iter().enumerate() {
        let k: Vec<f64> = values
            .iter()
            .map(|v| v.k_at_large_excursion_n_per_m[side])
            .collect();
        if let Some(tr) = track("k_at_x_n_per_m", Some(*x), &all_c, &k, &law) {
            change[side] = tr.change_percent.value;
            doc.tracks.push(tr);
        }
    }
    if change.iter().all(|c| c.is_finite()) && x_large[0] < 0.0 && x_large[1] > 0.0 {
        let below = change.iter().all(|c| c.abs() < 2.0);
        let k0_change = 100.0 * (law.value(law.c_max) / k_new - 1.0);
        doc.large_excursion = Some(LargeExcursion {
            x_m: x_large,
            change_percent: change,
            below_2_percent: below,
            statement: format!(
                "K at {:.2} mm and {:+.2} mm changed by {:+.2} % and {:+.2} % ({} 2 %) while K(0) changed by {:+.1} %: {}",
                x_large[0] * 1e3,
                x_large[1] * 1e3,
                change[0],
                change[1],
                if below { "both below" } else { "not both below" },
                k0_change,
                if below {
                    "the geometry held, the material near rest aged"
                } else {
                    "the part changed at large excursion too"
                }
            ),
        });
    }
    // The laws over the test, up to the prediction's time.
    {
        let t_last = used.last().map_or(0.0, |v| v.elapsed_s);
        let t_end = predict_s
            .filter(|t| t.is_finite() && *t > t_last)
            .unwrap_or(t_last);
        let knots: Vec<(f64, f64)> = used.iter().map(|v| (v.elapsed_s, coord(v))).collect();
        let c_of = |t: f64| -> f64 {
            if !by_load {
                return t;
            }
            let (t0, c0) = knots[0];
            let (tn, cn) = knots[knots.len() - 1];
            if t <= t0 {
                return c0;
            }
            if t >= tn {
                return cn + power * (t - tn);
            }
            let k = knots.partition_point(|&(a, _)| a <= t).max(1);
            let ((ta, ca), (tb, cb)) = (knots[k - 1], knots[k]);
            if tb > ta {
                ca + (cb - ca) * (t - ta) / (tb - ta)
            } else {
                ca
            }
        };
        let times: Vec<f64> = (0..CURVE_POINTS)
            .map(|i| t_end * i as f64 / (CURVE_POINTS - 1) as f64)
            .collect();
        let cs: Vec<f64> = times.iter().map(|&t| c_of(t)).collect();
        let curve = |quantity: &str, at: &dyn Fn(f64) -> (f64, f64), s2: f64| {
            let (value, se): (Vec<f64>, Vec<f64>) = cs.iter().map(|&c| at(c)).unzip();
            let half: Vec<f64> = se.iter().map(|e| 2.0 * (e * e + s2).sqrt()).collect();
            Curve {
                quantity: quantity.into(),
                band_low: value.iter().zip(&half).map(|(v, h)| v - h).collect(),
                band_high: value.iter().zip(&half).map(|(v, h)| v + h).collect(),
                value,
                se,
            }
        };
        let mut curves = vec![curve(
            "k0_n_per_m",
            &|c| law.predict(c),
            law.residual_sd * law.residual_sd,
        )];
        if let Some(f) = fit_track(&fc, &fy, &law) {
            curves.push(curve("f0_hz", &|c| f.predict(c), f.s2));
        }
        if let Some(f) = fit_track(&all_c, &keff, &law) {
            curves.push(curve("keff_n_per_m", &|c| f.predict(c), f.s2));
        }
        // Never a stored NaN: a curve that is not finite everywhere is left out.
        curves.retain(|k| {
            [&k.value, &k.se, &k.band_low, &k.band_high]
                .iter()
                .all(|v| v.iter().all(|x| x.is_finite()))
        });
        if cs.iter().all(|c| c.is_finite()) && t_end > 0.0 {
            doc.curves = Some(LawCurves {
                elapsed_s: times,
                load_j: by_load.then_some(cs),
                curves,
            });
        }
    }
    if let Some(ts) = predict_s.filter(|t| t.is_finite() && *t >= 0.0) {
        let last = used.last().expect("a fitted law has intervals");
        let t_last = last.elapsed_s;
        let c_at = if by_load {
            coord(last) + power * (ts - t_last)
        } else {
            ts
        };
        let (k0, se) = law.predict(c_at);
        let half = 2.0 * (se * se + law.residual_sd * law.residual_sd).sqrt();
        let f0 = (k0.max(0.0) / mass).sqrt() / (2.0 * std::f64::consts::PI);
        let f0_se = if k0 > 0.0 { 0.5 * f0 * se / k0 } else { 0.0 };
        let mut pv = prediction_validity(&validity, ts, t_last);
        if !(k0 > 0.0 && f0.is_finite()) {
            pv = HeadlineValidity {
                state: State::NotDetermined,
                reason: Some("the law gives no positive stiffness there".into()),
                fit_value: Some(k0),
            };
        }
        doc.prediction = Some(Prediction {
            elapsed_s: ts,
            load_j: by_load.then_some(c_at),
            k0_n_per_m: k0,
            k0_se_n_per_m: se,
            k0_band_n_per_m: [k0 - half, k0 + half],
            f0_hz: if f0.is_finite() { f0 } else { 0.0 },
            f0_se_hz: if f0_se.is_finite() { f0_se } else { 0.0 },
            validity: pv,
        });
    }
    doc
}

fn prediction_validity(law: &HeadlineValidity, ts: f64, t_last: f64) -> HeadlineValidity {
    if law.state != State::Valid {
        return HeadlineValidity {
            state: State::Unreliable,
            reason: Some(format!(
                "the law is {}: {}",
                serde_json::to_value(law.state)
                    .ok()
                    .and_then(|v| v.as_str().map(String::from))
                    .unwrap_or_default(),
                law.reason.clone().unwrap_or_default()
            )),
            fit_value: None,
        };
    }
    if ts > 3.0 * t_last {
        return HeadlineValidity {
            state: State::Unreliable,
            reason: Some(format!(
                "{ts:.0} s is more than three times the test's length ({t_last:.0} s)"
            )),
            fit_value: None,
        };
    }
    if ts > t_last {
        return HeadlineValidity {
            state: State::Extrapolated,
            reason: Some(format!(
                "beyond the last interval ({t_last:.0} s): the law extrapolated under the same stimulus"
            )),
            fit_value: None,
        };
    }
    HeadlineValidity::default()
}

/// The state of a value the measurement did not give.
fn not_measured(why: &str) -> HeadlineValidity {
    HeadlineValidity {
        state: State::NotDetermined,
        reason: Some(why.to_string()),
        fit_value: None,
    }
}
