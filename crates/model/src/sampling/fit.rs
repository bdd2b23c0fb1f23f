//! After the last denoising step: how a generated motion is made to meet its keyframes exactly.

use diffkfc_data::dataset::denormalise;
use diffkfc_data::motion::plausibility::foot_skating_ratio;
use diffkfc_data::motion::representation::{recover_from_ric_f32, Layout};
use diffkfc_data::motion::root_key::{RootKey, ROOT_CHANNELS};
use diffkfc_data::postprocess::footlock::{self, ContactSource, LockReport};
use diffkfc_data::postprocess::rigid::{self, RigidReport};
use diffkfc_data::postprocess::steps;
use diffkfc_data::postprocess::stride::{self, StrideReport};
use diffkfc_data::postprocess::warp::{self, Correction};
use diffkfc_data::Skeleton;

use crate::sampling::balance;
use crate::sampling::sampler::Request;

/// Frames over which a pose correction fades out past a key when the next key is further away
/// (1 s at 20 fps): long enough that the added acceleration stays far below a real motion's.
pub const FALLOFF: usize = 20;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum KeyframeFit {
    /// Root first, then the body (`pipeline`): the keyed sample's root warped to the keyed
    /// places and headings gives a dense root track; the motion is denoised again with that
    /// track observed on every frame, so the legs step at the path's speed; then warped.
    #[default]
    Track,
    /// Motion warping: the residual at each key spread smoothly over its neighbours, the root
    /// re-integrated to the keyed places and headings (`diffkfc_data::postprocess::warp`).
    Warp,
    /// The observed features written into the keyframe frames alone (the paper's implied
    /// behaviour; the pose jumps at the key).
    Paste,
    /// The network's output as it is.
    None,
}

impl KeyframeFit {
    const ALL: [KeyframeFit; 4] =
        [KeyframeFit::Track, KeyframeFit::Warp, KeyframeFit::Paste, KeyframeFit::None];

    /// The name flags and requests use.
    pub fn name(self) -> &'static str {
        match self {
            KeyframeFit::Track => "track",
            KeyframeFit::Warp => "warp",
            KeyframeFit::Paste => "paste",
            KeyframeFit::None => "none",
        }
    }
}

impl std::fmt::Display for KeyframeFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for KeyframeFit {
    type Err = diffkfc_data::UnknownChoice;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match KeyframeFit::ALL.into_iter().find(|k| k.name() == s) {
            Some(k) => Ok(k),
            None => Err(diffkfc_data::UnknownChoice {
                what: "keyframe fit",
                given: s.into(),
                choices: "track, warp, paste, none",
            }),
        }
    }
}

/// How the foot post-process finds and holds planted feet (with `Fit::foot_lock`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Feet {
    /// Contacts from the motion's geometry, strides warped to the root's speed, then pinned.
    Warp,
    /// Contacts from the motion's geometry, pinned (no stride warping).
    Pin,
    /// The network's contact channels, pinned.
    Network,
    /// Stances from the motion's gait (low and slow, low and slower than the pelvis, or set
    /// into a glide), the pelvis lowered where a leg could not hold them, pinned, and the
    /// swings between them lifted off the floor where they would skate: the default, lowest
    /// on generated walks and the table (docs/feet.md).
    #[default]
    Steps,
}

/// What follows the last denoising step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    pub keyframes: KeyframeFit,
    /// Hold planted feet still after the keyframe fit (`diffkfc_data::postprocess::footlock`).
    pub foot_lock: bool,
    /// How planted feet are found and held.
    pub feet: Feet,
    /// Largest move of a planted foot the lock makes (metres; `footlock::MAX_SHIFT_M` by
    /// default): spans that slide further are left as dragged.
    pub lock_reach: f64,
    /// Refit every frame to one skeleton before the foot lock (`diffkfc_data::postprocess::rigid`), so the
    /// BVH export reproduces the motion.
    pub rigid: bool,
    /// After a warp or track fit, pull each frame towards the keys' interpolation as far as the
    /// network missed the keys (`sampling::balance`), where the keys allow an interpolation.
    pub balance: bool,
}

impl Default for Fit {
    fn default() -> Self {
        Fit {
            keyframes: KeyframeFit::Track,
            foot_lock: true,
            feet: Feet::default(),
            lock_reach: footlock::MAX_SHIFT_M,
            rigid: true,
            balance: true,
        }
    }
}

/// A finished motion: de-normalised features [len, D], the correction made at each keyed
/// frame, what making it rigid and foot locking moved, and (track fit) the first stage's root
/// path.
#[derive(Clone, Debug, Default)]
pub struct Fitted {
    pub features: Vec<f32>,
    pub corrections: Vec<Correction>,
    pub feet: LockReport,
    /// What stride warping did (`Feet::Warp`).
    pub stride: Option<StrideReport>,
    pub rigid: Option<RigidReport>,
    /// [len, 3] the root positions (metres) of the track the second stage observed.
    pub root_path: Option<Vec<f32>>,
    /// How closely the second stage's own output followed that track.
    pub track: Option<TrackReport>,
}

