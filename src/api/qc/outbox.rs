//! The MES outbox over HTTP: list deliveries, retry, drop.

use crate::api::problem::{ApiResult, Problem};
use crate::api::{AppState, Q};
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::Json;
use serde::Deserialize;

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct OutboxQuery {
    /// pending, failed, delivered or dropped (default: pending and failed).
    #[param(pattern = "^(pending|failed|delivered|dropped)$")]
    state: Option<String>,
    /// Page size (1-500, default 50).
    limit: Option<i64>,
}

#[utoipa::path(get, path = "/api/v1/outbox", tag = "mes",
    summary = "MES outbox deliveries, oldest first (default pending and failed), with the totals.",
    params(OutboxQuery),
    responses(
        (status = 200, description = "Outbox", body = crate::api::schema::Outbox),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/outbox?state=`: deliveries (default: pending and failed), oldest first.
pub async fn outbox(
    State(st): State<AppState>,
    Q(q): Q<OutboxQuery>,
) -> ApiResult<Json<crate::api::Sorted<crate::api::schema::Outbox>>> {
    let state = match q.state.as_deref() {
        None | Some("") => None,
        Some(s @ ("pending" | "failed" | "delivered" | "dropped")) => Some(s),
        Some(_) => {
            return Err(Problem::field(
                "state",
                "one of pending, failed, delivered, dropped",
            ))
        }
    };
    let limit = crate::api::page_limit(q.limit)?;
    let items = st.store.list_outbox(state, limit).await?;
    let (pending, failed, failures) = st.store.outbox_counts().await?;
    Ok(Json(crate::api::Sorted(crate::api::schema::Outbox {
        items,
        pending,
        failed,
        failed_attempts_total: failures,
    })))
}

fn delivery_id(id: &str) -> ApiResult<i64> {
    id.parse::<i64>()
        .map_err(|_| Problem::not_found("outbox delivery", id))
}

/// `POST /api/v1/outbox/{id}/retry` (admin): a pending or failed delivery is tried now.
#[utoipa::path(post, path = "/api/v1/outbox/{id}/retry", tag = "mes",
    summary = "Retry a failed delivery now (attempts start again).",
    params(("id" = i64, Path, description = "Delivery id")),
    responses(
        (status = 200, description = "The delivery, pending again", body = crate::store::qc::DeliveryRow),
        (status = 404, description = "No such delivery"),
        (status = 409, description = "Delivered or dropped")))]
pub async fn outbox_retry(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<crate::api::Sorted<crate::store::qc::DeliveryRow>>> {
    change_delivery(&st, &id, DeliveryChange::Retry).await
}

/// `DELETE /api/v1/outbox/{id}` (admin): the delivery is dropped (the message stays stored).
#[utoipa::path(delete, path = "/api/v1/outbox/{id}", tag = "mes",
    summary = "Drop a delivery (it is kept, state dropped, never sent).",
    params(("id" = i64, Path, description = "Delivery id")),
    responses(
        (status = 200, description = "The delivery, dropped", body = crate::store::qc::DeliveryRow),
        (status = 404, description = "No such delivery"),
        (status = 409, description = "Delivered or dropped already")))]
pub async fn outbox_drop(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<crate::api::Sorted<crate::store::qc::DeliveryRow>>> {
    change_delivery(&st, &id, DeliveryChange::Drop).await
}

enum DeliveryChange {
    Retry,
    Drop,
}

/// Retries or drops a pending or failed delivery and wakes the worker;
/// 404 when there is none, 409 when it is final already; the delivery after
/// the change.
async fn change_delivery(
    st: &AppState,
    id: &str,
    change: DeliveryChange,
) -> ApiResult<Json<crate::api::Sorted<crate::store::qc::DeliveryRow>>> {
    let n = delivery_id(id)?;
    let d = st
        .store
        .get_delivery(n)
        .await?
        .ok_or_else(|| Problem::not_found("outbox delivery", id))?;
    let changed = match change {
        DeliveryChange::Retry => st.store.retry_delivery(n).await?,
        DeliveryChange::Drop => st.store.drop_delivery(n).await?,
    };
    if !changed {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "delivery-final",
            "Delivery final",
            format!("delivery {id} is {}", d.state),
        ));
    }
    st.runner.outbox_wake().notify_one();
    let d = st
        .store
        .get_delivery(n)
        .await?
        .ok_or_else(|| Problem::not_found("outbox delivery", id))?;
    Ok(Json(crate::api::Sorted(d)))
}
