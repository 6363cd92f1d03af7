//! The read traits of the results interface on PostgreSQL: the same rows,
//! order and derived figures as the SQLite backend (the conformance suite
//! `crates/store/tests/results.rs` runs both), plus the station of every
//! row. Every listing is a keyset page on an index; nothing loads a table.

use crate::{parse_json, PgStore};
use springbench_store::results::{
    Fit, FitReads, HeadlineChoice, MeasurementInfo, MeasurementReads, Part, PartReads, RecipeReads,
    RecipeRow, StoredMeasurement, VerdictReads, VerdictRow,
};
use springbench_store::StoreResult;
use sqlx::postgres::PgRow;
use sqlx::Row;

/// A measurement's listing columns; `summary` is the same document the
/// SQLite backend builds (headline values, an unreliable k0 nulled with its
/// reason, the headline values' validity states).
macro_rules! meas_select {
    () => {
        "SELECT m.seq, m.id, m.part_serial, m.job_id, m.source, m.bench_id, m.software_version, \
     m.target_xpeak_m, m.repeat_index, m.level_index, m.analysis_error, m.created_at, m.config_json::text AS config_json, \
     m.station_id, \
     jsonb_build_object('keff_n_per_m', m.result_json->'large_signal'->'keff_n_per_m', \
                 'keff_validity', m.result_json->'large_signal'->'validity'->'keff_n_per_m', \
                 'resonance_validity', m.result_json->'large_signal'->'validity'->'resonance_hz', \
                 'xpeak_m', m.result_json->'large_signal'->'xpeak_m', \
                 'resonance_hz', m.result_json->'large_signal'->'resonance_hz', \
                 'k0_n_per_m', CASE WHEN m.result_json->'small_signal'->'reliable' = 'false'::jsonb THEN NULL \
                                    ELSE m.result_json->'small_signal'->'k0_n_per_m' END, \
                 'k0_null_reason', CASE WHEN m.result_json->'small_signal'->'reliable' = 'false'::jsonb \
                                    THEN format('small_signal.reliable is false (k0 %s +- %s N/m, misfit %s %%): not a plain number', \
                                         round((m.result_json->'small_signal'->>'k0_n_per_m')::numeric, 1), \
                                         round((m.result_json->'small_signal'->>'k0_se_n_per_m')::numeric, 1), \
                                         round((m.result_json->'small_signal'->>'misfit_percent')::numeric, 2)) END)::text AS summary"
    };
}
pub(crate) use meas_select;

macro_rules! verdict_cols {
    () => {
        "seq, id, job_id, measurement_id, part_serial, recipe_name, recipe_version, recipe_sha256, verdict, \
         detail_json::text AS detail_json, trace_json::text AS trace_json, created_at, station_id"
    };
}

macro_rules! part_select {
    () => {
        "SELECT p.serial, p.kind, p.notes, p.created_at, p.updated_at, \
         (SELECT COUNT(*) FROM measurements m WHERE m.part_serial = p.serial), \
         (SELECT v.verdict FROM qc_verdicts v WHERE v.part_serial = p.serial AND v.measurement_id IS NULL AND NOT v.voided \
          ORDER BY v.seq DESC LIMIT 1), \
         p.station_id FROM parts p"
    };
}

fn part_from_row(r: &PgRow) -> Part {
    Part {
        serial: r.get(0),
        kind: r.get(1),
        notes: r.get(2),
        created_at: r.get(3),
        updated_at: r.get(4),
        measurement_count: r.get(5),
        verdict: r.get(6),
        station_id: r.get(7),
    }
}

pub(crate) fn meas_from_row(r: &PgRow) -> StoreResult<MeasurementInfo> {
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
        station_id: r.get("station_id"),
    })
}

