//! MES delivery: the outbox worker posts stored messages to the configured
//! webhooks, signed with HMAC-SHA256, with exponential backoff, in order per
//! (webhook, part), at least once. Only this worker talks to the network;
//! the messages themselves ([`cfx`]) are written by the runner in the
//! transaction of the result they announce.

pub use crate::qc::cfx;

pub mod amqp;

use crate::store::qc::DeliveryRow;
use crate::store::Store;
use hmac::{Hmac, Mac};
use serde::{Deserialize, Serialize};
use sha2::Sha256;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{watch, Notify};
use tokio::task::JoinHandle;

/// Header with the signature: `sha256=<hex HMAC-SHA256 of the body with the webhook's secret>`.
pub const SIGNATURE_HEADER: &str = "x-springbench-signature";
/// Header with the message's UniqueID (also in the body).
pub const UNIQUE_ID_HEADER: &str = "x-springbench-unique-id";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Webhook {
    /// Label (outbox listings, logs).
    pub name: String,
    /// `http://host:port/path` or `https://host:port/path` (TLS 1.2/1.3
    /// through rustls; the receiver's certificate is checked against
    /// `ca_file`, or else the system's trust store). Credentials in the URL
    /// (`https://user:password@host/...`) are sent as HTTP Basic
    /// authentication.
    pub url: String,
    /// HMAC key (at least 16 characters).
    pub secret: String,
    /// PEM file of the certificate authorities an `https://` receiver's
    /// certificate must chain to (instead of the system's trust store): a
    /// factory's own CA, or a receiver's self-signed certificate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ca_file: Option<String>,
}

/// `[mes]` in the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MesConfig {
    /// The station's CFX handle (a dotted, globally unique name such as
    /// `Acme.Line3.Springbench`; `source` before issue 34). Each bench's
    /// handle, the `Source` of its messages, is this plus `.` and the bench
    /// id, unless `bench_handles` names it.
    #[serde(alias = "source")]
    pub handle: String,
    /// A bench's own CFX handle (bench id -> handle).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub bench_handles: BTreeMap<String, String>,
    pub webhooks: Vec<Webhook>,
    /// An AMQP 1.0 broker (CFX's transport): a target of the outbox beside
    /// the webhooks, with the same bodies (decision 0097).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub broker: Option<amqp::Broker>,
    /// First retry after this (s); doubles per failed attempt up to `max_backoff_s`.
    pub initial_backoff_s: f64,
    pub max_backoff_s: f64,
    /// Attempts before a delivery is marked `failed` (0: never give up).
    pub max_attempts: u32,
    /// Per-request timeout (s).
    pub timeout_s: f64,
}

impl Default for MesConfig {
    fn default() -> Self {
        MesConfig {
            handle: "Springbench".into(),
            bench_handles: BTreeMap::new(),
            webhooks: vec![],
            broker: None,
            initial_backoff_s: 1.0,
            max_backoff_s: 300.0,
            max_attempts: 0,
            timeout_s: 10.0,
        }
    }
}

/// Whether `h` is a CFX handle: dotted (two names at least), each name of
/// letters, digits, `_` and `-`.
pub fn check_handle(h: &str) -> Result<(), String> {
    let names: Vec<&str> = h.split('.').collect();
    if names.len() < 2
        || names.iter().any(|n| {
            n.is_empty()
                || !n
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        })
    {
        return Err(format!(
            "'{h}' is not a CFX handle: dotted names of letters, digits, '_' and '-', such as Acme.Line3.Springbench"
        ));
    }
    Ok(())
}

impl MesConfig {
    /// The outbox's targets: every webhook's name and the broker's.
    pub fn targets(&self) -> Vec<String> {
        self.webhooks
            .iter()
            .map(|w| w.name.clone())
            .chain(self.broker.iter().map(|b| b.name.clone()))
            .collect()
    }

    /// The CFX handle of bench `bench_id` (the `Source` of its messages).
    pub fn handle_of(&self, bench_id: &str) -> String {
        match self.bench_handles.get(bench_id) {
            Some(h) => h.clone(),
            None => format!("{}.{bench_id}", self.handle),
        }
    }

