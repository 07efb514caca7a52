//! The daemon (`stagehand serve`): the only owner of the rig's devices. It runs capture
//! scripts one at a time and serves the HTTP API under `/api/`, its OpenAPI document at
//! `/openapi.json` with a vendored Swagger UI at `/docs/`, live events over SSE, Prometheus
//! metrics and the dashboard at `/`.
//!
//! The daemon runs in real time on a multi-threaded runtime, also on the simulated rig (the
//! CLI's `run` uses the virtual clock instead): a simulated rig then behaves like the hardware,
//! and the dashboard shows a run at the pace the real rig would go.

pub mod api;
pub mod auth;
pub mod device_state;
pub mod error;
pub mod estop;
pub mod events;
pub mod frame_index;
pub mod image_convert;
pub mod jog_ws;
pub mod manual;
pub mod operator;
pub mod queue;
pub mod run_start;
pub mod runs;
pub mod scripts;
pub mod state;
pub mod stored_runs;
mod web;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::http::{HeaderValue, StatusCode, Uri, header};
use axum::response::IntoResponse;
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};
use stagehand_devices::clock::RigClock;
use tokio::sync::oneshot;
use tower_http::set_header::SetResponseHeaderLayer;
use utoipa_swagger_ui::SwaggerUi;

use self::auth::Tokens;
use self::error::ApiError;
use self::state::{AppState, Daemon};
use crate::rig::Emulation;
use crate::rig::{Rig, RigSource};

/// How long shutdown waits for open requests and the run to wind down.
const SHUTDOWN_GRACE_S: u64 = 5;

/// Largest request body the API accepts (scripts are text; nothing else is big).
pub const MAX_BODY_BYTES: usize = 1 << 20;

/// `stagehand serve` options.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// `None`, `lightstage`, `reflectometer` or a rig TOML file (as for `run`).
    pub rig: Option<String>,
    pub listen: SocketAddr,
    pub data: PathBuf,
    /// Built-in scripts offered on the dashboard.
    pub scripts: Option<PathBuf>,
    pub seed: u64,
    pub emulation: Option<Emulation>,
}

/// Why the daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("{0}")]
    Rig(#[from] stagehand_devices::rig::RigError),
    #[error("{0}")]
    Open(#[from] crate::rig::OpenError),
    #[error("data directory {path}: {reason}")]
    Data { path: String, reason: String },
    #[error(transparent)]
    Tokens(#[from] crate::daemon::auth::TokensError),
    #[error(
        "cannot listen on {addr}: {reason}; is another daemon running? pick another with --listen"
    )]
    Listen { addr: SocketAddr, reason: String },
    #[error("{0}")]
    Io(String),
}

/// A daemon serving in the background of the current runtime.
pub struct RunningDaemon {
    /// The address it listens on (useful with port 0).
    pub addr: SocketAddr,
    pub state: AppState,
    /// Where the tokens are, and whether they were created just now.
    pub tokens_path: PathBuf,
    pub tokens_created: bool,
    shutdown: Option<oneshot::Sender<()>>,
    server: tokio::task::JoinHandle<()>,
}

impl RunningDaemon {
    /// Stops serving: aborts any run, puts the rig in its safe state, closes the listener.
    /// The rig is made safe first, before any client is waited for.
    /// The run's final `run` event reaches the SSE clients before their streams end.
    pub async fn shutdown(mut self) {
        self.state.runs.abort();
        self.state.estop.latch();
        if let Err(e) = self.state.rig.safe_state().await {
            tracing::error!("shutdown: safe state: {e}");
        }
        let grace = std::time::Duration::from_secs(SHUTDOWN_GRACE_S);
        // The aborted run publishes its final event once it has wound down.
        if tokio::time::timeout(grace, self.state.runs.wait_idle())
            .await
            .is_err()
        {
            tracing::warn!("shutdown: the run did not wind down within {SHUTDOWN_GRACE_S} s");
        }
        self.state.hub.close();
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if tokio::time::timeout(grace, &mut self.server).await.is_err() {
            tracing::warn!("shutdown: clients still connected after {SHUTDOWN_GRACE_S} s; closing");
            self.server.abort();
        }
        // The run's own abort path ends in the safe state too; make sure of it.
        if let Err(e) = self.state.rig.safe_state().await {
            tracing::error!("shutdown: safe state: {e}");
        }
    }
}

