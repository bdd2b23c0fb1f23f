//! `diffkfc data ...`: motion-file conversions (and, later, dataset tools).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use diffkfc_data::motion_file::{load_features, load_joints};
use diffkfc_data::representation::{self as rep, FOOT_CONTACT_THRESHOLD};
use diffkfc_data::rig::{self, ImportOptions};
use diffkfc_data::{npy, Skeleton};

#[derive(Args)]
pub struct DataArgs {
    #[command(subcommand)]
    command: DataCommand,
}

#[derive(Subcommand)]
enum DataCommand {
    /// Joint positions (T,22,3) -- or SMPL-H (T,52,3), first 22 joints used -- to HumanML3D
    /// features (T-1,263), exactly as HumanML3D's `process_file`.
    #[command(after_help = "Examples:\n  diffkfc data features 000021.npy -o 000021_features.npy\n  diffkfc data features amass_clip.npy --fps 120 --up z -o clip.npy")]
    Features(FeaturesArgs),
    /// Validate a HumanML3D / KIT-ML dataset directory and print its statistics. Lists every
    /// problem (file and problem, one per line) and exits non-zero if there is any.
    #[command(after_help = "Examples:\n  diffkfc data check ~/data/HumanML3D\n  diffkfc data check ~/data/HumanML3D --json > check.json")]
    Check(CheckArgs),
    /// Write a synthetic text-motion dataset in the HumanML3D layout (the default data).
    #[command(after_help = "Examples:\n  diffkfc data synth --out work/synth\n  diffkfc data synth --out work/small --clips 200 --seed 7")]
    Synth(SynthArgs),
    /// Benchmark the data loader: cache build/open time, items per second, resident memory.
    /// Prints one JSON line.
    #[command(after_help = "Example:\n  diffkfc data bench-loader work/synth --batches 200 --batch-size 64")]
    BenchLoader(BenchLoaderArgs),
    /// HumanML3D features (T,263) to global joint positions (T,22,3) (`recover_from_ric`), or
    /// a BVH's joints (metres, Y up, 20 fps).
    #[command(after_help = "Examples:\n  diffkfc data joints new_joint_vecs/012314.npy -o 012314_joints.npy\n  diffkfc data joints walk.bvh --bvh-units cm -o walk_joints.npy")]
    Joints(JointsArgs),
    /// Any motion (features, joints, a BVH of another rig) to a BVH on our rig: T-pose rest,
    /// common joint names, Y up, centimetres. Prints how far its joints are from the input's.
    #[command(after_help = "Examples:\n  diffkfc data bvh new_joints/012314.npy -o 012314.bvh\n  diffkfc data bvh mixamo_walk.bvh -o walk.bvh")]
    Bvh(BvhArgs),
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
enum Up {
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
    up: Up,
    /// Foot-contact threshold (squared displacement per frame).
    #[arg(long, default_value_t = FOOT_CONTACT_THRESHOLD)]
    feet_threshold: f64,
    #[arg(long, value_enum, default_value = "t2m")]
    skeleton: SkeletonArg,
}

#[derive(Args)]
struct SynthArgs {
    /// Output directory (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// Number of clips.
    #[arg(long, default_value_t = 3000)]
    clips: usize,
    /// Random seed: the same seed and clip count give the same bytes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
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
    /// Output BVH: T-pose rig with the common joint names (Hips, LeftUpLeg, ...), Y up,
    /// centimetres, the skeleton's frame rate.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, value_enum, default_value = "t2m")]
    skeleton: SkeletonArg,
    #[command(flatten)]
    bvh: BvhInputArgs,
}

fn is_bvh(path: &std::path::Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("bvh"))
}

/// How a BVH input is read: its joint names, units and up axis.
#[derive(Args, Clone, Debug, Default)]
pub struct BvhInputArgs {
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
    pub fn options(&self) -> Result<ImportOptions> {
        let metres_per_unit = match self.bvh_units.as_str() {
            "auto" => None,
            u => Some(rig::UNITS.iter().find(|(n, _)| *n == u).map(|x| x.1).with_context(|| format!("--bvh-units: '{u}' is not one of auto, m, cm, mm, in"))?),
        };
        let up = match self.bvh_up.as_str() {
            "auto" => None,
            u => Some(rig::Up::parse(u).with_context(|| format!("--bvh-up: '{u}' is not one of auto, y, z, -y, -z, x, -x"))?),
        };
        let mut rig_map = Vec::new();
        if let Some(p) = &self.rig_map {
            let text = std::fs::read_to_string(p).with_context(|| format!("--rig-map: reading {}", p.display()))?;
            let v: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("--rig-map: {} is not JSON", p.display()))?;
            let obj = v.as_object().with_context(|| format!("--rig-map: {} must hold a JSON object from our joint names to the file's", p.display()))?;
            for (k, v) in obj {
                let name = v.as_str().with_context(|| format!("--rig-map: {}: \"{k}\" maps to {v}; must be a joint name (a string)", p.display()))?;
                rig_map.push((k.clone(), name.to_string()));
            }
        }
        Ok(ImportOptions { metres_per_unit, up, rig_map })
    }
}

