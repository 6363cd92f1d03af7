//! IPC-CFX-shaped messages of a finished job: `CFX.Production.WorkStarted`,
//! `CFX.Production.TestAndInspection.UnitsTested` (every test's value,
//! limits and result) and `CFX.Production.WorkCompleted`, sharing a
//! `TransactionID` (the job id). Pure: ids and times come from the caller.
//!
//! Envelope (as CFX): `MessageName`, `Version`, `TimeStamp` (when the event
//! happened, not when it is sent), `UniqueID` (for de-duplication), `Source`,
//! `Target`, `RequestID`, `MessageBody`. The transport is an HTTP POST per
//! message instead of AMQP (see docs/qc.md).

use crate::qc::{ParamResult, Verdict, VerdictKind};
use serde_json::{json, Value};

pub const CFX_VERSION: &str = "2.0";
pub const WORK_STARTED: &str = "CFX.Production.WorkStarted";
pub const UNITS_TESTED: &str = "CFX.Production.TestAndInspection.UnitsTested";
pub const WORK_COMPLETED: &str = "CFX.Production.WorkCompleted";

/// One measurement of the job as tested.
#[derive(Debug, Clone)]
pub struct TestedMeasurement {
    pub measurement_id: String,
    pub target_xpeak_m: Option<f64>,
    pub level_index: Option<i64>,
    pub repeat_index: Option<i64>,
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
    /// `Source` of the envelope, e.g. `springbench/virtual-1`.
    pub source: String,
    pub started_at: String,
    pub finished_at: String,
    /// Job state: succeeded, failed, cancelled, interrupted.
    pub state: String,
    /// `name@version` and content hash of the recipe.
    pub recipe: Option<(String, String)>,
    pub job_verdict: Option<Verdict>,
    pub operator: Option<String>,
    pub measurements: Vec<TestedMeasurement>,
}

fn result_of(v: VerdictKind) -> &'static str {
    match v {
        VerdictKind::Pass => "Passed",
        VerdictKind::Fail => "Failed",
        VerdictKind::Invalid => "Inconclusive",
        VerdictKind::NoLimits => "Skipped",
    }
}

fn envelope(name: &str, unique_id: &str, time: &str, source: &str, body: Value) -> Value {
    json!({
        "MessageName": name,
        "Version": CFX_VERSION,
        "TimeStamp": time,
        "UniqueID": unique_id,
        "Source": source,
        "Target": null,
        "RequestID": null,
        "MessageBody": body,
    })
}

fn num(v: f64, unit: &str) -> Value {
    json!({"Value": v, "ValueUnits": unit})
}

