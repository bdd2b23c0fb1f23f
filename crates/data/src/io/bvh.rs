//! The BVH format: a joint hierarchy with rest offsets, per-joint channels and frames of values.
//! [`Bvh::parse`] reads any BVH (any channel order, position channels on any joint);
//! [`Bvh::world_positions`] is plain BVH forward kinematics: a joint's position is its parent's
//! plus the parent's global rotation applied to the joint's offset, and each joint's rotation is
//! the product of its rotation channels in the order they are listed (Blender's reading).
//! Mapping a file onto a skeleton, and fitting a skeleton's motion into a rig, live in `rig.rs`.

use std::fmt::Write;

use crate::motion::quat::{self, Quat, Vec3};
use crate::DataError;

/// One channel of a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    Position(usize),
    Rotation(usize),
}

impl Channel {
    fn parse(s: &str) -> Option<Channel> {
        let axis = match s.as_bytes().first()?.to_ascii_lowercase() {
            b'x' => 0,
            b'y' => 1,
            b'z' => 2,
            _ => return None,
        };
        match s[1..].to_ascii_lowercase().as_str() {
            "position" => Some(Channel::Position(axis)),
            "rotation" => Some(Channel::Rotation(axis)),
            _ => None,
        }
    }

    fn name(self) -> String {
        let (a, kind) = match self {
            Channel::Position(a) => (a, "position"),
            Channel::Rotation(a) => (a, "rotation"),
        };
        format!("{}{kind}", ["X", "Y", "Z"][a])
    }
}

/// A joint of the hierarchy (End Sites are kept as `end_site` of their joint).
#[derive(Clone, Debug)]
pub struct BvhJoint {
    pub name: String,
    pub parent: Option<usize>,
    pub offset: Vec3,
    pub channels: Vec<Channel>,
    pub end_site: Option<Vec3>,
}

/// A whole BVH file: joints in file order (parents before children), frames of channel values.
#[derive(Clone, Debug)]
pub struct Bvh {
    pub joints: Vec<BvhJoint>,
    pub frame_time: f64,
    pub frames: Vec<Vec<f64>>,
}

fn bad(m: impl std::fmt::Display) -> DataError {
    DataError::Invalid(format!("BVH: {m}"))
}

/// Rotation of Euler angles (degrees) applied in the listed axis order: R = R(a0) R(a1) R(a2).
pub fn euler_to_quat(axes: [usize; 3], deg: [f64; 3]) -> Quat {
    let mut q = quat::IDENTITY;
    for (a, d) in axes.iter().zip(deg) {
        let mut axis = [0.0; 3];
        axis[*a] = 1.0;
        q = quat::qmul(q, quat::from_axis_angle(axis, d.to_radians()));
    }
    q
}

/// Euler angles (degrees) for channels "Zrotation Yrotation Xrotation" (R = Rz Ry Rx), the one
/// of the two equivalent solutions (with whole turns added) nearest to `prev`, so that curves
/// do not flip between frames.
pub fn zyx_degrees(q: Quat, prev: Option<[f64; 3]>) -> [f64; 3] {
    let m = quat::to_matrix(q);
    let b = (-m[2][0]).clamp(-1.0, 1.0).asin();
    let (a, c) = if m[2][0].abs() < 1.0 - 1e-9 {
        (m[1][0].atan2(m[0][0]), m[2][1].atan2(m[2][2]))
    } else {
        ((-m[0][1]).atan2(m[1][1]), 0.0)
    };
    let first = [a.to_degrees(), b.to_degrees(), c.to_degrees()];
    let Some(p) = prev else {
        return first;
    };
    let second = [first[0] + 180.0, 180.0 - first[1], first[2] + 180.0];
    let near = |v: [f64; 3]| {
        v.iter().zip(p).map(|(x, p)| x + 360.0 * ((p - x) / 360.0).round()).collect::<Vec<_>>()
    };
    let (u, w) = (near(first), near(second));
    let dist = |v: &[f64]| v.iter().zip(p).map(|(x, p)| (x - p).abs()).sum::<f64>();
    let best = if dist(&u) <= dist(&w) { u } else { w };
    [best[0], best[1], best[2]]
}

