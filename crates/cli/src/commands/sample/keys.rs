//! Keyframes of a sample request: from a motion (`--from`, `--frames`/`--keyframe-rate`) or a
//! keyframe JSON file (`--keyframes`), with their places and headings.

use super::*;

/// Keyframes in the raw (de-normalised) feature space.
pub(super) struct Keys {
    pub(super) length: usize,
    pub(super) frames: Vec<usize>,
    /// [length, D]
    pub(super) values: Vec<f32>,
    pub(super) mask: Vec<f32>,
    /// Source motion joints (for global K-Err and the real K-TranS), when there is one.
    pub(super) source: Option<rep::Joints>,
    /// Joints the keyframes observe.
    pub(super) joints: Vec<usize>,
    /// [length] keyed place and heading (unobserved: default).
    pub(super) root: Vec<RootKey>,
}

pub(super) fn parse_frames(spec: &str, len: usize) -> Result<Vec<usize>> {
    if spec.trim() == "all" {
        return Ok((0..len).collect());
    }
    if spec.trim().is_empty() {
        bail!("--frames: empty; give frame numbers (0,40,80) or `all`");
    }
    let mut v = Vec::new();
    for p in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let f: usize = p.parse().map_err(|_| anyhow::anyhow!("--frames: '{p}' is not a frame number"))?;
        if f >= len {
            bail!("--frames: frame {f} is beyond the motion ({len} frames)");
        }
        v.push(f);
    }
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

pub(super) fn joint_set(spec: Option<&str>, flag: &str) -> Result<Vec<usize>> {
    match spec {
        None => Ok((0..T2M.num_joints()).collect()),
        Some(s) => T2M.resolve_joints(s).map_err(|e| anyhow::anyhow!("{flag}: {e}")),
    }
}

pub(super) fn keys_from_motion(a: &SampleArgs, path: &Path, length: Option<usize>, joints: Vec<usize>) -> Result<Keys> {
    let feats = diffkfc_data::motion_file::load_motion_features(path, &T2M, &a.bvh.options()?)?;
    let d = T2M.feature_dim();
    let t = feats.len() / d;
    let length = length.unwrap_or(t.min(diffkfc_data::dataset::MAX_FRAMES));
    if length > t {
        bail!("--length {length} is longer than {} ({t} frames)", path.display());
    }
    let frames = if let Some(rate) = a.keyframe_rate {
        if !(0.0..=1.0).contains(&rate) {
            bail!("--keyframe-rate: {rate} is not in [0, 1]");
        }
        let strategy: Strategy = a.keyframe_strategy.parse().map_err(|e: String| anyhow::anyhow!("--keyframe-strategy: {e}"))?;
        keyframes::select(strategy, length, rate, &feats, d, &mut Rng::new(a.seed))
    } else {
        parse_frames(a.frames.as_deref().context("--from needs --frames or --keyframe-rate")?, length)?
    };
    let dims = keyframes::dim_mask(&T2M, Some(&joints));
    let mask = keyframes::frame_mask(length, &frames, &dims);
    let values = feats[..length * d].iter().zip(&mask).map(|(v, m)| v * m).collect();
    let source = rep::recover_from_ric(&T2M, &feats[..length * d].iter().map(|&v| v as f64).collect::<Vec<_>>());
    let mut root = vec![RootKey::default(); length];
    if !a.no_root_keys {
        let traj = warp::root_trajectory(&feats[..length * d], d);
        for &f in &frames {
            root[f] = traj[f];
        }
    }
    Ok(Keys { length, frames, values, mask, source: Some(source), joints, root })
}

