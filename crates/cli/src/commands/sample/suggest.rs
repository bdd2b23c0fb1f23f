//! `diffkfc keyframes suggest`: KeyMotion's two stages for an animator. A motion is generated
//! from the text alone (or read with --from), its most telling poses are picked, and written as
//! a keyframe file that `sample --keyframes` reads: edit a few, then in-fill.

use clap::{FromArgMatches, Subcommand};
use diffkfc_data::io::keyframe_file::KeySpec;
use diffkfc_data::io::motion_file::load_motion_features;

use super::*;

#[derive(Args)]
pub struct KeyframesArgs {
    #[command(subcommand)]
    command: KeyframesCommand,
}

#[derive(Subcommand)]
enum KeyframesCommand {
    /// Suggest keyframes: generate a motion from the text alone (or take --from), pick its most
    /// distinct poses, and write them (pose, place, heading) as a `sample --keyframes` file.
    #[command(
        after_help = "Examples:\n  diffkfc keyframes suggest --checkpoint models/mid-synth --text \"a person jumps forward.\" --count 4 -o keys.json\n  diffkfc sample --checkpoint models/mid-synth --text \"a person jumps forward.\" --keyframes keys.json --out out/jump\n  diffkfc keyframes suggest --from work/synth/new_joint_vecs/000001.npy --count 5 --strategy uniform -o keys.json"
    )]
    Suggest(SuggestArgs),
}

#[derive(Args)]
struct SuggestArgs {
    /// Model directory or training run (as `sample --checkpoint`); needed unless --from.
    #[arg(long, required_unless_present = "from")]
    checkpoint: Option<PathBuf>,
    /// The prompt of the motion whose poses are suggested.
    #[arg(long, required_unless_present = "from")]
    text: Option<String>,
    /// Take the keyframes from this motion instead of generating one: features (T,263),
    /// joints (T,22,3) or a BVH.
    #[arg(long, conflicts_with_all = ["checkpoint", "text"])]
    from: Option<PathBuf>,
    /// Frames of the generated motion (1 to 196).
    #[arg(long, default_value_t = 120)]
    length: usize,
    /// How many keyframes (default 5).
    #[arg(long, conflicts_with = "rate")]
    count: Option<usize>,
    /// Or this fraction of the frames.
    #[arg(long)]
    rate: Option<f64>,
    /// How frames are chosen: mdo (KeyMotion's maximum-distance-optimal: the most distinct
    /// poses), uniform (evenly spaced) or random.
    #[arg(long, default_value = "mdo", value_name = "mdo|uniform|random")]
    strategy: String,
    /// Random seed of the generated motion (and of the random strategy).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Sampler steps of the generated motion (the sample command's default sampler).
    #[arg(long, default_value_t = diffkfc_model::sampling::sampler::DEFAULT_STEPS)]
    steps: usize,
    /// Output keyframe file (the JSON `sample --keyframes` reads).
    #[arg(short, long, default_value = "keys.json")]
    out: PathBuf,
    #[command(flatten)]
    bvh: BvhInputArgs,
}

pub fn run(a: KeyframesArgs) -> Result<()> {
    match a.command {
        KeyframesCommand::Suggest(s) => suggest(s),
    }
}

/// The motion to key and its description: the --from file's, or one generated from --text by
/// --checkpoint with the sampler's own flags and defaults, as `sample` would take them.
fn source_motion(a: &SuggestArgs) -> Result<(Vec<f32>, String)> {
    Ok(match (&a.from, &a.checkpoint, &a.text) {
        (Some(p), _, _) => {
            (load_motion_features(p, &T2M, &a.bvh.options()?)?, p.display().to_string())
        }
        (None, Some(ck), Some(text)) => {
            let argv = [
                "sample",
                "--checkpoint",
                &ck.to_string_lossy(),
                "--text",
                text,
                "--length",
                &a.length.to_string(),
                "--seed",
                &a.seed.to_string(),
                "--steps",
                &a.steps.to_string(),
            ];
            let m = SampleArgs::augment_args(clap::Command::new("sample"))
                .try_get_matches_from(argv)
                .map_err(|e| anyhow::anyhow!("{}", e.to_string().lines().next().unwrap_or("")))?;
            let s = SampleArgs::from_arg_matches(&m)?;
            (
                text_only_motion(&s)?,
                format!("generated from \"{text}\" by {} (seed {})", ck.display(), a.seed),
            )
        }
        _ => bail!("keyframes suggest: needs --checkpoint and --text, or --from"),
    })
}

fn suggest(a: SuggestArgs) -> Result<()> {
    let strategy: Strategy = a
        .strategy
        .parse()
        .map_err(|e: diffkfc_data::UnknownChoice| anyhow::anyhow!("--strategy: {e}"))?;
    let d = T2M.feature_dim();
    let (feats, source) = source_motion(&a)?;
    let n = feats.len() / d;
    let rate = match (a.count, a.rate) {
        (_, Some(r)) if !(r > 0.0 && r <= 1.0) => bail!("--rate: {r} must be in (0, 1]"),
        (_, Some(r)) => r,
        (Some(0), _) => bail!("--count: must be at least 1"),
        (Some(c), _) if c > n => bail!("--count: {c} keyframes but the motion has {n} frames"),
        (c, None) => c.unwrap_or(5).min(n) as f64 / n as f64,
    };
    let frames = keyframes::select(strategy, n, rate, &feats, d, &mut Rng::new(a.seed));
    let joints = rep::recover_from_ric_f32(&T2M, &feats);
    let traj = root_key::root_trajectory(&feats, d);
    let keys = KeySpec::from_motion(&joints, &traj, &frames);
    let doc = json!({"length": n, "source": source, "strategy": a.strategy, "keyframes": keys});
    diffkfc_data::write_atomic(&a.out, serde_json::to_string_pretty(&doc)?.as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "{}: {} keyframes at frames {:?} of {n} ({}; {})",
        a.out.display(),
        frames.len(),
        frames,
        a.strategy,
        source
    );
    Ok(())
}
