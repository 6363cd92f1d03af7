//! PostgreSQL for tests: a private server in a temporary directory
//! (`.ci/pg`, Debian's packages), or the one `.ci/run` started
//! (`SPRINGBENCH_PG_URL`).
//!
//! `SPRINGBENCH_PG_TESTS=require` (set by `.ci/run`) makes a missing server
//! a failure; otherwise a PostgreSQL test prints why it skips and passes, so
//! a plain `cargo test` needs no server.

use std::io;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The script that starts and stops a private server (one source for CI,
/// developers and these tests).
fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.ci/pg")
}

/// A private PostgreSQL server in a temporary directory, on a Unix socket
/// in that directory (no TCP: it disturbs nothing else on the machine).
/// [`TestServer::stop`] is a real outage (`pg_ctl stop -m immediate`);
/// [`TestServer::start_again`] brings the same database back on the same
/// URL. Dropped, it stops and its directory is removed.
pub struct TestServer {
    dir: tempfile::TempDir,
    port: u16,
    running: bool,
}

impl TestServer {
    /// Creates and starts a server (`port` only names its socket file).
    pub fn start(port: u16) -> io::Result<TestServer> {
        let dir = tempfile::Builder::new().prefix("sb-pg-").tempdir()?;
        // The server runs as `postgres` when we are root: it must reach the directory.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755))?;
        }
        let mut s = TestServer {
            dir,
            port,
            running: false,
        };
        s.start_again()?;
        Ok(s)
    }

    fn data(&self) -> PathBuf {
        self.dir.path().join("pg")
    }

    fn run(&self, args: &[&str]) -> io::Result<String> {
        let out = Command::new(script())
            .args(args)
            .arg(self.data())
            .arg(self.port.to_string())
            .output()?;
        if !out.status.success() {
            return Err(io::Error::other(format!(
                ".ci/pg {}: {}",
                args.join(" "),
                String::from_utf8_lossy(&out.stderr).trim()
            )));
        }
        Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
    }

    /// (Re)starts the server on its directory and port.
    pub fn start_again(&mut self) -> io::Result<()> {
        if !self.running {
            self.run(&["start"])?;
            self.running = true;
        }
        Ok(())
    }

    /// Stops the server at once (clients see their connections cut).
    pub fn stop(&mut self) -> io::Result<()> {
        if self.running {
            self.run(&["stop"])?;
            self.running = false;
        }
        Ok(())
    }

    /// `postgres://sb@localhost:PORT/postgres?host=DIR`.
    pub fn url(&self) -> String {
        format!(
            "postgres://sb@localhost:{}/postgres?host={}",
            self.port,
            self.data().display()
        )
    }

    /// The server's Unix socket (a test's proxy forwards to it).
    pub fn socket(&self) -> PathBuf {
        self.data().join(format!(".s.PGSQL.{}", self.port))
    }

    pub fn is_running(&self) -> bool {
        self.running
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

/// Whether PostgreSQL tests must run (`SPRINGBENCH_PG_TESTS=require`).
pub fn required() -> bool {
    std::env::var("SPRINGBENCH_PG_TESTS").as_deref() == Ok("require")
}

/// The server the tests use: `SPRINGBENCH_PG_URL` when set; None (after
/// printing why) when there is none and it is not required; a panic when
/// it is required.
pub fn url_or_skip(test: &str) -> Option<String> {
    match std::env::var("SPRINGBENCH_PG_URL") {
        Ok(u) if !u.is_empty() => Some(u),
        _ if required() => panic!(
            "{test}: SPRINGBENCH_PG_TESTS=require but SPRINGBENCH_PG_URL is not set \
             (.ci/run starts a server with .ci/pg)"
        ),
        _ => {
            say(&format!(
                "{test}: skipped: no PostgreSQL (set SPRINGBENCH_PG_URL, e.g. from \
                 `.ci/pg start /tmp/sb-pg`; .ci/run does it and sets SPRINGBENCH_PG_TESTS=require)"
            ));
            None
        }
    }
}

/// Whether a private server can be started here (Debian's binaries);
/// prints why not and panics when required.
pub fn can_start_private(test: &str) -> bool {
    let found = std::fs::read_dir("/usr/lib/postgresql")
        .map(|d| d.flatten().any(|e| e.path().join("bin/pg_ctl").exists()))
        .unwrap_or(false)
        || std::env::var_os("PG_BIN").is_some();
    if !found {
        if required() {
            panic!("{test}: SPRINGBENCH_PG_TESTS=require but no PostgreSQL binaries (apt-get install postgresql)");
        }
        say(&format!(
            "{test}: skipped: no PostgreSQL server binaries (apt-get install postgresql)"
        ));
    }
    found
}

/// Straight to stderr: the test harness does not capture it, so a plain
/// `cargo test` shows why a PostgreSQL test passed without running.
fn say(msg: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{msg}");
}

/// A fresh schema name for one test: `t_<test>_<random>`.
pub fn fresh_schema(test: &str) -> String {
    let tag: String = test
        .chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .take(20)
        .collect::<String>()
        .to_ascii_lowercase();
    format!(
        "t_{tag}_{}",
        &uuid::Uuid::new_v4().simple().to_string()[..12]
    )
}
