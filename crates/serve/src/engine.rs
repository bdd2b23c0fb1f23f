//! The loaded model behind the API: the generation session `sample` also uses
//! (`diffkfc_model::sampling::session`: cached prompt embeddings, the pipeline, the divergence
//! check), the request's defaults (the library's), and the motion in the editor's
//! world frame (keys are given in the world; the representation starts every motion at the
//! origin facing +Z, so a keyed first frame places the whole motion).

use burn::prelude::Device;
use diffkfc_data::io::keyframe_file::{self, KeyframeSet, KeyframeSpec};
use diffkfc_data::motion::representation::Joints;
use diffkfc_data::motion::root_key::{self, RootKey};
use diffkfc_data::{motion::representation as rep, T2M};
use diffkfc_model::error::ModelError;
use diffkfc_model::sampling::fit::{Fit, Fitted};
use diffkfc_model::sampling::guidance;
use diffkfc_model::sampling::pipeline::KeyedItem;
use diffkfc_model::sampling::sampler::{Options, DEFAULT_SAMPLER, DEFAULT_STEPS};
use diffkfc_model::sampling::session::Session;

use crate::api::{Limits, SampleRequest};
use crate::error::{ApiError, ServeError};

/// The loaded session (model and text encoder) and the request bounds it implies.
pub struct Engine {
    session: Session,
    pub limits: Limits,
}

/// One generated motion, in the world frame of its keys.
pub struct Generated {
    /// Joint positions and per-frame place and heading, in the world.
    pub joints: Joints,
    pub traj: Vec<RootKey>,
    /// The resolved keyframes (places relative to frame 0, as the sampler reads them).
    pub keys: KeyframeSet,
    /// Where frame 0 stands in the world.
    pub origin: RootKey,
    /// The fitted motion: de-normalised features `[length, D]` in the representation's own
    /// frame, and what the fit did.
    pub fitted: Fitted,
    /// Milliseconds the pipeline (both stages and the fit) took.
    pub generate_ms: f64,
}

impl Engine {
    /// The model at `checkpoint` (a run or model folder, or a checkpoint file) on `device`, and
    /// the text encoder.
    pub fn load(checkpoint: &std::path::Path, device: &Device) -> Result<Engine, ServeError> {
        let session = Session::load(checkpoint, device, &T2M).map_err(|e| match e {
            ModelError::Text(e) => ServeError::Load(format!("text encoder: {e}")),
            e => ServeError::Load(format!("--checkpoint {}: {e}", checkpoint.display())),
        })?;
        let limits = Limits::for_model(session.max_frames(), session.loaded.schedule.steps);
        Ok(Engine { session, limits })
    }

    /// The checkpoint's training step.
    pub fn step(&self) -> usize {
        self.session.step()
    }

    /// Generate the motion `r` asks for: checked, sampled and fitted as `sample` does, then
    /// placed in the world.
    pub fn generate(&mut self, r: &SampleRequest) -> Result<Generated, ApiError> {
        r.check(&self.limits)?;
        let length = r.length(&self.limits)?;
        let keys = r
            .keyframes
            .resolve(&T2M, Some(length), None, self.limits.max_frames)
            .map_err(|e| ApiError::invalid(format!("keyframes: {e}")))?;
        let cfg = &self.session.loaded.cfg;
        let text_guidance = guidance::text_guidance("text_guidance", r.text_guidance, cfg)
            .map_err(|e| ApiError::invalid(e.to_string()))?;
        let text =
            self.session.embed(&r.text).map_err(|e| ApiError::invalid(format!("text: {e}")))?;
        let t0 = std::time::Instant::now();
        let defaults = Options::default();
        let opts = Options {
            sampler: DEFAULT_SAMPLER.with_steps(r.steps.unwrap_or(DEFAULT_STEPS)),
            kf_guidance: r.kf_guidance.unwrap_or(defaults.kf_guidance),
            text_guidance,
            transition: r.transition_guidance.unwrap_or(defaults.transition),
            seed: r.seed,
            ..defaults
        };
        let fit = Fit {
            keyframes: r.fit.unwrap_or_default(),
            foot_lock: r.foot_lock.unwrap_or(Fit::default().foot_lock),
            feet: r.feet.unwrap_or_default(),
            ..Fit::default()
        };
        let item = KeyedItem {
            text: &text,
            length,
            values: &keys.values,
            mask: &keys.mask,
            root: &keys.root,
        };
        let req = self.session.request(length, &[item]);
        let fitted = self
            .session
            .generate(&req, &opts, fit, |_, _| {})
            .map_err(|e| {
                ApiError::invalid(format!("{e}; lower kf_guidance or transition_guidance"))
            })?
            .remove(0);
        let generate_ms = t0.elapsed().as_secs_f64() * 1e3;
        // The session refused a motion that is not drawable, so these joints are.
        let local = rep::recover_from_ric_f32(&T2M, &fitted.features);
        let origin = origin_of(&r.keyframes);
        let joints = in_world(&local, origin);
        let traj = root_key::root_trajectory(&fitted.features, T2M.feature_dim())
            .into_iter()
            .map(|k| keyframe_file::from_frame(k, origin))
            .collect();
        Ok(Generated { joints, traj, keys, origin, fitted, generate_ms })
    }
}

impl Generated {
    /// Frames of the motion.
    pub fn length(&self) -> usize {
        self.keys.length
    }

    /// De-normalised features `[length, D]`.
    pub fn features(&self) -> &[f32] {
        &self.fitted.features
    }
}

/// Where the keys put frame 0: its keyed place and heading (the origin facing +Z otherwise).
pub fn origin_of(spec: &KeyframeSpec) -> RootKey {
    spec.keyframes
        .iter()
        .find(|k| k.frame == 0)
        .map(|k| RootKey {
            place: k.root.map(|p| [p[0], p[2]]),
            heading: k.heading.map(f64::to_radians),
        })
        .unwrap_or_default()
}

/// Joint positions given in the frame that stands at `origin`, in the world.
pub fn in_world(joints: &Joints, origin: RootKey) -> Joints {
    joints
        .iter()
        .map(|f| f.iter().map(|&p| keyframe_file::point_from_frame(p, origin)).collect())
        .collect()
}
