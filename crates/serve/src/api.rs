//! The JSON API's requests, their bounds and their checks. A sample request carries a
//! keyframe object in the format `sample --keyframes` reads, in world coordinates.

use diffkfc_data::io::keyframe_file::KeyframeSpec;
use diffkfc_data::keyframes::Strategy;
use diffkfc_model::sampling::fit::{Feet, KeyframeFit};
use serde::{Deserialize, Serialize};

use crate::error::ApiError;

/// Bounds on what one request may ask for.
#[derive(Clone, Debug, Serialize)]
pub struct Limits {
    /// Longest motion (the model's `max_frames`).
    pub max_frames: usize,
    /// Most keyframes in one request.
    pub max_keys: usize,
    /// Longest prompt, in characters.
    pub max_text_chars: usize,
    /// Most denoising steps (the model's schedule).
    pub max_steps: usize,
    /// Largest JSON body and largest uploaded motion, in bytes.
    pub max_json_bytes: usize,
    pub max_upload_bytes: usize,
    /// Most frames of an uploaded motion.
    pub max_upload_frames: usize,
    /// Generations waiting behind the running one before requests get 503.
    pub queue: usize,
}

impl Limits {
    /// The bounds for a model of `max_frames` frames and `max_steps` diffusion steps.
    pub fn for_model(max_frames: usize, max_steps: usize) -> Limits {
        Limits {
            max_frames,
            max_keys: max_frames,
            max_text_chars: 1000,
            max_steps,
            max_json_bytes: 2 << 20,
            max_upload_bytes: 16 << 20,
            max_upload_frames: 20_000,
            queue: 16,
        }
    }
}

/// `POST /api/sample`, `/api/export` and (inside) `/api/suggest`: a prompt, keyframes and
/// sampler settings.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleRequest {
    pub text: String,
    /// Keyframes as in a `sample --keyframes` file; its `length` is the motion's length.
    #[serde(default)]
    pub keyframes: KeyframeSpec,
    /// Frames when `keyframes` has no length (default 120).
    pub length: Option<usize>,
    #[serde(default)]
    pub seed: u64,
    /// Steps of the default sampler (`sample`'s; default 20).
    pub steps: Option<usize>,
    /// Keyframe guidance scale (default 1).
    pub kf_guidance: Option<f64>,
    /// Text guidance scale (default 2.5 for a model trained with text drop, else 1; other
    /// values need such a model).
    pub text_guidance: Option<f64>,
    /// Transition guidance strength (default 10).
    pub transition_guidance: Option<f64>,
    /// track (default), warp, paste or none.
    pub fit: Option<KeyframeFit>,
    /// Hold planted feet (default on).
    pub foot_lock: Option<bool>,
    /// How planted feet are found and held: steps (default), warp, pin or network.
    pub feet: Option<Feet>,
}

impl SampleRequest {
    /// The motion's length, checked against `limits`.
    pub fn length(&self, limits: &Limits) -> Result<usize, ApiError> {
        let n = self.keyframes.length.or(self.length).unwrap_or(120);
        if n == 0 || n > limits.max_frames {
            return Err(ApiError::invalid(format!(
                "length: {n} frames; must be 1 to {} (the model's max_frames)",
                limits.max_frames
            )));
        }
        Ok(n)
    }

    /// Everything checkable before the model runs (the keyframes themselves are checked when
    /// they are resolved, with the CLI's messages).
    pub fn check(&self, limits: &Limits) -> Result<(), ApiError> {
        let chars = self.text.chars().count();
        if self.text.trim().is_empty() {
            return Err(ApiError::invalid("text: empty prompt"));
        }
        if chars > limits.max_text_chars {
            return Err(ApiError::invalid(format!(
                "text: {chars} characters; at most {}",
                limits.max_text_chars
            )));
        }
        self.length(limits)?;
        let keys = self.keyframes.keyframes.len();
        if keys > limits.max_keys {
            return Err(ApiError::invalid(format!(
                "keyframes: {keys} keys; at most {}",
                limits.max_keys
            )));
        }
        if let Some(s) = self.steps.filter(|&s| s == 0 || s > limits.max_steps) {
            return Err(ApiError::invalid(format!(
                "steps: {s}; must be 1 to {} (the model's diffusion steps)",
                limits.max_steps
            )));
        }
        use diffkfc_model::sampling::guidance::{check_range, MAX_GUIDANCE, MAX_STRENGTH};
        if let Some(s) = self.kf_guidance {
            check_range("kf_guidance", s, MAX_GUIDANCE, " (1 = no guidance)")
                .map_err(|e| ApiError::invalid(e.to_string()))?;
        }
        if let Some(s) = self.text_guidance {
            check_range("text_guidance", s, MAX_GUIDANCE, " (1 = no guidance)")
                .map_err(|e| ApiError::invalid(e.to_string()))?;
        }
        if let Some(r) = self.transition_guidance {
            check_range("transition_guidance", r, MAX_STRENGTH, "")
                .map_err(|e| ApiError::invalid(e.to_string()))?;
        }
        Ok(())
    }
}

/// The three files `/api/export` writes.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    /// BVH of the world-space motion (our rig).
    Bvh,
    /// HumanML3D features (T, 263) `.npy`.
    Features,
    /// Joint positions (T, 22, 3) `.npy`, world space.
    Joints,
    /// glTF 2.0 binary of the world-space motion (our rig as a skin, a simple body).
    Glb,
}

/// `?format=` of `/api/export`.
#[derive(Debug, Deserialize)]
pub struct ExportQuery {
    pub format: ExportFormat,
}

/// `?name=` of `/api/import`: the uploaded file's name (only its extension is used).
#[derive(Debug, Deserialize)]
pub struct ImportQuery {
    #[serde(default)]
    pub name: String,
}

/// `POST /api/suggest`: keyframes picked from the motion a request generates.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuggestRequest {
    pub request: SampleRequest,
    /// Keys to pick (default 5).
    pub count: Option<usize>,
    /// random, uniform or mdo (default).
    pub strategy: Option<String>,
}

impl SuggestRequest {
    /// The strategy and key count, checked against the motion's `length`.
    pub fn choice(&self, length: usize) -> Result<(Strategy, usize), ApiError> {
        let strategy: Strategy = self.strategy.as_deref().unwrap_or("mdo").parse().map_err(
            |e: diffkfc_data::UnknownChoice| ApiError::invalid(format!("strategy: {e}")),
        )?;
        let count = self.count.unwrap_or(5);
        if count == 0 || count > length {
            return Err(ApiError::invalid(format!(
                "count: {count} keyframes; must be 1 to the motion's {length} frames"
            )));
        }
        Ok((strategy, count))
    }
}
