//! Generation from a loaded model: sample a request and finish every motion (`fit`). The
//! default track fit runs two stages, root first and then the body: a sparse keyed place is
//! easily ignored by the denoiser, a dense root track is not (GMD, CondMDI).

use diffkfc_data::dataset::normalise;
use diffkfc_data::motion::representation::recover_root_rot_pos;
use diffkfc_data::motion::root_key::{self, RootKey, ROOT_CHANNELS};
use diffkfc_data::motion::root_track;
use diffkfc_data::Skeleton;

use crate::diffusion::Schedule;
use crate::sampling::fit::{fit_sample, Fit, Fitted, KeyframeFit, TrackReport};
use crate::sampling::interpolation;
use crate::sampling::sampler::{self, Options, Request};
use crate::Denoiser;

/// A model ready to generate: the network, its noise schedule and the dataset's normalisation.
#[derive(Clone, Copy)]
pub struct Generator<'a> {
    pub model: &'a Denoiser,
    pub schedule: &'a Schedule,
    pub mean: &'a [f32],
    pub std: &'a [f32],
    pub skel: &'a Skeleton,
}

/// One motion to generate: its text embedding and length, and what its keyframes observe.
pub struct KeyedItem<'a> {
    /// The text embedding.
    pub text: &'a [f32],
    pub length: usize,
    /// Raw (de-normalised) feature values `[length, D]`, read where `mask` is set.
    pub values: &'a [f32],
    /// `[length, D]`: 1 where a keyframe observes a feature.
    pub mask: &'a [f32],
    /// `[length]` keyed places and headings (the default where a frame has none).
    pub root: &'a [RootKey],
}

impl Generator<'_> {
    /// The request for `items`, padded to `frames` frames: keyframe values normalised with the
    /// model's statistics where observed (zero elsewhere), root keys as the network's channels.
    pub fn request(&self, frames: usize, items: &[KeyedItem]) -> Request {
        let d = self.mean.len();
        let text_dim = items.first().map_or(0, |i| i.text.len());
        let lengths = items.iter().map(|i| i.length).collect();
        let mut req = Request::text_only(frames, d, Vec::new(), text_dim, lengths);
        for (r, it) in items.iter().enumerate() {
            req.text.extend_from_slice(it.text);
            let o = r * frames * d;
            for (e, (&m, &v)) in it.mask.iter().zip(it.values).enumerate() {
                req.mask[o + e] = m;
                if m > 0.0 {
                    req.kf[o + e] = (v - self.mean[e % d]) / self.std[e % d];
                }
            }
            for (f, k) in it.root.iter().enumerate() {
                let (v, m) = k.channels();
                let at = (r * frames + f) * ROOT_CHANNELS;
                req.root[at..at + ROOT_CHANNELS].copy_from_slice(&v);
                req.root_mask[at..at + ROOT_CHANNELS].copy_from_slice(&m);
            }
        }
        req.interpolation = self.interpolation(frames, items);
        req
    }

    /// The keys' interpolation of every item, padded to `frames` (`sampling::interpolation`),
    /// when every item's keys allow one.
    fn interpolation(&self, frames: usize, items: &[KeyedItem]) -> Option<Vec<f32>> {
        let d = self.mean.len();
        let mut out = vec![0.0; items.len() * frames * d];
        for (r, it) in items.iter().enumerate() {
            let a = interpolation::interpolated_keys(
                self.skel, it.values, it.mask, it.root, it.length, self.mean, self.std,
            )?;
            out[r * frames * d..r * frames * d + a.len()].copy_from_slice(&a);
        }
        Some(out)
    }

    /// Sample every motion of `req` and finish it with `fit`; `progress(done, total)` after
    /// every denoising step (of both stages with the track fit).
    pub fn generate(
        &self,
        req: &Request,
        opts: &Options,
        fit: Fit,
        mut progress: impl FnMut(usize, usize),
    ) -> Vec<Fitted> {
        let two_stage = fit.keyframes == KeyframeFit::Track && has_root_keys(req);
        let stages = if two_stage { 2 } else { 1 };
        let x =
            sampler::sample(self.model, self.schedule, req, opts, |k, n| progress(k, stages * n));
        let finish_all = |x: &[f32], fit: Fit| -> Vec<Fitted> {
            (0..req.batch)
                .map(|i| fit_sample(x, req, i, self.mean, self.std, self.skel, fit))
                .collect()
        };
        if !two_stage {
            return finish_all(&x, fit);
        }
        // Stage 1: the keyed sample's root, warped to the keyed places and headings.
        let stage1 = finish_all(
            &x,
            Fit { keyframes: KeyframeFit::Warp, foot_lock: false, rigid: false, ..fit },
        );
        let tracked = self.track_request(req, &stage1);
        // Stage 2: the whole motion again, with that root observed on every frame. The track
        // also overwrites the prediction's root velocities at every step (CondMDI's
        // imputation), so x_t carries it: observed through the condition alone, the fine-tuned
        // reference model kept much of its own speed.
        let opts2 = Options { impose_track: true, ..opts.clone() };
        let x2 = sampler::sample(self.model, self.schedule, &tracked, &opts2, |k, n| {
            progress(n + k, 2 * n)
        });
        let raw = finish_all(
            &x2,
            Fit { keyframes: KeyframeFit::None, foot_lock: false, rigid: false, ..fit },
        );
        let judged = Request { unaided: Some(x), ..req.clone() };
        let mut out: Vec<Fitted> = (0..req.batch)
            .map(|i| {
                let fit = Fit { keyframes: KeyframeFit::Warp, ..fit };
                fit_sample(&x2, &judged, i, self.mean, self.std, self.skel, fit)
            })
            .collect();
        for ((o, s), r) in out.iter_mut().zip(&stage1).zip(&raw) {
            let (path, raw_path) =
                (root_positions(&s.features, req.dim), root_positions(&r.features, req.dim));
            o.track = Some(TrackReport::of(&path, &raw_path, self.skel.fps));
            o.root_path = Some(path);
        }
        out
    }

    /// `req` with the root track of each finished motion `stage1` observed on all its frames
    /// (pose keys keep their own values).
    pub fn track_request(&self, req: &Request, stage1: &[Fitted]) -> Request {
        let (n, d, r) = (req.frames, req.dim, ROOT_CHANNELS);
        let mut out = req.clone();
        for (i, s) in stage1.iter().enumerate() {
            let len = req.lengths[i];
            let channels = root_key::root_channels(&s.features, d);
            let mut x = s.features.clone();
            normalise(&mut x, self.mean, self.std);
            let frames: Vec<usize> = (0..len).collect();
            root_track::observe(
                &x,
                &channels,
                d,
                &frames,
                &mut out.kf[i * n * d..(i + 1) * n * d],
                &mut out.mask[i * n * d..(i + 1) * n * d],
                &mut out.root[i * n * r..(i + 1) * n * r],
                &mut out.root_mask[i * n * r..(i + 1) * n * r],
            );
        }
        out
    }
}

/// Whether any motion of `req` has a keyed place or heading (otherwise the first stage's root
/// is the network's own, and a second stage would only repeat it).
fn has_root_keys(req: &Request) -> bool {
    req.root_mask.iter().any(|&m| m > 0.0)
}

/// Root positions [T, 3] (metres) of de-normalised features [T, D].
fn root_positions(features: &[f32], dim: usize) -> Vec<f32> {
    let f64s: Vec<f64> = features.iter().map(|&v| v as f64).collect();
    let (_, pos) = recover_root_rot_pos(&f64s, dim);
    pos.iter().flat_map(|p| p.iter().map(|&v| v as f32)).collect()
}
