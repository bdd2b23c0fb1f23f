//! A HumanML3D / KIT-ML dataset directory: normalisation, splits, and the item rules of
//! MDM / T2M (clip length bounds, sub-clip captions as their own items).

pub mod batch;
pub mod cache;
pub mod check;
pub mod loader_bench;

use std::path::{Path, PathBuf};

use crate::io::npy;
use crate::io::texts::{self, Caption};
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// Longest motion a batch holds (frames); HumanML3D clips shorter than 200 frames fit after
/// rounding down to a multiple of 4.
pub const MAX_FRAMES: usize = 196;
/// Lengths are multiples of this many frames.
pub const UNIT_LENGTH: usize = 4;

/// An opened dataset root: its skeleton (from the feature width) and normalisation.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    pub skeleton: &'static Skeleton,
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
}

/// One training item: a span of a clip and the captions that describe it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ItemSpec {
    pub clip: String,
    /// First frame within the clip.
    pub start: usize,
    pub len: usize,
    pub captions: Vec<String>,
}

/// What a dataset directory holds, for messages about one that does not.
pub const LAYOUT: &str = "a dataset directory holds Mean.npy, Std.npy, new_joint_vecs/ID.npy, texts/ID.txt and train.txt, val.txt, test.txt (HumanML3D's layout; `diffkfc data synth --out DIR` makes one)";

impl Dataset {
    pub fn open(root: impl AsRef<Path>) -> Result<Dataset, DataError> {
        let root = root.as_ref().to_path_buf();
        let not_one =
            |why: &str| DataError::Invalid(format!("{}: {why}; {LAYOUT}", root.display()));
        if root.is_file() {
            return Err(not_one("is a file, not a dataset directory"));
        }
        if !root.is_dir() {
            return Err(not_one("dataset directory not found"));
        }
        if !root.join("Mean.npy").exists() {
            let empty = std::fs::read_dir(&root).map(|mut d| d.next().is_none()).unwrap_or(false);
            return Err(not_one(if empty {
                "the directory is empty"
            } else {
                "no Mean.npy: not a dataset directory"
            }));
        }
        let (mean, std) = read_normalisation(&root, None)?;
        let skeleton = match mean.len() {
            263 => &crate::T2M,
            251 => &crate::KIT,
            n => {
                return Err(DataError::Npy {
                    path: root.join("Mean.npy"),
                    msg: format!("width {n} is neither HumanML3D (263) nor KIT-ML (251)"),
                })
            }
        };
        Ok(Dataset { root, skeleton, mean, std })
    }

    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Shortest clip kept (T2M: 40 frames, KIT: 24).
    pub fn min_frames(&self) -> usize {
        if self.skeleton.name == "kit" {
            24
        } else {
            40
        }
    }

    pub fn motion_path(&self, id: &str) -> PathBuf {
        self.root.join("new_joint_vecs").join(format!("{id}.npy"))
    }

    pub fn text_path(&self, id: &str) -> PathBuf {
        self.root.join("texts").join(format!("{id}.txt"))
    }

    /// Ids listed in `<split>.txt`.
    pub fn split_ids(&self, split: &str) -> Result<Vec<String>, DataError> {
        let p = self.root.join(format!("{split}.txt"));
        let text =
            std::fs::read_to_string(&p).map_err(|e| DataError::Io { path: p.clone(), err: e })?;
        Ok(text.lines().map(str::trim).filter(|l| !l.is_empty()).map(String::from).collect())
    }

    /// Items of one clip of `frames` frames under MDM's rules: the whole clip with its whole-clip
    /// captions if min <= T < 200, and each tagged caption's span as its own item.
    pub fn items_of_clip(&self, id: &str, frames: usize, captions: &[Caption]) -> Vec<ItemSpec> {
        let fps = self.skeleton.fps;
        let ok = |n: usize| n >= self.min_frames() && n < 200;
        let mut out = Vec::new();
        let whole: Vec<String> =
            captions.iter().filter(|c| c.whole_clip()).map(|c| c.text.clone()).collect();
        for c in captions.iter().filter(|c| !c.whole_clip()) {
            let s = (c.start * fps) as usize;
            let e = ((c.end * fps) as usize).min(frames);
            if e > s && ok(e - s) {
                out.push(ItemSpec {
                    clip: id.to_string(),
                    start: s,
                    len: e - s,
                    captions: vec![c.text.clone()],
                });
            }
        }
        if !whole.is_empty() && ok(frames) {
            out.insert(
                0,
                ItemSpec { clip: id.to_string(), start: 0, len: frames, captions: whole },
            );
        }
        out
    }

    /// Normalise a row-major (T, D) slice in place.
    pub fn normalise(&self, x: &mut [f32]) {
        normalise(x, &self.mean, &self.std);
    }

    /// Undo `normalise`.
    pub fn denormalise(&self, x: &mut [f32]) {
        denormalise(x, &self.mean, &self.std);
    }
}

