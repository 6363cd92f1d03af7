//! Corrections with an audit trail over HTTP (issue 20): an admin corrects
//! a part's serial or kind, or voids a measurement, with a reason; nothing
//! is deleted; the audit log is readable by any role. A station's
//! corrections reach the center through the fleet outbox like its
//! measurements (`crates/store/src/corrections.rs`).

use super::auth::Caller;
use super::problem::{ApiResult, Problem};
use super::qc::parse_body;
use super::{AppState, JsonBody, Q};
use crate::store::corrections::Corrections;
use crate::store::fleet::Correction;
use crate::store::{MeasurementReads, PartReads, StoreError};
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::Deserialize;
use serde_json::{json, Value};

/// A correction as an admin asks for it.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CorrectionRequest {
    /// `part_serial` (the part's serial becomes `new_value`; with
    /// `measurement_id`, only that measurement moves), `part_kind` (the
    /// part's kind becomes `new_value`) or `void_measurement` (the
    /// measurement stays stored, out of SPC).
    pub kind: String,
    /// The part concerned (for `part_serial`: its serial now).
    pub part_serial: String,
    /// A measurement of that part: the one to void, or the one to move.
    pub measurement_id: Option<String>,
    /// The new serial or kind.
    pub new_value: Option<String>,
    /// Why (required).
    pub reason: String,
}

#[derive(Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AuditQuery {
    /// Only the corrections of this part (by its serial before or after a serial correction).
    part: Option<String>,
    /// Keyset cursor: the `seq` of the last entry of the previous page.
    after: Option<i64>,
    /// Page size (1-500, default 50).
    limit: Option<i64>,
}

#[utoipa::path(post, path = "/api/v1/corrections", tag = "parts",
    summary = "Correct a part's serial or kind, or void a measurement, with a reason; recorded in the audit log, replicated to the fleet's center.",
    request_body(content = CorrectionRequest, content_type = "application/json"),
    responses(
        (status = 201, description = "Applied; the correction as the audit log keeps it (`old_value` as found)", body = crate::store::fleet::Correction),
        (status = 409, description = "The measurement is void already"),
        (status = 422, description = "A missing or bad field (kind, part_serial, measurement_id, new_value, reason)")))]
/// `POST /api/v1/corrections` (admin).
pub async fn create(
    State(st): State<AppState>,
    Extension(caller): Extension<Caller>,
    JsonBody(body): JsonBody,
) -> ApiResult<Response> {
    let r: CorrectionRequest = parse_body(body)?;
    if !matches!(
        r.kind.as_str(),
        "part_serial" | "part_kind" | "void_measurement"
    ) {
        return Err(Problem::field(
            "kind",
            "one of part_serial, part_kind, void_measurement",
        ));
    }
    if r.reason.trim().is_empty() {
        return Err(Problem::field(
            "reason",
            "required: why the correction is made",
        ));
    }
    let new_value = r.new_value.as_deref().map(str::trim);
    match (r.kind.as_str(), new_value) {
        ("void_measurement", _) if r.measurement_id.is_none() => {
            return Err(Problem::field(
                "measurement_id",
                "required: the measurement to void",
            ))
        }
        ("void_measurement", Some(_)) => {
            return Err(Problem::field("new_value", "a void has no new value"))
        }
        ("part_serial" | "part_kind", None | Some("")) => {
            return Err(Problem::field(
                "new_value",
                "required: the new serial or kind",
            ))
        }
        ("part_serial", Some(v)) if v == r.part_serial => {
            return Err(Problem::field(
                "new_value",
                "the new serial is the part's serial",
            ))
        }
        _ => {}
    }
    // What the center would refuse is refused here, before the 201: the
    // serial rule of a job's part, text without control characters,
    // bounded lengths (issue 36: an 8 000-character serial stopped the
    // station's replication for good).
    if let ("part_serial", Some(v)) = (r.kind.as_str(), new_value) {
        if !springbench_core::job::valid_serial(v) {
            return Err(Problem::field(
                "new_value",
                format!("a serial is {}", springbench_core::job::SERIAL_RULE),
            ));
        }
    }
    for (field, text, max) in [
        ("new_value", new_value, 64),
        ("reason", Some(r.reason.as_str()), 4096),
    ] {
        let Some(t) = text else { continue };
        if t.chars().count() > max {
            return Err(Problem::field(field, format!("at most {max} characters")));
        }
        if let Some(c) = springbench_core::job::bad_char(t) {
            return Err(Problem::field(
                field,
                format!("holds the control character U+{:04X}", c as u32),
            ));
        }
    }
    if st.store.get_part(&r.part_serial).await?.is_none() {
        return Err(Problem::field(
            "part_serial",
            format!("no part '{}'", r.part_serial),
        ));
    }
    if let Some(m) = &r.measurement_id {
        let of = st.store.get_measurement(m).await?.map(|m| m.0.part_serial);
        if of.as_deref() != Some(r.part_serial.as_str()) {
            return Err(Problem::field(
                "measurement_id",
                format!("no measurement '{m}' of part '{}'", r.part_serial),
            ));
        }
        if r.kind == "void_measurement" {
            if let Some(by) = st.store.measurement_void(m).await? {
                return Err(Problem::new(
                    StatusCode::CONFLICT,
                    "conflict",
                    "Void already",
                    format!("measurement '{m}' is void already (correction {by})"),
                ));
            }
        }
    }
    let c = Correction {
        id: crate::runner::new_id(),
        kind: r.kind,
        part_serial: r.part_serial,
        measurement_id: r.measurement_id,
        old_value: None,
        new_value: new_value.map(str::to_string),
        reason: r.reason.trim().to_string(),
        made_by: caller.0,
        made_at: crate::store::now(),
    };
    match st.store.correct(&c).await {
        Ok(_) => {}
        // A change in between (another admin's correction): say it.
        Err(StoreError::Invalid(m)) => return Err(Problem::field("body", m)),
        Err(e) => return Err(e.into()),
    }
    let stored = st
        .store
        .correction(&c.id)
        .await?
        .ok_or_else(|| Problem::internal("the correction is not in the audit log"))?;
    Ok((
        StatusCode::CREATED,
        [(
            header::LOCATION,
            format!(
                "/api/v1/corrections?part={}",
                form_urlencoded::byte_serialize(stored.part_serial.as_bytes()).collect::<String>()
            ),
        )],
        Json(stored),
    )
        .into_response())
}

#[utoipa::path(get, path = "/api/v1/corrections", tag = "parts",
    summary = "The audit log of corrections, oldest first, in keyset pages (`after` = the last entry's seq); of one part with `part`.",
    params(AuditQuery),
    responses(
        (status = 200, description = "`items`: audit log entries; `next_after`: the cursor of the next page (null at the end)", body = serde_json::Value),
        (status = 422, description = "A bad query parameter")))]
/// `GET /api/v1/corrections?part=&after=&limit=`.
pub async fn list(State(st): State<AppState>, Q(q): Q<AuditQuery>) -> ApiResult<Json<Value>> {
    let limit = super::page_limit(q.limit)?;
    if q.after.is_some_and(|a| a < 0) {
        return Err(Problem::field(
            "after",
            "a seq of the audit log (0 or more)",
        ));
    }
    let items = st
        .store
        .audit_log(q.part.as_deref().filter(|p| !p.is_empty()), q.after, limit)
        .await?;
    let next = (items.len() as i64 == limit)
        .then(|| items.last().map(|e| e.seq))
        .flatten();
    Ok(Json(json!({ "items": items, "next_after": next })))
}
