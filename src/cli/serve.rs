//! `springbench serve [--config FILE] [--bind ADDR] [--data-dir DIR]`: the
//! bench daemon (also what `springbench` without a command starts).
//!
//! Prints `listening on http://ADDR` on stdout once the socket is bound (with
//! port 0 the line tells the port). SIGTERM or ctrl-c: the running job is
//! aborted (the bench ramps its drive down), its state is written as
//! `interrupted`, open requests finish, the database is checkpointed.

use crate::api::{self, AppState};
use crate::config::Config;
use crate::runner::{EventBus, Runner};
use crate::store::Store;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(clap::Args, Debug, Default, Clone)]
pub struct ServeArgs {
    /// Configuration file (TOML, see deploy/springbench.toml); defaults apply without it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Listen address (overrides the configuration's `bind`).
    #[arg(long)]
    pub bind: Option<String>,
    /// Data directory (overrides the configuration's `data_dir`).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
}

/// Loads the configuration with the command-line overrides applied.
pub fn load_config(args: &ServeArgs) -> Result<Config, String> {
    let mut cfg = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    if let Some(b) = &args.bind {
        cfg.bind = b.clone();
    }
    if let Some(d) = &args.data_dir {
        cfg.data_dir = d.clone();
    }
    let names = crate::physics::preset_names();
    if !names.is_empty() {
        for b in &cfg.benches {
            if crate::physics::preset(&b.preset).is_err() {
                return Err(format!(
                    "bench '{}': unknown preset '{}' (presets: {})",
                    b.id,
                    b.preset,
                    names.join(", ")
                ));
            }
        }
    }
    cfg.validate()?;
    Ok(cfg)
}

/// The address to bind: without tokens only loopback (a non-loopback
/// address is replaced by 127.0.0.1 with the same port, and said so).
pub fn bind_address(cfg: &Config) -> Result<(SocketAddr, Option<String>), String> {
    let addr: SocketAddr = cfg
        .bind
        .parse()
        .map_err(|e| format!("bind address '{}': {e}", cfg.bind))?;
    if cfg.open_access() && !addr.ip().is_loopback() {
        let lo = SocketAddr::from(([127, 0, 0, 1], addr.port()));
        return Ok((
            lo,
            Some(format!(
                "no auth tokens configured: refusing to listen on {addr}; listening on loopback {lo} only"
            )),
        ));
    }
    let note = cfg
        .open_access()
        .then(|| "no auth tokens configured: open access, loopback only".to_string());
    Ok((addr, note))
}

pub fn run(args: ServeArgs) -> Result<(), String> {
    let cfg = load_config(&args)?;
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .try_init();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the runtime: {e}"))?;
    rt.block_on(serve(cfg, shutdown_signal()))
}

/// Resolves on SIGTERM or ctrl-c.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}

