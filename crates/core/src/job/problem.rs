//! Why a job failed or was interrupted: a kind the code matches on and a
//! detail for people, stored with the job (`problem_json`) as an RFC 9457
//! problem document (`{"type": "/problems/<kind>", "title", "status": 500,
//! "detail"}`, the document earlier versions stored).

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// What went wrong, by kind. Its name is the problem type's last segment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProblemKind {
    /// The part could not be mounted (virtual bench: no such preset).
    Part,
    /// The bench could not be made, or failed during the procedure.
    Bench,
    /// The bench faulted (drive ramped to zero), a self-check failed, or a
    /// faulted bench refused the job; the bench stays faulted.
    BenchFault,
    /// The procedure refused its configuration.
    ProcedureInvalid,
    /// The procedure failed.
    Procedure,
    /// A recording could not be stored losslessly.
    Recording,
    /// The results could not be stored.
    Storage,
    /// The stored request no longer reads.
    JobUnreadable,
    /// The job's recipe is gone, retired or changed, or its bench calibration unreadable.
    Recipe,
    /// The measurement task ended abnormally.
    Internal,
    /// The daemon stopped while the job ran.
    Interrupted,
    /// A self-check of a virtual bench.
    SelfCheckUnsupported,
    /// The job's bench is no longer configured.
    UnknownBench,
    /// A long-term test reached one of its failure limits (the detail names it).
    FailureLimit,
    /// A kind this version does not know (a row of another version).
    Other(String),
}

const KINDS: [(ProblemKind, &str); 14] = [
    (ProblemKind::Part, "part"),
    (ProblemKind::Bench, "bench"),
    (ProblemKind::BenchFault, "bench-fault"),
    (ProblemKind::ProcedureInvalid, "procedure-invalid"),
    (ProblemKind::Procedure, "procedure"),
    (ProblemKind::Recording, "recording"),
    (ProblemKind::Storage, "storage"),
    (ProblemKind::JobUnreadable, "job-unreadable"),
    (ProblemKind::Recipe, "recipe"),
    (ProblemKind::Internal, "internal"),
    (ProblemKind::Interrupted, "interrupted"),
    (ProblemKind::SelfCheckUnsupported, "self-check-unsupported"),
    (ProblemKind::UnknownBench, "unknown-bench"),
    (ProblemKind::FailureLimit, "failure-limit"),
];

impl ProblemKind {
    /// The last segment of the problem type (`/problems/<name>`).
    pub fn name(&self) -> &str {
        match self {
            ProblemKind::Other(s) => s,
            k => KINDS
                .iter()
                .find(|(kk, _)| kk == k)
                .map(|(_, n)| *n)
                .unwrap_or(""),
        }
    }

    fn from_type(t: &str) -> ProblemKind {
        let name = t.strip_prefix("/problems/").unwrap_or(t);
        KINDS
            .iter()
            .find(|(_, n)| *n == name)
            .map(|(k, _)| k.clone())
            .unwrap_or_else(|| ProblemKind::Other(t.to_string()))
    }
}

/// A job's problem: its kind, a title and the detail.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JobProblem {
    pub kind: ProblemKind,
    pub title: String,
    pub detail: String,
}

impl JobProblem {
    pub fn new(kind: ProblemKind, title: &str, detail: impl Into<String>) -> JobProblem {
        JobProblem {
            kind,
            title: title.to_string(),
            detail: detail.into(),
        }
    }

    /// The reason of the `invalid` verdict a job with this problem gets
    /// under a recipe: `hardware_fault` when its bench could not be made or
    /// failed, `job_failed` otherwise (the mapping earlier versions made
    /// from the problem type's text).
    pub fn invalid_reason(&self) -> &'static str {
        match self.kind {
            ProblemKind::Bench => "hardware_fault",
            _ => "job_failed",
        }
    }
}

/// The stored document; members in serde_json's sorted order, so the text
/// is the one earlier versions wrote through a `serde_json::Value`.
#[derive(Serialize, Deserialize)]
struct Document {
    detail: String,
    status: u16,
    title: String,
    #[serde(rename = "type")]
    type_: String,
}

impl Serialize for JobProblem {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        Document {
            detail: self.detail.clone(),
            status: 500,
            title: self.title.clone(),
            type_: match &self.kind {
                ProblemKind::Other(t) => t.clone(),
                k => format!("/problems/{}", k.name()),
            },
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for JobProblem {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let doc = Document::deserialize(d)?;
        Ok(JobProblem {
            kind: ProblemKind::from_type(&doc.type_),
            title: doc.title,
            detail: doc.detail,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_as_the_problem_document_earlier_versions_wrote() {
        for (kind, name) in KINDS {
            let p = JobProblem::new(kind.clone(), "Bench failed", "no audio device");
            let old = serde_json::json!({"type": format!("/problems/{name}"), "title": "Bench failed",
                                         "status": 500, "detail": "no audio device"});
            assert_eq!(serde_json::to_string(&p).unwrap(), old.to_string());
            assert_eq!(serde_json::from_value::<JobProblem>(old).unwrap(), p);
        }
        // a kind of another version reads and is written back as it was
        let other = serde_json::json!({"type": "/problems/thermal", "title": "Too hot",
                                       "status": 500, "detail": "45 C"});
        let p: JobProblem = serde_json::from_value(other.clone()).unwrap();
        assert_eq!(p.kind, ProblemKind::Other("/problems/thermal".into()));
        assert_eq!(serde_json::to_string(&p).unwrap(), other.to_string());
    }

    #[test]
    fn only_a_bench_that_failed_is_a_hardware_fault() {
        // what `kind.ends_with("/bench")` on the type's text decided
        for (kind, name) in KINDS {
            let want = if format!("/problems/{name}").ends_with("/bench") {
                "hardware_fault"
            } else {
                "job_failed"
            };
            assert_eq!(
                JobProblem::new(kind, "", "").invalid_reason(),
                want,
                "{name}"
            );
        }
    }
}
