//! Hardware benches: self-check jobs and calibration records.

use super::problem::{ApiResult, Problem};
use super::AppState;
use crate::bench::settings::BenchKind;
use crate::runner::{hardware, new_id, JobEvent};
use crate::store::Inserted;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

/// A faulted bench takes no part (issue 35): a job for it is refused at
/// submission with a 409 problem (`bench-faulted`) that names the fault,
/// since when, and the self-check that clears it, instead of being queued
/// and failing (or, before, being chosen without a warning).
pub fn refuse_faulted(st: &AppState, bench_id: &str) -> ApiResult<()> {
    let Some(f) = st
        .runner
        .bench_statuses()
        .into_iter()
        .find(|b| b.id == bench_id)
        .and_then(|b| b.fault)
    else {
        return Ok(());
    };
    Err(Problem::new(
        StatusCode::CONFLICT,
        "bench-faulted",
        "Bench is faulted",
        format!(
            "bench '{bench_id}' is faulted since {}: {}; it takes no part until a self-check passes (POST /api/v1/benches/{bench_id}/self-check)",
            f.since, f.detail
        ),
    )
    .with_extra(json!({"bench": bench_id, "fault": f})))
}

/// `POST /api/v1/benches/{id}/self-check`: queue a self-check job (202 + Location).
#[utoipa::path(post, path = "/api/v1/benches/{id}/self-check", tag = "operations",
    summary = "Queue a self-check of a hardware bench (latency, noise floors, laser at rest, microphone at silence); a pass stores a calibration record and clears a fault.",
    params(("id" = String, Path, description = "Bench id")),
    responses(
        (status = 202, description = "Queued (a job; its log names the calibration record)", body = crate::store::Job,
            headers(("Location" = String, description = "The job"))),
        (status = 404, description = "No such bench"),
        (status = 409, description = "The bench is virtual")))]
pub async fn self_check(State(st): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    let Some(b) = st.cfg.benches.iter().find(|b| b.id == id) else {
        return Err(Problem::not_found("bench", &id));
    };
    if b.kind == BenchKind::Virtual {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "self-check-unsupported",
            "Self-check needs a hardware bench",
            format!("bench '{id}' is virtual: it has no devices to check"),
        ));
    }
    let request = hardware::self_check_request(&id);
    let sha: String = Sha256::digest(request.to_json().as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let job_id = new_id();
    let serial = hardware::self_check_serial(&id);
    let inserted = st
        .store
        .insert_job(
            &job_id,
            &id,
            (&serial, Some("bench-self-check"), None),
            // Before queued measurements of the bench.
            1000,
            &request,
            &sha,
            None,
        )
        .await?;
    let j = match inserted {
        Inserted::New(j) | Inserted::Replayed(j) | Inserted::Conflict(j) => j,
    };
    st.runner
        .events()
        .publish(
            Some(&j.id),
            &JobEvent::Queued {
                state: crate::store::JobState::Queued,
                part_serial: j.part_serial.clone(),
                bench_id: j.bench_id.clone(),
                kind: None,
                type_: Some("self_check"),
                study: None,
            },
        )
        .await?;
    st.runner.wake(&j.bench_id);
    let mut r = (StatusCode::ACCEPTED, Json(&j)).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/jobs/{}", j.id)) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

/// `GET /api/v1/benches/{id}/calibrations`: the bench's self-checks, newest first.
#[utoipa::path(get, path = "/api/v1/benches/{id}/calibrations", tag = "operations",
    summary = "The bench's calibration records (self-checks), newest first (at most 100).",
    params(("id" = String, Path, description = "Bench id")),
    responses(
        (status = 200, description = "Calibration records", body = super::schema::CalibrationList),
        (status = 404, description = "No such bench")))]
pub async fn calibrations(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    if !st.cfg.benches.iter().any(|b| b.id == id) {
        return Err(Problem::not_found("bench", &id));
    }
    let items = st.store.list_calibrations(&id).await?;
    Ok(Json(json!({ "items": items })))
}

/// `GET /api/v1/calibrations/{id}`: one calibration record.
#[utoipa::path(get, path = "/api/v1/calibrations/{id}", tag = "operations",
    summary = "One calibration record; measurements reference it (`calibration_id`, `config.hardware`).",
    params(("id" = String, Path, description = "Calibration record id")),
    responses(
        (status = 200, description = "The record", body = crate::store::hardware::CalibrationRecord),
        (status = 404, description = "Not found")))]
pub async fn calibration(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    match st.store.get_calibration(&id).await? {
        Some(c) => Ok(Json(serde_json::to_value(c).map_err(Problem::internal)?)),
        None => Err(Problem::not_found("calibration record", &id)),
    }
}
