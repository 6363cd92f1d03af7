//! The fleet (issue 20): a station's replication worker. (The fleet role,
//! the daemon started on the center's database without benches, is
//! `api::fleet`: it is an HTTP front of the center and nothing else.)
//!
//! The worker sends the station's outbox (`crates/store/src/outbox.rs`,
//! filled in the transactions that store results) to the center, oldest
//! first, in batches the center applies in one transaction each and
//! idempotently by item id. Nothing is removed from the station: an item
//! is marked delivered once the center acknowledged it. While the center is
//! unreachable the station keeps measuring; the worker waits 1 s, 2 s, 4 s
//! ... up to `retry_max_s` between attempts and catches up afterwards. An
//! item the center refuses (it contradicts itself) is parked with the
//! reason; later items of the same part wait behind it, others go on.
//! Recipes travel the other way: every `recipe_poll_s` the worker takes the
//! center's versions and retirements.

use crate::config::{FleetConfig, RecordingsPolicy};
use crate::store::fleet::{BenchState, CenterIngest, StationHello};
use crate::store::{Store, StoreError};
use serde::Serialize;
use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// The station's link to the center as the worker last saw it (the
/// station's `/metrics` and `GET /api/v1/fleet/link`).
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub struct LinkStatus {
    pub station_id: String,
    /// The center's URL without its password.
    pub center: String,
    /// `full` or `reference`.
    pub recordings: String,
    /// True while the last attempt reached the center.
    pub connected: bool,
    /// When the center last answered (RFC 3339 UTC, ms); null: never since start.
    pub last_contact_at: Option<String>,
    /// The last failure (unreachable, refused item) and when it happened.
    pub last_error: Option<String>,
    pub last_error_at: Option<String>,
    /// Items the center acknowledged since the daemon started.
    pub items_sent: u64,
    /// Items the center answered with a conflict (another content under the
    /// same id) since start; each is named in the outbox's `last_error`.
    pub conflicts: u64,
    /// When the station last took the center's recipe list (RFC 3339 UTC).
    pub recipes_synced_at: Option<String>,
    /// Attempts that failed in a row (0 while the link is up).
    pub failures_in_a_row: u64,
}

/// Shared between the worker, the API and the runner.
#[derive(Debug, Default)]
pub struct Link {
    status: Mutex<LinkStatus>,
}

impl Link {
    pub fn new(cfg: &FleetConfig) -> Link {
        Link {
            status: Mutex::new(LinkStatus {
                station_id: cfg.station_id.clone(),
                center: crate::config::redact_url_password(&cfg.center),
                recordings: match cfg.recordings {
                    RecordingsPolicy::Full => "full".into(),
                    RecordingsPolicy::Reference => "reference".into(),
                },
                ..LinkStatus::default()
            }),
        }
    }

    pub fn status(&self) -> LinkStatus {
        self.status.lock().unwrap().clone()
    }

    fn contact(&self, sent: u64, conflicts: u64) {
        let mut s = self.status.lock().unwrap();
        s.connected = true;
        s.last_contact_at = Some(crate::store::now());
        s.items_sent += sent;
        s.conflicts += conflicts;
        s.failures_in_a_row = 0;
    }

    fn failed(&self, error: &str, reached: bool) {
        let mut s = self.status.lock().unwrap();
        s.connected = reached;
        s.last_error = Some(error.to_string());
        s.last_error_at = Some(crate::store::now());
        if !reached {
            s.failures_in_a_row += 1;
        }
    }

    fn recipes_synced(&self) {
        self.status.lock().unwrap().recipes_synced_at = Some(crate::store::now());
    }

    /// The recipe provenance a verdict records: whether the station could
    /// confirm its recipe versions with the center lately (`offline` when
    /// its last recipe sync is older than `max_age`, or never happened).
    pub fn recipe_trace(&self, max_age: Duration) -> crate::qc::FleetTrace {
        let s = self.status.lock().unwrap();
        let fresh = s.recipes_synced_at.as_deref().is_some_and(|t| {
            chrono::DateTime::parse_from_rfc3339(t).is_ok_and(|t| {
                (chrono::Utc::now() - t.with_timezone(&chrono::Utc))
                    .to_std()
                    .is_ok_and(|age| age <= max_age)
            })
        });
        crate::qc::FleetTrace {
            station_id: s.station_id.clone(),
            recipes_synced_at: s.recipes_synced_at.clone(),
            offline: !fresh,
        }
    }
}

