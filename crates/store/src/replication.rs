//! A station's outbox rows as the fleet contract's items (`fleet.rs`):
//! what the replication worker hands the center. Apart from `outbox.rs`
//! because the contract names the outbox's `Correction` (no import circle).

use crate::fleet::{ItemBody, JobVerdictsItem, MeasurementItem, ReplicationItem, VerdictItem};
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
            };
            items.push(ReplicationItem { seq: r.seq, body });
        }
        Ok(items)
    }
}
