//! A typed API client for the tests: the daemon's base URL and a bearer
//! token, one call a request, and the answer's status, headers and JSON
//! together ([`Reply`]), so that a test reads as the exchange it checks
//! instead of reqwest's builder chain. Replaces the `get`, `post_job`,
//! `create_recipe`, `import` and `finished` each test file defined again.

use super::Daemon;
use reqwest::Method;
use serde_json::Value;
use std::time::{Duration, Instant};

/// One answer: status, headers, and the body as JSON (`Null` when it is not
/// JSON; the text is kept for messages).
pub struct Reply {
    pub status: u16,
    pub headers: reqwest::header::HeaderMap,
    pub body: Value,
    pub text: String,
}

impl Reply {
    /// Asserts `status`; the JSON body.
    #[track_caller]
    pub fn expect(self, status: u16) -> Value {
        assert_eq!(self.status, status, "{}", self.text);
        self.body
    }

    /// A header's value ("" when absent).
    pub fn header(&self, name: &str) -> &str {
        self.headers
            .get(name)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
    }

    /// Asserts an RFC 9457 problem document with `status` (content type,
    /// status, a `/problems/` type, a title and a detail); returns it.
    #[track_caller]
    pub fn problem(self, status: u16) -> Value {
        assert_eq!(self.status, status, "status: {}", self.text);
        assert_eq!(self.header("content-type"), "application/problem+json");
        let v = self.body;
        assert_eq!(v["status"].as_u64(), Some(status as u64), "{v}");
        assert!(v["type"].as_str().unwrap().starts_with("/problems/"), "{v}");
        assert!(!v["title"].as_str().unwrap().is_empty(), "{v}");
        assert!(!v["detail"].as_str().unwrap_or("").is_empty(), "{v}");
        v
    }
}

