//! Stride warping on a real HumanML3D clip (`../shared/fixtures/humanml3d/new_joint_vecs/
//! 012314.npy`): its strides shortened to simulate a network that glides, then warped back.

use diffkfc_data::motion::plausibility::foot_skating_ratio;
use diffkfc_data::motion::representation::{recover_from_ric, Joints};
use diffkfc_data::postprocess::stride::{scale_strides, warp_strides};
use diffkfc_data::testing::feet::assert_legs_and_keys_kept;
use diffkfc_data::{io::npy, testing::fixtures, T2M};

fn joints(f: &[f32]) -> Joints {
    recover_from_ric(&T2M, &f.iter().map(|&v| v as f64).collect::<Vec<_>>())
}

#[test]
fn a_real_walk_glided_is_warped_back_to_its_own_skating() {
    let Some(p) = fixtures::require("humanml3d/new_joint_vecs/012314.npy") else { return };
    let real: Vec<f32> = npy::read_f64(p).unwrap().data.iter().map(|&v| v as f32).collect();
    let d = T2M.feature_dim();
    let t = real.len() / d;
    let own = foot_skating_ratio(&T2M, &joints(&real));
    // Two keyed frames that must stay exact.
    let hold: Vec<bool> = (0..t).map(|f| f == 20 || f == 120).collect();
    for s in [0.6, 0.8, 1.0] {
        let mut f = real.clone();
        scale_strides(&T2M, &mut f, &vec![false; t], &vec![s; t]);
        let glided = f.clone();
        let before = foot_skating_ratio(&T2M, &joints(&f));
        let rep = warp_strides(&T2M, &mut f, &hold);
        let after_j = joints(&f);
        let after = foot_skating_ratio(&T2M, &after_j);
        eprintln!(
            "clip 012314, strides x{s}: foot skating {before:.3} -> {after:.3} (its own {own:.3}), mean factor {:.3}, pelvis drop {:.3} m",
            rep.mean_factor, rep.pelvis_drop_m
        );
        assert!(rep.warped, "{rep:?}");
        assert!(after <= (1.5 * own).max(own + 0.02), "x{s}: {after} against its own {own}");
        // Bones keep their lengths; keyed rows are unchanged.
        assert_legs_and_keys_kept((&after_j, &joints(&glided)), (&f, &glided), d, &[20, 120]);
    }
}
