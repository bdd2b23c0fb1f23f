//! Training batches: random item order per epoch, MDM crops, z-normalisation, zero padding,
//! and keyframe masks. Every random choice comes from a generator derived from
//! (seed, epoch, position), so a batch is the same whatever the number of loader threads.

use serde::{Deserialize, Serialize};

use crate::dataset::cache::PackedSplit;
use crate::dataset::{crop, Dataset, MAX_FRAMES};
use crate::keyframes::{self, Strategy};
use crate::motion::root_key::{self, ROOT_CHANNELS};
use crate::motion::root_track::{self, TrackSchedule};
use crate::rng::Rng;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KeyframeConfig {
    pub strategy: Strategy,
    /// Fraction of a clip's frames that are keyframes (at least one when > 0).
    pub rate: f64,
    /// Probability of dropping all keyframes of a sample (classifier-free guidance).
    pub drop_prob: f64,
    /// Probability that a training keyframe does not observe its root place, and, drawn
    /// independently, its heading (so pose-only keyframes stay learned).
    pub root_drop_prob: f64,
    /// Probability that a sample (whose keyframes are not dropped) also observes its dense root
    /// track (`root_track`); 0 keeps the sparse schedule and its random draws unchanged.
    pub dense_root_prob: f64,
    /// Smallest fraction of frames a dense root track observes (`root_track::TrackSchedule`).
    pub dense_root_min_density: f64,
    /// Probability that a sample's keys (when not dropped) observe one body part only, the
    /// lower body (with the root) or the upper body at even odds, as `sample --joints` asks:
    /// the network learns to read the legs and the root's velocity apart from the arms. 0 keeps
    /// every key whole and the random draws of earlier runs unchanged.
    pub part_prob: f64,
    /// Feature elements further than this many standard deviations from the mean stay
    /// unobserved by keys and root tracks. Over a full turn HumanML3D's smoothed heading flips
    /// within one frame (up to 185 std on the root's angular velocity); a key on that frame asks
    /// the network to copy a value it cannot reach, and the keyframe loss of the batch jumps
    /// from ~0.01 to ~5. `None` observes every element (the batches of earlier runs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_observed_sigma: Option<f64>,
}

impl KeyframeConfig {
    pub fn track_schedule(&self) -> TrackSchedule {
        TrackSchedule { prob: self.dense_root_prob, min_density: self.dense_root_min_density }
    }
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        KeyframeConfig {
            strategy: Strategy::Random,
            rate: 0.05,
            drop_prob: 0.1,
            root_drop_prob: 0.5,
            dense_root_prob: 0.0,
            dense_root_min_density: 0.25,
            part_prob: 0.0,
            max_observed_sigma: None,
        }
    }
}

/// Clears `mask` where the normalised feature `x0` lies further than `limit` from 0 (both
/// [frames, D], `x0` possibly shorter than `mask`: padding is never observed).
pub fn unobserve_outliers(mask: &mut [f32], x0: &[f32], limit: f32) {
    for (m, &x) in mask.iter_mut().zip(x0) {
        if x.abs() > limit {
            *m = 0.0;
        }
    }
}

/// A batch in flat row-major buffers, ready to become tensors.
#[derive(Clone, Debug, PartialEq)]
pub struct Batch {
    pub batch_size: usize,
    pub frames: usize,
    pub dim: usize,
    /// [B, N, D] normalised features, zero on padding.
    pub x0: Vec<f32>,
    /// [B, N]: 1 for real frames, 0 for padding.
    pub valid: Vec<f32>,
    /// [B, N, D]: 1 where a keyframe observes the feature.
    pub kf_mask: Vec<f32>,
    /// [B, N, ROOT_CHANNELS] root place and heading of every real frame in the crop's frame
    /// (its first frame at the origin facing +Z; `root_key::RootKey::channels`).
    pub root: Vec<f32>,
    /// [B, N, ROOT_CHANNELS]: 1 where a keyframe observes the channel.
    pub root_mask: Vec<f32>,
    pub lengths: Vec<usize>,
    pub captions: Vec<String>,
    /// Samples whose text is dropped (`Loader::text_drop_prob`): they see no caption.
    pub text_dropped: Vec<bool>,
    /// Item indices in the split.
    pub items: Vec<usize>,
}

