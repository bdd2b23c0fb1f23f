//! The synthetic set's bodies against real HumanML3D clips (`../shared/fixtures/humanml3d`):
//! the `humanml3d` body has their hips, collars and pelvis height; the legacy body does not.

use diffkfc_data::motion::quat::{self, Vec3};
use diffkfc_data::{io::npy, testing::fixtures};
use diffkfc_synth::{self as synth, body, Body, SynthSpec};

/// Mean over frames of: pelvis height above its hips' midpoint, distance between the hips,
/// the up component of the chest -> collar directions (both sides), pelvis height above the
/// floor.
#[derive(Debug)]
struct Geometry {
    hip_drop: f64,
    hips_apart: f64,
    collar_up: f64,
    pelvis_height: f64,
}

fn geometry(joints: &[Vec<Vec3>]) -> Geometry {
    let n = joints.len() as f64;
    let mean = |f: &dyn Fn(&[Vec3]) -> f64| joints.iter().map(|j| f(j)).sum::<f64>() / n;
    Geometry {
        hip_drop: mean(&|j| j[0][1] - 0.5 * (j[1][1] + j[2][1])),
        hips_apart: mean(&|j| quat::norm(quat::sub(j[1], j[2]))),
        collar_up: mean(&|j| {
            0.5 * (quat::normalize(quat::sub(j[13], j[9]))[1]
                + quat::normalize(quat::sub(j[14], j[9]))[1])
        }),
        pelvis_height: mean(&|j| j[0][1]),
    }
}

fn real(rel: &str) -> Option<Geometry> {
    let a = npy::read_f64(fixtures::require(rel)?).unwrap();
    let joints: Vec<Vec<Vec3>> =
        a.data.chunks(66).map(|f| f.chunks(3).map(|p| [p[0], p[1], p[2]]).collect()).collect();
    Some(geometry(&joints))
}

fn drawn(b: Body) -> Geometry {
    // Standing and walking frames of the set's first clips.
    let joints: Vec<Vec<Vec3>> =
        (0..6).flat_map(|i| synth::clip(b, 0, i).0.joints).collect::<Vec<_>>();
    geometry(&joints)
}

#[test]
fn humanml3d_body_has_the_real_clips_hips_and_collars() {
    let clips = ["humanml3d/000021_joints_reference.npy", "humanml3d/new_joints/012314.npy"];
    let Some(reals) = clips.iter().map(|c| real(c)).collect::<Option<Vec<_>>>() else {
        return;
    };
    let ours = drawn(Body::HumanMl3d);
    let legacy = drawn(Body::Legacy);
    for r in &reals {
        assert!((ours.hip_drop - r.hip_drop).abs() < 0.01, "{ours:?} vs {r:?}");
        assert!((ours.hips_apart - r.hips_apart).abs() < 0.01, "{ours:?} vs {r:?}");
        assert!((ours.collar_up - r.collar_up).abs() < 0.1, "{ours:?} vs {r:?}");
        assert!((ours.pelvis_height - r.pelvis_height).abs() < 0.05, "{ours:?} vs {r:?}");
        // The legacy body is what the test tells apart.
        assert!((legacy.hip_drop - r.hip_drop).abs() > 0.04, "{legacy:?} vs {r:?}");
        assert!((legacy.collar_up - r.collar_up).abs() > 0.3, "{legacy:?} vs {r:?}");
    }
}

#[test]
fn bodies_share_legs_and_feet() {
    let p = body::Pose::standing(0.3, -1.0, 0.7);
    let (a, b) = (body::joints(Body::Legacy, &p), body::joints(Body::HumanMl3d, &p));
    // Ankles and toes are where the legacy body put them and the left hip (whose bone sets
    // the lift) as high: the pelvis rose by what the hips dropped (the knees follow the
    // narrower hips by a centimetre or two).
    for j in [7, 8, 10, 11] {
        assert!(quat::norm(quat::sub(a[j], b[j])) < 1e-6, "joint {j}: {:?} vs {:?}", a[j], b[j]);
    }
    assert!((a[1][1] - b[1][1]).abs() < 1e-4, "left hip: {:?} vs {:?}", a[1], b[1]);
    assert!(b[0][1] - a[0][1] > 0.05, "pelvis {} vs {}", b[0][1], a[0][1]);
    for (i, &par) in diffkfc_data::T2M.parents().iter().enumerate().skip(1) {
        let l = quat::norm(quat::sub(b[i], b[par as usize]));
        assert!((l - body::len(i)).abs() < 1e-9, "joint {i}: {l} vs {}", body::len(i));
    }
}

#[test]
fn manifest_records_the_body_and_bad_names_are_refused() {
    let d = std::env::temp_dir().join(format!("diffkfc-body-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let spec = SynthSpec { clips: 3, seed: 1, body: Body::HumanMl3d, vary: 0.0 };
    synth::write_dataset(&d, &spec, 1, &|_, _| {}).unwrap();
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["body"], "humanml3d");
    std::fs::remove_dir_all(&d).unwrap();
    assert_eq!("legacy".parse::<Body>(), Ok(Body::Legacy));
    let e = "smpl".parse::<Body>().unwrap_err();
    assert!(e.contains("'smpl'") && e.contains("humanml3d"), "{e}");
}
