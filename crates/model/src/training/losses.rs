//! Training losses: L_simple on the non-keyframe, non-padding elements (paper Eq. 3) and the
//! MDM-style kinematic losses on recovered joints.

use burn::prelude::*;

use diffkfc_data::motion::root_track::TRACK_DIMS;

use crate::kernels;
use crate::training::kinematics::recover_from_ric;

/// Loss terms of one batch (scalars on the device).
pub struct Losses {
    pub simple: Tensor<1>,
    /// Squared error on the observed keyframe elements (only when its weight is positive).
    pub key: Option<Tensor<1>>,
    /// Squared error of the frame-to-frame change of every feature (only when its weight is positive).
    pub smooth: Option<Tensor<1>>,
    pub pos: Option<Tensor<1>>,
    pub vel: Option<Tensor<1>>,
    pub foot: Option<Tensor<1>>,
}

/// || (x0 - pred) * (1 - M) ||^2 averaged over the elements that count: not observed by a
/// keyframe and not padding. `valid` [B, N]; `kf_mask` [B, N, D].
pub fn l_simple(x0: Tensor<3>, pred: Tensor<3>, kf_mask: Tensor<3>, valid: Tensor<2>) -> Tensor<1> {
    let w = (kf_mask.ones_like() - kf_mask) * valid.unsqueeze_dim::<3>(2);
    let num = ((x0 - pred).powf_scalar(2.0) * w.clone()).sum();
    num / w.sum().clamp_min(1.0)
}

/// Mean squared error over the elements a keyframe observes (real frames only).
pub fn l_key(x0: Tensor<3>, pred: Tensor<3>, kf_mask: Tensor<3>, valid: Tensor<2>) -> Tensor<1> {
    let w = kf_mask * valid.unsqueeze_dim::<3>(2);
    let num = ((x0 - pred).powf_scalar(2.0) * w.clone()).sum();
    num / w.sum().clamp_min(1.0)
}

/// || (pred[f+1] - pred[f]) - (x0[f+1] - x0[f]) ||^2 over pairs of real frames, in the
/// normalised space, every feature. A noisy frame costs L_simple its own error once, this
/// loss twice more: it trains away the frame-to-frame jitter that an x0 predictor otherwise
/// copies from its noisy input (measured: tiny models left it at 15x the data's roughness).
pub fn l_smooth(x0: Tensor<3>, pred: Tensor<3>, valid: Tensor<2>) -> Tensor<1> {
    let [b, n, d] = x0.dims();
    if n < 2 {
        return Tensor::<1>::zeros([1], &x0.device());
    }
    let e = pred - x0;
    let de = e.clone().slice([0..b, 1..n, 0..d]) - e.slice([0..b, 0..n - 1, 0..d]);
    let pair = valid.clone().slice([0..b, 1..n]) * valid.slice([0..b, 0..n - 1]);
    let num = (de.powf_scalar(2.0) * pair.clone().unsqueeze_dim::<3>(2)).sum();
    num / (pair.sum() * d as f64).clamp_min(1.0)
}

/// Weights and normalisation the kinematic losses need.
pub struct Kinematic<'a> {
    pub mean: &'a [f32],
    pub std: &'a [f32],
    pub joints: usize,
    /// Foot joints in the order of the four contact channels (l_ankle, l_foot, r_ankle, r_foot).
    pub feet: [usize; 4],
    pub lambda_pos: f64,
    pub lambda_vel: f64,
    pub lambda_foot: f64,
    /// Weight of `Losses::key`.
    pub keyframe_loss: f64,
    /// Weight of `Losses::smooth`.
    pub smooth_loss: f64,
}

impl Kinematic<'_> {
    pub fn any(&self) -> bool {
        self.lambda_pos > 0.0 || self.lambda_vel > 0.0 || self.lambda_foot > 0.0
    }
}

