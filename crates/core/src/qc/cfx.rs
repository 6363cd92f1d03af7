//! IPC-CFX messages (IPC-2591, as the reference C# SDK's classes define them;
//! decision 0095): a job's `CFX.Production.WorkStarted`,
//! `CFX.Production.TestAndInspection.UnitsTested` (every value with its
//! limits and units inside `NumericValue`, each measurement a
//! `NumericMeasurement` named by `$type`) and `CFX.Production.WorkCompleted`,
//! sharing the `TransactionID` (the job id); and the endpoint's own messages
//! (`EndpointConnected`, `Heartbeat`, `EndpointShuttingDown`, the answers to
//! requests). Pure: ids and times come from the caller.
//!
//! Envelope: `MessageName`, `Version`, `TimeStamp` (when the event happened,
//! not when it is sent), `UniqueID` (a GUID derived from the job and the
//! message, so a message written twice is the same message), `Source` (the
//! station's CFX handle), `Target`, `RequestID`, `MessageBody`.
//!
//! Nothing is dropped: what CFX has no member for goes where CFX leaves
//! room for text. The K(x) excursion of a K-at-x value is in the
//! measurement's name (`k_at_4mm @ x=+4.000 mm`); the recipe's hash and the
//! procedure are in `Test.TestProcedure`; a level's target excursion in
//! `TestName`; why a measurement is invalid in `Test.Error` and
//! `SymptomsFound`.

use crate::job::RecipeRef;
use crate::qc::{ParamResult, Verdict, VerdictKind};
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

/// The CFX version the messages follow (the SDK's `CFXEnvelope.CFXVERSION`):
/// `WorkStarted.RecipeName`/`Revision` are 2.1 members.
pub const CFX_VERSION: &str = "2.1";
pub const WORK_STARTED: &str = "CFX.Production.WorkStarted";
pub const UNITS_TESTED: &str = "CFX.Production.TestAndInspection.UnitsTested";
pub const WORK_COMPLETED: &str = "CFX.Production.WorkCompleted";
pub const ENDPOINT_CONNECTED: &str = "CFX.EndpointConnected";
pub const HEARTBEAT: &str = "CFX.Heartbeat";
pub const ENDPOINT_SHUTTING_DOWN: &str = "CFX.EndpointShuttingDown";
pub const ARE_YOU_THERE_REQUEST: &str = "CFX.AreYouThereRequest";
pub const ARE_YOU_THERE_RESPONSE: &str = "CFX.AreYouThereResponse";
pub const GET_ENDPOINT_INFORMATION_REQUEST: &str = "CFX.GetEndpointInformationRequest";
pub const GET_ENDPOINT_INFORMATION_RESPONSE: &str = "CFX.GetEndpointInformationResponse";
pub const WHO_IS_THERE_REQUEST: &str = "CFX.WhoIsThereRequest";
pub const WHO_IS_THERE_RESPONSE: &str = "CFX.WhoIsThereResponse";
pub const NOT_SUPPORTED_RESPONSE: &str = "CFX.NotSupportedResponse";
/// `$type` of a measurement: `Test.Measurements` is a list of the abstract
/// `CFX.Structures.Measurement`, which the SDK reads only with this as the
/// first member of each item.
pub const NUMERIC_MEASUREMENT_TYPE: &str = "CFX.Structures.NumericMeasurement, CFX";

