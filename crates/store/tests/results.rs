//! The results interface's conformance suite (decision 0034): one set of
//! assertions, generic over the traits of `springbench_store::results`, that
//! every backend must pass after the same ingests. The SQLite store runs it
//! here (in memory and on a file, as a station opens it), the center's
//! PostgreSQL store (`springbench-store-pg`) in a fresh schema per test on
//! the server `SPRINGBENCH_PG_URL` names (without one it prints why and
//! skips, unless `SPRINGBENCH_PG_TESTS=require`, as `.ci/run` sets).
//!
//! The figures are the ones ingested: what goes in through
//! `upsert_measurement` must come out of every read, with the station's
//! software version and time, the derived `summary` and counts, newest-first
//! pages and oldest-first SPC verdicts.

use serde_json::{json, Value};
use springbench_store::corrections::Corrections;
use springbench_store::fleet::Correction;
use springbench_store::qc::{NewVerdict, RecipeExpect};
use springbench_store::{
    FinishedMeasurement, FitReads, NewMeasurement, NewRecording, RecipeReads, ResultStore, Store,
    StoreError, Upserted,
};

const T1: &str = "2026-03-01T08:00:00.000Z";
const T2: &str = "2026-03-01T08:05:00.000Z";
const T3: &str = "2026-03-02T09:00:00.000Z";
const STATION_VERSION: &str = "0.9.1-station";

fn recording(kind: &'static str, tag: u8) -> NewRecording {
    NewRecording {
        kind,
        sample_rate_hz: 48_000.0,
        frames: 4,
        stored: springbench_recording::codec::Stored {
            bytes: vec![tag, 1, 2, 3],
            channel_scale: None,
        },
    }
}

/// A Keff of 16 significant digits (the summary must keep them all).
const KEFF: f64 = 2781.628737573798;

/// A result document with the figures the listing's `summary` is made of.
fn result(keff_n_per_m: f64, k0_n_per_m: f64, reliable: bool) -> Value {
    json!({
        "large_signal": {"keff_n_per_m": keff_n_per_m, "xpeak_m": 0.002, "resonance_hz": 31.5},
        "small_signal": {"k0_n_per_m": k0_n_per_m, "k0_se_n_per_m": 12.0,
                         "misfit_percent": 0.5, "reliable": reliable},
    })
}

/// Verdict `verdict` under recipe R version 3 of measurement `id`.
fn verdict(id: &str, serial: &str, verdict: &'static str) -> NewVerdict {
    NewVerdict {
        id: format!("v-{id}"),
        job_id: None,
        measurement_id: Some(id.to_string()),
        part_serial: serial.to_string(),
        recipe_name: "R".into(),
        recipe_version: 3,
        recipe_sha256: "ab".repeat(32),
        verdict,
        detail: json!({"verdict": verdict}),
        trace: json!({"bench": "line-1"}),
    }
}

#[allow(clippy::too_many_arguments)]
fn finished(
    id: &str,
    serial: &str,
    kind: Option<&str>,
    created_at: &str,
    level: Option<i64>,
    result: Option<Value>,
    verdicts: Vec<NewVerdict>,
) -> FinishedMeasurement {
    FinishedMeasurement {
        part: (serial.to_string(), kind.map(str::to_string), None),
        measurement: NewMeasurement {
            id: id.to_string(),
            part_serial: serial.to_string(),
            job_id: None,
            source: "bench",
            bench_id: Some("line-1".into()),
            config: serde_json::from_value(json!({"target_xpeak_m": 0.002})).unwrap(),
            meta: springbench_store::Doc::Received(json!({"sample_rate_hz": 48000, "id": id})),
            analysis_error: result.is_none().then(|| "laser signal lost".to_string()),
            result: result.map(springbench_store::Doc::Received),
            target_xpeak_m: Some(0.002),
            repeat_index: Some(0),
            level_index: level,
            pre: 0,
            main: 1,
        },
        recordings: vec![recording("pre", 1), recording("main", 2)],
        verdicts,
        software_version: STATION_VERSION.into(),
        created_at: created_at.into(),
    }
}