/// Starts a station's replication worker on the center named by `cfg`
/// (connecting, and reconnecting, with backoff while it is unreachable).
pub fn start_station(
    store: Store,
    cfg: FleetConfig,
    runner: Arc<crate::runner::Runner>,
    stop: watch::Receiver<bool>,
) -> (Arc<Link>, tokio::task::JoinHandle<()>) {
    let link = Arc::new(Link::new(&cfg));
    // A verdict is `offline` once the worker missed two recipe polls.
    let max_age = Duration::from_secs_f64(2.0 * cfg.recipe_poll_s);
    let l = link.clone();
    runner.set_recipe_trace(Arc::new(move || l.recipe_trace(max_age)));
    let benches: Arc<dyn Fn() -> Vec<BenchState> + Send + Sync> = Arc::new(move || {
        runner
            .bench_statuses()
            .into_iter()
            .map(|b| BenchState {
                bench_id: b.id,
                state: b.state.to_string(),
                detail: b
                    .fault
                    .map(|f| serde_json::to_string(&f).unwrap_or_default()),
            })
            .collect()
    });
    let c = cfg.clone();
    let task = tokio::spawn(run(
        store,
        cfg,
        link.clone(),
        benches,
        move || {
            let c = c.clone();
            async move { http::HttpCenter::new(&c) }
        },
        stop,
    ));
    (link, task)
}

/// The station's fleet figures in Prometheus text: backlog, oldest
/// pending item's age, last contact's age, items sent, conflicts.
pub async fn render_metrics(
    store: &Store,
    link: &Link,
    out: &mut String,
) -> Result<(), StoreError> {
    use std::fmt::Write;
    let b = store.outbox_backlog().await?;
    let s = link.status();
    let age = |t: &Option<String>| {
        t.as_deref()
            .and_then(|t| chrono::DateTime::parse_from_rfc3339(t).ok())
            .map(|t| {
                (chrono::Utc::now() - t.with_timezone(&chrono::Utc)).num_milliseconds() as f64
                    / 1000.0
            })
            .map_or("NaN".to_string(), |s| format!("{s:.3}"))
    };
    let _ = writeln!(
        out,
        "# HELP springbench_fleet_backlog_items Outbox items the fleet's center has not acknowledged, by state.\n\
         # TYPE springbench_fleet_backlog_items gauge\n\
         springbench_fleet_backlog_items{{state=\"pending\"}} {}\n\
         springbench_fleet_backlog_items{{state=\"refused\"}} {}\n\
         # HELP springbench_fleet_oldest_pending_age_seconds Age of the oldest unacknowledged item (NaN: none).\n\
         # TYPE springbench_fleet_oldest_pending_age_seconds gauge\n\
         springbench_fleet_oldest_pending_age_seconds {}\n\
         # HELP springbench_fleet_last_contact_age_seconds Time since the center last answered (NaN: not since start).\n\
         # TYPE springbench_fleet_last_contact_age_seconds gauge\n\
         springbench_fleet_last_contact_age_seconds {}\n\
         # HELP springbench_fleet_connected 1 while the last attempt reached the center.\n\
         # TYPE springbench_fleet_connected gauge\n\
         springbench_fleet_connected {}\n\
         # HELP springbench_fleet_last_seq The station's newest outbox sequence number.\n\
         # TYPE springbench_fleet_last_seq gauge\n\
         springbench_fleet_last_seq {}\n\
         # HELP springbench_fleet_items_sent_total Items the center acknowledged since start.\n\
         # TYPE springbench_fleet_items_sent_total counter\n\
         springbench_fleet_items_sent_total {}\n\
         # HELP springbench_fleet_conflicts_total Items the center held with another content, since start.\n\
         # TYPE springbench_fleet_conflicts_total counter\n\
         springbench_fleet_conflicts_total {}\n\
         # HELP springbench_fleet_stuck 1 while an item is parked (refused by the center) or the center has not answered 3 attempts in a row with items waiting.\n\
         # TYPE springbench_fleet_stuck gauge\n\
         springbench_fleet_stuck {}",
        b.pending - b.refused,
        b.refused,
        age(&b.oldest_pending_at),
        age(&s.last_contact_at),
        u8::from(s.connected),
        b.last_seq,
        s.items_sent,
        s.conflicts,
        u8::from(stuck(&b, &s)),
    );
    Ok(())
}

