//! Writing a synthetic set: every clip's features, joints and captions, the splits, the
//! normalisation and the manifest, built in a staging folder and renamed into place.

use std::path::{Path, PathBuf};

use serde_json::json;

use crate::{captions, clip_of, ClipMeta, SynthSpec};
use diffkfc_data::io::texts::Caption;
use diffkfc_data::motion::representation::{self as rep, Layout};
use diffkfc_data::{io::npy, DataError, T2M};

/// Split of the `k`-th clip of a (pattern, first action) group: about 75% train, 5% val,
/// 20% test, and every group with two or more clips in both train and test.
fn split_of(k: usize) -> &'static str {
    match k % 20 {
        1 | 6 | 11 | 16 => "test",
        3 => "val",
        _ => "train",
    }
}

pub struct SynthSummary {
    pub clips: usize,
    pub frames: usize,
    pub out: PathBuf,
}

/// Write the synthetic dataset `spec` to `out` (built in a temporary sibling directory and
/// renamed at the end). `progress(done, total)`.
pub fn write_dataset(
    out: &Path,
    spec: &SynthSpec,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<SynthSummary, DataError> {
    let (n, seed) = (spec.clips, spec.seed);
    let tmp = staging_dir(out)?;
    let dim = T2M.feature_dim();
    let Written { mut metas, sum, sq, frames } = write_clips(&tmp, spec, threads, progress)?;
    write_texts_and_splits(&tmp, &mut metas)?;
    let (mean, std) = mean_std(&sum, &sq, frames);
    npy::write(tmp.join("Mean.npy"), &[dim], &mean)?;
    npy::write(tmp.join("Std.npy"), &[dim], &std)?;
    let mut manifest = json!({"generator": "diffkfc data synth", "version": env!("CARGO_PKG_VERSION"), "seed": seed, "body": spec.body.name(), "clips": metas});
    if spec.vary > 0.0 {
        // Only where set, so sets without variation keep their bytes.
        manifest["vary"] = json!(spec.vary);
    }
    diffkfc_data::write_atomic(
        &tmp.join("manifest.json"),
        &serde_json::to_vec_pretty(&manifest).expect("json"),
    )?;
    diffkfc_data::io::ownership::Output::Dataset.mark(&tmp)?;
    if out.exists() {
        std::fs::remove_dir(out).map_err(io_at(out))?;
    }
    std::fs::rename(&tmp, out).map_err(io_at(out))?;
    Ok(SynthSummary { clips: n, frames, out: out.to_path_buf() })
}

fn io_at(p: &Path) -> impl Fn(std::io::Error) -> DataError + '_ {
    move |err| DataError::Io { path: p.to_path_buf(), err }
}

/// The hidden sibling `.NAME.partial<PID>` the set is built in (`out` must be new or empty);
/// what dead runs left beside it is removed first (up to hundreds of MB each).
fn staging_dir(out: &Path) -> Result<PathBuf, DataError> {
    if out.exists() && std::fs::read_dir(out).map(|mut d| d.next().is_some()).unwrap_or(true) {
        let holds = diffkfc_data::io::ownership::found(out)
            .map_or(String::new(), |k| format!(" (it holds {})", k.noun()));
        return Err(DataError::Invalid(format!(
            "{}: already exists and is not empty{holds}; data synth writes a new dataset into a new or empty folder",
            out.display()
        )));
    }
    let name =
        out.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "synth".into());
    let tmp = out.with_file_name(format!(".{name}.partial{}", std::process::id()));
    let parent = tmp.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    diffkfc_data::io::atomic::remove_dead_leftovers(parent, &format!(".{name}"), "partial");
    let _ = std::fs::remove_dir_all(&tmp);
    for sub in ["new_joint_vecs", "new_joints", "texts"] {
        std::fs::create_dir_all(tmp.join(sub)).map_err(io_at(&tmp))?;
    }
    Ok(tmp)
}

/// What the clips' files add up to: their metadata in index order, per-feature sums and sums
/// of squares, and the frame count.
struct Written {
    metas: Vec<ClipMeta>,
    sum: Vec<f64>,
    sq: Vec<f64>,
    frames: usize,
}

