//! The results interface: what every storage backend of Springbench
//! implements, and the plain data it exchanges (decision 0034).
//!
//! A station's SQLite ([`crate::Store`]) implements it today; the fleet's
//! central PostgreSQL (issue 20) implements the same traits with its own
//! migrations. The interface is about results, not the job queue: a
//! station's SQLite stays the source of truth for its jobs, events and MES
//! outbox (inherent methods of `Store`, station-only), and what leaves the
//! station is a finished measurement, ingested with
//! [`ResultIngest::upsert_measurement`] (idempotent by measurement id).
//!
//! One trait per concept, each implemented beside its SQL
//! (`parts.rs`, `measurements.rs`, `fits.rs`, `qc.rs`); [`ResultStore`]
//! names them all, for a caller (or a test suite) that needs every one.
//! The methods return `impl Future + Send` (native async functions in
//! traits, no boxing, no extra crate): a caller is generic over the backend
//! or holds an enum of backends, chosen by the database URL.
//!
//! Every backend answers the same: same rows, same order, same derived
//! figures (a part's measurement count and newest job verdict, a
//! measurement's `summary`). `crates/store/tests/results.rs` runs one suite,
//! generic over [`ResultStore`], against each backend.

use crate::StoreResult;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::future::Future;

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Part {
    pub serial: String,
    pub kind: Option<String>,
    pub notes: Option<String>,
    pub created_at: String,
    pub updated_at: String,
    pub measurement_count: i64,
    /// The QC verdict of the part's newest job judged under a recipe (`pass`,
    /// `fail`, `invalid`, `no_limits`); null when no job was judged.
    #[schema(value_type = Option<springbench_core::qc::VerdictKind>)]
    pub verdict: Option<String>,
    /// The station of the part's newest measurement (a fleet's center answers it; absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub station_id: Option<String>,
}

/// A measurement's listing entry (the result document itself is `result`).
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct MeasurementInfo {
    pub id: String,
    pub part_serial: String,
    pub job_id: Option<String>,
    /// "bench" or "import".
    pub source: String,
    pub bench_id: Option<String>,
    pub software_version: String,
    pub target_xpeak_m: Option<f64>,
    pub repeat_index: Option<i64>,
    pub level_index: Option<i64>,
    /// Why the analysis failed (the recordings are kept and can be fitted again).
    pub analysis_error: Option<String>,
    pub created_at: String,
    /// Configuration used (procedure and analysis options).
    pub config: Value,
    /// Headline numbers from the result, for listings.
    pub summary: Value,
    /// The station that made it (a fleet's center answers it; absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub station_id: Option<String>,
    #[serde(skip)]
    pub seq: i64,
}

/// A fit of a stored measurement.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Fit {
    pub id: String,
    pub measurement_id: String,
    /// `{"effects": [...], "order": ..., "method": ...}` as accepted.
    pub request: Value,
    /// The refitted result document (with `model` and `diagnostics`).
    #[schema(value_type = springbench_core::identify::Report)]
    pub result: Value,
    pub software_version: String,
    pub created_at: String,
}

/// Which fit supplies a measurement's headline figures, chosen by whom and when.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct HeadlineChoice {
    /// The fit (`GET /api/v1/measurements/{id}/fits`); null: the measurement's own result.
    pub fit_id: Option<String>,
    /// The token name of who chose it (null with open access).
    pub chosen_by: Option<String>,
    pub chosen_at: String,
}

/// A stored recipe version.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RecipeRow {
    pub name: String,
    pub version: i64,
    pub sha256: String,
    /// The recipe document (its keys in sorted order).
    #[serde(serialize_with = "crate::sorted")]
    pub recipe: springbench_core::qc::Recipe,
    /// `created`, `edited` or `limits_approved`.
    pub origin: String,
    pub proposal_id: Option<String>,
    pub retired: bool,
    pub created_by: Option<String>,
    pub created_at: String,
    /// `center`: authored and approved at the fleet's center; `local`: made
    /// on this station only (decision 0106). A center's rows are all `center`.
    #[serde(default)]
    pub source: springbench_core::job::RecipeSource,
    /// The center's approver of this version, when it came from a proposal.
    #[serde(default)]
    pub approved_by: Option<String>,
}

