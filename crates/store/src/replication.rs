//! A station's outbox rows as the fleet contract's items (`fleet.rs`):
//! what the replication worker hands the center. Apart from `outbox.rs`
//! because the contract names the outbox's `Correction` (no import circle).

use crate::fleet::{
    ItemBody, JobVerdictsItem, LongTermTestItem, MeasurementItem, ReplicationItem, VerdictItem,
};
use crate::longterm_view::LongTermSummary;
use crate::outbox::{OutboxKind, OutboxRow};
use crate::{Store, StoreError, StoreResult};

impl Store {
    /// The replication items of outbox rows, in their order: a measurement
    /// with its verdicts, calibration record and recordings (their bytes
    /// when `with_bytes`, otherwise a reference: length and SHA-256); a
    /// job's own verdicts; a correction.
    pub async fn outbox_items(
        &self,
        rows: &[OutboxRow],
        with_bytes: bool,
    ) -> StoreResult<Vec<ReplicationItem>> {
        let mut items = Vec::with_capacity(rows.len());
        for r in rows {
            let missing = |what: &str| {
                StoreError::Corrupt(format!(
                    "outbox item {} names {what} '{}', which is not stored",
                    r.seq, r.ref_id
                ))
            };
            let body = match r.kind {
                OutboxKind::Measurement => {
                    let f = self
                        .finished_measurement(&r.ref_id, true)
                        .await?
                        .ok_or_else(|| missing("measurement"))?;
                    let calibration = match self.measurement_calibration_id(&r.ref_id).await? {
                        Some(id) => self.get_calibration(&id).await?,
                        None => None,
                    };
                    let mut m = MeasurementItem::from_finished(&f, calibration, with_bytes)
                        .map_err(StoreError::Corrupt)?;
                    // Each verdict with the time it was made (the job's end).
                    let times = self.verdict_times(&r.ref_id).await?;
                    for v in &mut m.verdicts {
                        if let Some((_, t)) = times.iter().find(|(id, _)| *id == v.id) {
                            v.created_at = t.clone();
                        }
                    }
                    ItemBody::Measurement(Box::new(m))
                }
                OutboxKind::JobVerdicts => ItemBody::JobVerdicts(JobVerdictsItem {
                    job_id: r.ref_id.clone(),
                    part_serial: r.part_serial.clone(),
                    verdicts: self
                        .job_verdict_rows(&r.ref_id)
                        .await?
                        .iter()
                        .map(|(v, t)| VerdictItem::from_new(v, t))
                        .collect(),
                }),
                OutboxKind::Correction => ItemBody::Correction(
                    self.correction(&r.ref_id)
                        .await?
                        .ok_or_else(|| missing("correction"))?,
                ),
                OutboxKind::LongTermTest => {
                    let doc = self
                        .long_term_document(&r.ref_id)
                        .await?
                        .ok_or_else(|| missing("long-term test"))?;
                    let spec = crate::longterm_view::spec_of(&doc.job)
                        .ok_or_else(|| missing("long-term test"))?;
                    let summary = LongTermSummary::of(doc.job.clone(), spec, doc.state.clone());
                    let value = |v: serde_json::Result<serde_json::Value>| {
                        v.map_err(|e| StoreError::Corrupt(format!("outbox item {}: {e}", r.seq)))
                    };
                    ItemBody::LongTermTest(Box::new(LongTermTestItem {
                        job_id: doc.job.id.clone(),
                        part_serial: doc.job.part_serial.clone(),
                        bench_id: doc.job.bench_id.clone(),
                        job_state: doc.job.state.as_str().to_string(),
                        created_at: doc.job.created_at.clone(),
                        last_signals_at_station: doc.last_signals.is_some(),
                        summary: value(serde_json::to_value(&summary))?,
                        document: value(serde_json::to_value(&doc))?,
                    }))
                }
            };
            items.push(ReplicationItem { seq: r.seq, body });
        }
        Ok(items)
    }
}
