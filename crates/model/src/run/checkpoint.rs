//! Checkpoints: model, EMA, Adam state, step and the resolved config in one safetensors file,
//! written to a temporary name and renamed, so a run killed at any moment leaves either the
//! previous checkpoint or the new one, never half of one. Tensors are stored by the parameter's
//! module path (`model/decoder.layers.0.ffn.weight`); files from before names (`model/0000`,
//! format 1) still load, by position.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use diffkfc_data::io::ownership::{self, Output};
use safetensors::tensor::{Dtype, TensorView};

use crate::error::{ModelError, Result};

#[derive(Clone, Debug)]
pub struct Checkpoint {
    pub step: usize,
    pub shapes: Vec<Vec<usize>>,
    pub model: Vec<Vec<f32>>,
    pub ema: Option<Vec<Vec<f32>>>,
    pub adam_step: u64,
    pub adam_m: Vec<Vec<f32>>,
    pub adam_v: Vec<Vec<f32>>,
    /// The resolved run config (JSON).
    pub config: String,
    pub seed: u64,
    /// Module path of every parameter, in the order of the vectors above (`params::names`);
    /// empty for checkpoints written before names, which are read by position.
    pub names: Vec<String>,
}

/// Tensors by name (format 2) and by position (format 1, read only).
const FORMAT: &str = "diffkfc-checkpoint-2";
const FORMAT_1: &str = "diffkfc-checkpoint-1";
/// Inference weights alone (`diffkfc model export`): no optimiser state, optionally f16.
const WEIGHTS_FORMAT: &str = "diffkfc-weights-2";
const WEIGHTS_FORMAT_1: &str = "diffkfc-weights-1";
/// File name of exported weights inside a model directory.
pub const WEIGHTS_FILE: &str = "model.safetensors";

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// `safetensors::serialize`, the header's keys then sorted: the crate writes its metadata in a
/// HashMap's order, which changes from one process to the next, and equal checkpoints should be
/// equal files. Readers find tensors by name and offset, so the order is free.
fn serialize(
    views: Vec<(String, TensorView)>,
    meta: HashMap<String, String>,
) -> std::result::Result<Vec<u8>, String> {
    let mut data = safetensors::serialize(views, Some(meta)).map_err(|e| e.to_string())?;
    let n = u64::from_le_bytes(data[..8].try_into().expect("8 bytes")) as usize;
    let mut header: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(&data[8..8 + n]).map_err(|e| e.to_string())?;
    if let Some(m) = header.get_mut("__metadata__") {
        let sorted: BTreeMap<String, String> =
            serde_json::from_value(m.take()).map_err(|e| e.to_string())?;
        *m = serde_json::to_value(sorted).map_err(|e| e.to_string())?;
    }
    let text = serde_json::to_vec(&header).map_err(|e| e.to_string())?;
    // The same entries in another order have the same length; the alignment padding stays.
    if text.len() > n {
        return Err(format!("sorted header of {} bytes exceeds the {n} written", text.len()));
    }
    data[8..8 + text.len()].copy_from_slice(&text);
    data[8 + text.len()..8 + n].fill(b' ');
    Ok(data)
}

/// Shapes and values of a checkpoint's parameters, in order.
type Tensors = (Vec<Vec<usize>>, Vec<Vec<f32>>);

/// The parameter names a named checkpoint's metadata lists, `n` of them.
fn stored_names(
    meta: &std::collections::HashMap<String, String>,
    n: usize,
) -> std::result::Result<Vec<String>, String> {
    let v: Vec<String> = meta
        .get("names")
        .and_then(|t| serde_json::from_str(t).ok())
        .ok_or_else(|| "metadata 'names' missing".to_string())?;
    if v.len() != n {
        return Err(format!("{} names for {n} parameters", v.len()));
    }
    Ok(v)
}

/// Little-endian f32 bytes (a safetensors F32 tensor's data) as values.
pub(crate) fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

