//! What the server answers when a request cannot be served: a status and the same one-line
//! message the CLI would print, as `{"error": "..."}`.

use axum::extract::Request;
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Json;

/// A refused or failed request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
}

impl ApiError {
    /// The request is well-formed JSON but asks for something out of range (422).
    pub fn invalid(message: impl Into<String>) -> ApiError {
        ApiError { status: StatusCode::UNPROCESSABLE_ENTITY, message: message.into() }
    }

    /// The request cannot be read (400).
    pub fn bad_request(message: impl Into<String>) -> ApiError {
        ApiError { status: StatusCode::BAD_REQUEST, message: message.into() }
    }

    /// Every generation slot and queue place is taken (503).
    pub fn busy(queued: usize) -> ApiError {
        ApiError {
            status: StatusCode::SERVICE_UNAVAILABLE,
            message: format!("busy: {queued} generation(s) already queued; try again shortly"),
        }
    }

    /// Something on our side failed (500); never expected.
    pub fn internal(message: impl Into<String>) -> ApiError {
        ApiError { status: StatusCode::INTERNAL_SERVER_ERROR, message: message.into() }
    }

    pub fn with_status(status: StatusCode, message: impl Into<String>) -> ApiError {
        ApiError { status, message: message.into() }
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({})", self.message, self.status.as_u16())
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.status, Json(serde_json::json!({ "error": self.message }))).into_response()
    }
}

/// Axum's own refusals (a body over its limit, a wrong method) are plain text: this middleware
/// answers them as `{"error": "<path>: <its one line>"}` like every other refusal.
pub async fn json_errors(req: Request, next: Next) -> Response {
    let path = req.uri().path().to_string();
    let resp = next.run(req).await;
    let status = resp.status();
    let json = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    if json || !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    let body = axum::body::to_bytes(resp.into_body(), 4096).await.unwrap_or_default();
    let text = String::from_utf8_lossy(&body);
    let line = text.lines().next().map(str::trim).filter(|l| !l.is_empty());
    let line = line.unwrap_or(status.canonical_reason().unwrap_or("refused"));
    ApiError::with_status(status, format!("{path}: {line}")).into_response()
}

/// Starting the server failed.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("--host/--port: cannot listen on {addr}: {err}")]
    Bind { addr: String, err: std::io::Error },
    #[error("{0}")]
    Load(String),
    #[error("server stopped: {0}")]
    Io(#[from] std::io::Error),
}