/// A GUID derived from `parts` (RFC 9562 section 5.8, the SHA-256
/// name-based version 8 of its appendix B.2): equal parts, equal GUID.
pub fn derived_uuid(parts: &[&str]) -> String {
    let mut h = Sha256::new();
    h.update(b"springbench-cfx");
    for p in parts {
        h.update((p.len() as u64).to_le_bytes());
        h.update(p.as_bytes());
    }
    let d = h.finalize();
    let mut b = [0u8; 16];
    b.copy_from_slice(&d[..16]);
    b[6] = (b[6] & 0x0f) | 0x80; // version 8
    b[8] = (b[8] & 0x3f) | 0x80; // variant RFC 9562
    let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

/// `id` when it is a GUID (8-4-4-4-12 hex digits), else a GUID derived from it
/// (CFX's `TransactionID` is a GUID; job ids are UUIDs, imported ones may not be).
pub fn as_guid(id: &str) -> String {
    let groups: Vec<&str> = id.split('-').collect();
    let lens = [8, 4, 4, 4, 12];
    if groups.len() == 5
        && groups
            .iter()
            .zip(lens)
            .all(|(g, n)| g.len() == n && g.chars().all(|c| c.is_ascii_hexdigit()))
    {
        id.to_ascii_lowercase()
    } else {
        derived_uuid(&["id", id])
    }
}

/// One measurement of the job as tested.
#[derive(Debug, Clone)]
pub struct TestedMeasurement {
    pub measurement_id: String,
    pub target_xpeak_m: Option<f64>,
    pub level_index: Option<i64>,
    pub repeat_index: Option<i64>,
    /// `full` or `production` (the procedure that measured it), if known.
    pub procedure: Option<String>,
    /// The verdict under the job's recipe; None without a recipe.
    pub verdict: Option<Verdict>,
    /// Headline values without a recipe: (name, value, unit).
    pub values: Vec<(String, f64, String)>,
}

/// The headline values a job's `UnitsTested` carries without a recipe, from
/// the typed result document: (name, value, unit). A small-signal k0 that
/// was not determined is left out (it is null in the document).
pub fn tested_values(r: &crate::identify::Report) -> Vec<(String, f64, String)> {
    let l = &r.large_signal;
    [
        (
            "k0",
            r.small_signal.as_ref().and_then(|s| s.k0_n_per_m),
            "N/m",
        ),
        ("keff", Some(l.keff_n_per_m), "N/m"),
        ("xpeak", Some(l.xpeak_m), "m"),
        ("resonance", Some(l.resonance_hz), "Hz"),
    ]
    .into_iter()
    .filter_map(|(n, v, u)| v.map(|v| (n.to_string(), v, u.to_string())))
    .collect()
}

/// What the messages of one job say.
#[derive(Debug, Clone)]
pub struct JobFacts {
    pub job_id: String,
    pub part_serial: String,
    /// `Source` of the envelope: the station's CFX handle.
    pub source: String,
    pub started_at: String,
    pub finished_at: String,
    /// Job state: succeeded, failed, cancelled, interrupted.
    pub state: String,
    /// The recipe (name, version, content hash).
    pub recipe: Option<RecipeRef>,
    pub job_verdict: Option<Verdict>,
    pub operator: Option<String>,
    pub measurements: Vec<TestedMeasurement>,
}

/// A measurement's CFX result. An invalid measurement is `Error` (it could
/// not be judged: no pass or fail); a valid one without limits (golden
/// units, a recipe still learning its limits) has nothing to fail: `Passed`,
/// and its values carry no limits. `Skipped` is CFX's bad mark: never sent.
fn result_of(v: VerdictKind) -> &'static str {
    match v {
        VerdictKind::Pass | VerdictKind::NoLimits => "Passed",
        VerdictKind::Fail => "Failed",
        VerdictKind::Invalid => "Error",
    }
}

/// An envelope: (UniqueID, MessageName, JSON).
pub type Message = (String, String, Value);

/// An envelope. `request_id` / `target`: the answer to a request.
pub fn envelope(
    name: &str,
    unique_id: &str,
    time: &str,
    source: &str,
    target: Option<&str>,
    request_id: Option<&str>,
    body: Value,
) -> Message {
    (
        unique_id.to_string(),
        name.to_string(),
        json!({
            "MessageName": name,
            "Version": CFX_VERSION,
            "TimeStamp": time,
            "UniqueID": unique_id,
            "Source": source,
            "Target": target,
            "RequestID": request_id,
            "MessageBody": body,
        }),
    )
}

fn job_envelope(f: &JobFacts, name: &str, time: &str, body: Value) -> Message {
    let uid = derived_uuid(&["job", &f.job_id, name]);
    envelope(name, &uid, time, &f.source, None, None, body)
}

fn units(f: &JobFacts) -> Value {
    json!([{"UnitIdentifier": f.part_serial, "PositionNumber": 1, "PositionName": null}])
}