/// The process's metrics recorder (installed once; every daemon in the process shares it).
/// Public so a test can install it before running the executor in-process.
pub fn metrics_handle() -> PrometheusHandle {
    static HANDLE: OnceLock<PrometheusHandle> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let recorder = PrometheusBuilder::new().build_recorder();
            let handle = recorder.handle();
            if metrics::set_global_recorder(recorder).is_err() {
                tracing::warn!("a metrics recorder was already installed; /api/metrics is empty");
            }
            crate::executor::describe_metrics();
            handle
        })
        .clone()
}

/// Opens the rig and the data directory, binds and serves in the background. Must run inside
/// a multi-threaded tokio runtime.
pub async fn start(opts: ServeOptions) -> Result<RunningDaemon, DaemonError> {
    let data_err = |reason: String| DaemonError::Data {
        path: opts.data.display().to_string(),
        reason,
    };
    for dir in [
        opts.data.clone(),
        opts.data.join("runs"),
        opts.data.join("scripts"),
    ] {
        std::fs::create_dir_all(&dir)
            .map_err(|e| data_err(format!("cannot create {}: {e}", dir.display())))?;
    }
    let (tokens, tokens_path, tokens_created) =
        Tokens::load_or_create(&opts.data).map_err(DaemonError::Tokens)?;
    let rig_source = RigSource::load(opts.rig.as_deref())?;
    // The rig clock continues from the latest rig time of the stored runs, so a run resumed
    // after a daemon restart still records increasing rig times.
    let rig_time_s = stored_runs::list(&opts.data.join("runs"))
        .unwrap_or_default()
        .iter()
        .map(|r| r.rig_time_s)
        .filter(|t| t.is_finite())
        .fold(0.0_f64, f64::max);
    let rig = Rig::open_with(
        rig_source.spec.clone(),
        RigClock::starting_at(rig_time_s),
        opts.seed,
        opts.emulation.as_ref(),
    )?;
    let daemon = Daemon {
        rig,
        rig_source,
        data_dir: opts.data.clone(),
        scripts_dir: opts.scripts.clone(),
        seed: opts.seed,
        emulation: opts.emulation.clone(),
        tokens,
        hub: events::EventHub::new(),
        runs: runs::RunManager::default(),
        estop: estop::EStop::default(),
        metrics: metrics_handle(),
        manual: manual::ManualLocks::default(),
        started: std::time::Instant::now(),
        queue: queue::RunQueue::default(),
    };
    let state = AppState(Arc::new(daemon));
    device_state::spawn_device_watch(state.clone());
    queue::spawn_worker(state.clone());
    let listener = tokio::net::TcpListener::bind(opts.listen)
        .await
        .map_err(|e| DaemonError::Listen {
            addr: opts.listen,
            reason: e.to_string(),
        })?;
    let addr = listener
        .local_addr()
        .map_err(|e| DaemonError::Io(e.to_string()))?;
    // A CLI refused the rig's ports is told where to send its run instead.
    crate::rig::port_lock::record_listen_addr(addr);
    let app = router(state.clone());
    let (tx, rx) = oneshot::channel::<()>();
    let server = tokio::spawn(async move {
        let served = axum::serve(listener, app)
            .with_graceful_shutdown(async {
                let _ = rx.await;
            })
            .await;
        if let Err(e) = served {
            tracing::error!("the HTTP server stopped: {e}");
        }
    });
    Ok(RunningDaemon {
        addr,
        state,
        tokens_path,
        tokens_created,
        shutdown: Some(tx),
        server,
    })
}

