//! Degenerate motions through generation's library entry points: all-zero features, a constant
//! pose, one or two frames, coinciding joints, a root that never moves, a motion far from the
//! origin, a tiny or huge skeleton, and random mixtures of these. Every case is read as a user's
//! file would be (`motion_features_from_bytes`: works or refuses with one line) and, refused or
//! not, pushed through the fit's whole chain as the keys and the network's output (the guards
//! sit where a NaN would arise, so even inputs the readers refuse must come out finite). A
//! share of the cases also runs the full two-stage generation with a tiny random-weight model.
//! Half of `DIFFKFC_FUZZ_CASES` cases (the fuzzers' count: 10 000 by default).

// Column groups are lists of ranges, one or several.
#![allow(clippy::single_range_in_vec_init)]

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use burn::prelude::*;
use diffkfc_data::io::motion_file::motion_features_from_bytes;
use diffkfc_data::io::npy;
use diffkfc_data::io::rig::{self, ImportOptions};
use diffkfc_data::motion::representation::{joints_to_f32, recover_from_ric_f32, Layout};
use diffkfc_data::motion::root_key::root_trajectory;
use diffkfc_data::rng::Rng;
use diffkfc_data::T2M;
use diffkfc_model::diffusion::scheduler::Sampler;
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::sampling::fit::{fit_sample, Feet, Fit, KeyframeFit};
use diffkfc_model::sampling::pipeline::{Generator, KeyedItem};
use diffkfc_model::sampling::sampler::Options;
use diffkfc_model::DiffKfcConfig;

const D: usize = 263;

/// The degenerate classes, each built from a real-looking walk `base` (features [T, D]).
const CLASSES: [&str; 9] =
    ["zeros", "constant", "short", "collapsed", "still", "far", "tiny", "huge", "mixture"];

fn case(base: &[f32], class: &str, r: &mut Rng) -> Vec<f32> {
    let l = Layout::of(&T2M);
    let t_base = base.len() / D;
    let t = 1 + r.below(t_base.min(48));
    let start = r.below(t_base - t + 1);
    let mut f = base[start * D..(start + t) * D].to_vec();
    let rows = |f: &mut Vec<f32>, cols: &[std::ops::Range<usize>], v: &dyn Fn(f32) -> f32| {
        for row in f.chunks_mut(D) {
            for c in cols.iter().flat_map(|c| c.clone()) {
                row[c] = v(row[c]);
            }
        }
    };
    match class {
        "zeros" => f.iter_mut().for_each(|v| *v = 0.0),
        "constant" => {
            let first = f[..D].to_vec();
            f.chunks_mut(D).for_each(|row| row.copy_from_slice(&first));
            rows(&mut f, &[0..3, l.vel()], &|_| 0.0);
        }
        "short" => f.truncate(D * (1 + r.below(2)).min(f.len() / D)),
        "collapsed" => {
            // Every joint at the root, or one bone of zero length.
            if r.below(2) == 0 {
                rows(&mut f, &[l.ric()], &|_| 0.0);
            } else {
                let j = 1 + r.below(20);
                let (a, b) = (l.ric().start + 3 * (j - 1), l.ric().start + 3 * j);
                for row in f.chunks_mut(D) {
                    let (p, c) = row[a..b + 3].split_at_mut(3);
                    c.copy_from_slice(p);
                }
            }
        }
        "still" => rows(&mut f, &[0..3], &|_| 0.0),
        "far" => {
            let k = [1e2f32, 1e3, 1e4][r.below(3)];
            rows(&mut f, &[1..3], &|v| v + k / t as f32);
        }
        "tiny" => rows(&mut f, &[3..4, l.ric(), l.vel()], &|v| v * 1e-3),
        "huge" => rows(&mut f, &[3..4, l.ric(), l.vel()], &|v| v * 1e3),
        _ => {
            // A mixture: each row from another class (or noise), so one motion holds several.
            let parts: Vec<Vec<f32>> = CLASSES[..8].iter().map(|c| case(base, c, r)).collect();
            for (i, row) in f.chunks_mut(D).enumerate() {
                let p = &parts[r.below(parts.len())];
                let n = p.len() / D;
                row.copy_from_slice(&p[(i % n) * D..(i % n + 1) * D]);
                if r.below(4) == 0 {
                    row.iter_mut().for_each(|v| *v += (r.normal() * 0.5) as f32);
                }
            }
        }
    }
    f
}

