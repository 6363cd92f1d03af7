//! Corrections with an audit trail (issue 20): an admin corrects a part's
//! serial or kind, or voids a measurement, with a reason. Nothing is
//! deleted: a serial correction moves the part's measurements and verdicts
//! (or one measurement's) to the new serial and leaves the old part row; a
//! void keeps the measurement and takes its verdicts out of SPC. Every
//! correction is a row of `corrections`, readable as the audit log.
//!
//! [`Corrections`] is what both backends answer alike (the station's SQLite
//! here, the center's PostgreSQL in `springbench-store-pg`); on a station a
//! correction also becomes an outbox item (the `corrections` trigger of
//! migration 0240) and reaches the center like a measurement.

use crate::outbox::{correction_from_row, Correction};
use crate::{now, Store, StoreError, StoreResult};
use serde::Serialize;
use sqlx::Row;
use std::future::Future;

/// A row of the audit trail.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct AuditEntry {
    /// The cursor of the audit log's pages.
    pub seq: i64,
    /// At the center: the station it was made on (None: at the center).
    /// On a station: None (made there).
    pub station_id: Option<String>,
    #[serde(flatten)]
    pub correction: Correction,
    /// When this store applied it (a station: when it was made).
    pub applied_at: String,
}

/// Corrections and the audit log, on either backend.
pub trait Corrections: Sync {
    /// Applies a correction in one transaction and records it; false (and
    /// nothing changed) when its id is recorded already. A missing reason,
    /// an unknown kind, part or measurement is `StoreError::Invalid`. On a
    /// station, `old_value` is recorded as the store found it.
    fn correct(&self, c: &Correction) -> impl Future<Output = StoreResult<bool>> + Send;

    /// The audit log, oldest first, in keyset pages (`after_seq`); of one
    /// part when `part` is given (also the corrections that gave it its serial).
    fn audit_log(
        &self,
        part: Option<&str>,
        after_seq: Option<i64>,
        limit: i64,
    ) -> impl Future<Output = StoreResult<Vec<AuditEntry>>> + Send;

    /// The correction that voided a measurement, if any.
    fn measurement_void(
        &self,
        id: &str,
    ) -> impl Future<Output = StoreResult<Option<String>>> + Send;
}

/// SQL (SQLite): the job of the verdict row `v` has no voided measurement.
/// A void takes its job out of the part's verdict (decision 0057); the
/// indexes `measurements_job` and `corrections_one_void` answer it.
pub(crate) const JOB_WITHOUT_VOID: &str = "NOT EXISTS (SELECT 1 FROM measurements vm \
     JOIN corrections vc ON vc.measurement_id = vm.id AND vc.kind = 'void_measurement' \
     WHERE vm.job_id = v.job_id)";

/// The checks both backends make before applying `c`.
pub fn check(c: &Correction) -> StoreResult<()> {
    let bad = |m: &str| Err(StoreError::Invalid(format!("correction {}: {m}", c.id)));
    if c.id.trim().is_empty() {
        return bad("an id is required");
    }
    if c.reason.trim().is_empty() {
        return bad("a reason is required");
    }
    // Every text of a correction travels to the center: no control
    // character, bounded lengths, a new serial by the serial rule (an
    // 8 000-character serial was accepted and stopped replication, issue 36).
    for (field, text, max) in [
        ("id", Some(c.id.as_str()), 128),
        ("part_serial", Some(c.part_serial.as_str()), 64),
        ("measurement_id", c.measurement_id.as_deref(), 128),
        ("old_value", c.old_value.as_deref(), 4096),
        ("new_value", c.new_value.as_deref(), 4096),
        ("reason", Some(c.reason.as_str()), 4096),
        ("made_by", c.made_by.as_deref(), 256),
    ] {
        let Some(t) = text else { continue };
        if t.chars().count() > max {
            return bad(&format!("{field}: at most {max} characters"));
        }
        if let Some(ch) = springbench_core::job::bad_char(t) {
            return bad(&format!(
                "{field}: holds the control character U+{:04X}",
                ch as u32
            ));
        }
    }
    if c.kind == "part_serial" {
        let new = c.new_value.as_deref().unwrap_or_default();
        if !new.trim().is_empty() && !springbench_core::job::valid_serial(new) {
            return bad(&format!(
                "new_value: a serial is {}",
                springbench_core::job::SERIAL_RULE
            ));
        }
    }
    if c.kind == "part_kind"
        && c.new_value
            .as_deref()
            .is_some_and(|k| k.chars().count() > 64)
    {
        return bad("new_value: a kind has at most 64 characters");
    }
    match c.kind.as_str() {
        "void_measurement" if c.measurement_id.is_none() => bad("a void names its measurement"),
        "part_serial" if c.new_value.as_deref().is_none_or(|v| v.trim().is_empty()) => {
            bad("a serial correction names the new serial")
        }
        "part_serial" if c.new_value.as_deref() == Some(c.part_serial.as_str()) => {
            bad("the new serial is the old one")
        }
        "void_measurement" | "part_serial" | "part_kind" => Ok(()),
        k => bad(&format!(
            "kind 'part_serial', 'part_kind' or 'void_measurement', got '{k}'"
        )),
    }
}

