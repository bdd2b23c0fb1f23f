//! Contrastive training of the evaluator on a dataset's training split, and its R-precision on
//! real motions of another split.

use std::path::PathBuf;

use burn::prelude::*;
use diffkfc_data::dataset::batch::{Batch, KeyframeConfig, Loader};
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_model::network::params;
use diffkfc_model::run::checkpoint::Checkpoint;
use diffkfc_model::text::cache::EmbeddingCache;
use diffkfc_model::training::optim::{Optimiser, StateLocation};

use crate::error::{EvalError, Result};
use crate::evaluator::{
    eval_length, info_nce, motion_tensor, text_tensor, ContrastiveEvaluator, Evaluator,
    EvaluatorConfig, TextMotionEvaluator,
};
use crate::text_motion::{finite, r_precision};

pub struct EvaluatorTraining<'a> {
    pub cfg: EvaluatorConfig,
    pub ds: &'a Dataset,
    pub train: &'a PackedSplit,
    pub test: &'a PackedSplit,
    pub text: &'a EmbeddingCache,
    pub device: Device,
    pub out: PathBuf,
    pub batch_size: usize,
    pub steps: usize,
    pub lr: f64,
    pub seed: u64,
}

fn same_caption(b: &Batch) -> Vec<bool> {
    let n = b.captions.len();
    (0..n * n).map(|k| b.captions[k / n] == b.captions[k % n]).collect()
}

/// Embeddings of every item of a split with its first caption, whole clip (first 196 frames,
/// length rounded down to a multiple of 4), in item order: (text rows, motion rows).
/// Embeddings, one vector per item.
pub type Embeddings = Vec<Vec<f64>>;

pub fn embed_split(
    ev: &dyn TextMotionEvaluator,
    ds: &Dataset,
    split: &PackedSplit,
) -> Result<(Embeddings, Embeddings)> {
    let d = ds.dim();
    let motions: Vec<&[f32]> = (0..split.items.len())
        .map(|i| &split.item_frames(i)[..eval_length(split.items[i].len) * d])
        .collect();
    let captions: Vec<&str> = split.items.iter().map(|it| it.captions[0].as_str()).collect();
    Ok((
        finite(ev.embed_texts(&captions)?, "the text embeddings")?,
        finite(ev.embed_motions(&motions), "the motion embeddings")?,
    ))
}

pub struct EvaluatorReport {
    pub steps: usize,
    pub first_loss: f64,
    pub last_loss: f64,
    pub r_precision: [f64; 3],
    pub mm_dist: f64,
    pub items: usize,
}

impl EvaluatorTraining<'_> {
    pub fn run(&self, mut on_step: impl FnMut(usize, f64)) -> Result<EvaluatorReport> {
        std::fs::create_dir_all(&self.out)
            .map_err(|err| EvalError::Io { path: self.out.clone(), err })?;
        let device = self.device.clone().autodiff();
        device.seed(self.seed);
        let mut model = self.cfg.init(&device);
        let shapes = params::shapes(&model);
        let mut optim = Optimiser::new(&model, StateLocation::for_device(&device), false);
        let kf = KeyframeConfig { rate: 0.0, drop_prob: 0.0, ..Default::default() };
        let loader = Loader::new(self.ds, self.train, self.batch_size, self.seed, kf);
        let per_epoch = loader.batches_per_epoch().max(1);
        let (mut first, mut last) = (f64::NAN, f64::NAN);
        for step in 0..self.steps {
            let b = loader.batch((step / per_epoch) as u64, step % per_epoch);
            let m = model.encode_motion(
                motion_tensor(&b.x0, b.batch_size, b.frames, b.dim, &device),
                &b.lengths,
            );
            let captions: Vec<&str> = b.captions.iter().map(String::as_str).collect();
            let t = model.encode_text(text_tensor(self.text, &captions, &device)?);
            let loss = info_nce(m, t, self.cfg.temperature, &same_caption(&b));
            let l: f64 =
                loss.clone().into_data().convert::<f64>().try_to_vec::<f64>().expect("scalar")[0];
            if !l.is_finite() {
                return Err(EvalError::NonFinite(format!("{}: step {}: InfoNCE loss is {l} (not finite): training stopped, nothing saved; lower --lr ({})", self.out.display(), step + 1, self.lr)));
            }
            model = optim.descend(model, loss, 1.0, self.lr).0;
            if step == 0 {
                first = l;
            }
            last = l;
            on_step(step + 1, l);
        }
        let vals = self.save(&optim, &model, shapes)?;
        let ev = ContrastiveEvaluator {
            model: params::load(self.cfg.init(&self.device), &vals),
            mean: self.ds.mean.clone(),
            std: self.ds.std.clone(),
            text: self.text,
            device: self.device.clone(),
        };
        let (t, m) = embed_split(&ev, self.ds, self.test)?;
        let (r, mm) = r_precision(&t, &m, 32);
        Ok(EvaluatorReport {
            steps: self.steps,
            first_loss: first,
            last_loss: last,
            r_precision: r,
            mm_dist: mm,
            items: t.len(),
        })
    }

    /// The trained weights as a checkpoint in --out (with the set's normalisation beside it);
    /// returns them. Refused if a weight is not finite.
    fn save(
        &self,
        optim: &Optimiser,
        model: &Evaluator,
        shapes: Vec<Vec<usize>>,
    ) -> Result<Vec<Vec<f32>>> {
        let snap = optim.snapshot(model);
        if let Some(x) = snap.model.iter().flatten().find(|x| !x.is_finite()) {
            return Err(EvalError::NonFinite(format!(
                "{}: after {} steps a weight is {x} (not finite): nothing saved; lower --lr ({})",
                self.out.display(),
                self.steps,
                self.lr
            )));
        }
        let vals = snap.model.clone();
        let ck = Checkpoint {
            step: self.steps,
            shapes,
            model: snap.model,
            ema: None,
            adam_step: snap.step,
            adam_m: snap.m,
            adam_v: snap.v,
            config: serde_json::to_string(&self.cfg).expect("config serialises"),
            seed: self.seed,
            names: params::names(model),
        };
        ck.save(&self.out)?;
        Checkpoint::prune(&self.out, 1);
        let dims = [self.ds.dim()];
        diffkfc_data::io::npy::write(self.out.join("Mean.npy"), &dims, &self.ds.mean)?;
        diffkfc_data::io::npy::write(self.out.join("Std.npy"), &dims, &self.ds.std)?;
        Ok(vals)
    }
}
