//! Measurements: the rows of a finished measurement with its recordings
//! (written in the caller's transaction), a measurement read back, listings.

use crate::results::{
    FinishedMeasurement, MeasurementInfo, MeasurementReads, NewMeasurement, NewRecording,
    ResultIngest, StoredMeasurement, Upserted,
};
use crate::{now, parse_json, Store, StoreError, StoreResult};
use sqlx::sqlite::SqliteRow;
use sqlx::Row;

// The summary's numbers are taken with `->` (the JSON text as stored, every
// digit), not `json_extract` (a REAL, which `json_object` prints with 15
// significant digits): the same numbers as the result document and the center's.
macro_rules! meas_select {
    () => {
        "SELECT m.seq, m.id, m.part_serial, m.job_id, m.source, m.bench_id, m.software_version, \
     m.target_xpeak_m, m.repeat_index, m.level_index, m.analysis_error, m.created_at, m.config_json, \
     json_object('keff_n_per_m', m.result_json -> '$.large_signal.keff_n_per_m', \
                 'keff_validity', json_extract(m.result_json, '$.large_signal.validity.keff_n_per_m'), \
                 'resonance_validity', json_extract(m.result_json, '$.large_signal.validity.resonance_hz'), \
                 'xpeak_m', m.result_json -> '$.large_signal.xpeak_m', \
                 'resonance_hz', m.result_json -> '$.large_signal.resonance_hz', \
                 'k0_n_per_m', CASE WHEN json_extract(m.result_json, '$.small_signal.reliable') = 0 THEN NULL \
                                    ELSE m.result_json -> '$.small_signal.k0_n_per_m' END, \
                 'k0_null_reason', CASE WHEN json_extract(m.result_json, '$.small_signal.reliable') = 0 \
                                    THEN printf('small_signal.reliable is false (k0 %.1f +- %.1f N/m, misfit %.2f %%): not a plain number', \
                                         json_extract(m.result_json, '$.small_signal.k0_n_per_m'), \
                                         json_extract(m.result_json, '$.small_signal.k0_se_n_per_m'), \
                                         json_extract(m.result_json, '$.small_signal.misfit_percent')) END) AS summary"
    };
}

impl Store {
    /// Stores measurements without a job (multipart import), in one transaction.
    pub async fn insert_measurements(
        &self,
        part: (&str, Option<&str>, Option<&str>),
        recordings: Vec<NewRecording>,
        measurements: Vec<NewMeasurement>,
    ) -> StoreResult<()> {
        self.upsert_part(part.0, part.1, part.2).await?;
        let mut tx = self.begin_write().await?;
        insert_results(&mut tx, recordings, measurements).await?;
        tx.commit().await?;
        Ok(())
    }

    /// A measurement's report read into its type: `None` when the
    /// measurement is unknown or its analysis failed; a stored document
    /// that does not read as this version's report is `Corrupt`.
    pub async fn measurement_report(
        &self,
        id: &str,
    ) -> StoreResult<Option<springbench_core::identify::Report>> {
        let text: Option<Option<String>> =
            sqlx::query_scalar("SELECT result_json FROM measurements WHERE id = ?")
                .bind(id.to_string())
                .fetch_optional(&self.pool)
                .await?;
        text.flatten()
            .map(|s| {
                serde_json::from_str(&s)
                    .map_err(|e| StoreError::Corrupt(format!("measurement {id}: result_json: {e}")))
            })
            .transpose()
    }

    pub async fn counts(&self) -> StoreResult<(i64, i64)> {
        let r =
            sqlx::query("SELECT (SELECT COUNT(*) FROM parts), (SELECT COUNT(*) FROM measurements)")
                .fetch_one(&self.pool)
                .await?;
        Ok((r.get(0), r.get(1)))
    }
}

pub(crate) async fn insert_results(
    tx: &mut sqlx::SqliteConnection,
    recordings: Vec<NewRecording>,
    measurements: Vec<NewMeasurement>,
) -> StoreResult<Vec<i64>> {
    insert_results_at(
        tx,
        recordings,
        measurements,
        springbench_core::VERSION,
        &now(),
    )
    .await
}

