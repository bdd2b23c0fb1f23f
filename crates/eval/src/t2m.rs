//! The official text-motion evaluator of Guo et al. (2022), as MDM and the DiffKFC paper use it
//! for FID, R-precision, MultiModal distance and Diversity, read from a user's converted copy of
//! its weights (`scripts/convert-t2m-evaluator.py`: `finest.tar` and the GloVe vocabulary ->
//! `evaluator.safetensors`, `glove.npy`, `glove_words.txt`, with the evaluator's `mean.npy` and
//! `std.npy`). Every size is read from the weights' shapes.
//!
//! Motion: normalised with the evaluator's own mean/std, foot contacts dropped, zero-padded to
//! [`MAX_MOTION_LENGTH`] frames as the official loaders pad real motions
//! (`Text2MotionDatasetV2`) and generated ones (the comparison loader of `comp_v6_model_dataset`)
//! before the movement encoder (generated motions are padded with zeros too, not with frames
//! generated past their length as MDM's evaluation does); the movement encoder (two Conv1d k4 s2 p1 + LeakyReLU 0.2, Linear) gives one code per 4
//! frames; a bidirectional GRU over the first `len / 4` codes, from a learned initial state,
//! ends in an MLP (Linear, LayerNorm, LeakyReLU, Linear). Text: each `word/POS` token becomes
//! its GloVe vector plus a projected 15-way POS one-hot (a word list overrides the POS of
//! location, body, object, action and manner words; unknown words are `unk/OTHER`), between
//! `sos/OTHER` and `eos/OTHER` (at most 20 tokens kept), then the same GRU and MLP shape.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::tensor::activation::{leaky_relu, sigmoid};
use diffkfc_data::dataset::Dataset;
use diffkfc_data::io::texts::Caption;

use crate::error::{EvalError, Result};
use crate::evaluator::TextMotionEvaluator;

/// Frames every motion is zero-padded to (the official loaders' `max_motion_length`).
pub const MAX_MOTION_LENGTH: usize = 196;

/// The 15 POS slots of the one-hot, in order.
pub const POS: [&str; 15] = [
    "VERB", "NOUN", "DET", "ADP", "NUM", "AUX", "PRON", "ADJ", "ADV", "Loc_VIP", "Body_VIP",
    "Obj_VIP", "Act_VIP", "Desc_VIP", "OTHER",
];

/// Words whose POS slot is their group's, whatever the tagger said.
const VIP: [(&str, &[&str]); 5] = [
    (
        "Loc_VIP",
        &[
            "left",
            "right",
            "clockwise",
            "counterclockwise",
            "anticlockwise",
            "forward",
            "back",
            "backward",
            "up",
            "down",
            "straight",
            "curve",
        ],
    ),
    (
        "Body_VIP",
        &[
            "arm", "chin", "foot", "feet", "face", "hand", "mouth", "leg", "waist", "eye", "knee",
            "shoulder", "thigh",
        ],
    ),
    (
        "Obj_VIP",
        &[
            "stair",
            "dumbbell",
            "chair",
            "window",
            "floor",
            "car",
            "ball",
            "handrail",
            "baseball",
            "basketball",
        ],
    ),
    (
        "Act_VIP",
        &[
            "walk", "run", "swing", "pick", "bring", "kick", "put", "squat", "throw", "hop",
            "dance", "jump", "turn", "stumble", "stop", "sit", "lift", "lower", "raise", "wash",
            "stand", "kneel", "stroll", "rub", "bend", "balance", "flap", "jog", "shuffle", "lean",
            "rotate", "spin", "spread", "climb",
        ],
    ),
    (
        "Desc_VIP",
        &[
            "slowly",
            "carefully",
            "fast",
            "careful",
            "slow",
            "quickly",
            "happy",
            "angry",
            "sad",
            "happily",
            "angrily",
            "sadly",
        ],
    ),
];

/// Caption tokens kept between `sos` and `eos`.
pub const MAX_TOKENS: usize = 20;

/// The files of a converted evaluator directory.
pub const FILES: [&str; 5] =
    ["evaluator.safetensors", "glove.npy", "glove_words.txt", "mean.npy", "std.npy"];

/// The POS slot of a token: a VIP word's group, else its tag (unknown tags are OTHER).
pub fn pos_slot(word: &str, tag: &str) -> usize {
    let slot = |name: &str| POS.iter().position(|p| *p == name).expect("a POS slot");
    match VIP.iter().find(|(_, words)| words.contains(&word)) {
        Some((group, _)) => slot(group),
        None => POS.iter().position(|p| *p == tag).unwrap_or(slot("OTHER")),
    }
}

