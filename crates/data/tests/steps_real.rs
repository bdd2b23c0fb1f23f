//! Steps out of a shuffle on a real HumanML3D clip (`../shared/fixtures/humanml3d/
//! new_joint_vecs/012314.npy`): its strides shortened until the feet glide along the floor,
//! then stances pinned and swings lifted (`postprocess::steps`, `--feet steps`).

use diffkfc_data::motion::plausibility::foot_skating_ratio;
use diffkfc_data::motion::quat;
use diffkfc_data::motion::representation::{recover_from_ric, Joints};
use diffkfc_data::postprocess::footlock::{lock_feet, ContactSource, BLEND, MAX_SHIFT_M};
use diffkfc_data::postprocess::stride::scale_strides;
use diffkfc_data::testing::feet::assert_legs_and_keys_kept;
use diffkfc_data::{io::npy, testing::fixtures, T2M};

fn joints(f: &[f32]) -> Joints {
    recover_from_ric(&T2M, &f.iter().map(|&v| v as f64).collect::<Vec<_>>())
}

/// Share of toe steps on the floor (below 5 cm) slower than 0.15 m/s.
fn planted(j: &Joints) -> f64 {
    let toes = [T2M.feet_left[1], T2M.feet_right[1]];
    let n = (j.len() - 1) * 2;
    let still = j
        .windows(2)
        .flat_map(|w| toes.map(|k| (w[0][k], w[1][k])))
        .filter(|(a, b)| b[1] < 0.05 && (b[0] - a[0]).hypot(b[2] - a[2]) * 20.0 < 0.15)
        .count();
    still as f64 / n as f64
}

#[test]
fn a_real_walk_made_to_shuffle_gets_its_steps_back() {
    let Some(p) = fixtures::require("humanml3d/new_joint_vecs/012314.npy") else { return };
    let real: Vec<f32> = npy::read_f64(p).unwrap().data.iter().map(|&v| v as f32).collect();
    let d = T2M.feature_dim();
    let t = real.len() / d;
    let own_j = joints(&real);
    let own = foot_skating_ratio(&T2M, &own_j);
    let hold: Vec<bool> = (0..t).map(|f| f == 20 || f == 120).collect();
    for s in [0.4, 0.6, 1.0] {
        let mut f = real.clone();
        scale_strides(&T2M, &mut f, &vec![false; t], &vec![s; t]);
        let glided = f.clone();
        let gj = joints(&glided);
        let before = foot_skating_ratio(&T2M, &gj);
        let rep = lock_feet(&T2M, &mut f, &hold, BLEND, MAX_SHIFT_M, ContactSource::Gait);
        let after_j = joints(&f);
        let after = foot_skating_ratio(&T2M, &after_j);
        let moved = after_j
            .iter()
            .zip(&gj)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| quat::norm(quat::sub(*p, *q))))
            .fold(0.0, f64::max);
        eprintln!(
            "clip 012314, strides x{s}: foot skating {before:.3} -> {after:.3} (its own {own:.3}), \
             planted share {:.2} -> {:.2} (its own {:.2}), {} frames lifted, largest joint move {moved:.3} m",
            planted(&gj),
            planted(&after_j),
            planted(&own_j),
            rep.lifted
        );
        assert!(after <= (1.5 * own).max(own + 0.02), "x{s}: {after} against its own {own}");
        assert!(planted(&after_j) >= planted(&gj), "x{s}");
        // The real walk as it is: its own stances stand, so it keeps its shape (its toes only
        // lifted where they slid; measured 6 cm at most, a knee).
        if s == 1.0 {
            assert!(moved < 0.08 && after <= own, "{moved} m, skating {after}");
        }
        // Bones keep their lengths; keyed rows are unchanged.
        assert_legs_and_keys_kept((&after_j, &gj), (&f, &glided), d, &[20, 120]);
    }
}

/// A synthetic clip whose only action is `action`: its features.
fn synthetic(action: &str) -> Vec<f32> {
    (0..600)
        .map(|i| diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 3, i))
        .find(|(c, _)| c.meta.actions.len() == 1 && c.meta.actions[0].action == action)
        .map(|(_, f)| f)
        .unwrap_or_else(|| panic!("a {action} among the first synthetic clips"))
}

#[test]
fn motions_that_do_not_walk_keep_their_still_feet() {
    for action in ["squat", "jump_in_place", "wave"] {
        let before = synthetic(action);
        let t = before.len() / T2M.feature_dim();
        let mut f = before.clone();
        let rep = lock_feet(&T2M, &mut f, &vec![false; t], BLEND, MAX_SHIFT_M, ContactSource::Gait);
        let (a, b) = (joints(&f), joints(&before));
        // Frames on which both toes stand still: below 5 cm, and slower than 0.15 m/s on the
        // way in and out (a toe about to slide to its landing place is not still).
        let slow = |k: usize, f: usize| {
            let (p, q) = (b[f - 1][k], b[f][k]);
            (q[0] - p[0]).hypot(q[2] - p[2]) * 20.0 < 0.15
        };
        let still = |fr: usize| {
            fr > 0
                && fr + 1 < t
                && [T2M.feet_left[1], T2M.feet_right[1]]
                    .iter()
                    .all(|&k| b[fr][k][1] < 0.05 && slow(k, fr) && slow(k, fr + 1))
        };
        let moved = |fr: usize| {
            a[fr].iter().zip(&b[fr]).map(|(p, q)| quat::norm(quat::sub(*p, *q))).fold(0.0, f64::max)
        };
        let on_still = (0..t).filter(|&fr| still(fr)).map(moved).fold(0.0, f64::max);
        let anywhere = (0..t).map(moved).fold(0.0, f64::max);
        let n = (0..t).filter(|&fr| still(fr)).count();
        eprintln!(
            "{action}: {n} of {t} frames with both feet still, moved by at most {:.2} mm there, {:.1} mm anywhere; {} frames lifted",
            on_still * 1e3,
            anywhere * 1e3,
            rep.lifted
        );
        assert!(n > t / 4, "{action}: {n} still frames");
        assert!(on_still < 1e-3, "{action}: still feet moved by {on_still} m");
    }
}
