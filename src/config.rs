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
    /// The fleet role's central database (`postgres://...`): set it, with
    /// `benches = []`, and the daemon serves the fleet (every station's
    /// results) instead of benches. Absent on a station.
    pub database: Option<String>,
    /// A station of a fleet (`[fleet]`): where and how it replicates.
    pub fleet: Option<FleetConfig>,
    /// The fleet role's stations (`[[stations]]`): each one's id and the
    /// token it posts its items with (decision 0105). A station not listed
    /// here cannot deliver to the center.
    pub stations: Vec<StationCredential>,
    /// The fleet role: heavy SPC queries (`/api/v1/fleet/recipes/{name}/spc`)
    /// running at once per client; one more is answered 429 with
    /// `Retry-After` (default 2).
    pub spc_per_client: usize,
    /// The fleet role: largest body of a station's batch (bytes, default
    /// 256 MiB; a larger one is 413 and the station sends its items one by one).
    pub max_ingest_bytes: usize,
}

/// `[[stations]]` of the fleet role: one station's credential.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationCredential {
    /// The station's id (its `[fleet] station_id`).
    pub station_id: String,
    /// The bearer secret the station posts with (its `[fleet] token`), at
    /// least 16 characters, no placeholder.
    pub token: String,
    /// The station's former ids (a rename on purpose): the center moves its
    /// record of the station's stream to this id and lets the station
    /// correct and void what it made under them; the rows keep their id.
    #[serde(default)]
    pub former_ids: Vec<String>,
    /// A station taken out of the fleet: its token is refused (and each
    /// attempt recorded), its history stays.
    #[serde(default)]
    pub retired: bool,
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
                virtual_: None,
                ambient: None,
            }],
            defaults: JobDefaults::default(),
            http: HttpConfig::default(),
            min_free_bytes: 64 * 1024 * 1024,
            mes: crate::mes::MesConfig::default(),
            retention: Retention::default(),
            database: None,
            fleet: None,
            stations: vec![],
            spc_per_client: 2,
            max_ingest_bytes: 256 * 1024 * 1024,
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
        if let Some(db) = &self.database {
            check_postgres_url("database", db)?;
            if !self.benches.is_empty() {
                return Err(format!(
                    "database = \"{}\" starts the fleet role, which runs no bench: set benches = [] (a station keeps its SQLite in data_dir and names the center in [fleet] center)",
                    redact_url_password(db)
                ));
            }
            if self.fleet.is_some() {
                return Err(
                    "[fleet] is a station's table; the fleet role (database = ...) has none".into(),
                );
            }
            let mut seen = std::collections::HashSet::new();
            for s in &self.stations {
                check_station_id("stations.station_id", &s.station_id)?;
                check_secret(&format!("stations[{}].token", s.station_id), &s.token)?;
                for f in &s.former_ids {
                    check_station_id(&format!("stations[{}].former_ids", s.station_id), f)?;
                }
                for id in std::iter::once(&s.station_id).chain(&s.former_ids) {
                    if !seen.insert(id.as_str()) {
                        return Err(format!(
                            "stations: station id '{id}' is given twice (an id, once used, names one station for good)"
                        ));
                    }
                }
            }
            if self.spc_per_client == 0 {
                return Err("spc_per_client must be >= 1".into());
            }
        } else if !self.stations.is_empty() {
            return Err("[[stations]] is the fleet role's table (database = ...); a station names its center in [fleet]".into());
        } else if self.benches.is_empty() {
            return Err("at least one [[benches]] entry is needed (or database = \"postgres://...\" for the fleet role)".into());
        }
        if let Some(f) = &self.fleet {
            f.validate()?;
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
        self.mes.validate_handles(
            &self
                .benches
                .iter()
                .map(|b| b.id.as_str())
                .collect::<Vec<_>>(),
        )?;
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
            check_secret(&format!("auth token '{}'", t.name), &t.token)?;
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

    /// True when the daemon runs the fleet role (a central database, no benches).
    pub fn is_fleet_role(&self) -> bool {
        self.database.is_some()
    }

    /// True when no tokens are configured: the daemon then binds to loopback only.
    pub fn open_access(&self) -> bool {
        self.auth.tokens.is_empty()
    }
}