/// The token sequence the text encoder reads: `sos`, at most 20 caption tokens, `eos`.
pub fn sequence(tokens: &[(String, String)]) -> Vec<(String, String)> {
    let mark = |w: &str| (w.to_string(), "OTHER".to_string());
    let mut s = vec![mark("sos")];
    s.extend(tokens.iter().take(MAX_TOKENS).cloned());
    s.push(mark("eos"));
    s
}

/// A Linear layer: weight transposed once to [in, out].
struct Dense {
    w: Tensor<2>,
    b: Tensor<1>,
}

impl Dense {
    /// [N, in] -> [N, out]
    fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        x.matmul(self.w.clone()) + self.b.clone().unsqueeze()
    }

    /// [B, T, in] -> [B, T, out]
    fn forward3(&self, x: Tensor<3>) -> Tensor<3> {
        let [b, t, i] = x.dims();
        let o = self.w.dims()[1];
        self.forward(x.reshape([b * t, i])).reshape([b, t, o])
    }
}

/// One direction of a GRU (PyTorch's gate order r, z, n).
struct GruDir {
    ih: Dense,
    hh: Dense,
}

/// Bidirectional GRU with a learned initial state, then Linear, LayerNorm, LeakyReLU, Linear.
struct BiGruHead {
    input: Dense,
    fwd: GruDir,
    bwd: GruDir,
    /// [2, H]: the initial state of each direction.
    h0: Tensor<2>,
    out1: Dense,
    ln_g: Tensor<1>,
    ln_b: Tensor<1>,
    out2: Dense,
}

impl BiGruHead {
    /// Final state of one direction over `x` [B, T, 3H] (input projections), each sequence
    /// `lens[b]` long: steps past a sequence's end leave its state alone.
    fn run(
        &self,
        dir: &GruDir,
        gi: &Tensor<3>,
        h0: Tensor<2>,
        lens: &[usize],
        rev: bool,
    ) -> Tensor<2> {
        let [b, t, h3] = gi.dims();
        let h = h3 / 3;
        let device = gi.device();
        let mut state = h0.expand([b, h]);
        for s in 0..t {
            let step = if rev { t - 1 - s } else { s };
            let keep: Vec<f32> = lens.iter().map(|&l| if step < l { 1.0 } else { 0.0 }).collect();
            let keep = Tensor::<1>::from_floats(keep.as_slice(), &device).reshape([b, 1]);
            let x = gi.clone().slice([0..b, step..step + 1, 0..h3]).reshape([b, h3]);
            let g = dir.hh.forward(state.clone());
            let part = |t: &Tensor<2>, k: usize| t.clone().slice([0..b, k * h..(k + 1) * h]);
            let r = sigmoid(part(&x, 0) + part(&g, 0));
            let z = sigmoid(part(&x, 1) + part(&g, 1));
            let n = (part(&x, 2) + r * part(&g, 2)).tanh();
            let new = (z.ones_like() - z.clone()) * n + z * state.clone();
            state = keep.clone() * new + (keep.ones_like() - keep) * state;
        }
        state
    }

    /// [B, T, in] with lengths -> [B, out]
    fn forward(&self, x: Tensor<3>, lens: &[usize]) -> Tensor<2> {
        let e = self.input.forward3(x);
        let hdim = self.h0.dims()[1];
        let h0f = self.h0.clone().slice([0..1, 0..hdim]);
        let h0b = self.h0.clone().slice([1..2, 0..hdim]);
        let f = self.run(&self.fwd, &self.fwd.ih.forward3(e.clone()), h0f, lens, false);
        let b = self.run(&self.bwd, &self.bwd.ih.forward3(e), h0b, lens, true);
        let y = self.out1.forward(Tensor::cat(vec![f, b], 1));
        // LayerNorm (PyTorch's eps 1e-5, biased variance).
        let mean = y.clone().mean_dim(1);
        let c = y - mean;
        let var = c.clone().powf_scalar(2.0).mean_dim(1);
        let y =
            c / (var + 1e-5).sqrt() * self.ln_g.clone().unsqueeze() + self.ln_b.clone().unsqueeze();
        self.out2.forward(leaky_relu(y, 0.2))
    }
}

/// The converted T2M evaluator with its vocabulary, normalisation and the captions' tokens.
pub struct T2mEvaluator {
    conv1: (Tensor<2>, Tensor<1>),
    conv2: (Tensor<2>, Tensor<1>),
    movement_out: Dense,
    motion: BiGruHead,
    text: BiGruHead,
    pos_emb: Dense,
    glove: HashMap<String, Vec<f32>>,
    word_dim: usize,
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
    /// Caption text -> its `word/POS` tokens (from the dataset's text files).
    tokens: HashMap<String, Vec<(String, String)>>,
    device: Device,
    pub dir: PathBuf,
}