    /// Checks the handles of `benches` (ids): each a CFX handle, no two
    /// alike, and `bench_handles` naming configured benches only.
    pub fn validate_handles(&self, benches: &[&str]) -> Result<(), String> {
        if self.handle.is_empty() || self.handle.split('.').any(|n| n.is_empty()) {
            return Err(format!(
                "mes.handle '{}' is not a dotted CFX handle",
                self.handle
            ));
        }
        for b in self.bench_handles.keys() {
            if !benches.contains(&b.as_str()) {
                return Err(format!(
                    "mes.bench_handles names bench '{b}', which is not configured"
                ));
            }
        }
        let mut seen = std::collections::HashMap::new();
        for b in benches {
            let h = self.handle_of(b);
            check_handle(&h).map_err(|e| format!("mes: the handle of bench '{b}': {e}"))?;
            if let Some(other) = seen.insert(h.clone(), *b) {
                return Err(format!(
                    "mes: benches '{other}' and '{b}' have the same CFX handle '{h}': a handle is unique"
                ));
            }
        }
        Ok(())
    }

    pub fn validate(&self) -> Result<(), String> {
        let mut names = std::collections::HashSet::new();
        for w in &self.webhooks {
            if w.name.is_empty() || !names.insert(w.name.as_str()) {
                return Err(format!(
                    "mes webhook '{}': names must be unique and non-empty",
                    w.name
                ));
            }
            let https = w.url.starts_with("https://");
            if !https && !w.url.starts_with("http://") {
                return Err(format!(
                    "mes webhook '{}': url must start with http:// or https://, got {}",
                    w.name, w.url
                ));
            }
            if let Err(e) = w.url.parse::<hyper::Uri>() {
                return Err(format!(
                    "mes webhook '{}': url {} is not a valid URL: {e}",
                    w.name, w.url
                ));
            }
            if w.ca_file.is_some() && !https {
                return Err(format!(
                    "mes webhook '{}': ca_file applies to https:// receivers only",
                    w.name
                ));
            }
            if https {
                tls_config(w).map_err(|e| format!("mes webhook '{}': {e}", w.name))?;
            }
            if w.secret.len() < 16 {
                return Err(format!(
                    "mes webhook '{}': secret must have at least 16 characters",
                    w.name
                ));
            }
        }
        if let Some(b) = &self.broker {
            b.validate()?;
            if names.contains(b.name.as_str()) {
                return Err(format!(
                    "mes.broker.name '{}' is also a webhook's name: the outbox tells its targets apart by name",
                    b.name
                ));
            }
        }
        for (n, v) in [
            ("initial_backoff_s", self.initial_backoff_s),
            ("max_backoff_s", self.max_backoff_s),
            ("timeout_s", self.timeout_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 86400.0) {
                return Err(format!("mes.{n} must be in (0, 86400] s, got {v}"));
            }
        }
        if self.max_backoff_s < self.initial_backoff_s {
            return Err("mes.max_backoff_s must be >= mes.initial_backoff_s".into());
        }
        Ok(())
    }
}

/// `sha256=<hex>` of the body under `secret`.
pub fn signature(secret: &str, body: &[u8]) -> String {
    let mut mac =
        Hmac::<Sha256>::new_from_slice(secret.as_bytes()).expect("HMAC takes any key length");
    mac.update(body);
    let tag = mac.finalize().into_bytes();
    format!(
        "sha256={}",
        tag.iter().map(|b| format!("{b:02x}")).collect::<String>()
    )
}

/// Delay before the next attempt after `attempts` failed ones (s).
pub fn backoff_s(cfg: &MesConfig, attempts: i64) -> f64 {
    let exp = attempts.clamp(0, 40) as i32;
    (cfg.initial_backoff_s * 2f64.powi(exp)).min(cfg.max_backoff_s)
}

