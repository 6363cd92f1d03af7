//! Daemon configuration (TOML). Every field is optional; `Config::default()`
//! is what `cargo run --release` uses: one virtual bench on 127.0.0.1:8750,
//! data in `./springbench-data`. See `deploy/springbench.toml` for an
//! annotated example.

use crate::bench::settings::{default_limits, default_preset};
pub use crate::bench::settings::{BenchConfig, BenchKind, DEFAULT_PRESET};
pub use crate::store::Retention;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Roles of bearer tokens; each role includes the rights of the ones before it.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Reads jobs, parts, measurements, events, metrics.
    Viewer,
    /// Also submits and cancels jobs, imports recordings, runs fits.
    Operator,
    /// Also reads the configuration.
    Admin,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Token {
    /// A label for logs (never the secret itself).
    pub name: String,
    /// The bearer secret (at least 16 characters).
    pub token: String,
    pub role: Role,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Auth {
    pub tokens: Vec<Token>,
}

/// Defaults applied to a job that leaves a field out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JobDefaults {
    /// Target peak displacement of the narrow sweep (m).
    pub target_xpeak_m: f64,
    /// Identification method: "two-signal" or "one-signal".
    pub method: crate::identify::Method,
    /// Order of K(x); chosen from the data when absent.
    pub order: Option<usize>,
}

impl Default for JobDefaults {
    fn default() -> Self {
        JobDefaults {
            target_xpeak_m: crate::procedure::ProcedureConfig::default().levels_m[0],
            method: crate::identify::Method::TwoSignal,
            order: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Listen address; port 0 picks a free port (the bound address is printed at start).
    pub bind: String,
    /// Directory of the SQLite database (created if missing).
    pub data_dir: PathBuf,
    /// Largest accepted upload (multipart import), bytes; larger requests get 413.
    pub max_upload_bytes: usize,
    /// Largest accepted JSON body, bytes.
    pub max_json_bytes: usize,
    /// Longest recording (frames) analysed, fitted or diagnosed: the analysis
    /// holds the recording in memory several times over. Longer imports are
    /// stored without a result (`analysis_error` says why); fits and
    /// diagnostics of them answer 422. Default 2^22 (87 s at 48 kHz).
    pub max_analysis_frames: u64,
    pub auth: Auth,
    pub benches: Vec<BenchConfig>,
    pub defaults: JobDefaults,
    /// Browser safety and resource bounds of the HTTP server (`[http]`).
    pub http: HttpConfig,
    /// Free space the data directory must keep: below it `/readyz` is not
    /// ready and jobs and imports are refused (503) instead of failing later.
    pub min_free_bytes: u64,
    /// MES delivery: CFX `Source` and the webhooks of the outbox worker.
    pub mes: crate::mes::MesConfig,
    pub retention: Retention,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            bind: "127.0.0.1:8750".into(),
            data_dir: PathBuf::from("./springbench-data"),
            max_upload_bytes: 256 * 1024 * 1024,
            max_json_bytes: 1024 * 1024,
            max_analysis_frames: 1 << 22,
            auth: Auth::default(),
            benches: vec![BenchConfig {
                id: "virtual-1".into(),
                kind: BenchKind::Virtual,
                preset: default_preset(),
                seed: 1,
                limits: default_limits(),
                hardware: None,
                emulator: None,
            }],
            defaults: JobDefaults::default(),
            http: HttpConfig::default(),
            min_free_bytes: 64 * 1024 * 1024,
            mes: crate::mes::MesConfig::default(),
            retention: Retention::default(),
        }
    }
}

impl Config {
    /// Reads and validates a TOML file.
    pub fn load(path: &Path) -> Result<Config, String> {
        let text =
            std::fs::read_to_string(path).map_err(|e| format!("config {}: {e}", path.display()))?;
        Config::parse(&text).map_err(|e| format!("config {}: {e}", path.display()))
    }

