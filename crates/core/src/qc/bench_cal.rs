//! Bench calibration from golden units (issue 21, decision 0049).
//!
//! Two benches of one station differ where the analysis cannot calibrate the
//! difference away (decision 0038): the laser's sensitivity (the bench reads
//! (1 + e) x) and the inner clamp's mass dm (the fit, which takes the
//! recipe's moving mass m, reads every stiffness and R scaled by
//! s = m / (m + dm)). So a part's K(x) on a bench is
//!
//! ```text
//! K_bench(x) = s K(x / (1 + e))        k0_bench = s k0
//! f0_bench = sqrt(s) f0                Q_bench = Q / sqrt(s)
//! ```
//!
//! The same golden units measured on the reference bench (where the
//! recipe's golden reference and limits were measured) and on a bench give
//! s (the k0 ratio) and e (a least-squares fit of the bench's K(x) against
//! the reference's with the displacement scaled by 1 + e). Every later
//! measurement on that bench is judged on the corrected copy of its result
//! (the inverse map); the stored result stays as measured. A bench whose
//! estimated error exceeds a bound, or whose golden units disagree, is
//! `out_of_calibration`: its measurements are `invalid`, never corrected
//! silently. Pure: the store keeps the calibrations, the runner applies them.

use super::verdict::{judge, set_keff_at_target, InvalidReason, RunFacts, Verdict, VerdictKind};
use super::Recipe;
use crate::identify::Report;
use serde::{Deserialize, Serialize};

/// A laser sensitivity error beyond this (relative) is a bench out of
/// calibration: recalibrate the laser, do not correct it (a usual laser
/// calibration is good to about 0.2 %).
pub const MAX_LASER_GAIN_ERROR: f64 = 0.01;
/// A stiffness scale beyond 1 +- this (a clamp mass difference of 1 % of the
/// moving mass, 0.5 g on a 50 g spider) is a bench out of calibration: a
/// wrong or damaged clamp, not a tolerance.
pub const MAX_SCALE_ERROR: f64 = 0.01;
/// Golden units whose single estimates of e spread (standard deviation)
/// more than this disagree: a unit changed or was mixed up between the
/// benches; the calibration is refused.
pub const MAX_LASER_SPREAD: f64 = 0.001;
/// The same for the single k0 ratios.
pub const MAX_SCALE_SPREAD: f64 = 0.002;
/// Fewest golden units a calibration is estimated from.
pub const MIN_UNITS: usize = 3;

/// A calibration's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CalState {
    /// Within the bounds: measurements on the bench are judged corrected.
    InCalibration,
    /// Beyond a bound (or the golden units disagree): measurements on the
    /// bench are `invalid` (`bench_out_of_calibration`) until a new
    /// calibration is in bounds.
    OutOfCalibration,
}

impl CalState {
    pub fn as_str(self) -> &'static str {
        match self {
            CalState::InCalibration => "in_calibration",
            CalState::OutOfCalibration => "out_of_calibration",
        }
    }
}

/// One golden unit's estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct UnitEstimate {
    pub serial: String,
    /// k0 on the bench over k0 on the reference bench (1).
    pub k0_ratio: f64,
    /// K(x) scale of the fit (1).
    pub kx_scale: f64,
    /// Laser sensitivity error relative to the reference bench (1).
    pub laser_gain_error: f64,
    /// RMS of the K(x) fit's residual over the compared range (N/m).
    pub residual_rms_n_per_m: f64,
    /// Pairs of results (a repeat on the reference bench, a repeat on the
    /// bench) the figures above are the mean of; 1 in calibrations stored
    /// before repeats counted.
    #[serde(default = "one_pair")]
    pub pairs: usize,
}

fn one_pair() -> usize {
    1
}

