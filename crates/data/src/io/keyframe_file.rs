//! The keyframe file `sample --keyframes` reads (and `keyframes suggest` writes): JSON read
//! into a typed spec, checked, and resolved into observed features, masks and root keys.
//!
//! ```json
//! {"length": 120, "joints": "lower_body", "keyframes": [
//!   {"frame": 0, "joints": [[x, y, z], ... 22 joints]},
//!   {"frame": 60, "features": [263 numbers], "root": [1.5, 0.9, 3.0], "heading": 90},
//!   {"frame": 100, "root": [0.0, 0.9, 5.0]}]}
//! ```
//! Poses are joint positions in metres (or raw features); `root` is the pelvis place and height
//! and `heading` its facing in degrees (0 faces +Z, 90 faces +X), both in the output's frame.

use serde::{de::DeserializeOwned, Deserialize, Serialize};

use crate::keyframes;
use crate::motion::pose;
use crate::motion::quat::Vec3;
use crate::motion::root_key::RootKey;
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// Largest place coordinate or heading accepted (metres or degrees).
const MAX_ABS: f64 = 1e4;

/// A keyframe file as written.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframeSpec {
    /// Frames of the motion (absent: the caller's length).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length: Option<usize>,
    /// Body parts or joints every keyframe observes (absent: all).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joints: Option<String>,
    pub keyframes: Vec<KeySpec>,
    /// Where the keys came from and how they were picked (`keyframes suggest` writes them; read
    /// and ignored).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source: Option<serde_json::Value>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub strategy: Option<serde_json::Value>,
}

/// One keyframe: a pose (joint positions or features) and/or a place and a heading.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct KeySpec {
    pub frame: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joints: Option<Vec<Vec3>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub features: Option<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub root: Option<Vec3>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading: Option<f64>,
}

impl KeySpec {
    /// The pose's feature values and which of them it observes (a place-only key observes
    /// none); the error says what is wrong with the key's pose.
    fn observed(&self, skel: &Skeleton) -> Result<(Vec<f32>, Vec<bool>), DataError> {
        let d = skel.feature_dim();
        let bad = |m: String| DataError::Invalid(m);
        Ok(match (&self.joints, &self.features) {
            (Some(pose), _) => {
                crate::motion::magnitude::check_joints(skel, &vec![pose.clone()])
                    .map_err(|e| bad(e.to_string()))?;
                crate::motion::representation::check_pose(skel, pose).map_err(bad)?;
                let (vals, obs) = pose::pose_features(skel, pose).map_err(|e| bad(e.to_string()))?;
                if vals.iter().zip(&obs).any(|(v, &o)| o && !v.is_finite()) {
                    return Err(bad("the pose gives non-finite features (joints too far apart or coinciding)".into()));
                }
                (vals, obs)
            }
            (None, Some(fe)) if fe.len() != d => return Err(bad(format!("{} features, expected {d}", fe.len()))),
            (None, Some(fe)) => {
                let pose = &crate::motion::representation::recover_from_ric(skel, fe)[0];
                crate::motion::representation::check_pose(skel, pose).map_err(bad)?;
                (fe.iter().map(|&x| x as f32).collect(), vec![true; d])
            }
            (None, None) if self.root.is_some() || self.heading.is_some() => (vec![0.0; d], vec![false; d]),
            (None, None) => return Err(bad(format!("needs \"joints\" ({} x [x,y,z]), \"features\" ({d} numbers), \"root\" or \"heading\"", skel.num_joints()))),
        })
    }

    /// Keys at `frames` of a motion: its pose (joints, metres), the pelvis place and height and
    /// its heading (degrees) from `traj`, rounded to 0.1 mm and 0.0001 degree.
    pub fn from_motion(joints: &[Vec<Vec3>], traj: &[RootKey], frames: &[usize]) -> Vec<KeySpec> {
        let round = |v: f64| (v * 1e4).round() / 1e4;
        frames
            .iter()
            .map(|&f| {
                let [x, z] = traj[f].place.unwrap_or([0.0, 0.0]);
                KeySpec {
                    frame: f,
                    joints: Some(joints[f].iter().map(|p| p.map(round)).collect()),
                    features: None,
                    root: Some([round(x), round(joints[f][0][1]), round(z)]),
                    heading: Some(round(traj[f].heading.unwrap_or(0.0).to_degrees())),
                }
            })
            .collect()
    }
}