/// The track fit's second stage against the track it observed, before any fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TrackReport {
    /// Mean ground speed (m/s) of the track and of the network's root.
    pub track_speed_mps: f64,
    pub raw_speed_mps: f64,
    /// Mean and largest ground distance (m) of the network's root from the track.
    pub raw_distance_m: f64,
    pub raw_distance_max_m: f64,
}

impl TrackReport {
    /// From root positions [T, 3] of the track and of the network's output.
    pub fn of(track: &[f32], raw: &[f32], fps: f64) -> TrackReport {
        let ground = |p: &[f32], a: usize, b: usize| {
            ((p[3 * a] - p[3 * b]) as f64).hypot((p[3 * a + 2] - p[3 * b + 2]) as f64)
        };
        let t = track.len() / 3;
        let speed = |p: &[f32]| {
            (1..t).map(|f| ground(p, f, f - 1)).sum::<f64>() * fps / (t.max(2) - 1) as f64
        };
        let dist: Vec<f64> = (0..t)
            .map(|f| {
                ((track[3 * f] - raw[3 * f]) as f64)
                    .hypot((track[3 * f + 2] - raw[3 * f + 2]) as f64)
            })
            .collect();
        TrackReport {
            track_speed_mps: speed(track),
            raw_speed_mps: speed(raw),
            raw_distance_m: dist.iter().sum::<f64>() / t.max(1) as f64,
            raw_distance_max_m: dist.iter().copied().fold(0.0, f64::max),
        }
    }
}

/// Sample `i` of the sampler's normalised output `x` [B, N, D], de-normalised, fitted to the
/// request's keyframes and, with `fit.foot_lock`, its planted feet held (pose keyframes untouched).
pub fn fit_sample(
    x: &[f32],
    req: &Request,
    i: usize,
    mean: &[f32],
    std: &[f32],
    skel: &Skeleton,
    fit: Fit,
) -> Fitted {
    let (mut features, corrections) = fit_keys(x, req, i, mean, std, skel, fit);
    let mut hold = vec![false; req.lengths[i]];
    req.key_frames(i).into_iter().for_each(|f| hold[f] = true);
    let rigid = fit.rigid.then(|| rigid::make_rigid(skel, &mut features, &hold));
    let (feet, stride) =
        if fit.foot_lock { hold_feet(skel, &mut features, &hold, fit) } else { Default::default() };
    Fitted { features, corrections, feet, stride, rigid, root_path: None, track: None }
}

/// The foot post-process: stride warping (`Feet::Warp`), then the lock with the contacts its
/// mode reads; each planted span records the warp's factor at its middle. A warp after which
/// the feet skate more than with the pinning alone is undone (the report says so).
fn hold_feet(
    skel: &Skeleton,
    features: &mut [f32],
    hold: &[bool],
    fit: Fit,
) -> (LockReport, Option<StrideReport>) {
    let lock = |f: &mut [f32], source| {
        footlock::lock_feet(skel, f, hold, footlock::BLEND, fit.lock_reach, source)
    };
    match fit.feet {
        Feet::Network => return (lock(features, ContactSource::Network), None),
        Feet::Pin => return (lock(features, ContactSource::Motion), None),
        Feet::Steps => return (steps_or_pin(skel, features, hold, fit, &lock), None),
        Feet::Warp => {}
    }
    let mut warped = features.to_vec();
    let mut stride = stride::warp_strides(skel, &mut warped, hold);
    let mut feet = lock(&mut warped, ContactSource::Motion);
    if stride.warped {
        let mut pinned = features.to_vec();
        let pinned_feet = lock(&mut pinned, ContactSource::Motion);
        if skating_ratio(skel, &warped) > skating_ratio(skel, &pinned) {
            stride.undo("undone: the feet skated more with the warp than with the pinning alone");
            (warped, feet) = (pinned, pinned_feet);
        }
    }
    features.copy_from_slice(&warped);
    if !stride.factors.is_empty() {
        for span in &mut feet.spans {
            span.warp_factor = stride.factors[(span.start + span.end) / 2];
        }
    }
    (feet, Some(stride))
}

