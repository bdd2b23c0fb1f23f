//! Keyframes of a sample request: from a motion (`--from`, `--frames`/`--keyframe-rate`) or a
//! keyframe JSON file (`--keyframes`), with their places and headings.

use diffkfc_data::io::keyframe_file::KeyframeSpec;

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
    /// `[length]` keyed place and heading (unobserved: default).
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
        let f: usize =
            p.parse().map_err(|_| anyhow::anyhow!("--frames: '{p}' is not a frame number"))?;
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

pub(super) fn keys_from_motion(
    a: &SampleArgs,
    path: &Path,
    length: Option<usize>,
    joints: Vec<usize>,
) -> Result<Keys> {
    let feats = diffkfc_data::io::motion_file::load_motion_features(path, &T2M, &a.bvh.options()?)?;
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
        let strategy: Strategy =
            a.keyframe_strategy.parse().map_err(|e: diffkfc_data::UnknownChoice| {
                anyhow::anyhow!("--keyframe-strategy: {e}")
            })?;
        keyframes::select(strategy, length, rate, &feats, d, &mut Rng::new(a.seed))
    } else {
        parse_frames(
            a.frames.as_deref().context("--from needs --frames or --keyframe-rate")?,
            length,
        )?
    };
    let dims = keyframes::dim_mask(&T2M, Some(&joints));
    let mask = keyframes::frame_mask(length, &frames, &dims);
    let values = feats[..length * d].iter().zip(&mask).map(|(v, m)| v * m).collect();
    let source = rep::recover_from_ric(
        &T2M,
        &feats[..length * d].iter().map(|&v| v as f64).collect::<Vec<_>>(),
    );
    let mut root = vec![RootKey::default(); length];
    if !a.no_root_keys {
        let traj = root_key::root_trajectory(&feats[..length * d], d);
        for &f in &frames {
            root[f] = traj[f];
        }
    }
    Ok(Keys { length, frames, values, mask, source: Some(source), joints, root })
}

pub(super) fn keys_from_json(
    path: &Path,
    length: Option<usize>,
    joints_flag: Option<&str>,
) -> Result<Keys> {
    let err = |e: diffkfc_data::DataError| anyhow::anyhow!("{}: {e}", path.display());
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let spec = KeyframeSpec::parse(&text).map_err(err)?;
    let k =
        spec.resolve(&T2M, length, joints_flag, diffkfc_data::dataset::MAX_FRAMES).map_err(err)?;
    Ok(Keys {
        length: k.length,
        frames: k.frames,
        values: k.values,
        mask: k.mask,
        source: None,
        joints: k.joints,
        root: k.root,
    })
}

#[cfg(test)]
mod tests {
    /// Bounded fuzzing of the keyframe JSON reader (`diffkfc_data::testing::fuzz`): mutated keyframe
    /// files give keyframes or a clean error, never a panic or a hang; whatever is accepted has
    /// finite values, frames inside the motion and a length from 1 to 196.
    #[test]
    fn keyframe_json_never_panics() {
        let dir = std::env::temp_dir().join(format!("diffkfc-kjfuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pose: Vec<[f64; 3]> = diffkfc_data::T2M
            .target_offsets()
            .map(|o| {
                let rot = vec![vec![diffkfc_data::motion::quat::IDENTITY; 22]];
                super::rep::forward_kinematics(&diffkfc_data::T2M, &rot, &[[0.0, 0.9, 0.0]], &o)[0]
                    .clone()
            })
            .unwrap();
        let feats = vec![0.1f32; 263];
        let seeds: Vec<Vec<u8>> = vec![
            serde_json::json!({"length": 60, "joints": "lower_body", "keyframes": [{"frame": 0, "joints": pose}, {"frame": 30, "features": feats, "root": [1.0, 0.9, 2.0], "heading": 45}]})
                .to_string()
                .into_bytes(),
            serde_json::json!({"length": 40, "keyframes": [{"frame": 10, "root": [0.5, 0.9, 1.5]}, {"frame": 39, "heading": -90}]}).to_string().into_bytes(),
        ];
        let path = dir.join("keys.json");
        diffkfc_data::testing::fuzz::fuzz(
            "keyframe json",
            &seeds,
            diffkfc_data::testing::fuzz::cases() / 10,
            &|b| {
                std::fs::write(&path, b).unwrap();
                match super::keys_from_json(&path, None, None) {
                    Ok(k) => {
                        assert!(
                            (1..=196).contains(&k.length) && k.frames.iter().all(|&f| f < k.length)
                        );
                        assert!(
                            k.values.iter().all(|v| v.is_finite()),
                            "non-finite keyframe values accepted"
                        );
                        true
                    }
                    Err(_) => false,
                }
            },
        );
        std::fs::remove_dir_all(dir).unwrap();
    }
}
