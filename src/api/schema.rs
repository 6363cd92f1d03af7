//! The schemas the handlers name that the types cannot derive alone: the
//! envelopes the handlers build with `json!` around typed values (pages,
//! lists, a job with its verdict, the measurement document), the
//! diagnostics document of
//! `diagnose::engine::EngineResult::diagnostics_json`, the problem document,
//! and the request bodies the handlers validate field by field (job, fit,
//! import). The API tests (`tests/contract.rs`) validate every route's real
//! responses against these schemas with unknown members refused, so a
//! hand-described schema that drifts from the code fails there.
//!
//! A type that contains itself (e.g. `base: Option<Box<Stiffness>>`) needs
//! `#[schema(no_recursion)]` on that field: without it, collecting the
//! schemas recurses until the stack overflows (the tests abort).
//!
//! The handlers name these; [`super::openapi`] names the handlers. Nothing
//! here names a handler, so the two never import each other.

use crate::config::Role;
use crate::identify::{Model, Report};
use crate::runner::{BenchStatus, FieldError};
use crate::store::hardware::CalibrationRecord;
use crate::store::qc::{DeliveryRow, RecipeRow, VerdictRow};
use crate::store::{Fit, Job, MeasurementInfo, Part};
use serde_json::Value;
use utoipa::openapi::{RefOr, Schema};
use utoipa::ToSchema;

// ---------------------------------------------------------------------------
// Envelopes built with `json!` around typed values (hand-described).

/// `GET /healthz`.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Health {
    /// Always `ok` while the process serves.
    pub status: String,
    /// The daemon's software version.
    pub version: String,
    /// `fleet` at the fleet's center (`database = "postgres://..."`); absent at a station.
    #[schema(required = false, pattern = "^fleet$")]
    pub role: Option<String>,
}

/// `GET /readyz`.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Ready {
    /// `ready` or `not_ready`.
    #[schema(pattern = "^(ready|not_ready)$")]
    pub status: String,
    /// `ok`, or why the database is not usable (lost file, full disk, ...).
    pub database: String,
    pub benches: Vec<BenchStatus>,
}

/// A list of benches.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct BenchList {
    pub items: Vec<BenchStatus>,
}

/// `GET /api/v1/session`: who the caller is.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Session {
    /// The token's label; null without a known token (and with open access).
    pub name: Option<String>,
    /// The caller's role; `admin` with open access (no tokens configured),
    /// null when no known token was sent.
    pub role: Option<Role>,
    /// False with open access.
    pub auth_required: bool,
    /// `station` (runs benches) or `center` (the fleet role: reads only, no
    /// jobs, benches or writes; docs/fleet.md).
    #[schema(pattern = "^(station|center)$")]
    pub daemon: String,
}

/// A job with its QC verdict (`GET /api/v1/jobs/{id}`; the job's `verdict`,
/// details at `/api/v1/jobs/{id}/verdict`).
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct JobWithVerdict {
    #[schema(inline)]
    #[serde(flatten)]
    pub job: Job,
}

/// A page of jobs, newest first.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct JobPage {
    pub items: Vec<Job>,
    /// Pass as `cursor` for the next page; null on the last page.
    pub next_cursor: Option<String>,
}

/// A part with the link to its measurements.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct PartDocument {
    #[schema(inline)]
    #[serde(flatten)]
    pub part: Part,
    /// `/api/v1/parts/{serial}/measurements`.
    pub measurements: String,
}

/// A page of parts, by serial.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct PartPage {
    pub items: Vec<Part>,
    /// The last serial of this page (pass as `cursor`); null on the last page.
    pub next_cursor: Option<String>,
}

/// A page of measurements, newest first.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct MeasurementPage {
    pub items: Vec<MeasurementInfo>,
    pub next_cursor: Option<String>,
}

/// Links to a measurement's raw recordings.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct RecordingLinks {
    /// `/api/v1/measurements/{id}/recordings/pre.wav`.
    pub pre: String,
    /// `/api/v1/measurements/{id}/recordings/main.wav`.
    pub main: String,
}

/// The measurement's record inside its document.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct MeasurementRecord {
    #[schema(inline)]
    #[serde(flatten)]
    pub info: MeasurementInfo,
    /// The recording set's meta.json as stored.
    pub meta: Value,
    pub recordings: RecordingLinks,
    /// The QC verdict of this measurement (`GET /api/v1/measurements/{id}`
    /// only; null without a recipe).
    #[schema(required = false)]
    pub verdict: Option<VerdictRow>,
    /// Which stored fit supplies the headline figures, who chose it and
    /// when (`GET /api/v1/measurements/{id}` only; null: never chosen, the
    /// measurement's own result).
    #[schema(required = false)]
    pub headline: Option<crate::store::HeadlineChoice>,
    /// The correction that voided this measurement (`GET
    /// /api/v1/measurements/{id}` only; its reason and who: the audit log);
    /// null: not voided. A voided measurement counts in no SPC, yield or
    /// part verdict; it stays readable.
    #[schema(required = false)]
    pub void_correction_id: Option<String>,
}

