//! HTTP + websocket API (axum): translation only, no science.
//!
//! Every route is registered through [`routes`], which also returns the list
//! of (method, path) pairs; tests keep the OpenAPI document ([`openapi`],
//! generated from the handlers' annotations) equal to it.
//! Errors are RFC 9457 problem documents ([`problem::Problem`]).

pub mod auth;
pub mod benches;
pub mod corrections;
pub mod derived;
pub mod events;
pub mod fleet;
pub mod gauge;
pub mod guard;
pub mod import;
pub mod jobs;
pub mod longterm;
pub mod measurements;
pub mod metrics;
pub mod openapi;
pub mod ops;
pub mod problem;
pub mod problem_io;
pub mod qc;
pub mod reads;
pub mod report;
pub mod schema;
pub mod server;
pub mod session;
pub mod stimuli;
pub mod studies;

use crate::config::Config;
use crate::runner::Runner;
use crate::store::Store;
use axum::extract::{DefaultBodyLimit, FromRequest, Request};
use axum::routing::{delete, get, post, put, MethodRouter};
use axum::Router;
use problem::Problem;
use serde_json::Value;
use std::sync::Arc;
use tokio::sync::watch;

/// A document served with its object keys sorted: the order every document
/// the API built as a `serde_json::Value` was served in (that map sorts), so
/// a document now served from its type reads byte for byte as before.
pub struct Sorted<T>(pub T);

impl<T: serde::Serialize> serde::Serialize for Sorted<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        crate::store::sorted(&self.0, s)
    }
}

#[derive(Clone)]
pub struct AppState {
    pub store: Store,
    pub runner: Arc<Runner>,
    pub cfg: Arc<Config>,
    pub metrics: Arc<metrics::Metrics>,
    /// Becomes true when the daemon shuts down (websockets close).
    pub shutdown: watch::Receiver<bool>,
    /// The link to the fleet's center (a station with `[fleet]`).
    pub fleet: Option<Arc<crate::fleet::Link>>,
}

/// Lowercase hex digits of `b` (a digest's id).
pub(crate) fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

struct Reg {
    router: Router<AppState>,
    list: Vec<(&'static str, &'static str)>,
}

impl Reg {
    fn add(mut self, method: &'static str, path: &'static str, h: MethodRouter<AppState>) -> Reg {
        self.list.push((method, path));
        self.router = self.router.route(path, h);
        self
    }
}

fn limited(
    h: MethodRouter<AppState>,
    l: &tower::limit::GlobalConcurrencyLimitLayer,
) -> MethodRouter<AppState> {
    h.layer(l.clone())
}

