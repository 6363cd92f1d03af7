//! IPC-CFX over AMQP 1.0 (decision 0097): the outbox's broker target.
//!
//! One connection to the broker in `[mes.broker]` (fe2o3-amqp; TLS by
//! tokio-rustls on ring, handed to fe2o3 as its stream). On it:
//! - the outbox's deliveries of the broker target, in order per part, each
//!   marked delivered only once the broker has accepted it (at least once:
//!   a message whose acceptance was lost goes again, with the same
//!   message-id); while the broker is away, attempts back off as for a
//!   webhook, and nothing leaves the outbox undelivered;
//! - the endpoint's life, for each bench's handle: `EndpointConnected` on
//!   every connection, a `Heartbeat` every `heartbeat_s`,
//!   `EndpointShuttingDown` when the daemon stops;
//! - requests taken from `request_address`: `AreYouThereRequest`,
//!   `GetEndpointInformationRequest` and `WhoIsThereRequest` are answered,
//!   anything else gets `NotSupportedResponse`, each with the request's
//!   `RequestID`, to the request's reply-to address (else `address`).
//!
//! Every message carries the SDK's AMQP properties
//! (`CFX/Transport/AmqpUtilities.cs`): message-id = UniqueID, subject
//! `{handle}.{MessageName}`, content type `application/json;
//! charset="utf-8"`, durable, and the application properties `cfx-topic`,
//! `cfx-message`, `cfx-handle`, `cfx-target`; the body is one data section
//! of the envelope's UTF-8 JSON.

use super::{backoff_s, rfc3339_in, MesConfig};
use crate::qc::cfx::{self, EndpointFacts};
use crate::store::Store;
use fe2o3_amqp::connection::ConnectionHandle;
use fe2o3_amqp::sasl_profile::SaslProfile;
use fe2o3_amqp::session::SessionHandle;
use fe2o3_amqp::types::messaging::{
    ApplicationProperties, Body, Data, Header, Message, Outcome, Properties,
};
use fe2o3_amqp::types::primitives::{Binary, SimpleValue, Timestamp, Value as AmqpValue};
use fe2o3_amqp::{Connection, Receiver, Sender, Session};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{watch, Notify};

/// A secret of the configuration: read from the file, never written out
/// (`GET /api/v1/config` shows `<redacted>`) nor logged (`Debug` too).
#[derive(Clone, PartialEq, Deserialize)]
#[serde(transparent)]
pub struct Secret(pub String);

impl Serialize for Secret {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str("<redacted>")
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

/// `[mes.broker]`: an AMQP 1.0 broker, the CFX transport.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Broker {
    /// The target's name in the outbox (`GET /api/v1/outbox` lists it
    /// beside the webhooks'); default `broker`.
    #[serde(default = "default_name")]
    pub name: String,
    /// `amqp://host:port` (default port 5672) or `amqps://host:port` (TLS,
    /// default port 5671). No credentials in it: `user` and `password`.
    pub url: String,
    /// The node messages are published to, e.g. `/exchange/amq.topic`
    /// (RabbitMQ: the subject `{handle}.{MessageName}` is the routing key)
    /// or `/queue/cfx`.
    pub address: String,
    /// The node requests to the station are taken from (e.g.
    /// `/queue/Acme.Line3.Springbench`); none: no requests are taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub request_address: Option<String>,
    /// SASL PLAIN user (none: SASL ANONYMOUS).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub password: Option<Secret>,
    /// PEM file of the certificate authorities an `amqps://` broker's
    /// certificate must chain to (else the system's trust store).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ca_file: Option<String>,
    /// Period of the `Heartbeat` (s): CFX's default is 60, at most 300.
    #[serde(default = "default_heartbeat")]
    pub heartbeat_s: u64,
}

fn default_name() -> String {
    "broker".into()
}

fn default_heartbeat() -> u64 {
    60
}

