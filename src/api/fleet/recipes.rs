//! Recipes authored at the center (issue 36, decision 0106). The center's
//! readers' tokens (`[auth] tokens`) carry the roles: a `viewer` reads, an
//! `operator` is a recipe **author** (proposes a new recipe, a new version,
//! new limits), an `admin` is an **approver** (approves or rejects a
//! proposal, retires a recipe) and never approves a proposal of their own.
//! An approved proposal is the recipe's next version; the stations take it
//! (`GET /api/v1/fleet/ingest/recipes`) and their verdicts name it with its
//! approver (`traceability.recipe.origin`). A station publishes its local
//! recipe as a proposal (`POST /api/v1/fleet/ingest/recipe-proposals`).

use super::FleetState;
use crate::api::problem::{ApiResult, Problem};
use crate::api::JsonBody;
use crate::config::Role;
use crate::qc::Recipe;
use crate::store::results::RecipeRow;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use springbench_store_pg::{Decided, NewRecipeProposal, ProposalState, Proposed, RecipeProposal};

/// The token's name when it has role `need` (None with open access): 401
/// without a reader's token, 403 with a lower role.
pub(super) fn authorised(
    st: &FleetState,
    headers: &HeaderMap,
    need: Role,
    what: &str,
) -> ApiResult<Option<String>> {
    if st.cfg.open_access() {
        return Ok(None);
    }
    let Some(t) = crate::api::auth::bearer_token(&st.cfg, headers) else {
        let mut p = Problem::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "Authentication required",
            "send 'Authorization: Bearer <token>'",
        );
        p.headers.push((
            header::WWW_AUTHENTICATE,
            HeaderValue::from_static("Bearer realm=\"springbench-fleet\""),
        ));
        return Err(p);
    };
    if t.role < need {
        return Err(Problem::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            "Forbidden",
            format!(
                "token '{}' has role {}; {what} needs {} at the center",
                t.name,
                role_name(t.role),
                role_name(need)
            ),
        ));
    }
    Ok(Some(t.name.clone()))
}

fn role_name(r: Role) -> &'static str {
    match r {
        Role::Viewer => "viewer",
        Role::Operator => "operator (a recipe author)",
        Role::Admin => "admin (a recipe approver)",
    }
}

/// A proposal's body.
#[derive(Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProposalBody {
    /// The recipe as it is to be (a new one, a new version, new limits).
    #[schema(value_type = crate::qc::Recipe)]
    pub recipe: serde_json::Value,
    /// The version this change is made on (from `GET /api/v1/fleet/recipes`);
    /// 409 when the recipe moved on. Without it: the newest.
    #[serde(default)]
    #[schema(minimum = 1)]
    pub base_version: Option<i64>,
    /// Why (at most 4 096 characters).
    #[serde(default)]
    #[schema(max_length = 4096)]
    pub note: Option<String>,
}

/// A decision's body (a rejection's reason).
#[derive(Deserialize, Default, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DecisionBody {
    /// Why (required to reject; at most 4 096 characters).
    #[serde(default)]
    #[schema(max_length = 4096)]
    pub reason: Option<String>,
}

/// A retirement's body.
#[derive(Deserialize, Default, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RetireBody {
    /// One version; without it every version (the recipe).
    #[serde(default)]
    #[schema(minimum = 1)]
    pub version: Option<i64>,
}

/// A page of proposals, newest first.
#[derive(Serialize, utoipa::ToSchema)]
pub struct ProposalPage {
    pub items: Vec<RecipeProposal>,
    /// `before` for the next (older) page; null on the last.
    pub next_before: Option<i64>,
}

/// A text field a person typed: no control character, at most `max`.
fn text(field: &str, v: Option<String>, max: usize) -> ApiResult<Option<String>> {
    match v {
        Some(s) if s.chars().any(char::is_control) => Err(Problem::field(
            field,
            "holds a control character (NUL, ...)",
        )),
        Some(s) if s.chars().count() > max => {
            Err(Problem::field(field, format!("at most {max} characters")))
        }
        Some(s) if s.trim().is_empty() => Ok(None),
        v => Ok(v),
    }
}

