//! `diffkfc data check`: validate every file of a dataset and gather statistics. It never stops
//! at the first problem: users fixing a 30k-file dataset want the whole list at once.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::Serialize;

use crate::dataset::Dataset;
use crate::io::motion_file::first_non_finite;
use crate::DataError;
use crate::{io::npy, io::texts};

pub const SPLITS: [&str; 3] = ["train", "val", "test"];

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Problem {
    pub file: String,
    pub problem: String,
}

/// Normalised values (|x - Mean| / Std) this large are listed: a frame with one dominates its
/// batch's loss. A fast synthetic spin's facing direction flips for a frame (a yaw rate of
/// 100-190 std, turning every later frame of the recovered body): one such clip in the
/// reference set's validation split takes its validation loss from 0.12 to 1.57.
pub const OUTLIER_STDS: f64 = 50.0;
/// The largest outliers listed.
const MAX_OUTLIERS: usize = 10;

/// A feature value far outside the dataset's distribution.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Outlier {
    pub file: String,
    pub frame: usize,
    pub feature: usize,
    pub group: &'static str,
    /// |x - Mean| / Std.
    pub stds: f64,
}

#[derive(Clone, Debug, Serialize, Default)]
pub struct SplitStats {
    pub split: String,
    pub ids: usize,
    /// Clips whose motion and text are both usable.
    pub clips: usize,
    /// Training items under the MDM rules (whole clips and tagged sub-clips).
    pub items: usize,
    pub frames: usize,
    pub hours: f64,
    pub captions: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct CheckReport {
    pub root: String,
    pub skeleton: String,
    pub dim: usize,
    pub problems: Vec<Problem>,
    /// The largest values at least [`OUTLIER_STDS`] from the mean, largest first; not problems.
    pub outliers: Vec<Outlier>,
    pub splits: Vec<SplitStats>,
    pub distinct_words: usize,
    /// (first frame, last frame + 1, clips) in bins of 20 frames; the last bin is open.
    pub length_histogram: Vec<(usize, Option<usize>, usize)>,
}

impl CheckReport {
    pub fn ok(&self) -> bool {
        self.problems.is_empty()
    }

    /// Human-readable report: problems (one per line) then statistics.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        for p in &self.problems {
            s += &format!("{}: {}\n", p.file, p.problem);
        }
        for o in &self.outliers {
            s += &format!(
                "{}: frame {}, feature {} ({}): {:.0} std from the mean, a loss it dominates\n",
                o.file, o.frame, o.feature, o.group, o.stds
            );
        }
        s +=
            &format!("dataset {} ({} skeleton, {} features)\n", self.root, self.skeleton, self.dim);
        s += &format!(
            "{:<6} {:>7} {:>7} {:>7} {:>9} {:>7} {:>8}\n",
            "split", "ids", "clips", "items", "frames", "hours", "captions"
        );
        for st in &self.splits {
            s += &format!(
                "{:<6} {:>7} {:>7} {:>7} {:>9} {:>7.2} {:>8}\n",
                st.split, st.ids, st.clips, st.items, st.frames, st.hours, st.captions
            );
        }
        s += &format!("distinct words: {}\nclip lengths (frames):\n", self.distinct_words);
        let max = self.length_histogram.iter().map(|b| b.2).max().unwrap_or(0).max(1);
        for (lo, hi, n) in &self.length_histogram {
            let label = match hi {
                Some(h) => format!("{lo:>4}-{:<4}", h - 1),
                None => format!("{lo:>4}+    "),
            };
            s += &format!("  {label} {n:>7} {}\n", "#".repeat(n * 40 / max));
        }
        s += &if self.ok() {
            "OK: no problems found\n".to_string()
        } else {
            format!("{} problem(s) found\n", self.problems.len())
        };
        s
    }
}

/// Check a dataset directory.
/// The report of a root that is not a dataset at all.
fn unreadable(root: &Path, e: DataError) -> CheckReport {
    CheckReport {
        root: root.display().to_string(),
        skeleton: "unknown".into(),
        dim: 0,
        problems: vec![Problem { file: root.display().to_string(), problem: e.to_string() }],
        outliers: vec![],
        splits: vec![],
        distinct_words: 0,
        length_histogram: vec![],
    }
}

/// A caption's words, lower-cased.
fn words_of(text: &str) -> impl Iterator<Item = String> + '_ {
    text.split(|ch: char| !ch.is_alphanumeric()).filter(|w| !w.is_empty()).map(str::to_lowercase)
}

