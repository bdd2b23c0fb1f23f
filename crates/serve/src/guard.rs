//! Who may drive the server. It binds to loopback, but a page on any other site can still
//! send requests to 127.0.0.1 from the user's browser: through DNS rebinding (its own name
//! resolving to 127.0.0.1, so the Host header names that site) or with a cross-site POST. So:
//! the Host header must name this server, an Origin header (sent on cross-site and on all
//! POST requests) must be this server's, and POST bodies must have a content type a plain HTML
//! form cannot send (JSON, or octet-stream for uploads), which forces a CORS preflight that
//! this server never answers with permission.

use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{header, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::error::ApiError;

/// The `host:port` names this server answers to (lower case).
#[derive(Clone, Debug)]
pub struct Guard {
    pub hosts: Vec<String>,
}

impl Guard {
    /// For a server listening on `addr`: its own address, `localhost` for loopback, and the
    /// extra names (`--allow-host`), each with the port.
    pub fn new(addr: std::net::SocketAddr, extra: &[String]) -> Guard {
        let port = addr.port();
        let mut hosts = vec![addr.to_string()];
        if addr.ip().is_loopback() {
            hosts.extend([format!("localhost:{port}"), format!("127.0.0.1:{port}")]);
        }
        hosts.extend(extra.iter().map(|h| format!("{h}:{port}")));
        hosts.iter_mut().for_each(|h| *h = h.to_ascii_lowercase());
        hosts.dedup();
        Guard { hosts }
    }

    fn check(&self, req: &Request) -> Result<(), ApiError> {
        let forbidden = |m: String| ApiError::with_status(StatusCode::FORBIDDEN, m);
        let text = |v: Option<&header::HeaderValue>| {
            v.map(|v| v.to_str().unwrap_or("(not text)").to_ascii_lowercase())
        };
        let host = text(req.headers().get(header::HOST)).unwrap_or_default();
        if !self.hosts.contains(&host) {
            return Err(forbidden(format!(
                "Host '{host}' is not this server ({}); refused (a page on another site cannot drive the editor)",
                self.hosts[0]
            )));
        }
        if let Some(origin) = text(req.headers().get(header::ORIGIN)) {
            if !self.hosts.iter().any(|h| origin == format!("http://{h}")) {
                return Err(forbidden(format!(
                    "Origin '{origin}' is not this server (http://{}); refused",
                    self.hosts[0]
                )));
            }
        }
        if req.method() == Method::POST {
            let want = if req.uri().path() == "/api/import" {
                "application/octet-stream"
            } else {
                "application/json"
            };
            let ct = text(req.headers().get(header::CONTENT_TYPE)).unwrap_or_default();
            if ct.split(';').next().map(str::trim) != Some(want) {
                return Err(ApiError::with_status(
                    StatusCode::UNSUPPORTED_MEDIA_TYPE,
                    format!("Content-Type '{ct}': {} takes {want}", req.uri().path()),
                ));
            }
        }
        Ok(())
    }
}

/// The middleware: refuse what [`Guard`] refuses before any handler runs.
pub async fn guard(State(g): State<Arc<Guard>>, req: Request, next: Next) -> Response {
    match g.check(&req) {
        Ok(()) => next.run(req).await,
        Err(e) => e.into_response(),
    }
}