/// The recipe of a body, checked as a station checks it; a field is named
/// under `recipe.` (RFC 9457 problem, 422).
pub(super) fn parse_recipe(v: serde_json::Value) -> ApiResult<Recipe> {
    let r: Recipe = serde_path_to_error::deserialize(v).map_err(|e| {
        let path = e.path().to_string();
        let field = if path.is_empty() || path == "." {
            "recipe".to_string()
        } else {
            format!("recipe.{path}")
        };
        Problem::field(&field, e.into_inner().to_string())
    })?;
    r.validate().map_err(|errs| {
        Problem::validation(
            errs.into_iter()
                .map(|mut e| {
                    e.field = format!("recipe.{}", e.field);
                    e
                })
                .collect(),
        )
    })?;
    Ok(r)
}

fn located(status: StatusCode, loc: &str, body: impl Serialize) -> Response {
    let mut r = (status, Json(body)).into_response();
    if let Ok(v) = HeaderValue::from_str(loc) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    r
}

/// Stores a proposal; the answer (201, or the 409 problem).
pub(super) async fn store_proposal(st: &FleetState, p: NewRecipeProposal) -> ApiResult<Response> {
    let name = p.recipe.name.clone();
    match st.store.propose_recipe(&p).await? {
        Proposed::Stored(row) => Ok(located(
            StatusCode::CREATED,
            &format!("/api/v1/fleet/recipe-proposals/{}", row.id),
            &*row,
        )),
        Proposed::Stale(cur) => Err(Problem::new(
            StatusCode::CONFLICT,
            "recipe-moved-on",
            "Recipe moved on",
            match cur {
                Some(v) => format!(
                    "recipe '{name}' is at version {v}, not base_version {}: read it again",
                    p.base_version.unwrap_or(0)
                ),
                None => {
                    format!("there is no recipe '{name}' (leave base_version out to create it)")
                }
            },
        )),
        Proposed::Unchanged(v) => Err(Problem::new(
            StatusCode::CONFLICT,
            "recipe-unchanged",
            "Recipe unchanged",
            format!("version {v} of recipe '{name}' has this content already"),
        )),
    }
}

#[utoipa::path(post, path = "/api/v1/fleet/recipe-proposals", tag = "fleet",
    summary = "Propose a recipe at the center (a recipe author: role operator): a new recipe, a new version or new limits. An approver (admin, not the author) makes it the next version, which the stations take.",
    request_body(content = ProposalBody, content_type = "application/json"),
    responses(
        (status = 201, description = "Proposed", body = RecipeProposal,
            headers(("Location" = String, description = "The proposal"))),
        (status = 401, description = "No reader's token"),
        (status = 403, description = "The token is a viewer's"),
        (status = 409, description = "The recipe moved on from base_version, or has this content already"),
        (status = 422, description = "Invalid fields (named, e.g. recipe.parameters[0].upper)")))]
pub async fn propose(
    State(st): State<FleetState>,
    headers: HeaderMap,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let by = authorised(&st, &headers, Role::Operator, "proposing a recipe")?;
    let b: ProposalBody = crate::api::qc::parse_body(body)?;
    let recipe = parse_recipe(b.recipe)?;
    if b.base_version.is_some_and(|v| v < 1) {
        return Err(Problem::field("base_version", "a version number, from 1"));
    }
    let note = text("note", b.note, 4096)?;
    store_proposal(
        &st,
        NewRecipeProposal {
            id: crate::runner::new_id(),
            recipe,
            base_version: b.base_version,
            note,
            proposed_by: by,
            station_id: None,
            station_version: None,
        },
    )
    .await
}

