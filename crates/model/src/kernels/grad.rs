//! The fused ops under autodiff: forward on the flex tensors, backward by the host kernels.
//! Each op keeps its inputs (already alive in the graph) and recomputes what it needs.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::autodiff::NodeId;
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Flex};
use burn::tensor::Shape;
use rayon::prelude::*;
use std::sync::Arc;

use super::{
    attn_shape, conv, conv_shape, flex_masked_mse, host, mse, slice, tensor, AttnArgs, ConvArgs,
    DropMask, FusedOps, LN_EPS,
};

/// Record an op of N inputs: `tracked` computes the output and the state its backward needs,
/// `untracked` just the output (no input needs a gradient).
fn record<B: Backward<Flex, N>, C: CheckpointStrategy, const N: usize>(
    backward: B,
    inputs: [FloatTensor<Autodiff<Flex, C>>; N],
    tracked: impl FnOnce([FlexTensor; N]) -> (FlexTensor, B::State),
    untracked: impl FnOnce([FlexTensor; N]) -> FlexTensor,
) -> FloatTensor<Autodiff<Flex, C>> {
    let nodes = inputs.each_ref().map(|t| t.node());
    let prims = inputs.map(|t| t.into_primitive());
    match backward.prepare::<C>(nodes).compute_bound().stateful() {
        OpsKind::Tracked(prep) => {
            let (out, state) = tracked(prims);
            prep.finish(state, out)
        }
        OpsKind::UnTracked(prep) => prep.finish(untracked(prims)),
    }
}

/// Hand each input that needs one its gradient.
fn register<const N: usize>(
    grads: &mut Gradients,
    parents: [Option<NodeId>; N],
    values: [(Vec<f32>, Shape); N],
) {
    for (id, (g, shape)) in parents.into_iter().zip(values) {
        if let Some(id) = id {
            grads.register::<Flex>(id, tensor(g, shape));
        }
    }
}

fn shape(t: &FlexTensor) -> Shape {
    t.layout().shape().clone()
}

/// Gradients of x . w + b for the product's gradient `dh`.
fn linear_grads(
    grads: &mut Gradients,
    parents: [Option<NodeId>; 3],
    x: &FlexTensor,
    w: &FlexTensor,
    dh: &[f32],
) {
    let n_out = w.layout().shape()[1];
    let (dx, dw, db) = host::linear_backward(&slice(x), &slice(w), dh, n_out);
    register(grads, parents, [(dx, shape(x)), (dw, shape(w)), (db, [n_out].into())]);
}

#[derive(Debug)]
struct LayerNormBackward;

impl Backward<Flex, 3> for LayerNormBackward {
    /// (x, gamma)
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, gamma) = ops.state;
        let (dx, dgamma, dbeta) =
            host::layer_norm_backward(&slice(&x), &slice(&gamma), &slice(&dy), LN_EPS);
        register(
            grads,
            ops.parents.map(|p| p.map(|n| n.id)),
            [(dx, shape(&x)), (dgamma, shape(&gamma)), (dbeta, shape(&gamma))],
        );
    }
}

#[derive(Debug)]
struct ResidualLayerNormBackward;

impl Backward<Flex, 4> for ResidualLayerNormBackward {
    /// (h, a, gamma, dropout mask)
    type State = (FlexTensor, FlexTensor, FlexTensor, DropMask);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (h, a, gamma, drop) = ops.state;
        let m = drop.values();
        let x = host::residual(&slice(&h), &slice(&a), m);
        let (dx, dgamma, dbeta) =
            host::layer_norm_backward(&x, &slice(&gamma), &slice(&dy), LN_EPS);
        // d(h + a o m): dx to h, dx o m to a.
        let da = match m {
            Some(m) => dx.par_iter().zip(m.par_iter()).map(|(g, m)| g * m).collect(),
            None => dx.clone(),
        };
        let values =
            [(dx, shape(&h)), (da, shape(&a)), (dgamma, shape(&gamma)), (dbeta, shape(&gamma))];
        register(grads, ops.parents.map(|p| p.map(|n| n.id)), values);
    }
}

