//! Gauge R&R (measurement-system analysis) by the ANOVA method of AIAG MSA
//! (4th edition): a crossed study of n parts, each measured r times on each
//! of a appraisers (here: benches or stations). Pure.
//!
//! With y_ijk the k-th value of part i on appraiser j, cell means ȳ_ij.,
//! part means ȳ_i.., appraiser means ȳ_.j. and the grand mean ȳ:
//!
//! | source | SS | df |
//! |---|---|---|
//! | part | a r Σ_i (ȳ_i.. − ȳ)² | n − 1 |
//! | appraiser | n r Σ_j (ȳ_.j. − ȳ)² | a − 1 |
//! | part × appraiser | r Σ_ij (ȳ_ij. − ȳ_i.. − ȳ_.j. + ȳ)² | (n − 1)(a − 1) |
//! | repeatability | Σ_ijk (y_ijk − ȳ_ij.)² | n a (r − 1) |
//!
//! MS = SS / df. The interaction is tested with F = MS_PA / MS_E; when its
//! p-value exceeds [`INTERACTION_ALPHA`] (AIAG: 0.25) it is pooled into the
//! repeatability (MS_E' = (SS_PA + SS_E) / (df_PA + df_E)) and the variance
//! components are σ²_E = MS_E', σ²_A = (MS_A − MS_E') / (n r),
//! σ²_P = (MS_P − MS_E') / (a r); otherwise σ²_E = MS_E,
//! σ²_PA = (MS_PA − MS_E) / r, σ²_A = (MS_A − MS_PA) / (n r),
//! σ²_P = (MS_P − MS_PA) / (a r). A negative component is 0.
//!
//! EV = σ_E (repeatability), AV = sqrt(σ²_A + σ²_PA) (reproducibility),
//! GRR = sqrt(EV² + AV²), PV = σ_P, TV = sqrt(GRR² + PV²);
//! %GRR of the tolerance = 100 · 6 GRR / (USL − LSL), of the process =
//! 100 · GRR / TV; ndc = ⌊1.41 · PV / GRR⌋. Acceptance: below 10 %
//! acceptable, 10-30 % conditionally acceptable, above 30 % not; ndc ≥ 5.

use crate::diagnose::stats::f_upper_p;
use crate::job::JobProduction;
use serde::{Deserialize, Serialize};

/// AIAG's significance level for keeping the part × appraiser interaction.
pub const INTERACTION_ALPHA: f64 = 0.25;
/// Spread that covers the process (AIAG 4th edition: 6 σ; older: 5.15 σ).
pub const SPREAD_SIGMAS: f64 = 6.0;

/// One line of the ANOVA table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AnovaRow {
    /// `part`, `appraiser`, `part_x_appraiser`, `repeatability`, `total`.
    pub source: String,
    pub df: f64,
    /// Sum of squares (in the quantity's unit, squared).
    pub ss: f64,
    /// Mean square (None for `total`).
    pub ms: Option<f64>,
    /// F statistic against its error term (None where not tested).
    pub f: Option<f64>,
    pub p_value: Option<f64>,
}

