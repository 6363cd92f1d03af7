//! The fleet's replication contract (issue 20, decision 0036): what a
//! station sends to the center and what the center answers.
//!
//! A station keeps its SQLite as the source of truth and puts every item
//! that must reach the center into a durable outbox, as JSON of the types
//! below; its replication worker hands batches to a [`CenterIngest`] (the
//! center's PostgreSQL store). The center applies a batch in one
//! transaction, keyed by item id (a measurement's id, a verdict's id, a
//! correction's id): a batch delivered twice (lost acknowledgement, retry
//! after an outage) stores nothing twice.
//!
//! Every item carries the station's outbox sequence number (`seq`, 1, 2,
//! ... per station, without gaps, in the station's per-part order); the
//! center records which numbers it holds, so a gap in a station's stream is
//! visible ([`CenterIngest::stations`]: `missing_items`).
//!
//! Everything here is plain data (serde), no backend: the SQLite side
//! builds items from what it stored, the PostgreSQL side
//! (`springbench-store-pg`) ingests them.

use crate::hardware::CalibrationRecord;
pub use crate::outbox::Correction;
use crate::results::{FinishedMeasurement, NewMeasurement, NewRecording, NewVerdict, RecipeRow};
use crate::StoreResult;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};
use springbench_recording::codec::Stored;
use std::future::Future;

/// The contract's version; a station sends it in its hello. A center
/// accepts the versions it knows (today: 1).
pub const CONTRACT_VERSION: u32 = 1;

fn contract_v1() -> u32 {
    1
}

/// A station's report of itself, sent before each batch and at least every
/// few seconds while idle: the center shows it as the station's last
/// contact, software, benches and backlog.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StationHello {
    /// The station's id (configuration key `station_id`), unique in the fleet.
    pub station_id: String,
    /// The station's Springbench version.
    pub software_version: String,
    #[serde(default = "contract_v1")]
    pub contract_version: u32,
    pub bench_states: Vec<BenchState>,
    /// Items in the station's outbox not yet acknowledged by the center.
    pub backlog_items: i64,
    /// When the oldest of them was made (RFC 3339 UTC, ms); None when empty.
    #[serde(default)]
    pub oldest_backlog_at: Option<String>,
    /// The station's clock when it sent this (RFC 3339 UTC, ms).
    pub sent_at: String,
}

/// One bench of a station and its state as the station's runner sees it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BenchState {
    pub bench_id: String,
    /// `idle`, `running`, `faulted`, ... (the station's `GET /api/v1/benches` state).
    pub state: String,
    #[serde(default)]
    pub detail: Option<String>,
}

/// What the center knows of a station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct StationStatus {
    pub station_id: String,
    pub software_version: String,
    pub contract_version: u32,
    pub bench_states: Vec<BenchState>,
    /// The backlog the station reported in its last hello.
    pub backlog_items: i64,
    pub oldest_backlog_at: Option<String>,
    /// The station's clock in its last hello.
    pub sent_at: String,
    /// The center's clock when the last hello or batch arrived (RFC 3339 UTC, ms).
    pub last_contact_at: String,
    pub first_contact_at: String,
    /// Items of this station the center holds, and the highest `seq` among them.
    pub items: i64,
    pub last_seq: Option<i64>,
    /// Sequence numbers below `last_seq` the center does not hold (a gap:
    /// 0 after a complete catch-up).
    pub missing_items: i64,
    /// The station's clock minus the center's at its last hello (s); a
    /// large value is a station whose clock is off (decision 0105: the
    /// center's clock stamps contact and receipt, the station's stays the
    /// measurements' own time).
    #[serde(default)]
    pub clock_skew_s: Option<f64>,
    /// Items and requests of (or claiming) this station the center refused,
    /// each with its reason (`GET /api/v1/fleet/refusals?station=`).
    #[serde(default)]
    pub refused: i64,
    /// When the station was retired on purpose (its token no longer
    /// accepted; its history stays). None: active.
    #[serde(default)]
    pub retired_at: Option<String>,
    /// The station's new id after a rename (its rows keep this id).
    #[serde(default)]
    pub renamed_to: Option<String>,
}

/// The clock skew (s) above which the center reports a station's clock as
/// off (log line, `/metrics`, the station listing's `clock_skew_s`).
pub const CLOCK_SKEW_REPORT_S: f64 = 60.0;