/// JSON `text` read as `T`; errors name where in the text the problem is and, for a misspelt
/// field, the name that was meant.
pub fn parse_json<T: DeserializeOwned>(text: &str) -> Result<T, DataError> {
    let de = &mut serde_json::Deserializer::from_str(text);
    let v = serde_path_to_error::deserialize(&mut *de).map_err(|e| {
        let at = e.path().to_string();
        let msg = with_suggestion(&e.into_inner().to_string());
        DataError::Invalid(if at == "." { msg } else { format!("{at}: {msg}") })
    })?;
    de.end().map_err(|e| DataError::Invalid(format!("after the JSON object: {e}")))?;
    Ok(v)
}

/// Keyframes resolved for a motion of `length` frames.
pub struct KeyframeSet {
    pub length: usize,
    /// Keyed frames, sorted.
    pub frames: Vec<usize>,
    /// [length, D] observed feature values (zero where unobserved) and their mask.
    pub values: Vec<f32>,
    pub mask: Vec<f32>,
    /// Joints the keyframes observe.
    pub joints: Vec<usize>,
    /// `[length]` keyed place and heading, relative to frame 0 (see [`relative_to`]).
    pub root: Vec<RootKey>,
}

/// serde's "unknown field `heding`, expected one of `frame`, ..." with the closest known name
/// added, so a misspelt key says what was meant.
fn with_suggestion(msg: &str) -> String {
    let ticked =
        |t: &str| -> Vec<String> { t.split('`').skip(1).step_by(2).map(str::to_string).collect() };
    let Some(rest) = msg.strip_prefix("unknown field ") else {
        return msg.to_string();
    };
    let (unknown, expected) = match rest.split_once(", expected") {
        Some((u, e)) => (ticked(u), ticked(e)),
        None => return msg.to_string(),
    };
    let best = unknown.first().and_then(|u| {
        expected.iter().map(|k| (strsim::levenshtein(u, k), k)).filter(|(d, _)| *d <= 3).min()
    });
    let Some((_, k)) = best else {
        return msg.to_string();
    };
    match msg.split_once(" at line ") {
        Some((head, at)) => format!("{head} (did you mean `{k}`?) at line {at}"),
        None => format!("{msg} (did you mean `{k}`?)"),
    }
}

impl KeyframeSpec {
    /// Parse the JSON text; errors name where in the file the problem is.
    pub fn parse(text: &str) -> Result<KeyframeSpec, DataError> {
        parse_json(text)
    }

    /// The keyframes for `skel`: `length` overrides the file's, `joints` its body parts;
    /// `max_len` bounds a length taken from the file.
    pub fn resolve(
        &self,
        skel: &Skeleton,
        length: Option<usize>,
        joints: Option<&str>,
        max_len: usize,
    ) -> Result<KeyframeSet, DataError> {
        let bad = |m: String| DataError::Invalid(m);
        let length = self.length_of(length, max_len)?;
        let observed = self.observed_joints(skel, joints)?;
        let d = skel.feature_dim();
        let dims = keyframes::dim_mask(skel, Some(&observed));
        let (mut values, mut mask) = (vec![0f32; length * d], vec![0f32; length * d]);
        let mut root = vec![RootKey::default(); length];
        let mut frames: Vec<usize> = Vec::new();
        for (i, k) in self.keyframes.iter().enumerate() {
            let at = |m: String| bad(format!("keyframes[{i}]: {m}"));
            let f = k.frame;
            if f >= length {
                return Err(at(format!("frame {f} is beyond the length {length}")));
            }
            if let Some(j) = frames.iter().position(|&g| g == f) {
                return Err(at(format!("frame {f} is keyed twice (also keyframes[{j}]); put its pose, root and heading in one keyframe")));
            }
            let (vals, obs) = k.observed(skel).map_err(|e| at(e.to_string()))?;
            for c in 0..d {
                if obs[c] && dims[c] {
                    values[f * d + c] = vals[c];
                    mask[f * d + c] = 1.0;
                }
            }
            if let Some(p) = k.root {
                if p.iter().any(|v| !(v.is_finite() && v.abs() < MAX_ABS)) {
                    return Err(at(format!("root {p:?}: must be finite metres")));
                }
                root[f].place = Some([p[0], p[2]]);
                // The root's height is the pelvis height feature.
                if dims[3] {
                    values[f * d + 3] = p[1] as f32;
                    mask[f * d + 3] = 1.0;
                }
            }
            if let Some(h) = k.heading {
                if !(h.is_finite() && h.abs() < MAX_ABS) {
                    return Err(at(format!("heading {h:e}: must be finite degrees")));
                }
                root[f].heading = Some(h.to_radians());
            }
            frames.push(f);
        }
        frames.sort_unstable();
        relative_to_first_frame(&mut root);
        Ok(KeyframeSet { length, frames, values, mask, joints: observed, root })
    }

