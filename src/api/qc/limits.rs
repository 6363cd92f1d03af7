//! Limit proposals from golden units over HTTP: propose, list, approve, reject.

use super::parse_body;
use super::recipes::{located, recipe_response};
use crate::api::auth::Caller;
use crate::api::problem::{ApiResult, Problem};
use crate::api::{AppState, JsonBody};
use crate::qc::limits::{GoldenUnit, ProposalOptions};
use crate::qc::{Recipe, RunFacts};
use crate::runner::FieldError;
use crate::store::qc::Approval;
use crate::store::RecipeReads;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::Response;
use axum::{Extension, Json};
use serde::Deserialize;

#[derive(Deserialize, utoipa::ToSchema)]
pub struct ProposalBody {
    /// Serials of the golden units (each measured with the recipe, valid): 5 to 200.
    #[schema(min_items = 5, max_items = 200)]
    serials: Vec<String>,
    /// Serials of golden units to use although they fail the recipe's
    /// current limits (otherwise such units are left out and listed in
    /// `left_out`).
    #[serde(default)]
    #[schema(max_items = 200)]
    keep_failed: Vec<String>,
    #[serde(flatten)]
    options: ProposalOptions,
}

fn run_facts(g: &crate::store::qc::GoldenRow) -> RunFacts {
    RunFacts {
        report: g.result.clone(),
        analysis_error: g.analysis_error.clone(),
        target_xpeak_m: g.target_xpeak_m,
        level_index: g.level_index.unwrap_or(0).max(0) as usize,
        drive_v: g.config.narrow_sweep.as_ref().map(|n| n.drive_v),
        max_drive_v: g.config.limits.map(|l| l.max_drive_v),
        pre_drive_v: g.config.pre_sweep.as_ref().map(|p| p.sweep.drive_v),
        pre_q_drive_to_x: g.config.pre_sweep.as_ref().and_then(|p| p.q_drive_to_x),
    }
}

/// `POST /api/v1/recipes/{name}/limit-proposals`: limits from golden units
/// (their newest valid job under this recipe), stored as `proposed`.
#[utoipa::path(post, path = "/api/v1/recipes/{name}/limit-proposals", tag = "qc",
    summary = "Propose limits from N >= 5 golden units (their newest valid job under this recipe): per parameter mean +- k sigma or +- tolerance_percent of the mean, and a K(x) mask. Stored as `proposed` until an admin approves.",
    params(("name" = String, Path, description = "Recipe name")),
    request_body(content = ProposalBody, content_type = "application/json",
        example = json!({"serials": ["G-01", "G-02", "G-03", "G-04", "G-05"], "method": "k_sigma", "k": 6})),
    responses(
        (status = 201, description = "Proposed", body = crate::store::qc::ProposalRow,
            headers(("Location" = String, description = "The proposal"))),
        (status = 404, description = "No such recipe"),
        (status = 422, description = "Invalid fields, or a serial without a valid measurement under this recipe")))]
pub async fn propose(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(name): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let b: ProposalBody = parse_body(body)?;
    let mut errors = b.options.validate();
    if b.serials.len() > crate::qc::limits::MAX_GOLDEN {
        errors.push(crate::qc::FieldError {
            field: "serials".into(),
            message: format!(
                "{} serials; at most {} golden units",
                b.serials.len(),
                crate::qc::limits::MAX_GOLDEN
            ),
        });
    }
    if !errors.is_empty() {
        return Err(Problem::validation(errors));
    }
    let row = st
        .store
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let recipe = row.recipe;
    let mut golden = Vec::new();
    let mut errors = Vec::new();
    for (i, s) in b.serials.iter().enumerate() {
        match st.store.golden_measurements(&name, s).await? {
            Some(ms) if !ms.is_empty() => golden.push(GoldenUnit {
                serial: s.clone(),
                measurements: ms.iter().map(run_facts).collect(),
            }),
            _ => errors.push(FieldError {
                field: format!("serials[{i}]"),
                message: format!("part '{s}' has no valid measurement under recipe '{name}'"),
            }),
        }
    }
    if !errors.is_empty() {
        return Err(Problem::validation(errors));
    }
    let (golden, left_out, kept_failed) =
        crate::qc::limits::screen_golden(&recipe, golden, &b.keep_failed);
    let mut p = crate::qc::limits::propose(&recipe, &golden, &b.options).map_err(|e| {
        let named: Vec<&str> = left_out.iter().map(|l| l.serial.as_str()).collect();
        if named.is_empty() {
            Problem::field("serials", e)
        } else {
            Problem::field(
                "serials",
                format!(
                    "{e} ({} left out: they fail the current limits; keep_failed keeps them)",
                    named.join(", ")
                ),
            )
        }
    })?;
    p.left_out = left_out;
    p.kept_failed = kept_failed;
    let id = crate::runner::new_id();
    let row = st
        .store
        .insert_proposal(&id, &name, row.version, &p, caller.0.as_deref())
        .await?;
    Ok(located(
        StatusCode::CREATED,
        format!("/api/v1/limit-proposals/{id}"),
        crate::api::Sorted(&row),
    ))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/limit-proposals", tag = "qc",
    summary = "The recipe's newest 50 limit proposals (all states), newest first.",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Proposals", body = crate::api::schema::ProposalList),
        (status = 404, description = "No such recipe")))]
