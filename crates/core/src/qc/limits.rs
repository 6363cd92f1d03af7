//! Limits from golden units: per parameter mean +- k sigma (or +- a relative
//! tolerance) over N >= 5 good parts, and a K(x) mask over the range all of
//! them measured. Pure.

use super::{judge, k_of_x, KxMask, Quantity, Recipe, RunFacts, VerdictKind};
use crate::identify::Report;
use serde::{Deserialize, Serialize};

/// Fewest golden units (distinct serials) a proposal needs.
pub const MIN_GOLDEN: usize = 5;

/// How the limits are spread around the golden mean.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(tag = "method", rename_all = "snake_case")]
pub enum Spread {
    /// mean +- k * sigma (sample standard deviation of the golden units).
    KSigma { k: f64 },
    /// mean +- tolerance_percent / 100 * |mean|.
    Tolerance { tolerance_percent: f64 },
}

impl Spread {
    fn half_width(&self, mean: f64, sigma: f64) -> f64 {
        match *self {
            Spread::KSigma { k } => k * sigma,
            Spread::Tolerance { tolerance_percent } => tolerance_percent / 100.0 * mean.abs(),
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        let (n, v) = match *self {
            Spread::KSigma { k } => ("k", k),
            Spread::Tolerance { tolerance_percent } => ("tolerance_percent", tolerance_percent),
        };
        if v.is_finite() && v > 0.0 && v <= 100.0 {
            Ok(())
        } else {
            Err(format!("{n} must be in (0, 100], got {v}"))
        }
    }
}

/// Options of a proposal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProposalOptions {
    #[serde(flatten)]
    pub spread: Spread,
    /// K(x) mask points (0: no mask).
    #[serde(default = "default_mask_points")]
    pub mask_points: usize,
    /// The mask spans this fraction of the range every golden unit measured.
    #[serde(default = "default_mask_range")]
    pub mask_range_fraction: f64,
}

fn default_mask_points() -> usize {
    21
}
fn default_mask_range() -> f64 {
    0.9
}

impl ProposalOptions {
    /// One message per bad option, named as in the request body.
    pub fn validate(&self) -> Vec<super::FieldError> {
        let mut e = vec![];
        if let Err(m) = self.spread.validate() {
            let field = match self.spread {
                Spread::KSigma { .. } => "k",
                Spread::Tolerance { .. } => "tolerance_percent",
            };
            e.push(super::FieldError {
                field: field.into(),
                message: m,
            });
        }
        if !(self.mask_range_fraction > 0.0 && self.mask_range_fraction <= 1.0) {
            e.push(super::FieldError {
                field: "mask_range_fraction".into(),
                message: format!("must be in (0, 1], got {}", self.mask_range_fraction),
            });
        }
        if self.mask_points == 1 || self.mask_points > super::MAX_MASK_POINTS {
            e.push(super::FieldError {
                field: "mask_points".into(),
                message: format!("must be 0 or 2 to {}", super::MAX_MASK_POINTS),
            });
        }
        e
    }
}

/// Most golden units one proposal may name.
pub const MAX_GOLDEN: usize = 200;

/// One golden unit: its measurements, one per level (level index, facts).
#[derive(Debug, Clone)]
pub struct GoldenUnit {
    pub serial: String,
    pub measurements: Vec<RunFacts>,
}

/// Statistics and proposed limits of one parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProposedLimit {
    pub name: String,
    pub unit: String,
    pub n: usize,
    pub mean: f64,
    pub sigma: f64,
    pub lower: Option<f64>,
    pub upper: Option<f64>,
    /// The golden values, in the order of `serials`.
    pub values: Vec<f64>,
}

/// A proposal: statistics per parameter and the recipe with these limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Proposal {
    pub serials: Vec<String>,
    /// Golden units named but left out: they fail the recipe's current
    /// limits (a failed part is no golden unit unless the engineer keeps it
    /// with `keep_failed`).
    #[serde(default)]
    pub left_out: Vec<LeftOut>,
    /// Golden units that fail the current limits and were kept on request.
    #[serde(default)]
    pub kept_failed: Vec<LeftOut>,
    pub options: ProposalOptions,
    pub parameters: Vec<ProposedLimit>,
    pub kx_mask: Option<KxMask>,
    /// The golden units' own K(x) over the range all of them measured (what
    /// the mask was drawn from; absent in proposals made before it was kept,
    /// or when the units' common range is empty). Shown, never judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub golden_kx: Option<GoldenKx>,
    /// The recipe as it would be after approval (limits filled in).
    pub recipe: Recipe,
}

/// The golden units' K(x) at each `x_m` (N/m): the smallest and largest of
/// the units, their mean and sample standard deviation (n - 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GoldenKx {
    /// How many golden units.
    pub n: usize,
    /// Level of the series the curves are from (the highest); absent: one level.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level_index: Option<usize>,
    pub x_m: Vec<f64>,
    pub min_n_per_m: Vec<f64>,
    pub mean_n_per_m: Vec<f64>,
    pub sigma_n_per_m: Vec<f64>,
    pub max_n_per_m: Vec<f64>,
}

