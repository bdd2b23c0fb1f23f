//! `diffkfc sample`: text + keyframes -> motion, with keyframe and transition guidance.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use diffkfc_data::keyframes::{self, Strategy};
use diffkfc_data::motion::root_key::{self, RootKey};
use diffkfc_data::rng::Rng;
use diffkfc_data::{io::npy, motion::representation as rep, T2M};
use diffkfc_eval::keyframe_metrics::{k_err_global, k_err_local, k_trans};
use diffkfc_model::sampling::fit::{Fit, Fitted};
use diffkfc_model::sampling::guidance;
use diffkfc_model::sampling::pipeline::KeyedItem;
use diffkfc_model::sampling::place::PlaceGuidance;
use diffkfc_model::sampling::sampler::{self, Options, Request};
use diffkfc_model::sampling::session::Session;
use diffkfc_render as render;
use diffkfc_render::viewer::{self, escape, ViewMotion};
use serde_json::json;

use crate::args::{BvhInputArgs, FitArgs, KeyframeMode, SamplerArg, TgModeArg};

#[derive(Args, Clone, Debug)]
pub struct SampleArgs {
    /// Run directory of `diffkfc train` (its newest checkpoint) or one of its ckpt-*.safetensors
    /// files; EMA weights when present.
    #[arg(long)]
    checkpoint: PathBuf,
    /// The prompt (required unless --prompts or --timeline).
    #[arg(long, required_unless_present_any = ["prompts", "timeline", "text_lower"], default_value = "", hide_default_value = true)]
    text: String,
    /// Body-part prompts (with --text-upper): the lower body (legs, pelvis, the path) is
    /// generated from this text first, then the upper body from --text-upper with the lower
    /// body kept as keyframes on every frame.
    #[arg(long, requires = "text_upper", conflicts_with_all = ["text", "prompts", "timeline"], value_name = "TEXT")]
    text_lower: Option<String>,
    /// Body-part prompts: the upper body's text (with --text-lower).
    #[arg(long, requires = "text_lower", value_name = "TEXT")]
    text_upper: Option<String>,
    /// Body-part prompts: keyframe guidance scale of the upper-body pass. With the lower body
    /// keyed on every frame the keyframe branch would bring back the first motion's own arms
    /// (at 1, a walk's swing); 0 takes the arms from the text alone and the fit joins them to
    /// the kept lower body (see README).
    #[arg(long, default_value_t = 0.0)]
    part_guidance: f64,
    /// A motion of any length from a timeline of prompts: "0-4s: a person walks forward |
    /// 4-6.5s: a person jumps | 6.5-12s: a person sits down", or a file with one segment per
    /// line. Segments start at 0, follow one another and last at least 1 s. Each is generated
    /// in windows of at most 196 frames that start from the last 0.5 s of the motion so far
    /// (given as keyframes: pose, place and heading), so the joins have no seam; --keyframes
    /// JSON frames count on the whole timeline.
    #[arg(long, conflicts_with_all = ["text", "prompts", "from", "length", "seconds"], value_name = "SEGMENTS|FILE")]
    timeline: Option<String>,
    /// Many prompts: one per line, optionally `text#length`; outputs go to `<out>`/promptNNN.
    #[arg(long, conflicts_with = "text")]
    prompts: Option<PathBuf>,
    /// Keyframes from a motion: features (T,263) or joints (T,22,3) .npy, or a BVH (ours,
    /// Mixamo, LaFAN1, CMU names, or any rig with --rig-map).
    #[arg(long, conflicts_with = "keyframes")]
    from: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) bvh: BvhInputArgs,
    /// Frames of --from that become keyframes: a list (0,40,80) or `all`.
    #[arg(long, requires = "from")]
    frames: Option<String>,
    /// With --from: pick keyframes as in training at this rate instead of --frames.
    #[arg(long, requires = "from", conflicts_with = "frames")]
    keyframe_rate: Option<f64>,
    /// How --keyframe-rate picks frames: random, uniform (evenly spaced) or mdo (KeyMotion's
    /// maximum-distance-optimal).
    #[arg(long, default_value = "random", value_name = "random|uniform|mdo")]
    keyframe_strategy: String,
    /// Keyframes from a JSON file: {"length": 120, "joints": "lower_body", "keyframes":
    /// [{"frame": 0, "joints": [`[x,y,z]` x 22]}, {"frame": 60, "features": [263 numbers],
    /// "root": [x, y, z], "heading": 90}, {"frame": 100, "root": [0, 0.9, 5]}]}. Each keyframe
    /// has a pose ("joints" in metres, or "features") and/or a place ("root", metres) and a
    /// heading (degrees, 0 faces +Z, 90 faces +X) in the output's frame: frame 0 at the origin
    /// facing +Z. "length" and "joints" (body parts) are optional.
    #[arg(long)]
    keyframes: Option<PathBuf>,
    /// Restrict keyframes to body parts or joints (lower_body, left_arm, head, ...).
    #[arg(long)]
    joints: Option<String>,
    /// Frames to generate (default: the keyframe source's length, else 120).
    #[arg(long, conflicts_with = "seconds")]
    length: Option<usize>,
    /// Length in seconds (20 fps), instead of --length.
    #[arg(long)]
    seconds: Option<f64>,
    /// Motions generated for the prompt (1 to 256), in one batch.
    #[arg(long, default_value_t = 1)]
    num_samples: usize,
    /// Random seed: the same seed and inputs give the same bytes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// ddim: deterministic, --steps evenly spaced steps; dpm: DPM-Solver++(2M), second-order
    /// multistep over --steps steps; ddpm: ancestral over every step of the schedule (the
    /// paper's 1000). The default is measured on the reference model (docs/sampling.md).
    #[arg(long, value_enum, default_value_t = SamplerArg::DEFAULT)]
    sampler: SamplerArg,
    /// Steps of ddim and dpm (DDPM always runs every step of the schedule).
    #[arg(long, default_value_t = sampler::DEFAULT_STEPS)]
    steps: usize,
    /// Keyframe guidance scale s: X(C, none) + s (X(C, kf) - X(C, none)); 1 = the keyframe
    /// branch alone (the default: measured better than the paper's 2.5 with DDIM-50, see README).
    #[arg(long, default_value_t = sampler::DEFAULT_KF_GUIDANCE, allow_negative_numbers = true)]
    kf_guidance: f64,
    /// Text guidance scale s (MDM's classifier-free guidance over the text): X(no text) +
    /// s (X(text) - X(no text)); 1 = off. Default: 2.5 for a model trained with text drop
    /// (`training.text_drop_prob`), 1 for others (which refuse any other value). A scale other
    /// than 1 adds a branch to every denoiser call.
    #[arg(long, allow_negative_numbers = true)]
    text_guidance: Option<f64>,
    /// Transition guidance strength r (paper Eq. 4-5): each reverse step is nudged to make the
    /// window around every keyframe smooth in the DCT sense; 0 = off. The default 10 lowers
    /// K-TranS at equal FID; the paper's 100 doubles FID here (see README).
    #[arg(long, default_value_t = sampler::DEFAULT_TRANSITION, allow_negative_numbers = true)]
    transition_guidance: f64,
    /// Place guidance strength: each reverse step pulls the root path of the predicted motion
    /// towards the keyed places (root keyframes only); 0 = off.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    place_guidance: f64,
    /// Half window l of transition guidance (frames on each side of a keyframe).
    #[arg(long, default_value_t = sampler::DEFAULT_TG_WINDOW)]
    tg_window: usize,
    /// Number of DCT bases m kept by transition guidance.
    #[arg(long, default_value_t = sampler::DEFAULT_TG_BASES)]
    tg_bases: usize,
    /// How the transition-guidance gradient is taken.
    #[arg(long, value_enum, default_value = "x0")]
    tg_mode: TgModeArg,
    /// Which method generates: the trained keyframe branch, or the MDM-inp baseline.
    #[arg(long, value_enum, default_value = "diffkfc")]
    keyframe_mode: KeyframeMode,
    #[command(flatten)]
    pub(crate) fit: FitArgs,
    /// Keyframes from --from observe their pose only, not their place on the ground and their
    /// heading.
    #[arg(long)]
    pub(crate) no_root_keys: bool,
    /// Output folder (created): sample_NN.npy/_joints.npy/.bvh/.gif, results.json, index.html.
    /// A folder of an earlier `sample` is replaced whole (other files in it are kept); one that
    /// holds other files is refused unless --force.
    #[arg(long, default_value = "out/sample")]
    out: PathBuf,
    /// Write into an --out folder that holds files diffkfc did not write (only sample_NN*,
    /// source_joints.npy, results.json and index.html are written; nothing is removed).
    #[arg(long)]
    force: bool,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