/// A bench's calibration against the reference bench, from golden units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BenchCalibration {
    pub bench_id: String,
    /// The bench the golden units' reference values were measured on.
    pub reference_bench_id: String,
    /// The procedure the golden units were measured with on both benches:
    /// the calibration corrects measurements made with it (the full
    /// procedure's pre-measurement reaches its level on the laser's scale,
    /// the production one drives the golden voltage, so a laser error moves
    /// k0 differently in each).
    pub procedure: crate::job::ProcedureMode,
    pub state: CalState,
    /// Why the calibration is out of calibration (empty when in).
    pub problems: Vec<String>,
    /// Mean small-signal stiffness scale s = k0 on the bench / on the
    /// reference (1): the small-signal values are corrected by it.
    pub k_scale: f64,
    pub k_scale_sd: f64,
    /// Mean K(x) scale of the fit (1): K(x) and Keff are corrected by it.
    pub kx_scale: f64,
    pub kx_scale_sd: f64,
    /// Mean laser sensitivity error e (the bench reads (1 + e) x).
    pub laser_gain_error: f64,
    pub laser_gain_error_sd: f64,
    /// The recipe's moving mass the clamp mass is stated against (kg).
    pub moving_mass_kg: f64,
    /// The clamp's extra mass m (1 / a - 1) with a the K(x) scale (kg): the
    /// K(x) fit separates the laser from the clamp, where the small-signal
    /// k0 ratio also carries the laser's shift of the pre-measurement's level
    /// (4.7e-5 of k0 for a 0.2 % laser error on spider_4in: 52 mg would be
    /// read for a 50 mg clamp).
    pub clamp_mass_kg: f64,
    pub units: Vec<UnitEstimate>,
}

fn poly(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |a, &k| a * x + k)
}

fn dpoly(c: &[f64], x: f64) -> f64 {
    c.iter()
        .enumerate()
        .skip(1)
        .rev()
        .fold(0.0, |a, (i, &k)| a * x + i as f64 * k)
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let sd = if v.len() > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (m, sd)
}

/// One golden unit: s and e from its result on the reference bench and on
/// the bench. The K(x) fit minimises sum (K_b(x) - a K_r(x / (1 + e)))^2
/// over 41 points of the range both measured (Gauss-Newton in a and e).
pub fn estimate_unit(
    serial: &str,
    reference: &Report,
    bench: &Report,
) -> Result<UnitEstimate, String> {
    let k0 = |r: &Report| r.small_signal.as_ref().and_then(|s| s.k0_n_per_m);
    let (Some(k0r), Some(k0b)) = (k0(reference), k0(bench)) else {
        return Err(format!("{serial}: k0 not determined in both results"));
    };
    let (cr, cb) = (
        &reference.stiffness.coefficients_n_per_m_pow_i_plus_1,
        &bench.stiffness.coefficients_n_per_m_pow_i_plus_1,
    );
    if cr.is_empty() || cb.is_empty() || !(k0r > 0.0 && k0b > 0.0) {
        return Err(format!("{serial}: no K(x) or k0 <= 0 in both results"));
    }
    let lo = reference.stiffness.valid_range_m[0].max(bench.stiffness.valid_range_m[0]);
    let hi = reference.stiffness.valid_range_m[1].min(bench.stiffness.valid_range_m[1]);
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Err(format!("{serial}: the two results share no measured range"));
    }
    // 95 % of the shared range: the reference is read at x / (1 + e).
    let (lo, hi) = (0.95 * lo, 0.95 * hi);
    let xs: Vec<f64> = (0..41).map(|j| lo + (hi - lo) * j as f64 / 40.0).collect();
    let (mut a, mut e) = (k0b / k0r, 0.0f64);
    for _ in 0..20 {
        // r = K_b(x) - a K_r(y), y = x / (1 + e); dr/da = -K_r(y), dr/de = a K_r'(y) x / (1 + e)^2
        let (mut saa, mut sae, mut see, mut sar, mut ser) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &x in &xs {
            let y = x / (1.0 + e);
            let r = poly(cb, x) - a * poly(cr, y);
            let ja = -poly(cr, y);
            let je = a * dpoly(cr, y) * x / (1.0 + e).powi(2);
            saa += ja * ja;
            sae += ja * je;
            see += je * je;
            sar += ja * r;
            ser += je * r;
        }
        let det = saa * see - sae * sae;
        if !(det.is_finite() && det > 0.0) {
            return Err(format!(
                "{serial}: K(x) has no slope over the shared range: the laser scale cannot be estimated"
            ));
        }
        let da = -(see * sar - sae * ser) / det;
        let de = -(saa * ser - sae * sar) / det;
        a += da;
        e += de;
        if da.abs() < 1e-12 && de.abs() < 1e-12 {
            break;
        }
    }
    let rms = (xs
        .iter()
        .map(|&x| (poly(cb, x) - a * poly(cr, x / (1.0 + e))).powi(2))
        .sum::<f64>()
        / xs.len() as f64)
        .sqrt();
    if !(a.is_finite() && e.is_finite() && e > -0.5) {
        return Err(format!("{serial}: the K(x) fit did not converge"));
    }
    Ok(UnitEstimate {
        serial: serial.to_string(),
        k0_ratio: k0b / k0r,
        kx_scale: a,
        laser_gain_error: e,
        residual_rms_n_per_m: rms,
        pairs: 1,
    })
}