impl RecipeRow {
    /// The provenance a job's recipe reference (and so its verdicts' trace)
    /// records.
    pub fn origin(&self) -> springbench_core::job::RecipeOrigin {
        springbench_core::job::RecipeOrigin {
            source: self.source,
            approved_by: self.approved_by.clone(),
            proposal_id: self.proposal_id.clone(),
        }
    }
}

/// A stored verdict.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct VerdictRow {
    pub id: String,
    pub job_id: Option<String>,
    /// None for the verdict of a whole job.
    pub measurement_id: Option<String>,
    pub part_serial: String,
    pub recipe_name: String,
    pub recipe_version: i64,
    pub recipe_sha256: String,
    /// `pass`, `fail`, `invalid` or `no_limits`.
    pub verdict: String,
    /// Failures, invalid reasons, every parameter's value / limits / result.
    #[schema(value_type = springbench_core::qc::Verdict)]
    pub detail: Value,
    /// Software version, recipe, bench, calibration, sensors, submitter, timestamps.
    pub traceability: Value,
    pub created_at: String,
    /// The station that judged it (a fleet's center answers it; absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub station_id: Option<String>,
    #[serde(skip)]
    pub seq: i64,
    /// The measurement's level in a series (read by [`Store::recipe_verdicts`] only).
    #[serde(skip)]
    pub level_index: Option<i64>,
}

impl VerdictRow {
    /// The stored detail read into its type; Err says why it does not read
    /// (written by another software version, or damaged).
    pub fn verdict_detail(&self) -> Result<springbench_core::qc::Verdict, String> {
        serde_json::from_value(self.detail.clone()).map_err(|e| e.to_string())
    }

    /// The stored traceability read into its type.
    pub fn trace(&self) -> Result<springbench_core::qc::trace::VerdictTrace, String> {
        serde_json::from_value(self.traceability.clone()).map_err(|e| e.to_string())
    }

    /// The row as it is shown: an invalid verdict is never judged, not even
    /// per parameter (values and limits as measured, each `not_judged`, no
    /// failures; issue 35), also when it was stored before that rule. A
    /// detail this version cannot read is passed on unchanged.
    pub fn shown(mut self) -> Self {
        if self.verdict == springbench_core::qc::VerdictKind::Invalid.as_str() {
            if let Ok(v) = self.shown_detail() {
                if let Ok(d) = serde_json::to_value(v) {
                    self.detail = d;
                }
            }
        }
        self
    }

    /// The detail as [`VerdictRow::shown`] shows it, typed, read once.
    pub fn shown_detail(&self) -> Result<springbench_core::qc::Verdict, String> {
        let v = self.verdict_detail()?;
        Ok(
            if self.verdict == springbench_core::qc::VerdictKind::Invalid.as_str() {
                springbench_core::qc::never_judge_invalid(v)
            } else {
                v
            },
        )
    }
}

/// A recording of three frames for the store's own tests.
#[cfg(test)]
pub(crate) fn tiny_recording(kind: &'static str) -> NewRecording {
    NewRecording {
        kind,
        sample_rate_hz: 48000.0,
        frames: 3,
        stored: springbench_recording::codec::Stored {
            bytes: vec![1, 2, 3, kind.len() as u8],
            channel_scale: None,
        },
    }
}

/// A document a measurement stores (`meta_json`, `result_json`): the type
/// this version made, or the JSON another station's version sent to the
/// fleet, kept whole as it came (a newer version's members are not lost by
/// reading them into this version's type).
#[derive(Debug, Clone, PartialEq)]
pub enum Doc<T> {
    Made(T),
    Received(Value),
}