/// `WorkStarted`: written when the job starts measuring.
pub fn work_started(f: &JobFacts) -> Message {
    job_envelope(
        f,
        WORK_STARTED,
        &f.started_at,
        json!({
            "PrimaryIdentifier": f.part_serial,
            "HermesIdentifier": null,
            "TransactionID": as_guid(&f.job_id),
            "Lane": null,
            "Units": units(f),
            "RecipeName": f.recipe.as_ref().map(|r| r.name.clone()),
            "Revision": f.recipe.as_ref().map(|r| r.version.to_string()),
        }),
    )
}

/// A measured value in CFX: a `NumericMeasurement` whose `NumericValue`
/// holds the value, the limits and their units.
#[allow(clippy::too_many_arguments)]
fn numeric(
    uid: String,
    name: String,
    seq: usize,
    value: f64,
    unit: &str,
    lower: Option<f64>,
    upper: Option<f64>,
    result: &str,
) -> Value {
    json!({
        "$type": NUMERIC_MEASUREMENT_TYPE,
        "UniqueIdentifier": uid,
        "MeasurementName": name,
        "Sequence": seq,
        "Result": result,
        "MeasuredValue": {
            "Value": value,
            "ValueUnits": unit,
            "MinimumAcceptableValue": lower,
            "MinimumAcceptableValueUnits": lower.map(|_| unit),
            "MaximumAcceptableValue": upper,
            "MaximumAcceptableValueUnits": upper.map(|_| unit),
        },
    })
}

fn fmt_limit(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_else(|| "-".into())
}

/// The `Test` of one measurement.
fn test_of(f: &JobFacts, m: &TestedMeasurement) -> Value {
    let name = format!(
        "suspension level {} repeat {}{}",
        m.level_index.unwrap_or(0),
        m.repeat_index.unwrap_or(0),
        m.target_xpeak_m
            .map(|x| format!(" (target Xpeak {:.3} mm)", x * 1e3))
            .unwrap_or_default()
    );
    let mid = &m.measurement_id;
    let muid = |what: &str| derived_uuid(&["measurement", mid, what]);
    let procedure = format!(
        "springbench suspension test (dynamic method), procedure {}{}",
        m.procedure.as_deref().unwrap_or("full"),
        f.recipe
            .as_ref()
            .map(|r| format!(
                "; recipe {} revision {} sha256 {}",
                r.name, r.version, r.sha256
            ))
            .unwrap_or_else(|| "; no recipe: values not judged".into())
    );
    let mut comments = None;
    let mut error = None;
    let (result, measurements, symptoms) = match &m.verdict {
        Some(v) => {
            let invalid = v.verdict == VerdictKind::Invalid;
            let ms: Vec<Value> = v
                .parameters
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let name = match p.x_m {
                        Some(x) => format!("{} @ x={:+.3} mm", p.name, x * 1e3),
                        None => p.name.clone(),
                    };
                    // An invalid measurement has no pass or fail per value.
                    let r = match (invalid, p.result) {
                        (true, _) => "Error",
                        (false, ParamResult::Fail) => "Failed",
                        (false, ParamResult::Pass | ParamResult::NotJudged) => "Passed",
                    };
                    numeric(
                        muid(&format!("{i}:{}", p.name)),
                        name,
                        i + 1,
                        p.value,
                        &p.unit,
                        p.lower,
                        p.upper,
                        r,
                    )
                })
                .collect();
            // An invalid measurement's values were not judged: no
            // out-of-limits symptom, only why it is invalid.
            let judged = if invalid { &[][..] } else { &v.failures[..] };
            let mut sy: Vec<Value> = judged
                .iter()
                .map(|p| {
                    let code = format!("{}-out-of-limits", p.name);
                    json!({"UniqueIdentifier": muid(&format!("symptom:{code}")),
                           "SymptomCode": code,
                           "Description": format!("{} = {} {} outside [{}, {}]{}", p.name, p.value, p.unit,
                                fmt_limit(p.lower), fmt_limit(p.upper),
                                p.x_m.map(|x| format!(" at x = {:+.3} mm", x * 1e3)).unwrap_or_default())})
                })
                .collect();
            sy.extend(v.invalid_reasons.iter().map(|r| {
                let code = format!("invalid-{}", r.code);
                json!({"UniqueIdentifier": muid(&format!("symptom:{code}")),
                       "SymptomCode": code, "Description": r.detail})
            }));
            if invalid {
                error = Some(
                    v.invalid_reasons
                        .iter()
                        .map(|r| format!("{}: {}", r.code, r.detail))
                        .collect::<Vec<_>>()
                        .join("; "),
                );
            }
            if v.verdict == VerdictKind::NoLimits {
                comments = Some("the recipe has no limits yet (golden units): values not judged");
            }
            (result_of(v.verdict), ms, sy)
        }
        None => {
            comments = Some("no recipe: values not judged");
            (
                "Passed",
                m.values
                    .iter()
                    .enumerate()
                    .map(|(i, (n, v, u))| {
                        numeric(
                            muid(&format!("{i}:{n}")),
                            n.clone(),
                            i + 1,
                            *v,
                            u,
                            None,
                            None,
                            "Passed",
                        )
                    })
                    .collect(),
                vec![],
            )
        }
    };
    json!({
        "UniqueIdentifier": mid,
        "TestName": name,
        "TestProcedure": procedure,
        "Comments": comments,
        "Result": result,
        "Error": error,
        "TestStartTime": f.started_at,
        "TestEndTime": f.finished_at,
        "Measurements": measurements,
        "SymptomsFound": symptoms,
    })
}

