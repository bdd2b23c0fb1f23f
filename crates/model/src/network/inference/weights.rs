//! The network's weights as the host path reads them: each Linear's [in, out] weight and bias,
//! each LayerNorm's scale and shift, viewed in the module's own buffers (no copy).

use std::ops::Range;

use burn::nn::{LayerNorm, Linear};

use super::par::RowsMut;
use crate::kernels::rows::linear;
use crate::kernels::HostView;
use crate::network::decoder::DecoderLayer;
use crate::network::keyframe_encoder::DmaBlock;

/// A Linear layer's weight [in, out] and bias [out].
pub(super) struct HostLinear {
    pub w: HostView,
    pub b: HostView,
}

impl HostLinear {
    pub fn new(l: &Linear) -> HostLinear {
        let out = l.weight.dims()[1];
        let b = l
            .bias
            .as_ref()
            .map_or_else(|| HostView::Owned(vec![0.0; out]), |b| HostView::of(b.val()));
        HostLinear { w: HostView::of(l.weight.val()), b }
    }

    pub fn width(&self) -> usize {
        self.b.len()
    }

    /// y [rows, out] = x [rows, in] . w + b (single-threaded: the caller owns these rows).
    pub fn apply(&self, x: &[f32], y: &mut [f32]) {
        linear(x, &self.w, &self.b, y)
    }

    /// x [rows, in] . w + b into a new [rows, out].
    pub fn applied(&self, x: &[f32]) -> Vec<f32> {
        let mut y = vec![0f32; x.len() / (self.w.len() / self.width()) * self.width()];
        self.apply(x, &mut y);
        y
    }
}

/// A LayerNorm's scale and shift (zeros without shift).
pub(super) fn norm(ln: &LayerNorm) -> (HostView, HostView) {
    let gamma = HostView::of(ln.gamma.val());
    let beta = ln
        .beta
        .as_ref()
        .map_or_else(|| HostView::Owned(vec![0.0; gamma.len()]), |b| HostView::of(b.val()));
    (gamma, beta)
}

/// One decoder layer; its cross- and word attentions' keys and values are the encoding's.
pub(super) struct HostLayer {
    pub qkv: [HostLinear; 3],
    pub self_out: HostLinear,
    pub cross_q: HostLinear,
    pub cross_out: HostLinear,
    pub words: Option<[HostLinear; 2]>,
    pub ff1: HostLinear,
    pub ff2: HostLinear,
    pub ln: [(HostView, HostView); 3],
    /// Temporal taps [K, d] and K.
    pub temporal: Option<(HostView, usize)>,
}

impl HostLayer {
    pub fn new(l: &DecoderLayer) -> HostLayer {
        let a = &l.self_attn;
        HostLayer {
            qkv: [&a.query, &a.key, &a.value].map(HostLinear::new),
            self_out: HostLinear::new(&a.output),
            cross_q: HostLinear::new(&l.cross_attn.query),
            cross_out: HostLinear::new(&l.cross_attn.output),
            words: l.words.as_ref().map(|w| [&w.query, &w.output].map(HostLinear::new)),
            ff1: HostLinear::new(&l.ff1),
            ff2: HostLinear::new(&l.ff2),
            ln: [&l.ln1, &l.ln2, &l.ln3].map(norm),
            temporal: l.temporal.as_ref().map(|t| (HostView::of(t.weight.val()), t.kernel)),
        }
    }

    /// Self-attention's queries, keys and values of token rows `r` (`h` holding those rows).
    pub fn project(&self, h: &[f32], r: &Range<usize>, dst: [RowsMut; 3]) {
        for (lin, dst) in self.qkv.iter().zip(dst) {
            // SAFETY: the regions hand each task its own rows.
            lin.apply(h, unsafe { dst.get(r) });
        }
    }
}

/// One DMA block of the keyframe encoder.
pub(super) struct HostBlock {
    pub qkv: [HostLinear; 3],
    pub out: HostLinear,
    pub fc: HostLinear,
    pub mlp1: HostLinear,
    pub mlp2: HostLinear,
    pub heads: usize,
}

impl HostBlock {
    pub fn new(b: &DmaBlock) -> HostBlock {
        let a = &b.attn;
        HostBlock {
            qkv: [&a.query, &a.key, &a.value].map(HostLinear::new),
            out: HostLinear::new(&a.output),
            fc: HostLinear::new(&b.fc),
            mlp1: HostLinear::new(&b.mlp1),
            mlp2: HostLinear::new(&b.mlp2),
            heads: a.heads,
        }
    }
}
