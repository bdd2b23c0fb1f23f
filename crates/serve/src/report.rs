//! What `/api/sample` answers: the motion in the world (joints, per-frame place and heading,
//! planted spans, the followed root path) and how well every key was hit.

use diffkfc_data::io::keyframe_file::{self, KeyframeSpec};
use diffkfc_data::motion::plausibility::foot_skating_ratio;
use diffkfc_data::motion::root_key::RootKey;
use diffkfc_data::{keyframes, T2M};
use diffkfc_eval::keyframe_metrics::{k_err_local, k_trans};
use serde::Serialize;
use serde_json::{json, Value};

use crate::engine::Generated;

/// A key whose fit moved its pose features more than this (metres) was not reached by the
/// network itself: the page marks it.
pub const LARGE_POSE_CORRECTION: f64 = 0.25;
/// The same for a keyed place (metres on the ground) and a heading (degrees).
pub const LARGE_PLACE_CORRECTION_M: f64 = 0.5;
pub const LARGE_HEADING_CORRECTION_DEG: f64 = 45.0;

/// How one key was hit.
#[derive(Clone, Debug, Serialize)]
pub struct KeyReport {
    pub frame: usize,
    /// Mean root-relative error of the keyed joints (metres), when the key has a pose.
    pub pose_err_m: Option<f64>,
    /// Ground distance of the pelvis from the keyed place (metres), when it has one.
    pub place_err_m: Option<f64>,
    /// Heading error (degrees), when it has one.
    pub heading_err_deg: Option<f64>,
    /// What the fit had to move: pose features (largest, metres), place (m), heading (deg).
    pub correction: Option<diffkfc_data::postprocess::warp::Correction>,
    /// The correction was large: the network did not reach this key by itself.
    pub large: bool,
}

fn round(v: f64, unit: f64) -> f64 {
    (v / unit).round() * unit
}

/// Every key of `spec` against the generated motion.
pub fn key_reports(g: &Generated, spec: &KeyframeSpec) -> Vec<KeyReport> {
    let mut keys: Vec<&keyframe_file::KeySpec> = spec.keyframes.iter().collect();
    keys.sort_by_key(|k| k.frame);
    keys.iter()
        .map(|k| {
            let f = k.frame;
            let posed = !keyframes::posed_frames(&T2M, &g.keys.mask, &[f]).is_empty();
            let pose_err_m = posed
                .then(|| k_err_local(&T2M, g.features(), &g.keys.values, &[f], &g.keys.joints))
                .flatten();
            let at = g.traj[f];
            let place_err_m = k.root.map(|p| {
                let q = at.place.unwrap_or([0.0, 0.0]);
                (p[0] - q[0]).hypot(p[2] - q[1])
            });
            let heading_err_deg = k.heading.map(|h| {
                let e = (h - at.heading.unwrap_or(0.0).to_degrees()).rem_euclid(360.0);
                e.min(360.0 - e)
            });
            let correction = g.fitted.corrections.iter().find(|c| c.frame == f).cloned();
            let large = correction.as_ref().is_some_and(|c| {
                c.pose > LARGE_POSE_CORRECTION
                    || c.place_m.is_some_and(|m| m > LARGE_PLACE_CORRECTION_M)
                    || c.heading_deg.is_some_and(|h| h.abs() > LARGE_HEADING_CORRECTION_DEG)
            });
            KeyReport { frame: f, pose_err_m, place_err_m, heading_err_deg, correction, large }
        })
        .collect()
}

/// The `/api/sample` answer for `g`, generated from keys `spec`.
pub fn sample_reply(g: &Generated, spec: &KeyframeSpec) -> Value {
    let keys = key_reports(g, spec);
    let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let max = |v: Vec<f64>| v.into_iter().reduce(f64::max);
    let root_path = g.fitted.root_path.as_ref().map(|p| {
        p.chunks(3)
            .flat_map(|v| {
                let w = keyframe_file::point_from_frame(
                    [v[0] as f64, v[1] as f64, v[2] as f64],
                    g.origin,
                );
                [round(w[0], 1e-3), round(w[2], 1e-3)]
            })
            .collect::<Vec<_>>()
    });
    let planted: Vec<[usize; 3]> = g
        .fitted
        .feet
        .spans
        .iter()
        .map(|s| {
            let toe = if s.foot == "left" { T2M.feet_left[1] } else { T2M.feet_right[1] };
            [toe, s.start, s.end]
        })
        .collect();
    let frames: Vec<usize> = keys.iter().map(|k| k.frame).collect();
    let mut reply = motion_json(&g.joints, &g.traj);
    reply.as_object_mut().unwrap().extend(
        json!({
            "root_path": root_path,
            "planted": planted,
            "keys": keys,
            "metrics": {
                "k_err_m": mean(keys.iter().filter_map(|k| k.pose_err_m).collect()),
                "place_err_m": max(keys.iter().filter_map(|k| k.place_err_m).collect()),
                "heading_err_deg": max(keys.iter().filter_map(|k| k.heading_err_deg).collect()),
                "k_trans": k_trans(&g.joints, &frames, 2),
                "foot_skating": foot_skating_ratio(&T2M, &g.joints),
                "large_corrections": keys.iter().filter(|k| k.large).count(),
            },
            "generate_ms": g.generate_ms,
        })
        .as_object()
        .unwrap()
        .clone(),
    );
    reply
}

/// A motion for the page: `length`, `fps`, `joints` `[T * J * 3]` and `root` `[T]` of
/// [x, pelvis y, z, heading degrees], in the world, to 0.1 mm and 0.001 degree.
pub fn motion_json(joints: &diffkfc_data::Joints, traj: &[RootKey]) -> Value {
    let flat: Vec<f64> = joints.iter().flatten().flatten().map(|&v| round(v, 1e-4)).collect();
    let root: Vec<[f64; 4]> = joints
        .iter()
        .zip(traj)
        .map(|(p, k)| {
            let [x, z] = k.place.unwrap_or([0.0, 0.0]);
            let h = k.heading.unwrap_or(0.0).to_degrees();
            [round(x, 1e-4), round(p[0][1], 1e-4), round(z, 1e-4), round(h, 1e-3)]
        })
        .collect();
    json!({"length": joints.len(), "fps": T2M.fps, "joints": flat, "root": root})
}