impl Broker {
    pub fn validate(&self) -> Result<(), String> {
        let u =
            url::Url::parse(&self.url).map_err(|e| format!("mes.broker.url {}: {e}", self.url))?;
        if !matches!(u.scheme(), "amqp" | "amqps") {
            return Err(format!(
                "mes.broker.url must start with amqp:// or amqps://, got {}",
                self.url
            ));
        }
        if !u.username().is_empty() || u.password().is_some() {
            return Err(
                "mes.broker.url holds credentials: give them as mes.broker.user and mes.broker.password".into(),
            );
        }
        if u.host_str().is_none_or(str::is_empty) {
            return Err(format!("mes.broker.url {} names no host", self.url));
        }
        if self.address.is_empty() {
            return Err("mes.broker.address must name a node (e.g. /exchange/amq.topic)".into());
        }
        if self.user.is_some() != self.password.is_some() {
            return Err("mes.broker: give both user and password, or neither".into());
        }
        if self.ca_file.is_some() && u.scheme() != "amqps" {
            return Err("mes.broker.ca_file applies to amqps:// only".into());
        }
        if u.scheme() == "amqps" {
            super::tls_config_from(self.ca_file.as_deref())
                .map_err(|e| format!("mes.broker: {e}"))?;
        }
        if !(1..=300).contains(&self.heartbeat_s) {
            return Err(format!(
                "mes.broker.heartbeat_s must be in [1, 300] s (CFX: at most 5 min), got {}",
                self.heartbeat_s
            ));
        }
        if self.name.is_empty() {
            return Err("mes.broker.name must not be empty".into());
        }
        Ok(())
    }

    /// The broker as a URI for `RequestNetworkUri` (no credentials).
    pub fn network_uri(&self) -> String {
        self.url.clone()
    }
}

/// The namespace of a message (`cfx-topic`): `CFX.Production` for
/// `CFX.Production.WorkStarted`.
pub fn topic_of(name: &str) -> &str {
    name.rsplit_once('.').map(|x| x.0).unwrap_or(name)
}

/// The application property of a message sent again after an attempt
/// without outcome: the number of earlier attempts (decision 0098).
pub const PRIOR_ATTEMPTS: &str = "springbench-prior-attempts";

/// The AMQP message of a CFX envelope, with the SDK's properties.
///
/// `prior_attempts` is the number of earlier sends of this envelope whose
/// outcome the station never learnt (a timeout or a lost connection): the
/// broker may hold such a copy already, so the resend says so, beside the
/// unchanged `UniqueID` (decision 0098): in the application property
/// `springbench-prior-attempts` (absent on a first send), which RabbitMQ
/// passes on, and in the AMQP header's `delivery-count` ("the number of
/// prior unsuccessful delivery attempts", AMQP 1.0 §3.2.1), which RabbitMQ
/// 3.10 replaces by its own count.
pub fn amqp_message(env: &Value, prior_attempts: u32) -> Message<Data> {
    let name = env["MessageName"].as_str().unwrap_or_default();
    let source = env["Source"].as_str().unwrap_or_default();
    let mut props = Properties::builder()
        .message_id(env["UniqueID"].as_str().unwrap_or_default().to_string())
        .subject(format!("{source}.{name}"))
        .reply_to(source.to_string())
        .content_type("application/json; charset=\"utf-8\"");
    if let Some(t) = env["Target"].as_str() {
        props = props.to(t.to_string());
    }
    if let Some(r) = env["RequestID"].as_str() {
        props = props.correlation_id(r.to_string());
    }
    if let Some(t) = env["TimeStamp"]
        .as_str()
        .and_then(|t| chrono::DateTime::parse_from_rfc3339(t).ok())
    {
        props = props.creation_time(Timestamp::from_milliseconds(t.timestamp_millis()));
    }
    let target = match env["Target"].as_str() {
        Some(t) => SimpleValue::String(t.to_string()),
        None => SimpleValue::Null,
    };
    let mut app = ApplicationProperties::builder()
        .insert("cfx-topic", SimpleValue::String(topic_of(name).to_string()))
        .insert("cfx-message", SimpleValue::String(name.to_string()))
        .insert("cfx-handle", SimpleValue::String(source.to_string()))
        .insert("cfx-target", target);
    if prior_attempts > 0 {
        app = app.insert(PRIOR_ATTEMPTS, SimpleValue::Uint(prior_attempts));
    }
    let app = app.build();
    Message::builder()
        .header(Header {
            durable: true,
            delivery_count: prior_attempts,
            ..Default::default()
        })
        .properties(props.build())
        .application_properties(app)
        .data(Binary::from(env.to_string().into_bytes()))
        .build()
}

