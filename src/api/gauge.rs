//! Gauge studies over HTTP (issue 21): N parts × M repeats on one or more
//! benches under a recipe; for each judged quantity, repeatability,
//! reproducibility, %GRR against the recipe's tolerance and ndc
//! (`core::qc::grr`, AIAG's ANOVA method; docs/qc.md "Gauge study").
//!
//! A study is a plan of jobs. Each run is an ordinary job (the path of
//! `POST /api/v1/jobs`, with the idempotency key `gauge:{study}:{run}`), so
//! the recipe, the safety rules and the verdicts are the same as on the
//! line. Within each repeat the parts go in a shuffled order (AIAG asks for
//! a randomised order), the same on every bench.

use super::problem::{ApiResult, Problem};
use super::qc::parse_body;
use super::{AppState, JsonBody, Sorted};
use crate::qc::grr;
use crate::qc::Recipe;
use crate::store::{Inserted, JobState, RecipeReads, VerdictReads};
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

/// Bounds of a study (AIAG: typically 10 parts, 2-3 appraisers, 2-3 repeats).
pub const MIN_PARTS: usize = 2;
pub const MAX_PARTS: usize = 50;
pub const MIN_REPEATS: u32 = 2;
pub const MAX_REPEATS: u32 = 10;
pub const MAX_RUNS: usize = 1000;

pub use crate::qc::grr::{GaugePart, GaugeRun, GaugeStudyRequest};

fn check(req: &GaugeStudyRequest, benches: &[String]) -> ApiResult<Vec<String>> {
    if !(MIN_PARTS..=MAX_PARTS).contains(&req.parts.len()) {
        return Err(Problem::field(
            "parts",
            format!("{MIN_PARTS} to {MAX_PARTS} parts, got {}", req.parts.len()),
        ));
    }
    let mut seen = std::collections::HashSet::new();
    for (i, p) in req.parts.iter().enumerate() {
        if !seen.insert(&p.serial) {
            return Err(Problem::field(
                &format!("parts[{i}].serial"),
                format!("'{}' is in the study twice", p.serial),
            ));
        }
    }
    if !(MIN_REPEATS..=MAX_REPEATS).contains(&req.repeats) {
        return Err(Problem::field(
            "repeats",
            format!("{MIN_REPEATS} to {MAX_REPEATS}, got {}", req.repeats),
        ));
    }
    let chosen = match &req.benches {
        None => benches.to_vec(),
        Some(b) if b.is_empty() => {
            return Err(Problem::field(
                "benches",
                "at least one bench, or leave it out",
            ))
        }
        Some(b) => {
            for (i, id) in b.iter().enumerate() {
                if !benches.contains(id) {
                    return Err(Problem::field(
                        &format!("benches[{i}]"),
                        format!("no bench '{id}' (configured: {})", benches.join(", ")),
                    ));
                }
                if b[..i].contains(id) {
                    return Err(Problem::field(
                        &format!("benches[{i}]"),
                        format!("'{id}' is named twice"),
                    ));
                }
            }
            b.clone()
        }
    };
    let runs = req.parts.len() * chosen.len() * req.repeats as usize;
    if runs > MAX_RUNS {
        return Err(Problem::field(
            "parts",
            format!("{runs} runs (parts x benches x repeats); at most {MAX_RUNS}"),
        ));
    }
    if let Some(job) = &req.job {
        for k in ["part", "recipe", "bench", "production", "purpose"] {
            if job.contains_key(k) {
                return Err(Problem::field(
                    &format!("job.{k}"),
                    "set by the study for each run; leave it out",
                ));
            }
        }
    }
    Ok(chosen)
}

/// The job request of one run.
fn run_request(req: &GaugeStudyRequest, run: &GaugeRun) -> Value {
    let part = &req.parts[run.part_index];
    let mut body = serde_json::Map::new();
    if let Some(extra) = &req.job {
        body.extend(extra.clone());
    }
    body.insert("part".into(), json!({ "serial": part.serial }));
    body.insert("recipe".into(), json!(req.recipe));
    body.insert("bench".into(), json!(run.bench_id));
    // A study's runs are its own pool: never production SPC or yield.
    body.insert("purpose".into(), json!(crate::job::Purpose::GaugeStudy));
    if let Some(p) = &part.production {
        body.insert("production".into(), json!(p));
    }
    Value::Object(body)
}