    /// The motion's length: `length` (a flag) over the file's, which must be 1 to `max_len`.
    fn length_of(&self, length: Option<usize>, max_len: usize) -> Result<usize, DataError> {
        let bad = |m: String| DataError::Invalid(m);
        match (length, self.length) {
            (Some(l), _) => Ok(l),
            (None, None) => Err(bad("no \"length\" (or pass --length)".into())),
            (None, Some(l)) if l == 0 || l > max_len => {
                Err(bad(format!("length: {l} frames; must be 1 to {max_len}")))
            }
            (None, Some(l)) => Ok(l),
        }
    }

    /// The joints the keys observe: `joints` (a flag) over the file's, else all of them.
    fn observed_joints(
        &self,
        skel: &Skeleton,
        joints: Option<&str>,
    ) -> Result<Vec<usize>, DataError> {
        let bad = |m: String| DataError::Invalid(m);
        let spec = joints.map(str::to_string).or_else(|| self.joints.clone());
        if spec.as_deref().is_some_and(|s| s.trim().is_empty()) {
            return Err(bad("joints: empty; name body parts or joints, e.g. \"lower_body\" or \"left_arm,head\"".into()));
        }
        match &spec {
            Some(s) => skel.resolve_joints(s).map_err(|e| bad(format!("joints: {e}"))),
            None => Ok((0..skel.num_joints()).collect()),
        }
    }
}

/// Keyed places and headings are in the output motion's frame, where frame 0 stands at the
/// origin facing +Z. A keyframe at frame 0 with its own place or heading moves that frame:
/// every key is re-expressed relative to it.
pub fn relative_to_first_frame(root: &mut [RootKey]) {
    let Some(first) = root.first().copied() else {
        return;
    };
    for k in root.iter_mut() {
        *k = relative_to(*k, first);
    }
}

/// The inverse of [`relative_to`]: a place and heading given in the frame that stands at
/// `origin` re-expressed in the world.
pub fn from_frame(k: RootKey, origin: RootKey) -> RootKey {
    let h0 = origin.heading.unwrap_or(0.0);
    RootKey {
        place: k.place.map(|[x, z]| {
            let p = point_from_frame([x, 0.0, z], origin);
            [p[0], p[2]]
        }),
        heading: k.heading.map(|h| h + h0),
    }
}

/// A point given in the frame that stands at `origin` (heading about +Y) in the world.
pub fn point_from_frame(p: Vec3, origin: RootKey) -> Vec3 {
    let [ox, oz] = origin.place.unwrap_or([0.0, 0.0]);
    let (s, c) = origin.heading.unwrap_or(0.0).sin_cos();
    [p[0] * c + p[2] * s + ox, p[1], -p[0] * s + p[2] * c + oz]
}

