//! SQLite storage (sqlx): parts, jobs, measurements, recordings, events.
//!
//! WAL journal with `synchronous = FULL`: a transaction that has committed
//! survives a crash or a power cut. Results are written in one transaction
//! (recordings, measurements, job state), so a finished result is either
//! entirely there or not at all. Queries are runtime-checked (`sqlx::query`),
//! the schema lives in `migrations/`.

mod blob;
pub mod corrections;
mod derived;
mod events;
mod fits;
pub mod fleet;
mod gauge;
pub mod hardware;
pub mod health;
mod imports;
mod jobs;
pub mod longterm;
pub mod longterm_view;
mod measurements;
pub mod migrations;
pub mod outbox;
mod parts;
pub mod qc;
mod raw;
mod replication;
pub mod results;
pub mod stimuli;
pub mod studies;

pub use blob::BlobRef;
pub use derived::Derived;
pub use events::Event;
pub use fleet::{
    CenterIngest, IngestReport, ItemBody, MeasurementItem, ReplicationItem, StationHello,
    StationStatus,
};
pub use gauge::{BenchCalibrationRow, GaugeStudyRow};
pub use imports::{ImportInserted, RecordingFile};
pub use jobs::{Inserted, Job, JobRequestRow, JobState};
pub use raw::{dir_bytes, BlobReader, RecordingInfo, Retention, RetentionReport, StoredRecording};
pub use results::{
    Doc, FinishedMeasurement, Fit, FitReads, HeadlineChoice, MeasurementInfo, MeasurementReads,
    NewMeasurement, NewRecording, Part, PartReads, RecipeReads, ResultIngest, ResultStore,
    StoredMeasurement, Upserted, VerdictReads,
};

use serde_json::Value;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteSynchronous,
};
use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

pub type StoreResult<T> = Result<T, StoreError>;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Db(#[from] sqlx::Error),
    #[error("database migration: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("{0}")]
    Corrupt(String),
    /// Data handed to the store that contradicts itself (nothing was written).
    #[error("{0}")]
    Invalid(String),
}

/// Current time as RFC 3339 UTC with milliseconds.
pub fn now() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

#[derive(Clone)]
pub struct Store {
    pool: SqlitePool,
    /// The data directory (None in memory): free-space checks (health.rs).
    dir: Option<std::sync::Arc<std::path::PathBuf>>,
    /// Every write of this process queues here, first come first served,
    /// before it asks SQLite for the write lock ([`Store::begin_write`],
    /// [`Store::writer`]). SQLite's busy handler polls with sleeps of up
    /// to 100 ms and gives the lock to whoever asks when it is free, nearly
    /// always the writer that just let it go: a job submitted while a bench
    /// streamed its progress waited 0.6-1.3 s (decision 0145).
    write_gate: std::sync::Arc<tokio::sync::Mutex<()>>,
}

/// How long a write waits for its turn: SQLite's busy timeout before it.
const WRITE_WAIT: Duration = Duration::from_secs(10);

/// A write transaction (`BEGIN IMMEDIATE`) holding this process's turn to
/// write until it is committed, rolled back or dropped. Derefs to its
/// connection: `.execute(&mut *tx)`.
pub struct WriteTx {
    tx: sqlx::Transaction<'static, sqlx::Sqlite>,
    _turn: tokio::sync::OwnedMutexGuard<()>,
}

impl WriteTx {
    /// Commits; dropped uncommitted, the transaction rolls back.
    pub async fn commit(self) -> Result<(), sqlx::Error> {
        self.tx.commit().await
    }
}

impl std::ops::Deref for WriteTx {
    type Target = sqlx::SqliteConnection;
    fn deref(&self) -> &sqlx::SqliteConnection {
        &self.tx
    }
}

impl std::ops::DerefMut for WriteTx {
    fn deref_mut(&mut self) -> &mut sqlx::SqliteConnection {
        &mut self.tx
    }
}

/// A pooled connection for one autocommit write, holding this process's
/// turn to write while it lives: `.execute(&mut *self.writer().await?)`.
pub struct Writer {
    conn: sqlx::pool::PoolConnection<sqlx::Sqlite>,
    _turn: tokio::sync::OwnedMutexGuard<()>,
}

impl std::ops::Deref for Writer {
    type Target = sqlx::SqliteConnection;
    fn deref(&self) -> &sqlx::SqliteConnection {
        &self.conn
    }
}

impl std::ops::DerefMut for Writer {
    fn deref_mut(&mut self) -> &mut sqlx::SqliteConnection {
        &mut self.conn
    }
}

