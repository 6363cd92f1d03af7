//! The center on PostgreSQL: replication ingest (idempotent, conflicts,
//! gaps), SPC in SQL against `core::qc::spc` on the same values, the audit
//! trail, and a real outage in the middle of a batch.
//!
//! Runs on the server `SPRINGBENCH_PG_URL` names, a fresh schema per test;
//! the outage test starts a private server of its own (`.ci/pg`). Without a
//! server they print why and pass, unless `SPRINGBENCH_PG_TESTS=require`.

use serde_json::json;
use springbench_core::qc::spc::{compute, Spc, SpcPoint};
use springbench_core::qc::VerdictKind;
use springbench_store::corrections::Corrections;
use springbench_store::fleet::{
    BenchState, CenterIngest, Correction, ItemBody, JobVerdictsItem, MeasurementItem,
    RecordingItem, ReplicationItem, StationHello, VerdictItem,
};
use springbench_store::results::{MeasurementReads, NewRecording, PartReads, VerdictReads};
use springbench_store::StoreError;
use springbench_store_pg::test_server::{can_start_private, fresh_schema, url_or_skip, TestServer};
use springbench_store_pg::{PgStore, SpcQuery};

async fn store(test: &str) -> Option<PgStore> {
    let url = url_or_skip(test)?;
    Some(
        PgStore::connect_schema(&url, Some(&fresh_schema(test)))
            .await
            .unwrap(),
    )
}

fn recording(kind: &'static str, content: &str) -> RecordingItem {
    RecordingItem::from_new(
        &NewRecording {
            kind,
            sample_rate_hz: 48_000.0,
            frames: 4,
            stored: springbench_recording::codec::Stored {
                bytes: content.as_bytes().to_vec(),
                channel_scale: None,
            },
        },
        true,
    )
}

fn time(i: usize) -> String {
    // one measurement a minute from 2026-03-01 06:00 UTC
    let t = chrono::DateTime::parse_from_rfc3339("2026-03-01T06:00:00Z").unwrap()
        + chrono::Duration::minutes(i as i64);
    t.with_timezone(&chrono::Utc)
        .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// A measurement of `serial` by `job` with Keff `value` judged `verdict`.
#[allow(clippy::too_many_arguments)]
fn measurement(
    seq: i64,
    id: &str,
    serial: &str,
    job: Option<&str>,
    level: Option<i64>,
    value: f64,
    verdict: &str,
    t: &str,
) -> ReplicationItem {
    let params = if verdict == "invalid" {
        json!([])
    } else {
        json!([{"name": "keff_n_per_m", "value": value, "lower": 950.0, "upper": 1050.0}])
    };
    ReplicationItem {
        seq,
        body: ItemBody::Measurement(Box::new(MeasurementItem {
            id: id.into(),
            part_serial: serial.into(),
            part_kind: Some("spider".into()),
            part_notes: None,
            job_id: job.map(str::to_string),
            source: "bench".into(),
            bench_id: Some("b1".into()),
            config: serde_json::from_value(json!({"target_xpeak_m": 0.002})).unwrap(),
            meta: json!({"id": id}),
            result: Some(json!({"large_signal": {"keff_n_per_m": value}})),
            analysis_error: None,
            target_xpeak_m: Some(0.002),
            repeat_index: Some(0),
            level_index: level,
            pre: recording("pre", &format!("pre of {}", job.unwrap_or(id))),
            main: recording("main", &format!("main of {id}")),
            calibration: None,
            verdicts: vec![VerdictItem {
                id: format!("v-{id}"),
                job_id: job.map(str::to_string),
                measurement_id: Some(id.into()),
                part_serial: serial.into(),
                recipe_name: "R".into(),
                recipe_version: 1,
                recipe_sha256: "ab".repeat(32),
                verdict: verdict.into(),
                detail: json!({"verdict": verdict, "parameters": params}),
                trace: json!({"bench": "b1"}),
                created_at: t.into(),
            }],
            software_version: "0.9.0".into(),
            created_at: t.into(),
        })),
    }
}

fn hello(station: &str, backlog: i64) -> StationHello {
    StationHello {
        station_id: station.into(),
        software_version: "0.9.0".into(),
        contract_version: 1,
        bench_states: vec![BenchState {
            bench_id: "b1".into(),
            state: "idle".into(),
            detail: None,
        }],
        backlog_items: backlog,
        oldest_backlog_at: None,
        sent_at: time(0),
    }
}

/// A deterministic spread around 1000 N/m (a linear congruential generator).
fn values(n: usize, seed: u64) -> Vec<f64> {
    let mut x = seed;
    (0..n)
        .map(|_| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            1000.0 + ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 120.0
        })
        .collect()
}

fn close(a: Option<f64>, b: Option<f64>, what: &str) {
    match (a, b) {
        (Some(a), Some(b)) => assert!(
            (a - b).abs() <= 1e-9 * b.abs().max(1.0),
            "{what}: PostgreSQL {a}, core {b}"
        ),
        (a, b) => assert_eq!(a, b, "{what}"),
    }
}

fn same_spc(pg: &Spc, core: &Spc, what: &str) {
    assert_eq!(pg.n, core.n, "{what}: n");
    assert_eq!(pg.passed, core.passed, "{what}: passed");
    assert_eq!(pg.failed, core.failed, "{what}: failed");
    assert_eq!(pg.invalid, core.invalid, "{what}: invalid");
    assert_eq!(
        (pg.lower, pg.upper),
        (core.lower, core.upper),
        "{what}: limits"
    );
    close(pg.mean, core.mean, &format!("{what}: mean"));
    close(pg.sigma, core.sigma, &format!("{what}: sigma"));
    close(
        pg.sigma_within,
        core.sigma_within,
        &format!("{what}: sigma_within"),
    );
    close(pg.cp, core.cp, &format!("{what}: cp"));
    close(pg.cpk, core.cpk, &format!("{what}: cpk"));
    close(pg.pp, core.pp, &format!("{what}: pp"));
    close(pg.ppk, core.ppk, &format!("{what}: ppk"));
    close(
        pg.yield_fraction,
        core.yield_fraction,
        &format!("{what}: yield"),
    );
}

/// What went in, to compute the truth from.
#[derive(Clone)]
struct Made {
    station: String,
    id: String,
    job: Option<String>,
    level: Option<i64>,
    value: f64,
    verdict: &'static str,
    time: String,
}