/// Tensors of a safetensors file by name, as f32.
struct EvaluatorWeights {
    path: PathBuf,
    map: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

impl EvaluatorWeights {
    fn read(path: &Path) -> Result<EvaluatorWeights> {
        let bytes = std::fs::read(path).map_err(|err| EvalError::Io { path: path.into(), err })?;
        let st = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| EvalError::file(path, format!("not a safetensors file ({e})")))?;
        let mut map = HashMap::new();
        for (name, t) in st.tensors() {
            let v: Vec<f32> = match t.dtype() {
                safetensors::Dtype::F32 => t
                    .data()
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
                other => {
                    return Err(EvalError::file(
                        path,
                        format!("tensor {name} is {other:?}, expected F32"),
                    ))
                }
            };
            map.insert(name, (t.shape().to_vec(), v));
        }
        Ok(EvaluatorWeights { path: path.into(), map })
    }

    fn get(&self, name: &str, rank: usize) -> Result<(Vec<usize>, Vec<f32>)> {
        let (shape, v) = self
            .map
            .get(name)
            .ok_or_else(|| EvalError::file(&self.path, format!("tensor {name} missing")))?;
        if shape.len() != rank {
            return Err(EvalError::file(
                &self.path,
                format!("tensor {name} has shape {shape:?}, expected {rank} dimensions"),
            ));
        }
        Ok((shape.clone(), v.clone()))
    }

    fn vector(&self, name: &str, device: &Device) -> Result<Tensor<1>> {
        Ok(Tensor::<1>::from_floats(self.get(name, 1)?.1.as_slice(), device))
    }

    /// PyTorch's Linear `prefix` ([out, in] weight) as [in, out].
    fn dense(&self, prefix: &str, device: &Device) -> Result<Dense> {
        let (s, w) = self.get(&format!("{prefix}.weight"), 2)?;
        let w = Tensor::<1>::from_floats(w.as_slice(), device).reshape([s[0], s[1]]).transpose();
        let b = self.vector(&format!("{prefix}.bias"), device)?;
        Ok(Dense { w, b })
    }

    /// A GRU direction (`suffix` "" or "_reverse") of `prefix`.
    fn gru(&self, prefix: &str, suffix: &str, device: &Device) -> Result<GruDir> {
        let part = |kind: &str| -> Result<Dense> {
            let (s, w) = self.get(&format!("{prefix}.weight_{kind}_l0{suffix}"), 2)?;
            let w =
                Tensor::<1>::from_floats(w.as_slice(), device).reshape([s[0], s[1]]).transpose();
            Ok(Dense { w, b: self.vector(&format!("{prefix}.bias_{kind}_l0{suffix}"), device)? })
        };
        Ok(GruDir { ih: part("ih")?, hh: part("hh")? })
    }

    fn head(&self, m: &str, device: &Device) -> Result<BiGruHead> {
        let (s, h0) = self.get(&format!("{m}.hidden"), 3)?;
        Ok(BiGruHead {
            input: self.dense(&format!("{m}.input_emb"), device)?,
            fwd: self.gru(&format!("{m}.gru"), "", device)?,
            bwd: self.gru(&format!("{m}.gru"), "_reverse", device)?,
            h0: Tensor::<1>::from_floats(h0.as_slice(), device).reshape([s[0], s[2]]),
            out1: self.dense(&format!("{m}.output_net.0"), device)?,
            ln_g: self.vector(&format!("{m}.output_net.1.weight"), device)?,
            ln_b: self.vector(&format!("{m}.output_net.1.bias"), device)?,
            out2: self.dense(&format!("{m}.output_net.3"), device)?,
        })
    }

    /// Conv1d `prefix` (weight [out, in, 4]) as an im2col product: [4 * in, out] and bias.
    fn conv(&self, prefix: &str, device: &Device) -> Result<(Tensor<2>, Tensor<1>)> {
        let (s, w) = self.get(&format!("{prefix}.weight"), 3)?;
        if s[2] != 4 {
            return Err(EvalError::file(
                &self.path,
                format!("{prefix}.weight: kernel {} (expected 4)", s[2]),
            ));
        }
        let w = Tensor::<1>::from_floats(w.as_slice(), device)
            .reshape([s[0], s[1], 4])
            .permute([2, 1, 0])
            .reshape([4 * s[1], s[0]]);
        Ok((w, self.vector(&format!("{prefix}.bias"), device)?))
    }
}