/// The daemon's API as one role sees it.
#[derive(Clone)]
pub struct Api {
    c: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Api {
    /// Without a token (a daemon without `[auth]`).
    pub fn new(d: &Daemon) -> Api {
        Api {
            c: super::client(),
            base: d.base.clone(),
            token: None,
        }
    }

    /// With a bearer token.
    pub fn with(d: &Daemon, token: &str) -> Api {
        Api::new(d).token(token)
    }

    /// The same daemon, as another token.
    pub fn token(&self, token: &str) -> Api {
        Api {
            token: Some(token.to_string()),
            ..self.clone()
        }
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// A request builder with the token (for headers or bodies of another kind).
    pub fn builder(&self, method: Method, path: &str) -> reqwest::RequestBuilder {
        let r = self.c.request(method, self.url(path));
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    /// Sends a built request; the reply.
    pub async fn send(&self, r: reqwest::RequestBuilder) -> Reply {
        let r = r.send().await.expect("the request is sent");
        let status = r.status().as_u16();
        let headers = r.headers().clone();
        let text = r.text().await.unwrap_or_default();
        let body = serde_json::from_str(&text).unwrap_or(Value::Null);
        Reply {
            status,
            headers,
            body,
            text,
        }
    }

    /// `method path` with an optional JSON body.
    pub async fn call(&self, method: Method, path: &str, body: Option<&Value>) -> Reply {
        let mut r = self.builder(method, path);
        if let Some(b) = body {
            r = r.json(b);
        }
        self.send(r).await
    }

    /// `method path` with an optional JSON body: the status and the JSON
    /// answer (`Null` when the body is not JSON).
    /// (As `common::send` did: the JSON content type on every request.)
    pub async fn exchange(&self, method: Method, path: &str, body: Option<&Value>) -> (u16, Value) {
        let mut r = self
            .builder(method, path)
            .header("content-type", "application/json");
        if let Some(b) = body {
            r = r.body(b.to_string());
        }
        let r = self.send(r).await;
        (r.status, r.body)
    }

    /// GET, whatever the status.
    pub async fn get_reply(&self, path: &str) -> Reply {
        self.call(Method::GET, path, None).await
    }

    /// GET a JSON document (asserts 200).
    pub async fn get(&self, path: &str) -> Value {
        let r = self.get_reply(path).await;
        assert_eq!(r.status, 200, "GET {path}: {}", r.text);
        r.body
    }

    /// GET the body as text (CSV, Prometheus metrics).
    pub async fn text(&self, path: &str) -> String {
        self.get_reply(path).await.text
    }

    /// POST a JSON body, whatever the status.
    pub async fn post(&self, path: &str, body: &Value) -> Reply {
        self.call(Method::POST, path, Some(body)).await
    }

    /// POST with no body.
    pub async fn post_empty(&self, path: &str) -> Reply {
        self.send(
            self.builder(Method::POST, path)
                .header("content-type", "application/json"),
        )
        .await
    }

    /// PUT a JSON body, whatever the status.
    pub async fn put(&self, path: &str, body: &Value) -> Reply {
        self.call(Method::PUT, path, Some(body)).await
    }

    /// Polls `GET path` until it answers 200 with a body `done` accepts, at
    /// most `within` (it fails the test then, with the last answer); that body.
    pub async fn poll(&self, path: &str, within: Duration, done: impl Fn(&Value) -> bool) -> Value {
        let t = Instant::now();
        loop {
            let r = self.get_reply(path).await;
            if r.status == 200 && done(&r.body) {
                return r.body;
            }
            assert!(
                t.elapsed() < within,
                "GET {path}: not as expected within {within:?}: {} {}",
                r.status,
                r.text
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    /// The value of a `/metrics` line that starts with `line` (a name with
    /// its labels, e.g. `springbench_fleet_stuck`).
    pub async fn metric(&self, line: &str) -> f64 {
        let text = self.text("/metrics").await;
        text.lines()
            .find_map(|l| {
                l.strip_prefix(line)
                    .map(|v| v.trim().parse::<f64>().expect("a number"))
            })
            .unwrap_or_else(|| panic!("no {line} in /metrics"))
    }

    /// Every item of a paged listing: `path` (with its own query) page by
    /// page, the next page's `param` taken from the answer's `next` field
    /// (a cursor string or a number), in the order served.
    pub async fn all_pages(&self, path: &str, param: &str, next: &str) -> Vec<Value> {
        let mut out = vec![];
        let mut at: Option<String> = None;
        loop {
            let sep = if path.contains('?') { '&' } else { '?' };
            let q = at.map_or(String::new(), |a| format!("{sep}{param}={a}"));
            let page = self.get(&format!("{path}{q}")).await;
            out.extend(page["items"].as_array().expect("items").iter().cloned());
            at = match &page[next] {
                Value::String(s) => Some(s.clone()),
                Value::Number(n) => Some(n.to_string()),
                _ => return out,
            };
        }
    }

    /// Submits a job and waits for it; asserts it succeeded; the ids of its
    /// measurements.
    pub async fn measured(&self, body: &Value) -> Vec<String> {
        let id = self.submit(body).await;
        let j = self.finished(&id).await;
        assert_eq!(j["state"], "succeeded", "{j}");
        let m = self.get(&format!("/api/v1/measurements?job={id}")).await;
        m["items"]
            .as_array()
            .expect("items")
            .iter()
            .map(|x| x["id"].as_str().expect("an id").to_string())
            .collect()
    }

    /// Submits a job (asserts 202 Accepted); its id.
    pub async fn submit(&self, body: &Value) -> String {
        let v = self.post("/api/v1/jobs", body).await.expect(202);
        v["id"].as_str().expect("the job's id").to_string()
    }

    /// Creates a recipe (asserts 201 Created); the answer.
    pub async fn create_recipe(&self, body: &Value) -> Value {
        self.post("/api/v1/recipes", body).await.expect(201)
    }

    /// Polls a job until it has finished (not queued, not running), at most
    /// `within`; the last job document.
    pub async fn finished_within(&self, id: &str, within: Duration) -> Value {
        let t = Instant::now();
        loop {
            let j = self.get(&format!("/api/v1/jobs/{id}")).await;
            if super::terminal(j["state"].as_str().unwrap_or("")) {
                return j;
            }
            assert!(t.elapsed() < within, "job {id} not finished: {j}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// [`Api::finished_within`] ten minutes.
    pub async fn finished(&self, id: &str) -> Value {
        self.finished_within(id, Duration::from_secs(600)).await
    }

    /// Submits each job, then waits for all; the finished job documents.
    pub async fn run_all(&self, bodies: &[Value]) -> Vec<Value> {
        let mut ids = vec![];
        for b in bodies {
            ids.push(self.submit(b).await);
        }
        let mut out = vec![];
        for id in &ids {
            out.push(self.finished(id).await);
        }
        out
    }

    /// Imports a reference recording set (meta.json, pre.wav, main.wav) as
    /// part `serial`; the measurement's id (asserts 201).
    pub async fn import(&self, name: &str, serial: &str) -> String {
        let dir = super::reference_dir(name);
        let part = |f: &str| {
            reqwest::multipart::Part::bytes(std::fs::read(dir.join(f)).expect("reference file"))
                .file_name(f.to_string())
        };
        let form = reqwest::multipart::Form::new()
            .part("meta", part("meta.json"))
            .part("pre", part("pre.wav"))
            .part("main", part("main.wav"))
            .text("serial", serial.to_string())
            .text("kind", "spider");
        let r = self.builder(Method::POST, "/api/v1/measurements");
        let v = self.send(r.multipart(form)).await.expect(201);
        v["measurement"]["id"].as_str().unwrap().to_string()
    }
}
