//! A long-term test as it is shown (issue 32): the document of its page
//! (`GET /api/v1/long-term-tests/{id}`) and its line in the list, built from
//! the store's rows alone. The station's API serves them, and the fleet's
//! replication sends the same document to the center, which shows it read
//! only (decision 0134): one author for both.

use crate::longterm::{LongTermEventKind, LongTermInterval, LongTermState, PauseCause, UserPause};
use crate::{Job, Store, StoreResult};
use serde::Serialize;
use springbench_core::identify::validity::HeadlineValidity;
use springbench_core::job::{Failure, LongTermSpec, ProblemKind, StoredRequest};

/// `GET /api/v1/long-term-tests/{id}`.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct LongTermDocument {
    /// The job (state, progress, eta_s: the time left, problem).
    pub job: Job,
    /// Intervals planned (one at the start and one per interval).
    pub intervals_planned: usize,
    /// Finished intervals: each an ordinary measurement linked to the test.
    pub intervals: Vec<LongTermInterval>,
    /// The test's state after its last finished interval (the fitted law in `document`).
    pub state: Option<LongTermState>,
    /// Every interval was run faster than real time (virtual bench).
    pub accelerated: bool,
    /// The series as CSV, and the last signals when a failure limit stopped the test.
    pub series_csv: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_signals: Option<String>,
    /// What happened besides the intervals, in test time: pauses and their
    /// ends, resumptions after a stop of the daemon, the failure limit.
    pub events: Vec<TestEvent>,
    /// The user's pause in effect (`POST .../pause`), until `POST .../resume`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub user_pause: Option<UserPause>,
    /// At a fleet's center: the station that runs the test (absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub station_id: Option<String>,
    /// At a fleet's center: the station's outbox sequence number of this
    /// copy, and when the center received it (RFC 3339 UTC): how current
    /// the copy is (absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub copy_seq: Option<i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub copy_received_at: Option<String>,
}

/// What kind of event of a test's life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum TestEventKind {
    /// The disk was full, or a user paused it.
    Paused,
    /// Space returned, or a user resumed it.
    Resumed,
    /// Resumed after the daemon stopped.
    Restarted,
    /// A failure limit stopped it.
    Failure,
    /// A fault of a hardware or emulated bench stopped it.
    Stopped,
}

/// One event of a test's life, as its page lists it beside the plots.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct TestEvent {
    /// `paused` (the disk was full, or a user paused it), `resumed` (space
    /// returned, or a user resumed it),
    /// `restarted` (resumed after the daemon stopped), `failure` (a limit stopped it),
    /// `stopped` (a fault of a hardware or emulated bench stopped it).
    pub kind: TestEventKind,
    /// What paused it (`paused`, `resumed`): `disk` or `user`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cause: Option<PauseCause>,
    /// Test time (s), when known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elapsed_s: Option<f64>,
    /// The interval it happened before (or at, for a failure).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub interval: Option<usize>,
    pub detail: String,
    /// Wall time (RFC 3339), when known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at: Option<String>,
}

/// One test of `GET /api/v1/long-term-tests`.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct LongTermSummary {
    /// The job (state, progress, eta_s: the time left, problem).
    pub job: Job,
    pub intervals_planned: usize,
    pub intervals_done: usize,
    /// Length of the test and time between measurements (test time, s).
    pub duration_s: f64,
    pub interval_s: f64,
    pub accelerated: bool,
    /// The fitted law's state so far (absent before 7 intervals).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub law_validity: Option<HeadlineValidity>,
    /// The failure limit that stopped it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failure: Option<Failure>,
    /// At a fleet's center: the station that runs the test (absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub station_id: Option<String>,
    /// At a fleet's center: the station's outbox sequence number of this
    /// copy, and when the center received it (RFC 3339 UTC): how current
    /// the copy is (absent on a station).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub copy_seq: Option<i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub copy_received_at: Option<String>,
}

/// The long-term test's plan, when the job is one.
pub fn spec_of(j: &Job) -> Option<&LongTermSpec> {
    match j.request.read() {
        Ok(StoredRequest::LongTerm(t)) => Some(t),
        _ => None,
    }
}

impl LongTermSummary {
    /// The list's line of a test, from its job and its state.
    pub fn of(job: Job, spec: &LongTermSpec, state: Option<LongTermState>) -> LongTermSummary {
        LongTermSummary {
            intervals_planned: spec.intervals(),
            intervals_done: state.as_ref().map_or(0, |s| s.intervals_done),
            duration_s: spec.duration_s,
            interval_s: spec.interval_s,
            accelerated: spec.accelerated,
            law_validity: state
                .as_ref()
                .and_then(|s| s.document.as_ref())
                .and_then(|d| d.law.as_ref())
                .map(|l| l.validity.clone()),
            failure: state.and_then(|s| s.failure),
            job,
            station_id: None,
            copy_seq: None,
            copy_received_at: None,
        }
    }
}

