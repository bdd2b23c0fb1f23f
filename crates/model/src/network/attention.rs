//! Multi-head attention: query/key/value/output projections around the attention core of
//! `kernels` (a fused kernel on flex, Burn's ops elsewhere). Keys are masked with a host-side
//! [`Mask`] (true = this query must not see this key). Unlike torch's nn.MultiheadAttention
//! there is no dropout on the attention weights; dropout stays on the residual branches.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::kernels::{self, linear, worth_gathering, Mask};

#[derive(Module, Debug)]
pub struct Attention {
    pub(super) query: Linear,
    pub(super) key: Linear,
    pub(super) value: Linear,
    pub(super) output: Linear,
    pub(super) heads: usize,
}

impl Attention {
    pub fn new(d: usize, heads: usize, device: &Device) -> Self {
        assert_eq!(d % heads, 0, "d_model {d} is not a multiple of {heads} heads");
        Attention {
            query: LinearConfig::new(d, d).init(device),
            key: LinearConfig::new(d, d).init(device),
            value: LinearConfig::new(d, d).init(device),
            output: LinearConfig::new(d, d).init(device),
            heads,
        }
    }

    /// An attention whose output projection starts at zero: a branch added to a trained model
    /// that computes nothing until training moves it.
    pub fn zero_output(d: usize, heads: usize, device: &Device) -> Self {
        Attention {
            output: LinearConfig::new(d, d)
                .with_initializer(burn::nn::Initializer::Zeros)
                .init(device),
            ..Attention::new(d, heads, device)
        }
    }

    /// `q_in` [B, Lq, d] attends to `kv_in` [B, Lk, d] under `mask` -> [B, Lq, d]. Every query
    /// must see at least one key.
    pub fn forward(&self, q_in: Tensor<3>, kv_in: Tensor<3>, mask: Mask) -> Tensor<3> {
        let kv = self.keys_values(kv_in);
        self.forward_kv(q_in, &kv, mask)
    }

    /// Keys and values [B, Lk, d] of `kv_in`: computed once where the same keys serve many
    /// calls (the encoder output across denoising steps).
    pub fn keys_values(&self, kv_in: Tensor<3>) -> (Tensor<3>, Tensor<3>) {
        (linear(&self.key, kv_in.clone()), linear(&self.value, kv_in))
    }

    /// Self-attention of the token rows `x` [B*L, d] where only `queries` are wanted and only
    /// `keys` may be seen (the mask blocks the rest): projections run on those rows only, the
    /// attention core on the whole [B, L, d] layout (zeros elsewhere) -> [queries, d].
    pub fn forward_rows(
        &self,
        x: Tensor<2>,
        b: usize,
        queries: &TokenRows,
        keys: &TokenRows,
        mask: Mask,
    ) -> Tensor<2> {
        let [bl, d] = x.dims();
        let full = |rows: &TokenRows, lin: &Linear| {
            rows.scatter(linear(lin, rows.gather(x.clone()))).reshape([b, bl / b, d])
        };
        let ctx = kernels::attention(
            full(queries, &self.query),
            full(keys, &self.key),
            full(keys, &self.value),
            self.heads,
            mask,
        );
        linear(&self.output, queries.gather(ctx.reshape([bl, d])))
    }

    /// Attention of `q_in` [B, Lq, d] to precomputed keys and values.
    pub fn forward_kv(
        &self,
        q_in: Tensor<3>,
        kv: &(Tensor<3>, Tensor<3>),
        mask: Mask,
    ) -> Tensor<3> {
        let q = linear(&self.query, q_in);
        linear(&self.output, kernels::attention(q, kv.0.clone(), kv.1.clone(), self.heads, mask))
    }
}

/// A subset of the B x (1+N) token rows, as the index to gather them (None: all rows, or so
/// many that gathering would cost more than it saves).
pub struct TokenRows {
    pub count: usize,
    pub total: usize,
    pub index: Option<Tensor<1, Int>>,
}

impl TokenRows {
    pub fn new(mask: &[bool], device: &Device) -> TokenRows {
        let rows: Vec<i64> =
            mask.iter().enumerate().filter(|(_, &v)| v).map(|(i, _)| i as i64).collect();
        let (count, total) = (rows.len(), mask.len());
        let index = worth_gathering(count, total)
            .then(|| Tensor::<1, Int>::from_data(TensorData::new(rows, [count]), device));
        TokenRows { count, total, index }
    }

    /// The subset's rows of x [total, d] -> [count or total, d].
    pub fn gather(&self, x: Tensor<2>) -> Tensor<2> {
        match &self.index {
            Some(idx) => x.select(0, idx.clone()),
            None => x,
        }
    }

    /// Rows [count, d] back in place among zeros -> [total, d].
    pub fn scatter(&self, x: Tensor<2>) -> Tensor<2> {
        match &self.index {
            Some(idx) => Tensor::zeros([self.total, x.dims()[1]], &x.device()).select_assign(
                0,
                idx.clone(),
                x,
                IndexingUpdateOp::Add,
            ),
            None => x,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::activation::softmax;
    use burn::tensor::Distribution;

    /// The fused op against softmax(QK^T/sqrt(dk) + mask) V written out by hand.
    #[test]
    fn matches_explicit_attention() {
        let dev = Device::flex();
        let (b, lq, lk, d, h) = (2, 7, 9, 16, 4);
        let att = Attention::new(d, h, &dev);
        let x = Tensor::<3>::random([b, lq, d], Distribution::Normal(0.0, 1.0), &dev);
        let y = Tensor::<3>::random([b, lk, d], Distribution::Normal(0.0, 1.0), &dev);
        let blocked: Vec<bool> =
            (0..b * lq * lk).map(|i| i % lk != 0 && (i * 7919) % 3 == 0).collect();
        let m = Mask::Full(std::sync::Arc::new(blocked.clone()));
        let got = att.forward(x.clone(), y.clone(), m).into_data().try_to_vec::<f32>().unwrap();
        let split = |t: Tensor<3>, l: usize| t.reshape([b, l, h, d / h]).swap_dims(1, 2);
        let q = split(att.query.forward(x), lq);
        let k = split(att.key.forward(y.clone()), lk);
        let v = split(att.value.forward(y), lk);
        let bias: Vec<f32> = blocked.iter().map(|&x| if x { -1e9 } else { 0.0 }).collect();
        let bias = Tensor::<1>::from_floats(bias.as_slice(), &dev).reshape([b, 1, lq, lk]);
        let w = softmax(q.matmul(k.transpose()).div_scalar(((d / h) as f32).sqrt()) + bias, 3);
        let want = att
            .output
            .forward(w.matmul(v).swap_dims(1, 2).reshape([b, lq, d]))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let e = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(e < 1e-5, "{e}");
    }
}
