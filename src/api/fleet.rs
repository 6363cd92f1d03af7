//! The fleet role's HTTP API (issue 20): the daemon started with
//! `database = "postgres://..."` and `benches = []` serves the fleet's
//! center read-only: the stations (last contact, software, bench states,
//! backlog, gaps), every station's parts, measurements and verdicts with
//! the station in every row, SPC of a recipe across stations and per
//! station (the station as a subgroup), yield per station and day, and the
//! audit trail of corrections. Bad query parameters get problem+json naming
//! the parameter. The reads go through the results interface and
//! `springbench_store_pg::PgStore`'s center queries. It also serves the web
//! UI and the station's read routes its parts, measurement, compare and QC
//! views use, with the station's own handlers over the center's store
//! ([`station_reads`], decision 0066).

use super::problem::{ApiResult, Problem};
use crate::config::Config;
use crate::store::corrections::AuditEntry;
use crate::store::corrections::Corrections;
use crate::store::fleet::CenterIngest;
use crate::store::fleet::StationStatus;
use crate::store::results::{
    MeasurementInfo, MeasurementReads, Part, PartReads, RecipeReads, RecipeRow, VerdictReads,
    VerdictRow,
};
use axum::extract::{Path, Query, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, MethodRouter};
use axum::{Json, Router};
use serde::Serialize;
use serde_json::{json, Value};
use springbench_core::qc::spc::Spc;
use springbench_store_pg::{PgStore, SpcGroup, YieldDay};
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

mod ingest;
mod longterm;
mod recipes;
pub use ingest::{ItemsRequest, ITEM_REFUSED};
pub use recipes::*;

#[derive(Clone)]
pub struct FleetState {
    pub store: PgStore,
    pub cfg: Arc<Config>,
    /// Heavy SPC queries running now, per client (token name, or "open").
    pub spc_running: Arc<std::sync::Mutex<HashMap<String, usize>>>,
}

impl FleetState {
    pub fn new(store: PgStore, cfg: Arc<Config>) -> FleetState {
        FleetState {
            store,
            cfg,
            spc_running: Arc::default(),
        }
    }
}

/// The most verdicts one listing answers (`last`, a page's `limit`): 10 000
/// verdicts are about 7 MB of JSON (issue 36: `last=1000000` took the
/// center to 6.3 GB).
pub const VERDICTS_MAX: i64 = 10_000;

/// The fleet role's routes that write: recipes authored at the center
/// (decision 0106), each with its role ([`recipes::authorised`]).
fn authoring() -> Vec<(&'static str, &'static str, MethodRouter<FleetState>)> {
    use axum::routing::post;
    vec![
        (
            "post",
            "/api/v1/fleet/recipe-proposals",
            post(recipes::propose),
        ),
        (
            "post",
            "/api/v1/fleet/recipe-proposals/{id}/approve",
            post(recipes::approve),
        ),
        (
            "post",
            "/api/v1/fleet/recipe-proposals/{id}/reject",
            post(recipes::reject),
        ),
        (
            "post",
            "/api/v1/fleet/recipes/{name}/retire",
            post(recipes::retire),
        ),
    ]
}

/// (method, path) of the fleet role's writing routes.
pub fn write_paths() -> Vec<(&'static str, &'static str)> {
    authoring().into_iter().map(|(m, p, _)| (m, p)).collect()
}

/// True for a path of [`authoring`] (a POST there is not the readers' 405).
fn is_authoring(path: &str) -> bool {
    let rest = |p: &str| path.strip_prefix(p);
    path == "/api/v1/fleet/recipe-proposals"
        || rest("/api/v1/fleet/recipe-proposals/")
            .is_some_and(|r| r.ends_with("/approve") || r.ends_with("/reject"))
        || rest("/api/v1/fleet/recipes/").is_some_and(|r| r.ends_with("/retire"))
}

/// The fleet role's API routes, every one a GET (the OpenAPI document
/// describes these; its test compares them with the document).
fn table() -> Vec<(&'static str, MethodRouter<FleetState>)> {
    vec![
        ("/api/v1/fleet/stations", get(stations)),
        ("/api/v1/fleet/parts", get(parts)),
        ("/api/v1/fleet/parts/{serial}", get(part)),
        ("/api/v1/fleet/measurements", get(measurements)),
        ("/api/v1/fleet/measurements/{id}", get(measurement)),
        ("/api/v1/fleet/recipes", get(recipes)),
        ("/api/v1/fleet/recipes/{name}/verdicts", get(verdicts)),
        ("/api/v1/fleet/recipes/{name}/spc", get(spc)),
        ("/api/v1/fleet/recipes/{name}/yield", get(yield_per_day)),
        ("/api/v1/fleet/audit", get(audit)),
        ("/api/v1/fleet/refusals", get(refusals)),
        ("/api/v1/fleet/recipe-proposals", get(recipes::list)),
        ("/api/v1/fleet/recipe-proposals/{id}", get(recipes::get_one)),
    ]
}

/// The paths of the fleet role's API (all GET; `/healthz` apart).
pub fn paths() -> Vec<&'static str> {
    table().into_iter().map(|(p, _)| p).collect()
}

