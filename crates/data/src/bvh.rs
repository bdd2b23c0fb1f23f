//! BVH export and import of joint-position motions on a skeleton, positions in centimetres.
//!
//! Rotations come from HumanML3D's inverse kinematics, whose local rotation of joint j turns the
//! bone *ending* at j; BVH rotates the bones leaving a joint. Where a joint has one child the two
//! agree after a shift along the chain; where it has several (the pelvis, spine3) each child gets
//! a zero-length `<parent>_to_<child>` joint carrying that bone's rotation. The export
//! reproduces the input positions exactly (up to float rounding; tested).

use std::fmt::Write;

use crate::quat::{self, Quat, Vec3};
use crate::representation::{inverse_kinematics, Joints};
use crate::skeleton::Skeleton;
use crate::DataError;

const CM: f64 = 100.0;

/// A BVH node: a skeleton joint, or a zero-length joint before a child of a branching joint.
struct Node {
    name: String,
    parent: Option<usize>,
    offset: Vec3,
    /// Which skeleton bone's global rotation this node carries (None: its parent's).
    bone: Option<usize>,
    end_site: bool,
}

fn children(skel: &Skeleton, j: usize) -> Vec<usize> {
    let p = skel.parents();
    (0..skel.num_joints()).filter(|&c| p[c] == j as i64).collect()
}

fn nodes(skel: &Skeleton) -> Vec<Node> {
    let offsets = skel.target_offsets().unwrap_or_else(|| skel.raw_offsets.to_vec());
    let mut out = Vec::new();
    fn add(skel: &Skeleton, offsets: &[Vec3], j: usize, parent: Option<usize>, out: &mut Vec<Node>) {
        let kids = children(skel, j);
        let idx = out.len();
        let bone = match kids.len() {
            1 => Some(kids[0]),
            0 => None,
            _ => (j == 0).then_some(0),
        };
        out.push(Node { name: skel.joint_names[j].to_string(), parent, offset: if parent.is_some() { offsets[j] } else { [0.0; 3] }, bone, end_site: kids.is_empty() });
        if kids.len() > 1 {
            for &c in &kids {
                let d = out.len();
                out.push(Node { name: format!("{}_to_{}", skel.joint_names[j], skel.joint_names[c]), parent: Some(idx), offset: [0.0; 3], bone: Some(c), end_site: false });
                add(skel, offsets, c, Some(d), out);
            }
        } else {
            for &c in &kids {
                add(skel, offsets, c, Some(idx), out);
            }
        }
    }
    add(skel, &offsets, 0, None, &mut out);
    out
}

/// Euler angles (degrees) for channels "Zrotation Yrotation Xrotation": R = Rz Ry Rx.
fn zyx_degrees(q: Quat) -> [f64; 3] {
    let m = quat::to_matrix(q);
    let b = (-m[2][0]).clamp(-1.0, 1.0).asin();
    let (a, c) = if m[2][0].abs() < 1.0 - 1e-9 { (m[1][0].atan2(m[0][0]), m[2][1].atan2(m[2][2])) } else { ((-m[0][1]).atan2(m[1][1]), 0.0) };
    [a.to_degrees(), b.to_degrees(), c.to_degrees()]
}

fn from_zyx_degrees(z: f64, y: f64, x: f64) -> Quat {
    let qz = quat::from_axis_angle([0.0, 0.0, 1.0], z.to_radians());
    let qy = quat::from_axis_angle([0.0, 1.0, 0.0], y.to_radians());
    let qx = quat::from_axis_angle([1.0, 0.0, 0.0], x.to_radians());
    quat::qmul(quat::qmul(qz, qy), qx)
}

