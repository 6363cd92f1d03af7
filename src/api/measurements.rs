//! Measurements: listing, result documents, raw recordings, fits and the
//! headline choice (the diagnostics and plots are served by `derived.rs`,
//! the import by `import.rs`). The numeric work (analyze, diagnose) runs on
//! blocking threads.

use super::problem::{ApiResult, Problem};
use super::reads::Reads;
use super::{page_limit, parse_cursor, AppState, JsonBody, Q};
use crate::diagnose::{self, DiagnoseOptions};
use crate::effects::EffectId;
use crate::identify::{AnalyzeOptions, Method};
use crate::recording::codec::{self, WavStream};
use crate::recording::{Meta, RecordingSet};
use crate::runner::{new_id, FieldError};
use crate::store::corrections::Corrections;
use crate::store::MeasurementInfo;
use crate::store::{FitReads, MeasurementReads, VerdictReads};
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::{json, Value};

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct MeasQuery {
    /// Part serial.
    part: Option<String>,
    /// Job id.
    job: Option<String>,
    /// Only measurements stored at or after this time (RFC 3339).
    #[param(format = DateTime)]
    since: Option<String>,
    /// Page size (1-500, default 50).
    limit: Option<i64>,
    /// `next_cursor` of the previous page.
    cursor: Option<String>,
}

pub async fn list_page(
    store: &impl MeasurementReads,
    part: Option<&str>,
    job: Option<&str>,
    since: Option<&str>,
    limit: Option<i64>,
    cursor: Option<&str>,
) -> ApiResult<Json<Value>> {
    let limit = page_limit(limit)?;
    let before = parse_cursor(cursor)?;
    let since = super::qc::parse_time("since", since)?;
    let items = store
        .list_measurements_since(part, job, since.as_deref(), before, limit)
        .await?;
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|m| m.seq.to_string()))
        .flatten();
    Ok(Json(json!({"items": items, "next_cursor": next})))
}

