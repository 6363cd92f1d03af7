//! Production QC over HTTP: recipes (versioned), golden-unit limit
//! proposals and their approval, verdicts, SPC; and the MES outbox.
//! Translation only: the statistics are `crate::qc`, the tables `store::qc`.

use super::auth::Caller;
use super::problem::{ApiResult, Problem};
use super::{AppState, JsonBody, Q};
use crate::qc::limits::{GoldenUnit, ProposalOptions};
use crate::qc::{Recipe, RunFacts};
use crate::runner::FieldError;
use crate::store::qc::{Approval, RecipeExpect, RecipeRow, RecipeWrite};
use crate::store::{RecipeReads, VerdictReads};
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::Deserialize;
use serde_json::{json, Value};

/// Parses a JSON body into `T`; a failure is a 422 naming the field it
/// failed at (`procedure.levels_m[2]`; `body` for the document itself).
pub fn parse_body<T: serde::de::DeserializeOwned>(body: Value) -> ApiResult<T> {
    serde_path_to_error::deserialize(body).map_err(|e| {
        let path = e.path().to_string();
        let field = if path.is_empty() || path == "." {
            "body".to_string()
        } else {
            path
        };
        Problem::field(&field, e.into_inner().to_string())
    })
}

/// Parses and checks a recipe body; `name` (from the path) must match when given.
fn parse_recipe(body: Value, name: Option<&str>) -> ApiResult<Recipe> {
    let mut body = body;
    if let (Some(n), Some(o)) = (name, body.as_object_mut()) {
        match o.get("name") {
            None => {
                o.insert("name".into(), json!(n));
            }
            Some(v) if v.as_str() == Some(n) => {}
            Some(_) => return Err(Problem::field("name", format!("must be '{n}' (the path)"))),
        }
    }
    let r: Recipe = parse_body(body)?;
    r.validate().map_err(Problem::validation)?;
    Ok(r)
}

fn recipe_doc(r: &RecipeRow) -> Value {
    let mut v = serde_json::to_value(r).unwrap_or(Value::Null);
    v["has_limits"] = json!(serde_json::from_value::<Recipe>(r.recipe.clone())
        .map(|x| x.has_limits())
        .unwrap_or(false));
    v
}

fn located(status: StatusCode, loc: String, body: Value) -> Response {
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
fn recipe_response(status: StatusCode, loc: Option<String>, r: &RecipeRow) -> Response {
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
        (status = 201, description = "Created", body = super::schema::RecipeDocument,
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
    let body = serde_json::to_value(&r).map_err(Problem::internal)?;
    // Checked inside the write: of two concurrent creations one gets 409.
    match st
        .store
        .write_recipe(
            &r.name,
            &r.sha256(),
            &body,
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
        (status = 200, description = "Unchanged", body = super::schema::RecipeDocument),
        (status = 201, description = "New version", body = super::schema::RecipeDocument,
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
    let body = serde_json::to_value(&r).map_err(Problem::internal)?;
    let origin = if cur.is_some() { "edited" } else { "created" };
    let expect = expect.unwrap_or(RecipeExpect::Any);
    match st
        .store
        .write_recipe(&name, &sha, &body, origin, caller.0.as_deref(), expect)
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
    responses((status = 200, description = "Recipes", body = super::schema::RecipeList)))]
pub async fn list(State(st): State<AppState>) -> ApiResult<Json<Value>> {
    let items: Vec<Value> = st
        .store
        .list_recipes()
        .await?
        .iter()
        .map(recipe_doc)
        .collect();
    Ok(Json(json!({"items": items})))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}", tag = "qc",
    summary = "The newest version of a recipe.",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Recipe", body = super::schema::RecipeDocument,
            headers(("ETag" = String, description = "The version's ETag, for `If-Match` on PUT"))),
        (status = 404, description = "No such recipe")))]
