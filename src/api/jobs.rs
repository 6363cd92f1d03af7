//! Jobs and parts.

use super::problem::{ApiResult, Problem};
use super::reads::Reads;
use super::{page_limit, parse_cursor, AppState, JsonBody, Q};
use crate::runner::{job, new_id, CancelOutcome, JobEvent};
use crate::store::PartReads;
use crate::store::{Inserted, Job, JobState};
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

fn job_response(status: StatusCode, j: &Job, replayed: bool) -> Response {
    let loc = format!("/api/v1/jobs/{}", j.id);
    let mut r = (status, Json(j)).into_response();
    if let Ok(v) = HeaderValue::from_str(&loc) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    if replayed {
        r.headers_mut()
            .insert("idempotent-replayed", HeaderValue::from_static("true"));
    }
    r
}

#[utoipa::path(post, path = "/api/v1/jobs", tag = "jobs",
    summary = "Submit a measurement job (queued; runs when its bench is free, priority first, then FIFO).",
    params(("Idempotency-Key" = Option<String>, Header, max_length = 255,
        description = "Same key and same body give the same job (200, header `Idempotent-Replayed`); another body gives 409.")),
    request_body(content = crate::job::JobRequest, content_type = "application/json",
        example = json!({"part": {"serial": "SN-0001", "kind": "spider"}, "target_xpeak_m": 0.008})),
    responses(
        (status = 202, description = "Queued", body = crate::store::Job,
            headers(("Location" = String, description = "The job"))),
        (status = 200, description = "Replayed (same Idempotency-Key and body)", body = crate::store::Job,
            headers(("Idempotent-Replayed" = String, description = "`true`"))),
        (status = 400, description = "Unreadable body or Idempotency-Key"),
        (status = 409, description = "Idempotency-Key used before with another body (`job_id` names its job), or the bench is faulted (`bench-faulted`: `fault` names it; a self-check clears it)"),
        (status = 413, description = "Body too large"),
        (status = 422, description = "Invalid fields, one message each in `errors`"),
        (status = 503, description = "Storage unavailable or the disk is full: not acknowledged, retry later")))]
/// `POST /api/v1/jobs`: validate, store as queued, wake the bench. 202 + Location.
pub async fn submit(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    headers: HeaderMap,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let key = match headers.get("idempotency-key") {
        None => None,
        Some(v) => match v.to_str() {
            Ok(s) if !s.is_empty() && s.len() <= 255 => Some(s.to_string()),
            _ => {
                return Err(Problem::bad_request(
                    "Idempotency-Key must be 1-255 visible ASCII characters",
                ))
            }
        },
    };
    match enqueue(&st, caller.0, &body, key.as_deref()).await? {
        Inserted::New(j) => Ok(job_response(StatusCode::ACCEPTED, &j, false)),
        Inserted::Replayed(j) => Ok(job_response(StatusCode::OK, &j, true)),
        Inserted::Conflict(j) => Err(Problem::new(
            StatusCode::CONFLICT,
            "idempotency-conflict",
            "Idempotency key reused",
            "this Idempotency-Key was used before with another request body",
        )
        .with_extra(json!({"job_id": j.id}))),
    }
}