/// [`insert_results`] made by `software_version` at `t` (a measurement
/// ingested from a station keeps the station's).
async fn insert_results_at(
    tx: &mut sqlx::SqliteConnection,
    recordings: Vec<NewRecording>,
    measurements: Vec<NewMeasurement>,
    software_version: &str,
    t: &str,
) -> StoreResult<Vec<i64>> {
    let mut rec_ids = Vec::with_capacity(recordings.len());
    for r in recordings {
        let row = sqlx::query(
            "INSERT INTO recordings (kind, sample_rate_hz, frames, wav, channel_scale_json, created_at) VALUES (?, ?, ?, ?, ?, ?) RETURNING id",
        )
        .bind(r.kind)
        .bind(r.sample_rate_hz)
        .bind(r.frames)
        .bind(r.stored.bytes)
        .bind(
            r.stored
                .channel_scale
                .map(|c| serde_json::to_string(&c).unwrap_or_default()),
        )
        .bind(t.to_string())
        .fetch_one(&mut *tx)
        .await?;
        rec_ids.push(row.get::<i64, _>(0));
    }
    insert_measurement_rows_at(tx, measurements, &rec_ids, software_version, t).await?;
    Ok(rec_ids)
}

/// The measurement rows; `pre` / `main` index into `rec_ids`.
pub(crate) async fn insert_measurement_rows(
    tx: &mut sqlx::SqliteConnection,
    measurements: Vec<NewMeasurement>,
    rec_ids: &[i64],
) -> StoreResult<()> {
    insert_measurement_rows_at(tx, measurements, rec_ids, springbench_core::VERSION, &now()).await
}