/// The study of one quantity. Standard deviations are in the quantity's
/// `unit`; percentages of the tolerance need the recipe's limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GaugeRr {
    /// The quantity (a recipe parameter's id) and its SI unit.
    pub quantity: String,
    pub unit: String,
    pub parts: usize,
    pub appraisers: usize,
    pub repeats: usize,
    pub anova: Vec<AnovaRow>,
    /// True when the interaction was not significant (p > 0.25) and was
    /// pooled into the repeatability.
    pub interaction_pooled: bool,
    /// Repeatability, equipment variation EV (σ, unit).
    pub ev_sd: f64,
    /// Reproducibility, appraiser variation AV incl. the interaction (σ, unit).
    pub av_sd: f64,
    /// The interaction's share of AV (σ, unit; 0 when pooled).
    pub interaction_sd: f64,
    /// sqrt(EV² + AV²) (σ, unit).
    pub grr_sd: f64,
    /// Part variation PV (σ, unit).
    pub pv_sd: f64,
    /// Total variation sqrt(GRR² + PV²) (σ, unit).
    pub tv_sd: f64,
    /// USL − LSL (unit), when the recipe judges the quantity with both limits.
    pub tolerance: Option<f64>,
    /// 100 · 6 σ / tolerance.
    pub ev_percent_of_tolerance: Option<f64>,
    pub av_percent_of_tolerance: Option<f64>,
    pub grr_percent_of_tolerance: Option<f64>,
    /// 100 · σ / TV.
    pub grr_percent_of_total: f64,
    pub pv_percent_of_total: f64,
    /// Number of distinct categories, ⌊1.41 · PV / GRR⌋ (None when GRR is 0).
    pub ndc: Option<u32>,
    /// `acceptable` (< 10 %), `conditionally_acceptable` (10-30 %),
    /// `not_acceptable` (> 30 %): %GRR of the tolerance, of the distance to
    /// a one-sided limit ([`study`]), or of the total variation without
    /// limits; `not_applicable` when a one-sided limit lies on the wrong
    /// side of the parts' mean (no distance to judge against).
    pub acceptance: String,
    /// The grand mean of every value (unit).
    #[serde(default)]
    pub mean: f64,
    /// `two_sided`, `upper` or `lower` (one-sided), or `none` ([`study`]).
    #[serde(default)]
    pub limits: String,
    /// The one limit of a one-sided tolerance (unit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub one_sided_limit: Option<f64>,
    /// |limit − mean| for a one-sided limit (unit): AIAG MSA judges a
    /// one-sided characteristic against it with 3 σ, the half spread.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limit_distance: Option<f64>,
    /// 100 · 3 GRR / |limit − mean| (one-sided limit, mean inside it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grr_percent_of_limit_distance: Option<f64>,
    /// What a reader must know before signing: too few parts or benches,
    /// a one-sided figure not applicable.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// AIAG MSA's minimum number of parts in a study.
pub const MIN_PARTS: usize = 10;
/// AIAG MSA's minimum number of appraisers (here: benches or operators).
pub const MIN_APPRAISERS: usize = 2;

/// The study of one recipe parameter under its limits (issue 35): both
/// limits judge %GRR against the tolerance USL − LSL (6 σ); one limit, as
/// AIAG MSA does for a one-sided characteristic, against the distance from
/// the parts' mean to that limit (3 σ: 100 · 3 GRR / |limit − mean|), or
/// `not_applicable` when the mean is not inside the limit; no limit,
/// against the total variation. Warns below [`MIN_PARTS`] parts or
/// [`MIN_APPRAISERS`] benches.
pub fn study(
    quantity: &str,
    unit: &str,
    values: &[Vec<Vec<f64>>],
    lower: Option<f64>,
    upper: Option<f64>,
) -> Result<GaugeRr, String> {
    let tolerance = match (lower, upper) {
        (Some(l), Some(u)) if u > l => Some(u - l),
        _ => None,
    };
    let mut g = anova(quantity, unit, values, tolerance)?;
    let all: Vec<f64> = values.iter().flatten().flatten().copied().collect();
    g.mean = all.iter().sum::<f64>() / all.len().max(1) as f64;
    let one = match (lower, upper) {
        (Some(_), Some(_)) => None,
        (None, Some(u)) => Some(("upper", u, u - g.mean)),
        (Some(l), None) => Some(("lower", l, g.mean - l)),
        (None, None) => None,
    };
    g.limits = match (lower, upper, one) {
        (Some(_), Some(_), _) => "two_sided".into(),
        (_, _, Some((side, _, _))) => side.into(),
        _ => "none".into(),
    };
    if let Some((side, limit, dist)) = one {
        g.one_sided_limit = Some(limit);
        if dist > 0.0 && dist.is_finite() {
            let pct = 100.0 * 0.5 * SPREAD_SIGMAS * g.grr_sd / dist;
            g.limit_distance = Some(dist);
            g.grr_percent_of_limit_distance = Some(pct);
            g.acceptance = acceptance(pct).into();
        } else {
            g.acceptance = "not_applicable".into();
            g.warnings.push(format!(
                "%GRR is not applicable: the parts' mean lies {} the {side} limit, so there is no distance to the limit to judge the gauge against",
                if dist == 0.0 { "on" } else { "beyond" }
            ));
        }
    }
    if g.parts < MIN_PARTS {
        g.warnings.push(format!(
            "{} parts: AIAG MSA asks for at least {MIN_PARTS}; the figures are less certain than they look",
            g.parts
        ));
    }
    if g.appraisers < MIN_APPRAISERS {
        g.warnings.push(format!(
            "{} bench: the reproducibility (AV) cannot be estimated; AIAG MSA asks for at least {MIN_APPRAISERS} benches or operators",
            g.appraisers
        ));
    }
    Ok(g)
}