/// The HIERARCHY section: one ROOT and its JOINTs (parents before children), their offsets,
/// channels and End Sites; at least one offset not zero.
fn parse_hierarchy(hier: &str) -> Result<Vec<BvhJoint>, DataError> {
    let mut joints: Vec<BvhJoint> = Vec::new();
    // Stack of open blocks: Some(joint) or None for an End Site.
    let mut stack: Vec<Option<usize>> = Vec::new();
    let (mut pending, mut in_end) = (None::<usize>, false);
    let mut end_offset = [0.0; 3];
    let open_joint = |stack: &[Option<usize>], what: &str| {
        stack.last().copied().flatten().ok_or_else(|| bad(format!("{what} outside a joint")))
    };
    for line in hier.lines().map(str::trim) {
        let mut it = line.split_whitespace();
        match it.next() {
            Some(kw @ ("ROOT" | "JOINT")) => {
                let parent = stack.last().copied().flatten();
                joints.push(new_joint(kw, it, parent, joints.is_empty())?);
                pending = Some(joints.len() - 1);
            }
            Some("End") => in_end = true,
            Some("{") => stack.push(if in_end { None } else { pending }),
            Some("}") => match stack.pop() {
                Some(None) => {
                    in_end = false;
                    joints[open_joint(&stack, "End Site")?].end_site = Some(end_offset);
                }
                Some(Some(_)) => {}
                None => return Err(bad("unbalanced '}'")),
            },
            Some("OFFSET") if in_end => end_offset = parse_offset(it)?,
            Some("OFFSET") => joints[open_joint(&stack, "OFFSET")?].offset = parse_offset(it)?,
            Some("CHANNELS") => {
                let k = open_joint(&stack, "CHANNELS")?;
                joints[k].channels = parse_channels(it, &joints[k].name)?;
            }
            _ => {}
        }
    }
    if joints.is_empty() {
        return Err(bad("no ROOT joint"));
    }
    if !stack.is_empty() {
        return Err(bad("unclosed '{' in HIERARCHY"));
    }
    if joints.iter().all(|j| j.offset == [0.0; 3] && j.end_site.is_none_or(|e| e == [0.0; 3])) {
        return Err(bad("every OFFSET is zero: the hierarchy has no bones"));
    }
    Ok(joints)
}

/// The joint a `ROOT` or `JOINT` line (`kw`, then its name in `it`) opens under `parent`: a
/// ROOT first, a JOINT after it, never a second ROOT.
fn new_joint<'a>(
    kw: &str,
    it: impl Iterator<Item = &'a str>,
    parent: Option<usize>,
    first: bool,
) -> Result<BvhJoint, DataError> {
    if first && kw != "ROOT" {
        return Err(bad("the hierarchy starts with a JOINT, not a ROOT"));
    }
    if parent.is_none() && !first {
        return Err(bad("a second ROOT (one skeleton per file is read)"));
    }
    let name = it.collect::<Vec<_>>().join(" ");
    if name.is_empty() {
        return Err(bad("joint without a name"));
    }
    Ok(BvhJoint { name, parent, offset: [0.0; 3], channels: Vec::new(), end_site: None })
}

/// The three finite numbers after `OFFSET`.
fn parse_offset<'a>(it: impl Iterator<Item = &'a str>) -> Result<Vec3, DataError> {
    let v: Vec<f64> = it
        .map(|x| x.parse().map_err(|_| bad(format!("OFFSET value '{x}' is not a number"))))
        .collect::<Result<_, _>>()?;
    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
        return Err(bad("OFFSET needs three finite numbers"));
    }
    Ok([v[0], v[1], v[2]])
}

