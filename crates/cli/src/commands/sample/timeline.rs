//! `sample --timeline`: one long motion from a timeline of prompts, window after window
//! (`diffkfc_data::keyframes::timeline` plans the windows). Each window after the first is given the last
//! [`OVERLAP`] frames of the motion so far as keyframes (every feature, place and heading, in
//! the window's own frame), and its frames from the last repeated one on replace the motion's.

use diffkfc_data::keyframes::timeline::{self as tl, Window};
use diffkfc_data::postprocess::footlock::LockReport;

use super::*;

/// Frames each window repeats from the motion before it (0.5 s).
pub(super) const OVERLAP: usize = 10;

/// The first frame of every window after the first: where two windows join.
pub(super) fn joins(windows: &[Window]) -> Vec<usize> {
    windows.iter().skip(1).map(|w| w.start + w.keyed).collect()
}

pub(super) fn run(a: SampleArgs, spec_arg: &str) -> Result<()> {
    check_flags(&a)?;
    let spec = if Path::new(spec_arg).is_file() {
        std::fs::read_to_string(spec_arg)
            .with_context(|| format!("--timeline: reading {spec_arg}"))?
    } else {
        spec_arg.to_string()
    };
    let segments = tl::parse(&spec, T2M.fps).map_err(|e| anyhow::anyhow!("--timeline: {e}"))?;
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
    let gen = Generator::load(&a)?;
    let window = gen.max_frames().min(diffkfc_data::dataset::MAX_FRAMES);
    if window <= 2 * OVERLAP {
        bail!("--timeline: {} was built for motions of at most {window} frames (model.max_frames); a timeline needs windows longer than {}", a.checkpoint.display(), 2 * OVERLAP);
    }
    let windows = tl::windows(&segments, window, OVERLAP);
    let embs =
        segments.iter().map(|s| gen.embed(&s.text, "--timeline")).collect::<Result<Vec<_>>>()?;
    let b = a.num_samples;
    let mut motion: Vec<Vec<f32>> = vec![Vec::with_capacity(total * d); b];
    let mut corrections: Vec<Vec<warp::Correction>> = vec![Vec::new(); b];
    let mut feet = vec![LockReport::default(); b];
    let mut secs = 0.0;
    for (wi, w) in windows.iter().enumerate() {
        let n = w.end - w.start;
        let items: Vec<(Vec<f32>, Vec<f32>, Vec<RootKey>)> =
            motion.iter().map(|so_far| window_keys(so_far, &keys, w, d)).collect();
        let refs: Vec<(&[f32], &[f32], &[RootKey])> =
            items.iter().map(|(v, m, r)| (v.as_slice(), m.as_slice(), r.as_slice())).collect();
        let req = gen.request(&embs[w.segment], n, b, &refs);
        eprintln!(
            "window {}/{}: frames {}..{} ({} repeated), \"{}\"",
            wi + 1,
            windows.len(),
            w.start,
            w.end,
            w.keyed,
            segments[w.segment].text
        );
        let (fitted, s) = gen.generate(&req, &a)?;
        secs += s;
        for (i, f) in fitted.into_iter().enumerate() {
            // From the last repeated frame on: its pose is the motion's own (keyed), but the
            // fit may have changed its root velocities to reach the window's later keys, and
            // the new frames are placed by them.
            let from = w.keyed.saturating_sub(1);
            motion[i].truncate((w.start + from) * d);
            motion[i].extend_from_slice(&f.features[from * d..]);
            corrections[i].extend(
                f.corrections
                    .into_iter()
                    .filter(|c| c.frame >= w.keyed)
                    .map(|c| warp::Correction { frame: c.frame + w.start, ..c }),
            );
            feet[i].frames += f.feet.frames;
            feet[i].dragged += f.feet.dragged;
            feet[i].out_of_reach += f.feet.out_of_reach;
            feet[i].max_shift_m = feet[i].max_shift_m.max(f.feet.max_shift_m);
        }
    }
    let fitted: Vec<Fitted> = motion
        .into_iter()
        .zip(corrections)
        .zip(feet)
        .map(|((features, corrections), feet)| Fitted {
            features,
            corrections,
            feet,
            ..Default::default()
        })
        .collect();
    let joins = joins(&windows);
    let away: Vec<usize> = (5..total.saturating_sub(5))
        .step_by(10)
        .filter(|f| joins.iter().all(|j| f.abs_diff(*j) > 5))
        .collect();
    let k_trans_at = |frames: &[usize]| -> Vec<Option<f64>> {
        fitted
            .iter()
            .map(|f| {
                diffkfc_eval::keyframe_metrics::k_trans(
                    &rep::recover_from_ric(
                        &T2M,
                        &f.features.iter().map(|&v| v as f64).collect::<Vec<_>>(),
                    ),
                    frames,
                    2,
                )
            })
            .collect()
    };
    let extra = json!({
        "timeline": segments.iter().map(|s| json!({"start": s.start, "end": s.end, "text": s.text})).collect::<Vec<_>>(),
        "windows": windows.iter().map(|w| json!({"segment": w.segment, "start": w.start, "end": w.end, "repeated": w.keyed})).collect::<Vec<_>>(),
        "joins": joins,
        "k_trans_at_joins": k_trans_at(&joins),
        "k_trans_away_from_joins": k_trans_at(&away),
    });
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

/// Keyframes of one window for one motion: its first `keyed` frames repeat the motion so far
/// (every feature, place and heading), and the user's keys among its new frames move into the
/// window's frame (which stands where the motion so far is at the window's first frame).
fn window_keys(
    so_far: &[f32],
    keys: &Keys,
    w: &Window,
    d: usize,
) -> (Vec<f32>, Vec<f32>, Vec<RootKey>) {
    let n = w.end - w.start;
    let (mut v, mut m, mut root) =
        (vec![0f32; n * d], vec![0f32; n * d], vec![RootKey::default(); n]);
    if w.keyed > 0 {
        let tail = &so_far[w.start * d..];
        let traj = root_key::root_trajectory(tail, d);
        v[..w.keyed * d].copy_from_slice(&tail[..w.keyed * d]);
        m[..w.keyed * d].fill(1.0);
        root[..w.keyed].copy_from_slice(&traj[..w.keyed]);
    }
    let origin = if w.start == 0 {
        RootKey::default()
    } else {
        root_key::root_trajectory(so_far, d)[w.start]
    };
    for &g in keys.frames.iter().filter(|&&g| g >= w.start + w.keyed && g < w.end) {
        let f = g - w.start;
        v[f * d..(f + 1) * d].copy_from_slice(&keys.values[g * d..(g + 1) * d]);
        m[f * d..(f + 1) * d].copy_from_slice(&keys.mask[g * d..(g + 1) * d]);
        root[f] = diffkfc_data::io::keyframe_file::relative_to(keys.root[g], origin);
    }
    (v, m, root)
}