/// Checks a job request (a recipe's procedure filled in), stores it as
/// queued and wakes its bench: the path of `POST /api/v1/jobs` and of the
/// runs of a gauge study. A new job's `job.state` event is published.
pub(crate) async fn enqueue(
    st: &AppState,
    submitted_by: Option<String>,
    body: &Value,
    key: Option<&str>,
) -> ApiResult<Inserted> {
    // Refused (503) rather than acknowledged when its results could not be kept.
    st.store.check_space(st.cfg.min_free_bytes)?;
    // serde_json maps are sorted: the text is canonical for equal bodies.
    let sha = super::hex(&Sha256::digest(body.to_string().as_bytes()));
    // Parsed once into the typed request; a recipe fills in its procedure
    // settings (and names the version judged by), read once.
    let parsed = crate::job::parse_lenient::<job::JobRequest>(body);
    let recipe = match parsed.0.as_ref().and_then(|r| r.recipe.as_deref()) {
        Some(name) => Some(super::qc::recipe_for_job(st, name).await?),
        None => None,
    };
    let mut spec = job::JobRequest::check(parsed, &job::admission(&st.cfg), |r| match &recipe {
        Some(rc) => rc.recipe.procedure.apply_to(&rc.reference.name, r),
        None => Ok(()),
    })
    .map_err(Problem::validation)?;
    // The space the queue and this job will need (503 when it is not there).
    let measurements = spec.levels_m.len().max(1) as u64 * u64::from(spec.repeats.max(1));
    st.store
        .check_admission(st.cfg.min_free_bytes, measurements)
        .await?;
    // A part measured under a recipe is of the recipe's kind unless the job says otherwise.
    if let (None, Some(r)) = (&spec.part.kind, &recipe) {
        spec.part.kind = r.recipe.part_kind.clone();
    }
    spec.recipe = recipe.map(|r| r.reference);
    spec.submitted_by = submitted_by;
    super::benches::refuse_faulted(st, &spec.bench)?;
    let request = crate::job::StoredRequest::Measure(spec.clone());
    let id = new_id();
    let inserted = st
        .store
        .insert_job(
            &id,
            &spec.bench,
            (
                &spec.part.serial,
                spec.part.kind.as_deref(),
                spec.part.notes.as_deref(),
            ),
            spec.priority,
            &request,
            &sha,
            key,
        )
        .await?;
    if let Inserted::New(j) = &inserted {
        st.runner
            .events()
            .publish(Some(&j.id), &JobEvent::queued(&j.part_serial, &j.bench_id))
            .await?;
        st.runner.wake(&j.bench_id);
    }
    Ok(inserted)
}

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct JobQuery {
    /// queued, running, succeeded, failed, cancelled or interrupted.
    #[param(value_type = Option<crate::store::JobState>)]
    state: Option<String>,
    /// Part serial.
    part: Option<String>,
    /// Only jobs created at or after this time (RFC 3339).
    #[param(format = DateTime)]
    since: Option<String>,
    /// Page size (1-500, default 50).
    limit: Option<i64>,
    /// `next_cursor` of the previous page.
    cursor: Option<String>,
}