impl Store {
    /// Opens (creating if missing) `data_dir/springbench.db` and migrates it.
    pub async fn open(data_dir: &Path) -> StoreResult<Store> {
        std::fs::create_dir_all(data_dir).map_err(|e| {
            StoreError::Corrupt(format!("data directory {}: {e}", data_dir.display()))
        })?;
        let path = data_dir.join("springbench.db");
        let opts = SqliteConnectOptions::new()
            .filename(&path)
            .create_if_missing(false)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(SqliteSynchronous::Full)
            .foreign_keys(true)
            // Every write transaction starts with BEGIN IMMEDIATE (the write
            // lock first, waiting up to this timeout): a deferred transaction
            // that reads and then writes fails at once with "database is
            // locked" when another connection wrote in between (WAL snapshot
            // upgrade), whatever the timeout; seen approving a limit proposal
            // while jobs finished.
            .busy_timeout(Duration::from_secs(10));
        // Created here only: the pool never creates a file by itself, so a
        // lost database is not silently replaced by an empty one (health.rs).
        if !path.exists() {
            use sqlx::{ConnectOptions, Connection};
            opts.clone()
                .create_if_missing(true)
                .connect()
                .await?
                .close()
                .await?;
        }
        let guard = health::FileGuard::new(&path)
            .map_err(|e| StoreError::Corrupt(format!("database file {}: {e}", path.display())))?;
        let (g1, g2) = (guard.clone(), guard.clone());
        let pool = SqlitePoolOptions::new()
            .max_connections(8)
            .min_connections(1)
            .acquire_timeout(Duration::from_secs(5))
            .after_connect(move |_, _| {
                let g = g1.clone();
                Box::pin(async move { g.connect_check() })
            })
            .before_acquire(move |_, meta| {
                let g = g2.clone();
                Box::pin(async move { g.usable(meta.age) })
            })
            // A connection whose COMMIT or ROLLBACK failed (full disk, I/O
            // error) may still be inside its transaction: pooled again, the
            // next BEGIN fails with "begin_with at non-zero transaction
            // depth" or writes into the stale transaction. It is closed.
            .after_release(|conn, _| Box::pin(async move { health::reusable(conn).await }))
            .connect_with(opts.clone())
            .await?;
        migrations::migrator(migrations::SQLITE).run(&pool).await?;
        health::spawn_watchdog(guard, opts, pool.clone());
        Ok(Store {
            pool,
            dir: Some(std::sync::Arc::new(data_dir.to_path_buf())),
            write_gate: Default::default(),
        })
    }

    /// An in-memory database (tests).
    pub async fn memory() -> StoreResult<Store> {
        let opts = SqliteConnectOptions::from_str("sqlite::memory:")?.foreign_keys(true);
        Store::with_options(opts, 1).await
    }

    async fn with_options(opts: SqliteConnectOptions, max: u32) -> StoreResult<Store> {
        let pool = SqlitePoolOptions::new()
            .max_connections(max)
            .min_connections(1)
            .connect_with(opts)
            .await?;
        migrations::migrator(migrations::SQLITE).run(&pool).await?;
        Ok(Store {
            pool,
            dir: None,
            write_gate: Default::default(),
        })
    }

    /// This process's turn to write, first come first served (at most
    /// [`WRITE_WAIT`]; past it the pool's timeout, answered 503).
    async fn turn(&self) -> StoreResult<tokio::sync::OwnedMutexGuard<()>> {
        tokio::time::timeout(WRITE_WAIT, self.write_gate.clone().lock_owned())
            .await
            .map_err(|_| StoreError::Db(sqlx::Error::PoolTimedOut))
    }

    /// A write transaction (`BEGIN IMMEDIATE`), in its turn.
    pub(crate) async fn begin_write(&self) -> StoreResult<WriteTx> {
        let turn = self.turn().await?;
        let tx = self.pool.begin_with("BEGIN IMMEDIATE").await?;
        Ok(WriteTx { tx, _turn: turn })
    }

    /// A connection for one autocommit write, in its turn.
    pub(crate) async fn writer(&self) -> StoreResult<Writer> {
        let turn = self.turn().await?;
        let conn = self.pool.acquire().await?;
        Ok(Writer { conn, _turn: turn })
    }

    pub async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await?;
        Ok(())
    }

    /// Flushes the WAL into the database file (at shutdown).
    pub async fn close(&self) {
        let _ = sqlx::query("PRAGMA wal_checkpoint(TRUNCATE)")
            .execute(&self.pool)
            .await;
        self.pool.close().await;
    }
}

/// A measurement's stored configuration (its members lenient: a row of an
/// earlier version reads).
fn parse_config(s: &str) -> StoreResult<springbench_core::job::MeasurementConfig> {
    serde_json::from_str(s)
        .map_err(|e| StoreError::Corrupt(format!("stored configuration unreadable: {e}")))
}

fn parse_json(s: &str) -> StoreResult<Value> {
    serde_json::from_str(s).map_err(|e| StoreError::Corrupt(format!("stored JSON unreadable: {e}")))
}

/// A stored recipe version's document, read into its type at the store's
/// edge: a body the recipe type does not accept is `Corrupt`, naming the
/// version, never a half-read recipe.
pub fn parse_recipe(
    name: &str,
    version: i64,
    body: &str,
) -> StoreResult<springbench_core::qc::Recipe> {
    serde_json::from_str(body).map_err(|e| {
        StoreError::Corrupt(format!("recipe '{name}' version {version} unreadable: {e}"))
    })
}

/// A typed document's stored text, its keys sorted: the text it had when the
/// store held it as a `serde_json::Value` (whose maps sort).
pub fn json_text<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_value(v)
        .map(|v| v.to_string())
        .unwrap_or_default()
}

/// Serialises a document with its object keys sorted, so that a stored
/// document served from its type reads byte for byte as it did when it was
/// served from a `serde_json::Value`.
pub fn sorted<T: serde::Serialize, S: serde::Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    use serde::Serialize;
    serde_json::to_value(v)
        .map_err(serde::ser::Error::custom)?
        .serialize(s)
}
