//! Bounded fuzzing of the readers of untrusted files: valid inputs mutated at random (bit flips,
//! byte and token replacement, truncation, duplication, digit runs that overflow), each fed to
//! the reader inside `catch_unwind`. Every input must give Ok or a clean error: no panic, and no
//! call slower than a second (`diffkfc_data::fuzz`).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use diffkfc_data::fuzz::{cases, fuzz};
use diffkfc_data::rng::Rng;
use diffkfc_data::{npy, representation as rep, rig, T2M};

fn walk(frames: usize) -> rep::Joints {
    let pose = T2M
        .target_offsets()
        .map(|o| {
            rep::forward_kinematics(
                &T2M,
                &[vec![diffkfc_data::quat::IDENTITY; 22]],
                &[[0.0, 0.9, 0.0]],
                &o,
            )[0]
            .clone()
        })
        .unwrap();
    (0..frames)
        .map(|f| pose.iter().map(|p| [p[0], p[1], p[2] + 0.05 * f as f64]).collect())
        .collect()
}

#[test]
fn npy_reader_never_panics() {
    let mut r = Rng::new(1);
    let feats: Vec<f32> = (0..6 * 263).map(|_| r.normal() as f32).collect();
    let seeds = vec![
        npy::encode(&[6, 263], &feats),
        npy::encode(&[4, 22, 3], &vec![0.5f64; 264]),
        npy::encode(&[263], &vec![1f32; 263]),
    ];
    let (_, errors) = fuzz("npy", &seeds, cases(), &|b| {
        let Ok((a, _)) = npy::decode_f64(Path::new("fuzz.npy"), b) else {
            return false;
        };
        // What the commands do next with an array must hold too.
        if a.ndim() == 2
            && a.shape[1] == 263
            && a.shape[0] >= 2
            && a.data.iter().all(|v| v.is_finite() && v.abs() < 1e6)
        {
            let _ = rep::recover_from_ric(&T2M, &a.data);
        }
        true
    });
    assert!(errors > 0);
}

#[test]
fn bvh_reader_never_panics() {
    let seeds = vec![rig::write(&T2M, &walk(4)).into_bytes()];
    fuzz("bvh", &seeds, cases(), &|b| {
        let Ok(text) = std::str::from_utf8(b) else {
            return false;
        };
        rig::read(&T2M, text, &Default::default()).is_ok()
    });
}

#[test]
fn joints_to_features_never_panics() {
    // Joint arrays as `data features` and `sample --from` get them: any finite values.
    let mut r = Rng::new(2);
    for k in 0..cases() / 10 {
        let frames = 2 + r.below(6);
        let mut j = walk(frames);
        for f in j.iter_mut() {
            for p in f.iter_mut() {
                for v in p.iter_mut() {
                    *v = match r.below(5) {
                        0 => r.normal() * 1e3,
                        1 => 0.0,
                        _ => *v + r.normal() * 0.1,
                    };
                }
            }
        }
        let out = catch_unwind(AssertUnwindSafe(|| {
            rep::features_from_joints(&T2M, &j, 0.002).map(|f| f.iter().all(|v| v.is_finite()))
        }));
        match out {
            Ok(Ok(finite)) => assert!(finite, "case {k}: non-finite features from finite joints"),
            Ok(Err(_)) => {}
            Err(_) => panic!("case {k} panicked on {j:?}"),
        }
    }
}