/// Points of [`GoldenKx`] over the golden units' common range.
pub const GOLDEN_KX_POINTS: usize = 41;

/// The golden units' K(x) statistics on `n` points over `lo..=hi` (m).
fn golden_kx(
    reports: &[Report],
    lo: f64,
    hi: f64,
    n: usize,
    level_index: Option<usize>,
) -> GoldenKx {
    let mut g = GoldenKx {
        n: reports.len(),
        level_index,
        x_m: vec![],
        min_n_per_m: vec![],
        mean_n_per_m: vec![],
        sigma_n_per_m: vec![],
        max_n_per_m: vec![],
    };
    for i in 0..n {
        let x = lo + (hi - lo) * i as f64 / (n - 1) as f64;
        let ks: Vec<f64> = reports.iter().map(|r| k_of_x(r, x)).collect();
        let (mean, sigma) = mean_sigma(&ks);
        g.x_m.push(x);
        g.min_n_per_m
            .push(ks.iter().copied().fold(f64::INFINITY, f64::min));
        g.mean_n_per_m.push(mean);
        g.sigma_n_per_m.push(sigma);
        g.max_n_per_m
            .push(ks.iter().copied().fold(f64::NEG_INFINITY, f64::max));
    }
    g
}

/// A golden unit that fails the recipe's current limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LeftOut {
    pub serial: String,
    /// The failing parameters (value, limits), one line each.
    pub failures: Vec<String>,
}