/// The bytes of a received message's body (data sections, or a string or
/// binary value).
pub fn body_bytes(b: &Body<AmqpValue>) -> Option<Vec<u8>> {
    match b {
        Body::Data(batch) => Some(batch.iter().flat_map(|d| d.0.iter().copied()).collect()),
        Body::Value(v) => match &v.0 {
            AmqpValue::String(s) => Some(s.clone().into_bytes()),
            AmqpValue::Binary(b) => Some(b.to_vec()),
            _ => None,
        },
        _ => None,
    }
}

/// An open link to the broker.
struct Link {
    connection: ConnectionHandle<()>,
    session: SessionHandle<()>,
    sender: Sender,
    requests: Option<Receiver>,
    replies: HashMap<String, Sender>,
}

async fn connect(b: &Broker) -> Result<Link, String> {
    let u = url::Url::parse(&b.url).map_err(|e| e.to_string())?;
    let tls = u.scheme() == "amqps";
    let host = u.host_str().unwrap_or_default().to_string();
    let port = u.port().unwrap_or(if tls { 5671 } else { 5672 });
    let tcp = tokio::time::timeout(
        Duration::from_secs(10),
        tokio::net::TcpStream::connect((host.as_str(), port)),
    )
    .await
    .map_err(|_| format!("no TCP connection to {host}:{port} within 10 s"))?
    .map_err(|e| format!("TCP {host}:{port}: {e}"))?;
    let container = format!("springbench-{}", uuid::Uuid::new_v4());
    let mut builder = Connection::builder()
        .container_id(container)
        .hostname(host.as_str())
        .scheme("amqp");
    builder = match (&b.user, &b.password) {
        (Some(u), Some(p)) => builder.sasl_profile(SaslProfile::Plain {
            username: u.clone(),
            password: p.0.clone(),
        }),
        _ => builder.sasl_profile(SaslProfile::Anonymous),
    };
    let open = async {
        if tls {
            let cfg = super::tls_config_from(b.ca_file.as_deref())?;
            let name = rustls::pki_types::ServerName::try_from(host.clone())
                .map_err(|e| format!("TLS server name {host}: {e}"))?;
            let s = tokio_rustls::TlsConnector::from(Arc::new(cfg))
                .connect(name, tcp)
                .await
                .map_err(|e| format!("TLS with {host}:{port}: {}", super::chain(&e)))?;
            builder
                .open_with_stream(s)
                .await
                .map_err(|e| format!("AMQP open: {e}"))
        } else {
            builder
                .open_with_stream(tcp)
                .await
                .map_err(|e| format!("AMQP open: {e}"))
        }
    };
    let mut connection = tokio::time::timeout(Duration::from_secs(10), open)
        .await
        .map_err(|_| "the broker did not open the connection within 10 s".to_string())??;
    let mut session = Session::begin(&mut connection)
        .await
        .map_err(|e| format!("AMQP session: {e}"))?;
    let sender = Sender::attach(&mut session, "springbench-cfx", b.address.as_str())
        .await
        .map_err(|e| format!("AMQP sender to {}: {e}", b.address))?;
    let requests = match &b.request_address {
        Some(a) => Some(
            Receiver::attach(&mut session, "springbench-cfx-requests", a.as_str())
                .await
                .map_err(|e| format!("AMQP receiver of {a}: {e}"))?,
        ),
        None => None,
    };
    Ok(Link {
        connection,
        session,
        sender,
        requests,
        replies: HashMap::new(),
    })
}

impl Link {
    /// Sends one envelope to `to` (None: the publishing address) as its
    /// `prior_attempts`+1-th try; Ok(false) when the broker refused it (not
    /// accepted).
    async fn send(
        &mut self,
        env: &Value,
        to: Option<&str>,
        timeout: Duration,
        prior_attempts: u32,
    ) -> Result<bool, String> {
        let msg = amqp_message(env, prior_attempts);
        let sender = match to {
            None => &mut self.sender,
            Some(a) => {
                if !self.replies.contains_key(a) {
                    let name = format!("springbench-reply-{}", uuid::Uuid::new_v4());
                    let s = Sender::attach(&mut self.session, name, a)
                        .await
                        .map_err(|e| format!("AMQP sender to {a}: {e}"))?;
                    self.replies.insert(a.to_string(), s);
                }
                self.replies.get_mut(a).expect("inserted")
            }
        };
        match tokio::time::timeout(timeout, sender.send(msg)).await {
            Err(_) => Err(format!(
                "the broker did not settle the message within {:.1} s",
                timeout.as_secs_f64()
            )),
            Ok(Err(e)) => Err(format!("AMQP send: {e}")),
            Ok(Ok(Outcome::Accepted(_))) => Ok(true),
            Ok(Ok(o)) => {
                tracing::warn!("the broker did not accept a CFX message: {o:?}");
                Ok(false)
            }
        }
    }