#[derive(Debug)]
struct LinearBackward;

impl Backward<Flex, 3> for LinearBackward {
    /// (x, w)
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, w) = ops.state;
        linear_grads(grads, ops.parents.map(|p| p.map(|n| n.id)), &x, &w, &slice(&dy));
    }
}

#[derive(Debug)]
struct LinearGeluBackward;

impl Backward<Flex, 3> for LinearGeluBackward {
    /// (x, w, pre-activation, dropout mask)
    type State = (FlexTensor, FlexTensor, FlexTensor, DropMask);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, w, h, drop) = ops.state;
        let m = drop.values();
        let dh = host::gelu_backward(&slice(&h), &slice(&dy), m);
        linear_grads(grads, ops.parents.map(|p| p.map(|n| n.id)), &x, &w, &dh);
    }
}

#[derive(Debug)]
struct AttentionBackward;

impl Backward<Flex, 3> for AttentionBackward {
    /// (q, k, v, args, the rows' log-sum-exp where the flash kernel ran)
    type State = (FlexTensor, FlexTensor, FlexTensor, AttnArgs, Option<Arc<Vec<f32>>>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dout = grads.consume::<Flex>(&ops.node);
        let (q, k, v, args, lse) = ops.state;
        let s = attn_shape(&q, &k, args.heads);
        let (qs, ks, vs, g) = (slice(&q), slice(&k), slice(&v), slice(&dout));
        let (dq, dk, dv) = match lse {
            Some(lse) => super::flash::backward((&qs, &ks, &vs), &g, &lse, &s, &args.mask),
            None => super::mha::attention_backward(&qs, &ks, &vs, &g, &s, &args.mask),
        };
        register(
            grads,
            ops.parents.map(|p| p.map(|n| n.id)),
            [(dq, shape(&q)), (dk, shape(&k)), (dv, shape(&v))],
        );
    }
}

#[derive(Debug)]
struct MaskedMseBackward;

impl Backward<Flex, 4> for MaskedMseBackward {
    /// (pred, x0, kf_mask, valid, the two means' counts)
    type State = (FlexTensor, FlexTensor, FlexTensor, FlexTensor, [f32; 2]);

    fn backward(self, ops: Ops<Self::State, 4>, grads: &mut Gradients, _: &mut Checkpointer) {
        let g = slice(&grads.consume::<Flex>(&ops.node)).to_vec();
        let (pred, x0, m, valid, counts) = ops.state;
        let [p_id, x_id, m_id, v_id] = ops.parents.map(|p| p.map(|n| n.id));
        assert!(m_id.is_none() && v_id.is_none(), "the loss masks are data, not parameters");
        let d = pred.layout().shape()[2];
        let (ps, xs, ms, vs) = (slice(&pred), slice(&x0), slice(&m), slice(&valid));
        let dp = mse::masked_mse_backward(&ps, &xs, &ms, &vs, d, [g[0], g[1]], counts);
        let dx = if x_id.is_some() { dp.par_iter().map(|v| -v).collect() } else { Vec::new() };
        register(grads, [p_id, x_id], [(dp, shape(&pred)), (dx, shape(&x0))]);
    }
}

#[derive(Debug)]
struct TemporalConvBackward;

impl Backward<Flex, 2> for TemporalConvBackward {
    /// (h, w, args)
    type State = (FlexTensor, FlexTensor, ConvArgs);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let dy = grads.consume::<Flex>(&ops.node);
        let (h, w, args) = ops.state;
        let s = conv_shape(&h, &w, args.skip);
        let (dh, dw) = conv::temporal_backward(&slice(&h), &slice(&w), &args.real, &slice(&dy), &s);
        register(grads, ops.parents.map(|p| p.map(|n| n.id)), [(dh, shape(&h)), (dw, shape(&w))]);
    }
}