/// Splits `golden` into the units to use and those that fail the recipe's
/// current limits (left out unless their serial is in `keep`): (used, left
/// out, kept although failing).
pub fn screen_golden(
    recipe: &Recipe,
    golden: Vec<GoldenUnit>,
    keep: &[String],
) -> (Vec<GoldenUnit>, Vec<LeftOut>, Vec<LeftOut>) {
    let (mut used, mut out, mut kept) = (vec![], vec![], vec![]);
    for g in golden {
        let failures: Vec<String> = g
            .measurements
            .iter()
            .map(|m| super::judge(recipe, m))
            .filter(|v| v.verdict == super::VerdictKind::Fail)
            .flat_map(|v| {
                v.failures
                    .iter()
                    .map(|f| {
                        let lim = |l: Option<f64>| l.map(|x| x.to_string()).unwrap_or("-".into());
                        format!(
                            "{} = {} {} outside [{}, {}]",
                            f.name,
                            f.value,
                            f.unit,
                            lim(f.lower),
                            lim(f.upper)
                        )
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        if failures.is_empty() {
            used.push(g);
        } else if keep.contains(&g.serial) {
            kept.push(LeftOut {
                serial: g.serial.clone(),
                failures,
            });
            used.push(g);
        } else {
            out.push(LeftOut {
                serial: g.serial,
                failures,
            });
        }
    }
    (used, out, kept)
}

/// Mean and sample standard deviation (n - 1).
pub fn mean_sigma(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mean = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (mean, 0.0);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

fn level_dependent(q: Quantity) -> bool {
    !matches!(q, Quantity::K0 | Quantity::F0 | Quantity::Q | Quantity::R)
}

/// Proposes limits from golden units. Every golden measurement must be valid
/// under the recipe (an invalid one is refused by serial), and at least
/// [`MIN_GOLDEN`] distinct serials are needed.
pub fn propose(
    recipe: &Recipe,
    golden: &[GoldenUnit],
    opts: &ProposalOptions,
) -> Result<Proposal, String> {
    opts.spread.validate()?;
    if !(opts.mask_range_fraction > 0.0 && opts.mask_range_fraction <= 1.0) {
        return Err(format!(
            "mask_range_fraction must be in (0, 1], got {}",
            opts.mask_range_fraction
        ));
    }
    if opts.mask_points == 1 || opts.mask_points > super::MAX_MASK_POINTS {
        return Err(format!(
            "mask_points must be 0 or 2 to {}",
            super::MAX_MASK_POINTS
        ));
    }
    let mut serials: Vec<String> = golden.iter().map(|g| g.serial.clone()).collect();
    serials.sort();
    serials.dedup();
    if serials.len() != golden.len() {
        return Err("a golden serial is named twice".into());
    }
    if golden.len() < MIN_GOLDEN {
        return Err(format!(
            "{} golden units given; at least {MIN_GOLDEN} are needed",
            golden.len()
        ));
    }
    let levels = recipe.procedure.levels_m.len();
    // Judge every golden measurement for validity only (limits stripped).
    let mut bare = recipe.clone();
    for p in &mut bare.parameters {
        p.lower = None;
        p.upper = None;
    }
    bare.kx_mask = None;
    let mut by_level: Vec<Vec<RunFacts>> = vec![Vec::new(); levels];
    for g in golden {
        #[allow(clippy::needless_range_loop)] // li is also the level index searched for
        for li in 0..levels {
            let Some(f) = g.measurements.iter().find(|f| f.level_index == li) else {
                return Err(format!(
                    "golden unit {}: no measurement of level {li}",
                    g.serial
                ));
            };
            let v = judge(&bare, f);
            if v.verdict == VerdictKind::Invalid {
                let why: Vec<String> = v.invalid_reasons.iter().map(|r| r.detail.clone()).collect();
                return Err(format!(
                    "golden unit {}: the measurement is invalid ({})",
                    g.serial,
                    why.join("; ")
                ));
            }
            by_level[li].push(f.clone());
        }
    }
    let mut out = recipe.clone();
    let mut stats = Vec::new();
    for p in &mut out.parameters {
        if !p.from_golden() {
            continue;
        }
        if levels > 1 && level_dependent(p.quantity) && p.level_index.is_none() {
            return Err(format!(
                "parameter {}: a level series needs level_index for golden limits",
                p.name
            ));
        }
        let li = p.level_index.unwrap_or(0);
        let mut values = Vec::with_capacity(golden.len());
        for (gi, f) in by_level[li].iter().enumerate() {
            // The golden unit's own facts (its target level: Keff is judged there).
            let facts = RunFacts {
                report: f.report.clone(),
                target_xpeak_m: f.target_xpeak_m,
                level_index: li,
                ..Default::default()
            };
            let mut single = bare.clone();
            single.parameters = vec![p.clone()];
            let v = judge(&single, &facts);
            let Some(o) = v.parameters.first() else {
                return Err(format!(
                    "golden unit {}: parameter {} has no value",
                    golden[gi].serial, p.name
                ));
            };
            values.push(o.value);
        }
        let (mean, sigma) = mean_sigma(&values);
        let h = opts.spread.half_width(mean, sigma);
        p.lower = Some(mean - h);
        p.upper = Some(mean + h);
        stats.push(ProposedLimit {
            name: p.name.clone(),
            unit: p.unit(),
            n: values.len(),
            mean,
            sigma,
            lower: p.lower,
            upper: p.upper,
            values,
        });
    }
    // The mask and the golden curves are taken at the highest level (the widest range).
    let li = (0..levels)
        .max_by(|&a, &b| recipe.procedure.levels_m[a].total_cmp(&recipe.procedure.levels_m[b]))
        .unwrap_or(0);
    let reports: Vec<Report> = by_level[li]
        .iter()
        .map(|f| f.report.clone().unwrap_or_default())
        .collect();
    let lo = reports
        .iter()
        .map(|r| r.stiffness.valid_range_m[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let hi = reports
        .iter()
        .map(|r| r.stiffness.valid_range_m[1])
        .fold(f64::INFINITY, f64::min);
    let golden_curves = (lo.is_finite() && hi.is_finite() && lo < hi).then(|| {
        golden_kx(
            &reports,
            lo,
            hi,
            GOLDEN_KX_POINTS,
            (levels > 1).then_some(li),
        )
    });
    if opts.mask_points >= 2 {
        if !(lo < 0.0 && hi > 0.0) {
            return Err(format!(
                "the golden units' common measured range {lo} .. {hi} m does not span x = 0"
            ));
        }
        let (lo, hi) = (lo * opts.mask_range_fraction, hi * opts.mask_range_fraction);
        let n = opts.mask_points;
        let mut mask = KxMask {
            x_m: vec![],
            lower_n_per_m: vec![],
            upper_n_per_m: vec![],
            level_index: (levels > 1).then_some(li),
        };
        for i in 0..n {
            let x = lo + (hi - lo) * i as f64 / (n - 1) as f64;
            let ks: Vec<f64> = reports.iter().map(|r| k_of_x(r, x)).collect();
            let (mean, sigma) = mean_sigma(&ks);
            let h = opts.spread.half_width(mean, sigma);
            mask.x_m.push(x);
            mask.lower_n_per_m.push(mean - h);
            mask.upper_n_per_m.push(mean + h);
        }
        out.kx_mask = Some(mask);
    }
    // The production procedure's reference, when every golden unit has its
    // drives and resonances (a recipe's own deviation bound is kept).
    if let Some(mut g) = super::GoldenReference::from_golden(golden, levels) {
        if let Some(old) = &recipe.procedure.golden {
            g.max_f0_deviation_percent = old.max_f0_deviation_percent;
        }
        out.procedure.golden = Some(g);
    }
    if let Err(e) = out.validate() {
        let msgs: Vec<String> = e
            .iter()
            .map(|e| format!("{}: {}", e.field, e.message))
            .collect();
        return Err(format!(
            "the proposed limits are not usable: {}",
            msgs.join("; ")
        ));
    }
    Ok(Proposal {
        serials: golden.iter().map(|g| g.serial.clone()).collect(),
        left_out: vec![],
        kept_failed: vec![],
        options: opts.clone(),
        parameters: stats,
        kx_mask: out.kx_mask.clone(),
        golden_kx: golden_curves,
        recipe: out,
    })
}
