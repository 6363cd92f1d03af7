//! What a job asks for, as the queue stores it and the runner reads it back:
//! a measurement (the accepted [`JobSpec`]) or a bench's self-check. One
//! type from the submission to the runner, so that a new kind of job is a
//! new variant here, not another shape of the same JSON column.
//!
//! The stored text is the one earlier versions wrote: a measurement is the
//! [`JobSpec`] document itself (no tag), every other kind names itself in
//! `type` (`{"type": "self_check", "bench": "b1"}`).

use super::spec::JobSpec;
use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A job's request as stored with the job.
// One per job, read from the queue: a box would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum StoredRequest {
    /// Measure a part: the procedure, the fit per level, a verdict under a recipe.
    Measure(JobSpec),
    /// Check a hardware bench (latency, noise floors) and store a calibration record.
    SelfCheck(SelfCheck),
    /// A long-term test: the full procedure at intervals under a stimulus that ages the part.
    LongTerm(super::long_term::LongTermSpec),
    /// A study of the part's memory (issue 33): added mass, recovery.
    Study(crate::diagnose::studies::Study),
}

/// A self-check of a hardware bench.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SelfCheck {
    /// The bench checked.
    pub bench: String,
}

/// The kinds that name themselves in `type` (every kind but a measurement).
// Serialized or read once per job: a box would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
enum Tagged {
    SelfCheck(SelfCheck),
    LongTerm(super::long_term::LongTermSpec),
    Study(crate::diagnose::studies::Study),
}

impl StoredRequest {
    /// A self-check of bench `bench`.
    pub fn self_check(bench: &str) -> StoredRequest {
        StoredRequest::SelfCheck(SelfCheck {
            bench: bench.to_string(),
        })
    }

    /// The measurement this job asks for, if it is one.
    pub fn measure(&self) -> Option<&JobSpec> {
        match self {
            StoredRequest::Measure(s) => Some(s),
            _ => None,
        }
    }

    /// The document as stored: serde_json's sorted members, so the text is
    /// the same for equal requests (and the one earlier versions wrote).
    pub fn to_json(&self) -> String {
        serde_json::to_value(self)
            .map(|v| v.to_string())
            .unwrap_or_default()
    }
}

impl Serialize for StoredRequest {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            StoredRequest::Measure(spec) => spec.serialize(s),
            StoredRequest::SelfCheck(c) => Tagged::SelfCheck(c.clone()).serialize(s),
            StoredRequest::LongTerm(t) => Tagged::LongTerm(t.clone()).serialize(s),
            StoredRequest::Study(c) => Tagged::Study(c.clone()).serialize(s),
        }
    }
}

impl<'de> Deserialize<'de> for StoredRequest {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = serde_json::Value::deserialize(d)?;
        if v.get("type").is_none() {
            return JobSpec::deserialize(v)
                .map(StoredRequest::Measure)
                .map_err(D::Error::custom);
        }
        match Tagged::deserialize(v).map_err(D::Error::custom)? {
            Tagged::SelfCheck(c) => Ok(StoredRequest::SelfCheck(c)),
            Tagged::LongTerm(t) => Ok(StoredRequest::LongTerm(t)),
            Tagged::Study(c) => Ok(StoredRequest::Study(c)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{JobPart, Limits, ProcedureMode};

    fn spec() -> JobSpec {
        JobSpec {
            part: JobPart {
                serial: "SN-1".into(),
                kind: Some("spider".into()),
                notes: None,
            },
            bench: "b1".into(),
            moving_mass_kg: 0.05,
            levels_m: vec![0.004, 0.008],
            method: crate::identify::Method::TwoSignal,
            order: None,
            repeats: 1,
            procedure: ProcedureMode::Full,
            priority: 0,
            preset: Some("spider-4in".into()),
            part_spec: None,
            limits: Limits {
                max_displacement_m: 0.012,
                max_drive_v: 4.0,
            },
            recipe: None,
            production: None,
            submitted_by: None,
            purpose: crate::job::Purpose::Engineering,
        }
    }

    #[test]
    fn a_spec_stored_before_purposes_reads_as_production() {
        let mut old = serde_json::to_value(spec()).unwrap();
        old.as_object_mut().unwrap().remove("purpose");
        let read: StoredRequest = serde_json::from_value(old).unwrap();
        assert_eq!(
            read.measure().unwrap().purpose,
            crate::job::Purpose::Production
        );
    }

    #[test]
    fn the_stored_text_is_the_one_earlier_versions_wrote() {
        // a measurement: the JobSpec document itself, members sorted
        let m = StoredRequest::Measure(spec());
        let old = serde_json::to_value(spec()).unwrap().to_string();
        assert_eq!(m.to_json(), old);
        assert_eq!(serde_json::from_str::<StoredRequest>(&old).unwrap(), m);
        // a self-check: what `self_check_request` stored before
        let c = StoredRequest::SelfCheck(SelfCheck {
            bench: "hw1".into(),
        });
        let old = r#"{"bench":"hw1","type":"self_check"}"#;
        assert_eq!(c.to_json(), old);
        assert_eq!(serde_json::from_str::<StoredRequest>(old).unwrap(), c);
    }

    #[test]
    fn an_unreadable_request_says_why() {
        let e = serde_json::from_str::<StoredRequest>(r#"{"bench":"b1"}"#).unwrap_err();
        assert!(e.to_string().contains("missing field `part`"), "{e}");
        let e = serde_json::from_str::<StoredRequest>(r#"{"type":"calibrate"}"#).unwrap_err();
        assert!(e.to_string().contains("unknown variant `calibrate`"), "{e}");
    }
}