/// Three stations, 30 jobs each of two repeats at two levels, a few
/// measurements without a job; ingested interleaved, one batch per job.
async fn ingest_fleet(s: &PgStore) -> Vec<Made> {
    let mut made = Vec::new();
    let stations = ["line-1", "line-2", "line-3"];
    let mut seqs = [0i64; 3];
    let v = values(3 * 30 * 4 + 30, 7);
    let mut k = 0;
    for job in 0..30 {
        for (si, st) in stations.iter().enumerate() {
            // line-3 drifts: +25 N/m
            let drift = if si == 2 { 25.0 } else { 0.0 };
            let job_id = format!("{st}-job-{job}");
            let serial = format!("{st}-P{job:03}");
            let mut batch = Vec::new();
            for level in 0..2 {
                for rep in 0..2 {
                    let value = v[k] + drift;
                    let verdict = if k % 17 == 5 {
                        "invalid"
                    } else if (950.0..=1050.0).contains(&value) {
                        "pass"
                    } else {
                        "fail"
                    };
                    let id = format!("{job_id}-l{level}-r{rep}");
                    let t = time(k);
                    seqs[si] += 1;
                    batch.push(measurement(
                        seqs[si],
                        &id,
                        &serial,
                        Some(&job_id),
                        Some(level),
                        value,
                        verdict,
                        &t,
                    ));
                    made.push(Made {
                        station: st.to_string(),
                        id,
                        job: Some(job_id.clone()),
                        level: Some(level),
                        value,
                        verdict,
                        time: t,
                    });
                    k += 1;
                }
            }
            // A measurement without a job (an import) now and then.
            if job % 3 == si {
                let value = v[k] + drift;
                let id = format!("{st}-import-{job}");
                let t = time(k);
                seqs[si] += 1;
                batch.push(measurement(
                    seqs[si], &id, &serial, None, None, value, "pass", &t,
                ));
                made.push(Made {
                    station: st.to_string(),
                    id,
                    job: None,
                    level: None,
                    value,
                    verdict: "pass",
                    time: t,
                });
                k += 1;
            }
            let r = s.ingest(st, &batch).await.unwrap();
            assert_eq!(r.inserted as usize, batch.len());
        }
    }
    made
}

/// `core::qc::spc::compute` over the newest `last` of `made` (of `station`).
fn truth(made: &[Made], last: usize, station: Option<&str>) -> Spc {
    let window = &made[made.len().saturating_sub(last)..];
    let mut points = Vec::new();
    let mut invalid = 0;
    for m in window
        .iter()
        .filter(|m| station.is_none_or(|s| m.station == s))
    {
        if m.verdict == "invalid" {
            invalid += 1;
            continue;
        }
        points.push(SpcPoint {
            recipe_version: None,
            time: m.time.clone(),
            part_serial: String::new(),
            measurement_id: m.id.clone(),
            // job ids are unique per station here, as UUIDs are in a fleet
            job_id: m.job.clone(),
            level_index: m.level,
            value: m.value,
            repeats: 1,
            verdict: match m.verdict {
                "pass" => VerdictKind::Pass,
                _ => VerdictKind::Fail,
            },
        });
    }
    compute(
        "keff_n_per_m",
        "N/m",
        Some(950.0),
        Some(1050.0),
        points,
        invalid,
    )
}

/// Keff of recipe R with its limits, every verdict, all stations.
fn keff() -> SpcQuery<'static> {
    SpcQuery {
        recipe: "R",
        parameter: "keff_n_per_m",
        unit: "N/m",
        lower: Some(950.0),
        upper: Some(1050.0),
        ..Default::default()
    }
}

#[tokio::test]
async fn spc_in_sql_equals_core_across_and_per_station() {
    let Some(s) = store("spc_in_sql").await else {
        return;
    };
    let made = ingest_fleet(&s).await;
    assert_eq!(made.len(), 390);
    // Windows whose oldest verdict is a point's second repeat (its first
    // outside) are among them: the center recomputes that point.
    let cuts = [390usize, 150, 149, 7, 6]
        .iter()
        .filter(|&&last| cuts_a_point(&made, last))
        .count();
    assert!(cuts > 0, "a window starts inside a point");
    for last in [390usize, 150, 149, 7, 6] {
        let all = s
            .spc(&SpcQuery {
                last: Some(last as i64),
                ..keff()
            })
            .await
            .unwrap();
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].station_id, None);
        let t = truth(&made, last, None);
        assert!(t.n > 1, "a window of {last} has points");
        same_spc(&all[0].spc, &t, &format!("all stations, last {last}"));
        let per = s
            .spc(&SpcQuery {
                last: Some(last as i64),
                per_station: true,
                ..keff()
            })
            .await
            .unwrap();
        let ids: Vec<Option<&str>> = per.iter().map(|g| g.station_id.as_deref()).collect();
        if last >= 150 {
            assert_eq!(ids, [Some("line-1"), Some("line-2"), Some("line-3")]);
        }
        for g in &per {
            let t = truth(&made, last, g.station_id.as_deref());
            same_spc(&g.spc, &t, &format!("{:?}, last {last}", g.station_id));
        }
    }
    // The drifting line shows: its mean is 25 N/m above the others' (within the spread).
    let per = s
        .spc(&SpcQuery {
            per_station: true,
            ..keff()
        })
        .await
        .unwrap();
    let mean = |i: usize| per[i].spc.mean.unwrap();
    assert!(mean(2) - (mean(0) + mean(1)) / 2.0 > 10.0, "{per:?}");
    // A time window: [since, until) on the station's times.
    let (since, until) = (time(100), time(200));
    let w = s
        .spc(&SpcQuery {
            since: Some(&since),
            until: Some(&until),
            ..keff()
        })
        .await
        .unwrap();
    let inside: Vec<Made> = made
        .iter()
        .filter(|m| m.time >= since && m.time < until)
        .cloned()
        .collect();
    same_spc(&w[0].spc, &truth(&inside, usize::MAX, None), "time window");
    // Unknown parameter: no points, the invalid verdicts still counted.
    let none = s
        .spc(&SpcQuery {
            recipe: "R",
            parameter: "no_such",
            last: Some(100),
            ..Default::default()
        })
        .await
        .unwrap();
    assert_eq!(none[0].spc.n, 0);
    assert_eq!(none[0].spc.mean, None);
    // A void of one repeat of a point: the point is its other repeat now,
    // across stations and on its station, in the whole and in a cut window.
    let gone = made
        .iter()
        .rev()
        .find(|m| m.id.ends_with("-l1-r0") && m.verdict != "invalid")
        .unwrap();
    let job: usize = gone
        .job
        .as_ref()
        .unwrap()
        .rsplit('-')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(s
        .correct(&Correction {
            id: "void-1".into(),
            kind: "void_measurement".into(),
            part_serial: format!("{}-P{job:03}", gone.station),
            measurement_id: Some(gone.id.clone()),
            old_value: None,
            new_value: None,
            reason: "clamp not closed".into(),
            made_by: Some("qe".into()),
            made_at: time(0),
        })
        .await
        .unwrap());
    let left: Vec<Made> = made.iter().filter(|m| m.id != gone.id).cloned().collect();
    for last in [389usize, 150, 149] {
        let all = s
            .spc(&SpcQuery {
                last: Some(last as i64),
                ..keff()
            })
            .await
            .unwrap();
        same_spc(
            &all[0].spc,
            &truth(&left, last, None),
            &format!("after the void, last {last}"),
        );
        let per = s
            .spc(&SpcQuery {
                last: Some(last as i64),
                per_station: true,
                ..keff()
            })
            .await
            .unwrap();
        for g in &per {
            let t = truth(&left, last, g.station_id.as_deref());
            same_spc(
                &g.spc,
                &t,
                &format!("after the void, {:?}, last {last}", g.station_id),
            );
        }
    }
}

