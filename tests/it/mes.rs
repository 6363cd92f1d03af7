//! CFX over AMQP 1.0 against a real broker (issue 34, decision 0097):
//! RabbitMQ from Debian with its AMQP 1.0 plugin, private to the tests
//! (`.ci/amqp`; `.ci/run` starts it and sets `SPRINGBENCH_AMQP_DIR` and
//! `SPRINGBENCH_AMQP_TESTS=require`). Without it the tests print why they
//! skip (and fail where it is required).
//!
//! The tests share the broker and one of them stops it: they run one at a
//! time (`BROKER`). Each uses queues of its own.

use crate::common::{self, client, Daemon};
use fe2o3_amqp::sasl_profile::SaslProfile;
use fe2o3_amqp::types::messaging::{Body, Message, Properties, Source, TerminusDurability};
use fe2o3_amqp::types::primitives::{SimpleValue, Value as AmqpValue};
use fe2o3_amqp::{Connection, Receiver, Sender, Session};
use serde_json::{json, Value};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::PathBuf;
use std::time::{Duration, Instant};

static BROKER: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// The private broker: its directory and what `.ci/amqp env` says.
struct Broker {
    dir: PathBuf,
    env: HashMap<String, String>,
}

impl Broker {
    /// None (why printed) without a broker; a panic where one is required.
    fn find() -> Option<Broker> {
        let required = std::env::var("SPRINGBENCH_AMQP_TESTS").as_deref() == Ok("require");
        let Some(dir) = std::env::var_os("SPRINGBENCH_AMQP_DIR").map(PathBuf::from) else {
            assert!(
                !required,
                "SPRINGBENCH_AMQP_TESTS=require but SPRINGBENCH_AMQP_DIR is not set"
            );
            eprintln!(
                "SKIPPED: no AMQP broker (start one: .ci/amqp start DIR; then SPRINGBENCH_AMQP_DIR=DIR)"
            );
            return None;
        };
        let env = match std::fs::read_to_string(dir.join("env")) {
            Ok(s) => s
                .lines()
                .filter_map(|l| l.split_once('='))
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            Err(e) => {
                assert!(!required, "{}: {e}", dir.display());
                eprintln!("SKIPPED: {} holds no broker: {e}", dir.display());
                return None;
            }
        };
        Some(Broker { dir, env })
    }

    fn get(&self, k: &str) -> &str {
        &self.env[k]
    }