/// The unit's overall result. A cancelled job is `Aborted`; a job that
/// failed or was interrupted is `Error` (no verdict could be reached); else
/// the job's verdict.
fn overall_of(f: &JobFacts) -> &'static str {
    match (f.state.as_str(), &f.job_verdict) {
        ("cancelled", _) => "Aborted",
        ("succeeded", Some(v)) => result_of(v.verdict),
        ("succeeded", None) => "Passed",
        _ => "Error",
    }
}

/// `UnitsTested`: every measurement of the job.
pub fn units_tested(f: &JobFacts) -> Message {
    let tests: Vec<Value> = f.measurements.iter().map(|m| test_of(f, m)).collect();
    job_envelope(
        f,
        UNITS_TESTED,
        &f.finished_at,
        json!({
            "TransactionId": as_guid(&f.job_id),
            "RecipeName": f.recipe.as_ref().map(|r| r.name.clone()),
            "RecipeRevision": f.recipe.as_ref().map(|r| r.version.to_string()),
            "Tester": {"OperatorIdentifier": f.operator, "ActorType": "Robot"},
            "TestMethod": "Automated",
            "TestedUnits": [{
                "UnitIdentifier": f.part_serial,
                "UnitPositionNumber": 1,
                "OverallResult": overall_of(f),
                "Tests": tests,
            }],
        }),
    )
}

/// `WorkCompleted`: `Completed` when the job ran and the part passed (or
/// had nothing to fail), `Failed` when it ran and the part failed or could
/// not be judged (CFX: completed, with an undesirable result), `Aborted`
/// when the job did not complete (cancelled, failed, interrupted).
pub fn work_completed(f: &JobFacts) -> Message {
    let result = match (f.state.as_str(), &f.job_verdict) {
        ("succeeded", Some(v)) if matches!(v.verdict, VerdictKind::Fail | VerdictKind::Invalid) => {
            "Failed"
        }
        ("succeeded", _) => "Completed",
        _ => "Aborted",
    };
    job_envelope(
        f,
        WORK_COMPLETED,
        &f.finished_at,
        json!({"TransactionID": as_guid(&f.job_id), "PrimaryIdentifier": f.part_serial,
               "HermesIdentifier": null, "Result": result, "Units": units(f)}),
    )
}

/// The three messages of a job, in order. `WorkStarted` is the one written
/// when the job started (same UniqueID): the outbox keeps one of each.
pub fn job_messages(f: &JobFacts) -> Vec<Message> {
    vec![work_started(f), units_tested(f), work_completed(f)]
}