pub(crate) fn verdict_from_row(r: &PgRow) -> StoreResult<VerdictRow> {
    Ok(VerdictRow {
        seq: r.get("seq"),
        id: r.get("id"),
        job_id: r.get("job_id"),
        measurement_id: r.get("measurement_id"),
        part_serial: r.get("part_serial"),
        recipe_name: r.get("recipe_name"),
        recipe_version: r.get("recipe_version"),
        recipe_sha256: r.get("recipe_sha256"),
        verdict: r.get("verdict"),
        detail: parse_json(&r.get::<String, _>("detail_json"))?,
        traceability: parse_json(&r.get::<String, _>("trace_json"))?,
        created_at: r.get("created_at"),
        station_id: r.get("station_id"),
        level_index: r.try_get("level_index").ok().flatten(),
    })
}

pub(crate) fn recipe_from_row(r: &PgRow) -> StoreResult<RecipeRow> {
    Ok(RecipeRow {
        name: r.get("name"),
        version: r.get("version"),
        sha256: r.get("sha256"),
        recipe: springbench_store::parse_recipe(
            &r.get::<String, _>("name"),
            r.get("version"),
            &r.get::<String, _>("body_json"),
        )?,
        origin: r.get("origin"),
        proposal_id: r.get("proposal_id"),
        retired: r.get("retired"),
        created_by: r.get("created_by"),
        created_at: r.get("created_at"),
        source: springbench_core::job::RecipeSource::Center,
        approved_by: r.get("approved_by"),
    })
}

macro_rules! recipe_cols {
    () => {
        "name, version, sha256, body_json::text AS body_json, origin, proposal_id, retired, created_by, created_at, approved_by"
    };
}
pub(crate) use recipe_cols;

impl PartReads for PgStore {
    async fn get_part(&self, serial: &str) -> StoreResult<Option<Part>> {
        let row = sqlx::query(concat!(part_select!(), " WHERE p.serial = $1"))
            .bind(serial)
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.map(|r| part_from_row(&r)))
    }

    async fn list_parts(&self, after: Option<&str>, limit: i64) -> StoreResult<Vec<Part>> {
        let rows = sqlx::query(concat!(
            part_select!(),
            " WHERE ($1::text IS NULL OR p.serial > $1) ORDER BY p.serial LIMIT $2"
        ))
        .bind(after)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(part_from_row).collect())
    }
}

impl MeasurementReads for PgStore {
    async fn get_measurement(&self, id: &str) -> StoreResult<Option<StoredMeasurement>> {
        let row = sqlx::query(concat!(
            meas_select!(),
            ", m.result_json::text AS result_json, m.meta_json::text AS meta_json FROM measurements m WHERE m.id = $1"
        ))
        .bind(id)
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
        // Custom plans (connect: plan_cache_mode): an absent filter folds
        // away, a present one uses its index (part, job: (x, seq)).
        let rows = sqlx::query(concat!(
            meas_select!(),
            " FROM measurements m WHERE ($1::text IS NULL OR m.part_serial = $1) \
             AND ($2::text IS NULL OR m.job_id = $2) AND ($3::text IS NULL OR m.created_at >= $3) \
             AND ($4::bigint IS NULL OR m.seq < $4) ORDER BY m.seq DESC LIMIT $5"
        ))
        .bind(part)
        .bind(job)
        .bind(since)
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(meas_from_row).collect()
    }
}

impl FitReads for PgStore {
    async fn list_fits(&self, measurement_id: &str) -> StoreResult<Vec<Fit>> {
        let rows = sqlx::query(
            "SELECT id, measurement_id, request_json::text, result_json::text, software_version, created_at \
             FROM fits WHERE measurement_id = $1 ORDER BY seq",
        )
        .bind(measurement_id)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(Fit {
                    id: r.get(0),
                    measurement_id: r.get(1),
                    request: parse_json(&r.get::<String, _>(2))?,
                    result: parse_json(&r.get::<String, _>(3))?,
                    software_version: r.get(4),
                    created_at: r.get(5),
                })
            })
            .collect()
    }

    async fn headline_choice(&self, measurement_id: &str) -> StoreResult<Option<HeadlineChoice>> {
        let row = sqlx::query(
            "SELECT fit_id, chosen_by, chosen_at FROM headline_choices \
             WHERE measurement_id = $1 ORDER BY seq DESC LIMIT 1",
        )
        .bind(measurement_id)
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| HeadlineChoice {
            fit_id: r.get(0),
            chosen_by: r.get(1),
            chosen_at: r.get(2),
        }))
    }
}

