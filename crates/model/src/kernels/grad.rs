//! The fused ops under autodiff: forward on the flex tensors, backward by the host kernels.
//! Each op keeps its inputs (already alive in the graph) and recomputes what it needs.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Flex};

use super::{attn_shape, host, slice, tensor, AttnArgs, FusedOps, LN_EPS};

#[derive(Debug)]
struct LayerNormBackward;

impl Backward<Flex, 3> for LayerNormBackward {
    /// (x, gamma)
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, gamma_node, beta_node] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, gamma) = ops.state;
        let (dx, dgamma, dbeta) = host::layer_norm_backward(&slice(&x), &slice(&gamma), &slice(&dy), LN_EPS);
        let d = gamma.layout().shape().clone();
        if let Some(n) = x_node {
            grads.register::<Flex>(n.id, tensor(dx, x.layout().shape().clone()));
        }
        if let Some(n) = gamma_node {
            grads.register::<Flex>(n.id, tensor(dgamma, d.clone()));
        }
        if let Some(n) = beta_node {
            grads.register::<Flex>(n.id, tensor(dbeta, d));
        }
    }
}

#[derive(Debug)]
struct LinearBackward;

impl Backward<Flex, 3> for LinearBackward {
    /// (x, w)
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, w_node, b_node] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, w) = ops.state;
        let n_out = w.layout().shape()[1];
        let (dx, dw, db) = host::linear_backward(&slice(&x), &slice(&w), &slice(&dy), n_out);
        for (node, g, shape) in [(x_node, dx, x.layout().shape().clone()), (w_node, dw, w.layout().shape().clone()), (b_node, db, [n_out].into())] {
            if let Some(n) = node {
                grads.register::<Flex>(n.id, tensor(g, shape));
            }
        }
    }
}

#[derive(Debug)]
struct LinearGeluBackward;

impl Backward<Flex, 3> for LinearGeluBackward {
    /// (x, w, pre-activation)
    type State = (FlexTensor, FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [x_node, w_node, b_node] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, w, h) = ops.state;
        let n_out = w.layout().shape()[1];
        let dh = host::gelu_backward(&slice(&h), &slice(&dy));
        let (dx, dw, db) = host::linear_backward(&slice(&x), &slice(&w), &dh, n_out);
        for (node, g, shape) in [(x_node, dx, x.layout().shape().clone()), (w_node, dw, w.layout().shape().clone()), (b_node, db, [n_out].into())] {
            if let Some(n) = node {
                grads.register::<Flex>(n.id, tensor(g, shape));
            }
        }
    }
}

#[derive(Debug)]
struct AttentionBackward;

impl Backward<Flex, 3> for AttentionBackward {
    /// (q, k, v, args)
    type State = (FlexTensor, FlexTensor, FlexTensor, AttnArgs);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [q_node, k_node, v_node] = ops.parents;
        let dout = grads.consume::<Flex>(&ops.node);
        let (q, k, v, args) = ops.state;
        let s = attn_shape(&q, &k, args.heads);
        let (dq, dk, dv) = host::attention_backward(&slice(&q), &slice(&k), &slice(&v), &slice(&dout), &s, &args.mask);
        for (node, g, t) in [(q_node, dq, &q), (k_node, dk, &k), (v_node, dv, &v)] {
            if let Some(n) = node {
                grads.register::<Flex>(n.id, tensor(g, t.layout().shape().clone()));
            }
        }
    }
}

impl<C: CheckpointStrategy> FusedOps for Autodiff<Flex, C> {
    fn fused_layer_norm(x: FloatTensor<Self>, gamma: FloatTensor<Self>, beta: FloatTensor<Self>) -> FloatTensor<Self> {
        match LayerNormBackward.prepare::<C>([x.node(), gamma.node(), beta.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (x, gamma, beta) = (x.into_primitive(), gamma.into_primitive(), beta.into_primitive());
                let y = Flex::fused_layer_norm(x.clone(), gamma.clone(), beta);
                prep.finish((x, gamma), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::fused_layer_norm(x.into_primitive(), gamma.into_primitive(), beta.into_primitive())),
        }
    }

    fn fused_linear(x: FloatTensor<Self>, w: FloatTensor<Self>, b: FloatTensor<Self>) -> FloatTensor<Self> {
        match LinearBackward.prepare::<C>([x.node(), w.node(), b.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (x, w, b) = (x.into_primitive(), w.into_primitive(), b.into_primitive());
                let y = Flex::fused_linear(x.clone(), w.clone(), b);
                prep.finish((x, w), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::fused_linear(x.into_primitive(), w.into_primitive(), b.into_primitive())),
        }
    }

    fn fused_linear_gelu(x: FloatTensor<Self>, w: FloatTensor<Self>, b: FloatTensor<Self>) -> FloatTensor<Self> {
        match LinearGeluBackward.prepare::<C>([x.node(), w.node(), b.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (x, w, b) = (x.into_primitive(), w.into_primitive(), b.into_primitive());
                let h = host::linear_forward(&slice(&x), &slice(&w), &slice(&b));
                let mut y = h.clone();
                host::gelu_inplace(&mut y);
                let shape: burn::tensor::Shape = [x.layout().shape()[0], w.layout().shape()[1]].into();
                prep.finish((x, w, tensor(h, shape.clone())), tensor(y, shape))
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::fused_linear_gelu(x.into_primitive(), w.into_primitive(), b.into_primitive())),
        }
    }

    fn fused_attention(q: FloatTensor<Self>, k: FloatTensor<Self>, v: FloatTensor<Self>, args: AttnArgs) -> FloatTensor<Self> {
        match AttentionBackward.prepare::<C>([q.node(), k.node(), v.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (q, k, v) = (q.into_primitive(), k.into_primitive(), v.into_primitive());
                let out = Flex::fused_attention(q.clone(), k.clone(), v.clone(), args.clone());
                prep.finish((q, k, v, args), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::fused_attention(q.into_primitive(), k.into_primitive(), v.into_primitive(), args)),
        }
    }
}
