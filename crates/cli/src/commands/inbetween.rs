//! `diffkfc eval inbetween`: the in-betweening benchmark on a HumanML3D-format folder (keys
//! every G seconds or at a rate, one sample per clip, beside interpolation of the same keys).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use diffkfc_data::dataset::{read_captions, Dataset};
use diffkfc_data::io::ownership::{self, Output};
use diffkfc_data::io::{motion_file, npy};
use diffkfc_data::motion::representation::{joints_to_f32, Joints};
use diffkfc_eval::inbetween::{interpolate, table, Bench, ClipScores, Gap, SourceClip};
use diffkfc_model::sampling::guidance;
use diffkfc_model::sampling::sampler::{self, Options};
use diffkfc_model::sampling::session::Session;
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::{FitArgs, SamplerArg};

pub const AFTER_HELP: &str = "\
Examples:
  diffkfc eval inbetween --checkpoint models/mid-synth --data work/synth --clips 64 --out work/inbetween-synth
  python3 scripts/devset.py work/devset && diffkfc eval inbetween --checkpoint models/mid-synth --data work/devset --out work/inbetween-dev

Each clip (its first 196 frames at most) is keyed at every --gaps entry: a key every G seconds
from frame 0 and the last frame, or N% of the frames evenly spaced with both ends (keys observe
the whole pose, its place and heading). One sample per clip and gap (seed + clip index), by the
network alone (no fit, no feet) and by the pipeline (the fit flags below; the default pipeline
unless changed). Scored on the frames between keys, on global joint positions in metres:
  error: mean L2 joint error; root-rel.: the same with each frame's pelvis subtracted;
  key places: mean ground distance of the root from the clip's at the keys;
  skating, planted share (a toe within 5 cm of the floor and under 0.15 m/s), K-TranS: beside
  the clip's own. Interpolation: the clip's joints linearly interpolated between the keys.