/// Whether the newest `last` of `made` begin with a repeat whose point's
/// earlier repeat is outside (same job and level, both with a value).
fn cuts_a_point(made: &[Made], last: usize) -> bool {
    let i = made.len() - last;
    i > 0
        && made[i].job.is_some()
        && (made[i].job.as_ref(), made[i].level) == (made[i - 1].job.as_ref(), made[i - 1].level)
        && made[i].verdict != "invalid"
        && made[i - 1].verdict != "invalid"
}

#[tokio::test]
async fn ingest_is_idempotent_reports_conflicts_and_gaps() {
    let Some(s) = store("ingest_idempotent").await else {
        return;
    };
    let st = s.hello(&hello("line-1", 4)).await.unwrap();
    assert_eq!((st.backlog_items, st.items, st.last_seq), (4, 0, None));
    let t = time(0);
    let batch = vec![
        measurement(1, "m-1", "P-1", Some("j-1"), None, 1000.0, "pass", &t),
        measurement(2, "m-2", "P-1", Some("j-1"), None, 1010.0, "pass", &t),
        ReplicationItem {
            seq: 3,
            body: ItemBody::JobVerdicts(JobVerdictsItem {
                job_id: "j-1".into(),
                part_serial: "P-1".into(),
                verdicts: vec![VerdictItem {
                    id: "v-j-1".into(),
                    job_id: Some("j-1".into()),
                    measurement_id: None,
                    part_serial: "P-1".into(),
                    recipe_name: "R".into(),
                    recipe_version: 1,
                    recipe_sha256: "ab".repeat(32),
                    verdict: "pass".into(),
                    detail: json!({"verdict": "pass"}),
                    trace: json!({}),
                    created_at: t.clone(),
                }],
            }),
        },
    ];
    let r = s.ingest("line-1", &batch).await.unwrap();
    assert_eq!((r.inserted, r.already_stored, r.conflicts.len()), (3, 0, 0));
    let counts = s.counts().await.unwrap();
    // 1 part, 2 measurements, 3 verdicts, 3 recordings (the job's pre once)
    assert_eq!(counts, (1, 2, 3, 3));
    // The same batch again (a lost acknowledgement): nothing twice.
    let r = s.ingest("line-1", &batch).await.unwrap();
    assert_eq!((r.inserted, r.already_stored, r.conflicts.len()), (0, 3, 0));
    assert_eq!(s.counts().await.unwrap(), counts);
    // Rows name their station.
    let p = s.get_part("P-1").await.unwrap().unwrap();
    assert_eq!(p.station_id.as_deref(), Some("line-1"));
    assert_eq!(p.verdict.as_deref(), Some("pass"));
    let hist = s
        .list_measurements(Some("P-1"), None, None, 10)
        .await
        .unwrap();
    assert!(hist
        .iter()
        .all(|m| m.station_id.as_deref() == Some("line-1")));
    let v = s.measurement_verdict("m-1").await.unwrap().unwrap();
    assert_eq!(v.station_id.as_deref(), Some("line-1"));

    // Same id, other content: a conflict, the first copy stays.
    let changed = measurement(4, "m-2", "P-1", Some("j-1"), None, 1234.0, "fail", &t);
    // Another station sending an id line-1 holds.
    let stolen = measurement(1, "m-1", "P-1", Some("j-1"), None, 1000.0, "pass", &t);
    let r = s
        .ingest("line-1", std::slice::from_ref(&changed))
        .await
        .unwrap();
    assert_eq!(r.conflicts.len(), 1);
    assert!(r.conflicts[0].reason.contains("another content"), "{r:?}");
    let r = s.ingest("line-2", &[stolen]).await.unwrap();
    assert_eq!(r.conflicts.len(), 1);
    assert!(
        r.conflicts[0].reason.contains("from station line-1"),
        "{r:?}"
    );
    assert_eq!(s.counts().await.unwrap(), counts);
    let (m2, _, _) = s.get_measurement("m-2").await.unwrap().unwrap();
    assert_eq!(m2.summary["keff_n_per_m"], json!(1010.0));

    // A gap in line-1's stream shows until it is filled.
    let r = s
        .ingest(
            "line-1",
            &[measurement(6, "m-6", "P-2", None, None, 990.0, "pass", &t)],
        )
        .await
        .unwrap();
    assert_eq!(r.inserted, 1);
    let st = s.hello(&hello("line-1", 1)).await.unwrap();
    // seq 4 was a conflict (kept in the log, not held), 5 never arrived.
    assert_eq!((st.items, st.last_seq, st.missing_items), (4, Some(6), 2));
    s.ingest(
        "line-1",
        &[
            measurement(4, "m-4", "P-2", None, None, 995.0, "pass", &t),
            measurement(5, "m-5", "P-2", None, None, 996.0, "pass", &t),
        ],
    )
    .await
    .unwrap();
    let stations = s.stations().await.unwrap();
    let l1 = stations.iter().find(|x| x.station_id == "line-1").unwrap();
    assert_eq!((l1.items, l1.last_seq, l1.missing_items), (6, Some(6), 0));
    assert_eq!(l1.bench_states[0].state, "idle");
    // line-2 sent a batch without a hello: it is listed, and says so.
    let l2 = stations.iter().find(|x| x.station_id == "line-2").unwrap();
    assert!(l2.software_version.contains("no hello"), "{l2:?}");

    // A batch that contradicts itself is refused whole.
    let mut bad = measurement(7, "m-7", "P-3", None, None, 1.0, "pass", &t);
    if let ItemBody::Measurement(m) = &mut bad.body {
        m.verdicts[0].verdict = "maybe".into();
    }
    let ok = measurement(8, "m-8", "P-3", None, None, 1.0, "pass", &t);
    match s.ingest("line-1", &[ok, bad]).await {
        Err(StoreError::Invalid(e)) => assert!(e.contains("item 7") && e.contains("maybe"), "{e}"),
        other => panic!("expected Invalid, got {other:?}"),
    }
    assert!(s.get_measurement("m-8").await.unwrap().is_none());
    assert!(s.get_part("P-3").await.unwrap().is_none());
    // A contract this center does not know is refused.
    let mut h = hello("line-9", 0);
    h.contract_version = 99;
    assert!(matches!(s.hello(&h).await, Err(StoreError::Invalid(_))));
}