/// Clip `i`'s features and joints in `tmp`: its manifest entry, its features' per-channel sums
/// and sums of squares, and its frame count.
fn write_clip(
    tmp: &Path,
    spec: &SynthSpec,
    i: usize,
) -> Result<(ClipMeta, Vec<f64>, Vec<f64>, usize), DataError> {
    let dim = T2M.feature_dim();
    let (c, feats) = clip_of(spec, i);
    let t = feats.len() / dim;
    let fdata: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
    let rec = rep::recover_from_ric(&T2M, &fdata);
    npy::write(tmp.join(format!("new_joint_vecs/{}.npy", c.meta.id)), &[t, dim], &feats)?;
    npy::write(
        tmp.join(format!("new_joints/{}.npy", c.meta.id)),
        &[t, 22, 3],
        &rep::joints_to_f32(&rec),
    )?;
    let mut sum = vec![0.0; dim];
    let mut sq = vec![0.0; dim];
    for row in fdata.chunks(dim) {
        for k in 0..dim {
            sum[k] += row[k];
            sq[k] += row[k] * row[k];
        }
    }
    Ok((c.meta, sum, sq, t))
}

/// Every clip's features and joints in `tmp`, `threads` at a time (each clip depends only on
/// (seed, index), so the bytes do not depend on the thread count).
fn write_clips(
    tmp: &Path,
    spec: &SynthSpec,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Written, DataError> {
    let dim = T2M.feature_dim();
    let n = spec.clips;
    let done = std::sync::atomic::AtomicUsize::new(0);
    type Out = (ClipMeta, Vec<f64>, Vec<f64>, usize);
    let work = |i: usize| -> Result<Out, DataError> {
        let out = write_clip(tmp, spec, i)?;
        let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(d, n);
        Ok(out)
    };
    let threads = threads.max(1);
    let mut results: Vec<Option<Result<Out, DataError>>> = (0..n).map(|_| None).collect();
    std::thread::scope(|s| {
        let chunks: Vec<_> = results.chunks_mut(n.div_ceil(threads).max(1)).enumerate().collect();
        let per = n.div_ceil(threads).max(1);
        for (ci, chunk) in chunks {
            let work = &work;
            s.spawn(move || {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    *slot = Some(work(ci * per + k));
                }
            });
        }
    });
    let mut w = Written {
        metas: Vec::with_capacity(n),
        sum: vec![0.0; dim],
        sq: vec![0.0; dim],
        frames: 0,
    };
    for r in results {
        let (m, s1, s2, t) = r.expect("every clip generated")?;
        for k in 0..dim {
            w.sum[k] += s1[k];
            w.sq[k] += s2[k];
        }
        w.frames += t;
        w.metas.push(m);
    }
    Ok(w)
}

/// The clips' caption files and the split lists, splits balanced within each (pattern, first
/// action) group.
fn write_texts_and_splits(tmp: &Path, metas: &mut [ClipMeta]) -> Result<(), DataError> {
    let mut counts = std::collections::HashMap::new();
    for m in metas.iter_mut() {
        let k = counts.entry((m.pattern as u8, m.actions[0].action)).or_insert(0usize);
        m.split = split_of(*k);
        *k += 1;
    }
    for m in metas.iter() {
        let lines: Vec<String> = m
            .captions
            .iter()
            .map(|c| {
                Caption { text: c.clone(), tokens: captions::tokens(c), start: 0.0, end: 0.0 }
                    .to_line()
            })
            .collect();
        diffkfc_data::write_atomic(
            &tmp.join(format!("texts/{}.txt", m.id)),
            (lines.join("\n") + "\n").as_bytes(),
        )?;
    }
    for split in ["train", "val", "test"] {
        let ids: Vec<&str> =
            metas.iter().filter(|m| m.split == split).map(|m| m.id.as_str()).collect();
        diffkfc_data::write_atomic(
            &tmp.join(format!("{split}.txt")),
            (ids.join("\n") + "\n").as_bytes(),
        )?;
    }
    Ok(())
}

/// Per-dim mean, and std averaged within each feature group as HumanML3D does.
pub fn mean_std(sum: &[f64], sq: &[f64], frames: usize) -> (Vec<f32>, Vec<f32>) {
    let nf = frames.max(1) as f64;
    let mean: Vec<f64> = sum.iter().map(|s| s / nf).collect();
    let std: Vec<f64> =
        sq.iter().zip(&mean).map(|(q, m)| (q / nf - m * m).max(0.0).sqrt()).collect();
    let mut grouped = std.clone();
    for (_, range) in Layout::of(&T2M).groups() {
        let g = std[range.clone()].iter().sum::<f64>() / range.len() as f64;
        grouped[range].iter_mut().for_each(|v| *v = g.max(1e-4));
    }
    (mean.iter().map(|&v| v as f32).collect(), grouped.iter().map(|&v| v as f32).collect())
}
