//! The synthetic dataset: determinism, plausibility of every clip, coverage of actions and
//! patterns in train and test, captions that parse, and walking feet that alternate.

use std::collections::{HashMap, HashSet};

use diffkfc_data::motion::plausibility;
use diffkfc_data::motion::representation as rep;
use diffkfc_data::{io::npy, io::texts, T2M};
use diffkfc_synth::{self as synth, actions::ACTIONS, Body, SynthSpec};

fn out_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("diffkfc-synth-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn same_seed_same_bytes_any_thread_count() {
    let (a, b, c) = (out_dir("a"), out_dir("b"), out_dir("c"));
    synth::write_dataset(&a, &SynthSpec::legacy(40, 5), 1, &|_, _| {}).unwrap();
    synth::write_dataset(&b, &SynthSpec::legacy(40, 5), 3, &|_, _| {}).unwrap();
    synth::write_dataset(&c, &SynthSpec::legacy(40, 6), 2, &|_, _| {}).unwrap();
    let files = |d: &std::path::Path| -> Vec<(String, Vec<u8>)> {
        let mut v = Vec::new();
        for sub in ["", "new_joint_vecs", "new_joints", "texts"] {
            let mut names: Vec<_> = std::fs::read_dir(d.join(sub))
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.is_file())
                .collect();
            names.sort();
            v.extend(names.into_iter().map(|p| {
                (p.strip_prefix(d).unwrap().display().to_string(), std::fs::read(&p).unwrap())
            }));
        }
        v
    };
    let (fa, fb, fc) = (files(&a), files(&b), files(&c));
    // 40 clips x 3 files, Mean, Std, 3 splits, the manifest and the dataset marker.
    assert_eq!(fa.len(), 3 * 40 + 7);
    assert!(fa == fb, "same seed, different bytes");
    assert!(fa != fc, "different seeds, same bytes");
    // The output is a valid dataset.
    let report = diffkfc_data::dataset::check::check(&a, |_, _| {});
    assert!(report.ok(), "{:?}", report.problems);
    for d in [a, b, c] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn every_clip_is_plausible_and_everything_is_covered() {
    let d = out_dir("cover");
    let n = 600;
    synth::write_dataset(&d, &SynthSpec::legacy(n, 1), 2, &|_, _| {}).unwrap();
    let clips = manifest(&d)["clips"].as_array().unwrap().clone();
    assert_eq!(clips.len(), n);
    let mut seen: HashMap<&str, HashSet<String>> = HashMap::new();
    for c in &clips {
        let split = c["split"].as_str().unwrap();
        for a in c["actions"].as_array().unwrap() {
            seen.entry(split).or_default().insert(a["action"].as_str().unwrap().to_string());
        }
        seen.entry(split)
            .or_default()
            .insert(format!("pattern:{}", c["pattern"].as_str().unwrap()));
    }
    assert_plausible(&d, &clips);
    for a in ACTIONS {
        for split in ["train", "test"] {
            assert!(seen[split].contains(a.name), "{} missing from {split}", a.name);
        }
    }
    for p in ["single", "sequence", "simultaneous", "ambiguous"] {
        for split in ["train", "test"] {
            assert!(seen[split].contains(&format!("pattern:{p}")), "{p} missing from {split}");
        }
    }
    std::fs::remove_dir_all(d).unwrap();
}

