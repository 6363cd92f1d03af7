//! MES delivery: the outbox worker posts stored messages to the configured
//! webhooks, signed with HMAC-SHA256, with exponential backoff, in order per
//! (webhook, part), at least once. Only this worker talks to the network;
//! the messages themselves ([`cfx`]) are written by the runner in the
//! transaction of the result they announce.

pub use crate::qc::cfx;

use crate::store::qc::DeliveryRow;
use crate::store::Store;
use hmac::{Hmac, Mac};
use serde::{Deserialize, Serialize};
use sha2::Sha256;
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
    /// `http://host:port/path` (plain HTTP: no TLS stack is built in; put a
    /// TLS-terminating proxy in front for remote receivers).
    pub url: String,
    /// HMAC key (at least 16 characters).
    pub secret: String,
}

/// `[mes]` in the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MesConfig {
    /// `Source` of the CFX envelopes (the station's name).
    pub source: String,
    pub webhooks: Vec<Webhook>,
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
            source: "springbench".into(),
            webhooks: vec![],
            initial_backoff_s: 1.0,
            max_backoff_s: 300.0,
            max_attempts: 0,
            timeout_s: 10.0,
        }
    }
}

impl MesConfig {
    pub fn validate(&self) -> Result<(), String> {
        let mut names = std::collections::HashSet::new();
        for w in &self.webhooks {
            if w.name.is_empty() || !names.insert(w.name.as_str()) {
                return Err(format!(
                    "mes webhook '{}': names must be unique and non-empty",
                    w.name
                ));
            }
            if !w.url.starts_with("http://") {
                return Err(format!(
                    "mes webhook '{}': url must start with http:// (no TLS built in), got {}",
                    w.name, w.url
                ));
            }
            if w.secret.len() < 16 {
                return Err(format!(
                    "mes webhook '{}': secret must have at least 16 characters",
                    w.name
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

fn rfc3339_in(s: f64) -> String {
    let t = chrono::Utc::now() + chrono::Duration::milliseconds((s * 1000.0) as i64);
    t.to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// Starts the delivery workers: one per webhook, so a slow or hanging
/// receiver delays only its own messages; `wake` makes every worker look at
/// the outbox at once. The handle ends when every worker has stopped.
pub fn start(
    store: Store,
    cfg: MesConfig,
    wake: Arc<Notify>,
    shutdown: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let client = match reqwest::Client::builder()
            .timeout(Duration::from_secs_f64(cfg.timeout_s))
            // A redirect is not a delivery: the body would be lost (a 303
            // turns the POST into a GET). 3xx is a failed attempt.
            .redirect(reqwest::redirect::Policy::none())
            .build()
        {
            Ok(c) => c,
            Err(e) => {
                tracing::error!("MES delivery worker not started: {e}");
                return;
            }
        };
        let cfg = Arc::new(cfg);
        let mut wakes = vec![];
        let mut workers = vec![];
        for hook in cfg
            .webhooks
            .iter()
            .map(|w| Some(w.name.clone()))
            .chain([None])
        {
            let w = Arc::new(Notify::new());
            wakes.push(w.clone());
            workers.push(tokio::spawn(worker(
                store.clone(),
                cfg.clone(),
                client.clone(),
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
    client: reqwest::Client,
    hook: Option<String>,
    wake: Arc<Notify>,
    mut shutdown: watch::Receiver<bool>,
) {
    let configured: Vec<String> = cfg.webhooks.iter().map(|w| w.name.clone()).collect();
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
            deliver(&store, &cfg, &client, d).await;
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

async fn deliver(store: &Store, cfg: &MesConfig, client: &reqwest::Client, d: &DeliveryRow) {
    let Some(hook) = cfg.webhooks.iter().find(|w| w.name == d.webhook) else {
        // A webhook removed from the configuration: keep the delivery, retry later.
        let _ = store
            .mark_attempt_failed(
                d.id,
                &format!("webhook '{}' is not configured any more", d.webhook),
                &rfc3339_in(cfg.max_backoff_s),
                false,
            )
            .await;
        return;
    };
    let body = d.body.to_string().into_bytes();
    let res = client
        .post(&hook.url)
        .header("content-type", "application/json")
        .header(SIGNATURE_HEADER, signature(&hook.secret, &body))
        .header(UNIQUE_ID_HEADER, d.unique_id.clone())
        .body(body)
        .send()
        .await;
    let err = match res {
        Ok(r) if r.status().is_success() => None,
        Ok(r) if r.status().is_redirection() => Some(format!(
            "HTTP {} redirect to {} not followed: the receiver must accept the message itself (2xx)",
            r.status().as_u16(),
            r.headers()
                .get(reqwest::header::LOCATION)
                .and_then(|v| v.to_str().ok())
                .unwrap_or("(no Location)")
        )),
        Ok(r) => Some(format!("HTTP {}", r.status().as_u16())),
        Err(e) => Some(e.to_string()),
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
            url: "https://x".into(),
            secret: "0123456789abcdef".into(),
        });
        assert!(c.validate().unwrap_err().contains("http://"));
        c.webhooks[0].url = "http://127.0.0.1:9/cfx".into();
        assert!(c.validate().is_ok());
        c.webhooks[0].secret = "short".into();
        assert!(c.validate().unwrap_err().contains("16"));
    }
}
