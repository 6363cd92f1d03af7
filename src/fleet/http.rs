//! The station's way to the center (decision 0105): HTTP(S) posts to the
//! fleet role's ingest routes (`src/api/fleet/ingest.rs`) with the
//! station's own token. The station holds no credential of the center's
//! database; the center runs the ingest in its own transaction.
//!
//! Answers as the worker needs them: 200 is the center's answer; 422
//! `item-refused` and 413 (a batch too large) are `StoreError::Invalid`
//! (the worker sends the batch's items one by one and parks the refused
//! one); anything else (no answer, 5xx, a refused token) is an outage the
//! worker retries with backoff, its reason on the link.

use crate::config::FleetConfig;
use crate::store::fleet::{
    CenterIngest, IngestReport, ReplicationItem, StationHello, StationStatus,
};
use crate::store::results::RecipeRow;
use crate::store::{StoreError, StoreResult};
use http_body_util::BodyExt;
use std::sync::Arc;
use std::time::Duration;

/// The `items` request's body (`POST /api/v1/fleet/ingest/items`), as the
/// station sends it and the center reads it.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct ItemsRequest {
    pub station_id: String,
    pub items: Vec<crate::store::fleet::ReplicationItem>,
}

/// A station's publication of its local recipe (`POST
/// /api/v1/fleet/ingest/recipe-proposals`): a proposal at the center, which
/// an approver there makes the center's version (decision 0106).
#[derive(Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PublishRequest {
    pub station_id: String,
    pub recipe: crate::qc::Recipe,
    /// The station's version of it.
    pub version: i64,
    #[serde(default)]
    pub note: Option<String>,
}

/// The problem `type` of a refused item (the station parks it).
pub const ITEM_REFUSED: &str = "item-refused";

type Client = hyper_util::client::legacy::Client<
    hyper_rustls::HttpsConnector<hyper_util::client::legacy::connect::HttpConnector>,
    http_body_util::Full<bytes::Bytes>,
>;

/// The center as a station reaches it.
pub struct HttpCenter {
    client: Client,
    base: String,
    station_id: String,
    token: String,
    timeout: Duration,
}

/// Longest answer the station reads (the center's answers are small).
const MAX_ANSWER_BYTES: usize = 64 * 1024 * 1024;

impl HttpCenter {
    pub fn new(cfg: &FleetConfig) -> Result<HttpCenter, String> {
        let tls = tls_config(cfg.ca_file.as_deref(), cfg.center.starts_with("https://"))?;
        let https = hyper_rustls::HttpsConnectorBuilder::new()
            .with_tls_config(tls)
            .https_or_http()
            .enable_http1()
            .build();
        let client =
            hyper_util::client::legacy::Client::builder(hyper_util::rt::TokioExecutor::new())
                .build(https);
        Ok(HttpCenter {
            client,
            base: cfg.center.trim_end_matches('/').to_string(),
            station_id: cfg.station_id.clone(),
            token: cfg.token.clone(),
            // a batch of full recordings over a slow line takes a while
            timeout: Duration::from_secs(120),
        })
    }

    /// Publishes a local recipe: the center's status and body as they are
    /// (201 and the proposal, or its problem); Err when it did not answer.
    pub async fn publish_recipe(&self, req: &PublishRequest) -> StoreResult<(u16, Vec<u8>)> {
        let body = serde_json::to_vec(req).map_err(|e| StoreError::Invalid(e.to_string()))?;
        self.send(
            hyper::Method::POST,
            "/api/v1/fleet/ingest/recipe-proposals",
            Some(body),
        )
        .await
    }

