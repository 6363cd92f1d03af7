//! The fleet role's HTTP API (issue 20): the daemon started with
//! `database = "postgres://..."` and `benches = []` serves the fleet's
//! center read-only: the stations (last contact, software, bench states,
//! backlog, gaps), every station's parts, measurements and verdicts with
//! the station in every row, SPC of a recipe across stations and per
//! station (the station as a subgroup), yield per station and day, and the
//! audit trail of corrections. Bad query parameters get problem+json naming
//! the parameter. The reads go through the results interface and
//! `springbench_store_pg::PgStore`'s center queries.

use super::problem::{ApiResult, Problem};
use crate::config::Config;
use crate::store::corrections::Corrections;
use crate::store::fleet::CenterIngest;
use crate::store::results::{MeasurementReads, PartReads, RecipeReads, VerdictReads};
use axum::extract::{Path, Query, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::{json, Value};
use springbench_store_pg::PgStore;
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

#[derive(Clone)]
pub struct FleetState {
    pub store: PgStore,
    pub cfg: Arc<Config>,
}

/// The fleet role's routes (every one a read).
pub fn router(state: FleetState) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/api/v1/fleet/stations", get(stations))
        .route("/api/v1/fleet/parts", get(parts))
        .route("/api/v1/fleet/parts/{serial}", get(part))
        .route("/api/v1/fleet/measurements", get(measurements))
        .route("/api/v1/fleet/measurements/{id}", get(measurement))
        .route("/api/v1/fleet/recipes", get(recipes))
        .route("/api/v1/fleet/recipes/{name}/verdicts", get(verdicts))
        .route("/api/v1/fleet/recipes/{name}/spc", get(spc))
        .route("/api/v1/fleet/recipes/{name}/yield", get(yield_per_day))
        .route("/api/v1/fleet/audit", get(audit))
        .fallback(|uri: axum::http::Uri| async move {
            Problem::new(
                StatusCode::NOT_FOUND,
                "not-found",
                "Not found",
                format!(
                    "no route {} (the fleet role serves /api/v1/fleet/...)",
                    uri.path()
                ),
            )
        })
        .layer(axum::middleware::from_fn_with_state(state.clone(), viewer))
        .layer(axum::middleware::from_fn(super::guard::problem_everywhere))
        .with_state(state)
}

/// Every route but `/healthz` needs a viewer token (or none when no tokens
/// are configured: then the daemon listens on loopback only). Only reads.
async fn viewer(State(st): State<FleetState>, req: Request, next: Next) -> Response {
    if req.method() != axum::http::Method::GET && req.method() != axum::http::Method::HEAD {
        return Problem::new(
            StatusCode::METHOD_NOT_ALLOWED,
            "method-not-allowed",
            "Method not allowed",
            "the fleet role's API is read-only",
        )
        .into_response();
    }
    if st.cfg.open_access() || req.uri().path() == "/healthz" {
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
        Ok(()) => Json(json!({"status": "ok", "role": "fleet"})).into_response(),
        Err(e) => Problem::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "database-unreachable",
            "Database unreachable",
            e.to_string(),
        )
        .into_response(),
    }
}

