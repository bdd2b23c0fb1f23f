//! One long motion from a timeline of prompts, window after window
//! (`plan` parses the timeline and plans the windows). Each window after the first is given
//! the last frames of the motion so far as keyframes (every feature, place and heading, in the
//! window's own frame), and its frames from the last repeated one on replace the motion's, so
//! the root path integrates through every join.

pub mod plan;

use diffkfc_data::io::keyframe_file::relative_to;
use diffkfc_data::motion::root_key::{root_trajectory, RootKey};
use diffkfc_data::postprocess::footlock::LockReport;
use diffkfc_data::postprocess::warp::Correction;

use plan::Window;

use crate::sampling::fit::Fitted;
use crate::sampling::pipeline::{Generator, KeyedItem};
use crate::sampling::sampler::Request;

/// The user's keyframes on the whole timeline: raw feature values and masks `[T, D]`, places
/// and headings `[T]`, and the keyed frames.
pub struct TimelineKeys<'a> {
    pub frames: &'a [usize],
    pub values: &'a [f32],
    pub mask: &'a [f32],
    pub root: &'a [RootKey],
}

/// The first frame of every window after the first: where two windows join.
pub fn joins(windows: &[Window]) -> Vec<usize> {
    windows.iter().skip(1).map(|w| w.start + w.keyed).collect()
}

/// `batch` motions of the whole timeline: `texts[s]` is segment s's text embedding; `sample(i,
/// request)` generates window i (the caller's sampler, checks and progress). Each motion's fit
/// corrections are moved onto the timeline's frames and its foot-lock counts summed.
pub fn generate<E>(
    gen: &Generator,
    windows: &[Window],
    texts: &[Vec<f32>],
    keys: &TimelineKeys,
    batch: usize,
    mut sample: impl FnMut(usize, &Request) -> Result<Vec<Fitted>, E>,
) -> Result<Vec<Fitted>, E> {
    let d = gen.mean.len();
    let total = windows.last().map_or(0, |w| w.end);
    let mut motion: Vec<Vec<f32>> = vec![Vec::with_capacity(total * d); batch];
    let mut corrections: Vec<Vec<Correction>> = vec![Vec::new(); batch];
    let mut feet = vec![LockReport::default(); batch];
    for (wi, w) in windows.iter().enumerate() {
        let n = w.end - w.start;
        let items: Vec<(Vec<f32>, Vec<f32>, Vec<RootKey>)> =
            motion.iter().map(|so_far| window_keys(so_far, keys, w, d)).collect();
        let keyed: Vec<KeyedItem> = items
            .iter()
            .map(|(values, mask, root)| KeyedItem {
                text: &texts[w.segment],
                length: n,
                values,
                mask,
                root,
            })
            .collect();
        for (i, f) in sample(wi, &gen.request(n, &keyed))?.into_iter().enumerate() {
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
                    .map(|c| Correction { frame: c.frame + w.start, ..c }),
            );
            feet[i].frames += f.feet.frames;
            feet[i].dragged += f.feet.dragged;
            feet[i].out_of_reach += f.feet.out_of_reach;
            feet[i].worse += f.feet.worse;
            feet[i].max_shift_m = feet[i].max_shift_m.max(f.feet.max_shift_m);
        }
    }
    Ok(motion
        .into_iter()
        .zip(corrections)
        .zip(feet)
        .map(|((features, corrections), feet)| Fitted {
            features,
            corrections,
            feet,
            ..Default::default()
        })
        .collect())
}

/// Keyframes of one window for one motion: its first `keyed` frames repeat the motion so far
/// (every feature, place and heading), and the user's keys among its new frames move into the
/// window's frame (which stands where the motion so far is at the window's first frame).
fn window_keys(
    so_far: &[f32],
    keys: &TimelineKeys,
    w: &Window,
    d: usize,
) -> (Vec<f32>, Vec<f32>, Vec<RootKey>) {
    let n = w.end - w.start;
    let (mut v, mut m, mut root) =
        (vec![0f32; n * d], vec![0f32; n * d], vec![RootKey::default(); n]);
    if w.keyed > 0 {
        let tail = &so_far[w.start * d..];
        let traj = root_trajectory(tail, d);
        v[..w.keyed * d].copy_from_slice(&tail[..w.keyed * d]);
        m[..w.keyed * d].fill(1.0);
        root[..w.keyed].copy_from_slice(&traj[..w.keyed]);
    }
    let origin =
        if w.start == 0 { RootKey::default() } else { root_trajectory(so_far, d)[w.start] };
    for &g in keys.frames.iter().filter(|&&g| g >= w.start + w.keyed && g < w.end) {
        let f = g - w.start;
        v[f * d..(f + 1) * d].copy_from_slice(&keys.values[g * d..(g + 1) * d]);
        m[f * d..(f + 1) * d].copy_from_slice(&keys.mask[g * d..(g + 1) * d]);
        root[f] = relative_to(keys.root[g], origin);
    }
    (v, m, root)
}
