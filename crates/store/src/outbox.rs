//! The fleet outbox of a station (issue 20): what the station has still to
//! send to the fleet's center, in the station's own event order.
//!
//! Triggers of migration `0240_fleet_outbox.sql` fill it inside the very
//! transaction that stores the event: a job's end (its measurements, their
//! verdicts, the job's verdict), a measurement imported without a job, a
//! correction. A committed result is in the outbox, a rolled-back one is
//! not, whatever code path wrote it. Rows are never deleted: `seq` is the
//! station's event sequence (the center checks it for gaps), `delivered_at`
//! what the center acknowledged. This file reads the outbox, marks rows
//! delivered or refused, and reads back what an event carries
//! ([`Store::finished_measurement`], [`Store::correction`]); `replication.rs`
//! makes the contract's items of them.

use crate::results::{FinishedMeasurement, NewMeasurement, NewRecording, NewVerdict, RecipeRow};
use crate::{now, parse_json, Store, StoreError, StoreResult};
use serde::Serialize;
use sqlx::sqlite::SqliteRow;
use sqlx::Row;

/// What an outbox row announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OutboxKind {
    /// A finished measurement with its verdicts (`ref_id` its id): at its
    /// job's end, or when stored for an import.
    Measurement,
    /// The verdicts of a whole job, after its measurements (`ref_id` the job id).
    JobVerdicts,
    /// A row of `corrections` (`ref_id` its id).
    Correction,
    /// A long-term test changed (`ref_id` its job id): its document as it
    /// stands when the item is sent (decision 0134).
    LongTermTest,
}

impl OutboxKind {
    fn parse(s: &str) -> StoreResult<OutboxKind> {
        match s {
            "measurement" => Ok(OutboxKind::Measurement),
            "job_verdicts" => Ok(OutboxKind::JobVerdicts),
            "correction" => Ok(OutboxKind::Correction),
            "long_term_test" => Ok(OutboxKind::LongTermTest),
            o => Err(StoreError::Corrupt(format!("unknown outbox kind '{o}'"))),
        }
    }
}

/// One event of the station's outbox.
#[derive(Debug, Clone, Serialize)]
pub struct OutboxRow {
    /// The station's event sequence number (1, 2, 3... without gaps).
    pub seq: i64,
    pub kind: OutboxKind,
    pub ref_id: String,
    pub part_serial: String,
    pub created_at: String,
    pub attempts: i64,
    pub last_error: Option<String>,
}

/// The outbox's state: what is still to send, what was sent.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct OutboxBacklog {
    /// Events not yet acknowledged by the center.
    pub pending: i64,
    /// Of those, refused by the center (they hold later events of their part).
    pub refused: i64,
    /// When the oldest pending event happened (RFC 3339 UTC).
    pub oldest_pending_at: Option<String>,
    /// The station's newest event sequence number (0: none yet).
    pub last_seq: i64,
    /// Events the center acknowledged.
    pub delivered: i64,
}

fn outbox_from_row(r: &SqliteRow) -> StoreResult<OutboxRow> {
    Ok(OutboxRow {
        seq: r.get("seq"),
        kind: OutboxKind::parse(&r.get::<String, _>("kind"))?,
        ref_id: r.get("ref_id"),
        part_serial: r.get("part_serial"),
        created_at: r.get("created_at"),
        attempts: r.get("attempts"),
        last_error: r.get("last_error"),
    })
}

/// A recording kind as the store's types name it.
fn recording_kind(s: &str) -> StoreResult<&'static str> {
    match s {
        "pre" => Ok("pre"),
        "main" => Ok("main"),
        o => Err(StoreError::Corrupt(format!("unknown recording kind '{o}'"))),
    }
}

fn measurement_source(s: &str) -> StoreResult<&'static str> {
    match s {
        "bench" => Ok("bench"),
        "import" => Ok("import"),
        o => Err(StoreError::Corrupt(format!(
            "unknown measurement source '{o}'"
        ))),
    }
}

/// A verdict kind as [`NewVerdict`] names it.
fn verdict_kind(s: &str) -> StoreResult<&'static str> {
    match s {
        "pass" => Ok("pass"),
        "fail" => Ok("fail"),
        "invalid" => Ok("invalid"),
        "no_limits" => Ok("no_limits"),
        o => Err(StoreError::Corrupt(format!("unknown verdict '{o}'"))),
    }
}

