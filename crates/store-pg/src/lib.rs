//! The fleet's center on PostgreSQL (issue 20, decisions 0034 and 0036).
//!
//! [`PgStore`] implements the results interface of `springbench-store`
//! (`ResultStore`: parts, measurements, fits, verdicts, recipes, the ingest
//! of a finished measurement) and the center's side of replication
//! (`CenterIngest`), with its own `migrations/` (the tables it shares with a
//! station's SQLite have the same meaning and column names). On top, what
//! only a center has: the station of every row, SPC per recipe across
//! stations and per station in SQL aggregates, yield per station and day,
//! the audit trail of corrections, and the stations' last contact and
//! backlog (`center.rs`).
//!
//! Like `springbench-store`, it never depends on the bench or the daemon
//! (`tests/layers.rs`).

mod center;
mod ingest;
pub mod longterm;
mod reads;
mod recipes;
pub mod test_server;

pub use center::{SpcGroup, SpcQuery, YieldDay};
pub use ingest::{Refusal, StationRegistration};
pub use reads::CenterRecording;
pub use recipes::{
    Decided, NewRecipeProposal, ProposalKind, ProposalState, Proposed, RecipeProposal,
};
pub use springbench_store::corrections::{AuditEntry, Corrections};

use springbench_store::{StoreError, StoreResult};
use sqlx::postgres::{PgConnectOptions, PgPool, PgPoolOptions};
use std::str::FromStr;
use std::time::Duration;

/// The center's migrations (`migrations/*.sql`), embedded by the store
/// crate's build script (decision 0042).
const MIGRATIONS: springbench_store::migrations::MigrationList =
    include!(concat!(env!("OUT_DIR"), "/migrations.rs"));

/// The center's store: a pool on one PostgreSQL database (and schema).
#[derive(Clone)]
pub struct PgStore {
    pool: PgPool,
}

impl PgStore {
    /// Connects to `url` (`postgres://user@host:port/db`, a Unix socket
    /// with `?host=/dir`) and runs the center's migrations.
    pub async fn connect(url: &str) -> StoreResult<PgStore> {
        PgStore::connect_schema(url, None).await
    }

    /// [`PgStore::connect`] into `schema` (created when missing): every
    /// table, and the migrations' bookkeeping, live there. The tests give
    /// each test a schema of its own on one server.
    pub async fn connect_schema(url: &str, schema: Option<&str>) -> StoreResult<PgStore> {
        // Custom plans for every statement: the listings' optional filters
        // (`$1 IS NULL OR x = $1`) fold away and the present ones use their
        // index, however often a statement ran before.
        let opts = PgConnectOptions::from_str(url)?;
        let mut settings = vec![("plan_cache_mode", "force_custom_plan")];
        if let Some(s) = schema {
            if s.is_empty() || !s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_') {
                return Err(StoreError::Invalid(format!(
                    "schema name '{s}': letters, digits and _ only"
                )));
            }
            let admin = PgPoolOptions::new()
                .max_connections(1)
                .connect_with(opts.clone())
                .await?;
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "CREATE SCHEMA IF NOT EXISTS {s}"
            )))
            .execute(&admin)
            .await?;
            admin.close().await;
            settings.push(("search_path", s));
        }
        let opts = opts.options(settings);
        let pool = PgPoolOptions::new()
            .max_connections(8)
            .acquire_timeout(Duration::from_secs(5))
            .connect_with(opts)
            .await?;
        springbench_store::migrations::migrator(MIGRATIONS)
            .run(&pool)
            .await?;
        Ok(PgStore { pool })
    }

    pub async fn ping(&self) -> StoreResult<()> {
        sqlx::query("SELECT 1").execute(&self.pool).await?;
        Ok(())
    }

    pub async fn close(&self) {
        self.pool.close().await;
    }

    /// Rows of the main tables: (parts, measurements, verdicts, recordings).
    pub async fn counts(&self) -> StoreResult<(i64, i64, i64, i64)> {
        let r: (i64, i64, i64, i64) = sqlx::query_as(
            "SELECT (SELECT COUNT(*) FROM parts), (SELECT COUNT(*) FROM measurements), \
             (SELECT COUNT(*) FROM qc_verdicts), (SELECT COUNT(*) FROM recordings)",
        )
        .fetch_one(&self.pool)
        .await?;
        Ok(r)
    }
}

fn parse_json(s: &str) -> StoreResult<serde_json::Value> {
    serde_json::from_str(s).map_err(|e| StoreError::Corrupt(format!("stored JSON unreadable: {e}")))
}
