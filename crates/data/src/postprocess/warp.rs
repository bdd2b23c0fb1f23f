//! Reaching keyframes exactly without a seam (motion warping): the residual at every keyframe
//! is spread over the neighbouring frames as a smooth displacement, exact at the keys and with
//! zero slope there, so the motion keeps its own velocity through each key.
//!
//! Pose features (root height, root-relative positions, rotations, joint velocities) get a
//! displacement that blends between neighbouring keys and fades to zero over `falloff` frames
//! where keys are far apart. The root's heading and place on the ground cannot fade (the motion
//! would walk back), so they are displaced from frame 0 (the origin, facing +Z, fixed by the
//! representation) to each key and held after the last; the root velocity channels are then
//! rewritten so that they integrate exactly to the displaced trajectory.

use crate::motion::quat::{self, Vec3};
use crate::motion::representation::Layout;
use crate::motion::root_key::{root_trajectory, RootKey};
use crate::postprocess::smoothstep;

/// How a displacement behaves away from its anchors.
#[derive(Clone, Copy, Debug)]
enum Ends {
    /// Fades to zero over this many frames on either side of a key.
    Fade(usize),
    /// Starts at zero at frame 0 and holds its last value after the last key.
    Hold,
}

/// A displacement curve over `len` frames through `anchors` (frame, value; sorted, distinct):
/// equal to the value at each anchor, zero slope there, C1 everywhere.
fn displacement(len: usize, anchors: &[(usize, f64)], ends: Ends) -> Vec<f64> {
    let mut d = vec![0.0; len];
    if anchors.is_empty() {
        return d;
    }
    let mut pts = anchors.to_vec();
    if matches!(ends, Ends::Hold) && pts[0].0 != 0 {
        pts.insert(0, (0, 0.0));
    }
    let (first, last) = (pts[0], pts[pts.len() - 1]);
    for (f, v) in d.iter_mut().enumerate() {
        if f < first.0 {
            if let Ends::Fade(w) = ends {
                let dist = first.0 - f;
                *v = if dist < w {
                    first.1 * (1.0 - smoothstep(dist as f64 / w as f64))
                } else {
                    0.0
                };
            }
        } else if f >= last.0 {
            *v = match ends {
                Ends::Hold => last.1,
                Ends::Fade(w) => {
                    let dist = f - last.0;
                    if dist < w {
                        last.1 * (1.0 - smoothstep(dist as f64 / w as f64))
                    } else {
                        0.0
                    }
                }
            };
        }
    }
    for pair in pts.windows(2) {
        let ((k1, r1), (k2, r2)) = (pair[0], pair[1]);
        let gap = k2 - k1;
        for (f, v) in d.iter_mut().enumerate().take(k2.min(len)).skip(k1) {
            *v = match ends {
                Ends::Fade(w) if gap > 2 * w => {
                    let (a, b) = (f - k1, k2 - f);
                    if a < w {
                        r1 * (1.0 - smoothstep(a as f64 / w as f64))
                    } else if b < w {
                        r2 * (1.0 - smoothstep(b as f64 / w as f64))
                    } else {
                        0.0
                    }
                }
                _ => r1 + (r2 - r1) * smoothstep((f - k1) as f64 / gap as f64),
            };
        }
    }
    d
}

/// Wrap an angle into (-pi, pi].
fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let r = a.rem_euclid(t);
    if r > std::f64::consts::PI {
        r - t
    } else {
        r
    }
}

/// The correction the fit applied at one keyframe: how far the model was from it.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Correction {
    pub frame: usize,
    /// Largest absolute change of an observed pose feature (de-normalised units).
    pub pose: f64,
    /// Distance moved on the ground plane (metres), when the place is keyed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub place_m: Option<f64>,
    /// Heading turned (degrees), when the heading is keyed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_deg: Option<f64>,
}

