//! Fused CPU kernels for the ops that dominate a step outside the matrix products:
//! multi-head attention (scores, mask, softmax, weighted values), LayerNorm, and the decoder's
//! temporal convolution.
//!
//! On the flex backend (with or without autodiff) they run as one Burn backend extension op
//! each, forward and hand-written backward (`grad.rs`) on host slices (`host.rs`); on any other
//! backend, or with `DIFFKFC_KERNELS=burn`, the same math is composed from Burn tensor ops, which
//! is also the reference the tests compare against.

mod attention_call;
mod conv;
mod flash;
mod grad;
pub mod host;
mod mha;
mod mse;
pub mod rows;
mod simd;
mod softmax;
mod tiles;

use std::sync::{Arc, OnceLock};

use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Backend, Dispatch, DispatchDevice, Flex};
use burn::backend::{BackendTensor, DispatchTensorKind};
use burn::nn::{LayerNorm, Linear};
use burn::prelude::*;
use burn::tensor::activation::softmax;
use burn::tensor::TensorData;

use crate::network::dropout::Dropout;

pub use attention_call::{AttnShape, Mask};
pub use conv::{temporal_add_rows, ConvShape};

/// Whether running on `count` of `total` rows (or keys) through a gather is worth it: above ~3/4
/// the saved products no longer pay for the gather and scatter. One rule for the DMA blocks' row
/// subsets, the attention kernel's key compaction and the FLOP count of what they run.
pub fn worth_gathering(count: usize, total: usize) -> bool {
    count * 4 < total * 3
}

/// How many of `total` rows (or keys) a gathered op runs on: the `count` it needs when
/// gathering them is worth it, else all of them.
pub fn rows_run(count: usize, total: usize) -> usize {
    if worth_gathering(count, total) {
        count
    } else {
        total
    }
}

/// LayerNorm's epsilon (Burn's `LayerNormConfig` default, which every LayerNorm here uses).
pub const LN_EPS: f32 = 1e-5;

/// A dropout mask (scale folded in) for [`FusedOps::fused_residual_layer_norm`]; None: no dropout.
#[derive(Clone, Debug)]
pub struct DropMask(pub Option<Arc<Vec<f32>>>);

impl DropMask {
    /// The mask's values (None: no dropout).
    pub fn values(&self) -> Option<&[f32]> {
        self.0.as_deref().map(Vec::as_slice)
    }
}

/// Arguments of a temporal convolution that are not tensors: the token rows before the frames,
/// and which frames are real ([B, N]: 1 real, 0 padding).
#[derive(Clone, Debug)]
pub struct ConvArgs {
    pub skip: usize,
    pub real: Arc<Vec<f32>>,
}

/// Arguments of an attention call that are not tensors.
#[derive(Clone, Debug)]
pub struct AttnArgs {
    pub heads: usize,
    pub mask: Mask,
}

#[backend_extension(Flex, Autodiff)]
pub trait FusedOps: Backend {
    /// LayerNorm over the last dim: x `[.., d]`, gamma and beta `[d]`.
    fn fused_layer_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
    /// LayerNorm of h + a (o mask) over the last dim: the post-norm residual of a decoder layer.
    fn fused_residual_layer_norm(
        h: FloatTensor<Self>,
        a: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        drop: DropMask,
    ) -> FloatTensor<Self>;
    /// x `[rows, in]` . w `[in, out]` + b `[out]` -> `[rows, out]`.
    fn fused_linear(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
    /// gelu(x `[rows, in]` . w `[in, out]` + b `[out]`) o mask -> `[rows, out]`.
    fn fused_linear_gelu(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
        drop: DropMask,
    ) -> FloatTensor<Self>;
    /// q [B, Lq, d], k and v [B, Lk, d] -> [B, Lq, d] (heads split along d).
    fn fused_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        args: AttnArgs,
    ) -> FloatTensor<Self>;
    /// [L_simple, keyframe term] of pred against x0 `[B, N, D]`: the mean squared error over the
    /// elements kf_mask `[B, N, D]` leaves unobserved, and over those it observes, on the frames
    /// `valid` `[B, N]` marks real -> `[2]`. The masks are data: they take no gradient.
    fn fused_masked_mse(
        pred: FloatTensor<Self>,
        x0: FloatTensor<Self>,
        kf_mask: FloatTensor<Self>,
        valid: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
    /// Depthwise convolution over the frames of h `[B, M, d]` (its rows `args.skip`..) with
    /// taps w `[K, d]`, padding frames read as 0 -> `[B, M, d]`, the first `skip` rows 0.
    fn fused_temporal_conv(
        h: FloatTensor<Self>,
        w: FloatTensor<Self>,
        args: ConvArgs,
    ) -> FloatTensor<Self>;
}

/// Contiguous f32 data of a flex tensor (a copy only when it is a strided view).
fn slice(t: &FlexTensor) -> std::borrow::Cow<'_, [f32]> {
    match t.as_slice::<f32>() {
        Some(s) if s.len() == t.layout().num_elements() => std::borrow::Cow::Borrowed(s),
        _ => std::borrow::Cow::Owned(
            t.clone()
                .into_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .expect("the fused kernels run on f32 tensors"),
        ),
    }
}

