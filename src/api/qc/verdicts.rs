//! Verdicts of a part and a job, and SPC of a recipe, over HTTP.

use crate::api::problem::{ApiResult, Problem};
use crate::api::reads::Reads;
use crate::api::Sorted;
use crate::api::Q;
use crate::store::{RecipeReads, VerdictReads};
use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;

/// `GET /api/v1/parts/{serial}/verdict`: the newest job verdict of a part.
#[utoipa::path(get, path = "/api/v1/parts/{serial}/verdict", tag = "qc",
    summary = "The newest job verdict of a part (what a station shows).",
    params(("serial" = String, Path, description = "Part serial")),
    responses(
        (status = 200, description = "Verdict", body = crate::store::qc::VerdictRow),
        (status = 404, description = "No verdict for this part")))]
pub async fn part_verdict<R: Reads>(
    State(st): State<R>,
    Path(serial): Path<String>,
) -> ApiResult<Json<Sorted<crate::store::qc::VerdictRow>>> {
    let v = st
        .results()
        .part_verdict(&serial)
        .await?
        .map(crate::store::qc::VerdictRow::shown)
        .ok_or_else(|| Problem::not_found("verdict of part", &serial))?;
    Ok(Json(Sorted(v)))
}

/// `GET /api/v1/jobs/{id}/verdict`: the job's verdict and its measurements'.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/verdict", tag = "qc",
    summary = "A job's verdict and, under `measurements`, the verdict of each of its measurements.",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Verdicts", body = crate::api::schema::JobVerdict),
        (status = 404, description = "No verdict for this job")))]
pub async fn job_verdict<R: Reads>(
    State(st): State<R>,
    Path(id): Path<String>,
) -> ApiResult<Json<Sorted<crate::api::schema::JobVerdict>>> {
    let v: Vec<_> = st
        .results()
        .job_verdicts(&id)
        .await?
        .into_iter()
        .map(crate::store::qc::VerdictRow::shown)
        .collect();
    let Some(job) = v.iter().find(|x| x.measurement_id.is_none()) else {
        return Err(Problem::not_found("verdict of job", &id));
    };
    let doc = crate::api::schema::JobVerdict {
        verdict: job.clone(),
        measurements: v
            .iter()
            .filter(|x| x.measurement_id.is_some())
            .cloned()
            .collect(),
    };
    Ok(Json(Sorted(doc)))
}

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SpcQuery {
    /// The recipe parameter's name (required).
    parameter: Option<String>,
    /// The newest N verdicts (1-100000, at the fleet's center 1-10000; default
    /// 100 without since/until). A since/until window may hold as many.
    last: Option<i64>,
    #[param(format = DateTime)]
    since: Option<String>,
    #[param(format = DateTime)]
    until: Option<String>,
    /// `json` (default) or `csv` (the chart points).
    #[param(pattern = "^(json|csv)$")]
    format: Option<String>,
    /// The pool counted: `production` (default), another purpose
    /// (`golden_unit`, `bench_calibration`, `gauge_study`, `repeat`,
    /// `engineering`), or `all` (decision 0100).
    #[param(
        pattern = "^(all|production|golden_unit|bench_calibration|gauge_study|repeat|engineering)$"
    )]
    purpose: Option<String>,
}