/// `Feet::Steps`, or the pinning alone where the lifted swings leave a higher foot skating
/// ratio than the motion had (a lift takes frames off the floor, which the ratio counts).
fn steps_or_pin(
    skel: &Skeleton,
    features: &mut [f32],
    hold: &[bool],
    fit: Fit,
    lock: &dyn Fn(&mut [f32], ContactSource) -> LockReport,
) -> LockReport {
    let mut stepped = features.to_vec();
    let drop = steps::lower_for_stances(skel, &mut stepped, hold, fit.lock_reach);
    let mut report = lock(&mut stepped, ContactSource::Gait);
    report.pelvis_drop_m = drop;
    if skating_ratio(skel, &stepped) <= skating_ratio(skel, features) {
        features.copy_from_slice(&stepped);
        return report;
    }
    let mut pinned = lock(features, ContactSource::Motion);
    pinned.note = Some("steps undone: the feet skated more with the lifted swings".into());
    pinned
}

/// The foot skating ratio (`plausibility::foot_skating_ratio`) of de-normalised features.
fn skating_ratio(skel: &Skeleton, features: &[f32]) -> f64 {
    foot_skating_ratio(skel, &recover_from_ric_f32(skel, features))
}

fn fit_keys(
    x: &[f32],
    req: &Request,
    i: usize,
    mean: &[f32],
    std: &[f32],
    skel: &Skeleton,
    fit: Fit,
) -> (Vec<f32>, Vec<Correction>) {
    let layout = &Layout::of(skel);
    let (n, d, r) = (req.frames, req.dim, ROOT_CHANNELS);
    let len = req.lengths[i];
    let span = |v: &[f32], w: usize| v[i * n * w..(i * n + len) * w].to_vec();
    let mut out = span(x, d);
    denormalise(&mut out, mean, std);
    let mask = span(&req.mask, d);
    let mut target = span(&req.kf, d);
    denormalise(&mut target, mean, std);
    match fit.keyframes {
        KeyframeFit::None => (out, Vec::new()),
        KeyframeFit::Paste => {
            let mut corr: Vec<Correction> = Vec::new();
            for f in 0..len {
                let row = f * d..(f + 1) * d;
                if !mask[row.clone()].iter().any(|&m| m > 0.0) {
                    continue;
                }
                let mut worst = 0.0f64;
                for k in row {
                    if mask[k] > 0.0 {
                        worst = worst.max((target[k] - out[k]).abs() as f64);
                        out[k] = target[k];
                    }
                }
                corr.push(Correction { frame: f, pose: worst, ..Default::default() });
            }
            (out, corr)
        }
        KeyframeFit::Warp | KeyframeFit::Track => {
            let (rv, rm) = (span(&req.root, r), span(&req.root_mask, r));
            let root: Vec<RootKey> = (0..len)
                .map(|f| RootKey::from_channels(&rv[f * r..(f + 1) * r], &rm[f * r..(f + 1) * r]))
                .collect();
            let targets = warp::Targets { features: &target, mask: &mask, root: &root };
            let raw = out.clone();
            let corr = warp::warp(layout, &mut out, &targets, FALLOFF);
            let sampled = Sampled { raw: &raw, req, i, mean, std };
            if fit.balance && lean_on_keys(skel, &mut out, &target, sampled) {
                // The blend of two motions through the keys meets them only approximately
                // (the root integrates its blended velocities): warp again.
                warp::warp(layout, &mut out, &targets, FALLOFF);
            }
            (out, corr)
        }
    }
}

/// Sample `i` of a request as the fit reads it: its de-normalised raw output `[len, D]` and the
/// normalisation that reads the request's own arrays.
struct Sampled<'a> {
    raw: &'a [f32],
    req: &'a Request,
    i: usize,
    mean: &'a [f32],
    std: &'a [f32],
}

/// `balance` on sample `s`: each body part of `out` (`balance::parts`) pulled towards the keys'
/// interpolation as far as the network (and, with the track fit, its first unaided sample)
/// missed that part of the keys `target`. False where the keys allow no interpolation (nothing
/// changed).
fn lean_on_keys(skel: &Skeleton, out: &mut [f32], target: &[f32], s: Sampled) -> bool {
    let layout = &Layout::of(skel);
    let Some(interp) = &s.req.interpolation else { return false };
    let (n, d, len) = (s.req.frames, s.req.dim, s.req.lengths[s.i]);
    let read = |v: &[f32]| {
        let mut x = v[s.i * n * d..(s.i * n + len) * d].to_vec();
        denormalise(&mut x, s.mean, s.std);
        x
    };
    let keys = s.req.key_frames(s.i);
    let (interp, unaided) = (read(interp), s.req.unaided.as_ref().map(|u| read(u)));
    for part in balance::parts(skel) {
        let mut w = balance::weights(layout, (s.raw, target), &part.joints, &keys, len);
        if let Some(u) = &unaided {
            let w1 = balance::weights(layout, (u, target), &part.joints, &keys, len);
            w.iter_mut().zip(w1).for_each(|(a, b)| *a = a.min(b));
        }
        balance::pull_towards(layout, out, &interp, &w, &part.channels);
    }
    true
}