fn tensor(v: Vec<f32>, shape: burn::tensor::Shape) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(v, shape))
}

/// [`FusedOps::fused_masked_mse`] on flex: the two means and their counts.
fn flex_masked_mse(
    pred: &FlexTensor,
    x0: &FlexTensor,
    kf_mask: &FlexTensor,
    valid: &FlexTensor,
) -> ([f32; 2], [f32; 2]) {
    let d = pred.layout().shape()[2];
    mse::masked_mse(&slice(pred), &slice(x0), &slice(kf_mask), &slice(valid), d)
}

fn conv_shape(h: &FlexTensor, w: &FlexTensor, skip: usize) -> conv::ConvShape {
    let hs = h.layout().shape();
    conv::ConvShape { batch: hs[0], rows: hs[1], skip, d: hs[2], kernel: w.layout().shape()[0] }
}

fn attn_shape(q: &FlexTensor, k: &FlexTensor, heads: usize) -> AttnShape {
    let (qs, ks) = (q.layout().shape(), k.layout().shape());
    AttnShape { batch: qs[0], lq: qs[1], lk: ks[1], heads, d: qs[2] }
}

impl FusedOps for Flex {
    fn fused_layer_norm(x: FlexTensor, gamma: FlexTensor, beta: FlexTensor) -> FlexTensor {
        let y = host::layer_norm_forward(&slice(&x), &slice(&gamma), &slice(&beta), LN_EPS);
        tensor(y, x.layout().shape().clone())
    }

    fn fused_residual_layer_norm(
        h: FlexTensor,
        a: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        drop: DropMask,
    ) -> FlexTensor {
        let x = host::residual(&slice(&h), &slice(&a), drop.values());
        let y = host::layer_norm_forward(&x, &slice(&gamma), &slice(&beta), LN_EPS);
        tensor(y, h.layout().shape().clone())
    }

    fn fused_linear(x: FlexTensor, w: FlexTensor, b: FlexTensor) -> FlexTensor {
        let y = host::linear_forward(&slice(&x), &slice(&w), &slice(&b));
        let (rows, out) = (x.layout().shape()[0], b.layout().shape()[0]);
        tensor(y, [rows, out].into())
    }

    fn fused_linear_gelu(
        x: FlexTensor,
        w: FlexTensor,
        b: FlexTensor,
        drop: DropMask,
    ) -> FlexTensor {
        let mut h = host::linear_forward(&slice(&x), &slice(&w), &slice(&b));
        host::gelu_inplace(&mut h, drop.values());
        let (rows, out) = (x.layout().shape()[0], b.layout().shape()[0]);
        tensor(h, [rows, out].into())
    }

    fn fused_attention(q: FlexTensor, k: FlexTensor, v: FlexTensor, args: AttnArgs) -> FlexTensor {
        attention_with_lse(&q, &k, &v, &args).0
    }

    fn fused_masked_mse(
        pred: FlexTensor,
        x0: FlexTensor,
        kf_mask: FlexTensor,
        valid: FlexTensor,
    ) -> FlexTensor {
        tensor(flex_masked_mse(&pred, &x0, &kf_mask, &valid).0.to_vec(), [2].into())
    }

    fn fused_temporal_conv(h: FlexTensor, w: FlexTensor, args: ConvArgs) -> FlexTensor {
        let s = conv_shape(&h, &w, args.skip);
        let y = conv::temporal_forward(&slice(&h), &slice(&w), &args.real, &s);
        tensor(y, h.layout().shape().clone())
    }
}

/// The flex attention and, where the flash kernel ran (small heads), its rows' log-sum-exp for
/// the backward.
fn attention_with_lse(
    q: &FlexTensor,
    k: &FlexTensor,
    v: &FlexTensor,
    args: &AttnArgs,
) -> (FlexTensor, Option<Arc<Vec<f32>>>) {
    let s = attn_shape(q, k, args.heads);
    let (q, k, v) = (slice(q), slice(k), slice(v));
    let (out, lse) = if uses_flash(&s) {
        let (out, lse) = flash::forward(&q, &k, &v, &s, &args.mask);
        (out, Some(Arc::new(lse)))
    } else {
        (mha::attention_forward(&q, &k, &v, &s, &args.mask), None)
    };
    (tensor(out, [s.batch, s.lq, s.d].into()), lse)
}