    /// Parses and validates TOML text.
    pub fn parse(text: &str) -> Result<Config, String> {
        let cfg: Config = toml::from_str(text).map_err(|e| one_line(&e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks everything that would otherwise fail later (or, worse, silently).
    pub fn validate(&self) -> Result<(), String> {
        if self.benches.is_empty() {
            return Err("at least one [[benches]] entry is needed".into());
        }
        let mut ids = std::collections::HashSet::new();
        for b in &self.benches {
            if b.id.is_empty()
                || !b
                    .id
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
            {
                return Err(format!(
                    "bench id '{}': use letters, digits, '-', '_' or '.'",
                    b.id
                ));
            }
            if !ids.insert(b.id.as_str()) {
                return Err(format!("bench id '{}' is used twice", b.id));
            }
            let l = b.limits;
            if !(l.max_displacement_m.is_finite()
                && l.max_displacement_m > 0.0
                && l.max_displacement_m <= 0.1)
            {
                return Err(format!(
                    "bench '{}': limits.max_displacement_m must be in (0, 0.1] m, got {}",
                    b.id, l.max_displacement_m
                ));
            }
            if !(l.max_drive_v.is_finite() && l.max_drive_v > 0.0) {
                return Err(format!(
                    "bench '{}': limits.max_drive_v must be > 0 V, got {}",
                    b.id, l.max_drive_v
                ));
            }
            b.validate_devices()?;
        }
        self.mes.validate()?;
        let mut secrets = std::collections::HashSet::new();
        for t in &self.auth.tokens {
            if is_published_example_token(&t.token) {
                return Err(format!(
                    "auth token '{}': this secret is the published example; set your own (e.g. `openssl rand -hex 24`)",
                    t.name
                ));
            }
            if t.token.len() < 16 {
                return Err(format!(
                    "auth token '{}': the secret must have at least 16 characters",
                    t.name
                ));
            }
            if !secrets.insert(t.token.as_str()) {
                return Err(format!(
                    "auth token '{}': the same secret is used twice",
                    t.name
                ));
            }
        }
        let x = self.defaults.target_xpeak_m;
        if !(x.is_finite() && x > 0.0) {
            return Err(format!("defaults.target_xpeak_m must be > 0 m, got {x}"));
        }
        if self.max_upload_bytes == 0 || self.max_json_bytes == 0 {
            return Err("max_upload_bytes and max_json_bytes must be > 0".into());
        }
        self.http.validate()?;
        let r = &self.retention;
        if let Some(d) = r.raw_max_age_days {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!("retention.raw_max_age_days must be > 0, got {d}"));
            }
        }
        if r.raw_keep_last_per_part == Some(0) {
            return Err("retention.raw_keep_last_per_part must be >= 1 (leave it out to keep every part's raw signals)".into());
        }
        if !(r.interval_s.is_finite() && r.interval_s >= 1.0) {
            return Err(format!(
                "retention.interval_s must be >= 1 s, got {}",
                r.interval_s
            ));
        }
        Ok(())
    }

    /// True when no tokens are configured: the daemon then binds to loopback only.
    pub fn open_access(&self) -> bool {
        self.auth.tokens.is_empty()
    }
}

/// Token secrets shown in published examples (`deploy/springbench.toml` of
/// earlier versions, the docs): the daemon refuses to start with them.
pub fn is_published_example_token(secret: &str) -> bool {
    secret.to_ascii_lowercase().contains("change-me")
}

/// `[http]`: browser safety (Host and Origin checks) and resource bounds.
/// See docs/http-hardening.md.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    /// Host names (without port) accepted in the `Host` header besides IP
    /// literals and `localhost` (DNS-rebinding protection), e.g. `["bench-7.lab"]`.
    pub allowed_hosts: Vec<String>,
    /// Origins (`scheme://host[:port]`) accepted in an `Origin` header besides
    /// the daemon's own (the origin named by the request's `Host`).
    pub allowed_origins: Vec<String>,
    /// A client must send its request headers within this time (s).
    pub header_read_timeout_s: f64,
    /// Longest pause between two pieces of a request body (s).
    pub body_read_timeout_s: f64,
    /// Open connections at most; further ones wait in the kernel's backlog.
    pub max_connections: usize,
    /// Expensive requests (diagnostics, plots, fits, imports) computed at once;
    /// further ones wait their turn.
    pub max_expensive: usize,
}

impl Default for HttpConfig {
    fn default() -> Self {
        HttpConfig {
            allowed_hosts: vec![],
            allowed_origins: vec![],
            header_read_timeout_s: 10.0,
            body_read_timeout_s: 30.0,
            max_connections: 4096,
            max_expensive: 2,
        }
    }
}

