//! CFX conformance against the reference C# SDK (issue 34, decision 0095).
//!
//! CI has no network and so no SDK: what the SDK says is pinned here as
//! fixtures the SDK itself produced (`tests/cfx_sdk/run.sh`, with
//! `CFX_SDK_DIR` pointing at a checkout of the SDK):
//! - `shapes.json`: every CFX class's JSON members and their types, every
//!   enum's names, each class's base and whether it is abstract (the SDK's
//!   own contract resolver, by reflection: `Check.exe dump`);
//! - `examples/*.json`: the messages this code writes for a set of jobs
//!   that covers every kind (golden, pass, fail, invalid, production
//!   procedure with a fall-back, level series, cancelled, failed,
//!   interrupted, no recipe) and the endpoint's own messages and answers;
//! - `sdk_check.json`: the SDK's reading of each example (`Check.exe check`):
//!   `CFXEnvelope.FromJson`, the strict reading (unknown member = error,
//!   `$type` honoured) and the SDK's round trip (`ToJson`).
//!
//! [`Shapes::check`] reads a message as strictly as the SDK's strict reading
//! does, from the dump: an unknown or miscased member, a value of the
//! wrong type, an enum name the SDK lacks, a missing `$type` where a list
//! is of an abstract class, `$type` not first: each is an error.

#![allow(dead_code)]

use serde_json::{json, Value};
use springbench::qc::cfx::{self, EndpointFacts, JobFacts, TestedMeasurement};
use springbench::qc::{InvalidReason, ParamOutcome, ParamResult, Quantity, Verdict, VerdictKind};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/cfx_sdk")
}

/// The SDK's JSON shapes (`shapes.json`).
pub struct Shapes {
    types: serde_json::Map<String, Value>,
}

impl Shapes {
    pub fn load() -> Shapes {
        let p = dir().join("shapes.json");
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        Shapes {
            types: v["types"].as_object().unwrap().clone(),
        }
    }

    fn is_a(&self, class: &str, base: &str) -> bool {
        let mut c = class.to_string();
        loop {
            if c == base {
                return true;
            }
            match self.types.get(&c).and_then(|t| t["base"].as_str()) {
                Some(b) => c = b.to_string(),
                None => return false,
            }
        }
    }

    /// Every reason the SDK's strict reading refuses envelope `env`.
    pub fn check(&self, env: &Value) -> Vec<String> {
        let mut errs = vec![];
        let Some(o) = env.as_object() else {
            return vec!["the envelope is not an object".into()];
        };
        let mut head = o.clone();
        head.remove("MessageBody");
        self.object(
            &Value::Object(head),
            "CFX.CFXEnvelope",
            "envelope",
            &mut errs,
        );
        match env["MessageName"].as_str() {
            Some(name) if self.types.contains_key(name) && self.is_a(name, "CFX.CFXMessage") => {
                self.object(&env["MessageBody"], name, name, &mut errs)
            }
            other => errs.push(format!(
                "MessageName {other:?} is no CFX message of the SDK"
            )),
        }
        errs
    }

    fn object(&self, v: &Value, declared: &str, path: &str, errs: &mut Vec<String>) {
        let Some(o) = v.as_object() else {
            if !v.is_null() {
                errs.push(format!("{path}: {v} is not an object ({declared})"));
            }
            return;
        };
        let mut class = declared.to_string();
        if let Some(t) = o.get("$type") {
            if !serde_json::to_string(v).unwrap().starts_with("{\"$type\":") {
                errs.push(format!(
                    "{path}: $type is not the first member (Newtonsoft reads it only there)"
                ));
            }
            let name = t
                .as_str()
                .unwrap_or("")
                .split(',')
                .next()
                .unwrap_or("")
                .trim();
            if !self.types.contains_key(name) || !self.is_a(name, declared) {
                errs.push(format!("{path}: $type {t} is no {declared}"));
                return;
            }
            class = name.to_string();
        }
        let shape = &self.types[&class];
        if shape["abstract"] == true {
            errs.push(format!(
                "{path}: {class} is abstract: the SDK needs \"$type\" (e.g. \"{}\")",
                cfx::NUMERIC_MEASUREMENT_TYPE
            ));
            return;
        }
        let members = shape["members"].as_object().unwrap();
        for (k, x) in o {
            if k == "$type" {
                continue;
            }
            match members.get(k) {
                Some(t) => self.value(x, t.as_str().unwrap(), &format!("{path}.{k}"), errs),
                None => errs.push(format!("{path}: {class} has no member {k}")),
            }
        }
    }