#[utoipa::path(post, path = "/api/v1/gauge-studies", tag = "qc",
    summary = "Start a gauge study: every part measured `repeats` times on every bench under a recipe (one job per run).",
    request_body(content = GaugeStudyRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "Planned and submitted; the study as `GET` returns it", body = GaugeStudyDocument,
            headers(("Location" = String, description = "The study"))),
        (status = 422, description = "Invalid fields (also any run's job request), one message each"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/gauge-studies`.
pub async fn create(
    State(st): State<AppState>,
    Extension(caller): Extension<super::auth::Caller>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let req: GaugeStudyRequest = parse_body(body)?;
    let configured: Vec<String> = st.cfg.benches.iter().map(|b| b.id.clone()).collect();
    let benches = check(&req, &configured)?;
    // The recipe exists and is not retired (422 naming `recipe` otherwise).
    super::qc::recipe_for_job(&st, &req.recipe).await?;
    let id = crate::runner::new_id();
    // Repeat by repeat, the parts in a shuffled order (seeded by the id).
    let seed = id.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    });
    let mut runs = Vec::new();
    for (repeat, order) in (0..req.repeats).zip(grr::part_order(req.parts.len(), req.repeats, seed))
    {
        for part_index in order {
            for b in &benches {
                runs.push(GaugeRun {
                    part_index,
                    bench_id: b.clone(),
                    repeat,
                    idempotency_key: format!("gauge:{id}:{}", runs.len()),
                    job_id: None,
                });
            }
        }
    }
    // Every run's request is checked before anything is stored.
    for run in runs.iter().take(req.parts.len() * benches.len()) {
        let body = run_request(&req, run);
        let parsed = crate::job::parse_lenient::<crate::job::JobRequest>(&body);
        if let Err(errors) =
            crate::job::JobRequest::check(parsed, &crate::runner::job::admission(&st.cfg), |_| {
                Ok(())
            })
        {
            return Err(Problem::validation(errors));
        }
    }
    st.store
        .insert_gauge_study(&id, &req, &runs, caller.0.as_deref())
        .await?;
    for run in runs.iter_mut() {
        let body = run_request(&req, run);
        let job =
            match super::jobs::enqueue(&st, caller.0.clone(), &body, Some(&run.idempotency_key))
                .await?
            {
                Inserted::New(j) | Inserted::Replayed(j) | Inserted::Conflict(j) => j,
            };
        run.job_id = Some(job.id);
    }
    st.store.update_gauge_runs(&id, &runs).await?;
    let doc = study_document(&st, &id).await?;
    let mut r = (StatusCode::CREATED, Json(Sorted(doc))).into_response();
    if let Ok(v) = HeaderValue::from_str(&format!("/api/v1/gauge-studies/{id}")) {
        r.headers_mut().insert(header::LOCATION, v);
    }
    Ok(r)
}

#[utoipa::path(get, path = "/api/v1/gauge-studies/{id}", tag = "qc",
    summary = "A gauge study: its runs and, once every run has ended, repeatability, reproducibility, %GRR and ndc per judged quantity.",
    params(("id" = String, Path, description = "Study id")),
    responses(
        (status = 200, description = "The study", body = GaugeStudyDocument),
        (status = 404, description = "No such study")))]
/// `GET /api/v1/gauge-studies/{id}`.
pub async fn get_one(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<Sorted<GaugeStudyDocument>>> {
    Ok(Json(Sorted(study_document(&st, &id).await?)))
}

/// `GET /api/v1/gauge-studies/{id}`: the plan, each run's state and, once
/// every run has ended, the gauge figures of each judged parameter.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct GaugeStudyDocument {
    pub id: String,
    /// The recipe every run is measured and judged with, and the version
    /// the runs were judged with (null before the first verdict).
    pub recipe: String,
    pub recipe_version: Option<i64>,
    pub parts: Vec<crate::qc::grr::GaugePart>,
    pub repeats: u32,
    /// The benches (appraisers), in the order of their first run.
    pub benches: Vec<String>,
    /// More members of each run's job request, as given.
    #[schema(value_type = Option<Object>)]
    pub job: Option<serde_json::Map<String, Value>>,
    pub created_at: String,
    /// The token that created it (null with open access).
    pub created_by: Option<String>,
    /// `running` until every run has ended, then `done`.
    pub state: GaugeStudyState,
    pub runs_total: usize,
    pub runs_finished: usize,
    pub runs: Vec<GaugeRunDocument>,
    /// The gauge figures of each judged parameter (once `done`).
    pub quantities: Vec<grr::GaugeRr>,
    /// The parameters without figures, each with why.
    pub not_computed: Vec<NotComputed>,
    /// How the figures are computed.
    pub method: &'static str,
}

/// A study's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum GaugeStudyState {
    Running,
    Done,
}

/// One run of a study.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct GaugeRunDocument {
    pub part_index: usize,
    /// The part's serial.
    pub serial: Option<String>,
    pub bench_id: String,
    pub repeat: u32,
    /// Its job (null before it was queued).
    pub job_id: Option<String>,
    /// Its job's state (null before it was queued).
    pub state: Option<JobState>,
}

/// A judged parameter without gauge figures, and why.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct NotComputed {
    pub parameter: String,
    pub reason: String,
}

#[utoipa::path(get, path = "/api/v1/gauge-studies", tag = "qc",
    summary = "The newest 50 gauge studies (plan and state; the figures are in each study).",
    responses((status = 200, description = "Studies, newest first", body = GaugeStudyList)))]
/// `GET /api/v1/gauge-studies`.
pub async fn list(State(st): State<AppState>) -> ApiResult<Json<Sorted<GaugeStudyList>>> {
    let rows = st.store.list_gauge_studies(50).await?;
    let items = rows
        .iter()
        .map(|r| GaugeStudySummary {
            id: r.id.clone(),
            recipe: r.recipe_name.clone(),
            runs_total: r.runs.len(),
            created_at: r.created_at.clone(),
            created_by: r.created_by.clone(),
            href: format!("/api/v1/gauge-studies/{}", r.id),
        })
        .collect();
    Ok(Json(Sorted(GaugeStudyList { items })))
}

/// `GET /api/v1/gauge-studies`: the newest studies, newest first.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct GaugeStudyList {
    pub items: Vec<GaugeStudySummary>,
}

/// One study in the list: its plan's size; the figures are in the study.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct GaugeStudySummary {
    pub id: String,
    /// The recipe the study measures and judges with.
    pub recipe: String,
    /// Runs planned (parts x benches x repeats).
    pub runs_total: usize,
    pub created_at: String,
    /// The token that created it (null with open access).
    pub created_by: Option<String>,
    /// The study (`GET`).
    pub href: String,
}

use crate::qc::grr::RunValues;

/// A run's value of each judged parameter (`core::qc::grr::run_values`:
/// the mean over its measurements' valid verdicts). None when the run has
/// no value (invalid, failed, not finished).
async fn run_values(
    st: &AppState,
    job_id: &str,
) -> ApiResult<(Option<JobState>, RunValues, Option<i64>)> {
    let job = st.store.get_job(job_id).await?;
    let state = job.as_ref().map(|j| j.state);
    let mut version = None;
    let mut verdicts = vec![];
    for v in st.store.job_verdicts(job_id).await? {
        if v.measurement_id.is_none() {
            continue;
        }
        version = Some(v.recipe_version);
        if let Ok(verdict) = v.verdict_detail() {
            verdicts.push(verdict);
        }
    }
    Ok((state, crate::qc::grr::run_values(&verdicts), version))
}

/// The study with its runs' states and, when every run has ended, the
/// gauge figures of each parameter the recipe judges.
async fn study_document(st: &AppState, id: &str) -> ApiResult<GaugeStudyDocument> {
    let row = st
        .store
        .get_gauge_study(id)
        .await?
        .ok_or_else(|| Problem::not_found("gauge study", id))?;
    let (req, runs) = (row.request, row.runs);
    let mut benches: Vec<String> = vec![];
    for r in &runs {
        if !benches.contains(&r.bench_id) {
            benches.push(r.bench_id.clone());
        }
    }
    let mut run_docs = vec![];
    let mut values = vec![];
    let mut finished = 0usize;
    let mut version = None;
    for r in &runs {
        let (state, vals, v) = match &r.job_id {
            Some(j) => run_values(st, j).await?,
            None => (None, Default::default(), None),
        };
        version = version.or(v);
        if state.is_some_and(|s| s.is_terminal()) {
            finished += 1;
        }
        run_docs.push(GaugeRunDocument {
            part_index: r.part_index,
            serial: req.parts.get(r.part_index).map(|p| p.serial.clone()),
            bench_id: r.bench_id.clone(),
            repeat: r.repeat,
            job_id: r.job_id.clone(),
            state,
        });
        values.push(vals);
    }
    let done = finished == runs.len();
    let mut quantities = vec![];
    let mut not_computed = vec![];
    if done {
        let recipe_row = st.store.get_recipe(&req.recipe, version).await?;
        let recipe: Option<Recipe> = recipe_row.map(|r| r.recipe);
        for p in recipe.iter().flat_map(|r| r.parameters.iter()) {
            // values[part][bench][repeat]
            let mut grid =
                vec![vec![vec![f64::NAN; req.repeats as usize]; benches.len()]; req.parts.len()];
            let mut missing = vec![];
            let mut unit = String::new();
            for (r, vals) in runs.iter().zip(&values) {
                let b = benches.iter().position(|x| *x == r.bench_id).unwrap_or(0);
                match vals.get(&p.name) {
                    Some((v, u)) => {
                        grid[r.part_index][b][r.repeat as usize] = *v;
                        unit.clone_from(u);
                    }
                    None => missing.push(format!(
                        "{} on {} (repeat {})",
                        req.parts[r.part_index].serial,
                        r.bench_id,
                        r.repeat + 1
                    )),
                }
            }
            if !missing.is_empty() {
                not_computed.push(NotComputed {
                    parameter: p.name.clone(),
                    reason: format!(
                        "no valid value from {} run(s): {}",
                        missing.len(),
                        missing
                            .iter()
                            .take(5)
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                });
                continue;
            }
            match grr::study(&p.name, &unit, &grid, p.lower, p.upper) {
                Ok(g) => quantities.push(g),
                Err(e) => not_computed.push(NotComputed {
                    parameter: p.name.clone(),
                    reason: e,
                }),
            }
        }
    }
    Ok(GaugeStudyDocument {
        id: row.id,
        recipe: req.recipe,
        recipe_version: version,
        parts: req.parts,
        repeats: req.repeats,
        benches,
        job: req.job,
        created_at: row.created_at,
        created_by: row.created_by,
        state: if done {
            GaugeStudyState::Done
        } else {
            GaugeStudyState::Running
        },
        runs_total: runs.len(),
        runs_finished: finished,
        runs: run_docs,
        quantities,
        not_computed,
        method: "ANOVA, AIAG MSA 4th edition: crossed parts x benches x repeats; interaction pooled when p > 0.25; %GRR of tolerance = 100 * 6 GRR / (USL - LSL); one-sided limit: %GRR = 100 * 3 GRR / |limit - mean| (not applicable with the mean beyond the limit); no limits: %GRR of the total variation; ndc = floor(1.41 PV / GRR); warnings below 10 parts or 2 benches",
    })
}

/// `POST /api/v1/recipes/{name}/bench-calibrations`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BenchCalibrationRequest {
    /// The bench to calibrate.
    pub bench: String,
    /// The bench the recipe's golden units were measured on (its golden
    /// reference and limits): the calibration maps `bench` onto it.
    pub reference_bench: String,
    /// Golden units measured under the recipe on both benches (the newest
    /// succeeded job of each on each bench), at least 3.
    #[schema(min_items = 3, max_items = 200)]
    pub serials: Vec<String>,
    /// The procedure the golden units were measured with on both benches
    /// and whose later measurements the calibration corrects (default: the
    /// recipe's `procedure.mode`). A station running both calibrates both.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub procedure: Option<crate::qc::ProcedureMode>,
}

/// A bench calibration as served (`POST` and `GET .../bench-calibrations`).
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct BenchCalibrationDocument {
    pub id: String,
    pub recipe: String,
    pub bench_id: String,
    /// `full` or `production`: the procedure it was measured with and corrects.
    pub procedure: String,
    /// `in_calibration` or `out_of_calibration`.
    pub state: String,
    pub calibration: crate::qc::BenchCalibration,
    /// The token that made it (null with open access).
    pub created_by: Option<String>,
    pub created_at: String,
}

/// `GET /api/v1/recipes/{name}/bench-calibrations`: newest first.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct BenchCalibrationList {
    pub items: Vec<BenchCalibrationDocument>,
}

fn calibration_doc(r: &crate::store::BenchCalibrationRow) -> BenchCalibrationDocument {
    BenchCalibrationDocument {
        id: r.id.clone(),
        recipe: r.recipe_name.clone(),
        bench_id: r.bench_id.clone(),
        procedure: r.procedure.clone(),
        state: r.state.clone(),
        calibration: r.calibration.clone(),
        created_by: r.created_by.clone(),
        created_at: r.created_at.clone(),
    }
}

#[utoipa::path(post, path = "/api/v1/recipes/{name}/bench-calibrations", tag = "qc",
    summary = "Calibrate a bench against the reference bench from golden units measured on both (laser sensitivity error, stiffness scale of the clamp mass); later measurements on the bench under the recipe are judged corrected, or invalid when the bench is out of calibration.",
    params(("name" = String, Path, description = "Recipe name")),
    request_body(content = BenchCalibrationRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "Stored (in or out of calibration)", body = BenchCalibrationDocument),
        (status = 422, description = "Invalid fields, or too few golden units measured on both benches"),
        (status = 503, description = "Storage unavailable or the disk is full")))]
/// `POST /api/v1/recipes/{name}/bench-calibrations`.
pub async fn create_calibration(
    State(st): State<AppState>,
    Extension(caller): Extension<super::auth::Caller>,
    Path(name): Path<String>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let req: BenchCalibrationRequest = parse_body(body)?;
    for (f, b) in [
        ("bench", &req.bench),
        ("reference_bench", &req.reference_bench),
    ] {
        if !st.cfg.benches.iter().any(|c| &c.id == b) {
            return Err(Problem::field(f, format!("no bench '{b}' is configured")));
        }
    }
    if !(crate::qc::bench_cal::MIN_UNITS..=200).contains(&req.serials.len()) {
        return Err(Problem::field(
            "serials",
            format!(
                "{} serials; a bench calibration takes {} to 200 golden units",
                req.serials.len(),
                crate::qc::bench_cal::MIN_UNITS
            ),
        ));
    }
    let recipe = super::qc::recipe_for_job(&st, &name).await?.recipe;
    let mass = recipe
        .procedure
        .moving_mass_kg
        .ok_or_else(|| Problem::field("recipe", "the recipe has no moving mass"))?;
    let procedure = req.procedure.unwrap_or(recipe.procedure.mode);
    let pname = procedure.as_str();
    let mut units = vec![];
    let mut missing = vec![];
    for s in &req.serials {
        let a = st
            .store
            .newest_results_on_bench(&name, s, &req.reference_bench, pname)
            .await?;
        let b = st
            .store
            .newest_results_on_bench(&name, s, &req.bench, pname)
            .await?;
        // Every repeat of the newest job's first level: a golden unit
        // measured several times calibrates with all of them (their mean).
        // (A result this version cannot read makes the unit missing, named
        // in the error, rather than calibrating with fewer repeats unseen.)
        let reports = |x: Option<(String, Vec<Value>)>| -> Vec<crate::identify::Report> {
            x.and_then(|(_, v)| {
                v.into_iter()
                    .map(serde_json::from_value)
                    .collect::<Result<Vec<_>, _>>()
                    .ok()
            })
            .unwrap_or_default()
        };
        let (a, b) = (reports(a), reports(b));
        if a.is_empty() || b.is_empty() {
            missing.push(s.clone());
        } else {
            units.push((s.clone(), a, b));
        }
    }
    if !missing.is_empty() {
        return Err(Problem::field(
            "serials",
            format!(
                "no succeeded job with a result under recipe '{name}' measured with the {pname} procedure on both '{}' and '{}' for: {}",
                req.reference_bench,
                req.bench,
                missing.join(", ")
            ),
        ));
    }
    let cal =
        crate::qc::bench_cal::estimate(&req.bench, &req.reference_bench, procedure, mass, &units)
            .map_err(|e| Problem::field("serials", e))?;
    let row = crate::store::BenchCalibrationRow {
        id: crate::runner::new_id(),
        recipe_name: name.clone(),
        bench_id: req.bench.clone(),
        procedure: pname.to_string(),
        state: cal.state.as_str().to_string(),
        calibration: cal,
        created_by: caller.0.clone(),
        created_at: crate::store::now(),
    };
    st.store.insert_bench_calibration(&row).await?;
    Ok((StatusCode::CREATED, Json(Sorted(calibration_doc(&row)))).into_response())
}

#[utoipa::path(get, path = "/api/v1/recipes/{name}/bench-calibrations", tag = "qc",
    summary = "The bench calibrations of a recipe, newest first (the newest per bench is in effect).",
    params(("name" = String, Path, description = "Recipe name")),
    responses((status = 200, description = "Calibrations", body = BenchCalibrationList)))]
/// `GET /api/v1/recipes/{name}/bench-calibrations`.
pub async fn list_calibrations(
    State(st): State<AppState>,
    Path(name): Path<String>,
) -> ApiResult<Json<Sorted<BenchCalibrationList>>> {
    let rows = st.store.list_bench_calibrations(&name).await?;
    Ok(Json(Sorted(BenchCalibrationList {
        items: rows.iter().map(calibration_doc).collect(),
    })))
}
