//! Test harness: the real `springbench` binary on an ephemeral port with a
//! temporary data directory, driven over real HTTP and websocket.
#![allow(dead_code)]

pub mod api;
pub mod config;
pub mod tmpfs;
// The hardware binaries include this module and use neither.
#[allow(unused_imports)]
pub use api::Api;
#[allow(unused_imports)]
pub use config::Config;
#[allow(unused_imports)]
pub use tmpfs::Tmpfs;

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub struct Daemon {
    child: Child,
    /// `http://127.0.0.1:PORT`
    pub base: String,
    pub dir: PathBuf,
    _tmp: Option<tempfile::TempDir>,
}

impl Daemon {
    /// Starts a daemon in a fresh temporary directory; `extra` is appended to its TOML config.
    pub fn start(extra: &str) -> Daemon {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path().to_path_buf();
        let mut d = Daemon::start_in(&dir, extra);
        d._tmp = Some(tmp);
        d
    }

    /// Starts a daemon on `dir` (config and data inside it): used again after a kill.
    pub fn start_in(dir: &Path, extra: &str) -> Daemon {
        Daemon::start_logged(dir, extra, None)
    }

    /// [`Daemon::start_in`] with the daemon's log (stderr) appended to `log`.
    pub fn start_logged(dir: &Path, extra: &str, log: Option<&Path>) -> Daemon {
        Daemon::start_logged_at(dir, extra, log, "warn")
    }