fn verdict_from_row(r: &SqliteRow) -> StoreResult<(NewVerdict, String)> {
    Ok((
        NewVerdict {
            id: r.get("id"),
            job_id: r.get("job_id"),
            measurement_id: r.get("measurement_id"),
            part_serial: r.get("part_serial"),
            recipe_name: r.get("recipe_name"),
            recipe_version: r.get("recipe_version"),
            recipe_sha256: r.get("recipe_sha256"),
            verdict: verdict_kind(&r.get::<String, _>("verdict"))?,
            detail: parse_json(&r.get::<String, _>("detail_json"))?,
            trace: parse_json(&r.get::<String, _>("trace_json"))?,
        },
        r.get("created_at"),
    ))
}

/// A correction as the audit log keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct Correction {
    pub id: String,
    /// `part_serial`, `part_kind` or `void_measurement`.
    pub kind: String,
    /// The part concerned (for `part_serial`: the serial before the correction).
    pub part_serial: String,
    pub measurement_id: Option<String>,
    pub old_value: Option<String>,
    pub new_value: Option<String>,
    pub reason: String,
    /// The token name of who made it (null with open access).
    pub made_by: Option<String>,
    pub made_at: String,
}

pub(crate) fn correction_from_row(r: &SqliteRow) -> Correction {
    Correction {
        id: r.get("id"),
        kind: r.get("kind"),
        part_serial: r.get("part_serial"),
        measurement_id: r.get("measurement_id"),
        old_value: r.get("old_value"),
        new_value: r.get("new_value"),
        reason: r.get("reason"),
        made_by: r.get("made_by"),
        made_at: r.get("made_at"),
    }
}

