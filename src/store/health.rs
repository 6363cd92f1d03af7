//! Storage faults: a lost or replaced database file, a full disk.
//!
//! - Identity: the database file's (device, inode) is recorded at open; every
//!   connection is checked against it when the pool hands it out or opens
//!   it. A deleted or replaced file makes every query fail (the API answers
//!   503, `/readyz` is not ready) instead of writing into an unlinked inode
//!   whose contents vanish at the next start. The pool never creates a new
//!   file by itself.
//! - Rescue: when the file was deleted, a watchdog writes the still-open
//!   database back to its path (`VACUUM INTO`, a consistent copy of every
//!   committed transaction), adopts the new file's identity and retires every
//!   pooled connection opened before (they point at the old inode), so no
//!   connection serves a stale view. A replaced file is never overwritten:
//!   the store stays unavailable until the operator restarts the daemon.
//! - Writability: `/readyz` commits a one-row write (the `store_probe`
//!   table); a full disk makes it fail, so the daemon is not ready while
//!   writes cannot be kept. Writes that fail with SQLITE_FULL / I/O errors
//!   are answered 503 ([`super::StoreError::is_unavailable`]), never
//!   acknowledged.

use super::{now, Store, StoreResult};
use sqlx::sqlite::SqliteConnectOptions;
use sqlx::{ConnectOptions, Connection};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The database file as it was opened, and when connections were last retired.
#[derive(Debug)]
pub struct FileGuard {
    path: PathBuf,
    ident: Mutex<(u64, u64)>,
    started: Instant,
    /// Connections older than `started.elapsed() - this` (ms) are retired.
    retired_before_ms: AtomicU64,
}

fn ident(path: &Path) -> std::io::Result<(u64, u64)> {
    let m = std::fs::metadata(path)?;
    Ok((m.dev(), m.ino()))
}

impl FileGuard {
    pub fn new(path: &Path) -> std::io::Result<Arc<FileGuard>> {
        Ok(Arc::new(FileGuard {
            path: path.to_path_buf(),
            ident: Mutex::new(ident(path)?),
            started: Instant::now(),
            retired_before_ms: AtomicU64::new(0),
        }))
    }

    /// Ok when the path still names the file the store opened.
    pub fn check(&self) -> Result<(), String> {
        match ident(&self.path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(format!(
                "the database file {} was deleted",
                self.path.display()
            )),
            Err(e) => Err(format!("database file {}: {e}", self.path.display())),
            Ok(i) if i != *self.ident.lock().unwrap() => Err(format!(
                "the database file {} was replaced by another file; restart the daemon",
                self.path.display()
            )),
            Ok(_) => Ok(()),
        }
    }

    fn deleted(&self) -> bool {
        matches!(ident(&self.path), Err(e) if e.kind() == std::io::ErrorKind::NotFound)
    }

    /// The pool's check when it hands out a connection of age `age`.
    pub fn usable(&self, age: Duration) -> Result<bool, sqlx::Error> {
        self.check()
            .map_err(|m| sqlx::Error::Io(std::io::Error::other(m)))?;
        let since_start = self.started.elapsed().as_millis() as u64;
        let retire = self.retired_before_ms.load(Ordering::SeqCst);
        // opened before the last rescue: points at the old inode
        Ok(since_start.saturating_sub(age.as_millis() as u64) >= retire)
    }

    pub fn connect_check(&self) -> Result<(), sqlx::Error> {
        self.check()
            .map_err(|m| sqlx::Error::Io(std::io::Error::other(m)))
    }
}