#[tokio::test]
async fn corrections_and_voids_keep_an_audit_trail_and_leave_spc() {
    let Some(s) = store("corrections").await else {
        return;
    };
    let t = time(0);
    let items: Vec<ReplicationItem> = [1000.0, 1020.0, 980.0, 1040.0]
        .iter()
        .enumerate()
        .map(|(i, v)| {
            measurement(
                i as i64 + 1,
                &format!("m-{i}"),
                if i < 3 { "P-1" } else { "P-X" },
                None,
                None,
                *v,
                "pass",
                &time(i),
            )
        })
        .collect();
    s.ingest("line-1", &items).await.unwrap();
    let spc = |s: PgStore| async move {
        s.spc(&SpcQuery {
            lower: None,
            upper: None,
            ..keff()
        })
        .await
        .unwrap()
        .remove(0)
        .spc
    };
    assert_eq!(spc(s.clone()).await.n, 4);
    // A void from the station, replicated: the measurement stays, out of SPC.
    let void = Correction {
        id: "c-1".into(),
        kind: "void_measurement".into(),
        part_serial: "P-1".into(),
        measurement_id: Some("m-1".into()),
        old_value: None,
        new_value: None,
        reason: "clamp not closed".into(),
        made_by: Some("admin".into()),
        made_at: t.clone(),
    };
    let r = s
        .ingest(
            "line-1",
            &[ReplicationItem {
                seq: 5,
                body: ItemBody::Correction(void.clone()),
            }],
        )
        .await
        .unwrap();
    assert_eq!(r.inserted, 1);
    assert!(s.get_measurement("m-1").await.unwrap().is_some());
    assert_eq!(
        s.measurement_void("m-1").await.unwrap().as_deref(),
        Some("c-1")
    );
    let after = spc(s.clone()).await;
    assert_eq!(after.n, 3);
    // = core over the three left
    let t3 = compute(
        "keff_n_per_m",
        "N/m",
        None,
        None,
        [1000.0, 980.0, 1040.0]
            .iter()
            .enumerate()
            .map(|(i, v)| SpcPoint {
                recipe_version: None,
                time: time(i),
                part_serial: String::new(),
                measurement_id: format!("{i}"),
                job_id: None,
                level_index: None,
                value: *v,
                repeats: 1,
                verdict: VerdictKind::Pass,
            })
            .collect(),
        0,
    );
    same_spc(&after, &t3, "after the void");
    // A serial correction at the center: P-X was P-2.
    let fix = Correction {
        id: "c-2".into(),
        kind: "part_serial".into(),
        part_serial: "P-X".into(),
        measurement_id: None,
        old_value: Some("P-X".into()),
        new_value: Some("P-2".into()),
        reason: "label misread".into(),
        made_by: Some("qe".into()),
        made_at: t.clone(),
    };
    assert!(s.correct(&fix).await.unwrap());
    assert!(!s.correct(&fix).await.unwrap(), "applied once");
    let p2 = s.get_part("P-2").await.unwrap().unwrap();
    assert_eq!(p2.measurement_count, 1);
    let px = s
        .get_part("P-X")
        .await
        .unwrap()
        .expect("nothing is deleted");
    assert_eq!(px.measurement_count, 0);
    assert_eq!(
        s.measurement_verdict("m-3")
            .await
            .unwrap()
            .unwrap()
            .part_serial,
        "P-2"
    );
    // The kind, too.
    let kind = Correction {
        id: "c-3".into(),
        kind: "part_kind".into(),
        part_serial: "P-2".into(),
        measurement_id: None,
        old_value: Some("spider".into()),
        new_value: Some("cone".into()),
        reason: "wrong recipe chosen".into(),
        made_by: None,
        made_at: t.clone(),
    };
    assert!(s.correct(&kind).await.unwrap());
    assert_eq!(
        s.get_part("P-2").await.unwrap().unwrap().kind.as_deref(),
        Some("cone")
    );
    // The audit trail, readable: all of it, and a part's (by its new serial too).
    let log = s.audit_log(None, None, 10).await.unwrap();
    let got: Vec<(&str, Option<&str>, &str)> = log
        .iter()
        .map(|e| {
            (
                e.correction.id.as_str(),
                e.station_id.as_deref(),
                e.correction.reason.as_str(),
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            ("c-1", Some("line-1"), "clamp not closed"),
            ("c-2", None, "label misread"),
            ("c-3", None, "wrong recipe chosen")
        ]
    );
    let p2log = s.audit_log(Some("P-2"), None, 10).await.unwrap();
    assert_eq!(p2log.len(), 2);
    let page = s.audit_log(None, Some(log[0].seq), 1).await.unwrap();
    assert_eq!(page[0].correction.id, "c-2");
    // No reason, no correction.
    let mut bad = kind.clone();
    bad.id = "c-4".into();
    bad.reason = " ".into();
    assert!(matches!(s.correct(&bad).await, Err(StoreError::Invalid(_))));
    // A void of a measurement the center does not have refuses the batch.
    let mut ghost = void;
    ghost.id = "c-5".into();
    ghost.measurement_id = Some("nope".into());
    assert!(matches!(
        s.ingest(
            "line-1",
            &[ReplicationItem {
                seq: 6,
                body: ItemBody::Correction(ghost)
            }]
        )
        .await,
        Err(StoreError::Invalid(_))
    ));
}

#[tokio::test]
async fn a_stopped_server_mid_batch_stores_nothing_and_the_retry_all() {
    const TEST: &str = "a_stopped_server_mid_batch";
    if !can_start_private(TEST) {
        return;
    }
    let mut server = TestServer::start(55433).expect("a private PostgreSQL starts");
    let url = server.url();
    let s = PgStore::connect(&url).await.unwrap();
    let batch: Vec<ReplicationItem> = (0..50)
        .map(|i| {
            measurement(
                i + 1,
                &format!("m-{i}"),
                &format!("P-{}", i / 5),
                None,
                None,
                1000.0 + i as f64,
                "pass",
                &time(i as usize),
            )
        })
        .collect();
    // Another session holds the key of the batch's last item in an open
    // transaction: the ingest stops there, in the middle of its
    // transaction, until the server goes down.
    let mut hold = sqlx::PgPool::connect(&url)
        .await
        .unwrap()
        .begin()
        .await
        .unwrap();
    sqlx::query(
        "INSERT INTO station_items (item_id, station_id, seq, content_sha256, received_at) \
         VALUES ('measurement:m-49', 'line-1', 50, 'x', 'now')",
    )
    .execute(&mut *hold)
    .await
    .unwrap();
    let ingest = {
        let s = s.clone();
        let batch = batch.clone();
        tokio::spawn(async move { s.ingest("line-1", &batch).await })
    };
    // Wait until the ingest waits for that lock (49 items written, uncommitted).
    let watcher = sqlx::PgPool::connect(&url).await.unwrap();
    let mut waited = 0;
    loop {
        let n: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM pg_stat_activity WHERE wait_event_type = 'Lock' AND query LIKE 'INSERT INTO station_items%'",
        )
        .fetch_one(&watcher)
        .await
        .unwrap();
        if n == 1 {
            break;
        }
        waited += 1;
        assert!(waited < 600, "the ingest never reached the held item");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    watcher.close().await;
    server.stop().unwrap();
    let r = ingest.await.unwrap();
    assert!(
        r.is_err(),
        "the batch cannot commit without a server: {r:?}"
    );
    drop(hold);
    server.start_again().unwrap();
    // Nothing of the batch is there; the retry (same store, its pool
    // reconnects) stores all of it, once.
    assert_eq!(s.counts().await.unwrap(), (0, 0, 0, 0));
    let r = s.ingest("line-1", &batch).await.unwrap();
    assert_eq!((r.inserted, r.already_stored), (50, 0));
    assert_eq!(s.counts().await.unwrap(), (10, 50, 50, 100));
    let st = s.stations().await.unwrap();
    assert_eq!((st[0].items, st[0].missing_items), (50, 0));
    let r = s.ingest("line-1", &batch).await.unwrap();
    assert_eq!((r.inserted, r.already_stored), (0, 50));
    s.close().await;
}

/// A station's corrections travel its outbox to the center: the center
/// applies them after the measurements of their part, in the station's
/// order, with the station in its audit log; nothing is deleted there either.
#[tokio::test]
async fn a_stations_corrections_reach_the_center_in_order() {
    use springbench_store::results::{FinishedMeasurement, NewMeasurement, ResultIngest};
    let Some(center) = store("station_corrections").await else {
        return;
    };
    let station = springbench_store::Store::memory().await.unwrap();
    for (i, serial) in ["P-X", "P-X", "P-Y"].iter().enumerate() {
        let id = format!("m-{i}");
        let rec = |kind: &'static str, tag: u8| NewRecording {
            kind,
            sample_rate_hz: 48_000.0,
            frames: 4,
            stored: springbench_recording::codec::Stored {
                bytes: vec![tag, i as u8, 2, 3],
                channel_scale: None,
            },
        };
        let f = FinishedMeasurement {
            part: (serial.to_string(), Some("spider".into()), None),
            measurement: NewMeasurement {
                id: id.clone(),
                part_serial: serial.to_string(),
                job_id: None,
                source: "import",
                bench_id: None,
                config: Default::default(),
                meta: springbench_store::Doc::Received(json!({"id": id})),
                analysis_error: None,
                result: Some(springbench_store::Doc::Received(
                    json!({"large_signal": {"keff_n_per_m": 1000.0}}),
                )),
                target_xpeak_m: Some(0.002),
                repeat_index: None,
                level_index: None,
                pre: 0,
                main: 1,
            },
            recordings: vec![rec("pre", 1), rec("main", 2)],
            verdicts: vec![],
            software_version: "0.9.0".into(),
            created_at: time(i),
        };
        station.upsert_measurement(&f).await.unwrap();
    }
    let c = |id: &str, kind: &str, part: &str, m: Option<&str>, new: Option<&str>| Correction {
        id: id.into(),
        kind: kind.into(),
        part_serial: part.into(),
        measurement_id: m.map(str::to_string),
        old_value: None,
        new_value: new.map(str::to_string),
        reason: format!("why {id}"),
        made_by: Some("admin".into()),
        made_at: time(10),
    };
    // P-X's second measurement was P-Y's; then m-0 is voided; P-Y is a cone.
    for x in [
        c("c-1", "part_serial", "P-X", Some("m-1"), Some("P-Y")),
        c("c-2", "void_measurement", "P-X", Some("m-0"), None),
        c("c-3", "part_kind", "P-Y", None, Some("cone")),
    ] {
        assert!(station.correct(&x).await.unwrap());
    }
    let rows = station.outbox_next(100).await.unwrap();
    let items = station.outbox_items(&rows, false).await.unwrap();
    let kinds: Vec<&str> = items
        .iter()
        .map(|i| match &i.body {
            ItemBody::Measurement(_) => "measurement",
            ItemBody::JobVerdicts(_) => "job",
            ItemBody::Correction(_) => "correction",
            ItemBody::LongTermTest(_) => "long_term_test",
        })
        .collect();
    assert_eq!(
        kinds,
        [
            "measurement",
            "measurement",
            "measurement",
            "correction",
            "correction",
            "correction"
        ]
    );
    let r = center.ingest("line-1", &items).await.unwrap();
    assert_eq!(r.inserted, 6);
    // The center holds what the station holds.
    for s in ["P-X", "P-Y"] {
        let (a, b) = (
            station.get_part(s).await.unwrap().unwrap(),
            center.get_part(s).await.unwrap().unwrap(),
        );
        assert_eq!(
            (a.kind.clone(), a.measurement_count),
            (b.kind, b.measurement_count),
            "{s}"
        );
    }
    assert_eq!(
        center
            .get_part("P-Y")
            .await
            .unwrap()
            .unwrap()
            .measurement_count,
        2
    );
    assert_eq!(
        center
            .get_measurement("m-1")
            .await
            .unwrap()
            .unwrap()
            .0
            .part_serial,
        "P-Y"
    );
    assert_eq!(
        center.measurement_void("m-0").await.unwrap().as_deref(),
        Some("c-2")
    );
    assert!(
        center.get_measurement("m-0").await.unwrap().is_some(),
        "kept"
    );
    let log: Vec<(String, Option<String>, Option<String>)> = center
        .audit_log(None, None, 10)
        .await
        .unwrap()
        .into_iter()
        .map(|e| (e.correction.id, e.station_id, e.correction.old_value))
        .collect();
    let line = Some("line-1".to_string());
    assert_eq!(
        log,
        [
            ("c-1".into(), line.clone(), Some("P-X".into())),
            ("c-2".into(), line.clone(), None),
            ("c-3".into(), line, Some("spider".into())),
        ]
    );
    // Delivered again (a lost acknowledgement): applied once.
    let again = center.ingest("line-1", &items).await.unwrap();
    assert_eq!((again.inserted, again.already_stored), (0, 6));
    assert_eq!(center.audit_log(None, None, 10).await.unwrap().len(), 3);
}

