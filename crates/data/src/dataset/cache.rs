//! The packed cache of a split: every clip's raw features in one contiguous f32 file,
//! memory-mapped, plus a JSON index of clips, items and the source files' sizes and times.
//! Resident memory stays bounded by what a batch touches; a second start only stats files.
//! A change to any source file (or to Mean/Std) rebuilds the cache.

use std::io::Write;
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use serde::{Deserialize, Serialize};

use crate::dataset::{read_captions, Dataset, ItemSpec};
use crate::io::motion_file::first_non_finite;
use crate::io::npy;
use crate::io::texts::Caption;
use crate::DataError;

const FORMAT: u32 = 2;

/// A source file as the cache saw it. The inode change time moves on every write, and no tool
/// sets it back (`cp -p`, `touch -r` and rsync restore the modification time only).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Source {
    path: String,
    size: u64,
    mtime_ns: u128,
    ctime_ns: i128,
    inode: u64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClipEntry {
    pub id: String,
    /// Offset in frames into the packed file.
    pub offset: usize,
    pub frames: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct Index {
    format: u32,
    dim: usize,
    total_frames: usize,
    sources: Vec<Source>,
    clips: Vec<ClipEntry>,
    items: Vec<ItemSpec>,
    /// Clips left out, with the reason (see `diffkfc data check`).
    skipped: Vec<(String, String)>,
}

/// A split's items over memory-mapped features.
pub struct PackedSplit {
    pub split: String,
    pub dim: usize,
    pub clips: Vec<ClipEntry>,
    pub items: Vec<ItemSpec>,
    pub skipped: Vec<(String, String)>,
    clip_of: std::collections::HashMap<String, usize>,
    map: Option<Mmap>,
    /// Whether this open built the cache (false: reused).
    pub built: bool,
}

fn source(path: &Path) -> Result<Source, DataError> {
    let md =
        std::fs::metadata(path).map_err(|e| DataError::Io { path: path.to_path_buf(), err: e })?;
    let mtime_ns = md
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    use std::os::unix::fs::MetadataExt;
    Ok(Source {
        path: path.to_string_lossy().into_owned(),
        size: md.len(),
        mtime_ns,
        ctime_ns: md.ctime() as i128 * 1_000_000_000 + md.ctime_nsec() as i128,
        inode: md.ino(),
    })
}

/// Source files a split depends on, in a fixed order (missing files are left out; the build
/// records them as skipped, and their later appearance changes the list).
fn sources(ds: &Dataset, split: &str, ids: &[String]) -> Vec<Source> {
    let mut paths = vec![
        ds.root.join("Mean.npy"),
        ds.root.join("Std.npy"),
        ds.root.join(format!("{split}.txt")),
    ];
    for id in ids {
        paths.push(ds.motion_path(id));
        paths.push(ds.text_path(id));
    }
    paths.iter().filter_map(|p| source(p).ok()).collect()
}

/// Where a dataset's caches live by default.
pub fn default_cache_dir(ds: &Dataset) -> PathBuf {
    ds.root.join(".diffkfc-cache")
}

impl PackedSplit {
    /// Open the cache of `split`, building it first if it is missing or stale.
    /// `progress(done, total)` is called while building.
    pub fn open(
        ds: &Dataset,
        split: &str,
        cache_dir: &Path,
        mut progress: impl FnMut(usize, usize),
    ) -> Result<PackedSplit, DataError> {
        let ids = ds.split_ids(split)?;
        let srcs = sources(ds, split, &ids);
        let index_path = cache_dir.join(format!("{split}.index.json"));
        let data_path = cache_dir.join(format!("{split}.f32"));
        let mut built = false;
        let index = match read_index(&index_path) {
            Some(ix)
                if ix.format == FORMAT
                    && ix.dim == ds.dim()
                    && ix.sources == srcs
                    && data_ok(&data_path, &ix) =>
            {
                ix
            }
            _ => {
                built = true;
                build(ds, &ids, srcs, cache_dir, &index_path, &data_path, &mut progress)?
            }
        };
        let map = if index.total_frames > 0 {
            let f = std::fs::File::open(&data_path)
                .map_err(|e| DataError::Io { path: data_path.clone(), err: e })?;
            // SAFETY: the file is ours, written once and renamed into place; it is not modified
            // while mapped (a rebuild writes a new file and renames over it).
            Some(
                unsafe { Mmap::map(&f) }
                    .map_err(|e| DataError::Io { path: data_path.clone(), err: e })?,
            )
        } else {
            None
        };
        let clip_of = index.clips.iter().enumerate().map(|(i, c)| (c.id.clone(), i)).collect();
        Ok(PackedSplit {
            split: split.to_string(),
            dim: index.dim,
            clips: index.clips,
            items: index.items,
            skipped: index.skipped,
            clip_of,
            map,
            built,
        })
    }

    /// Raw (un-normalised) features of frames [start, start+len) of a clip, row-major.
    pub fn clip_frames(&self, clip: &str, start: usize, len: usize) -> &[f32] {
        let c = &self.clips[self.clip_of[clip]];
        assert!(start + len <= c.frames, "frames {start}+{len} beyond clip {clip} ({})", c.frames);
        let map = self.map.as_ref().expect("empty cache");
        let bytes =
            &map[(c.offset + start) * self.dim * 4..(c.offset + start + len) * self.dim * 4];
        // The mapping is page-aligned and every offset a multiple of 4 bytes.
        let (pre, floats, _) = unsafe { bytes.align_to::<f32>() };
        assert!(pre.is_empty());
        floats
    }

    /// Raw features of an item.
    pub fn item_frames(&self, i: usize) -> &[f32] {
        let it = &self.items[i];
        self.clip_frames(&it.clip, it.start, it.len)
    }

    pub fn total_frames(&self) -> usize {
        self.clips.iter().map(|c| c.frames).sum()
    }
}

fn read_index(path: &Path) -> Option<Index> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

fn data_ok(path: &Path, ix: &Index) -> bool {
    let want = (ix.total_frames * ix.dim * 4) as u64;
    std::fs::metadata(path).map(|m| m.len() == want).unwrap_or(want == 0)
}

/// A clip's captions and features, checked: its shape, finite and physical values.
fn load_clip(ds: &Dataset, id: &str) -> Result<(Vec<Caption>, npy::Array<f32>), DataError> {
    let caps = read_captions(&ds.text_path(id))?;
    let mp = ds.motion_path(id);
    let a = npy::read_f32(&mp)?;
    if a.ndim() != 2 || a.shape[1] != ds.dim() {
        return Err(DataError::Npy {
            path: mp,
            msg: format!("expected shape (T, {}), got {:?}", ds.dim(), a.shape),
        });
    }
    if let Some((r, c)) = first_non_finite(&a.data, ds.dim()) {
        return Err(DataError::Npy {
            path: mp,
            msg: format!("NaN or infinite value at frame {r}, feature {c}"),
        });
    }
    crate::motion::magnitude::check_features(ds.skeleton, &a.data)
        .map_err(|e| DataError::Npy { path: mp.clone(), msg: e.to_string() })?;
    Ok((caps, a))
}

/// Why a readable clip gives no training item: its length, or its captions' spans.
fn no_item_reason(ds: &Dataset, frames: usize, caps: &[Caption]) -> String {
    let (min, fps) = (ds.min_frames(), ds.skeleton.fps);
    let spans = caps.iter().filter(|c| !c.whole_clip()).count();
    let why = if caps.iter().any(|c| c.whole_clip()) {
        format!("its {frames} frames are outside [{min}, 200)")
    } else {
        format!("it has no whole-clip caption ({frames} frames)")
    };
    let also = if spans > 0 {
        format!("; its {spans} sub-clip caption span(s) run past its end or are not {min} to 199 frames long at {fps} fps")
    } else {
        String::new()
    };
    format!("no item: {why}{also}")
}

fn build(
    ds: &Dataset,
    ids: &[String],
    srcs: Vec<Source>,
    dir: &Path,
    index_path: &Path,
    data_path: &Path,
    progress: &mut impl FnMut(usize, usize),
) -> Result<Index, DataError> {
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |e| DataError::Io { path: p, err: e }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    if let Some(name) = data_path.file_name() {
        crate::io::atomic::remove_stale_temps(dir, &name.to_string_lossy());
    }
    let tmp = data_path.with_extension(format!("f32.tmp{}", std::process::id()));
    let mut out = std::io::BufWriter::new(std::fs::File::create(&tmp).map_err(io(&tmp))?);
    let (mut clips, mut items, mut skipped) = (Vec::new(), Vec::new(), Vec::new());
    let mut offset = 0usize;
    for (k, id) in ids.iter().enumerate() {
        progress(k, ids.len());
        let (caps, a) = match load_clip(ds, id) {
            Ok(x) => x,
            Err(e) => {
                skipped.push((id.clone(), e.to_string()));
                continue;
            }
        };
        let frames = a.shape[0];
        let its = ds.items_of_clip(id, frames, &caps);
        if its.is_empty() {
            skipped.push((id.clone(), no_item_reason(ds, frames, &caps)));
            continue;
        }
        for v in &a.data {
            out.write_all(&v.to_le_bytes()).map_err(io(&tmp))?;
        }
        clips.push(ClipEntry { id: id.clone(), offset, frames });
        items.extend(its);
        offset += frames;
    }
    progress(ids.len(), ids.len());
    out.into_inner().map_err(|e| e.into_error()).and_then(|f| f.sync_all()).map_err(io(&tmp))?;
    std::fs::rename(&tmp, data_path).map_err(io(data_path))?;
    let index = Index {
        format: FORMAT,
        dim: ds.dim(),
        total_frames: offset,
        sources: srcs,
        clips,
        items,
        skipped,
    };
    let bytes = serde_json::to_vec(&index).expect("index serialises");
    crate::write_atomic(index_path, &bytes)?;
    Ok(index)
}
