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
    /// For a server listening on `addr`: its own address, `localhost` and 127.0.0.1 when it
    /// listens on loopback, and the extra names (`--allow-host`), each with the port.
    pub fn new(addr: std::net::SocketAddr, extra: &[String]) -> Guard {
        let port = addr.port();
        let mut hosts = vec![addr.to_string()];
        // Listening on every interface (0.0.0.0) includes loopback.
        if addr.ip().is_loopback() || addr.ip().is_unspecified() {
            hosts.extend([format!("localhost:{port}"), format!("127.0.0.1:{port}")]);
        }
        hosts.extend(extra.iter().map(|h| format!("{h}:{port}")));
        hosts.iter_mut().for_each(|h| *h = h.to_ascii_lowercase());
        let mut seen = std::collections::HashSet::new();
        hosts.retain(|h| seen.insert(h.clone()));
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Loopback and every-interface servers answer to localhost; another address only to itself
    /// and the names allowed.
    #[test]
    fn names_a_server_answers_to() {
        let g = Guard::new("127.0.0.1:7860".parse().unwrap(), &[]);
        assert_eq!(g.hosts, ["127.0.0.1:7860", "localhost:7860"]);
        let g = Guard::new("0.0.0.0:80".parse().unwrap(), &["Studio.local".into()]);
        assert_eq!(g.hosts, ["0.0.0.0:80", "localhost:80", "127.0.0.1:80", "studio.local:80"]);
        let g = Guard::new("192.168.1.5:7860".parse().unwrap(), &[]);
        assert_eq!(g.hosts, ["192.168.1.5:7860"]);
    }
}