fn read_bvh(path: &std::path::Path, skel: &Skeleton, bvh: &ImportOptions) -> Result<rep::Joints> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let j = rig::read(skel, &text, bvh).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if j.len() < MIN_MOTION_FRAMES {
        anyhow::bail!("{}: has {} frame(s); at least {MIN_MOTION_FRAMES} needed", path.display(), j.len());
    }
    Ok(j)
}

/// A motion has at least two frames (one pose has no velocity, no path, nothing to animate).
pub const MIN_MOTION_FRAMES: usize = 2;

/// Joint positions from a motion file: features (T, D) are recovered, joints (T, J, 3) taken
/// as they are, a BVH read through the rig import.
pub fn load_motion(path: &std::path::Path, skel: &Skeleton, bvh: &ImportOptions) -> Result<rep::Joints> {
    if is_bvh(path) {
        return read_bvh(path, skel, bvh);
    }
    let a = npy::read_f64(path)?;
    if a.ndim() == 2 {
        let f = load_features(path, skel, MIN_MOTION_FRAMES)?;
        Ok(rep::recover_from_ric(skel, &f.data.iter().map(|&v| v as f64).collect::<Vec<_>>()))
    } else {
        Ok(load_joints(path, skel, MIN_MOTION_FRAMES)?)
    }
}

/// Features (T, D) of a motion file: features as they are, joints or BVH through
/// `process_file` (one frame fewer).
pub fn load_motion_features(path: &std::path::Path, skel: &Skeleton, bvh: &ImportOptions) -> Result<Vec<f32>> {
    let joints = if is_bvh(path) {
        read_bvh(path, skel, bvh)?
    } else if npy::read_f64(path)?.ndim() == 2 {
        return Ok(load_features(path, skel, MIN_MOTION_FRAMES)?.data);
    } else {
        load_joints(path, skel, 2)?
    };
    Ok(rep::features_from_joints(skel, &joints, FOOT_CONTACT_THRESHOLD).map_err(|e| e.in_file(path))?)
}

pub fn run(args: DataArgs) -> Result<()> {
    match args.command {
        DataCommand::Features(a) => features(a),
        DataCommand::Joints(a) => joints(a),
        DataCommand::Bvh(a) => bvh(a),
        DataCommand::Check(a) => check(a),
        DataCommand::Synth(a) => synth(a),
        DataCommand::BenchLoader(a) => bench_loader(a),
    }
}

/// Resident memory of this process in MiB (Linux): (total, anonymous). Memory-mapped cache
/// pages count in the total but are clean file pages the kernel can drop; the anonymous part is
/// what the process itself holds.
pub fn rss_mib() -> (f64, f64) {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| -> f64 { s.lines().find(|l| l.starts_with(name)).and_then(|l| l.split_whitespace().nth(1)).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0) / 1024.0 };
    (field("VmRSS:"), field("RssAnon:"))
}

fn bench_loader(a: BenchLoaderArgs) -> Result<()> {
    println!("{}", loader_case(&a)?);
    Ok(())
}

/// Packed-cache loading throughput (also a case of `diffkfc bench`).
pub fn loader_case(a: &BenchLoaderArgs) -> Result<serde_json::Value> {
    use diffkfc_data::batch::{KeyframeConfig, Loader};
    use diffkfc_data::cache::{default_cache_dir, PackedSplit};
    if a.batch_size == 0 || a.batches == 0 {
        bail!("--batch-size and --batches: must be at least 1 (got {} and {})", a.batch_size, a.batches);
    }
    let ds = diffkfc_data::dataset::Dataset::open(&a.dir)?;
    let rss0 = rss_mib();
    let t0 = std::time::Instant::now();
    let split = PackedSplit::open(&ds, &a.split, &default_cache_dir(&ds), crate::progress::bar("caching"))?;
    let open_s = t0.elapsed().as_secs_f64();
    if split.items.is_empty() {
        bail!("{}: split '{}' has no usable items", a.dir.display(), a.split);
    }
    let mut loader = Loader::new(&ds, &split, a.batch_size, 0, KeyframeConfig::default());
    loader.threads = a.threads;
    let per_epoch = loader.batches_per_epoch();
    let t1 = std::time::Instant::now();
    let (mut peak, mut peak_anon) = rss0;
    let mut checksum = 0.0f64;
    for b in 0..a.batches {
        let batch = loader.batch((b / per_epoch) as u64, b % per_epoch);
        checksum += batch.x0[0] as f64;
        if b % 10 == 0 {
            let (r, an) = rss_mib();
            peak = peak.max(r);
            peak_anon = peak_anon.max(an);
        }
    }
    let secs = t1.elapsed().as_secs_f64();
    let line = serde_json::json!({
        "case": "loader",
        "split": a.split,
        "frames_in_split": split.total_frames(),
        "cache_bytes": split.total_frames() * ds.dim() * 4,
        "cache_built": split.built,
        "open_s": open_s,
        "batches": a.batches,
        "batch_size": a.batch_size,
        "threads": a.threads,
        "items_per_s": (a.batches * a.batch_size) as f64 / secs,
        "ms_per_batch": secs * 1000.0 / a.batches as f64,
        "rss_mib_before": rss0.0,
        "rss_mib_peak": peak,
        "rss_anon_mib_before": rss0.1,
        "rss_anon_mib_peak": peak_anon,
        "checksum": checksum,
    });
    Ok(line)
}

