//! Operations: health, readiness (bench states), Prometheus metrics, configuration.

use super::problem::{ApiResult, Problem};
use super::AppState;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::{json, Value};
use std::fmt::Write;

#[utoipa::path(get, path = "/healthz", tag = "operations",
    summary = "Liveness (always 200 while the process serves; the fleet role: 503 while its database does not answer).",
    responses(
        (status = 200, description = "Serving", body = super::schema::Health),
        (status = 503, description = "The fleet role only: its database does not answer")))]
pub async fn healthz() -> Json<Value> {
    Json(json!({"status": "ok", "version": crate::VERSION}))
}

/// Ready when the database answers and no bench has stopped.
#[utoipa::path(get, path = "/readyz", tag = "operations",
    summary = "Readiness: the database takes a committed write, the disk has room, no bench stopped, not shutting down.",
    responses(
        (status = 200, description = "Ready", body = super::schema::Ready),
        (status = 503, description = "Not ready (database lost or full disk, shutting down, a bench stopped)", body = super::schema::Ready)))]
pub async fn readyz(State(st): State<AppState>) -> Response {
    // A committed write: a full disk or a lost database file is not ready.
    let db = match st.store.ping().await {
        Ok(()) => match st.store.check_space(st.cfg.min_free_bytes) {
            Ok(()) => st.store.probe_write().await,
            Err(e) => Err(e),
        },
        Err(e) => Err(e),
    };
    let benches = st.runner.bench_statuses();
    let shutting_down = *st.shutdown.borrow();
    let ready = db.is_ok() && !shutting_down && benches.iter().all(|b| b.state != "stopped");
    let body = json!({
        "status": if ready { "ready" } else { "not_ready" },
        "database": match &db { Ok(()) => "ok".to_string(), Err(e) => e.to_string() },
        "benches": benches,
    });
    let code = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, Json(body)).into_response()
}

#[utoipa::path(get, path = "/api/v1/benches", tag = "operations",
    summary = "The benches and what they are doing.",
    responses((status = 200, description = "Benches", body = super::schema::BenchList)))]
pub async fn benches(State(st): State<AppState>) -> Json<Value> {
    Json(json!({"items": st.runner.bench_statuses()}))
}

#[utoipa::path(get, path = "/metrics", tag = "operations",
    summary = "Prometheus text exposition: jobs by state, MES outbox, parts, measurements, data directory and recording bytes, bench busy, request counts and latency histograms.",
    responses((status = 200, description = "Metrics", content_type = "text/plain", body = String)))]
