//! The in-betweening benchmark (DESIGN.md §4, after LaFAN1's practice of reporting every method
//! beside interpolation): each clip keyed every G seconds (and the last frame) or at a rate,
//! one sample per clip, scored on the frames between keys beside linear interpolation of the
//! same keys and the clip's own realism numbers. `diffkfc eval inbetween` runs it.

pub mod score;

use std::str::FromStr;

use diffkfc_data::keyframes;
use diffkfc_data::motion::representation::{recover_from_ric_f32, Joints};
use diffkfc_data::motion::root_key::{self, RootKey};
use diffkfc_model::diffusion::scheduler::timesteps;
use diffkfc_model::sampling::fit::{Fit, KeyframeFit};
use diffkfc_model::sampling::pipeline::{Generator, KeyedItem};
use diffkfc_model::sampling::sampler::{Options, Request};
use serde::Serialize;

pub use score::{interpolate, score, Scores};

/// How a clip is keyed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub enum Gap {
    /// A key every this many seconds from frame 0, and the last frame.
    Seconds(f64),
    /// This share of the frames, evenly spaced, both ends included (DiffKFC's 5%).
    Rate(f64),
}

impl FromStr for Gap {
    type Err = String;
    /// `0.5`, `1`, `2` (seconds) or `5%` (a rate).
    fn from_str(s: &str) -> Result<Gap, String> {
        let s = s.trim();
        let bad = || format!("'{s}' is neither seconds between keys (0.5, 1, 2) nor a rate (5%)");
        match s.strip_suffix('%') {
            Some(p) => {
                let r: f64 = p.trim().parse().map_err(|_| bad())?;
                (r > 0.0 && r <= 100.0).then_some(Gap::Rate(r / 100.0)).ok_or_else(bad)
            }
            None => {
                let g: f64 = s.parse().map_err(|_| bad())?;
                (g.is_finite() && g > 0.0 && g <= 60.0).then_some(Gap::Seconds(g)).ok_or_else(bad)
            }
        }
    }
}

impl Gap {
    /// The keyed frames of a clip of `len` frames at `fps`: sorted, first and last included.
    pub fn keys(self, len: usize, fps: f64) -> Vec<usize> {
        if len == 0 {
            return vec![];
        }
        let mut k: Vec<usize> = match self {
            Gap::Seconds(g) => (0..len).step_by(((g * fps).round() as usize).max(1)).collect(),
            Gap::Rate(r) => keyframes::uniform(len, keyframes::count(len, r).max(2)),
        };
        if k.last() != Some(&(len - 1)) {
            k.push(len - 1);
        }
        k
    }

    /// As a table shows it: `1 s`, `5%`.
    pub fn label(self) -> String {
        match self {
            Gap::Seconds(g) => format!("{g} s"),
            Gap::Rate(r) => format!("{}%", r * 100.0),
        }
    }
}

/// A clip to key: its raw (de-normalised) features `[frames, D]` and a caption.
pub struct SourceClip {
    pub id: String,
    pub caption: String,
    pub features: Vec<f32>,
}

/// One clip at one gap: the keys and every method's scores.
#[derive(Clone, Debug, Serialize)]
pub struct GapScores {
    pub gap: String,
    pub keys: Vec<usize>,
    /// The clip itself (its realism numbers; zero error).
    pub clip: Scores,
    /// Linear interpolation of the joints between the keys.
    pub interpolation: Scores,
    /// The network's sample before any fit (`--keyframe-fit none --no-foot-lock --no-rigid`).
    pub network: Scores,
    /// The sample through the pipeline's fit.
    pub pipeline: Scores,
}

/// The motions behind one clip's scores, per gap: (network, pipeline) joints.
pub type Motions = Vec<(Joints, Joints)>;

/// A clip's result: its id, length and per-gap scores.
#[derive(Clone, Debug, Serialize)]
pub struct ClipScores {
    pub id: String,
    pub frames: usize,
    pub gaps: Vec<GapScores>,
}

/// The benchmark of one model: how it samples and fits, and the gaps.
pub struct Bench<'a> {
    pub gen: Generator<'a>,
    pub opts: Options,
    pub fit: Fit,
    pub gaps: Vec<Gap>,
}