    async fn close(mut self) {
        for (_, s) in self.replies.drain() {
            let _ = s.close().await;
        }
        if let Some(r) = self.requests.take() {
            let _ = r.close().await;
        }
        let _ = self.sender.close().await;
        let _ = self.session.end().await;
        let _ = self.connection.close().await;
    }
}

/// What the endpoint of each handle says about itself.
fn endpoints(b: &Broker, handles: &[String]) -> Vec<EndpointFacts> {
    handles
        .iter()
        .map(|h| EndpointFacts {
            handle: h.clone(),
            request_uri: b.network_uri(),
            request_address: b.request_address.clone().unwrap_or_default(),
            software_version: crate::VERSION.to_string(),
        })
        .collect()
}

fn new_uid() -> String {
    uuid::Uuid::new_v4().to_string()
}

/// Runs the broker target until `shutdown`: connects (again, with backoff),
/// announces, delivers, beats, answers.
pub async fn run(
    store: Store,
    cfg: Arc<MesConfig>,
    handles: Vec<String>,
    wake: Arc<Notify>,
    mut shutdown: watch::Receiver<bool>,
) {
    let Some(b) = cfg.broker.clone() else { return };
    let eps = endpoints(&b, &handles);
    let mut failures: i64 = 0;
    let mut last_error = String::new();
    loop {
        if *shutdown.borrow() {
            return;
        }
        let mut link = match connect(&b).await {
            Ok(l) => l,
            Err(e) => {
                if e != last_error {
                    tracing::warn!(broker = %b.url, "MES broker unreachable, retrying with backoff: {e}");
                    last_error = e;
                }
                let wait = backoff_s(&cfg, failures);
                failures += 1;
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs_f64(wait)) => {}
                    _ = shutdown.changed() => {}
                }
                continue;
            }
        };
        tracing::info!(broker = %b.url, address = %b.address, "MES broker connected");
        failures = 0;
        last_error.clear();
        let r = serve(&store, &cfg, &b, &eps, &mut link, &wake, &mut shutdown).await;
        match r {
            Ok(()) => {
                let t = crate::store::now();
                for e in &eps {
                    let env = cfx::endpoint_shutting_down(e, &new_uid(), &t).2;
                    let _ = link.send(&env, None, Duration::from_secs(2), 0).await;
                }
                link.close().await;
                return;
            }
            Err(e) => {
                tracing::warn!(broker = %b.url, "MES broker connection lost: {e}");
                // the connection is broken: closing it would wait for the peer
                drop(link);
                let wait = backoff_s(&cfg, 0);
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs_f64(wait)) => {}
                    _ = shutdown.changed() => {}
                }
            }
        }
    }
}

