//! What the decoder reads of one condition, computed on the host: `Denoiser::encode` (the text
//! token, the keyframe encoder's DMA blocks, the cross-attention keys and values of its output,
//! the word tokens' keys and values, the masks) with the same kernels, once per sample.

use std::borrow::Borrow;
use std::sync::Arc;

use burn::prelude::*;
use rayon::prelude::*;

use super::par::{at, par_rows, RowsMut};
use super::weights::{HostBlock, HostLinear};
use crate::kernels::rows::gelu;
use crate::kernels::{attention_host, key_mask, worth_gathering, AttnShape, Mask};
use crate::network::condition::Condition;
use crate::network::denoiser::{self_padding, Denoiser, Encoded};
use crate::network::keyframe_encoder::DmaPlan;
use crate::network::params::host;
use crate::network::sinusoidal::position_table;
use crate::network::words;

/// Keys and values [B, Lk, d] an attention reads, with the keys it may not see.
pub(super) struct Memory {
    pub kv: (Vec<f32>, Vec<f32>),
    pub lk: usize,
    pub mask: Mask,
}

/// Everything the decoder's calls read of one condition: B samples of N frames, width d.
pub(super) struct Encoding {
    pub batch: usize,
    pub n: usize,
    pub d: usize,
    /// [B, d] text tokens, [N, d] frame positions, [B, N, d] embedded key observations.
    pub text_tok: Vec<f32>,
    pub pos: Vec<f32>,
    pub key: Option<Vec<f32>>,
    /// Padding of the decoder's own sequence [B * (2 + N)].
    pub self_pad: Mask,
    /// Per decoder layer: the encoder output's keys and values, and the word tokens'.
    pub cross: Vec<Memory>,
    pub words: Vec<Memory>,
    /// [B * N] 1 on real frames.
    pub real: Vec<f32>,
}

/// x [rows, in] . w + b on all threads -> [rows, out].
fn applied_par(lin: &HostLinear, x: &[f32]) -> Vec<f32> {
    applied_each(&[lin], x).pop().expect("one layer")
}

/// Each of `lins` (of one input width) on x [rows, in], in one parallel region: every thread
/// applies them all to its block of rows, the blocks `par_rows` gives each alone -> one
/// [rows, out] per layer.
fn applied_each<L: Borrow<HostLinear> + Sync>(lins: &[L], x: &[f32]) -> Vec<Vec<f32>> {
    let Some(first) = lins.first().map(Borrow::borrow) else {
        return Vec::new();
    };
    let n_in = first.w.len() / first.width();
    let rows = x.len() / n_in;
    let lins: Vec<&HostLinear> = lins.iter().map(Borrow::borrow).collect();
    let mut ys: Vec<Vec<f32>> = lins.iter().map(|l| vec![0f32; rows * l.width()]).collect();
    let dst: Vec<RowsMut> =
        ys.iter_mut().zip(&lins).map(|(y, l)| RowsMut::of(y, l.width())).collect();
    par_rows(rows, |r| {
        for (lin, dst) in lins.iter().zip(&dst) {
            // SAFETY: each task writes its own rows.
            lin.apply(at(x, &r, n_in), unsafe { dst.get(&r) });
        }
    });
    ys
}

/// Rows `rows` of x [_, width].
fn gather(x: &[f32], rows: &[usize], width: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(rows.len() * width);
    for &r in rows {
        out.extend_from_slice(&x[r * width..(r + 1) * width]);
    }
    out
}

/// The rows a block runs on (`attention::TokenRows`): those `mask` marks, or all `mask.len()` of them
/// when gathering would cost more than it saves.
fn rows_of(mask: &[bool]) -> Vec<usize> {
    let picked: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
    if worth_gathering(picked.len(), mask.len()) {
        picked
    } else {
        (0..mask.len()).collect()
    }
}