impl super::reads::Reads for FleetState {
    type Store = PgStore;
    fn results(&self) -> &PgStore {
        &self.store
    }
    /// The chart's SPC reads every verdict of its window: 1.5 s for 8 000
    /// at the center (docs/fleet.md), so at most 10 000 here; the fleet's
    /// own SPC (in SQL, no points) answers larger windows.
    const SPC_WINDOW_MAX: i64 = 10_000;
    const SPC_WINDOW_HINT: &'static str = " (at the fleet's center; GET /api/v1/fleet/recipes/{name}/spc gives the figures of larger windows, without chart points)";
}

/// A station's read routes that the web UI's parts, measurement, compare
/// and QC views call, served by the same handlers from the center's store
/// (the same shapes, with the station of every row). Nothing that writes,
/// runs a bench or needs a station's own tables (jobs, events, proposals,
/// gauge studies, recordings' bytes, diagnostics) is among them.
fn station_reads() -> Vec<(&'static str, MethodRouter<FleetState>)> {
    use super::{jobs, measurements, qc};
    type F = FleetState;
    vec![
        ("/api/v1/session", get(session)),
        ("/api/v1/parts", get(jobs::list_parts::<F>)),
        ("/api/v1/parts/{serial}", get(jobs::get_part::<F>)),
        (
            "/api/v1/parts/{serial}/measurements",
            get(jobs::part_measurements::<F>),
        ),
        ("/api/v1/parts/{serial}/verdict", get(qc::part_verdict::<F>)),
        ("/api/v1/measurements", get(measurements::list::<F>)),
        ("/api/v1/measurements/{id}", get(measurements::get_one::<F>)),
        (
            "/api/v1/measurements/{id}/fits",
            get(measurements::list_fits::<F>),
        ),
        (
            "/api/v1/measurements/{id}/recordings/{file}",
            get(recording),
        ),
        ("/api/v1/jobs/{id}/verdict", get(qc::job_verdict::<F>)),
        ("/api/v1/recipes", get(qc::list::<F>)),
        ("/api/v1/recipes/{name}", get(qc::get_one::<F>)),
        ("/api/v1/recipes/{name}/versions", get(qc::versions::<F>)),
        (
            "/api/v1/recipes/{name}/versions/{version}",
            get(qc::version::<F>),
        ),
        ("/api/v1/recipes/{name}/spc", get(qc::spc::<F>)),
        // The stations' long-term tests, read only (decision 0134).
        ("/api/v1/long-term-tests", get(longterm::list)),
        ("/api/v1/long-term-tests/{id}", get(longterm::get_one)),
        (
            "/api/v1/long-term-tests/{id}/series.csv",
            get(longterm::series_csv),
        ),
        (
            "/api/v1/long-term-tests/{id}/last-signals.wav",
            get(longterm::last_signals),
        ),
    ]
}

/// `GET /api/v1/measurements/{id}/recordings/{pre|main}.wav` at the center:
/// the WAV as the station serves it, when the station sends its recordings
/// (`[fleet] recordings = "full"`); a 404 naming the station when it sends
/// references only.
async fn recording(
    State(st): State<FleetState>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    let kind = file
        .strip_suffix(".wav")
        .filter(|k| ["pre", "main"].contains(k))
        .ok_or_else(|| Problem::not_found("recording (use pre.wav or main.wav)", &file))?;
    let r = st
        .store
        .recording(&id, kind)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", &id))?;
    let Some((rec_id, len)) = r.stored else {
        return Err(Problem::new(
            StatusCode::NOT_FOUND,
            "recording-at-station",
            "Recording held by the station",
            format!(
                "the raw signals of measurement '{id}' are on station '{}', which sends the center references only ([fleet] recordings = \"reference\")",
                r.station_id.as_deref().unwrap_or("?")
            ),
        ));
    };
    let scale = r
        .channel_scale_json
        .map(|j| serde_json::from_str(&j))
        .transpose()
        .map_err(|e| Problem::internal(format!("stored channel scale unreadable: {e}")))?;
    // Streamed: read 1 MiB at a time from the database (issue 36).
    super::measurements::wav_response(st.store.recording_reader(rec_id, len), scale).await
}

/// The station routes the fleet role serves too (all GET).
pub fn station_paths() -> Vec<&'static str> {
    station_reads().into_iter().map(|(p, _)| p).collect()
}

/// `GET /api/v1/session` at the center: as a station's, with `daemon: "center"`
/// (the UI then offers no job, bench or write control and says why).
async fn session(State(st): State<FleetState>, headers: axum::http::HeaderMap) -> Json<Value> {
    Json(super::session::caller(&st.cfg, &headers, "center"))
}

/// The fleet role's routes (every one a read) and the web UI.
pub fn router(state: FleetState) -> Router {
    let mut r = Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics));
    // One MethodRouter per path: a proposal list's GET and POST are one.
    let mut routes: Vec<(&'static str, MethodRouter<FleetState>)> = vec![];
    for (path, h) in table()
        .into_iter()
        .chain(station_reads())
        .chain(authoring().into_iter().map(|(_, p, h)| (p, h)))
    {
        match routes.iter_mut().find(|(p, _)| *p == path) {
            Some((_, m)) => *m = std::mem::take(m).merge(h),
            None => routes.push((path, h)),
        }
    }
    for (path, h) in routes {
        r = r.route(path, h);
    }
    r.merge(ingest::routes(state.cfg.max_ingest_bytes))
        .merge(crate::ui::router(|path| {
        Problem::not_found("UI file", path).into_response()
    }))
    .fallback(|uri: axum::http::Uri| async move {
        Problem::new(
            StatusCode::NOT_FOUND,
            "not-found",
            "Not found",
            format!(
                "no route {} (the fleet role serves /api/v1/fleet/..., the web UI and a station's reads of parts, measurements and recipes)",
                uri.path()
            ),
        )
    })
    .layer(axum::middleware::from_fn_with_state(state.clone(), viewer))
    .layer(axum::middleware::from_fn(bad_bytes))
    .layer(axum::middleware::from_fn(super::guard::problem_everywhere))
    .with_state(state)
}