pub async fn metrics(State(st): State<AppState>) -> ApiResult<Response> {
    let mut out = String::new();
    out.push_str("# HELP springbench_jobs Jobs by state.\n# TYPE springbench_jobs gauge\n");
    let counts = st.store.job_counts().await?;
    for s in crate::store::JobState::ALL {
        let n = counts
            .iter()
            .find(|(k, _)| k == s.as_str())
            .map(|(_, n)| *n)
            .unwrap_or(0);
        let _ = writeln!(out, "springbench_jobs{{state=\"{}\"}} {n}", s.as_str());
    }
    let (pending, failed, failures) = st.store.outbox_counts().await?;
    let _ = writeln!(
        out,
        "# HELP springbench_mes_outbox_depth MES deliveries not yet delivered, by state.\n# TYPE springbench_mes_outbox_depth gauge\n\
         springbench_mes_outbox_depth{{state=\"pending\"}} {pending}\nspringbench_mes_outbox_depth{{state=\"failed\"}} {failed}\n\
         # HELP springbench_mes_delivery_failures_total Failed MES delivery attempts.\n# TYPE springbench_mes_delivery_failures_total counter\n\
         springbench_mes_delivery_failures_total {failures}"
    );
    let (parts, meas) = st.store.counts().await?;
    let _ = writeln!(
        out,
        "# HELP springbench_parts Parts known.\n# TYPE springbench_parts gauge\nspringbench_parts {parts}"
    );
    let _ = writeln!(
        out,
        "# HELP springbench_measurements Measurements stored.\n# TYPE springbench_measurements gauge\nspringbench_measurements {meas}"
    );
    let (raw_bytes, kept, pruned) = st.store.raw_usage().await?;
    let dir = st.cfg.data_dir.clone();
    let dir_bytes = tokio::task::spawn_blocking(move || crate::store::dir_bytes(&dir))
        .await
        .unwrap_or(0);
    let _ = writeln!(
        out,
        "# HELP springbench_data_dir_bytes Bytes of the files in the data directory (database and WAL).\n\
         # TYPE springbench_data_dir_bytes gauge\nspringbench_data_dir_bytes {dir_bytes}\n\
         # HELP springbench_recordings_bytes Bytes of stored raw signals (FLAC or WAV blobs).\n\
         # TYPE springbench_recordings_bytes gauge\nspringbench_recordings_bytes {raw_bytes}\n\
         # HELP springbench_recordings Recordings by whether the retention policy removed their raw signals.\n\
         # TYPE springbench_recordings gauge\n\
         springbench_recordings{{state=\"kept\"}} {kept}\nspringbench_recordings{{state=\"pruned\"}} {pruned}"
    );
    out.push_str("# HELP springbench_bench_busy 1 while the bench runs a job.\n# TYPE springbench_bench_busy gauge\n");
    for b in st.runner.bench_statuses() {
        let _ = writeln!(
            out,
            "springbench_bench_busy{{bench=\"{}\"}} {}",
            b.id,
            u8::from(b.state == "running")
        );
    }
    out.push_str(
        "# HELP springbench_parts_measured_total Parts measured (procedure runs), by bench and procedure.\n\
         # TYPE springbench_parts_measured_total counter\n",
    );
    let tp = st.runner.throughput();
    for (b, mode, t) in &tp {
        let _ = writeln!(
            out,
            "springbench_parts_measured_total{{bench=\"{b}\",procedure=\"{mode}\"}} {}",
            t.parts
        );
    }
    for (name, help, get) in [
        (
            "springbench_production_fallbacks_total",
            "Production runs that fell back to the full procedure.",
            (|t: &crate::runner::Throughput| t.fallbacks as f64)
                as fn(&crate::runner::Throughput) -> f64,
        ),
        (
            "springbench_bench_time_seconds_total",
            "Stimulus time played and captured (s).",
            |t| t.bench_time_s,
        ),
        (
            "springbench_analysis_seconds_total",
            "Fit and judging time of the measured parts (s).",
            |t| t.analysis_s,
        ),
        (
            "springbench_job_wall_seconds_total",
            "Wall time of the finished jobs, start to end (s).",
            |t| t.wall_s,
        ),
    ] {
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} counter");
        for (b, mode, t) in &tp {
            let _ = writeln!(
                out,
                "{name}{{bench=\"{b}\",procedure=\"{mode}\"}} {}",
                get(t)
            );
        }
    }
    out.push_str(
        "# HELP springbench_parts_per_hour Parts per hour of a busy bench: 3600 x parts / job wall time.\n\
         # TYPE springbench_parts_per_hour gauge\n",
    );
    for (b, mode, t) in &tp {
        if t.wall_s > 0.0 {
            let _ = writeln!(
                out,
                "springbench_parts_per_hour{{bench=\"{b}\",procedure=\"{mode}\"}} {:.1}",
                3600.0 * t.parts as f64 / t.wall_s
            );
        }
    }
    if let Some(link) = &st.fleet {
        crate::fleet::render_metrics(&st.store, link, &mut out).await?;
    }
    st.metrics.render(&mut out);
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], out).into_response())
}

#[utoipa::path(get, path = "/api/v1/config", tag = "operations",
    summary = "The configuration in effect (token and webhook secrets, and credentials in webhook URLs, redacted).",
    responses((status = 200, description = "The configuration (the TOML file's structure as JSON)", body = Object)))]
/// The configuration in effect, token and webhook secrets left out (admin only).
pub async fn config(State(st): State<AppState>) -> ApiResult<Json<Value>> {
    let mut v = serde_json::to_value(&*st.cfg).map_err(Problem::internal)?;
    for (list, secret) in [("/auth/tokens", "token"), ("/mes/webhooks", "secret")] {
        if let Some(items) = v.pointer_mut(list).and_then(|t| t.as_array_mut()) {
            for t in items {
                t[secret] = json!("<redacted>");
            }
        }
    }
    if let Some(hooks) = v
        .pointer_mut("/mes/webhooks")
        .and_then(|t| t.as_array_mut())
    {
        for h in hooks {
            if let Some(u) = h["url"].as_str() {
                h["url"] = json!(redact_url(u));
            }
        }
    }
    // A station's center URL: its password (the fleet role never serves this route's state).
    if let Some(c) = v.pointer_mut("/fleet/center") {
        if let Some(u) = c.as_str() {
            *c = json!(crate::config::redact_url_password(u));
        }
    }
    Ok(Json(v))
}

/// A receiver's URL without its secrets: the password of the user info and
/// the query (tokens often ride there) become `redacted`; scheme, host, port
/// and path stay, so the operator still sees which receiver it is.
fn redact_url(s: &str) -> String {
    let Ok(mut u) = url::Url::parse(s) else {
        return "<redacted>".to_string();
    };
    if u.password().is_some() {
        let _ = u.set_password(Some("redacted"));
    }
    if u.query().is_some() {
        u.set_query(Some("redacted"));
    }
    if u.fragment().is_some() {
        u.set_fragment(Some("redacted"));
    }
    u.to_string()
}