/// A secret the daemon accepts: no placeholder of the shipped deploy files
/// or docs (`<your secret ...>`, `change-me`, `...`), at least 16
/// characters, and not a run of a few characters repeated. `key` names the
/// configuration key in the error.
pub fn check_secret(key: &str, secret: &str) -> Result<(), String> {
    let lower = secret.to_ascii_lowercase();
    let placeholder = [
        "<",
        ">",
        "your secret",
        "your-secret",
        "change-me",
        "changeme",
        "placeholder",
        "replace",
        "...",
    ]
    .iter()
    .any(|p| lower.contains(p));
    if placeholder || is_published_example_token(secret) {
        return Err(format!(
            "{key}: '{secret}' is a placeholder; set a secret of your own (e.g. `openssl rand -hex 24`)"
        ));
    }
    if secret.chars().count() < 16 {
        return Err(format!(
            "{key}: the secret must have at least 16 characters"
        ));
    }
    let distinct: std::collections::HashSet<char> = secret.chars().collect();
    if distinct.len() < 6 || secret.chars().any(char::is_control) {
        return Err(format!(
            "{key}: a weak secret (fewer than 6 different characters, or control characters); use e.g. `openssl rand -hex 24`"
        ));
    }
    Ok(())
}

fn check_station_id(key: &str, id: &str) -> Result<(), String> {
    if id.is_empty()
        || id.len() > 64
        || !id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
    {
        return Err(format!(
            "{key} '{id}': 1 to 64 letters, digits, '-', '_' or '.'"
        ));
    }
    Ok(())
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

/// What a station sends to the center with each measurement (`[fleet] recordings`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RecordingsPolicy {
    /// The FLAC recordings themselves: the center can fit them again.
    #[default]
    Full,
    /// Only a reference (station, measurement id, kind, size, SHA-256): the
    /// recordings stay on the station (and its retention policy applies).
    Reference,
}

/// `[fleet]`: a station replicating its finished measurements to the
/// fleet's central PostgreSQL (docs/fleet.md, README "Running a fleet").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FleetConfig {
    /// The center's fleet role, `https://center.lab:8760` (or `http://`
    /// on a trusted network): the station posts its items there (decision
    /// 0105); it holds no credential of the center's database.
    pub center: String,
    /// This station's secret at the center (the center's `[[stations]]`
    /// entry of this `station_id` holds the same): at least 16 characters.
    pub token: String,
    /// A PEM file of the certificate authority that signed the center's
    /// certificate (`https://`); default: the system's trust store.
    #[serde(default)]
    pub ca_file: Option<String>,
    /// This station's name in the fleet (letters, digits, '-', '_', '.';
    /// at most 64): every row the center shows carries it. Never reuse one
    /// station's id for another.
    pub station_id: String,
    /// `full` (default) or `reference`.
    #[serde(default)]
    pub recordings: RecordingsPolicy,
    /// Items sent to the center per transaction (1..=1000, default 50).
    #[serde(default = "default_batch_items")]
    pub batch_items: usize,
    /// Longest wait between two attempts while the center is unreachable
    /// (s, 1..=3600, default 30); the wait doubles from 1 s up to it.
    #[serde(default = "default_retry_max_s")]
    pub retry_max_s: f64,
    /// How often the station asks the center for new recipe versions and
    /// retirements (s, 5..=86400, default 60).
    #[serde(default = "default_recipe_poll_s")]
    pub recipe_poll_s: f64,
}

fn default_batch_items() -> usize {
    50
}
fn default_retry_max_s() -> f64 {
    30.0
}
fn default_recipe_poll_s() -> f64 {
    60.0
}

impl FleetConfig {
    fn validate(&self) -> Result<(), String> {
        let u = url::Url::parse(&self.center).map_err(|e| {
            format!("fleet.center: not a URL ({e}); expected https://center.lab:8760")
        })?;
        match u.scheme() {
            "http" | "https" => {}
            "postgres" | "postgresql" => return Err(
                "fleet.center: a station no longer writes the center's database (decision 0105); name the center's fleet role, e.g. https://center.lab:8760, and set fleet.token".into(),
            ),
            other => {
                return Err(format!(
                    "fleet.center: scheme '{other}'; expected https://center.lab:8760"
                ))
            }
        }
        if u.host_str().is_none_or(str::is_empty) {
            return Err("fleet.center: no host; expected https://center.lab:8760".into());
        }
        if !u.username().is_empty() || u.password().is_some() {
            return Err(
                "fleet.center: no credentials in the URL; the station's secret is fleet.token"
                    .into(),
            );
        }
        check_secret("fleet.token", &self.token)?;
        check_station_id("fleet.station_id", &self.station_id)?;
        if !(1..=1000).contains(&self.batch_items) {
            return Err(format!(
                "fleet.batch_items must be in 1..=1000, got {}",
                self.batch_items
            ));
        }
        let r = self.retry_max_s;
        if !(r.is_finite() && (1.0..=3600.0).contains(&r)) {
            return Err(format!("fleet.retry_max_s must be in [1, 3600] s, got {r}"));
        }
        let p = self.recipe_poll_s;
        if !(p.is_finite() && (5.0..=86400.0).contains(&p)) {
            return Err(format!(
                "fleet.recipe_poll_s must be in [5, 86400] s, got {p}"
            ));
        }
        Ok(())
    }
}