/// Every route but `/healthz`, `/api/v1/session` and the UI's pages needs
/// a viewer token (or none when no tokens are configured: then the daemon
/// listens on loopback only). Only reads; Host and Origin as on a station.
async fn viewer(State(st): State<FleetState>, req: Request, next: Next) -> Response {
    if let Some(r) = super::guard::host_and_origin(&st.cfg.http, &req) {
        return r;
    }
    if ingest::is_ingest(req.uri().path()) {
        // A station's routes: its own token, checked by the handlers.
        return next.run(req).await;
    }
    let read = req.method() == axum::http::Method::GET || req.method() == axum::http::Method::HEAD;
    if !read && is_authoring(req.uri().path()) {
        // Recipes authored at the center: each handler checks its role.
        return next.run(req).await;
    }
    if !read {
        return Problem::new(
            StatusCode::METHOD_NOT_ALLOWED,
            "method-not-allowed",
            "Method not allowed",
            "the fleet role's API is read-only but for recipes authored at the center (/api/v1/fleet/recipe-proposals)",
        )
        .into_response();
    }
    let path = req.uri().path();
    if st.cfg.open_access()
        || path == "/healthz"
        || path == "/readyz"
        || path == "/api/v1/session"
        || crate::ui::is_public(path)
    {
        return next.run(req).await;
    }
    if super::auth::bearer_token(&st.cfg, req.headers()).is_none() {
        let mut p = Problem::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "Authentication required",
            "send 'Authorization: Bearer <token>'",
        );
        p.headers.push((
            header::WWW_AUTHENTICATE,
            header::HeaderValue::from_static("Bearer realm=\"springbench-fleet\""),
        ));
        return p.into_response();
    }
    next.run(req).await
}

/// A path or query whose decoded bytes hold a NUL or another control
/// character, or are not UTF-8, is a 400 here: it never reaches the
/// database (`%00` gave a 500 carrying the database's error text).
async fn bad_bytes(req: Request, next: Next) -> Response {
    let uri = req.uri();
    let bad = |raw: &str, plus: bool| {
        let raw = if plus {
            raw.replace('+', " ")
        } else {
            raw.to_string()
        };
        match percent_decode(&raw) {
            Some(s) => s.chars().any(char::is_control),
            None => true,
        }
    };
    if bad(uri.path(), false) || uri.query().is_some_and(|q| bad(q, true)) {
        return Problem::new(
            StatusCode::BAD_REQUEST,
            "bad-bytes",
            "Bad bytes in the request",
            "the path or query holds a control character (such as %00) or bytes that are not UTF-8",
        )
        .into_response();
    }
    next.run(req).await
}

fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = (b[i] == b'%' && i + 2 < b.len())
            .then(|| std::str::from_utf8(&b[i + 1..i + 3]).ok())
            .flatten()
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        if let Some(x) = hex {
            out.push(x);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The query of a request: only the `known` parameters, each once.
struct Params(HashMap<String, String>);

impl Params {
    fn of(q: Vec<(String, String)>, known: &[&str]) -> ApiResult<Params> {
        let mut m = HashMap::new();
        for (k, v) in q {
            if !known.contains(&k.as_str()) {
                return Err(Problem::field(
                    &k,
                    format!("unknown query parameter (known: {})", known.join(", ")),
                ));
            }
            if m.insert(k.clone(), v).is_some() {
                return Err(Problem::field(&k, "given twice"));
            }
        }
        Ok(Params(m))
    }

    fn str(&self, k: &str) -> Option<&str> {
        self.0.get(k).map(String::as_str).filter(|s| !s.is_empty())
    }

    fn int(&self, k: &str, range: std::ops::RangeInclusive<i64>) -> ApiResult<Option<i64>> {
        match self.str(k) {
            None => Ok(None),
            Some(s) => match s.parse::<i64>() {
                Ok(n) if range.contains(&n) => Ok(Some(n)),
                _ => Err(Problem::field(
                    k,
                    format!(
                        "an integer from {} to {}, got '{s}'",
                        range.start(),
                        range.end()
                    ),
                )),
            },
        }
    }

    fn time(&self, k: &str) -> ApiResult<Option<String>> {
        super::qc::parse_time(k, self.str(k))
    }
}

type Q = Query<Vec<(String, String)>>;

async fn healthz(State(st): State<FleetState>) -> Response {
    match st.store.ping().await {
        Ok(()) => Json(json!({"status": "ok", "version": crate::VERSION, "role": "fleet"}))
            .into_response(),
        Err(e) => Problem::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "database-unreachable",
            "Database unreachable",
            e.to_string(),
        )
        .into_response(),
    }
}