impl VerdictReads for PgStore {
    async fn part_verdict(&self, serial: &str) -> StoreResult<Option<VerdictRow>> {
        let row = sqlx::query(concat!(
            "SELECT ",
            verdict_cols!(),
            // a job with a voided measurement no longer judges the part (decision 0057)
            " FROM qc_verdicts WHERE part_serial = $1 AND measurement_id IS NULL AND NOT voided ORDER BY seq DESC LIMIT 1"
        ))
        .bind(serial)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| verdict_from_row(&r)).transpose()
    }

    async fn job_verdicts(&self, job_id: &str) -> StoreResult<Vec<VerdictRow>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            verdict_cols!(),
            " FROM qc_verdicts WHERE job_id = $1 ORDER BY measurement_id IS NOT NULL, seq"
        ))
        .bind(job_id)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(verdict_from_row).collect()
    }

    async fn measurement_verdict(&self, measurement_id: &str) -> StoreResult<Option<VerdictRow>> {
        let row = sqlx::query(concat!(
            "SELECT ",
            verdict_cols!(),
            " FROM qc_verdicts WHERE measurement_id = $1 ORDER BY seq DESC LIMIT 1"
        ))
        .bind(measurement_id)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| verdict_from_row(&r)).transpose()
    }

    async fn recipe_verdicts(
        &self,
        recipe: &str,
        purpose: Option<springbench_core::job::Purpose>,
        since: Option<&str>,
        until: Option<&str>,
        last: Option<i64>,
    ) -> StoreResult<Vec<VerdictRow>> {
        // A voided measurement's verdicts are no part of SPC; the pool is
        // the trace's (a verdict without one is production, decision 0100).
        let rows = sqlx::query(concat!(
            "SELECT * FROM (SELECT ",
            verdict_cols!(),
            ", level_index FROM qc_verdicts WHERE recipe_name = $1 AND measurement_id IS NOT NULL AND NOT voided \
             AND ($2::text IS NULL OR created_at >= $2) AND ($3::text IS NULL OR created_at < $3) \
             AND ($5::text IS NULL OR COALESCE(trace_json->>'purpose', 'production') = $5) \
             ORDER BY seq DESC LIMIT $4) w ORDER BY seq"
        ))
        .bind(recipe)
        .bind(since)
        .bind(until)
        .bind(last)
        .bind(purpose.map(|p| p.as_str()))
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(verdict_from_row).collect()
    }
}

impl RecipeReads for PgStore {
    async fn get_recipe(&self, name: &str, version: Option<i64>) -> StoreResult<Option<RecipeRow>> {
        let row = sqlx::query(concat!(
            "SELECT ",
            recipe_cols!(),
            " FROM qc_recipes WHERE name = $1 AND ($2::bigint IS NULL OR version = $2) ORDER BY version DESC LIMIT 1"
        ))
        .bind(name)
        .bind(version)
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| recipe_from_row(&r)).transpose()
    }

    async fn list_recipes(&self) -> StoreResult<Vec<RecipeRow>> {
        let rows = sqlx::query(concat!(
            "SELECT DISTINCT ON (name) ",
            recipe_cols!(),
            " FROM qc_recipes ORDER BY name, version DESC"
        ))
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(recipe_from_row).collect()
    }

    async fn recipe_versions(&self, name: &str) -> StoreResult<Vec<RecipeRow>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            recipe_cols!(),
            " FROM qc_recipes WHERE name = $1 ORDER BY version"
        ))
        .bind(name)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(recipe_from_row).collect()
    }
}

/// A measurement's recording as the center holds it.
#[derive(Debug, Clone)]
pub struct CenterRecording {
    /// The stored bytes' recording id and length (FLAC, or WAV for some
    /// imports); None when the station sends references only
    /// (`[fleet] recordings = "reference"`).
    pub stored: Option<(i64, i64)>,
    /// The channel scale of a FLAC recording (JSON), as the station sent it.
    pub channel_scale_json: Option<String>,
    /// The station that measured it.
    pub station_id: Option<String>,
}