/// A void takes its job out of the part's verdict and the yield, on the
/// station and at the center: the job was judged with the voided
/// measurement among its repeats, so its verdict no longer judges the part
/// (decision 0057). The part's verdict falls back to its newest job without
/// a void (none: no verdict); the job's own verdict stays readable.
#[tokio::test]
async fn a_void_takes_its_job_out_of_the_parts_verdict_and_the_yield() {
    use springbench_store::qc::JobRecords;
    use springbench_store::results::{NewMeasurement, NewVerdict};
    use springbench_store::{Inserted, JobState};
    let Some(center) = store("void_verdicts").await else {
        return;
    };
    let station = springbench_store::Store::memory().await.unwrap();
    let rec = |kind: &'static str, tag: u8| NewRecording {
        kind,
        sample_rate_hz: 48_000.0,
        frames: 4,
        stored: springbench_recording::codec::Stored {
            bytes: vec![tag, 1, 2, 3],
            channel_scale: None,
        },
    };
    let verdict =
        |id: &str, job: &str, m: Option<&str>, serial: &str, v: &'static str| NewVerdict {
            id: id.into(),
            job_id: Some(job.into()),
            measurement_id: m.map(str::to_string),
            part_serial: serial.into(),
            recipe_name: "r".into(),
            recipe_version: 1,
            recipe_sha256: "ab".repeat(32),
            verdict: v,
            detail: json!({"verdict": v}),
            trace: json!({"recipe": {"name": "r", "version": 1}}),
        };
    // P-1: job j1 passes (m1); job j2 fails (m2 passes, m3 fails).
    // P-2: job j3 passes (m4).
    // (job, part, its measurements and their verdicts, the job's verdict)
    type Job<'a> = (
        &'a str,
        &'a str,
        &'a [(&'a str, &'static str)],
        &'static str,
    );
    let jobs: [Job; 3] = [
        ("j1", "P-1", &[("m1", "pass")], "pass"),
        ("j2", "P-1", &[("m2", "pass"), ("m3", "fail")], "fail"),
        ("j3", "P-2", &[("m4", "pass")], "pass"),
    ];
    for (job, serial, ms, jv) in jobs {
        let r = station
            .insert_job(
                job,
                "b1",
                (serial, None, None),
                0,
                &springbench_core::job::StoredRequest::self_check("b1"),
                job,
                None,
            )
            .await
            .unwrap();
        assert!(matches!(r, Inserted::New(_)));
        assert!(station.start_job(job).await.unwrap());
        let mut verdicts: Vec<NewVerdict> = ms
            .iter()
            .map(|(m, v)| verdict(&format!("v-{m}"), job, Some(m), serial, v))
            .collect();
        verdicts.push(verdict(&format!("v-{job}"), job, None, serial, jv));
        let meas = ms
            .iter()
            .enumerate()
            .map(|(i, (m, _))| NewMeasurement {
                id: m.to_string(),
                part_serial: serial.into(),
                job_id: Some(job.into()),
                source: "bench",
                bench_id: Some("b1".into()),
                config: Default::default(),
                meta: springbench_store::Doc::Received(json!({"id": m})),
                result: Some(springbench_store::Doc::Received(
                    json!({"large_signal": {"keff_n_per_m": 1000.0}}),
                )),
                analysis_error: None,
                target_xpeak_m: Some(0.002),
                repeat_index: Some(i as i64),
                level_index: Some(0),
                pre: 0,
                main: 1,
            })
            .collect();
        station
            .finish_job_qc(
                job,
                JobState::Succeeded,
                None,
                Some(1.0),
                &[],
                &[],
                vec![rec("pre", 1), rec("main", 2)],
                meas,
                &JobRecords {
                    verdicts,
                    ..JobRecords::default()
                },
            )
            .await
            .unwrap();
    }
    let c = |id: &str, serial: &str, m: &str| Correction {
        id: id.into(),
        kind: "void_measurement".into(),
        part_serial: serial.into(),
        measurement_id: Some(m.into()),
        old_value: None,
        new_value: None,
        reason: format!("why {id}"),
        made_by: Some("admin".into()),
        made_at: time(10),
    };
    let verdict_of = |p: Option<springbench_store::results::Part>| p.unwrap().verdict;
    assert_eq!(
        station.part_verdict("P-1").await.unwrap().unwrap().id,
        "v-j2"
    );
    // m3 was mis-clamped: j2 no longer judges P-1, j1 does; P-2's only job goes.
    assert!(station.correct(&c("c-1", "P-1", "m3")).await.unwrap());
    assert!(station.correct(&c("c-2", "P-2", "m4")).await.unwrap());
    assert_eq!(
        station.part_verdict("P-1").await.unwrap().map(|v| v.id),
        Some("v-j1".into()),
        "station"
    );
    assert_eq!(
        verdict_of(station.get_part("P-1").await.unwrap()).as_deref(),
        Some("pass")
    );
    assert_eq!(
        station.part_verdict("P-2").await.unwrap().map(|v| v.id),
        None
    );
    let listed: Vec<_> = station
        .list_parts(None, 10)
        .await
        .unwrap()
        .into_iter()
        .map(|p| (p.serial, p.verdict))
        .collect();
    assert_eq!(
        listed,
        [
            ("P-1".to_string(), Some("pass".to_string())),
            ("P-2".to_string(), None)
        ]
    );
    // The job's own verdict stays as it was judged.
    assert_eq!(station.job_verdicts("j2").await.unwrap()[0].verdict, "fail");

    // The center, after the station's outbox: the same answers, and the
    // yield counts j1 only.
    let rows = station.outbox_next(100).await.unwrap();
    let items = station.outbox_items(&rows, false).await.unwrap();
    center.ingest("line-1", &items).await.unwrap();
    assert_eq!(
        center.part_verdict("P-1").await.unwrap().map(|v| v.id),
        Some("v-j1".into()),
        "center"
    );
    assert_eq!(
        verdict_of(center.get_part("P-1").await.unwrap()).as_deref(),
        Some("pass")
    );
    assert_eq!(
        center.part_verdict("P-2").await.unwrap().map(|v| v.id),
        None
    );
    assert_eq!(verdict_of(center.get_part("P-2").await.unwrap()), None);
    let days = center
        .yield_per_day("r", "2000-01-01T00:00:00.000Z", "2100-01-01T00:00:00.000Z")
        .await
        .unwrap();
    let (passed, failed): (i64, i64) = days
        .iter()
        .fold((0, 0), |(p, f), d| (p + d.passed, f + d.failed));
    assert_eq!((passed, failed), (1, 0), "{days:?}");
    assert_eq!(center.job_verdicts("j2").await.unwrap()[0].verdict, "fail");
}