/// `/readyz`: 200 while the database answers, else 503 (no internals).
async fn readyz(State(st): State<FleetState>) -> Response {
    match st.store.ping().await {
        Ok(()) => Json(json!({"status": "ready", "role": "fleet"})).into_response(),
        Err(e) => {
            tracing::warn!("readyz: {e}");
            Problem::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "database-unreachable",
                "Database unreachable",
                "the center's database does not answer",
            )
            .into_response()
        }
    }
}

/// `/metrics` (Prometheus text): per station, the age of its last contact
/// (the center's clock), its clock skew, items held and missing, refusals;
/// SPC queries running. An alert on `springbench_center_station_refused`
/// rising or a contact age above a few minutes says a station is stuck.
async fn metrics(State(st): State<FleetState>) -> Response {
    use std::fmt::Write;
    let stations = match st.store.stations().await {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!("metrics: {e}");
            return Problem::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "database-unreachable",
                "Database unreachable",
                "the center's database does not answer",
            )
            .into_response();
        }
    };
    let mut out = String::new();
    let now = chrono::Utc::now();
    let mut family = |name: &str, help: &str, f: &dyn Fn(&StationStatus) -> Option<f64>| {
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} gauge");
        for s in &stations {
            if s.renamed_to.is_some() {
                continue;
            }
            let v = f(s).map_or("NaN".to_string(), |v| format!("{v}"));
            let _ = writeln!(out, "{name}{{station=\"{}\"}} {v}", s.station_id);
        }
    };
    family(
        "springbench_center_station_last_contact_age_seconds",
        "Time since the station's last hello or batch, by the center's clock.",
        &|s| {
            chrono::DateTime::parse_from_rfc3339(&s.last_contact_at)
                .ok()
                .map(|t| (now - t.with_timezone(&chrono::Utc)).num_milliseconds() as f64 / 1000.0)
        },
    );
    family(
        "springbench_center_station_clock_skew_seconds",
        "The station's clock minus the center's at its last hello.",
        &|s| s.clock_skew_s,
    );
    family(
        "springbench_center_station_items",
        "Items of the station the center holds.",
        &|s| Some(s.items as f64),
    );
    family(
        "springbench_center_station_missing_items",
        "Sequence numbers below the station's highest the center lacks.",
        &|s| Some(s.missing_items as f64),
    );
    family(
        "springbench_center_station_refused",
        "Refused items and requests of (or claiming) the station (GET /api/v1/fleet/refusals).",
        &|s| Some(s.refused as f64),
    );
    family(
        "springbench_center_station_backlog_items",
        "The backlog the station reported in its last hello.",
        &|s| Some(s.backlog_items as f64),
    );
    let running: usize = st.spc_running.lock().unwrap().values().sum();
    let _ = writeln!(
        out,
        "# HELP springbench_center_spc_running SPC queries running now.\n# TYPE springbench_center_spc_running gauge\nspringbench_center_spc_running {running}"
    );
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], out).into_response()
}

/// Every station the center heard of.
#[derive(Serialize, utoipa::ToSchema)]
pub struct StationList {
    pub items: Vec<StationStatus>,
}

/// A page of parts across stations.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetPartPage {
    /// Each with the station of its newest measurement (`station_id`).
    pub items: Vec<Part>,
    /// The `after` of the next page (null at the end).
    pub next_after: Option<String>,
}

/// A part at the center: the part, its newest job verdict, its measurements.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetPart {
    pub part: Part,
    /// The newest job verdict of a job without a voided measurement (null: none).
    pub verdict: Option<VerdictRow>,
    /// Newest first, at most 100, each with its station.
    pub measurements: Vec<MeasurementInfo>,
}

/// A page of measurements, newest first.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetMeasurementPage {
    pub items: Vec<MeasurementInfo>,
    /// The `cursor` of the next page (null at the end).
    pub next_cursor: Option<String>,
}

/// A measurement at the center.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetMeasurement {
    pub measurement: MeasurementInfo,
    /// The result document (null when the analysis failed: `analysis_error`).
    #[schema(value_type = Option<Object>)]
    pub result: Option<Value>,
    /// The station's meta.json of the measurement.
    #[schema(value_type = Object)]
    pub meta: Value,
    /// The correction that voided it (its reason: `GET /api/v1/fleet/audit`);
    /// null: not voided. A voided measurement counts in no SPC, yield or verdict.
    pub void_correction_id: Option<String>,
}

/// The newest version of every recipe.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetRecipeList {
    pub items: Vec<RecipeRow>,
}

/// A measurement verdict with the measurement's level in its series.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetVerdict {
    #[serde(flatten)]
    pub verdict: VerdictRow,
    pub level_index: Option<i64>,
}

/// A recipe's measurement verdicts across stations, oldest first.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetVerdictList {
    pub items: Vec<FleetVerdict>,
    /// The `after` of the next page (paged listings; null at the end or with `last`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub next_after: Option<i64>,
}

/// SPC of a parameter across stations and per station.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetSpc {
    pub recipe: String,
    /// The recipe version whose limits judge capability (the newest).
    pub version: i64,
    pub parameter: String,
    /// Every station together (no `points`: the center does not ship them).
    pub fleet: Option<Spc>,
    /// Each station as a subgroup of the same window.
    pub stations: Vec<SpcGroup>,
}

/// Job verdicts per station and day.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetYield {
    pub items: Vec<YieldDay>,
}