/// The count and names after `CHANNELS` of joint `name`: 3 rotations, optionally after 3
/// positions.
fn parse_channels<'a>(
    mut it: impl Iterator<Item = &'a str>,
    name: &str,
) -> Result<Vec<Channel>, DataError> {
    let n: usize =
        it.next().and_then(|n| n.parse().ok()).ok_or_else(|| bad("CHANNELS needs a count"))?;
    let ch: Vec<Channel> = it
        .map(|c| {
            Channel::parse(c).ok_or_else(|| bad(format!("joint '{name}': unknown channel '{c}'")))
        })
        .collect::<Result<_, _>>()?;
    if ch.len() != n {
        return Err(bad(format!("joint '{name}': CHANNELS says {n} but lists {}", ch.len())));
    }
    if ch.iter().filter(|c| matches!(c, Channel::Rotation(_))).count() % 3 != 0 || ch.len() > 6 {
        return Err(bad(format!(
            "joint '{name}': channels must be 3 rotations, optionally after 3 positions"
        )));
    }
    Ok(ch)
}

/// Largest channel value read: a position of 100 km in metres (or 1 km in centimetres) or
/// 1e5 degrees is a broken file, not a motion.
const MAX_CHANNEL_VALUE: f64 = 1e5;
/// Most frames read (about 14 hours at 20 fps).
pub const MAX_FRAMES: usize = 1_000_000;

/// The MOTION section: `Frames: N` (present, a count that matches the frame lines),
/// `Frame Time: s` and N lines of finite channel values of plausible size.
fn parse_motion(motion: &str, joints: &[BvhJoint]) -> Result<(f64, Vec<Vec<f64>>), DataError> {
    let names: Vec<(String, Channel)> =
        joints.iter().flat_map(|j| j.channels.iter().map(move |c| (j.name.clone(), *c))).collect();
    let (mut frame_time, mut declared) = (None, None);
    let mut frames = Vec::new();
    for line in motion.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if let Some(ft) = line.strip_prefix("Frame Time:") {
            let ft: f64 = ft
                .trim()
                .parse()
                .map_err(|_| bad(format!("Frame Time '{}' is not a number", ft.trim())))?;
            if !(ft.is_finite() && ft > 0.0) {
                return Err(bad(format!("Frame Time {ft} must be a positive number of seconds")));
            }
            frame_time = Some(ft);
            continue;
        }
        if let Some(n) = line.strip_prefix("Frames:") {
            let n = n.trim();
            declared = match n.parse::<usize>() {
                Ok(n) if n <= MAX_FRAMES => Some(n),
                _ => {
                    return Err(bad(format!(
                        "'Frames: {n}' is not a frame count from 0 to {MAX_FRAMES}"
                    )))
                }
            };
            continue;
        }
        if frames.len() >= declared.unwrap_or(0) {
            return Err(match declared {
                None => bad("no 'Frames:' line before the frame values"),
                Some(n) => bad(format!("more frame lines than 'Frames: {n}' says")),
            });
        }
        frames.push(frame_values(line, frames.len(), &names)?);
    }
    let frame_time = frame_time.ok_or_else(|| bad("no 'Frame Time:' line"))?;
    match declared {
        None => Err(bad("no 'Frames:' line")),
        Some(n) if n != frames.len() => {
            Err(bad(format!("'Frames: {n}' but the file has {} frame lines", frames.len())))
        }
        Some(_) => Ok((frame_time, frames)),
    }
}

/// Frame `f`'s channel values from its line: one number per channel (`names`: each channel's
/// joint and kind), finite and of plausible size.
fn frame_values(line: &str, f: usize, names: &[(String, Channel)]) -> Result<Vec<f64>, DataError> {
    let v: Vec<f64> = line
        .split_whitespace()
        .map(|x| x.parse().map_err(|_| bad(format!("frame {f}: '{x}' is not a number"))))
        .collect::<Result<_, _>>()?;
    if v.len() != names.len() {
        return Err(bad(format!(
            "frame {f} has {} values, the hierarchy's channels need {}",
            v.len(),
            names.len()
        )));
    }
    if let Some(k) = v.iter().position(|x| !crate::motion::magnitude::within(*x, MAX_CHANNEL_VALUE))
    {
        let (joint, ch) = &names[k];
        return Err(bad(format!("frame {f}: joint '{joint}' {} is {}; values must be finite and at most {MAX_CHANNEL_VALUE:e} in size", ch.name(), v[k])));
    }
    Ok(v)
}