/// One connection's life: Ok when the daemon stops, Err when the link broke.
async fn serve(
    store: &Store,
    cfg: &MesConfig,
    b: &Broker,
    eps: &[EndpointFacts],
    link: &mut Link,
    wake: &Notify,
    shutdown: &mut watch::Receiver<bool>,
) -> Result<(), String> {
    let timeout = Duration::from_secs_f64(cfg.timeout_s);
    let t = crate::store::now();
    for e in eps {
        let env = cfx::endpoint_connected(e, &new_uid(), &t).2;
        link.send(&env, None, timeout, 0).await?;
    }
    let period = Duration::from_secs(b.heartbeat_s);
    let mut beat = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
    beat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        if *shutdown.borrow() {
            return Ok(());
        }
        let due = store
            .due_deliveries(Some(&b.name), &crate::store::now(), 100)
            .await
            .unwrap_or_else(|e| {
                tracing::warn!("reading the MES outbox failed: {e}");
                vec![]
            });
        for d in &due {
            if *shutdown.borrow() {
                return Ok(());
            }
            // every earlier attempt of an outbox item ended without an
            // outcome the station saw (a refusal is final or backed off
            // the same way): each may have reached the queue
            let prior = u32::try_from(d.attempts).unwrap_or(u32::MAX);
            let r = link.send(&d.body, None, timeout, prior).await;
            let stored = match &r {
                Ok(true) => store.mark_delivered(d.id).await,
                Ok(false) | Err(_) => {
                    let why = match &r {
                        Err(e) => e.clone(),
                        _ => "the broker did not accept the message".to_string(),
                    };
                    let give_up = cfg.max_attempts > 0 && d.attempts + 1 >= cfg.max_attempts as i64;
                    store
                        .mark_attempt_failed(
                            d.id,
                            &why,
                            &rfc3339_in(backoff_s(cfg, d.attempts)),
                            give_up,
                        )
                        .await
                }
            };
            if let Err(e) = stored {
                tracing::warn!("recording an MES delivery failed: {e}");
            }
            r?;
        }
        if !due.is_empty() {
            // a backlog (after an outage) goes out in batches; the heartbeat
            // keeps its period between them
            tokio::select! {
                biased;
                _ = beat.tick() => heartbeats(link, eps, b.heartbeat_s, timeout).await?,
                _ = std::future::ready(()) => {}
            }
            continue;
        }
        let wait = match store.next_delivery_due(Some(&b.name)).await {
            Ok(Some(t)) => chrono::DateTime::parse_from_rfc3339(&t)
                .ok()
                .map(|t| (t.with_timezone(&chrono::Utc) - chrono::Utc::now()).num_milliseconds())
                .unwrap_or(1000)
                .clamp(10, 1000),
            _ => 1000,
        };
        let request = async {
            match link.requests.as_mut() {
                Some(r) => Some(r.recv::<Body<AmqpValue>>().await),
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(wait as u64)) => {}
            _ = wake.notified() => {}
            _ = shutdown.changed() => {}
            _ = beat.tick() => heartbeats(link, eps, b.heartbeat_s, timeout).await?,
            got = request => match got {
                Some(Ok(delivery)) => {
                    let reply_to = delivery
                        .message()
                        .properties
                        .as_ref()
                        .and_then(|p| p.reply_to.clone());
                    let req: Option<Value> = body_bytes(delivery.body())
                        .and_then(|b| serde_json::from_slice(&b).ok());
                    if let Some(r) = link.requests.as_mut() {
                        r.accept(&delivery).await.map_err(|e| format!("AMQP accept: {e}"))?;
                    }
                    match req {
                        Some(req) => answer(link, eps, &req, reply_to.as_deref(), timeout).await?,
                        None => tracing::warn!("an MES request that is not a JSON CFX envelope was dropped"),
                    }
                }
                Some(Err(e)) => return Err(format!("AMQP receive: {e}")),
                None => {}
            }
        }
    }
}

/// A `Heartbeat` of every endpoint.
async fn heartbeats(
    link: &mut Link,
    eps: &[EndpointFacts],
    period_s: u64,
    timeout: Duration,
) -> Result<(), String> {
    let t = crate::store::now();
    for e in eps {
        let env = cfx::heartbeat(e, &new_uid(), &t, period_s).2;
        link.send(&env, None, timeout, 0).await?;
    }
    Ok(())
}