mod keys;
mod output;
mod parts;
pub mod suggest;
mod timeline;
use keys::*;
use output::{write_outputs, Outputs};

pub fn run(a: SampleArgs) -> Result<()> {
    if let Some(spec) = a.timeline.clone() {
        return timeline::run(a, &spec);
    }
    if a.text_lower.is_some() {
        return parts::run(a);
    }
    let Some(file) = a.prompts.clone() else {
        return run_one(a);
    };
    let text =
        std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    // (line number in the file, text): blank and comment lines are skipped but still counted.
    let lines: Vec<(usize, &str)> = text
        .lines()
        .map(str::trim)
        .enumerate()
        .filter(|(_, l)| !l.is_empty() && !l.starts_with("//"))
        .map(|(n, l)| (n + 1, l))
        .collect();
    if lines.is_empty() {
        bail!("{}: no prompts", file.display());
    }
    // Every line is parsed before any is sampled: a bad line 4 writes nothing for lines 1-3.
    let max = diffkfc_data::dataset::MAX_FRAMES;
    let prompts: Vec<(usize, &str, Option<usize>)> = lines
        .iter()
        .map(|&(line_no, line)| match line.rsplit_once('#') {
            Some((t, l)) => {
                match l.trim().parse::<usize>().ok().filter(|&n| (1..=max).contains(&n)) {
                    Some(n) => Ok((line_no, t.trim(), Some(n))),
                    None => bail!(
                    "{}: line {line_no}: length '{l}' is not a number of frames from 1 to {max}",
                    file.display()
                ),
                }
            }
            None => Ok((line_no, line, None)),
        })
        .collect::<Result<_>>()?;
    for (k, &(line_no, t, len)) in prompts.iter().enumerate() {
        let mut one = a.clone();
        one.prompts = None;
        one.text = t.to_string();
        one.length = len.or(a.length);
        one.out = a.out.join(format!("prompt{k:03}"));
        run_one(one).with_context(|| format!("{}: line {line_no}", file.display()))?;
    }
    Ok(())
}

