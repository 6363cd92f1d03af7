//! The center's ingest over HTTP (issue 36, decision 0105): the fleet role
//! is the only writer of the center's database. A station posts its hello
//! and its outbox items here with its own bearer token; the center binds the
//! token to the station's id (`[[stations]]` of its configuration), applies
//! the items in its own transaction (`PgStore::ingest`, idempotent by item
//! id) and stamps them with its own clock. A request claiming another
//! station's id, or a retired station's, is refused and recorded
//! (`GET /api/v1/fleet/refusals`), as is every item the center refuses.
//!
//! Routes (a station's, not the readers'; not in the OpenAPI document,
//! the contract is `crates/store/src/fleet.rs`):
//! - `POST /api/v1/fleet/ingest/hello`: a [`StationHello`] → the center's [`StationStatus`];
//! - `POST /api/v1/fleet/ingest/items`: `{"station_id", "items": [ReplicationItem]}` →
//!   an [`IngestReport`]; an item the center refuses: 422 `item-refused`, its reason
//!   in `detail` (nothing of the batch written);
//! - `GET /api/v1/fleet/ingest/recipes`: every recipe version ([`RecipeRow`]);
//! - `POST /api/v1/fleet/ingest/recipe-proposals`: a station publishes its
//!   local recipe ([`PublishRequest`]) as a proposal at the center, by
//!   `station:<id>` (decision 0106) → 201 and the proposal.

use super::FleetState;
use crate::api::problem::Problem;
use crate::config::StationCredential;
use crate::store::fleet::{CenterIngest, StationHello};
use crate::store::StoreError;
use axum::extract::{DefaultBodyLimit, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};

// The wire types both ends share live with the station's worker (a lower
// room: `fleet` may not import `api`, tests/it/layers.rs).
pub use crate::fleet::http::{ItemsRequest, PublishRequest, ITEM_REFUSED};

pub fn routes(max_body: usize) -> Router<FleetState> {
    Router::new()
        .route("/api/v1/fleet/ingest/hello", post(hello))
        .route("/api/v1/fleet/ingest/items", post(items))
        .route("/api/v1/fleet/ingest/recipes", get(recipes))
        .route("/api/v1/fleet/ingest/recipe-proposals", post(publish))
        .layer(DefaultBodyLimit::max(max_body))
}

/// True for the station routes (their own authentication, POST allowed).
pub fn is_ingest(path: &str) -> bool {
    path.starts_with("/api/v1/fleet/ingest/")
}

fn same(a: &[u8], b: &[u8]) -> bool {
    // Constant time in the secret's length: the token is a secret.
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |x, (p, q)| x | (p ^ q)) == 0
}

/// The station whose token the request carries, or the answer: 401
/// without a station's token, 403 for a retired station (recorded).
async fn caller<'a>(
    st: &'a FleetState,
    headers: &HeaderMap,
    claimed: Option<&str>,
) -> Result<&'a StationCredential, Response> {
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|s| s.split_once(' '))
        .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        .map(|(_, t)| t.trim().to_string());
    let found = token.as_deref().and_then(|t| {
        st.cfg
            .stations
            .iter()
            .find(|s| same(s.token.as_bytes(), t.as_bytes()))
    });
    let Some(s) = found else {
        if let Some(c) = claimed {
            let _ = st
                .store
                .record_refusal(c, None, "", None, "no valid station token")
                .await;
        }
        let mut p = Problem::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "Station token required",
            "a station posts with its own token ('Authorization: Bearer <[fleet] token>'), one of the center's [[stations]]",
        );
        p.headers.push((
            header::WWW_AUTHENTICATE,
            header::HeaderValue::from_static("Bearer realm=\"springbench-fleet-ingest\""),
        ));
        return Err(p.into_response());
    };
    if s.retired {
        let why = format!("station {} is retired at the center", s.station_id);
        let _ = st
            .store
            .record_refusal(
                claimed.unwrap_or(&s.station_id),
                Some(&s.station_id),
                "",
                None,
                &why,
            )
            .await;
        return Err(Problem::new(
            StatusCode::FORBIDDEN,
            "station-retired",
            "Station retired",
            why,
        )
        .into_response());
    }
    Ok(s)
}