/// `GET /api/v1/fleet/stations`: every station the center heard of.
async fn stations(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<Value>> {
    Params::of(q, &[])?;
    let items = st.store.stations().await?;
    Ok(Json(json!({ "items": items })))
}

/// `GET /api/v1/fleet/parts?after=&limit=` (keyset on serial).
async fn parts(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<Value>> {
    let p = Params::of(q, &["after", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let items = st.store.list_parts(p.str("after"), limit).await?;
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|x| x.serial.clone()))
        .flatten();
    Ok(Json(json!({ "items": items, "next_after": next })))
}

/// `GET /api/v1/fleet/parts/{serial}`: the part, its newest job verdict and
/// its measurements (newest first, at most 100), each with its station.
async fn part(State(st): State<FleetState>, Path(serial): Path<String>) -> ApiResult<Json<Value>> {
    let p = st
        .store
        .get_part(&serial)
        .await?
        .ok_or_else(|| Problem::not_found("part", &serial))?;
    let ms = st
        .store
        .list_measurements(Some(&serial), None, None, 100)
        .await?;
    let v = st.store.part_verdict(&serial).await?;
    Ok(Json(json!({ "part": p, "verdict": v, "measurements": ms })))
}

/// `GET /api/v1/fleet/measurements?station=&part=&job=&cursor=&limit=`
/// newest first; `next_cursor` is the cursor of the next page (as on a station).
async fn measurements(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<Value>> {
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
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|m| m.seq.to_string()))
        .flatten();
    Ok(Json(json!({ "items": items, "next_cursor": next })))
}

/// `GET /api/v1/fleet/measurements/{id}`: record, result document, meta.
async fn measurement(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    let (info, result, meta) = st
        .store
        .get_measurement(&id)
        .await?
        .ok_or_else(|| Problem::not_found("measurement", &id))?;
    let void = st.store.measurement_void(&id).await?;
    Ok(Json(
        json!({ "measurement": info, "result": result, "meta": meta, "void_reason": void }),
    ))
}

/// `GET /api/v1/fleet/recipes`: the newest version of every recipe.
async fn recipes(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<Value>> {
    Params::of(q, &[])?;
    Ok(Json(json!({ "items": st.store.list_recipes().await? })))
}

/// `GET /api/v1/fleet/recipes/{name}/verdicts?last=&since=&until=`: the
/// measurement verdicts of a recipe across stations, oldest first.
async fn verdicts(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    Query(q): Q,
) -> ApiResult<Json<Value>> {
    let p = Params::of(q, &["last", "since", "until"])?;
    let (since, until) = (p.time("since")?, p.time("until")?);
    let last = window_last(&p, &since, &until)?;
    let rows = st
        .store
        .recipe_verdicts(&name, since.as_deref(), until.as_deref(), last)
        .await?;
    let items: Vec<Value> = rows
        .iter()
        .map(|r| {
            let mut v = serde_json::to_value(r).unwrap_or(Value::Null);
            v["level_index"] = json!(r.level_index);
            v
        })
        .collect();
    Ok(Json(json!({ "items": items })))
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
async fn spc(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    Query(q): Q,
) -> ApiResult<Json<Value>> {
    let p = Params::of(q, &["parameter", "last", "since", "until"])?;
    let row = st
        .store
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let recipe: crate::qc::Recipe =
        serde_json::from_value(row.recipe.clone()).map_err(Problem::internal)?;
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
    let fleet = st.store.spc(&q(false)).await?;
    let stations = st.store.spc(&q(true)).await?;
    Ok(Json(json!({
        "recipe": name,
        "version": row.version,
        "parameter": pname,
        "fleet": fleet.into_iter().next().map(|g| g.spc),
        "stations": stations,
    })))
}

/// `GET /api/v1/fleet/recipes/{name}/yield?since=&until=`: job verdicts per
/// station and day (UTC); default the last 30 days.
async fn yield_per_day(
    State(st): State<FleetState>,
    Path(name): Path<String>,
    Query(q): Q,
) -> ApiResult<Json<Value>> {
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
    Ok(Json(json!({ "items": items })))
}

/// `GET /api/v1/fleet/audit?part=&after=&limit=`: corrections, oldest first.
async fn audit(State(st): State<FleetState>, Query(q): Q) -> ApiResult<Json<Value>> {
    let p = Params::of(q, &["part", "after", "limit"])?;
    let limit = p.int("limit", 1..=1000)?.unwrap_or(100);
    let after = p.int("after", 0..=i64::MAX)?;
    let items = st.store.audit_log(p.str("part"), after, limit).await?;
    Ok(Json(json!({ "items": items })))
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
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let local = listener
        .local_addr()
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let http = cfg.http.clone();
    let (max_conn, fd_note) = super::server::fit_connection_limit(http.max_connections);
    let app = router(FleetState {
        store: store.clone(),
        cfg: Arc::new(cfg),
    });
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