/// The keys a user could pin on `feats`: whole poses at a few frames with their places and
/// headings, as `sample --from` takes them.
fn keys(feats: &[f32], r: &mut Rng) -> (Vec<f32>, Vec<diffkfc_data::motion::root_key::RootKey>) {
    let t = feats.len() / D;
    let mut mask = vec![0f32; t * D];
    let traj = root_trajectory(feats, D);
    let mut root = vec![Default::default(); t];
    for _ in 0..1 + r.below(4) {
        let f = r.below(t);
        mask[f * D..(f + 1) * D].iter_mut().for_each(|m| *m = 1.0);
        root[f] = traj[f];
    }
    (mask, root)
}

fn finite(what: &str, class: &str, v: &[f32]) {
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        panic!("{class}: {what} has a non-finite value at {i} ({})", v[i]);
    }
}

/// What `data joints | features | bvh` and `render` do with a motion the reader took: its
/// joints, those joints read back as a joints file (the features route), and its BVH, which
/// must read back finite.
fn convert(feats: &[f32], class: &str) {
    let joints = recover_from_ric_f32(&T2M, feats);
    finite("the recovered joints", class, &joints_to_f32(&joints));
    let bytes = npy::encode(&[joints.len(), 22, 3], &joints_to_f32(&joints));
    let opts = ImportOptions::default();
    if let Ok(f) = motion_features_from_bytes(Path::new("j.npy"), &bytes, &T2M, &opts) {
        finite("features of the recovered joints", class, &f);
    }
    let bvh = rig::write(&T2M, &joints);
    let back = rig::read(&T2M, &bvh, &opts).unwrap_or_else(|e| panic!("{class}: our BVH: {e}"));
    finite("the BVH read back", class, &joints_to_f32(&back));
}

#[test]
fn degenerate_motions_never_panic_and_never_give_nan() {
    // Half the readers' count: each case runs the whole fit chain, not one parse.
    let n = diffkfc_data::testing::fuzz::cases() / 2;
    let (_, base) = diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 0, 0);
    let model = DiffKfcConfig::tiny().init(&Device::flex());
    let schedule = Schedule::cosine(1000);
    let (mean, std) = (vec![0f32; D], vec![1f32; D]);
    let gen = Generator { model: &model, schedule: &schedule, mean: &mean, std: &std, skel: &T2M };
    let opts = Options { sampler: Sampler::Ddim(2), seed: 1, ..Options::default() };
    let text = vec![0.01f32; DiffKfcConfig::tiny().text_dim];
    let (mut refused, mut generated) = (0, 0);
    let mut r = Rng::new(7);
    for i in 0..n {
        let class = CLASSES[i % CLASSES.len()];
        let feats = case(&base, class, &mut r);
        let t = feats.len() / D;
        let bytes = npy::encode(&[t, D], &feats);
        let read = catch_unwind(|| {
            motion_features_from_bytes(Path::new("m.npy"), &bytes, &T2M, &ImportOptions::default())
        })
        .unwrap_or_else(|_| panic!("case {i} ({class}, {t} frames): reading panicked"));
        match read {
            Ok(f) => {
                finite("the read features", class, &f);
                convert(&f, class);
            }
            Err(e) => {
                refused += 1;
                let msg = e.to_string();
                assert!(!msg.contains('\n') && msg.contains("m.npy"), "{class}: {msg}");
            }
        }
        let (mask, root) = keys(&feats, &mut r);
        let item = KeyedItem { text: &text, length: t, values: &feats, mask: &mask, root: &root };
        let full = i % 50 == 0;
        let run = catch_unwind(AssertUnwindSafe(|| {
            let req = gen.request(t, std::slice::from_ref(&item));
            if let Some(a) = &req.interpolation {
                finite("the keys' interpolation", class, a);
            }
            for keyframes in [KeyframeFit::Warp, KeyframeFit::Paste, KeyframeFit::None] {
                for feet in [Feet::Steps, Feet::Warp, Feet::Pin, Feet::Network] {
                    let fit = Fit { keyframes, feet, ..Fit::default() };
                    let done = fit_sample(&feats, &req, 0, &mean, &std, &T2M, fit);
                    finite("the fitted motion", class, &done.features);
                }
            }
            if full {
                for done in gen.generate(&req, &opts, Fit::default(), |_, _| {}) {
                    finite("the generated motion", class, &done.features);
                }
            }
        }));
        if run.is_err() {
            panic!("case {i} ({class}, {t} frames): the fit or generation panicked");
        }
        generated += usize::from(full);
    }
    println!(
        "{n} degenerate cases: {refused} refused by the reader, {generated} generated in full"
    );
    assert!(refused > 0 && refused < n, "the classes should hold both usable and refused motions");
}