/// The whole HTTP surface: the API (behind the token check and the body limit), the OpenAPI
/// document and Swagger UI, the dashboard, and a JSON 404 for everything else.
pub fn router(state: AppState) -> Router {
    let (api, mut openapi) = api::routes().split_for_parts();
    let (public, public_doc) = api::public_routes().split_for_parts();
    openapi.merge(public_doc);
    api::document_common_errors(&mut openapi);
    let api = api
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_token,
        ))
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES));
    let own = Router::new()
        .merge(api)
        .merge(public)
        .merge(web::routes())
        .fallback(not_found)
        .layer(SetResponseHeaderLayer::if_not_present(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(CONTENT_SECURITY_POLICY),
        ));
    own.with_state(state)
        .merge(SwaggerUi::new("/docs").url("/openapi.json", openapi))
        .layer(axum::middleware::from_fn(error::json_errors))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_FRAME_OPTIONS,
            HeaderValue::from_static("DENY"),
        ))
        .layer(SetResponseHeaderLayer::overriding(
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ))
}

/// The Content-Security-Policy of the dashboard and the API: only the daemon's own scripts,
/// styles, images and connections (no inline script or style, no other origin, no framing).
/// Swagger UI (`/docs/`) is vendored code with inline styles and keeps only the headers below.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; script-src 'self'; \
    style-src 'self'; img-src 'self' data: blob:; \
    connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; \
    frame-ancestors 'none'";

async fn not_found(uri: Uri) -> impl IntoResponse {
    ApiError::new(StatusCode::NOT_FOUND, format!("no route {}", uri.path()))
        .hint("the API is under /api/ and described at /openapi.json (Swagger UI at /docs/)")
}

/// `stagehand serve`: runs the daemon until Ctrl-C or SIGTERM, then aborts any run and leaves
/// the rig in its safe state.
pub fn serve(opts: ServeOptions) -> Result<(), DaemonError> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .on_thread_start(stagehand_devices::realtime::raise_this_thread)
        .build()
        .map_err(|e| DaemonError::Io(format!("cannot start the runtime: {e}")))?;
    runtime.block_on(async move {
        let daemon = start(opts).await?;
        let addr = daemon.addr;
        eprintln!(
            "stagehand daemon on rig `{}`",
            daemon.state.rig_source.spec.rig.name
        );
        eprintln!("  dashboard:  {}", dashboard_url(addr));
        if addr.ip().is_unspecified() {
            eprintln!(
                "              (listening on every interface, port {})",
                addr.port()
            );
        }
        eprintln!("  API:        http://{addr}/api/  (OpenAPI: /openapi.json, Swagger UI: /docs/)");
        eprintln!("  scheduling: {}", stagehand_devices::realtime::describe());
        eprintln!(
            "  tokens:     {}{}",
            daemon.tokens_path.display(),
            if daemon.tokens_created {
                " (created now; mode 0600)"
            } else {
                ""
            }
        );
        shutdown_signal().await;
        eprintln!("stopping: aborting any run, switching lamps and laser off, stopping axes…");
        daemon.shutdown().await;
        Ok(())
    })
}

/// The dashboard's URL for the startup banner: `http://ADDR/`, on loopback when the daemon
/// listens on every interface (`0.0.0.0` is not an address a browser can open).
pub fn dashboard_url(addr: SocketAddr) -> String {
    let mut addr = addr;
    if addr.ip().is_unspecified() {
        let loopback: std::net::IpAddr = if addr.is_ipv4() {
            std::net::Ipv4Addr::LOCALHOST.into()
        } else {
            std::net::Ipv6Addr::LOCALHOST.into()
        };
        addr.set_ip(loopback);
    }
    format!("http://{addr}/")
}

async fn shutdown_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_banner_names_a_dashboard_url_a_browser_can_open() {
        let url = |a: &str| dashboard_url(a.parse().expect("address"));
        assert_eq!(url("127.0.0.1:8080"), "http://127.0.0.1:8080/");
        assert_eq!(url("192.168.1.20:80"), "http://192.168.1.20:80/");
        assert_eq!(url("0.0.0.0:8080"), "http://127.0.0.1:8080/");
        assert_eq!(url("[::]:9000"), "http://[::1]:9000/");
    }
}