/// Ingests three measurements of two parts (one twice) and checks every
/// read of the interface against what went in.
pub async fn results_suite<S: ResultStore>(s: &S) {
    // Empty.
    assert!(s.get_part("P-1").await.unwrap().is_none());
    assert!(s.list_parts(None, 10).await.unwrap().is_empty());
    assert!(s.get_measurement("m-1").await.unwrap().is_none());
    assert!(s
        .list_measurements(None, None, None, 10)
        .await
        .unwrap()
        .is_empty());

    let m1 = finished(
        "m-1",
        "P-1",
        Some("spider"),
        T1,
        Some(0),
        Some(result(KEFF, 1500.0, true)),
        vec![verdict("m-1", "P-1", "pass")],
    );
    let mut m2 = finished(
        "m-2",
        "P-1",
        None,
        T2,
        Some(1),
        Some(result(1100.0, 1490.0, false)),
        vec![verdict("m-2", "P-1", "fail")],
    );
    let keff_state = json!({"state": "unreliable", "reason": "noise floor 4.2 %"});
    if let Some(springbench_store::Doc::Received(doc)) = m2.measurement.result.as_mut() {
        doc["large_signal"]["validity"] = json!({"keff_n_per_m": keff_state});
    }
    let m3 = finished("m-3", "P-2", Some("cone"), T3, None, None, vec![]);
    assert_eq!(s.upsert_measurement(&m1).await.unwrap(), Upserted::Inserted);
    // A delivery repeated after a lost acknowledgement stores nothing twice.
    assert_eq!(
        s.upsert_measurement(&m1).await.unwrap(),
        Upserted::AlreadyStored
    );
    assert_eq!(s.upsert_measurement(&m2).await.unwrap(), Upserted::Inserted);
    assert_eq!(s.upsert_measurement(&m3).await.unwrap(), Upserted::Inserted);
    assert_eq!(
        s.upsert_measurement(&m2).await.unwrap(),
        Upserted::AlreadyStored
    );

    // Parts: by serial, keyset pages, counts; measurement verdicts are not
    // a job's verdict, so no part has one.
    let parts = s.list_parts(None, 10).await.unwrap();
    let got: Vec<(&str, Option<&str>, i64)> = parts
        .iter()
        .map(|p| (p.serial.as_str(), p.kind.as_deref(), p.measurement_count))
        .collect();
    assert_eq!(got, [("P-1", Some("spider"), 2), ("P-2", Some("cone"), 1)]);
    assert!(parts.iter().all(|p| p.verdict.is_none()));
    let first = s.list_parts(None, 1).await.unwrap();
    assert_eq!(first.len(), 1);
    assert_eq!(first[0].serial, "P-1");
    let rest = s.list_parts(Some("P-1"), 10).await.unwrap();
    assert_eq!(rest.len(), 1);
    assert_eq!(rest[0].serial, "P-2");
    let p1 = s.get_part("P-1").await.unwrap().expect("P-1 stored");
    assert_eq!(
        p1.created_at, T1,
        "the part is as old as its first measurement"
    );
    assert_eq!(p1.measurement_count, 2);

    // One measurement read back whole, as the station made it.
    let (info, doc, meta) = s.get_measurement("m-1").await.unwrap().expect("m-1");
    assert_eq!(info.part_serial, "P-1");
    assert_eq!(info.software_version, STATION_VERSION);
    assert_eq!(info.created_at, T1);
    assert_eq!(info.level_index, Some(0));
    assert_eq!(info.target_xpeak_m, Some(0.002));
    assert_eq!(info.bench_id.as_deref(), Some("line-1"));
    assert_eq!(doc, Some(result(KEFF, 1500.0, true)));
    assert_eq!(meta, json!({"sample_rate_hz": 48000, "id": "m-1"}));
    // Every digit, as in the result document (a REAL printed with 15 digits lost them).
    assert_eq!(info.summary["keff_n_per_m"], json!(KEFF));
    assert_eq!(info.summary["xpeak_m"], json!(0.002));
    assert_eq!(info.summary["resonance_hz"], json!(31.5));
    assert_eq!(info.summary["k0_n_per_m"], json!(1500.0));
    assert_eq!(info.summary["k0_null_reason"], Value::Null);
    assert_eq!(info.summary["keff_validity"], Value::Null);
    // An unreliable k0 is no plain number in a listing, and says why.
    let (info2, _, _) = s.get_measurement("m-2").await.unwrap().expect("m-2");
    assert_eq!(info2.summary["k0_n_per_m"], Value::Null);
    // A headline value's state stands beside it in a listing (issue 22).
    assert_eq!(info2.summary["keff_validity"], keff_state);
    assert_eq!(info2.summary["resonance_validity"], Value::Null);
    assert_eq!(
        info2.summary["k0_null_reason"],
        json!("small_signal.reliable is false (k0 1490.0 +- 12.0 N/m, misfit 0.50 %): not a plain number")
    );
    // A failed analysis: no document, the reason kept.
    let (info3, doc3, _) = s.get_measurement("m-3").await.unwrap().expect("m-3");
    assert_eq!(doc3, None);
    assert_eq!(info3.analysis_error.as_deref(), Some("laser signal lost"));

    // A part's history, newest first, in keyset pages.
    let hist = s
        .list_measurements(Some("P-1"), None, None, 10)
        .await
        .unwrap();
    let ids: Vec<&str> = hist.iter().map(|m| m.id.as_str()).collect();
    assert_eq!(ids, ["m-2", "m-1"]);
    let page = s
        .list_measurements(Some("P-1"), None, Some(hist[0].seq), 10)
        .await
        .unwrap();
    let ids: Vec<&str> = page.iter().map(|m| m.id.as_str()).collect();
    assert_eq!(ids, ["m-1"]);
    let all = s.list_measurements(None, None, None, 2).await.unwrap();
    let ids: Vec<&str> = all.iter().map(|m| m.id.as_str()).collect();
    assert_eq!(ids, ["m-3", "m-2"]);
    let since = s
        .list_measurements_since(None, None, Some(T2), None, 10)
        .await
        .unwrap();
    let ids: Vec<&str> = since.iter().map(|m| m.id.as_str()).collect();
    assert_eq!(ids, ["m-3", "m-2"]);

    // Verdicts: per measurement; a recipe's, oldest first (SPC).
    let v1 = s
        .measurement_verdict("m-1")
        .await
        .unwrap()
        .expect("verdict");
    assert_eq!(
        (
            v1.verdict.as_str(),
            v1.recipe_name.as_str(),
            v1.recipe_version
        ),
        ("pass", "R", 3)
    );
    assert_eq!(v1.recipe_sha256, "ab".repeat(32));
    assert_eq!(v1.created_at, T1);
    assert_eq!(v1.traceability, json!({"bench": "line-1"}));
    assert!(s.measurement_verdict("m-3").await.unwrap().is_none());
    let spc = s
        .recipe_verdicts("R", None, None, None, None)
        .await
        .unwrap();
    let got: Vec<(Option<&str>, &str, Option<i64>)> = spc
        .iter()
        .map(|v| {
            (
                v.measurement_id.as_deref(),
                v.verdict.as_str(),
                v.level_index,
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            (Some("m-1"), "pass", Some(0)),
            (Some("m-2"), "fail", Some(1))
        ]
    );
    let last = s
        .recipe_verdicts("R", None, None, None, Some(1))
        .await
        .unwrap();
    assert_eq!(last.len(), 1);
    assert_eq!(last[0].measurement_id.as_deref(), Some("m-2"));
    let from_t2 = s
        .recipe_verdicts("R", None, Some(T2), None, None)
        .await
        .unwrap();
    assert_eq!(from_t2.len(), 1);
    assert_eq!(from_t2[0].measurement_id.as_deref(), Some("m-2"));
    let before_t2 = s
        .recipe_verdicts("R", None, None, Some(T2), None)
        .await
        .unwrap();
    assert_eq!(before_t2.len(), 1);
    assert_eq!(before_t2[0].measurement_id.as_deref(), Some("m-1"));
    assert!(s
        .recipe_verdicts("other", None, None, None, None)
        .await
        .unwrap()
        .is_empty());
    assert!(s.part_verdict("P-1").await.unwrap().is_none());
    assert!(s.job_verdicts("no-such-job").await.unwrap().is_empty());

    // Nothing ingested: no fits, no headline choice, no recipes.
    assert!(s.list_fits("m-1").await.unwrap().is_empty());
    assert!(s.headline_choice("m-1").await.unwrap().is_none());
    assert!(s.get_recipe("R", None).await.unwrap().is_none());

    // A batch that contradicts itself is refused whole.
    let bad = finished(
        "m-4",
        "P-9",
        None,
        T3,
        None,
        Some(result(1.0, 1.0, true)),
        vec![verdict("m-1", "P-9", "pass")],
    );
    match s.upsert_measurement(&bad).await {
        Err(StoreError::Invalid(e)) => assert!(e.contains("v-m-1") && e.contains("m-4"), "{e}"),
        other => panic!("expected Invalid, got {other:?}"),
    }
    assert!(s.get_measurement("m-4").await.unwrap().is_none());
    assert!(s.get_part("P-9").await.unwrap().is_none());
    assert_eq!(s.list_parts(None, 10).await.unwrap().len(), 2);

    // Pools (decision 0100): a verdict's purpose is its trace's; one
    // without (stored before purposes) is production.
    for (id, purpose) in [
        ("m-5", None),
        ("m-6", Some("gauge_study")),
        ("m-7", Some("production")),
    ] {
        let mut v = verdict(id, "P-5", "pass");
        v.recipe_name = "R-pools".into();
        if let Some(p) = purpose {
            v.trace = json!({"bench": "line-1", "purpose": p});
        }
        let m = finished(
            id,
            "P-5",
            None,
            T3,
            Some(0),
            Some(result(1.0, 1.0, true)),
            vec![v],
        );
        assert_eq!(s.upsert_measurement(&m).await.unwrap(), Upserted::Inserted);
    }
    use springbench_core::job::Purpose;
    for (purpose, want) in [
        (None, vec!["m-5", "m-6", "m-7"]),
        (Some(Purpose::Production), vec!["m-5", "m-7"]),
        (Some(Purpose::GaugeStudy), vec!["m-6"]),
        (Some(Purpose::GoldenUnit), vec![]),
    ] {
        let got: Vec<String> = s
            .recipe_verdicts("R-pools", purpose, None, None, None)
            .await
            .unwrap()
            .into_iter()
            .filter_map(|v| v.measurement_id)
            .collect();
        assert_eq!(got, want, "{purpose:?}");
    }
}

/// Version `v` of recipe R: its description names the version.
pub fn recipe_v(v: i64) -> springbench_core::qc::Recipe {
    serde_json::from_value(json!({"name": "R", "description": format!("version {v}"),
        "procedure": {"levels_m": [0.004]}, "parameters": []}))
    .unwrap()
}

/// A backend that holds versions 1 and 2 of recipe `name` (described
/// "version v") and, on measurement `m`, fit `fit` chosen as its
/// headline by `who`.
pub async fn recipe_and_fit_reads<S: RecipeReads + FitReads>(
    s: &S,
    name: &str,
    m: &str,
    fit: &str,
    who: &str,
) {
    let newest = s.get_recipe(name, None).await.unwrap().expect("recipe");
    assert_eq!((newest.version, newest.recipe.clone()), (2, recipe_v(2)));
    let v1 = s.get_recipe(name, Some(1)).await.unwrap().expect("v1");
    assert_eq!(v1.recipe, recipe_v(1));
    assert!(s.get_recipe(name, Some(3)).await.unwrap().is_none());
    let versions: Vec<i64> = s
        .recipe_versions(name)
        .await
        .unwrap()
        .iter()
        .map(|r| r.version)
        .collect();
    assert_eq!(versions, [1, 2]);
    let list = s.list_recipes().await.unwrap();
    assert_eq!(list.len(), 1);
    assert_eq!((list[0].name.as_str(), list[0].version), (name, 2));
    let fits = s.list_fits(m).await.unwrap();
    assert_eq!(fits.len(), 1);
    assert_eq!(fits[0].id, fit);
    let choice = s.headline_choice(m).await.unwrap().expect("chosen");
    assert_eq!(choice.fit_id.as_deref(), Some(fit));
    assert_eq!(choice.chosen_by.as_deref(), Some(who));
}

/// Writes of recipes (versions 1 and 2 of R) and of a fit chosen as m-1's
/// headline, for [`recipe_and_fit_reads`]: the station's `Store` and the
/// center's `PgStore` have the same inherent methods for them.
macro_rules! seed {
    ($s:expr) => {{
        let s = $s;
        for v in 1..=2 {
            s.write_recipe(
                "R",
                &format!("{v:064}"),
                &recipe_v(v),
                "created",
                Some("qe"),
                RecipeExpect::Any,
            )
            .await
            .unwrap();
        }
        s.insert_fit(
            "f-1",
            "m-1",
            &json!({"effects": []}),
            &result(1200.0, 1500.0, true),
        )
        .await
        .unwrap();
        s.choose_headline("m-1", Some("f-1"), Some("engineer"))
            .await
            .unwrap();
    }};
}

fn correction(
    id: &str,
    kind: &str,
    part: &str,
    m: Option<&str>,
    old: Option<&str>,
    new: Option<&str>,
) -> Correction {
    Correction {
        id: id.into(),
        kind: kind.into(),
        part_serial: part.into(),
        measurement_id: m.map(str::to_string),
        old_value: old.map(str::to_string),
        new_value: new.map(str::to_string),
        reason: format!("reason of {id}"),
        made_by: Some("admin".into()),
        made_at: T3.into(),
    }
}

/// Corrections and voids: nothing deleted, SPC without the void, the audit
/// log in order and by part, bad corrections refused and not recorded.
pub async fn corrections_suite<S: ResultStore + Corrections>(s: &S) {
    for (id, serial, v) in [
        ("m-1", "P-1", "pass"),
        ("m-2", "P-1", "fail"),
        ("m-3", "P-X", "pass"),
    ] {
        let m = finished(
            id,
            serial,
            Some("spider"),
            T1,
            Some(0),
            Some(result(1200.0, 1500.0, true)),
            vec![verdict(id, serial, v)],
        );
        assert_eq!(s.upsert_measurement(&m).await.unwrap(), Upserted::Inserted);
    }
    let spc_ids = || async {
        s.recipe_verdicts("R", None, None, None, None)
            .await
            .unwrap()
            .into_iter()
            .map(|v| v.measurement_id.unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(spc_ids().await, ["m-1", "m-2", "m-3"]);
    // A void: the measurement stays, out of SPC; once.
    let void = correction("c-1", "void_measurement", "P-1", Some("m-2"), None, None);
    assert!(s.correct(&void).await.unwrap());
    assert!(!s.correct(&void).await.unwrap(), "applied once");
    assert!(s.get_measurement("m-2").await.unwrap().is_some());
    assert_eq!(
        s.measurement_void("m-2").await.unwrap().as_deref(),
        Some("c-1")
    );
    assert_eq!(s.measurement_void("m-1").await.unwrap(), None);
    assert_eq!(spc_ids().await, ["m-1", "m-3"]);
    // A serial: P-X was P-2; the old part row stays, empty.
    let fix = correction("c-2", "part_serial", "P-X", None, Some("P-X"), Some("P-2"));
    assert!(s.correct(&fix).await.unwrap());
    assert_eq!(
        s.get_part("P-2").await.unwrap().unwrap().measurement_count,
        1
    );
    assert_eq!(
        s.get_part("P-X")
            .await
            .unwrap()
            .expect("nothing is deleted")
            .measurement_count,
        0
    );
    assert_eq!(
        s.measurement_verdict("m-3")
            .await
            .unwrap()
            .unwrap()
            .part_serial,
        "P-2"
    );
    assert_eq!(
        s.get_measurement("m-3")
            .await
            .unwrap()
            .unwrap()
            .0
            .part_serial,
        "P-2"
    );
    // A kind.
    let kind = correction(
        "c-3",
        "part_kind",
        "P-2",
        None,
        Some("spider"),
        Some("cone"),
    );
    assert!(s.correct(&kind).await.unwrap());
    assert_eq!(
        s.get_part("P-2").await.unwrap().unwrap().kind.as_deref(),
        Some("cone")
    );
    assert_eq!(
        s.get_part("P-1").await.unwrap().unwrap().kind.as_deref(),
        Some("spider")
    );
    // Refused, and not recorded: no reason, an unknown kind, part or
    // measurement, a serial onto itself.
    let mut no_reason = correction("c-4", "part_kind", "P-1", None, None, Some("cone"));
    no_reason.reason = " ".into();
    for bad in [
        no_reason,
        correction("c-5", "rename", "P-1", None, None, Some("x")),
        correction("c-6", "part_kind", "P-none", None, None, Some("cone")),
        correction("c-7", "void_measurement", "P-1", Some("m-none"), None, None),
        correction("c-8", "part_serial", "P-1", None, None, Some("P-1")),
    ] {
        let r = s.correct(&bad).await;
        assert!(
            matches!(r, Err(StoreError::Invalid(_))),
            "{}: {r:?}",
            bad.id
        );
    }
    // The audit log: oldest first, by part (old or new serial), in pages.
    let log = s.audit_log(None, None, 10).await.unwrap();
    type Row<'a> = (&'a str, &'a str, Option<&'a str>, Option<&'a str>, &'a str);
    let got: Vec<Row> = log
        .iter()
        .map(|e| {
            let c = &e.correction;
            (
                c.id.as_str(),
                c.part_serial.as_str(),
                c.old_value.as_deref(),
                c.new_value.as_deref(),
                c.reason.as_str(),
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            ("c-1", "P-1", None, None, "reason of c-1"),
            ("c-2", "P-X", Some("P-X"), Some("P-2"), "reason of c-2"),
            ("c-3", "P-2", Some("spider"), Some("cone"), "reason of c-3"),
        ]
    );
    assert!(log
        .iter()
        .all(|e| e.station_id.is_none() && e.correction.made_by.as_deref() == Some("admin")));
    let ids = |v: Vec<springbench_store::corrections::AuditEntry>| {
        v.into_iter().map(|e| e.correction.id).collect::<Vec<_>>()
    };
    assert_eq!(
        ids(s.audit_log(Some("P-2"), None, 10).await.unwrap()),
        ["c-2", "c-3"]
    );
    assert_eq!(
        ids(s.audit_log(Some("P-1"), None, 10).await.unwrap()),
        ["c-1"]
    );
    assert_eq!(
        ids(s.audit_log(None, Some(log[0].seq), 1).await.unwrap()),
        ["c-2"]
    );
}

#[tokio::test]
async fn sqlite_and_corrections() {
    corrections_suite(&Store::memory().await.unwrap()).await;
}

#[tokio::test]
async fn postgres_and_corrections() {
    use springbench_store_pg::test_server::{fresh_schema, url_or_skip};
    let Some(url) = url_or_skip("postgres_and_corrections") else {
        return;
    };
    let s = springbench_store_pg::PgStore::connect_schema(&url, Some(&fresh_schema("corrections")))
        .await
        .unwrap();
    corrections_suite(&s).await;
    s.close().await;
}

#[tokio::test]
async fn sqlite_in_memory_passes_the_results_suite() {
    let s = Store::memory().await.unwrap();
    results_suite(&s).await;
    seed!(&s);
    recipe_and_fit_reads(&s, "R", "m-1", "f-1", "engineer").await;
}

#[tokio::test]
async fn sqlite_station_file_passes_the_results_suite() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).await.unwrap();
    results_suite(&s).await;
    seed!(&s);
    recipe_and_fit_reads(&s, "R", "m-1", "f-1", "engineer").await;
    s.close().await;
}

#[tokio::test]
async fn postgres_passes_the_results_suite() {
    use springbench_store_pg::test_server::{fresh_schema, url_or_skip};
    let Some(url) = url_or_skip("postgres_passes_the_results_suite") else {
        return;
    };
    let s = springbench_store_pg::PgStore::connect_schema(&url, Some(&fresh_schema("results")))
        .await
        .unwrap();
    results_suite(&s).await;
    seed!(&s);
    recipe_and_fit_reads(&s, "R", "m-1", "f-1", "engineer").await;
    s.close().await;
}

/// A correction on a station's database file while another connection
/// keeps writing (the fleet worker marking its outbox, jobs ending): it
/// waits for the write lock. A deferred transaction that reads and then
/// writes cannot wait: it failed at once with "database is locked" (seen
/// as a 500 of `POST /api/v1/corrections` right after two jobs ended).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_correction_waits_for_another_writer() {
    use std::sync::atomic::{AtomicBool, Ordering};
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).await.unwrap();
    s.upsert_part("P", Some("spider"), None).await.unwrap();
    let on = std::sync::Arc::new(AtomicBool::new(true));
    let writer = tokio::spawn({
        let (s, on) = (s.clone(), on.clone());
        async move {
            let mut n = 0u32;
            while on.load(Ordering::SeqCst) {
                s.append_event("test.write", None, &json!({"n": n}))
                    .await
                    .unwrap();
                n += 1;
            }
            n
        }
    });
    for i in 0..100 {
        let c = Correction {
            id: format!("c-{i}"),
            kind: "part_kind".into(),
            part_serial: "P".into(),
            measurement_id: None,
            old_value: None,
            new_value: Some(format!("kind-{i}")),
            reason: "relabelled".into(),
            made_by: None,
            made_at: springbench_store::now(),
        };
        let r = s.correct(&c).await;
        assert!(matches!(r, Ok(true)), "correction {i}: {r:?}");
    }
    on.store(false, Ordering::SeqCst);
    let writes = writer.await.unwrap();
    assert!(writes > 0, "the other connection wrote meanwhile");
    assert_eq!(s.audit_log(Some("P"), None, 1000).await.unwrap().len(), 100);
    s.close().await;
}