/// One outbox item of a station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplicationItem {
    /// The station's outbox sequence number (1, 2, ...; no gaps; per-part
    /// order is the order of `seq`).
    pub seq: i64,
    #[serde(flatten)]
    pub body: ItemBody,
}

/// What an item carries.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ItemBody {
    /// A finished measurement with its recordings (or their reference), its
    /// verdicts, traceability and calibration record.
    Measurement(Box<MeasurementItem>),
    /// A job's verdicts of a whole job (measurement_id None), at the job's end.
    JobVerdicts(JobVerdictsItem),
    /// An admin's correction of a part's serial or kind, or the void of a
    /// measurement (it stays stored, marked void), with reason, who, when:
    /// a row of the station's audit log (`corrections`).
    Correction(Correction),
    /// A long-term test as the station's page shows it, when it changed
    /// (submitted, started, an interval stored, a pause, its end): the
    /// center keeps the newest and shows it read only (decision 0134).
    LongTermTest(Box<LongTermTestItem>),
}

impl ReplicationItem {
    /// The idempotency key of the item across the fleet:
    /// `measurement:<id>`, `job_verdicts:<job id>`, `correction:<id>`.
    pub fn item_id(&self) -> String {
        match &self.body {
            ItemBody::Measurement(m) => format!("measurement:{}", m.id),
            ItemBody::JobVerdicts(j) => format!("job_verdicts:{}", j.job_id),
            ItemBody::Correction(c) => format!("correction:{}", c.id),
            // A document of the test as it stood when sent: one per outbox
            // row. A resend may carry a newer one (the newest is kept).
            ItemBody::LongTermTest(t) => format!("long_term_test:{}:{}", t.job_id, self.seq),
        }
    }

    /// SHA-256 (hex) of the item's JSON: a repeated delivery with another
    /// content is a conflict, not a silent no-op.
    pub fn content_sha256(&self) -> String {
        let body = serde_json::to_vec(&self.body).unwrap_or_default();
        hex(&Sha256::digest(&body))
    }
}

/// A long-term test as it leaves a station: its page's document and its
/// line in the list, as the station's API serves them (their author is the
/// store's `longterm_view`; the center serves them back as they came).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LongTermTestItem {
    pub job_id: String,
    pub part_serial: String,
    pub bench_id: String,
    /// The job's state when sent (`queued`, `running`, `succeeded`, ...).
    pub job_state: String,
    /// When the test was submitted (RFC 3339 UTC, the station's clock).
    pub created_at: String,
    /// `GET /api/v1/long-term-tests/{id}` of the station.
    pub document: Value,
    /// The test's line of `GET /api/v1/long-term-tests` of the station.
    pub summary: Value,
    /// The last signals before a failure limit stopped it are stored at the
    /// station (their bytes are not sent): download them there.
    #[serde(default)]
    pub last_signals_at_station: bool,
}

impl LongTermTestItem {
    /// Checks what the center files the item under.
    pub fn check(&self) -> Result<(), String> {
        if self.job_id.is_empty() || self.part_serial.is_empty() {
            return Err("long_term_test: job_id and part_serial must not be empty".into());
        }
        if !self.document.is_object() || !self.summary.is_object() {
            return Err("long_term_test: document and summary must be JSON objects".into());
        }
        if crate::jobs::JobState::parse(&self.job_state).is_none() {
            return Err(format!(
                "long_term_test.job_state: a job state, got '{}'",
                self.job_state
            ));
        }
        Ok(())
    }
}

/// A finished measurement as it leaves a station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasurementItem {
    pub id: String,
    pub part_serial: String,
    /// Updates the part's kind / notes at the center when given.
    #[serde(default)]
    pub part_kind: Option<String>,
    #[serde(default)]
    pub part_notes: Option<String>,
    /// The station's job (a reference: the job queue stays on the station).
    pub job_id: Option<String>,
    /// `bench` or `import`.
    pub source: String,
    pub bench_id: Option<String>,
    pub config: Value,
    pub meta: Value,
    /// The result document; None when the analysis failed.
    pub result: Option<Value>,
    pub analysis_error: Option<String>,
    pub target_xpeak_m: Option<f64>,
    pub repeat_index: Option<i64>,
    pub level_index: Option<i64>,
    pub pre: RecordingItem,
    pub main: RecordingItem,
    /// The calibration record (self-check) the measurement was made with.
    #[serde(default)]
    pub calibration: Option<CalibrationRecord>,
    /// The measurement's own verdicts (each names this measurement).
    pub verdicts: Vec<VerdictItem>,
    /// The station's software that made it, and when it was stored there.
    pub software_version: String,
    pub created_at: String,
}

