//! Stimulus files (issue 32, decision 0144): a WAV file uploaded to the
//! station for a long-term test to play as a loop (`stimulus.kind` `wav`,
//! `stimulus.wav_id`). Kept as sent, named by the SHA-256 of its bytes.

use super::problem::{ApiResult, Problem};
use super::AppState;
use crate::store::stimuli::{NewStimulus, StimulusInfo};
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

pub use crate::recording::stimulus::{decode, drive_loop, MAX_STIMULUS_BYTES};

/// `POST /api/v1/stimuli` query.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
pub struct UploadQuery {
    /// A name for people (the file's name); not used by the daemon.
    pub name: Option<String>,
}

#[utoipa::path(post, path = "/api/v1/stimuli", tag = "jobs",
    summary = "Upload a WAV file (mono, 2 to 600 s, at most 32 MiB) for a long-term test to play as a loop (stimulus.kind \"wav\", stimulus.wav_id = the answer's id). The body is the file's bytes; being not JSON, the request needs an Authorization: Bearer header (the cross-site guard).",
    params(UploadQuery),
    request_body(content = Vec<u8>, content_type = "audio/wav"),
    responses(
        (status = 201, description = "Stored", body = StimulusInfo,
            headers(("Location" = String, description = "The stimulus"))),
        (status = 200, description = "The same bytes were uploaded before: that stimulus", body = StimulusInfo),
        (status = 413, description = "Larger than 32 MiB"),
        (status = 422, description = "Not a usable WAV file; `errors[0].field` is `body` (not a WAV, more than one channel, shorter than 2 s or longer than 600 s, a sample not finite, silent) or `name`"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/stimuli`.
pub async fn upload(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    Query(q): Query<UploadQuery>,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<Response> {
    let bytes = body.map_err(|e| match e {
        BytesRejection::FailedToBufferBody(_) => Problem::too_large(MAX_STIMULUS_BYTES),
        e => Problem::bad_request(e.body_text()),
    })?;
    st.store.check_space(st.cfg.min_free_bytes)?;
    if let Some(n) = &q.name {
        if n.len() > 200 || n.chars().any(char::is_control) {
            return Err(Problem::field(
                "name",
                "at most 200 characters, no control characters",
            ));
        }
    }
    let d = decode(&bytes).map_err(|m| Problem::field("body", m))?;
    drive_loop(&d.samples).map_err(|m| Problem::field("body", m))?;
    let id = super::hex(&Sha256::digest(&bytes));
    let info = NewStimulus {
        id: &id,
        uploaded_by: caller.0.as_deref(),
        file_name: q.name.as_deref(),
        sample_rate_hz: d.sample_rate_hz,
        frames: d.samples.len() as u64,
        bits: d.bits,
        sample_format: d.sample_format,
        rms_fs: d.rms_fs(),
        peak_fs: d.peak_fs(),
    };
    let (stored, new) = st.store.put_stimulus(&info, &bytes).await?;
    let status = if new {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    let mut res = (status, Json(&stored)).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/stimuli/{}", stored.id)) {
        res.headers_mut().insert(header::LOCATION, v);
    }
    Ok(res)
}

/// `GET /api/v1/stimuli`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct StimulusList {
    pub items: Vec<StimulusInfo>,
}

#[utoipa::path(get, path = "/api/v1/stimuli", tag = "jobs",
    summary = "The station's uploaded stimulus files, newest first (at most 500).",
    responses((status = 200, description = "The list", body = StimulusList)))]
/// `GET /api/v1/stimuli`.
pub async fn list(State(st): State<AppState>) -> ApiResult<Json<StimulusList>> {
    Ok(Json(StimulusList {
        items: st.store.list_stimuli(500).await?,
    }))
}

#[utoipa::path(get, path = "/api/v1/stimuli/{id}", tag = "jobs",
    summary = "One uploaded stimulus file: what the daemon read from it.",
    params(("id" = String, Path, description = "The SHA-256 of the file's bytes")),
    responses(
        (status = 200, description = "The stimulus", body = StimulusInfo),
        (status = 404, description = "No such stimulus")))]
/// `GET /api/v1/stimuli/{id}`.
pub async fn get_one(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<StimulusInfo>> {
    st.store
        .stimulus(&id)
        .await?
        .map(Json)
        .ok_or_else(|| Problem::not_found("stimulus", &id))
}