/// A station is stuck when an item is parked (the center refused it), or
/// the center has not answered 3 attempts in a row while items wait.
pub fn stuck(b: &crate::store::outbox::OutboxBacklog, s: &LinkStatus) -> bool {
    b.refused > 0 || (b.pending > 0 && s.failures_in_a_row >= 3)
}

/// What one round of the worker did.
#[derive(Debug, PartialEq)]
enum Round {
    /// Items went to the center (more may be waiting).
    Sent,
    /// Nothing to send.
    Idle,
}

/// Runs the worker until `stop` turns true. `connect` opens the center
/// (retried with backoff while it fails); `benches` reports the station's
/// bench states for the hello.
pub async fn run<C, F, Fut>(
    store: Store,
    cfg: FleetConfig,
    link: Arc<Link>,
    benches: Arc<dyn Fn() -> Vec<BenchState> + Send + Sync>,
    connect: F,
    mut stop: watch::Receiver<bool>,
) where
    C: CenterIngest + Send + Sync,
    F: Fn() -> Fut + Send,
    Fut: Future<Output = Result<C, String>> + Send,
{
    match store.outbox_retry_refused().await {
        Ok(n) if n > 0 => tracing::info!(items = n, "fleet: refused items offered again"),
        Ok(_) => {}
        Err(e) => tracing::warn!("fleet outbox: {e}"),
    }
    let max = Duration::from_secs_f64(cfg.retry_max_s);
    let mut wait = Duration::from_secs(1);
    let mut center: Option<C> = None;
    let mut next_recipes = Instant::now();
    let mut next_hello = Instant::now();
    loop {
        if *stop.borrow() {
            return;
        }
        let pause = match &center {
            None => match connect().await {
                Ok(c) => {
                    center = Some(c);
                    tracing::info!("fleet: center connected");
                    Duration::ZERO
                }
                Err(e) => {
                    link.failed(&format!("center unreachable: {e}"), false);
                    tracing::warn!("fleet: center unreachable: {e} (next attempt in {wait:?})");
                    backoff(&mut wait, max)
                }
            },
            Some(c) => {
                let r = round(
                    &store,
                    c,
                    &cfg,
                    &link,
                    &*benches,
                    &mut next_hello,
                    &mut next_recipes,
                )
                .await;
                match r {
                    Ok(Round::Sent) => {
                        wait = Duration::from_secs(1);
                        Duration::ZERO
                    }
                    Ok(Round::Idle) => {
                        wait = Duration::from_secs(1);
                        Duration::from_millis(500)
                    }
                    Err(e) => {
                        link.failed(&e, false);
                        tracing::warn!("fleet: {e} (next attempt in {wait:?})");
                        backoff(&mut wait, max)
                    }
                }
            }
        };
        if !pause.is_zero() {
            tokio::select! {
                _ = tokio::time::sleep(pause) => {}
                _ = stop.wait_for(|v| *v) => return,
            }
        }
    }
}

/// The current wait, doubled for the next time (at most `max`).
fn backoff(wait: &mut Duration, max: Duration) -> Duration {
    let now = (*wait).min(max);
    *wait = (*wait * 2).min(max);
    now
}

const HELLO_EVERY: Duration = Duration::from_secs(5);

