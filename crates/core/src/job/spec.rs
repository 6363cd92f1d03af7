//! The job as accepted: every default filled in, everything checked. Stored
//! with the job, read back by the runner.

use crate::identify::Method;
use crate::physics::PartSpec;
use serde::{Deserialize, Serialize};

/// The part a job measures.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobPart {
    /// Part serial (letters, digits and `._-`, not `.` or `..`).
    #[schema(pattern = "^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")]
    pub serial: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
}

/// One part of a production lot on the virtual bench: the nominal `preset`
/// with the lot's spread drawn from `seed`, and an optional defect.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobProduction {
    /// The lot's nominal preset.
    pub preset: String,
    /// Draws the part's spread.
    pub seed: u64,
    /// A defect of this part (`physics::production::Defect`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub defect: Option<crate::physics::production::Defect>,
}

/// Which procedure a job runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ProcedureMode {
    /// Level probe, 16 s pre-measurement, resonance search, 10 s narrow
    /// sweep per level (about 33 s of bench time for one level).
    #[default]
    Full,
    /// A short pre-measurement and one short narrow sweep per level at the
    /// golden units' resonance and drive (`procedure.golden`); falls back to
    /// the full procedure when the part is too far from the golden units.
    Production,
}

impl ProcedureMode {
    pub fn is_full(&self) -> bool {
        *self == ProcedureMode::Full
    }
    pub fn as_str(self) -> &'static str {
        match self {
            ProcedureMode::Full => "full",
            ProcedureMode::Production => "production",
        }
    }
}

/// Why a part is measured: the pool its measurement belongs to (issue 35).
/// SPC, yield, the shift counters and the lot statistics count
/// `production` only; golden units, bench calibrations, gauge-study runs,
/// repeats and engineering runs are kept in their own pools (decision 0100).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Purpose {
    /// A part of the line judged for shipping. The default of a job under a
    /// recipe and of every verdict stored before purposes existed.
    #[default]
    Production,
    /// A reference part measured to set or check limits (limit proposals).
    GoldenUnit,
    /// A golden unit measured to calibrate a bench against the reference bench.
    BenchCalibration,
    /// A run of a gauge study (repeatability and reproducibility).
    GaugeStudy,
    /// A production part measured again (a re-test): not a new part.
    Repeat,
    /// Engineering / R&D: anything else. The default of a job without a recipe.
    Engineering,
}

impl Purpose {
    pub const ALL: [Purpose; 6] = [
        Purpose::Production,
        Purpose::GoldenUnit,
        Purpose::BenchCalibration,
        Purpose::GaugeStudy,
        Purpose::Repeat,
        Purpose::Engineering,
    ];
    pub fn as_str(self) -> &'static str {
        match self {
            Purpose::Production => "production",
            Purpose::GoldenUnit => "golden_unit",
            Purpose::BenchCalibration => "bench_calibration",
            Purpose::GaugeStudy => "gauge_study",
            Purpose::Repeat => "repeat",
            Purpose::Engineering => "engineering",
        }
    }
    /// The purpose named `s` (its `as_str`).
    pub fn parse(s: &str) -> Option<Purpose> {
        Purpose::ALL.into_iter().find(|p| p.as_str() == s)
    }
}

/// Hard limits of a bench; a procedure never exceeds them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Largest allowed |x| of the part (m).
    pub max_displacement_m: f64,
    /// Largest allowed amplifier output amplitude (V peak).
    pub max_drive_v: f64,
}

/// A job as accepted: every default filled in, everything checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobSpec {
    pub part: JobPart,
    /// Bench that runs the job.
    pub bench: String,
    /// Moving mass of part plus inner clamp (kg).
    pub moving_mass_kg: f64,
    /// Target peak displacement of each narrow sweep (m): one measurement per level and repeat.
    pub levels_m: Vec<f64>,
    pub method: Method,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
    /// How often the whole procedure runs.
    pub repeats: u32,
    /// `full` or `production` (the request's `procedure`, else the recipe's `procedure.mode`).
    #[serde(default, skip_serializing_if = "ProcedureMode::is_full")]
    pub procedure: ProcedureMode,
    /// Higher runs first; equal priorities run in submission order.
    pub priority: i64,
    /// Virtual bench: the preset mounted (when `part_spec` is absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// Virtual bench: the physical parameters of the part mounted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_spec: Option<PartSpec>,
    /// Limits of this job (the bench's, or tighter).
    pub limits: Limits,
    /// The QC recipe (version and hash) the job runs and is judged by.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe: Option<RecipeRef>,
    /// Virtual bench: a part of a production lot (preset with manufacturing spread).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub production: Option<JobProduction>,
    /// Name of the token that submitted the job (traceability); None with open access.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub submitted_by: Option<String>,
    /// The pool of this job's measurements (a job stored before purposes
    /// existed reads as `production`, as it was counted then).
    #[serde(default)]
    pub purpose: Purpose,
}

/// The recipe version a job runs (`"recipe": NAME` in the request; filled in at submission).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecipeRef {
    pub name: String,
    pub version: i64,
    pub sha256: String,
    /// Where the version comes from (issue 36): the fleet's center (who
    /// approved it there) or this station alone. None outside a fleet
    /// and in jobs stored before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<RecipeOrigin>,
}

/// Who made a recipe version a job runs (decision 0106).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecipeOrigin {
    pub source: RecipeSource,
    /// The center's approver of this version (a center version made from
    /// a proposal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub approved_by: Option<String>,
    /// The center's proposal the version was approved from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proposal_id: Option<String>,
}

/// Where a recipe version was authored (decision 0106).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum RecipeSource {
    /// Authored and approved at the fleet's center; a station holds it as
    /// the center sent it.
    #[default]
    Center,
    /// Made on this station only (not, or not yet, the center's).
    Local,
}

/// A bench a job may run on, as the station's configuration offers it.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchOffer {
    pub id: String,
    pub limits: Limits,
    /// Virtual bench: the preset mounted when the job names no part.
    pub preset: String,
}

/// What a request is checked against and completed from: the benches (the
/// first is the default) and the station's defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct Admission {
    pub benches: Vec<BenchOffer>,
    pub target_xpeak_m: f64,
    pub method: Method,
    pub order: Option<usize>,
}

/// The part a [`JobProduction`] describes.
pub fn production_part(p: &JobProduction) -> Result<PartSpec, String> {
    let nominal = crate::physics::preset(&p.preset)?;
    Ok(crate::physics::production::part(
        &nominal,
        &crate::physics::production::Spread::default(),
        p.seed,
        p.defect,
    ))
}