    async fn call(
        &self,
        method: hyper::Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> StoreResult<Vec<u8>> {
        let (status, bytes) = self.send(method, path, body).await?;
        let unreachable = |e: String| StoreError::Corrupt(format!("center {}: {e}", self.base));
        match status {
            200 => Ok(bytes),
            413 => Err(StoreError::Invalid(
                "the batch is larger than the center takes (its max_ingest_bytes)".into(),
            )),
            s => {
                let p: serde_json::Value = serde_json::from_slice(&bytes).unwrap_or_default();
                let detail = p["detail"].as_str().unwrap_or("").to_string();
                let kind = p["type"].as_str().unwrap_or("");
                if s == 422 && kind.ends_with(ITEM_REFUSED) {
                    return Err(StoreError::Invalid(detail));
                }
                Err(unreachable(format!("{s}: {detail}")))
            }
        }
    }

    /// One request: the status and the body, whatever the status.
    async fn send(
        &self,
        method: hyper::Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> StoreResult<(u16, Vec<u8>)> {
        let req = hyper::Request::builder()
            .method(method)
            .uri(format!("{}{path}", self.base))
            .header(
                hyper::header::AUTHORIZATION,
                format!("Bearer {}", self.token),
            )
            .header(hyper::header::CONTENT_TYPE, "application/json")
            .body(http_body_util::Full::new(bytes::Bytes::from(
                body.unwrap_or_default(),
            )))
            .map_err(|e| StoreError::Corrupt(format!("request: {e}")))?;
        let unreachable = |e: String| StoreError::Corrupt(format!("center {}: {e}", self.base));
        let r = tokio::time::timeout(self.timeout, self.client.request(req))
            .await
            .map_err(|_| unreachable(format!("no answer within {:?}", self.timeout)))?
            .map_err(|e| unreachable(chain(&e)))?;
        let status = r.status().as_u16();
        let bytes = tokio::time::timeout(
            self.timeout,
            http_body_util::Limited::new(r.into_body(), MAX_ANSWER_BYTES).collect(),
        )
        .await
        .map_err(|_| unreachable("the answer did not arrive in time".into()))?
        .map_err(|e| unreachable(format!("answer: {e}")))?
        .to_bytes()
        .to_vec();
        Ok((status, bytes))
    }

    fn decode<T: serde::de::DeserializeOwned>(&self, bytes: &[u8]) -> StoreResult<T> {
        serde_json::from_slice(bytes).map_err(|e| {
            StoreError::Corrupt(format!("center {}: unreadable answer: {e}", self.base))
        })
    }
}

impl CenterIngest for HttpCenter {
    async fn hello(&self, h: &StationHello) -> StoreResult<StationStatus> {
        let body = serde_json::to_vec(h).map_err(|e| StoreError::Invalid(e.to_string()))?;
        let a = self
            .call(
                hyper::Method::POST,
                "/api/v1/fleet/ingest/hello",
                Some(body),
            )
            .await?;
        self.decode(&a)
    }

    async fn ingest(&self, station: &str, items: &[ReplicationItem]) -> StoreResult<IngestReport> {
        debug_assert_eq!(station, self.station_id);
        let req = ItemsRequest {
            station_id: station.to_string(),
            items: items.to_vec(),
        };
        let body = serde_json::to_vec(&req).map_err(|e| StoreError::Invalid(e.to_string()))?;
        let a = self
            .call(
                hyper::Method::POST,
                "/api/v1/fleet/ingest/items",
                Some(body),
            )
            .await?;
        self.decode(&a)
    }

    /// Each version is read on its own: one the station cannot read (a
    /// newer center's recipe field) is left out with a warning naming it,
    /// and does not hold back the others.
    async fn recipes(&self) -> StoreResult<Vec<RecipeRow>> {
        let a = self
            .call(hyper::Method::GET, "/api/v1/fleet/ingest/recipes", None)
            .await?;
        let rows: Vec<Box<serde_json::value::RawValue>> = self.decode(&a)?;
        Ok(rows
            .iter()
            .filter_map(|r| match serde_json::from_str::<RecipeRow>(r.get()) {
                Ok(row) => Some(row),
                Err(e) => {
                    tracing::warn!(
                        "fleet: a recipe version from the center is unreadable here, left out: {e}"
                    );
                    None
                }
            })
            .collect())
    }

    async fn stations(&self) -> StoreResult<Vec<StationStatus>> {
        Err(StoreError::Invalid(
            "a station does not list the fleet's stations".into(),
        ))
    }
}

/// TLS 1.2/1.3 (rustls, ring) with the center's CA file or the system's
/// trust store; unused for `http://`.
fn tls_config(ca_file: Option<&str>, https: bool) -> Result<rustls::ClientConfig, String> {
    use rustls::pki_types::{pem::PemObject, CertificateDer};
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?;
    let mut roots = rustls::RootCertStore::empty();
    if https {
        match ca_file {
            Some(path) => {
                for c in CertificateDer::pem_file_iter(path)
                    .map_err(|e| format!("fleet.ca_file {path}: {e}"))?
                {
                    let c = c.map_err(|e| format!("fleet.ca_file {path}: {e}"))?;
                    roots
                        .add(c)
                        .map_err(|e| format!("fleet.ca_file {path}: certificate refused: {e}"))?;
                }
                if roots.is_empty() {
                    return Err(format!("fleet.ca_file {path} holds no PEM certificate"));
                }
            }
            None => {
                for c in rustls_native_certs::load_native_certs().certs {
                    let _ = roots.add(c);
                }
                if roots.is_empty() {
                    return Err(
                        "no certificate authority in the system's trust store: set fleet.ca_file"
                            .into(),
                    );
                }
            }
        }
    }
    Ok(builder.with_root_certificates(roots).with_no_client_auth())
}

fn chain(e: &dyn std::error::Error) -> String {
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