impl Bvh {
    /// Parse BVH text; errors name what is wrong (and the frame, for values).
    pub fn parse(text: &str) -> Result<Bvh, DataError> {
        let (hier, motion) = text.split_once("MOTION").ok_or_else(|| bad("no MOTION section"))?;
        let joints = parse_hierarchy(hier)?;
        let (frame_time, frames) = parse_motion(motion, &joints)?;
        Ok(Bvh { joints, frame_time, frames })
    }

    /// BVH text (six decimals).
    pub fn to_text(&self) -> String {
        let mut s = String::from("HIERARCHY\n");
        self.write_joint(0, 0, &mut s);
        let _ = writeln!(
            s,
            "MOTION\nFrames: {}\nFrame Time: {:.6}",
            self.frames.len(),
            self.frame_time
        );
        for f in &self.frames {
            let line: Vec<String> = f.iter().map(|v| format!("{v:.6}")).collect();
            let _ = writeln!(s, "{}", line.join(" "));
        }
        s
    }

    fn write_joint(&self, i: usize, depth: usize, s: &mut String) {
        let ind = "  ".repeat(depth);
        let j = &self.joints[i];
        let kw = if j.parent.is_none() { "ROOT" } else { "JOINT" };
        let o = j.offset;
        let _ = writeln!(
            s,
            "{ind}{kw} {}\n{ind}{{\n{ind}  OFFSET {:.6} {:.6} {:.6}",
            j.name, o[0], o[1], o[2]
        );
        let ch: Vec<String> = j.channels.iter().map(|c| c.name()).collect();
        let _ = writeln!(s, "{ind}  CHANNELS {} {}", ch.len(), ch.join(" "));
        for k in (0..self.joints.len()).filter(|&k| self.joints[k].parent == Some(i)) {
            self.write_joint(k, depth + 1, s);
        }
        if let Some(e) = j.end_site {
            let _ = writeln!(
                s,
                "{ind}  End Site\n{ind}  {{\n{ind}    OFFSET {:.6} {:.6} {:.6}\n{ind}  }}",
                e[0], e[1], e[2]
            );
        }
        let _ = writeln!(s, "{ind}}}");
    }

    /// Position of every joint at every frame, in the file's units and axes.
    pub fn world_positions(&self) -> Vec<Vec<Vec3>> {
        let n = self.joints.len();
        self.frames
            .iter()
            .map(|v| {
                let (mut pos, mut g) = (vec![[0.0; 3]; n], vec![quat::IDENTITY; n]);
                let mut c = 0;
                for (k, j) in self.joints.iter().enumerate() {
                    let (pp, pg) =
                        j.parent.map(|p| (pos[p], g[p])).unwrap_or(([0.0; 3], quat::IDENTITY));
                    let mut local = j.offset;
                    let (mut axes, mut deg, mut r) = ([0; 3], [0.0; 3], 0);
                    for ch in &j.channels {
                        match *ch {
                            Channel::Position(a) => local[a] = v[c],
                            Channel::Rotation(a) if r < 3 => {
                                axes[r] = a;
                                deg[r] = v[c];
                                r += 1;
                            }
                            Channel::Rotation(_) => {}
                        }
                        c += 1;
                    }
                    pos[k] = quat::add(pp, quat::qrot(pg, local));
                    g[k] = if r == 3 { quat::qmul(pg, euler_to_quat(axes, deg)) } else { pg };
                }
                pos
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_round_trip_and_continuity() {
        let q = quat::from_axis_angle([0.3, -1.0, 0.4], 1.1);
        let d = zyx_degrees(q, None);
        let r = euler_to_quat([2, 1, 0], d);
        let v = [0.2, 0.5, -0.7];
        let (a, b) = (quat::qrot(q, v), quat::qrot(r, v));
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-9));
        // A half-turn about Z and a little more: the nearest solution to 179 degrees is 181, not -179.
        let q = quat::from_axis_angle([0.0, 0.0, 1.0], 181f64.to_radians());
        let d = zyx_degrees(q, Some([179.0, 0.0, 0.0]));
        assert!((d[0] - 181.0).abs() < 1e-9 && d[1].abs() < 1e-9, "{d:?}");
        let back = euler_to_quat([2, 1, 0], d);
        assert!(quat::dot([back[1], back[2], back[3]], [q[1], q[2], q[3]]).abs() > 0.99);
    }

    /// A hand-written two-bone file: the forearm turned 90 degrees about Z puts the hand on +Y.
    #[test]
    fn forward_kinematics_by_the_convention() {
        let text = "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\n JOINT b\n {\n  OFFSET 10 0 0\n  CHANNELS 3 Xrotation Zrotation Yrotation\n  JOINT c\n  {\n   OFFSET 5 0 0\n   CHANNELS 3 Zrotation Xrotation Yrotation\n   End Site\n   {\n    OFFSET 1 0 0\n   }\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.05\n1 2 3 0 0 0 0 90 0 0 0 0\n";
        let b = Bvh::parse(text).unwrap();
        assert_eq!(b.joints.len(), 3);
        assert_eq!(b.joints[2].end_site, Some([1.0, 0.0, 0.0]));
        let p = &b.world_positions()[0];
        let want = [[1.0, 2.0, 3.0], [11.0, 2.0, 3.0], [11.0, 7.0, 3.0]];
        for (x, y) in p.iter().zip(want) {
            assert!(quat::norm(quat::sub(*x, y)) < 1e-9, "{p:?}");
        }
        let again = Bvh::parse(&b.to_text()).unwrap();
        assert_eq!(again.world_positions(), b.world_positions());
        for broken in [
            "HIERARCHY\n",
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 x\n}\nMOTION\nFrame Time: 0.1\n",
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\nFrame Time: 0.1\n1 2\n",
        ] {
            assert!(Bvh::parse(broken).is_err(), "{broken}");
        }
    }