/// A page of the fleet's audit trail.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetAudit {
    /// Oldest first; `station_id` the station it was made on.
    pub items: Vec<AuditEntry>,
    /// The `after` of the next page (null at the end).
    pub next_after: Option<i64>,
}

/// `GET /api/v1/fleet/stations`: every station the center heard of.
#[utoipa::path(get, path = "/api/v1/fleet/stations", tag = "fleet",
    summary = "Every station the center heard of: last contact (center's clock), software and contract version, bench states, backlog (as the station reported it), items held and missing outbox sequence numbers.",
    responses(
        (status = 200, description = "Stations", body = StationList),
        (status = 422, description = "An unknown query parameter")))]
pub async fn stations(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<StationList>> {
    Params::of(q, &[])?;
    let items = st.store.stations().await?;
    Ok(Json(StationList { items }))
}

/// `GET /api/v1/fleet/parts?after=&limit=` (keyset on serial).
#[utoipa::path(get, path = "/api/v1/fleet/parts", tag = "fleet",
    summary = "Parts of every station, by serial (keyset pages).",
    params(
        ("after" = Option<String>, Query, description = "The `next_after` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 1000, description = "Page size (default 100)")),
    responses(
        (status = 200, description = "A page of parts", body = FleetPartPage),
        (status = 422, description = "A bad or unknown query parameter")))]
pub async fn parts(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<FleetPartPage>> {
    let p = Params::of(q, &["after", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let items = st.store.list_parts(p.str("after"), limit).await?;
    let next_after = (items.len() as i64 == limit)
        .then(|| items.last().map(|x| x.serial.clone()))
        .flatten();
    Ok(Json(FleetPartPage { items, next_after }))
}

/// `GET /api/v1/fleet/parts/{serial}`: the part, its newest job verdict and
/// its measurements (newest first, at most 100), each with its station.
#[utoipa::path(get, path = "/api/v1/fleet/parts/{serial}", tag = "fleet",
    summary = "A part's history across stations: the part, its newest job verdict (jobs with a voided measurement do not count), its measurements newest first (at most 100) with their stations.",
    params(("serial" = String, Path, description = "Part serial")),
    responses(
        (status = 200, description = "The part", body = FleetPart),
        (status = 404, description = "No such part at the center")))]
pub async fn part(
    State(st): State<FleetState>,
    Path(serial): Path<String>,
) -> ApiResult<Json<FleetPart>> {
    let part = st
        .store
        .get_part(&serial)
        .await?
        .ok_or_else(|| Problem::not_found("part", &serial))?;
    let measurements = st
        .store
        .list_measurements(Some(&serial), None, None, 100)
        .await?;
    let verdict = st.store.part_verdict(&serial).await?;
    Ok(Json(FleetPart {
        part,
        verdict,
        measurements,
    }))
}

/// `GET /api/v1/fleet/measurements?station=&part=&job=&cursor=&limit=`
/// newest first; `next_cursor` is the cursor of the next page (as on a station).
#[utoipa::path(get, path = "/api/v1/fleet/measurements", tag = "fleet",
    summary = "Measurements of every station, newest first (keyset pages): of one station, or of a part and / or a job.",
    params(
        ("station" = Option<String>, Query, description = "A station's id (not with part or job)"),
        ("part" = Option<String>, Query, description = "A part's serial"),
        ("job" = Option<String>, Query, description = "A job's id"),
        ("cursor" = Option<i64>, Query, minimum = 1, description = "The `next_cursor` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 1000, description = "Page size (default 100)")),
    responses(
        (status = 200, description = "A page of measurements", body = FleetMeasurementPage),
        (status = 422, description = "A bad or unknown query parameter, or station with part or job")))]
pub async fn measurements(
    State(st): State<FleetState>,
    Query(q): Q,
) -> ApiResult<Json<FleetMeasurementPage>> {
    let p = Params::of(q, &["station", "part", "job", "cursor", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let before = p.int("cursor", 1..=i64::MAX)?;
    let items = match p.str("station") {
        Some(s) => {
            if p.str("part").is_some() || p.str("job").is_some() {
                return Err(Problem::field(
                    "station",
                    "give station, or part / job, not both",
                ));
            }
            st.store.station_measurements(s, before, limit).await?
        }
        None => {
            st.store
                .list_measurements(p.str("part"), p.str("job"), before, limit)
                .await?
        }
    };
    let next_cursor = (items.len() as i64 == limit)
        .then(|| items.last().map(|m| m.seq.to_string()))
        .flatten();
    Ok(Json(FleetMeasurementPage { items, next_cursor }))
}

/// `GET /api/v1/fleet/measurements/{id}`: record, result document, meta.
#[utoipa::path(get, path = "/api/v1/fleet/measurements/{id}", tag = "fleet",
    summary = "A measurement at the center: its record (with its station), result document, meta.json, and the correction that voided it, if any.",
    params(("id" = String, Path, description = "Measurement id")),
    responses(
        (status = 200, description = "The measurement", body = FleetMeasurement),
        (status = 404, description = "No such measurement at the center")))]
pub async fn measurement(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Json<FleetMeasurement>> {
    let (measurement, result, meta) = st
        .store
        .get_measurement(&id)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", &id))?;
    let void_correction_id = st.store.measurement_void(&id).await?;
    Ok(Json(FleetMeasurement {
        measurement,
        result,
        meta,
        void_correction_id,
    }))
}

/// `GET /api/v1/fleet/recipes`: the newest version of every recipe.
#[utoipa::path(get, path = "/api/v1/fleet/recipes", tag = "fleet",
    summary = "The newest version of every recipe the center holds (the stations run these).",
    responses(
        (status = 200, description = "Recipes", body = FleetRecipeList),
        (status = 422, description = "An unknown query parameter")))]
pub async fn recipes(
    State(st): State<FleetState>,
    Query(q): Q,
) -> ApiResult<Json<FleetRecipeList>> {
    Params::of(q, &[])?;
    Ok(Json(FleetRecipeList {
        items: st.store.list_recipes().await?,
    }))
}

/// `GET /api/v1/fleet/recipes/{name}/verdicts?last=&since=&until=&after=&limit=`:
/// the measurement verdicts of a recipe across stations, oldest first.
#[utoipa::path(get, path = "/api/v1/fleet/recipes/{name}/verdicts", tag = "fleet",
    summary = "A recipe's measurement verdicts across stations (voided measurements left out), oldest first: the newest `last` (default 100 without since / until / after; at most 10 000), or a page of those judged in [since, until) after the verdict `after` (`limit`, default 1 000, at most 10 000; `next_after` gives the next page).",
    params(
        ("name" = String, Path, description = "Recipe name"),
        ("last" = Option<i64>, Query, minimum = 1, maximum = 10000, description = "The newest N verdicts"),
        ("since" = Option<String>, Query, format = DateTime, description = "RFC 3339"),
        ("until" = Option<String>, Query, format = DateTime, description = "RFC 3339 (exclusive)"),
        ("after" = Option<i64>, Query, minimum = 0, description = "The `next_after` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 10000, description = "Page size (default 1 000)")),
    responses(
        (status = 200, description = "Verdicts", body = FleetVerdictList),
        (status = 422, description = "A bad or unknown query parameter")))]
pub async fn verdicts(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    Query(q): Q,
) -> ApiResult<Json<FleetVerdictList>> {
    let p = Params::of(q, &["last", "since", "until", "after", "limit"])?;
    let (since, until) = (p.time("since")?, p.time("until")?);
    let after = p.int("after", 0..=i64::MAX)?;
    let paged = after.is_some() || p.str("limit").is_some() || since.is_some() || until.is_some();
    let (rows, limit) = if paged && p.str("last").is_none() {
        let limit = p.int("limit", 1..=VERDICTS_MAX)?.unwrap_or(1000);
        let rows = st
            .store
            .recipe_verdicts_page(&name, since.as_deref(), until.as_deref(), after, limit)
            .await?;
        (rows, Some(limit))
    } else {
        if p.str("after").is_some() || p.str("limit").is_some() {
            return Err(Problem::field(
                "last",
                "give last, or after / limit, not both",
            ));
        }
        let last = p.int("last", 1..=VERDICTS_MAX)?.unwrap_or(100);
        let rows = st
            .store
            .recipe_verdicts(&name, None, since.as_deref(), until.as_deref(), Some(last))
            .await?;
        (rows, None)
    };
    let next_after = limit
        .filter(|l| rows.len() as i64 == *l)
        .and_then(|_| rows.last().map(|v| v.seq));
    let items = rows
        .into_iter()
        .map(|verdict| FleetVerdict {
            level_index: verdict.level_index,
            verdict,
        })
        .collect();
    Ok(Json(FleetVerdictList { items, next_after }))
}

/// One of a client's SPC slots (`spc_per_client`), given back on drop: a
/// burst of heavy queries from one client is answered 429 with
/// `Retry-After` at once instead of piling up until the pool times out
/// (issue 36: 124 x 503 in a 200-way burst).
struct SpcSlot {
    running: Arc<std::sync::Mutex<HashMap<String, usize>>>,
    client: String,
}

impl SpcSlot {
    fn take(st: &FleetState, headers: &axum::http::HeaderMap) -> ApiResult<SpcSlot> {
        let client = super::auth::bearer_token(&st.cfg, headers)
            .map_or_else(|| "open".to_string(), |t| t.name.clone());
        let mut m = st.spc_running.lock().unwrap();
        let n = m.entry(client.clone()).or_default();
        if *n >= st.cfg.spc_per_client {
            let mut p = Problem::new(
                StatusCode::TOO_MANY_REQUESTS,
                "too-many-spc-queries",
                "Too many SPC queries",
                format!(
                    "this client runs {} SPC queries already (spc_per_client); retry after the Retry-After seconds",
                    *n
                ),
            );
            p.headers
                .push((header::RETRY_AFTER, header::HeaderValue::from_static("1")));
            return Err(p);
        }
        *n += 1;
        Ok(SpcSlot {
            running: st.spc_running.clone(),
            client,
        })
    }
}

impl Drop for SpcSlot {
    fn drop(&mut self) {
        let mut m = self.running.lock().unwrap();
        if let Some(n) = m.get_mut(&self.client) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                m.remove(&self.client);
            }
        }
    }
}

