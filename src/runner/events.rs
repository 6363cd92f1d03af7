//! The event stream: every stored event has a sequence number (the resume
//! point of `GET /api/v1/events?after=N`); live samples during sweeps are
//! broadcast only (not stored, `seq` = the last stored event's).

use crate::job::JobProblem;
use crate::store::{Event, JobState, Store, StoreResult};
use std::sync::Arc;
use tokio::sync::{broadcast, Mutex};

/// Every event the daemon publishes (issue 37): one type for every
/// publisher (the runner, the job, bench and long-term APIs, import), so a
/// field is named in one place and renaming it is a compile error at each
/// publisher. [`JobEvent::kind`] is the event's `type`; the variant's fields,
/// serialised, are its `data` (the documents are those the `json!` bags
/// made: the same keys, `null` where a value is absent).
#[derive(Debug, Clone, serde::Serialize)]
#[serde(untagged)]
pub enum JobEvent {
    /// `job.state`: a job accepted; `kind` is set for a long-term test,
    /// `type` for a self-check.
    Queued {
        state: JobState,
        part_serial: String,
        bench_id: String,
        #[serde(skip_serializing_if = "Option::is_none")]
        kind: Option<&'static str>,
        #[serde(rename = "type", skip_serializing_if = "Option::is_none")]
        type_: Option<&'static str>,
        /// A study job's kind (`added_mass`, `recovery`).
        #[serde(skip_serializing_if = "Option::is_none")]
        study: Option<&'static str>,
    },
    /// `job.state` with the state alone (running, cancelled).
    State { state: JobState },
    /// `job.state`: ended with its problem (failed at start, or a
    /// queued job whose bench is gone).
    Failed {
        state: JobState,
        problem: Option<JobProblem>,
    },
    /// `job.state`: ended `interrupted` at a restart, with the job's verdict.
    Interrupted {
        state: JobState,
        problem: JobProblem,
        verdict: Option<&'static str>,
    },
    /// `job.state`: a measurement job's end.
    Finished {
        state: JobState,
        problem: Option<JobProblem>,
        bench_time_s: Option<f64>,
        measurement_ids: Vec<String>,
        warnings: Vec<String>,
        verdict: Option<&'static str>,
    },
    /// `job.state`: a long-term test's end.
    LongTermEnded {
        state: JobState,
        problem: Option<JobProblem>,
        measurement_ids: Vec<String>,
    },
    /// `job.state`: a self-check passed, with its calibration record.
    SelfCheckPassed {
        state: JobState,
        calibration_id: String,
    },
    /// `job.state`: a study done, with its kind.
    StudySucceeded {
        state: JobState,
        study: &'static str,
    },
    /// `study.state`: a study's step alone (the runner saw the confirmation).
    StudyStep { state: StudyStep },
    /// `study.state`: the study waits for the operator, who is told what to do.
    StudyAwaitingOperator {
        state: StudyStep,
        instruction: String,
    },
    /// `study.state`: the operator confirmed (`by`: the token's name, if any).
    StudyConfirmed {
        state: StudyStep,
        by: Option<String>,
    },
    /// `job.progress`.
    Progress {
        step: &'static str,
        progress: f64,
        eta_s: f64,
    },
    /// `job.samples` (live only, never stored).
    Samples {
        step: &'static str,
        t0_s: f64,
        dt_s: f64,
        x_m: Vec<f32>,
        microphone_v: Vec<f32>,
    },
    /// `measurement.created` (`source`: `bench` or `import`).
    MeasurementCreated {
        measurement_id: String,
        part_serial: String,
        source: &'static str,
    },
    /// `bench.faulted`.
    BenchFaulted { bench_id: String, detail: String },
    /// `longterm.resumed`: a long-term test resumed after its last stored interval.
    LongTermResumed { intervals_done: usize, load_j: f64 },
    /// `longterm.interval`: an interval stored.
    LongTermInterval {
        index: usize,
        measurement_id: String,
        elapsed_s: f64,
        load_j: f64,
    },
}

impl JobEvent {
    /// The event's `type`.
    pub fn kind(&self) -> &'static str {
        match self {
            JobEvent::Queued { .. }
            | JobEvent::State { .. }
            | JobEvent::Failed { .. }
            | JobEvent::Interrupted { .. }
            | JobEvent::Finished { .. }
            | JobEvent::LongTermEnded { .. }
            | JobEvent::SelfCheckPassed { .. }
            | JobEvent::StudySucceeded { .. } => "job.state",
            JobEvent::StudyStep { .. }
            | JobEvent::StudyAwaitingOperator { .. }
            | JobEvent::StudyConfirmed { .. } => "study.state",
            JobEvent::Progress { .. } => "job.progress",
            JobEvent::Samples { .. } => "job.samples",
            JobEvent::MeasurementCreated { .. } => "measurement.created",
            JobEvent::BenchFaulted { .. } => "bench.faulted",
            JobEvent::LongTermResumed { .. } => "longterm.resumed",
            JobEvent::LongTermInterval { .. } => "longterm.interval",
        }
    }

    /// `job.state` of a job just accepted.
    pub fn queued(part_serial: &str, bench_id: &str) -> JobEvent {
        JobEvent::Queued {
            state: JobState::Queued,
            part_serial: part_serial.to_string(),
            bench_id: bench_id.to_string(),
            kind: None,
            type_: None,
            study: None,
        }
    }

    /// The `data` document (what is stored and sent).
    fn data(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

/// A study's step in its `study.state` events.
#[derive(Debug, Clone, Copy, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StudyStep {
    AwaitingOperator,
    Confirmed,
}