/// A PostgreSQL URL as sqlx takes it; `key` names the configuration key.
fn check_postgres_url(key: &str, s: &str) -> Result<(), String> {
    let u = url::Url::parse(s).map_err(|e| {
        format!("{key}: not a URL ({e}); expected postgres://user@host:5432/database")
    })?;
    if !matches!(u.scheme(), "postgres" | "postgresql") {
        return Err(format!(
            "{key}: scheme '{}' is not PostgreSQL; expected postgres://user@host:5432/database",
            u.scheme()
        ));
    }
    let socket = u.query_pairs().any(|(k, _)| k == "host");
    if u.host_str().is_none_or(str::is_empty) && !socket {
        return Err(format!(
            "{key}: no host; expected postgres://user@host:5432/database"
        ));
    }
    if u.path().trim_start_matches('/').is_empty() {
        return Err(format!(
            "{key}: no database name; expected postgres://user@host:5432/database"
        ));
    }
    Ok(())
}

/// A database URL fit for a log line or an error: the password replaced.
pub fn redact_url_password(s: &str) -> String {
    match url::Url::parse(s) {
        Ok(mut u) => {
            if u.password().is_some() {
                let _ = u.set_password(Some("redacted"));
            }
            u.to_string()
        }
        Err(_) => "<not a URL>".to_string(),
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
    fn virtual_table_is_checked_and_belongs_to_a_virtual_bench() {
        let ok = Config::parse(
            "[[benches]]\nid = \"a\"\n[benches.virtual]\npaced = true\nlaser_gain_error = 0.002\nclamp_mass_kg = -0.0001",
        )
        .unwrap();
        let v = ok.benches[0].virtual_.unwrap();
        assert!(v.paced);
        assert_eq!((v.laser_gain_error, v.clamp_mass_kg), (0.002, -0.0001));
        for (table, field) in [
            ("laser_gain_error = 0.2", "laser_gain_error"),
            ("clamp_mass_kg = 0.5", "clamp_mass_kg"),
            ("gain = 1.0", "gain"),
        ] {
            let e = Config::parse(&format!(
                "[[benches]]\nid = \"a\"\n[benches.virtual]\n{table}"
            ))
            .unwrap_err();
            assert!(e.contains(field), "{e}");
        }
        let e = Config::parse(
            "[[benches]]\nid = \"a\"\nkind = \"hardware\"\n[benches.virtual]\npaced = true",
        )
        .unwrap_err();
        assert!(e.contains("[benches."), "{e}");
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
    fn the_shipped_fleet_configs_do_not_start_until_their_placeholders_are_replaced() {
        let station = include_str!("../deploy/fleet-station.toml");
        let center = include_str!("../deploy/fleet-center.toml");
        // As shipped: refused, naming the first key with a placeholder.
        let e = Config::parse(station).unwrap_err();
        assert!(
            e.contains("placeholder") && e.contains("fleet.token"),
            "{e}"
        );
        let e = Config::parse(center).unwrap_err();
        assert!(
            e.contains("placeholder") && e.contains("stations[line-3].token"),
            "{e}"
        );
        // With every placeholder replaced: valid.
        let mut n = 0;
        let fill = |t: &str, n: &mut usize| {
            let mut out = String::new();
            for (i, part) in t.split("<your secret, 16+ characters>").enumerate() {
                if i > 0 {
                    *n += 1;
                    out.push_str(&format!("k3y-{i}-9f2c71ab04d8e6"));
                }
                out.push_str(part);
            }
            out
        };
        let s = Config::parse(&fill(station, &mut n)).expect("deploy/fleet-station.toml is valid");
        let f = s.fleet.unwrap();
        assert_eq!(f.station_id, "line-3");
        assert!(f.center.starts_with("https://"));
        let c = Config::parse(&fill(center, &mut n)).expect("deploy/fleet-center.toml is valid");
        assert!(c.is_fleet_role() && c.benches.is_empty());
        assert!(c.stations.iter().any(|s| s.station_id == "line-3"));
        assert!(n >= 3, "{n}");
    }

    #[test]
    fn placeholder_and_weak_secrets_are_refused_naming_the_key() {
        for (secret, needle) in [
            ("<your secret, 16+ characters>", "placeholder"),
            ("change-me-please-0001", "placeholder"),
            ("aaaaaaaaaaaaaaaaaaaa", "weak"),
            ("abababababababababab", "weak"),
            ("short-1", "16 characters"),
        ] {
            let e = Config::parse(&format!(
                "[fleet]\ncenter = \"https://center.lab:8760\"\nstation_id = \"line-3\"\ntoken = \"{secret}\""
            ))
            .unwrap_err();
            assert!(
                e.contains("fleet.token") && e.contains(needle),
                "{secret}: {e}"
            );
            let e = Config::parse(&format!(
                "database = \"postgres://sb@h/db\"\nbenches = []\n[[stations]]\nstation_id = \"line-4\"\ntoken = \"{secret}\""
            ))
            .unwrap_err();
            assert!(
                e.contains("stations[line-4].token") && e.contains(needle),
                "{secret}: {e}"
            );
            let e = Config::parse(&format!(
                "[[auth.tokens]]\nname = \"qe\"\ntoken = \"{secret}\"\nrole = \"viewer\""
            ))
            .unwrap_err();
            assert!(e.contains("'qe'"), "{secret}: {e}");
        }
    }

    #[test]
    fn fleet_keys_are_checked_with_one_line_each() {
        const T: &str = "token = \"s3cret-line-3-0123456789\"";
        let station = Config::parse(&format!(
            "[fleet]\ncenter = \"https://center.lab:8760\"\nstation_id = \"line-3\"\nrecordings = \"reference\"\n{T}"
        ))
        .unwrap();
        let f = station.fleet.as_ref().unwrap();
        assert_eq!(f.station_id, "line-3");
        assert_eq!(f.recordings, RecordingsPolicy::Reference);
        assert_eq!((f.batch_items, f.retry_max_s), (50, 30.0));
        assert!(!station.is_fleet_role());
        let center = Config::parse(&format!(
            "database = \"postgres://sb@center.lab/springbench\"\nbenches = []\n[[stations]]\nstation_id = \"line-3\"\n{T}"
        ))
        .unwrap();
        assert!(center.is_fleet_role());
        for (text, needle) in [
            ("database = \"postgres://sb@h/db\"".to_string(), "benches = []"),
            ("benches = []".into(), "at least one [[benches]]"),
            ("database = \"mysql://h/db\"\nbenches = []".into(), "scheme 'mysql'"),
            ("database = \"postgres://sb@h\"\nbenches = []".into(), "no database name"),
            (format!("[fleet]\ncenter = \"https://h\"\nstation_id = \"line 3\"\n{T}"), "fleet.station_id"),
            (format!("[fleet]\ncenter = \"sqlite://x\"\nstation_id = \"a\"\n{T}"), "fleet.center"),
            // The center's database is no station's business any more.
            (format!("[fleet]\ncenter = \"postgres://sb@h/db\"\nstation_id = \"a\"\n{T}"), "decision 0105"),
            (format!("[fleet]\ncenter = \"https://u:p@h\"\nstation_id = \"a\"\n{T}"), "fleet.token"),
            ("[fleet]\ncenter = \"https://h\"\nstation_id = \"a\"".into(), "token"),
            (format!("[fleet]\ncenter = \"https://h\"\nstation_id = \"a\"\nrecordings = \"some\"\n{T}"), "some"),
            (format!("[fleet]\ncenter = \"https://h\"\nstation_id = \"a\"\nretry_max_s = 0\n{T}"), "fleet.retry_max_s"),
            (format!("[fleet]\ncenter = \"https://h\"\nstation_id = \"a\"\nbatch_items = 0\n{T}"), "fleet.batch_items"),
            ("[fleet]\nstation_id = \"a\"".into(), "center"),
            (format!("database = \"postgres://h/db\"\nbenches = []\n[fleet]\ncenter = \"https://h\"\nstation_id = \"a\"\n{T}"), "station's table"),
            (format!("[[stations]]\nstation_id = \"a\"\n{T}"), "fleet role's table"),
            (format!("database = \"postgres://h/db\"\nbenches = []\n[[stations]]\nstation_id = \"a\"\n{T}\n[[stations]]\nstation_id = \"b\"\ntoken = \"s3cret-line-4-0123456789\"\nformer_ids = [\"a\"]"), "given twice"),
        ] {
            let e = Config::parse(&text).unwrap_err();
            assert!(e.contains(needle), "{text}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        // The password never appears in an error.
        let e = Config::parse("database = \"postgres://sb:hunter22@h/db\"").unwrap_err();
        assert!(!e.contains("hunter22") && e.contains("redacted"), "{e}");
        // A Unix-socket URL (host in the query) is a URL sqlx takes.
        Config::parse("database = \"postgres://sb@localhost:55432/db?host=/tmp/pg\"\nbenches = []")
            .unwrap();
    }

    #[test]
    fn roles_are_ordered() {
        assert!(Role::Viewer < Role::Operator && Role::Operator < Role::Admin);
    }
}