/// A recording: its bytes (FLAC or WAV, as the station stores them), or
/// only a reference to them (`bytes` None: they stay on the station), per
/// the station's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordingItem {
    /// `pre` or `main`.
    pub kind: String,
    pub sample_rate_hz: f64,
    pub frames: i64,
    #[serde(default)]
    pub channel_scale: Option<springbench_core::recording::ChannelScale>,
    /// SHA-256 (hex) and length of the stored bytes (what a reference names).
    pub sha256: String,
    pub byte_len: i64,
    /// The bytes, base64 in JSON; None: a reference only.
    #[serde(default, with = "b64")]
    pub bytes: Option<Vec<u8>>,
}

/// A verdict as the station made it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VerdictItem {
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
    /// [`springbench_core::qc::Verdict`].
    pub detail: Value,
    /// Software version, recipe, bench, calibration, sensors, submitter,
    /// timestamps; `offline: true` when judged with a recipe version the
    /// station could not check against the center.
    pub trace: Value,
    pub created_at: String,
}

/// The verdicts of a whole job, at its end.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobVerdictsItem {
    pub job_id: String,
    pub part_serial: String,
    pub verdicts: Vec<VerdictItem>,
}

/// What the center did with a batch.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct IngestReport {
    /// Items stored now.
    pub inserted: u64,
    /// Items the center held already with the same content (nothing written).
    pub already_stored: u64,
    /// Items the center held already with another content, or whose id
    /// another station holds: nothing written, kept in the center's
    /// conflict log for an engineer; the station may drop them from its
    /// outbox (a retry would not change the answer).
    pub conflicts: Vec<IngestConflict>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct IngestConflict {
    pub seq: i64,
    pub item_id: String,
    pub reason: String,
}

/// The center's side of replication.
///
/// `ingest` applies a batch in one transaction: every item or none (a
/// database error, a stopped server); an item that contradicts itself
/// refuses the whole batch (`StoreError::Invalid`, naming the item's seq)
/// so the station can send the rest one by one and park it.
pub trait CenterIngest: Sync {
    /// Records a station's hello (software, benches, backlog, last contact).
    fn hello(
        &self,
        hello: &StationHello,
    ) -> impl Future<Output = StoreResult<StationStatus>> + Send;

    /// Applies a batch of one station's items, in order, in one transaction;
    /// idempotent by item id.
    fn ingest(
        &self,
        station_id: &str,
        items: &[ReplicationItem],
    ) -> impl Future<Output = StoreResult<IngestReport>> + Send;

    /// Every version of every recipe the center holds (name, version order),
    /// with its hash and retired flag: what stations pull.
    fn recipes(&self) -> impl Future<Output = StoreResult<Vec<RecipeRow>>> + Send;

    /// Every station the center has heard of, by id.
    fn stations(&self) -> impl Future<Output = StoreResult<Vec<StationStatus>>> + Send;
}

impl RecordingItem {
    /// A recording as a station stored it; `with_bytes` false: a reference only.
    pub fn from_new(r: &NewRecording, with_bytes: bool) -> RecordingItem {
        RecordingItem {
            kind: r.kind.to_string(),
            sample_rate_hz: r.sample_rate_hz,
            frames: r.frames,
            channel_scale: r.stored.channel_scale,
            sha256: hex(&Sha256::digest(&r.stored.bytes)),
            byte_len: r.stored.bytes.len() as i64,
            bytes: with_bytes.then(|| r.stored.bytes.clone()),
        }
    }