/// `Mean.npy` and `Std.npy` of `dir` (a dataset root or a run directory): vectors of one width
/// (`width` when given), the mean finite, every std finite and > 0.
pub fn read_normalisation(
    dir: &Path,
    width: Option<usize>,
) -> Result<(Vec<f32>, Vec<f32>), DataError> {
    let read_vec = |name: &str, want: Option<usize>| -> Result<Vec<f32>, DataError> {
        let p = dir.join(name);
        let a = npy::read_f32(&p)?;
        if a.ndim() != 1 {
            return Err(DataError::Npy {
                path: p,
                msg: format!("expected a vector, got shape {:?}", a.shape),
            });
        }
        if let Some(w) = want.filter(|&w| w != a.data.len()) {
            return Err(DataError::Npy {
                path: p,
                msg: format!("{} values, expected {w}", a.data.len()),
            });
        }
        Ok(a.data)
    };
    let mean = read_vec("Mean.npy", width)?;
    let std = read_vec("Std.npy", width)?;
    if std.len() != mean.len() {
        return Err(DataError::Npy {
            path: dir.join("Std.npy"),
            msg: format!("width {} differs from Mean.npy ({})", std.len(), mean.len()),
        });
    }
    if let Some(i) = mean.iter().position(|m| !m.is_finite()) {
        return Err(DataError::Npy {
            path: dir.join("Mean.npy"),
            msg: format!("entry {i} is {} (not finite)", mean[i]),
        });
    }
    if let Some(i) = std.iter().position(|&s| !(s.is_finite() && s > 0.0)) {
        return Err(DataError::Npy {
            path: dir.join("Std.npy"),
            msg: format!("entry {i} is {} (must be > 0)", std[i]),
        });
    }
    Ok((mean, std))
}

/// Z-normalise row-major rows of width `mean.len()` in place.
pub fn normalise(x: &mut [f32], mean: &[f32], std: &[f32]) {
    for row in x.chunks_mut(mean.len()) {
        for ((v, m), s) in row.iter_mut().zip(mean).zip(std) {
            *v = (*v - m) / s;
        }
    }
}

/// Undo z-normalisation of row-major rows of width `mean.len()` in place.
pub fn denormalise(x: &mut [f32], mean: &[f32], std: &[f32]) {
    for row in x.chunks_mut(mean.len()) {
        for ((v, m), s) in row.iter_mut().zip(mean).zip(std) {
            *v = *v * s + m;
        }
    }
}

/// Read a clip's captions, failing on unreadable files or unparsable lines.
pub fn read_captions(path: &Path) -> Result<Vec<Caption>, DataError> {
    let (caps, errs) =
        texts::parse_file(path).map_err(|e| DataError::Io { path: path.to_path_buf(), err: e })?;
    if let Some(e) = errs.first() {
        return Err(DataError::Npy { path: path.to_path_buf(), msg: e.clone() });
    }
    if caps.is_empty() {
        return Err(DataError::Npy { path: path.to_path_buf(), msg: "no captions".into() });
    }
    Ok(caps)
}

/// Choose the training crop of an item of `len` frames: the length rounded down to a
/// multiple of 4 (one unit shorter with probability 1/3), capped at 196, and a random start.
pub fn crop(len: usize, rng: &mut crate::rng::Rng) -> (usize, usize) {
    let units = len / UNIT_LENGTH;
    let units = if rng.below(3) == 2 && units > 1 { units - 1 } else { units };
    let m = (units * UNIT_LENGTH).min(MAX_FRAMES);
    let start = rng.below(len - m + 1);
    (start, m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ds() -> Dataset {
        Dataset {
            root: PathBuf::new(),
            skeleton: &crate::T2M,
            mean: vec![0.0; 263],
            std: vec![1.0; 263],
        }
    }

    fn cap(text: &str, s: f64, e: f64) -> Caption {
        Caption { text: text.into(), tokens: vec![], start: s, end: e }
    }

    #[test]
    fn item_rules() {
        let d = ds();
        let caps = [
            cap("a", 0.0, 0.0),
            cap("b", 0.0, 0.0),
            cap("c", 1.0, 4.0),
            cap("d", 0.0, 1.0),
            cap("e", 2.0, 20.0),
        ];
        let items = d.items_of_clip("x", 150, &caps);
        // whole clip with a and b; c spans frames 20..80; d is 20 frames (too short); e clips to 40..150.
        assert_eq!(
            items[0],
            ItemSpec {
                clip: "x".into(),
                start: 0,
                len: 150,
                captions: vec!["a".into(), "b".into()]
            }
        );
        assert_eq!(
            items[1],
            ItemSpec { clip: "x".into(), start: 20, len: 60, captions: vec!["c".into()] }
        );
        assert_eq!(
            items[2],
            ItemSpec { clip: "x".into(), start: 40, len: 110, captions: vec!["e".into()] }
        );
        assert_eq!(items.len(), 3);
        // Too long or too short whole clips are dropped; their sub-clips may stay.
        assert!(d.items_of_clip("y", 200, &caps[..2]).is_empty());
        assert!(d.items_of_clip("y", 39, &caps[..2]).is_empty());
        assert_eq!(d.items_of_clip("y", 250, &caps[2..3]).len(), 1);
    }

    #[test]
    fn crop_lengths_follow_mdm() {
        let mut rng = crate::rng::Rng::new(3);
        let mut long = 0;
        for _ in 0..3000 {
            let (s, m) = crop(199, &mut rng);
            assert!(m == 196 || m == 192, "{m}");
            assert!(s + m <= 199);
            long += (m == 196) as usize;
        }
        // Two thirds keep the full length.
        assert!((1850..2150).contains(&long), "{long}");
        let (s, m) = crop(41, &mut rng);
        assert!(m == 40 || m == 36);
        assert!(s + m <= 41);
    }
}
