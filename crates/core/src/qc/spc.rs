//! Statistical process control of one judged parameter: n, mean, sigma,
//! Cp, Cpk (within: average moving range / d2), Pp, Ppk (overall sample
//! sigma), yield and the data of an individuals control chart. Pure.
//!
//! One point per part and job (and level of a series): the repeats of a job
//! are one part measured again, not more parts. Their values are averaged
//! into one point ([`per_part`]); counting them as parts would shrink the
//! moving ranges to the repeatability and inflate Cp/Cpk (docs/qc.md).

use super::limits::mean_sigma;
use super::VerdictKind;
use serde::{Deserialize, Serialize};

/// d2 of a moving range of two (individuals chart).
pub const D2: f64 = 1.128;

/// One value of the parameter: a part measured by one job at one level
/// (the mean of the job's repeats at that level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SpcPoint {
    /// When the verdict was made (RFC 3339 UTC; the first repeat's).
    pub time: String,
    pub part_serial: String,
    /// The first of the measurements averaged into this point.
    pub measurement_id: String,
    /// The job that measured the part (None: a measurement without a job).
    #[serde(default)]
    pub job_id: Option<String>,
    /// Level of a series (index into the recipe's `levels_m`).
    #[serde(default)]
    pub level_index: Option<i64>,
    /// Mean of the repeats' values.
    pub value: f64,
    /// How many measurements (repeats) were averaged into `value`.
    #[serde(default = "one")]
    pub repeats: usize,
    /// `fail` when any repeat failed, else the first repeat's verdict.
    pub verdict: VerdictKind,
    /// The recipe version the point was judged by (the first repeat's):
    /// the QC view marks where it changes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe_version: Option<i64>,
}

fn one() -> usize {
    1
}

/// One point per (job, level): the values of a job's repeats at a level
/// averaged (arithmetic mean), in the order of their first repeat. Points
/// without a job stay single.
pub fn per_part(points: Vec<SpcPoint>) -> Vec<SpcPoint> {
    let mut out: Vec<SpcPoint> = Vec::with_capacity(points.len());
    let mut sums: Vec<f64> = Vec::with_capacity(points.len());
    let mut index: std::collections::HashMap<(String, Option<i64>), usize> = Default::default();
    for p in points {
        let key = p.job_id.clone().map(|j| (j, p.level_index));
        match key.as_ref().and_then(|k| index.get(k)) {
            Some(&i) => {
                let g = &mut out[i];
                sums[i] += p.value;
                g.repeats += 1;
                g.value = sums[i] / g.repeats as f64;
                if p.verdict == VerdictKind::Fail {
                    g.verdict = VerdictKind::Fail;
                }
            }
            None => {
                if let Some(k) = key {
                    index.insert(k, out.len());
                }
                sums.push(p.value);
                out.push(SpcPoint { repeats: 1, ..p });
            }
        }
    }
    out
}

/// The statistics of a window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Spc {
    pub parameter: String,
    pub unit: String,
    /// Values in the window (valid measurements only).
    pub n: usize,
    pub mean: Option<f64>,
    /// Overall sample standard deviation (n - 1): used by Pp and Ppk.
    pub sigma: Option<f64>,
    /// Within (short-term) sigma: average moving range / 1.128: used by Cp, Cpk and the chart.
    pub sigma_within: Option<f64>,
    pub lower: Option<f64>,
    pub upper: Option<f64>,
    pub cp: Option<f64>,
    pub cpk: Option<f64>,
    pub pp: Option<f64>,
    pub ppk: Option<f64>,
    /// Passed / (passed + failed) over the window's verdicts (invalid ones apart).
    pub yield_fraction: Option<f64>,
    pub passed: usize,
    pub failed: usize,
    pub invalid: usize,
    /// Individuals chart: centre line and control limits (mean +- 3 sigma_within).
    pub center_line: Option<f64>,
    pub ucl: Option<f64>,
    pub lcl: Option<f64>,
    /// The values in time order.
    pub points: Vec<SpcPoint>,
    /// Out-of-control signals of the individuals chart (Western Electric
    /// rules 1-4 against the centre line and sigma_within), in point order.
    #[serde(default)]
    pub rules: Vec<RuleSignal>,
}

/// A Western Electric rule met at a point of the individuals chart.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RuleSignal {
    /// 1: one point beyond 3 sigma; 2: two of three successive points
    /// beyond 2 sigma on one side; 3: four of five beyond 1 sigma on one
    /// side; 4: eight successive points on one side of the centre line.
    pub rule: u8,
    /// The point (index into `points`) that completes the pattern; it lies
    /// itself in the zone the rule names.
    pub index: usize,
    /// `above` or `below` the centre line.
    pub side: String,
}