/// One golden unit measured with repeats: [`estimate_unit`] of every pair
/// (a repeat on the reference bench, a repeat on the bench), averaged. The
/// repeats measure the same unit again, so the unit's estimate is their
/// mean, and the spread between units (the calibration's agreement check)
/// stays a spread between units.
pub fn estimate_unit_repeats(
    serial: &str,
    reference: &[Report],
    bench: &[Report],
) -> Result<UnitEstimate, String> {
    if reference.is_empty() || bench.is_empty() {
        return Err(format!("{serial}: no result on both benches"));
    }
    let mut all = vec![];
    for r in reference {
        for b in bench {
            all.push(estimate_unit(serial, r, b)?);
        }
    }
    let n = all.len() as f64;
    let mean = |f: fn(&UnitEstimate) -> f64| all.iter().map(f).sum::<f64>() / n;
    Ok(UnitEstimate {
        serial: serial.to_string(),
        k0_ratio: mean(|u| u.k0_ratio),
        kx_scale: mean(|u| u.kx_scale),
        laser_gain_error: mean(|u| u.laser_gain_error),
        residual_rms_n_per_m: mean(|u| u.residual_rms_n_per_m),
        pairs: all.len(),
    })
}

/// A bench's calibration from golden units, each as (serial, its results
/// on the reference bench, its results on the bench: one per repeat). Err:
/// fewer than [`MIN_UNITS`] units or a unit without the values; a
/// calibration beyond the bounds comes back `out_of_calibration` with its
/// problems.
pub fn estimate(
    bench_id: &str,
    reference_bench_id: &str,
    procedure: crate::job::ProcedureMode,
    moving_mass_kg: f64,
    units: &[(String, Vec<Report>, Vec<Report>)],
) -> Result<BenchCalibration, String> {
    if units.len() < MIN_UNITS {
        return Err(format!(
            "{} golden unit(s) measured on both benches; a bench calibration needs at least {MIN_UNITS}",
            units.len()
        ));
    }
    if !(moving_mass_kg.is_finite() && moving_mass_kg > 0.0) {
        return Err(format!("moving mass {moving_mass_kg} kg is not positive"));
    }
    let est = units
        .iter()
        .map(|(s, r, b)| estimate_unit_repeats(s, r, b))
        .collect::<Result<Vec<_>, _>>()?;
    let col = |f: fn(&UnitEstimate) -> f64| est.iter().map(f).collect::<Vec<_>>();
    let (k_scale, k_scale_sd) = mean_sd(&col(|u| u.k0_ratio));
    let (kx_scale, kx_scale_sd) = mean_sd(&col(|u| u.kx_scale));
    let (e, e_sd) = mean_sd(&col(|u| u.laser_gain_error));
    let mut problems = vec![];
    if e.abs() > MAX_LASER_GAIN_ERROR {
        problems.push(format!(
            "laser sensitivity {:+.3} % from the reference bench's (bound +-{} %): calibrate the laser",
            100.0 * e,
            100.0 * MAX_LASER_GAIN_ERROR
        ));
    }
    for (what, v) in [("k0", k_scale), ("K(x)", kx_scale)] {
        if (v - 1.0).abs() > MAX_SCALE_ERROR {
            problems.push(format!(
                "{what} reads {:+.3} % from the reference bench's (bound +-{} %): check the clamp",
                100.0 * (v - 1.0),
                100.0 * MAX_SCALE_ERROR
            ));
        }
    }
    if e_sd > MAX_LASER_SPREAD {
        problems.push(format!(
            "the golden units' laser errors spread {:.3} % (bound {} %): a unit changed or was mixed up",
            100.0 * e_sd,
            100.0 * MAX_LASER_SPREAD
        ));
    }
    if k_scale_sd > MAX_SCALE_SPREAD {
        problems.push(format!(
            "the golden units' k0 ratios spread {:.3} % (bound {} %): a unit changed or was mixed up",
            100.0 * k_scale_sd,
            100.0 * MAX_SCALE_SPREAD
        ));
    }
    Ok(BenchCalibration {
        bench_id: bench_id.to_string(),
        reference_bench_id: reference_bench_id.to_string(),
        procedure,
        state: if problems.is_empty() {
            CalState::InCalibration
        } else {
            CalState::OutOfCalibration
        },
        problems,
        k_scale,
        k_scale_sd,
        kx_scale,
        kx_scale_sd,
        laser_gain_error: e,
        laser_gain_error_sd: e_sd,
        moving_mass_kg,
        clamp_mass_kg: moving_mass_kg * (1.0 / kx_scale - 1.0),
        units: est,
    })
}

