//! `diffkfc serve`: the keyframe editor. A local HTTP server loads the model once and serves
//! one page (the 3D view, a timeline of keys, the prompt) and a small JSON API; every edit on
//! the page samples again through the same pipeline as `sample`.
//!
//! - `GET /`: the page. `GET /api/status`: queue and bounds.
//! - `POST /api/sample` (JSON [`api::SampleRequest`]): the motion, per-key errors, metrics.
//! - `POST /api/export?format=bvh|glb|features|joints`: the same request, as a file.
//! - `POST /api/suggest` ([`api::SuggestRequest`]): keyframes picked from the generated motion.
//! - `POST /api/import?name=walk.bvh` (the file's bytes): a motion to take keys from.
//!
//! Errors are `{"error": "<one line>"}` with a 4xx status (503 when the queue is full).

pub mod api;
pub mod engine;
pub mod error;
pub mod guard;
pub mod handlers;
pub mod page;
pub mod report;
pub mod worker;

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post};
use axum::Router;

pub use engine::Engine;
pub use error::{ApiError, ServeError};

/// Where and how to serve.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    pub host: IpAddr,
    /// 0 picks a free port (tests).
    pub port: u16,
    /// Extra names the Host header may carry (with the port), for a non-loopback --host.
    pub allow_hosts: Vec<String>,
    /// Generations that may wait behind the running one.
    pub queue: usize,
}

/// A server running on its own threads.
pub struct Running {
    pub addr: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<std::io::Result<()>>>,
}

impl Running {
    /// Stop accepting, finish the requests in flight and wait for the server to end.
    pub fn stop(mut self) -> Result<(), ServeError> {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => Ok(r?),
            Some(Err(_)) => Err(ServeError::Load("the server thread panicked".into())),
            None => Ok(()),
        }
    }
}

/// The routes, their body limits and the guard.
pub fn router(state: handlers::AppState, guard: guard::Guard) -> Router {
    let json_limit = DefaultBodyLimit::max(state.limits.max_json_bytes);
    Router::new()
        .route("/", get(handlers::index))
        .route("/api/status", get(handlers::status))
        .route("/api/sample", post(handlers::sample).layer(json_limit))
        .route("/api/export", post(handlers::export).layer(json_limit))
        .route("/api/suggest", post(handlers::suggest).layer(json_limit))
        .route(
            "/api/import",
            post(handlers::import).layer(DefaultBodyLimit::max(state.limits.max_upload_bytes)),
        )
        .fallback(handlers::not_found)
        .layer(axum::middleware::from_fn_with_state(Arc::new(guard), guard::guard))
        .layer(axum::middleware::from_fn(error::json_errors))
        .with_state(state)
}

/// Load the model (`load` runs on the model's own thread), bind and serve until
/// [`Running::stop`].
pub fn start(
    opts: &ServeOptions,
    load: impl FnOnce() -> Result<Engine, ServeError> + Send + 'static,
) -> Result<Running, ServeError> {
    let (worker, limits, step) = worker::Worker::start(load, opts.queue)?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    let addr_text = SocketAddr::new(opts.host, opts.port).to_string();
    let listener = rt
        .block_on(tokio::net::TcpListener::bind((opts.host, opts.port)))
        .map_err(|err| ServeError::Bind { addr: addr_text, err })?;
    let addr = listener.local_addr()?;
    let page = page::html(&limits, step);
    let state = handlers::AppState { worker, limits: Arc::new(limits), page: page.into() };
    let app = router(state, guard::Guard::new(addr, &opts.allow_hosts));
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let thread = std::thread::Builder::new().name("diffkfc-http".into()).spawn(move || {
        rt.block_on(async move {
            axum::serve(listener, app)
                .with_graceful_shutdown(async move {
                    let _ = stopped.await;
                })
                .await
        })
    })?;
    Ok(Running { addr, stop: Some(stop), thread: Some(thread) })
}