/// The prediction with its observed root velocities (`root_track::TRACK_DIMS` where `kf_mask`
/// observes them) replaced by the observation, as sampling imposes a root track: the kinematic
/// losses then teach legs that plant their feet under the observed root, not under the
/// network's own guess of it (which the imposed track overrides). [B, N, D] each.
fn with_observed_root(pred: Tensor<3>, x0: Tensor<3>, kf_mask: Tensor<3>) -> Tensor<3> {
    let d = pred.dims()[2];
    let dims: Vec<f32> = (0..d).map(|k| if TRACK_DIMS.contains(&k) { 1.0 } else { 0.0 }).collect();
    let m = kf_mask * Tensor::<1>::from_floats(dims.as_slice(), &pred.device()).reshape([1, 1, d]);
    pred * (m.ones_like() - m.clone()) + x0 * m
}

/// L_simple and (with `keyed`) the keyframe term, on target and prediction scaled by `sqrt_w`.
fn reconstruction(
    x0: &Tensor<3>,
    pred: &Tensor<3>,
    kf_mask: &Tensor<3>,
    valid: &Tensor<2>,
    sqrt_w: Option<Tensor<3>>,
    keyed: bool,
) -> (Tensor<1>, Option<Tensor<1>>) {
    let (rx0, rpred) = match sqrt_w {
        Some(w) => (x0.clone() * w.clone(), pred.clone() * w),
        None => (x0.clone(), pred.clone()),
    };
    if kernels::fused(&x0.device()) {
        let both = kernels::masked_mse(rpred, rx0, kf_mask.clone(), valid.clone());
        (both.clone().narrow(0, 0, 1), keyed.then(|| both.narrow(0, 1, 1)))
    } else {
        let simple = l_simple(rx0.clone(), rpred.clone(), kf_mask.clone(), valid.clone());
        let key = keyed.then(|| l_key(rx0, rpred, kf_mask.clone(), valid.clone()));
        (simple, key)
    }
}

/// All loss terms; the kinematic ones only when their weight is positive. `sqrt_w` [1, 1, D]
/// (`training::weighting::sqrt_weights`) scales target and prediction of the reconstruction
/// terms (L_simple and the keyframe term), so they become weighted means.
pub fn losses(
    x0: Tensor<3>,
    pred: Tensor<3>,
    kf_mask: Tensor<3>,
    valid: Tensor<2>,
    sqrt_w: Option<Tensor<3>>,
    k: &Kinematic,
) -> Losses {
    let (simple, key) = reconstruction(&x0, &pred, &kf_mask, &valid, sqrt_w, k.keyframe_loss > 0.0);
    let smooth = (k.smooth_loss > 0.0).then(|| l_smooth(x0.clone(), pred.clone(), valid.clone()));
    if !k.any() {
        return Losses { simple, key, smooth, pos: None, vel: None, foot: None };
    }
    let device = x0.device();
    let [b, n, d] = x0.dims();
    let pred = with_observed_root(pred, x0.clone(), kf_mask);
    let mean = Tensor::<1>::from_floats(k.mean, &device).reshape([1, 1, d]);
    let std = Tensor::<1>::from_floats(k.std, &device).reshape([1, 1, d]);
    let gt_feats = x0 * std.clone() + mean.clone();
    let jg = recover_from_ric(gt_feats.clone(), k.joints);
    let jp = recover_from_ric(pred * std + mean, k.joints);
    let v4 = valid.clone().reshape([b, n, 1, 1]);
    let frames = valid.clone().sum().clamp_min(1.0);
    let per_joint = (k.joints * 3) as f64;
    let pos = (k.lambda_pos > 0.0).then(|| {
        ((jg.clone() - jp.clone()).powf_scalar(2.0) * v4.clone()).sum()
            / (frames.clone() * per_joint)
    });
    // Velocities between consecutive real frames.
    let vel_of = |j: Tensor<4>| {
        j.clone().slice([0..b, 1..n, 0..k.joints, 0..3])
            - j.slice([0..b, 0..n - 1, 0..k.joints, 0..3])
    };
    let pair_valid = valid.clone().slice([0..b, 1..n]) * valid.slice([0..b, 0..n - 1]);
    let pv4 = pair_valid.clone().reshape([b, n - 1, 1, 1]);
    let pairs = pair_valid.clone().sum().clamp_min(1.0);
    let vp = vel_of(jp);
    let vel = (k.lambda_vel > 0.0).then(|| {
        ((vel_of(jg) - vp.clone()).powf_scalar(2.0) * pv4.clone()).sum()
            / (pairs.clone() * per_joint)
    });
    let foot = (k.lambda_foot > 0.0).then(|| {
        // Predicted foot velocity where the ground truth says the foot is in contact.
        let contact = gt_feats.slice([0..b, 0..n - 1, d - 4..d]);
        let mut total = Tensor::<1>::zeros([1], &device);
        for (c, &joint) in k.feet.iter().enumerate() {
            let fv =
                vp.clone().slice([0..b, 0..n - 1, joint..joint + 1, 0..3]).reshape([b, n - 1, 3]);
            let m = contact.clone().slice([0..b, 0..n - 1, c..c + 1])
                * pair_valid.clone().unsqueeze_dim::<3>(2);
            total = total + (fv.powf_scalar(2.0) * m).sum();
        }
        total / (pairs * 12.0)
    });
    Losses { simple, key, smooth, pos, vel, foot }
}