/// What an endpoint says about itself (`EndpointConnected`, answers).
#[derive(Debug, Clone)]
pub struct EndpointFacts {
    pub handle: String,
    /// The broker's address as a URI (`amqp://host:port`), without credentials.
    pub request_uri: String,
    /// The node the endpoint takes requests on.
    pub request_address: String,
    pub software_version: String,
}

pub fn endpoint_connected(e: &EndpointFacts, uid: &str, time: &str) -> Message {
    envelope(
        ENDPOINT_CONNECTED,
        uid,
        time,
        &e.handle,
        None,
        None,
        json!({"CFXHandle": e.handle, "RequestNetworkUri": e.request_uri,
               "RequestTargetAddress": e.request_address}),
    )
}

/// `HeartbeatFrequency` as .NET writes a `TimeSpan` (`hh:mm:ss`).
pub fn timespan(s: u64) -> String {
    format!("{:02}:{:02}:{:02}", s / 3600, (s / 60) % 60, s % 60)
}

pub fn heartbeat(e: &EndpointFacts, uid: &str, time: &str, period_s: u64) -> Message {
    envelope(
        HEARTBEAT,
        uid,
        time,
        &e.handle,
        None,
        None,
        json!({"CFXHandle": e.handle, "HeartbeatFrequency": timespan(period_s),
               "ActiveFaults": [], "ActiveRecipes": []}),
    )
}

pub fn endpoint_shutting_down(e: &EndpointFacts, uid: &str, time: &str) -> Message {
    envelope(
        ENDPOINT_SHUTTING_DOWN,
        uid,
        time,
        &e.handle,
        None,
        None,
        json!({"CFXHandle": e.handle}),
    )
}

fn success() -> Value {
    json!({"Result": "Success", "ResultCode": 0, "Message": null})
}