/// The Western Electric rules (Statistical Quality Control Handbook, 1956)
/// over `values` in time order, with centre line `center` and sigma
/// `sigma` (> 0). A point exactly on the centre line is on neither side. A
/// signal is raised at the point that completes a pattern and lies in its
/// zone; each rule once per point and side.
pub fn western_electric(values: &[f64], center: f64, sigma: f64) -> Vec<RuleSignal> {
    let mut out = Vec::new();
    if !(sigma.is_finite() && sigma > 0.0 && center.is_finite()) {
        return out;
    }
    // z-scores, signed: > 0 above the centre line
    let z: Vec<f64> = values.iter().map(|v| (v - center) / sigma).collect();
    // (rule, window, how many of it, zone in sigma)
    const ZONES: [(u8, usize, usize, f64); 4] = [
        (1, 1, 1, 3.0),
        (2, 3, 2, 2.0),
        (3, 5, 4, 1.0),
        (4, 8, 8, 0.0),
    ];
    for i in 0..z.len() {
        for (rule, window, need, zone) in ZONES {
            if i + 1 < window {
                continue;
            }
            for (side, sign) in [("above", 1.0), ("below", -1.0)] {
                let beyond = |x: f64| sign * x > zone;
                if beyond(z[i])
                    && z[i + 1 - window..=i].iter().filter(|&&x| beyond(x)).count() >= need
                {
                    out.push(RuleSignal {
                        rule,
                        index: i,
                        side: side.to_string(),
                    });
                }
            }
        }
    }
    out
}

/// Cp and Cpk (or Pp and Ppk) of `mean` and the sigma `s` against the
/// limits; None without a positive finite sigma (Cp: without both limits).
/// Also the center's SPC from SQL aggregates (`springbench-store-pg`).
pub fn capability(
    lower: Option<f64>,
    upper: Option<f64>,
    mean: f64,
    s: f64,
) -> (Option<f64>, Option<f64>) {
    if !(s.is_finite() && s > 0.0) {
        return (None, None);
    }
    let cp = match (lower, upper) {
        (Some(l), Some(u)) => Some((u - l) / (6.0 * s)),
        _ => None,
    };
    let k = [
        upper.map(|u| (u - mean) / (3.0 * s)),
        lower.map(|l| (mean - l) / (3.0 * s)),
    ]
    .into_iter()
    .flatten()
    .fold(None, |a: Option<f64>, v| Some(a.map_or(v, |a| a.min(v))));
    (cp, k)
}

/// Statistics of `points` (one per measurement, time order) against the
/// limits, after [`per_part`]; `invalid` is the number of invalid verdicts
/// in the same window (they carry no value).
pub fn compute(
    parameter: &str,
    unit: &str,
    lower: Option<f64>,
    upper: Option<f64>,
    points: Vec<SpcPoint>,
    invalid: usize,
) -> Spc {
    let points = per_part(points);
    let v: Vec<f64> = points.iter().map(|p| p.value).collect();
    let n = v.len();
    let (mean, sigma) = if n > 0 {
        mean_sigma(&v)
    } else {
        (f64::NAN, f64::NAN)
    };
    let sigma_within = if n >= 2 {
        let mr: f64 = v.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (n - 1) as f64;
        mr / D2
    } else {
        f64::NAN
    };
    let (cp, cpk) = capability(lower, upper, mean, sigma_within);
    let (pp, ppk) = capability(lower, upper, mean, sigma);
    let passed = points
        .iter()
        .filter(|p| p.verdict == VerdictKind::Pass)
        .count();
    let failed = points
        .iter()
        .filter(|p| p.verdict == VerdictKind::Fail)
        .count();
    let fin = |x: f64| x.is_finite().then_some(x);
    Spc {
        parameter: parameter.to_string(),
        unit: unit.to_string(),
        n,
        mean: fin(mean),
        sigma: if n >= 2 { fin(sigma) } else { None },
        sigma_within: fin(sigma_within),
        lower,
        upper,
        cp,
        cpk,
        pp,
        ppk,
        yield_fraction: (passed + failed > 0).then(|| passed as f64 / (passed + failed) as f64),
        passed,
        failed,
        invalid,
        center_line: fin(mean),
        ucl: fin(mean + 3.0 * sigma_within),
        lcl: fin(mean - 3.0 * sigma_within),
        rules: western_electric(&v, mean, sigma_within),
        points,
    }
}

/// CSV of the control-chart points with the limits on every line.
pub fn to_csv(s: &Spc) -> String {
    let o = |x: Option<f64>| x.map(|v| format!("{v}")).unwrap_or_default();
    let mut out = String::from(
        "time,part_serial,measurement_id,parameter,unit,value,verdict,lower,upper,center_line,lcl,ucl,job_id,level_index,repeats\n",
    );
    for p in &s.points {
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            p.time,
            p.part_serial,
            p.measurement_id,
            s.parameter,
            s.unit,
            p.value,
            p.verdict.as_str(),
            o(s.lower),
            o(s.upper),
            o(s.center_line),
            o(s.lcl),
            o(s.ucl),
            p.job_id.as_deref().unwrap_or(""),
            p.level_index.map(|l| l.to_string()).unwrap_or_default(),
            p.repeats
        ));
    }
    out
}