    fn value(&self, v: &Value, ty: &str, path: &str, errs: &mut Vec<String>) {
        if let Some(inner) = ty.strip_suffix('?') {
            if !v.is_null() {
                self.value(v, inner, path, errs);
            }
            return;
        }
        if let Some(item) = ty.strip_prefix("List<").and_then(|t| t.strip_suffix('>')) {
            match v {
                Value::Null => {}
                Value::Array(a) => {
                    for (i, x) in a.iter().enumerate() {
                        self.value(x, item, &format!("{path}[{i}]"), errs);
                    }
                }
                _ => errs.push(format!("{path}: {v} is not a list")),
            }
            return;
        }
        let ok = match ty {
            "System.Object" => true,
            "System.String" => v.is_string() || v.is_null(),
            "System.Double" | "System.Single" | "System.Decimal" => v.is_number(),
            "System.Int32" | "System.Int64" | "System.Int16" | "System.Byte" | "System.UInt32" => {
                v.is_i64() || v.is_u64()
            }
            "System.Boolean" => v.is_boolean(),
            "System.Guid" => v.as_str().is_some_and(is_guid),
            "System.DateTime" => v
                .as_str()
                .is_some_and(|s| chrono::DateTime::parse_from_rfc3339(s).is_ok()),
            "System.TimeSpan" => v.as_str().is_some_and(|s| {
                let p: Vec<&str> = s.split(':').collect();
                p.len() == 3 && p.iter().all(|x| x.parse::<f64>().is_ok())
            }),
            _ if ty.starts_with("Dictionary<") => v.is_object() || v.is_null(),
            _ => match self.types.get(ty) {
                Some(t) if t["kind"] == "enum" => {
                    let names = t["values"].as_array().unwrap();
                    match v {
                        Value::String(s) => names.iter().any(|n| n == s.as_str()),
                        Value::Number(_) => t["as_string"] == false,
                        _ => false,
                    }
                }
                Some(_) => {
                    self.object(v, ty, path, errs);
                    true
                }
                None => {
                    errs.push(format!("{path}: type {ty} is not in the SDK's shapes"));
                    true
                }
            },
        };
        if !ok {
            errs.push(format!("{path}: {v} is not a {ty}"));
        }
    }
}

pub fn is_guid(s: &str) -> bool {
    let g: Vec<&str> = s.split('-').collect();
    g.len() == 5
        && g.iter()
            .zip([8, 4, 4, 4, 12])
            .all(|(x, n)| x.len() == n && x.chars().all(|c| c.is_ascii_hexdigit()))
}

/// Every leaf of `ours` that the SDK's round trip `back` does not hold
/// alike (numbers equal, times the same instant, strings equal); `$type`
/// (the SDK writes without type names) and nulls aside.
pub fn lost_in_round_trip(ours: &Value, back: &Value, path: &str, out: &mut Vec<String>) {
    match (ours, back) {
        (Value::Null, _) => {}
        (Value::Object(a), Value::Object(b)) => {
            for (k, x) in a {
                if k == "$type" {
                    continue;
                }
                lost_in_round_trip(
                    x,
                    b.get(k).unwrap_or(&Value::Null),
                    &format!("{path}.{k}"),
                    out,
                );
            }
        }
        (Value::Array(a), Value::Array(b)) if a.len() == b.len() => {
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                lost_in_round_trip(x, y, &format!("{path}[{i}]"), out);
            }
        }
        (Value::Number(a), Value::Number(b)) if a.as_f64() == b.as_f64() => {}
        (Value::String(a), Value::String(b)) if a == b => {}
        (Value::String(a), Value::String(b))
            if matches!(
                (chrono::DateTime::parse_from_rfc3339(a), chrono::DateTime::parse_from_rfc3339(b)),
                (Ok(x), Ok(y)) if x == y
            ) => {}
        (Value::Bool(a), Value::Bool(b)) if a == b => {}
        _ => out.push(format!("{path}: sent {ours}, the SDK read back {back}")),
    }
}