fn acceptance(pct: f64) -> &'static str {
    if pct < 10.0 {
        "acceptable"
    } else if pct <= 30.0 {
        "conditionally_acceptable"
    } else {
        "not_acceptable"
    }
}

/// The ANOVA gauge study of `values[part][appraiser][repeat]` (a balanced
/// crossed design: every part on every appraiser, the same number of
/// repeats everywhere, at least 2 parts and 2 repeats). `tolerance` is
/// USL − LSL in the values' unit. One-line error for a design the method
/// cannot take.
pub fn anova(
    quantity: &str,
    unit: &str,
    values: &[Vec<Vec<f64>>],
    tolerance: Option<f64>,
) -> Result<GaugeRr, String> {
    let n = values.len();
    if n < 2 {
        return Err(format!(
            "{quantity}: a gauge study needs at least 2 parts, got {n}"
        ));
    }
    let a = values[0].len();
    if a < 1 {
        return Err(format!("{quantity}: no appraiser (bench) has values"));
    }
    let r = values[0].first().map_or(0, |c| c.len());
    if r < 2 {
        return Err(format!(
            "{quantity}: a gauge study needs at least 2 repeats per part and bench, got {r}"
        ));
    }
    for (i, p) in values.iter().enumerate() {
        if p.len() != a || p.iter().any(|c| c.len() != r) {
            return Err(format!(
                "{quantity}: part {} does not have {r} values on each of {a} benches (the design must be balanced)",
                i + 1
            ));
        }
        if p.iter().flatten().any(|v| !v.is_finite()) {
            return Err(format!(
                "{quantity}: part {} has a value that is not a finite number",
                i + 1
            ));
        }
    }
    if let Some(t) = tolerance {
        if !(t.is_finite() && t > 0.0) {
            return Err(format!(
                "{quantity}: the tolerance must be a positive number, got {t}"
            ));
        }
    }
    let (nf, af, rf) = (n as f64, a as f64, r as f64);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let cell: Vec<Vec<f64>> = values
        .iter()
        .map(|p| p.iter().map(|c| mean(c)).collect())
        .collect();
    let part_mean: Vec<f64> = cell.iter().map(|p| mean(p)).collect();
    let appr_mean: Vec<f64> = (0..a)
        .map(|j| cell.iter().map(|p| p[j]).sum::<f64>() / nf)
        .collect();
    let grand = mean(&part_mean);
    let ss_p = af * rf * part_mean.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_a = nf * rf * appr_mean.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let mut ss_pa = 0.0;
    let mut ss_e = 0.0;
    for i in 0..n {
        for j in 0..a {
            ss_pa += (cell[i][j] - part_mean[i] - appr_mean[j] + grand).powi(2);
            ss_e += values[i][j]
                .iter()
                .map(|y| (y - cell[i][j]).powi(2))
                .sum::<f64>();
        }
    }
    ss_pa *= rf;
    let (df_p, df_a) = (nf - 1.0, af - 1.0);
    let df_pa = df_p * df_a;
    let df_e = nf * af * (rf - 1.0);
    let ms = |ss: f64, df: f64| (df > 0.0).then(|| ss / df);
    let (ms_p, ms_a, ms_pa, ms_e) = (ss_p / df_p, ms(ss_a, df_a), ms(ss_pa, df_pa), ss_e / df_e);
    // The interaction's test (only with two or more appraisers).
    let f_pa = ms_pa.map(|m| ratio(m, ms_e));
    let p_pa = f_pa.map(|f| f_upper_p(f, df_pa, df_e));
    let pooled = p_pa.is_none_or(|p| p > INTERACTION_ALPHA);
    let (var_e, var_pa, var_a, var_p, err_ms, err_df) = if pooled {
        let ms_pool = (ss_pa + ss_e) / (df_pa + df_e);
        (
            ms_pool,
            0.0,
            ms_a.map_or(0.0, |m| ((m - ms_pool) / (nf * rf)).max(0.0)),
            ((ms_p - ms_pool) / (af * rf)).max(0.0),
            ms_pool,
            df_pa + df_e,
        )
    } else {
        let m_pa = ms_pa.unwrap_or(0.0);
        (
            ms_e,
            ((m_pa - ms_e) / rf).max(0.0),
            ms_a.map_or(0.0, |m| ((m - m_pa) / (nf * rf)).max(0.0)),
            ((ms_p - m_pa) / (af * rf)).max(0.0),
            m_pa,
            df_pa,
        )
    };
    // Part and appraiser against the interaction when it stays, else
    // against the pooled error.
    let test = |m: f64, df: f64| {
        let f = ratio(m, err_ms);
        (Some(f), Some(f_upper_p(f, df, err_df)))
    };
    let (f_p, p_p) = test(ms_p, df_p);
    let (f_a, p_a) = ms_a.map_or((None, None), |m| test(m, df_a));
    let mut rows = vec![AnovaRow {
        source: "part".into(),
        df: df_p,
        ss: ss_p,
        ms: Some(ms_p),
        f: f_p,
        p_value: p_p,
    }];
    if a > 1 {
        rows.push(AnovaRow {
            source: "appraiser".into(),
            df: df_a,
            ss: ss_a,
            ms: ms_a,
            f: f_a,
            p_value: p_a,
        });
        rows.push(AnovaRow {
            source: "part_x_appraiser".into(),
            df: df_pa,
            ss: ss_pa,
            ms: ms_pa,
            f: f_pa,
            p_value: p_pa,
        });
    }
    rows.push(AnovaRow {
        source: "repeatability".into(),
        df: df_e,
        ss: ss_e,
        ms: Some(ms_e),
        f: None,
        p_value: None,
    });
    rows.push(AnovaRow {
        source: "total".into(),
        df: nf * af * rf - 1.0,
        ss: ss_p + ss_a + ss_pa + ss_e,
        ms: None,
        f: None,
        p_value: None,
    });
    let ev = var_e.sqrt();
    let av = (var_a + var_pa).sqrt();
    let grr = (var_e + var_a + var_pa).sqrt();
    let pv = var_p.sqrt();
    let tv = (grr * grr + var_p).sqrt();
    let of_tol = |sd: f64| tolerance.map(|t| 100.0 * SPREAD_SIGMAS * sd / t);
    let of_total = |sd: f64| if tv > 0.0 { 100.0 * sd / tv } else { 0.0 };
    let grr_tol = of_tol(grr);
    let judged = grr_tol.unwrap_or_else(|| of_total(grr));
    Ok(GaugeRr {
        quantity: quantity.into(),
        unit: unit.into(),
        parts: n,
        appraisers: a,
        repeats: r,
        anova: rows,
        interaction_pooled: pooled,
        ev_sd: ev,
        av_sd: av,
        interaction_sd: var_pa.sqrt(),
        grr_sd: grr,
        pv_sd: pv,
        tv_sd: tv,
        tolerance,
        ev_percent_of_tolerance: of_tol(ev),
        av_percent_of_tolerance: of_tol(av),
        grr_percent_of_tolerance: grr_tol,
        grr_percent_of_total: of_total(grr),
        pv_percent_of_total: of_total(pv),
        ndc: (grr > 0.0).then(|| (1.41 * pv / grr).floor().min(u32::MAX as f64) as u32),
        acceptance: acceptance(judged).into(),
        mean: 0.0,
        limits: if tolerance.is_some() {
            "two_sided"
        } else {
            "none"
        }
        .into(),
        one_sided_limit: None,
        limit_distance: None,
        grr_percent_of_limit_distance: None,
        warnings: vec![],
    })
}