impl HttpConfig {
    fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("http.header_read_timeout_s", self.header_read_timeout_s),
            ("http.body_read_timeout_s", self.body_read_timeout_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
                return Err(format!("{name} must be in (0, 3600] s, got {v}"));
            }
        }
        if self.max_connections < 16 {
            return Err(format!(
                "http.max_connections must be at least 16, got {}",
                self.max_connections
            ));
        }
        if self.max_expensive == 0 {
            return Err("http.max_expensive must be at least 1".into());
        }
        for o in &self.allowed_origins {
            if !(o.starts_with("http://") || o.starts_with("https://")) || o.ends_with('/') {
                return Err(format!(
                    "http.allowed_origins: '{o}' is not an origin (scheme://host[:port], no path)"
                ));
            }
        }
        Ok(())
    }
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn example_config_in_deploy_parses() {
        let text = include_str!("../deploy/springbench.toml");
        let cfg = Config::parse(text).expect("deploy/springbench.toml is valid");
        assert_eq!(cfg.benches.len(), 1);
        // Safe as installed: no tokens, so open access on loopback only.
        assert!(cfg.auth.tokens.is_empty());
        assert_eq!(cfg.bind, "127.0.0.1:8750");
        assert_eq!(cfg.http, HttpConfig::default());
        assert_eq!(cfg.benches[0].limits.max_displacement_m, 0.015);
    }

    #[test]
    fn example_emulated_bench_config_parses_with_the_feature() {
        for text in [
            include_str!("../deploy/emulated-bench.toml"),
            include_str!("../deploy/emulated-serial-bench.toml"),
        ] {
            let r = Config::parse(text);
            if cfg!(feature = "hardware") {
                let cfg = r.expect("deploy/emulated*-bench.toml is valid");
                assert_eq!(cfg.benches[0].kind, BenchKind::Emulated);
                let hw = cfg.benches[0].hardware.as_ref().unwrap();
                assert_eq!(hw.calibration.amplifier_gain, 100.0);
            } else {
                let e = r.unwrap_err();
                assert!(e.contains("`hardware` feature"), "{e}");
            }
        }
    }

    #[test]
    fn hardware_tables_must_fit_the_kind() {
        let e = Config::parse("[[benches]]\nid = \"a\"\nkind = \"emulated\"").unwrap_err();
        assert!(e.contains("[benches.hardware]"), "{e}");
        let text = include_str!("../deploy/emulated-bench.toml")
            .replace("ramp_down_s = 0.01", "ramp_down_s = 0.2");
        let e = Config::parse(&text).unwrap_err();
        assert!(
            e.contains("ramp_down_s") || e.contains("`hardware` feature"),
            "{e}"
        );
        let text =
            include_str!("../deploy/emulated-bench.toml").replace("laser = 2 }", "laser = 1 }");
        let e = Config::parse(&text).unwrap_err();
        assert!(
            e.contains("both 1") || e.contains("`hardware` feature"),
            "{e}"
        );
    }

    #[test]
    fn empty_config_is_the_default() {
        assert_eq!(Config::parse("").unwrap(), Config::default());
        assert!(Config::default().open_access());
    }

    #[test]
    fn bad_configs_are_refused_with_a_reason() {
        let e = Config::parse("bnid = \"x\"").unwrap_err();
        assert!(e.contains("bnid"), "{e}");
        let e = Config::parse("[[benches]]\nid = \"a\"\n[[benches]]\nid = \"a\"").unwrap_err();
        assert!(e.contains("twice"), "{e}");
        let e = Config::parse(
            "[[benches]]\nid = \"a\"\nlimits = { max_displacement_m = -1.0, max_drive_v = 1.0 }",
        )
        .unwrap_err();
        assert!(e.contains("max_displacement_m"), "{e}");
        let e =
            Config::parse("[[auth.tokens]]\nname = \"x\"\ntoken = \"short\"\nrole = \"viewer\"")
                .unwrap_err();
        assert!(e.contains("16"), "{e}");
        let e = Config::parse(
            "[[auth.tokens]]\nname = \"x\"\ntoken = \"0123456789abcdefg\"\nrole = \"boss\"",
        )
        .unwrap_err();
        assert!(e.contains("boss") || e.contains("role"), "{e}");
        let e = Config::parse("[retention]\nraw_keep_last_per_part = 0").unwrap_err();
        assert!(e.contains("raw_keep_last_per_part"), "{e}");
        let e = Config::parse("[retention]\nraw_max_age_days = -3").unwrap_err();
        assert!(e.contains("raw_max_age_days"), "{e}");
        let c = Config::parse("[retention]\nraw_max_age_days = 30\nraw_keep_last_per_part = 3")
            .unwrap();
        assert_eq!(c.retention.raw_max_age_days, Some(30.0));
        assert_eq!(c.retention.raw_keep_last_per_part, Some(3));
    }

    #[test]
    fn the_published_example_tokens_are_refused() {
        let e = Config::parse(
            "[[auth.tokens]]\nname = \"mes\"\ntoken = \"change-me-viewer-0001\"\nrole = \"viewer\"",
        )
        .unwrap_err();
        assert!(e.contains("published example"), "{e}");
        let e = Config::parse("[http]\nallowed_origins = [\"mes.lab\"]").unwrap_err();
        assert!(e.contains("allowed_origins"), "{e}");
    }

    #[test]
    fn roles_are_ordered() {
        assert!(Role::Viewer < Role::Operator && Role::Operator < Role::Admin);
    }
}