pub fn check(root: &Path, mut progress: impl FnMut(usize, usize)) -> CheckReport {
    let ds = match Dataset::open(root) {
        Ok(ds) => ds,
        Err(e) => return unreadable(root, e),
    };
    let dim = ds.dim();
    let mut problems = Vec::new();
    let mut outliers = Vec::new();
    let splits = read_splits(&ds, root, &mut problems);
    let mut report = |file: &Path, problem: String| {
        problems.push(Problem { file: file.display().to_string(), problem })
    };
    let total: usize = splits.iter().map(|s| s.1.len()).sum();
    // Per id: (frames, captions) when usable; checked once even if listed in several splits.
    let mut seen: BTreeMap<String, Option<(usize, Vec<texts::Caption>)>> = BTreeMap::new();
    let mut words = BTreeSet::new();
    let mut hist = [0usize; 11];
    let mut stats = Vec::new();
    let mut done = 0;
    for (split, ids) in &splits {
        let mut st = SplitStats { split: split.clone(), ids: ids.len(), ..Default::default() };
        for id in ids {
            progress(done, total);
            done += 1;
            let entry = seen.entry(id.clone()).or_insert_with(|| {
                let frames = check_motion(&ds, &ds.motion_path(id), &mut report, &mut outliers);
                let caps = check_text(&ds.text_path(id), &mut report);
                if let Some(f) = frames {
                    hist[(f / 20).min(10)] += 1;
                }
                Some((frames?, caps?))
            });
            let Some((frames, caps)) = entry else {
                continue;
            };
            words.extend(caps.iter().flat_map(|c| words_of(&c.text)));
            st.clips += 1;
            st.frames += *frames;
            st.captions += caps.len();
            st.items += ds.items_of_clip(id, *frames, caps).len();
        }
        st.hours = st.frames as f64 / ds.skeleton.fps / 3600.0;
        stats.push(st);
    }
    progress(total, total);
    outliers.sort_by(|a: &Outlier, b| b.stds.total_cmp(&a.stds));
    outliers.truncate(MAX_OUTLIERS);
    CheckReport {
        root: root.display().to_string(),
        skeleton: ds.skeleton.name.to_string(),
        dim,
        problems,
        outliers,
        splits: stats,
        distinct_words: words.len(),
        length_histogram: length_histogram(&hist),
    }
}

/// Clip counts per 20 frames (the last bin open-ended) as (from, to, clips).
fn length_histogram(hist: &[usize; 11]) -> Vec<(usize, Option<usize>, usize)> {
    hist.iter().enumerate().map(|(i, &n)| (i * 20, (i < 10).then_some(i * 20 + 20), n)).collect()
}

/// Each split's ids; a split list that cannot be read is a problem.
fn read_splits(
    ds: &Dataset,
    root: &Path,
    problems: &mut Vec<Problem>,
) -> Vec<(String, Vec<String>)> {
    SPLITS
        .iter()
        .filter_map(|s| match ds.split_ids(s) {
            Ok(ids) => Some((s.to_string(), ids)),
            Err(e) => {
                problems.push(Problem {
                    file: root.join(format!("{s}.txt")).display().to_string(),
                    problem: format!("split list unreadable: {}", short(&e)),
                });
                None
            }
        })
        .collect()
}

/// An io error without the path (the report line already names the file).
fn short(e: &crate::DataError) -> String {
    match e {
        crate::DataError::Io { err, .. } => err.to_string(),
        crate::DataError::Npy { msg, .. } => msg.clone(),
        other => other.to_string(),
    }
}

fn check_motion(
    ds: &Dataset,
    path: &Path,
    report: &mut impl FnMut(&Path, String),
    outliers: &mut Vec<Outlier>,
) -> Option<usize> {
    let dim = ds.dim();
    let a = match npy::read_f32(path) {
        Ok(a) => a,
        Err(e) => {
            report(path, short(&e));
            return None;
        }
    };
    let mut ok = true;
    if a.ndim() != 2 || a.shape[1] != dim {
        report(path, format!("shape {:?}, expected (T, {dim}) to match Mean/Std", a.shape));
        return None;
    }
    if a.shape[0] < 2 {
        report(path, format!("{} frame(s), at least 2 needed", a.shape[0]));
        ok = false;
    }
    if let Some((r, c)) = first_non_finite(&a.data, dim) {
        report(path, format!("NaN or infinite value at frame {r}, feature {c}"));
        ok = false;
    } else if let Err(m) = crate::motion::magnitude::check_features(ds.skeleton, &a.data) {
        // The loader skips such a clip; training on it would go NaN.
        report(path, m.to_string());
        ok = false;
    }
    if ok {
        outliers.extend(largest_deviation(ds, path, &a.data));
    }
    ok.then_some(a.shape[0])
}

/// The value of `data` (T, D) farthest from the dataset's mean, in its standard deviations,
/// if at least [`OUTLIER_STDS`].
fn largest_deviation(ds: &Dataset, path: &Path, data: &[f32]) -> Option<Outlier> {
    let d = ds.dim();
    let stds = |(i, &x): (usize, &f32)| (i, ((x - ds.mean[i % d]) / ds.std[i % d]).abs() as f64);
    let (i, z) = data.iter().enumerate().map(stds).max_by(|a, b| a.1.total_cmp(&b.1))?;
    let layout = crate::motion::representation::Layout::of(ds.skeleton);
    (z >= OUTLIER_STDS).then(|| Outlier {
        file: path.display().to_string(),
        frame: i / d,
        feature: i % d,
        group: crate::motion::magnitude::feature_group(&layout, i % d),
        stds: z,
    })
}

fn check_text(path: &Path, report: &mut impl FnMut(&Path, String)) -> Option<Vec<texts::Caption>> {
    match texts::parse_file(path) {
        Err(e) => {
            report(path, e.to_string());
            None
        }
        Ok((caps, errs)) => {
            for e in &errs {
                report(path, e.clone());
            }
            if caps.is_empty() && errs.is_empty() {
                report(path, "no captions".into());
            }
            (errs.is_empty() && !caps.is_empty()).then_some(caps)
        }
    }
}