/// The three messages of a job: (UniqueID, MessageName, envelope), in order.
pub fn job_messages(f: &JobFacts, ids: [String; 3]) -> Vec<(String, String, Value)> {
    let units =
        json!([{"UnitIdentifier": f.part_serial, "PositionNumber": 1, "PositionName": null}]);
    let started = envelope(
        WORK_STARTED,
        &ids[0],
        &f.started_at,
        &f.source,
        json!({"PrimaryIdentifier": f.part_serial, "HermesIdentifier": null, "TransactionID": f.job_id,
               "Lane": null, "Stage": null, "Units": units}),
    );
    let mut tests = Vec::new();
    for m in &f.measurements {
        let name = format!(
            "suspension level {} repeat {}{}",
            m.level_index.unwrap_or(0),
            m.repeat_index.unwrap_or(0),
            m.target_xpeak_m
                .map(|x| format!(" (target Xpeak {:.3} mm)", x * 1e3))
                .unwrap_or_default()
        );
        let (result, measurements, symptoms) = match &m.verdict {
            Some(v) => {
                let ms: Vec<Value> = v
                    .parameters
                    .iter()
                    .map(|p| {
                        json!({
                            "MeasurementName": p.name,
                            "MeasuredValue": num(p.value, &p.unit),
                            "MinimumAcceptableValue": p.lower.map(|l| num(l, &p.unit)),
                            "MaximumAcceptableValue": p.upper.map(|u| num(u, &p.unit)),
                            "Result": match p.result {
                                ParamResult::Pass => "Passed",
                                ParamResult::Fail => "Failed",
                                ParamResult::NotJudged => "Skipped",
                            },
                            "DisplacementM": p.x_m,
                        })
                    })
                    .collect();
                let mut sy: Vec<Value> = v
                    .failures
                    .iter()
                    .map(|p| json!({"SymptomCode": format!("{}-out-of-limits", p.name),
                                    "Description": format!("{} = {} {} outside [{}, {}]", p.name, p.value, p.unit,
                                        p.lower.map(|x| x.to_string()).unwrap_or_default(),
                                        p.upper.map(|x| x.to_string()).unwrap_or_default())}))
                    .collect();
                sy.extend(v.invalid_reasons.iter().map(
                    |r| json!({"SymptomCode": format!("invalid-{}", r.code), "Description": r.detail}),
                ));
                (result_of(v.verdict), ms, sy)
            }
            None => (
                "Skipped",
                m.values
                    .iter()
                    .map(|(n, v, u)| json!({"MeasurementName": n, "MeasuredValue": num(*v, u),
                                            "MinimumAcceptableValue": null, "MaximumAcceptableValue": null,
                                            "Result": "Skipped"}))
                    .collect(),
                vec![],
            ),
        };
        tests.push(json!({
            "TestName": name,
            "UniqueIdentifier": m.measurement_id,
            "Result": result,
            "TestStartTime": f.started_at,
            "TestEndTime": f.finished_at,
            "Measurements": measurements,
            "SymptomsFound": symptoms,
        }));
    }
    let overall = match (&f.job_verdict, f.state.as_str()) {
        (Some(v), _) => result_of(v.verdict),
        (None, "succeeded") => "Skipped",
        _ => "Aborted",
    };
    let tested = envelope(
        UNITS_TESTED,
        &ids[1],
        &f.finished_at,
        &f.source,
        json!({
            "TransactionID": f.job_id,
            "OverallResult": overall,
            "RecipeName": f.recipe.as_ref().map(|r| r.0.clone()),
            "RecipeSha256": f.recipe.as_ref().map(|r| r.1.clone()),
            "Tester": {"OperatorIdentifier": f.operator},
            "TestMethod": "Automated",
            "TestedUnits": [{
                "UnitIdentifier": f.part_serial,
                "UnitPositionNumber": 1,
                "OverallResult": overall,
                "Tests": tests,
            }],
        }),
    );
    let completed = envelope(
        WORK_COMPLETED,
        &ids[2],
        &f.finished_at,
        &f.source,
        json!({"TransactionID": f.job_id, "PrimaryIdentifier": f.part_serial, "HermesIdentifier": null,
               "Result": if f.state == "succeeded" { "Completed" } else { "Failed" },
               "Units": units}),
    );
    vec![
        (ids[0].clone(), WORK_STARTED.to_string(), started),
        (ids[1].clone(), UNITS_TESTED.to_string(), tested),
        (ids[2].clone(), WORK_COMPLETED.to_string(), completed),
    ]
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
            job_id: "J1".into(),
            part_serial: "SN-1".into(),
            source: "springbench/virtual-1".into(),
            started_at: "2026-01-01T00:00:00.000Z".into(),
            finished_at: "2026-01-01T00:00:02.000Z".into(),
            state: "succeeded".into(),
            recipe: Some(("spider@2".into(), "ab".into())),
            job_verdict: Some(v.clone()),
            operator: Some("station-1".into()),
            measurements: vec![TestedMeasurement {
                measurement_id: "M1".into(),
                target_xpeak_m: Some(0.008),
                level_index: Some(0),
                repeat_index: Some(0),
                verdict: Some(v),
                values: vec![],
            }],
        };
        let m = job_messages(&f, ["a".into(), "b".into(), "c".into()]);
        let names: Vec<&str> = m.iter().map(|x| x.1.as_str()).collect();
        assert_eq!(names, [WORK_STARTED, UNITS_TESTED, WORK_COMPLETED]);
        assert_eq!(m[0].2["TimeStamp"], "2026-01-01T00:00:00.000Z");
        assert_eq!(m[1].2["UniqueID"], "b");
        let body = &m[1].2["MessageBody"];
        assert_eq!(body["TransactionID"], "J1");
        assert_eq!(body["OverallResult"], "Failed");
        let t = &body["TestedUnits"][0]["Tests"][0];
        assert_eq!(t["Result"], "Failed");
        assert_eq!(t["Measurements"][0]["MeasuredValue"]["Value"], 2700.0);
        assert_eq!(
            t["Measurements"][0]["MaximumAcceptableValue"]["Value"],
            2500.0
        );
        assert_eq!(t["Measurements"][1]["Result"], "Passed");
        assert_eq!(t["SymptomsFound"][0]["SymptomCode"], "k0-out-of-limits");
        assert_eq!(m[2].2["MessageBody"]["Result"], "Completed");
    }
}