fn param(
    name: &str,
    q: Quantity,
    unit: &str,
    v: f64,
    lim: (f64, f64),
    x_m: Option<f64>,
) -> ParamOutcome {
    let result = if v < lim.0 || v > lim.1 {
        ParamResult::Fail
    } else {
        ParamResult::Pass
    };
    ParamOutcome {
        name: name.into(),
        quantity: Some(q),
        unit: unit.into(),
        value: v,
        lower: Some(lim.0),
        upper: Some(lim.1),
        result,
        x_m,
    }
}

fn unjudged(name: &str, q: Quantity, unit: &str, v: f64) -> ParamOutcome {
    ParamOutcome {
        name: name.into(),
        quantity: Some(q),
        unit: unit.into(),
        value: v,
        lower: None,
        upper: None,
        result: ParamResult::NotJudged,
        x_m: None,
    }
}

fn verdict(params: Vec<ParamOutcome>, invalid: Vec<(&str, &str)>, no_limits: bool) -> Verdict {
    let failures: Vec<ParamOutcome> = params
        .iter()
        .filter(|p| p.result == ParamResult::Fail)
        .cloned()
        .collect();
    let verdict = match (invalid.is_empty(), failures.is_empty(), no_limits) {
        (false, _, _) => VerdictKind::Invalid,
        (true, false, _) => VerdictKind::Fail,
        (true, true, true) => VerdictKind::NoLimits,
        (true, true, false) => VerdictKind::Pass,
    };
    Verdict {
        verdict,
        failures,
        invalid_reasons: invalid
            .into_iter()
            .map(|(c, d)| InvalidReason {
                code: c.into(),
                detail: d.into(),
            })
            .collect(),
        parameters: params,
    }
}

/// A spider's values: k0, Keff, K(+4 mm) and the model error under the
/// recipe's limits (`spider-4in` revision 3).
fn spider(k0: f64, keff: f64, k4: f64, err: f64) -> Vec<ParamOutcome> {
    vec![
        param("k0", Quantity::K0, "N/m", k0, (2200.0, 2600.0), None),
        param("keff", Quantity::Keff, "N/m", keff, (2300.0, 2800.0), None),
        param(
            "k_at_4mm",
            Quantity::KAtX,
            "N/m",
            k4,
            (2500.0, 3300.0),
            Some(0.004),
        ),
        param(
            "model_error",
            Quantity::ModelError,
            "%",
            err,
            (0.0, 5.0),
            None,
        ),
    ]
}

const SHA: &str = "5f1c0e9a7d3b2c4e6f8091a2b3c4d5e6f708192a3b4c5d6e7f8091a2b3c4d5e6";

fn job(
    n: u32,
    serial: &str,
    state: &str,
    v: Option<Verdict>,
    ms: Vec<TestedMeasurement>,
) -> JobFacts {
    JobFacts {
        job_id: format!("7c9e6679-7425-40de-944b-e07fc1f90a{n:02}"),
        part_serial: serial.into(),
        source: "Acme.Line3.Springbench.virtual-1".into(),
        started_at: "2026-11-28T09:15:02.125Z".into(),
        finished_at: "2026-11-28T09:15:09.480Z".into(),
        state: state.into(),
        recipe: Some(springbench::job::RecipeRef {
            name: "spider-4in".into(),
            version: 3,
            sha256: SHA.into(),
            origin: None,
        }),
        job_verdict: v,
        operator: Some("station-1".into()),
        measurements: ms,
    }
}

fn meas(n: u32, level: i64, xt: f64, procedure: &str, v: Option<Verdict>) -> TestedMeasurement {
    TestedMeasurement {
        measurement_id: format!("2b1e4c7a-3d5f-4a6b-8c9d-0e1f2a3b4c{n:02}"),
        target_xpeak_m: Some(xt),
        level_index: Some(level),
        repeat_index: Some(0),
        procedure: Some(procedure.into()),
        verdict: v,
        values: vec![],
    }
}