/// What one motion's keyframes observe, de-normalised.
pub struct Targets<'a> {
    /// [T, D] observed feature values (ignored where `mask` is 0).
    pub features: &'a [f32],
    /// [T, D]
    pub mask: &'a [f32],
    /// One entry per frame (unobserved: both None).
    pub root: &'a [RootKey],
}

/// Warp de-normalised features `feats` [T, D] so that every observed keyframe value, place and
/// heading is met exactly; `falloff` frames is how far a pose correction reaches past a key
/// when the next key is further away. Returns the correction made at each keyed frame.
pub fn warp(
    layout: &Layout,
    feats: &mut [f32],
    targets: &Targets,
    falloff: usize,
) -> Vec<Correction> {
    let d = layout.dim();
    let len = feats.len() / d;
    let keyed = |f: usize| targets.mask[f * d..(f + 1) * d].iter().any(|&m| m > 0.0);
    let mut corr: Vec<Correction> = (0..len)
        .filter(|&f| keyed(f) || targets.root[f] != RootKey::default())
        .map(|frame| Correction { frame, ..Default::default() })
        .collect();
    let slot = |corr: &mut Vec<Correction>, f: usize| corr.iter().position(|c| c.frame == f);
    // Pose: every observed channel except the root's velocities (rewritten below from the
    // trajectory) and the foot contacts (labels, not values to blend).
    for c in 3..layout.contacts().start {
        let observed: Vec<bool> = (0..len).map(|f| targets.mask[f * d + c] > 0.0).collect();
        let key = |f: usize| targets.features[f * d + c] as f64;
        let raw = |f: usize| feats[f * d + c] as f64;
        let mut anchors: Vec<(usize, f64)> =
            (0..len).filter(|&f| observed[f]).map(|f| (f, key(f) - raw(f))).collect();
        if anchors.is_empty() {
            continue;
        }
        for &(f, r) in &anchors {
            if let Some(i) = slot(&mut corr, f) {
                corr[i].pose = corr[i].pose.max(r.abs());
            }
        }
        anchors.extend(continuity_anchors(&observed, key, raw));
        anchors.sort_by_key(|a| a.0);
        for (f, v) in displacement(len, &anchors, Ends::Fade(falloff)).into_iter().enumerate() {
            feats[f * d + c] += v as f32;
        }
    }
    warp_root(feats, d, targets.root, &mut corr);
    corr
}

/// Free frames each side of a run of keys that continue the run's step ([`continuity_anchors`]).
const CONTINUE: usize = 3;

/// Extra anchors for runs of two or more consecutive observed frames: the [`CONTINUE`] free
/// frames just before and just after a run continue the run's own step (`key` linearly
/// extrapolated), so a network that copies a block of keys but jumps on the first frames it is
/// free (a timeline's join) has that jump spread over the fade instead. `observed` per frame;
/// `key(f)` the observed value, `raw(f)` the motion's; returns (frame, residual) pairs.
fn continuity_anchors(
    observed: &[bool],
    key: impl Fn(usize) -> f64,
    raw: impl Fn(usize) -> f64,
) -> Vec<(usize, f64)> {
    let len = observed.len();
    let at = |f: usize| f < len && observed[f];
    let mut out = Vec::new();
    let mut claimed = vec![false; len];
    for b in 1..len {
        // b ends a run of at least two keys: continue it forwards.
        if at(b) && at(b - 1) && !at(b + 1) {
            let step = key(b) - key(b - 1);
            for (i, f) in (b + 1..len).take(CONTINUE).enumerate() {
                if at(f) || claimed[f] {
                    break;
                }
                claimed[f] = true;
                out.push((f, key(b) + step * (i + 1) as f64 - raw(f)));
            }
        }
    }
    for a in 0..len.saturating_sub(1) {
        // a starts a run of at least two keys: continue it backwards.
        if at(a) && at(a + 1) && (a == 0 || !at(a - 1)) {
            let step = key(a) - key(a + 1);
            for (i, f) in (0..a).rev().take(CONTINUE).enumerate() {
                if at(f) || claimed[f] {
                    break;
                }
                claimed[f] = true;
                out.push((f, key(a) + step * (i + 1) as f64 - raw(f)));
            }
        }
    }
    out
}