pub async fn get_one(State(st): State<AppState>, Path(name): Path<String>) -> ApiResult<Response> {
    let r = st
        .store
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    Ok(recipe_response(StatusCode::OK, None, &r))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/versions", tag = "qc",
    summary = "Every version of a recipe, oldest first (origin created / edited / limits_approved, who, when, hash).",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Versions", body = super::schema::RecipeList),
        (status = 404, description = "No such recipe")))]
pub async fn versions(
    State(st): State<AppState>,
    Path(name): Path<String>,
) -> ApiResult<Json<Value>> {
    let v = st.store.recipe_versions(&name).await?;
    if v.is_empty() {
        return Err(Problem::not_found("recipe", &name));
    }
    let items: Vec<Value> = v.iter().map(recipe_doc).collect();
    Ok(Json(json!({"items": items})))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/versions/{version}", tag = "qc",
    summary = "One version of a recipe.",
    params(("name" = String, Path, description = "Recipe name"), ("version" = i64, Path, description = "Version number (from 1)")),
    responses(
        (status = 200, description = "Recipe version", body = super::schema::RecipeDocument),
        (status = 404, description = "No such recipe version")))]
pub async fn version(
    State(st): State<AppState>,
    Path((name, version)): Path<(String, i64)>,
) -> ApiResult<Json<Value>> {
    let r = st
        .store
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
    let recipe: Recipe = serde_json::from_value(row.recipe).map_err(Problem::internal)?;
    Ok(JobRecipe {
        reference: crate::runner::job::RecipeRef {
            name: name.to_string(),
            version: row.version,
            sha256: row.sha256,
        },
        recipe,
    })
}

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
        report: g
            .result
            .clone()
            .and_then(|r| serde_json::from_value(r).ok()),
        analysis_error: g.analysis_error.clone(),
        target_xpeak_m: g.target_xpeak_m,
        level_index: g.level_index.unwrap_or(0).max(0) as usize,
        drive_v: g
            .config
            .pointer("/narrow_sweep/drive_v")
            .and_then(|v| v.as_f64()),
        max_drive_v: g
            .config
            .pointer("/limits/max_drive_v")
            .and_then(|v| v.as_f64()),
        pre_drive_v: g
            .config
            .pointer("/pre_sweep/drive_v")
            .and_then(|v| v.as_f64()),
        pre_q_drive_to_x: g
            .config
            .pointer("/pre_sweep/q_drive_to_x")
            .and_then(|v| v.as_f64()),
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
    let recipe: Recipe = serde_json::from_value(row.recipe.clone()).map_err(Problem::internal)?;
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
    let body = serde_json::to_value(&p).map_err(Problem::internal)?;
    let row = st
        .store
        .insert_proposal(&id, &name, row.version, &body, caller.0.as_deref())
        .await?;
    Ok(located(
        StatusCode::CREATED,
        format!("/api/v1/limit-proposals/{id}"),
        serde_json::to_value(&row).map_err(Problem::internal)?,
    ))
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/limit-proposals", tag = "qc",
    summary = "The recipe's newest 50 limit proposals (all states), newest first.",
    params(("name" = String, Path, description = "Recipe name")),
    responses(
        (status = 200, description = "Proposals", body = super::schema::ProposalList),
        (status = 404, description = "No such recipe")))]
