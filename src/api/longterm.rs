//! Long-term tests (issue 32): submit one (a job of its own kind, run by the
//! bench's runner, cancelled like any job at `/api/v1/jobs/{id}/cancel`),
//! read its intervals, state and the fitted ageing law, the series as CSV,
//! and the last signals before a failure limit stopped it.

use super::problem::{ApiResult, Problem};
use super::{AppState, JsonBody};
use crate::config::BenchKind;
use crate::job::{FieldError, LongTermRequest, LongTermSpec, StoredRequest};
use crate::runner::{job, new_id, JobEvent};
use crate::store::Inserted;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;

pub use crate::store::longterm_view::{
    LongTermDocument, LongTermSummary, TestEvent, TestEventKind,
};

/// `GET /api/v1/long-term-tests`.
#[derive(Serialize, utoipa::ToSchema)]
pub struct LongTermList {
    pub items: Vec<LongTermSummary>,
}

#[utoipa::path(post, path = "/api/v1/long-term-tests", tag = "jobs",
    summary = "Submit a long-term test: the full procedure at intervals while a stimulus ages it (a sine held at the part's current resonance, or band-limited noise at an RMS displacement; a virtual bench accelerated or paced; a hardware or emulated bench in real time under its safety rules; cancel it as a job).",
    request_body(content = crate::job::LongTermRequest, content_type = "application/json",
        example = json!({"measurement": {"part": {"serial": "LT-0001"}, "preset": "spider_3in", "target_xpeak_m": 0.006},
            "duration_s": 36000.0, "interval_s": 900.0, "stimulus": {"excursion_m": 0.0053}})),
    responses(
        (status = 202, description = "Queued", body = crate::store::Job,
            headers(("Location" = String, description = "The test"))),
        (status = 400, description = "Unreadable body"),
        (status = 409, description = "The bench is faulted"),
        (status = 413, description = "Body too large"),
        (status = 422, description = "Invalid fields, one message each in `errors` (e.g. `interval_s` longer than `duration_s`, a negative `stimulus.excursion_m`)"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/long-term-tests`: validate, store as a queued job, wake the bench.
pub async fn submit(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    st.store.check_space(st.cfg.min_free_bytes)?;
    let parsed = crate::job::parse_lenient::<LongTermRequest>(&body);
    let mut spec =
        LongTermRequest::check(parsed, &job::admission(&st.cfg)).map_err(Problem::validation)?;
    let bench = st
        .cfg
        .benches
        .iter()
        .find(|b| b.id == spec.measurement.bench);
    // A hardware or emulated bench plays the stimulus in its own time:
    // never accelerated (the default there), never a held drive level
    // (its controller holds the excursion; decision 0126).
    if let Some(b) = bench.filter(|b| b.kind != BenchKind::Virtual) {
        let mut errors = vec![];
        if spec.accelerated {
            if body.get("accelerated").is_some() {
                errors.push(FieldError::new(
                    "accelerated",
                    format!(
                        "bench '{}' is {}: it plays the stimulus in real time, it cannot accelerate",
                        b.id,
                        b.kind.as_str()
                    ),
                ));
            }
            spec.accelerated = false;
        }
        if spec.stimulus.hold != crate::job::Hold::Excursion {
            errors.push(FieldError::new(
                "stimulus.hold",
                format!(
                    "bench '{}' is {}: its stimulus holds the excursion (\"excursion\")",
                    b.id,
                    b.kind.as_str()
                ),
            ));
        }
        if !errors.is_empty() {
            return Err(Problem::validation(errors));
        }
    }
    // A WAV stimulus names a file uploaded here, at the bench's sample rate
    // (decision 0144: it is played as recorded, not resampled).
    if spec.stimulus.kind == crate::job::StimulusKind::Wav {
        let id = spec.stimulus.wav_id.clone().unwrap_or_default();
        // A hardware or emulated bench's converters' rate, a virtual bench's simulation's.
        let fs = match bench {
            Some(b) if b.kind != BenchKind::Virtual => {
                b.hardware.as_ref().map(|h| f64::from(h.sample_rate_hz))
            }
            _ => None,
        }
        .unwrap_or(crate::physics::model::BenchParams::default().sample_rate_hz);
        match st.store.stimulus(&id).await? {
            None => {
                return Err(Problem::field(
                    "stimulus.wav_id",
                    format!("no stimulus '{id}' on this station: upload the WAV file with POST /api/v1/stimuli"),
                ))
            }
            Some(w) if f64::from(w.sample_rate_hz) != fs => {
                return Err(Problem::field(
                    "stimulus.wav_id",
                    format!(
                        "the file runs at {} Hz, the bench at {fs} Hz: resample it to {fs} Hz and upload it again",
                        w.sample_rate_hz
                    ),
                ))
            }
            Some(_) => {}
        }
    }
    st.store
        .check_admission(st.cfg.min_free_bytes, spec.intervals() as u64)
        .await?;
    spec.measurement.submitted_by = caller.0;
    super::benches::refuse_faulted(&st, &spec.measurement.bench)?;
    let m = &spec.measurement;
    let request = StoredRequest::LongTerm(spec.clone());
    let sha = super::hex(&sha2::Digest::finalize(sha2::Digest::chain_update(
        <sha2::Sha256 as sha2::Digest>::new(),
        body.to_string().as_bytes(),
    )));
    let id = new_id();
    let inserted = st
        .store
        .insert_job(
            &id,
            &m.bench,
            (
                &m.part.serial,
                m.part.kind.as_deref(),
                m.part.notes.as_deref(),
            ),
            m.priority,
            &request,
            &sha,
            None,
        )
        .await?;
    let Inserted::New(j) = inserted else {
        return Err(Problem::internal("a new job was not inserted"));
    };
    st.runner
        .events()
        .publish(
            Some(&j.id),
            &JobEvent::Queued {
                state: crate::store::JobState::Queued,
                part_serial: j.part_serial.clone(),
                bench_id: j.bench_id.clone(),
                kind: Some("long_term"),
                type_: None,
                study: None,
            },
        )
        .await?;
    st.store.add_long_term_test(&j.id).await?;
    st.runner.wake(&j.bench_id);
    let mut r = (StatusCode::ACCEPTED, Json(&j)).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/long-term-tests/{}", j.id)) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

async fn test_job(st: &AppState, id: &str) -> ApiResult<(crate::store::Job, LongTermSpec)> {
    let j = st
        .store
        .get_job(id)
        .await?
        .ok_or_else(|| Problem::not_found("long-term test", id))?;
    let spec = crate::store::longterm_view::spec_of(&j)
        .cloned()
        .ok_or_else(|| Problem::not_found("long-term test", id))?;
    Ok((j, spec))
}

#[utoipa::path(get, path = "/api/v1/long-term-tests/{id}", tag = "jobs",
    summary = "A long-term test: its job (progress, time left, problem), the finished intervals (measurement, elapsed_s, load_j), its state and the ageing law fitted so far.",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 200, description = "The test", body = LongTermDocument),
        (status = 404, description = "No such long-term test")))]
pub async fn get_one(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<super::Sorted<LongTermDocument>>> {
    let doc = st
        .store
        .long_term_document(&id)
        .await?
        .ok_or_else(|| Problem::not_found("long-term test", &id))?;
    Ok(Json(super::Sorted(doc)))
}

#[derive(serde::Deserialize, utoipa::IntoParams)]
pub struct ListQuery {
    /// At most this many tests, newest first (default 100, at most 1000).
    pub limit: Option<i64>,
}

#[utoipa::path(get, path = "/api/v1/long-term-tests", tag = "jobs",
    summary = "The station's long-term tests, newest first: each job (state, progress, time left), its intervals done and planned, the law's state so far and the failure limit that stopped it.",
    params(ListQuery),
    responses(
        (status = 200, description = "The tests", body = LongTermList),
        (status = 422, description = "A bad `limit`")))]
pub async fn list(
    State(st): State<AppState>,
    axum::extract::Query(q): axum::extract::Query<ListQuery>,
) -> ApiResult<Json<LongTermList>> {
    let items = st.store.long_term_summaries(list_limit(q.limit)?).await?;
    Ok(Json(LongTermList { items }))
}

/// The list's `limit` (default 100, 1 to 1000), at a station and at the
/// fleet's center.
pub fn list_limit(limit: Option<i64>) -> ApiResult<i64> {
    let limit = limit.unwrap_or(100);
    if !(1..=1000).contains(&limit) {
        return Err(Problem::validation(vec![FieldError::new(
            "limit",
            format!("must be 1 to 1000, got {limit}"),
        )]));
    }
    Ok(limit)
}

fn num(v: Option<f64>) -> String {
    v.filter(|x| x.is_finite())
        .map(|x| format!("{x}"))
        .unwrap_or_default()
}

#[utoipa::path(get, path = "/api/v1/long-term-tests/{id}/series.csv", tag = "jobs",
    summary = "A long-term test's series as CSV: one row per finished interval (elapsed_s, load_j, k0_n_per_m, its standard error, f0_hz, keff_n_per_m, xpeak_m, measurement_id, accelerated, temperature_k and relative_humidity_percent with their sources, empty when unknown).",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 200, description = "CSV", content_type = "text/csv", body = String),
        (status = 404, description = "No such long-term test")))]
pub async fn series_csv(State(st): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    test_job(&st, &id).await?;
    let intervals = st.store.long_term_intervals(&id).await?;
    let out = series_text(&st.store, &intervals).await?;
    Ok(([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], out).into_response())
}

/// The series as CSV, one row per interval, with each interval's
/// measurement read from `store` (the station's, or the fleet center's).
pub async fn series_text<S: crate::store::MeasurementReads>(
    store: &S,
    intervals: &[crate::store::longterm::LongTermInterval],
) -> ApiResult<String> {
    let mut out = String::from(
        "index,elapsed_s,load_j,k0_n_per_m,k0_se_n_per_m,f0_hz,keff_n_per_m,xpeak_m,measurement_id,accelerated,\
         temperature_k,temperature_source,relative_humidity_percent,humidity_source\n",
    );
    for iv in intervals {
        let report = match store.get_measurement(&iv.measurement_id).await? {
            Some((_, Some(r), _)) => serde_json::from_value::<crate::identify::Report>(r).ok(),
            _ => None,
        };
        let ss = report.as_ref().and_then(|r| r.small_signal.as_ref());
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            iv.index,
            iv.elapsed_s,
            iv.load_j,
            num(ss.and_then(|s| s.k0_n_per_m)),
            num(ss.map(|s| s.k0_se_n_per_m)),
            num(ss.and_then(|s| s.f0_hz)),
            num(report.as_ref().map(|r| r.large_signal.keff_n_per_m)),
            num(report.as_ref().map(|r| r.large_signal.xpeak_m)),
            iv.measurement_id,
            iv.accelerated,
            num(iv.temperature_k),
            iv.temperature_source.map_or("", |s| s.as_str()),
            num(iv.relative_humidity_percent),
            iv.humidity_source.map_or("", |s| s.as_str()),
        ));
    }
    Ok(out)
}

#[utoipa::path(post, path = "/api/v1/long-term-tests/{id}/pause", tag = "jobs",
    summary = "Pause a long-term test: it stops its stimulus at its next step (a hardware or emulated bench at the end of the held chunk, faded out; an interval being measured is finished first), and its test time and load stand still until it is resumed. The pause outlives a restart of the daemon; cancel still works.",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 202, description = "Pausing (the event is recorded when it stops)", body = crate::store::Job),
        (status = 404, description = "No such long-term test"),
        (status = 409, description = "Finished, or paused already (`state` names the job's state)")))]
/// `POST /api/v1/long-term-tests/{id}/pause`.
pub async fn pause(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    pause_or_resume(st, caller, id, true).await
}

#[utoipa::path(post, path = "/api/v1/long-term-tests/{id}/resume", tag = "jobs",
    summary = "Resume a long-term test paused by a user: it carries on from its test time and load where it paused (no interval lost or repeated).",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 202, description = "Resuming", body = crate::store::Job),
        (status = 404, description = "No such long-term test"),
        (status = 409, description = "Finished, or not paused (`state` names the job's state)")))]
/// `POST /api/v1/long-term-tests/{id}/resume`.
pub async fn resume(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    pause_or_resume(st, caller, id, false).await
}

async fn pause_or_resume(
    st: AppState,
    caller: super::auth::Caller,
    id: String,
    pause: bool,
) -> ApiResult<Response> {
    use crate::runner::PauseOutcome;
    let conflict =
        |j: &crate::store::Job, kind: &'static str, title: &'static str, detail: String| {
            Problem::new(StatusCode::CONFLICT, kind, title, detail)
                .with_extra(serde_json::json!({"state": j.state.as_str()}))
        };
    match st.runner.pause_long_term(&id, caller.0, pause).await? {
        PauseOutcome::Done(j) => Ok((StatusCode::ACCEPTED, Json(j)).into_response()),
        PauseOutcome::Unchanged(j) => Err(if pause {
            conflict(
                &j,
                "long-term-paused",
                "Test paused already",
                format!("long-term test '{id}' is paused already; resume it at /api/v1/long-term-tests/{id}/resume"),
            )
        } else {
            conflict(
                &j,
                "long-term-not-paused",
                "Test not paused",
                format!("long-term test '{id}' is not paused by a user"),
            )
        }),
        PauseOutcome::Finished(j) => Err(conflict(
            &j,
            "job-finished",
            "Test finished",
            format!(
                "long-term test '{id}' is {}; it cannot be {}",
                j.state.as_str(),
                if pause { "paused" } else { "resumed" }
            ),
        )),
        PauseOutcome::NotFound => Err(Problem::not_found("long-term test", &id)),
    }
}

#[utoipa::path(put, path = "/api/v1/long-term-tests/{id}/intervals/{index}/ambient", tag = "jobs",
    summary = "Enter by hand the ambient conditions of a finished interval of a long-term test: air temperature (K) and relative humidity (%), either or both; a value given replaces the bench sensor's (its source becomes `hand`).",
    params(("id" = String, Path, description = "The test's job id"),
        ("index" = u32, Path, description = "The interval's index (0 is the first measurement)")),
    request_body(content = crate::job::AmbientRequest, content_type = "application/json",
        example = json!({"temperature_k": 296.15, "relative_humidity_percent": 45.0})),
    responses(
        (status = 200, description = "The interval with its ambient conditions", body = crate::store::longterm::LongTermInterval),
        (status = 400, description = "Unreadable body"),
        (status = 404, description = "No such long-term test or interval"),
        (status = 413, description = "Body too large"),
        (status = 422, description = "Invalid fields, one message each in `errors` (`temperature_k` outside 173.15 to 423.15 K, `relative_humidity_percent` outside 0 to 100 %, neither given)"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `PUT /api/v1/long-term-tests/{id}/intervals/{index}/ambient`.
pub async fn put_ambient(
    State(st): State<AppState>,
    Path((id, index)): Path<(String, String)>,
    JsonBody(body): JsonBody,
) -> ApiResult<Json<crate::store::longterm::LongTermInterval>> {
    st.store.check_space(st.cfg.min_free_bytes)?;
    test_job(&st, &id).await?;
    let no_interval = || Problem::not_found(&format!("interval of long-term test '{id}'"), &index);
    let i: usize = index.parse::<u32>().map_err(|_| no_interval())? as usize;
    let ambient = crate::job::AmbientRequest::check(crate::job::parse_lenient(&body))
        .map_err(Problem::validation)?;
    if !st.store.set_long_term_ambient(&id, i, ambient).await? {
        return Err(no_interval());
    }
    let iv = st
        .store
        .long_term_intervals(&id)
        .await?
        .into_iter()
        .find(|iv| iv.index == i)
        .ok_or_else(no_interval)?;
    Ok(Json(iv))
}

#[utoipa::path(get, path = "/api/v1/long-term-tests/{id}/last-signals.wav", tag = "jobs",
    summary = "The last 10 s of the signals before a failure limit stopped the test: float32 WAV (channel 0 displacement m, 1 microphone V, 2 drive V when present).",
    params(("id" = String, Path, description = "The test's job id")),
    responses(
        (status = 200, description = "WAV", content_type = "audio/wav", body = Vec<u8>),
        (status = 404, description = "No such long-term test, or no failure limit stopped it")))]
pub async fn last_signals(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    test_job(&st, &id).await?;
    let info = st
        .store
        .long_term_signals_info(&id)
        .await?
        .ok_or_else(|| Problem::not_found("last signals of long-term test", &id))?;
    let reader: crate::recording::codec::BlobRead =
        Box::new(std::io::BufReader::new(st.store.blob_reader(info.blob)));
    super::measurements::wav_response(reader, info.channel_scale).await
}