/// Displace the root's heading, then its place, and rewrite channels 0..3 to integrate to them.
fn warp_root(feats: &mut [f32], d: usize, keys: &[RootKey], corr: &mut [Correction]) {
    let len = feats.len() / d;
    if len < 2 || keys.iter().all(|k| k.place.is_none() && k.heading.is_none()) {
        return;
    }
    // Heading first: channel 0 is the per-frame change of the yaw angle a (heading = -2a).
    let heading_of =
        |t: &[RootKey], f: usize| t[f].heading.expect("a trajectory has every heading");
    let traj = root_trajectory(feats, d);
    // Each correction is taken within half a turn of the one before (the first of zero, frame
    // 0's): a heading is only known modulo a turn, and corrections wrapped one by one would
    // make the body spin the long way round between two keys whose corrections straddle 180°.
    let mut before = 0.0;
    let heading_anchors: Vec<(usize, f64)> = (0..len)
        .filter_map(|f| {
            let h = keys[f].heading?;
            before += wrap(h - heading_of(&traj, f) - before);
            Some((f, before))
        })
        .collect();
    let dh = displacement(len, &heading_anchors, Ends::Hold);
    for f in 0..len - 1 {
        feats[f * d] -= ((dh[f + 1] - dh[f]) / 2.0) as f32;
    }
    // The path the new headings give with the model's own facing-frame steps, then displaced.
    let traj = root_trajectory(feats, d);
    let mut pos: Vec<Vec3> = traj
        .iter()
        .map(|k| k.place.map(|[x, z]| [x, 0.0, z]).expect("a trajectory has every place"))
        .collect();
    let place_anchors: Vec<(usize, [f64; 2])> = (0..len)
        .filter_map(|f| keys[f].place.map(|[x, z]| (f, [x - pos[f][0], z - pos[f][2]])))
        .collect();
    for axis in 0..2 {
        let anchors: Vec<(usize, f64)> = place_anchors.iter().map(|(f, r)| (*f, r[axis])).collect();
        for (p, v) in pos.iter_mut().zip(displacement(len, &anchors, Ends::Hold)) {
            p[axis * 2] += v;
        }
    }
    // Channels 1..3: the displaced path's steps in the facing frame of the next frame (the
    // inverse of `recover_root_rot_pos`).
    for f in 0..len - 1 {
        let q = quat::root_yaw_quat(-heading_of(&traj, f + 1) / 2.0);
        let v = quat::qrot(q, quat::sub(pos[f + 1], pos[f]));
        feats[f * d + 1] = v[0] as f32;
        feats[f * d + 2] = v[2] as f32;
    }
    for c in corr.iter_mut() {
        if let Some(&(_, r)) = heading_anchors.iter().find(|a| a.0 == c.frame) {
            c.heading_deg = Some(wrap(r).to_degrees());
        }
        if let Some(&(_, [x, z])) = place_anchors.iter().find(|a| a.0 == c.frame) {
            c.place_m = Some((x * x + z * z).sqrt());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    const D: usize = 263;

    /// A walking-like motion: steady forward speed, a slow turn, wobbling pose features.
    fn motion(len: usize, seed: u64) -> Vec<f32> {
        let mut r = Rng::new(seed);
        let mut x = vec![0f32; len * D];
        for f in 0..len {
            x[f * D] = 0.01;
            x[f * D + 2] = 0.06;
            x[f * D + 3] = 0.9 + 0.05 * (f as f32 * 0.2).sin();
            for c in 4..D - 4 {
                x[f * D + c] = (f as f32 * 0.1 + c as f32).sin() * 0.3 + r.normal() as f32 * 0.01;
            }
        }
        x
    }

    fn layout() -> Layout {
        Layout::of(&crate::T2M)
    }

    /// A block of keys the motion already meets, then a jump on the first free frame (what a
    /// network that copies keyed frames does at a timeline's join): the warp continues the
    /// block's own step there and spreads the jump over the fade.
    #[test]
    fn a_jump_after_a_block_of_keys_is_spread_out() {
        let len = 60;
        let x = motion(len, 2);
        let mut y = x.clone();
        for f in 20..len {
            for c in 4..D - 4 {
                y[f * D + c] += 0.3;
            }
        }
        let mask: Vec<f32> =
            (0..len * D).map(|k| if (10..20).contains(&(k / D)) { 1.0 } else { 0.0 }).collect();
        let root = vec![RootKey::default(); len];
        warp(&layout(), &mut y, &Targets { features: &x, mask: &mask, root: &root }, 20);
        let c = 100;
        let step = |v: &[f32], f: usize| (v[(f + 1) * D + c] - v[f * D + c]).abs();
        assert!((step(&y, 19) - step(&x, 18)).abs() < 0.05, "{} vs {}", step(&y, 19), step(&x, 18));
        let worst = (19..len - 1).map(|f| (step(&y, f) - step(&x, f)).abs()).fold(0.0, f32::max);
        assert!(worst < 0.05, "the 0.3 jump is spread: largest extra step {worst}");
        for f in 10..20 {
            assert!((y[f * D + c] - x[f * D + c]).abs() < 1e-5, "keys still met");
        }
    }

    #[test]
    fn zero_residual_is_the_identity() {
        let x = motion(80, 1);
        let mut y = x.clone();
        let mask: Vec<f32> =
            (0..80 * D).map(|k| if [10, 40].contains(&(k / D)) { 1.0 } else { 0.0 }).collect();
        let traj = root_trajectory(&x, D);
        let root: Vec<RootKey> = (0..80)
            .map(|f| if f == 40 || f == 70 { traj[f] } else { RootKey::default() })
            .collect();
        warp(&layout(), &mut y, &Targets { features: &x, mask: &mask, root: &root }, 20);
        let worst = x.iter().zip(&y).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn keys_are_hit_smoothly_and_the_root_integrates_to_them() {
        let len = 120;
        let mut x = motion(len, 2);
        let target = motion(len, 3);
        let keys = [15usize, 30, 90];
        let mask: Vec<f32> =
            (0..len * D).map(|k| if keys.contains(&(k / D)) { 1.0 } else { 0.0 }).collect();
        let mut root = vec![RootKey::default(); len];
        root[30] = RootKey { place: Some([1.5, 2.0]), heading: Some(0.7) };
        root[90] = RootKey { place: Some([-0.5, 5.0]), heading: None };
        root[110] = RootKey { place: None, heading: Some(-2.5) };
        let before = x.clone();
        warp(&layout(), &mut x, &Targets { features: &target, mask: &mask, root: &root }, 20);
        // Observed pose features are met at the keys.
        for &f in &keys {
            for c in 3..D - 4 {
                assert!((x[f * D + c] - target[f * D + c]).abs() < 1e-5, "frame {f} channel {c}");
            }
        }
        // The displacement is smooth: bounded second differences everywhere.
        for c in [3usize, 10, 100, 200] {
            let disp: Vec<f32> = (0..len).map(|f| x[f * D + c] - before[f * D + c]).collect();
            let worst = (1..len - 1)
                .map(|f| (disp[f + 1] - 2.0 * disp[f] + disp[f - 1]).abs())
                .fold(0.0, f32::max);
            let scale = disp.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(
                worst <= 6.0 * scale / 15.0f32.powi(2) * 1.5 + 1e-6,
                "channel {c}: {worst} vs {scale}"
            );
        }
        // The rewritten root velocities integrate to the keyed places and headings.
        let traj = root_trajectory(&x, D);
        for (f, k) in root.iter().enumerate() {
            if let Some([px, pz]) = k.place {
                let [gx, gz] = traj[f].place.unwrap();
                assert!((gx - px).abs() < 1e-4 && (gz - pz).abs() < 1e-4, "frame {f}: {gx},{gz}");
            }
            if let Some(h) = k.heading {
                assert!(wrap(traj[f].heading.unwrap() - h).abs() < 1e-5, "frame {f} heading");
            }
        }
        // Frame 0 stays at the origin facing +Z, and the path has no jump.
        assert_eq!(traj[0].place, Some([0.0, 0.0]));
        for f in 1..len {
            let (a, b) = (traj[f - 1].place.unwrap(), traj[f].place.unwrap());
            assert!(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() < 0.2, "step at {f}");
        }
    }

    /// Two keys whose heading corrections straddle 180° (179° and -179° against a motion that
    /// does not turn): the warp turns the 2° between them, not the 358° the other way round.
    #[test]
    fn corrections_across_half_a_turn_take_the_short_way() {
        let len = 60;
        let mut x = motion(len, 5);
        let traj = root_trajectory(&x, D);
        let turned = |f: usize, deg: f64| RootKey {
            place: None,
            heading: Some(traj[f].heading.unwrap() + deg.to_radians()),
        };
        let mut root = vec![RootKey::default(); len];
        root[30] = turned(30, 179.0);
        root[34] = turned(34, -179.0);
        let mask = vec![0f32; len * D];
        let features = x.clone();
        let corr =
            warp(&layout(), &mut x, &Targets { features: &features, mask: &mask, root: &root }, 20);
        let turn: f64 = (30..34).map(|f| (x[f * D] - features[f * D]) as f64 * -2.0).sum();
        assert!((turn.to_degrees() - 2.0).abs() < 1e-3, "turned {} degrees", turn.to_degrees());
        let after = root_trajectory(&x, D);
        for f in [30, 34] {
            let h = root[f].heading.unwrap();
            assert!(wrap(after[f].heading.unwrap() - h).abs() < 1e-5, "frame {f} heading");
        }
        let reported: Vec<f64> = corr.iter().filter_map(|c| c.heading_deg).collect();
        assert!(
            (reported[0] - 179.0).abs() < 1e-3 && (reported[1] + 179.0).abs() < 1e-3,
            "{reported:?}"
        );
    }

    #[test]
    fn root_channels_round_trip() {
        let k = RootKey { place: Some([1.25, -3.0]), heading: Some(-2.0) };
        let (v, m) = k.channels();
        let back = RootKey::from_channels(&v, &m);
        assert!(
            (back.place.unwrap()[0] - 1.25).abs() < 1e-6
                && (back.heading.unwrap() + 2.0).abs() < 1e-6
        );
        let (v, m) = RootKey { place: None, heading: Some(1.0) }.channels();
        assert_eq!(RootKey::from_channels(&v, &m).place, None);
    }

    #[test]
    fn heading_matches_the_recovered_facing_direction() {
        // Facing direction from the hips of recovered joints agrees with heading_of_angle.
        let len = 30;
        let mut x = motion(len, 4);
        for f in 0..len {
            x[f * D] = 0.05;
        }
        let f64s: Vec<f64> = x.iter().map(|&v| v as f64).collect();
        let (quats, _) = crate::motion::representation::recover_root_rot_pos(&f64s, D);
        let traj = root_trajectory(&x, D);
        for f in 0..len {
            let fwd = quat::qrot(quat::qinv(quats[f]), [0.0, 0.0, 1.0]);
            let h = fwd[0].atan2(fwd[2]);
            assert!(wrap(h - traj[f].heading.unwrap()).abs() < 1e-9, "frame {f}");
        }
    }
}
