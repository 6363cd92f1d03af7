//! The worker against a center in memory that can be down, lose an
//! acknowledgement or refuse an item: what reaches it is checked against
//! the station's own outbox (the truth), item by item.

use super::*;
use crate::store::fleet::{IngestReport, ItemBody, ReplicationItem, StationStatus};
use crate::store::qc::JobRecords;
use crate::store::results::{NewMeasurement, NewRecording, NewVerdict, RecipeRow};
use crate::store::{Inserted, JobState, StoreResult};
use serde_json::json;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

#[derive(Default)]
struct Center {
    down: AtomicBool,
    /// Store the next batch, then answer with an error (the ack is lost).
    lose_ack: AtomicBool,
    /// An item id the center refuses (it contradicts itself).
    refuse: Mutex<Option<String>>,
    /// Every item stored, in arrival order (idempotent by item id).
    items: Mutex<Vec<ReplicationItem>>,
    ingests: AtomicUsize,
    hellos: Mutex<Vec<StationHello>>,
    recipes: Mutex<Vec<RecipeRow>>,
}

fn status(h: &StationHello) -> StationStatus {
    StationStatus {
        station_id: h.station_id.clone(),
        software_version: h.software_version.clone(),
        contract_version: h.contract_version,
        bench_states: h.bench_states.clone(),
        backlog_items: h.backlog_items,
        oldest_backlog_at: h.oldest_backlog_at.clone(),
        sent_at: h.sent_at.clone(),
        last_contact_at: h.sent_at.clone(),
        first_contact_at: h.sent_at.clone(),
        items: 0,
        last_seq: None,
        missing_items: 0,
        clock_skew_s: None,
        refused: 0,
        retired_at: None,
        renamed_to: None,
    }
}

/// The center as the worker holds it (a connection to it).
struct Conn(Arc<Center>);

impl CenterIngest for Conn {
    async fn hello(&self, h: &StationHello) -> StoreResult<StationStatus> {
        if self.0.down.load(Ordering::SeqCst) {
            return Err(StoreError::Corrupt("connection refused".into()));
        }
        self.0.hellos.lock().unwrap().push(h.clone());
        Ok(status(h))
    }

    async fn ingest(&self, _station: &str, items: &[ReplicationItem]) -> StoreResult<IngestReport> {
        self.0.ingests.fetch_add(1, Ordering::SeqCst);
        if self.0.down.load(Ordering::SeqCst) {
            return Err(StoreError::Corrupt("connection refused".into()));
        }
        let refuse = self.0.refuse.lock().unwrap().clone();
        if let Some(bad) = items.iter().find(|i| Some(i.item_id()) == refuse) {
            return Err(StoreError::Invalid(format!(
                "item {} contradicts itself",
                bad.seq
            )));
        }
        let mut held = self.0.items.lock().unwrap();
        let mut report = IngestReport::default();
        for i in items {
            if held.iter().any(|h| h.item_id() == i.item_id()) {
                report.already_stored += 1;
            } else {
                held.push(i.clone());
                report.inserted += 1;
            }
        }
        if self.0.lose_ack.swap(false, Ordering::SeqCst) {
            return Err(StoreError::Corrupt(
                "connection reset before the answer".into(),
            ));
        }
        Ok(report)
    }

    async fn recipes(&self) -> StoreResult<Vec<RecipeRow>> {
        if self.0.down.load(Ordering::SeqCst) {
            return Err(StoreError::Corrupt("connection refused".into()));
        }
        Ok(self.0.recipes.lock().unwrap().clone())
    }

    async fn stations(&self) -> StoreResult<Vec<StationStatus>> {
        Ok(self
            .0
            .hellos
            .lock()
            .unwrap()
            .last()
            .map(status)
            .into_iter()
            .collect())
    }
}

fn rec(kind: &'static str) -> NewRecording {
    NewRecording {
        kind,
        sample_rate_hz: 48000.0,
        frames: 3,
        stored: springbench_recording::codec::Stored {
            bytes: vec![1, 2, 3, kind.len() as u8],
            channel_scale: None,
        },
    }
}

/// A job of `serial` run to its end with `n` measurements, each judged, and the job's verdict.
async fn job(s: &Store, id: &str, serial: &str, n: usize) {
    let r = s
        .insert_job(
            id,
            "b1",
            (serial, None, None),
            0,
            &crate::job::StoredRequest::SelfCheck(crate::job::SelfCheck { bench: "b1".into() }),
            id,
            None,
        )
        .await
        .unwrap();
    assert!(matches!(r, Inserted::New(_)));
    assert!(s.start_job(id).await.unwrap());
    let mut recs = vec![];
    let mut ms = vec![];
    let mut verdicts = vec![];
    for i in 0..n {
        recs.push(rec("pre"));
        recs.push(rec("main"));
        let mid = format!("{id}-m{i}");
        ms.push(NewMeasurement {
            id: mid.clone(),
            part_serial: serial.into(),
            job_id: Some(id.into()),
            source: "bench",
            bench_id: Some("b1".into()),
            config: Default::default(),
            meta: crate::store::Doc::Received(json!({})),
            result: Some(crate::store::Doc::Received(
                json!({"large_signal": {"keff_n_per_m": 1000.0 + i as f64}}),
            )),
            analysis_error: None,
            target_xpeak_m: Some(0.004),
            repeat_index: Some(i as i64),
            level_index: Some(0),
            pre: 2 * i,
            main: 2 * i + 1,
        });
        verdicts.push(verdict(&format!("v-{mid}"), id, Some(&mid), serial));
    }
    verdicts.push(verdict(&format!("v-{id}"), id, None, serial));
    let records = JobRecords {
        verdicts,
        ..JobRecords::default()
    };
    s.finish_job_qc(
        id,
        JobState::Succeeded,
        None,
        None,
        &[],
        &[],
        recs,
        ms,
        &records,
    )
    .await
    .unwrap();
}

