//! The OpenAPI 3.1 document of the API, generated from the Rust types
//! (`#[derive(serde::Serialize, ToSchema)]`), the hand-described schemas of
//! [`super::schema`] and the handlers' `#[utoipa::path]` annotations
//! (decision 0020). Served at `GET /api/openapi.json`; `api/openapi.yaml` is
//! the same document checked into the repository (a test regenerates it and
//! fails on a difference; `SPRINGBENCH_WRITE_OPENAPI=1 cargo test --lib
//! api::openapi` or `springbench openapi` writes it).

use super::auth;
use super::schema::{MeasurementDocumentSchema, Problem};
use crate::config::Role;
use axum::http::{header, HeaderValue, Method};
use axum::response::{IntoResponse, Response};
use std::sync::OnceLock;
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityRequirement, SecurityScheme};
use utoipa::openapi::{Content, Ref, RefOr, Response as OaResponse, Schema};
use utoipa::{Modify, OpenApi};

#[derive(OpenApi)]
#[openapi(
    paths(
        super::ops::healthz,
        super::ops::readyz,
        super::ops::metrics,
        super::ops::config,
        super::ops::benches,
        openapi_json,
        super::benches::self_check,
        super::benches::calibrations,
        super::benches::calibration,
        super::session::session,
        super::jobs::submit,
        super::jobs::list,
        super::jobs::get_one,
        super::jobs::cancel,
        super::longterm::submit,
        super::longterm::list,
        super::longterm::get_one,
        super::longterm::series_csv,
        super::longterm::last_signals,
        super::longterm::put_ambient,
        super::longterm::pause,
        super::longterm::resume,
        super::jobs::list_parts,
        super::jobs::get_part,
        super::jobs::part_measurements,
        super::measurements::list,
        super::import::import,
        super::measurements::get_one,
        super::measurements::recording,
        super::measurements::fit,
        super::measurements::list_fits,
        super::measurements::choose_headline,
        super::report::report,
        super::report::long_term_report,
        super::derived::diagnostics,
        super::derived::plot,
        super::events::events,
        super::qc::create,
        super::qc::list,
        super::qc::get_one,
        super::qc::update,
        super::qc::retire,
        super::qc::versions,
        super::qc::version,
        super::qc::propose,
        super::qc::list_proposals,
        super::qc::spc,
        super::qc::lot_csv,
        super::qc::get_proposal,
        super::qc::approve,
        super::qc::reject,
        super::qc::part_verdict,
        super::qc::job_verdict,
        super::qc::outbox,
        super::qc::outbox_retry,
        super::qc::outbox_drop,
        super::studies::submit,
        super::studies::get_one,
        super::studies::confirm,
        super::stimuli::upload,
        super::stimuli::list,
        super::stimuli::get_one,
        super::gauge::create,
        super::gauge::list,
        super::gauge::get_one,
        super::gauge::create_calibration,
        super::gauge::list_calibrations,
        super::corrections::create,
        super::corrections::list,
        super::fleet::stations,
        super::fleet::parts,
        super::fleet::part,
        super::fleet::measurements,
        super::fleet::measurement,
        super::fleet::recipes,
        super::fleet::verdicts,
        super::fleet::spc,
        super::fleet::yield_per_day,
        super::fleet::audit,
        super::fleet::refusals,
        super::fleet::station_link,
        super::fleet::propose,
        super::fleet::list,
        super::fleet::get_one,
        super::fleet::approve,
        super::fleet::reject,
        super::fleet::retire,
        super::qc::publish,
    ),
    components(schemas(Problem, MeasurementDocumentSchema)),
    modifiers(&Conventions),
    tags(
        (name = "operations", description = "Health, readiness, metrics, configuration, benches, calibration records"),
        (name = "jobs", description = "Measurement jobs"),
        (name = "parts", description = "Parts and their measurements"),
        (name = "measurements", description = "Results, recordings, fits, diagnostics"),
        (name = "events", description = "Websocket event stream"),
        (name = "qc", description = "Recipes, limits, verdicts, SPC"),
        (name = "mes", description = "MES outbox"),
        (name = "fleet", description = "The fleet's center: served only by a daemon in the fleet role \
            (`database = \"postgres://...\"`, no benches; docs/fleet.md), read-only, every route a GET. \
            A station does not serve these. Of the others the fleet role serves the web UI and the \
            reads its parts, measurement, compare and QC views use (`/api/v1/session` with `daemon: center`, \
            parts, measurements, fits, verdicts, recipes, SPC) from the center's store, in the station's \
            shapes with the station of every row; its `/healthz` answers \
            `{\"status\": \"ok\", \"version\": ..., \"role\": \"fleet\"}`."),
    )
)]
struct ApiDoc;