fn synth(a: SynthArgs) -> Result<()> {
    if a.clips == 0 {
        bail!("--clips: must be at least 1");
    }
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let bar = std::sync::Mutex::new(crate::progress::bar("synthesising"));
    let t0 = std::time::Instant::now();
    let s = diffkfc_data::synth::write_dataset(&a.out, a.clips, a.seed, threads, &|d, n| (bar.lock().unwrap())(d, n))?;
    println!("{}: {} clips, {} frames ({:.2} h at 20 fps), seed {}, in {:.1} s", s.out.display(), s.clips, s.frames, s.frames as f64 / 20.0 / 3600.0, a.seed, t0.elapsed().as_secs_f64());
    Ok(())
}

fn check(a: CheckArgs) -> Result<()> {
    let report = diffkfc_data::check::check(&a.dir, crate::progress::bar("checking"));
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
    if !(a.feet_threshold.is_finite() && a.feet_threshold > 0.0) {
        bail!("--feet-threshold: {} must be a positive number (squared metres per frame; HumanML3D: 0.002)", a.feet_threshold);
    }
    let skel = a.skeleton.skeleton();
    let mut joints = load_joints(&a.input, skel, 2)?;
    let frames_in = joints.len();
    if a.up == Up::Z {
        rep::z_up_to_y_up(&mut joints);
    }
    if let Some(fps) = a.fps {
        // Checked before resampling allocates frames_in * 20 / fps frames.
        if !(fps.is_finite() && (1.0..=1000.0).contains(&fps)) {
            bail!("--fps: {fps} must be a frame rate from 1 to 1000");
        }
        joints = rep::resample(&joints, fps, skel.fps);
        if joints.len() < 2 {
            bail!("{}: only {} frame(s) after resampling from {fps} to {} fps", a.input.display(), joints.len(), skel.fps);
        }
    }
    let feats = rep::features_from_joints(skel, &joints, a.feet_threshold).map_err(|e| e.in_file(&a.input))?;
    let dim = skel.feature_dim();
    let t = feats.len() / dim;
    npy::write(&a.output, &[t, dim], &feats).with_context(|| format!("writing {}", a.output.display()))?;
    println!("{}: ({t}, {dim}) features from {frames_in} input frames ({} at {} fps)", a.output.display(), joints.len(), skel.fps);
    Ok(())
}

fn joints(a: JointsArgs) -> Result<()> {
    let skel = a.skeleton.skeleton();
    let joints = if is_bvh(&a.input) {
        read_bvh(&a.input, skel, &a.bvh.options()?)?
    } else {
        let feats = load_features(&a.input, skel, MIN_MOTION_FRAMES)?;
        rep::recover_from_ric(skel, &feats.data.iter().map(|&v| v as f64).collect::<Vec<_>>())
    };
    let jn = skel.num_joints();
    npy::write(&a.output, &[joints.len(), jn, 3], &rep::joints_to_f32(&joints)).with_context(|| format!("writing {}", a.output.display()))?;
    println!("{}: ({}, {jn}, 3) joint positions", a.output.display(), joints.len());
    Ok(())
}

fn bvh(a: BvhArgs) -> Result<()> {
    let skel = a.skeleton.skeleton();
    let joints = load_motion(&a.input, skel, &a.bvh.options()?)?;
    let b = rig::export(skel, &joints);
    diffkfc_data::write_atomic(&a.output, b.to_text().as_bytes())?;
    let (mean, max) = rig::export_error(skel, &joints, &b);
    println!("{}: {} frames at {} fps; joints within {:.2} mm of the input on average, {:.2} mm at most", a.output.display(), joints.len(), skel.fps, mean * 1e3, max * 1e3);
    Ok(())
}
