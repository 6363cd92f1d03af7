//! The schema migrations, embedded at build time by `build.rs` (decision
//! 0042): sqlx's `Migrator` built from the list, with the checksums sqlx's
//! own `migrate!` and `Migrator::new(dir)` compute, so databases migrated
//! before keep validating.

use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::{AssertSqlSafe, SqlSafeStr};
use std::borrow::Cow;

/// (version, description, SQL) of each migration file, in version order.
pub type MigrationList = &'static [(i64, &'static str, &'static str)];

/// This crate's migrations (`migrations/*.sql`).
pub const SQLITE: MigrationList = include!(concat!(env!("OUT_DIR"), "/migrations.rs"));

/// The `Migrator` of a list, as `sqlx::migrate!` builds it: every file a
/// simple migration, run in a transaction unless its SQL starts with
/// `-- no-transaction`.
pub fn migrator(list: MigrationList) -> Migrator {
    Migrator::with_migrations(
        list.iter()
            .map(|(version, description, sql)| {
                Migration::new(
                    *version,
                    Cow::Borrowed(*description),
                    MigrationType::Simple,
                    AssertSqlSafe(*sql).into_sql_str(),
                    sql.starts_with("-- no-transaction"),
                )
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The embedded migrations equal what sqlx's own resolver reads from the
    /// directory (the source `migrate!` used): versions, descriptions,
    /// checksums and the transaction flag. A database migrated by an older
    /// build validates against them.
    #[tokio::test]
    async fn the_embedded_migrations_are_sqlxs_own_reading_of_the_directory() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("migrations");
        let theirs = Migrator::new(dir.as_path()).await.unwrap();
        let ours = migrator(SQLITE);
        assert_eq!(ours.migrations.len(), theirs.migrations.len());
        assert!(ours.migrations.len() >= 14);
        for (a, b) in ours.migrations.iter().zip(theirs.migrations.iter()) {
            assert_eq!(a.version, b.version);
            assert_eq!(a.description, b.description);
            assert_eq!(a.migration_type, b.migration_type);
            assert_eq!(a.checksum, b.checksum, "checksum of {}", a.version);
            assert_eq!(a.no_tx, b.no_tx);
            assert_eq!(a.sql.as_str(), b.sql.as_str());
        }
    }
}