/// The router (without state) and the (method, path) pairs it serves.
pub fn routes(cfg: &Config) -> (Router<AppState>, Vec<(&'static str, &'static str)>) {
    let json_limit = DefaultBodyLimit::max(cfg.max_json_bytes);
    let upload_limit = DefaultBodyLimit::max(cfg.max_upload_bytes);
    // Expensive work (fits, imports, first diagnoses: api::derived) shares one queue.
    let expensive = tower::limit::GlobalConcurrencyLimitLayer::with_semaphore(
        derived::expensive_slots(cfg.http.max_expensive),
    );
    let r = Reg {
        router: Router::new(),
        list: vec![],
    }
    .add("get", "/healthz", get(ops::healthz))
    .add("get", "/readyz", get(ops::readyz))
    .add("get", "/metrics", get(ops::metrics))
    .add("get", "/api/openapi.json", get(openapi::openapi_json))
    .add("get", "/api/v1/config", get(ops::config))
    .add("get", "/api/v1/benches", get(ops::benches))
    .add(
        "post",
        "/api/v1/benches/{id}/self-check",
        post(benches::self_check),
    )
    .add(
        "get",
        "/api/v1/benches/{id}/calibrations",
        get(benches::calibrations),
    )
    .add(
        "get",
        "/api/v1/calibrations/{id}",
        get(benches::calibration),
    )
    .add("get", "/api/v1/session", get(session::session))
    .add("post", "/api/v1/jobs", post(jobs::submit).layer(json_limit))
    .add("get", "/api/v1/jobs", get(jobs::list))
    .add("get", "/api/v1/jobs/{id}", get(jobs::get_one))
    .add("post", "/api/v1/jobs/{id}/cancel", post(jobs::cancel))
    .add(
        "post",
        "/api/v1/long-term-tests",
        post(longterm::submit).layer(json_limit),
    )
    .add("get", "/api/v1/long-term-tests", get(longterm::list))
    .add(
        "get",
        "/api/v1/long-term-tests/{id}",
        get(longterm::get_one),
    )
    .add(
        "get",
        "/api/v1/long-term-tests/{id}/series.csv",
        get(longterm::series_csv),
    )
    .add(
        "get",
        "/api/v1/long-term-tests/{id}/report.html",
        get(report::long_term_report),
    )
    .add(
        "post",
        "/api/v1/long-term-tests/{id}/pause",
        post(longterm::pause),
    )
    .add(
        "post",
        "/api/v1/long-term-tests/{id}/resume",
        post(longterm::resume),
    )
    .add(
        "put",
        "/api/v1/long-term-tests/{id}/intervals/{index}/ambient",
        put(longterm::put_ambient).layer(json_limit),
    )
    .add(
        "get",
        "/api/v1/long-term-tests/{id}/last-signals.wav",
        get(longterm::last_signals),
    )
    .add(
        "post",
        "/api/v1/studies",
        post(studies::submit).layer(json_limit),
    )
    .add("get", "/api/v1/studies/{id}", get(studies::get_one))
    .add(
        "post",
        "/api/v1/stimuli",
        post(stimuli::upload).layer(DefaultBodyLimit::max(stimuli::MAX_STIMULUS_BYTES)),
    )
    .add("get", "/api/v1/stimuli", get(stimuli::list))
    .add("get", "/api/v1/stimuli/{id}", get(stimuli::get_one))
    .add(
        "post",
        "/api/v1/studies/{id}/confirm",
        post(studies::confirm),
    )
    .add("get", "/api/v1/parts", get(jobs::list_parts::<AppState>))
    .add(
        "get",
        "/api/v1/parts/{serial}",
        get(jobs::get_part::<AppState>),
    )
    .add(
        "get",
        "/api/v1/parts/{serial}/measurements",
        get(jobs::part_measurements::<AppState>),
    )
    .add(
        "get",
        "/api/v1/measurements",
        get(measurements::list::<AppState>),
    )
    .add(
        "post",
        "/api/v1/measurements",
        // The slot is taken inside, once the body is spooled (api::import).
        post(import::import).layer(upload_limit),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}",
        get(measurements::get_one::<AppState>),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}/recordings/{file}",
        get(measurements::recording),
    )
    .add(
        "post",
        "/api/v1/measurements/{id}/fits",
        limited(post(measurements::fit).layer(json_limit), &expensive),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}/fits",
        get(measurements::list_fits::<AppState>),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}/report",
        get(report::report),
    )
    .add(
        "put",
        "/api/v1/measurements/{id}/headline",
        put(measurements::choose_headline).layer(json_limit),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}/diagnostics",
        get(derived::diagnostics),
    )
    .add(
        "get",
        "/api/v1/measurements/{id}/plots/{file}",
        get(derived::plot),
    )
    .add("get", "/api/v1/events", get(events::events))
    .add(
        "post",
        "/api/v1/recipes",
        post(qc::create).layer(json_limit),
    )
    .add("get", "/api/v1/recipes", get(qc::list::<AppState>))
    .add(
        "get",
        "/api/v1/recipes/{name}",
        get(qc::get_one::<AppState>),
    )
    .add(
        "put",
        "/api/v1/recipes/{name}",
        put(qc::update).layer(json_limit),
    )
    .add("delete", "/api/v1/recipes/{name}", delete(qc::retire))
    .add(
        "post",
        "/api/v1/recipes/{name}/publish",
        post(qc::publish).layer(json_limit),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/versions",
        get(qc::versions::<AppState>),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/versions/{version}",
        get(qc::version::<AppState>),
    )
    .add(
        "post",
        "/api/v1/recipes/{name}/limit-proposals",
        post(qc::propose).layer(json_limit),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/limit-proposals",
        get(qc::list_proposals),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/spc",
        get(qc::spc::<AppState>),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/lot.csv",
        get(qc::lot_csv::<AppState>),
    )
    .add("get", "/api/v1/limit-proposals/{id}", get(qc::get_proposal))
    .add(
        "post",
        "/api/v1/limit-proposals/{id}/approve",
        post(qc::approve),
    )
    .add(
        "post",
        "/api/v1/limit-proposals/{id}/reject",
        post(qc::reject),
    )
    .add(
        "get",
        "/api/v1/parts/{serial}/verdict",
        get(qc::part_verdict::<AppState>),
    )
    .add(
        "get",
        "/api/v1/jobs/{id}/verdict",
        get(qc::job_verdict::<AppState>),
    )
    .add("get", "/api/v1/fleet/link", get(fleet::station_link))
    .add("get", "/api/v1/outbox", get(qc::outbox))
    .add("post", "/api/v1/outbox/{id}/retry", post(qc::outbox_retry))
    .add("delete", "/api/v1/outbox/{id}", delete(qc::outbox_drop))
    .add(
        "post",
        "/api/v1/gauge-studies",
        post(gauge::create).layer(json_limit),
    )
    .add("get", "/api/v1/gauge-studies", get(gauge::list))
    .add("get", "/api/v1/gauge-studies/{id}", get(gauge::get_one))
    .add(
        "post",
        "/api/v1/recipes/{name}/bench-calibrations",
        post(gauge::create_calibration).layer(json_limit),
    )
    .add(
        "get",
        "/api/v1/recipes/{name}/bench-calibrations",
        get(gauge::list_calibrations),
    )
    .add(
        "post",
        "/api/v1/corrections",
        post(corrections::create).layer(json_limit),
    )
    .add("get", "/api/v1/corrections", get(corrections::list));
    (r.router, r.list)
}