/// The GloVe vectors of the evaluator's vocabulary (glove.npy, glove_words.txt) by word, and
/// their width; the vocabulary must hold 'unk', 'sos' and 'eos'.
fn read_glove(dir: &Path) -> Result<(HashMap<String, Vec<f32>>, usize)> {
    let glove_path = dir.join("glove.npy");
    let vectors = diffkfc_data::io::npy::read_f32(&glove_path)?;
    let words_path = dir.join("glove_words.txt");
    let words = std::fs::read_to_string(&words_path)
        .map_err(|err| EvalError::Io { path: words_path.clone(), err })?;
    let words: Vec<&str> = words.lines().collect();
    if vectors.shape.len() != 2 || vectors.shape[0] != words.len() {
        return Err(EvalError::file(
            &glove_path,
            format!(
                "shape {:?} does not match the {} words of glove_words.txt",
                vectors.shape,
                words.len()
            ),
        ));
    }
    let word_dim = vectors.shape[1];
    let glove: HashMap<String, Vec<f32>> = words
        .iter()
        .enumerate()
        .map(|(i, w)| (w.to_string(), vectors.data[i * word_dim..(i + 1) * word_dim].to_vec()))
        .collect();
    for needed in ["unk", "sos", "eos"] {
        if !glove.contains_key(needed) {
            return Err(EvalError::file(&words_path, format!("the vocabulary has no '{needed}'")));
        }
    }
    Ok((glove, word_dim))
}

impl T2mEvaluator {
    /// Load a converted evaluator directory; `captions` give the tokens of every caption the
    /// evaluation will embed (the dataset's text files).
    pub fn load(dir: &Path, captions: &[Caption], device: &Device) -> Result<T2mEvaluator> {
        for f in FILES {
            if !dir.join(f).is_file() {
                return Err(EvalError::file(
                    dir,
                    format!("missing {f}: convert MDM's T2M evaluator with scripts/convert-t2m-evaluator.py (README, section Evaluation)"),
                ));
            }
        }
        let w = EvaluatorWeights::read(&dir.join("evaluator.safetensors"))?;
        let (glove, word_dim) = read_glove(dir)?;
        let read = |n: &str| diffkfc_data::io::npy::read_f32(dir.join(n)).map(|a| a.data);
        let (mean, std) = (read("mean.npy")?, read("std.npy")?);
        let conv1 = w.conv("movement_encoder.main.0", device)?;
        let conv2 = w.conv("movement_encoder.main.3", device)?;
        if mean.len() != std.len() || conv1.0.dims()[0] != 4 * (mean.len() - 4) {
            return Err(EvalError::file(dir, format!("mean.npy/std.npy have {}/{} values; the movement encoder reads {} features (+4 foot contacts)", mean.len(), std.len(), conv1.0.dims()[0] / 4)));
        }
        let tokens = captions.iter().map(|c| (c.text.clone(), c.tokens.clone())).collect();
        Ok(T2mEvaluator {
            conv1,
            conv2,
            movement_out: w.dense("movement_encoder.out_net", device)?,
            motion: w.head("motion_encoder", device)?,
            text: w.head("text_encoder", device)?,
            pos_emb: w.dense("text_encoder.pos_emb", device)?,
            glove,
            word_dim,
            mean,
            std,
            tokens,
            device: device.clone(),
            dir: dir.to_path_buf(),
        })
    }

    /// Conv1d (kernel 4, stride 2, padding 1) then LeakyReLU: [B, T, C] (T even) -> [B, T/2, O].
    fn conv(&self, x: Tensor<3>, (w, b): &(Tensor<2>, Tensor<1>)) -> Tensor<3> {
        let [bs, t, c] = x.dims();
        let zero = Tensor::<3>::zeros([bs, 1, c], &self.device);
        // Pairs of padded frames: window t' = frames 2t'..2t'+3 = pair t' and pair t' + 1.
        let pairs = Tensor::cat(vec![zero.clone(), x, zero], 1).reshape([bs, t / 2 + 1, 2 * c]);
        let cols = Tensor::cat(
            vec![
                pairs.clone().slice([0..bs, 0..t / 2, 0..2 * c]),
                pairs.slice([0..bs, 1..t / 2 + 1, 0..2 * c]),
            ],
            2,
        );
        let o = w.dims()[1];
        let y = cols.reshape([bs * (t / 2), 4 * c]).matmul(w.clone()) + b.clone().unsqueeze();
        leaky_relu(y, 0.2).reshape([bs, t / 2, o])
    }