    /// Checks the kind, the figures and, when the bytes are here, their
    /// length and hash against what the item says of them.
    pub fn check(&self, what: &str) -> Result<&'static str, String> {
        let kind = match self.kind.as_str() {
            "pre" => "pre",
            "main" => "main",
            k => return Err(format!("{what}.kind: 'pre' or 'main', got '{k}'")),
        };
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(format!(
                "{what}.sample_rate_hz: a positive number, got {}",
                self.sample_rate_hz
            ));
        }
        if self.frames < 0 || self.byte_len < 0 {
            return Err(format!("{what}: negative frames or byte_len"));
        }
        if self.sha256.len() != 64 || !self.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(format!(
                "{what}.sha256: 64 hex digits, got '{}'",
                self.sha256
            ));
        }
        if let Some(b) = &self.bytes {
            if b.len() as i64 != self.byte_len {
                return Err(format!(
                    "{what}: {} bytes, byte_len says {}",
                    b.len(),
                    self.byte_len
                ));
            }
            let h = hex(&Sha256::digest(b));
            if h != self.sha256.to_ascii_lowercase() {
                return Err(format!(
                    "{what}: the bytes' SHA-256 is {h}, not {}",
                    self.sha256
                ));
            }
        }
        Ok(kind)
    }
}

impl VerdictItem {
    pub fn from_new(v: &NewVerdict, created_at: &str) -> VerdictItem {
        VerdictItem {
            id: v.id.clone(),
            job_id: v.job_id.clone(),
            measurement_id: v.measurement_id.clone(),
            part_serial: v.part_serial.clone(),
            recipe_name: v.recipe_name.clone(),
            recipe_version: v.recipe_version,
            recipe_sha256: v.recipe_sha256.clone(),
            verdict: v.verdict.to_string(),
            detail: v.detail.clone(),
            trace: v.trace.clone(),
            created_at: created_at.to_string(),
        }
    }

    /// The verdict as the store takes it; an unknown verdict kind is refused.
    pub fn to_new(&self) -> Result<NewVerdict, String> {
        Ok(NewVerdict {
            id: self.id.clone(),
            job_id: self.job_id.clone(),
            measurement_id: self.measurement_id.clone(),
            part_serial: self.part_serial.clone(),
            recipe_name: self.recipe_name.clone(),
            recipe_version: self.recipe_version,
            recipe_sha256: self.recipe_sha256.clone(),
            verdict: verdict_kind(&self.verdict)
                .ok_or_else(|| format!("verdict {}: unknown kind '{}'", self.id, self.verdict))?,
            detail: self.detail.clone(),
            trace: self.trace.clone(),
        })
    }
}

/// `pass`, `fail`, `invalid`, `no_limits` as the store's static names.
pub fn verdict_kind(s: &str) -> Option<&'static str> {
    use springbench_core::qc::VerdictKind as K;
    [K::Pass, K::Fail, K::Invalid, K::NoLimits]
        .into_iter()
        .map(K::as_str)
        .find(|k| *k == s)
}

impl MeasurementItem {
    /// The item of a finished measurement as a station stored it;
    /// `with_bytes` false sends the recordings as references.
    pub fn from_finished(
        f: &FinishedMeasurement,
        calibration: Option<CalibrationRecord>,
        with_bytes: bool,
    ) -> Result<MeasurementItem, String> {
        let m = &f.measurement;
        let rec = |i: usize, what: &str| {
            f.recordings
                .get(i)
                .map(|r| RecordingItem::from_new(r, with_bytes))
                .ok_or_else(|| format!("measurement {}: no {what} recording {i}", m.id))
        };
        Ok(MeasurementItem {
            id: m.id.clone(),
            part_serial: f.part.0.clone(),
            part_kind: f.part.1.clone(),
            part_notes: f.part.2.clone(),
            job_id: m.job_id.clone(),
            source: m.source.to_string(),
            bench_id: m.bench_id.clone(),
            config: serde_json::to_value(&m.config).map_err(|e| e.to_string())?,
            meta: m
                .meta
                .to_value()
                .map_err(|e| format!("measurement {}: meta: {e}", m.id))?,
            result: m
                .result
                .as_ref()
                .map(|d| d.to_value())
                .transpose()
                .map_err(|e| format!("measurement {}: result: {e}", m.id))?,
            analysis_error: m.analysis_error.clone(),
            target_xpeak_m: m.target_xpeak_m,
            repeat_index: m.repeat_index,
            level_index: m.level_index,
            pre: rec(m.pre, "pre")?,
            main: rec(m.main, "main")?,
            calibration,
            verdicts: f
                .verdicts
                .iter()
                .map(|v| VerdictItem::from_new(v, &f.created_at))
                .collect(),
            software_version: f.software_version.clone(),
            created_at: f.created_at.clone(),
        })
    }

