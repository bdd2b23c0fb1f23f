//! Command-line argument groups more than one command takes: how a BVH input is read, what
//! follows the last denoising step, which sampler and which keyframe method.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use diffkfc_data::io::rig::{self, ImportOptions};
use diffkfc_model::diffusion::scheduler::Sampler;
use diffkfc_model::sampling::fit::{Feet, Fit, KeyframeFit};
use diffkfc_model::sampling::sampler::DEFAULT_SAMPLER;

/// How a BVH input is read: its joint names, units and up axis.
#[derive(Args, Clone, Debug, Default)]
pub(crate) struct BvhInputArgs {
    /// BVH input whose joint names follow no known convention (ours, Mixamo, LaFAN1, CMU):
    /// a JSON object from joint (ours, e.g. "l_wrist" or "LeftHand") to the file's joint name,
    /// e.g. {"pelvis": "root", "l_wrist": "lHand"}; joints it leaves out use the closest
    /// known naming.
    #[arg(long, value_name = "MAP.json")]
    pub rig_map: Option<PathBuf>,
    /// Units of a BVH input; auto picks the one that makes the leg (hip to ankle) nearest 0.8 m.
    #[arg(long, default_value = "auto", value_name = "auto|m|cm|mm|in")]
    pub bvh_units: String,
    /// Up axis of a BVH input; auto takes the axis from the ankles to the head.
    #[arg(long, default_value = "auto", value_name = "auto|y|z|-y|-z|x|-x")]
    pub bvh_up: String,
}

impl BvhInputArgs {
    pub(crate) fn options(&self) -> Result<ImportOptions> {
        let metres_per_unit =
            match self.bvh_units.as_str() {
                "auto" => None,
                u => Some(rig::UNITS.iter().find(|(n, _)| *n == u).map(|x| x.1).with_context(
                    || format!("--bvh-units: '{u}' is not one of auto, m, cm, mm, in"),
                )?),
            };
        let up = match self.bvh_up.as_str() {
            "auto" => None,
            u => Some(rig::Up::parse(u).with_context(|| {
                format!("--bvh-up: '{u}' is not one of auto, y, z, -y, -z, x, -x")
            })?),
        };
        let mut rig_map = Vec::new();
        if let Some(p) = &self.rig_map {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("--rig-map: reading {}", p.display()))?;
            let v: serde_json::Value = serde_json::from_str(&text)
                .with_context(|| format!("--rig-map: {} is not JSON", p.display()))?;
            let obj = v.as_object().with_context(|| {
                format!(
                    "--rig-map: {} must hold a JSON object from our joint names to the file's",
                    p.display()
                )
            })?;
            for (k, v) in obj {
                let name = v.as_str().with_context(|| {
                    format!(
                        "--rig-map: {}: \"{k}\" maps to {v}; must be a joint name (a string)",
                        p.display()
                    )
                })?;
                rig_map.push((k.clone(), name.to_string()));
            }
        }
        Ok(ImportOptions { metres_per_unit, up, rig_map })
    }
}

