//! The stations' long-term tests at the fleet's center (issue 32, decision
//! 0134): the station's own routes, read only, from the documents the
//! stations sent. Each answer names the station that runs the test; the
//! series' CSV is built from the center's copies of the intervals'
//! measurements; the last signals before a failure stay at the station.

use super::FleetState;
use crate::api::problem::{ApiResult, Problem};
use crate::api::Sorted;
use crate::store::longterm::LongTermInterval;
use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use springbench_store_pg::longterm::CenterLongTerm;

/// A station's long-term test at the center: the station's own document
/// (or list line), with the station that runs it.
#[derive(Serialize)]
pub struct AtStation {
    /// The station that runs the test (and holds its last signals).
    pub station_id: String,
    /// The station's outbox sequence number of this copy, and when the
    /// center received it (RFC 3339 UTC): how current the copy is.
    pub copy_seq: i64,
    pub copy_received_at: String,
    #[serde(flatten)]
    pub document: Value,
}

impl AtStation {
    fn of(t: CenterLongTerm, list: bool) -> AtStation {
        AtStation {
            station_id: t.station_id,
            copy_seq: t.item_seq,
            copy_received_at: t.received_at,
            document: if list { t.summary } else { t.document },
        }
    }
}

/// `GET /api/v1/long-term-tests` at the center.
#[derive(Serialize)]
pub struct CenterLongTermList {
    pub items: Vec<AtStation>,
}

#[derive(Deserialize)]
pub struct ListQuery {
    /// At most this many tests, newest first (default 100, at most 1000).
    pub limit: Option<i64>,
    /// Only this station's tests.
    pub station: Option<String>,
}

/// `GET /api/v1/long-term-tests`: every station's tests, newest first.
pub async fn list(
    State(st): State<FleetState>,
    Query(q): Query<ListQuery>,
) -> ApiResult<Json<Sorted<CenterLongTermList>>> {
    let limit = crate::api::longterm::list_limit(q.limit)?;
    let items = st
        .store
        .long_term_tests(q.station.as_deref(), limit)
        .await?
        .into_iter()
        .map(|t| AtStation::of(t, true))
        .collect();
    Ok(Json(Sorted(CenterLongTermList { items })))
}

async fn held(st: &FleetState, id: &str) -> ApiResult<CenterLongTerm> {
    st.store
        .long_term_test(id)
        .await?
        .ok_or_else(|| Problem::not_found("long-term test", id))
}

/// `GET /api/v1/long-term-tests/{id}`: the station's document of the test.
pub async fn get_one(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Sorted<AtStation>>> {
    Ok(Json(Sorted(AtStation::of(held(&st, &id).await?, false))))
}

/// The intervals of a station's document, typed.
#[derive(Deserialize)]
struct Intervals {
    intervals: Vec<LongTermInterval>,
}

/// `GET /api/v1/long-term-tests/{id}/series.csv`: as the station's, from the
/// center's copies of the intervals' measurements.
pub async fn series_csv(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    let t = held(&st, &id).await?;
    let Intervals { intervals } = serde_json::from_value(t.document).map_err(|e| {
        Problem::internal(format!(
            "long-term test {id}: the station's document has no readable intervals: {e}"
        ))
    })?;
    let out = crate::api::longterm::series_text(&st.store, &intervals).await?;
    Ok(([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], out).into_response())
}

/// `GET /api/v1/long-term-tests/{id}/last-signals.wav`: the bytes stay at
/// the station; a 404 naming it.
pub async fn last_signals(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    let t = held(&st, &id).await?;
    if !t.last_signals_at_station {
        return Err(Problem::not_found("last signals of long-term test", &id));
    }
    Err(Problem::new(
        StatusCode::NOT_FOUND,
        "signals-at-station",
        "Signals held by the station",
        format!(
            "the last signals before the failure of long-term test '{id}' are on station '{}': download them there",
            t.station_id
        ),
    ))
}
