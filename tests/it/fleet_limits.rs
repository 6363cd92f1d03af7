//! The center's bounds on one reader (issue 36, M4): a client running
//! `spc_per_client` SPC queries already is answered 429 with `Retry-After`
//! at once, while another client's query is not refused (the 200-way
//! burst from one client gave 124 × 503 after a 16 s median wait).
//!
//! Made deterministic without timing: the test holds an `ACCESS EXCLUSIVE`
//! lock on the tables the SPC reads, so each admitted query waits on it
//! (visible in `pg_stat_activity`) and keeps its slot for as long as the
//! test wants. Without the limit the third query of the client waits on
//! the lock like the first two, and the test says so.
//!
//! Without PostgreSQL binaries the test prints why it skips;
//! `SPRINGBENCH_PG_TESTS=require` (set by `.ci/run`) makes that a failure.

use crate::common::{client, problem, Daemon};
use serde_json::{json, Value};
use springbench_store_pg::test_server::{can_start_private, TestServer};
use std::time::{Duration, Instant};

const RECIPE: &str = "spider-limits";
const QE_1: &str = "qe-one-secret-5b1f0c77e2";
const QE_2: &str = "qe-two-secret-91d4a3c6f8";

fn recipe() -> Value {
    json!({
        "name": RECIPE,
        "part_kind": "spider",
        "procedure": {"levels_m": [0.004], "method": "two-signal", "order": 4, "moving_mass_kg": 0.05},
        "parameters": [
            {"name": "keff", "quantity": "keff", "lower": 900.0, "upper": 1100.0}
        ]
    })
}

/// SPC queries of the center waiting on a lock (the test's).
async fn waiting(pool: &sqlx::PgPool) -> i64 {
    sqlx::query_scalar(
        "SELECT count(*) FROM pg_stat_activity WHERE wait_event_type = 'Lock' AND pid <> pg_backend_pid()",
    )
    .fetch_one(pool)
    .await
    .unwrap()
}

/// One SPC query of the fleet with `token`: (status, Retry-After, body).
fn spc(
    c: &reqwest::Client,
    fleet: &Daemon,
    token: &str,
) -> tokio::task::JoinHandle<(u16, Option<String>, reqwest::Response)> {
    let req = c
        .get(fleet.url(&format!(
            "/api/v1/fleet/recipes/{RECIPE}/spc?parameter=keff&last=1000"
        )))
        .bearer_auth(token);
    tokio::spawn(async move {
        let r = req.send().await.unwrap();
        let retry = r
            .headers()
            .get("retry-after")
            .map(|v| v.to_str().unwrap().to_string());
        (r.status().as_u16(), retry, r)
    })
}

/// Waits until `n` queries wait on the lock; panics naming what answered
/// instead (each of `pending` must still be waiting).
async fn until_waiting(
    pool: &sqlx::PgPool,
    n: i64,
    pending: &[&tokio::task::JoinHandle<(u16, Option<String>, reqwest::Response)>],
    what: &str,
) {
    let t0 = Instant::now();
    while waiting(pool).await < n {
        assert!(
            pending.iter().all(|h| !h.is_finished()),
            "{what}: a query answered instead of waiting on the lock"
        );
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{what}: {} of {n} queries wait on the lock after 60 s",
            waiting(pool).await
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_over_its_spc_limit_gets_429_with_retry_after_and_another_client_does_not() {
    if !can_start_private("center SPC limit test") {
        return;
    }
    let pg = TestServer::start(55473).expect("a private PostgreSQL server");
    let url = pg.url();
    crate::fleet::center_holds(&url, &recipe()).await;
    let fleet = Daemon::start(&format!(
        "database = \"{url}\"\nbenches = []\nspc_per_client = 2\n\
         [[auth.tokens]]\nname = \"qe-1\"\ntoken = \"{QE_1}\"\nrole = \"viewer\"\n\
         [[auth.tokens]]\nname = \"qe-2\"\ntoken = \"{QE_2}\"\nrole = \"viewer\"\n"
    ));
    let c = client();
    // Unlocked, a query answers (the recipe has no verdicts yet: n 0).
    let (s, _, _) = spc(&c, &fleet, QE_1).await.unwrap();
    assert_eq!(s, 200);

    let pool = sqlx::PgPool::connect(&url).await.unwrap();
    let mut lock = pool.begin().await.unwrap();
    sqlx::query("LOCK TABLE qc_verdicts, spc_points IN ACCESS EXCLUSIVE MODE")
        .execute(&mut *lock)
        .await
        .unwrap();

    // qe-1's two queries are admitted and wait on the lock.
    let a = spc(&c, &fleet, QE_1);
    let b = spc(&c, &fleet, QE_1);
    until_waiting(&pool, 2, &[&a, &b], "qe-1's first two").await;

    // Its third is refused at once: 429, Retry-After, a problem naming the
    // limit (without the limit it waits on the lock as the third query).
    let third = spc(&c, &fleet, QE_1);
    let t0 = Instant::now();
    while !third.is_finished() {
        assert!(
            waiting(&pool).await < 3,
            "qe-1's third SPC query was admitted (waits on the lock) instead of a 429"
        );
        assert!(t0.elapsed() < Duration::from_secs(60), "no answer in 60 s");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (s, retry, resp) = third.await.unwrap();
    assert_eq!((s, retry.as_deref()), (429, Some("1")));
    let p = problem(resp, 429).await;
    assert_eq!(p["type"], "/problems/too-many-spc-queries", "{p}");
    assert!(
        p["detail"].as_str().unwrap().contains("spc_per_client"),
        "{p}"
    );

    // Another client is not refused: its query is admitted and waits too.
    let other = spc(&c, &fleet, QE_2);
    until_waiting(&pool, 3, &[&a, &b, &other], "qe-2's query").await;

    // The lock released: every admitted query answers, and qe-1's slots are
    // given back (a next query of qe-1 is admitted again).
    lock.rollback().await.unwrap();
    for (who, h) in [("qe-1 a", a), ("qe-1 b", b), ("qe-2", other)] {
        let (s, _, resp) = h.await.unwrap();
        let body: Value = resp.json().await.unwrap();
        assert_eq!(s, 200, "{who}: {body}");
        assert_eq!(body["recipe"], RECIPE, "{who}: {body}");
    }
    let (s, _, _) = spc(&c, &fleet, QE_1).await.unwrap();
    assert_eq!(s, 200, "qe-1's slots were not given back");
    pool.close().await;
}