/// What follows the last denoising step (shared by `sample` and `eval`).
#[derive(Args, Clone, Debug)]
pub(crate) struct FitArgs {
    /// How the motion meets its keyframes after the last step: track (root first, then the
    /// body: the keyed sample's root warped through the keyed places and headings becomes a
    /// root track, the motion is denoised again with it observed on every frame, then warped;
    /// twice the denoising), warp (the residual at each key spread smoothly over its neighbours
    /// and the root re-integrated to the keyed places and headings: exact, no seam), paste
    /// (observed features written into the key frames alone: the pose jumps there), none (the
    /// network's output as it is).
    #[arg(long, default_value_t = Fit::default().keyframes, value_name = "track|warp|paste|none")]
    keyframe_fit: KeyframeFit,
    /// Same as --keyframe-fit none (kept for older scripts).
    #[arg(long, hide = true)]
    no_snap: bool,
    /// No foot post-process at all: feet stay where the network put them. By default a
    /// standing foot is held still on the ground and a swinging one lifted clear of it, the
    /// leg re-solved by two-bone IK (pose keyframes and the root's path untouched; see
    /// --feet): generated walks otherwise slide their feet.
    #[arg(long)]
    no_foot_lock: bool,
    /// How the foot post-process finds and holds planted feet: steps (the default: stances
    /// where a low toe is slow or slower than the pelvis, and set into glides; the pelvis
    /// lowered up to 6 cm where a leg could not hold them; pinned, and the swings between them
    /// lifted off the floor where they would slide), network (the network's contact channels,
    /// pinned), warp (contacts from the motion: a toe or ankle low and slow; strides scaled so
    /// the stance foot stands still under the root's speed, then pinned) or pin (contacts from
    /// the motion, pinned only). docs/feet.md compares them.
    #[arg(long, value_enum, default_value_t = FeetArg::of(Fit::default().feet))]
    feet: FeetArg,
    /// Largest move of a planted foot the lock makes, in metres; a contact span whose foot
    /// slides further is left as it is (a dragged foot), as is one whose leg cannot reach the
    /// held foot to within 2 cm at every frame (docs/sampling.md).
    #[arg(long, default_value_t = diffkfc_data::postprocess::footlock::MAX_SHIFT_M, value_name = "METRES")]
    foot_lock_reach: f64,
    /// Keep the network's joint positions as they are. By default every frame is refitted to
    /// one skeleton (bone directions kept, lengths the skeleton's) before the foot lock, so the
    /// BVH reproduces the motion the page shows; generated bones otherwise stretch.
    #[arg(long)]
    no_rigid: bool,
    /// Keep the network's in-betweens whatever its poses at the keys. By default, after the
    /// keyframe fit, each frame is pulled towards the keys' linear interpolation as far as the
    /// network missed the keys it was given (whole-pose keys with places and headings only), so
    /// motion unlike the training set falls back on the keys (docs/inbetween.md).
    #[arg(long)]
    no_balance: bool,
}

impl FitArgs {
    pub(crate) fn fit(&self) -> Fit {
        Fit {
            keyframes: if self.no_snap { KeyframeFit::None } else { self.keyframe_fit },
            foot_lock: !self.no_foot_lock,
            feet: self.feet.feet(),
            lock_reach: self.foot_lock_reach,
            rigid: !self.no_rigid,
            balance: !self.no_balance,
        }
    }

    /// The flags in their ranges.
    pub(crate) fn check(&self) -> anyhow::Result<()> {
        let r = self.foot_lock_reach;
        if !(r.is_finite() && (0.0..=2.0).contains(&r)) {
            anyhow::bail!("--foot-lock-reach: {r} must be a number of metres from 0 to 2");
        }
        Ok(())
    }
}

/// Most motions `eval` generates at once, and most pairs in an evaluator's training batch.
pub(crate) const MAX_GENERATION_BATCH: usize = 1024;

/// Largest keyframe and transition guidance accepted: far beyond any useful value, small
/// enough that the sampler stays finite.
pub(crate) use diffkfc_model::sampling::guidance::MAX_GUIDANCE;

/// The guidance and step flags of `sample` and `eval`, in their ranges.
pub(crate) fn check_guidance(
    kf: f64,
    text: f64,
    place: f64,
    transition: f64,
    steps: usize,
) -> anyhow::Result<()> {
    use diffkfc_model::sampling::guidance::{check_range, MAX_STRENGTH};
    check_range("--kf-guidance", kf, MAX_GUIDANCE, " (1 = no guidance, 2.5 = the paper)")
        .and_then(|_| check_range("--text-guidance", text, MAX_GUIDANCE, " (1 = no guidance)"))
        .and_then(|_| check_range("--place-guidance", place, MAX_STRENGTH, ""))
        .and_then(|_| {
            check_range("--transition-guidance", transition, MAX_STRENGTH, " (100 = the paper)")
        })
        .map_err(anyhow::Error::new)?;
    if steps == 0 || steps > 1000 {
        anyhow::bail!("--steps: {steps} must be 1 to 1000 (the schedule's length)");
    }
    Ok(())
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum KeyframeMode {
    /// The trained keyframe branch with keyframe guidance.
    Diffkfc,
    /// MDM-inp baseline: keyframes pasted into x0 at every step, no keyframe branch.
    Inpaint,
}

/// `--feet`: how planted feet are found and held.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum FeetArg {
    Warp,
    Pin,
    Network,
    Steps,
}