#[utoipa::path(get, path = "/api/v1/jobs", tag = "jobs",
    summary = "Jobs, newest first.",
    params(JobQuery),
    responses(
        (status = 200, description = "A page of jobs", body = super::schema::JobPage),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/jobs?state=&part=&limit=&cursor=`: newest first.
pub async fn list(State(st): State<AppState>, Q(q): Q<JobQuery>) -> ApiResult<Json<Value>> {
    let state = match q.state.as_deref() {
        None | Some("") => None,
        Some(s) => Some(JobState::parse(s).ok_or_else(|| {
            Problem::field(
                "state",
                "one of queued, running, succeeded, failed, cancelled, interrupted",
            )
        })?),
    };
    let limit = page_limit(q.limit)?;
    let before = parse_cursor(q.cursor.as_deref())?;
    let items = st
        .store
        .list_jobs_since(
            state,
            q.part.as_deref(),
            super::qc::parse_time("since", q.since.as_deref())?.as_deref(),
            before,
            limit,
        )
        .await?;
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|j| j.seq.to_string()))
        .flatten();
    Ok(Json(json!({"items": items, "next_cursor": next})))
}

#[utoipa::path(get, path = "/api/v1/jobs/{id}", tag = "jobs",
    summary = "One job (state, step, progress, eta, problem, measurements) with its QC verdict.",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = super::schema::JobWithVerdict),
        (status = 404, description = "No such job")))]
/// `GET /api/v1/jobs/{id}`: the job, with `verdict` (pass / fail / invalid /
/// no_limits, or null without a recipe; details at `/api/v1/jobs/{id}/verdict`).
pub async fn get_one(State(st): State<AppState>, Path(id): Path<String>) -> ApiResult<Json<Value>> {
    let j = st
        .store
        .get_job(&id)
        .await?
        .ok_or_else(|| Problem::not_found("job", &id))?;
    Ok(Json(serde_json::to_value(&j).map_err(Problem::internal)?))
}

#[utoipa::path(post, path = "/api/v1/jobs/{id}/cancel", tag = "jobs",
    summary = "Cancel a job. A queued job is cancelled at once (200); a running one is told to stop, the bench ramps down (202, then always state `cancelled`); 409 once it has finished or is storing its results.",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled", body = crate::store::Job),
        (status = 202, description = "Stopping", body = crate::store::Job),
        (status = 404, description = "No such job"),
        (status = 409, description = "Finished or storing its results (`state` names its state)")))]
/// `POST /api/v1/jobs/{id}/cancel`: 200 when a queued job is cancelled, 202
/// when a running job is told to stop, 409 when it has finished.
pub async fn cancel(State(st): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    match st.runner.cancel(&id).await? {
        CancelOutcome::Cancelled(j) => Ok((StatusCode::OK, Json(j)).into_response()),
        CancelOutcome::Requested(j) => Ok((StatusCode::ACCEPTED, Json(j)).into_response()),
        CancelOutcome::Finished(j) => Err(Problem::new(
            StatusCode::CONFLICT,
            "job-finished",
            "Job already finished",
            format!(
                "job '{}' is {}; it cannot be cancelled",
                j.id,
                j.state.as_str()
            ),
        )
        .with_extra(json!({"state": j.state.as_str()}))),
        CancelOutcome::Finishing(j) => Err(Problem::new(
            StatusCode::CONFLICT,
            "job-finishing",
            "Job finishing",
            format!("job '{}' has finished measuring and its results are being stored; it cannot be cancelled", j.id),
        )
        .with_extra(json!({"state": j.state.as_str()}))),
        CancelOutcome::NotFound => Err(Problem::not_found("job", &id)),
    }
}

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PageQuery {
    /// Page size (1-500, default 50).
    limit: Option<i64>,
    /// `next_cursor` of the previous page.
    cursor: Option<String>,
}

#[utoipa::path(get, path = "/api/v1/parts", tag = "parts",
    summary = "Parts, by serial.",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of parts", body = super::schema::PartPage),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/parts`: by serial.
pub async fn list_parts<R: Reads>(
    State(st): State<R>,
    Q(q): Q<PageQuery>,
) -> ApiResult<Json<Value>> {
    let limit = page_limit(q.limit)?;
    let items = st
        .results()
        .list_parts(q.cursor.as_deref().filter(|c| !c.is_empty()), limit)
        .await?;
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|p| p.serial.clone()))
        .flatten();
    Ok(Json(json!({"items": items, "next_cursor": next})))
}

#[utoipa::path(get, path = "/api/v1/parts/{serial}", tag = "parts",
    summary = "One part.",
    params(("serial" = String, Path, description = "Part serial")),
    responses(
        (status = 200, description = "The part", body = super::schema::PartDocument),
        (status = 404, description = "No such part")))]
pub async fn get_part<R: Reads>(
    State(st): State<R>,
    Path(serial): Path<String>,
) -> ApiResult<Json<Value>> {
    let p = st
        .results()
        .get_part(&serial)
        .await?
        .ok_or_else(|| Problem::not_found("part", &serial))?;
    let mut v = serde_json::to_value(&p).map_err(Problem::internal)?;
    v["measurements"] = json!(format!("/api/v1/parts/{serial}/measurements"));
    Ok(Json(v))
}

#[utoipa::path(get, path = "/api/v1/parts/{serial}/measurements", tag = "parts",
    summary = "Measurements of a part, newest first.",
    params(("serial" = String, Path, description = "Part serial"), PageQuery),
    responses(
        (status = 200, description = "A page of measurements", body = super::schema::MeasurementPage),
        (status = 404, description = "No such part"),
        (status = 422, description = "A bad query parameter")))]
pub async fn part_measurements<R: Reads>(
    State(st): State<R>,
    Path(serial): Path<String>,
    Q(q): Q<PageQuery>,
) -> ApiResult<Json<Value>> {
    if st.results().get_part(&serial).await?.is_none() {
        return Err(Problem::not_found("part", &serial));
    }
    super::measurements::list_page(
        st.results(),
        Some(&serial),
        None,
        None,
        q.limit,
        q.cursor.as_deref(),
    )
    .await
}