/// The example jobs: (name, facts).
pub fn example_jobs() -> Vec<(&'static str, JobFacts)> {
    let golden = verdict(
        vec![
            unjudged("k0", Quantity::K0, "N/m", 2391.4),
            unjudged("keff", Quantity::Keff, "N/m", 2544.0),
            param(
                "model_error",
                Quantity::ModelError,
                "%",
                1.8,
                (0.0, 5.0),
                None,
            ),
        ],
        vec![],
        true,
    );
    let pass = verdict(spider(2405.2, 2551.7, 2873.0, 1.6), vec![], false);
    let fail = verdict(spider(2398.0, 2560.3, 3412.5, 2.1), vec![], false);
    let invalid = verdict(
        spider(2350.0, 2490.0, 2700.0, 9.4),
        vec![(
            "model_error_high",
            "model error 9.4 % above 5 %: the force balance does not hold",
        )],
        false,
    );
    let production = verdict(spider(2410.9, 2549.2, 2866.1, 1.9), vec![], false);
    let levels: Vec<Verdict> = [
        (2402.0, 2470.0, 2791.0),
        (2402.0, 2551.0, 2868.0),
        (2402.0, 2688.0, 2960.0),
    ]
    .iter()
    .map(|&(a, b, c)| verdict(spider(a, b, c, 1.7), vec![], false))
    .collect();
    let no_recipe = JobFacts {
        recipe: None,
        job_verdict: None,
        measurements: vec![TestedMeasurement {
            values: vec![
                ("k0".into(), 2401.0, "N/m".into()),
                ("keff".into(), 2552.5, "N/m".into()),
                ("xpeak".into(), 0.00601, "m".into()),
                ("resonance".into(), 31.7, "Hz".into()),
            ],
            verdict: None,
            ..meas(90, 0, 0.006, "full", None)
        }],
        ..job(90, "S-090", "succeeded", None, vec![])
    };
    let stopped = |code: &str, detail: &str| verdict(vec![], vec![(code, detail)], false);
    vec![
        (
            "golden",
            job(
                1,
                "G-01",
                "succeeded",
                Some(golden.clone()),
                vec![meas(1, 0, 0.006, "full", Some(golden))],
            ),
        ),
        (
            "pass",
            job(
                2,
                "P-02",
                "succeeded",
                Some(pass.clone()),
                vec![meas(2, 0, 0.006, "full", Some(pass))],
            ),
        ),
        (
            "fail",
            job(
                3,
                "P-03",
                "succeeded",
                Some(fail.clone()),
                vec![meas(3, 0, 0.006, "full", Some(fail))],
            ),
        ),
        (
            "invalid",
            job(
                4,
                "P-04",
                "succeeded",
                Some(invalid.clone()),
                vec![meas(4, 0, 0.006, "full", Some(invalid))],
            ),
        ),
        (
            "production",
            job(
                5,
                "P-05",
                "succeeded",
                Some(production.clone()),
                vec![meas(
                5,
                0,
                0.006,
                "production (fell back to the full procedure: the short sweep missed the target)",
                Some(production),
            )],
            ),
        ),
        (
            "levels",
            job(
                6,
                "P-06",
                "succeeded",
                Some(levels[2].clone()),
                levels
                    .iter()
                    .enumerate()
                    .map(|(i, v)| {
                        meas(
                            10 + i as u32,
                            i as i64,
                            0.004 + 0.002 * i as f64,
                            "full",
                            Some(v.clone()),
                        )
                    })
                    .collect(),
            ),
        ),
        ("cancelled", job(7, "P-07", "cancelled", None, vec![])),
        (
            "failed",
            job(
                8,
                "P-08",
                "failed",
                Some(stopped("hardware_fault", "laser: no frames for 2.0 s")),
                vec![],
            ),
        ),
        (
            "interrupted",
            job(
                9,
                "P-09",
                "interrupted",
                Some(stopped(
                    "interrupted",
                    "the daemon stopped while the job ran",
                )),
                vec![],
            ),
        ),
        ("no_recipe", no_recipe),
    ]
}