pub(crate) fn rfc3339_in(s: f64) -> String {
    let t = chrono::Utc::now() + chrono::Duration::milliseconds((s * 1000.0) as i64);
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// Starts the delivery workers: one per webhook, so a slow or hanging
/// receiver delays only its own messages; `wake` makes every worker look at
/// the outbox at once. The handle ends when every worker has stopped.
/// `handles`: the benches' CFX handles (the broker's endpoints).
pub fn start(
    store: Store,
    cfg: MesConfig,
    handles: Vec<String>,
    wake: Arc<Notify>,
    shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let cfg = Arc::new(cfg);
        let mut wakes = vec![];
        let mut workers = vec![];
        if cfg.broker.is_some() {
            let w = Arc::new(Notify::new());
            wakes.push(w.clone());
            workers.push(tokio::spawn(amqp::run(
                store.clone(),
                cfg.clone(),
                handles,
                w,
                shutdown.clone(),
            )));
        }
        for hook in cfg
            .webhooks
            .iter()
            .map(|w| Some(w.name.clone()))
            .chain([None])
        {
            let w = Arc::new(Notify::new());
            wakes.push(w.clone());
            let sender = match &hook {
                Some(name) => cfg
                    .webhooks
                    .iter()
                    .find(|w| &w.name == name)
                    .map(sender)
                    .unwrap_or_else(|| Err("not configured".into())),
                None => Err("not configured".into()),
            };
            if let (Some(name), Err(e)) = (&hook, &sender) {
                tracing::error!(webhook = %name, "MES webhook cannot send: {e}");
            }
            workers.push(tokio::spawn(worker(
                store.clone(),
                cfg.clone(),
                sender,
                hook,
                w,
                shutdown.clone(),
            )));
        }
        let mut stop = shutdown.clone();
        let fan_out = tokio::spawn(async move {
            loop {
                tokio::select! {
                    _ = wake.notified() => wakes.iter().for_each(|w| w.notify_one()),
                    _ = stop.changed() => break,
                }
            }
        });
        for w in workers {
            let _ = w.await;
        }
        fan_out.abort();
    })
}

/// Delivers the outbox of one webhook (`hook`), in order per part; `None`:
/// the deliveries of webhooks no longer configured (kept, retried later).
async fn worker(
    store: Store,
    cfg: Arc<MesConfig>,
    sender: Result<Sender, String>,
    hook: Option<String>,
    wake: Arc<Notify>,
    mut shutdown: watch::Receiver<bool>,
) {
    let configured: Vec<String> = cfg.targets();
    loop {
        if *shutdown.borrow() {
            break;
        }
        let due = match store
            .due_deliveries(hook.as_deref(), &crate::store::now(), 100)
            .await
        {
            Ok(d) => d,
            Err(e) => {
                tracing::warn!("reading the MES outbox failed: {e}");
                vec![]
            }
        };
        let due: Vec<_> = match &hook {
            Some(_) => due,
            None => due
                .into_iter()
                .filter(|d| !configured.contains(&d.webhook))
                .collect(),
        };
        for d in &due {
            if *shutdown.borrow() {
                break;
            }
            deliver(&store, &cfg, &sender, d).await;
        }
        if due.is_empty() {
            let wait = match (&hook, store.next_delivery_due(hook.as_deref()).await) {
                (Some(_), Ok(Some(t))) => chrono::DateTime::parse_from_rfc3339(&t)
                    .ok()
                    .map(|t| {
                        (t.with_timezone(&chrono::Utc) - chrono::Utc::now()).num_milliseconds()
                    })
                    .unwrap_or(1000)
                    .clamp(10, 1000),
                (Some(_), _) => 1000,
                // unconfigured webhooks: looked at now and then
                (None, _) => 10_000,
            };
            tokio::select! {
                _ = tokio::time::sleep(Duration::from_millis(wait as u64)) => {}
                _ = wake.notified() => {}
                _ = shutdown.changed() => {}
            }
        }
    }
}

/// A webhook's HTTP client: hyper's, over TCP or TLS (rustls with the ring
/// provider), HTTP/1.1, never following a redirect.
pub type Sender = hyper_util::client::legacy::Client<
    hyper_rustls::HttpsConnector<hyper_util::client::legacy::connect::HttpConnector>,
    http_body_util::Full<bytes::Bytes>,
>;

/// The TLS configuration of an `https://` webhook: TLS 1.2 and 1.3 by
/// rustls's safe defaults, its certificate checked against the webhook's
/// `ca_file`, or the system's trust store.
pub fn tls_config(w: &Webhook) -> Result<rustls::ClientConfig, String> {
    tls_config_from(w.ca_file.as_deref())
}