/// The result as the reference bench would have measured it: the inverse
/// of the bench's map (module doc). Keff at a target is recomputed by
/// [`judge_calibrated`] from the corrected K(x).
pub fn correct(r: &Report, c: &BenchCalibration) -> Report {
    let mut r = r.clone();
    let g = 1.0 + c.laser_gain_error;
    let (s, sk) = (c.k_scale, c.kx_scale);
    let rs = s.sqrt();
    if let Some(ss) = r.small_signal.as_mut() {
        ss.k0_n_per_m = ss.k0_n_per_m.map(|v| v / s);
        ss.k0_se_n_per_m /= s;
        ss.r_ns_per_m = ss.r_ns_per_m.map(|v| v / s);
        ss.r_se_ns_per_m /= s;
        ss.f0_hz = ss.f0_hz.map(|v| v / rs);
        ss.f0_se_hz = ss.f0_se_hz.map(|v| v / rs);
        ss.q = ss.q.map(|v| v * rs);
        ss.q_se = ss.q_se.map(|v| v * rs);
    }
    let st = &mut r.stiffness;
    for v in [
        &mut st.coefficients_n_per_m_pow_i_plus_1,
        &mut st.coefficients_se_n_per_m_pow_i_plus_1,
        &mut st.coefficients_n_per_mm_pow_i_plus_1,
    ] {
        for (i, k) in v.iter_mut().enumerate() {
            *k *= g.powi(i as i32) / sk;
        }
    }
    st.valid_range_m = [st.valid_range_m[0] / g, st.valid_range_m[1] / g];
    st.xc_m = st.xc_m.map(|x| x.map(|x| x / g));
    st.r_ns_per_m /= sk;
    st.r_se_ns_per_m /= sk;
    let l = &mut r.large_signal;
    l.keff_n_per_m /= sk;
    l.keff_from_k_of_x_n_per_m /= sk;
    l.ceff_m_per_n *= sk;
    l.resonance_hz /= sk.sqrt();
    for x in [
        &mut l.xpeak_m,
        &mut l.x_min_m,
        &mut l.x_max_m,
        &mut l.dc_m,
        &mut l.x_min_at_resonance_m,
        &mut l.x_max_at_resonance_m,
    ] {
        *x /= g;
    }
    for h in l.harmonics_m.iter_mut() {
        *h /= g;
    }
    r
}