async fn insert_measurement_rows_at(
    tx: &mut sqlx::SqliteConnection,
    measurements: Vec<NewMeasurement>,
    rec_ids: &[i64],
    software_version: &str,
    t: &str,
) -> StoreResult<()> {
    for m in measurements {
        let pre = *rec_ids.get(m.pre).ok_or_else(|| {
            StoreError::Corrupt("measurement names a missing pre recording".into())
        })?;
        let main = *rec_ids.get(m.main).ok_or_else(|| {
            StoreError::Corrupt("measurement names a missing main recording".into())
        })?;
        let meta = doc_text(&m.id, "meta", &m.meta)?;
        let result = m
            .result
            .as_ref()
            .map(|d| doc_text(&m.id, "result", d))
            .transpose()?;
        sqlx::query(
            "INSERT INTO measurements (id, part_serial, job_id, source, bench_id, software_version, config_json, meta_json, \
             result_json, analysis_error, target_xpeak_m, repeat_index, level_index, pre_recording_id, main_recording_id, created_at) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(m.id)
        .bind(m.part_serial)
        .bind(m.job_id)
        .bind(m.source)
        .bind(m.bench_id)
        .bind(software_version.to_string())
        .bind(m.config.to_json())
        .bind(meta)
        .bind(result)
        .bind(m.analysis_error)
        .bind(m.target_xpeak_m)
        .bind(m.repeat_index)
        .bind(m.level_index)
        .bind(pre)
        .bind(main)
        .bind(t.to_string())
        .execute(&mut *tx)
        .await?;
    }
    Ok(())
}

fn meas_from_row(r: &SqliteRow) -> StoreResult<MeasurementInfo> {
    Ok(MeasurementInfo {
        seq: r.get("seq"),
        id: r.get("id"),
        part_serial: r.get("part_serial"),
        job_id: r.get("job_id"),
        source: r.get("source"),
        bench_id: r.get("bench_id"),
        software_version: r.get("software_version"),
        target_xpeak_m: r.get("target_xpeak_m"),
        repeat_index: r.get("repeat_index"),
        level_index: r.get("level_index"),
        analysis_error: r.get("analysis_error"),
        created_at: r.get("created_at"),
        config: parse_json(&r.get::<String, _>("config_json"))?,
        summary: parse_json(&r.get::<String, _>("summary"))?,
        station_id: None,
    })
}

impl MeasurementReads for Store {
    async fn get_measurement(&self, id: &str) -> StoreResult<Option<StoredMeasurement>> {
        let row = sqlx::query(concat!(
            meas_select!(),
            ", m.result_json, m.meta_json FROM measurements m WHERE m.id = ?"
        ))
        .bind(id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        let Some(r) = row else { return Ok(None) };
        let info = meas_from_row(&r)?;
        let result = r
            .get::<Option<String>, _>("result_json")
            .map(|s| parse_json(&s))
            .transpose()?;
        let meta = parse_json(&r.get::<String, _>("meta_json"))?;
        Ok(Some((info, result, meta)))
    }

    async fn list_measurements_since(
        &self,
        part: Option<&str>,
        job: Option<&str>,
        since: Option<&str>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<MeasurementInfo>> {
        let rows = sqlx::query(concat!(
            meas_select!(),
            " FROM measurements m WHERE (? IS NULL OR m.part_serial = ?) \
             AND (? IS NULL OR m.job_id = ?) AND (? IS NULL OR m.created_at >= ?) \
             AND (? IS NULL OR m.seq < ?) ORDER BY m.seq DESC LIMIT ?"
        ))
        .bind(part.map(str::to_string))
        .bind(part.map(str::to_string))
        .bind(job.map(str::to_string))
        .bind(job.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(since.map(str::to_string))
        .bind(before_seq)
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(meas_from_row).collect()
    }
}

impl ResultIngest for Store {
    async fn upsert_measurement(&self, f: &FinishedMeasurement) -> StoreResult<Upserted> {
        let m = &f.measurement;
        if m.part_serial != f.part.0 {
            return Err(StoreError::Invalid(format!(
                "measurement {} is of part '{}', not of '{}'",
                m.id, m.part_serial, f.part.0
            )));
        }
        if let Some(v) = f
            .verdicts
            .iter()
            .find(|v| v.measurement_id.as_deref() != Some(m.id.as_str()))
        {
            return Err(StoreError::Invalid(format!(
                "verdict {} is not of measurement {}",
                v.id, m.id
            )));
        }
        let mut tx = self.begin_write().await?;
        let known: Option<i64> = sqlx::query_scalar("SELECT 1 FROM measurements WHERE id = ?")
            .bind(m.id.clone())
            .fetch_optional(&mut *tx)
            .await?;
        if known.is_some() {
            return Ok(Upserted::AlreadyStored);
        }
        sqlx::query(
            "INSERT INTO parts (serial, kind, notes, created_at, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(serial) DO UPDATE SET kind = COALESCE(excluded.kind, parts.kind), \
             notes = COALESCE(excluded.notes, parts.notes), updated_at = excluded.updated_at",
        )
        .bind(f.part.0.clone())
        .bind(f.part.1.clone())
        .bind(f.part.2.clone())
        .bind(f.created_at.clone())
        .bind(f.created_at.clone())
        .execute(&mut *tx)
        .await?;
        insert_results_at(
            &mut tx,
            f.recordings.clone(),
            vec![m.clone()],
            &f.software_version,
            &f.created_at,
        )
        .await?;
        crate::qc::insert_verdicts(&mut tx, &f.verdicts, &f.created_at).await?;
        tx.commit().await?;
        Ok(Upserted::Inserted)
    }
}

/// A measurement's document as stored text; a non-finite number refuses
/// the whole write (nothing is stored, the caller keeps the reason).
fn doc_text<T: serde::Serialize>(
    id: &str,
    what: &str,
    d: &crate::results::Doc<T>,
) -> StoreResult<String> {
    d.to_value()
        .map(|v| v.to_string())
        .map_err(|e| StoreError::Invalid(format!("measurement {id}: {what}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::Doc;
    use springbench_core::recording::Meta;

    use crate::results::tiny_recording as rec;

    fn measurement(id: &str, meta: Meta) -> NewMeasurement {
        NewMeasurement {
            id: id.into(),
            part_serial: "SN-1".into(),
            job_id: None,
            source: "import",
            bench_id: None,
            config: Default::default(),
            meta: Doc::Made(meta),
            result: None,
            analysis_error: Some("not analysed".into()),
            target_xpeak_m: None,
            repeat_index: None,
            level_index: None,
            pre: 0,
            main: 1,
        }
    }

    /// The store checks a made document on write: a NaN is refused with
    /// the measurement and the field named, and nothing of the call is
    /// stored (`serde_json::to_value` had written it as `null`).
    #[tokio::test]
    async fn a_non_finite_number_in_a_made_document_is_refused_on_write() {
        let s = Store::memory().await.unwrap();
        let good = measurement("m-good", Meta::standard(0.0123, 48000.0));
        s.insert_measurements(
            ("SN-1", None, None),
            vec![rec("pre"), rec("main")],
            vec![good],
        )
        .await
        .unwrap();
        let stored: String =
            sqlx::query_scalar("SELECT meta_json FROM measurements WHERE id = 'm-good'")
                .fetch_one(&s.pool)
                .await
                .unwrap();
        let back: Meta = serde_json::from_str(&stored).unwrap();
        assert_eq!(back.moving_mass_kg, 0.0123);
        assert_eq!(back.sample_rate_hz, 48000.0);

        let bad = measurement("m-nan", Meta::standard(f64::NAN, 48000.0));
        let e = s
            .insert_measurements(
                ("SN-1", None, None),
                vec![rec("pre"), rec("main")],
                vec![bad],
            )
            .await
            .unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, StoreError::Invalid(_)), "{msg}");
        assert!(
            msg.contains("m-nan") && msg.contains("meta") && msg.contains("moving_mass_kg"),
            "{msg}"
        );
        let (_, n) = s.counts().await.unwrap();
        assert_eq!(n, 1, "only the good measurement is stored");
        let recs: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM recordings")
            .fetch_one(&s.pool)
            .await
            .unwrap();
        assert_eq!(
            recs, 2,
            "the refused call's recordings are not stored either"
        );
    }
}