fn window_last(
    p: &Params,
    since: &Option<String>,
    until: &Option<String>,
) -> ApiResult<Option<i64>> {
    Ok(match p.int("last", 1..=1_000_000)? {
        None if since.is_none() && until.is_none() => Some(100),
        l => l,
    })
}

/// `GET /api/v1/fleet/recipes/{name}/spc?parameter=&last=&since=&until=`:
/// the statistics of a parameter over the window, every station together
/// (`fleet`) and each station as a subgroup of the same window
/// (`stations`); limits are the newest recipe version's.
#[utoipa::path(get, path = "/api/v1/fleet/recipes/{name}/spc", tag = "fleet",
    summary = "SPC of one parameter over a window of a recipe's valid measurement verdicts across stations (`fleet`) and per station (`stations`: the station as a subgroup, Cpk per line); one point per part and job and level, as on a station; limits of the newest recipe version. No chart points.",
    params(
        ("name" = String, Path, description = "Recipe name"),
        ("parameter" = String, Query, description = "The recipe parameter's name (required)"),
        ("last" = Option<i64>, Query, minimum = 1, maximum = 1000000, description = "The newest N verdicts (default 100 without since / until)"),
        ("since" = Option<String>, Query, format = DateTime, description = "RFC 3339"),
        ("until" = Option<String>, Query, format = DateTime, description = "RFC 3339 (exclusive)")),
    responses(
        (status = 200, description = "SPC", body = FleetSpc),
        (status = 404, description = "No such recipe"),
        (status = 429, description = "This client runs `spc_per_client` SPC queries already (Retry-After)"),
        (status = 422, description = "A bad, unknown or missing query parameter")))]