/// TLS 1.2 and 1.3 by rustls's safe defaults, the peer's certificate
/// checked against `ca_file`, or the system's trust store.
pub fn tls_config_from(ca_file: Option<&str>) -> Result<rustls::ClientConfig, String> {
    use rustls::pki_types::{pem::PemObject, CertificateDer};
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?;
    let mut roots = rustls::RootCertStore::empty();
    match ca_file {
        Some(path) => {
            let certs =
                CertificateDer::pem_file_iter(path).map_err(|e| format!("ca_file {path}: {e}"))?;
            for c in certs {
                let c = c.map_err(|e| format!("ca_file {path}: {e}"))?;
                roots
                    .add(c)
                    .map_err(|e| format!("ca_file {path}: certificate refused: {e}"))?;
            }
            if roots.is_empty() {
                return Err(format!("ca_file {path} holds no PEM certificate"));
            }
        }
        None => {
            let found = rustls_native_certs::load_native_certs();
            for c in found.certs {
                let _ = roots.add(c);
            }
            if roots.is_empty() {
                return Err(format!(
                    "no certificate authority in the system's trust store ({}): set ca_file",
                    found
                        .errors
                        .first()
                        .map(|e| e.to_string())
                        .unwrap_or_else(|| "empty".into())
                ));
            }
        }
    }
    Ok(builder.with_root_certificates(roots).with_no_client_auth())
}

/// The client of webhook `w` (its own: its own TLS trust and connections).
pub fn sender(w: &Webhook) -> Result<Sender, String> {
    let tls = if w.url.starts_with("https://") {
        tls_config(w)?
    } else {
        // never used for a TLS handshake: the scheme is http
        rustls::ClientConfig::builder_with_provider(Arc::new(
            rustls::crypto::ring::default_provider(),
        ))
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?
        .with_root_certificates(rustls::RootCertStore::empty())
        .with_no_client_auth()
    };
    let https = hyper_rustls::HttpsConnectorBuilder::new()
        .with_tls_config(tls)
        .https_or_http()
        .enable_http1()
        .build();
    Ok(
        hyper_util::client::legacy::Client::builder(hyper_util::rt::TokioExecutor::new())
            .build(https),
    )
}

/// An error with its causes, one line (a TLS refusal names its reason).
pub(crate) fn chain(e: &dyn std::error::Error) -> String {
    let mut out = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !out.contains(&t) {
            out.push_str(": ");
            out.push_str(&t);
        }
        cur = c.source();
    }
    out
}

/// Posts `body` to `url` with `headers`; the status and the Location, or why not.
async fn post(
    sender: &Sender,
    url: &str,
    headers: &[(&str, String)],
    body: Vec<u8>,
    timeout: Duration,
) -> Result<(u16, Option<String>), String> {
    let mut u = url::Url::parse(url).map_err(|e| format!("url: {e}"))?;
    let mut req = hyper::Request::post("/");
    if !u.username().is_empty() || u.password().is_some() {
        use base64::Engine;
        let user = percent_decoded(u.username());
        let pass = percent_decoded(u.password().unwrap_or(""));
        let token = base64::engine::general_purpose::STANDARD.encode(format!("{user}:{pass}"));
        req = req.header(hyper::header::AUTHORIZATION, format!("Basic {token}"));
        let _ = u.set_username("");
        let _ = u.set_password(None);
    }
    req = req.uri(u.as_str());
    for (k, v) in headers {
        req = req.header(*k, v.as_str());
    }
    let req = req
        .body(http_body_util::Full::new(bytes::Bytes::from(body)))
        .map_err(|e| format!("request: {e}"))?;
    match tokio::time::timeout(timeout, sender.request(req)).await {
        Err(_) => Err(format!(
            "no answer within {:.1} s (mes.timeout_s)",
            timeout.as_secs_f64()
        )),
        Ok(Err(e)) => Err(chain(&e)),
        Ok(Ok(r)) => Ok((
            r.status().as_u16(),
            r.headers()
                .get(hyper::header::LOCATION)
                .and_then(|v| v.to_str().ok())
                .map(str::to_string),
        )),
    }
}