impl PgStore {
    /// A recipe's valid measurement verdicts in [since, until), oldest
    /// first, after the verdict `after_seq` (keyset), at most `limit`:
    /// the center's listing pages with a hard cap (issue 36).
    pub async fn recipe_verdicts_page(
        &self,
        recipe: &str,
        since: Option<&str>,
        until: Option<&str>,
        after_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<VerdictRow>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            verdict_cols!(),
            ", level_index FROM qc_verdicts WHERE recipe_name = $1 AND measurement_id IS NOT NULL AND NOT voided \
             AND ($2::text IS NULL OR created_at >= $2) AND ($3::text IS NULL OR created_at < $3) \
             AND ($4::bigint IS NULL OR seq > $4) ORDER BY seq LIMIT $5"
        ))
        .bind(recipe)
        .bind(since)
        .bind(until)
        .bind(after_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(verdict_from_row).collect()
    }

    /// The `pre` or `main` recording of a measurement (None: no such
    /// measurement): where its bytes are, not the bytes (they are read in
    /// chunks by [`PgStore::recording_reader`]).
    pub async fn recording(
        &self,
        measurement_id: &str,
        kind: &str,
    ) -> StoreResult<Option<CenterRecording>> {
        let row = sqlx::query(
            "SELECT r.id, octet_length(r.wav)::bigint, r.channel_scale_json, m.station_id FROM measurements m \
             JOIN recordings r ON r.id = CASE WHEN $2 = 'pre' THEN m.pre_recording_id ELSE m.main_recording_id END \
             WHERE m.id = $1",
        )
        .bind(measurement_id)
        .bind(kind)
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.map(|r| CenterRecording {
            stored: r.get::<Option<i64>, _>(1).map(|len| (r.get(0), len)),
            channel_scale_json: r.get(2),
            station_id: r.get(3),
        }))
    }

    /// The bytes of recording `id` (`len` bytes) as a reader that fetches
    /// 1 MiB at a time: a download holds one chunk, not the recording
    /// (issue 36: 24 downloads of a 120 MB recording took the center to
    /// 3.3 GB). Read it off the async workers (`spawn_blocking`): each
    /// chunk is a query run on the runtime it was made on.
    pub fn recording_reader(&self, id: i64, len: i64) -> Box<dyn std::io::Read + Send> {
        Box::new(ChunkReader {
            pool: self.pool.clone(),
            rt: tokio::runtime::Handle::current(),
            id,
            off: 0,
            len,
            buf: vec![],
            pos: 0,
        })
    }
}

const CHUNK_BYTES: i64 = 1 << 20;

struct ChunkReader {
    pool: sqlx::PgPool,
    rt: tokio::runtime::Handle,
    id: i64,
    off: i64,
    len: i64,
    buf: Vec<u8>,
    pos: usize,
}

impl std::io::Read for ChunkReader {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.pos == self.buf.len() {
            if self.off >= self.len {
                return Ok(0);
            }
            let n = CHUNK_BYTES.min(self.len - self.off);
            // substring() of bytea counts from 1; the column is stored
            // uncompressed (migration 0320), so it reads only these pages.
            let chunk: Option<Vec<u8>> = self
                .rt
                .block_on(
                    sqlx::query_scalar(
                        "SELECT substring(wav FROM $2::int FOR $3::int) FROM recordings WHERE id = $1",
                    )
                    .bind(self.id)
                    .bind(self.off + 1)
                    .bind(n)
                    .fetch_optional(&self.pool),
                )
                .map_err(std::io::Error::other)?
                .flatten();
            let chunk = chunk.filter(|c| !c.is_empty()).ok_or_else(|| {
                std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "the recording is shorter than stored",
                )
            })?;
            self.off += chunk.len() as i64;
            self.buf = chunk;
            self.pos = 0;
        }
        let k = out.len().min(self.buf.len() - self.pos);
        out[..k].copy_from_slice(&self.buf[self.pos..self.pos + k]);
        self.pos += k;
        Ok(k)
    }
}
