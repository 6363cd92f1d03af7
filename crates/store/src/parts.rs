//! Parts: one row per serial, with its measurement count and newest verdict.

use crate::results::{Part, PartReads};
use crate::{now, Store, StoreResult};
use sqlx::sqlite::SqliteRow;
use sqlx::Row;

impl Store {
    /// Creates the part if new; updates kind/notes when given.
    pub async fn upsert_part(
        &self,
        serial: &str,
        kind: Option<&str>,
        notes: Option<&str>,
    ) -> StoreResult<()> {
        let t = now();
        sqlx::query(
            "INSERT INTO parts (serial, kind, notes, created_at, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(serial) DO UPDATE SET kind = COALESCE(excluded.kind, parts.kind), \
             notes = COALESCE(excluded.notes, parts.notes), \
             updated_at = CASE WHEN excluded.kind IS NULL AND excluded.notes IS NULL THEN parts.updated_at ELSE excluded.updated_at END",
        )
        .bind(serial.to_string())
        .bind(kind.map(str::to_string))
        .bind(notes.map(str::to_string))
        .bind(t.clone())
        .bind(t)
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }
}

fn part_from_row(r: &SqliteRow) -> Part {
    Part {
        serial: r.get(0),
        kind: r.get(1),
        notes: r.get(2),
        created_at: r.get(3),
        updated_at: r.get(4),
        measurement_count: r.get(5),
        verdict: r.get(6),
        station_id: None,
    }
}

/// A part with its measurement count and its verdict: the newest job
/// verdict of a job without a voided measurement (decision 0057).
fn part_select() -> String {
    format!(
        "SELECT p.serial, p.kind, p.notes, p.created_at, p.updated_at, \
         (SELECT COUNT(*) FROM measurements m WHERE m.part_serial = p.serial), \
         (SELECT v.verdict FROM qc_verdicts v WHERE v.part_serial = p.serial AND v.measurement_id IS NULL \
          AND {} ORDER BY v.seq DESC LIMIT 1) \
         FROM parts p",
        crate::corrections::JOB_WITHOUT_VOID
    )
}

impl PartReads for Store {
    async fn get_part(&self, serial: &str) -> StoreResult<Option<Part>> {
        let row = sqlx::query(sqlx::AssertSqlSafe(format!(
            "{} WHERE p.serial = ?",
            part_select()
        )))
        .bind(serial.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| part_from_row(&r)))
    }

    async fn list_parts(&self, after: Option<&str>, limit: i64) -> StoreResult<Vec<Part>> {
        let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
            "{} WHERE (? IS NULL OR p.serial > ?) ORDER BY p.serial LIMIT ?",
            part_select()
        )))
        .bind(after.map(str::to_string))
        .bind(after.map(str::to_string))
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(part_from_row).collect())
    }
}