/// 403 and a refusal row when the token's station is not the one claimed.
async fn bound(st: &FleetState, cred: &StationCredential, claimed: &str) -> Result<(), Response> {
    if cred.station_id == claimed {
        return Ok(());
    }
    let why = format!(
        "station {}'s credential claims station id '{claimed}'; a station delivers as itself only",
        cred.station_id
    );
    let _ = st
        .store
        .record_refusal(claimed, Some(&cred.station_id), "", None, &why)
        .await;
    Err(Problem::new(
        StatusCode::FORBIDDEN,
        "station-mismatch",
        "Not this station's credential",
        why,
    )
    .into_response())
}

// The error is the answer itself, made once per refused request.
#[allow(clippy::result_large_err)]
fn body<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, Response> {
    serde_json::from_slice(bytes).map_err(|e| {
        Problem::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-body",
            "Unreadable body",
            format!("the body is not the fleet contract's JSON: {e}"),
        )
        .into_response()
    })
}

/// A station's posted request: its body read, the caller's credential
/// checked (before a bad body is named: a stranger learns nothing of the
/// contract) and bound to the station the body claims.
async fn station_request<T: serde::de::DeserializeOwned>(
    st: &FleetState,
    headers: &HeaderMap,
    bytes: &[u8],
    station_id: impl Fn(&T) -> &str,
) -> Result<T, Response> {
    let req: Result<T, _> = body(bytes);
    let claimed = req.as_ref().ok().map(|r| station_id(r).to_string());
    let cred = caller(st, headers, claimed.as_deref()).await?;
    let req = req?;
    bound(st, cred, station_id(&req)).await?;
    Ok(req)
}

/// The answer to a store error: a refused item is 422 with its reason; an
/// unavailable database 503 with Retry-After and no internals.
fn store_error(e: StoreError) -> Response {
    match e {
        StoreError::Invalid(why) => Problem::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            ITEM_REFUSED,
            "Item refused",
            why,
        )
        .into_response(),
        e => {
            tracing::error!("fleet ingest: {e}");
            let mut p = Problem::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "center-unavailable",
                "The center cannot store now",
                "nothing of the request was stored; send it again later",
            );
            p.headers
                .push((header::RETRY_AFTER, header::HeaderValue::from_static("5")));
            p.into_response()
        }
    }
}

async fn hello(
    State(st): State<FleetState>,
    headers: HeaderMap,
    bytes: axum::body::Bytes,
) -> Response {
    let h = match station_request(&st, &headers, &bytes, |h: &StationHello| &h.station_id).await {
        Ok(h) => h,
        Err(r) => return r,
    };
    match st.store.hello(&h).await {
        Ok(s) => Json(s).into_response(),
        Err(e) => store_error(e),
    }
}

async fn items(
    State(st): State<FleetState>,
    headers: HeaderMap,
    bytes: axum::body::Bytes,
) -> Response {
    let req = match station_request(&st, &headers, &bytes, |r: &ItemsRequest| &r.station_id).await {
        Ok(r) => r,
        Err(r) => return r,
    };
    match st.store.ingest(&req.station_id, &req.items).await {
        Ok(report) => Json(report).into_response(),
        Err(e) => store_error(e),
    }
}

async fn recipes(State(st): State<FleetState>, headers: HeaderMap) -> Response {
    if let Err(r) = caller(&st, &headers, None).await {
        return r;
    }
    match st.store.recipes().await {
        Ok(rows) => Json(rows).into_response(),
        Err(e) => store_error(e),
    }
}

/// A station's local recipe, published: a proposal at the center by
/// `station:<id>`, which an approver there decides like any other.
async fn publish(
    State(st): State<FleetState>,
    headers: HeaderMap,
    bytes: axum::body::Bytes,
) -> Response {
    let req = match station_request(&st, &headers, &bytes, |r: &PublishRequest| &r.station_id).await
    {
        Ok(r) => r,
        Err(r) => return r,
    };
    let checked = serde_json::to_value(&req.recipe)
        .map_err(Problem::internal)
        .and_then(super::recipes::parse_recipe);
    let recipe = match checked {
        Ok(r) => r,
        Err(p) => return p.into_response(),
    };
    let note = req
        .note
        .filter(|n| !n.chars().any(char::is_control))
        .map(|n| n.chars().take(4096).collect());
    let p = springbench_store_pg::NewRecipeProposal {
        id: crate::runner::new_id(),
        recipe,
        base_version: None,
        note,
        proposed_by: Some(format!("station:{}", req.station_id)),
        station_id: Some(req.station_id.clone()),
        station_version: Some(req.version),
    };
    match super::recipes::store_proposal(&st, p).await {
        Ok(r) => r,
        Err(p) => p.into_response(),
    }
}
