//! Diagnostics and plots are computed once per fit and stored (issue 11/12):
//! the first request for any of them runs the diagnosis and renders every
//! plot, stores them all in one transaction, and every later request reads
//! the stored answer. Fits are immutable, so nothing is invalidated.
//!
//! Concurrent first requests for one measurement wait for a single
//! computation (one lock per measurement id); computations for different
//! measurements share the `http.max_expensive` slots with fits and imports,
//! which bounds the memory they hold (docs/http-hardening.md has the figures).
//! Reading a stored answer takes no slot.

use super::problem::{ApiResult, Problem};
use super::AppState;
use crate::diagnose;
use crate::store::Derived;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::json;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use tokio::sync::Semaphore;

/// The slots for expensive work (diagnoses, fits, imports), sized by the
/// first configuration that asks (the daemon has one).
pub fn expensive_slots(n: usize) -> Arc<Semaphore> {
    static SLOTS: OnceLock<Arc<Semaphore>> = OnceLock::new();
    SLOTS
        .get_or_init(|| Arc::new(Semaphore::new(n.max(1))))
        .clone()
}

type Locks = Mutex<HashMap<String, Arc<tokio::sync::Mutex<()>>>>;

fn locks() -> &'static Locks {
    static LOCKS: OnceLock<Locks> = OnceLock::new();
    LOCKS.get_or_init(Default::default)
}

pub const DIAGNOSTICS: &str = "diagnostics.json";

fn respond(d: Derived) -> Response {
    let status = StatusCode::from_u16(d.status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
    let ct = HeaderValue::from_str(&d.content_type)
        .unwrap_or(HeaderValue::from_static("application/octet-stream"));
    (status, [(header::CONTENT_TYPE, ct)], d.body).into_response()
}

/// The stored answer `name` (`diagnostics.json` or `<plot>.svg`) of the
/// measurement's own fit, computed and stored first if needed.
pub async fn answer(st: &AppState, id: &str, name: &str) -> ApiResult<Response> {
    if let Some(d) = st.store.get_derived(id, "", name).await? {
        return Ok(respond(d));
    }
    let lock = locks()
        .lock()
        .unwrap()
        .entry(id.to_string())
        .or_default()
        .clone();
    let res = {
        let _one = lock.lock().await;
        match st.store.get_derived(id, "", name).await? {
            Some(d) => Ok(d),
            None => compute(st, id, name).await,
        }
    };
    {
        // the last one out removes the lock (the map holds one reference)
        let mut m = locks().lock().unwrap();
        if Arc::strong_count(&lock) == 2 {
            m.remove(id);
        }
    }
    res.map(respond)
}

async fn compute(st: &AppState, id: &str, name: &str) -> ApiResult<Derived> {
    let slots = expensive_slots(st.cfg.http.max_expensive);
    let _slot = slots.acquire().await.map_err(Problem::internal)?;
    let items = match super::measurements::diagnose_stored(st, id).await {
        Ok((set, d)) => {
            let id2 = id.to_string();
            tokio::task::spawn_blocking(move || {
                // Never stored with a NaN written as null (issue 11).
                let checked = crate::finite::to_value(&d.report.model).and_then(|m| {
                    Ok((m, crate::finite::to_value(&d.report.diagnostics)?))
                });
                let (model, diagnostics) = match checked {
                    Ok(x) => x,
                    Err(e) => {
                        let p = Problem::new(
                            StatusCode::UNPROCESSABLE_ENTITY,
                            "analysis-failed",
                            "Diagnostics failed",
                            format!("result refused: {e}"),
                        );
                        return all_problems(&p);
                    }
                };
                let doc = json!({
                    "measurement_id": id2,
                    "model": model,
                    "diagnostics": diagnostics,
                    "plots": diagnose::plot_names().iter()
                        .map(|n| format!("/api/v1/measurements/{id2}/plots/{n}.svg")).collect::<Vec<_>>(),
                });
                let mut items = vec![Derived {
                    name: DIAGNOSTICS.into(),
                    status: 200,
                    content_type: "application/json".into(),
                    body: doc.to_string().into_bytes(),
                }];
                for n in diagnose::plot_names() {
                    let file = format!("{n}.svg");
                    items.push(match diagnose::plot(&set, &d, n) {
                        Some(svg) => Derived {
                            name: file,
                            status: 200,
                            content_type: "image/svg+xml".into(),
                            body: svg.into_bytes(),
                        },
                        None => problem_item(file.clone(), Problem::not_found("plot", &file)),
                    });
                }
                items
            })
            .await
            .map_err(Problem::internal)?
        }
        // A diagnosis that fails on this fit's data fails every time: kept too.
        Err(p) if p.status == StatusCode::UNPROCESSABLE_ENTITY => all_problems(&p),
        Err(p) => return Err(p),
    };
    st.store.put_derived(id, "", &items).await?;
    items
        .into_iter()
        .find(|d| d.name == name)
        .ok_or_else(|| Problem::not_found("plot", name))
}

/// The same problem as the answer to the diagnostics and every plot.
fn all_problems(p: &Problem) -> Vec<Derived> {
    let mut items = vec![problem_item(DIAGNOSTICS.into(), clone_problem(p))];
    for n in diagnose::plot_names() {
        items.push(problem_item(format!("{n}.svg"), clone_problem(p)));
    }
    items
}

fn clone_problem(p: &Problem) -> Problem {
    Problem::new(p.status, p.kind, p.title, p.detail.clone())
}

fn problem_item(name: String, p: Problem) -> Derived {
    Derived {
        name,
        status: p.status.as_u16(),
        content_type: "application/problem+json".into(),
        body: p.body().to_string().into_bytes(),
    }
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}/diagnostics", tag = "measurements",
    summary = "Model diagnostics of the stored recordings (candidate effects, model ladder, plot data and links); computed once, then served from the store.",
    params(("id" = String, Path, description = "Measurement id")),
    responses(
        (status = 200, description = "Diagnostics", body = super::schema::DiagnosticsDocument),
        (status = 404, description = "No such measurement"),
        (status = 410, description = "The retention policy removed the raw signals"),
        (status = 422, description = "The diagnosis fails on this data")))]
/// `GET /api/v1/measurements/{id}/diagnostics`: candidates and ladder of the
/// base model (computed once, then served from the store: this module).
pub async fn diagnostics(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    answer(&st, &id, DIAGNOSTICS).await
}

#[utoipa::path(get, path = "/api/v1/measurements/{id}/plots/{file}", tag = "measurements",
    summary = "A diagnostic plot as SVG (`{name}.svg`, names listed by the diagnostics).",
    params(("id" = String, Path, description = "Measurement id"),
        ("file" = String, Path, pattern = "^[a-z0-9_]+\\.svg$", description = "Plot file name")),
    responses(
        (status = 200, description = "SVG", content_type = "image/svg+xml", body = String),
        (status = 404, description = "No such measurement or plot"),
        (status = 410, description = "The retention policy removed the raw signals"),
        (status = 422, description = "The diagnosis fails on this data")))]
/// `GET /api/v1/measurements/{id}/plots/{name}.svg` (stored like the diagnostics).
pub async fn plot(
    State(st): State<AppState>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    file.strip_suffix(".svg")
        .filter(|n| diagnose::plot_names().contains(n))
        .ok_or_else(|| {
            Problem::not_found(
                &format!(
                    "plot (plots: {})",
                    diagnose::plot_names()
                        .iter()
                        .map(|n| format!("{n}.svg"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                &file,
            )
        })?;
    answer(&st, &id, &file).await
}
