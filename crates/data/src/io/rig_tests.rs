use super::super::rig_names::{convention_names, T2M_CONVENTIONS};
use super::*;
use crate::{io::npy, motion::representation as rep, testing::fixtures, T2M};

fn real_walk() -> Option<Joints> {
    let p = fixtures::require("humanml3d/new_joints/012314.npy")?;
    let a = npy::read_f64(p).unwrap();
    Some(rep::joints_from_array(&a.data, 170, 22, 22))
}

fn max_err(a: &Joints, b: &Joints) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| quat::norm(quat::sub(*x, *y)))
        .fold(0.0, f64::max)
}

#[test]
fn best_rotation_recovers_a_rotation() {
    let q = quat::from_axis_angle([0.3, -1.0, 0.4], 2.5);
    let from = [[0.1, 0.0, 0.02], [-0.1, -0.01, 0.0], [0.0, 0.12, -0.03]];
    let to: Vec<Vec3> = from.iter().map(|v| quat::qrot(q, *v)).collect();
    let r = best_rotation(&from, &to);
    for v in from {
        assert!(quat::norm(quat::sub(quat::qrot(r, v), quat::qrot(q, v))) < 1e-12);
    }
}

/// A real HumanML3D clip (rigid bones) through the rig and back: the same joints, read by plain
/// BVH forward kinematics of the text.
#[test]
fn real_motion_is_reproduced_exactly() {
    let Some(j) = real_walk() else {
        return;
    };
    let text = write(&T2M, &j);
    let b = Bvh::parse(&text).unwrap();
    let names: Vec<&str> = b.joints.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(names.len(), 22, "no helper joints: {names:?}");
    for n in T2M_NAMES {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    assert_eq!(b.joints[0].offset, [0.0; 3]);
    let back = read(&T2M, &text, &ImportOptions::default()).unwrap();
    let e = max_err(&back, &j);
    assert!(e < 1e-5, "real clip reproduced to {e} m");
}

/// The rest pose is a T-pose: arms straight out along +-X, legs down, spine up, feet forward.
#[test]
fn rest_pose_is_a_t_pose() {
    let Some(j) = real_walk() else {
        return;
    };
    let b = export(&T2M, &j);
    let off = |n: &str| quat::normalize(b.joints.iter().find(|j| j.name == n).unwrap().offset);
    for (n, d) in [
        ("LeftArm", [1.0, 0.0, 0.0]),
        ("LeftHand", [1.0, 0.0, 0.0]),
        ("RightForeArm", [-1.0, 0.0, 0.0]),
        ("LeftLeg", [0.0, -1.0, 0.0]),
        ("RightFoot", [0.0, -1.0, 0.0]),
        ("LeftToe", [0.0, 0.0, 1.0]),
        ("Spine1", [0.0, 1.0, 0.0]),
        ("Head", [0.0, 1.0, 0.0]),
    ] {
        assert!(quat::dot(off(n), d) > 0.999, "{n}: {:?}", off(n));
    }
    // The hips sit beside the pelvis (left on +X), the spine above it.
    assert!(off("LeftUpLeg")[0] > 0.5 && off("RightUpLeg")[0] < -0.5 && off("Spine")[1] > 0.7);
}

/// Bones that stretch from frame to frame (as generated motion's do) cannot be reproduced by a
/// rigid rig; the error stays at the size of the stretch.
#[test]
fn stretching_bones_give_an_error_the_size_of_the_stretch() {
    let Some(mut j) = real_walk() else {
        return;
    };
    let parents = T2M.parents();
    for (t, f) in j.iter_mut().enumerate() {
        // Stretch the left forearm by up to 1 cm, moving the wrist.
        let s = 0.01 * (t as f64 * 0.3).sin();
        let d = quat::normalize(quat::sub(f[20], f[parents[20] as usize]));
        f[20] = quat::add(f[20], quat::scale(d, s));
    }
    let b = export(&T2M, &j);
    let (mean, max) = export_error(&T2M, &j, &b);
    assert!(max < 0.0105 && max > 0.005 && mean < 0.001, "mean {mean} max {max}");
}

/// Renamed (Mixamo with a namespace, CMU, old snake_case), rescaled (inches), turned (Z up)
/// and at 40 fps: each is read back to the same motion at 20 fps.
#[test]
fn common_rigs_units_axes_and_rates_import() {
    let Some(j) = real_walk() else {
        return;
    };
    let base = export(&T2M, &j);
    for (ci, (_, changes)) in T2M_CONVENTIONS.iter().enumerate() {
        let names = convention_names(changes);
        let mut b = base.clone();
        for bj in &mut b.joints {
            let k = T2M_NAMES.iter().position(|n| *n == bj.name).unwrap();
            bj.name =
                if ci == 1 { format!("mixamorig:{}", names[k]) } else { names[k].to_string() };
        }
        let back = import(&T2M, &b, &ImportOptions::default()).unwrap();
        assert!(max_err(&back, &j) < 1e-5, "convention {ci}");
    }
    // Old diffkfc files used snake_case names.
    let mut b = base.clone();
    for bj in &mut b.joints {
        bj.name =
            T2M.joint_names[T2M_NAMES.iter().position(|n| *n == bj.name).unwrap()].to_string();
    }
    assert!(max_err(&import(&T2M, &b, &ImportOptions::default()).unwrap(), &j) < 1e-5);

    // Inches and Z up: scale every length, turn the root (position and rotation) by +90 about X.
    let mut b = base.clone();
    let turn = quat::from_axis_angle([1.0, 0.0, 0.0], std::f64::consts::FRAC_PI_2);
    let to_in = 1.0 / (CM * 0.0254);
    for bj in &mut b.joints {
        bj.offset = quat::scale(bj.offset, to_in);
        bj.end_site = bj.end_site.map(|e| quat::scale(e, to_in));
    }
    for f in &mut b.frames {
        let p = quat::qrot(turn, [f[0], f[1], f[2]]);
        f[..3].copy_from_slice(&quat::scale(p, to_in));
        let r = quat::qmul(turn, bvh::euler_to_quat([2, 1, 0], [f[3], f[4], f[5]]));
        f[3..6].copy_from_slice(&bvh::zyx_degrees(r, None));
    }
    b.frame_time = 0.025;
    let back = import(&T2M, &b, &ImportOptions::default()).unwrap();
    let every_other: Joints = j.iter().step_by(2).cloned().collect();
    assert_eq!(back.len(), every_other.len());
    assert!(max_err(&back, &every_other) < 1e-5, "inches, Z up, 40 fps");
}

#[test]
fn unmapped_joints_are_named_and_a_rig_map_resolves_them() {
    let Some(j) = real_walk() else {
        return;
    };
    let mut b = export(&T2M, &j);
    for bj in &mut b.joints {
        if bj.name == "LeftHand" {
            bj.name = "L_Wrist_custom".into();
        }
    }
    let e = import(&T2M, &b, &ImportOptions::default()).unwrap_err().to_string();
    assert!(e.contains("l_wrist (LeftHand)") && e.contains("--rig-map"), "{e}");
    let map = vec![("l_wrist".to_string(), "L_Wrist_custom".to_string())];
    let back = import(&T2M, &b, &ImportOptions { rig_map: map, ..Default::default() }).unwrap();
    assert!(max_err(&back, &j) < 1e-5);
    let bad = vec![("LeftHand".to_string(), "nope".to_string())];
    let e = import(&T2M, &b, &ImportOptions { rig_map: bad, ..Default::default() })
        .unwrap_err()
        .to_string();
    assert!(e.contains("'nope'"), "{e}");
}
