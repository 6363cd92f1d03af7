//! The event stream: every stored event has a sequence number (the resume
//! point of `GET /api/v1/events?after=N`); live samples during sweeps are
//! broadcast only (not stored, `seq` = the last stored event's).

use crate::store::{Event, Store, StoreResult};
use serde_json::Value;
use std::sync::Arc;
use tokio::sync::{broadcast, Mutex};

/// What subscribers receive.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Published {
    #[serde(flatten)]
    pub event: Event,
    /// True for live samples: not stored, not replayed after a reconnect.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub live: bool,
}

#[derive(Clone)]
pub struct EventBus {
    store: Store,
    tx: broadcast::Sender<Arc<Published>>,
    /// Serialises append + broadcast so subscribers see increasing `seq`.
    order: Arc<Mutex<i64>>,
}

impl EventBus {
    pub async fn new(store: Store) -> StoreResult<EventBus> {
        let last = store.last_event_seq().await?;
        let (tx, _) = broadcast::channel(4096);
        Ok(EventBus {
            store,
            tx,
            order: Arc::new(Mutex::new(last)),
        })
    }

    /// Stores an event and broadcasts it.
    pub async fn publish(&self, kind: &str, job_id: Option<&str>, data: Value) -> StoreResult<i64> {
        let mut last = self.order.lock().await;
        let event = self.store.append_event(kind, job_id, &data).await?;
        *last = event.seq;
        let seq = event.seq;
        let _ = self.tx.send(Arc::new(Published { event, live: false }));
        Ok(seq)
    }

    /// Broadcasts a live event without storing it.
    pub async fn publish_live(&self, kind: &str, job_id: Option<&str>, data: Value) {
        let last = self.order.lock().await;
        let event = Event {
            seq: *last,
            time: crate::store::now(),
            kind: kind.to_string(),
            job_id: job_id.map(str::to_string),
            data,
        };
        let _ = self.tx.send(Arc::new(Published { event, live: true }));
    }

    pub fn subscribe(&self) -> broadcast::Receiver<Arc<Published>> {
        self.tx.subscribe()
    }

    pub fn store(&self) -> &Store {
        &self.store
    }
}
