//! One pass of the decoder's layers over a run of samples: all of a call's samples, each row
//! region split over the threads, or, where the batch splits evenly over the threads, one run of
//! samples per thread, each thread taking its samples through every layer on its own.
//!
//! Why the second: a call is about 15 row regions and 9 attentions, each a hand-over between
//! the threads; the attentions split into per-head tasks, and short ones (32 words) gained
//! nothing from a second thread. Per thread, nothing waits. The row blocks are the ones the
//! regions give the threads (`par_rows` splits B x (2 + N) rows into equal blocks, one per
//! thread: one run of samples each), and every attention head is computed alone either way, so
//! the values are the same bits.

use std::ops::Range;

use super::encoder::{Encoding, Memory};
use super::par::{at, par_rows, RowsMut};
use super::weights::{HostLayer, HostLinear};
use crate::kernels::rows::{gelu, residual_layer_norm};
use crate::kernels::{attention_host, temporal_add_rows, AttnShape, ConvShape, Mask};

/// The masks of one run of samples: the decoder's own padding and, per layer, the cross- and
/// word attentions' (the encoding's, restricted to those samples).
pub(super) struct RunMasks {
    samples: Range<usize>,
    self_pad: Mask,
    cross: Vec<Mask>,
    words: Vec<Mask>,
}

impl RunMasks {
    pub fn new(enc: &Encoding, samples: Range<usize>) -> RunMasks {
        let lq = enc.n + 2;
        let cut = |m: &Mask, lk: usize| m.of_samples(samples.clone(), lq, lk);
        RunMasks {
            self_pad: cut(&enc.self_pad, lq),
            cross: enc.cross.iter().map(|m| cut(&m.mask, m.lk)).collect(),
            words: enc.words.iter().map(|m| cut(&m.mask, m.lk)).collect(),
            samples,
        }
    }
}

/// The activation buffers of a call, [B * (2 + N), width] each, as row views: a pass offsets
/// them to its first row and writes only its own rows.
#[derive(Clone, Copy)]
pub(super) struct Buffers {
    pub h: RowsMut,
    pub h2: RowsMut,
    pub q: RowsMut,
    pub k: RowsMut,
    pub v: RowsMut,
    pub tmp: RowsMut,
    pub ff: RowsMut,
    /// [B * N, D]: frame rows.
    pub out: RowsMut,
}

/// What a pass reads: the weights, the encoding, the timestep embeddings [B, d] and the input
/// frames [b, N, d] (sample s reads frames s mod b).
pub(super) struct Inputs<'a> {
    pub layers: &'a [HostLayer],
    pub out: &'a HostLinear,
    pub heads: usize,
    pub enc: &'a Encoding,
    pub time: &'a [f32],
    pub frames: &'a [f32],
}

/// The decoder's layers over the samples of `masks`, in `bufs` (views of the whole call's
/// buffers); each region over all threads, or on this thread alone (`alone`).
pub(super) struct Pass<'a> {
    x: &'a Inputs<'a>,
    masks: &'a RunMasks,
    bufs: Buffers,
    alone: bool,
}