fn entry(r: &sqlx::sqlite::SqliteRow) -> AuditEntry {
    AuditEntry {
        seq: r.get("seq"),
        station_id: None,
        correction: correction_from_row(r),
        applied_at: r.get("made_at"),
    }
}

impl Corrections for Store {
    async fn correct(&self, c: &Correction) -> StoreResult<bool> {
        check(c)?;
        let bad = |m: String| StoreError::Invalid(format!("correction {}: {m}", c.id));
        // The write lock first (as every station write, lib.rs): this reads,
        // then writes, and a deferred transaction cannot wait for it.
        let mut tx = self.begin_write().await?;
        let known: Option<i64> = sqlx::query_scalar("SELECT seq FROM corrections WHERE id = ?")
            .bind(c.id.clone())
            .fetch_optional(&mut *tx)
            .await?;
        if known.is_some() {
            return Ok(false);
        }
        let part: Option<Option<String>> =
            sqlx::query_scalar("SELECT kind FROM parts WHERE serial = ?")
                .bind(&c.part_serial)
                .fetch_optional(&mut *tx)
                .await?;
        let Some(kind) = part else {
            return Err(bad(format!("no part '{}'", c.part_serial)));
        };
        if let Some(m) = &c.measurement_id {
            let of: Option<String> =
                sqlx::query_scalar("SELECT part_serial FROM measurements WHERE id = ?")
                    .bind(m)
                    .fetch_optional(&mut *tx)
                    .await?;
            if of.as_deref() != Some(c.part_serial.as_str()) {
                return Err(bad(format!(
                    "no measurement {m} of part '{}'",
                    c.part_serial
                )));
            }
        }
        let old_value = match c.kind.as_str() {
            "void_measurement" => {
                let m = c.measurement_id.as_deref().unwrap_or_default();
                if let Some(v) = self.void_in(&mut tx, m).await? {
                    return Err(bad(format!("measurement {m} is void already ({v})")));
                }
                None
            }
            "part_kind" => {
                sqlx::query("UPDATE parts SET kind = ?, updated_at = ? WHERE serial = ?")
                    .bind(&c.new_value)
                    .bind(now())
                    .bind(&c.part_serial)
                    .execute(&mut *tx)
                    .await?;
                kind
            }
            _ => {
                let new = c.new_value.as_deref().unwrap_or_default();
                sqlx::query(
                    "INSERT OR IGNORE INTO parts (serial, kind, notes, created_at, updated_at) \
                     SELECT ?, kind, notes, created_at, ? FROM parts WHERE serial = ?",
                )
                .bind(new)
                .bind(now())
                .bind(&c.part_serial)
                .execute(&mut *tx)
                .await?;
                for table in ["measurements", "qc_verdicts"] {
                    let col = if table == "measurements" {
                        "id"
                    } else {
                        "measurement_id"
                    };
                    sqlx::query(sqlx::AssertSqlSafe(format!(
                        "UPDATE {table} SET part_serial = ? WHERE part_serial = ? AND (? IS NULL OR {col} = ?)"
                    )))
                    .bind(new)
                    .bind(&c.part_serial)
                    .bind(&c.measurement_id)
                    .bind(&c.measurement_id)
                    .execute(&mut *tx)
                    .await?;
                }
                Some(c.part_serial.clone())
            }
        };
        // The trigger of migration 0240 puts it into the fleet outbox.
        sqlx::query(
            "INSERT INTO corrections (id, kind, part_serial, measurement_id, old_value, new_value, reason, \
             made_by, made_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(&c.id)
        .bind(&c.kind)
        .bind(&c.part_serial)
        .bind(&c.measurement_id)
        .bind(old_value)
        .bind(&c.new_value)
        .bind(&c.reason)
        .bind(&c.made_by)
        .bind(&c.made_at)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(true)
    }

    async fn audit_log(
        &self,
        part: Option<&str>,
        after_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<AuditEntry>> {
        let rows = sqlx::query(
            "SELECT * FROM corrections WHERE (?1 IS NULL OR part_serial = ?1 \
             OR (kind = 'part_serial' AND new_value = ?1)) AND (?2 IS NULL OR seq > ?2) ORDER BY seq LIMIT ?3",
        )
        .bind(part.map(str::to_string))
        .bind(after_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(entry).collect())
    }

    async fn measurement_void(&self, id: &str) -> StoreResult<Option<String>> {
        let mut c = self.pool.acquire().await?;
        self.void_in(&mut c, id).await
    }
}

impl Store {
    async fn void_in(
        &self,
        c: &mut sqlx::SqliteConnection,
        measurement_id: &str,
    ) -> StoreResult<Option<String>> {
        Ok(sqlx::query_scalar(
            "SELECT id FROM corrections WHERE kind = 'void_measurement' AND measurement_id = ?",
        )
        .bind(measurement_id)
        .fetch_optional(c)
        .await?)
    }
}