/// The answer to a request envelope `req` (MessageName, Source, RequestID):
/// `Target` is the requester, `RequestID` the request's.
pub fn answer(e: &EndpointFacts, req: &Value, uid: &str, time: &str) -> Message {
    let name = req["MessageName"].as_str().unwrap_or("");
    let target = req["Source"].as_str();
    let rid = req["RequestID"].as_str();
    let me = || {
        json!({"Result": success(), "CFXHandle": e.handle, "RequestNetworkUri": e.request_uri,
               "RequestTargetAddress": e.request_address})
    };
    let (rname, body) = match name {
        ARE_YOU_THERE_REQUEST => (ARE_YOU_THERE_RESPONSE, me()),
        WHO_IS_THERE_REQUEST => (WHO_IS_THERE_RESPONSE, me()),
        GET_ENDPOINT_INFORMATION_REQUEST => (
            GET_ENDPOINT_INFORMATION_RESPONSE,
            json!({"Result": success(), "EndpointInformation": {
                "CFXHandle": e.handle, "CFXVersion": CFX_VERSION,
                "RequestNetworkUri": e.request_uri, "RequestTargetAddress": e.request_address,
                "UniqueIdentifier": derived_uuid(&["endpoint", &e.handle]),
                "FriendlyName": "Springbench loudspeaker suspension test bench",
                "Vendor": "Springbench", "ModelNumber": "springbench",
                "SoftwareVersion": e.software_version, "NumberOfLanes": 1,
                "SupportedTopics": [
                    {"TopicName": "CFX", "TopicSupportType": "Publisher"},
                    {"TopicName": "CFX.Production", "TopicSupportType": "Publisher"},
                    {"TopicName": "CFX.Production.TestAndInspection", "TopicSupportType": "Publisher"},
                ],
            }}),
        ),
        _ => (
            NOT_SUPPORTED_RESPONSE,
            json!({"RequestResult": {"Result": "Failed", "ResultCode": 0,
                   "Message": format!("{name} is not supported by this endpoint")}}),
        ),
    };
    envelope(rname, uid, time, &e.handle, target, rid, body)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::qc::{ParamOutcome, Quantity};

    #[test]
    fn units_tested_carries_every_value_limit_and_result() {
        let p = |name: &str, v: f64, r: ParamResult| ParamOutcome {
            name: name.into(),
            quantity: Some(Quantity::K0),
            unit: "N/m".into(),
            value: v,
            lower: Some(2300.0),
            upper: Some(2500.0),
            result: r,
            x_m: None,
        };
        let v = Verdict {
            verdict: VerdictKind::Fail,
            failures: vec![p("k0", 2700.0, ParamResult::Fail)],
            invalid_reasons: vec![],
            parameters: vec![
                p("k0", 2700.0, ParamResult::Fail),
                p("keff", 2400.0, ParamResult::Pass),
            ],
        };
        let f = JobFacts {
            job_id: "0d8f0b47-3f4c-4d8e-9a55-8b1f0c2a7e11".into(),
            part_serial: "SN-1".into(),
            source: "Springbench.Line3.Bench1".into(),
            started_at: "2026-01-01T00:00:00.000Z".into(),
            finished_at: "2026-01-01T00:00:02.000Z".into(),
            state: "succeeded".into(),
            recipe: Some(RecipeRef {
                name: "spider".into(),
                version: 2,
                sha256: "ab".into(),
                origin: None,
            }),
            job_verdict: Some(v.clone()),
            operator: Some("station-1".into()),
            measurements: vec![TestedMeasurement {
                measurement_id: "M1".into(),
                target_xpeak_m: Some(0.008),
                level_index: Some(0),
                repeat_index: Some(0),
                procedure: None,
                verdict: Some(v),
                values: vec![],
            }],
        };
        let m = job_messages(&f);
        let names: Vec<&str> = m.iter().map(|x| x.1.as_str()).collect();
        assert_eq!(names, [WORK_STARTED, UNITS_TESTED, WORK_COMPLETED]);
        assert_eq!(m[0].2["TimeStamp"], "2026-01-01T00:00:00.000Z");
        // Derived from the job: the same on every call, one per message.
        assert_eq!(m[1].0, job_messages(&f)[1].0);
        assert_ne!(m[0].0, m[1].0);
        assert_eq!(m[1].2["UniqueID"], m[1].0.as_str());
        let body = &m[1].2["MessageBody"];
        assert_eq!(body["TransactionId"], f.job_id.as_str());
        assert_eq!(body["RecipeName"], "spider");
        assert_eq!(body["RecipeRevision"], "2");
        assert_eq!(body["TestedUnits"][0]["OverallResult"], "Failed");
        let t = &body["TestedUnits"][0]["Tests"][0];
        assert_eq!(t["Result"], "Failed");
        let k0 = &t["Measurements"][0];
        assert_eq!(k0["$type"], NUMERIC_MEASUREMENT_TYPE);
        assert_eq!(k0["MeasuredValue"]["Value"], 2700.0);
        assert_eq!(k0["MeasuredValue"]["MaximumAcceptableValue"], 2500.0);
        assert_eq!(k0["MeasuredValue"]["MaximumAcceptableValueUnits"], "N/m");
        assert_eq!(t["Measurements"][1]["Result"], "Passed");
        assert_eq!(t["SymptomsFound"][0]["SymptomCode"], "k0-out-of-limits");
        assert!(t["TestProcedure"].as_str().unwrap().contains("sha256 ab"));
        // completed, with an undesirable result
        assert_eq!(m[2].2["MessageBody"]["Result"], "Failed");
    }

    #[test]
    fn derived_guids_are_version_8_and_stable() {
        let a = derived_uuid(&["job", "J1", WORK_STARTED]);
        assert_eq!(a, derived_uuid(&["job", "J1", WORK_STARTED]));
        assert_ne!(a, derived_uuid(&["job", "J1", WORK_COMPLETED]));
        // no ambiguity between ("ab","c") and ("a","bc")
        assert_ne!(derived_uuid(&["ab", "c"]), derived_uuid(&["a", "bc"]));
        assert_eq!(a.len(), 36);
        assert_eq!(&a[14..15], "8");
        assert!(matches!(&a[19..20], "8" | "9" | "a" | "b"));
        assert_eq!(as_guid(&a), a);
        assert_eq!(as_guid("job-7").len(), 36);
        assert_eq!(timespan(60), "00:01:00");
        assert_eq!(timespan(3725), "01:02:05");
    }
}