impl<T: serde::Serialize> Doc<T> {
    /// The document as stored: object keys sorted; a NaN or infinity is
    /// refused (issue 11), never written as null. The store checks here, on
    /// write, whoever made the document.
    pub fn to_value(&self) -> Result<Value, springbench_core::finite::NonFinite> {
        match self {
            Doc::Made(t) => springbench_core::finite::to_value(t),
            Doc::Received(v) => springbench_core::finite::check(v).map(|()| v.clone()),
        }
    }
}

/// A new measurement to store.
#[derive(Debug, Clone)]
pub struct NewMeasurement {
    pub id: String,
    pub part_serial: String,
    pub job_id: Option<String>,
    pub source: &'static str,
    pub bench_id: Option<String>,
    /// What the measurement was made with (stored as `config_json`).
    pub config: springbench_core::job::MeasurementConfig,
    /// How the signals were recorded (stored as `meta_json`).
    pub meta: Doc<springbench_core::recording::Meta>,
    /// The analysis' report (stored as `result_json`); `None` when the
    /// analysis failed (`analysis_error` says why).
    pub result: Option<Doc<springbench_core::identify::Report>>,
    pub analysis_error: Option<String>,
    pub target_xpeak_m: Option<f64>,
    pub repeat_index: Option<i64>,
    pub level_index: Option<i64>,
    /// Index into the `recordings` list handed to the same call.
    pub pre: usize,
    pub main: usize,
}

/// A recording to store: FLAC (or WAV) bytes and their channel scale
/// ([`springbench_recording::codec`]).
#[derive(Debug, Clone)]
pub struct NewRecording {
    pub kind: &'static str,
    pub sample_rate_hz: f64,
    pub frames: i64,
    pub stored: springbench_recording::codec::Stored,
}

/// A verdict to store.
#[derive(Debug, Clone)]
pub struct NewVerdict {
    pub id: String,
    pub job_id: Option<String>,
    pub measurement_id: Option<String>,
    pub part_serial: String,
    pub recipe_name: String,
    pub recipe_version: i64,
    pub recipe_sha256: String,
    pub verdict: &'static str,
    /// [`springbench_core::qc::Verdict`].
    pub detail: Value,
    pub trace: Value,
}

/// A measurement read back: its record, its result document (None when
/// the analysis failed) and its meta.json.
pub type StoredMeasurement = (MeasurementInfo, Option<Value>, Value);

/// Parts: one per serial, across every measurement of it.
pub trait PartReads: Sync {
    /// The part with its measurement count and its newest job verdict.
    fn get_part(&self, serial: &str) -> impl Future<Output = StoreResult<Option<Part>>> + Send;

    /// Parts ordered by serial; `after` is the last serial of the previous
    /// page (keyset pagination).
    fn list_parts(
        &self,
        after: Option<&str>,
        limit: i64,
    ) -> impl Future<Output = StoreResult<Vec<Part>>> + Send;
}

/// Measurements: a part's history, a job's measurements, one result.
pub trait MeasurementReads: Sync {
    fn get_measurement(
        &self,
        id: &str,
    ) -> impl Future<Output = StoreResult<Option<StoredMeasurement>>> + Send;