fn percent_decoded(s: &str) -> String {
    // form decoding without its `+` and `&` meanings is percent decoding
    let s = s.replace('+', "%2B").replace('&', "%26");
    form_urlencoded::parse(format!("a={s}").as_bytes())
        .next()
        .map(|(_, v)| v.into_owned())
        .unwrap_or_default()
}

async fn deliver(store: &Store, cfg: &MesConfig, sender: &Result<Sender, String>, d: &DeliveryRow) {
    let hook = cfg.webhooks.iter().find(|w| w.name == d.webhook);
    let (Some(hook), Ok(sender)) = (hook, sender) else {
        let why = match (hook, sender) {
            (Some(_), Err(e)) => format!("webhook '{}' cannot send: {e}", d.webhook),
            _ => format!("webhook '{}' is not configured any more", d.webhook),
        };
        // Keep the delivery, retry later.
        let _ = store
            .mark_attempt_failed(d.id, &why, &rfc3339_in(cfg.max_backoff_s), false)
            .await;
        return;
    };
    let body = d.body.to_string().into_bytes();
    let headers = [
        ("content-type", "application/json".to_string()),
        (SIGNATURE_HEADER, signature(&hook.secret, &body)),
        (UNIQUE_ID_HEADER, d.unique_id.clone()),
    ];
    let res = post(
        sender,
        &hook.url,
        &headers,
        body,
        Duration::from_secs_f64(cfg.timeout_s),
    )
    .await;
    let err = match res {
        Ok((s, _)) if (200..300).contains(&s) => None,
        // A redirect is not a delivery: the body would be lost (a 303
        // turns the POST into a GET). 3xx is a failed attempt.
        Ok((s, loc)) if (300..400).contains(&s) => Some(format!(
            "HTTP {s} redirect to {} not followed: the receiver must accept the message itself (2xx)",
            loc.as_deref().unwrap_or("(no Location)")
        )),
        Ok((s, _)) => Some(format!("HTTP {s}")),
        Err(e) => Some(e),
    };
    let r = match err {
        None => store.mark_delivered(d.id).await,
        Some(e) => {
            let give_up = cfg.max_attempts > 0 && d.attempts + 1 >= cfg.max_attempts as i64;
            tracing::warn!(webhook = %hook.name, message = %d.unique_id, attempt = d.attempts + 1, "MES delivery failed: {e}");
            store
                .mark_attempt_failed(d.id, &e, &rfc3339_in(backoff_s(cfg, d.attempts)), give_up)
                .await
        }
    };
    if let Err(e) = r {
        tracing::warn!("recording an MES delivery failed: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signature_is_rfc4231_hmac_sha256() {
        // RFC 4231 test case 2.
        assert_eq!(
            signature("Jefe", b"what do ya want for nothing?"),
            "sha256=5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
    }

    #[test]
    fn backoff_doubles_up_to_the_cap() {
        let c = MesConfig {
            initial_backoff_s: 0.5,
            max_backoff_s: 3.0,
            ..Default::default()
        };
        let v: Vec<f64> = (0..5).map(|a| backoff_s(&c, a)).collect();
        assert_eq!(v, [0.5, 1.0, 2.0, 3.0, 3.0]);
    }

    #[test]
    fn webhook_configuration_is_checked() {
        let mut c = MesConfig::default();
        c.webhooks.push(Webhook {
            name: "mes".into(),
            url: "ftp://x".into(),
            secret: "0123456789abcdef".into(),
            ca_file: None,
        });
        assert!(c.validate().unwrap_err().contains("http://"));
        c.webhooks[0].url = "https://127.0.0.1:9/cfx".into();
        c.webhooks[0].ca_file = Some("/nonexistent/ca.pem".into());
        assert!(c.validate().unwrap_err().contains("/nonexistent/ca.pem"));
        c.webhooks[0].ca_file = None;
        c.webhooks[0].url = "http://127.0.0.1:9/cfx".into();
        assert!(c.validate().is_ok());
        c.webhooks[0].secret = "short".into();
        assert!(c.validate().unwrap_err().contains("16"));
    }
}