#[utoipa::path(get, path = "/api/v1/fleet/recipe-proposals", tag = "fleet",
    summary = "Recipe proposals at the center, newest first (of one recipe, in one state).",
    params(
        ("recipe" = Option<String>, Query, description = "A recipe's name"),
        ("state" = Option<String>, Query, description = "proposed, approved or rejected"),
        ("before" = Option<i64>, Query, minimum = 1, description = "The `next_before` of the previous page"),
        ("limit" = Option<i64>, Query, minimum = 1, maximum = 500, description = "Page size (default 50)")),
    responses(
        (status = 200, description = "Proposals", body = ProposalPage),
        (status = 422, description = "A bad query parameter (named)")))]
pub async fn list(
    State(st): State<FleetState>,
    Query(q): Query<Vec<(String, String)>>,
) -> ApiResult<Json<ProposalPage>> {
    let p = super::Params::of(q, &["recipe", "state", "before", "limit"])?;
    let state = match p.str("state") {
        None => None,
        Some("proposed") => Some(ProposalState::Proposed),
        Some("approved") => Some(ProposalState::Approved),
        Some("rejected") => Some(ProposalState::Rejected),
        Some(s) => {
            return Err(Problem::field(
                "state",
                format!("proposed, approved or rejected, got '{s}'"),
            ))
        }
    };
    let before = p.int("before", 1..=i64::MAX)?;
    let limit = p.int("limit", 1..=500)?.unwrap_or(50);
    let rows = st
        .store
        .recipe_proposals(p.str("recipe"), state, before, limit)
        .await?;
    let next_before = (rows.len() as i64 == limit)
        .then(|| rows.last().map(|r| r.0))
        .flatten();
    Ok(Json(ProposalPage {
        items: rows.into_iter().map(|r| r.1).collect(),
        next_before,
    }))
}

#[utoipa::path(get, path = "/api/v1/fleet/recipe-proposals/{id}", tag = "fleet",
    summary = "One recipe proposal (its recipe, author, state, who decided, the version it became).",
    params(("id" = String, Path, description = "Proposal id")),
    responses(
        (status = 200, description = "Proposal", body = RecipeProposal),
        (status = 404, description = "No such proposal")))]
pub async fn get_one(
    State(st): State<FleetState>,
    Path(id): Path<String>,
) -> ApiResult<Json<RecipeProposal>> {
    st.store
        .recipe_proposal(&id)
        .await?
        .map(Json)
        .ok_or_else(|| Problem::not_found("recipe proposal", &id))
}

fn decided(p: &RecipeProposal) -> Problem {
    Problem::new(
        StatusCode::CONFLICT,
        "proposal-decided",
        "Proposal decided",
        format!("recipe proposal '{}' is {:?} already", p.id, p.state).to_lowercase(),
    )
}

#[utoipa::path(post, path = "/api/v1/fleet/recipe-proposals/{id}/approve", tag = "fleet",
    summary = "Approve a recipe proposal (a recipe approver: role admin, not its author): the recipe's next version (origin created / edited / limits_approved, approved_by), which the stations take.",
    params(("id" = String, Path, description = "Proposal id")),
    responses(
        (status = 201, description = "The new recipe version", body = crate::api::schema::RecipeDocument,
            headers(("Location" = String, description = "The new version"))),
        (status = 401, description = "No reader's token"),
        (status = 403, description = "Not an approver, or the proposal's own author"),
        (status = 404, description = "No such proposal"),
        (status = 409, description = "Decided already, or the recipe moved on since")))]