impl<'a> Pass<'a> {
    pub fn new(x: &'a Inputs<'a>, masks: &'a RunMasks, bufs: Buffers, alone: bool) -> Pass<'a> {
        let (s0, l, n) = (masks.samples.start, x.enc.n + 2, x.enc.n);
        let bufs = Buffers {
            h: bufs.h.offset(s0 * l),
            h2: bufs.h2.offset(s0 * l),
            q: bufs.q.offset(s0 * l),
            k: bufs.k.offset(s0 * l),
            v: bufs.v.offset(s0 * l),
            tmp: bufs.tmp.offset(s0 * l),
            ff: bufs.ff.offset(s0 * l),
            out: bufs.out.offset(s0 * n),
        };
        Pass { x, masks, bufs, alone }
    }

    /// Every layer; the output rows of these samples end in `out`.
    pub fn run(mut self) {
        self.input();
        for i in 0..self.x.layers.len() {
            self.layer(i);
        }
    }

    fn batch(&self) -> usize {
        self.masks.samples.len()
    }

    fn rows(&self) -> usize {
        self.batch() * (self.x.enc.n + 2)
    }

    /// `f` on the pass's rows: split over the threads, or in one block on this one.
    fn region(&self, f: impl Fn(Range<usize>) + Sync) {
        if self.alone {
            f(0..self.rows())
        } else {
            par_rows(self.rows(), f)
        }
    }

    /// All rows of a buffer of the pass, to read while no region writes it.
    fn all(&self, b: RowsMut) -> &[f32] {
        // SAFETY: the pass's own rows; between regions nothing writes them.
        unsafe { b.get(&(0..self.rows())) }
    }

    /// h = [y_t, text token, frames + positions (+ key observations)] per sample, then the
    /// first layer's projections of those rows.
    fn input(&self) {
        let (e, d, l, s0) = (self.x.enc, self.x.enc.d, self.x.enc.n + 2, self.masks.samples.start);
        let (n, xb) = (e.n, self.x.frames.len() / (e.n * d));
        let (time, fr) = (self.x.time, self.x.frames);
        let (text, pos, key) = (&e.text_tok, &e.pos, e.key.as_deref());
        let first = self.x.layers.first();
        let (h, qkv) = (self.bufs.h, [self.bufs.q, self.bufs.k, self.bufs.v]);
        self.region(|r| {
            // SAFETY: each task writes its own rows.
            let out = unsafe { h.get(&r) };
            for (row, o) in r.clone().zip(out.chunks_mut(d)) {
                let (s, i) = (s0 + row / l, row % l);
                match i {
                    0 => o.copy_from_slice(&time[s * d..(s + 1) * d]),
                    1 => o.copy_from_slice(&text[s * d..(s + 1) * d]),
                    _ => {
                        let f = i - 2;
                        let src = &fr[((s % xb) * n + f) * d..((s % xb) * n + f + 1) * d];
                        let p = &pos[f * d..(f + 1) * d];
                        o.iter_mut().zip(src).zip(p).for_each(|((o, x), p)| *o = x + p);
                        if let Some(k) = key {
                            let k = &k[(s * n + f) * d..(s * n + f + 1) * d];
                            o.iter_mut().zip(k).for_each(|(o, k)| *o += k);
                        }
                    }
                }
            }
            if let Some(layer) = first {
                layer.project(out, &r, qkv);
            }
        });
    }

    /// softmax(q k^T) v of the pass's queries over these samples' keys and values [b, lk, d]
    /// -> [rows, d].
    fn attend(&self, (k, v): (&[f32], &[f32]), lk: usize, mask: &Mask) -> Vec<f32> {
        let (batch, d) = (self.batch(), self.x.enc.d);
        let shape = AttnShape { batch, lq: self.x.enc.n + 2, lk, heads: self.x.heads, d };
        attention_host(self.all(self.bufs.q), k, v, &shape, mask)
    }

    /// The keys and values of an encoding's memory [B, lk, d] (all samples) that are these
    /// samples'.
    fn memory<'m>(&self, m: &'m Memory) -> (&'m [f32], &'m [f32]) {
        let (s, span) = (&self.masks.samples, m.lk * self.x.enc.d);
        let cut = |x: &'m [f32]| &x[s.start * span..s.end * span];
        (cut(&m.kv.0), cut(&m.kv.1))
    }

