//! `GET /api/v1/events?after=N` (websocket): replays the stored events after
//! sequence number N, then streams new ones. Each message is one JSON event
//! `{"seq", "time", "type", "job_id", "data"}`; live samples carry
//! `"live": true` and the `seq` of the last stored event (they are not stored
//! and not replayed). Without `after`, only new events are sent.

use super::problem::{ApiResult, Problem};
use super::{AppState, Q};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::response::Response;
use serde::Deserialize;
use tokio::sync::broadcast::error::RecvError;

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct EventsQuery {
    /// Replay the stored events after this sequence number (>= 0), then stream.
    after: Option<i64>,
    /// The bearer token, for browsers (which cannot set headers on a websocket).
    #[allow(dead_code)]
    token: Option<String>,
}

#[utoipa::path(get, path = "/api/v1/events", tag = "events",
    summary = "Websocket event stream. Replays stored events after `after`, then streams new ones.",
    description = "Each text message is one event `{\"seq\", \"time\", \"type\", \"job_id\", \"data\"}`. Types: `job.state` (`data.state`, `problem`, `measurement_ids`), `job.progress` (`step`, `progress`, `eta_s`), `measurement.created`, and `job.samples` (live decimated `x_m` and `microphone_v` with `t0_s`, `dt_s`; `\"live\": true`, not stored, not replayed). Without `after` only new events are sent.",
    params(EventsQuery),
    responses(
        (status = 101, description = "Switching to the websocket protocol"),
        (status = 426, description = "Not a websocket upgrade request (header `Upgrade: websocket`)"),
        (status = 422, description = "`after` below 0")))]
pub async fn events(
    State(st): State<AppState>,
    Q(q): Q<EventsQuery>,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> ApiResult<Response> {
    let ws = ws.map_err(|e| {
        // RFC 6455 / 9110: a plain request to a websocket-only resource is 426.
        let mut p = Problem::new(
            axum::http::StatusCode::UPGRADE_REQUIRED,
            "websocket-required",
            "Websocket upgrade required",
            format!("{} (connect with a websocket client)", e.body_text()),
        );
        p.headers.push((
            axum::http::header::UPGRADE,
            axum::http::HeaderValue::from_static("websocket"),
        ));
        p.headers.push((
            axum::http::header::CONNECTION,
            axum::http::HeaderValue::from_static("upgrade"),
        ));
        p
    })?;
    if let Some(a) = q.after {
        if a < 0 {
            return Err(Problem::field("after", "must be >= 0"));
        }
    }
    Ok(ws.on_upgrade(move |socket| stream(socket, st, q.after)))
}

const REPLAY_BATCH: i64 = 500;

async fn replay(st: &AppState, socket: &mut WebSocket, last: &mut i64) -> Result<(), ()> {
    loop {
        let batch = st
            .store
            .events_after(*last, REPLAY_BATCH)
            .await
            .map_err(|e| tracing::warn!("event replay failed: {e}"))?;
        let n = batch.len() as i64;
        for e in batch {
            *last = e.seq;
            let text = serde_json::to_string(&e).map_err(|_| ())?;
            socket
                .send(Message::Text(text.into()))
                .await
                .map_err(|_| ())?;
        }
        if n < REPLAY_BATCH {
            return Ok(());
        }
    }
}

async fn stream(mut socket: WebSocket, st: AppState, after: Option<i64>) {
    let mut rx = st.runner.events().subscribe();
    let mut shutdown = st.shutdown.clone();
    let mut last = match after {
        Some(a) => a,
        None => match st.store.last_event_seq().await {
            Ok(s) => s,
            Err(_) => return,
        },
    };
    if replay(&st, &mut socket, &mut last).await.is_err() {
        return;
    }
    loop {
        tokio::select! {
            r = rx.recv() => match r {
                Ok(ev) => {
                    if !ev.live && ev.event.seq <= last {
                        continue;
                    }
                    if !ev.live {
                        last = ev.event.seq;
                    }
                    let Ok(text) = serde_json::to_string(&*ev) else { continue };
                    if socket.send(Message::Text(text.into())).await.is_err() {
                        return;
                    }
                }
                Err(RecvError::Lagged(_)) => {
                    // Too slow: catch up from the database (live samples are lost).
                    if replay(&st, &mut socket, &mut last).await.is_err() {
                        return;
                    }
                }
                Err(RecvError::Closed) => break,
            },
            m = socket.recv() => match m {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return,
                Some(Ok(_)) => {}
            },
            _ = shutdown.changed() => break,
        }
    }
    let _ = socket.send(Message::Close(None)).await;
}
