//! Bearer tokens with roles. Reads need `viewer`, submitting, cancelling,
//! importing and fitting need `operator`, the configuration needs `admin`.
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

/// The role a request needs; None for open routes.
pub fn required_role(method: &Method, path: &str) -> Option<Role> {
    if path == "/healthz"
        || path == "/readyz"
        || path == "/api/v1/session"
        || path == "/api/openapi.json"
        || crate::ui::is_public(path)
    {
        return None;
    }
    if path == "/api/v1/config" {
        return Some(Role::Admin);
    }
    // QC engineering (recipes, limit approval) and the MES outbox's retry/drop.
    let qc_admin = (path.starts_with("/api/v1/recipes")
        && !path.ends_with("/limit-proposals")
        && method != Method::GET
        && method != Method::HEAD)
        || (path.starts_with("/api/v1/limit-proposals/")
            && (path.ends_with("/approve") || path.ends_with("/reject")))
        || (path.starts_with("/api/v1/outbox/") && method != Method::GET);
    if qc_admin {
        return Some(Role::Admin);
    }
    if method == Method::GET || method == Method::HEAD {
        Some(Role::Viewer)
    } else {
        Some(Role::Operator)
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
    let Some(need) = required_role(req.method(), req.uri().path()) else {
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