impl Store {
    /// The document of long-term test `id`; None when no such job or the
    /// job is not a long-term test.
    pub async fn long_term_document(&self, id: &str) -> StoreResult<Option<LongTermDocument>> {
        let Some(job) = self.get_job(id).await? else {
            return Ok(None);
        };
        let Some(spec) = spec_of(&job).cloned() else {
            return Ok(None);
        };
        let intervals = self.long_term_intervals(id).await?;
        let state = self.long_term_state(id).await?;
        let last = self.long_term_signals(id).await?;
        let mut events = self.test_events(id, &intervals, state.as_ref()).await?;
        // A hardware bench's fault stopped it (decision 0126): the last event.
        if let Some(p) = job
            .problem
            .as_ref()
            .filter(|p| p.kind == ProblemKind::BenchFault)
        {
            events.push(TestEvent {
                kind: TestEventKind::Stopped,
                cause: None,
                elapsed_s: None,
                interval: Some(intervals.len()),
                detail: format!(
                    "stopped by a bench fault, the drive ramped down (a self-check clears the bench): {}",
                    p.detail
                ),
                at: job.finished_at.clone(),
            });
        }
        // A finished test is no longer paused (a cancel while paused keeps the row).
        let user_pause = match job.state.is_terminal() {
            true => None,
            false => self.long_term_pause(id).await?,
        };
        Ok(Some(LongTermDocument {
            job,
            intervals_planned: spec.intervals(),
            intervals,
            state,
            accelerated: spec.accelerated,
            series_csv: format!("/api/v1/long-term-tests/{id}/series.csv"),
            last_signals: last.map(|_| format!("/api/v1/long-term-tests/{id}/last-signals.wav")),
            events,
            user_pause,
            station_id: None,
            copy_seq: None,
            copy_received_at: None,
        }))
    }

    /// The list's line of each of the newest `limit` long-term tests.
    pub async fn long_term_summaries(&self, limit: i64) -> StoreResult<Vec<LongTermSummary>> {
        let mut items = vec![];
        for job in self.list_long_term_tests(limit).await? {
            let Some(spec) = spec_of(&job).cloned() else {
                continue;
            };
            let state = self.long_term_state(&job.id).await?;
            items.push(LongTermSummary::of(job, &spec, state));
        }
        Ok(items)
    }

    /// The test's events in test time: the stored pauses, the resumptions
    /// after a stop (after the last stored interval: its measurement's end
    /// is not kept, so the interval's start stands for it) and the failure.
    async fn test_events(
        &self,
        id: &str,
        intervals: &[LongTermInterval],
        state: Option<&LongTermState>,
    ) -> StoreResult<Vec<TestEvent>> {
        let mut out: Vec<TestEvent> = self
            .long_term_events(id)
            .await?
            .into_iter()
            .map(|e| TestEvent {
                kind: match e.kind {
                    LongTermEventKind::Paused => TestEventKind::Paused,
                    LongTermEventKind::Resumed => TestEventKind::Resumed,
                },
                cause: Some(e.cause),
                elapsed_s: Some(e.elapsed_s),
                interval: None,
                detail: e.detail,
                at: Some(e.at),
            })
            .collect();
        if let Some(s) = state {
            for r in &s.resumptions {
                let after = r.intervals_done.checked_sub(1);
                out.push(TestEvent {
                    kind: TestEventKind::Restarted,
                    cause: None,
                    elapsed_s: after
                        .and_then(|i| intervals.iter().find(|iv| iv.index == i))
                        .map(|iv| iv.elapsed_s),
                    interval: Some(r.intervals_done),
                    detail: format!(
                        "the daemon had stopped: resumed after {} intervals, load {:.1} J",
                        r.intervals_done, r.load_j
                    ),
                    at: Some(r.at.clone()),
                });
            }
            if let Some(f) = &s.failure {
                let at_s = f.at_s.or_else(|| {
                    intervals
                        .iter()
                        .find(|iv| iv.index == f.interval)
                        .map(|iv| iv.elapsed_s)
                });
                out.push(TestEvent {
                    kind: TestEventKind::Failure,
                    cause: None,
                    elapsed_s: at_s,
                    interval: Some(f.interval),
                    detail: format!("failure limit `{}`: {}", f.limit, f.detail),
                    at: Some(s.updated_at.clone()),
                });
            }
        }
        out.sort_by(|a, b| {
            let t = |e: &TestEvent| e.elapsed_s.unwrap_or(f64::INFINITY);
            t(a).total_cmp(&t(b))
        });
        Ok(out)
    }
}