/// The complete application: routes, auth, metrics, problem+json fallbacks.
pub fn app(state: AppState) -> Router {
    let (router, _) = routes(&state.cfg);
    let body_timeout = std::time::Duration::from_secs_f64(state.cfg.http.body_read_timeout_s);
    router
        .merge(crate::ui::router(|path| {
            axum::response::IntoResponse::into_response(problem::Problem::not_found(
                "UI file", path,
            ))
        }))
        .fallback(fallback)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_role,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            guard::browser_safety,
        ))
        .layer(tower_http::timeout::RequestBodyTimeoutLayer::new(
            body_timeout,
        ))
        .layer(axum::middleware::from_fn(guard::problem_everywhere))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            metrics::track,
        ))
        .with_state(state)
}

async fn fallback(uri: axum::http::Uri) -> Problem {
    Problem::new(
        axum::http::StatusCode::NOT_FOUND,
        "not-found",
        "Not found",
        format!("no route {}", uri.path()),
    )
}

async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> Problem {
    Problem::new(
        axum::http::StatusCode::METHOD_NOT_ALLOWED,
        "method-not-allowed",
        "Method not allowed",
        format!("{method} is not allowed on {}", uri.path()),
    )
}

/// A JSON request body: size limit -> 413, unreadable -> 400, both as problem+json.
pub struct JsonBody(pub Value);

impl<S: Send + Sync> FromRequest<S> for JsonBody {
    type Rejection = Problem;
    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let bytes = axum::body::Bytes::from_request(req, state)
            .await
            .map_err(|e| {
                if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
                    Problem::new(e.status(), "too-large", "Request too large", e.body_text())
                } else if e.body_text().contains("timeout") {
                    guard::body_timeout(e.body_text())
                } else {
                    Problem::bad_request(e.body_text())
                }
            })?;
        let v: Value = serde_json::from_slice(&bytes)
            .map_err(|e| Problem::bad_request(format!("the body is not valid JSON: {e}")))?;
        Ok(JsonBody(v))
    }
}

/// Page size: `limit` query parameter, default 50, at most 500.
pub fn page_limit(limit: Option<i64>) -> Result<i64, Problem> {
    match limit {
        None => Ok(50),
        Some(n) if (1..=500).contains(&n) => Ok(n),
        Some(n) => Err(Problem::field(
            "limit",
            format!("must be from 1 to 500, got {n}"),
        )),
    }
}

/// An opaque cursor (a sequence number as text).
pub fn parse_cursor(c: Option<&str>) -> Result<Option<i64>, Problem> {
    match c {
        None | Some("") => Ok(None),
        Some(s) => s
            .parse::<i64>()
            .map(Some)
            .map_err(|_| Problem::field("cursor", "not a cursor returned by this API")),
    }
}

/// Query parameters; unreadable ones give a 400 problem document.
pub struct Q<T>(pub T);

impl<T, S> axum::extract::FromRequestParts<S> for Q<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = Problem;
    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, Self::Rejection> {
        axum::extract::Query::<T>::from_request_parts(parts, state)
            .await
            .map(|q| Q(q.0))
            .map_err(|e| Problem::bad_request(e.body_text()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roles_per_route() {
        use crate::config::Role;
        use axum::http::Method;
        assert_eq!(auth::required_role(&Method::GET, "/healthz"), None);
        assert_eq!(
            auth::required_role(&Method::GET, "/api/v1/jobs"),
            Some(Role::Viewer)
        );
        assert_eq!(
            auth::required_role(&Method::POST, "/api/v1/jobs/{id}/cancel"),
            Some(Role::Operator)
        );
        assert_eq!(
            auth::required_role(&Method::GET, "/api/v1/config"),
            Some(Role::Admin)
        );
        // Decided by the matched template, whatever the recipe is called.
        assert_eq!(
            auth::required_role(&Method::PUT, "/api/v1/recipes/{name}"),
            Some(Role::Admin)
        );
        assert_eq!(
            auth::required_role(&Method::POST, "/api/v1/recipes/{name}/limit-proposals"),
            Some(Role::Operator)
        );
        assert_eq!(auth::required_role(&Method::GET, "/ui/{*path}"), None);
    }
}
