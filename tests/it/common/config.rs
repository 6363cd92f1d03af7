//! A typed builder of the daemon's TOML configuration for the tests: tokens
//! are the daemon's own `config::Token` (a renamed field or role is a compile
//! error here, not a daemon that refuses its config at start), benches are
//! named with their noise seed, and whatever has no method yet is appended
//! as TOML with [`Config::toml`]. `Daemon::start(&cfg.text())` runs it.

use springbench::config::{Role, Token};

/// The tokens most tests use, one for each role.
pub const VIEWER: &str = "viewer-token-0123456789";
pub const OPERATOR: &str = "operator-token-0123456789";
pub const ADMIN: &str = "admin-token-0123456789";

#[derive(Default, Clone)]
pub struct Config {
    top: String,
    tokens: Vec<Token>,
    benches: Vec<(String, u64)>,
    extra: String,
}

#[derive(serde::Serialize)]
struct Auth<'a> {
    tokens: &'a [Token],
}

#[derive(serde::Serialize)]
struct Head<'a> {
    auth: Auth<'a>,
}

impl Config {
    pub fn new() -> Config {
        Config::default()
    }

    /// A bearer token `secret` named `name` with `role`.
    pub fn token(mut self, name: &str, secret: &str, role: Role) -> Config {
        self.tokens.push(Token {
            name: name.to_string(),
            token: secret.to_string(),
            role,
        });
        self
    }

    /// [`VIEWER`], [`OPERATOR`] and [`ADMIN`], named `viewer`, `operator`, `admin`.
    pub fn roles() -> Config {
        Config::new()
            .token("viewer", VIEWER, Role::Viewer)
            .token("operator", OPERATOR, Role::Operator)
            .token("admin", ADMIN, Role::Admin)
    }

    /// A virtual bench `id` whose first job has noise seed `seed`.
    pub fn bench(mut self, id: &str, seed: u64) -> Config {
        self.benches.push((id.to_string(), seed));
        self
    }

    /// The two virtual benches of the QC tests: `virtual-1` (seed 1) and
    /// `virtual-2` (seed 1001).
    pub fn two_benches(self) -> Config {
        self.bench("virtual-1", 1).bench("virtual-2", 1001)
    }

    /// Top-level keys, as TOML (written before every table).
    pub fn top(mut self, text: &str) -> Config {
        self.top.push_str(text);
        self.top.push('\n');
        self
    }

    /// More configuration, as TOML tables (written after the tokens and
    /// benches; top-level keys go in [`Config::top`]).
    pub fn toml(mut self, text: &str) -> Config {
        self.extra.push_str(text);
        self.extra.push('\n');
        self
    }

    /// The TOML text (what `Daemon::start` appends to its bind address and data directory).
    pub fn text(&self) -> String {
        let mut out = self.top.clone();
        if !self.tokens.is_empty() {
            let head = Head {
                auth: Auth {
                    tokens: &self.tokens,
                },
            };
            out.push_str(&toml::to_string(&head).expect("tokens as TOML"));
        }
        for (id, seed) in &self.benches {
            out.push_str(&format!("[[benches]]\nid = \"{id}\"\nseed = {seed}\n"));
        }
        out.push_str(&self.extra);
        out
    }
}

#[test]
fn the_builder_writes_what_the_daemon_reads() {
    let text = Config::roles()
        .two_benches()
        .toml("[mes]\nhandle = \"line-3\"")
        .text();
    let c: springbench::config::Config =
        toml::from_str(&format!("bind = \"127.0.0.1:0\"\n{text}")).expect("a valid config");
    assert_eq!(c.auth.tokens.len(), 3);
    assert_eq!(c.auth.tokens[1].role, Role::Operator);
    assert_eq!(c.auth.tokens[2].token, ADMIN);
    assert_eq!(c.benches.len(), 2);
    assert_eq!(
        (c.benches[1].id.as_str(), c.benches[1].seed),
        ("virtual-2", 1001)
    );
    assert_eq!(c.mes.handle, "line-3");
}