    fn script(&self, cmd: &str) {
        let st = std::process::Command::new("bash")
            .arg(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/amqp"))
            .arg(cmd)
            .arg(&self.dir)
            .status()
            .unwrap();
        assert!(st.success(), ".ci/amqp {cmd}: {st}");
    }

    /// The `[mes.broker]` table publishing to node `address` (e.g.
    /// `/queue/NAME`).
    fn config(&self, address: &str, requests: Option<&str>, heartbeat_s: u64) -> String {
        format!(
            "[mes]\nhandle = \"Acme.Line3.Springbench\"\ninitial_backoff_s = 0.2\nmax_backoff_s = 1.0\ntimeout_s = 5.0\n\
             [mes.broker]\nurl = \"{}\"\naddress = \"{address}\"\nuser = \"{}\"\npassword = \"{}\"\nheartbeat_s = {heartbeat_s}\n{}",
            self.get("SPRINGBENCH_AMQP_URL"),
            self.get("SPRINGBENCH_AMQP_USER"),
            self.get("SPRINGBENCH_AMQP_PASSWORD"),
            requests
                .map(|r| format!("request_address = \"/queue/{r}\"\n"))
                .unwrap_or_default()
        )
    }

    async fn connect(
        &self,
    ) -> (
        fe2o3_amqp::connection::ConnectionHandle<()>,
        fe2o3_amqp::session::SessionHandle<()>,
    ) {
        let url = self
            .get("SPRINGBENCH_AMQP_URL")
            .trim_start_matches("amqp://");
        let t = Instant::now();
        loop {
            let tcp = tokio::net::TcpStream::connect(url).await;
            if let Ok(tcp) = tcp {
                let c = Connection::builder()
                    .container_id(format!("test-{}", uuid::Uuid::new_v4()))
                    .hostname("localhost")
                    .scheme("amqp")
                    .sasl_profile(SaslProfile::Plain {
                        username: self.get("SPRINGBENCH_AMQP_USER").into(),
                        password: self.get("SPRINGBENCH_AMQP_PASSWORD").into(),
                    })
                    .open_with_stream(tcp)
                    .await;
                if let Ok(mut c) = c {
                    let s = Session::begin(&mut c).await.unwrap();
                    return (c, s);
                }
            }
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "no connection to the broker"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
}

/// One received message: the envelope and its AMQP properties.
#[derive(Debug, Clone)]
struct Got {
    env: Value,
    durable: Option<bool>,
    /// `springbench-prior-attempts`: the station's earlier tries without
    /// outcome (decision 0098), absent on a first send.
    prior_attempts: Option<u32>,
    message_id: Option<String>,
    to: Option<String>,
    reply_to: Option<String>,
    correlation_id: Option<String>,
    creation_ms: Option<i64>,
    subject: Option<String>,
    content_type: Option<String>,
    app: BTreeMap<String, Option<String>>,
}

fn id_text(m: fe2o3_amqp::types::messaging::MessageId) -> String {
    match m {
        fe2o3_amqp::types::messaging::MessageId::String(s) => s,
        o => format!("{o:?}"),
    }
}

async fn recv(r: &mut Receiver, within: Duration) -> Option<Got> {
    let d = tokio::time::timeout(within, r.recv::<Body<AmqpValue>>())
        .await
        .ok()?
        .unwrap();
    r.accept(&d).await.unwrap();
    let m = d.message();
    let p = m.properties.clone().unwrap_or_default();
    let bytes = springbench::mes::amqp::body_bytes(&m.body).expect("a data body");
    let app = m
        .application_properties
        .as_ref()
        .map(|a| {
            a.0.iter()
                .map(|(k, v)| {
                    (
                        k.clone(),
                        match v {
                            SimpleValue::String(s) => Some(s.clone()),
                            _ => None,
                        },
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    Some(Got {
        env: serde_json::from_slice(&bytes).unwrap(),
        durable: m.header.as_ref().map(|h| h.durable),
        prior_attempts: m.application_properties.as_ref().and_then(|a| {
            match a.get(springbench::mes::amqp::PRIOR_ATTEMPTS) {
                Some(SimpleValue::Uint(n)) => Some(*n),
                _ => None,
            }
        }),
        message_id: p.message_id.map(id_text),
        to: p.to,
        reply_to: p.reply_to,
        correlation_id: p.correlation_id.map(id_text),
        creation_ms: p.creation_time.map(|t| t.milliseconds()),
        subject: p.subject,
        content_type: p.content_type.map(|c| c.0),
        app,
    })
}

/// Every message of queue `q` until none came for `quiet`.
async fn drain(r: &mut Receiver, quiet: Duration) -> Vec<Got> {
    let mut out = vec![];
    while let Some(g) = recv(r, quiet).await {
        out.push(g);
    }
    out
}

/// The SDK's AMQP properties on `g`, as `AmqpUtilities.SetHeaders` of the
/// reference SDK (CFX/Transport/AmqpUtilities.cs) sets them: durable,
/// message-id = UniqueID, to = Target, reply-to = Source, correlation-id =
/// RequestID, content type, creation time = TimeStamp, subject
/// `{Source}.{MessageName}`, and `cfx-topic` (the body class's namespace),
/// `cfx-message`, `cfx-handle`, `cfx-target`.
fn assert_sdk_properties(g: &Got) {
    let e = &g.env;
    let name = e["MessageName"].as_str().unwrap();
    let source = e["Source"].as_str().unwrap();
    assert_eq!(g.durable, Some(true), "{e}");
    assert_eq!(g.message_id.as_deref(), e["UniqueID"].as_str(), "{e}");
    assert_eq!(g.to.as_deref(), e["Target"].as_str(), "{e}");
    assert_eq!(g.reply_to.as_deref(), Some(source), "{e}");
    assert_eq!(g.correlation_id.as_deref(), e["RequestID"].as_str(), "{e}");
    let t = chrono::DateTime::parse_from_rfc3339(e["TimeStamp"].as_str().unwrap()).unwrap();
    assert_eq!(g.creation_ms, Some(t.timestamp_millis()), "{e}");
    assert_eq!(
        g.subject.as_deref(),
        Some(format!("{source}.{name}").as_str())
    );
    assert_eq!(
        g.content_type.as_deref(),
        Some("application/json; charset=\"utf-8\"")
    );
    assert_eq!(g.app["cfx-message"].as_deref(), Some(name));
    assert_eq!(g.app["cfx-handle"].as_deref(), Some(source));
    // the namespace of the body's class: CFX.Production.TestAndInspection
    // for UnitsTested, CFX for Heartbeat
    let topic = match name {
        "CFX.Production.TestAndInspection.UnitsTested" => "CFX.Production.TestAndInspection",
        "CFX.Production.WorkStarted" | "CFX.Production.WorkCompleted" => "CFX.Production",
        _ => "CFX",
    };
    assert_eq!(g.app["cfx-topic"].as_deref(), Some(topic), "{e}");
    assert!(g.app.contains_key("cfx-target"), "{e}");
    assert_eq!(g.app["cfx-target"].as_deref(), e["Target"].as_str());
}

/// A QC lot judged by a recipe with limits on k0 (the virtual spider_4in
/// has 2400 N/m, the `stiff` defect 1.3 times that) and the model error:
/// a part measured twice (passed both times), a stiff part (failed), a
/// part the amplifier cannot drive to the recipe's 8 mm (invalid: Error),
/// another good one. Returns (serial, the job's verdict, the UnitsTested
/// OverallResult that goes with it) in submission order.
async fn qc_lot(c: &reqwest::Client, d: &Daemon) -> Vec<(String, String, &'static str)> {
    let recipe = json!({
        "name": "spider-4in",
        "part_kind": "spider",
        "procedure": {"levels_m": [0.008], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "k0", "quantity": "k0", "lower": 2000.0, "upper": 2800.0},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ]
    });
    common::Api::new(d).create_recipe(&recipe).await;
    let job = |serial: &str, seed: u64, defect: Option<&str>| {
        let mut production = json!({"preset": "spider_4in", "seed": seed});
        if let Some(x) = defect {
            production["defect"] = json!(x);
        }
        json!({"part": {"serial": serial, "kind": "spider"}, "recipe": "spider-4in", "production": production})
    };
    let mut weak = job("U-drive", 801, None);
    weak["limits"] = json!({"max_drive_v": 0.3});
    let lot = [
        (job("P-01", 501, None), "pass", "Passed"),
        (job("D-stiff", 701, Some("stiff")), "fail", "Failed"),
        (job("P-01", 501, None), "pass", "Passed"),
        (weak, "invalid", "Error"),
        (job("P-02", 502, None), "pass", "Passed"),
    ];
    let bodies: Vec<Value> = lot.iter().map(|l| l.0.clone()).collect();
    let ids = submit_all(c, d, &bodies).await;
    let mut out = vec![];
    for (id, (body, want, result)) in ids.iter().zip(&lot) {
        let j = common::wait_job(c, d, id, Duration::from_secs(600), common::terminal).await;
        assert_eq!(j["state"], "succeeded", "{j}");
        assert_eq!(j["verdict"], *want, "{}: {j}", body["part"]["serial"]);
        out.push((
            body["part"]["serial"].as_str().unwrap().to_string(),
            want.to_string(),
            *result,
        ));
    }
    out
}

fn jobs(parts: usize, per_part: usize) -> Vec<Value> {
    (0..parts * per_part)
        .map(|i| json!({"part": {"serial": format!("A-{}", i % parts)}, "preset": "spider_4in", "target_xpeak_m": 0.006}))
        .collect()
}

async fn submit_all(c: &reqwest::Client, d: &Daemon, bodies: &[Value]) -> Vec<String> {
    let mut ids = vec![];
    for b in bodies {
        ids.push(common::submit(c, d, b.clone()).await);
    }
    ids
}

async fn wait_all(c: &reqwest::Client, d: &Daemon, ids: &[String]) {
    for id in ids {
        let j = common::wait_job(c, d, id, Duration::from_secs(600), common::terminal).await;
        assert_eq!(j["state"], "succeeded", "{j}");
    }
}

/// The outbox's deliveries to the broker target, in outbox order.
async fn outbox_rows(d: &Daemon) -> Vec<springbench::store::qc::DeliveryRow> {
    let store = springbench::store::Store::open(&d.dir.join("data"))
        .await
        .unwrap();
    let mut all = vec![];
    for state in ["pending", "delivered", "failed"] {
        all.extend(store.list_outbox(Some(state), 100_000).await.unwrap());
    }
    all.sort_by_key(|x| x.id);
    all.into_iter().filter(|x| x.webhook == "broker").collect()
}

/// (UniqueID, part) of `rows` in outbox order, and the UniqueIDs the station
/// tried before without learning the outcome.
fn expected_and_in_doubt(
    rows: &[springbench::store::qc::DeliveryRow],
) -> (Vec<(String, String)>, Vec<String>) {
    let expected = rows
        .iter()
        .map(|x| (x.unique_id.clone(), x.part_serial.clone()))
        .collect();
    let in_doubt = rows
        .iter()
        // a delivered item's attempts count the one that succeeded
        .filter(|x| x.attempts - i64::from(x.state == "delivered") > 0)
        .map(|x| x.unique_id.clone())
        .collect();
    (expected, in_doubt)
}

/// Per part, the order of first arrival is the outbox's, each message at
/// least once; a message arrives again only if it is one of `in_doubt` (the
/// station tried it before without learning the outcome: a timeout or a lost
/// connection, after which the broker may or may not hold it), and then the
/// later copy is the same envelope and says so (`springbench-prior-attempts`).
/// Returns the UniqueIDs that arrived more than once.
fn assert_arrived_in_order(
    expected: &[(String, String)],
    got: &[Got],
    in_doubt: &[String],
) -> Vec<String> {
    let mut first: HashMap<String, &Got> = HashMap::new();
    let mut per_part: HashMap<String, Vec<String>> = HashMap::new();
    let mut again = vec![];
    for g in got {
        let uid = g.env["UniqueID"].as_str().unwrap().to_string();
        let Some(e) = expected.iter().find(|e| e.0 == uid) else {
            continue; // heartbeats, EndpointConnected
        };
        if let Some(f) = first.get(&uid) {
            assert!(
                in_doubt.contains(&uid),
                "{uid} arrived more than once, but the station never lost an outcome of it"
            );
            assert_eq!(f.env, g.env, "a copy of {uid} differs");
            assert!(
                g.prior_attempts.unwrap_or(0) >= 1,
                "the copy of {uid} does not say it is a retry (prior attempts {:?})",
                g.prior_attempts
            );
            again.push(uid);
        } else {
            per_part.entry(e.1.clone()).or_default().push(uid.clone());
            first.insert(uid, g);
        }
    }
    let missing: Vec<_> = expected
        .iter()
        .filter(|e| !first.contains_key(&e.0))
        .collect();
    assert!(missing.is_empty(), "lost: {missing:?}");
    for (part, uids) in &per_part {
        let want: Vec<String> = expected
            .iter()
            .filter(|e| &e.1 == part)
            .map(|e| e.0.clone())
            .collect();
        assert_eq!(uids, &want, "order of {part}");
    }
    again
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn amqp_qc_lot_arrives_once_in_order_with_the_sdks_properties_and_heartbeats() {
    let Some(b) = Broker::find() else { return };
    let _one = BROKER.lock().await;
    let q = format!("cfx-{}", uuid::Uuid::new_v4());
    let (_conn, mut session) = b.connect().await;
    let mut rx = Receiver::attach(&mut session, "test-lot", format!("/queue/{q}"))
        .await
        .unwrap();
    let log = tempfile::NamedTempFile::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cfg = format!(
        "[[benches]]\nid = \"virtual-1\"\nseed = 1\n[[benches]]\nid = \"virtual-2\"\nseed = 1001\n{}",
        b.config(&format!("/queue/{q}"), None, 2)
    );
    let mut d = Daemon::start_logged(dir.path(), &cfg, Some(log.path()));
    let c = client();
    let lot = qc_lot(&c, &d).await;
    let (expected, in_doubt) = expected_and_in_doubt(&outbox_rows(&d).await);
    assert_eq!(expected.len(), 3 * lot.len(), "three messages a job");
    // Heartbeats: at least three (2 s apart) besides the lot.
    let t = Instant::now();
    let mut got = vec![];
    loop {
        got.extend(drain(&mut rx, Duration::from_millis(500)).await);
        let beats = got
            .iter()
            .filter(|g| g.env["MessageName"] == "CFX.Heartbeat")
            .count();
        let uids: HashSet<&str> = got
            .iter()
            .filter_map(|g| g.env["UniqueID"].as_str())
            .collect();
        if beats >= 6 && expected.iter().all(|e| uids.contains(e.0.as_str())) {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "{beats} heartbeats, {} messages",
            got.len()
        );
    }
    // The configuration's password is neither shown nor logged.
    let shown = common::get(&c, &d, "/api/v1/config").await;
    assert_eq!(shown["mes"]["broker"]["password"], "<redacted>", "{shown}");
    d.terminate();
    got.extend(drain(&mut rx, Duration::from_secs(2)).await);
    let logged = std::fs::read_to_string(log.path()).unwrap();
    assert!(
        !logged.contains(b.get("SPRINGBENCH_AMQP_PASSWORD")),
        "password in the log"
    );
    assert!(!shown
        .to_string()
        .contains(b.get("SPRINGBENCH_AMQP_PASSWORD")));

    let shapes = crate::cfx_sdk::Shapes::load();
    for g in &got {
        assert_sdk_properties(g);
        assert_eq!(shapes.check(&g.env), Vec::<String>::new(), "{}", g.env);
    }
    assert_arrived_in_order(&expected, &got, &in_doubt);
    // The lot's results as the MES reads them, per part in arrival order.
    let mut results: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for g in got
        .iter()
        .filter(|g| g.env["MessageName"] == "CFX.Production.TestAndInspection.UnitsTested")
    {
        let unit = &g.env["MessageBody"]["TestedUnits"][0];
        assert_eq!(
            g.env["MessageBody"]["RecipeName"], "spider-4in",
            "{}",
            g.env
        );
        results
            .entry(unit["UnitIdentifier"].as_str().unwrap().to_string())
            .or_default()
            .push(unit["OverallResult"].as_str().unwrap().to_string());
    }
    let mut want: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for (serial, _, result) in &lot {
        want.entry(serial.clone())
            .or_default()
            .push(result.to_string());
    }
    assert_eq!(results, want);
    let names: Vec<&str> = got
        .iter()
        .map(|g| g.env["MessageName"].as_str().unwrap())
        .collect();
    // Each bench's endpoint: connected first, shutting down last.
    for h in [
        "Acme.Line3.Springbench.virtual-1",
        "Acme.Line3.Springbench.virtual-2",
    ] {
        let mine: Vec<&Got> = got.iter().filter(|g| g.env["Source"] == h).collect();
        assert_eq!(
            mine.first().unwrap().env["MessageName"],
            "CFX.EndpointConnected",
            "{names:?}"
        );
        assert_eq!(
            mine.last().unwrap().env["MessageName"],
            "CFX.EndpointShuttingDown",
            "{names:?}"
        );
        let beats: Vec<chrono::DateTime<chrono::FixedOffset>> = mine
            .iter()
            .filter(|g| g.env["MessageName"] == "CFX.Heartbeat")
            .map(|g| {
                chrono::DateTime::parse_from_rfc3339(g.env["TimeStamp"].as_str().unwrap()).unwrap()
            })
            .collect();
        assert!(beats.len() >= 3, "{h}: {} heartbeats", beats.len());
        // every 2 s: never sooner; a beat may wait while a delivery is
        // under way, so the typical gap (the median) is the period
        let mut gaps: Vec<i64> = beats
            .windows(2)
            .map(|w| (w[1] - w[0]).num_milliseconds())
            .collect();
        assert!(gaps.iter().all(|&g| g >= 1900), "{h}: gaps {gaps:?} ms");
        gaps.sort_unstable();
        let median = gaps[gaps.len() / 2];
        assert!(
            (1900..2600).contains(&median),
            "{h}: heartbeats {gaps:?} ms apart"
        );
        let hb = mine
            .iter()
            .find(|g| g.env["MessageName"] == "CFX.Heartbeat")
            .unwrap();
        assert_eq!(hb.env["MessageBody"]["HeartbeatFrequency"], "00:00:02");
    }
    println!(
        "AMQP: {} messages of a QC lot of {} jobs ({results:?}) arrived once each, in order per part, with the SDK's properties; {} in all",
        expected.len(),
        lot.len(),
        got.len()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn amqp_requests_are_answered_with_their_request_id() {
    let Some(b) = Broker::find() else { return };
    let _one = BROKER.lock().await;
    let q = format!("cfx-{}", uuid::Uuid::new_v4());
    let req_q = format!("req-{}", uuid::Uuid::new_v4());
    let reply_q = format!("reply-{}", uuid::Uuid::new_v4());
    let (_conn, mut session) = b.connect().await;
    let mut replies = Receiver::attach(&mut session, "test-replies", format!("/queue/{reply_q}"))
        .await
        .unwrap();
    let mut published = Receiver::attach(&mut session, "test-pub", format!("/queue/{q}"))
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cfg = format!(
        "[[benches]]\nid = \"virtual-1\"\nseed = 1\n[[benches]]\nid = \"virtual-2\"\nseed = 1001\n{}",
        b.config(&format!("/queue/{q}"), Some(&req_q), 60)
    );
    let mut d = Daemon::start_in(dir.path(), &cfg);
    // connected: the endpoint has announced itself
    let first = recv(&mut published, Duration::from_secs(60))
        .await
        .expect("EndpointConnected");
    assert_eq!(first.env["MessageName"], "CFX.EndpointConnected");
    assert_eq!(
        first.env["MessageBody"]["RequestTargetAddress"],
        format!("/queue/{req_q}")
    );
    let mut tx = Sender::attach(&mut session, "test-requests", format!("/queue/{req_q}"))
        .await
        .unwrap();
    // the second bench's endpoint: the one a request targets answers
    let handle = "Acme.Line3.Springbench.virtual-2";
    let asks = [
        (
            "CFX.AreYouThereRequest",
            json!({"CFXHandle": handle}),
            "CFX.AreYouThereResponse",
        ),
        (
            "CFX.GetEndpointInformationRequest",
            json!({"CFXHandle": handle}),
            "CFX.GetEndpointInformationResponse",
        ),
        (
            "CFX.WhoIsThereRequest",
            json!({"SupportedTopicQueryType": "Any", "SupportedTopics": []}),
            "CFX.WhoIsThereResponse",
        ),
        (
            "CFX.ResourcePerformance.GetActiveFaultsRequest",
            json!({}),
            "CFX.NotSupportedResponse",
        ),
    ];
    let shapes = crate::cfx_sdk::Shapes::load();
    for (i, (name, body, answer)) in asks.iter().enumerate() {
        let rid = format!("REQUEST-{i}-{}", uuid::Uuid::new_v4());
        // WhoIsThereRequest is a broadcast: no Target, every endpoint answers
        let broadcast = *name == "CFX.WhoIsThereRequest";
        let target = if broadcast {
            Value::Null
        } else {
            json!(handle)
        };
        let env = json!({"MessageName": name, "Version": "2.1", "TimeStamp": springbench::store::now(),
            "UniqueID": uuid::Uuid::new_v4().to_string(), "Source": "Acme.Mes", "Target": target,
            "RequestID": rid, "MessageBody": body});
        let msg = Message::builder()
            .properties(
                Properties::builder()
                    .reply_to(format!("/queue/{reply_q}"))
                    .build(),
            )
            .data(fe2o3_amqp::types::primitives::Binary::from(
                env.to_string().into_bytes(),
            ))
            .build();
        tx.send(msg).await.unwrap();
        let mut sources = vec![];
        for _ in 0..if broadcast { 2 } else { 1 } {
            let g = recv(&mut replies, Duration::from_secs(30))
                .await
                .expect("an answer");
            assert_eq!(g.env["MessageName"], *answer, "{}", g.env);
            assert_eq!(g.env["RequestID"], rid.as_str());
            assert_eq!(g.env["Target"], "Acme.Mes");
            assert_sdk_properties(&g);
            assert_eq!(shapes.check(&g.env), Vec::<String>::new(), "{}", g.env);
            if *answer == "CFX.GetEndpointInformationResponse" {
                assert_eq!(
                    g.env["MessageBody"]["EndpointInformation"]["CFXHandle"],
                    handle
                );
            }
            sources.push(g.env["Source"].as_str().unwrap().to_string());
        }
        sources.sort();
        if broadcast {
            assert_eq!(
                sources,
                [
                    "Acme.Line3.Springbench.virtual-1",
                    "Acme.Line3.Springbench.virtual-2"
                ]
            );
        } else {
            assert_eq!(sources, [handle]);
        }
    }
    // nothing more: one answer a request, one a bench for the broadcast
    assert!(recv(&mut replies, Duration::from_secs(1)).await.is_none());
    d.terminate();
    println!(
        "AMQP: 4 requests answered (3 supported, WhoIsThere by both benches, 1 NotSupportedResponse), RequestID kept"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn amqp_broker_away_30_s_during_a_lot_loses_nothing_and_marks_what_it_sends_again() {
    let Some(b) = Broker::find() else { return };
    let _one = BROKER.lock().await;
    let q = format!("cfx-{}", uuid::Uuid::new_v4());
    {
        // The MES's durable queue (a receiver with a durable source declares
        // it so on RabbitMQ), which the station publishes to as an existing
        // queue (`/amq/queue/NAME`: not declared again). A queue the
        // station's `/queue/NAME` declares is not durable, as with the SDK:
        // the broker's restart would lose what it had accepted.
        let (mut conn, mut session) = b.connect().await;
        let rx = Receiver::builder()
            .name("test-declare")
            .source(
                Source::builder()
                    .address(format!("/queue/{q}"))
                    .durable(TerminusDurability::Configuration)
                    .build(),
            )
            .attach(&mut session)
            .await
            .unwrap();
        // RabbitMQ 3.10 answers the detach of a fresh link in a way fe2o3
        // calls IllegalState; the queue exists by then, which is all we need
        let _ = rx.close().await;
        // the mark of a copy sent again (decision 0098) reaches the MES
        // through the broker: a message built as the station's third try
        let side = format!("/queue/{q}-mark");
        let mut rx = Receiver::attach(&mut session, "test-mark-rx", side.as_str())
            .await
            .unwrap();
        let mut tx = Sender::attach(&mut session, "test-mark-tx", side.as_str())
            .await
            .unwrap();
        let env = json!({"MessageName": "CFX.Production.WorkStarted", "UniqueID": "u-mark",
            "Source": "Acme.Line3.Springbench", "Target": null, "RequestID": null,
            "TimeStamp": "2026-11-28T09:00:00.000Z", "MessageBody": {}});
        tx.send(springbench::mes::amqp::amqp_message(&env, 2))
            .await
            .unwrap();
        let g = recv(&mut rx, Duration::from_secs(10))
            .await
            .expect("the marked message");
        assert_eq!(g.env, env);
        assert_eq!(g.prior_attempts, Some(2), "the broker kept the mark");
        let _ = tx.close().await;
        let _ = rx.close().await;
        let _ = session.end().await;
        let _ = conn.close().await;
    }
    let dir = tempfile::tempdir().unwrap();
    let cfg = format!(
        "[[benches]]\nid = \"virtual-1\"\nseed = 1\n{}",
        b.config(&format!("/amq/queue/{q}"), None, 60)
    );
    let mut d = Daemon::start_in(dir.path(), &cfg);
    let c = client();
    let ids = submit_all(&c, &d, &jobs(3, 3)).await;
    // the first job's messages went through; then the broker goes away
    common::wait_job(&c, &d, &ids[0], Duration::from_secs(300), common::terminal).await;
    let t = Instant::now();
    loop {
        let store = springbench::store::Store::open(&d.dir.join("data"))
            .await
            .unwrap();
        if !store
            .list_outbox(Some("delivered"), 10)
            .await
            .unwrap()
            .is_empty()
        {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "nothing delivered");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let count = |state: &'static str| {
        let data = d.dir.join("data");
        async move {
            let store = springbench::store::Store::open(&data).await.unwrap();
            store.list_outbox(Some(state), 100_000).await.unwrap().len()
        }
    };
    let before = count("delivered").await;
    b.script("stop");
    let down = Instant::now();
    // really away: nothing listens on its port
    let addr = b.get("SPRINGBENCH_AMQP_URL").trim_start_matches("amqp://");
    assert!(
        tokio::net::TcpStream::connect(addr).await.is_err(),
        "the broker still listens on {addr}"
    );
    tokio::time::sleep(Duration::from_secs(30)).await;
    let waiting = count("pending").await;
    b.script("start");
    let away_s = down.elapsed().as_secs_f64();
    assert!(
        waiting > 0,
        "nothing waited for the broker: the outage tested nothing"
    );
    wait_all(&c, &d, &ids).await;
    // delivered in full once the broker is back
    let t = Instant::now();
    loop {
        let store = springbench::store::Store::open(&d.dir.join("data"))
            .await
            .unwrap();
        if store.list_outbox(None, 10).await.unwrap().is_empty() {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "the outbox did not empty"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let (expected, in_doubt) = expected_and_in_doubt(&outbox_rows(&d).await);
    assert_eq!(expected.len(), 27);
    d.terminate();
    let (_conn, mut session) = b.connect().await;
    let mut rx = Receiver::builder()
        .name("test-drain")
        .source(
            Source::builder()
                .address(format!("/queue/{q}"))
                .durable(TerminusDurability::Configuration)
                .build(),
        )
        .attach(&mut session)
        .await
        .unwrap();
    let got = drain(&mut rx, Duration::from_secs(3)).await;
    let again = assert_arrived_in_order(&expected, &got, &in_doubt);
    println!(
        "AMQP outage: {} messages written, {before} delivered before the broker stopped, {waiting} waiting when it returned after {away_s:.1} s; \
         all arrived, in order per part; {} retried after an attempt without outcome, {} of them arrived twice, the copy marked (springbench-prior-attempts >= 1)",
        expected.len(),
        in_doubt.len(),
        again.len()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn amqp_over_tls_with_a_local_certificate() {
    let Some(b) = Broker::find() else { return };
    let _one = BROKER.lock().await;
    let q = format!("cfx-{}", uuid::Uuid::new_v4());
    let (_conn, mut session) = b.connect().await;
    let mut rx = Receiver::attach(&mut session, "test-tls", format!("/queue/{q}"))
        .await
        .unwrap();
    let tls_cfg = |ca: &str| {
        format!(
            "[[benches]]\nid = \"virtual-1\"\nseed = 1\n[mes]\nhandle = \"Acme.Line3.Springbench\"\n\
             [mes.broker]\nurl = \"{}\"\naddress = \"/queue/{q}\"\nuser = \"{}\"\npassword = \"{}\"\nca_file = \"{ca}\"\n",
            b.get("SPRINGBENCH_AMQPS_URL"),
            b.get("SPRINGBENCH_AMQP_USER"),
            b.get("SPRINGBENCH_AMQP_PASSWORD"),
        )
    };
    // A certificate authority the broker's certificate does not chain to: refused.
    let other = tempfile::tempdir().unwrap();
    let ca = rcgen::generate_simple_self_signed(vec!["localhost".into()]).unwrap();
    let other_ca = other.path().join("other-ca.pem");
    std::fs::write(&other_ca, ca.cert.pem()).unwrap();
    let log = other.path().join("daemon.log");
    std::fs::create_dir_all(other.path().join("d")).unwrap();
    let mut d = Daemon::start_logged(
        &other.path().join("d"),
        &tls_cfg(other_ca.to_str().unwrap()),
        Some(&log),
    );
    let t = Instant::now();
    let refused = loop {
        let l = std::fs::read_to_string(&log).unwrap_or_default();
        if l.contains("MES broker unreachable") {
            break l;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no TLS refusal logged: {l}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(refused.to_lowercase().contains("certificate"), "{refused}");
    d.terminate();
    assert!(
        recv(&mut rx, Duration::from_secs(1)).await.is_none(),
        "nothing went through"
    );
    // The broker's own CA: connected over TLS.
    let dir = tempfile::tempdir().unwrap();
    let mut d = Daemon::start_in(dir.path(), &tls_cfg(b.get("SPRINGBENCH_AMQP_CA")));
    let g = recv(&mut rx, Duration::from_secs(60))
        .await
        .expect("EndpointConnected over TLS");
    assert_eq!(g.env["MessageName"], "CFX.EndpointConnected");
    assert_eq!(
        g.env["MessageBody"]["RequestNetworkUri"],
        b.get("SPRINGBENCH_AMQPS_URL")
    );
    d.terminate();
    println!("AMQP over TLS: refused with a foreign CA, connected with the broker's");
}

/// Waits until the daemon's log holds `what`; returns the log.
async fn log_with(log: &std::path::Path, what: &str) -> String {
    let t = Instant::now();
    loop {
        let l = std::fs::read_to_string(log).unwrap_or_default();
        if l.contains(what) {
            return l;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no '{what}' in the log: {l}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// The broker's password is never in the log, at any level (RUST_LOG=trace),
/// neither when the broker refuses it nor when it takes it, and
/// `GET /api/v1/config` shows `<redacted>` in its place.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn amqp_credentials_are_never_logged_nor_shown() {
    let Some(b) = Broker::find() else { return };
    let _one = BROKER.lock().await;
    let q = format!("cfx-{}", uuid::Uuid::new_v4());
    let (_conn, mut session) = b.connect().await;
    let mut rx = Receiver::attach(&mut session, "test-secret", format!("/queue/{q}"))
        .await
        .unwrap();
    let right = b.get("SPRINGBENCH_AMQP_PASSWORD").to_string();
    let wrong = format!("wrong-{}", uuid::Uuid::new_v4().simple());
    let c = client();
    let tmp = tempfile::tempdir().unwrap();
    for (i, password) in [&wrong, &right].into_iter().enumerate() {
        let dir = tmp.path().join(format!("d{i}"));
        std::fs::create_dir_all(&dir).unwrap();
        let log = tmp.path().join(format!("daemon-{i}.log"));
        let cfg = format!(
            "[[benches]]\nid = \"virtual-1\"\nseed = 1\n{}",
            b.config(&format!("/queue/{q}"), None, 1).replace(
                &format!("password = \"{right}\""),
                &format!("password = \"{password}\"")
            )
        );
        assert!(cfg.contains(password.as_str()));
        let mut d = Daemon::start_logged_at(&dir, &cfg, Some(&log), "trace");
        let shown = common::get(&c, &d, "/api/v1/config").await;
        assert_eq!(shown["mes"]["broker"]["password"], "<redacted>", "{shown}");
        assert_eq!(
            shown["mes"]["broker"]["user"],
            b.get("SPRINGBENCH_AMQP_USER")
        );
        assert!(!shown.to_string().contains(password.as_str()), "{shown}");
        if password == &wrong {
            // refused by the broker: said in the log, without the password
            log_with(&log, "MES broker unreachable").await;
        } else {
            log_with(&log, "MES broker connected").await;
            let g = recv(&mut rx, Duration::from_secs(30))
                .await
                .expect("EndpointConnected");
            assert_eq!(g.env["MessageName"], "CFX.EndpointConnected");
            // a heartbeat: the connection has lived a while at trace level
            let g = recv(&mut rx, Duration::from_secs(30))
                .await
                .expect("Heartbeat");
            assert_eq!(g.env["MessageName"], "CFX.Heartbeat");
        }
        d.terminate();
        let logged = std::fs::read_to_string(&log).unwrap();
        assert!(logged.lines().count() > 10, "a trace-level log: {logged}");
        assert!(
            !logged.contains(password.as_str()),
            "the password is in the log (daemon {i})"
        );
        println!(
            "daemon {i} ({}): {} log lines at trace level, the password in none; /api/v1/config shows <redacted>",
            if password == &wrong { "refused" } else { "connected" },
            logged.lines().count()
        );
    }
}