/// One round: a hello when due, the recipes when due, then one batch.
async fn round<C: CenterIngest>(
    store: &Store,
    center: &C,
    cfg: &FleetConfig,
    link: &Link,
    benches: &(dyn Fn() -> Vec<BenchState> + Send + Sync),
    next_hello: &mut Instant,
    next_recipes: &mut Instant,
) -> Result<Round, String> {
    let rows = store
        .outbox_next(cfg.batch_items as i64)
        .await
        .map_err(|e| format!("station outbox: {e}"))?;
    if !rows.is_empty() || Instant::now() >= *next_hello {
        let b = store
            .outbox_backlog()
            .await
            .map_err(|e| format!("station outbox: {e}"))?;
        let hello = StationHello {
            station_id: cfg.station_id.clone(),
            software_version: crate::VERSION.to_string(),
            contract_version: crate::store::fleet::CONTRACT_VERSION,
            bench_states: benches(),
            backlog_items: b.pending,
            oldest_backlog_at: b.oldest_pending_at,
            sent_at: crate::store::now(),
        };
        center
            .hello(&hello)
            .await
            .map_err(|e| format!("center unreachable (hello): {e}"))?;
        link.contact(0, 0);
        *next_hello = Instant::now() + HELLO_EVERY;
    }
    if Instant::now() >= *next_recipes {
        let recipes = center
            .recipes()
            .await
            .map_err(|e| format!("center unreachable (recipes): {e}"))?;
        let sync = store
            .apply_center_recipes(&recipes)
            .await
            .map_err(|e| format!("station recipes: {e}"))?;
        if sync.added > 0 || sync.retired > 0 {
            tracing::info!(
                added = sync.added,
                retired = sync.retired,
                "fleet: recipes from the center"
            );
        }
        for c in &sync.conflicts {
            tracing::warn!("fleet: {c}");
        }
        link.recipes_synced();
        *next_recipes = Instant::now() + Duration::from_secs_f64(cfg.recipe_poll_s);
    }
    if rows.is_empty() {
        return Ok(Round::Idle);
    }
    let with_bytes = cfg.recordings == RecordingsPolicy::Full;
    let items = store
        .outbox_items(&rows, with_bytes)
        .await
        .map_err(|e| format!("station outbox: {e}"))?;
    let seqs: Vec<i64> = rows.iter().map(|r| r.seq).collect();
    match center.ingest(&cfg.station_id, &items).await {
        Ok(report) => {
            store
                .outbox_delivered(&seqs)
                .await
                .map_err(|e| format!("station outbox: {e}"))?;
            for c in &report.conflicts {
                tracing::warn!(seq = c.seq, item = %c.item_id, "fleet: the center holds another content: {}", c.reason);
                let _ = store
                    .outbox_note(c.seq, &format!("conflict at the center: {}", c.reason))
                    .await;
            }
            link.contact(seqs.len() as u64, report.conflicts.len() as u64);
            Ok(Round::Sent)
        }
        Err(StoreError::Invalid(why)) => {
            // The batch holds an item the center refuses: one by one, the
            // refused one parked, later items of its part held behind it.
            tracing::warn!(
                "fleet: the center refused a batch ({why}); sending its items one by one"
            );
            let mut held: Vec<&str> = vec![];
            for (row, item) in rows.iter().zip(&items) {
                if held.contains(&row.part_serial.as_str()) {
                    continue;
                }
                match center
                    .ingest(&cfg.station_id, std::slice::from_ref(item))
                    .await
                {
                    Ok(_) => {
                        store
                            .outbox_delivered(&[row.seq])
                            .await
                            .map_err(|e| format!("station outbox: {e}"))?;
                        link.contact(1, 0);
                    }
                    Err(StoreError::Invalid(why)) => {
                        let msg = format!("refused by the center: {why}");
                        store
                            .outbox_failed(&[row.seq], &msg, true)
                            .await
                            .map_err(|e| format!("station outbox: {e}"))?;
                        link.failed(&format!("item {}: {msg}", row.seq), true);
                        tracing::error!(
                            seq = row.seq,
                            part = %row.part_serial,
                            "fleet: item parked, the center refused it: {why} (later items of its part wait behind it; GET /api/v1/fleet/link)"
                        );
                        held.push(&row.part_serial);
                    }
                    Err(e) => return Err(format!("center unreachable (ingest): {e}")),
                }
            }
            Ok(Round::Sent)
        }
        Err(e) => {
            let msg = format!("center unreachable (ingest): {e}");
            let _ = store.outbox_failed(&seqs, &msg, false).await;
            Err(msg)
        }
    }
}

pub mod http;
#[cfg(test)]
mod tests;
