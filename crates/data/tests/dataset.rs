//! Dataset reading, packed cache and batching on small datasets written from the fixture clip.

use std::path::{Path, PathBuf};

use diffkfc_data::dataset::batch::{KeyframeConfig, Loader};
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_data::keyframes::{self, Strategy};
use diffkfc_data::{io::npy, testing::fixtures};

fn write_clip(root: &Path, id: &str, feats: &[f32], dim: usize, captions: &[&str]) {
    npy::write(
        root.join("new_joint_vecs").join(format!("{id}.npy")),
        &[feats.len() / dim, dim],
        feats,
    )
    .unwrap();
    std::fs::write(root.join("texts").join(format!("{id}.txt")), captions.join("\n")).unwrap();
}

/// A dataset from the fixture clip 012314 (170 frames): A whole, B too short, C with a tagged
/// sub-clip caption, M012314 a mirrored id. Returns (root, clip features).
fn small_dataset(name: &str) -> Option<(PathBuf, Vec<f32>)> {
    let clip =
        npy::read_f32(fixtures::require("humanml3d/new_joint_vecs/012314.npy")?).unwrap().data;
    let dir = std::env::temp_dir().join(format!("diffkfc-ds-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    for sub in ["new_joint_vecs", "texts"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    for f in ["Mean.npy", "Std.npy"] {
        std::fs::copy(fixtures::require(&format!("humanml3d/{f}")).unwrap(), dir.join(f)).unwrap();
    }
    let d = 263;
    write_clip(
        &dir,
        "A",
        &clip,
        d,
        &[
            "a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0",
            "someone strolls.#someone/PRON stroll/VERB#0.0#0.0",
        ],
    );
    write_clip(&dir, "B", &clip[..30 * d], d, &["too short.#too/ADV short/ADJ#0.0#0.0"]);
    write_clip(
        &dir,
        "C",
        &clip[..100 * d],
        d,
        &["whole c.#whole/ADJ c/NOUN#0.0#0.0", "part of c.#part/NOUN of/ADP c/NOUN#1.0#4.0"],
    );
    write_clip(&dir, "M012314", &clip, d, &["a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0"]);
    std::fs::write(dir.join("train.txt"), "A\nB\nC\nM012314\n").unwrap();
    std::fs::write(dir.join("val.txt"), "C\n").unwrap();
    std::fs::write(dir.join("test.txt"), "A\n").unwrap();
    Some((dir, clip))
}

#[test]
fn items_follow_mdm_rules_and_cache_maps_the_features() {
    let Some((root, clip)) = small_dataset("items") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    assert_eq!(ds.skeleton.name, "t2m");
    let cache = root.join(".cache");
    let split = PackedSplit::open(&ds, "train", &cache, |_, _| {}).unwrap();
    assert!(split.built);
    let items: Vec<(String, usize, usize, usize)> =
        split.items.iter().map(|i| (i.clip.clone(), i.start, i.len, i.captions.len())).collect();
    assert_eq!(
        items,
        vec![
            ("A".into(), 0, 170, 2),
            ("C".into(), 0, 100, 1),
            ("C".into(), 20, 60, 1),
            ("M012314".into(), 0, 170, 1)
        ]
    );
    assert_eq!(split.skipped.len(), 1);
    assert!(split.skipped[0].1.contains("30 frames"), "{:?}", split.skipped);
    assert_eq!(split.item_frames(0), &clip[..]);
    assert_eq!(split.item_frames(2), &clip[20 * 263..80 * 263]);
    assert_eq!(split.total_frames(), 170 + 100 + 170);

    // Reopened unchanged: reused, not rebuilt.
    let again = PackedSplit::open(&ds, "train", &cache, |_, _| {}).unwrap();
    assert!(!again.built);
    assert_eq!(again.item_frames(2), split.item_frames(2));

    // A changed source file rebuilds the cache and the new data is seen.
    let mut changed = clip.clone();
    changed[0] += 1.0;
    changed.extend_from_slice(&clip[..263]);
    write_clip(&root, "A", &changed, 263, &["a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0"]);
    let rebuilt = PackedSplit::open(&ds, "train", &cache, |_, _| {}).unwrap();
    assert!(rebuilt.built);
    assert_eq!(rebuilt.item_frames(0), &changed[..]);
    std::fs::remove_dir_all(root).unwrap();
}

/// A clip whose only caption spans past its end is skipped with the reason.
#[test]
fn skipped_clip_says_why() {
    let Some((root, clip)) = small_dataset("skip") else {
        return;
    };
    write_clip(&root, "D", &clip, 263, &["a person turns.#a/DET person/NOUN turn/VERB#8.0#12.0"]);
    std::fs::write(root.join("val.txt"), "D\n").unwrap();
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "val", &root.join(".cache"), |_, _| {}).unwrap();
    assert!(split.items.is_empty());
    let why = &split.skipped[0].1;
    assert!(
        why.contains("no whole-clip caption")
            && why.contains("1 sub-clip caption span(s) run past its end"),
        "{why}"
    );
    std::fs::remove_dir_all(root).unwrap();
}