    /// Checks the item (kinds, recordings, verdicts of this measurement and
    /// part, finite numbers) and gives it as the store's
    /// [`FinishedMeasurement`]; a reference-only recording has no bytes.
    pub fn to_finished(&self) -> Result<FinishedMeasurement, String> {
        let source = match self.source.as_str() {
            "bench" => "bench",
            "import" => "import",
            s => {
                return Err(format!(
                    "measurement {}: source 'bench' or 'import', got '{s}'",
                    self.id
                ))
            }
        };
        if self.id.is_empty() || self.part_serial.is_empty() {
            return Err("a measurement needs an id and a part serial".into());
        }
        if let Some(x) = self.target_xpeak_m.filter(|x| !x.is_finite()) {
            return Err(format!(
                "measurement {}: target_xpeak_m is {x}, not a number",
                self.id
            ));
        }
        let pre = self.pre.check("pre")?;
        let main = self.main.check("main")?;
        let recording = |r: &RecordingItem, kind: &'static str| NewRecording {
            kind,
            sample_rate_hz: r.sample_rate_hz,
            frames: r.frames,
            stored: Stored {
                bytes: r.bytes.clone().unwrap_or_default(),
                channel_scale: r.channel_scale,
            },
        };
        let mut verdicts = Vec::with_capacity(self.verdicts.len());
        for v in &self.verdicts {
            if v.measurement_id.as_deref() != Some(self.id.as_str()) {
                return Err(format!(
                    "verdict {} is not of measurement {}",
                    v.id, self.id
                ));
            }
            if v.part_serial != self.part_serial {
                return Err(format!(
                    "verdict {} is of part '{}', its measurement {} of '{}'",
                    v.id, v.part_serial, self.id, self.part_serial
                ));
            }
            verdicts.push(v.to_new()?);
        }
        Ok(FinishedMeasurement {
            part: (
                self.part_serial.clone(),
                self.part_kind.clone(),
                self.part_notes.clone(),
            ),
            measurement: NewMeasurement {
                id: self.id.clone(),
                part_serial: self.part_serial.clone(),
                job_id: self.job_id.clone(),
                source,
                bench_id: self.bench_id.clone(),
                config: serde_json::from_value(self.config.clone())
                    .map_err(|e| format!("measurement {}: config: {e}", self.id))?,
                // A station's documents, whatever its version: kept whole.
                meta: crate::Doc::Received(self.meta.clone()),
                result: self.result.clone().map(crate::Doc::Received),
                analysis_error: self.analysis_error.clone(),
                target_xpeak_m: self.target_xpeak_m,
                repeat_index: self.repeat_index,
                level_index: self.level_index,
                pre: 0,
                main: 1,
            },
            recordings: vec![recording(&self.pre, pre), recording(&self.main, main)],
            verdicts,
            software_version: self.software_version.clone(),
            created_at: self.created_at.clone(),
        })
    }
}

/// Lower-case hex of a digest.
pub fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    bytes
        .iter()
        .fold(String::with_capacity(bytes.len() * 2), |mut s, b| {
            let _ = write!(s, "{b:02x}");
            s
        })
}