    /// Measurements newest first, optionally of one part or one job, stored
    /// at or after `since` (RFC 3339 UTC, ms); `before_seq` is the cursor of
    /// the previous page (keyset pagination on the storage order).
    fn list_measurements_since(
        &self,
        part: Option<&str>,
        job: Option<&str>,
        since: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> impl Future<Output = StoreResult<Vec<MeasurementInfo>>> + Send;

    /// [`MeasurementReads::list_measurements_since`] without a time bound.
    fn list_measurements(
        &self,
        part: Option<&str>,
        job: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> impl Future<Output = StoreResult<Vec<MeasurementInfo>>> + Send {
        self.list_measurements_since(part, job, None, before_seq, limit)
    }
}

/// Fits of a stored measurement and the choice of its headline fit.
pub trait FitReads: Sync {
    /// The fits of a measurement, oldest first.
    fn list_fits(&self, measurement_id: &str)
        -> impl Future<Output = StoreResult<Vec<Fit>>> + Send;

    /// The newest headline choice of a measurement (None: never chosen).
    fn headline_choice(
        &self,
        measurement_id: &str,
    ) -> impl Future<Output = StoreResult<Option<HeadlineChoice>>> + Send;
}

/// QC verdicts: of a part, a job, a measurement; a recipe's (SPC).
pub trait VerdictReads: Sync {
    /// The newest job verdict of a part (any recipe).
    fn part_verdict(
        &self,
        serial: &str,
    ) -> impl Future<Output = StoreResult<Option<VerdictRow>>> + Send;

    /// The verdicts of a job: the job's (measurement_id None) first, then per measurement.
    fn job_verdicts(
        &self,
        job_id: &str,
    ) -> impl Future<Output = StoreResult<Vec<VerdictRow>>> + Send;

    /// The newest verdict of a measurement.
    fn measurement_verdict(
        &self,
        measurement_id: &str,
    ) -> impl Future<Output = StoreResult<Option<VerdictRow>>> + Send;

    /// Measurement verdicts of a recipe (any version), oldest first: the
    /// newest `last` of them, or those made in [since, until); each with its
    /// measurement's level in a series (SPC reads these). `purpose`: only
    /// the verdicts of that pool (a verdict without one in its trace is
    /// `production`); None: every pool.
    fn recipe_verdicts(
        &self,
        recipe: &str,
        purpose: Option<springbench_core::job::Purpose>,
        since: Option<&str>,
        until: Option<&str>,
        last: Option<i64>,
    ) -> impl Future<Output = StoreResult<Vec<VerdictRow>>> + Send;
}

/// Versioned QC recipes.
pub trait RecipeReads: Sync {
    /// A recipe version (the newest when `version` is None).
    fn get_recipe(
        &self,
        name: &str,
        version: Option<i64>,
    ) -> impl Future<Output = StoreResult<Option<RecipeRow>>> + Send;

    /// The newest version of every recipe, by name.
    fn list_recipes(&self) -> impl Future<Output = StoreResult<Vec<RecipeRow>>> + Send;

    /// Every version of a recipe, oldest first.
    fn recipe_versions(
        &self,
        name: &str,
    ) -> impl Future<Output = StoreResult<Vec<RecipeRow>>> + Send;
}

/// A finished measurement as it leaves a station: the part, the
/// measurement with its recordings, its verdicts, when and with which
/// software it was made (kept as the station wrote them).
#[derive(Debug, Clone)]
pub struct FinishedMeasurement {
    /// Serial, kind, notes (kind and notes update the part when given).
    pub part: (String, Option<String>, Option<String>),
    /// `pre` and `main` index into `recordings`.
    pub measurement: NewMeasurement,
    pub recordings: Vec<NewRecording>,
    /// The measurement's own verdicts (each names this measurement).
    pub verdicts: Vec<NewVerdict>,
    pub software_version: String,
    /// When the station stored it (RFC 3339 UTC, ms); also the verdicts' time.
    pub created_at: String,
}

/// What [`ResultIngest::upsert_measurement`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Upserted {
    /// Stored now, in one transaction.
    Inserted,
    /// A measurement with this id is stored already: nothing was written
    /// (a repeated delivery of the same measurement is a no-op).
    AlreadyStored,
}

/// The ingest of finished measurements.
pub trait ResultIngest: Sync {
    /// Stores a finished measurement with its recordings and verdicts in one
    /// transaction, or nothing when its id is stored already. Idempotent: a
    /// delivery repeated after a lost acknowledgement stores nothing twice.
    fn upsert_measurement(
        &self,
        m: &FinishedMeasurement,
    ) -> impl Future<Output = StoreResult<Upserted>> + Send;
}

/// Every results trait: what a backend implements, what a fleet-wide
/// caller or the conformance suite asks for.
pub trait ResultStore:
    PartReads + MeasurementReads + FitReads + VerdictReads + RecipeReads + ResultIngest
{
}

impl<T> ResultStore for T where
    T: PartReads + MeasurementReads + FitReads + VerdictReads + RecipeReads + ResultIngest
{
}