pub async fn approve(
    State(st): State<FleetState>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    let by = authorised(&st, &headers, Role::Admin, "approving a recipe")?;
    let p = st
        .store
        .recipe_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("recipe proposal", &id))?;
    if by.is_some() && by == p.proposed_by {
        return Err(Problem::new(
            StatusCode::FORBIDDEN,
            "own-proposal",
            "Own proposal",
            format!(
                "'{}' proposed this recipe; another approver approves it (four eyes)",
                by.unwrap_or_default()
            ),
        ));
    }
    match st
        .store
        .decide_recipe_proposal(&id, true, by.as_deref(), None)
        .await?
    {
        Decided::Approved(row) => Ok(version_response(&row)),
        Decided::Unknown => Err(Problem::not_found("recipe proposal", &id)),
        Decided::AlreadyDecided(p) => Err(decided(&p)),
        Decided::Stale(why) => Err(Problem::new(
            StatusCode::CONFLICT,
            "proposal-stale",
            "Proposal stale",
            why,
        )),
        Decided::Rejected(_) => Err(Problem::internal("an approval rejected")),
    }
}

fn version_response(row: &RecipeRow) -> Response {
    let doc = crate::api::Sorted(crate::api::schema::RecipeDocument::of(row));
    let mut r = located(
        StatusCode::CREATED,
        &format!("/api/v1/recipes/{}/versions/{}", row.name, row.version),
        doc,
    );
    if let Ok(v) = HeaderValue::from_str(&crate::api::qc::etag(row)) {
        r.headers_mut().insert(header::ETAG, v);
    }
    r
}

#[utoipa::path(post, path = "/api/v1/fleet/recipe-proposals/{id}/reject", tag = "fleet",
    summary = "Reject a recipe proposal (role admin), with a reason.",
    params(("id" = String, Path, description = "Proposal id")),
    request_body(content = DecisionBody, content_type = "application/json"),
    responses(
        (status = 200, description = "Rejected", body = RecipeProposal),
        (status = 401, description = "No reader's token"),
        (status = 403, description = "Not an approver"),
        (status = 404, description = "No such proposal"),
        (status = 409, description = "Decided already"),
        (status = 422, description = "No reason")))]
pub async fn reject(
    State(st): State<FleetState>,
    headers: HeaderMap,
    Path(id): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Json<RecipeProposal>> {
    let by = authorised(&st, &headers, Role::Admin, "rejecting a recipe")?;
    let b: DecisionBody = crate::api::qc::parse_body(body)?;
    let reason = text("reason", b.reason, 4096)?
        .ok_or_else(|| Problem::field("reason", "say why the proposal is rejected"))?;
    match st
        .store
        .decide_recipe_proposal(&id, false, by.as_deref(), Some(&reason))
        .await?
    {
        Decided::Rejected(p) => Ok(Json(*p)),
        Decided::Unknown => Err(Problem::not_found("recipe proposal", &id)),
        Decided::AlreadyDecided(p) => Err(decided(&p)),
        Decided::Approved(_) | Decided::Stale(_) => Err(Problem::internal("a rejection approved")),
    }
}

#[utoipa::path(post, path = "/api/v1/fleet/recipes/{name}/retire", tag = "fleet",
    summary = "Retire a recipe, or one version (role admin): the stations retire it at their next recipe poll and judge no new job with it; versions and verdicts stay.",
    params(("name" = String, Path, description = "Recipe name")),
    request_body(content = RetireBody, content_type = "application/json"),
    responses(
        (status = 204, description = "Retired"),
        (status = 401, description = "No reader's token"),
        (status = 403, description = "Not an approver"),
        (status = 404, description = "No such recipe (version)"),
        (status = 422, description = "A bad version")))]
pub async fn retire(
    State(st): State<FleetState>,
    headers: HeaderMap,
    Path(name): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<StatusCode> {
    authorised(&st, &headers, Role::Admin, "retiring a recipe")?;
    let b: RetireBody = crate::api::qc::parse_body(body)?;
    if b.version.is_some_and(|v| v < 1) {
        return Err(Problem::field("version", "a version number, from 1"));
    }
    if st.store.retire_recipe(&name, b.version).await? {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(Problem::not_found(
            "recipe",
            &b.version.map_or(name.clone(), |v| format!("{name}@{v}")),
        ))
    }
}