/// Flag values in their ranges, before any work.
fn check_flags(a: &SampleArgs) -> Result<()> {
    crate::args::check_guidance(
        a.kf_guidance,
        a.text_guidance.unwrap_or(1.0),
        a.place_guidance,
        a.transition_guidance,
        a.steps,
    )?;
    if a.tg_bases == 0 {
        bail!("--tg-bases: must be at least 1");
    }
    a.fit.check()?;
    output::check_out(a)?;
    if a.num_samples == 0 || a.num_samples > 256 {
        bail!("--num-samples: {} must be 1 to 256", a.num_samples);
    }
    Ok(())
}

fn run_one(a: SampleArgs) -> Result<()> {
    if a.text.trim().is_empty() {
        bail!("--text: empty prompt");
    }
    check_flags(&a)?;
    let keys = request_keys(&a)?;
    let gen = Job::load(&a)?;
    let emb = gen.embed(&a.text, "--text")?;
    let req =
        gen.request(&emb, keys.length, a.num_samples, &[(&keys.values, &keys.mask, &keys.root)]);
    let (fitted, secs) = gen.generate(&req, &a)?;
    write_outputs(&a, &gen, Outputs { keys: &keys, fitted, secs, extra: json!({}), segments: &[] })
}

/// One motion from `a`'s text and keyframes (the first sample): de-normalised, fitted features.
fn text_only_motion(a: &SampleArgs) -> Result<Vec<f32>> {
    check_flags(a)?;
    let keys = request_keys(a)?;
    let gen = Job::load(a)?;
    let req = gen.request(
        &gen.embed(&a.text, "--text")?,
        keys.length,
        1,
        &[(&keys.values, &keys.mask, &keys.root)],
    );
    Ok(gen.generate(&req, a)?.0.remove(0).features)
}

/// The keyframes the flags ask for (none: a motion of --length, --seconds or 120 frames).
fn request_keys(a: &SampleArgs) -> Result<Keys> {
    let max = diffkfc_data::dataset::MAX_FRAMES;
    // Checked before anything is allocated for the motion.
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s * T2M.fps >= 0.5 && s * T2M.fps <= max as f64) {
            bail!(
                "--seconds: {s} is not between {:.2} and {:.1} ({max} frames at {} fps)",
                0.5 / T2M.fps,
                max as f64 / T2M.fps,
                T2M.fps
            );
        }
    }
    let length = a.length.or(a.seconds.map(|s| (s * T2M.fps).round() as usize));
    if let Some(l) = length.filter(|&l| l == 0 || l > max) {
        bail!("--length: {l} frames; must be 1 to {max}");
    }
    let keys = match (&a.from, &a.keyframes) {
        (Some(p), _) => {
            keys_from_motion(a, p, length, joint_set(a.joints.as_deref(), "--joints")?)?
        }
        (None, Some(p)) => keys_from_json(p, length, a.joints.as_deref())?,
        (None, None) => {
            let length = length.unwrap_or(120);
            Keys {
                length,
                frames: vec![],
                values: vec![0.0; length * T2M.feature_dim()],
                mask: vec![0.0; length * T2M.feature_dim()],
                source: None,
                joints: vec![],
                root: vec![RootKey::default(); length],
            }
        }
    };
    if keys.length == 0 || keys.length > max {
        bail!("--length: {} frames; must be 1 to {max}", keys.length);
    }
    Ok(keys)
}

/// One `sample` command's generation: the loaded session and the settings it generates with.
pub(super) struct Job {
    session: Session,
    opts: Options,
    fit: Fit,
    checkpoint: std::path::PathBuf,
}