impl<C: CheckpointStrategy> FusedOps for Autodiff<Flex, C> {
    fn fused_layer_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        record::<_, C, 3>(
            LayerNormBackward,
            [x, gamma, beta],
            |[x, g, b]| (Flex::fused_layer_norm(x.clone(), g.clone(), b), (x, g)),
            |[x, g, b]| Flex::fused_layer_norm(x, g, b),
        )
    }

    fn fused_residual_layer_norm(
        h: FloatTensor<Self>,
        a: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        drop: DropMask,
    ) -> FloatTensor<Self> {
        let plain = drop.clone(); // an Arc'd mask: cheap
        record::<_, C, 4>(
            ResidualLayerNormBackward,
            [h, a, gamma, beta],
            |[h, a, g, b]| {
                (
                    Flex::fused_residual_layer_norm(
                        h.clone(),
                        a.clone(),
                        g.clone(),
                        b,
                        drop.clone(),
                    ),
                    (h, a, g, drop),
                )
            },
            |[h, a, g, b]| Flex::fused_residual_layer_norm(h, a, g, b, plain),
        )
    }

    fn fused_linear(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        record::<_, C, 3>(
            LinearBackward,
            [x, w, b],
            |[x, w, b]| (Flex::fused_linear(x.clone(), w.clone(), b), (x, w)),
            |[x, w, b]| Flex::fused_linear(x, w, b),
        )
    }

    fn fused_linear_gelu(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
        drop: DropMask,
    ) -> FloatTensor<Self> {
        let plain = drop.clone(); // an Arc'd mask: cheap
        let tracked = |[x, w, b]: [FlexTensor; 3]| {
            // The pre-activation is kept for the backward pass.
            let h = host::linear_forward(&slice(&x), &slice(&w), &slice(&b));
            let y = host::gelu(&h, drop.values());
            let out: Shape = [x.layout().shape()[0], w.layout().shape()[1]].into();
            (tensor(y, out.clone()), (x, w, tensor(h, out), drop))
        };
        record::<_, C, 3>(LinearGeluBackward, [x, w, b], tracked, |[x, w, b]| {
            Flex::fused_linear_gelu(x, w, b, plain)
        })
    }

    fn fused_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        args: AttnArgs,
    ) -> FloatTensor<Self> {
        let plain = args.clone(); // an Arc'd mask: cheap
        record::<_, C, 3>(
            AttentionBackward,
            [q, k, v],
            |[q, k, v]| {
                let (out, lse) = super::attention_with_lse(&q, &k, &v, &args);
                (out, (q, k, v, args, lse))
            },
            |[q, k, v]| Flex::fused_attention(q, k, v, plain),
        )
    }

    fn fused_temporal_conv(
        h: FloatTensor<Self>,
        w: FloatTensor<Self>,
        args: ConvArgs,
    ) -> FloatTensor<Self> {
        let plain = args.clone(); // an Arc'd mask: cheap
        record::<_, C, 2>(
            TemporalConvBackward,
            [h, w],
            |[h, w]| (Flex::fused_temporal_conv(h.clone(), w.clone(), args.clone()), (h, w, args)),
            |[h, w]| Flex::fused_temporal_conv(h, w, plain),
        )
    }

    fn fused_masked_mse(
        pred: FloatTensor<Self>,
        x0: FloatTensor<Self>,
        kf_mask: FloatTensor<Self>,
        valid: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        record::<_, C, 4>(
            MaskedMseBackward,
            [pred, x0, kf_mask, valid],
            |[p, x, m, v]| {
                let (means, counts) = flex_masked_mse(&p, &x, &m, &v);
                (tensor(means.to_vec(), [2].into()), (p, x, m, v, counts))
            },
            |[p, x, m, v]| Flex::fused_masked_mse(p, x, m, v),
        )
    }
}
