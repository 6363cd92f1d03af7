//! The HTTP server's accept loop with resource bounds (hyper-util, hyper's
//! HTTP/1 connection builder): at most `http.max_connections` open
//! connections (further ones wait in the kernel's backlog), request headers
//! within `http.header_read_timeout_s` (hyper closes the connection
//! otherwise, also an idle keep-alive one), request bodies without a pause
//! longer than `http.body_read_timeout_s` (tower-http's `RequestBodyTimeout`,
//! applied in [`super::app`]). axum::serve has no header timeout and no
//! connection limit, hence this loop; see docs/decisions/0012-http-hardening.md.

use crate::config::HttpConfig;
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};

/// Descriptors kept free for the database, recordings and the runtime.
const RESERVED_FDS: u64 = 256;

/// Raises the soft descriptor limit to what `max_connections` needs (at most
/// the hard limit). Returns the connection limit that fits the descriptors
/// available, and a note when it had to be lowered.
pub fn fit_connection_limit(wanted: usize) -> (usize, Option<String>) {
    let need = wanted as u64 + RESERVED_FDS;
    let have = match rlimit::increase_nofile_limit(need) {
        Ok(n) => n,
        Err(e) => {
            return (
                wanted,
                Some(format!("cannot read the descriptor limit ({e})")),
            )
        }
    };
    if have >= need {
        return (wanted, None);
    }
    let fit = have.saturating_sub(RESERVED_FDS).max(16) as usize;
    (
        fit,
        Some(format!(
            "descriptor limit {have}: serving at most {fit} connections instead of {wanted} (raise LimitNOFILE)"
        )),
    )
}

/// Serves `app` on `listener` until `stop` turns true, then lets open
/// requests finish (the caller bounds how long it waits).
pub async fn serve(
    listener: TcpListener,
    app: Router,
    http: &HttpConfig,
    max_connections: usize,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(max_connections));
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(Duration::from_secs_f64(http.header_read_timeout_s))
        .keep_alive(true);
    loop {
        let permit = tokio::select! {
            p = slots.clone().acquire_owned() => match p {
                Ok(p) => p,
                Err(_) => break,
            },
            _ = stopped(&mut stop) => break,
        };
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((s, _)) => s,
                Err(e) => {
                    // EMFILE and friends: wait a moment instead of spinning.
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = stopped(&mut stop) => break,
        };
        let _ = stream.set_nodelay(true);
        let svc = TowerToHyperService::new(app.clone());
        let conn = builder
            // hyper's own refusals (414, 431, 400) as problem documents
            .serve_connection(TokioIo::new(super::problem_io::ProblemIo::new(stream)), svc)
            .with_upgrades();
        let mut conn_stop = stop.clone();
        tokio::spawn(async move {
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => {}
                _ = stopped(&mut conn_stop) => {
                    // finish the request in flight, then close
                    conn.as_mut().graceful_shutdown();
                    let _ = conn.await;
                }
            }
            drop(permit);
        });
    }
    drop(listener);
    // Every connection returns its permit when it has closed.
    let _ = slots.acquire_many(max_connections as u32).await;
    Ok(())
}

async fn stopped(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|v| *v).await;
}