impl Job {
    fn load(a: &SampleArgs) -> Result<Job> {
        let device = crate::device::parse(&a.device)?;
        // Exact transition guidance differentiates through the denoiser.
        let device = a.tg_mode.device(device);
        let session = Session::load(&a.checkpoint, &device, &T2M)?;
        let loaded = &session.loaded;
        if a.steps > loaded.schedule.steps {
            bail!(
                "--steps: {} is more than the checkpoint's {} diffusion steps",
                a.steps,
                loaded.schedule.steps
            );
        }
        let place = PlaceGuidance::of_strength(a.place_guidance, &loaded.mean, &loaded.std);
        let text_guidance =
            guidance::text_guidance("--text-guidance", a.text_guidance, &loaded.cfg)?;
        let opts = Options {
            sampler: a.sampler.sampler(a.steps),
            kf_guidance: a.kf_guidance,
            text_guidance,
            transition: a.transition_guidance,
            seed: a.seed,
            window: a.tg_window,
            dct_bases: a.tg_bases,
            tg_mode: a.tg_mode.mode(),
            inpaint: matches!(a.keyframe_mode, KeyframeMode::Inpaint),
            place,
            impose_track: false,
        };
        Ok(Job { session, opts, fit: a.fit.fit(), checkpoint: a.checkpoint.clone() })
    }

    /// The checkpoint's step.
    fn step(&self) -> usize {
        self.session.step()
    }

    /// Longest motion the checkpoint's model was built for (`model.max_frames`).
    fn max_frames(&self) -> usize {
        self.session.max_frames()
    }

    /// The library's generator of the loaded model.
    fn pipeline(&self) -> diffkfc_model::sampling::pipeline::Generator<'_> {
        self.session.generator()
    }

    fn embed(&self, text: &str, flag: &str) -> Result<Vec<f32>> {
        self.session.embed(text).context(flag.to_string())
    }

    /// A request for `b` motions of `n` frames of the text `emb`; item i observes `keys[i]`
    /// (raw features `[n, D]`, their mask, root keys `[n]`), or `keys[0]` when one is given.
    fn request(
        &self,
        emb: &[f32],
        n: usize,
        b: usize,
        keys: &[(&[f32], &[f32], &[RootKey])],
    ) -> Request {
        let items: Vec<KeyedItem> = (0..b)
            .map(|i| {
                let (values, mask, root) = keys[i.min(keys.len() - 1)];
                KeyedItem { text: emb, length: n, values, mask, root }
            })
            .collect();
        self.session.request(n, &items)
    }

    /// Sample, fit and check every motion of `req`; also the seconds the sampler took. A
    /// diverged sampler (extreme guidance) gives an error, not NaN files with exit 0.
    fn generate(&self, req: &Request, a: &SampleArgs) -> Result<(Vec<Fitted>, f64)> {
        if req.frames > self.max_frames() {
            bail!("--length: {} frames, but {} was built for at most {} (model.max_frames); ask for fewer frames or use --timeline for longer motions", req.frames, self.checkpoint.display(), self.max_frames());
        }
        let t0 = std::time::Instant::now();
        let bar = crate::progress::bar("denoising");
        let fitted = self.session.generate(req, &self.opts, self.fit, bar).map_err(|e| {
            anyhow::anyhow!(
                "{e}; lower --kf-guidance ({}) or --transition-guidance ({})",
                a.kf_guidance,
                a.transition_guidance
            )
        })?;
        Ok((fitted, t0.elapsed().as_secs_f64()))
    }
}

/// One keyed sample prepared from `sample`'s flags as `sample` prepares it (keys read, model and
/// prompt loaded), to be generated again and again: `bench`'s `sample` case.
pub(crate) struct Prepared {
    job: Job,
    req: Request,
    args: SampleArgs,
    /// The motion's frames and keyed frames.
    pub frames: usize,
    pub keys: usize,
}

impl Prepared {
    /// `argv`: `sample`'s flags, the command name first.
    pub(crate) fn new(argv: &[&str]) -> Result<Prepared> {
        use clap::FromArgMatches;
        let m =
            SampleArgs::augment_args(clap::Command::new("sample")).try_get_matches_from(argv)?;
        let args = SampleArgs::from_arg_matches(&m)?;
        check_flags(&args)?;
        let keys = request_keys(&args)?;
        let job = Job::load(&args)?;
        let emb = job.embed(&args.text, "--text")?;
        let req = job.request(&emb, keys.length, 1, &[(&keys.values, &keys.mask, &keys.root)]);
        Ok(Prepared { job, req, args, frames: keys.length, keys: keys.frames.len() })
    }

    /// The sample, fitted and checked, as `sample` generates it.
    pub(crate) fn generate(&self) -> Result<Vec<Fitted>> {
        Ok(self.job.generate(&self.req, &self.args)?.0)
    }
}