impl Store {
    /// The next events to send, oldest first: at most `limit`, none of a
    /// part that has an earlier refused event (per-part order holds).
    pub async fn outbox_next(&self, limit: i64) -> StoreResult<Vec<OutboxRow>> {
        let rows = sqlx::query(
            "SELECT o.* FROM fleet_outbox o WHERE o.delivered_at IS NULL AND o.refused_at IS NULL \
             AND NOT EXISTS (SELECT 1 FROM fleet_outbox r WHERE r.part_serial = o.part_serial \
                 AND r.delivered_at IS NULL AND r.refused_at IS NOT NULL AND r.seq < o.seq) \
             ORDER BY o.seq LIMIT ?",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(outbox_from_row).collect()
    }

    /// The center acknowledged these events.
    pub async fn outbox_delivered(&self, seqs: &[i64]) -> StoreResult<()> {
        let t = now();
        let mut tx = self.begin_write().await?;
        for s in seqs {
            sqlx::query(
                "UPDATE fleet_outbox SET delivered_at = ?, attempts = attempts + 1, last_attempt_at = ?, \
                 last_error = NULL, refused_at = NULL WHERE seq = ? AND delivered_at IS NULL",
            )
            .bind(t.clone())
            .bind(t.clone())
            .bind(s)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// An attempt to send these events failed (`refused`: the center
    /// answered and refused them; otherwise it was not reached).
    pub async fn outbox_failed(&self, seqs: &[i64], error: &str, refused: bool) -> StoreResult<()> {
        let t = now();
        let mut tx = self.begin_write().await?;
        for s in seqs {
            sqlx::query(
                "UPDATE fleet_outbox SET attempts = attempts + 1, last_attempt_at = ?, last_error = ?, \
                 refused_at = CASE WHEN ? THEN ? ELSE refused_at END WHERE seq = ? AND delivered_at IS NULL",
            )
            .bind(t.clone())
            .bind(error.to_string())
            .bind(refused)
            .bind(t.clone())
            .bind(s)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// Notes what the center said of a delivered item (a conflict).
    pub async fn outbox_note(&self, seq: i64, note: &str) -> StoreResult<()> {
        sqlx::query("UPDATE fleet_outbox SET last_error = ? WHERE seq = ?")
            .bind(note.to_string())
            .bind(seq)
            .execute(&mut *self.writer().await?)
            .await?;
        Ok(())
    }

    /// Refused events are offered again (at the worker's start: a center
    /// fixed meanwhile takes them).
    pub async fn outbox_retry_refused(&self) -> StoreResult<u64> {
        let r = sqlx::query(
            "UPDATE fleet_outbox SET refused_at = NULL WHERE refused_at IS NOT NULL AND delivered_at IS NULL",
        )
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(r.rows_affected())
    }

    /// The outbox's state (the station's `/metrics`, `GET /api/v1/fleet/station`).
    pub async fn outbox_backlog(&self) -> StoreResult<OutboxBacklog> {
        let r = sqlx::query(
            "SELECT \
               (SELECT COUNT(*) FROM fleet_outbox WHERE delivered_at IS NULL), \
               (SELECT COUNT(*) FROM fleet_outbox WHERE delivered_at IS NULL AND refused_at IS NOT NULL), \
               (SELECT MIN(created_at) FROM fleet_outbox WHERE delivered_at IS NULL), \
               (SELECT COALESCE(MAX(seq), 0) FROM fleet_outbox), \
               (SELECT COUNT(*) FROM fleet_outbox WHERE delivered_at IS NOT NULL)",
        )
        .fetch_one(&self.pool)
        .await?;
        Ok(OutboxBacklog {
            pending: r.get(0),
            refused: r.get(1),
            oldest_pending_at: r.get(2),
            last_seq: r.get(3),
            delivered: r.get(4),
        })
    }

    /// The items the center refused (parked, with the center's reason in
    /// `last_error`), oldest first: `GET /api/v1/fleet/link`.
    pub async fn outbox_refused(&self, limit: i64) -> StoreResult<Vec<OutboxRow>> {
        let rows = sqlx::query(
            "SELECT * FROM fleet_outbox WHERE delivered_at IS NULL AND refused_at IS NOT NULL ORDER BY seq LIMIT ?",
        )
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(outbox_from_row).collect()
    }

    /// Every outbox row after `after_seq`, oldest first (the API; tests).
    pub async fn outbox_rows(&self, after_seq: i64, limit: i64) -> StoreResult<Vec<OutboxRow>> {
        let rows = sqlx::query("SELECT * FROM fleet_outbox WHERE seq > ? ORDER BY seq LIMIT ?")
            .bind(after_seq)
            .bind(limit)
            .fetch_all(&self.pool)
            .await?;
        rows.iter().map(outbox_from_row).collect()
    }

    /// A stored measurement as it leaves the station: part, record,
    /// recordings (`with_recordings`; otherwise none), its own verdicts, the
    /// software version and time it was stored with (the verdicts' own time
    /// is in [`Store::verdict_times`]). None when unknown.
    pub async fn finished_measurement(
        &self,
        id: &str,
        with_recordings: bool,
    ) -> StoreResult<Option<FinishedMeasurement>> {
        let Some(r) = sqlx::query(
            "SELECT m.*, p.kind AS part_kind, p.notes AS part_notes FROM measurements m \
             JOIN parts p ON p.serial = m.part_serial WHERE m.id = ?",
        )
        .bind(id.to_string())
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        let mut recordings = vec![];
        if with_recordings {
            for kind in ["pre", "main"] {
                let rec = self.get_recording(id, kind).await?.ok_or_else(|| {
                    StoreError::Corrupt(format!("measurement {id} has no {kind} recording"))
                })?;
                recordings.push(NewRecording {
                    kind: recording_kind(kind)?,
                    sample_rate_hz: rec.sample_rate_hz,
                    frames: rec.frames,
                    stored: springbench_recording::codec::Stored {
                        bytes: rec.bytes,
                        channel_scale: rec.channel_scale,
                    },
                });
            }
        }
        let measurement = NewMeasurement {
            id: r.get("id"),
            part_serial: r.get("part_serial"),
            job_id: r.get("job_id"),
            source: measurement_source(&r.get::<String, _>("source"))?,
            bench_id: r.get("bench_id"),
            config: crate::parse_config(&r.get::<String, _>("config_json"))?,
            // Sent on as stored (a document of an older version included).
            meta: crate::Doc::Received(parse_json(&r.get::<String, _>("meta_json"))?),
            result: r
                .get::<Option<String>, _>("result_json")
                .map(|s| parse_json(&s).map(crate::Doc::Received))
                .transpose()?,
            analysis_error: r.get("analysis_error"),
            target_xpeak_m: r.get("target_xpeak_m"),
            repeat_index: r.get("repeat_index"),
            level_index: r.get("level_index"),
            pre: 0,
            main: 1,
        };
        let verdicts =
            sqlx::query("SELECT * FROM qc_verdicts WHERE measurement_id = ? ORDER BY seq")
                .bind(id.to_string())
                .fetch_all(&self.pool)
                .await?
                .iter()
                .map(|v| verdict_from_row(v).map(|(v, _)| v))
                .collect::<StoreResult<Vec<_>>>()?;
        Ok(Some(FinishedMeasurement {
            part: (
                r.get("part_serial"),
                r.get("part_kind"),
                r.get("part_notes"),
            ),
            measurement,
            recordings,
            verdicts,
            software_version: r.get("software_version"),
            created_at: r.get("created_at"),
        }))
    }

    /// When each verdict of a measurement was made, by verdict id.
    pub async fn verdict_times(&self, measurement_id: &str) -> StoreResult<Vec<(String, String)>> {
        let rows = sqlx::query(
            "SELECT id, created_at FROM qc_verdicts WHERE measurement_id = ? ORDER BY seq",
        )
        .bind(measurement_id.to_string())
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(|r| (r.get(0), r.get(1))).collect())
    }

    /// The verdicts of a whole job (measurement_id None), oldest first,
    /// each with when it was made.
    pub async fn job_verdict_rows(&self, job_id: &str) -> StoreResult<Vec<(NewVerdict, String)>> {
        sqlx::query(
            "SELECT * FROM qc_verdicts WHERE job_id = ? AND measurement_id IS NULL ORDER BY seq",
        )
        .bind(job_id.to_string())
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(verdict_from_row)
        .collect()
    }

    /// The calibration record a measurement was made with (hardware benches).
    pub async fn measurement_calibration_id(&self, id: &str) -> StoreResult<Option<String>> {
        let c: Option<Option<String>> =
            sqlx::query_scalar("SELECT calibration_id FROM measurements WHERE id = ?")
                .bind(id.to_string())
                .fetch_optional(&self.pool)
                .await?;
        Ok(c.flatten())
    }

    /// A correction by id.
    pub async fn correction(&self, id: &str) -> StoreResult<Option<Correction>> {
        let r = sqlx::query("SELECT * FROM corrections WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(r.as_ref().map(correction_from_row))
    }
}

/// What [`Store::apply_center_recipes`] changed.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RecipeSync {
    /// Versions the station did not hold and now does.
    pub added: u64,
    /// Versions the center has retired that the station now holds retired.
    pub retired: u64,
    /// Local versions the center holds with the same content (now `center`).
    pub confirmed: u64,
    /// Versions the station holds with another content than the center's
    /// (same name and version, another hash): left as they are, named here.
    pub conflicts: Vec<String>,
}

impl Store {
    /// Takes the center's recipe versions: the versions the station lacks
    /// are stored with the center's version number, hash and content; a
    /// version the center retired is retired here too (a station never
    /// judges with it while it can reach the center). A local version with
    /// the same number and another hash is left alone and named.
    pub async fn apply_center_recipes(&self, rows: &[RecipeRow]) -> StoreResult<RecipeSync> {
        let mut out = RecipeSync::default();
        let mut tx = self.begin_write().await?;
        for r in rows {
            let held: Option<(String, i64, String)> = sqlx::query_as(
                "SELECT sha256, retired, source FROM qc_recipes WHERE name = ? AND version = ?",
            )
            .bind(r.name.clone())
            .bind(r.version)
            .fetch_optional(&mut *tx)
            .await?;
            match held {
                None => {
                    sqlx::query(
                        "INSERT INTO qc_recipes (name, version, sha256, body_json, origin, proposal_id, retired, created_by, created_at, source, approved_by) \
                         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, 'center', ?)",
                    )
                    .bind(r.name.clone())
                    .bind(r.version)
                    .bind(r.sha256.clone())
                    .bind(crate::json_text(&r.recipe))
                    .bind(r.origin.clone())
                    .bind(r.proposal_id.clone())
                    .bind(i64::from(r.retired))
                    .bind(r.created_by.clone())
                    .bind(r.created_at.clone())
                    .bind(r.approved_by.clone())
                    .execute(&mut *tx)
                    .await?;
                    out.added += 1;
                }
                Some((sha, _, _)) if sha != r.sha256 => {
                    out.conflicts.push(format!(
                        "recipe '{}' version {}: the station holds sha256 {sha}, the center {}",
                        r.name, r.version, r.sha256
                    ));
                }
                Some((_, retired, source)) => {
                    if r.retired && retired == 0 {
                        sqlx::query(
                            "UPDATE qc_recipes SET retired = 1 WHERE name = ? AND version = ?",
                        )
                        .bind(r.name.clone())
                        .bind(r.version)
                        .execute(&mut *tx)
                        .await?;
                        out.retired += 1;
                    }
                    // The same version, the same content at the center: a
                    // local version the center approved (published), or
                    // one taken before sources were recorded.
                    if source != "center" {
                        sqlx::query(
                            "UPDATE qc_recipes SET source = 'center', approved_by = ? WHERE name = ? AND version = ?",
                        )
                        .bind(r.approved_by.clone())
                        .bind(r.name.clone())
                        .bind(r.version)
                        .execute(&mut *tx)
                        .await?;
                        out.confirmed += 1;
                    }
                }
            }
        }
        tx.commit().await?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::{Inserted, JobState};
    use crate::qc::JobRecords;
    use serde_json::json;

    use crate::results::tiny_recording as rec;

    fn meas(id: &str, job: &str, serial: &str) -> NewMeasurement {
        NewMeasurement {
            id: id.into(),
            part_serial: serial.into(),
            job_id: Some(job.into()),
            source: "bench",
            bench_id: Some("b1".into()),
            config: Default::default(),
            meta: crate::Doc::Received(json!({"moving_mass_kg": 0.01})),
            result: Some(crate::Doc::Received(
                json!({"large_signal": {"keff_n_per_m": 1500.0}}),
            )),
            analysis_error: None,
            target_xpeak_m: Some(0.004),
            repeat_index: Some(0),
            level_index: Some(0),
            pre: 0,
            main: 1,
        }
    }

    fn verdict(id: &str, job: &str, m: Option<&str>, serial: &str) -> NewVerdict {
        NewVerdict {
            id: id.into(),
            job_id: Some(job.into()),
            measurement_id: m.map(str::to_string),
            part_serial: serial.into(),
            recipe_name: "r".into(),
            recipe_version: 1,
            recipe_sha256: "h".into(),
            verdict: "pass",
            detail: json!({}),
            trace: json!({"recipe": {"version": 1}}),
        }
    }

    async fn queued(s: &Store, id: &str, serial: &str) {
        let r = s
            .insert_job(
                id,
                "b1",
                (serial, None, None),
                0,
                &springbench_core::job::StoredRequest::self_check("b1"),
                id,
                None,
            )
            .await
            .unwrap();
        assert!(matches!(r, Inserted::New(_)));
    }

    /// A job's end, an import and nothing else reach the outbox, each once,
    /// in the order they were committed; a job's end that fails to commit
    /// leaves no event behind.
    #[tokio::test]
    async fn events_enter_the_outbox_with_the_transaction_that_stores_them() {
        let s = Store::memory().await.unwrap();
        queued(&s, "j1", "SN-1").await;
        queued(&s, "j2", "SN-2").await;
        assert!(s.outbox_next(10).await.unwrap().is_empty());
        assert!(s.start_job("j1").await.unwrap());
        s.set_progress("j1", "fit", 0.9, 1.0).await.unwrap();
        assert_eq!(s.outbox_backlog().await.unwrap().last_seq, 0);
        let records = JobRecords {
            verdicts: vec![
                verdict("v-m1", "j1", Some("m1"), "SN-1"),
                verdict("v-j1", "j1", None, "SN-1"),
            ],
            ..JobRecords::default()
        };
        s.finish_job_qc(
            "j1",
            JobState::Succeeded,
            None,
            Some(1.0),
            &[],
            &[],
            vec![rec("pre"), rec("main")],
            vec![meas("m1", "j1", "SN-1")],
            &records,
        )
        .await
        .unwrap();
        // A job end whose transaction fails (a verdict naming an unknown
        // measurement breaks the foreign key) stores no event.
        assert!(s.start_job("j2").await.unwrap());
        let bad = JobRecords {
            verdicts: vec![verdict("v-x", "j2", Some("nope"), "SN-2")],
            ..JobRecords::default()
        };
        let e = s
            .finish_job_qc(
                "j2",
                JobState::Succeeded,
                None,
                None,
                &[],
                &[],
                vec![],
                vec![],
                &bad,
            )
            .await;
        assert!(e.is_err());
        assert_eq!(
            s.get_job("j2").await.unwrap().unwrap().state,
            JobState::Running
        );
        // An import.
        s.insert_measurements(
            ("SN-3", Some("spider"), None),
            vec![rec("pre"), rec("main")],
            vec![NewMeasurement {
                job_id: None,
                source: "import",
                ..meas("m-imp", "-", "SN-3")
            }],
        )
        .await
        .unwrap();
        // The failed job ends for real now; a second end writes nothing.
        let p = Store::interrupted_problem();
        let none = JobRecords::default();
        assert!(s
            .end_running_job("j2", JobState::Failed, Some(&p), None, &[], &[], &none)
            .await
            .unwrap());
        assert!(!s
            .end_running_job("j2", JobState::Failed, Some(&p), None, &[], &[], &none)
            .await
            .unwrap());
        let rows = s.outbox_next(10).await.unwrap();
        let got: Vec<_> = rows
            .iter()
            .map(|r| (r.seq, r.kind, r.ref_id.as_str(), r.part_serial.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (1, OutboxKind::Measurement, "m1", "SN-1"),
                (2, OutboxKind::JobVerdicts, "j1", "SN-1"),
                (3, OutboxKind::Measurement, "m-imp", "SN-3"),
                (4, OutboxKind::JobVerdicts, "j2", "SN-2"),
            ]
        );
        // What the items carry, read back from the station's tables.
        let m = s.finished_measurement("m1", true).await.unwrap().unwrap();
        assert_eq!(m.measurement.id, "m1");
        assert_eq!(
            m.verdicts.iter().map(|v| v.id.as_str()).collect::<Vec<_>>(),
            ["v-m1"]
        );
        assert_eq!(m.recordings.len(), 2);
        assert_eq!(m.recordings[1].stored.bytes, vec![1, 2, 3, 4]);
        assert_eq!(m.software_version, springbench_core::VERSION);
        let jv = s.job_verdict_rows("j1").await.unwrap();
        assert_eq!(
            jv.iter().map(|v| v.0.id.as_str()).collect::<Vec<_>>(),
            ["v-j1"]
        );
        let light = s.finished_measurement("m1", false).await.unwrap().unwrap();
        assert!(light.recordings.is_empty());
        assert!(s
            .finished_measurement("nope", false)
            .await
            .unwrap()
            .is_none());

        let b = s.outbox_backlog().await.unwrap();
        assert_eq!((b.pending, b.delivered, b.last_seq), (4, 0, 4));
        s.outbox_delivered(&[1]).await.unwrap();
        let b = s.outbox_backlog().await.unwrap();
        assert_eq!((b.pending, b.delivered, b.last_seq), (3, 1, 4));
        assert_eq!(s.outbox_next(10).await.unwrap()[0].seq, 2);
    }

    /// A long-term test reaches the outbox while it runs (decision 0134):
    /// submitted, started, each interval's measurement at once and then the
    /// test's document, ambient values entered by hand, a user's pause asked,
    /// the pause, the pause ended, its end; the interval's measurement is not
    /// sent a second time at the job's end.
    #[tokio::test]
    async fn a_long_term_test_reaches_the_outbox_as_it_runs() {
        use crate::longterm::{LongTermEventKind, NewInterval, PauseCause};
        let s = Store::memory().await.unwrap();
        queued(&s, "lt", "SN-LT").await;
        s.add_long_term_test("lt").await.unwrap();
        assert!(s.start_job("lt").await.unwrap());
        s.insert_long_term_interval(
            "lt",
            NewInterval {
                index: 0,
                elapsed_s: 0.0,
                load_j: 0.0,
                accelerated: true,
                recordings: vec![rec("pre"), rec("main")],
                measurement: meas("m0", "lt", "SN-LT"),
                clock_s: 20.0,
                part: springbench_core::job::PartState {
                    load_j: 0.0,
                    k0_true_n_per_m: Some(2000.0),
                    true_load_j: Some(0.0),
                },
                document: None,
                ambient: Default::default(),
            },
        )
        .await
        .unwrap();
        // Ambient values entered by hand, a user's pause asked, the pause
        // as it happened, the pause ended.
        let ambient = springbench_core::job::Ambient {
            temperature_k: Some(296.15),
            relative_humidity_percent: None,
        };
        assert!(s.set_long_term_ambient("lt", 0, ambient).await.unwrap());
        assert!(s.set_long_term_pause("lt", Some(Some("op"))).await.unwrap());
        s.add_long_term_event(
            "lt",
            LongTermEventKind::Paused,
            PauseCause::User,
            20.0,
            "paused by op",
        )
        .await
        .unwrap();
        assert!(s.set_long_term_pause("lt", None).await.unwrap());
        let none = JobRecords::default();
        assert!(s
            .end_running_job("lt", JobState::Cancelled, None, None, &[], &[], &none)
            .await
            .unwrap());
        let rows = s.outbox_next(20).await.unwrap();
        let got: Vec<_> = rows
            .iter()
            .map(|r| (r.seq, r.kind, r.ref_id.as_str(), r.part_serial.as_str()))
            .collect();
        let lt = OutboxKind::LongTermTest;
        assert_eq!(
            got,
            [
                (1, lt, "lt", "SN-LT"),
                (2, lt, "lt", "SN-LT"),
                (3, OutboxKind::Measurement, "m0", "SN-LT"),
                (4, lt, "lt", "SN-LT"),
                (5, lt, "lt", "SN-LT"),
                (6, lt, "lt", "SN-LT"),
                (7, lt, "lt", "SN-LT"),
                (8, lt, "lt", "SN-LT"),
                (9, lt, "lt", "SN-LT"),
                (10, OutboxKind::JobVerdicts, "lt", "SN-LT"),
            ]
        );
    }

    /// A refused event holds the later events of its part, not of others.
    #[tokio::test]
    async fn a_refused_event_holds_its_part_only() {
        let s = Store::memory().await.unwrap();
        for (j, p) in [("a1", "A"), ("b1", "B"), ("a2", "A")] {
            queued(&s, j, p).await;
            assert!(s.start_job(j).await.unwrap());
            let none = JobRecords::default();
            let ended = s.end_running_job(j, JobState::Failed, None, None, &[], &[], &none);
            assert!(ended.await.unwrap());
        }
        // A job cancelled while queued ran nothing and sends nothing.
        queued(&s, "c1", "C").await;
        assert!(s.cancel_queued("c1").await.unwrap());
        let seqs: Vec<i64> = s
            .outbox_next(10)
            .await
            .unwrap()
            .iter()
            .map(|r| r.seq)
            .collect();
        assert_eq!(seqs, [1, 2, 3]);
        s.outbox_failed(&[1], "center: no such recipe", true)
            .await
            .unwrap();
        let next: Vec<_> = s
            .outbox_next(10)
            .await
            .unwrap()
            .iter()
            .map(|r| r.ref_id.clone())
            .collect();
        assert_eq!(next, ["b1"]);
        // Unreachable is not refused: nothing is held.
        s.outbox_failed(&[2], "connection refused", false)
            .await
            .unwrap();
        assert_eq!(s.outbox_next(10).await.unwrap().len(), 1);
        let b = s.outbox_backlog().await.unwrap();
        assert_eq!((b.pending, b.refused), (3, 1));
        assert_eq!(s.outbox_retry_refused().await.unwrap(), 1);
        assert_eq!(s.outbox_next(10).await.unwrap().len(), 3);
        assert_eq!(s.outbox_rows(0, 10).await.unwrap()[1].attempts, 1);
    }
}
