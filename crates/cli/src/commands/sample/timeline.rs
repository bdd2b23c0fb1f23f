//! `sample --timeline`: the flags, the windows' progress and the output folder of one long
//! motion from a timeline of prompts (`diffkfc_model::sampling::timeline` generates it; each
//! window after the first repeats the last [`OVERLAP`] frames of the motion so far).

use diffkfc_model::sampling::timeline::plan as tl;
use diffkfc_model::sampling::timeline::{self, joins, TimelineKeys};

use super::*;

/// Frames each window repeats from the motion before it (0.5 s).
pub(super) const OVERLAP: usize = 10;

/// The timeline's segments from `--timeline` (a file's text, or the argument itself).
fn segments_of(spec_arg: &str) -> Result<Vec<tl::Segment>> {
    let spec = if Path::new(spec_arg).is_file() {
        std::fs::read_to_string(spec_arg)
            .with_context(|| format!("--timeline: reading {spec_arg}"))?
    } else {
        spec_arg.to_string()
    };
    tl::parse(&spec, T2M.fps).map_err(|e| anyhow::anyhow!("--timeline: {e}"))
}

/// results.json's timeline record: segments, windows, joins, and K-TranS at the joins beside
/// K-TranS away from them (frames every 10, more than 5 from a join).
fn timeline_record(
    segments: &[tl::Segment],
    windows: &[tl::Window],
    fitted: &[Fitted],
    total: usize,
) -> serde_json::Value {
    let joins = joins(windows);
    let away: Vec<usize> = (5..total.saturating_sub(5))
        .step_by(10)
        .filter(|f| joins.iter().all(|j| f.abs_diff(*j) > 5))
        .collect();
    let k_trans_at = |frames: &[usize]| -> Vec<Option<f64>> {
        fitted
            .iter()
            .map(|f| {
                let feats: Vec<f64> = f.features.iter().map(|&v| v as f64).collect();
                diffkfc_eval::keyframe_metrics::k_trans(
                    &rep::recover_from_ric(&T2M, &feats),
                    frames,
                    2,
                )
            })
            .collect()
    };
    json!({
        "timeline": segments.iter().map(|s| json!({"start": s.start, "end": s.end, "text": s.text})).collect::<Vec<_>>(),
        "windows": windows.iter().map(|w| json!({"segment": w.segment, "start": w.start, "end": w.end, "repeated": w.keyed})).collect::<Vec<_>>(),
        "joins": joins,
        "k_trans_at_joins": k_trans_at(&joins),
        "k_trans_away_from_joins": k_trans_at(&away),
    })
}

pub(super) fn run(a: SampleArgs, spec_arg: &str) -> Result<()> {
    check_flags(&a)?;
    let segments = segments_of(spec_arg)?;
    let total = segments.last().map_or(0, |s| s.end);
    let d = T2M.feature_dim();
    let keys = match &a.keyframes {
        Some(p) => keys_from_json(p, Some(total), a.joints.as_deref())?,
        None => Keys {
            length: total,
            frames: vec![],
            values: vec![0.0; total * d],
            mask: vec![0.0; total * d],
            source: None,
            joints: vec![],
            root: vec![RootKey::default(); total],
        },
    };
    let gen = Job::load(&a)?;
    let window = gen.max_frames().min(diffkfc_data::dataset::MAX_FRAMES);
    if window <= 2 * OVERLAP {
        bail!("--timeline: {} was built for motions of at most {window} frames (model.max_frames); a timeline needs windows longer than {}", a.checkpoint.display(), 2 * OVERLAP);
    }
    let windows = tl::windows(&segments, window, OVERLAP);
    let embs =
        segments.iter().map(|s| gen.embed(&s.text, "--timeline")).collect::<Result<Vec<_>>>()?;
    let tkeys = TimelineKeys {
        frames: &keys.frames,
        values: &keys.values,
        mask: &keys.mask,
        root: &keys.root,
    };
    let mut secs = 0.0;
    let fitted =
        timeline::generate(&gen.pipeline(), &windows, &embs, &tkeys, a.num_samples, |wi, req| {
            let w = &windows[wi];
            eprintln!(
                "window {}/{}: frames {}..{} ({} repeated), \"{}\"",
                wi + 1,
                windows.len(),
                w.start,
                w.end,
                w.keyed,
                segments[w.segment].text
            );
            let (fitted, s) = gen.generate(req, &a)?;
            secs += s;
            Ok::<_, anyhow::Error>(fitted)
        })?;
    let extra = timeline_record(&segments, &windows, &fitted, total);
    let marks: Vec<(usize, String)> = segments.iter().map(|s| (s.start, s.text.clone())).collect();
    let mut a = a;
    a.text = segments
        .iter()
        .map(|s| {
            format!("{:.2}-{:.2}s: {}", s.start as f64 / T2M.fps, s.end as f64 / T2M.fps, s.text)
        })
        .collect::<Vec<_>>()
        .join(" | ");
    write_outputs(&a, &gen, Outputs { keys: &keys, fitted, secs, extra, segments: &marks })
}