/// Attention of q [B, Lq, d] to k, v [B, Lk, d] on host slices -> [B, Lq, d]: the kernel the
/// flex op runs for these shapes (`attention_with_lse`), parallel over heads.
pub fn attention_host(q: &[f32], k: &[f32], v: &[f32], s: &AttnShape, mask: &Mask) -> Vec<f32> {
    if uses_flash(s) {
        flash::forward(q, k, v, s, mask).0
    } else {
        mha::attention_forward(q, k, v, s, mask)
    }
}

/// Whether an attention of these shapes runs the flash kernel (small heads) rather than the
/// per-head one; `DIFFKFC_ATTENTION=head` keeps every head on the per-head path (A/B runs).
fn uses_flash(s: &AttnShape) -> bool {
    static PER_HEAD: OnceLock<bool> = OnceLock::new();
    let per_head =
        *PER_HEAD.get_or_init(|| std::env::var("DIFFKFC_ATTENTION").is_ok_and(|v| v == "head"));
    flash::serves(s.dh()) && !per_head
}

/// A float tensor's values on the host: the flex tensor's own buffer where it is contiguous f32
/// (no copy: the sampling path reads every weight of the network once per sample), else a copy.
pub enum HostView {
    Flex(FlexTensor),
    Owned(Vec<f32>),
}

impl HostView {
    pub fn of<const D: usize>(t: Tensor<D>) -> HostView {
        let flex = match t.clone().into_dispatch().kind {
            DispatchTensorKind::Flex(BackendTensor::Float(f)) => Some(f),
            _ => None,
        };
        match flex.filter(|f| f.as_slice::<f32>().is_some()) {
            Some(f) => HostView::Flex(f),
            None => HostView::Owned(crate::network::params::host(t)),
        }
    }
}

impl std::ops::Deref for HostView {
    type Target = [f32];

    fn deref(&self) -> &[f32] {
        match self {
            HostView::Flex(f) => f.as_slice::<f32>().expect("checked contiguous f32 when made"),
            HostView::Owned(v) => v,
        }
    }
}

/// Whether the fused kernels serve this device: flex, with or without autodiff, unless
/// `DIFFKFC_KERNELS=burn` asks for the composed ops (for A/B measurements).
pub fn fused(device: &Device) -> bool {
    static COMPOSED: OnceLock<bool> = OnceLock::new();
    if *COMPOSED.get_or_init(|| std::env::var("DIFFKFC_KERNELS").is_ok_and(|v| v == "burn")) {
        return false;
    }
    matches!(device.as_dispatch().clone().inner(), DispatchDevice::Flex(_))
}

/// A LayerNorm's scale and shift for the fused ops (zeros for a LayerNorm without shift).
fn ln_params(ln: &LayerNorm) -> (FloatTensor<Dispatch>, FloatTensor<Dispatch>) {
    let beta = ln.beta.as_ref().map(|b| b.val()).unwrap_or_else(|| ln.gamma.val().zeros_like());
    (ln.gamma.val().into_dispatch(), beta.into_dispatch())
}

/// LayerNorm `ln` of x [B, L, d].
pub fn layer_norm(ln: &LayerNorm, x: Tensor<3>) -> Tensor<3> {
    if !fused(&x.device()) {
        return ln.forward(x);
    }
    let (gamma, beta) = ln_params(ln);
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_layer_norm(x.into_dispatch(), gamma, beta))
}

/// LayerNorm `ln` of h + drop(a), h and a [B, L, d] (one pass on flex, dropout mask included).
pub fn residual_layer_norm(
    ln: &LayerNorm,
    h: Tensor<3>,
    a: Tensor<3>,
    drop: &Dropout,
) -> Tensor<3> {
    if !fused(&h.device()) {
        return layer_norm(ln, h + drop.forward(a));
    }
    let mask = DropMask(drop.host_mask(&a).map(Arc::new));
    let (gamma, beta) = ln_params(ln);
    let y = <Dispatch as FusedOps>::fused_residual_layer_norm(
        h.into_dispatch(),
        a.into_dispatch(),
        gamma,
        beta,
        mask,
    );
    Tensor::from_dispatch(y)
}

/// `lin` applied to x [.., in] -> [.., out].
pub fn linear<const D: usize>(lin: &Linear, x: Tensor<D>) -> Tensor<D> {
    linear_with(lin, x, None)
}

/// gelu(`lin`(x)) for x [.., in] -> [.., out] (one pass on flex).
pub fn linear_gelu<const D: usize>(lin: &Linear, x: Tensor<D>) -> Tensor<D> {
    linear_with(lin, x, Some(&Dropout::new(0.0)))
}

