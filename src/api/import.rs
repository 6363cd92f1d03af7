//! `POST /api/v1/measurements` (multipart import), bounded (issue 11):
//!
//! - the recordings (`pre`, `main`) are spooled to files in the data
//!   directory while they arrive (`<data_dir>/tmp/`, removed afterwards),
//!   hashed on the way; the small fields are capped at `max_json_bytes`;
//! - an expensive-work slot (`http.max_expensive`) is taken only once the
//!   body is on disk, so slow uploads do not hold it;
//! - `Idempotency-Key` works as for jobs: the same key with the same fields
//!   answers the stored measurement (200, `Idempotent-Replayed: true`), with
//!   other fields 409 `idempotency-conflict` (decision 0021);
//! - nothing non-finite is stored ([`crate::finite`]).

use super::problem::{ApiResult, Problem};
use super::AppState;
use crate::identify::{self, AnalyzeOptions, Method};
use crate::recording::stream::{self, Streamed};
use crate::recording::{Meta, RecordingSet};
use crate::runner::{job::valid_serial, new_id, FieldError};
use crate::store::MeasurementReads;
use crate::store::{ImportInserted, NewMeasurement, RecordingFile};
use axum::extract::multipart::{MultipartError, MultipartRejection};
use axum::extract::{Multipart, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tokio::io::AsyncWriteExt;

/// The form fields an import may have (anything else is refused).
pub const FIELDS: [&str; 8] = [
    "meta", "pre", "main", "serial", "kind", "notes", "method", "order",
];
/// Fields spooled to disk; the others are kept in memory (capped).
const FILES: [&str; 2] = ["pre", "main"];

/// A spooled part, removed when dropped.
pub struct Spool(PathBuf);

impl Spool {
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Spool {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The import's fields as received.
#[derive(Default)]
struct Received {
    small: BTreeMap<String, Vec<u8>>,
    files: BTreeMap<String, Spool>,
    /// SHA-256 per field name (the last field of a name counts).
    digests: BTreeMap<String, [u8; 32]>,
    errors: Vec<FieldError>,
}

impl Received {
    /// The import request's identity: SHA-256 over the fields by name (not
    /// the multipart bytes, whose boundary a retry may change).
    fn sha256(&self) -> String {
        let mut h = Sha256::new();
        for (k, d) in &self.digests {
            h.update((k.len() as u64).to_le_bytes());
            h.update(k.as_bytes());
            h.update(d);
        }
        super::hex(&h.finalize())
    }

    fn text(&self, k: &str) -> Option<String> {
        self.small
            .get(k)
            .map(|b| String::from_utf8_lossy(b).trim().to_string())
    }
}

fn multipart_problem(e: MultipartError, limit: usize) -> Problem {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        Problem::too_large(limit)
    } else {
        Problem::bad_request(format!("multipart body unreadable: {}", e.body_text()))
    }
}

/// The `Idempotency-Key` header (1-255 visible ASCII characters).
pub fn idempotency_key(headers: &HeaderMap) -> ApiResult<Option<String>> {
    match headers.get("idempotency-key") {
        None => Ok(None),
        Some(v) => match v.to_str() {
            Ok(s) if !s.is_empty() && s.len() <= 255 => Ok(Some(s.to_string())),
            _ => Err(Problem::bad_request(
                "Idempotency-Key must be 1-255 visible ASCII characters",
            )),
        },
    }
}

/// Reads the multipart body: recordings to files under `dir`, small fields
/// into memory (at most `small_limit` bytes each).
async fn receive(
    mut mp: Multipart,
    dir: &Path,
    limit: usize,
    small_limit: usize,
) -> ApiResult<Received> {
    let mut got = Received::default();
    while let Some(mut f) = mp
        .next_field()
        .await
        .map_err(|e| multipart_problem(e, limit))?
    {
        let name = f.name().unwrap_or("").to_string();
        let known = FIELDS.contains(&name.as_str());
        if !known {
            got.errors.push(FieldError {
                field: name.clone(),
                message: "unknown field".into(),
            });
        }
        let mut h = Sha256::new();
        if known && FILES.contains(&name.as_str()) {
            let spool = Spool(dir.join(format!("import-{}-{name}", new_id())));
            let mut file = tokio::fs::File::create(spool.path())
                .await
                .map_err(|e| Problem::internal(format!("spooling the import: {e}")))?;
            while let Some(chunk) = f.chunk().await.map_err(|e| multipart_problem(e, limit))? {
                h.update(&chunk);
                file.write_all(&chunk)
                    .await
                    .map_err(|e| Problem::internal(format!("spooling the import: {e}")))?;
            }
            file.flush()
                .await
                .map_err(|e| Problem::internal(format!("spooling the import: {e}")))?;
            got.files.insert(name.clone(), spool);
        } else {
            let mut buf = Vec::new();
            let mut too_long = false;
            while let Some(chunk) = f.chunk().await.map_err(|e| multipart_problem(e, limit))? {
                h.update(&chunk);
                if buf.len() + chunk.len() > small_limit {
                    too_long = true;
                } else if known {
                    buf.extend_from_slice(&chunk);
                }
            }
            if too_long && known {
                got.errors.push(FieldError {
                    field: name.clone(),
                    message: format!("longer than {small_limit} bytes"),
                });
            }
            if known {
                got.small.insert(name.clone(), buf);
            }
        }
        got.digests.insert(name, h.finalize().into());
    }
    Ok(got)
}

/// meta.json's field of a validation message (`meta.channel_scale.drive`),
/// for the per-field problem.
fn meta_field(msg: &str) -> String {
    let first = msg.split_whitespace().next().unwrap_or("");
    let known = [
        "moving_mass_kg",
        "sample_rate_hz",
        "channel_scale.",
        "channels",
    ];
    if known.iter().any(|k| first.starts_with(k)) {
        format!("meta.{}", first.trim_end_matches(':'))
    } else {
        "meta".into()
    }
}

/// What an import stores, prepared off the runtime from the spooled files.
pub struct Prepared {
    /// meta.json of the stored (standard) layout.
    pub meta: Meta,
    pub pre: (Streamed, Spool),
    pub main: (Streamed, Spool),
    pub analysis: Result<identify::Report, String>,
}

/// Reads, checks and stores an import block by block: the meta.json text and
/// the two spooled WAV files become stored recordings (files under `dir`,
/// [`crate::recording::stream`]); per-field errors. The analysis runs on
/// recordings of at most `max_frames` frames (it holds them in memory);
/// longer ones are stored with the reason in `analysis`.
pub fn prepare(
    meta_json: &[u8],
    pre_wav: &Path,
    main_wav: &Path,
    dir: &Path,
    opts: &AnalyzeOptions,
    max_frames: u64,
) -> Result<Prepared, FieldError> {
    let fe = |field: &str, message: String| FieldError {
        field: field.into(),
        message,
    };
    let text = std::str::from_utf8(meta_json).map_err(|_| fe("meta", "not UTF-8 text".into()))?;
    let meta = crate::recording::parse_meta(text).map_err(|m| fe(&meta_field(&m), m))?;
    let store = |field: &str, wav: &Path| {
        let out = Spool(dir.join(format!("stored-{}-{field}", new_id())));
        let scratch = Spool(dir.join(format!("scratch-{}-{field}", new_id())));
        stream::store_wav(wav, &meta, out.path(), scratch.path())
            .map(|s| (s, out))
            .map_err(|e| fe(field, e.to_string()))
    };
    let pre = store("pre", pre_wav)?;
    let main = store("main", main_wav)?;
    if pre.0.sample_rate_hz != main.0.sample_rate_hz {
        return Err(fe(
            "meta.sample_rate_hz",
            format!(
                "pre.wav is sampled at {} Hz, main.wav at {} Hz",
                pre.0.sample_rate_hz, main.0.sample_rate_hz
            ),
        ));
    }
    let mut stored_meta = Meta {
        channel_scale: None,
        ..Meta::standard(meta.moving_mass_kg, main.0.sample_rate_hz)
    };
    stored_meta.long_term = meta.long_term.clone();
    stored_meta.extra = meta.extra.clone();
    stored_meta.channels.drive = meta.channels.drive.map(|_| 2);
    let longest = [("pre", pre.0.frames), ("main", main.0.frames)]
        .into_iter()
        .max_by_key(|x| x.1)
        .unwrap_or(("main", 0));
    let analysis = if longest.1 > max_frames {
        Err(format!(
            "not analysed: {} has {} frames, more than max_analysis_frames = {max_frames} (configuration); the recordings are stored",
            longest.0, longest.1
        ))
    } else {
        let read = |p: &Path| {
            let f = std::fs::File::open(p).map_err(|e| e.to_string())?;
            crate::recording::read_signals(std::io::BufReader::new(f), &meta)
                .map_err(|e| e.to_string())
        };
        (|| {
            let set = RecordingSet::settled(meta.clone(), read(pre_wav)?, read(main_wav)?)
                .map_err(|e| e.to_string())?;
            identify::analyze(&set, opts).map_err(|e| e.to_string())
        })()
    };
    Ok(Prepared {
        meta: stored_meta,
        pre,
        main,
        analysis,
    })
}

#[utoipa::path(post, path = "/api/v1/measurements", tag = "measurements",
    summary = "Import an external recording set (meta.json, pre.wav, main.wav); analysed and stored like a bench measurement.",
    params(("Idempotency-Key" = Option<String>, Header, max_length = 255,
        description = "Same key and same fields give the stored measurement (200, header `Idempotent-Replayed`); other fields give 409.")),
    request_body(content = super::schema::ImportForm, content_type = "multipart/form-data"),
    responses(
        (status = 201, description = "Stored (an analysis that failed is kept with `measurement.analysis_error`)",
            body = super::schema::MeasurementDocumentSchema,
            headers(("Location" = String, description = "The measurement"))),
        (status = 200, description = "Replayed (same Idempotency-Key and fields)",
            body = super::schema::MeasurementDocumentSchema,
            headers(("Location" = String, description = "The measurement"),
                ("Idempotent-Replayed" = String, description = "`true`"))),
        (status = 400, description = "Unreadable multipart body or Idempotency-Key"),
        (status = 409, description = "Idempotency-Key used before with other fields (`measurement_id` names its measurement)"),
        (status = 413, description = "Upload too large"),
        (status = 422, description = "Invalid fields or recordings, one message each in `errors`"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/measurements` (multipart): fields `meta` (meta.json), `pre`
/// and `main` (WAV), `serial` (or `"part_serial"` in meta), optional `kind`,
/// `notes`, `method`, `order`. Analysed and stored like a bench measurement;
/// 201 with the result document (an analysis that fails is stored with its
/// `analysis_error`, the recordings are kept for a later fit).
pub async fn import(
    State(st): State<AppState>,
    headers: HeaderMap,
    multipart: Result<Multipart, MultipartRejection>,
) -> ApiResult<Response> {
    let limit = st.cfg.max_upload_bytes;
    let key = idempotency_key(&headers)?;
    st.store.check_space(st.cfg.min_free_bytes)?;
    let mp = multipart.map_err(|e| {
        if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
            Problem::too_large(limit)
        } else {
            Problem::bad_request(e.body_text())
        }
    })?;
    let dir = st.cfg.data_dir.join("tmp");
    tokio::fs::create_dir_all(&dir)
        .await
        .map_err(|e| Problem::internal(format!("spool directory {}: {e}", dir.display())))?;
    let mut got = receive(mp, &dir, limit, st.cfg.max_json_bytes).await?;
    let sha = got.sha256();
    if let Some(k) = &key {
        if let Some((mid, s)) = st.store.import_by_key(k).await? {
            return answer_key(&st, &mid, s == sha).await;
        }
    }
    for k in ["meta", "pre", "main"] {
        if !got.small.contains_key(k) && !got.files.contains_key(k) {
            got.errors.push(FieldError {
                field: k.into(),
                message: "required".into(),
            });
        }
    }
    let meta_serial = got
        .small
        .get("meta")
        .and_then(|m| serde_json::from_slice::<Value>(m).ok())
        .and_then(|m| {
            m.get("part_serial")
                .and_then(|s| s.as_str())
                .map(String::from)
        });
    let serial = got.text("serial").or(meta_serial);
    match &serial {
        None => got.errors.push(FieldError {
            field: "serial".into(),
            message: "required (the part's serial number)".into(),
        }),
        Some(s) if !valid_serial(s) => got.errors.push(FieldError {
            field: "serial".into(),
            message: crate::runner::job::SERIAL_RULE.into(),
        }),
        _ => {}
    }
    let mut opts = AnalyzeOptions {
        method: st.cfg.defaults.method,
        order: st.cfg.defaults.order,
    };
    if let Some(m) = got.text("method") {
        match serde_json::from_value::<Method>(json!(m)) {
            Ok(m) => opts.method = m,
            Err(_) => got.errors.push(FieldError {
                field: "method".into(),
                message: "must be two-signal or one-signal".into(),
            }),
        }
    }
    if let Some(o) = got.text("order") {
        match o.parse::<usize>() {
            Ok(n) if (1..=crate::runner::job::MAX_ORDER).contains(&n) => opts.order = Some(n),
            _ => got.errors.push(FieldError {
                field: "order".into(),
                message: format!(
                    "must be an integer from 1 to {}",
                    crate::runner::job::MAX_ORDER
                ),
            }),
        }
    }
    if !got.errors.is_empty() {
        return Err(Problem::validation(got.errors));
    }
    let serial = serial.unwrap_or_default();
    let kind = got.text("kind").filter(|s| !s.is_empty());
    let notes = got.text("notes").filter(|s| !s.is_empty());
    let meta_json = got.small.remove("meta").unwrap_or_default();
    let (Some(pre), Some(main)) = (got.files.remove("pre"), got.files.remove("main")) else {
        return Err(Problem::field("pre", "required"));
    };
    // The body is on disk: now the expensive part, one slot of http.max_expensive.
    let slots = super::derived::expensive_slots(st.cfg.http.max_expensive);
    let _slot = slots.acquire().await.map_err(Problem::internal)?;
    let opts2 = opts.clone();
    let max_frames = st.cfg.max_analysis_frames;
    let p = tokio::task::spawn_blocking(move || {
        let p = prepare(
            &meta_json,
            pre.path(),
            main.path(),
            &dir,
            &opts2,
            max_frames,
        );
        drop((pre, main));
        p
    })
    .await
    .map_err(Problem::internal)?
    .map_err(|e| Problem::validation(vec![e]))?;
    let (result, analysis_error) = match p.analysis.and_then(crate::qc::level::storable) {
        Ok(r) => (Some(crate::store::Doc::Made(r)), None),
        Err(e) => (None, Some(e)),
    };
    let id = new_id();
    let recordings = vec![
        recording_file("pre", &p.pre),
        recording_file("main", &p.main),
    ];
    let inserted = st
        .store
        .insert_import(
            (&serial, kind.as_deref(), notes.as_deref()),
            recordings,
            NewMeasurement {
                id: id.clone(),
                part_serial: serial.clone(),
                job_id: None,
                source: "import",
                bench_id: None,
                config: crate::job::MeasurementConfig {
                    analysis: Some(opts),
                    ..Default::default()
                },
                meta: match crate::finite::check(&p.meta) {
                    Ok(()) => crate::store::Doc::Made(p.meta),
                    Err(e) => return Err(Problem::field("meta", e.to_string())),
                },
                result,
                analysis_error,
                target_xpeak_m: None,
                repeat_index: None,
                level_index: None,
                pre: 0,
                main: 1,
            },
            key.as_deref().map(|k| (k, sha.as_str())),
        )
        .await?;
    match inserted {
        ImportInserted::New => {}
        ImportInserted::Replayed(mid) => return answer_key(&st, &mid, true).await,
        ImportInserted::Conflict(mid) => return answer_key(&st, &mid, false).await,
    }
    let _ = st
        .runner
        .events()
        .publish(
            None,
            &crate::runner::JobEvent::MeasurementCreated {
                measurement_id: id.clone(),
                part_serial: serial.clone(),
                source: "import",
            },
        )
        .await;
    document_response(&st, &id, StatusCode::CREATED, false).await
}

fn recording_file<'a>(kind: &'static str, (s, f): &'a (Streamed, Spool)) -> RecordingFile<'a> {
    RecordingFile {
        kind,
        sample_rate_hz: s.sample_rate_hz,
        frames: s.frames as i64,
        path: f.path(),
        channel_scale: s.channel_scale,
    }
}

/// The answer to a known key: the stored measurement (same fields) or 409.
async fn answer_key(st: &AppState, mid: &str, same: bool) -> ApiResult<Response> {
    if same {
        document_response(st, mid, StatusCode::OK, true).await
    } else {
        Err(Problem::new(
            StatusCode::CONFLICT,
            "idempotency-conflict",
            "Idempotency key reused",
            "this Idempotency-Key was used before with other import fields",
        )
        .with_extra(json!({"measurement_id": mid})))
    }
}

async fn document_response(
    st: &AppState,
    id: &str,
    status: StatusCode,
    replayed: bool,
) -> ApiResult<Response> {
    let (info, result, meta) = st
        .store
        .get_measurement(id)
        .await?
        .ok_or_else(|| Problem::internal("imported measurement vanished"))?;
    let mut r = (
        status,
        Json(super::measurements::document(&info, result, meta)),
    )
        .into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/measurements/{id}")) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    if replayed {
        r.headers_mut()
            .insert("idempotent-replayed", HeaderValue::from_static("true"));
    }
    Ok(r)
}
