//! The routes: the page, `POST /api/sample`, `/api/export`, `/api/suggest`, `/api/import`,
//! `GET /api/status`. Bodies are parsed here (one-line errors naming the field); the work runs
//! on the model's thread (`worker`), uploads on a blocking thread, never on the async runtime.

use std::sync::Arc;
use std::time::Instant;

use axum::body::Bytes;
use axum::extract::{RawQuery, State};
use axum::http::{header, StatusCode, Uri};
use axum::response::{Html, IntoResponse, Response};
use axum::Json;
use diffkfc_data::io::keyframe_file::{self, KeySpec, KeyframeSpec};
use diffkfc_data::io::{gltf, motion_file, npy, rig};
use diffkfc_data::motion::{representation as rep, root_key};
use diffkfc_data::rng::Rng;
use diffkfc_data::{keyframes, T2M};
use serde::de::DeserializeOwned;
use serde_json::{json, Value};

use crate::api::{ExportFormat, Limits, SampleRequest, SuggestRequest};
use crate::engine::Generated;
use crate::error::ApiError;
use crate::report;
use crate::worker::Worker;

/// What every handler shares.
#[derive(Clone)]
pub struct AppState {
    pub worker: Worker,
    pub limits: Arc<Limits>,
    /// The page (built once; shared, not copied, by every GET).
    pub page: Bytes,
}

fn parse<T: DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    let text = std::str::from_utf8(body)
        .map_err(|_| ApiError::bad_request("request body: not UTF-8 text"))?;
    keyframe_file::parse_json(text).map_err(|e| ApiError::bad_request(format!("request body: {e}")))
}

/// `key=value` of a query string (values are file names and formats: no escapes needed).
fn query_value(q: &Option<String>, key: &str) -> Option<String> {
    q.as_deref()?.split('&').find_map(|kv| {
        let (k, v) = kv.split_once('=')?;
        (k == key).then(|| v.to_string())
    })
}

pub async fn index(State(s): State<AppState>) -> Html<Bytes> {
    Html(s.page)
}

pub async fn status(State(s): State<AppState>) -> Json<Value> {
    let (pending, done) = s.worker.load();
    Json(json!({"pending": pending, "done": done, "limits": *s.limits}))
}

pub async fn not_found(uri: Uri) -> ApiError {
    ApiError::with_status(StatusCode::NOT_FOUND, format!("{}: no such page", uri.path()))
}

/// Generate `req` on the model's thread and turn the motion into `T` there.
async fn generated<T: Send + 'static>(
    s: &AppState,
    req: SampleRequest,
    then: impl FnOnce(&Generated, &SampleRequest) -> Result<T, ApiError> + Send + 'static,
) -> Result<(T, f64), ApiError> {
    // Refused before it waits in the queue (the engine checks again for its other callers).
    req.check(&s.limits)?;
    let sent = Instant::now();
    s.worker
        .run(move |e| {
            let queue_ms = sent.elapsed().as_secs_f64() * 1e3;
            let g = e.generate(&req)?;
            Ok((then(&g, &req)?, queue_ms))
        })
        .await
}

pub async fn sample(State(s): State<AppState>, body: Bytes) -> Result<Json<Value>, ApiError> {
    let t0 = Instant::now();
    let req: SampleRequest = parse(&body)?;
    let (mut reply, queue_ms) =
        generated(&s, req, |g, r| Ok(report::sample_reply(g, &r.keyframes))).await?;
    let timing = json!({"queue_ms": queue_ms, "server_ms": t0.elapsed().as_secs_f64() * 1e3});
    reply.as_object_mut().unwrap().extend(timing.as_object().unwrap().clone());
    Ok(Json(reply))
}

pub async fn export(
    State(s): State<AppState>,
    RawQuery(q): RawQuery,
    body: Bytes,
) -> Result<Response, ApiError> {
    let format: ExportFormat = query_value(&q, "format")
        .and_then(|f| serde_json::from_value(Value::String(f)).ok())
        .ok_or_else(|| ApiError::bad_request("?format=: must be bvh, glb, features or joints"))?;
    let req: SampleRequest = parse(&body)?;
    let (bytes, _) = generated(&s, req, move |g, _| {
        Ok(match format {
            ExportFormat::Bvh => rig::export(&T2M, &g.joints).to_text().into_bytes(),
            ExportFormat::Features => npy::encode(&[g.length(), T2M.feature_dim()], g.features()),
            ExportFormat::Joints => {
                npy::encode(&[g.length(), T2M.num_joints(), 3], &rep::joints_to_f32(&g.joints))
            }
            ExportFormat::Glb => gltf::to_glb(&T2M, &g.joints, "motion")
                .map_err(|e| ApiError::invalid(format!("glb: {e}")))?,
        })
    })
    .await?;
    let (name, kind) = match format {
        ExportFormat::Bvh => ("motion.bvh", "text/plain"),
        ExportFormat::Features => ("motion_features.npy", "application/octet-stream"),
        ExportFormat::Joints => ("motion_joints.npy", "application/octet-stream"),
        ExportFormat::Glb => ("motion.glb", "model/gltf-binary"),
    };
    let disposition = format!("attachment; filename=\"{name}\"");
    Ok((
        [(header::CONTENT_TYPE, kind.to_string()), (header::CONTENT_DISPOSITION, disposition)],
        bytes,
    )
        .into_response())
}

pub async fn suggest(State(s): State<AppState>, body: Bytes) -> Result<Json<Value>, ApiError> {
    let sr: SuggestRequest = parse(&body)?;
    let (strategy, count) = sr.choice(sr.request.length(&s.limits)?)?;
    let label = sr.strategy.clone().unwrap_or_else(|| "mdo".into());
    let (spec, _) = generated(&s, sr.request, move |g, r| {
        let d = T2M.feature_dim();
        let rate = count as f64 / g.length() as f64;
        let frames =
            keyframes::select(strategy, g.length(), rate, g.features(), d, &mut Rng::new(r.seed));
        Ok(KeyframeSpec {
            length: Some(g.length()),
            keyframes: KeySpec::from_motion(&g.joints, &g.traj, &frames),
            strategy: Some(Value::String(label)),
            ..KeyframeSpec::default()
        })
    })
    .await?;
    Ok(Json(serde_json::to_value(spec).map_err(|e| ApiError::internal(e.to_string()))?))
}

pub async fn import(
    State(s): State<AppState>,
    RawQuery(q): RawQuery,
    body: Bytes,
) -> Result<Json<Value>, ApiError> {
    let name = query_value(&q, "name").unwrap_or_else(|| "upload".into());
    let max_frames = s.limits.max_upload_frames;
    let work = move || -> Result<Value, ApiError> {
        let path = std::path::Path::new(&name);
        let feats = motion_file::motion_features_from_bytes(path, &body, &T2M, &Default::default())
            .map_err(|e| ApiError::invalid(e.to_string()))?;
        let n = feats.len() / T2M.feature_dim();
        if n > max_frames {
            return Err(ApiError::invalid(format!(
                "{name}: {n} frames; at most {max_frames} are read"
            )));
        }
        let joints = rep::recover_from_ric_f32(&T2M, &feats);
        let traj = root_key::root_trajectory(&feats, T2M.feature_dim());
        let mut v = report::motion_json(&joints, &traj);
        v["name"] = Value::String(name);
        Ok(v)
    };
    let v = tokio::task::spawn_blocking(work)
        .await
        .map_err(|_| ApiError::internal("reading the upload failed"))??;
    Ok(Json(v))
}