/// Writes the database a rescue connection still has open back to `path`,
/// when the file was deleted. Runs every second until the store is closed.
pub fn spawn_watchdog(guard: Arc<FileGuard>, opts: SqliteConnectOptions) {
    tokio::spawn(async move {
        // a connection of our own, to the file as opened
        let mut rescue = match opts.clone().connect().await {
            Ok(c) => c,
            Err(e) => {
                tracing::error!("database watchdog: {e}");
                return;
            }
        };
        let mut missing_ticks = 0;
        loop {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if !guard.deleted() {
                missing_ticks = 0;
                continue;
            }
            // missing for a second at least (a file being moved back is not rescued)
            missing_ticks += 1;
            if missing_ticks < 2 {
                continue;
            }
            missing_ticks = 0;
            tracing::error!(
                "the database file {} was deleted while the daemon runs: refusing writes, writing it back",
                guard.path.display()
            );
            let tmp = guard.path.with_extension("db.rescue");
            let _ = std::fs::remove_file(&tmp);
            // VACUUM INTO takes an expression: the path is a bound parameter.
            let res = sqlx::query("VACUUM INTO ?")
                .bind(tmp.display().to_string())
                .execute(&mut rescue)
                .await;
            let res = match res {
                Ok(_) => std::fs::rename(&tmp, &guard.path).map_err(|e| e.to_string()),
                Err(e) => Err(e.to_string()),
            };
            match res {
                Ok(()) => {
                    if let Ok(i) = ident(&guard.path) {
                        *guard.ident.lock().unwrap() = i;
                    }
                    guard.retired_before_ms.store(
                        guard.started.elapsed().as_millis() as u64 + 1,
                        Ordering::SeqCst,
                    );
                    let _ = rescue.close().await;
                    rescue = match opts.clone().connect().await {
                        Ok(c) => c,
                        Err(e) => {
                            tracing::error!("database watchdog: {e}");
                            return;
                        }
                    };
                    tracing::warn!(
                        "the database file {} was written back from the open database; every committed result is in it",
                        guard.path.display()
                    );
                }
                Err(e) => {
                    tracing::error!("writing the database back failed: {e}; retrying");
                    let _ = std::fs::remove_file(&tmp);
                }
            }
        }
    });
}

impl Store {
    /// Commits a one-row write: fails on a full disk, a read-only or lost file.
    pub async fn probe_write(&self) -> StoreResult<()> {
        sqlx::query("INSERT OR REPLACE INTO store_probe (id, at) VALUES (1, ?)")
            .bind(now())
            .execute(&self.pool)
            .await?;
        Ok(())
    }
}

impl super::StoreError {
    /// The store cannot keep data right now (full disk, lost or read-only
    /// file, I/O error): the request may succeed later (HTTP 503).
    pub fn is_unavailable(&self) -> bool {
        match self {
            super::StoreError::Db(e) => match e {
                sqlx::Error::Io(_) | sqlx::Error::PoolTimedOut | sqlx::Error::PoolClosed => true,
                sqlx::Error::Database(d) => {
                    let code: i64 = d.code().and_then(|c| c.parse().ok()).unwrap_or(0);
                    // SQLITE_READONLY 8, IOERR 10, FULL 13, CANTOPEN 14, NOTADB 26
                    matches!(code & 0xff, 8 | 10 | 13 | 14 | 26)
                }
                _ => false,
            },
            _ => false,
        }
    }
}

/// Bytes available to this process on the file system of `dir` (statvfs).
pub fn free_bytes(dir: &Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes())
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a valid NUL-terminated path and `s` a valid out-pointer.
    if unsafe { libc::statvfs(c.as_ptr(), &mut s) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(s.f_bavail as u64 * s.f_frsize as u64)
}

impl Store {
    /// The store's directory has at least `min` bytes free (a job's results
    /// need room; refusing up front beats failing after the measurement).
    pub fn check_space(&self, min: u64) -> StoreResult<()> {
        let Some(dir) = self.dir.as_deref() else {
            return Ok(());
        };
        match free_bytes(dir) {
            Ok(free) if free < min => Err(super::StoreError::Db(sqlx::Error::Io(
                std::io::Error::other(format!(
                    "disk full: {free} bytes free in {}, at least {min} needed (min_free_bytes)",
                    dir.display()
                )),
            ))),
            _ => Ok(()),
        }
    }
}