/// drop(gelu(`lin`(x))) for x [.., in] -> [.., out] (one pass on flex, the dropout mask
/// applied inside the op, forward and backward).
pub fn linear_gelu_dropout<const D: usize>(
    lin: &Linear,
    x: Tensor<D>,
    drop: &Dropout,
) -> Tensor<D> {
    linear_with(lin, x, Some(drop))
}

/// `lin`(x), then with `gelu` GELU and that dropout.
fn linear_with<const D: usize>(lin: &Linear, x: Tensor<D>, gelu: Option<&Dropout>) -> Tensor<D> {
    let Some(bias) = lin.bias.as_ref().filter(|_| fused(&x.device())) else {
        let y = lin.forward(x);
        return match gelu {
            Some(drop) => drop.forward(burn::tensor::activation::gelu(y)),
            None => y,
        };
    };
    let mut shape = x.dims();
    let [n_in, n_out] = lin.weight.dims();
    let rows = x.shape().num_elements() / n_in;
    let device = x.device();
    let (x, w, b) = (
        x.reshape([rows, n_in]).into_dispatch(),
        lin.weight.val().into_dispatch(),
        bias.val().into_dispatch(),
    );
    let y = match gelu {
        Some(drop) => {
            let mask = DropMask(drop.host_mask_of(rows * n_out, &device).map(Arc::new));
            <Dispatch as FusedOps>::fused_linear_gelu(x, w, b, mask)
        }
        None => <Dispatch as FusedOps>::fused_linear(x, w, b),
    };
    shape[D - 1] = n_out;
    Tensor::<2>::from_dispatch(y).reshape(shape)
}

/// [L_simple, keyframe term] of pred against x0 [B, N, D] under kf_mask [B, N, D] on the real
/// frames `valid` [B, N] (`FusedOps::fused_masked_mse`), for the devices [`fused`] serves.
pub fn masked_mse(
    pred: Tensor<3>,
    x0: Tensor<3>,
    kf_mask: Tensor<3>,
    valid: Tensor<2>,
) -> Tensor<1> {
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_masked_mse(
        pred.into_dispatch(),
        x0.into_dispatch(),
        kf_mask.into_dispatch(),
        valid.into_dispatch(),
    ))
}

/// The depthwise convolution of h [B, M, d]'s frames (rows `args.skip`..) with taps w [K, d]
/// (`FusedOps::fused_temporal_conv`), for the devices [`fused`] serves; `TemporalConv`
/// composes the same from Burn ops elsewhere.
pub fn temporal_conv(h: Tensor<3>, w: Tensor<2>, args: ConvArgs) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_temporal_conv(
        h.into_dispatch(),
        w.into_dispatch(),
        args,
    ))
}

/// Attention of q [B, Lq, d] to k, v [B, Lk, d] with `heads` heads -> [B, Lq, d].
pub fn attention(q: Tensor<3>, k: Tensor<3>, v: Tensor<3>, heads: usize, mask: Mask) -> Tensor<3> {
    if fused(&q.device()) {
        let args = AttnArgs { heads, mask };
        return Tensor::from_dispatch(<Dispatch as FusedOps>::fused_attention(
            q.into_dispatch(),
            k.into_dispatch(),
            v.into_dispatch(),
            args,
        ));
    }
    attention_composed(q, k, v, heads, &mask)
}

/// The same attention from Burn tensor ops (any backend; the kernels' reference).
pub fn attention_composed(
    q: Tensor<3>,
    k: Tensor<3>,
    v: Tensor<3>,
    heads: usize,
    mask: &Mask,
) -> Tensor<3> {
    let [b, lq, d] = q.dims();
    let lk = k.dims()[1];
    let dh = d / heads;
    let split = |t: Tensor<3>, l: usize| t.reshape([b, l, heads, dh]).swap_dims(1, 2);
    let (q, k, v) = (split(q, lq), split(k, lk), split(v, lk));
    let scores = q.matmul(k.swap_dims(2, 3)).mul_scalar(1.0 / (dh as f32).sqrt());
    let device = scores.device();
    let blocked: Option<Vec<bool>> = match mask {
        Mask::None => None,
        Mask::Keys(m) => Some((0..b * lq * lk).map(|i| m[i / (lq * lk) * lk + i % lk]).collect()),
        Mask::Full(m) => Some(m.to_vec()),
    };
    let scores = match blocked {
        Some(m) => {
            let m = Tensor::<3, Bool>::from_data(TensorData::new(m, [b, lq, lk]), &device)
                .unsqueeze_dim::<4>(1)
                .expand([b, heads, lq, lk]);
            scores.mask_fill(m, f32::NEG_INFINITY)
        }
        None => scores,
    };
    softmax(scores, 3).matmul(v).swap_dims(1, 2).reshape([b, lq, d])
}

/// A key-padding mask [B * Lk] (true = not a key).
pub fn key_mask(pad: Vec<bool>) -> Mask {
    Mask::Keys(Arc::new(pad))
}