    /// [`Daemon::start_logged`] with `RUST_LOG` = `rust_log` (e.g. `trace`:
    /// what no log line may hold, at every level).
    pub fn start_logged_at(dir: &Path, extra: &str, log: Option<&Path>, rust_log: &str) -> Daemon {
        let stderr = match log {
            Some(p) => Stdio::from(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(p)
                    .expect("log file"),
            ),
            None => Stdio::null(),
        };
        let cfg = dir.join("springbench.toml");
        let text = format!(
            "bind = \"127.0.0.1:0\"\ndata_dir = \"{}\"\n{extra}\n",
            dir.join("data").display()
        );
        std::fs::write(&cfg, text).expect("write config");
        let mut child = Command::new(env!("CARGO_BIN_EXE_springbench"))
            .arg("serve")
            .arg("--config")
            .arg(&cfg)
            .env("RUST_LOG", rust_log)
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .expect("start springbench");
        let out = child.stdout.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut lines = BufReader::new(out).lines();
            while let Some(Ok(l)) = lines.next() {
                if let Some(a) = l.strip_prefix("listening on ") {
                    let _ = tx.send(a.to_string());
                }
            }
        });
        let base = match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(b) => b,
            Err(_) => {
                let _ = child.kill();
                panic!("the daemon did not print 'listening on' within 30 s");
            }
        };
        Daemon {
            child,
            base,
            dir: dir.to_path_buf(),
            _tmp: None,
        }
    }

    /// The daemon's process id (memory figures from /proc/PID/status).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// `127.0.0.1:PORT`, for raw TCP clients.
    pub fn addr(&self) -> String {
        self.base.trim_start_matches("http://").to_string()
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    pub fn ws_url(&self, path: &str) -> String {
        format!("{}{path}", self.base.replacen("http://", "ws://", 1))
    }

    /// SIGKILL: no chance to clean up.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then waits for the process to exit (graceful shutdown).
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(self.child.id().to_string())
            .status();
        let t = Instant::now();
        loop {
            if let Ok(Some(s)) = self.child.try_wait() {
                return s;
            }
            if t.elapsed() > Duration::from_secs(40) {
                let _ = self.child.kill();
                panic!("the daemon did not stop within 40 s of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Keeps the data directory when the daemon is dropped (for a restart).
    pub fn take_dir(&mut self) -> Option<tempfile::TempDir> {
        self._tmp.take()
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(Duration::from_secs(60))
        .build()
        .unwrap()
}

/// Polls a job until `done(state)` or the timeout; returns the last job document.
pub async fn wait_job(
    c: &reqwest::Client,
    d: &Daemon,
    id: &str,
    timeout: Duration,
    done: impl Fn(&str) -> bool,
) -> Value {
    let t = Instant::now();
    loop {
        let j: Value = c
            .get(d.url(&format!("/api/v1/jobs/{id}")))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if done(j["state"].as_str().unwrap_or("")) || t.elapsed() > timeout {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

pub fn terminal(s: &str) -> bool {
    !matches!(s, "queued" | "running")
}

/// Asserts a problem+json response with `status`; returns the document.
pub async fn problem(r: reqwest::Response, status: u16) -> Value {
    assert_eq!(r.status().as_u16(), status, "status");
    let ct = r
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap().to_string())
        .unwrap_or_default();
    assert_eq!(ct, "application/problem+json");
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["status"].as_u64(), Some(status as u64), "{v}");
    assert!(v["type"].as_str().unwrap().starts_with("/problems/"), "{v}");
    assert!(!v["title"].as_str().unwrap().is_empty(), "{v}");
    assert!(!v["detail"].as_str().unwrap_or("").is_empty(), "{v}");
    v
}

pub fn reference_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings")
        .join(name)
}

/// Submits a job and returns its id (asserts 202 Accepted).
pub async fn submit(c: &reqwest::Client, d: &Daemon, body: Value) -> String {
    let r = c
        .post(d.url("/api/v1/jobs"))
        .json(&body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string()
}

/// `method path` with a bearer token and an optional JSON body: the status
/// and the JSON answer (Null when the body is not JSON).
pub async fn send(
    c: &reqwest::Client,
    d: &Daemon,
    method: reqwest::Method,
    path: &str,
    token: &str,
    body: Option<Value>,
) -> (u16, Value) {
    let mut r = c
        .request(method, d.url(path))
        .bearer_auth(token)
        .header("content-type", "application/json");
    if let Some(b) = body {
        r = r.body(b.to_string());
    }
    let r = r.send().await.unwrap();
    let s = r.status().as_u16();
    (s, r.json::<Value>().await.unwrap_or(Value::Null))
}

/// GET a JSON document (asserts 200).
pub async fn get(c: &reqwest::Client, d: &Daemon, path: &str) -> Value {
    let r = c.get(d.url(path)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 200, "{path}");
    r.json().await.unwrap()
}

/// GET the raw body (WAV, SVG).
pub async fn get_bytes(c: &reqwest::Client, d: &Daemon, path: &str) -> Vec<u8> {
    c.get(d.url(path))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap()
        .to_vec()
}

/// GET the body as text (Prometheus metrics).
pub async fn get_text(c: &reqwest::Client, d: &Daemon, path: &str) -> String {
    c.get(d.url(path))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap()
}

/// A daemon with `config` whose bench `bench` carries a stored fault
/// `detail`, as a hardware bench stores it when its laser fails (a
/// `bench_faults` row; it outlives a restart): started once to create its
/// database, stopped, the row written, started again. The directory holds
/// its data.
pub async fn with_bench_fault(
    config: &str,
    bench: &str,
    detail: &str,
) -> (Daemon, tempfile::TempDir) {
    use sqlx::ConnectOptions;
    let mut d = Daemon::start(config);
    let tmp = d.take_dir().unwrap();
    d.terminate();
    drop(d);
    let mut db = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(tmp.path().join("data").join("springbench.db"))
        .connect()
        .await
        .unwrap();
    sqlx::query(
        "INSERT INTO bench_faults (bench_id, job_id, detail, created_at) \
         VALUES (?, NULL, ?, '2026-11-28T08:00:00.000Z')",
    )
    .bind(bench)
    .bind(detail)
    .execute(&mut db)
    .await
    .unwrap();
    drop(db);
    (Daemon::start_in(tmp.path(), config), tmp)
}

/// The fault a hardware bench stores when its laser fails.
pub const LASER_LOST: &str = "laser signal lost: 0 valid frames in 0.5 s";

/// Resident memory of a process (VmRSS from /proc/PID/status), kB.
pub fn rss_kb(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    s.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("VmRSS")
}

/// `key` of /proc/PID/status (`VmRSS:`, `VmHWM:`), kB.
pub fn status_kb(pid: u32, key: &str) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    s.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect(key)
}

/// Samples a process's VmRSS every `period` on a thread of its own until
/// [`RssSampler::peak_kb`], which answers the largest sample or VmHWM,
/// whichever is larger (kB).
pub struct RssSampler {
    pid: u32,
    peak: std::sync::Arc<std::sync::atomic::AtomicU64>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<()>,
}

impl RssSampler {
    pub fn start(pid: u32, period: Duration) -> RssSampler {
        use std::sync::atomic::Ordering::Relaxed;
        let peak = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (p, s) = (peak.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Relaxed) {
                p.fetch_max(status_kb(pid, "VmRSS:"), Relaxed);
                std::thread::sleep(period);
            }
        });
        RssSampler {
            pid,
            peak,
            stop,
            thread,
        }
    }

    pub fn peak_kb(self) -> u64 {
        use std::sync::atomic::Ordering::Relaxed;
        self.stop.store(true, Relaxed);
        self.thread.join().unwrap();
        self.peak.load(Relaxed).max(status_kb(self.pid, "VmHWM:"))
    }
}

/// One raw HTTP/1.1 exchange on a fresh connection: `request` is sent as
/// is; returns (status, headers as text, body).
pub fn raw(addr: &str, request: &[u8]) -> (u16, String, Vec<u8>) {
    use std::io::Write;
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(request).expect("send");
    let mut r = BufReader::new(s);
    read_response(&mut r).expect("a response")
}

/// Reads one HTTP/1.1 response with a Content-Length (or until close).
pub fn read_response(r: &mut impl BufRead) -> Option<(u16, String, Vec<u8>)> {
    let mut status_line = String::new();
    if r.read_line(&mut status_line).ok()? == 0 {
        return None;
    }
    let status: u16 = status_line.split_whitespace().nth(1)?.parse().ok()?;
    let mut headers = String::new();
    let mut len: Option<usize> = None;
    loop {
        let mut l = String::new();
        r.read_line(&mut l).ok()?;
        if l == "\r\n" || l.is_empty() {
            break;
        }
        if let Some((k, v)) = l.split_once(':') {
            if k.eq_ignore_ascii_case("content-length") {
                len = v.trim().parse().ok();
            }
        }
        headers.push_str(&l);
    }
    let mut body = vec![];
    match len {
        Some(n) => {
            body.resize(n, 0);
            std::io::Read::read_exact(r, &mut body).ok()?;
        }
        None => {
            let _ = std::io::Read::read_to_end(r, &mut body);
        }
    }
    Some((status, headers, body))
}

/// The parameters of issue 21's equivalence recipes: every quantity a recipe
/// can judge (k0, f0, Q, R, Keff at target, K at `x_m`, the asymmetry there,
/// model error below 5 %). Shared by `tests/it/production.rs` (virtual bench)
/// and `tests/hardware_emulated.rs` (emulated hardware bench).
pub fn production_equivalence_parameters(x_m: f64) -> Value {
    serde_json::json!([
        {"name": "k0", "quantity": "k0"},
        {"name": "f0", "quantity": "f0"},
        {"name": "q", "quantity": "q"},
        {"name": "r", "quantity": "r"},
        {"name": "keff", "quantity": "keff"},
        {"name": "k_at_half", "quantity": "k_at_x", "x_m": x_m},
        {"name": "asym_half", "quantity": "k_asymmetry", "x_m": x_m},
        {"name": "model_error", "quantity": "model_error", "upper": 5.0}
    ])
}

/// POST `path` with no body; the answer's status.
pub async fn post_status(c: &reqwest::Client, d: &Daemon, path: &str) -> u16 {
    c.post(d.url(path))
        .header("content-type", "application/json")
        .send()
        .await
        .unwrap()
        .status()
        .as_u16()
}

/// A long-term test's document says it is paused (its job's step).
pub fn paused(v: &Value) -> bool {
    v["job"]["step"]
        .as_str()
        .is_some_and(|s| s.starts_with("paused"))
}

/// A long-term test's events caused by the user: (kind, test time in s).
pub fn user_events(v: &Value) -> Vec<(String, f64)> {
    v["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["cause"] == "user")
        .map(|e| {
            (
                e["kind"].as_str().unwrap().to_string(),
                e["elapsed_s"].as_f64().unwrap(),
            )
        })
        .collect()
}