#[test]
fn batches_are_normalised_padded_and_deterministic() {
    let Some((root, _)) = small_dataset("batch") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let kf = KeyframeConfig {
        strategy: Strategy::Random,
        rate: 0.05,
        drop_prob: 0.0,
        ..Default::default()
    };
    let mut loader = Loader::new(&ds, &split, 3, 42, kf.clone());
    let b = loader.batch(0, 0);
    let (n, d) = (b.frames, b.dim);
    assert_eq!((n, d), (196, 263));
    for i in 0..3 {
        let len = b.lengths[i];
        assert_eq!(len % 4, 0);
        let item = &split.items[b.items[i]];
        assert!(
            len == item.len / 4 * 4 || len == (item.len / 4 - 1) * 4,
            "{len} from {}",
            item.len
        );
        assert!(item.captions.contains(&b.captions[i]));
        // Valid mask and zero padding.
        assert!(b.valid[i * n..i * n + len].iter().all(|&v| v == 1.0));
        assert!(b.valid[i * n + len..(i + 1) * n].iter().all(|&v| v == 0.0));
        assert!(b.x0[(i * n + len) * d..(i + 1) * n * d].iter().all(|&v| v == 0.0));
        // The sample is a normalised window of the item.
        let raw = split.item_frames(b.items[i]);
        let first: Vec<f32> =
            (0..d).map(|k| b.x0[i * n * d + k] * ds.std[k] + ds.mean[k]).collect();
        let start = (0..=item.len - len)
            .find(|&s| (0..d).all(|k| (raw[s * d + k] - first[k]).abs() < 1e-4))
            .expect("crop start");
        for f in 0..len {
            for k in 0..d {
                let want = (raw[(start + f) * d + k] - ds.mean[k]) / ds.std[k];
                assert!((b.x0[(i * n + f) * d + k] - want).abs() < 1e-5);
            }
        }
        // Keyframes: 5% of the length, whole frames, never on padding.
        let kf_frames: Vec<usize> = (0..n).filter(|&f| b.kf_mask[(i * n + f) * d] == 1.0).collect();
        assert_eq!(kf_frames.len(), ((len as f64) * 0.05).round().max(1.0) as usize);
        assert!(kf_frames.iter().all(|&f| f < len));
        for &f in &kf_frames {
            assert!(b.kf_mask[(i * n + f) * d..(i * n + f + 1) * d].iter().all(|&v| v == 1.0));
        }
        // Root channels: the crop's own frame (its first frame at the origin facing +Z), the
        // whole trajectory of the crop, observed only at keyframes.
        let r = diffkfc_data::motion::root_key::ROOT_CHANNELS;
        assert_eq!(&b.root[i * n * r..i * n * r + r], &[0.0, 0.0, 0.0, 1.0]);
        let want =
            diffkfc_data::motion::root_key::root_channels(&raw[start * d..(start + len) * d], d);
        assert!(b.root[i * n * r..(i * n + len) * r]
            .iter()
            .zip(&want)
            .all(|(a, b)| (a - b).abs() < 1e-6));
        for f in 0..n {
            if !kf_frames.contains(&f) {
                assert!(
                    b.root_mask[(i * n + f) * r..(i * n + f + 1) * r].iter().all(|&m| m == 0.0),
                    "root observed off a keyframe"
                );
            }
        }
    }
    // Same seed: same batch, whatever the number of threads; another seed: another batch.
    assert_eq!(loader.batch(0, 0), b);
    loader.threads = 3;
    assert_eq!(loader.batch(0, 0), b);
    let other = Loader::new(&ds, &split, 3, 43, kf);
    assert_ne!(other.batch(0, 0), b);
    assert_ne!(loader.batch(1, 0), b);
    // Dropped keyframes (classifier-free guidance).
    let drop =
        Loader::new(&ds, &split, 3, 42, KeyframeConfig { drop_prob: 1.0, ..Default::default() });
    assert!(drop.batch(0, 0).kf_mask.iter().all(|&v| v == 0.0));
    std::fs::remove_dir_all(root).unwrap();
}