    /// Raw motions [len, D] (len a multiple of 4) -> embeddings.
    fn embed_batch(&self, motions: &[&[f32]]) -> Vec<Vec<f64>> {
        let d = self.mean.len();
        let lens: Vec<usize> = motions.iter().map(|m| m.len() / d).collect();
        // Every motion zero-padded to the loader's 196 frames: the second convolution's last
        // window of a shorter motion then reads codes of zero frames, as the official one does.
        let t = lens.iter().copied().max().unwrap_or(0).max(MAX_MOTION_LENGTH).div_ceil(4) * 4;
        let mut x = vec![0f32; motions.len() * t * (d - 4)];
        for (k, m) in motions.iter().enumerate() {
            for (f, frame) in m.chunks_exact(d).enumerate() {
                let dst = &mut x[(k * t + f) * (d - 4)..(k * t + f + 1) * (d - 4)];
                for (j, v) in dst.iter_mut().enumerate() {
                    *v = (frame[j] - self.mean[j]) / self.std[j];
                }
            }
        }
        let x =
            Tensor::<1>::from_floats(x.as_slice(), &self.device).reshape([motions.len(), t, d - 4]);
        let codes = self.movement_out.forward3(self.conv(self.conv(x, &self.conv1), &self.conv2));
        let code_lens: Vec<usize> = lens.iter().map(|l| l / 4).collect();
        rows(self.motion.forward(codes, &code_lens))
    }

    fn embed_captions(&self, captions: &[&str]) -> Result<Vec<Vec<f64>>> {
        let seqs: Vec<Vec<(String, String)>> = captions
            .iter()
            .map(|c| {
                self.tokens.get(*c).map(|t| sequence(t)).ok_or_else(|| {
                    EvalError::CaptionNotEmbedded(format!(
                        "{c} (no word/POS tokens in the dataset's texts)"
                    ))
                })
            })
            .collect::<Result<_>>()?;
        let n = seqs.iter().map(Vec::len).max().unwrap_or(2);
        let (b, wd) = (seqs.len(), self.word_dim);
        let (mut words, mut pos) = (vec![0f32; b * n * wd], vec![0f32; b * n * POS.len()]);
        for (i, s) in seqs.iter().enumerate() {
            for (j, (w, tag)) in s.iter().enumerate() {
                // Unknown words read as `unk` with the OTHER slot, as T2M's vectoriser does.
                let (vec, slot) = match self.glove.get(w) {
                    Some(v) => (v, pos_slot(w, tag)),
                    None => (&self.glove["unk"], POS.len() - 1),
                };
                words[(i * n + j) * wd..(i * n + j + 1) * wd].copy_from_slice(vec);
                pos[(i * n + j) * POS.len() + slot] = 1.0;
            }
        }
        let words = Tensor::<1>::from_floats(words.as_slice(), &self.device).reshape([b, n, wd]);
        let pos = Tensor::<1>::from_floats(pos.as_slice(), &self.device).reshape([b, n, POS.len()]);
        let lens: Vec<usize> = seqs.iter().map(Vec::len).collect();
        Ok(rows(self.text.forward(words + self.pos_emb.forward3(pos), &lens)))
    }
}

/// Every caption (with its tokens) of a split's clips, for [`T2mEvaluator::load`].
pub fn split_captions(ds: &Dataset, split: &str) -> Result<Vec<Caption>> {
    let mut out = Vec::new();
    for id in ds.split_ids(split)? {
        out.extend(diffkfc_data::dataset::read_captions(&ds.text_path(&id))?);
    }
    Ok(out)
}

/// Rows of a [B, E] tensor as f64 vectors.
fn rows(t: Tensor<2>) -> Vec<Vec<f64>> {
    let e = t.dims()[1];
    diffkfc_model::network::params::host(t)
        .chunks(e)
        .map(|r| r.iter().map(|&x| x as f64).collect())
        .collect()
}

impl TextMotionEvaluator for T2mEvaluator {
    fn embed_motions(&self, motions: &[&[f32]]) -> Vec<Vec<f64>> {
        motions.chunks(32).flat_map(|c| self.embed_batch(c)).collect()
    }

    fn embed_texts(&self, captions: &[&str]) -> Result<Vec<Vec<f64>>> {
        let mut out = Vec::with_capacity(captions.len());
        for chunk in captions.chunks(256) {
            out.extend(self.embed_captions(chunk)?);
        }
        Ok(out)
    }

    fn feature_dim(&self) -> usize {
        self.mean.len()
    }

    fn name(&self) -> String {
        format!(
            "the T2M evaluator of Guo et al. 2022 ({}; comparable with published numbers)",
            self.dir.display()
        )
    }
}