    /// Decoder layer `i`: h -> h (`DecoderLayer::forward` without dropout).
    fn layer(&mut self, i: usize) {
        let (e, d, l) = (self.x.enc, self.x.enc.d, self.x.enc.n + 2);
        let layer = &self.x.layers[i];
        let b = self.bufs;
        // Self-attention's core over each whole sequence (its projections were the last
        // region's).
        let kv = (self.all(b.k), self.all(b.v));
        let ctx = self.attend(kv, l, &self.masks.self_pad);
        // Its output, the temporal convolution, h2 = LN1(h + a), and the cross-attention's
        // queries.
        let conv = layer.temporal.as_ref().map(|(w, kernel)| {
            let s = ConvShape { batch: self.batch(), rows: l, skip: 2, d, kernel: *kernel };
            (w, s)
        });
        let (h, s) = (self.all(b.h), &self.masks.samples);
        let real = &e.real[s.start * e.n..s.end * e.n];
        self.region(|r| {
            // SAFETY: each task writes its own rows of tmp, h2 and q; h is only read.
            let (a, y, q) = unsafe { (b.tmp.get(&r), b.h2.get(&r), b.q.get(&r)) };
            layer.self_out.apply(at(&ctx, &r, d), a);
            if let Some((w, s)) = &conv {
                temporal_add_rows(h, w, real, s, r.clone(), a);
            }
            residual_layer_norm(at(h, &r, d), a, &layer.ln[0].0, &layer.ln[0].1, y);
            layer.cross_q.apply(y, q);
        });
        let cross = &e.cross[i];
        let ctx = self.attend(self.memory(cross), cross.lk, &self.masks.cross[i]);
        // Its output and h = LN2(h2 + c), then the words' queries.
        let h2 = self.all(b.h2);
        self.region(|r| {
            // SAFETY: each task writes its own rows of tmp, h and q; h2 is only read.
            let (a, y, q) = unsafe { (b.tmp.get(&r), b.h.get(&r), b.q.get(&r)) };
            layer.cross_out.apply(at(&ctx, &r, d), a);
            residual_layer_norm(at(h2, &r, d), a, &layer.ln[1].0, &layer.ln[1].1, y);
            if let Some([wq, _]) = &layer.words {
                wq.apply(y, q);
            }
        });
        let words = layer.words.as_ref().and(e.words.get(i));
        let words = words.map(|m| self.attend(self.memory(m), m.lk, &self.masks.words[i]));
        self.feed_forward(i, words);
    }

    /// The words' attention output added to h (a plain residual), then the feed-forward block:
    /// h = LN3(h + W2 gelu(W1 h)), written to h2, which becomes h; then on the same rows the
    /// next layer's projections, or after the last layer the output.
    fn feed_forward(&mut self, i: usize, words: Option<Vec<f32>>) {
        let (n, d) = (self.x.enc.n, self.x.enc.d);
        let layer = &self.x.layers[i];
        let next = self.x.layers.get(i + 1);
        let (b, out) = (self.bufs, self.x.out);
        self.region(|r| {
            // SAFETY: each task reads and writes only its own rows of every buffer.
            let (h, a, ff, y) = unsafe { (b.h.get(&r), b.tmp.get(&r), b.ff.get(&r), b.h2.get(&r)) };
            if let (Some([_, wo]), Some(ctx)) = (&layer.words, &words) {
                wo.apply(at(ctx, &r, d), a);
                h.iter_mut().zip(a.iter()).for_each(|(h, a)| *h += a);
            }
            layer.ff1.apply(h, ff);
            gelu(ff);
            layer.ff2.apply(ff, a);
            residual_layer_norm(h, a, &layer.ln[2].0, &layer.ln[2].1, y);
            match next {
                Some(next) => next.project(y, &r, [b.q, b.k, b.v]),
                // SAFETY: each task writes the output rows of its own frames.
                None => unsafe { output(out, y, &r, n, b.out) },
            }
        });
        std::mem::swap(&mut self.bufs.h, &mut self.bufs.h2);
    }
}

/// The output rows [B * N, D] of the token rows `r` of h (`h` holding those rows): their frame
/// rows . W_out + b, in runs within one sample each (two tokens per sample are not frames).
///
/// # Safety
/// No other task may write the output rows of these frames meanwhile.
unsafe fn output(lin: &HostLinear, h: &[f32], r: &Range<usize>, n: usize, out: RowsMut) {
    let (l, d) = (n + 2, h.len() / r.len());
    let mut row = r.start;
    while row < r.end {
        let (s, i) = (row / l, row % l);
        let end = r.end.min((s + 1) * l);
        if i < 2 {
            row = (s * l + 2).min(end);
            continue;
        }
        let frames = s * n + i - 2..s * n + end - s * l - 2;
        lin.apply(at(h, &(row - r.start..end - r.start), d), out.get(&frames));
        row = end;
    }
}