/// The measurement's record alone: the document of a measurement whose
/// analysis failed (`measurement.analysis_error`; the recordings are kept).
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct MeasurementRecordOnly {
    pub measurement: MeasurementRecord,
}

/// A fit's list.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct FitList {
    pub items: Vec<Fit>,
}

/// The calibration records of a bench.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct CalibrationList {
    pub items: Vec<CalibrationRecord>,
}

/// A recipe version with whether it has limits.
#[derive(serde::Serialize, ToSchema)]
pub struct RecipeDocument {
    #[schema(inline)]
    #[serde(flatten)]
    pub row: RecipeRow,
    /// True when any parameter has a limit or the recipe has a K(x) mask.
    pub has_limits: bool,
}

impl RecipeDocument {
    pub fn of(row: &RecipeRow) -> Self {
        RecipeDocument {
            has_limits: row.recipe.has_limits(),
            row: row.clone(),
        }
    }
}

/// A list of recipe versions.
#[derive(serde::Serialize, ToSchema)]
pub struct RecipeList {
    pub items: Vec<RecipeDocument>,
}

/// A recipe's limit proposals.
#[derive(serde::Serialize, ToSchema)]
pub struct ProposalList {
    pub items: Vec<crate::store::qc::ProposalRow>,
}

/// A job's verdict with its measurements' verdicts.
#[derive(serde::Serialize, ToSchema)]
pub struct JobVerdict {
    #[schema(inline)]
    #[serde(flatten)]
    pub verdict: VerdictRow,
    pub measurements: Vec<VerdictRow>,
}

/// The recipe version an SPC window was judged by.
#[derive(serde::Serialize, ToSchema)]
pub struct RecipeVersionRef {
    pub name: String,
    pub version: i64,
    pub sha256: String,
}

/// SPC of one parameter with the recipe version.
#[derive(serde::Serialize, ToSchema)]
pub struct SpcDocument {
    #[schema(inline)]
    #[serde(flatten)]
    pub spc: crate::qc::spc::Spc,
    pub recipe: RecipeVersionRef,
    /// Verdicts of the window left out of every figure because their stored
    /// detail does not read in this software version (0 normally).
    pub unreadable_verdicts: usize,
    /// The pool counted: a purpose (`production` unless asked) or `all`.
    #[schema(
        pattern = "^(all|production|golden_unit|bench_calibration|gauge_study|repeat|engineering)$"
    )]
    pub purpose: String,
    /// Present when `unreadable_verdicts` is not 0: what was left out and why.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// The MES outbox: deliveries and totals.
#[derive(serde::Serialize, ToSchema)]
pub struct Outbox {
    pub items: Vec<DeliveryRow>,
    pub pending: i64,
    pub failed: i64,
    /// Failed delivery attempts since the database was created.
    pub failed_attempts_total: i64,
}

/// `GET /api/v1/measurements/{id}/diagnostics`.
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct DiagnosticsDocument {
    pub measurement_id: String,
    /// The chosen model (effects with their parameters, residual, noise floor, model error).
    pub model: Model,
    pub diagnostics: Diagnostics,
    /// Links to the SVG plots.
    pub plots: Vec<String>,
}

/// A fitted model in the diagnostics (base or final).
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct ModelSummary {
    /// Effect ids in the order they were added.
    pub effects: Vec<String>,
    /// Fitted effect parameters (names of effects.rs, SI units in the names).
    pub parameters: crate::effects::Effects,
    /// Block-robust standard errors of the parameters (same names).
    pub parameters_se: Value,
    pub order: usize,
    pub stiffness_coefficients_n_per_m_pow_i_plus_1: Vec<f64>,
    pub r_ns_per_m: f64,
    pub force_per_mic_n_per_v: f64,
    pub residual_percent: f64,
    pub cv_residual_percent: f64,
    pub model_error_percent: f64,
}

/// The diagnostics document (`diagnostics` of a diagnosed report).
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Diagnostics {
    /// Every candidate effect, ranked against the model it would extend.
    pub candidates: Vec<crate::diagnose::engine::CandidateResult>,
    /// The model ladder, base model first.
    pub ladder: Vec<crate::diagnose::engine::LadderStep>,
    pub base_model: ModelSummary,
    pub final_model: ModelSummary,
    pub noise_floor_percent: f64,
    /// How the base model's K(x) order was chosen.
    pub order_note: String,
    /// How the statistics were done, one sentence per aspect.
    pub method: std::collections::BTreeMap<String, String>,
    /// The data the plots draw (detail, envelope, residual vs x and v,
    /// spectrum, small-signal comparison), arrays with units in their names.
    pub comparison: std::collections::BTreeMap<String, Value>,
    /// Pairs of effects the data cannot tell apart (swap test; issue 12).
    #[schema(required = false)]
    pub ambiguities: Option<Vec<Value>>,
    /// What the chosen model leaves unexplained (issue 12).
    #[schema(required = false)]
    pub unexplained: Option<Value>,
    /// The small-signal model's ladder and choice (when the set has a pre sweep).
    #[schema(required = false)]
    pub small_signal_model: Option<Value>,
}

