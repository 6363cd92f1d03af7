//! `GET /api/v1/recipes/{name}/lot.csv`: the lot export (issue 35). The
//! table is `crate::qc::lot`; this reads the verdicts and their trace.

use super::verdicts::VerdictWindow;
use crate::api::problem::{ApiResult, Problem};
use crate::api::reads::Reads;
use crate::api::Q;
use crate::qc::lot::LotRow;
use crate::store::RecipeReads;
use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct LotQuery {
    /// Verdicts judged at or after this time (RFC 3339).
    #[param(format = DateTime)]
    since: Option<String>,
    /// Verdicts judged before this time (RFC 3339).
    #[param(format = DateTime)]
    until: Option<String>,
    /// The pool exported: `production` (default), another purpose, or `all`
    /// (decision 0100). The `purpose` column names each row's.
    #[param(
        pattern = "^(all|production|golden_unit|bench_calibration|gauge_study|repeat|engineering)$"
    )]
    purpose: Option<String>,
}

/// `GET /api/v1/recipes/{name}/lot.csv?since=&until=&purpose=`.
#[utoipa::path(get, path = "/api/v1/recipes/{name}/lot.csv", tag = "qc",
    summary = "The lot export: every measurement verdict of the recipe in the window and pool (default production), oldest first, as CSV. One row per measurement (time_utc, part_serial, measurement_id, job_id, level_index, bench_id, recipe_name, recipe_version, purpose, verdict), then per parameter its value (`NAME [UNIT]`, the shortest form that reads back as the same number) and its result (`pass`, `fail`, `not_judged`; an invalid measurement is never judged), then invalid_reasons and note. Voided measurements are left out. At most as many verdicts as the SPC window holds: a larger window is a 422.",
    params(("name" = String, Path, description = "Recipe name"), LotQuery),
    responses(
        (status = 200, description = "The lot", content((String = "text/csv"))),
        (status = 404, description = "No such recipe"),
        (status = 422, description = "A bad query parameter, or a window holding too many verdicts")))]
pub async fn lot_csv<R: Reads>(
    State(st): State<R>,
    Path(name): Path<String>,
    Q(q): Q<LotQuery>,
) -> ApiResult<Response> {
    st.results()
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let w = VerdictWindow::parse(q.since.as_deref(), q.until.as_deref(), q.purpose.as_deref())?;
    let rows = w.read(&st, &name, None, "export it in parts").await?;
    let lot: Vec<LotRow> = rows
        .into_iter()
        .map(|r| {
            let trace = r.trace().ok();
            LotRow {
                time_utc: r.created_at.clone(),
                part_serial: r.part_serial.clone(),
                measurement_id: r.measurement_id.clone().unwrap_or_default(),
                job_id: r.job_id.clone(),
                level_index: r.level_index,
                bench_id: trace.as_ref().map(|t| t.bench_id.clone()),
                recipe_name: r.recipe_name.clone(),
                recipe_version: r.recipe_version,
                purpose: trace.as_ref().map(|t| t.purpose),
                verdict: r.verdict.clone(),
                detail: r.shown_detail(),
            }
        })
        .collect();
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"lot-{}.csv\"", safe_file_name(&name)),
            ),
        ],
        crate::qc::lot::to_csv(&lot),
    )
        .into_response())
}

/// A recipe name as a file name: letters, digits, `-`, `_` and `.`; the rest `_`.
fn safe_file_name(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}