/// A station's serial correction that names no measurement moves that
/// station's measurements and verdicts of the part, not another station's
/// of the same serial: the station that corrects knows only what it
/// measured (it found the serial misread on its own line). Before the fix
/// the center moved every station's measurements of the serial.
#[tokio::test]
async fn a_stations_serial_correction_moves_only_its_own_measurements() {
    let Some(s) = store("serial_per_station").await else {
        return;
    };
    s.ingest(
        "line-1",
        &[measurement(
            1,
            "a-1",
            "P-7",
            None,
            None,
            1000.0,
            "pass",
            &time(0),
        )],
    )
    .await
    .unwrap();
    s.ingest(
        "line-2",
        &[measurement(
            1,
            "b-1",
            "P-7",
            None,
            None,
            1010.0,
            "pass",
            &time(1),
        )],
    )
    .await
    .unwrap();
    let fix = Correction {
        id: "c-7".into(),
        kind: "part_serial".into(),
        part_serial: "P-7".into(),
        measurement_id: None,
        old_value: Some("P-7".into()),
        new_value: Some("P-8".into()),
        reason: "label misread on line 1".into(),
        made_by: Some("admin".into()),
        made_at: time(2),
    };
    s.ingest(
        "line-1",
        &[ReplicationItem {
            seq: 2,
            body: ItemBody::Correction(fix),
        }],
    )
    .await
    .unwrap();
    let serial_of = |id: &'static str| {
        let s = s.clone();
        async move {
            let m = s.get_measurement(id).await.unwrap().unwrap();
            let v = s.measurement_verdict(id).await.unwrap().unwrap();
            (m.0.part_serial, v.part_serial)
        }
    };
    assert_eq!(serial_of("a-1").await, ("P-8".into(), "P-8".into()));
    assert_eq!(serial_of("b-1").await, ("P-7".into(), "P-7".into()));
    let count = |serial: &'static str| {
        let s = s.clone();
        async move { s.get_part(serial).await.unwrap().unwrap().measurement_count }
    };
    assert_eq!(count("P-7").await, 1, "line 2's measurement stays");
    assert_eq!(count("P-8").await, 1, "line 1's measurement moved");
}