/// Each of `lins` of the rows `rows` of z, put back in place among zeros -> [B * L, d] each.
fn projected(lins: &[&HostLinear], z: &[f32], rows: &[usize], d: usize) -> Vec<Vec<f32>> {
    let ys = applied_each(lins, &gather(z, rows, d));
    ys.iter()
        .map(|y| {
            let mut full = vec![0f32; z.len()];
            for (k, &r) in rows.iter().enumerate() {
                full[r * d..(r + 1) * d].copy_from_slice(&y[k * d..(k + 1) * d]);
            }
            full
        })
        .collect()
}

/// One DMA block on z [B * L, d] (`DmaBlock::forward`): the active rows attend to the valid ones
/// under the block's mask and take FC([a || z]) through the MLP; inactive rows stay as they were
/// unless so many rows are active that all of them run.
fn dma_block(
    bl: &HostBlock,
    z: &mut [f32],
    s: AttnShape,
    blocked: &[bool],
    active: &[bool],
    valid: &[bool],
) {
    let d = s.d;
    if !active.iter().any(|&a| a) {
        return;
    }
    let (queries, keys) = (rows_of(active), rows_of(valid));
    let [wq, wk, wv] = &bl.qkv;
    let zs = gather(z, &queries, d);
    let q = applied_par(wq, &zs);
    let [k, v]: [Vec<f32>; 2] = projected(&[wk, wv], z, &keys, d).try_into().expect("two");
    let zk = block_mlp(bl, &attention_of_rows(&q, &k, &v, s, blocked, &queries), &zs);
    if queries.len() == z.len() / d {
        z.copy_from_slice(&zk);
        return;
    }
    for (k, &r) in queries.iter().enumerate() {
        let (row, new, old) =
            (&mut z[r * d..(r + 1) * d], &zk[k * d..(k + 1) * d], &zs[k * d..(k + 1) * d]);
        row.iter_mut().zip(new.iter().zip(old)).for_each(|(z, (n, o))| *z += n - o);
    }
}

/// The block's rows after attention: mlp2(GELU(mlp1(FC([out(a) || zs])))) of a and zs
/// [rows, d], each thread chaining them on its block of rows (the blocks `par_rows` gives each
/// layer alone) -> [rows, d].
fn block_mlp(bl: &HostBlock, a: &[f32], zs: &[f32]) -> Vec<f32> {
    let d = bl.out.width();
    let rows = a.len() / d;
    let (fc, wide) = (bl.fc.width(), bl.mlp1.width());
    let mut zk = vec![0f32; rows * d];
    let dst = RowsMut::of(&mut zk, d);
    par_rows(rows, |r| {
        let n = r.len();
        let (mut o, mut cat) = (vec![0f32; n * d], Vec::with_capacity(2 * n * d));
        bl.out.apply(at(a, &r, d), &mut o);
        for (o, z) in o.chunks(d).zip(at(zs, &r, d).chunks(d)) {
            cat.extend_from_slice(o);
            cat.extend_from_slice(z);
        }
        let (mut f, mut h) = (vec![0f32; n * fc], vec![0f32; n * wide]);
        bl.fc.apply(&cat, &mut f);
        bl.mlp1.apply(&f, &mut h);
        gelu(&mut h);
        // SAFETY: each task writes its own rows.
        bl.mlp2.apply(&h, unsafe { dst.get(&r) });
    });
    zk
}

/// The attention of the query rows `rows` (ascending, of B * L) alone, their queries `q`
/// [rows, d] -> [rows, d]: each sample's rows against its keys and values (`k`, `v` [B * L, d])
/// under their rows of the mask, the samples in parallel. A query row's result does not depend
/// on the rows computed beside it, and the keys the rows see are those all rows see (an inactive
/// row sees only the text token, which the text query, always active, sees too): the same bits
/// as the whole attention's rows, without the inactive rows (most rows of the narrow blocks, and
/// of a guided batch's keyless branch).
fn attention_of_rows(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    s: AttnShape,
    blocked: &[bool],
    rows: &[usize],
) -> Vec<f32> {
    let (l, d) = (s.lk, s.d);
    let first = |b: usize| rows.partition_point(|&r| r < b * l);
    let parts: Vec<Vec<f32>> = (0..s.batch)
        .into_par_iter()
        .map(|b| {
            let span = first(b)..first(b + 1);
            if span.is_empty() {
                return Vec::new();
            }
            let mine = &rows[span.clone()];
            let mask = mine.iter().flat_map(|&r| &blocked[r * l..(r + 1) * l]).copied().collect();
            let shape = AttnShape { batch: 1, lq: mine.len(), ..s };
            let kv = b * l * d..(b + 1) * l * d;
            let q = &q[span.start * d..span.end * d];
            attention_host(q, &k[kv.clone()], &v[kv], &shape, &Mask::Full(Arc::new(mask)))
        })
        .collect();
    parts.concat()
}

