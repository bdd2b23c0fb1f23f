//! Bounded fuzzing of the readers of untrusted files: valid inputs mutated at random (bit flips,
//! byte and token replacement, truncation, duplication, digit runs that overflow), each fed to
//! the reader inside `catch_unwind`. Every input must give Ok or a clean error: no panic, and no
//! call slower than a second (`diffkfc_data::testing::fuzz`).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use diffkfc_data::rng::Rng;
use diffkfc_data::testing::fuzz::{cases, fuzz};
use diffkfc_data::{io::npy, io::rig, motion::magnitude, motion::representation as rep, T2M};

fn walk(frames: usize) -> rep::Joints {
    let pose = T2M
        .target_offsets()
        .map(|o| {
            rep::forward_kinematics(
                &T2M,
                &[vec![diffkfc_data::motion::quat::IDENTITY; 22]],
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
        let Ok(j) = rig::read(&T2M, text, &Default::default()) else {
            return false;
        };
        // What the readers accept (the magnitude rule passed) is finite joints.
        if magnitude::check_joints(&T2M, &j).is_ok() {
            assert!(
                j.iter().flatten().flatten().all(|v| v.is_finite()),
                "accepted non-finite joints"
            );
        }
        true
    });
}

#[test]
fn accepted_features_give_finite_joints() {
    // Feature files of any magnitude, 1e-3 to 1e38, in one channel group or all.
    let mut r = Rng::new(3);
    let d = T2M.feature_dim();
    let (mut accepted, mut refused) = (0, 0);
    for k in 0..cases() / 20 {
        let frames = 2 + r.below(40);
        let scale = 10f64.powf(-3.0 + 41.0 * r.uniform());
        let one = r.below(2) == 0;
        let c = r.below(d);
        let f: Vec<f32> = (0..frames * d)
            .map(|i| {
                let v = r.normal() * 0.1;
                (if !one || i % d == c { v * scale } else { v }) as f32
            })
            .collect();
        if f.iter().any(|v| !v.is_finite()) || magnitude::check_features(&T2M, &f).is_err() {
            refused += 1;
            continue;
        }
        accepted += 1;
        let j = rep::recover_from_ric(&T2M, &f.iter().map(|&v| v as f64).collect::<Vec<_>>());
        assert!(j.iter().flatten().flatten().all(|v| v.is_finite()), "case {k}: non-finite joints");
    }
    assert!(accepted > 0 && refused > 0, "{accepted} accepted, {refused} refused");
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