/// A varied set (`--vary 1`) is as plausible as the plain one, the same actions at other
/// paces: its clips' lengths differ, their action spans stay inside them.
#[test]
fn a_varied_set_is_plausible_at_other_paces() {
    let (plain, varied) = (out_dir("plain"), out_dir("varied"));
    let n = 300;
    synth::write_dataset(&plain, &SynthSpec::legacy(n, 1), 2, &|_, _| {}).unwrap();
    let spec = SynthSpec { vary: 1.0, ..SynthSpec::legacy(n, 1) };
    synth::write_dataset(&varied, &spec, 2, &|_, _| {}).unwrap();
    let (m0, m1) = (manifest(&plain), manifest(&varied));
    assert_eq!((m0.get("vary"), m1["vary"].as_f64()), (None, Some(1.0)));
    let clips = m1["clips"].as_array().unwrap().clone();
    assert_plausible(&varied, &clips);
    let frames = |c: &serde_json::Value| c["frames"].as_u64().unwrap();
    // The same draws (a varied clip that its features cannot represent is redrawn).
    let pairs = clips.iter().zip(m0["clips"].as_array().unwrap());
    let same: Vec<_> = pairs.filter(|(a, b)| a["captions"] == b["captions"]).collect();
    let other = same.iter().filter(|(a, b)| frames(a) != frames(b)).count();
    assert!(same.len() > n * 9 / 10 && other > same.len() * 3 / 4, "{} {other}", same.len());
    for c in &clips {
        for a in c["actions"].as_array().unwrap() {
            let (s, e) = (a["start"].as_u64().unwrap(), a["end"].as_u64().unwrap());
            assert!(s < e && e <= frames(c) + 1, "{}: span {s}..{e} of {}", c["id"], frames(c));
        }
    }
    for d in [plain, varied] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

fn manifest(d: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap()
}

/// Every clip of `d` has rigid bones, stays above the ground, has no velocity or acceleration
/// spike and three captions that parse; the mean foot skating is small.
fn assert_plausible(d: &std::path::Path, clips: &[serde_json::Value]) {
    let (mut worst_bone, mut min_h, mut max_v, mut max_a) = (0.0f64, f64::INFINITY, 0.0f64, 0.0f64);
    let mut skate_sum = 0.0;
    for c in clips {
        let id = c["id"].as_str().unwrap();
        let j = npy::read_f64(d.join(format!("new_joints/{id}.npy"))).unwrap();
        let t = j.shape[0];
        assert!((40..196).contains(&t), "{id}: {t} frames");
        let joints = rep::joints_from_array(&j.data, t, 22, 22);
        let p = plausibility::measure(&T2M, &joints);
        assert!(p.bone_length_std < 1e-4, "{id}: bone length std {}", p.bone_length_std);
        assert!(p.min_height > -0.02, "{id}: ground penetration {}", p.min_height);
        // Running toes reach about 13 m/s; 3000 clips of seed 0 peak at 12.9 m/s and 238 m/s^2.
        assert!(p.max_speed < 15.0, "{id}: velocity spike {} m/s", p.max_speed);
        assert!(p.max_accel < 300.0, "{id}: acceleration spike {} m/s^2", p.max_accel);
        max_a = max_a.max(p.max_accel);
        worst_bone = worst_bone.max(p.bone_length_std);
        min_h = min_h.min(p.min_height);
        max_v = max_v.max(p.max_speed);
        skate_sum += p.foot_skating;
        let (caps, errs) = texts::parse_file(&d.join(format!("texts/{id}.txt"))).unwrap();
        assert!(errs.is_empty() && caps.len() == 3, "{id}: {errs:?}");
    }
    let skate = skate_sum / clips.len() as f64;
    eprintln!("synth plausibility over {} clips: bone std {worst_bone:.2e} m, min height {min_h:.3} m, max speed {max_v:.2} m/s, max accel {max_a:.0} m/s^2, mean foot skating {skate:.4}", clips.len());
    assert!(skate < 0.05, "foot skating ratio {skate}");
}

/// A walk puts its feet down in turn: left and right toe contacts alternate, and each
/// planted foot stays put.
#[test]
fn walking_feet_alternate_on_the_ground() {
    use diffkfc_synth::{actions, body::Pose};
    let mut rng = diffkfc_data::rng::Rng::new(3);
    let seg = (actions::by_name("walk_forward").gen)(&mut rng, &Pose::standing(0.0, 0.0, 0.0), 120);
    let joints: rep::Joints = synth::body::joints_seq(Body::Legacy, &seg.poses);
    let feats = rep::features_from_joints(&T2M, &joints, rep::FOOT_CONTACT_THRESHOLD).unwrap();
    // Contact channels 259 (l_ankle) and 261 (r_ankle) over the middle of the walk.
    let c = |f: usize, k: usize| feats[f * 263 + k] > 0.5;
    let mut runs = Vec::new();
    for f in 20..100 {
        let state = (c(f, 259), c(f, 261));
        if runs.last() != Some(&state) {
            runs.push(state);
        }
    }
    // Single supports of each foot occur, in turn, several times.
    let singles: Vec<bool> = runs.iter().filter(|s| s.0 != s.1).map(|s| s.0).collect();
    assert!(singles.len() >= 4, "{runs:?}");
    assert!(singles.windows(2).all(|w| w[0] != w[1]), "feet do not alternate: {runs:?}");
    let p = plausibility::measure(&T2M, &joints);
    assert!(p.foot_skating < 0.05, "{}", p.foot_skating);
}