#[test]
fn dense_root_tracks_keep_the_sparse_keys_and_observe_the_root() {
    let Some((root, _)) = small_dataset("dense_root") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let sparse = KeyframeConfig { drop_prob: 0.0, ..Default::default() };
    let dense = KeyframeConfig { dense_root_prob: 1.0, ..sparse.clone() };
    let a = Loader::new(&ds, &split, 4, 7, sparse).batch(0, 0);
    let b = Loader::new(&ds, &split, 4, 7, dense.clone()).batch(0, 0);
    assert_eq!(b, Loader::new(&ds, &split, 4, 7, dense).batch(0, 0), "reproducible by seed");
    let (n, d, r) = (a.frames, a.dim, diffkfc_data::motion::root_key::ROOT_CHANNELS);
    assert_eq!((&a.x0, &a.root, &a.lengths), (&b.x0, &b.root, &b.lengths));
    for i in 0..4 {
        let len = b.lengths[i];
        let mut tracked = 0;
        for f in 0..n {
            let (ma, mb) = (&a.kf_mask[(i * n + f) * d..][..d], &b.kf_mask[(i * n + f) * d..][..d]);
            // The sparse pose keys are the same keys; the track adds dims 0..3 only.
            assert_eq!(&ma[3..], &mb[3..], "sample {i} frame {f}");
            let on = mb[..3].iter().all(|&m| m == 1.0);
            assert!(on || ma[..3] == mb[..3]);
            if on && ma[0] == 0.0 {
                tracked += 1;
                assert!(f < len, "no track on padding");
                let rm = &b.root_mask[(i * n + f) * r..][..r];
                assert!(rm.iter().all(|&m| m == 1.0), "track frames observe place and heading");
            }
        }
        let keys = a.kf_mask[i * n * d..(i + 1) * n * d].iter().step_by(d).filter(|&&m| m > 0.0);
        assert!(tracked + keys.count() >= len / 4, "sample {i}: {tracked} of {len} tracked");
    }
    std::fs::remove_dir_all(root).unwrap();
}

#[test]
fn text_drop_keeps_the_batch_and_drops_some_texts() {
    let Some((root, _)) = small_dataset("text_drop") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let kf = KeyframeConfig::default();
    let plain = Loader::new(&ds, &split, 4, 7, kf.clone());
    let dropping = Loader { text_drop_prob: 0.5, ..Loader::new(&ds, &split, 4, 7, kf.clone()) };
    let all = Loader { text_drop_prob: 1.0, ..Loader::new(&ds, &split, 4, 7, kf) };
    let (mut dropped, mut total) = (0, 0);
    for b in 0..plain.batches_per_epoch().min(8) {
        let (a, c) = (plain.batch(0, b), dropping.batch(0, b));
        assert!(a.text_dropped.iter().all(|&d| !d), "no drop when the probability is 0");
        // The draw comes last: motions, keys, root tracks and captions are those of the plain run.
        let mut same = c.clone();
        same.text_dropped = a.text_dropped.clone();
        assert_eq!(same, a, "batch {b}");
        assert!(all.batch(0, b).text_dropped.iter().all(|&d| d));
        dropped += c.text_dropped.iter().filter(|&&d| d).count();
        total += c.text_dropped.len();
    }
    assert!(dropped > 0 && dropped < total, "{dropped} of {total} texts dropped at 0.5");
    let shard = dropping.batch(0, 0).shard(1..3);
    assert_eq!(shard.text_dropped, dropping.batch(0, 0).text_dropped[1..3]);
    std::fs::remove_dir_all(root).unwrap();
}

/// `text_drop_prob_unkeyed` drops the text of exactly the samples whose keys were dropped (at
/// 1, with no drop elsewhere) and leaves motions, keys and captions as the plain run draws them.
#[test]
fn unkeyed_text_drop_drops_the_texts_of_the_key_free_samples_only() {
    let Some((root, _)) = small_dataset("text_drop_unkeyed") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let kf = KeyframeConfig { drop_prob: 0.5, ..KeyframeConfig::default() };
    let plain = Loader::new(&ds, &split, 8, 3, kf.clone());
    let unkeyed =
        Loader { text_drop_prob_unkeyed: Some(1.0), ..Loader::new(&ds, &split, 8, 3, kf) };
    let (mut key_free, mut keyed) = (0, 0);
    for b in 0..plain.batches_per_epoch().min(8) {
        let (a, c) = (plain.batch(0, b), unkeyed.batch(0, b));
        let per = |v: &[f32], i: usize| {
            v.chunks(v.len() / a.batch_size).nth(i).unwrap().iter().sum::<f32>()
        };
        for i in 0..a.batch_size {
            let has_keys = per(&a.kf_mask, i) > 0.0 || per(&a.root_mask, i) > 0.0;
            assert_eq!(c.text_dropped[i], !has_keys, "batch {b} sample {i}");
            if has_keys {
                keyed += 1
            } else {
                key_free += 1
            }
        }
        let mut same = c.clone();
        same.text_dropped = a.text_dropped.clone();
        assert_eq!(same, a, "batch {b}");
    }
    assert!(key_free > 0 && keyed > 0, "{key_free} key-free, {keyed} keyed samples");
    std::fs::remove_dir_all(root).unwrap();
}

