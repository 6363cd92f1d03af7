//! Recipes over HTTP: create, update (If-Match), list, versions, retire;
//! the recipe a job names, read once at submission.

use super::parse_body;
use crate::api::auth::Caller;
use crate::api::problem::{ApiResult, Problem};
use crate::api::reads::Reads;
use crate::api::schema::{RecipeDocument, RecipeList};
use crate::api::{AppState, JsonBody, Sorted};
use crate::qc::Recipe;
use crate::store::qc::{RecipeExpect, RecipeRow, RecipeWrite};
use crate::store::RecipeReads;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde_json::Value;

/// Parses and checks a recipe body; `name` (from the path) must match when given.
fn parse_recipe(body: Value, name: Option<&str>) -> ApiResult<Recipe> {
    let mut body = body;
    if let (Some(n), Some(o)) = (name, body.as_object_mut()) {
        match o.get("name") {
            None => {
                o.insert("name".into(), Value::String(n.to_string()));
            }
            Some(v) if v.as_str() == Some(n) => {}
            Some(_) => return Err(Problem::field("name", format!("must be '{n}' (the path)"))),
        }
    }
    let r: Recipe = parse_body(body)?;
    r.validate().map_err(Problem::validation)?;
    Ok(r)
}

/// A recipe version as served: the row, whether it has limits, keys sorted.
fn recipe_doc(r: &RecipeRow) -> Sorted<RecipeDocument> {
    Sorted(RecipeDocument::of(r))
}

pub(super) fn located<T: serde::Serialize>(status: StatusCode, loc: String, body: T) -> Response {
    let mut r = (status, Json(body)).into_response();
    if let Ok(v) = HeaderValue::from_str(&loc) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    r
}

/// The strong ETag of a recipe version: its number and content hash.
pub fn etag(r: &RecipeRow) -> String {
    format!("\"{}-{}\"", r.version, r.sha256)
}

/// A recipe document with its version's ETag.
pub(super) fn recipe_response(status: StatusCode, loc: Option<String>, r: &RecipeRow) -> Response {
    let mut resp = match loc {
        Some(l) => located(status, l, recipe_doc(r)),
        None => (status, Json(recipe_doc(r))).into_response(),
    };
    if let Ok(v) = HeaderValue::from_str(&etag(r)) {
        resp.headers_mut().insert(header::ETAG, v);
    }
    resp
}

fn precondition_failed(detail: String) -> Problem {
    Problem::new(
        StatusCode::PRECONDITION_FAILED,
        "precondition-failed",
        "Recipe changed",
        detail,
    )
}

/// What `If-Match` asks of the recipe's newest version (RFC 9110 13.1.1):
/// None without the header, Err(412) when `cur` does not match.
fn if_match(
    headers: &axum::http::HeaderMap,
    name: &str,
    cur: Option<&RecipeRow>,
) -> ApiResult<Option<RecipeExpect>> {
    let Some(v) = headers.get(header::IF_MATCH) else {
        return Ok(None);
    };
    let v = v
        .to_str()
        .map_err(|_| Problem::field("If-Match", "not visible ASCII"))?;
    let wanted: Vec<&str> = v.split(',').map(str::trim).collect();
    match cur {
        Some(c) if wanted.contains(&"*") || wanted.contains(&etag(c).as_str()) => {
            Ok(Some(RecipeExpect::Version(c.version)))
        }
        Some(c) => Err(precondition_failed(format!(
            "If-Match {v} does not name the newest version of recipe '{name}' (version {}, ETag {}): read it again",
            c.version,
            etag(c)
        ))),
        None => Err(precondition_failed(format!(
            "If-Match {v}: there is no recipe '{name}'"
        ))),
    }
}

#[utoipa::path(post, path = "/api/v1/recipes", tag = "qc",
    summary = "Create a QC recipe (version 1). 409 when the name exists (use PUT for a new version).",
    request_body(content = crate::qc::Recipe, content_type = "application/json"),
    responses(
        (status = 201, description = "Created", body = crate::api::schema::RecipeDocument,
            headers(("Location" = String, description = "The recipe"))),
        (status = 409, description = "A recipe of this name exists"),
        (status = 422, description = "Invalid fields")))]
/// `POST /api/v1/recipes`: version 1 of a new recipe (409 when the name exists).
pub async fn create(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let r = parse_recipe(body, None)?;
    let exists = || {
        Problem::new(
            StatusCode::CONFLICT,
            "recipe-exists",
            "Recipe exists",
            format!(
                "recipe '{}' exists; PUT /api/v1/recipes/{} makes a new version",
                r.name, r.name
            ),
        )
    };
    // Checked inside the write: of two concurrent creations one gets 409.
    match st
        .store
        .write_recipe(
            &r.name,
            &r.sha256(),
            &r,
            "created",
            caller.0.as_deref(),
            RecipeExpect::Absent,
        )
        .await?
    {
        RecipeWrite::Stored(row) => Ok(recipe_response(
            StatusCode::CREATED,
            Some(format!("/api/v1/recipes/{}", r.name)),
            &row,
        )),
        RecipeWrite::Conflict(_) => Err(exists()),
    }
}