/// The order of the parts in each repeat of a study: a shuffle per repeat
/// (AIAG asks for a randomised order), drawn from `seed`.
pub fn part_order(parts: usize, repeats: u32, seed: u64) -> Vec<Vec<usize>> {
    use rand::seq::SliceRandom;
    use rand::SeedableRng;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..repeats)
        .map(|_| {
            let mut order: Vec<usize> = (0..parts).collect();
            order.shuffle(&mut rng);
            order
        })
        .collect()
}

/// m / e, with 0 / 0 = 0 and m / 0 = infinity (an exact gauge).
fn ratio(m: f64, e: f64) -> f64 {
    if e > 0.0 {
        m / e
    } else if m > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// Each judged parameter's value in one run of a study, with its unit.
pub type RunValues = std::collections::BTreeMap<String, (f64, String)>;

/// A run's value of each judged parameter: the mean over the run's
/// measurement verdicts that judged it (a recipe with several levels or
/// repeats judges a parameter on each of its measurements). Invalid
/// verdicts and non-finite values are left out; an empty map when the run
/// has no value.
pub fn run_values<'a>(verdicts: impl IntoIterator<Item = &'a super::Verdict>) -> RunValues {
    let mut sums: std::collections::BTreeMap<String, (f64, usize, String)> = Default::default();
    for verdict in verdicts {
        if verdict.verdict == super::VerdictKind::Invalid {
            continue;
        }
        for p in &verdict.parameters {
            if p.value.is_finite() {
                let e = sums.entry(p.name.clone()).or_default();
                e.0 += p.value;
                e.1 += 1;
                e.2.clone_from(&p.unit);
            }
        }
    }
    sums.into_iter()
        .map(|(k, (s, n, unit))| (k, (s / n as f64, unit)))
        .collect()
}

