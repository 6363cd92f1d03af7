//! Bearer tokens with roles. Reads need `viewer`, submitting, cancelling,
//! importing, fitting and proposing limits need `operator`; the
//! configuration, recipe changes, limit approval, corrections and the
//! outbox's retry and drop need `admin`. The role is decided per matched route template and
//! method ([`required_role`]), never from the path's text.
//! `/healthz`, `/readyz`, `/api/v1/session` (who am I) and the UI's pages
//! (`/`, `/ui/...`) are open. Without configured tokens everything is
//! open (the daemon then listens on loopback only). Websocket clients that
//! cannot set headers may pass `?token=`.

use super::problem::Problem;
use super::AppState;
use crate::config::Role;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

/// Who made a request: the token's name (None with open access). Handlers
/// read it as `Extension<Caller>` (traceability of jobs, recipes, approvals).
#[derive(Debug, Clone, Default)]
pub struct Caller(pub Option<String>);

/// The role a request needs; None for open routes. `route` is the route
/// template the router matched (`/api/v1/recipes/{name}`, axum's
/// `MatchedPath`), never the request's path: a recipe named
/// `limit-proposals` or `approve` is still a recipe. Unmatched requests
/// (404, 405) need a viewer token.
pub fn required_role(method: &Method, route: &str) -> Option<Role> {
    let read = method == Method::GET || method == Method::HEAD;
    match route {
        "/healthz" | "/readyz" | "/api/v1/session" | "/api/openapi.json" => None,
        r if crate::ui::is_public(r) => None,
        "/api/v1/config" => Some(Role::Admin),
        // QC engineering: recipes and the approval of limits.
        "/api/v1/recipes" | "/api/v1/recipes/{name}" | "/api/v1/recipes/{name}/publish"
            if !read =>
        {
            Some(Role::Admin)
        }
        // A bench calibration changes how the bench's measurements are judged.
        "/api/v1/recipes/{name}/bench-calibrations" if !read => Some(Role::Admin),
        "/api/v1/limit-proposals/{id}/approve" | "/api/v1/limit-proposals/{id}/reject" => {
            Some(Role::Admin)
        }
        // Corrections of parts and voids of measurements (the audit log is a read).
        "/api/v1/corrections" if !read => Some(Role::Admin),
        // The MES outbox's retry and drop.
        "/api/v1/outbox/{id}/retry" | "/api/v1/outbox/{id}" if !read => Some(Role::Admin),
        _ if read => Some(Role::Viewer),
        _ => Some(Role::Operator),
    }
}

fn same(a: &[u8], b: &[u8]) -> bool {
    // constant time for equal lengths
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The configured token named by a request's `Authorization: Bearer` header.
pub fn bearer_token<'a>(
    cfg: &'a crate::config::Config,
    headers: &axum::http::HeaderMap,
) -> Option<&'a crate::config::Token> {
    let s = headers.get(header::AUTHORIZATION)?.to_str().ok()?;
    let (scheme, tok) = s.split_once(' ')?;
    if !scheme.eq_ignore_ascii_case("bearer") {
        return None;
    }
    cfg.auth
        .tokens
        .iter()
        .find(|t| same(t.token.as_bytes(), tok.trim().as_bytes()))
}

fn token_from(req: &Request) -> Option<String> {
    if let Some(h) = req.headers().get(header::AUTHORIZATION) {
        let s = h.to_str().ok()?;
        let (scheme, tok) = s.split_once(' ')?;
        if scheme.eq_ignore_ascii_case("bearer") {
            return Some(tok.trim().to_string());
        }
        return None;
    }
    if req.uri().path() == "/api/v1/events" {
        let q = req.uri().query()?;
        // percent-decoded, as a browser's URLSearchParams encodes it
        for (k, v) in form_urlencoded::parse(q.as_bytes()) {
            if k == "token" {
                return Some(v.into_owned());
            }
        }
    }
    None
}

pub async fn require_role(State(st): State<AppState>, mut req: Request, next: Next) -> Response {
    req.extensions_mut().insert(Caller(None));
    if st.cfg.open_access() {
        return next.run(req).await;
    }
    let route = req
        .extensions()
        .get::<axum::extract::MatchedPath>()
        .map(|m| m.as_str().to_string())
        .unwrap_or_else(|| "unmatched".into());
    let Some(need) = required_role(req.method(), &route) else {
        return next.run(req).await;
    };
    let Some(tok) = token_from(&req) else {
        let mut p = Problem::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "Authentication required",
            "send 'Authorization: Bearer <token>'",
        );
        p.headers.push((
            header::WWW_AUTHENTICATE,
            HeaderValue::from_static("Bearer realm=\"springbench\""),
        ));
        return p.into_response();
    };
    let found = st
        .cfg
        .auth
        .tokens
        .iter()
        .find(|t| same(t.token.as_bytes(), tok.as_bytes()));
    match found {
        None => {
            let mut p = Problem::new(
                StatusCode::UNAUTHORIZED,
                "unauthorized",
                "Invalid token",
                "the bearer token is not known",
            );
            p.headers.push((
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"springbench\", error=\"invalid_token\""),
            ));
            p.into_response()
        }
        Some(t) if t.role < need => Problem::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            "Forbidden",
            format!(
                "token '{}' has role {:?}; this request needs {:?}",
                t.name, t.role, need
            )
            .to_lowercase(),
        )
        .into_response(),
        Some(t) => {
            let name = t.name.clone();
            req.extensions_mut().insert(Caller(Some(name)));
            next.run(req).await
        }
    }
}