pub async fn spc(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    headers: axum::http::HeaderMap,
    Query(q): Q,
) -> ApiResult<Json<FleetSpc>> {
    let p = Params::of(q, &["parameter", "last", "since", "until"])?;
    let row = st
        .store
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let recipe = row.recipe;
    let names = || {
        recipe
            .parameters
            .iter()
            .map(|p| p.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let pname = p
        .str("parameter")
        .ok_or_else(|| Problem::field("parameter", format!("required: one of {}", names())))?;
    let spec = recipe
        .parameters
        .iter()
        .find(|x| x.name == pname)
        .ok_or_else(|| {
            Problem::field(
                "parameter",
                format!(
                    "recipe '{name}' has no parameter '{pname}' (one of {})",
                    names()
                ),
            )
        })?;
    let (since, until) = (p.time("since")?, p.time("until")?);
    let last = window_last(&p, &since, &until)?;
    let unit = spec.unit();
    let q = |per_station| springbench_store_pg::SpcQuery {
        recipe: &name,
        parameter: pname,
        unit: &unit,
        lower: spec.lower,
        upper: spec.upper,
        since: since.as_deref(),
        until: until.as_deref(),
        last,
        per_station,
    };
    let _slot = SpcSlot::take(&st, &headers)?;
    let fleet = st.store.spc(&q(false)).await?;
    let stations = st.store.spc(&q(true)).await?;
    Ok(Json(FleetSpc {
        recipe: name.clone(),
        version: row.version,
        parameter: pname.to_string(),
        fleet: fleet.into_iter().next().map(|g| g.spc),
        stations,
    }))
}

/// `GET /api/v1/fleet/recipes/{name}/yield?since=&until=`: job verdicts per
/// station and day (UTC); default the last 30 days.
#[utoipa::path(get, path = "/api/v1/fleet/recipes/{name}/yield", tag = "fleet",
    summary = "Job verdicts of a recipe per station and day (UTC) and the yield (pass / (pass + fail)); jobs with a voided measurement do not count. Default: the last 30 days.",
    params(
        ("name" = String, Path, description = "Recipe name"),
        ("since" = Option<String>, Query, format = DateTime, description = "RFC 3339 (default 30 days ago)"),
        ("until" = Option<String>, Query, format = DateTime, description = "RFC 3339, exclusive (default tomorrow)")),
    responses(
        (status = 200, description = "Yield per station and day", body = FleetYield),
        (status = 422, description = "A bad or unknown query parameter, or since not before until")))]
pub async fn yield_per_day(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    Query(q): Q,
) -> ApiResult<Json<FleetYield>> {
    let p = Params::of(q, &["since", "until"])?;
    let until = p.time("until")?.unwrap_or_else(|| {
        (chrono::Utc::now() + chrono::Duration::days(1))
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
    });
    let since = p.time("since")?.unwrap_or_else(|| {
        (chrono::Utc::now() - chrono::Duration::days(30))
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
    });
    if since >= until {
        return Err(Problem::field("since", "must be before until"));
    }
    let items = st.store.yield_per_day(&name, &since, &until).await?;
    Ok(Json(FleetYield { items }))
}

/// `GET /api/v1/fleet/audit?part=&after=&limit=`: corrections, oldest first.
#[utoipa::path(get, path = "/api/v1/fleet/audit", tag = "fleet",
    summary = "The audit trail of corrections the stations made (serial, kind, voids), oldest first, in keyset pages; `part` matches the old or the new serial. Corrections are made on the station (decision 0056).",
    params(
        ("part" = Option<String>, Query, description = "A part's serial (old or new)"),
        ("after" = Option<i64>, Query, minimum = 0, description = "The `next_after` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 1000, description = "Page size (default 100)")),
    responses(
        (status = 200, description = "Audit log", body = FleetAudit),
        (status = 422, description = "A bad or unknown query parameter")))]