impl Batch {
    /// The samples `range` of this batch, as their own batch (same frame count): one device's
    /// share in data-parallel training.
    pub fn shard(&self, range: std::ops::Range<usize>) -> Batch {
        let (n, d, r) = (self.frames, self.dim, ROOT_CHANNELS);
        let rows = |v: &[f32], w: usize| v[range.start * w..range.end * w].to_vec();
        Batch {
            batch_size: range.len(),
            frames: n,
            dim: d,
            x0: rows(&self.x0, n * d),
            valid: rows(&self.valid, n),
            kf_mask: rows(&self.kf_mask, n * d),
            root: rows(&self.root, n * r),
            root_mask: rows(&self.root_mask, n * r),
            lengths: self.lengths[range.clone()].to_vec(),
            captions: self.captions[range.clone()].to_vec(),
            text_dropped: self.text_dropped[range.clone()].to_vec(),
            items: self.items[range].to_vec(),
        }
    }
}

/// One drawn sample.
struct Sample {
    x0: Vec<f32>,
    len: usize,
    kf: Vec<usize>,
    /// Frames observing the dense root track.
    track: Vec<usize>,
    /// [len, ROOT_CHANNELS] channels and mask.
    root: Vec<f32>,
    root_mask: Vec<f32>,
    caption: String,
    text_dropped: bool,
    /// The joints its keys observe (`KeyframeConfig::part_prob`); None: whole keys.
    part: Option<&'static [usize]>,
}

pub struct Loader<'a> {
    pub ds: &'a Dataset,
    pub split: &'a PackedSplit,
    pub batch_size: usize,
    pub seed: u64,
    pub keyframes: KeyframeConfig,
    pub threads: usize,
    /// Probability that a sample's text is dropped (text classifier-free guidance; 0 = never).
    pub text_drop_prob: f64,
    /// The text drop's probability for a sample whose keys were dropped (`drop_prob`); `None`
    /// = `text_drop_prob`. Raising it trains the key-free, text-free branch that text-only
    /// guidance subtracts without taking keys or text from the keyed samples.
    pub text_drop_prob_unkeyed: Option<f64>,
}

impl<'a> Loader<'a> {
    pub fn new(
        ds: &'a Dataset,
        split: &'a PackedSplit,
        batch_size: usize,
        seed: u64,
        keyframes: KeyframeConfig,
    ) -> Self {
        Loader {
            ds,
            split,
            batch_size,
            seed,
            keyframes,
            threads: 1,
            text_drop_prob: 0.0,
            text_drop_prob_unkeyed: None,
        }
    }

    /// Full batches per epoch (the last partial one is dropped, as MDM does); at least one when
    /// the split has any item (a tiny split repeats items).
    pub fn batches_per_epoch(&self) -> usize {
        (self.split.items.len() / self.batch_size).max(usize::from(!self.split.items.is_empty()))
    }

    /// Item order of an epoch.
    fn order(&self, epoch: u64) -> Vec<usize> {
        let mut v: Vec<usize> = (0..self.split.items.len()).collect();
        Rng::derive(self.seed, u64::MAX, epoch).shuffle(&mut v);
        v
    }

    /// Batch `b` of `epoch`.
    pub fn batch(&self, epoch: u64, b: usize) -> Batch {
        let order = self.order(epoch);
        let picks: Vec<(usize, usize)> = (0..self.batch_size)
            .map(|k| {
                let pos = b * self.batch_size + k;
                (pos, order[pos % order.len()])
            })
            .collect();
        let samples: Vec<Sample> = if self.threads <= 1 {
            picks.iter().map(|&(pos, item)| self.sample(epoch, pos, item)).collect()
        } else {
            let chunk = picks.len().div_ceil(self.threads);
            std::thread::scope(|s| {
                let handles: Vec<_> = picks
                    .chunks(chunk)
                    .map(|c| {
                        s.spawn(move || {
                            c.iter()
                                .map(|&(pos, item)| self.sample(epoch, pos, item))
                                .collect::<Vec<_>>()
                        })
                    })
                    .collect();
                handles.into_iter().flat_map(|h| h.join().expect("loader thread")).collect()
            })
        };
        self.assemble(samples, picks.iter().map(|p| p.1).collect())
    }

