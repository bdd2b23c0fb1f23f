//! `diffkfc data ...`: motion-file conversions (and, later, dataset tools).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use diffkfc_data::io::motion_file::{
    is_bvh, load_bvh, load_feature_joints, load_joints, load_motion,
};
use diffkfc_data::motion::representation::{self as rep, FOOT_CONTACT_THRESHOLD};

use crate::args::{refuse_overwriting_input, BvhInputArgs};
use diffkfc_data::{dataset::loader_bench, io::rig};
use diffkfc_data::{io::npy, Skeleton};
use diffkfc_synth::variation::MAX_STRENGTH;
use diffkfc_synth::{Body, SynthSpec};

#[derive(Args)]
pub struct DataArgs {
    #[command(subcommand)]
    command: DataCommand,
}

#[derive(Subcommand)]
enum DataCommand {
    /// Joint positions (T,22,3) -- or SMPL-H (T,52,3), first 22 joints used -- to HumanML3D
    /// features (T-1,263), exactly as HumanML3D's `process_file`.
    #[command(
        after_help = "Examples:\n  diffkfc data features 000021.npy -o 000021_features.npy\n  diffkfc data features amass_clip.npy --fps 120 --up z -o clip.npy"
    )]
    Features(FeaturesArgs),
    /// Validate a HumanML3D / KIT-ML dataset directory and print its statistics. Lists every
    /// problem (file and problem, one per line) and exits non-zero if there is any.
    #[command(
        after_help = "Examples:\n  diffkfc data check ~/data/HumanML3D\n  diffkfc data check ~/data/HumanML3D --json > check.json"
    )]
    Check(CheckArgs),
    /// Write a synthetic text-motion dataset in the HumanML3D layout (the default data).
    #[command(
        after_help = "Examples:\n  diffkfc data synth --out work/synth\n  diffkfc data synth --out work/small --clips 200 --seed 7"
    )]
    Synth(SynthArgs),
    /// Benchmark the data loader: cache build/open time, items per second, resident memory.
    /// Prints one JSON line.
    #[command(
        after_help = "Example:\n  diffkfc data bench-loader work/synth --batches 200 --batch-size 64"
    )]
    BenchLoader(BenchLoaderArgs),
    /// HumanML3D features (T,263) to global joint positions (T,22,3) (`recover_from_ric`), or
    /// a BVH's joints (metres, Y up, 20 fps).
    #[command(
        after_help = "Examples:\n  diffkfc data joints new_joint_vecs/012314.npy -o 012314_joints.npy\n  diffkfc data joints walk.bvh --bvh-units cm -o walk_joints.npy"
    )]
    Joints(JointsArgs),
    /// Any motion (features, joints, a BVH of another rig) to a BVH on our rig: T-pose rest,
    /// common joint names, Y up, centimetres. Prints how far its joints are from the input's.
    #[command(
        after_help = "Examples:\n  diffkfc data bvh new_joints/012314.npy -o 012314.bvh\n  diffkfc data bvh mixamo_walk.bvh -o walk.bvh"
    )]
    Bvh(BvhArgs),
    /// Any motion to glTF 2.0 binary (.glb): our rig as a skin with one animation (metres, Y
    /// up) and a simple body, for Blender, game engines and web viewers.
    #[command(
        after_help = "Examples:\n  diffkfc data gltf out/walk/sample_00_joints.npy -o walk.glb\n  diffkfc data gltf mixamo_walk.bvh -o walk.glb"
    )]
    Gltf(BvhArgs),
    /// Ids of a synthetic set's clips (its manifest.json) by split, actions, pattern and
    /// length, one per line in the manifest's order; exits non-zero when none matches.
    #[command(
        after_help = "Examples:\n  diffkfc data clips work/synth --split test --action walk_forward --action wave --count 1\n  diffkfc data clips work/synth --split test --action walk_forward --min-frames 120 --count 6"
    )]
    Clips(ClipsArgs),
}