/// Optional bytes as base64 (standard alphabet, padded) in JSON.
mod b64 {
    use base64::engine::general_purpose::STANDARD;
    use base64::Engine;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &Option<Vec<u8>>, s: S) -> Result<S::Ok, S::Error> {
        match v {
            Some(b) => s.serialize_some(&STANDARD.encode(b)),
            None => s.serialize_none(),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec<u8>>, D::Error> {
        Option::<String>::deserialize(d)?
            .map(|s| STANDARD.decode(s).map_err(serde::de::Error::custom))
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn item() -> ReplicationItem {
        let rec = |kind: &'static str, tag: u8| NewRecording {
            kind,
            sample_rate_hz: 48_000.0,
            frames: 2,
            stored: Stored {
                bytes: vec![tag, 0, 255],
                channel_scale: None,
            },
        };
        let f = FinishedMeasurement {
            part: ("P-1".into(), Some("spider".into()), None),
            measurement: NewMeasurement {
                id: "m-1".into(),
                part_serial: "P-1".into(),
                job_id: Some("j-1".into()),
                source: "bench",
                bench_id: Some("b1".into()),
                config: Default::default(),
                meta: crate::Doc::Received(json!({"id": "m-1"})),
                result: Some(crate::Doc::Received(
                    json!({"large_signal": {"keff_n_per_m": 1000.0}}),
                )),
                analysis_error: None,
                target_xpeak_m: Some(0.002),
                repeat_index: Some(0),
                level_index: None,
                pre: 0,
                main: 1,
            },
            recordings: vec![rec("pre", 1), rec("main", 2)],
            verdicts: vec![NewVerdict {
                id: "v-1".into(),
                job_id: Some("j-1".into()),
                measurement_id: Some("m-1".into()),
                part_serial: "P-1".into(),
                recipe_name: "R".into(),
                recipe_version: 1,
                recipe_sha256: "ab".repeat(32),
                verdict: "pass",
                detail: json!({"verdict": "pass"}),
                trace: json!({}),
            }],
            software_version: "0.1.0".into(),
            created_at: "2026-03-01T08:00:00.000Z".into(),
        };
        ReplicationItem {
            seq: 7,
            body: ItemBody::Measurement(Box::new(
                MeasurementItem::from_finished(&f, None, true).unwrap(),
            )),
        }
    }

    #[test]
    fn an_item_survives_its_json_and_gives_back_the_measurement() {
        let it = item();
        let text = serde_json::to_string(&it).unwrap();
        let v: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["type"], "measurement");
        assert_eq!(v["seq"], 7);
        // base64 of [1, 0, 255]
        assert_eq!(v["pre"]["bytes"], "AQD/");
        let back: ReplicationItem = serde_json::from_str(&text).unwrap();
        assert_eq!(back, it);
        assert_eq!(back.item_id(), "measurement:m-1");
        assert_eq!(back.content_sha256(), it.content_sha256());
        let ItemBody::Measurement(m) = back.body else {
            panic!("not a measurement")
        };
        let f = m.to_finished().unwrap();
        assert_eq!(f.recordings[1].stored.bytes, vec![2, 0, 255]);
        assert_eq!(f.verdicts[0].verdict, "pass");
        assert_eq!(f.measurement.source, "bench");
    }

    #[test]
    fn a_reference_only_recording_keeps_its_hash_and_length() {
        let ItemBody::Measurement(mut m) = item().body else {
            unreachable!()
        };
        m.main.bytes = None;
        assert_eq!(m.main.byte_len, 3);
        assert_eq!(m.main.sha256, hex(&Sha256::digest([2u8, 0, 255])));
        assert!(m.to_finished().unwrap().recordings[1]
            .stored
            .bytes
            .is_empty());
    }

    #[test]
    fn a_contradictory_item_is_refused_with_its_reason() {
        let ItemBody::Measurement(m) = item().body else {
            unreachable!()
        };
        let mut bad = m.clone();
        bad.verdicts[0].verdict = "maybe".into();
        assert!(bad
            .to_finished()
            .unwrap_err()
            .contains("unknown kind 'maybe'"));
        let mut bad = m.clone();
        bad.main.bytes = Some(vec![9, 9, 9]);
        assert!(bad.to_finished().unwrap_err().contains("SHA-256"));
        let mut bad = m.clone();
        bad.verdicts[0].measurement_id = Some("m-2".into());
        assert!(bad
            .to_finished()
            .unwrap_err()
            .contains("not of measurement m-1"));
        let mut bad = m;
        bad.source = "guess".into();
        assert!(bad.to_finished().unwrap_err().contains("source"));
    }

    #[test]
    fn another_content_under_the_same_id_has_another_hash() {
        let a = item();
        let mut b = a.clone();
        if let ItemBody::Measurement(m) = &mut b.body {
            m.verdicts[0].verdict = "fail".into();
        }
        assert_eq!(a.item_id(), b.item_id());
        assert_ne!(a.content_sha256(), b.content_sha256());
        // seq is the station's bookkeeping, not the content.
        let mut c = a.clone();
        c.seq = 8;
        assert_eq!(a.content_sha256(), c.content_sha256());
    }
}