impl FeetArg {
    const ALL: [FeetArg; 4] = [FeetArg::Warp, FeetArg::Pin, FeetArg::Network, FeetArg::Steps];

    fn feet(self) -> Feet {
        match self {
            FeetArg::Warp => Feet::Warp,
            FeetArg::Pin => Feet::Pin,
            FeetArg::Network => Feet::Network,
            FeetArg::Steps => Feet::Steps,
        }
    }

    /// The flag value of the library's `feet` (the default comes from `Fit::default()`).
    fn of(feet: Feet) -> FeetArg {
        FeetArg::ALL.into_iter().find(|f| f.feet() == feet).unwrap_or(FeetArg::Steps)
    }
}

/// How the transition-guidance gradient is taken (`sample` and `eval`).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum TgModeArg {
    /// Gradient with respect to the predicted x0 (no backward pass).
    X0,
    /// Gradient through the denoiser with respect to x_t (paper Eq. 5).
    Exact,
}

impl TgModeArg {
    pub(crate) fn mode(self) -> diffkfc_model::sampling::sampler::TgMode {
        match self {
            TgModeArg::X0 => diffkfc_model::sampling::sampler::TgMode::X0,
            TgModeArg::Exact => diffkfc_model::sampling::sampler::TgMode::Exact,
        }
    }

    /// The device a model needs for this mode: exact guidance differentiates through it.
    pub(crate) fn device(self, device: burn::prelude::Device) -> burn::prelude::Device {
        match self {
            TgModeArg::X0 => device,
            TgModeArg::Exact => device.autodiff(),
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum SamplerArg {
    /// Ancestral DDPM over every step of the schedule (the paper's 1000).
    Ddpm,
    /// Deterministic DDIM over --steps evenly spaced steps.
    Ddim,
    /// DPM-Solver++(2M): second-order multistep over --steps evenly spaced steps.
    Dpm,
}

impl SamplerArg {
    /// The default sampler's kind (`sampling::sampler::DEFAULT_SAMPLER`).
    pub(crate) const DEFAULT: SamplerArg = match DEFAULT_SAMPLER {
        Sampler::Ddpm => SamplerArg::Ddpm,
        Sampler::Ddim(_) => SamplerArg::Ddim,
        Sampler::DpmSolver(_) => SamplerArg::Dpm,
    };

    /// The sampler; `steps` counts DDIM steps (DDPM runs every step of the schedule).
    pub(crate) fn sampler(self, steps: usize) -> Sampler {
        match self {
            SamplerArg::Ddpm => Sampler::Ddpm,
            SamplerArg::Ddim => Sampler::Ddim(steps),
            SamplerArg::Dpm => Sampler::DpmSolver(steps),
        }
    }
}

/// `-o` must not name an input, however it is spelt (`./x`, a symlink): the command would
/// replace a file it reads.
pub(crate) fn refuse_overwriting_input(inputs: &[&Path], output: &Path) -> anyhow::Result<()> {
    // The output may not exist yet: compare through its folder.
    let real_output = output.canonicalize().ok().or_else(|| {
        let dir = output.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        Some(dir.canonicalize().ok()?.join(output.file_name()?))
    });
    let named =
        real_output.is_some_and(|o| inputs.iter().any(|i| i.canonicalize().is_ok_and(|i| i == o)));
    if named {
        let which = if inputs.len() == 1 { "the input file" } else { "one of the input files" };
        anyhow::bail!("-o: {} is {which}; write the result to another file", output.display());
    }
    Ok(())
}