/// Shape and values (as f32) of tensor `name`, stored as F32 or F16; errors name `path`.
fn tensor_values(
    st: &safetensors::SafeTensors,
    name: &str,
    path: &Path,
) -> Result<(Vec<usize>, Vec<f32>)> {
    let t =
        st.tensor(name).map_err(|_| ModelError::file(path, format!("tensor {name} missing")))?;
    let values = match t.dtype() {
        Dtype::F32 => f32s(t.data()),
        Dtype::F16 => t
            .data()
            .chunks_exact(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect(),
        other => {
            return Err(ModelError::file(
                path,
                format!("tensor {name} is {other:?}; expected F32 or F16"),
            ))
        }
    };
    Ok((t.shape().to_vec(), values))
}

impl Checkpoint {
    pub fn file_name(step: usize) -> String {
        format!("ckpt-{step:08}.safetensors")
    }

    pub fn save(&self, dir: &Path) -> Result<PathBuf> {
        let mut owned: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
        for (i, shape) in self.shapes.iter().enumerate() {
            let key = self.key(i);
            owned.push((format!("model/{key}"), shape.clone(), bytes(&self.model[i])));
            owned.push((format!("adam_m/{key}"), shape.clone(), bytes(&self.adam_m[i])));
            owned.push((format!("adam_v/{key}"), shape.clone(), bytes(&self.adam_v[i])));
            if let Some(e) = &self.ema {
                owned.push((format!("ema/{key}"), shape.clone(), bytes(&e[i])));
            }
        }
        let views: Vec<(String, TensorView)> = owned
            .iter()
            .map(|(n, s, b)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).expect("view")))
            .collect();
        let meta = HashMap::from([
            ("format".to_string(), self.format(FORMAT, FORMAT_1).to_string()),
            ("step".to_string(), self.step.to_string()),
            ("adam_step".to_string(), self.adam_step.to_string()),
            ("seed".to_string(), self.seed.to_string()),
            ("params".to_string(), self.shapes.len().to_string()),
            ("config".to_string(), self.config.clone()),
            ("names".to_string(), self.names_json()),
        ]);
        let path = dir.join(Self::file_name(self.step));
        let data = serialize(views, meta).map_err(|e| ModelError::file(&path, e))?;
        diffkfc_data::write_atomic(&path, &data)?;
        Ok(path)
    }

    /// Write the inference weights (EMA when the checkpoint has them) as `dir/model.safetensors`,
    /// in f16 when `half` (tiny and small models lose nothing measurable, the file halves).
    pub fn save_weights(&self, dir: &Path, half: bool) -> Result<PathBuf> {
        let weights = self.ema.as_ref().unwrap_or(&self.model);
        let (dtype, owned): (Dtype, Vec<Vec<u8>>) = if half {
            (
                Dtype::F16,
                weights
                    .iter()
                    .map(|w| w.iter().flat_map(|&f| half::f16::from_f32(f).to_le_bytes()).collect())
                    .collect(),
            )
        } else {
            (Dtype::F32, weights.iter().map(|w| bytes(w)).collect())
        };
        let views: Vec<(String, TensorView)> = owned
            .iter()
            .enumerate()
            .map(|(i, b)| {
                (
                    format!("weights/{}", self.key(i)),
                    TensorView::new(dtype, self.shapes[i].clone(), b).expect("view"),
                )
            })
            .collect();
        let meta = HashMap::from([
            ("format".to_string(), self.format(WEIGHTS_FORMAT, WEIGHTS_FORMAT_1).to_string()),
            ("step".to_string(), self.step.to_string()),
            ("seed".to_string(), self.seed.to_string()),
            ("params".to_string(), self.shapes.len().to_string()),
            ("weights".to_string(), if self.ema.is_some() { "ema" } else { "model" }.to_string()),
            ("config".to_string(), self.config.clone()),
            ("names".to_string(), self.names_json()),
        ]);
        let path = dir.join(WEIGHTS_FILE);
        let data = serialize(views, meta).map_err(|e| ModelError::file(&path, e))?;
        diffkfc_data::write_atomic(&path, &data)?;
        Ok(path)
    }

    /// Read a training checkpoint, or exported weights (then `model` holds them, in f32, and
    /// there is no optimiser state: such a file serves inference only).
    /// Weights alone (no optimiser state, no EMA), as `diffkfc model export` stores them.
    pub fn weights(
        step: usize,
        shapes: Vec<Vec<usize>>,
        model: Vec<Vec<f32>>,
        config: String,
        seed: u64,
        names: Vec<String>,
    ) -> Checkpoint {
        Checkpoint {
            step,
            shapes,
            model,
            ema: None,
            adam_step: 0,
            adam_m: Vec::new(),
            adam_v: Vec::new(),
            config,
            seed,
            names,
        }
    }

    pub fn load(path: &Path) -> Result<Checkpoint> {
        let err = |m: String| ModelError::file(path, m);
        let data = std::fs::read(path).map_err(ModelError::io(path))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&data)
            .map_err(|e| err(format!("not a checkpoint ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let (weights_only, named) = match meta.get("format").map(String::as_str) {
            Some(FORMAT) => (false, true),
            Some(FORMAT_1) => (false, false),
            Some(WEIGHTS_FORMAT) => (true, true),
            Some(WEIGHTS_FORMAT_1) => (true, false),
            _ => return Err(err("not a diffkfc checkpoint".into())),
        };
        let num = |k: &str| -> Result<u64> {
            meta.get(k)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| err(format!("metadata '{k}' missing")))
        };
        let n = num("params")? as usize;
        let names = if named { stored_names(&meta, n).map_err(err)? } else { Vec::new() };
        // Format 2 stores tensors by name, format 1 by position.
        let key = |i: usize| names.get(i).cloned().unwrap_or_else(|| format!("{i:04}"));
        let st = safetensors::SafeTensors::deserialize(&data).map_err(|e| err(e.to_string()))?;
        // Every parameter's tensor under one prefix: shapes and values.
        let read = |prefix: &str| -> Result<Tensors> {
            (0..n).map(|i| tensor_values(&st, &format!("{prefix}/{}", key(i)), path)).collect()
        };
        if weights_only {
            let (shapes, model) = read("weights")?;
            let config = meta.get("config").cloned().unwrap_or_default();
            return Ok(Checkpoint::weights(
                num("step")? as usize,
                shapes,
                model,
                config,
                num("seed")?,
                names,
            ));
        }
        let (shapes, model) = read("model")?;
        let has_ema = st.names().iter().any(|k| k.starts_with("ema/"));
        Ok(Checkpoint {
            step: num("step")? as usize,
            shapes,
            model,
            ema: if has_ema { Some(read("ema")?.1) } else { None },
            adam_step: num("adam_step")?,
            adam_m: read("adam_m")?.1,
            adam_v: read("adam_v")?.1,
            config: meta.get("config").cloned().unwrap_or_default(),
            seed: num("seed")?,
            names,
        })
    }

    /// The stored name of parameter `i`: its module path, or its position for unnamed ones.
    fn key(&self, i: usize) -> String {
        self.names.get(i).cloned().unwrap_or_else(|| format!("{i:04}"))
    }

    /// Named checkpoints are format 2; one without names is written as format 1 (by position).
    fn format(&self, named: &'static str, positional: &'static str) -> &'static str {
        if self.names.is_empty() {
            positional
        } else {
            named
        }
    }

    fn names_json(&self) -> String {
        serde_json::to_string(&self.names).expect("names serialise")
    }

    /// Put the parameters in the order of a model's `names` (`params::names`), by name; a
    /// checkpoint without names is taken to be in that order already. Errors name the first
    /// parameter the checkpoint lacks, or the first it has that the model does not.
    pub fn align(&mut self, names: &[String], path: &Path) -> Result<()> {
        if self.names.is_empty() || self.names == names {
            self.names = names.to_vec();
            return Ok(());
        }
        let at: HashMap<&str, usize> =
            self.names.iter().enumerate().map(|(i, n)| (n.as_str(), i)).collect();
        let order: Vec<usize> = names
            .iter()
            .map(|n| {
                at.get(n.as_str()).copied().ok_or_else(|| {
                    ModelError::file(path, format!("checkpoint has no tensor for parameter {n}"))
                })
            })
            .collect::<Result<_>>()?;
        if let Some(extra) = self.names.iter().find(|n| !names.contains(n)) {
            return Err(ModelError::file(
                path,
                format!("checkpoint has tensor {extra}, which the model lacks"),
            ));
        }
        let pick = |v: &[Vec<f32>]| order.iter().map(|&i| v[i].clone()).collect::<Vec<_>>();
        self.shapes = order.iter().map(|&i| self.shapes[i].clone()).collect();
        self.model = pick(&self.model);
        if !self.adam_m.is_empty() {
            self.adam_m = pick(&self.adam_m);
            self.adam_v = pick(&self.adam_v);
        }
        if let Some(e) = &self.ema {
            self.ema = Some(pick(e));
        }
        self.names = names.to_vec();
        Ok(())
    }

    /// The checkpoint, if every weight (and EMA weight) is finite: a run resumed from
    /// non-finite weights would only produce NaN.
    fn finite(self, path: &Path) -> Result<Checkpoint> {
        let bad =
            self.model.iter().chain(self.ema.iter().flatten()).flatten().find(|x| !x.is_finite());
        match bad {
            Some(x) => Err(ModelError::file(path, format!("a weight is {x} (not finite)"))),
            None => Ok(self),
        }
    }

    /// Checkpoint files of a run directory, by step.
    pub fn list(dir: &Path) -> Vec<(usize, PathBuf)> {
        let mut v: Vec<(usize, PathBuf)> = std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let step =
                    name.strip_prefix("ckpt-")?.strip_suffix(".safetensors")?.parse().ok()?;
                Some((step, e.path()))
            })
            .collect();
        v.sort();
        v
    }

    /// The newest checkpoint that loads (a damaged one is skipped).
    pub fn latest(dir: &Path) -> Option<Result<Checkpoint>> {
        let list = Self::list(dir);
        let mut last_err = None;
        for (_, p) in list.iter().rev() {
            match Self::load(p).and_then(|c| c.finite(p)) {
                Ok(c) => return Some(Ok(c)),
                Err(e) => {
                    // Said, not hidden: the user should know an older checkpoint is in use.
                    eprintln!("warning: skipping {e}");
                    last_err = Some(e)
                }
            }
        }
        last_err.map(Err)
    }

    /// Delete all but the newest `keep` checkpoints.
    pub fn prune(dir: &Path, keep: usize) {
        let list = Self::list(dir);
        for (_, p) in list.iter().take(list.len().saturating_sub(keep.max(1))) {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// What `export` wrote.
#[derive(Debug)]
pub struct Exported {
    pub step: usize,
    pub weights: PathBuf,
    pub bytes: u64,
    pub files: Vec<PathBuf>,
}

/// Turn a run directory (or one checkpoint file in it) into a model directory `out` that
/// `--checkpoint` loads: `model.safetensors` (inference weights), `config.json` (the stored
/// config) and the run's `Mean.npy`, `Std.npy`, `metrics.jsonl`, `loss.svg` where present.
pub fn export(run: &Path, out: &Path, half: bool, force: bool) -> Result<Exported> {
    let (ck, dir) = if run.is_file() {
        (Checkpoint::load(run)?, run.parent().unwrap_or(Path::new(".")).to_path_buf())
    } else {
        let ck = Checkpoint::latest(run)
            .ok_or_else(|| ModelError::file(run, "no ckpt-*.safetensors to export"))??;
        (ck, run.to_path_buf())
    };
    let same = |a: &Path, b: &Path| {
        a == b || matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
    };
    if same(out, &dir) {
        return Err(ModelError::Refused(format!(
            "{}: export into the run directory itself is refused; choose another --out",
            out.display()
        )));
    }
    // A model directory needs the run's normalisation, readable and as wide as the model.
    let cfg = crate::run::config::RunConfig::parse(&ck.config)
        .map_err(|e| ModelError::file(run, format!("stored config: {e}")))?;
    diffkfc_data::dataset::read_normalisation(&dir, Some(cfg.model.feat_dim))?;
    let owned = ownership::check(out, Output::Model, force, "--out")?;
    std::fs::create_dir_all(out).map_err(ModelError::io(out))?;
    if owned {
        Output::Model.mark(out)?;
    }
    let weights = ck.save_weights(out, half)?;
    let mut files = vec![weights.clone()];
    let config: serde_json::Value = serde_json::from_str(&ck.config)
        .map_err(|e| ModelError::file(run, format!("stored config: {e}")))?;
    let text = serde_json::to_string_pretty(&config).expect("a JSON value serialises") + "\n";
    diffkfc_data::write_atomic(&out.join("config.json"), text.as_bytes())?;
    files.push(out.join("config.json"));
    for name in ["Mean.npy", "Std.npy", "metrics.jsonl", "loss.svg"] {
        let src = dir.join(name);
        if src.is_file() {
            let data = std::fs::read(&src).map_err(ModelError::io(&src))?;
            diffkfc_data::write_atomic(&out.join(name), &data)?;
            files.push(out.join(name));
        }
    }
    let bytes = std::fs::metadata(&weights).map(|m| m.len()).unwrap_or(0);
    Ok(Exported { step: ck.step, weights, bytes, files })
}