/// BVH text of a motion (Y up, centimetres).
pub fn write(skel: &Skeleton, j: &Joints) -> String {
    let ns = nodes(skel);
    let local = inverse_kinematics(skel, j, false);
    let mut s = String::from("HIERARCHY\n");
    fn hier(ns: &[Node], i: usize, depth: usize, s: &mut String) {
        let ind = "  ".repeat(depth);
        let kw = if depth == 0 { "ROOT" } else { "JOINT" };
        let o = ns[i].offset;
        let _ = writeln!(s, "{ind}{kw} {}\n{ind}{{\n{ind}  OFFSET {:.6} {:.6} {:.6}", ns[i].name, o[0] * CM, o[1] * CM, o[2] * CM);
        let ch = if depth == 0 { "CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation" } else { "CHANNELS 3 Zrotation Yrotation Xrotation" };
        let _ = writeln!(s, "{ind}  {ch}");
        for k in (0..ns.len()).filter(|&k| ns[k].parent == Some(i)) {
            hier(ns, k, depth + 1, s);
        }
        if ns[i].end_site {
            let _ = writeln!(s, "{ind}  End Site\n{ind}  {{\n{ind}    OFFSET 0.000000 0.000000 0.000000\n{ind}  }}");
        }
        let _ = writeln!(s, "{ind}}}");
    }
    hier(&ns, 0, 0, &mut s);
    let _ = writeln!(s, "MOTION\nFrames: {}\nFrame Time: {:.6}", j.len(), 1.0 / skel.fps);
    for (f, q) in local.iter().enumerate() {
        // Global rotation of every bone: as HumanML3D's forward kinematics, each chain starts
        // from the root rotation (not from its first joint's accumulated rotation).
        let mut g = vec![quat::IDENTITY; skel.num_joints()];
        g[0] = q[0];
        for chain in skel.kinematic_chain {
            let mut r = q[0];
            for &c in &chain[1..] {
                r = quat::qmul(r, q[c]);
                g[c] = r;
            }
        }
        let mut node_g = vec![quat::IDENTITY; ns.len()];
        let mut row = Vec::new();
        for (i, n) in ns.iter().enumerate() {
            let pg = n.parent.map(|p| node_g[p]).unwrap_or(quat::IDENTITY);
            node_g[i] = n.bone.map(|b| g[b]).unwrap_or(pg);
            let l = quat::qmul(quat::qinv(pg), node_g[i]);
            if i == 0 {
                row.extend(j[f][0].iter().map(|v| v * CM));
            }
            row.extend(zyx_degrees(l));
        }
        let line: Vec<String> = row.iter().map(|v| format!("{v:.6}")).collect();
        let _ = writeln!(s, "{}", line.join(" "));
    }
    s
}