/// What every operation shares: problem documents for errors, the bearer
/// scheme, which routes need no token (from [`auth::required_role`]).
struct Conventions;

impl Modify for Conventions {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        let components = doc.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(Http::new(HttpAuthScheme::Bearer)),
        );
        doc.security = Some(vec![SecurityRequirement::new(
            "bearer",
            Vec::<String>::new(),
        )]);
        let problem = || Content::new(Some(RefOr::<Schema>::Ref(Ref::from_schema_name("Problem"))));
        for (path, item) in doc.paths.paths.iter_mut() {
            let ops = [
                (Method::GET, item.get.as_mut()),
                (Method::POST, item.post.as_mut()),
                (Method::PUT, item.put.as_mut()),
                (Method::DELETE, item.delete.as_mut()),
            ];
            for (method, op) in ops {
                let Some(op) = op else { continue };
                let role = auth::required_role(&method, path);
                if role.is_none() {
                    op.security = Some(vec![]);
                } else {
                    let who = match role {
                        Some(Role::Admin) => "admin",
                        Some(Role::Operator) => "operator or admin",
                        _ => "any role",
                    };
                    let d = format!(
                        "{}\n\nRole: {who}.",
                        op.description.as_deref().unwrap_or("")
                    );
                    op.description = Some(d.trim_start().to_string());
                    op.responses
                        .responses
                        .entry("401".into())
                        .or_insert_with(|| {
                            RefOr::T(OaResponse::new("No token or an unknown token"))
                        });
                    op.responses
                        .responses
                        .entry("403".into())
                        .or_insert_with(|| {
                            RefOr::T(OaResponse::new("The token's role may not do this"))
                        });
                }
                op.responses.responses.entry("default".into()).or_insert_with(|| {
                    RefOr::T(OaResponse::new(
                        "Any other error: 400 unreadable request, 405, 413 too large, 415 not JSON, \
                         503 storage unavailable, 500",
                    ))
                });
                for (code, r) in op.responses.responses.iter_mut() {
                    let error = code == "default" || code.starts_with('4') || code.starts_with('5');
                    if let RefOr::T(r) = r {
                        if error && r.content.is_empty() {
                            r.content
                                .insert("application/problem+json".into(), problem());
                        }
                    }
                }
            }
        }
    }
}

/// The document, built once.
pub fn document() -> &'static utoipa::openapi::OpenApi {
    static DOC: OnceLock<utoipa::openapi::OpenApi> = OnceLock::new();
    DOC.get_or_init(|| {
        let mut d = ApiDoc::openapi();
        d.info.title = "Springbench bench daemon".into();
        d.info.description = Some(INTRO.into());
        d.servers = Some(vec![utoipa::openapi::Server::new("http://127.0.0.1:8750")]);
        d
    })
}

const INTRO: &str = "Measurement jobs for loudspeaker suspension parts (Klippel's dynamic method), results per part.\n\n\
All physical values are SI; the unit is part of every field name (`_m`, `_hz`, `_n_per_m`, ...).\n\
Every 4xx/5xx response is an RFC 9457 problem document (`application/problem+json`);\n\
validation errors (422) list one message per bad field in `errors`.\n\
Authentication: `Authorization: Bearer <token>` with roles viewer (reads), operator\n\
(also submits, cancels, imports, fits) and admin (also reads the configuration, edits recipes,\n\
approves limits, retries and drops MES deliveries). Without configured tokens the daemon listens\n\
on loopback only and needs no token.\n\
Lists are paginated: `limit` (1-500, default 50) and `cursor` (the `next_cursor` of the previous page).\n\n\
This document is generated from the code (src/api/openapi.rs, decision 0020).";

/// The document as pretty JSON (what `GET /api/openapi.json` serves).
pub fn json() -> &'static str {
    static JSON: OnceLock<String> = OnceLock::new();
    JSON.get_or_init(|| {
        document()
            .to_pretty_json()
            .expect("the document serializes")
    })
}

/// The document as YAML (`api/openapi.yaml`).
pub fn yaml() -> String {
    document().to_yaml().expect("the document serializes")
}