impl Bench<'_> {
    /// Denoising steps of one clip (all gaps in one batch; the pipeline's track fit is two
    /// passes), for progress bars.
    pub fn steps_per_clip(&self) -> usize {
        let pipeline = if self.fit.keyframes == KeyframeFit::Track { 2 } else { 1 };
        timesteps(self.gen.schedule, self.opts.sampler).len() * (1 + pipeline)
    }

    /// One motion per key set: `clip` keyed at `keys` (whole poses, places and headings).
    fn request(&self, clip: &SourceClip, text: &[f32], keys: &[Vec<usize>]) -> Request {
        let d = self.gen.skel.feature_dim();
        let len = clip.features.len() / d;
        let traj = root_key::root_trajectory(&clip.features, d);
        let keyed: Vec<(Vec<f32>, Vec<RootKey>)> = keys
            .iter()
            .map(|k| {
                let mut root = vec![RootKey::default(); len];
                k.iter().for_each(|&f| root[f] = traj[f]);
                (keyframes::frame_mask(len, k, &vec![true; d]), root)
            })
            .collect();
        let items: Vec<KeyedItem> = keyed
            .iter()
            .map(|(mask, root)| KeyedItem { text, length: len, values: &clip.features, mask, root })
            .collect();
        self.gen.request(len, &items)
    }

    /// Key `clip` at every gap, sample it (network alone, then the pipeline; noise from `seed`)
    /// and score everything against the clip. `text` is the caption's embedding.
    pub fn run_clip(
        &self,
        clip: &SourceClip,
        text: &[f32],
        seed: u64,
        mut progress: impl FnMut(),
    ) -> (ClipScores, Motions) {
        let skel = self.gen.skel;
        let len = clip.features.len() / skel.feature_dim();
        let truth = recover_from_ric_f32(skel, &clip.features);
        let keys: Vec<Vec<usize>> = self.gaps.iter().map(|g| g.keys(len, skel.fps)).collect();
        let req = self.request(clip, text, &keys);
        let opts = Options { seed, ..self.opts.clone() };
        let alone =
            Fit { keyframes: KeyframeFit::None, foot_lock: false, rigid: false, ..self.fit };
        // Both calls count their steps from zero; the bar advances by what each adds.
        let last = std::cell::Cell::new(0);
        let mut tick = |k: usize, _n: usize| {
            (last.get()..k).for_each(|_| progress());
            last.set(k);
        };
        let network = self.gen.generate(&req, &opts, alone, &mut tick);
        last.set(0);
        let pipeline = self.gen.generate(&req, &opts, self.fit, &mut tick);
        let mut motions = Vec::new();
        let gaps = self
            .gaps
            .iter()
            .zip(&keys)
            .zip(network.iter().zip(&pipeline))
            .map(|((g, k), (n, p))| {
                let (nj, pj) = (
                    recover_from_ric_f32(skel, &n.features),
                    recover_from_ric_f32(skel, &p.features),
                );
                let s = GapScores {
                    gap: g.label(),
                    keys: k.clone(),
                    clip: score(skel, &truth, &truth, k),
                    interpolation: score(skel, &interpolate(&truth, k), &truth, k),
                    network: score(skel, &nj, &truth, k),
                    pipeline: score(skel, &pj, &truth, k),
                };
                motions.push((nj, pj));
                s
            })
            .collect();
        (ClipScores { id: clip.id.clone(), frames: len, gaps }, motions)
    }
}

pub mod table;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_parse_and_key_both_ends() {
        assert_eq!("0.5".parse::<Gap>(), Ok(Gap::Seconds(0.5)));
        assert_eq!(" 5% ".parse::<Gap>(), Ok(Gap::Rate(0.05)));
        for bad in ["0", "-1", "x", "0%", "101%", "inf", "NaN"] {
            assert!(bad.parse::<Gap>().is_err(), "{bad}");
        }
        assert_eq!(Gap::Seconds(1.0).keys(45, 20.0), vec![0, 20, 40, 44]);
        assert_eq!(Gap::Seconds(1.0).keys(41, 20.0), vec![0, 20, 40]);
        // 5% of 100 frames: 5 keys evenly spaced with both ends.
        assert_eq!(Gap::Rate(0.05).keys(100, 20.0), vec![0, 25, 50, 74, 99]);
        // Never fewer than the two ends.
        assert_eq!(Gap::Rate(0.01).keys(30, 20.0), vec![0, 29]);
        assert_eq!(Gap::Seconds(0.5).label(), "0.5 s");
        assert_eq!(Gap::Rate(0.05).label(), "5%");
    }
}