pub async fn audit(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<FleetAudit>> {
    let p = Params::of(q, &["part", "after", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let after = p.int("after", 0..=i64::MAX)?;
    let items = st.store.audit_log(p.str("part"), after, limit).await?;
    let next_after = (items.len() as i64 == limit)
        .then(|| items.last().map(|e| e.seq))
        .flatten();
    Ok(Json(FleetAudit { items, next_after }))
}

/// A page of refusals, newest first.
#[derive(Serialize, utoipa::ToSchema)]
pub struct FleetRefusals {
    pub items: Vec<springbench_store_pg::Refusal>,
    /// The `before` of the next page (null at the end).
    pub next_before: Option<i64>,
}

/// `GET /api/v1/fleet/refusals?station=&before=&limit=`: what the center
/// refused, newest first.
#[utoipa::path(get, path = "/api/v1/fleet/refusals", tag = "fleet",
    summary = "What the center refused, newest first: requests claiming a station id with another station's credential (or none, or a retired station's), and items it would not store (a void of another station's measurement, a NUL byte, ...), each with its reason, the claimed station and the credential's station, first and last time (the center's clock) and how often. The station parks a refused item and goes on with the next.",
    params(
        ("station" = Option<String>, Query, description = "The station id claimed"),
        ("before" = Option<i64>, Query, minimum = 1, description = "The `next_before` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 1000, description = "Page size (default 100)")),
    responses(
        (status = 200, description = "Refusals", body = FleetRefusals),
        (status = 422, description = "A bad or unknown query parameter")))]
pub async fn refusals(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<FleetRefusals>> {
    let p = Params::of(q, &["station", "before", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let before = p.int("before", 1..=i64::MAX)?;
    let items = st.store.refusals(p.str("station"), before, limit).await?;
    let next_before = (items.len() as i64 == limit)
        .then(|| items.last().map(|r| r.seq))
        .flatten();
    Ok(Json(FleetRefusals { items, next_before }))
}

/// A station's link to its center and what the center refused.
#[derive(Serialize, utoipa::ToSchema)]
pub struct StationLink {
    pub link: crate::fleet::LinkStatus,
    /// Items the center refused, parked with its reason (`last_error`),
    /// oldest first (at most 100); later items of their parts wait behind them.
    #[schema(value_type = Vec<Object>)]
    pub refused: Vec<crate::store::outbox::OutboxRow>,
    /// True while an item is parked, or the center has not been reached
    /// for 3 attempts in a row with items waiting (`springbench_fleet_stuck`).
    pub stuck: bool,
}

/// `GET /api/v1/fleet/link` (a station with `[fleet]`): the link to the
/// center, the items it refused with their reasons.
#[utoipa::path(get, path = "/api/v1/fleet/link", tag = "operations",
    summary = "A station's link to the fleet's center (`[fleet]`): connected, last contact, last error, items sent, and the items the center refused, parked with its reason (replication goes on with the others). 404 without [fleet].",
    responses(
        (status = 200, description = "The link", body = StationLink),
        (status = 404, description = "This station has no [fleet]")))]
pub async fn station_link(State(st): State<super::AppState>) -> ApiResult<Json<StationLink>> {
    let link = st.fleet.as_ref().ok_or_else(|| {
        Problem::not_found("fleet link (no [fleet] in the configuration)", "link")
    })?;
    let refused = st.store.outbox_refused(100).await?;
    let b = st.store.outbox_backlog().await?;
    let link = link.status();
    Ok(Json(StationLink {
        stuck: crate::fleet::stuck(&b, &link),
        link,
        refused,
    }))
}

/// Runs the fleet role on `addr` until `stop` resolves (`springbench serve`
/// with `database = "postgres://..."`).
pub async fn serve_role(
    cfg: Config,
    addr: SocketAddr,
    note: Option<String>,
    stop: impl std::future::Future<Output = ()>,
) -> Result<(), String> {
    use std::io::Write;
    let url = cfg
        .database
        .clone()
        .ok_or("the fleet role needs database = \"postgres://...\"")?;
    let store = PgStore::connect(&url)
        .await
        .map_err(|e| format!("database {}: {e}", crate::config::redact_url_password(&url)))?;
    let registrations: Vec<_> = cfg
        .stations
        .iter()
        .map(|s| springbench_store_pg::StationRegistration {
            station_id: s.station_id.clone(),
            former_ids: s.former_ids.clone(),
            retired: s.retired,
        })
        .collect();
    store.register_stations(&registrations).await.map_err(|e| {
        format!(
            "database {}: stations: {e}",
            crate::config::redact_url_password(&url)
        )
    })?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let local = listener
        .local_addr()
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let http = cfg.http.clone();
    let (max_conn, fd_note) = super::server::fit_connection_limit(http.max_connections);
    let app = router(FleetState::new(store.clone(), Arc::new(cfg)));
    let server =
        tokio::spawn(
            async move { super::server::serve(listener, app, &http, max_conn, stop_rx).await },
        );
    for n in [note, fd_note].into_iter().flatten() {
        eprintln!("springbench: {n}");
    }
    println!("listening on http://{local}");
    let _ = std::io::stdout().flush();
    tracing::info!(version = crate::VERSION, "fleet role started");
    stop.await;
    let _ = stop_tx.send(true);
    match tokio::time::timeout(Duration::from_secs(5), server).await {
        Ok(Ok(Ok(()))) => {}
        Ok(Ok(Err(e))) => tracing::error!("server: {e}"),
        _ => tracing::warn!("open connections did not close within 5 s"),
    }
    store.close().await;
    Ok(())
}