/// What a loss term is a mean over: the count a data-parallel shard takes its share of.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Over {
    /// Feature elements a keyframe observes.
    Observed,
    /// Real frames.
    Frames,
    /// Pairs of consecutive real frames.
    Pairs,
}

impl Losses {
    /// The terms beside L_simple, each with its weight and what it is a mean over.
    pub(crate) fn terms(&self, k: &Kinematic) -> [(&Option<Tensor<1>>, f64, Over); 5] {
        [
            (&self.key, k.keyframe_loss, Over::Observed),
            (&self.smooth, k.smooth_loss, Over::Pairs),
            (&self.pos, k.lambda_pos, Over::Frames),
            (&self.vel, k.lambda_vel, Over::Pairs),
            (&self.foot, k.lambda_foot, Over::Pairs),
        ]
    }

    /// The weighted sum that is optimised.
    pub fn total(&self, k: &Kinematic) -> Tensor<1> {
        let mut t = self.simple.clone();
        for (term, w, _) in self.terms(k) {
            if let Some(x) = term {
                t = t + x.clone() * w;
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The T2M skeleton's kinematic losses, each at weight `w`, the others off.
    fn kinematic<'a>(mean: &'a [f32], std: &'a [f32], w: f64) -> Kinematic<'a> {
        Kinematic {
            mean,
            std,
            joints: 22,
            feet: [7, 10, 8, 11],
            lambda_pos: w,
            lambda_vel: w,
            lambda_foot: w,
            keyframe_loss: 0.0,
            smooth_loss: 0.0,
        }
    }

    #[test]
    fn kinematic_losses_vanish_for_identical_motions() {
        let dev = Device::flex();
        let (b, n, d) = (2, 12, 263);
        let x = Tensor::<3>::random([b, n, d], burn::tensor::Distribution::Normal(0.0, 1.0), &dev);
        let (mean, std) = (vec![0.0f32; d], vec![0.1f32; d]);
        let k = kinematic(&mean, &std, 1.0);
        let valid = Tensor::<2>::ones([b, n], &dev);
        let l = losses(x.clone(), x.clone(), x.zeros_like(), valid.clone(), None, &k);
        let pos: f32 = l.pos.unwrap().into_scalar();
        let vel: f32 = l.vel.unwrap().into_scalar();
        assert!(pos.abs() < 1e-10 && vel.abs() < 1e-10, "{pos} {vel}");
        // A different prediction is penalised.
        let l = losses(x.clone(), x.clone() + 0.5, x.zeros_like(), valid, None, &k);
        let pos: f32 = l.pos.unwrap().into_scalar();
        assert!(pos > 1e-4);
    }

    /// Kinematic losses read the observed root velocities, not the predicted ones: a prediction
    /// whose only error is its root velocity on observed frames costs nothing there, and costs
    /// where the root is not observed.
    #[test]
    fn kinematic_losses_read_the_observed_root() {
        let dev = Device::flex();
        let (b, n, d) = (1, 12, 263);
        let x = Tensor::<3>::random([b, n, d], burn::tensor::Distribution::Normal(0.0, 1.0), &dev);
        let (mean, std) = (vec![0.0f32; d], vec![0.1f32; d]);
        let k = Kinematic { lambda_vel: 0.0, lambda_foot: 0.0, ..kinematic(&mean, &std, 1.0) };
        let mut wrong = vec![0f32; n * d];
        (0..n).for_each(|f| wrong[f * d + 2] = 0.5);
        let wrong = Tensor::<1>::from_floats(wrong.as_slice(), &dev).reshape([b, n, d]);
        let mut track = vec![0f32; n * d];
        (0..n).for_each(|f| TRACK_DIMS.for_each(|c| track[f * d + c] = 1.0));
        let track = Tensor::<1>::from_floats(track.as_slice(), &dev).reshape([b, n, d]);
        let valid = Tensor::<2>::ones([b, n], &dev);
        let pos = |m: Tensor<3>| -> f32 {
            losses(x.clone(), x.clone() + wrong.clone(), m, valid.clone(), None, &k)
                .pos
                .unwrap()
                .into_scalar()
        };
        assert!(pos(track.clone()) < 1e-10, "{}", pos(track));
        assert!(pos(x.zeros_like()) > 1e-3);
    }

    /// Weights (as square roots) make L_simple the weighted mean of the squared errors: an
    /// error of 1 on a root channel of weight 4 and on an ordinary channel of weight 1, the
    /// first sample weighing 0.25 in all.
    #[test]
    fn weights_make_l_simple_a_weighted_mean() {
        let dev = Device::flex();
        let (b, n, d) = (2, 3, 8);
        let x = Tensor::<3>::zeros([b, n, d], &dev);
        let mut e = vec![0f32; b * n * d];
        for s in 0..b {
            for f in 0..n {
                e[(s * n + f) * d] = 1.0; // root channel 0
                e[(s * n + f) * d + 5] = 1.0; // an ordinary channel
            }
        }
        let pred = Tensor::<1>::from_floats(e.as_slice(), &dev).reshape([b, n, d]);
        let mut w = vec![1f32; b * d];
        w[0] = 4.0;
        w[d] = 4.0;
        (0..d).for_each(|c| w[c] *= 0.25);
        let sqrt_w: Vec<f32> = w.iter().map(|v| v.sqrt()).collect();
        let sqrt_w = Tensor::<1>::from_floats(sqrt_w.as_slice(), &dev).reshape([b, 1, d]);
        let k = Kinematic { keyframe_loss: 1.0, ..kinematic(&[], &[], 0.0) };
        let valid = Tensor::<2>::ones([b, n], &dev);
        let l = losses(x.clone(), pred, x.zeros_like(), valid, Some(sqrt_w), &k);
        let got: f32 = l.simple.into_scalar();
        // Per frame: sample 0 (4 + 1) * 0.25, sample 1 (4 + 1); over n * d elements each.
        let want = ((4.0 + 1.0) * 0.25 + (4.0 + 1.0)) * n as f32 / (b * n * d) as f32;
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
    }

    #[test]
    fn l_simple_ignores_keyframes_and_padding() {
        let dev = Device::flex();
        let x0 = Tensor::<1>::from_floats([1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0].as_slice(), &dev)
            .reshape([1, 3, 2]);
        let pred = Tensor::<1>::from_floats([1.0f32, 0.0, 0.0, 4.0, 0.0, 0.0].as_slice(), &dev)
            .reshape([1, 3, 2]);
        // Frame 0 dim 1 is a keyframe element; frame 2 is padding.
        let m = Tensor::<1>::from_floats([0.0f32, 1.0, 0.0, 0.0, 0.0, 0.0].as_slice(), &dev)
            .reshape([1, 3, 2]);
        let valid = Tensor::<1>::from_floats([1.0f32, 1.0, 0.0].as_slice(), &dev).reshape([1, 3]);
        let l: f32 = l_simple(x0, pred, m, valid).into_scalar();
        // Counted elements: (0,0) err 0, (1,0) err 9, (1,1) err 0 -> 9 / 3.
        assert!((l - 3.0).abs() < 1e-6, "{l}");
    }

    #[test]
    fn l_smooth_sees_jitter_not_offsets() {
        let dev = Device::flex();
        let x0 =
            Tensor::<3>::random([2, 10, 4], burn::tensor::Distribution::Normal(0.0, 1.0), &dev);
        let valid = Tensor::<2>::ones([2, 10], &dev);
        // A constant offset changes no frame-to-frame difference.
        let l: f32 = l_smooth(x0.clone(), x0.clone() + 0.7, valid.clone()).into_scalar();
        assert!(l.abs() < 1e-10, "{l}");
        // Alternating +-0.5: every difference is off by 1.
        let alt: Vec<f32> = (0..80).map(|k| if (k / 4) % 2 == 0 { 0.5 } else { -0.5 }).collect();
        let jitter = Tensor::<1>::from_floats(alt.as_slice(), &dev).reshape([2, 10, 4]);
        let l: f32 = l_smooth(x0.clone(), x0.clone() + jitter.clone(), valid).into_scalar();
        assert!((l - 1.0).abs() < 1e-5, "{l}");
        // Pairs that touch padding do not count.
        let v = Tensor::<1>::from_floats([[1.0f32; 5], [0.0; 5]].concat().as_slice(), &dev)
            .reshape([1, 10]);
        let l: f32 = l_smooth(
            x0.clone().slice([0..1, 0..10, 0..4]),
            (x0 + jitter).slice([0..1, 0..10, 0..4]),
            v,
        )
        .into_scalar();
        assert!((l - 1.0).abs() < 1e-5, "{l}");
    }

    /// The fused masked squared errors against `l_simple` and `l_key` composed from Burn ops: both
    /// values and the prediction's gradient of a weighted sum, with padding frames and a random
    /// keyframe mask (and a sample with no observed element).
    #[test]
    fn fused_masked_mse_matches_the_composed_losses_with_gradients() {
        use burn::tensor::Distribution;
        let random = |shape: [usize; 3], dev: &Device| -> Tensor<3> {
            Tensor::random(shape, Distribution::Normal(0.0, 1.0), dev)
        };
        use crate::network::params::host;
        let dev = Device::flex().autodiff();
        let (b, n, d) = (3, 70, 9);
        let x0 = random([b, n, d], &dev);
        let pred0 = random([b, n, d], &dev);
        let m: Vec<f32> = (0..b * n * d)
            .map(|i| if i / (n * d) != 1 && (i * 7919) % 5 < 2 { 1.0 } else { 0.0 })
            .collect();
        let m = Tensor::<1>::from_floats(m.as_slice(), &dev).reshape([b, n, d]);
        let v: Vec<f32> =
            (0..b * n).map(|i| if i % n < n - 13 * (i / n) { 1.0 } else { 0.0 }).collect();
        let valid = Tensor::<1>::from_floats(v.as_slice(), &dev).reshape([b, n]);
        let run = |fused: bool| {
            let pred = pred0.clone().detach().require_grad();
            let (s, k) = if fused {
                let both =
                    crate::kernels::masked_mse(pred.clone(), x0.clone(), m.clone(), valid.clone());
                (both.clone().narrow(0, 0, 1), both.narrow(0, 1, 1))
            } else {
                (
                    l_simple(x0.clone(), pred.clone(), m.clone(), valid.clone()),
                    l_key(x0.clone(), pred.clone(), m.clone(), valid.clone()),
                )
            };
            let grads = (s.clone() * 0.7 + k.clone() * 1.3).backward();
            let g = host(pred.grad(&grads).expect("the prediction's gradient"));
            (host(s)[0], host(k)[0], g)
        };
        let (fused, composed) = (run(true), run(false));
        assert!((fused.0 - composed.0).abs() < 1e-5 * composed.0, "simple {fused:?} {composed:?}");
        assert!((fused.1 - composed.1).abs() < 1e-5 * composed.1, "key {} {}", fused.1, composed.1);
        let scale = composed.2.iter().fold(0f32, |a, x| a.max(x.abs()));
        let e = fused.2.iter().zip(&composed.2).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max)
            / scale;
        assert!(e < 1e-5, "gradient: max error {e}");
    }
}