#[test]
fn body_part_keys_observe_one_half_of_the_body_and_keep_the_batch() {
    let Some((root, _)) = small_dataset("part_keys") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let whole = KeyframeConfig { drop_prob: 0.0, ..Default::default() };
    let parts = KeyframeConfig { part_prob: 1.0, ..whole.clone() };
    let skel = ds.skeleton;
    // One keyed frame's mask of that half, as the loader builds it.
    let half = |name: &str| {
        let dims = keyframes::dim_mask(skel, Some(skel.part(name).unwrap().joints));
        keyframes::frame_mask(1, &[0], &dims)
    };
    let (lower, upper) = (half("lower_body"), half("upper_body"));
    // The lower body owns the root's velocity and height, the upper body none of them.
    assert!(lower[..4].iter().all(|&m| m == 1.0) && upper[..4].iter().all(|&m| m == 0.0));
    let (mut seen_lower, mut seen_upper) = (false, false);
    for b in 0..8 {
        let a = Loader::new(&ds, &split, 4, 7, whole.clone()).batch(0, b);
        let p = Loader::new(&ds, &split, 4, 7, parts.clone()).batch(0, b);
        // Drawn last: motions, keyframe frames, places and captions are the whole-key run's.
        assert_eq!(
            (&a.x0, &a.root, &a.root_mask, &a.captions),
            (&p.x0, &p.root, &p.root_mask, &p.captions)
        );
        let d = a.dim;
        for (ka, kp) in a.kf_mask.chunks(d).zip(p.kf_mask.chunks(d)) {
            if ka.iter().all(|&m| m == 0.0) {
                assert!(kp.iter().all(|&m| m == 0.0), "a part key on a frame without a key");
                continue;
            }
            assert!(ka.iter().all(|&m| m == 1.0), "whole keys observe every dim");
            seen_lower |= kp == lower.as_slice();
            seen_upper |= kp == upper.as_slice();
            assert!(kp == lower.as_slice() || kp == upper.as_slice(), "a key observes one half");
        }
    }
    assert!(seen_lower && seen_upper, "both halves drawn");
    std::fs::remove_dir_all(root).unwrap();
}

/// `max_observed_sigma` leaves elements beyond it unobserved by keys and tracks (HumanML3D's
/// spin frames) and changes nothing else: the same motions, keyed frames, places and captions.
#[test]
fn outlying_elements_stay_unobserved_and_keep_the_batch() {
    let Some((root, _)) = small_dataset("outliers") else {
        return;
    };
    let ds = Dataset::open(&root).unwrap();
    let split = PackedSplit::open(&ds, "train", &root.join(".cache"), |_, _| {}).unwrap();
    let all = KeyframeConfig { drop_prob: 0.0, dense_root_prob: 0.5, ..Default::default() };
    // Low enough that this tiny set's keys observe some elements beyond it.
    let limit = 1.5;
    let capped = KeyframeConfig { max_observed_sigma: Some(limit), ..all.clone() };
    let (mut cleared, mut kept) = (0, 0);
    for b in 0..8 {
        let a = Loader::new(&ds, &split, 4, 7, all.clone()).batch(0, b);
        let c = Loader::new(&ds, &split, 4, 7, capped.clone()).batch(0, b);
        assert_eq!(
            (&a.x0, &a.valid, &a.root, &a.root_mask, &a.captions),
            (&c.x0, &c.valid, &c.root, &c.root_mask, &c.captions)
        );
        for ((&ma, &mc), &x) in a.kf_mask.iter().zip(&c.kf_mask).zip(&a.x0) {
            let beyond = x.abs() > limit as f32;
            assert_eq!(mc, if beyond { 0.0 } else { ma }, "x {x}");
            cleared += usize::from(ma == 1.0 && beyond);
            kept += usize::from(mc == 1.0);
        }
    }
    assert!(cleared > 0 && kept > cleared, "{cleared} cleared, {kept} kept");
    std::fs::remove_dir_all(root).unwrap();
}
