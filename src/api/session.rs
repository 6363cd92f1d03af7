//! `GET /api/v1/session`: who the caller is (token name and role), so a
//! client such as the web UI can show only the controls its role allows and
//! ask for a token only when one is needed. Open (no token needed): it tells
//! nothing but whether the token sent is known and its role.

use super::AppState;
use axum::extract::State;
use axum::http::HeaderMap;
use axum::Json;
use serde_json::{json, Value};

#[utoipa::path(get, path = "/api/v1/session", tag = "operations",
    summary = "Who the caller is (token name and role); open, so a client can tell whether it needs a token. The web UI shows the controls of this role.",
    responses((status = 200, description = "The caller", body = super::schema::Session)))]
pub async fn session(State(st): State<AppState>, headers: HeaderMap) -> Json<Value> {
    Json(caller(&st.cfg, &headers, "station"))
}

/// Who the caller is, at a `station` or at the fleet's `center` (the fleet
/// role's `/api/v1/session`).
pub fn caller(cfg: &crate::config::Config, headers: &HeaderMap, daemon: &str) -> Value {
    if cfg.open_access() {
        // No tokens configured: everything is open (loopback only).
        return json!({"name": null, "role": "admin", "auth_required": false, "daemon": daemon});
    }
    let t = super::auth::bearer_token(cfg, headers);
    json!({
        "name": t.map(|t| t.name.clone()),
        "role": t.map(|t| t.role),
        "auth_required": true,
        "daemon": daemon,
    })
}