pub(super) fn keys_from_json(path: &Path, length: Option<usize>, joints_flag: Option<&str>) -> Result<Keys> {
    let err = |m: String| anyhow::anyhow!("{}: {m}", path.display());
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).with_context(|| format!("reading {}", path.display()))?).map_err(|e| err(format!("not valid JSON: {e}")))?;
    let max = diffkfc_data::dataset::MAX_FRAMES;
    let length = match (length, v.get("length")) {
        (Some(l), _) => l,
        (None, None) => return Err(err("no \"length\" (or pass --length)".into())),
        (None, Some(l)) => match l.as_u64().filter(|&l| l >= 1 && l <= max as u64) {
            Some(l) => l as usize,
            None => return Err(err(format!("\"length\" is {l}; must be a whole number of frames from 1 to {max}"))),
        },
    };
    let spec = match (joints_flag, v.get("joints")) {
        (Some(f), _) => Some(f.to_string()),
        (None, None) => None,
        (None, Some(j)) => match j.as_str().map(str::trim).filter(|s| !s.is_empty()) {
            Some(s) => Some(s.to_string()),
            None => return Err(err(format!("\"joints\" is {j}; must name body parts or joints, e.g. \"lower_body\" or \"left_arm,head\""))),
        },
    };
    let joints = joint_set(spec.as_deref(), "joints")?;
    let d = T2M.feature_dim();
    let dims = keyframes::dim_mask(&T2M, Some(&joints));
    let (mut values, mut mask) = (vec![0f32; length * d], vec![0f32; length * d]);
    let mut root = vec![RootKey::default(); length];
    let mut frames = Vec::new();
    for (i, k) in v["keyframes"].as_array().ok_or_else(|| err("no \"keyframes\" array".into()))?.iter().enumerate() {
        let f = match k.get("frame") {
            None => return Err(err(format!("keyframe {i}: no \"frame\""))),
            Some(x) => x.as_u64().ok_or_else(|| err(format!("keyframe {i}: \"frame\" is {x}; must be a whole frame number from 0")))? as usize,
        };
        if f >= length {
            return Err(err(format!("keyframe {i}: frame {f} is beyond the length {length}")));
        }
        let (vals, obs): (Vec<f32>, Vec<bool>) = if let Some(j) = k["joints"].as_array() {
            let pose: Vec<[f64; 3]> = j
                .iter()
                .map(|p| {
                    let a = p.as_array().filter(|a| a.len() == 3).ok_or_else(|| err(format!("keyframe {i}: each joint must be [x, y, z]")))?;
                    let c: Vec<f64> = a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
                    Ok([c[0], c[1], c[2]])
                })
                .collect::<Result<_>>()?;
            let (vals, obs) = pose::pose_features(&T2M, &pose).map_err(|e| err(format!("keyframe {i}: {e}")))?;
            if vals.iter().zip(&obs).any(|(v, &o)| o && !v.is_finite()) {
                return Err(err(format!("keyframe {i}: the pose gives non-finite features (joints too far apart or coinciding)")));
            }
            (vals, obs)
        } else if let Some(fe) = k["features"].as_array() {
            if fe.len() != d {
                return Err(err(format!("keyframe {i}: {} features, expected {d}", fe.len())));
            }
            let vals: Vec<f32> = fe.iter().map(|x| x.as_f64().unwrap_or(f64::NAN) as f32).collect();
            if vals.iter().any(|x| !x.is_finite()) {
                return Err(err(format!("keyframe {i}: NaN or non-numeric feature")));
            }
            (vals, vec![true; d])
        } else if k.get("root").is_some() || k.get("heading").is_some() {
            (vec![0.0; d], vec![false; d])
        } else {
            return Err(err(format!("keyframe {i}: needs \"joints\" (22 x [x,y,z]), \"features\" ({d} numbers), \"root\" or \"heading\"")));
        };
        for c in 0..d {
            if obs[c] && dims[c] {
                values[f * d + c] = vals[c];
                mask[f * d + c] = 1.0;
            }
        }
        let number = |x: &serde_json::Value, what: &str| -> Result<f64> {
            x.as_f64().filter(|v| v.is_finite() && v.abs() < 1e4).ok_or_else(|| err(format!("keyframe {i}: \"{what}\" must hold finite numbers (metres or degrees), got {x}")))
        };
        if let Some(r) = k.get("root") {
            let a = r.as_array().filter(|a| a.len() == 3).ok_or_else(|| err(format!("keyframe {i}: \"root\" must be [x, y, z] in metres, got {r}")))?;
            let p: Vec<f64> = a.iter().map(|x| number(x, "root")).collect::<Result<_>>()?;
            root[f].place = Some([p[0], p[2]]);
            // The root's height is the pelvis height feature.
            if dims[3] {
                values[f * d + 3] = p[1] as f32;
                mask[f * d + 3] = 1.0;
            }
        }
        if let Some(h) = k.get("heading") {
            root[f].heading = Some(number(h, "heading")?.to_radians());
        }
        frames.push(f);
    }
    frames.sort_unstable();
    frames.dedup();
    relative_to_first_frame(&mut root);
    Ok(Keys { length, frames, values, mask, source: None, joints, root })
}

/// Keyed places and headings are in the output motion's frame, where frame 0 stands at the
/// origin facing +Z. A keyframe at frame 0 with its own place or heading moves that frame:
/// every key is re-expressed relative to it.
pub(super) fn relative_to_first_frame(root: &mut [RootKey]) {
    let Some(first) = root.first().copied() else {
        return;
    };
    for k in root.iter_mut() {
        *k = relative_to(*k, first);
    }
}

/// A keyed place and heading re-expressed in the frame that stands at `origin`'s place facing
/// its heading (a missing place or heading of the origin: the origin, facing +Z).
pub(super) fn relative_to(k: RootKey, origin: RootKey) -> RootKey {
    let [ox, oz] = origin.place.unwrap_or([0.0, 0.0]);
    let h0 = origin.heading.unwrap_or(0.0);
    let (s, c) = (-h0).sin_cos();
    // Rotate by -h0 about +Y (heading h turns +Z towards +X): x' = x cos + z sin.
    RootKey {
        place: k.place.map(|[x, z]| {
            let (x, z) = (x - ox, z - oz);
            [x * c + z * s, -x * s + z * c]
        }),
        heading: k.heading.map(|h| h - h0),
    }
}
