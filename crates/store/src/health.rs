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
use sqlx::sqlite::{SqliteConnectOptions, SqlitePool};
use sqlx::Row;
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

/// Whether a connection handed back to the pool may serve again: not when it
/// is still inside a transaction, by sqlx's count or by SQLite's own state
/// (a COMMIT or ROLLBACK that failed). A dropped transaction's ROLLBACK is
/// queued on the connection's worker; the round trip first lets it run.
pub async fn reusable(conn: &mut sqlx::SqliteConnection) -> Result<bool, sqlx::Error> {
    conn.ping().await?;
    if conn.is_in_transaction() {
        tracing::warn!("a database connection is still inside a transaction (a failed COMMIT or ROLLBACK): closed, not pooled");
        return Ok(false);
    }
    let mut h = conn.lock_handle().await?;
    // SAFETY: the handle is locked for the duration of this call; the
    // function only reads the connection's autocommit flag.
    let autocommit = unsafe { libsqlite3_sys::sqlite3_get_autocommit(h.as_raw_handle().as_ptr()) };
    if autocommit == 0 {
        tracing::warn!("a database connection is inside an SQLite transaction sqlx does not know of: closed, not pooled");
        return Ok(false);
    }
    Ok(true)
}

/// Writes the database a rescue connection still has open back to `path`,
/// when the file was deleted. Runs every second until the store is closed.
///
/// Connections to the deleted file and to the written-back one must never
/// be open at once: both use the same `-wal` and `-shm` files by name, so a
/// connection to the copy would read the old file's WAL frames (another page
/// layout: "database disk image is malformed") and a checkpoint would write
/// them into it. So: every pooled connection is closed first (the pool opens
/// none while the file is missing), the copy is taken, the rescue connection
/// closed (SQLite then folds and removes the old WAL), and only then is the
/// copy renamed into place.
pub fn spawn_watchdog(guard: Arc<FileGuard>, opts: SqliteConnectOptions, pool: SqlitePool) {
    tokio::spawn(async move {
        // a connection of our own, to the file as opened
        let mut rescue = match opts.clone().connect().await {
            Ok(c) => Some(c),
            Err(e) => {
                tracing::error!("database watchdog: {e}");
                return;
            }
        };
        let tmp = guard.path.with_extension("db.rescue");
        let mut missing_ticks = 0;
        loop {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if pool.is_closed() {
                return;
            }
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
            if let Some(conn) = rescue.take() {
                tracing::error!(
                    "the database file {} was deleted while the daemon runs: refusing writes, writing it back",
                    guard.path.display()
                );
                match copy_out(conn, &pool, &tmp).await {
                    Ok(()) => {}
                    Err((conn, e)) => {
                        tracing::error!("writing the database back failed: {e}; retrying");
                        let _ = std::fs::remove_file(&tmp);
                        rescue = Some(conn);
                        continue;
                    }
                }
            }
            // The copy holds every committed transaction and no connection to
            // the old file is open: the old WAL must not meet the copy.
            for ext in ["db-wal", "db-shm"] {
                let _ = std::fs::remove_file(guard.path.with_extension(ext));
            }
            if let Err(e) = std::fs::rename(&tmp, &guard.path) {
                // the data is in the copy; tried again next second
                tracing::error!(
                    "moving {} to {} failed: {e}; retrying",
                    tmp.display(),
                    guard.path.display()
                );
                continue;
            }
            if let Ok(i) = ident(&guard.path) {
                *guard.ident.lock().unwrap() = i;
            }
            guard.retired_before_ms.store(
                guard.started.elapsed().as_millis() as u64 + 1,
                Ordering::SeqCst,
            );
            rescue = match opts.clone().connect().await {
                Ok(c) => Some(c),
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
    });
}

/// Closes every pooled connection (waiting up to 10 s for those in use),
/// copies the database `conn` has open into `tmp` and closes `conn`. On an
/// error `conn` is handed back, still open (the only way to the data).
async fn copy_out(
    mut conn: sqlx::SqliteConnection,
    pool: &SqlitePool,
    tmp: &Path,
) -> Result<(), (sqlx::SqliteConnection, String)> {
    let t = Instant::now();
    loop {
        while let Some(c) = pool.try_acquire() {
            c.close().await.ok();
        }
        if pool.size() == 0 {
            break;
        }
        if t.elapsed() > Duration::from_secs(10) {
            return Err((
                conn,
                format!("{} database connections still in use", pool.size()),
            ));
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let _ = std::fs::remove_file(tmp);
    // VACUUM INTO takes an expression: the path is a bound parameter.
    if let Err(e) = sqlx::query("VACUUM INTO ?")
        .bind(tmp.display().to_string())
        .execute(&mut conn)
        .await
    {
        return Err((conn, e.to_string()));
    }
    if let Err(e) = std::fs::File::open(tmp).and_then(|f| f.sync_all()) {
        return Err((conn, format!("{}: {e}", tmp.display())));
    }
    if let Err(e) = conn.close().await {
        // the copy is complete; the old file's WAL is removed by the caller
        tracing::warn!("closing the rescue connection: {e}");
    }
    Ok(())
}

impl Store {
    /// Commits a one-row write: fails on a full disk, a read-only or lost file.
    pub async fn probe_write(&self) -> StoreResult<()> {
        sqlx::query("INSERT OR REPLACE INTO store_probe (id, at) VALUES (1, ?)")
            .bind(now())
            .execute(&mut *self.writer().await?)
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

/// Bytes a measurement is assumed to take before any is stored (pre and
/// main recordings as FLAC and the result; measured ones are 1-3 MB).
pub const DEFAULT_MEASUREMENT_BYTES: u64 = 8 << 20;

impl Store {
    /// Bytes one bench measurement takes in the store: the mean of the
    /// newest 20 (pre and main recording and result), twice over (a write
    /// goes through the WAL before the checkpoint copies it into the file).
    pub async fn measurement_bytes(&self) -> StoreResult<u64> {
        let r = sqlx::query(
            "SELECT AVG(b), COUNT(*) FROM (SELECT COALESCE(length(p.wav), 0) + COALESCE(length(x.wav), 0) \
             + COALESCE(length(m.result_json), 0) AS b FROM measurements m \
             JOIN recordings p ON p.id = m.pre_recording_id JOIN recordings x ON x.id = m.main_recording_id \
             WHERE m.source = 'bench' AND p.pruned_at IS NULL AND x.pruned_at IS NULL ORDER BY m.seq DESC LIMIT 20)",
        )
        .fetch_one(&self.pool)
        .await?;
        let n: i64 = r.get(1);
        let mean: Option<f64> = r.get(0);
        Ok(match mean {
            Some(b) if n > 0 && b.is_finite() && b > 0.0 => 2 * b as u64,
            _ => 2 * DEFAULT_MEASUREMENT_BYTES,
        })
    }

    /// Measurements the queued and running jobs will still store (levels x repeats each).
    pub async fn pending_measurements(&self) -> StoreResult<u64> {
        let r = sqlx::query(
            "SELECT COALESCE(SUM(MAX(1, COALESCE(json_array_length(request_json, '$.levels_m'), 1)) \
             * MAX(1, COALESCE(json_extract(request_json, '$.repeats'), 1))), 0) FROM jobs WHERE state IN ('queued', 'running')",
        )
        .fetch_one(&self.pool)
        .await?;
        Ok(r.get::<i64, _>(0).max(0) as u64)
    }

    /// Admission of a job of `measurements` measurements: the free space
    /// must hold `min` bytes plus what the queued and running jobs and this
    /// one will store, so the daemon never acknowledges work it cannot keep.
    pub async fn check_admission(&self, min: u64, measurements: u64) -> StoreResult<()> {
        if self.dir.is_none() {
            return Ok(());
        }
        let per = self.measurement_bytes().await?;
        let queued = self.pending_measurements().await?;
        let need = (queued + measurements).saturating_mul(per);
        self.check_space(min.saturating_add(need)).map_err(|_| {
            let free = self
                .dir
                .as_deref()
                .and_then(|d| free_bytes(d).ok())
                .unwrap_or(0);
            super::StoreError::Db(sqlx::Error::Io(std::io::Error::other(format!(
                "disk full for the queue: {free} bytes free; the {queued} measurements of the queued and running jobs \
                 and this job's {measurements} need about {need} bytes ({per} each) besides min_free_bytes {min}"
            ))))
        })
    }

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

#[cfg(test)]
mod tests {
    use super::super::{Inserted, Store};
    use sqlx::Row;
    use std::time::{Duration, Instant};

    async fn integrity(s: &Store) -> Result<(i64, String), sqlx::Error> {
        let n: i64 = sqlx::query("SELECT COUNT(*) FROM jobs")
            .fetch_one(&s.pool)
            .await?
            .get(0);
        let ok: String = sqlx::query("PRAGMA integrity_check")
            .fetch_one(&s.pool)
            .await?
            .get(0);
        Ok((n, ok))
    }

    /// The file deleted while committed pages are still in the WAL (not yet
    /// checkpointed). The rescued copy has another page layout than the
    /// deleted file; connections opened on it must not read the old file's
    /// WAL frames (they did: "database disk image is malformed", seen in CI
    /// as a 500 while the daemon wrote the file back).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn rescued_file_is_not_read_through_the_old_wal() {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        let s = Store::open(&data).await.unwrap();
        // Rows with bodies that span pages, in the WAL: a deleted job's
        // pages make the copy's layout differ (VACUUM compacts).
        let notes = "n".repeat(3000);
        for i in 0..120 {
            let serial = format!("SN-{i}");
            let req =
                springbench_core::job::StoredRequest::SelfCheck(springbench_core::job::SelfCheck {
                    bench: format!("b1-{i}"),
                });
            let r = s
                .insert_job(
                    &format!("j{i}"),
                    "b1",
                    (&serial, None, Some(&notes)),
                    0,
                    &req,
                    &format!("h{i}"),
                    None,
                )
                .await
                .unwrap();
            assert!(matches!(r, Inserted::New(_)));
        }
        sqlx::query("DELETE FROM jobs WHERE id LIKE 'j1%'")
            .execute(&s.pool)
            .await
            .unwrap();
        let wal = data.join("springbench.db-wal");
        assert!(std::fs::metadata(&wal).unwrap().len() > 0, "no WAL frames");
        let (before, _) = integrity(&s).await.unwrap();
        std::fs::remove_file(data.join("springbench.db")).unwrap();
        let t = Instant::now();
        while !data.join("springbench.db").exists() {
            assert!(t.elapsed() < Duration::from_secs(20), "never written back");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // Every query from here (retired and new connections) answers right
        // or refuses (unavailable); none reads garbage.
        let t = Instant::now();
        let mut answered = 0;
        while t.elapsed() < Duration::from_secs(3) {
            match integrity(&s).await {
                Ok((n, ok)) => {
                    assert_eq!((n, ok.as_str()), (before, "ok"));
                    answered += 1;
                }
                Err(e) => {
                    let e = super::super::StoreError::Db(e);
                    assert!(e.is_unavailable(), "{e}");
                }
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(answered > 0, "never usable again after the rescue");
        // a write on the rescued file, then a restart: everything is there
        let r = s
            .insert_job(
                "after",
                "b1",
                ("SN-A", None, None),
                0,
                &springbench_core::job::StoredRequest::SelfCheck(
                    springbench_core::job::SelfCheck { bench: "b1".into() },
                ),
                "ha",
                None,
            )
            .await
            .unwrap();
        assert!(matches!(r, Inserted::New(_)));
        s.pool.close().await;
        drop(s);
        let s = Store::open(&data).await.unwrap();
        assert_eq!(integrity(&s).await.unwrap(), (before + 1, "ok".to_string()));
    }
}