fn void_of(id: &str, measurement: &str, serial: &str) -> Correction {
    Correction {
        id: id.into(),
        kind: "void_measurement".into(),
        part_serial: serial.into(),
        measurement_id: Some(measurement.into()),
        old_value: None,
        new_value: None,
        reason: "mis-clamped".into(),
        made_by: Some("admin".into()),
        made_at: time(5),
    }
}

/// Issue 36: a station voided, moved and re-kinded another line's
/// measurement and part at the center (the center did not check who owns
/// what). Now each is refused, named, and recorded for the fleet's readers;
/// an item whose text the database cannot hold (a NUL byte) is refused as
/// the item's fault, not taken for an outage, and the next item goes in.
#[tokio::test]
async fn a_station_corrects_and_voids_only_its_own_and_a_refusal_is_recorded() {
    let Some(s) = store("owner_checks").await else {
        return;
    };
    s.ingest(
        "line-1",
        &[measurement(
            1,
            "a-1",
            "P-1",
            None,
            None,
            1000.0,
            "pass",
            &time(0),
        )],
    )
    .await
    .unwrap();
    let item = |seq, c: Correction| ReplicationItem {
        seq,
        body: ItemBody::Correction(c),
    };
    let mut moved = void_of("c-move", "a-1", "P-1");
    moved.kind = "part_serial".into();
    moved.new_value = Some("P-STOLEN".into());
    let mut kind = void_of("c-kind", "a-1", "P-1");
    kind.kind = "part_kind".into();
    kind.measurement_id = None;
    kind.new_value = Some("woofer".into());
    for (c, why) in [
        (
            void_of("c-void", "a-1", "P-1"),
            "made by station line-1; station line-2 voids its own",
        ),
        (
            moved,
            "made by station line-1; station line-2 moves its own",
        ),
        (kind, "station line-2 measured no part 'P-1'"),
    ] {
        let id = c.id.clone();
        match s.ingest("line-2", &[item(7, c)]).await {
            Err(StoreError::Invalid(m)) => {
                assert!(m.contains(why) && m.contains(&id), "{m}")
            }
            r => panic!("{id}: {r:?}"),
        }
    }
    assert_eq!(s.measurement_void("a-1").await.unwrap(), None);
    let m = s.get_measurement("a-1").await.unwrap().unwrap();
    assert_eq!(m.0.part_serial, "P-1");
    assert_eq!(
        s.get_part("P-1").await.unwrap().unwrap().kind.as_deref(),
        Some("spider")
    );
    let refused = s.refusals(Some("line-2"), None, 100).await.unwrap();
    let ids: Vec<&str> = refused.iter().map(|r| r.item_id.as_str()).collect();
    assert_eq!(
        ids,
        [
            "correction:c-kind",
            "correction:c-move",
            "correction:c-void"
        ]
    );
    assert!(refused
        .iter()
        .all(|r| r.credential_station.as_deref() == Some("line-2")));
    // Sent again (the station's item-by-item retry): counted, not listed twice.
    let _ = s
        .ingest("line-2", &[item(7, void_of("c-void", "a-1", "P-1"))])
        .await;
    let refused = s.refusals(Some("line-2"), None, 100).await.unwrap();
    assert_eq!(refused.len(), 3);
    assert_eq!(
        refused
            .iter()
            .find(|r| r.item_id == "correction:c-void")
            .unwrap()
            .times,
        2
    );
    // Its own: applied.
    assert!(s
        .ingest("line-1", &[item(2, void_of("c-own", "a-1", "P-1"))])
        .await
        .is_ok());
    assert_eq!(
        s.measurement_void("a-1").await.unwrap().as_deref(),
        Some("c-own")
    );

    // A NUL byte in a part's notes: the item's fault (Invalid, recorded),
    // nothing of the batch written; the next batch goes in.
    let mut bad = measurement(3, "a-2", "P-2", None, None, 1000.0, "pass", &time(1));
    if let ItemBody::Measurement(m) = &mut bad.body {
        m.part_notes = Some("torn\0edge".into());
    }
    let good = measurement(4, "a-3", "P-3", None, None, 1000.0, "pass", &time(2));
    match s.ingest("line-1", &[bad, good.clone()]).await {
        Err(StoreError::Invalid(m)) => assert!(m.contains("item 3") && m.contains("NUL"), "{m}"),
        r => panic!("{r:?}"),
    }
    assert!(s.get_measurement("a-3").await.unwrap().is_none());
    s.ingest("line-1", &[good]).await.unwrap();
    assert!(s.get_measurement("a-3").await.unwrap().is_some());
    let refused = s.refusals(Some("line-1"), None, 100).await.unwrap();
    assert_eq!(refused[0].item_id, "measurement:a-2");
    let st = s.stations().await.unwrap();
    let line2 = st.iter().find(|x| x.station_id == "line-2");
    assert!(line2.is_none_or(|x| x.refused == 3), "{line2:?}");
    let line1 = st.iter().find(|x| x.station_id == "line-1").unwrap();
    assert_eq!(line1.refused, 1);
}