/// [B * N, 2 (D + R)]: each frame's keyed values (masked) and mask, then its root channels and
/// theirs (`KeyframeEncoder::observations`).
fn observations(c: &Condition, root_channels: usize) -> Vec<f32> {
    let (kf, m, root, rm) = (
        host(c.kf.clone()),
        host(c.kf_mask.clone()),
        host(c.root.clone()),
        host(c.root_mask.clone()),
    );
    let [b, n, dim] = c.kf.dims();
    let rc = c.root.dims()[2];
    let mut out = Vec::with_capacity(b * n * 2 * (dim + root_channels));
    for f in 0..b * n {
        let (kf, m) = (&kf[f * dim..(f + 1) * dim], &m[f * dim..(f + 1) * dim]);
        out.extend(kf.iter().zip(m).map(|(v, m)| v * m));
        out.extend_from_slice(m);
        if root_channels > 0 {
            let (root, rm) =
                (&root[f * rc..f * rc + root_channels], &rm[f * rc..f * rc + root_channels]);
            out.extend(root.iter().zip(rm).map(|(v, m)| v * m));
            out.extend_from_slice(rm);
        }
    }
    out
}

/// The text token [B, d] of the pooled embedding, and (models with word states) each decoder
/// layer's keys and values of the word tokens (`words::WordInput`).
fn text(model: &Denoiser, c: &Condition) -> (Vec<f32>, Vec<Memory>) {
    let text = host(c.text.clone());
    let b = c.kf.dims()[0];
    let (td, w, d) = (model.text_dim, model.text_words, model.d_model);
    let width = text.len() / b;
    let pooled: Vec<f32> = text.chunks(width).flat_map(|t| &t[..td]).copied().collect();
    let text_tok = HostLinear::new(&model.text_in).applied(&pooled);
    let Some(wi) = model.word_in.as_ref().filter(|_| w > 0) else {
        return (text_tok, Vec::new());
    };
    let states: Vec<f32> =
        text.chunks(width).flat_map(|t| &t[td..]).map(|v| v * wi.scale).collect();
    let mut tokens = HostLinear::new(&wi.proj).applied(&states);
    let pos = position_table(w, d);
    for t in tokens.chunks_mut(w * d) {
        t.iter_mut().zip(&pos).for_each(|(t, p)| *t += p);
    }
    let mask = key_mask(words::padding(&text, b, td, w));
    let attns = model.layers.iter().filter_map(|l| l.words.as_ref());
    let lins: Vec<HostLinear> =
        attns.flat_map(|a| [&a.key, &a.value]).map(HostLinear::new).collect();
    (text_tok, memories(&lins, &tokens, w, &mask))
}

/// Per layer, the keys and values of `tokens` [B * lk, d] through `lins` (each layer's key and
/// value projections, one after the other), all in one parallel region.
fn memories(lins: &[HostLinear], tokens: &[f32], lk: usize, mask: &Mask) -> Vec<Memory> {
    let mut kv = applied_each(lins, tokens).into_iter();
    let mut out = Vec::new();
    while let (Some(k), Some(v)) = (kv.next(), kv.next()) {
        out.push(Memory { kv: (k, v), lk, mask: mask.clone() });
    }
    out
}

