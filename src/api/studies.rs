//! The memory's studies (issue 33, decision 0121): submit an added-mass
//! study or a recovery measurement as a job of its bench, read its state
//! (`awaiting_operator` with the instruction while the operator adds the
//! mass) and result, confirm the operator's step.

use super::problem::{ApiResult, Problem};
use super::{AppState, JsonBody};
use crate::diagnose::studies::{Study, StudyResult, StudyState};
use crate::job::{FieldError, JobProblem, StoredRequest};
use crate::runner::events::StudyStep;
use crate::runner::{new_id, JobEvent};
use crate::store::{Inserted, JobState};
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use sha2::{Digest, Sha256};

/// A study as the API shows it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct StudyView {
    /// The study's job id.
    pub id: String,
    /// `added_mass` or `recovery`.
    pub kind: String,
    /// The job's state (a study waiting for the operator is `running`).
    pub job_state: JobState,
    /// The study's own state; null while its job is queued.
    pub state: Option<StudyState>,
    /// What the operator must do (state `awaiting_operator`).
    pub instruction: Option<String>,
    /// The result (state `succeeded`), SI units in every member's name.
    pub result: Option<StudyResult>,
    /// Why the job failed.
    #[schema(value_type = Option<serde_json::Value>)]
    pub problem: Option<JobProblem>,
    /// Who confirmed the operator's step.
    pub confirmed_by: Option<String>,
    /// The request as accepted.
    pub request: Study,
}

async fn view(st: &AppState, id: &str) -> ApiResult<StudyView> {
    let job = st
        .store
        .get_job(id)
        .await?
        .ok_or_else(|| Problem::not_found("study", id))?;
    let Ok(StoredRequest::Study(request)) = job.request.read() else {
        return Err(Problem::not_found("study", id));
    };
    let row = st.store.get_study(id).await?;
    Ok(StudyView {
        id: job.id.clone(),
        kind: request.kind().to_string(),
        job_state: job.state,
        state: row.as_ref().map(|r| r.state),
        instruction: row.as_ref().and_then(|r| r.instruction.clone()),
        result: row.as_ref().and_then(|r| r.result.clone()),
        problem: job.problem.clone(),
        confirmed_by: row.and_then(|r| r.confirmed_by),
        request: request.clone(),
    })
}

#[utoipa::path(post, path = "/api/v1/studies", tag = "jobs",
    summary = "Submit a study of the part's memory (issue 33): `added_mass` (the part, then the part with a known mass added to the slide after the operator confirms) or `recovery` (a large excitation, then small-signal probes).",
    request_body(content = Study, content_type = "application/json",
        example = json!({"bench": "virtual-1", "part_serial": "SN-0001", "moving_mass_kg": 0.05,
            "plan": {"added_mass": {"added_mass_kg": 0.02, "level_m": 0.004}}})),
    responses(
        (status = 202, description = "Queued as a job of its bench", body = StudyView,
            headers(("Location" = String, description = "The study"))),
        (status = 400, description = "Unreadable body"),
        (status = 413, description = "Body too large"),
        (status = 422, description = "Invalid fields, one message each in `errors` naming the field"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/studies`.
pub async fn submit(State(st): State<AppState>, JsonBody(body): JsonBody) -> ApiResult<Response> {
    st.store.check_space(st.cfg.min_free_bytes)?;
    let (study, mut errors) = crate::job::parse_lenient::<Study>(&body);
    let Some(study) = study else {
        return Err(Problem::validation(errors));
    };
    errors.extend(
        study
            .check()
            .into_iter()
            .map(|e| FieldError::new(e.field, e.message)),
    );
    if !st.cfg.benches.iter().any(|b| b.id == study.bench) {
        errors.push(FieldError::new(
            "bench",
            format!("no bench '{}' on this station", study.bench),
        ));
    }
    if let Some(p) = &study.preset {
        if let Err(e) = crate::physics::preset(p) {
            errors.push(FieldError::new("preset", e));
        }
    }
    if !errors.is_empty() {
        return Err(Problem::validation(errors));
    }
    super::benches::refuse_faulted(&st, &study.bench)?;
    let sha: String = Sha256::digest(body.to_string().as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let id = new_id();
    let request = StoredRequest::Study(study.clone());
    let inserted = st
        .store
        .insert_job(
            &id,
            &study.bench,
            (&study.part_serial, None, None),
            0,
            &request,
            &sha,
            None,
        )
        .await?;
    let Inserted::New(j) = inserted else {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "study-conflict",
            "Study not queued",
            "the job could not be inserted as a new one",
        ));
    };
    st.runner
        .events()
        .publish(
            Some(&j.id),
            &JobEvent::Queued {
                state: JobState::Queued,
                part_serial: j.part_serial.clone(),
                bench_id: j.bench_id.clone(),
                kind: None,
                type_: None,
                study: Some(study.kind()),
            },
        )
        .await?;
    st.runner.wake(&j.bench_id);
    let v = view(&st, &j.id).await?;
    let mut r = (StatusCode::ACCEPTED, Json(v)).into_response();
    if let Ok(h) = HeaderValue::from_str(&format!("/api/v1/studies/{}", j.id)) {
        r.headers_mut().insert(header::LOCATION, h);
    }
    Ok(r)
}

#[utoipa::path(get, path = "/api/v1/studies/{id}", tag = "jobs",
    summary = "A study: its state, the operator's instruction while it waits, its result.",
    params(("id" = String, Path, description = "The study's job id")),
    responses(
        (status = 200, description = "The study", body = StudyView),
        (status = 404, description = "No such study")))]
/// `GET /api/v1/studies/{id}`.
pub async fn get_one(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<StudyView>> {
    Ok(Json(view(&st, &id).await?))
}

#[utoipa::path(post, path = "/api/v1/studies/{id}/confirm", tag = "jobs",
    summary = "The operator did what the instruction says (added the mass): the study goes on.",
    params(("id" = String, Path, description = "The study's job id")),
    responses(
        (status = 200, description = "Confirmed; the study measures again", body = StudyView),
        (status = 404, description = "No such study"),
        (status = 409, description = "The study is not waiting for the operator (`detail` names its state)")))]
/// `POST /api/v1/studies/{id}/confirm`.
pub async fn confirm(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    Path(id): Path<String>,
) -> ApiResult<Json<StudyView>> {
    let before = view(&st, &id).await?;
    if !st.store.confirm_study(&id, caller.0.as_deref()).await? {
        let state = before
            .state
            .map_or("queued".to_string(), |s| s.as_str().to_string());
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "study-not-waiting",
            "The study is not waiting for the operator",
            format!("study {id} is {state}, not awaiting_operator"),
        ));
    }
    st.runner
        .events()
        .publish(
            Some(&id),
            &JobEvent::StudyConfirmed {
                state: StudyStep::Confirmed,
                by: caller.0.clone(),
            },
        )
        .await?;
    Ok(Json(view(&st, &id).await?))
}