#[derive(Args)]
struct ClipsArgs {
    /// Dataset written by `diffkfc data synth` (its manifest.json).
    dir: PathBuf,
    /// Only clips of this split (train, val, test).
    #[arg(long)]
    split: Option<String>,
    /// Clips that contain this action (walk_forward, wave, jump, ...); repeat for several.
    #[arg(long = "action")]
    actions: Vec<String>,
    /// Clips with no action besides the --action ones.
    #[arg(long)]
    only: bool,
    /// Clips of this pattern (single, sequence, simultaneous, ...).
    #[arg(long)]
    pattern: Option<String>,
    /// Clips of at least this many frames.
    #[arg(long, default_value_t = 0)]
    min_frames: usize,
    /// Leave out this clip id; repeat for several.
    #[arg(long)]
    exclude: Vec<String>,
    /// Print at most this many ids.
    #[arg(long)]
    count: Option<usize>,
}

#[derive(Clone, Copy, ValueEnum)]
enum SkeletonArg {
    /// HumanML3D: 22 joints, 263 features, 20 fps, metres.
    T2m,
    /// KIT-ML: 21 joints, 251 features, 12.5 fps, millimetres.
    Kit,
}

impl SkeletonArg {
    fn skeleton(self) -> &'static Skeleton {
        match self {
            SkeletonArg::T2m => &diffkfc_data::T2M,
            SkeletonArg::Kit => &diffkfc_data::KIT,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum InputUp {
    Y,
    /// Z-up input (AMASS / SMPL world), turned to Y-up as HumanML3D does: (x,y,z) -> (-x,z,y).
    Z,
}

#[derive(Args)]
struct FeaturesArgs {
    /// Joint positions .npy, float32 or float64, shape (T, J, 3).
    input: PathBuf,
    /// Output features .npy (float32).
    #[arg(short, long)]
    output: PathBuf,
    /// Frame rate of the input; it is resampled (linear interpolation) to the skeleton's rate.
    #[arg(long)]
    fps: Option<f64>,
    /// Up axis of the input.
    #[arg(long, value_enum, default_value = "y")]
    up: InputUp,
    /// Foot-contact threshold (squared displacement per frame).
    #[arg(long, default_value_t = FOOT_CONTACT_THRESHOLD)]
    feet_threshold: f64,
    #[arg(long, value_enum, default_value = "t2m")]
    skeleton: SkeletonArg,
    /// Joint positions .npy whose first frame's bone lengths the motion is retargeted to (how
    /// HumanML3D's processing makes every clip one skeleton: 000021 for HumanML3D, 03950 for
    /// KIT-ML). Default: HumanML3D's built-in lengths; required for --skeleton kit.
    #[arg(long, value_name = "FILE")]
    target_skeleton: Option<PathBuf>,
}

#[derive(Args)]
struct SynthArgs {
    /// Output directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Number of clips.
    #[arg(long, default_value_t = 3000)]
    clips: usize,
    /// Random seed: the same seed, clip count and body give the same bytes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Skeleton the motions are drawn on: `humanml3d` (HumanML3D's bone directions: hips lower
    /// and closer, collars up; what real keys have, and the reference model's set) or `legacy`
    /// (the hand-set body of `models/tiny-synth`'s set and the sets before).
    #[arg(long, default_value = "humanml3d")]
    body: Body,
    /// Variation beyond the actions' own parameters, 0 to 2: at 1 each clip's pace changes
    /// across it (0.75-1.33x on average, a slow ±35% wave) and its posture drifts (spine,
    /// head, arms, pelvis height), so that text alone cannot tell how it moves between keys.
    /// 0 (the default) is the reference model's set.
    #[arg(long, default_value_t = 0.0)]
    vary: f64,
    /// Worker threads (default: all cores). The output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Args)]
pub struct BenchLoaderArgs {
    /// Dataset root (HumanML3D layout).
    pub dir: PathBuf,
    /// Split to load.
    #[arg(long, default_value = "train")]
    pub split: String,
    /// Batches to time.
    #[arg(long, default_value_t = 200)]
    pub batches: usize,
    /// Items per batch.
    #[arg(long, default_value_t = 64)]
    pub batch_size: usize,
    /// Loader worker threads.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
}

#[derive(Args)]
struct CheckArgs {
    /// Dataset root (holding new_joint_vecs/, texts/, Mean.npy, Std.npy, train.txt ...).
    dir: PathBuf,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct JointsArgs {
    /// Features .npy, shape (T, 263) (KIT: 251), or a BVH (any common rig; see --rig-map).
    input: PathBuf,
    /// Output joint positions .npy (float32, (T, J, 3)).
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, value_enum, default_value = "t2m")]
    skeleton: SkeletonArg,
    #[command(flatten)]
    bvh: BvhInputArgs,
}

#[derive(Args)]
struct BvhArgs {
    /// A motion: features (T,263), joints (T,22,3) .npy, or a BVH of any common rig.
    input: PathBuf,
    /// Output file: for `bvh` a T-pose rig with the common joint names (Hips, LeftUpLeg, ...),
    /// Y up, centimetres; for `gltf` the same rig in metres; the skeleton's frame rate.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, value_enum, default_value = "t2m")]
    skeleton: SkeletonArg,
    #[command(flatten)]
    bvh: BvhInputArgs,
}

pub fn run(args: DataArgs) -> Result<()> {
    match args.command {
        DataCommand::Features(a) => features(a),
        DataCommand::Joints(a) => joints(a),
        DataCommand::Bvh(a) => bvh(a),
        DataCommand::Gltf(a) => gltf(a),
        DataCommand::Check(a) => check(a),
        DataCommand::Synth(a) => synth(a),
        DataCommand::BenchLoader(a) => bench_loader(a),
        DataCommand::Clips(a) => clips(a),
    }
}

fn clips(a: ClipsArgs) -> Result<()> {
    use diffkfc_synth::manifest::{find_clips, ClipQuery};
    let q = ClipQuery {
        split: a.split,
        actions: a.actions,
        only: a.only,
        pattern: a.pattern,
        min_frames: a.min_frames,
        exclude: a.exclude,
    };
    let mut ids = find_clips(&a.dir, &q)?;
    ids.truncate(a.count.unwrap_or(usize::MAX));
    if ids.is_empty() {
        bail!("{}: no clip matches {q:?}", a.dir.join("manifest.json").display());
    }
    println!("{}", ids.join("\n"));
    Ok(())
}

fn bench_loader(a: BenchLoaderArgs) -> Result<()> {
    if a.batch_size == 0 || a.batches == 0 {
        bail!(
            "--batch-size and --batches: must be at least 1 (got {} and {})",
            a.batch_size,
            a.batches
        );
    }
    let r = loader_bench::run(
        &a.dir,
        &a.split,
        a.batches,
        a.batch_size,
        a.threads,
        crate::progress::bar("caching"),
    )?;
    println!("{}", r);
    Ok(())
}

fn synth(a: SynthArgs) -> Result<()> {
    if a.clips == 0 || a.clips > diffkfc_synth::MAX_CLIPS {
        bail!(
            "--clips: {} must be 1 to {} (each clip is about 120 KB of files)",
            a.clips,
            diffkfc_synth::MAX_CLIPS
        );
    }
    if a.threads.is_some_and(|t| t == 0 || t > 1024) {
        bail!("--threads: {} must be 1 to 1024", a.threads.unwrap_or(0));
    }
    if !(0.0..=MAX_STRENGTH).contains(&a.vary) {
        bail!("--vary: {} must be 0 to {MAX_STRENGTH}", a.vary);
    }
    let threads = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let bar = std::sync::Mutex::new(crate::progress::bar("synthesising"));
    let t0 = std::time::Instant::now();
    let spec = SynthSpec { clips: a.clips, seed: a.seed, body: a.body, vary: a.vary };
    let s =
        diffkfc_synth::write_dataset(&a.out, &spec, threads, &|d, n| (bar.lock().unwrap())(d, n))?;
    println!(
        "{}: {} clips, {} frames ({:.2} h at 20 fps), seed {}, {} body, in {:.1} s",
        s.out.display(),
        s.clips,
        s.frames,
        s.frames as f64 / 20.0 / 3600.0,
        a.seed,
        a.body.name(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

fn check(a: CheckArgs) -> Result<()> {
    let report = diffkfc_data::dataset::check::check(&a.dir, crate::progress::bar("checking"));
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.to_text());
    }
    if !report.ok() {
        // The list is printed above; the exit status carries the verdict.
        std::process::exit(1);
    }
    Ok(())
}

fn features(a: FeaturesArgs) -> Result<()> {
    refuse_overwriting_input(&[&a.input], &a.output)?;
    if !(a.feet_threshold.is_finite() && a.feet_threshold > 0.0) {
        bail!("--feet-threshold: {} must be a positive number (squared metres per frame; HumanML3D: 0.002)", a.feet_threshold);
    }
    let skel = a.skeleton.skeleton();
    let mut joints = load_joints(&a.input, skel, 2)?;
    let frames_in = joints.len();
    if a.up == InputUp::Z {
        rep::z_up_to_y_up(&mut joints);
    }
    if let Some(fps) = a.fps {
        // Checked before resampling allocates frames_in * 20 / fps frames.
        if !(fps.is_finite() && (1.0..=1000.0).contains(&fps)) {
            bail!("--fps: {fps} must be a frame rate from 1 to 1000");
        }
        joints = rep::resample(&joints, fps, skel.fps);
        if joints.len() < 2 {
            bail!(
                "{}: only {} frame(s) after resampling from {fps} to {} fps",
                a.input.display(),
                joints.len(),
                skel.fps
            );
        }
    }
    let lengths = match &a.target_skeleton {
        Some(p) => Some(rep::bone_lengths(skel, &load_joints(p, skel, 1)?[0])),
        None => None,
    };
    let feats = rep::features_from_joints_to(skel, &joints, a.feet_threshold, lengths.as_deref())
        .map_err(|e| e.in_file(&a.input))?;
    let dim = skel.feature_dim();
    let t = feats.len() / dim;
    npy::write(&a.output, &[t, dim], &feats)
        .with_context(|| format!("writing {}", a.output.display()))?;
    println!(
        "{}: ({t}, {dim}) features from {frames_in} input frames ({} at {} fps)",
        a.output.display(),
        joints.len(),
        skel.fps
    );
    Ok(())
}

fn joints(a: JointsArgs) -> Result<()> {
    refuse_overwriting_input(&[&a.input], &a.output)?;
    let skel = a.skeleton.skeleton();
    let joints = if is_bvh(&a.input) {
        load_bvh(&a.input, skel, &a.bvh.options()?)?
    } else {
        load_feature_joints(&a.input, skel)?
    };
    let jn = skel.num_joints();
    npy::write(&a.output, &[joints.len(), jn, 3], &rep::joints_to_f32(&joints))
        .with_context(|| format!("writing {}", a.output.display()))?;
    println!("{}: ({}, {jn}, 3) joint positions", a.output.display(), joints.len());
    Ok(())
}

fn bvh(a: BvhArgs) -> Result<()> {
    refuse_overwriting_input(&[&a.input], &a.output)?;
    let skel = a.skeleton.skeleton();
    let joints = load_motion(&a.input, skel, &a.bvh.options()?)?;
    let b = rig::export(skel, &joints);
    diffkfc_data::write_atomic(&a.output, b.to_text().as_bytes())?;
    let (mean, max) = rig::export_error(skel, &joints, &b);
    println!(
        "{}: {} frames at {} fps; joints within {:.2} mm of the input on average, {:.2} mm at most",
        a.output.display(),
        joints.len(),
        skel.fps,
        mean * 1e3,
        max * 1e3
    );
    Ok(())
}

fn gltf(a: BvhArgs) -> Result<()> {
    refuse_overwriting_input(&[&a.input], &a.output)?;
    let skel = a.skeleton.skeleton();
    let joints = load_motion(&a.input, skel, &a.bvh.options()?)?;
    diffkfc_data::io::gltf::write(&a.output, skel, &joints)?;
    println!(
        "{}: {} frames at {} fps, {} joints",
        a.output.display(),
        joints.len(),
        skel.fps,
        skel.num_joints()
    );
    Ok(())
}