/// `GET /api/v1/recipes/{name}/limit-proposals`: the recipe's newest 50
/// proposals (all states), newest first.
pub async fn list_proposals(
    State(st): State<AppState>,
    Path(name): Path<String>,
) -> ApiResult<Json<Value>> {
    if st.store.get_recipe(&name, None).await?.is_none() {
        return Err(Problem::not_found("recipe", &name));
    }
    let items = st.store.recipe_proposals(&name, 50).await?;
    Ok(Json(json!({"items": items})))
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
) -> ApiResult<Json<Value>> {
    let p = st
        .store
        .get_proposal(&id)
        .await?
        .ok_or_else(|| Problem::not_found("limit proposal", &id))?;
    Ok(Json(serde_json::to_value(&p).map_err(Problem::internal)?))
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
        (status = 201, description = "The new recipe version", body = super::schema::RecipeDocument,
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
    let recipe: Recipe =
        serde_json::from_value(p.proposal["recipe"].clone()).map_err(Problem::internal)?;
    let body = serde_json::to_value(&recipe).map_err(Problem::internal)?;
    match st
        .store
        .approve_proposal(&id, &recipe.sha256(), &body, caller.0.as_deref())
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
) -> ApiResult<Json<Value>> {
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
    Ok(Json(serde_json::to_value(&p).map_err(Problem::internal)?))
}

/// `GET /api/v1/parts/{serial}/verdict`: the newest job verdict of a part.
#[utoipa::path(get, path = "/api/v1/parts/{serial}/verdict", tag = "qc",
    summary = "The newest job verdict of a part (what a station shows).",
    params(("serial" = String, Path, description = "Part serial")),
    responses(
        (status = 200, description = "Verdict", body = crate::store::qc::VerdictRow),
        (status = 404, description = "No verdict for this part")))]
pub async fn part_verdict(
    State(st): State<AppState>,
    Path(serial): Path<String>,
) -> ApiResult<Json<Value>> {
    let v = st
        .store
        .part_verdict(&serial)
        .await?
        .ok_or_else(|| Problem::not_found("verdict of part", &serial))?;
    Ok(Json(serde_json::to_value(&v).map_err(Problem::internal)?))
}

/// `GET /api/v1/jobs/{id}/verdict`: the job's verdict and its measurements'.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/verdict", tag = "qc",
    summary = "A job's verdict and, under `measurements`, the verdict of each of its measurements.",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Verdicts", body = super::schema::JobVerdict),
        (status = 404, description = "No verdict for this job")))]
pub async fn job_verdict(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Value>> {
    let v = st.store.job_verdicts(&id).await?;
    let Some(job) = v.iter().find(|x| x.measurement_id.is_none()) else {
        return Err(Problem::not_found("verdict of job", &id));
    };
    let mut doc = serde_json::to_value(job).map_err(Problem::internal)?;
    doc["measurements"] = serde_json::to_value(
        v.iter()
            .filter(|x| x.measurement_id.is_some())
            .collect::<Vec<_>>(),
    )
    .map_err(Problem::internal)?;
    Ok(Json(doc))
}

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SpcQuery {
    /// The recipe parameter's name (required).
    parameter: Option<String>,
    /// The newest N verdicts (1-100000; default 100 without since/until).
    last: Option<i64>,
    #[param(format = DateTime)]
    since: Option<String>,
    #[param(format = DateTime)]
    until: Option<String>,
    /// `json` (default) or `csv` (the chart points).
    #[param(pattern = "^(json|csv)$")]
    format: Option<String>,
}

/// A time filter value: RFC 3339, normalised to the stored form (UTC, milliseconds).
pub fn parse_time(field: &str, s: Option<&str>) -> ApiResult<Option<String>> {
    match s {
        None | Some("") => Ok(None),
        Some(s) => chrono::DateTime::parse_from_rfc3339(s)
            .map(|t| {
                Some(
                    t.with_timezone(&chrono::Utc)
                        .to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
                )
            })
            .map_err(|e| Problem::field(field, format!("must be an RFC 3339 time: {e}"))),
    }
}

/// `GET /api/v1/recipes/{name}/spc?parameter=&last=&since=&until=&format=json|csv`.
#[utoipa::path(get, path = "/api/v1/recipes/{name}/spc", tag = "qc",
    summary = "SPC of one parameter over a window of valid measurement verdicts, one point per part and job (and level): a job's repeats are averaged into one point. n (points), mean, sigma (overall), sigma_within (average moving range of the points / 1.128), Cp, Cpk (within), Pp, Ppk (overall), yield, individuals-chart data. `format=csv` gives the chart points as CSV.",
    params(("name" = String, Path, description = "Recipe name"), SpcQuery),
    responses(
        (status = 200, description = "SPC", content(
            (super::schema::SpcDocument = "application/json"),
            (String = "text/csv"))),
        (status = 404, description = "No such recipe"),
        (status = 422, description = "A bad or missing query parameter")))]