/// What subscribers receive.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Published {
    #[serde(flatten)]
    pub event: Event,
    /// True for live samples: not stored, not replayed after a reconnect.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub live: bool,
}

#[derive(Clone)]
pub struct EventBus {
    store: Store,
    tx: broadcast::Sender<Arc<Published>>,
    /// Serialises append + broadcast so subscribers see increasing `seq`.
    order: Arc<Mutex<i64>>,
}

impl EventBus {
    pub async fn new(store: Store) -> StoreResult<EventBus> {
        let last = store.last_event_seq().await?;
        let (tx, _) = broadcast::channel(4096);
        Ok(EventBus {
            store,
            tx,
            order: Arc::new(Mutex::new(last)),
        })
    }

    /// Stores an event and broadcasts it.
    pub async fn publish(&self, job_id: Option<&str>, e: &JobEvent) -> StoreResult<i64> {
        let data = e.data();
        let mut last = self.order.lock().await;
        let event = self.store.append_event(e.kind(), job_id, &data).await?;
        *last = event.seq;
        let seq = event.seq;
        let _ = self.tx.send(Arc::new(Published { event, live: false }));
        Ok(seq)
    }

    /// Broadcasts a live event without storing it.
    pub async fn publish_live(&self, job_id: Option<&str>, e: &JobEvent) {
        let data = e.data();
        let last = self.order.lock().await;
        let event = Event {
            seq: *last,
            time: crate::store::now(),
            kind: e.kind().to_string(),
            job_id: job_id.map(str::to_string),
            data,
        };
        let _ = self.tx.send(Arc::new(Published { event, live: true }));
    }

    pub fn subscribe(&self) -> broadcast::Receiver<Arc<Published>> {
        self.tx.subscribe()
    }

    pub fn store(&self) -> &Store {
        &self.store
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::ProblemKind;
    use serde_json::json;

    /// The typed events write the documents the `json!` bags wrote: the
    /// same keys and values, `null` where a value is absent, nothing more.
    #[test]
    fn the_events_are_the_documents_the_json_bags_were() {
        let p = JobProblem::new(ProblemKind::Procedure, "Procedure failed", "no sweep");
        let cases = [
            (
                JobEvent::queued("SN-1", "virtual-1"),
                "job.state",
                json!({"state": "queued", "part_serial": "SN-1", "bench_id": "virtual-1"}),
            ),
            (
                JobEvent::Queued {
                    state: JobState::Queued,
                    part_serial: "SN-1".into(),
                    bench_id: "hw-1".into(),
                    kind: None,
                    type_: Some("self_check"),
                    study: None,
                },
                "job.state",
                json!({"state": "queued", "part_serial": "SN-1", "bench_id": "hw-1", "type": "self_check"}),
            ),
            (
                JobEvent::Finished {
                    state: JobState::Failed,
                    problem: Some(p.clone()),
                    bench_time_s: None,
                    measurement_ids: vec!["m1".into()],
                    warnings: vec![],
                    verdict: None,
                },
                "job.state",
                json!({"state": "failed", "problem": p, "bench_time_s": null,
                       "measurement_ids": ["m1"], "warnings": [], "verdict": null}),
            ),
            (
                JobEvent::Failed {
                    state: JobState::Failed,
                    problem: None,
                },
                "job.state",
                json!({"state": "failed", "problem": null}),
            ),
            (
                JobEvent::Progress {
                    step: "narrow",
                    progress: 0.5,
                    eta_s: 3.0,
                },
                "job.progress",
                json!({"step": "narrow", "progress": 0.5, "eta_s": 3.0}),
            ),
            (
                JobEvent::Samples {
                    step: "narrow",
                    t0_s: 0.0,
                    dt_s: 0.001,
                    x_m: vec![0.25f32],
                    microphone_v: vec![-0.5f32],
                },
                "job.samples",
                json!({"step": "narrow", "t0_s": 0.0, "dt_s": 0.001,
                       "x_m": [0.25f32], "microphone_v": [-0.5f32]}),
            ),
            (
                JobEvent::LongTermInterval {
                    index: 2,
                    measurement_id: "m2".into(),
                    elapsed_s: 60.0,
                    load_j: 1.5,
                },
                "longterm.interval",
                json!({"index": 2, "measurement_id": "m2", "elapsed_s": 60.0, "load_j": 1.5}),
            ),
        ];
        for (e, kind, want) in cases {
            assert_eq!(e.kind(), kind);
            assert_eq!(e.data().to_string(), want.to_string(), "{e:?}");
        }
    }
}