fn verdict(id: &str, job: &str, m: Option<&str>, serial: &str) -> NewVerdict {
    NewVerdict {
        id: id.into(),
        job_id: Some(job.into()),
        measurement_id: m.map(str::to_string),
        part_serial: serial.into(),
        recipe_name: "r".into(),
        recipe_version: 1,
        recipe_sha256: "ab".repeat(32),
        verdict: "pass",
        detail: json!({}),
        trace: json!({}),
    }
}

fn cfg() -> FleetConfig {
    FleetConfig {
        center: "https://center.lab:8760".into(),
        token: "tok-line-1-9f2c71ab04d8e6".into(),
        ca_file: None,
        station_id: "line-1".into(),
        recordings: RecordingsPolicy::Reference,
        batch_items: 3,
        retry_max_s: 1.0,
        recipe_poll_s: 5.0,
    }
}

async fn until(what: &str, f: impl Fn() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "gave up waiting: {what}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn spawn(
    store: &Store,
    center: &Arc<Center>,
) -> (Arc<Link>, watch::Sender<bool>, tokio::task::JoinHandle<()>) {
    let link = Arc::new(Link::new(&cfg()));
    let (tx, rx) = watch::channel(false);
    let c = center.clone();
    let benches: Arc<dyn Fn() -> Vec<BenchState> + Send + Sync> = Arc::new(|| {
        vec![BenchState {
            bench_id: "b1".into(),
            state: "idle".into(),
            detail: None,
        }]
    });
    let task = tokio::spawn(run(
        store.clone(),
        cfg(),
        link.clone(),
        benches,
        move || {
            let c = c.clone();
            async move { Ok::<_, String>(Conn(c)) }
        },
        rx,
    ));
    (link, tx, task)
}

/// Down, then a lost acknowledgement, then up: every outbox item reaches
/// the center once, in the station's order, the backlog drains to 0.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_station_catches_up_once_in_order_after_an_outage_and_a_lost_ack() {
    let store = Store::memory().await.unwrap();
    let center = Arc::new(Center::default());
    center.down.store(true, Ordering::SeqCst);
    let (link, stop, task) = spawn(&store, &center);
    for (j, part) in [("j1", "A"), ("j2", "B"), ("j3", "A"), ("j4", "C")] {
        job(&store, j, part, 2).await;
    }
    // 4 jobs x (2 measurements + the job's verdicts) = 12 items, none delivered.
    until("a failed attempt", || {
        center.ingests.load(Ordering::SeqCst) > 0 || link.status().failures_in_a_row > 1
    })
    .await;
    assert!(center.items.lock().unwrap().is_empty());
    let b = store.outbox_backlog().await.unwrap();
    assert_eq!((b.pending, b.last_seq), (12, 12));
    assert!(!link.status().connected);
    center.lose_ack.store(true, Ordering::SeqCst);
    center.down.store(false, Ordering::SeqCst);
    until("all 12 items at the center", || {
        center.items.lock().unwrap().len() == 12
    })
    .await;
    let mut backlog = store.outbox_backlog().await.unwrap();
    let t0 = Instant::now();
    while backlog.pending > 0 && t0.elapsed() < Duration::from_secs(30) {
        tokio::time::sleep(Duration::from_millis(20)).await;
        backlog = store.outbox_backlog().await.unwrap();
    }
    assert_eq!((backlog.pending, backlog.delivered), (0, 12));
    let items = center.items.lock().unwrap().clone();
    let seqs: Vec<i64> = items.iter().map(|i| i.seq).collect();
    assert_eq!(
        seqs,
        (1..=12).collect::<Vec<_>>(),
        "station order, no gap, nothing twice"
    );
    // What arrived is what the station holds: measurement ids and their verdicts.
    let rows = store.outbox_rows(0, 100).await.unwrap();
    for (row, item) in rows.iter().zip(&items) {
        match &item.body {
            ItemBody::Measurement(m) => {
                assert_eq!(
                    (m.id.as_str(), m.part_serial.as_str()),
                    (row.ref_id.as_str(), row.part_serial.as_str())
                );
                assert_eq!(m.verdicts.len(), 1);
                assert_eq!(m.verdicts[0].id, format!("v-{}", m.id));
                // recordings = "reference": hash and length, no bytes
                assert!(m.main.bytes.is_none());
                assert_eq!(m.main.byte_len, 4);
            }
            ItemBody::JobVerdicts(j) => {
                assert_eq!(j.job_id, row.ref_id);
                assert_eq!(j.verdicts.len(), 1);
            }
            ItemBody::Correction(_) => panic!("no correction was made"),
            ItemBody::LongTermTest(_) => panic!("no long-term test was run"),
        }
    }
    // The hello reported the backlog while it drained, and the bench.
    let hellos = center.hellos.lock().unwrap().clone();
    assert_eq!(hellos[0].backlog_items, 12);
    assert_eq!(hellos[0].bench_states[0].bench_id, "b1");
    let s = link.status();
    assert!(s.connected && s.last_contact_at.is_some());
    stop.send(true).unwrap();
    task.await.unwrap();
}