/// Answers request `req` as the endpoint it targets (`WhoIsThereRequest`:
/// every endpoint answers).
async fn answer(
    link: &mut Link,
    eps: &[EndpointFacts],
    req: &Value,
    reply_to: Option<&str>,
    timeout: Duration,
) -> Result<(), String> {
    let name = req["MessageName"].as_str().unwrap_or_default();
    let target = req["Target"].as_str();
    let who: Vec<&EndpointFacts> = if name == cfx::WHO_IS_THERE_REQUEST {
        eps.iter().collect()
    } else {
        match eps.iter().find(|e| Some(e.handle.as_str()) == target) {
            Some(e) => vec![e],
            None => eps.iter().take(1).collect(),
        }
    };
    let t = crate::store::now();
    for e in who {
        let env = cfx::answer(e, req, &new_uid(), &t).2;
        tracing::info!(request = %name, request_id = ?req["RequestID"].as_str(), answer = %env["MessageName"], "MES request answered");
        link.send(&env, reply_to, timeout, 0).await?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_password_is_never_written_out() {
        let b: Broker = toml::from_str(
            "url = \"amqps://mes.example:5671\"\naddress = \"/exchange/amq.topic\"\nuser = \"station\"\npassword = \"hunter2-hunter2\"\n",
        )
        .unwrap();
        assert_eq!(b.password.as_ref().unwrap().0, "hunter2-hunter2");
        let shown = serde_json::to_string(&b).unwrap();
        assert!(
            !shown.contains("hunter2") && shown.contains("<redacted>"),
            "{shown}"
        );
        assert!(!format!("{b:?}").contains("hunter2"));
        assert_eq!(b.heartbeat_s, 60);
        assert_eq!(b.name, "broker");
    }

    #[test]
    fn the_shipped_example_of_a_broker_is_valid() {
        // deploy/springbench.toml's commented [mes.broker], uncommented
        // (without its ca_file, a path of the factory's)
        let text = include_str!("../../deploy/springbench.toml");
        let from = text.find("# [mes]").expect("the example's [mes]");
        let example: String = text[from..]
            .lines()
            .map(|l| l.trim_start_matches("# "))
            .filter(|l| !l.starts_with("ca_file"))
            .collect::<Vec<_>>()
            .join("\n");
        let cfg = crate::config::Config::parse(&format!("{}\n{example}", &text[..from]))
            .expect("the example is valid");
        let b = cfg.mes.broker.as_ref().expect("a broker");
        assert_eq!(b.url, "amqps://mes-broker.acme.example:5671");
        assert_eq!(b.address, "/exchange/amq.topic");
        assert_eq!(b.heartbeat_s, 60);
        assert_eq!(cfg.mes.handle, "Acme.Line3.Springbench");
        assert_eq!(cfg.mes.targets(), ["broker"]);
    }

    #[test]
    fn broker_configuration_is_checked() {
        let ok = Broker {
            name: "broker".into(),
            url: "amqp://127.0.0.1:5672".into(),
            address: "/queue/cfx".into(),
            request_address: None,
            user: Some("u".into()),
            password: Some(Secret("p".into())),
            ca_file: None,
            heartbeat_s: 60,
        };
        assert!(ok.validate().is_ok());
        let bad = |f: &dyn Fn(&mut Broker), want: &str| {
            let mut b = ok.clone();
            f(&mut b);
            let e = b.validate().unwrap_err();
            assert!(e.contains(want), "{e}");
        };
        bad(&|b| b.url = "http://x".into(), "amqp://");
        bad(&|b| b.url = "amqp://u:p@x".into(), "credentials");
        bad(&|b| b.password = None, "both");
        bad(&|b| b.heartbeat_s = 301, "heartbeat_s");
        bad(&|b| b.ca_file = Some("/x.pem".into()), "amqps");
        bad(&|b| b.address.clear(), "address");
    }

    #[test]
    fn messages_carry_the_sdks_properties() {
        let env = serde_json::json!({"MessageName": "CFX.Production.WorkStarted", "UniqueID": "u-1",
            "Source": "Acme.Line3.Bench1", "Target": null, "RequestID": null,
            "TimeStamp": "2026-11-28T09:00:00.000Z", "MessageBody": {}});
        let m = amqp_message(&env, 0);
        let p = m.properties.unwrap();
        assert_eq!(
            p.subject.as_deref(),
            Some("Acme.Line3.Bench1.CFX.Production.WorkStarted")
        );
        assert_eq!(
            p.content_type.unwrap().0,
            "application/json; charset=\"utf-8\""
        );
        let a = m.application_properties.unwrap();
        assert_eq!(
            a.get("cfx-topic"),
            Some(&SimpleValue::String("CFX.Production".into()))
        );
        assert_eq!(a.get("cfx-target"), Some(&SimpleValue::Null));
        let h = m.header.unwrap();
        assert!(h.durable);
        assert_eq!(h.delivery_count, 0, "a first send");
        assert_eq!(a.get(PRIOR_ATTEMPTS), None, "a first send is the SDK's");
        let again = amqp_message(&env, 2);
        assert_eq!(again.header.unwrap().delivery_count, 2);
        assert_eq!(
            again.application_properties.unwrap().get(PRIOR_ATTEMPTS),
            Some(&SimpleValue::Uint(2))
        );
        assert_eq!(topic_of("CFX.Heartbeat"), "CFX");
    }
}