#[utoipa::path(put, path = "/api/v1/recipes/{name}", tag = "qc",
    summary = "Change a recipe. A changed content makes a new version (201) with a new hash; the same content returns the current version (200).",
    params(("name" = String, Path, description = "Recipe name"),
        ("If-Match" = Option<String>, Header, description = "The ETag of the version this change is made on (from GET); 412 when the recipe moved on")),
    request_body(content = crate::qc::Recipe, content_type = "application/json"),
    responses(
        (status = 200, description = "Unchanged", body = crate::api::schema::RecipeDocument),
        (status = 201, description = "New version", body = crate::api::schema::RecipeDocument,
            headers(("Location" = String, description = "The new version"))),
        (status = 412, description = "`If-Match` does not name the newest version"),
        (status = 422, description = "Invalid fields, or `name` differs from the path")))]
/// `PUT /api/v1/recipes/{name}`: a new version (200 with the current one
/// when nothing changed). With `If-Match`, only on top of that version (412).
pub async fn update(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    Path(name): Path<String>,
    headers: axum::http::HeaderMap,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let r = parse_recipe(body, Some(&name))?;
    let cur = st.store.get_recipe(&name, None).await?;
    let expect = if_match(&headers, &name, cur.as_ref())?;
    let sha = r.sha256();
    if let Some(c) = &cur {
        if c.sha256 == sha && !c.retired {
            return Ok(recipe_response(StatusCode::OK, None, c));
        }
    }
    let origin = if cur.is_some() { "edited" } else { "created" };
    let expect = expect.unwrap_or(RecipeExpect::Any);
    match st
        .store
        .write_recipe(&name, &sha, &r, origin, caller.0.as_deref(), expect)
        .await?
    {
        RecipeWrite::Stored(row) => Ok(recipe_response(
            StatusCode::CREATED,
            Some(format!("/api/v1/recipes/{name}/versions/{}", row.version)),
            &row,
        )),
        RecipeWrite::Conflict(c) => Err(precondition_failed(format!(
            "recipe '{name}' changed while this request ran (now version {}): read it again",
            c.map(|c| c.0).unwrap_or(0)
        ))),
    }
}

#[utoipa::path(get, path = "/api/v1/recipes", tag = "qc",
    summary = "The newest version of every recipe.",
    responses((status = 200, description = "Recipes", body = crate::api::schema::RecipeList)))]
pub async fn list<R: Reads>(State(st): State<R>) -> ApiResult<Json<Sorted<RecipeList>>> {
    let items = st
        .results()
        .list_recipes()
        .await?
        .iter()
        .map(RecipeDocument::of)
        .collect();
    Ok(Json(Sorted(RecipeList { items })))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}", tag = "qc",
    summary = "The newest version of a recipe.",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Recipe", body = crate::api::schema::RecipeDocument,
            headers(("ETag" = String, description = "The version's ETag, for `If-Match` on PUT"))),
        (status = 404, description = "No such recipe")))]
pub async fn get_one<R: Reads>(
    State(st): State<R>,
    Path(name): Path<String>,
) -> ApiResult<Response> {
    let r = st
        .results()
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    Ok(recipe_response(StatusCode::OK, None, &r))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/versions", tag = "qc",
    summary = "Every version of a recipe, oldest first (origin created / edited / limits_approved, who, when, hash).",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Versions", body = crate::api::schema::RecipeList),
        (status = 404, description = "No such recipe")))]
pub async fn versions<R: Reads>(
    State(st): State<R>,
    Path(name): Path<String>,
) -> ApiResult<Json<Sorted<RecipeList>>> {
    let v = st.results().recipe_versions(&name).await?;
    if v.is_empty() {
        return Err(Problem::not_found("recipe", &name));
    }
    let items = v.iter().map(RecipeDocument::of).collect();
    Ok(Json(Sorted(RecipeList { items })))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/versions/{version}", tag = "qc",
    summary = "One version of a recipe.",
    params(("name" = String, Path, description = "Recipe name"), ("version" = i64, Path, description = "Version number (from 1)")),
    responses(
        (status = 200, description = "Recipe version", body = crate::api::schema::RecipeDocument),
        (status = 404, description = "No such recipe version")))]
pub async fn version<R: Reads>(
    State(st): State<R>,
    Path((name, version)): Path<(String, i64)>,
) -> ApiResult<Json<Sorted<RecipeDocument>>> {
    let r = st
        .results()
        .get_recipe(&name, Some(version))
        .await?
        .ok_or_else(|| Problem::not_found("recipe version", &format!("{name}@{version}")))?;
    Ok(Json(recipe_doc(&r)))
}

#[utoipa::path(delete, path = "/api/v1/recipes/{name}", tag = "qc",
    summary = "Retire a recipe (no new jobs; versions and verdicts stay). A later PUT revives it as a new version.",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 204, description = "Retired"),
        (status = 404, description = "No such recipe")))]