/// `GET /api/v1/recipes/{name}/limit-proposals`: the recipe's newest 50
/// proposals (all states), newest first.
pub async fn list_proposals(
    State(st): State<AppState>,
    Path(name): Path<String>,
) -> ApiResult<Json<crate::api::Sorted<crate::api::schema::ProposalList>>> {
    if st.store.get_recipe(&name, None).await?.is_none() {
        return Err(Problem::not_found("recipe", &name));
    }
    let items = st.store.recipe_proposals(&name, 50).await?;
    Ok(Json(crate::api::Sorted(crate::api::schema::ProposalList {
        items,
    })))
}

#[utoipa::path(get, path = "/api/v1/limit-proposals/{id}", tag = "qc",
    summary = "A limit proposal (statistics per parameter, the mask, the recipe it would make, state, who decided).",
    params(("id" = String, Path, description = "Proposal id")),
    responses(
        (status = 200, description = "Proposal", body = crate::store::qc::ProposalRow),
        (status = 404, description = "No such proposal")))]
pub async fn get_proposal(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<crate::api::Sorted<crate::store::qc::ProposalRow>>> {
    let p = st
        .store
        .get_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("limit proposal", &id))?;
    Ok(Json(crate::api::Sorted(p)))
}

fn decided(p: &crate::store::qc::ProposalRow) -> Problem {
    Problem::new(
        StatusCode::CONFLICT,
        "proposal-decided",
        "Proposal decided",
        format!("limit proposal '{}' is {} already", p.id, p.state),
    )
}

/// `POST /api/v1/limit-proposals/{id}/approve` (admin): a new recipe version
/// with the proposed limits; the approver and time are recorded.
#[utoipa::path(post, path = "/api/v1/limit-proposals/{id}/approve", tag = "qc",
    summary = "Approve a proposal: a new recipe version with its limits (origin limits_approved); approver and time are recorded on the proposal.",
    params(("id" = String, Path, description = "Proposal id")),
    responses(
        (status = 201, description = "The new recipe version", body = crate::api::schema::RecipeDocument,
            headers(("Location" = String, description = "The new version"))),
        (status = 404, description = "No such proposal"),
        (status = 409, description = "Decided already, or not made on the current version of a live recipe")))]
pub async fn approve(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    let p = st
        .store
        .get_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("limit proposal", &id))?;
    if p.state != "proposed" {
        return Err(decided(&p));
    }
    let recipe: &Recipe = &p.proposal.recipe;
    match st
        .store
        .approve_proposal(&id, &recipe.sha256(), recipe, caller.0.as_deref())
        .await?
    {
        Approval::Approved(row) => Ok(recipe_response(
            StatusCode::CREATED,
            Some(format!(
                "/api/v1/recipes/{}/versions/{}",
                row.name, row.version
            )),
            &row,
        )),
        Approval::Decided => Err(decided(&p)),
        Approval::Stale(why) => Err(Problem::new(
            StatusCode::CONFLICT,
            "proposal-stale",
            "Proposal stale",
            why,
        )),
    }
}

#[utoipa::path(post, path = "/api/v1/limit-proposals/{id}/reject", tag = "qc",
    summary = "Reject a proposal.",
    params(("id" = String, Path, description = "Proposal id")),
    responses(
        (status = 200, description = "Rejected", body = crate::store::qc::ProposalRow),
        (status = 404, description = "No such proposal"),
        (status = 409, description = "Decided already")))]
pub async fn reject(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> ApiResult<Json<crate::api::Sorted<crate::store::qc::ProposalRow>>> {
    let p = st
        .store
        .get_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("limit proposal", &id))?;
    if !st.store.reject_proposal(&id, caller.0.as_deref()).await? {
        return Err(decided(&p));
    }
    let p = st
        .store
        .get_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("limit proposal", &id))?;
    Ok(Json(crate::api::Sorted(p)))
}
