//! The stations' long-term tests as the center holds them (issue 32,
//! decision 0134): the newest document each station sent, read only.

use crate::PgStore;
use serde_json::Value;
use springbench_store::{StoreError, StoreResult};
use sqlx::Row;

/// A long-term test at the center: the station's own documents, as sent.
#[derive(Debug, Clone, PartialEq)]
pub struct CenterLongTerm {
    pub job_id: String,
    pub station_id: String,
    pub part_serial: String,
    pub job_state: String,
    /// The station's `GET /api/v1/long-term-tests/{id}`.
    pub document: Value,
    /// The station's line of `GET /api/v1/long-term-tests`.
    pub summary: Value,
    /// The last signals before a failure stopped it are at the station.
    pub last_signals_at_station: bool,
    /// The station's outbox seq of the held document, and when it arrived.
    pub item_seq: i64,
    pub received_at: String,
}

fn parse(what: &str, id: &str, text: &str) -> StoreResult<Value> {
    serde_json::from_str(text).map_err(|e| {
        StoreError::Corrupt(format!(
            "long-term test {id}: stored {what} unreadable: {e}"
        ))
    })
}

fn from_row(r: &sqlx::postgres::PgRow) -> StoreResult<CenterLongTerm> {
    let job_id: String = r.get("job_id");
    Ok(CenterLongTerm {
        document: parse("document", &job_id, r.get("document_json"))?,
        summary: parse("summary", &job_id, r.get("summary_json"))?,
        station_id: r.get("station_id"),
        part_serial: r.get("part_serial"),
        job_state: r.get("job_state"),
        last_signals_at_station: r.get("last_signals_at_station"),
        item_seq: r.get("item_seq"),
        received_at: r.get("received_at"),
        job_id,
    })
}

macro_rules! cols {
    () => {
        "job_id, station_id, part_serial, job_state, document_json, summary_json, \
         last_signals_at_station, item_seq, received_at"
    };
}

impl PgStore {
    /// The newest `limit` long-term tests of every station (or of one), newest first.
    pub async fn long_term_tests(
        &self,
        station: Option<&str>,
        limit: i64,
    ) -> StoreResult<Vec<CenterLongTerm>> {
        let rows = sqlx::query(concat!(
            "SELECT ",
            cols!(),
            " FROM long_term_tests WHERE ($1::text IS NULL OR station_id = $1) \
             ORDER BY created_at DESC, job_id LIMIT $2"
        ))
        .bind(station)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter().map(from_row).collect()
    }

    /// One long-term test (None: the center holds none with this id).
    pub async fn long_term_test(&self, job_id: &str) -> StoreResult<Option<CenterLongTerm>> {
        let row = sqlx::query(concat!(
            "SELECT ",
            cols!(),
            " FROM long_term_tests WHERE job_id = $1"
        ))
        .bind(job_id)
        .fetch_optional(&self.pool)
        .await?;
        row.as_ref().map(from_row).transpose()
    }
}