/// `GET /api/openapi.json`: the API contract (public, like `/healthz`).
#[utoipa::path(
    get,
    path = "/api/openapi.json",
    tag = "operations",
    summary = "This document (OpenAPI 3.1, generated from the code; equals api/openapi.yaml).",
    responses((status = 200, description = "The OpenAPI document", content_type = "application/json", body = Object))
)]
pub async fn openapi_json() -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        json(),
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;
    use std::collections::BTreeSet;

    /// `api/openapi.yaml` is this document; `SPRINGBENCH_WRITE_OPENAPI=1` rewrites it.
    #[test]
    fn openapi_yaml_is_the_generated_document() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("api/openapi.yaml");
        let want = yaml();
        if std::env::var_os("SPRINGBENCH_WRITE_OPENAPI").is_some() {
            std::fs::write(&path, &want).expect("write api/openapi.yaml");
        }
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        if have != want {
            let line = have
                .lines()
                .zip(want.lines())
                .position(|(a, b)| a != b)
                .unwrap_or(have.lines().count().min(want.lines().count()));
            panic!(
                "api/openapi.yaml differs from the generated document from line {}: \
                 regenerate it with `SPRINGBENCH_WRITE_OPENAPI=1 cargo test --lib api::openapi` \
                 (or `springbench openapi > api/openapi.yaml`) and commit it",
                line + 1
            );
        }
    }

    /// The served JSON and the YAML are one document.
    #[test]
    fn json_and_yaml_are_the_same_document() {
        let from_yaml: Value = serde_norway::from_str(&yaml()).expect("yaml parses");
        let from_json: Value = serde_json::from_str(json()).expect("json parses");
        assert_eq!(from_yaml, from_json);
    }

    /// The router and the document list the same (method, path) pairs.
    #[test]
    fn document_lists_exactly_the_routes_of_the_router() {
        let doc: Value = serde_json::from_str(json()).unwrap();
        let mut documented = BTreeSet::new();
        for (path, item) in doc["paths"].as_object().unwrap() {
            for m in item.as_object().unwrap().keys() {
                if ["get", "post", "put", "patch", "delete", "head"].contains(&m.as_str()) {
                    documented.insert((m.clone(), path.clone()));
                }
            }
        }
        let (_, list) = super::super::routes(&crate::config::Config::default());
        // A station's routes and the fleet role's (all GET).
        let fleet = super::super::fleet::paths();
        let served: BTreeSet<(String, String)> = list
            .iter()
            .map(|(m, p)| (m.to_string(), p.to_string()))
            .chain(fleet.iter().map(|p| ("get".to_string(), p.to_string())))
            .chain(
                super::super::fleet::write_paths()
                    .iter()
                    .map(|(m, p)| (m.to_string(), p.to_string())),
            )
            .collect();
        assert_eq!(
            served.len(),
            list.len() + fleet.len() + super::super::fleet::write_paths().len(),
            "a route is registered twice"
        );
        // The station's reads the fleet role serves too are a station's GET
        // routes (documented once, the same shapes).
        for p in super::super::fleet::station_paths() {
            assert!(
                list.contains(&("get", p)),
                "the fleet role serves {p}, which is no station GET route"
            );
        }
        let missing: Vec<_> = served.difference(&documented).collect();
        let extra: Vec<_> = documented.difference(&served).collect();
        assert!(
            missing.is_empty() && extra.is_empty(),
            "routes without an operation in the document: {missing:?}; \
             operations without a route: {extra:?}"
        );
        assert!(served.len() >= 40, "{}", served.len());
    }

    /// Every operation answers errors with problem documents and names a success.
    #[test]
    fn every_operation_has_a_success_and_problem_errors() {
        let doc: Value = serde_json::from_str(json()).unwrap();
        for (path, item) in doc["paths"].as_object().unwrap() {
            for (m, op) in item.as_object().unwrap() {
                let rs = op["responses"].as_object().unwrap();
                assert!(
                    rs.keys().any(|k| k.starts_with('2') || k == "101"),
                    "{m} {path}: no success response"
                );
                for (code, r) in rs {
                    // /readyz answers 503 with its own document (a probe reads it).
                    let own = path == "/readyz" && code == "503";
                    if !own && (code == "default" || code.starts_with('4') || code.starts_with('5'))
                    {
                        assert!(
                            r["content"]["application/problem+json"].is_object(),
                            "{m} {path} {code}: not a problem document"
                        );
                    }
                }
            }
        }
    }
}