/// A refused item is parked; later items of its part wait behind it, the
/// other parts' items go on; at the next start it is offered again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_item_holds_its_part_and_no_other() {
    let store = Store::memory().await.unwrap();
    job(&store, "j1", "A", 1).await; // seq 1 A-m0, 2 A-jv
    job(&store, "j2", "B", 1).await; // seq 3, 4
    job(&store, "j3", "A", 1).await; // seq 5, 6
    let center = Arc::new(Center::default());
    *center.refuse.lock().unwrap() = Some("measurement:j1-m0".into());
    let (link, stop, task) = spawn(&store, &center);
    until("part B at the center", || {
        center.items.lock().unwrap().len() == 2
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let ids: Vec<String> = center
        .items
        .lock()
        .unwrap()
        .iter()
        .map(|i| i.item_id())
        .collect();
    assert_eq!(ids, ["measurement:j2-m0", "job_verdicts:j2"]);
    let b = store.outbox_backlog().await.unwrap();
    assert_eq!((b.pending, b.refused), (4, 1));
    assert!(link
        .status()
        .last_error
        .unwrap()
        .contains("contradicts itself"));
    stop.send(true).unwrap();
    task.await.unwrap();
    // The center is mended; the next start sends part A in its order.
    *center.refuse.lock().unwrap() = None;
    let (_link, stop, task) = spawn(&store, &center);
    until("every item at the center", || {
        center.items.lock().unwrap().len() == 6
    })
    .await;
    let seqs: Vec<i64> = center.items.lock().unwrap().iter().map(|i| i.seq).collect();
    assert_eq!(seqs, [3, 4, 1, 2, 5, 6]);
    stop.send(true).unwrap();
    task.await.unwrap();
}

/// The center's recipe versions reach the station; a retired one is
/// retired here too; the newest the station holds is what it runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recipes_come_from_the_center_with_their_retirements() {
    let store = Store::memory().await.unwrap();
    let center = Arc::new(Center::default());
    let row = |v: i64, retired: bool| RecipeRow {
        name: "spider-4in".into(),
        version: v,
        sha256: format!("{v:064}"),
        recipe: serde_json::from_value(
            json!({"name": "spider-4in", "description": format!("version {v}"),
            "procedure": {"levels_m": [0.004]}, "parameters": []}),
        )
        .unwrap(),
        origin: "created".into(),
        proposal_id: None,
        retired,
        created_by: Some("qe".into()),
        created_at: "2026-11-26T10:00:00.000Z".into(),
        source: crate::job::RecipeSource::Center,
        approved_by: Some("approver".into()),
    };
    *center.recipes.lock().unwrap() = vec![row(1, false), row(2, false)];
    let (link, stop, task) = spawn(&store, &center);
    until("recipes synced", || {
        link.status().recipes_synced_at.is_some()
    })
    .await;
    use crate::store::RecipeReads;
    let newest = store.get_recipe("spider-4in", None).await.unwrap().unwrap();
    assert_eq!((newest.version, newest.retired), (2, false));
    assert_eq!(newest.sha256, format!("{:064}", 2));
    stop.send(true).unwrap();
    task.await.unwrap();
    // The center retires version 2: the station takes it at its next sync.
    *center.recipes.lock().unwrap() = vec![row(1, false), row(2, true)];
    let rows = center.recipes.lock().unwrap().clone();
    let sync = store.apply_center_recipes(&rows).await.unwrap();
    assert_eq!((sync.added, sync.retired), (0, 1));
    assert!(
        store
            .get_recipe("spider-4in", Some(2))
            .await
            .unwrap()
            .unwrap()
            .retired
    );
    // A station's own version 1 with another content is named, not overwritten.
    let mut other = row(1, false);
    other.sha256 = "f".repeat(64);
    let sync = store.apply_center_recipes(&[other]).await.unwrap();
    assert_eq!(sync.conflicts.len(), 1, "{:?}", sync.conflicts);
    let trace = link.recipe_trace(Duration::from_secs(3600));
    assert!(!trace.offline);
    assert!(link.recipe_trace(Duration::ZERO).offline);
}