/// The keyframe encoder's output [B * (1 + N), d]: the text token and the frames' embedded
/// observations `frames` [B * N, d] (with positions) through the DMA blocks, plus the global skip.
fn keyframe_encoder(
    model: &Denoiser,
    plan: &DmaPlan,
    text_tok: &[f32],
    frames: &[f32],
    pos: &[f32],
) -> Vec<f32> {
    let enc = &model.encoder;
    let (b, n, d) = (plan.batch, plan.frames, model.d_model);
    let l = n + 1;
    let mut z0 = vec![0f32; b * l * d];
    for s in 0..b {
        z0[s * l * d..(s * l + 1) * d].copy_from_slice(&text_tok[s * d..(s + 1) * d]);
        let rows = z0[(s * l + 1) * d..(s + 1) * l * d].iter_mut();
        let src = frames[s * n * d..(s + 1) * n * d].iter().zip(pos);
        rows.zip(src).for_each(|(z, (f, p))| *z = f + p);
    }
    let mut z = z0.clone();
    for (k, block) in enc.blocks.iter().enumerate() {
        let bl = HostBlock::new(block);
        let s = AttnShape { batch: b, lq: l, lk: l, heads: bl.heads, d };
        dma_block(&bl, &mut z, s, &plan.blocked[k], &plan.active[k], plan.valid_before(k));
    }
    z.iter_mut().zip(&z0).for_each(|(z, z0)| *z += z0);
    z
}

impl Encoding {
    /// `Denoiser::encode` of `c` on the host.
    pub fn new(model: &Denoiser, c: &Condition) -> Encoding {
        let [b, n, _] = c.kf.dims();
        let d = model.d_model;
        let (text_tok, words) = text(model, c);
        let obs = observations(c, model.encoder.root_channels);
        // The frames' embedding and the decoder's key input read the same rows: one region.
        let embeds: Vec<HostLinear> = std::iter::once(&model.encoder.kf_in)
            .chain(&model.key_in)
            .map(HostLinear::new)
            .collect();
        let mut embedded = applied_each(&embeds, &obs).into_iter();
        let (frames, key) = (embedded.next().expect("kf_in"), embedded.next());
        let pos = position_table(n, d);
        let plan = DmaPlan::new(&c.kf_frames, &c.real, b, n, &model.dma_sizes);
        let tokens = keyframe_encoder(model, &plan, &text_tok, &frames, &pos);
        let key_pad = key_mask(plan.final_valid().iter().map(|v| !v).collect());
        let attns = model.layers.iter().map(|l| &l.cross_attn);
        let lins: Vec<HostLinear> =
            attns.flat_map(|a| [&a.key, &a.value]).map(HostLinear::new).collect();
        let cross = memories(&lins, &tokens, n + 1, &key_pad);
        Encoding {
            batch: b,
            n,
            d,
            text_tok,
            pos,
            key,
            self_pad: self_padding(&c.real, b, n),
            cross,
            words,
            real: c.real.iter().map(|&r| if r { 1.0 } else { 0.0 }).collect(),
        }
    }

    /// The tensor encoder's output read back (the decoder's tests take it apart from this
    /// encoder).
    pub fn of_encoded(e: &Encoded) -> Encoding {
        let [b, l, d] = e.tokens.dims();
        let memory = |kv: &(Tensor<3>, Tensor<3>), mask: &Mask| Memory {
            lk: kv.0.dims()[1],
            kv: (host(kv.0.clone()), host(kv.1.clone())),
            mask: mask.clone(),
        };
        let words = match &e.words {
            Some(m) => m.kv.iter().map(|kv| memory(kv, &m.pad)).collect(),
            None => Vec::new(),
        };
        Encoding {
            batch: b,
            n: l - 1,
            d,
            text_tok: host(e.text_tok.clone()),
            pos: host(e.pos.clone()),
            key: e.key.clone().map(host),
            self_pad: e.self_pad.clone(),
            cross: e.cross_kv.iter().map(|kv| memory(kv, &e.key_pad)).collect(),
            words,
            real: e.real.host.to_vec(),
        }
    }
}