    fn sample(&self, epoch: u64, pos: usize, item: usize) -> Sample {
        let mut rng = Rng::derive(self.seed, epoch, pos as u64);
        let spec = &self.split.items[item];
        let caption = rng.pick(&spec.captions).clone();
        let (start, len) = crop(spec.len, &mut rng);
        let dim = self.ds.dim();
        let mut x0 = self.split.clip_frames(&spec.clip, spec.start + start, len).to_vec();
        let root = root_key::root_channels(&x0, dim);
        self.ds.normalise(&mut x0);
        let kc = &self.keyframes;
        let dropped = rng.chance(kc.drop_prob);
        let kf = if dropped {
            vec![]
        } else {
            keyframes::select(kc.strategy, len, kc.rate, &x0, dim, &mut rng)
        };
        let mut root_mask = vec![0f32; len * ROOT_CHANNELS];
        for &f in &kf {
            for pair in [0..2, 2..4] {
                if !rng.chance(kc.root_drop_prob) {
                    root_mask[f * ROOT_CHANNELS..][pair].iter_mut().for_each(|m| *m = 1.0);
                }
            }
        }
        // Drawn last, so that the sparse keys of a seed stay those of the sparse schedule.
        let track = if dropped { vec![] } else { kc.track_schedule().draw(len, &mut rng) };
        for &f in &track {
            root_mask[f * ROOT_CHANNELS..(f + 1) * ROOT_CHANNELS].iter_mut().for_each(|m| *m = 1.0);
        }
        // Drawn after everything else and only when enabled, so that runs without text drop
        // keep their batches.
        let unkeyed = self.text_drop_prob_unkeyed.filter(|_| dropped);
        let enabled =
            self.text_drop_prob > 0.0 || self.text_drop_prob_unkeyed.is_some_and(|q| q > 0.0);
        let text_dropped = enabled && rng.chance(unkeyed.unwrap_or(self.text_drop_prob));
        // Drawn after the text drop, and only when enabled, for the same reason.
        let part = (kc.part_prob > 0.0 && !kf.is_empty() && rng.chance(kc.part_prob)).then(|| {
            let half = if rng.chance(0.5) { "lower_body" } else { "upper_body" };
            let part = self.ds.skeleton.part(half);
            part.expect("HumanML3D and KIT-ML skeletons name both body halves").joints
        });
        Sample { x0, len, kf, track, root, root_mask, caption, text_dropped, part }
    }

    fn assemble(&self, samples: Vec<Sample>, items: Vec<usize>) -> Batch {
        let (n, d) = (MAX_FRAMES, self.ds.dim());
        let bsz = samples.len();
        let mut x0 = vec![0f32; bsz * n * d];
        let mut valid = vec![0f32; bsz * n];
        let mut kf_mask = vec![0f32; bsz * n * d];
        let r = ROOT_CHANNELS;
        let (mut root, mut root_mask) = (vec![0f32; bsz * n * r], vec![0f32; bsz * n * r]);
        let all_dims = vec![true; d];
        let mut lengths = Vec::with_capacity(bsz);
        let mut captions = Vec::with_capacity(bsz);
        let mut text_dropped = Vec::with_capacity(bsz);
        for (i, s) in samples.into_iter().enumerate() {
            x0[i * n * d..i * n * d + s.len * d].copy_from_slice(&s.x0);
            valid[i * n..i * n + s.len].iter_mut().for_each(|v| *v = 1.0);
            let mask = &mut kf_mask[i * n * d..(i + 1) * n * d];
            let dims = s.part.map(|joints| keyframes::dim_mask(self.ds.skeleton, Some(joints)));
            mask.copy_from_slice(&keyframes::frame_mask(
                n,
                &s.kf,
                dims.as_deref().unwrap_or(&all_dims),
            ));
            for &f in &s.track {
                mask[f * d..][root_track::TRACK_DIMS].iter_mut().for_each(|m| *m = 1.0);
            }
            if let Some(limit) = self.keyframes.max_observed_sigma {
                unobserve_outliers(mask, &s.x0, limit as f32);
            }
            root[i * n * r..i * n * r + s.len * r].copy_from_slice(&s.root);
            root_mask[i * n * r..i * n * r + s.len * r].copy_from_slice(&s.root_mask);
            lengths.push(s.len);
            captions.push(s.caption);
            text_dropped.push(s.text_dropped);
        }
        Batch {
            batch_size: bsz,
            frames: n,
            dim: d,
            x0,
            valid,
            kf_mask,
            root,
            root_mask,
            lengths,
            captions,
            text_dropped,
            items,
        }
    }
}