pub async fn spc(
    State(st): State<AppState>,
    Path(name): Path<String>,
    Q(q): Q<SpcQuery>,
) -> ApiResult<Response> {
    let row = st
        .store
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let recipe: Recipe = serde_json::from_value(row.recipe.clone()).map_err(Problem::internal)?;
    let csv = match q.format.as_deref() {
        None | Some("") | Some("json") => false,
        Some("csv") => true,
        Some(f) => return Err(Problem::field("format", format!("json or csv, got '{f}'"))),
    };
    let since = parse_time("since", q.since.as_deref())?;
    let until = parse_time("until", q.until.as_deref())?;
    let last = match q.last {
        None if since.is_none() && until.is_none() => Some(100),
        None => None,
        Some(n) if (1..=100_000).contains(&n) => Some(n),
        Some(n) => {
            return Err(Problem::field(
                "last",
                format!("must be 1 to 100000, got {n}"),
            ))
        }
    };
    let Some(pname) = q.parameter.clone() else {
        return Err(Problem::field(
            "parameter",
            format!(
                "required: one of {}",
                recipe
                    .parameters
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    };
    let Some(spec) = recipe.parameters.iter().find(|p| p.name == pname) else {
        return Err(Problem::field(
            "parameter",
            format!("recipe '{name}' has no parameter '{pname}'"),
        ));
    };
    let rows = st
        .store
        .recipe_verdicts(&name, since.as_deref(), until.as_deref(), last)
        .await?;
    let mut points = Vec::new();
    let mut invalid = 0;
    for r in &rows {
        let v: crate::qc::Verdict = match serde_json::from_value(r.detail.clone()) {
            Ok(v) => v,
            Err(_) => continue,
        };
        if v.verdict == crate::qc::VerdictKind::Invalid {
            invalid += 1;
            continue;
        }
        if let Some(p) = v.parameters.iter().find(|p| p.name == pname) {
            points.push(crate::qc::spc::SpcPoint {
                time: r.created_at.clone(),
                part_serial: r.part_serial.clone(),
                measurement_id: r.measurement_id.clone().unwrap_or_default(),
                job_id: r.job_id.clone(),
                level_index: r.level_index,
                value: p.value,
                repeats: 1,
                verdict: v.verdict,
            });
        }
    }
    let s = crate::qc::spc::compute(
        &pname,
        &spec.unit(),
        spec.lower,
        spec.upper,
        points,
        invalid,
    );
    if csv {
        return Ok((
            [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
            crate::qc::spc::to_csv(&s),
        )
            .into_response());
    }
    let mut doc = serde_json::to_value(&s).map_err(Problem::internal)?;
    doc["recipe"] = json!({"name": row.name, "version": row.version, "sha256": row.sha256});
    Ok(Json(doc).into_response())
}

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
        (status = 200, description = "Outbox", body = super::schema::Outbox),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/outbox?state=`: deliveries (default: pending and failed), oldest first.
pub async fn outbox(State(st): State<AppState>, Q(q): Q<OutboxQuery>) -> ApiResult<Json<Value>> {
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
    let limit = super::page_limit(q.limit)?;
    let items = st.store.list_outbox(state, limit).await?;
    let (pending, failed, failures) = st.store.outbox_counts().await?;
    Ok(Json(
        json!({"items": items, "pending": pending, "failed": failed,
                   "failed_attempts_total": failures}),
    ))
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
) -> ApiResult<Json<Value>> {
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
) -> ApiResult<Json<Value>> {
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
) -> ApiResult<Json<Value>> {
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
    Ok(Json(serde_json::to_value(&d).map_err(Problem::internal)?))
}