/// The verdict of a measurement on a bench with calibration `cal`: none,
/// the plain verdict; in calibration, the verdict of the corrected result;
/// out of calibration, `invalid` (`bench_out_of_calibration`) whatever the
/// values (they are judged as measured, for the record).
pub fn judge_calibrated(
    recipe: &Recipe,
    facts: &RunFacts,
    cal: Option<&BenchCalibration>,
) -> Verdict {
    let Some(c) = cal else {
        return judge(recipe, facts);
    };
    if c.state == CalState::OutOfCalibration {
        let mut v = judge(recipe, facts);
        v.verdict = VerdictKind::Invalid;
        v.failures.clear();
        v.invalid_reasons.push(InvalidReason {
            code: "bench_out_of_calibration".into(),
            detail: format!(
                "bench '{}' is out of calibration against '{}': {}",
                c.bench_id,
                c.reference_bench_id,
                c.problems.join("; ")
            ),
        });
        return v;
    }
    let mut f = facts.clone();
    if let Some(r) = &facts.report {
        let mut cr = correct(r, c);
        if let Some(xt) = facts.target_xpeak_m {
            set_keff_at_target(&mut cr, Some(xt));
        }
        f.report = Some(cr);
    }
    judge(recipe, &f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{LargeSignal, SmallSignal, Stiffness};

    /// A spider-like K(x) (N/m^(i+1)), measured over +-8 mm.
    const K: [f64; 5] = [2450.0, -4.0e3, 1.2e7, 0.0, 2.0e11];

    fn unit(scale: f64, k0_scale: f64, e: f64, g_unit: f64) -> Report {
        let g = 1.0 + e;
        // K_b(x) = s K(x / g): coefficient i times s / g^i; a unit's own
        // stiffness times g_unit.
        let c: Vec<f64> = K
            .iter()
            .enumerate()
            .map(|(i, k)| k * g_unit * scale / g.powi(i as i32))
            .collect();
        Report {
            small_signal: Some(SmallSignal {
                f0_hz: Some(35.0 * k0_scale.sqrt()),
                k0_n_per_m: Some(K[0] * g_unit * k0_scale),
                q: Some(6.0 / k0_scale.sqrt()),
                r_ns_per_m: Some(1.5 * k0_scale),
                reliable: true,
                ..Default::default()
            }),
            large_signal: LargeSignal {
                xpeak_m: 0.008 * g,
                x_min_at_resonance_m: -0.008 * g,
                x_max_at_resonance_m: 0.008 * g,
                ..Default::default()
            },
            stiffness: Stiffness {
                coefficients_n_per_m_pow_i_plus_1: c,
                valid_range_m: [-0.008 * g, 0.008 * g],
                ..Default::default()
            },
            ..Default::default()
        }
    }

    fn golden(s: f64, e: f64) -> Vec<(String, Vec<Report>, Vec<Report>)> {
        [0.98, 1.0, 1.03]
            .iter()
            .enumerate()
            .map(|(i, &gu)| {
                (
                    format!("G-{i}"),
                    vec![unit(1.0, 1.0, 0.0, gu)],
                    vec![unit(s, s, e, gu)],
                )
            })
            .collect()
    }

    #[test]
    fn the_laser_error_and_clamp_mass_are_recovered_and_corrected_away() {
        // A clamp 0.05 g heavier on 50 g, a laser reading 0.2 % long.
        let (m, dm, e) = (0.05, 0.00005, 0.002);
        let s = m / (m + dm);
        let c = estimate(
            "b",
            "ref",
            crate::job::ProcedureMode::Full,
            m,
            &golden(s, e),
        )
        .unwrap();
        assert_eq!(c.state, CalState::InCalibration, "{:?}", c.problems);
        assert!(
            (c.laser_gain_error - e).abs() < 1e-9,
            "{}",
            c.laser_gain_error
        );
        assert!((c.k_scale - s).abs() < 1e-12 && (c.kx_scale - s).abs() < 1e-9);
        assert!((c.clamp_mass_kg - dm).abs() < 1e-10, "{}", c.clamp_mass_kg);
        // The corrected result equals the reference bench's.
        let want = unit(1.0, 1.0, 0.0, 1.0);
        let got = correct(&unit(s, s, e, 1.0), &c);
        for x in [-0.007, -0.004, 0.0, 0.004, 0.007] {
            let (a, b) = (
                poly(&got.stiffness.coefficients_n_per_m_pow_i_plus_1, x),
                poly(&want.stiffness.coefficients_n_per_m_pow_i_plus_1, x),
            );
            assert!((a - b).abs() < 1e-6 * b, "K({x}) {a} vs {b}");
        }
        let (gs, ws) = (got.small_signal.unwrap(), want.small_signal.unwrap());
        for (a, b) in [
            (gs.k0_n_per_m, ws.k0_n_per_m),
            (gs.f0_hz, ws.f0_hz),
            (gs.q, ws.q),
            (gs.r_ns_per_m, ws.r_ns_per_m),
        ] {
            let (a, b) = (a.unwrap(), b.unwrap());
            assert!((a - b).abs() < 1e-9 * b, "{a} vs {b}");
        }
        assert!((got.stiffness.valid_range_m[1] - 0.008).abs() < 1e-12);
    }

    #[test]
    fn a_unit_measured_with_repeats_is_the_mean_of_its_pairs() {
        // Two repeats on the bench whose lasers read 0.1 % and 0.3 % long
        // (a noisy laser), one on the reference: the unit's error is 0.2 %.
        let u = estimate_unit_repeats(
            "G-0",
            &[unit(1.0, 1.0, 0.0, 1.0)],
            &[unit(1.0, 1.0, 0.001, 1.0), unit(1.0, 1.0, 0.003, 1.0)],
        )
        .unwrap();
        assert_eq!(u.pairs, 2);
        assert!((u.laser_gain_error - 0.002).abs() < 1e-9, "{u:?}");
        assert!((u.kx_scale - 1.0).abs() < 1e-9, "{u:?}");
        assert!(estimate_unit_repeats("G-0", &[], &[unit(1.0, 1.0, 0.0, 1.0)]).is_err());
    }

    #[test]
    fn a_bench_beyond_the_bounds_or_with_disagreeing_units_is_out_of_calibration() {
        // Bench "b" against "ref", full procedure, a 50 g moving mass.
        let est = |g: &[_]| estimate("b", "ref", crate::job::ProcedureMode::Full, 0.05, g);
        let c = est(&golden(1.0, 0.02)).unwrap();
        assert_eq!(c.state, CalState::OutOfCalibration);
        assert!(c.problems[0].contains("laser"), "{:?}", c.problems);
        let c = est(&golden(0.97, 0.0)).unwrap();
        assert_eq!(c.state, CalState::OutOfCalibration);
        assert!(c.problems.iter().any(|p| p.contains("clamp")));
        // One unit read on the bench with a 0.5 % other laser error.
        let mut g = golden(1.0, 0.0);
        g[2].2 = vec![unit(1.0, 1.0, 0.005, 1.03)];
        let c = est(&g).unwrap();
        assert_eq!(c.state, CalState::OutOfCalibration);
        assert!(
            c.problems.iter().any(|p| p.contains("spread")),
            "{:?}",
            c.problems
        );
        assert!(est(&g[..2]).is_err());
    }

    #[test]
    fn out_of_calibration_makes_the_verdict_invalid_in_calibration_corrects_it() {
        use super::super::{ParamSpec, Quantity};
        let p = |name: &str, q, x_m, lo, hi| ParamSpec {
            name: String::from(name),
            quantity: q,
            x_m,
            effect: None,
            effect_parameter: None,
            level_index: None,
            lower: Some(lo),
            upper: Some(hi),
            from_golden: None,
        };
        let want = unit(1.0, 1.0, 0.0, 1.0);
        let k4 = poly(&want.stiffness.coefficients_n_per_m_pow_i_plus_1, 0.004);
        let recipe = Recipe {
            name: "r".into(),
            part_kind: None,
            description: None,
            procedure: super::super::ProcedureSettings {
                levels_m: vec![0.008],
                method: crate::identify::Method::TwoSignal,
                order: Some(4),
                repeats: 1,
                moving_mass_kg: Some(0.05),
                mode: Default::default(),
                golden: None,
            },
            parameters: vec![
                p("k0", Quantity::K0, None, 2449.0, 2451.0),
                p("k4", Quantity::KAtX, Some(0.004), k4 * 0.9995, k4 * 1.0005),
            ],
            validity: super::super::Validity {
                require_small_signal_reliable: false,
                ..Default::default()
            },
            kx_mask: None,
        };
        // 0.5 % laser, 0.2 % clamp: k0 and K(4 mm) fail as measured.
        let s = 0.998;
        let facts = RunFacts {
            report: Some(unit(s, s, 0.005, 1.0)),
            target_xpeak_m: Some(0.008),
            drive_v: Some(20.0),
            max_drive_v: Some(100.0),
            ..Default::default()
        };
        let raw = judge_calibrated(&recipe, &facts, None);
        assert_eq!(raw.verdict, VerdictKind::Fail, "{raw:?}");
        let mut c = estimate(
            "b",
            "ref",
            crate::job::ProcedureMode::Full,
            0.05,
            &golden(s, 0.005),
        )
        .unwrap();
        let v = judge_calibrated(&recipe, &facts, Some(&c));
        assert_eq!(v.verdict, VerdictKind::Pass, "{v:?}");
        c.state = CalState::OutOfCalibration;
        c.problems = vec!["laser".into()];
        let v = judge_calibrated(&recipe, &facts, Some(&c));
        assert_eq!(v.verdict, VerdictKind::Invalid);
        assert_eq!(
            v.invalid_reasons.last().unwrap().code,
            "bench_out_of_calibration"
        );
    }
}