    /// Headers and values a broken exporter writes are refused with what is wrong, never read.
    #[test]
    fn broken_headers_and_values_are_refused() {
        let good = "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\n JOINT b\n {\n  OFFSET 10 0 0\n  CHANNELS 3 Zrotation Yrotation Xrotation\n  End Site\n  {\n   OFFSET 1 0 0\n  }\n }\n}\nMOTION\nFrames: 2\nFrame Time: 0.05\n1 2 3 0 0 0 0 0 0\n1 2 3 0 0 0 0 0 0\n";
        assert_eq!(Bvh::parse(good).unwrap().frames.len(), 2);
        for (from, to, why) in [
            ("Frames: 2", "Frames: -2", "Frames: -2"),
            ("Frames: 2", "Frames: 99999999999999999999999", "not a frame count"),
            ("Frames: 2", "Frames: two", "not a frame count"),
            ("Frames: 2\n", "", "no 'Frames:' line"),
            ("Frames: 2", "Frames: 1", "more frame lines"),
            ("Frames: 2", "Frames: 3", "'Frames: 3' but the file has 2"),
            ("ROOT a", "JOINT a", "not a ROOT"),
            ("}\nMOTION", "}\nROOT c\n{\n OFFSET 1 0 0\n}\nMOTION", "a second ROOT"),
            ("JOINT b", "JOINT  ", "joint without a name"),
            ("OFFSET 10 0 0\n  CHANNELS 3 Zrotation Yrotation Xrotation\n  End Site\n  {\n   OFFSET 1 0 0", "OFFSET 0 0 0\n  CHANNELS 3 Zrotation Yrotation Xrotation\n  End Site\n  {\n   OFFSET 0 0 0", "every OFFSET is zero"),
            (
                "\n1 2 3 0 0 0 0 0 0\n",
                "\n1 2 1e30 0 0 0 0 0 0\n",
                "joint 'a' Zposition is 1000000000000000000000000000000",
            ),
            ("\n1 2 3 0 0 0 0 0 0\n", "\n1 2 3 0 0 0 0 1e308 0\n", "joint 'b' Yrotation"),
        ] {
            let e = Bvh::parse(&good.replacen(from, to, 1)).unwrap_err().to_string();
            assert!(e.contains(why), "{from} -> {to}: {e}");
        }
    }
}