/// An RFC 9457 problem document (`application/problem+json`). Some problems
/// carry more members (e.g. `job_id` of an idempotency conflict, `state` of
/// a job that cannot be cancelled).
#[derive(serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Problem {
    /// `/problems/{kind}`.
    #[schema(rename = "type", pattern = "^/problems/[a-z0-9-]+$")]
    pub kind: String,
    pub title: String,
    /// The HTTP status code.
    pub status: u16,
    pub detail: String,
    /// One message per bad field (422 validation problems).
    #[schema(required = false)]
    pub errors: Vec<FieldError>,
    /// The job an Idempotency-Key was first used for (409 `idempotency-conflict` of a job).
    pub job_id: Option<String>,
    /// The measurement an Idempotency-Key was first used for (409 `idempotency-conflict` of an import).
    pub measurement_id: Option<String>,
    /// The state of a job that cannot be cancelled (409 `job-finished`, `job-finishing`).
    pub state: Option<crate::store::JobState>,
}

// ---------------------------------------------------------------------------
// Request bodies validated field by field by the handlers (hand-described;
// tests/contract.rs checks each field against the validators: the names, a
// value of the schema's type accepted, null and other types as the
// validator takes them, unknown members refused by both).

/// `"auto"`: the diagnostics' ladder chooses the model.
#[derive(serde::Serialize, ToSchema)]
#[serde(rename_all = "lowercase")]
#[allow(dead_code)]
pub enum FitAuto {
    Auto,
}

/// The effects of a refit: a list fits exactly that model.
#[derive(serde::Serialize, ToSchema)]
#[serde(untagged)]
#[allow(dead_code)]
pub enum FitEffects {
    List(Vec<crate::effects::EffectId>),
    Auto(FitAuto),
}

/// `POST /api/v1/measurements/{id}/fits`.
#[derive(serde::Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
pub struct FitBody {
    /// A list of effect ids fits exactly that model; `"auto"` or absent lets the ladder choose.
    pub effects: Option<FitEffects>,
    /// Order of K(x) (1-12).
    #[schema(minimum = 1, maximum = 12)]
    pub order: Option<usize>,
    pub method: Option<crate::identify::Method>,
}

/// `PUT /api/v1/measurements/{id}/headline`.
#[derive(serde::Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
pub struct HeadlineBody {
    /// A fit of this measurement; null: the measurement's own result.
    pub fit_id: Option<String>,
}

/// `POST /api/v1/measurements` (multipart/form-data): an external recording set.
#[derive(serde::Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)]
pub struct ImportForm {
    /// meta.json of the set (may hold `part_serial`).
    pub meta: String,
    #[schema(format = Binary, content_media_type = "application/octet-stream")]
    pub pre: Vec<u8>,
    #[schema(format = Binary, content_media_type = "application/octet-stream")]
    pub main: Vec<u8>,
    /// Part serial (required unless meta.json has `part_serial`).
    pub serial: Option<String>,
    pub kind: Option<String>,
    pub notes: Option<String>,
    pub method: Option<crate::identify::Method>,
    pub order: Option<usize>,
}

/// The measurement document: the `identify::Report` (as `springbench analyze
/// --json` prints it) with the record under `measurement`; only the record
/// when the analysis failed.
pub struct MeasurementDocumentSchema;

impl utoipa::PartialSchema for MeasurementDocumentSchema {
    fn schema() -> RefOr<Schema> {
        schema_from_json(serde_json::json!({
            "description": "The identify::Report (small_signal, large_signal, stiffness, model, warnings; diagnostics after a fit) with the measurement's record under `measurement`; only `measurement` when the analysis failed (`measurement.analysis_error`).",
            "oneOf": [
                {"allOf": [
                    {"$ref": "#/components/schemas/Report"},
                    {"type": "object", "required": ["measurement"],
                     "properties": {"measurement": {"$ref": "#/components/schemas/MeasurementRecord"}}}
                ]},
                {"$ref": "#/components/schemas/MeasurementRecordOnly"}
            ]
        }))
    }
}

impl ToSchema for MeasurementDocumentSchema {
    fn name() -> std::borrow::Cow<'static, str> {
        "MeasurementDocument".into()
    }
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        schemas.push((
            Report::name().into(),
            <Report as utoipa::PartialSchema>::schema(),
        ));
        <Report as ToSchema>::schemas(schemas);
        schemas.push((
            MeasurementRecord::name().into(),
            <MeasurementRecord as utoipa::PartialSchema>::schema(),
        ));
        <MeasurementRecord as ToSchema>::schemas(schemas);
        schemas.push((
            MeasurementRecordOnly::name().into(),
            <MeasurementRecordOnly as utoipa::PartialSchema>::schema(),
        ));
    }
}

/// A schema written as JSON (what the derive cannot express, e.g. `oneOf` of `allOf`).
fn schema_from_json(v: Value) -> RefOr<Schema> {
    serde_json::from_value(v).expect("a valid schema literal")
}