/// A keyed place and heading re-expressed in the frame that stands at `origin`'s place facing
/// its heading (a missing place or heading of the origin: the origin, facing +Z).
pub fn relative_to(k: RootKey, origin: RootKey) -> RootKey {
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

#[cfg(test)]
mod tests {
    /// `from_frame` undoes `relative_to` (places and headings), and a key one step ahead of an
    /// origin facing +X (90 degrees) lies one step along +X in the world.
    #[test]
    fn from_frame_inverts_relative_to() {
        let origin = RootKey { place: Some([1.5, -2.0]), heading: Some(0.7) };
        let k = RootKey { place: Some([0.3, 4.0]), heading: Some(-1.1) };
        let back = from_frame(relative_to(k, origin), origin);
        let (p, q) = (back.place.unwrap(), k.place.unwrap());
        assert!((p[0] - q[0]).abs() < 1e-12 && (p[1] - q[1]).abs() < 1e-12, "{p:?}");
        assert!((back.heading.unwrap() - k.heading.unwrap()).abs() < 1e-12);
        let east = RootKey { place: Some([0.0, 0.0]), heading: Some(90f64.to_radians()) };
        let p = point_from_frame([0.0, 0.9, 1.0], east);
        assert!((p[0] - 1.0).abs() < 1e-12 && p[2].abs() < 1e-12 && p[1] == 0.9, "{p:?}");
    }

    use super::*;
    use crate::T2M;

    #[test]
    fn reads_places_headings_and_names_errors() {
        let pose = |k: f64| -> String {
            let j = &diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 0, 0).0.joints[0];
            serde_json::to_string(&j.iter().map(|p| p.map(|v| v * k)).collect::<Vec<_>>()).unwrap()
        };
        let keyed = |k: f64| {
            let text = format!(
                r#"{{"length": 20, "keyframes": [{{"frame": 2, "joints": {}}}]}}"#,
                pose(k)
            );
            KeyframeSpec::parse(&text).unwrap().resolve(&T2M, None, None, 196).map(|_| ())
        };
        keyed(1.0).unwrap();
        let e = keyed(1000.0).unwrap_err().to_string();
        assert!(e.contains("keyframes[0]:") && e.contains("millimetres"), "{e}");
        let spec = KeyframeSpec::parse(r#"{"length": 30, "source": "ignored", "keyframes": [{"frame": 5, "root": [1, 0.9, 2], "heading": 90}]}"#).unwrap();
        let k = spec.resolve(&T2M, None, None, 196).unwrap();
        assert_eq!((k.length, k.frames.clone()), (30, vec![5]));
        assert_eq!(k.root[5].place, Some([1.0, 2.0]));
        assert!((k.root[5].heading.unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(k.values[5 * 263 + 3], 0.9);
        for (text, needle) in [
            (r#"{"length": 1.5, "keyframes": []}"#, "length: invalid type: floating point `1.5`"),
            (
                r#"{"length": 20, "keyframes": [{"frame": -1, "root": [0, 1, 0]}]}"#,
                "keyframes[0].frame: invalid value: integer `-1`",
            ),
            (
                r#"{"length": 20, "keyframes": [{"frame": 3, "root": [1, 2]}]}"#,
                "keyframes[0].root: invalid length 2",
            ),
            (
                r#"{"length": 20, "keyframes": [{"frame": 3, "heading": "north"}]}"#,
                "keyframes[0].heading: invalid type: string \"north\"",
            ),
            (
                r#"{"length": 20, "keyframes": [{"frame": 3, "heding": 90}]}"#,
                "keyframes[0].heding: unknown field `heding`, expected one of `frame`, `joints`, `features`, `root`, `heading` (did you mean `heading`?) at line 1",
            ),
            (r#"{"lenght": 20, "keyframes": []}"#, "(did you mean `length`?)"),
            (r#"{"length": 20, "keyframes": []} trailing"#, "after the JSON object: trailing characters"),
        ] {
            let e = KeyframeSpec::parse(text).map(|_| ()).unwrap_err().to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
        for (text, needle) in [
            (r#"{"length": 500, "keyframes": []}"#, "length: 500 frames; must be 1 to 196"),
            (
                r#"{"length": 20, "keyframes": [{"frame": 25, "features": []}]}"#,
                "keyframes[0]: frame 25 is beyond the length 20",
            ),
            (
                r#"{"length": 20, "keyframes": [{"frame": 2, "features": [1, 2]}]}"#,
                "keyframes[0]: 2 features, expected 263",
            ),
            (
                r#"{"length": 20, "keyframes": [{"frame": 3, "heading": 1e300}]}"#,
                "keyframes[0]: heading 1e300: must be finite degrees",
            ),
            (
                r#"{"length": 20, "joints": "", "keyframes": [{"frame": 2, "root": [0, 1, 0]}]}"#,
                "joints: empty",
            ),
            (r#"{"length": 20, "keyframes": [{"frame": 2}]}"#, "keyframes[0]: needs \"joints\""),
            (
                r#"{"length": 20, "keyframes": [{"frame": 2, "root": [0, 1, 0]}, {"frame": 2, "heading": 5}]}"#,
                "keyframes[1]: frame 2 is keyed twice (also keyframes[0])",
            ),
        ] {
            let e = KeyframeSpec::parse(text)
                .unwrap()
                .resolve(&T2M, None, None, 196)
                .map(|_| ())
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }
}