/// `DELETE /api/v1/recipes/{name}`: retires the recipe (no new jobs; every
/// version and verdict stays for traceability). 204.
pub async fn retire(State(st): State<AppState>, Path(name): Path<String>) -> ApiResult<StatusCode> {
    if st.store.retire_recipe(&name).await? {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(Problem::not_found("recipe", &name))
    }
}

/// The recipe a job names, read once at submission: its newest version
/// (never a retired one), with the reference the verdict will name.
pub struct JobRecipe {
    pub reference: crate::runner::job::RecipeRef,
    pub recipe: Recipe,
}

/// Looks up the recipe `name` for a job (422 naming `recipe` when there is
/// none or it is retired).
pub async fn recipe_for_job(st: &AppState, name: &str) -> ApiResult<JobRecipe> {
    let row = st
        .store
        .get_recipe(name, None)
        .await?
        .filter(|r| !r.retired)
        .ok_or_else(|| {
            Problem::field("recipe", format!("no recipe '{name}' (or it is retired)"))
        })?;
    // A fleet station's verdicts name where the version comes from.
    let origin = st.cfg.fleet.is_some().then(|| row.origin());
    let recipe = row.recipe;
    Ok(JobRecipe {
        reference: crate::runner::job::RecipeRef {
            name: name.to_string(),
            version: row.version,
            sha256: row.sha256,
            origin,
        },
        recipe,
    })
}

/// The body of a publication (all optional).
#[derive(serde::Deserialize, Default, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PublishBody {
    /// The local version to publish; default the newest.
    #[serde(default)]
    #[schema(minimum = 1)]
    pub version: Option<i64>,
    /// Why (at most 4 096 characters).
    #[serde(default)]
    #[schema(max_length = 4096)]
    pub note: Option<String>,
}

#[utoipa::path(post, path = "/api/v1/recipes/{name}/publish", tag = "qc",
    summary = "A fleet station publishes its local recipe version to the center (admin): a proposal there, which the center's approver makes the center's version; the station then takes it back from the center like any other. The center's answer (201 and the proposal, or its problem) is passed on.",
    params(("name" = String, Path, description = "Recipe name")),
    request_body(content = PublishBody, content_type = "application/json"),
    responses(
        (status = 201, description = "Proposed at the center", body = springbench_store_pg::RecipeProposal),
        (status = 404, description = "No such recipe (version), or the station has no [fleet]"),
        (status = 409, description = "The version is the center's already, or the center has this content"),
        (status = 422, description = "Invalid fields"),
        (status = 502, description = "The center did not answer")))]
/// `POST /api/v1/recipes/{name}/publish`: a local version as a proposal
/// at the center (decision 0106).
pub async fn publish(
    State(st): State<AppState>,
    Path(name): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let b: PublishBody = parse_body(body)?;
    let note = match b.note {
        Some(n) if n.chars().any(char::is_control) => {
            return Err(Problem::field(
                "note",
                "holds a control character (NUL, ...)",
            ))
        }
        Some(n) if n.chars().count() > 4096 => {
            return Err(Problem::field("note", "at most 4096 characters"))
        }
        n => n,
    };
    let Some(fleet) = st.cfg.fleet.as_ref() else {
        return Err(Problem::new(
            StatusCode::NOT_FOUND,
            "no-fleet",
            "Not in a fleet",
            "this station has no [fleet] center to publish to",
        ));
    };
    let row = st
        .store
        .get_recipe(&name, b.version)
        .await?
        .ok_or_else(|| {
            Problem::not_found(
                "recipe",
                &b.version.map_or(name.clone(), |v| format!("{name}@{v}")),
            )
        })?;
    if row.source == crate::job::RecipeSource::Center {
        return Err(Problem::new(
            StatusCode::CONFLICT,
            "recipe-not-local",
            "Recipe from the center",
            format!(
                "version {} of recipe '{name}' is the center's already",
                row.version
            ),
        ));
    }
    let recipe = row.recipe;
    let center = crate::fleet::http::HttpCenter::new(fleet).map_err(Problem::internal)?;
    let req = crate::fleet::http::PublishRequest {
        station_id: fleet.station_id.clone(),
        recipe,
        version: row.version,
        note,
    };
    let (status, bytes) = center.publish_recipe(&req).await.map_err(|e| {
        Problem::new(
            StatusCode::BAD_GATEWAY,
            "center-unreachable",
            "Center unreachable",
            e.to_string(),
        )
    })?;
    let status = StatusCode::from_u16(status).unwrap_or(StatusCode::BAD_GATEWAY);
    let mut r = (status, bytes).into_response();
    let ct = if status.is_success() {
        "application/json"
    } else {
        "application/problem+json"
    };
    r.headers_mut()
        .insert(header::CONTENT_TYPE, HeaderValue::from_static(ct));
    Ok(r)
}