Writes <out>/report.json (every clip's scores) and <out>/report.md (the table).";

#[derive(Args)]
pub struct InbetweenArgs {
    /// Model or run directory (EMA weights when present).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Dataset root (HumanML3D layout; `scripts/devset.py` makes the real dev set).
    #[arg(long)]
    data: PathBuf,
    /// Split whose clips are keyed.
    #[arg(long, default_value = "test")]
    split: String,
    /// At most this many clips of the split (in its order).
    #[arg(long, default_value_t = 1000)]
    clips: usize,
    /// Key spacings: seconds between keys, or a share of the frames (5%).
    #[arg(long, default_value = "0.5,1,2,5%")]
    gaps: String,
    #[arg(long, value_enum, default_value_t = SamplerArg::DEFAULT)]
    sampler: SamplerArg,
    #[arg(long, default_value_t = sampler::DEFAULT_STEPS)]
    steps: usize,
    #[command(flatten)]
    fit: FitArgs,
    /// Seed of the first clip (clip i uses seed + i).
    #[arg(long, default_value_t = 11)]
    seed: u64,
    /// Also write every clip's motions (clip, interpolation, network, pipeline joints per gap)
    /// under `<out>/motions`, for `diffkfc render`.
    #[arg(long)]
    save_motions: bool,
    #[arg(long, default_value = "out/inbetween")]
    out: PathBuf,
    /// Write into an --out folder that holds other files.
    #[arg(long)]
    force: bool,
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

fn parse_gaps(spec: &str) -> Result<Vec<Gap>> {
    let gaps: Vec<Gap> = spec
        .split(',')
        .filter(|p| !p.trim().is_empty())
        .map(|p| p.parse().map_err(|e| anyhow::anyhow!("--gaps: {e}")))
        .collect::<Result<_>>()?;
    if gaps.is_empty() {
        bail!("--gaps: '{spec}' lists no gap (e.g. 0.5,1,2,5%)");
    }
    Ok(gaps)
}

/// The split's clips with their first captions, cut to `max_frames`; clips under a second are
/// left out (too short to key at a gap).
fn read_clips(
    ds: &Dataset,
    a: &InbetweenArgs,
    max_frames: usize,
) -> Result<(Vec<SourceClip>, usize)> {
    let ids = ds.split_ids(&a.split)?;
    let (d, min) = (ds.dim(), ds.skeleton.fps.ceil() as usize);
    let (mut clips, mut short) = (Vec::new(), 0);
    for id in ids.into_iter().take(a.clips) {
        let path = ds.motion_path(&id);
        let feats = motion_file::load_features(&path, ds.skeleton, 1).context("--data")?.data;
        let frames = (feats.len() / d).min(max_frames);
        if frames < min {
            short += 1;
            continue;
        }
        let caption = read_captions(&ds.text_path(&id))?.remove(0).text;
        clips.push(SourceClip { id, caption, features: feats[..frames * d].to_vec() });
    }
    if clips.is_empty() {
        bail!(
            "--data: split '{}' of {} has no clip of at least {min} frames",
            a.split,
            ds.root.display()
        );
    }
    Ok((clips, short))
}

pub fn run(a: InbetweenArgs) -> Result<()> {
    let gaps = parse_gaps(&a.gaps)?;
    a.fit.check()?;
    if a.clips == 0 {
        bail!("--clips: must be at least 1");
    }
    let owned = ownership::check(&a.out, Output::Report, a.force, "--out")?;
    let ds = Dataset::open(&a.data)?;
    let session = Session::load(&a.checkpoint, &crate::device::parse(&a.device)?, ds.skeleton)?;
    let loaded = &session.loaded;
    if ds.dim() != loaded.cfg.model.feat_dim {
        bail!(
            "--data: {} has {}-d features, {} reads {}",
            a.data.display(),
            ds.dim(),
            a.checkpoint.display(),
            loaded.cfg.model.feat_dim
        );
    }
    let (clips, short) = read_clips(&ds, &a, loaded.cfg.model.max_frames)?;
    let opts = Options {
        sampler: a.sampler.sampler(a.steps),
        text_guidance: guidance::text_guidance("--text-guidance", None, &loaded.cfg)?,
        ..Options::default()
    };
    let bench = Bench { gen: loaded.generator(ds.skeleton), opts, fit: a.fit.fit(), gaps };
    let pb = ProgressBar::new((clips.len() * bench.steps_per_clip()) as u64).with_style(
        ProgressStyle::with_template(
            "in-betweening [{bar:30}] {pos}/{len} steps {elapsed} ETA {eta}",
        )
        .expect("template")
        .progress_chars("=> "),
    );
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("--out: creating {}", a.out.display()))?;
    if owned {
        Output::Report.mark(&a.out)?;
    }
    let t0 = std::time::Instant::now();
    let mut results = Vec::new();
    for (i, clip) in clips.iter().enumerate() {
        let emb = session.embed(&clip.caption)?;
        let (scores, motions) = bench.run_clip(clip, &emb, a.seed + i as u64, || pb.inc(1));
        if a.save_motions {
            save_motions(&a.out.join("motions"), clip, &scores, &motions, ds.skeleton)?;
        }
        results.push(scores);
    }
    pb.finish_and_clear();
    write_report(&a, &bench, &results, short, t0.elapsed().as_secs_f64())
}

/// Every gap's four motions of one clip as joints .npy: `<id>_<gap>_<method>.npy`.
fn save_motions(
    dir: &std::path::Path,
    clip: &SourceClip,
    scores: &ClipScores,
    motions: &[(Joints, Joints)],
    skel: &diffkfc_data::Skeleton,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let truth = diffkfc_data::motion::representation::recover_from_ric_f32(skel, &clip.features);
    for (g, (net, pipe)) in scores.gaps.iter().zip(motions) {
        let tag = g.gap.replace(' ', "").replace('%', "pct");
        let interp = interpolate(&truth, &g.keys);
        for (name, j) in
            [("clip", &truth), ("interpolation", &interp), ("network", net), ("pipeline", pipe)]
        {
            let p = dir.join(format!("{}_{tag}_{name}.npy", clip.id));
            npy::write(&p, &[j.len(), skel.num_joints(), 3], &joints_to_f32(j))?;
        }
    }
    Ok(())
}

fn write_report(
    a: &InbetweenArgs,
    bench: &Bench,
    results: &[ClipScores],
    short: usize,
    secs: f64,
) -> Result<()> {
    let summary = table::summarise(results);
    let fit = bench.fit;
    let header = format!(
        "In-betweening: `{}` on split `{}` of `{}`, {} clip(s){}; {:?}, pipeline fit {:?}, foot lock {}, feet {:?}; seed {}; {secs:.0} s.",
        a.checkpoint.display(),
        a.split,
        a.data.display(),
        results.len(),
        if short > 0 { format!(" ({short} under a second left out)") } else { String::new() },
        bench.opts.sampler,
        fit.keyframes,
        if fit.foot_lock { "on" } else { "off" },
        fit.feet,
        a.seed,
    );
    let md = format!("{header}\n\n{}", table::to_markdown(&summary));
    let json = serde_json::json!({
        "checkpoint": a.checkpoint.display().to_string(), "data": a.data.display().to_string(),
        "split": a.split, "seed": a.seed, "seconds": secs, "sampler": format!("{:?}", bench.opts.sampler),
        "keyframe_fit": format!("{:?}", fit.keyframes), "foot_lock": fit.foot_lock, "feet": format!("{:?}", fit.feet),
        "short_clips_left_out": short, "summary": summary, "clips": results,
    });
    super::report_files::write(&a.out, &json, &md)
}