#[utoipa::path(get, path = "/api/v1/measurements", tag = "measurements",
    summary = "Measurements, newest first.",
    params(MeasQuery),
    responses(
        (status = 200, description = "A page of measurements", body = super::schema::MeasurementPage),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/measurements?part=&job=&limit=&cursor=`: newest first.
pub async fn list<R: Reads>(State(st): State<R>, Q(q): Q<MeasQuery>) -> ApiResult<Json<Value>> {
    list_page(
        st.results(),
        q.part.as_deref(),
        q.job.as_deref(),
        q.since.as_deref(),
        q.limit,
        q.cursor.as_deref(),
    )
    .await
}

/// The result document (`identify::Report`, as `analyze --json` prints it)
/// with the measurement's record under `measurement`.
pub(super) fn document(info: &MeasurementInfo, result: Option<Value>, meta: Value) -> Value {
    let mut doc = match result {
        Some(Value::Object(m)) => Value::Object(m),
        _ => json!({}),
    };
    let mut rec = serde_json::to_value(info).unwrap_or(Value::Null);
    rec["meta"] = meta;
    rec["recordings"] = json!({
        "pre": format!("/api/v1/measurements/{}/recordings/pre.wav", info.id),
        "main": format!("/api/v1/measurements/{}/recordings/main.wav", info.id),
    });
    doc["measurement"] = rec;
    doc
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}", tag = "measurements",
    summary = "The result document (the same as `springbench analyze --json`) plus the measurement record and its QC verdict.",
    params(("id" = String, Path, description = "Measurement id")),
    responses(
        (status = 200, description = "The result", body = super::schema::MeasurementDocumentSchema),
        (status = 404, description = "No such measurement")))]
pub async fn get_one<R: Reads>(
    State(st): State<R>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    let store = st.results();
    let (info, result, meta) = store
        .get_measurement(&id)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", &id))?;
    let mut doc = document(&info, result, meta);
    // The QC verdict of this measurement (with its traceability), null without a recipe.
    doc["measurement"]["verdict"] = serde_json::to_value(
        store
            .measurement_verdict(&id)
            .await?
            .map(crate::store::qc::VerdictRow::shown),
    )
    .unwrap_or(Value::Null);
    // Which stored fit supplies the headline (chosen by a person), null: this result.
    doc["measurement"]["headline"] =
        serde_json::to_value(store.headline_choice(&id).await?).unwrap_or(Value::Null);
    // The correction that voided it (the reason: the audit log), null: not voided.
    doc["measurement"]["void_correction_id"] = json!(store.measurement_void(&id).await?);
    Ok(Json(doc))
}

/// 410 for raw signals the retention policy removed (the results stay).
fn pruned(id: &str, at: &str) -> Problem {
    Problem::new(
        StatusCode::GONE,
        "raw-signals-removed",
        "Raw signals removed",
        format!(
            "the raw signals of measurement '{id}' were removed by the retention policy at {at}; its results are kept"
        ),
    )
}

/// A stored recording, present (not pruned).
async fn stored_recording(
    st: &AppState,
    id: &str,
    which: &str,
) -> ApiResult<crate::store::StoredRecording> {
    let rec = st
        .store
        .get_recording(id, which)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", id))?;
    if let Some(at) = &rec.pruned_at {
        return Err(pruned(id, at));
    }
    Ok(rec)
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}/recordings/{file}", tag = "measurements",
    summary = "A raw recording, float32 WAV (channel 0 displacement m, 1 microphone V, 2 drive V when present), decoded from the stored lossless copy while it is sent.",
    params(("id" = String, Path, description = "Measurement id"),
        ("file" = String, Path, pattern = "^(pre|main)\\.wav$", description = "`pre.wav` or `main.wav`")),
    responses(
        (status = 200, description = "WAV", content_type = "audio/wav", body = Vec<u8>),
        (status = 404, description = "No such measurement or file"),
        (status = 410, description = "The retention policy removed the raw signals (the results are kept)")))]
/// `GET /api/v1/measurements/{id}/recordings/{pre|main}.wav`: float32 WAV,
/// channels 0 displacement (m), 1 microphone (V), 2 drive (V) when present,
/// decoded from the stored FLAC block by block while it is sent.
pub async fn recording(
    State(st): State<AppState>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    let which = match file.as_str() {
        "pre.wav" => "pre",
        "main.wav" => "main",
        _ => {
            return Err(Problem::not_found(
                "recording (use pre.wav or main.wav)",
                &file,
            ))
        }
    };
    let info = st
        .store
        .recording_info(&id, which)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", &id))?;
    if let Some(at) = &info.pruned_at {
        return Err(pruned(&id, at));
    }
    // Read from the store in chunks while it is sent (issue 11: the blob was
    // read whole, +173 MB for a 200 MB import): memory per connection is the
    // reader's buffer, one FLAC block and one batch of output.
    let reader: codec::BlobRead = Box::new(std::io::BufReader::with_capacity(
        DOWNLOAD_READ_BYTES,
        st.store.blob_reader(info.blob),
    ));
    wav_response(reader, info.channel_scale).await
}

/// A stored recording (FLAC or WAV bytes from `reader`) as a float32 WAV
/// response, decoded while it is sent (a station's and the center's).
pub(super) async fn wav_response(
    reader: codec::BlobRead,
    scale: Option<crate::recording::ChannelScale>,
) -> ApiResult<Response> {
    let stream = tokio::task::spawn_blocking(move || WavStream::from_reader(reader, scale))
        .await
        .map_err(Problem::internal)?
        .map_err(|e| Problem::internal(format!("stored recording unreadable: {e}")))?;
    let len = stream.wav_len();
    // Pulled by the connection: one batch is decoded (off the async workers)
    // when the previous one was taken, so a slow client holds no thread.
    let body = axum::body::Body::from_stream(futures_util::stream::unfold(
        Some(stream),
        |st| async move {
            let mut stream = st?;
            let (batch, stream) = tokio::task::spawn_blocking(move || {
                let mut out: Vec<u8> = Vec::new();
                while out.len() < DOWNLOAD_BATCH_BYTES {
                    match stream.next() {
                        Some(Ok(c)) => out.extend_from_slice(&c),
                        // The response is cut (its length was announced).
                        Some(Err(e)) => return (Some(Err(e)), stream),
                        None => break,
                    }
                }
                ((!out.is_empty()).then_some(Ok(out)), stream)
            })
            .await
            .ok()?;
            let failed = matches!(batch, Some(Err(_)));
            let item = batch?.map_err(std::io::Error::other);
            Some((item, (!failed).then_some(stream)))
        },
    ));
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("audio/wav")),
            (header::CONTENT_LENGTH, HeaderValue::from(len)),
        ],
        body,
    )
        .into_response())
}

/// Bytes read from the store per query while a recording is downloaded.
const DOWNLOAD_READ_BYTES: usize = 1 << 20;
/// Bytes of WAV decoded per pull of the response body.
const DOWNLOAD_BATCH_BYTES: usize = 256 << 10;

/// Loads a stored measurement's recording set, its analysis options and its
/// target peak displacement (bench measurements).
async fn load_set(
    st: &AppState,
    id: &str,
) -> ApiResult<(RecordingSet, AnalyzeOptions, Option<f64>)> {
    let (info, _, meta) = st
        .store
        .get_measurement(id)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", id))?;
    // The analysis holds the recording in memory several times over: the
    // length is checked before the bytes are read.
    let max = st.cfg.max_analysis_frames;
    for which in ["pre", "main"] {
        let Some(r) = st.store.recording_info(id, which).await? else {
            continue;
        };
        if r.frames as u64 <= max {
            continue;
        }
        return Err(numeric_failure(
            "Recording too long to analyse",
            format!(
                "the recording has {} frames, more than max_analysis_frames = {max} (configuration)",
                r.frames
            ),
        ));
    }
    let pre = stored_recording(st, id, "pre").await?;
    let main = stored_recording(st, id, "main").await?;
    let opts: AnalyzeOptions = info
        .config
        .get("analysis")
        .and_then(|a| serde_json::from_value(a.clone()).ok())
        .unwrap_or_default();
    let meta: Meta = serde_json::from_value(meta)
        .map_err(|e| Problem::internal(format!("stored meta unreadable: {e}")))?;
    let set = tokio::task::spawn_blocking(move || {
        let pre = codec::decode(&pre.bytes, pre.channel_scale.as_ref())?;
        let main = codec::decode(&main.bytes, main.channel_scale.as_ref())?;
        Ok::<_, crate::recording::RecordingError>(RecordingSet { meta, pre, main })
    })
    .await
    .map_err(Problem::internal)?
    .map_err(|e| Problem::internal(format!("stored recordings unreadable: {e}")))?;
    Ok((set, opts, info.target_xpeak_m))
}

fn numeric_failure(title: &'static str, e: impl std::fmt::Display) -> Problem {
    Problem::new(
        StatusCode::UNPROCESSABLE_ENTITY,
        "analysis-failed",
        title,
        e.to_string(),
    )
}

/// A fit request as accepted (`POST /api/v1/measurements/{id}/fits`).
#[derive(Debug, Clone, PartialEq)]
pub struct FitRequest {
    pub effects: Vec<EffectId>,
    pub order: Option<usize>,
    pub method: Option<Method>,
    /// An explicit effect list: fit exactly that model (else the ladder chooses).
    pub exact: bool,
}

/// The members a fit body may have (anything else is refused).
pub const FIT_FIELDS: [&str; 3] = ["effects", "order", "method"];

/// Validates a fit body: `{"effects": [...], "order": N, "method": "..."}`,
/// one error per bad field.
pub fn fit_request(body: &Value) -> Result<FitRequest, Vec<FieldError>> {
    let Some(obj) = body.as_object() else {
        return Err(vec![FieldError {
            field: "".into(),
            message: "the body must be a JSON object".into(),
        }]);
    };
    let mut errors = vec![];
    for k in obj.keys() {
        if !FIT_FIELDS.contains(&k.as_str()) {
            errors.push(FieldError {
                field: k.clone(),
                message: "unknown field".into(),
            });
        }
    }
    let mut effects = vec![];
    // An explicit list fits exactly that model; "auto" (or no list) lets the
    // diagnostics' ladder choose.
    let mut exact = false;
    match obj.get("effects") {
        None | Some(Value::Null) => {}
        Some(Value::String(a)) if a == "auto" => {}
        Some(Value::Array(a)) => {
            exact = true;
            for (i, e) in a.iter().enumerate() {
                match serde_json::from_value::<EffectId>(e.clone()) {
                    Ok(x) => effects.push(x),
                    Err(_) => errors.push(FieldError {
                        field: format!("effects[{i}]"),
                        message: format!(
                            "unknown effect (effects: {})",
                            EffectId::ALL.map(|e| e.as_str()).join(", ")
                        ),
                    }),
                }
            }
        }
        Some(_) => errors.push(FieldError {
            field: "effects".into(),
            message: "must be a list of effect ids or \"auto\"".into(),
        }),
    }
    let order = match obj.get("order") {
        None | Some(Value::Null) => None,
        Some(v) => match v.as_u64() {
            Some(n) if (1..=crate::runner::job::MAX_ORDER as u64).contains(&n) => Some(n as usize),
            _ => {
                errors.push(FieldError {
                    field: "order".into(),
                    message: format!(
                        "must be an integer from 1 to {}",
                        crate::runner::job::MAX_ORDER
                    ),
                });
                None
            }
        },
    };
    let method = match obj.get("method") {
        None | Some(Value::Null) => None,
        Some(v) => match serde_json::from_value::<Method>(v.clone()) {
            Ok(m) => Some(m),
            Err(_) => {
                errors.push(FieldError {
                    field: "method".into(),
                    message: "must be \"two-signal\" or \"one-signal\"".into(),
                });
                None
            }
        },
    };
    if !errors.is_empty() {
        return Err(errors);
    }
    Ok(FitRequest {
        effects,
        order,
        method,
        exact,
    })
}

#[utoipa::path(post, path = "/api/v1/measurements/{id}/fits", tag = "measurements",
    summary = "Fit the stored recordings again with the given effects and order; every fit is kept, the same fit asked again is returned (200) instead of stored twice.",
    params(("id" = String, Path, description = "Measurement id")),
    request_body(content = super::schema::FitBody, content_type = "application/json"),
    responses(
        (status = 201, description = "The fit", body = crate::store::Fit,
            headers(("Location" = String, description = "The measurement's fits"))),
        (status = 200, description = "The same fit (effects, order, method, software version) was stored before: that fit, no copy", body = crate::store::Fit,
            headers(("Location" = String, description = "The measurement's fits"))),
        (status = 404, description = "No such measurement"),
        (status = 410, description = "The retention policy removed the raw signals"),
        (status = 422, description = "Invalid fields, or the fit failed on this data")))]
/// `POST /api/v1/measurements/{id}/fits` `{"effects": [...], "order": N, "method": "..."}`:
/// fits the stored recordings again with the given effects; every fit is kept.
pub async fn fit(
    State(st): State<AppState>,
    Path(id): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let FitRequest {
        effects,
        order,
        method,
        exact,
    } = fit_request(&body).map_err(Problem::validation)?;
    let (set, mut analyze, target) = load_set(&st, &id).await?;
    if let Some(m) = method {
        analyze.method = m;
    }
    if order.is_some() {
        analyze.order = order;
    }
    let opts = DiagnoseOptions {
        analyze,
        effects,
        exact,
    };
    let request = serde_json::to_value(&opts).map_err(Problem::internal)?;
    // The same model asked for again: the stored fit (200), not another copy.
    if let Some(same) = st
        .store
        .list_fits(&id)
        .await?
        .into_iter()
        .find(|f| f.request == request && f.software_version == crate::VERSION)
    {
        return Ok(fit_response(StatusCode::OK, &id, &same));
    }
    let mut d = tokio::task::spawn_blocking(move || diagnose::diagnose(&set, &opts))
        .await
        .map_err(Problem::internal)?
        .map_err(|e| numeric_failure("Fit failed", e))?;
    // Keff at the target amplitude from this fit's K(x), as the job's result has it.
    crate::qc::set_keff_at_target(&mut d.report, target);
    let result = crate::finite::to_value(&d.report)
        .map_err(|e| numeric_failure("Fit failed", format!("result refused: {e}")))?;
    let fit = st
        .store
        .insert_fit(&new_id(), &id, &request, &result)
        .await?;
    Ok(fit_response(StatusCode::CREATED, &id, &fit))
}

fn fit_response(status: StatusCode, id: &str, fit: &crate::store::Fit) -> Response {
    let mut r = (status, Json(fit)).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/measurements/{id}/fits")) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    r
}

#[utoipa::path(put, path = "/api/v1/measurements/{id}/headline", tag = "measurements",
    summary = "Choose which stored fit supplies the measurement's headline figures (`fit_id` null: its own result); who chose it and when is recorded, every choice is kept.",
    params(("id" = String, Path, description = "Measurement id")),
    request_body(content = super::schema::HeadlineBody, content_type = "application/json"),
    responses(
        (status = 200, description = "The choice", body = crate::store::HeadlineChoice),
        (status = 404, description = "No such measurement"),
        (status = 422, description = "`fit_id` is not a fit of this measurement")))]
pub async fn choose_headline(
    State(st): State<AppState>,
    axum::Extension(caller): axum::Extension<super::auth::Caller>,
    Path(id): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Json<crate::store::HeadlineChoice>> {
    if st.store.get_measurement(&id).await?.is_none() {
        return Err(Problem::not_found("measurement", &id));
    }
    let obj = body
        .as_object()
        .ok_or_else(|| Problem::field("", "the body must be a JSON object"))?;
    if let Some(k) = obj.keys().find(|k| k.as_str() != "fit_id") {
        return Err(Problem::field(k, "unknown field"));
    }
    let fit_id = match obj.get("fit_id") {
        Some(Value::Null) => None,
        Some(Value::String(f)) => Some(f.as_str()),
        _ => {
            return Err(Problem::field(
                "fit_id",
                "must be the id of a fit of this measurement, or null for its own result",
            ))
        }
    };
    if let Some(f) = fit_id {
        if !st.store.list_fits(&id).await?.iter().any(|x| x.id == f) {
            return Err(Problem::field(
                "fit_id",
                format!("'{f}' is not a fit of measurement '{id}'"),
            ));
        }
    }
    Ok(Json(
        st.store
            .choose_headline(&id, fit_id, caller.0.as_deref())
            .await?,
    ))
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}/fits", tag = "measurements",
    summary = "The fits of a measurement, oldest first.",
    params(("id" = String, Path, description = "Measurement id")),
    responses(
        (status = 200, description = "Fits", body = super::schema::FitList),
        (status = 404, description = "No such measurement")))]
pub async fn list_fits<R: Reads>(
    State(st): State<R>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    if st.results().get_measurement(&id).await?.is_none() {
        return Err(Problem::not_found("measurement", &id));
    }
    let items = st.results().list_fits(&id).await?;
    Ok(Json(json!({"items": items})))
}

pub(super) async fn diagnose_stored(
    st: &AppState,
    id: &str,
) -> ApiResult<(RecordingSet, diagnose::Diagnosis)> {
    let (set, analyze, _) = load_set(st, id).await?;
    let opts = DiagnoseOptions {
        analyze,
        effects: vec![],
        exact: false,
    };
    tokio::task::spawn_blocking(move || {
        let d = diagnose::diagnose(&set, &opts);
        d.map(|d| (set, d))
    })
    .await
    .map_err(Problem::internal)?
    .map_err(|e| numeric_failure("Diagnostics failed", e))
}
