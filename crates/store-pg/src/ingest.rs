//! The center's ingest: a station's batch in one transaction, idempotent by
//! item id (decision 0036), and `ResultIngest::upsert_measurement` through
//! the same measurement upsert. Corrections and voids of the audit trail
//! are applied here too (from a station's item or at the center).

use crate::reads::recipe_from_row;
use crate::PgStore;
use springbench_store::fleet::{
    verdict_kind, CenterIngest, Correction, IngestConflict, IngestReport, ItemBody,
    JobVerdictsItem, LongTermTestItem, MeasurementItem, RecordingItem, ReplicationItem,
    StationHello, StationStatus, VerdictItem, CLOCK_SKEW_REPORT_S, CONTRACT_VERSION,
};
use springbench_store::results::{FinishedMeasurement, RecipeRow, ResultIngest, Upserted};
use springbench_store::{now, StoreError, StoreResult};
use sqlx::{Postgres, Row, Transaction};

type Tx<'a> = Transaction<'a, Postgres>;

/// Stores one recording (each distinct content once) and gives its id; a
/// reference that arrives later with its bytes keeps them.
async fn upsert_recording(
    tx: &mut Tx<'_>,
    r: &RecordingItem,
    station: Option<&str>,
    t: &str,
) -> StoreResult<i64> {
    let row = sqlx::query(
        "INSERT INTO recordings (sha256, kind, sample_rate_hz, frames, byte_len, wav, channel_scale_json, station_id, created_at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9) \
         ON CONFLICT (sha256) DO UPDATE SET wav = COALESCE(recordings.wav, EXCLUDED.wav) RETURNING id",
    )
    .bind(r.sha256.to_ascii_lowercase())
    .bind(&r.kind)
    .bind(r.sample_rate_hz)
    .bind(r.frames)
    .bind(r.byte_len)
    .bind(r.bytes.as_deref())
    .bind(
        r.channel_scale
            .map(|c| serde_json::to_string(&c).unwrap_or_default()),
    )
    .bind(station)
    .bind(t)
    .fetch_one(&mut **tx)
    .await?;
    Ok(row.get(0))
}

/// Stores verdicts (ignoring ids stored already) with one row per judged
/// parameter value (SPC reads those).
async fn insert_verdicts(
    tx: &mut Tx<'_>,
    verdicts: &[VerdictItem],
    station: Option<&str>,
    level_index: Option<i64>,
) -> StoreResult<()> {
    for v in verdicts {
        let kind = verdict_kind(&v.verdict).ok_or_else(|| {
            StoreError::Invalid(format!("verdict {}: unknown kind '{}'", v.id, v.verdict))
        })?;
        let seq: Option<i64> = sqlx::query_scalar(
            // A job's verdict that arrives after a void of one of its
            // measurements arrives voided (decision 0057).
            "INSERT INTO qc_verdicts (id, station_id, job_id, measurement_id, part_serial, recipe_name, recipe_version, \
             recipe_sha256, verdict, detail_json, trace_json, created_at, level_index, voided) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10::jsonb, $11::jsonb, $12, $13, \
             $4::text IS NULL AND EXISTS (SELECT 1 FROM measurements m WHERE m.job_id = $3 AND m.void_id IS NOT NULL)) \
             ON CONFLICT (id) DO NOTHING RETURNING seq",
        )
        .bind(&v.id)
        .bind(station)
        .bind(&v.job_id)
        .bind(&v.measurement_id)
        .bind(&v.part_serial)
        .bind(&v.recipe_name)
        .bind(v.recipe_version)
        .bind(&v.recipe_sha256)
        .bind(kind)
        .bind(v.detail.to_string())
        .bind(v.trace.to_string())
        .bind(&v.created_at)
        .bind(level_index)
        .fetch_optional(&mut **tx)
        .await?;
        if let (Some(seq), Some(_)) = (seq, v.measurement_id.as_ref()) {
            sqlx::query(
                "INSERT INTO verdict_values (verdict_seq, parameter, value, recipe_name) \
                 SELECT $1, p->>'name', (p->>'value')::float8, $3 \
                 FROM jsonb_array_elements(CASE WHEN jsonb_typeof($2::jsonb->'parameters') = 'array' \
                                           THEN $2::jsonb->'parameters' ELSE '[]'::jsonb END) p \
                 WHERE jsonb_typeof(p->'value') = 'number' AND jsonb_typeof(p->'name') = 'string' \
                 ON CONFLICT DO NOTHING",
            )
            .bind(seq)
            .bind(v.detail.to_string())
            .bind(&v.recipe_name)
            .execute(&mut **tx)
            .await?;
            if kind != "invalid" {
                add_to_spc_points(tx, seq).await?;
            }
        }
    }
    Ok(())
}