pub fn endpoint() -> EndpointFacts {
    EndpointFacts {
        handle: "Acme.Line3.Springbench.virtual-1".into(),
        request_uri: "amqp://mes.acme.example:5672".into(),
        request_address: "/queue/Acme.Line3.Springbench.virtual-1".into(),
        software_version: "0.1.0".into(),
    }
}

/// A request from the MES (`Source` Acme.Mes).
pub fn request(name: &str, body: Value) -> Value {
    json!({"MessageName": name, "Version": "2.1", "TimeStamp": "2026-11-28T09:20:00.000Z",
           "UniqueID": "0f0e0d0c-0b0a-4908-8706-050403020100", "Source": "Acme.Mes",
           "Target": "Acme.Line3.Springbench.virtual-1", "RequestID": "REQ-42", "MessageBody": body})
}

/// Every example message: file name -> envelope.
pub fn examples() -> BTreeMap<String, Value> {
    let mut out = BTreeMap::new();
    for (name, f) in example_jobs() {
        for (i, (_, mname, env)) in cfx::job_messages(&f).into_iter().enumerate() {
            let short = mname.rsplit('.').next().unwrap();
            out.insert(format!("job_{name}_{i}_{short}.json"), env);
        }
    }
    let e = endpoint();
    let t = "2026-11-28T09:00:00.000Z";
    let uid = |n: u32| format!("a1b2c3d4-0000-4000-8000-0000000000{n:02}");
    out.insert(
        "endpoint_0_connected.json".into(),
        cfx::endpoint_connected(&e, &uid(1), t).2,
    );
    out.insert(
        "endpoint_1_heartbeat.json".into(),
        cfx::heartbeat(&e, &uid(2), t, 60).2,
    );
    out.insert(
        "endpoint_2_shutting_down.json".into(),
        cfx::endpoint_shutting_down(&e, &uid(3), t).2,
    );
    let reqs = [
        (
            "are_you_there",
            json!({"CFXHandle": "Acme.Line3.Springbench.virtual-1"}),
        ),
        (
            "get_endpoint_information",
            json!({"CFXHandle": "Acme.Line3.Springbench.virtual-1"}),
        ),
        (
            "who_is_there",
            json!({"SupportedTopicQueryType": "Any", "SupportedTopics": []}),
        ),
        ("unsupported", json!({})),
    ];
    let names = [
        cfx::ARE_YOU_THERE_REQUEST,
        cfx::GET_ENDPOINT_INFORMATION_REQUEST,
        cfx::WHO_IS_THERE_REQUEST,
        "CFX.ResourcePerformance.GetActiveFaultsRequest",
    ];
    for (i, ((short, body), name)) in reqs.into_iter().zip(names).enumerate() {
        let r = request(name, body);
        out.insert(
            format!("answer_{i}_{short}.json"),
            cfx::answer(&e, &r, &uid(10 + i as u32), t).2,
        );
    }
    out
}

/// Writes `msgs` to `dir` (one envelope a file, as `Check.exe check` reads them).
pub fn write_messages(dir: &Path, msgs: &BTreeMap<String, Value>) {
    std::fs::create_dir_all(dir).unwrap();
    for (name, v) in msgs {
        std::fs::write(
            dir.join(name),
            serde_json::to_string_pretty(v).unwrap() + "\n",
        )
        .unwrap();
    }
}

/// The SDK itself, when `CFX_SDK_DIR` names a checkout (and mono is
/// installed): its reading of every `*.json` in `msgs` (`Check.exe check`).
pub fn sdk_check(msgs: &Path, out: &Path) -> Option<Value> {
    std::env::var_os("CFX_SDK_DIR")?;
    let st = std::process::Command::new("bash")
        .arg(dir().join("run.sh"))
        .arg("check")
        .arg(msgs)
        .arg(out)
        .status()
        .expect("tests/cfx_sdk/run.sh");
    println!("SDK check: {st}");
    Some(serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap())
}