/// The pool a query names: `production` when absent, None for `all`.
pub fn parse_purpose(s: Option<&str>) -> ApiResult<Option<crate::job::Purpose>> {
    match s {
        None | Some("") => Ok(Some(crate::job::Purpose::Production)),
        Some("all") => Ok(None),
        Some(p) => crate::job::Purpose::parse(p).map(Some).ok_or_else(|| {
            Problem::field(
                "purpose",
                format!(
                    "all or one of {}, got '{p}'",
                    crate::job::Purpose::ALL.map(|p| p.as_str()).join(", ")
                ),
            )
        }),
    }
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

/// A window of a recipe's verdicts as the SPC and the lot export name it:
/// since and until (RFC 3339, normalised; each named when it does not read)
/// and the pool (`purpose`: production by default, `None` for `all`).
pub struct VerdictWindow {
    pub since: Option<String>,
    pub until: Option<String>,
    pub purpose: Option<crate::job::Purpose>,
}

impl VerdictWindow {
    pub fn parse(
        since: Option<&str>,
        until: Option<&str>,
        purpose: Option<&str>,
    ) -> ApiResult<VerdictWindow> {
        Ok(VerdictWindow {
            since: parse_time("since", since)?,
            until: parse_time("until", until)?,
            purpose: parse_purpose(purpose)?,
        })
    }

    /// The window's verdicts of recipe `name`, the newest `last` (every one
    /// when `None`); a 422 naming `since` when the window holds more than
    /// the reader's SPC maximum (`advice`: what the client does instead).
    pub async fn read<R: Reads>(
        &self,
        st: &R,
        name: &str,
        last: Option<i64>,
        advice: &str,
    ) -> ApiResult<Vec<crate::store::qc::VerdictRow>> {
        let max = R::SPC_WINDOW_MAX;
        let rows = st
            .results()
            .recipe_verdicts(
                name,
                self.purpose,
                self.since.as_deref(),
                self.until.as_deref(),
                Some(last.unwrap_or(max + 1)),
            )
            .await?;
        if rows.len() as i64 > max {
            return Err(Problem::field(
                "since",
                format!("the window [since, until) holds more than {max} verdicts: {advice}"),
            ));
        }
        Ok(rows)
    }
}

/// `GET /api/v1/recipes/{name}/spc?parameter=&last=&since=&until=&format=json|csv`.
#[utoipa::path(get, path = "/api/v1/recipes/{name}/spc", tag = "qc",
    summary = "SPC of one parameter over a window of valid measurement verdicts of one pool (`purpose`, default production: golden units, bench calibrations, gauge studies, repeats and engineering runs are not counted unless asked), one point per part and job (and level): a job's repeats are averaged into one point. n (points), mean, sigma (overall), sigma_within (average moving range of the points / 1.128), Cp, Cpk (within), Pp, Ppk (overall), yield, individuals-chart data. `format=csv` gives the chart points as CSV.",
    params(("name" = String, Path, description = "Recipe name"), SpcQuery),
    responses(
        (status = 200, description = "SPC", content(
            (crate::api::schema::SpcDocument = "application/json"),
            (String = "text/csv"))),
        (status = 404, description = "No such recipe"),
        (status = 422, description = "A bad or missing query parameter")))]
pub async fn spc<R: Reads>(
    State(st): State<R>,
    Path(name): Path<String>,
    Q(q): Q<SpcQuery>,
) -> ApiResult<Response> {
    let row = st
        .results()
        .get_recipe(&name, None)
        .await?
        .ok_or_else(|| Problem::not_found("recipe", &name))?;
    let recipe = &row.recipe;
    let csv = match q.format.as_deref() {
        None | Some("") | Some("json") => false,
        Some("csv") => true,
        Some(f) => return Err(Problem::field("format", format!("json or csv, got '{f}'"))),
    };
    let w = VerdictWindow::parse(q.since.as_deref(), q.until.as_deref(), q.purpose.as_deref())?;
    let max = R::SPC_WINDOW_MAX;
    let last = match q.last {
        None if w.since.is_none() && w.until.is_none() => Some(100),
        None => None,
        Some(n) if (1..=max).contains(&n) => Some(n),
        Some(n) => {
            return Err(Problem::field(
                "last",
                format!("must be 1 to {max}, got {n}{}", R::SPC_WINDOW_HINT),
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
    let advice = format!("narrow it or give last{}", R::SPC_WINDOW_HINT);
    let rows = w.read(&st, &name, last, &advice).await?;
    let mut points = Vec::new();
    let mut invalid = 0;
    // A verdict whose stored detail this version cannot read (written by
    // another software version, or damaged) is left out of the statistics,
    // counted and named, never dropped without a word.
    let mut unreadable: Vec<String> = Vec::new();
    for r in &rows {
        let v: crate::qc::Verdict = match r.verdict_detail() {
            Ok(v) => v,
            Err(e) => {
                tracing::warn!(
                    "SPC of recipe '{name}': verdict of part '{}' (measurement {:?}) left out: its detail does not read: {e}",
                    r.part_serial,
                    r.measurement_id
                );
                unreadable.push(r.part_serial.clone());
                continue;
            }
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
                recipe_version: Some(r.recipe_version),
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
    let left_out = unreadable.len();
    if csv {
        // The CSV holds the chart points only: the count of verdicts left
        // out travels in a header.
        return Ok((
            [
                (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
                (
                    header::HeaderName::from_static("springbench-unreadable-verdicts"),
                    left_out.to_string(),
                ),
            ],
            crate::qc::spc::to_csv(&s),
        )
            .into_response());
    }
    let mut warnings = vec![];
    if left_out > 0 {
        // Each part named once (a part's verdicts need not be adjacent).
        unreadable.sort();
        unreadable.dedup();
        warnings.push(format!(
            "{left_out} verdict(s) of the window are left out of these figures: their stored detail does not read in this software version (parts {})",
            unreadable.join(", ")
        ));
    }
    let doc = crate::api::schema::SpcDocument {
        spc: s,
        recipe: crate::api::schema::RecipeVersionRef {
            name: row.name.clone(),
            version: row.version,
            sha256: row.sha256.clone(),
        },
        unreadable_verdicts: left_out,
        purpose: w.purpose.map_or("all", |p| p.as_str()).to_string(),
        warnings,
    };
    Ok(Json(Sorted(doc)).into_response())
}