/// Adds a measurement verdict's values to their SPC points (migration
/// 0270): one row per point and parameter, its repeats summed.
async fn add_to_spc_points(tx: &mut Tx<'_>, verdict_seq: i64) -> StoreResult<()> {
    sqlx::query(
        "INSERT INTO spc_points (recipe_name, parameter, point_key, station_id, job_id, level_index, \
         first_seq, last_seq, n, value_sum, any_fail, min_verdict) \
         SELECT v.recipe_name, x.parameter, spc_point_key(v.station_id, v.job_id, v.seq, v.level_index), \
                v.station_id, v.job_id, v.level_index, v.seq, v.seq, 1, x.value, v.verdict = 'fail', v.verdict \
         FROM qc_verdicts v JOIN verdict_values x ON x.verdict_seq = v.seq WHERE v.seq = $1 \
         ON CONFLICT (recipe_name, parameter, point_key) DO UPDATE SET \
         first_seq = LEAST(spc_points.first_seq, EXCLUDED.first_seq), \
         last_seq = GREATEST(spc_points.last_seq, EXCLUDED.last_seq), \
         n = spc_points.n + 1, value_sum = spc_points.value_sum + EXCLUDED.value_sum, \
         any_fail = spc_points.any_fail OR EXCLUDED.any_fail, \
         min_verdict = LEAST(spc_points.min_verdict, EXCLUDED.min_verdict)",
    )
    .bind(verdict_seq)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// Recomputes the SPC points of a voided measurement's verdicts from the
/// verdicts left (a point of no verdict left goes: its rows are derived).
async fn recompute_spc_points(tx: &mut Tx<'_>, measurement_id: &str) -> StoreResult<()> {
    let keys = "SELECT DISTINCT recipe_name, station_id, job_id, level_index, \
                spc_point_key(station_id, job_id, seq, level_index) AS point_key \
                FROM qc_verdicts WHERE measurement_id = $1";
    sqlx::query(sqlx::AssertSqlSafe(format!(
        "DELETE FROM spc_points p USING ({keys}) k \
         WHERE p.recipe_name = k.recipe_name AND p.point_key = k.point_key"
    )))
    .bind(measurement_id)
    .execute(&mut **tx)
    .await?;
    // A point of a job: its other repeats (a verdict without a job is a
    // point of its own, gone with its void).
    sqlx::query(sqlx::AssertSqlSafe(format!(
        "INSERT INTO spc_points (recipe_name, parameter, point_key, station_id, job_id, level_index, \
         first_seq, last_seq, n, value_sum, any_fail, min_verdict) \
         SELECT v.recipe_name, x.parameter, k.point_key, k.station_id, k.job_id, k.level_index, \
                MIN(v.seq), MAX(v.seq), COUNT(*), SUM(x.value), bool_or(v.verdict = 'fail'), MIN(v.verdict) \
         FROM ({keys}) k JOIN qc_verdicts v ON v.job_id = k.job_id AND v.recipe_name = k.recipe_name \
              AND v.station_id IS NOT DISTINCT FROM k.station_id AND v.level_index IS NOT DISTINCT FROM k.level_index \
         JOIN verdict_values x ON x.verdict_seq = v.seq \
         WHERE v.measurement_id IS NOT NULL AND NOT v.voided AND v.verdict <> 'invalid' \
         GROUP BY v.recipe_name, x.parameter, k.point_key, k.station_id, k.job_id, k.level_index"
    )))
    .bind(measurement_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// The measurement upsert both paths share: the part, the recordings, the
/// calibration record, the measurement, its verdicts; nothing when its id
/// is stored already. `m` has been checked ([`MeasurementItem::to_finished`]).
async fn upsert_measurement_tx(
    tx: &mut Tx<'_>,
    station: Option<&str>,
    m: &MeasurementItem,
) -> StoreResult<Upserted> {
    let known: Option<i64> = sqlx::query_scalar("SELECT seq FROM measurements WHERE id = $1")
        .bind(&m.id)
        .fetch_optional(&mut **tx)
        .await?;
    if known.is_some() {
        return Ok(Upserted::AlreadyStored);
    }
    let t = &m.created_at;
    // A part measured on several stations: as old as its oldest measurement,
    // its station the one of its newest.
    sqlx::query(
        "INSERT INTO parts (serial, kind, notes, created_at, updated_at, station_id) VALUES ($1, $2, $3, $4, $4, $5) \
         ON CONFLICT (serial) DO UPDATE SET kind = COALESCE(EXCLUDED.kind, parts.kind), \
         notes = COALESCE(EXCLUDED.notes, parts.notes), \
         created_at = LEAST(parts.created_at, EXCLUDED.created_at), \
         station_id = CASE WHEN EXCLUDED.updated_at >= parts.updated_at THEN EXCLUDED.station_id ELSE parts.station_id END, \
         updated_at = GREATEST(parts.updated_at, EXCLUDED.updated_at)",
    )
    .bind(&m.part_serial)
    .bind(&m.part_kind)
    .bind(&m.part_notes)
    .bind(t)
    .bind(station)
    .execute(&mut **tx)
    .await?;
    let pre = upsert_recording(tx, &m.pre, station, t).await?;
    let main = upsert_recording(tx, &m.main, station, t).await?;
    if let Some(c) = &m.calibration {
        sqlx::query(
            "INSERT INTO calibrations (station_id, id, bench_id, job_id, passed, calibration_json, sensors_json, result_json, created_at) \
             VALUES ($1, $2, $3, $4, $5, $6::jsonb, $7::jsonb, $8::jsonb, $9) ON CONFLICT DO NOTHING",
        )
        .bind(station.unwrap_or(""))
        .bind(&c.id)
        .bind(&c.bench_id)
        .bind(&c.job_id)
        .bind(c.passed)
        .bind(c.calibration.to_string())
        .bind(c.sensors.to_string())
        .bind(c.result.to_json())
        .bind(&c.created_at)
        .execute(&mut **tx)
        .await?;
    }
    sqlx::query(
        "INSERT INTO measurements (id, station_id, part_serial, job_id, source, bench_id, software_version, config_json, \
         meta_json, result_json, analysis_error, target_xpeak_m, repeat_index, level_index, pre_recording_id, \
         main_recording_id, calibration_id, created_at, ingested_at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8::jsonb, $9::jsonb, $10::jsonb, $11, $12, $13, $14, $15, $16, $17, $18, $19)",
    )
    .bind(&m.id)
    .bind(station)
    .bind(&m.part_serial)
    .bind(&m.job_id)
    .bind(&m.source)
    .bind(&m.bench_id)
    .bind(&m.software_version)
    .bind(m.config.to_string())
    .bind(m.meta.to_string())
    .bind(m.result.as_ref().map(|v| v.to_string()))
    .bind(&m.analysis_error)
    .bind(m.target_xpeak_m)
    .bind(m.repeat_index)
    .bind(m.level_index)
    .bind(pre)
    .bind(main)
    .bind(m.calibration.as_ref().map(|c| c.id.clone()))
    .bind(t)
    .bind(now())
    .execute(&mut **tx)
    .await?;
    insert_verdicts(tx, &m.verdicts, station, m.level_index).await?;
    Ok(Upserted::Inserted)
}

/// Checks a job's verdicts item: every verdict of this job and part, none of a measurement.
fn check_job_verdicts(j: &JobVerdictsItem) -> Result<(), String> {
    for v in &j.verdicts {
        if v.job_id.as_deref() != Some(j.job_id.as_str()) || v.measurement_id.is_some() {
            return Err(format!(
                "verdict {} is not the verdict of job {}",
                v.id, j.job_id
            ));
        }
        if v.part_serial != j.part_serial {
            return Err(format!(
                "verdict {} is of part '{}', job {} of '{}'",
                v.id, v.part_serial, j.job_id, j.part_serial
            ));
        }
        v.to_new()?;
    }
    Ok(())
}

/// The ids a station's rows may carry: its own and its former names
/// (a rename keeps the rows as they were made, decision 0105).
pub(crate) async fn owned_ids(tx: &mut Tx<'_>, station: &str) -> StoreResult<Vec<String>> {
    let mut ids: Vec<String> =
        sqlx::query_scalar("SELECT former_id FROM station_names WHERE station_id = $1")
            .bind(station)
            .fetch_all(&mut **tx)
            .await?;
    ids.push(station.to_string());
    Ok(ids)
}

/// A station voids or moves only a measurement it made (under its id or
/// a former one); the center itself (station None) any.
async fn check_owner(
    tx: &mut Tx<'_>,
    station: Option<&str>,
    measurement: &str,
    what: &str,
) -> Result<(), String> {
    let Some(st) = station else { return Ok(()) };
    let owner: Option<Option<String>> =
        sqlx::query_scalar("SELECT station_id FROM measurements WHERE id = $1")
            .bind(measurement)
            .fetch_optional(&mut **tx)
            .await
            .map_err(|e| e.to_string())?;
    let Some(owner) = owner else {
        return Err(format!("no measurement {measurement} at the center"));
    };
    let owned = owned_ids(tx, st).await.map_err(|e| e.to_string())?;
    match owner {
        Some(o) if owned.contains(&o) => Ok(()),
        o => Err(format!(
            "measurement {measurement} was made by station {}; station {st} {what} its own measurements only",
            o.as_deref().unwrap_or("(the center)")
        )),
    }
}

/// Applies a correction and writes its audit row; false when its id is
/// stored already. Nothing is deleted: a serial correction moves the
/// measurements and verdicts (the old part row stays, with its history in
/// `corrections`); a void marks the measurement and takes its verdicts out
/// of SPC and yield.
pub(crate) async fn apply_correction(
    tx: &mut Tx<'_>,
    station: Option<&str>,
    c: &Correction,
) -> StoreResult<bool> {
    let bad = |m: String| StoreError::Invalid(format!("correction {}: {m}", c.id));
    springbench_store::corrections::check(c)?;
    let known: Option<i64> = sqlx::query_scalar("SELECT seq FROM corrections WHERE id = $1")
        .bind(&c.id)
        .fetch_optional(&mut **tx)
        .await?;
    if known.is_some() {
        return Ok(false);
    }
    match c.kind.as_str() {
        "void_measurement" => {
            let m = c
                .measurement_id
                .as_deref()
                .ok_or_else(|| bad("a void names its measurement".into()))?;
            check_owner(tx, station, m, "voids").await.map_err(bad)?;
            let r = sqlx::query(
                "UPDATE measurements SET void_id = COALESCE(void_id, $2) WHERE id = $1",
            )
            .bind(m)
            .bind(&c.id)
            .execute(&mut **tx)
            .await?;
            if r.rows_affected() == 0 {
                return Err(bad(format!("no measurement {m} at the center")));
            }
            sqlx::query("UPDATE qc_verdicts SET voided = true WHERE measurement_id = $1")
                .bind(m)
                .execute(&mut **tx)
                .await?;
            // Its job's verdict no longer judges the part or counts in the
            // yield (decision 0057); it stays readable as judged.
            sqlx::query(
                "UPDATE qc_verdicts SET voided = true WHERE measurement_id IS NULL \
                 AND job_id = (SELECT job_id FROM measurements WHERE id = $1)",
            )
            .bind(m)
            .execute(&mut **tx)
            .await?;
            recompute_spc_points(tx, m).await?;
        }
        "part_kind" => {
            if let Some(st) = station {
                // A station sets the kind of a part it measured, no other's.
                let measured: Option<i32> = sqlx::query_scalar(
                    "SELECT 1 FROM measurements WHERE part_serial = $1 AND station_id = ANY($2) LIMIT 1",
                )
                .bind(&c.part_serial)
                .bind(owned_ids(tx, st).await?)
                .fetch_optional(&mut **tx)
                .await?;
                if measured.is_none() {
                    return Err(bad(format!(
                        "station {st} measured no part '{}' at the center; a station corrects its own parts only",
                        c.part_serial
                    )));
                }
            }
            let r = sqlx::query("UPDATE parts SET kind = $2, updated_at = GREATEST(updated_at, $3) WHERE serial = $1")
                .bind(&c.part_serial)
                .bind(&c.new_value)
                .bind(&c.made_at)
                .execute(&mut **tx)
                .await?;
            if r.rows_affected() == 0 {
                return Err(bad(format!("no part '{}' at the center", c.part_serial)));
            }
        }
        "part_serial" => {
            let new = c
                .new_value
                .as_deref()
                .filter(|s| !s.is_empty())
                .ok_or_else(|| bad("a serial correction names the new serial".into()))?;
            if let Some(m) = c.measurement_id.as_deref() {
                check_owner(tx, station, m, "moves").await.map_err(bad)?;
            }
            let owned = match station {
                Some(st) => Some(owned_ids(tx, st).await?),
                None => None,
            };
            let r = sqlx::query(
                "INSERT INTO parts (serial, kind, notes, created_at, updated_at, station_id) \
                 SELECT $2, kind, notes, created_at, updated_at, station_id FROM parts WHERE serial = $1 \
                 ON CONFLICT (serial) DO NOTHING",
            )
            .bind(&c.part_serial)
            .bind(new)
            .execute(&mut **tx)
            .await?;
            let exists: Option<i32> = sqlx::query_scalar("SELECT 1 FROM parts WHERE serial = $1")
                .bind(&c.part_serial)
                .fetch_optional(&mut **tx)
                .await?;
            if exists.is_none() {
                return Err(bad(format!("no part '{}' at the center", c.part_serial)));
            }
            let _ = r;
            // One measurement, or the whole part as the correcting station
            // measured it: a station's correction moves its own measurements
            // and verdicts only (another line's of the same serial are that
            // line's to correct); one made at the center (station None)
            // moves every station's.
            sqlx::query(
                "UPDATE measurements SET part_serial = $2 WHERE part_serial = $1 AND ($3::text IS NULL OR id = $3) \
                 AND ($4::text[] IS NULL OR station_id = ANY($4))",
            )
            .bind(&c.part_serial)
            .bind(new)
            .bind(&c.measurement_id)
            .bind(&owned)
            .execute(&mut **tx)
            .await?;
            sqlx::query(
                "UPDATE qc_verdicts SET part_serial = $2 WHERE part_serial = $1 \
                 AND ($3::text IS NULL OR measurement_id = $3) AND ($4::text[] IS NULL OR station_id = ANY($4))",
            )
            .bind(&c.part_serial)
            .bind(new)
            .bind(&c.measurement_id)
            .bind(&owned)
            .execute(&mut **tx)
            .await?;
        }
        k => {
            return Err(bad(format!(
                "kind 'part_serial', 'part_kind' or 'void_measurement', got '{k}'"
            )))
        }
    }
    sqlx::query(
        "INSERT INTO corrections (id, station_id, kind, part_serial, measurement_id, old_value, new_value, reason, \
         made_by, made_at, applied_at) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)",
    )
    .bind(&c.id)
    .bind(station)
    .bind(&c.kind)
    .bind(&c.part_serial)
    .bind(&c.measurement_id)
    .bind(&c.old_value)
    .bind(&c.new_value)
    .bind(&c.reason)
    .bind(&c.made_by)
    .bind(&c.made_at)
    .bind(now())
    .execute(&mut **tx)
    .await?;
    Ok(true)
}

/// Applies one item's body (checked first; a contradiction refuses the batch).
async fn apply_item(tx: &mut Tx<'_>, station: &str, item: &ReplicationItem) -> StoreResult<()> {
    let refuse = |e: String| {
        StoreError::Invalid(format!(
            "item {} ({}) of station {station}: {e}",
            item.seq,
            item.item_id()
        ))
    };
    match &item.body {
        ItemBody::Measurement(m) => {
            m.to_finished().map_err(refuse)?;
            upsert_measurement_tx(tx, Some(station), m).await?;
        }
        ItemBody::JobVerdicts(j) => {
            check_job_verdicts(j).map_err(refuse)?;
            insert_verdicts(tx, &j.verdicts, Some(station), None).await?;
        }
        ItemBody::Correction(c) => {
            apply_correction(tx, Some(station), c).await?;
        }
        ItemBody::LongTermTest(t) => {
            t.check().map_err(refuse)?;
            apply_long_term_test(tx, station, item.seq, t)
                .await?
                .map_err(refuse)?;
        }
    }
    Ok(())
}

/// Keeps the newest document of a station's long-term test (by the
/// station's seq; a resend of the same seq replaces it). A test id another
/// station holds is refused.
async fn apply_long_term_test(
    tx: &mut Tx<'_>,
    station: &str,
    seq: i64,
    t: &LongTermTestItem,
) -> StoreResult<Result<(), String>> {
    let held: Option<String> =
        sqlx::query_scalar("SELECT station_id FROM long_term_tests WHERE job_id = $1")
            .bind(&t.job_id)
            .fetch_optional(&mut **tx)
            .await?;
    if let Some(by) = held.filter(|by| by != station) {
        return Ok(Err(format!(
            "long-term test {} is held from station {by}",
            t.job_id
        )));
    }
    sqlx::query(
        "INSERT INTO long_term_tests (job_id, station_id, part_serial, bench_id, job_state, created_at, \
         item_seq, document_json, summary_json, last_signals_at_station, received_at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11) \
         ON CONFLICT (job_id) DO UPDATE SET part_serial = EXCLUDED.part_serial, bench_id = EXCLUDED.bench_id, \
         job_state = EXCLUDED.job_state, created_at = EXCLUDED.created_at, item_seq = EXCLUDED.item_seq, \
         document_json = EXCLUDED.document_json, summary_json = EXCLUDED.summary_json, \
         last_signals_at_station = EXCLUDED.last_signals_at_station, received_at = EXCLUDED.received_at \
         WHERE long_term_tests.item_seq <= EXCLUDED.item_seq",
    )
    .bind(&t.job_id)
    .bind(station)
    .bind(&t.part_serial)
    .bind(&t.bench_id)
    .bind(&t.job_state)
    .bind(&t.created_at)
    .bind(seq)
    .bind(t.document.to_string())
    .bind(t.summary.to_string())
    .bind(t.last_signals_at_station)
    .bind(now())
    .execute(&mut **tx)
    .await?;
    Ok(Ok(()))
}

impl ResultIngest for PgStore {
    async fn upsert_measurement(&self, f: &FinishedMeasurement) -> StoreResult<Upserted> {
        if f.measurement.part_serial != f.part.0 {
            return Err(StoreError::Invalid(format!(
                "measurement {} is of part '{}', not of '{}'",
                f.measurement.id, f.measurement.part_serial, f.part.0
            )));
        }
        let item = MeasurementItem::from_finished(f, None, true).map_err(StoreError::Invalid)?;
        item.to_finished().map_err(StoreError::Invalid)?;
        let mut tx = self.pool.begin().await?;
        let done = upsert_measurement_tx(&mut tx, None, &item).await?;
        tx.commit().await?;
        Ok(done)
    }
}

fn status_from_row(r: &sqlx::postgres::PgRow) -> StoreResult<StationStatus> {
    let items: i64 = r.get("items");
    let distinct: i64 = r.get("distinct_seqs");
    let last_seq: Option<i64> = r.get("last_seq");
    Ok(StationStatus {
        station_id: r.get("station_id"),
        software_version: r.get("software_version"),
        contract_version: r.get::<i32, _>("contract_version") as u32,
        bench_states: crate::parse_json(&r.get::<String, _>("bench_states")).and_then(|v| {
            serde_json::from_value(v).map_err(|e| StoreError::Corrupt(e.to_string()))
        })?,
        backlog_items: r.get("backlog_items"),
        oldest_backlog_at: r.get("oldest_backlog_at"),
        sent_at: r.get("sent_at"),
        last_contact_at: r.get("last_contact_at"),
        first_contact_at: r.get("first_contact_at"),
        items,
        last_seq,
        missing_items: last_seq.map_or(0, |l| (l - distinct).max(0)),
        clock_skew_s: r.get("clock_skew_s"),
        refused: r.get("refused"),
        retired_at: r.get("retired_at"),
        renamed_to: r.get("renamed_to"),
    })
}

const STATION_SELECT: &str = "SELECT s.station_id, s.software_version, s.contract_version, s.bench_states::text AS bench_states, \
     s.backlog_items, s.oldest_backlog_at, s.sent_at, s.first_contact_at, s.last_contact_at, \
     s.items, s.distinct_seqs, s.last_seq, s.clock_skew_s, s.retired_at, s.renamed_to, \
     (SELECT COUNT(*) FROM ingest_refusals r WHERE r.station_id = s.station_id) AS refused FROM stations s";

/// What a batch added to a station's stream: items claimed, outbox seqs
/// new to the center, the highest seq claimed.
#[derive(Default)]
struct Held {
    items: i64,
    new_seqs: i64,
    last_seq: Option<i64>,
}

/// The center's time of a contact, and what the batch added to the
/// station's counters (`stations()` reads them, never counts); a station
/// heard of in a batch before its first hello gets a row that says so.
async fn touch_station(tx: &mut Tx<'_>, station: &str, t: &str, held: &Held) -> StoreResult<()> {
    sqlx::query(
        "INSERT INTO stations (station_id, software_version, contract_version, bench_states, backlog_items, \
         sent_at, first_contact_at, last_contact_at, items, distinct_seqs, last_seq) \
         VALUES ($1, 'unknown (no hello yet)', 1, '[]', 0, $2, $2, $2, $3, $4, $5) \
         ON CONFLICT (station_id) DO UPDATE SET last_contact_at = EXCLUDED.last_contact_at, \
         items = stations.items + EXCLUDED.items, distinct_seqs = stations.distinct_seqs + EXCLUDED.distinct_seqs, \
         last_seq = GREATEST(stations.last_seq, EXCLUDED.last_seq)",
    )
    .bind(station)
    .bind(t)
    .bind(held.items)
    .bind(held.new_seqs)
    .bind(held.last_seq)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

impl CenterIngest for PgStore {
    async fn hello(&self, h: &StationHello) -> StoreResult<StationStatus> {
        if h.station_id.is_empty() {
            return Err(StoreError::Invalid("hello: station_id is empty".into()));
        }
        if h.contract_version == 0 || h.contract_version > CONTRACT_VERSION {
            return Err(StoreError::Invalid(format!(
                "hello of station {}: contract version {} is unknown to this center (it knows 1 to {CONTRACT_VERSION})",
                h.station_id, h.contract_version
            )));
        }
        let t = now();
        let skew = clock_skew_s(&h.sent_at, &t);
        if let Some(x) = skew.filter(|x| x.abs() > CLOCK_SKEW_REPORT_S) {
            tracing::warn!(
                station = %h.station_id,
                skew_s = x,
                "fleet: the station's clock is {x:.0} s off the center's (its measurements keep their own time)"
            );
        }
        let states = serde_json::to_string(&h.bench_states)
            .map_err(|e| StoreError::Invalid(e.to_string()))?;
        sqlx::query(
            "INSERT INTO stations (station_id, software_version, contract_version, bench_states, backlog_items, \
             oldest_backlog_at, sent_at, first_contact_at, last_contact_at, clock_skew_s) \
             VALUES ($1, $2, $3, $4::jsonb, $5, $6, $7, $8, $8, $9) \
             ON CONFLICT (station_id) DO UPDATE SET software_version = EXCLUDED.software_version, \
             contract_version = EXCLUDED.contract_version, bench_states = EXCLUDED.bench_states, \
             backlog_items = EXCLUDED.backlog_items, oldest_backlog_at = EXCLUDED.oldest_backlog_at, \
             sent_at = EXCLUDED.sent_at, last_contact_at = EXCLUDED.last_contact_at, \
             clock_skew_s = EXCLUDED.clock_skew_s",
        )
        .bind(&h.station_id)
        .bind(&h.software_version)
        .bind(h.contract_version as i32)
        .bind(states)
        .bind(h.backlog_items)
        .bind(&h.oldest_backlog_at)
        .bind(&h.sent_at)
        .bind(&t)
        .bind(skew)
        .execute(&self.pool)
        .await?;
        let row = sqlx::query(sqlx::AssertSqlSafe(format!(
            "{STATION_SELECT} WHERE s.station_id = $1"
        )))
        .bind(&h.station_id)
        .fetch_one(&self.pool)
        .await?;
        status_from_row(&row)
    }

    async fn ingest(&self, station: &str, items: &[ReplicationItem]) -> StoreResult<IngestReport> {
        if station.is_empty() {
            return Err(StoreError::Invalid("ingest: station_id is empty".into()));
        }
        let t = now();
        let mut report = IngestReport::default();
        let mut tx = self.pool.begin().await?;
        let mut held = Held::default();
        for item in items {
            let id = item.item_id();
            let sha = item.content_sha256();
            // RETURNING: whether the center held no other item with this seq
            // (the subquery sees the rows before this insert, the batch's
            // earlier items included).
            let claimed: Option<bool> = sqlx::query_scalar(
                "INSERT INTO station_items (item_id, station_id, seq, content_sha256, received_at) \
                 VALUES ($1, $2, $3, $4, $5) ON CONFLICT (item_id) DO NOTHING \
                 RETURNING NOT EXISTS (SELECT 1 FROM station_items x WHERE x.station_id = $2 AND x.seq = $3)",
            )
            .bind(&id)
            .bind(station)
            .bind(item.seq)
            .bind(&sha)
            .bind(&t)
            .fetch_optional(&mut *tx)
            .await?;
            if let Some(new_seq) = claimed {
                held.items += 1;
                if new_seq {
                    held.new_seqs += 1;
                }
                held.last_seq = held.last_seq.max(Some(item.seq));
                if let Err(e) = apply_item(&mut tx, station, item).await {
                    drop(tx);
                    return Err(self.refused(station, &id, item, e).await);
                }
                report.inserted += 1;
                continue;
            }
            let held = sqlx::query(
                "SELECT station_id, content_sha256 FROM station_items WHERE item_id = $1",
            )
            .bind(&id)
            .fetch_one(&mut *tx)
            .await?;
            let (by, held_sha): (String, String) = (held.get(0), held.get(1));
            let reason = if by != station {
                format!("item {id} is held from station {by}")
            } else if held_sha != sha && matches!(item.body, ItemBody::LongTermTest(_)) {
                // A long-term test's document is built when sent: a resend
                // of the same seq (a lost acknowledgement) may carry a newer
                // one. It replaces the held one (decision 0134).
                if let Err(e) = apply_item(&mut tx, station, item).await {
                    drop(tx);
                    return Err(self.refused(station, &id, item, e).await);
                }
                sqlx::query("UPDATE station_items SET content_sha256 = $2 WHERE item_id = $1")
                    .bind(&id)
                    .bind(&sha)
                    .execute(&mut *tx)
                    .await?;
                report.already_stored += 1;
                continue;
            } else if held_sha != sha {
                format!("item {id} is held with another content (SHA-256 {held_sha}, this one {sha}); the first copy stays")
            } else {
                report.already_stored += 1;
                continue;
            };
            sqlx::query(
                "INSERT INTO ingest_conflicts (station_id, item_seq, item_id, content_sha256, reason, item_json, received_at) \
                 VALUES ($1, $2, $3, $4, $5, $6::jsonb, $7)",
            )
            .bind(station)
            .bind(item.seq)
            .bind(&id)
            .bind(&sha)
            .bind(&reason)
            .bind(serde_json::to_string(item).unwrap_or_else(|_| "null".into()))
            .bind(&t)
            .execute(&mut *tx)
            .await?;
            report.conflicts.push(IngestConflict {
                seq: item.seq,
                item_id: id,
                reason,
            });
        }
        touch_station(&mut tx, station, &t, &held).await?;
        tx.commit().await?;
        Ok(report)
    }

    async fn recipes(&self) -> StoreResult<Vec<RecipeRow>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            crate::reads::recipe_cols!(),
            " FROM qc_recipes ORDER BY name, version"
        ))
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(recipe_from_row).collect()
    }

    async fn stations(&self) -> StoreResult<Vec<StationStatus>> {
        let rows = sqlx::query(sqlx::AssertSqlSafe(format!(
            "{STATION_SELECT} ORDER BY s.station_id"
        )))
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(status_from_row).collect()
    }
}

/// The station's clock minus the center's (s), None when `sent_at` is unreadable.
fn clock_skew_s(sent_at: &str, center: &str) -> Option<f64> {
    let a = chrono::DateTime::parse_from_rfc3339(sent_at).ok()?;
    let b = chrono::DateTime::parse_from_rfc3339(center).ok()?;
    Some((a - b).num_milliseconds() as f64 / 1000.0)
}

/// An error of one item's apply as the station should see it: a value the
/// database refuses (a data exception: a NUL byte, bytes not UTF-8, a
/// number out of range; an integrity or size limit) is the item's fault,
/// `Invalid`, not an outage, so the station parks it and goes on; the
/// reason names the item, not the database's internals.
impl PgStore {
    /// An item whose application failed: nothing of its batch is written
    /// (the caller dropped the transaction). An item the center refuses (it
    /// contradicts itself or the center's rules, or its values do not fit the
    /// database: a NUL byte) is recorded with its reason, so the readers of
    /// the fleet see it, and the station parks it (decision 0105).
    async fn refused(
        &self,
        station: &str,
        id: &str,
        item: &ReplicationItem,
        e: StoreError,
    ) -> StoreError {
        let e = as_refusal(e, item);
        if let StoreError::Invalid(why) = &e {
            let _ = self
                .record_refusal(station, Some(station), id, Some(item.seq), why)
                .await;
        }
        e
    }
}

fn as_refusal(e: StoreError, item: &ReplicationItem) -> StoreError {
    let name = format!("item {} ({})", item.seq, item.item_id());
    match e {
        StoreError::Invalid(why) if why.starts_with("item ") => StoreError::Invalid(why),
        StoreError::Invalid(why) => StoreError::Invalid(format!("{name}: {why}")),
        StoreError::Db(sqlx::Error::Database(d)) => {
            let code = d.code().map(|c| c.to_string()).unwrap_or_default();
            let why = match code.as_str() {
                "22021" | "22P05" => {
                    "a text holds a NUL byte or a character the database cannot store".to_string()
                }
                c if c.starts_with("22") => format!("a value out of the database's range ({c})"),
                c if c.starts_with("23") => {
                    format!("a value breaks one of the center's rules ({c})")
                }
                c if c.starts_with("54") => format!("a value too long for the center ({c})"),
                _ => return StoreError::Db(sqlx::Error::Database(d)),
            };
            StoreError::Invalid(format!("{name}: refused by the center's database: {why}"))
        }
        e => e,
    }
}

/// A refused request or item, as the fleet's readers see it.
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct Refusal {
    pub seq: i64,
    /// The station id the request claimed.
    pub station_id: String,
    /// The station its credential belongs to (null: no valid credential).
    pub credential_station: Option<String>,
    /// The refused item's id (`measurement:<id>`, ...); empty: a request.
    pub item_id: String,
    pub item_seq: Option<i64>,
    pub reason: String,
    /// The center's clock: first and last time, and how often.
    pub first_at: String,
    pub last_at: String,
    pub times: i64,
}

/// A station of the center's configuration: its id, former ids, retired.
#[derive(Debug, Clone)]
pub struct StationRegistration {
    pub station_id: String,
    pub former_ids: Vec<String>,
    pub retired: bool,
}

impl PgStore {
    /// Records a refused request or item (one row per claimed station,
    /// item and reason; a repeat counts up).
    pub async fn record_refusal(
        &self,
        station: &str,
        credential_station: Option<&str>,
        item_id: &str,
        item_seq: Option<i64>,
        reason: &str,
    ) -> StoreResult<()> {
        let t = now();
        // What the database cannot hold is replaced (the reason is for people).
        let clean = |s: &str| s.replace('\0', "\u{fffd}");
        sqlx::query(
            "INSERT INTO ingest_refusals (station_id, credential_station, item_id, item_seq, reason, first_at, last_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $6) ON CONFLICT (station_id, item_id, reason) DO UPDATE SET \
             last_at = EXCLUDED.last_at, times = ingest_refusals.times + 1, \
             credential_station = EXCLUDED.credential_station, item_seq = EXCLUDED.item_seq",
        )
        .bind(clean(station))
        .bind(credential_station.map(clean))
        .bind(clean(item_id))
        .bind(item_seq)
        .bind(clean(reason))
        .bind(&t)
        .execute(&self.pool)
        .await?;
        tracing::warn!(station, item_id, "fleet: refused: {reason}");
        Ok(())
    }

    /// The refusals, newest first, of one station (claimed id) or all.
    pub async fn refusals(
        &self,
        station: Option<&str>,
        before: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<Refusal>> {
        let rows = sqlx::query(
            "SELECT seq, station_id, credential_station, item_id, item_seq, reason, first_at, last_at, times \
             FROM ingest_refusals WHERE ($1::text IS NULL OR station_id = $1) AND ($2::bigint IS NULL OR seq < $2) \
             ORDER BY seq DESC LIMIT $3",
        )
        .bind(station)
        .bind(before)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows
            .iter()
            .map(|r| Refusal {
                seq: r.get("seq"),
                station_id: r.get("station_id"),
                credential_station: r.get("credential_station"),
                item_id: r.get("item_id"),
                item_seq: r.get("item_seq"),
                reason: r.get("reason"),
                first_at: r.get("first_at"),
                last_at: r.get("last_at"),
                times: r.get("times"),
            })
            .collect())
    }

    /// Applies the center's configured stations at start: a rename
    /// (`former_ids`) once, in one transaction: the former id's rows keep
    /// their id (history), the station owns them under its new id, and the
    /// center's record of the stream (items held, sequence numbers) moves
    /// to the new id so that no false gap appears; a retirement marks the
    /// station (its history stays, its token is refused).
    pub async fn register_stations(&self, stations: &[StationRegistration]) -> StoreResult<()> {
        let t = now();
        let mut tx = self.pool.begin().await?;
        for s in stations {
            for old in &s.former_ids {
                let new: Option<String> = sqlx::query_scalar(
                    "INSERT INTO station_names (former_id, station_id, renamed_at) VALUES ($1, $2, $3) \
                     ON CONFLICT (former_id) DO NOTHING RETURNING station_id",
                )
                .bind(old)
                .bind(&s.station_id)
                .bind(&t)
                .fetch_optional(&mut *tx)
                .await?;
                if new.is_none() {
                    continue;
                }
                // A station renamed twice: its older names follow.
                sqlx::query("UPDATE station_names SET station_id = $2 WHERE station_id = $1")
                    .bind(old)
                    .bind(&s.station_id)
                    .execute(&mut *tx)
                    .await?;
                sqlx::query("UPDATE station_items SET station_id = $2 WHERE station_id = $1")
                    .bind(old)
                    .bind(&s.station_id)
                    .execute(&mut *tx)
                    .await?;
                sqlx::query(
                    "INSERT INTO stations (station_id, software_version, contract_version, bench_states, backlog_items, \
                     sent_at, first_contact_at, last_contact_at, items, distinct_seqs, last_seq) \
                     SELECT $2, software_version, contract_version, bench_states, backlog_items, sent_at, \
                     first_contact_at, last_contact_at, items, distinct_seqs, last_seq FROM stations WHERE station_id = $1 \
                     ON CONFLICT (station_id) DO UPDATE SET items = stations.items + EXCLUDED.items, \
                     distinct_seqs = stations.distinct_seqs + EXCLUDED.distinct_seqs, \
                     last_seq = GREATEST(stations.last_seq, EXCLUDED.last_seq)",
                )
                .bind(old)
                .bind(&s.station_id)
                .execute(&mut *tx)
                .await?;
                sqlx::query(
                    "UPDATE stations SET renamed_to = $2, items = 0, distinct_seqs = 0, last_seq = NULL \
                     WHERE station_id = $1",
                )
                .bind(old)
                .bind(&s.station_id)
                .execute(&mut *tx)
                .await?;
                tracing::info!(from = %old, to = %s.station_id, "fleet: station renamed");
            }
            sqlx::query(
                "UPDATE stations SET retired_at = CASE WHEN $2 THEN COALESCE(retired_at, $3) END WHERE station_id = $1",
            )
            .bind(&s.station_id)
            .bind(s.retired)
            .bind(&t)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }
}