/// Issue 36 (M1): the center's clock stamps contact and receipt; the
/// station's stays the measurement's own time; a skew is reported. The
/// station's clock is one day ahead in what it sends (its hello's
/// `sent_at`, its measurement's time): the seam is the item itself.
#[tokio::test]
async fn the_centers_clock_stamps_contact_and_a_day_ahead_station_is_reported() {
    let Some(s) = store("clock_skew").await else {
        return;
    };
    let day = chrono::Duration::days(1);
    let ahead = (chrono::Utc::now() + day).to_rfc3339_opts(chrono::SecondsFormat::Millis, true);
    let mut h = hello("line-9", 0);
    h.sent_at = ahead.clone();
    let before = chrono::Utc::now();
    let st = s.hello(&h).await.unwrap();
    s.ingest(
        "line-9",
        &[measurement(
            1,
            "z-1",
            "Z-1",
            Some("j-1"),
            None,
            1000.0,
            "pass",
            &ahead,
        )],
    )
    .await
    .unwrap();
    let after = chrono::Utc::now();
    let at = |t: &str| {
        chrono::DateTime::parse_from_rfc3339(t)
            .unwrap()
            .with_timezone(&chrono::Utc)
    };
    for t in [&st.last_contact_at, &st.first_contact_at] {
        let t = at(t);
        assert!(
            t >= before - chrono::Duration::seconds(1) && t <= after + chrono::Duration::seconds(1),
            "{t}"
        );
    }
    let skew = st.clock_skew_s.unwrap();
    assert!((skew - 86_400.0).abs() < 5.0, "{skew}");
    let listed = s.stations().await.unwrap();
    let l9 = listed.iter().find(|x| x.station_id == "line-9").unwrap();
    assert!(at(&l9.last_contact_at) <= after + chrono::Duration::seconds(1));
    assert_eq!(l9.sent_at, ahead, "the station's own clock stays visible");
    // The measurement keeps its own (the station's) time; yield counts its day.
    let m = s.get_measurement("z-1").await.unwrap().unwrap();
    assert_eq!(m.0.created_at, ahead);
    s.ingest(
        "line-9",
        &[ReplicationItem {
            seq: 2,
            body: ItemBody::JobVerdicts(JobVerdictsItem {
                job_id: "j-1".into(),
                part_serial: "Z-1".into(),
                verdicts: vec![VerdictItem {
                    id: "v-j-1".into(),
                    job_id: Some("j-1".into()),
                    measurement_id: None,
                    part_serial: "Z-1".into(),
                    recipe_name: "R".into(),
                    recipe_version: 1,
                    recipe_sha256: "ab".repeat(32),
                    verdict: "pass".into(),
                    detail: json!({"verdict": "pass"}),
                    trace: json!({}),
                    created_at: ahead.clone(),
                }],
            }),
        }],
    )
    .await
    .unwrap();
    let days = s
        .yield_per_day("R", "2000-01-01T00:00:00.000Z", "2100-01-01T00:00:00.000Z")
        .await
        .unwrap();
    assert_eq!(days.len(), 1, "{days:?}");
    assert_eq!(
        days[0].day,
        &ahead[..10],
        "the measurement's (station's) day"
    );
    assert_eq!(days[0].passed, 1);
}

/// Issue 36 (M2): a station renamed on purpose keeps its history (its rows
/// keep the old id), shows no false gap under its new id, and may still
/// void what it made under the old one; the old id says where it went.
#[tokio::test]
async fn a_renamed_station_keeps_its_history_without_false_gaps() {
    let Some(s) = store("rename").await else {
        return;
    };
    s.ingest(
        "line-3",
        &[
            measurement(1, "r-1", "R-1", None, None, 1000.0, "pass", &time(0)),
            measurement(2, "r-2", "R-2", None, None, 1001.0, "pass", &time(1)),
        ],
    )
    .await
    .unwrap();
    let reg = |retired| springbench_store_pg::StationRegistration {
        station_id: "line-3b".into(),
        former_ids: vec!["line-3".into()],
        retired,
    };
    s.register_stations(&[reg(false)]).await.unwrap();
    s.register_stations(&[reg(false)]).await.unwrap(); // at every start: once
    s.ingest(
        "line-3b",
        &[
            ReplicationItem {
                seq: 3,
                body: ItemBody::Correction(void_of("v-1", "r-1", "R-1")),
            },
            measurement(4, "r-3", "R-3", None, None, 1002.0, "pass", &time(2)),
        ],
    )
    .await
    .unwrap();
    assert_eq!(
        s.measurement_void("r-1").await.unwrap().as_deref(),
        Some("v-1")
    );
    let st = s.stations().await.unwrap();
    let new = st.iter().find(|x| x.station_id == "line-3b").unwrap();
    assert_eq!(
        (new.items, new.last_seq, new.missing_items),
        (4, Some(4), 0),
        "{new:?}"
    );
    let old = st.iter().find(|x| x.station_id == "line-3").unwrap();
    assert_eq!(old.renamed_to.as_deref(), Some("line-3b"));
    let m = s.get_measurement("r-1").await.unwrap().unwrap();
    assert_eq!(
        m.0.station_id.as_deref(),
        Some("line-3"),
        "history keeps the old id"
    );
    // Retired: marked, history stays.
    s.register_stations(&[reg(true)]).await.unwrap();
    let st = s.stations().await.unwrap();
    assert!(st
        .iter()
        .find(|x| x.station_id == "line-3b")
        .unwrap()
        .retired_at
        .is_some());
    assert!(s.get_measurement("r-3").await.unwrap().is_some());
}

fn long_term_item(seq: i64, job: &str, serial: &str, state: &str, k0: f64) -> ReplicationItem {
    ReplicationItem {
        seq,
        body: ItemBody::LongTermTest(Box::new(springbench_store::fleet::LongTermTestItem {
            job_id: job.into(),
            part_serial: serial.into(),
            bench_id: "virtual-1".into(),
            job_state: state.into(),
            created_at: time(0),
            document: json!({"id": job, "state": state, "intervals": [{"k0_n_per_m": k0}]}),
            summary: json!({"id": job, "state": state}),
            last_signals_at_station: false,
        })),
    }
}

/// Issue 32 (decision 0134): a long-term test's id is the station's. Another
/// station that sends a document under the same id is refused (recorded,
/// listed), and the owner's copy stays as it was; the owner's newer copy
/// replaces it, an older one (a late resend) does not.
#[tokio::test]
async fn a_long_term_test_held_by_another_station_is_refused_and_kept() {
    let Some(s) = store("long_term_owner").await else {
        return;
    };
    s.ingest(
        "line-1",
        &[long_term_item(5, "lt-1", "LT-1", "running", 4000.0)],
    )
    .await
    .unwrap();
    match s
        .ingest(
            "line-2",
            &[long_term_item(9, "lt-1", "LT-STOLEN", "succeeded", 1.0)],
        )
        .await
    {
        Err(StoreError::Invalid(m)) => assert!(
            m.contains("long-term test lt-1 is held from station line-1"),
            "{m}"
        ),
        r => panic!("{r:?}"),
    }
    let held = s.long_term_test("lt-1").await.unwrap().unwrap();
    assert_eq!(
        (held.station_id.as_str(), held.part_serial.as_str()),
        ("line-1", "LT-1")
    );
    assert_eq!((held.job_state.as_str(), held.item_seq), ("running", 5));
    assert_eq!(held.document["intervals"][0]["k0_n_per_m"], 4000.0);
    let refused = s.refusals(Some("line-2"), None, 100).await.unwrap();
    let ids: Vec<&str> = refused.iter().map(|r| r.item_id.as_str()).collect();
    assert_eq!(ids, ["long_term_test:lt-1:9"]);
    assert_eq!(
        s.long_term_tests(Some("line-2"), 100).await.unwrap().len(),
        0
    );

    // The owner's newer copy replaces; a late resend of an older one does not.
    s.ingest(
        "line-1",
        &[long_term_item(7, "lt-1", "LT-1", "succeeded", 3900.0)],
    )
    .await
    .unwrap();
    s.ingest(
        "line-1",
        &[long_term_item(6, "lt-1", "LT-1", "running", 3950.0)],
    )
    .await
    .unwrap();
    let held = s.long_term_test("lt-1").await.unwrap().unwrap();
    assert_eq!((held.job_state.as_str(), held.item_seq), ("succeeded", 7));
    assert_eq!(held.document["intervals"][0]["k0_n_per_m"], 3900.0);
}