/// Runs the daemon until `stop` resolves.
pub async fn serve(cfg: Config, stop: impl std::future::Future<Output = ()>) -> Result<(), String> {
    let (addr, note) = bind_address(&cfg)?;
    if cfg.is_fleet_role() {
        return api::fleet::serve_role(cfg, addr, note, stop).await;
    }
    if crate::physics::preset_names().is_empty() {
        tracing::warn!("no part presets are available in this build: jobs must give moving_mass_kg and the virtual bench cannot run yet");
    }
    let store = Store::open(&cfg.data_dir)
        .await
        .map_err(|e| format!("database in {}: {e}", cfg.data_dir.display()))?;
    let events = EventBus::new(store.clone())
        .await
        .map_err(|e| format!("database: {e}"))?;
    let (runner, tasks) = Runner::start(store.clone(), events, &cfg)
        .await
        .map_err(|e| format!("database: {e}"))?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let local = listener
        .local_addr()
        .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mes_worker = crate::mes::start(
        store.clone(),
        cfg.mes.clone(),
        cfg.benches
            .iter()
            .map(|b| cfg.mes.handle_of(&b.id))
            .collect(),
        runner.outbox_wake(),
        stop_rx.clone(),
    );
    let fleet = cfg
        .fleet
        .clone()
        .map(|f| crate::fleet::start_station(store.clone(), f, runner.clone(), stop_rx.clone()));
    let state = AppState {
        store: store.clone(),
        runner: runner.clone(),
        cfg: Arc::new(cfg),
        metrics: Default::default(),
        shutdown: stop_rx.clone(),
        fleet: fleet.as_ref().map(|(l, _)| l.clone()),
    };
    let http = state.cfg.http.clone();
    let (max_conn, fd_note) = api::server::fit_connection_limit(http.max_connections);
    let retention = tokio::spawn(retention_loop(
        store.clone(),
        state.cfg.retention.clone(),
        stop_rx.clone(),
    ));
    let app = api::app(state);
    let server_stop = stop_rx.clone();
    let server = tokio::spawn(async move {
        api::server::serve(listener, app, &http, max_conn, server_stop).await
    });
    if let Some(n) = note {
        eprintln!("springbench: {n}");
    }
    if let Some(n) = fd_note {
        eprintln!("springbench: {n}");
    }
    println!("listening on http://{local}");
    let _ = std::io::stdout().flush();
    tracing::info!(version = crate::VERSION, "daemon started");

    stop.await;
    tracing::info!("shutting down: aborting the running job, finishing writes");
    runner.shutdown();
    let _ = stop_tx.send(true);
    for t in tasks {
        if tokio::time::timeout(Duration::from_secs(25), t)
            .await
            .is_err()
        {
            tracing::error!("a bench did not stop within 25 s; its job will be marked interrupted at the next start");
        }
    }
    let _ = tokio::time::timeout(Duration::from_secs(5), mes_worker).await;
    if let Some((_, w)) = fleet {
        let _ = tokio::time::timeout(Duration::from_secs(5), w).await;
    }
    match tokio::time::timeout(Duration::from_secs(5), server).await {
        Ok(Ok(Ok(()))) => {}
        Ok(Ok(Err(e))) => tracing::error!("server: {e}"),
        _ => tracing::warn!("open connections did not close within 5 s"),
    }
    retention.abort();
    store.close().await;
    tracing::info!("stopped");
    Ok(())
}

/// Applies the retention policy at start and every `interval_s` (decision 0013).
async fn retention_loop(
    store: Store,
    policy: crate::config::Retention,
    mut stop: tokio::sync::watch::Receiver<bool>,
) {
    if policy.raw_max_age_days.is_none() && policy.raw_keep_last_per_part.is_none() {
        return;
    }
    loop {
        match store.prune_raw(&policy).await {
            Ok(r) if r.recordings_pruned > 0 => tracing::info!(
                recordings = r.recordings_pruned,
                bytes = r.bytes_freed,
                "retention: raw signals removed (results kept)"
            ),
            Ok(_) => {}
            Err(e) => tracing::warn!("retention pass failed: {e}"),
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_secs_f64(policy.interval_s)) => {}
            _ = stop.wait_for(|v| *v) => return,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_tokens_only_loopback_is_bound() {
        let mut cfg = Config {
            bind: "0.0.0.0:8750".into(),
            ..Config::default()
        };
        let (a, note) = bind_address(&cfg).unwrap();
        assert_eq!(a.to_string(), "127.0.0.1:8750");
        assert!(note.unwrap().contains("refusing"));
        cfg.auth.tokens.push(crate::config::Token {
            name: "t".into(),
            token: "0123456789abcdef".into(),
            role: crate::config::Role::Viewer,
        });
        let (a, note) = bind_address(&cfg).unwrap();
        assert_eq!(a.to_string(), "0.0.0.0:8750");
        assert!(note.is_none());
        cfg.bind = "localhost:x".into();
        assert!(bind_address(&cfg).unwrap_err().contains("bind address"));
    }

    #[test]
    fn the_default_configuration_mounts_an_existing_preset() {
        let cfg = load_config(&ServeArgs::default()).unwrap();
        assert!(crate::physics::preset(&cfg.benches[0].preset).is_ok());
        let bad = ServeArgs {
            bind: Some("127.0.0.1:0".into()),
            ..ServeArgs::default()
        };
        assert_eq!(load_config(&bad).unwrap().bind, "127.0.0.1:0");
    }
}