// The study's stored documents: its request and its planned runs (the
// store reads them into these types; `src/api/gauge.rs` serves them).

/// One part of a study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GaugePart {
    /// The part's serial (as in a job).
    pub serial: String,
    /// On a virtual bench: the production-lot part mounted (as in a job).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub production: Option<JobProduction>,
}

/// `POST /api/v1/gauge-studies`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GaugeStudyRequest {
    /// The recipe every run is measured and judged with; its parameters
    /// with both limits are the quantities studied against their tolerance.
    pub recipe: String,
    /// 2 to 50 parts, each measured `repeats` times on every bench.
    #[schema(min_items = 2, max_items = 50)]
    pub parts: Vec<GaugePart>,
    /// 2 to 10.
    #[schema(minimum = 2, maximum = 10)]
    pub repeats: u32,
    /// The benches (appraisers); default: every configured bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub benches: Option<Vec<String>>,
    /// More members of each run's job request (e.g. the procedure), checked
    /// as a job request is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub job: Option<serde_json::Map<String, serde_json::Value>>,
}

/// One planned run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GaugeRun {
    pub part_index: usize,
    pub bench_id: String,
    pub repeat: u32,
    pub idempotency_key: String,
    /// None until the job was submitted.
    pub job_id: Option<String>,
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_runs_value_is_the_mean_of_its_valid_finite_values() {
        use crate::qc::{ParamOutcome, ParamResult, Verdict, VerdictKind};
        let param = |name: &str, value: f64| ParamOutcome {
            name: name.into(),
            quantity: None,
            unit: "N/m".into(),
            value,
            lower: None,
            upper: None,
            result: ParamResult::Pass,
            x_m: None,
        };
        let verdict = |kind, parameters| Verdict {
            verdict: kind,
            failures: vec![],
            invalid_reasons: vec![],
            parameters,
        };
        let vs = [
            verdict(
                VerdictKind::Pass,
                vec![param("k0", 1000.0), param("keff", 900.0)],
            ),
            verdict(
                VerdictKind::Fail,
                vec![param("k0", 1100.0), param("keff", f64::NAN)],
            ),
            // never averaged in: the measurement cannot be trusted
            verdict(VerdictKind::Invalid, vec![param("k0", 5000.0)]),
        ];
        let v = super::run_values(&vs);
        assert_eq!(v["k0"], (1050.0, "N/m".to_string()));
        assert_eq!(v["keff"], (900.0, "N/m".to_string()));
        assert_eq!(v.len(), 2);
        assert!(super::run_values(&vs[2..]).is_empty());
    }

    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs().max(1e-300)
    }

    /// y = part + appraiser offset + (+-d in turn): every sum of squares is
    /// known in closed form.
    #[test]
    fn sums_of_squares_of_a_constructed_design() {
        let parts = [10.0, 12.0, 15.0];
        let offs = [0.0, 0.5];
        let d = 0.1;
        let values: Vec<Vec<Vec<f64>>> = parts
            .iter()
            .map(|p| offs.iter().map(|o| vec![p + o + d, p + o - d]).collect())
            .collect();
        let g = anova("k0_n_per_m", "N/m", &values, Some(10.0)).unwrap();
        let (n, a, r) = (3.0, 2.0, 2.0);
        let pm = (10.0 + 12.0 + 15.0) / 3.0 + 0.25;
        let ss_p: f64 = parts.iter().map(|p| (p + 0.25 - pm).powi(2)).sum::<f64>() * a * r;
        let ss_a = n * r * (0.25f64.powi(2) * 2.0);
        let ss_e = n * a * 2.0 * d * d;
        let row = |s: &str| g.anova.iter().find(|x| x.source == s).unwrap().clone();
        assert!(close(row("part").ss, ss_p, 1e-12), "{:?}", row("part"));
        assert!(close(row("appraiser").ss, ss_a, 1e-12));
        assert!(row("part_x_appraiser").ss.abs() < 1e-20);
        assert!(close(row("repeatability").ss, ss_e, 1e-12));
        // No interaction at all: pooled. MS_E' = SS_E / (df_PA + df_E).
        assert!(g.interaction_pooled);
        let ms_pool = ss_e / (2.0 + 6.0);
        assert!(close(g.ev_sd, ms_pool.sqrt(), 1e-12));
        let var_a = (ss_a / 1.0 - ms_pool) / (n * r);
        assert!(close(g.av_sd, var_a.sqrt(), 1e-12));
        let var_p = (ss_p / 2.0 - ms_pool) / (a * r);
        assert!(close(g.pv_sd, var_p.sqrt(), 1e-12));
        let grr = (ms_pool + var_a).sqrt();
        assert!(close(g.grr_sd, grr, 1e-12));
        assert!(close(
            g.grr_percent_of_tolerance.unwrap(),
            100.0 * 6.0 * grr / 10.0,
            1e-12
        ));
        assert_eq!(g.ndc, Some((1.41 * var_p.sqrt() / grr).floor() as u32));
    }

    /// Known variance components, many parts and appraisers: the estimates
    /// lie within 3 standard errors of the truth (the standard error of a
    /// variance estimated with df degrees of freedom is var·sqrt(2/df)).
    #[test]
    fn recovers_known_variance_components() {
        let (n, a, r) = (60, 40, 3);
        let (sd_p, sd_a, sd_e) = (1.0, 0.3, 0.1);
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let p: Vec<f64> = (0..n).map(|_| sd_p * unit.sample(&mut rng)).collect();
        let o: Vec<f64> = (0..a).map(|_| sd_a * unit.sample(&mut rng)).collect();
        let values: Vec<Vec<Vec<f64>>> = (0..n)
            .map(|i| {
                (0..a)
                    .map(|j| {
                        (0..r)
                            .map(|_| 100.0 + p[i] + o[j] + sd_e * unit.sample(&mut rng))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let g = anova("x", "m", &values, None).unwrap();
        // The realised components (the finite sample of p and o) are the
        // truth the ANOVA estimates.
        let var = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64
        };
        let check = |est_sd: f64, true_var: f64, df: f64, what: &str| {
            let se = true_var * (2.0 / df).sqrt();
            assert!(
                (est_sd * est_sd - true_var).abs() <= 3.0 * se,
                "{what}: estimated variance {} truth {true_var} (3 se = {})",
                est_sd * est_sd,
                3.0 * se
            );
        };
        check(
            g.ev_sd,
            sd_e * sd_e,
            (n * a * (r - 1)) as f64,
            "repeatability",
        );
        check(g.av_sd, var(&o), (a - 1) as f64, "reproducibility");
        check(g.pv_sd, var(&p), (n - 1) as f64, "part");
        assert!(g.ndc.unwrap() >= 3);
    }

    /// An interaction that is there is kept and tested.
    #[test]
    fn a_real_interaction_is_kept() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (n, a, r) = (10, 3, 3);
        let values: Vec<Vec<Vec<f64>>> = (0..n)
            .map(|i| {
                (0..a)
                    .map(|_| {
                        let inter = 0.5 * unit.sample(&mut rng);
                        (0..r)
                            .map(|_| i as f64 + inter + 0.05 * unit.sample(&mut rng))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let g = anova("x", "m", &values, Some(20.0)).unwrap();
        assert!(!g.interaction_pooled);
        let row = g
            .anova
            .iter()
            .find(|x| x.source == "part_x_appraiser")
            .unwrap();
        assert!(row.p_value.unwrap() < 1e-6, "{row:?}");
        assert!(
            g.interaction_sd > 0.3 && g.interaction_sd < 0.8,
            "{}",
            g.interaction_sd
        );
    }

    #[test]
    fn every_part_once_per_repeat() {
        let o = part_order(10, 3, 42);
        assert_eq!(o.len(), 3);
        for rep in &o {
            let mut s = rep.clone();
            s.sort();
            assert_eq!(s, (0..10).collect::<Vec<_>>());
        }
        assert_ne!(o[0], o[1], "shuffled per repeat");
        assert_eq!(
            o,
            part_order(10, 3, 42),
            "the same seed gives the same plan"
        );
    }

    #[test]
    fn designs_the_method_cannot_take_are_refused() {
        let one = vec![vec![vec![1.0, 1.1]]];
        assert!(anova("k", "N/m", &one, None)
            .unwrap_err()
            .contains("2 parts"));
        let single = vec![vec![vec![1.0]], vec![vec![2.0]]];
        assert!(anova("k", "N/m", &single, None)
            .unwrap_err()
            .contains("2 repeats"));
        let ragged = vec![vec![vec![1.0, 1.1]], vec![vec![2.0, 2.1, 2.2]]];
        assert!(anova("k", "N/m", &ragged, None)
            .unwrap_err()
            .contains("balanced"));
        let nan = vec![vec![vec![1.0, f64::NAN]], vec![vec![2.0, 2.1]]];
        assert!(anova("k", "N/m", &nan, None)
            .unwrap_err()
            .contains("finite"));
        let ok = vec![vec![vec![1.0, 1.1]], vec![vec![2.0, 2.1]]];
        assert!(anova("k", "N/m", &ok, Some(0.0))
            .unwrap_err()
            .contains("tolerance"));
        // One bench: repeatability only, no reproducibility.
        let g = anova("k", "N/m", &ok, Some(1.0)).unwrap();
        assert_eq!(g.av_sd, 0.0);
        // SS_E = 2 parts x 2 x 0.05^2 = 0.01 over 2 df.
        assert!(close(g.ev_sd, 0.005f64.sqrt(), 1e-9), "{}", g.ev_sd);
    }

    /// Issue 35: a one-sided limit (model error <= 5 %) is judged as AIAG
    /// judges a one-sided characteristic, 3 GRR against the distance from
    /// the mean to the limit, not against the total variation (which gave
    /// 100 % and "not acceptable" for parts alike); beyond the limit it is
    /// not applicable; 5 parts on 1 bench warn twice.
    #[test]
    fn a_one_sided_limit_is_judged_against_the_distance_to_it() {
        // 5 parts, all alike (PV = 0), 2 benches, 3 repeats; values about 1 %.
        let d = [0.0, 0.02, -0.02];
        let values: Vec<Vec<Vec<f64>>> = (0..5)
            .map(|_| {
                (0..2)
                    .map(|_| d.iter().map(|e| 1.0 + e).collect())
                    .collect()
            })
            .collect();
        let plain = anova("model_error", "%", &values, None).unwrap();
        assert!(close(plain.grr_percent_of_total, 100.0, 1e-9));
        assert_eq!(plain.acceptance, "not_acceptable");
        let g = study("model_error", "%", &values, None, Some(5.0)).unwrap();
        assert_eq!(g.limits, "upper");
        assert!(close(g.mean, 1.0, 1e-12));
        assert!(close(g.limit_distance.unwrap(), 4.0, 1e-12));
        // EV: SS_E = 10 cells x 2 x 0.02^2 = 0.008 over 20 df (pooled with
        // SS_PA = 0 over 4 df): sigma^2 = 0.008 / 24; AV = 0.
        let grr = (0.008f64 / 24.0).sqrt();
        assert!(close(g.grr_sd, grr, 1e-9), "{}", g.grr_sd);
        let pct = 100.0 * 3.0 * grr / 4.0;
        assert!(close(g.grr_percent_of_limit_distance.unwrap(), pct, 1e-9));
        assert_eq!(g.acceptance, "acceptable", "{pct} %");
        assert!(g.grr_percent_of_tolerance.is_none());
        assert_eq!(g.warnings.len(), 1, "{:?}", g.warnings);
        assert!(g.warnings[0].contains("5 parts") && g.warnings[0].contains("10"));
        // A lower limit: distance mean - limit.
        let g = study("q", "1", &values, Some(0.5), None).unwrap();
        assert_eq!(g.limits, "lower");
        assert!(close(g.limit_distance.unwrap(), 0.5, 1e-12));
        // The mean beyond the limit: not applicable, said so.
        let g = study("model_error", "%", &values, None, Some(0.9)).unwrap();
        assert_eq!(g.acceptance, "not_applicable");
        assert!(g.grr_percent_of_limit_distance.is_none());
        assert!(g.warnings.iter().any(|w| w.contains("not applicable")));
        // Both limits: the tolerance as before; no limits: the total variation.
        let g = study("k", "N/m", &values, Some(0.0), Some(2.0)).unwrap();
        assert_eq!(g.limits, "two_sided");
        assert!(close(
            g.grr_percent_of_tolerance.unwrap(),
            100.0 * 6.0 * grr / 2.0,
            1e-9
        ));
        assert_eq!(
            study("k", "N/m", &values, None, None).unwrap().limits,
            "none"
        );
        // One bench, 12 parts: the reproducibility warning only.
        let one: Vec<Vec<Vec<f64>>> = (0..12)
            .map(|i| vec![d.iter().map(|e| 1.0 + 0.1 * i as f64 + e).collect()])
            .collect();
        let g = study("k", "N/m", &one, None, Some(5.0)).unwrap();
        assert_eq!(g.warnings.len(), 1, "{:?}", g.warnings);
        assert!(g.warnings[0].contains("1 bench") && g.warnings[0].contains("AV"));
    }
}
