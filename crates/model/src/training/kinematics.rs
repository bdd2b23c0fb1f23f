//! Differentiable `recover_from_ric` in Burn: de-normalised features [B, N, D] -> global joint
//! positions [B, N, J, 3], for the kinematic losses and for guidance. Same maths as
//! `diffkfc_data::motion::representation::recover_from_ric` (tested against it).

use burn::prelude::*;

/// Joint positions [B, N, J, 3] of de-normalised features [B, N, D] of a `joints`-joint skeleton.
pub fn recover_from_ric(feats: Tensor<3>, joints: usize) -> Tensor<4> {
    let [b, n, _] = feats.dims();
    let device = feats.device();
    let col = |k: usize| feats.clone().slice([0..b, 0..n, k..k + 1]).reshape([b, n]);
    // Yaw: cumulative sum of the angular velocity, shifted by one frame (frame 0 has angle 0).
    let shift = |x: Tensor<2>| {
        Tensor::cat(vec![Tensor::zeros([b, 1], &device), x.slice([0..b, 0..n - 1])], 1)
    };
    let ang = shift(col(0)).cumsum(1);
    // q = (cos a, 0, sin a, 0) is a turn by 2a about +Y; q^-1 turns by -2a:
    // x' = x cos 2a - z sin 2a, z' = x sin 2a + z cos 2a.
    let (c, s) = ((ang.clone() * 2.0).cos(), (ang * 2.0).sin());
    let (vx, vz) = (shift(col(1)), shift(col(2)));
    let root_x = (vx.clone() * c.clone() - vz.clone() * s.clone()).cumsum(1);
    let root_z = (vx * s.clone() + vz * c.clone()).cumsum(1);
    let root_y = col(3);
    let ric =
        feats.clone().slice([0..b, 0..n, 4..4 + (joints - 1) * 3]).reshape([b, n, joints - 1, 3]);
    let rx = ric.clone().slice([0..b, 0..n, 0..joints - 1, 0..1]).reshape([b, n, joints - 1]);
    let ry = ric.clone().slice([0..b, 0..n, 0..joints - 1, 1..2]).reshape([b, n, joints - 1]);
    let rz = ric.slice([0..b, 0..n, 0..joints - 1, 2..3]).reshape([b, n, joints - 1]);
    let c3 = c.unsqueeze_dim::<3>(2);
    let s3 = s.unsqueeze_dim::<3>(2);
    let px =
        rx.clone() * c3.clone() - rz.clone() * s3.clone() + root_x.clone().unsqueeze_dim::<3>(2);
    let pz = rx * s3 + rz * c3 + root_z.clone().unsqueeze_dim::<3>(2);
    let others = Tensor::stack::<4>(vec![px, ry, pz], 3);
    let root = Tensor::stack::<3>(vec![root_x, root_y, root_z], 2).unsqueeze_dim::<4>(2);
    Tensor::cat(vec![root, others], 2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::{io::npy, motion::representation, testing::fixtures, T2M};

    #[test]
    fn matches_the_reference_implementation_on_real_data() {
        let Some(p) = fixtures::require("humanml3d/new_joint_vecs/012314.npy") else {
            return;
        };
        let a = npy::read_f32(p).unwrap();
        let dev = Device::flex();
        let t = Tensor::<1>::from_floats(a.data.as_slice(), &dev).reshape([1, 170, 263]);
        let got: Vec<f32> = recover_from_ric(t, 22).into_data().try_to_vec().unwrap();
        let want = representation::recover_from_ric(
            &T2M,
            &a.data.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        );
        let want: Vec<f32> = representation::joints_to_f32(&want);
        let e = got.iter().zip(&want).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
        assert!(e < 1e-4, "{e}");
    }
}