/// Joint positions (metres) of a BVH written by [`write`] (joints found by name).
pub fn read(skel: &Skeleton, text: &str) -> Result<Joints, DataError> {
    let bad = |m: &str| DataError::Invalid(format!("BVH: {m}"));
    let (hier, motion) = text.split_once("MOTION").ok_or_else(|| bad("no MOTION section"))?;
    // Parse the hierarchy: names, parents, offsets, channel counts.
    let (mut names, mut parents, mut offsets, mut chans) = (Vec::<String>::new(), Vec::<Option<usize>>::new(), Vec::<Vec3>::new(), Vec::<usize>::new());
    let mut stack: Vec<Option<usize>> = Vec::new();
    let mut pending: Option<usize> = None;
    let mut in_end = false;
    for line in hier.lines().map(str::trim) {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("ROOT") | Some("JOINT") => {
                let parent = stack.last().copied().flatten();
                names.push(it.next().ok_or_else(|| bad("joint without a name"))?.to_string());
                parents.push(parent);
                offsets.push([0.0; 3]);
                chans.push(0);
                pending = Some(names.len() - 1);
            }
            Some("End") => in_end = true,
            Some("{") => stack.push(if in_end { None } else { pending }),
            Some("}") => {
                if stack.pop().flatten().is_none() {
                    in_end = false;
                }
            }
            Some("OFFSET") if !in_end => {
                let v: Vec<f64> = it.map(|x| x.parse().map_err(|_| bad("bad OFFSET"))).collect::<Result<_, _>>()?;
                if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
                    return Err(bad("OFFSET needs three finite numbers"));
                }
                let k = stack.last().copied().flatten().ok_or_else(|| bad("OFFSET outside a joint"))?;
                offsets[k] = [v[0] / CM, v[1] / CM, v[2] / CM];
            }
            Some("CHANNELS") => {
                let k = stack.last().copied().flatten().ok_or_else(|| bad("CHANNELS outside a joint"))?;
                chans[k] = it.next().and_then(|n| n.parse().ok()).ok_or_else(|| bad("bad CHANNELS"))?;
            }
            _ => {}
        }
    }
    if let Some(k) = chans.iter().position(|&c| c != 3 && c != 6) {
        return Err(bad(&format!("joint '{}' has {} channels; this reader takes 3 (rotation) or 6 (position and rotation)", names[k], chans[k])));
    }
    let per_frame: usize = chans.iter().sum();
    let index: Vec<usize> = skel.joint_names.iter().map(|n| names.iter().position(|m| m == n).ok_or_else(|| bad(&format!("joint '{n}' missing")))).collect::<Result<_, _>>()?;
    if let Some(ft) = motion.lines().map(str::trim).find_map(|l| l.strip_prefix("Frame Time:")) {
        let ft: f64 = ft.trim().parse().map_err(|_| bad(&format!("Frame Time '{}' is not a number", ft.trim())))?;
        if !(ft.is_finite() && ft > 0.0) {
            return Err(bad(&format!("Frame Time {ft} must be a positive number of seconds")));
        }
    }
    let mut out = Vec::new();
    for line in motion.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("Frames") && !l.starts_with("Frame Time")) {
        let v: Vec<f64> = line.split_whitespace().map(|x| x.parse().map_err(|_| bad("bad number in MOTION"))).collect::<Result<_, _>>()?;
        if v.len() != per_frame {
            return Err(bad(&format!("a frame has {} values, expected {per_frame}", v.len())));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(bad("a frame has a value that is not finite"));
        }
        let (mut pos, mut g) = (vec![[0.0; 3]; names.len()], vec![quat::IDENTITY; names.len()]);
        let mut c = 0;
        for k in 0..names.len() {
            let (pp, pg) = parents[k].map(|p| (pos[p], g[p])).unwrap_or(([0.0; 3], quat::IDENTITY));
            if chans[k] == 6 {
                pos[k] = [v[c] / CM, v[c + 1] / CM, v[c + 2] / CM];
                c += 3;
            } else {
                pos[k] = quat::add(pp, quat::qrot(pg, offsets[k]));
            }
            g[k] = quat::qmul(pg, from_zyx_degrees(v[c], v[c + 1], v[c + 2]));
            c += 3;
        }
        out.push(index.iter().map(|&k| pos[k]).collect());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{fixtures, npy, representation as rep, T2M};

    #[test]
    fn euler_round_trip() {
        let q = quat::from_axis_angle([0.3, -1.0, 0.4], 1.1);
        let [z, y, x] = zyx_degrees(q);
        let r = from_zyx_degrees(z, y, x);
        let v = [0.2, 0.5, -0.7];
        let (a, b) = (quat::qrot(q, v), quat::qrot(r, v));
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-9));
    }

    /// Real motion -> BVH -> positions: the same motion (on the target skeleton).
    #[test]
    fn round_trip_real_motion() {
        let Some(p) = fixtures::require("humanml3d/new_joints/012314.npy") else {
            return;
        };
        let a = npy::read_f64(p).unwrap();
        let j = rep::joints_from_array(&a.data, 170, 22, 22);
        // BVH carries the target skeleton's bone lengths; compare against the retargeted motion.
        let j = rep::uniform_skeleton(&T2M, &j).unwrap();
        let text = write(&T2M, &j);
        assert!(text.contains("ROOT pelvis") && text.contains("JOINT pelvis_to_l_hip") && text.contains("Frames: 170"));
        let back = read(&T2M, &text).unwrap();
        let e = back.iter().flatten().zip(j.iter().flatten()).map(|(x, y)| quat::norm(quat::sub(*x, *y))).fold(0.0, f64::max);
        assert!(e < 1e-4, "BVH round trip error {e} m");
        assert!(read(&T2M, "HIERARCHY\n").is_err());
    }
}
