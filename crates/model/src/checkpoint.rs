//! Checkpoints: model, EMA, Adam state, step and the resolved config in one safetensors file,
//! written to a temporary name and renamed, so a run killed at any moment leaves either the
//! previous checkpoint or the new one, never half of one.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

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
}

const FORMAT: &str = "diffkfc-checkpoint-1";
/// Inference weights alone (`diffkfc model export`): no optimiser state, optionally f16.
const WEIGHTS_FORMAT: &str = "diffkfc-weights-1";
/// File name of exported weights inside a model directory.
pub const WEIGHTS_FILE: &str = "model.safetensors";

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|f| f.to_le_bytes()).collect()
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
        Dtype::F32 => {
            t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
        }
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
            owned.push((format!("model/{i:04}"), shape.clone(), bytes(&self.model[i])));
            owned.push((format!("adam_m/{i:04}"), shape.clone(), bytes(&self.adam_m[i])));
            owned.push((format!("adam_v/{i:04}"), shape.clone(), bytes(&self.adam_v[i])));
            if let Some(e) = &self.ema {
                owned.push((format!("ema/{i:04}"), shape.clone(), bytes(&e[i])));
            }
        }
        let views: Vec<(String, TensorView)> = owned
            .iter()
            .map(|(n, s, b)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).expect("view")))
            .collect();
        let meta = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("step".to_string(), self.step.to_string()),
            ("adam_step".to_string(), self.adam_step.to_string()),
            ("seed".to_string(), self.seed.to_string()),
            ("params".to_string(), self.shapes.len().to_string()),
            ("config".to_string(), self.config.clone()),
        ]);
        let path = dir.join(Self::file_name(self.step));
        let data =
            safetensors::serialize(views, Some(meta)).map_err(|e| ModelError::file(&path, e))?;
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
                    format!("weights/{i:04}"),
                    TensorView::new(dtype, self.shapes[i].clone(), b).expect("view"),
                )
            })
            .collect();
        let meta = HashMap::from([
            ("format".to_string(), WEIGHTS_FORMAT.to_string()),
            ("step".to_string(), self.step.to_string()),
            ("seed".to_string(), self.seed.to_string()),
            ("params".to_string(), self.shapes.len().to_string()),
            ("weights".to_string(), if self.ema.is_some() { "ema" } else { "model" }.to_string()),
            ("config".to_string(), self.config.clone()),
        ]);
        let path = dir.join(WEIGHTS_FILE);
        let data =
            safetensors::serialize(views, Some(meta)).map_err(|e| ModelError::file(&path, e))?;
        diffkfc_data::write_atomic(&path, &data)?;
        Ok(path)
    }

    /// Read a training checkpoint, or exported weights (then `model` holds them, in f32, and
    /// there is no optimiser state: such a file serves inference only).
    pub fn load(path: &Path) -> Result<Checkpoint> {
        let err = |m: String| ModelError::file(path, m);
        let data = std::fs::read(path).map_err(ModelError::io(path))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&data)
            .map_err(|e| err(format!("not a checkpoint ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let weights_only = match meta.get("format").map(String::as_str) {
            Some(FORMAT) => false,
            Some(WEIGHTS_FORMAT) => true,
            _ => return Err(err("not a diffkfc checkpoint".into())),
        };
        let num = |k: &str| -> Result<u64> {
            meta.get(k)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| err(format!("metadata '{k}' missing")))
        };
        let n = num("params")? as usize;
        let st = safetensors::SafeTensors::deserialize(&data).map_err(|e| err(e.to_string()))?;
        if weights_only {
            let (mut shapes, mut model) = (vec![], vec![]);
            for i in 0..n {
                let (shape, values) = tensor_values(&st, &format!("weights/{i:04}"), path)?;
                shapes.push(shape);
                model.push(values);
            }
            return Ok(Checkpoint {
                step: num("step")? as usize,
                shapes,
                model,
                ema: None,
                adam_step: 0,
                adam_m: Vec::new(),
                adam_v: Vec::new(),
                config: meta.get("config").cloned().unwrap_or_default(),
                seed: num("seed")?,
            });
        }
        let get = |name: String| tensor_values(&st, &name, path);
        let (mut shapes, mut model, mut m, mut v, mut ema) =
            (vec![], vec![], vec![], vec![], vec![]);
        let has_ema = st.names().iter().any(|k| k.starts_with("ema/"));
        for i in 0..n {
            let (s, p) = get(format!("model/{i:04}"))?;
            shapes.push(s);
            model.push(p);
            m.push(get(format!("adam_m/{i:04}"))?.1);
            v.push(get(format!("adam_v/{i:04}"))?.1);
            if has_ema {
                ema.push(get(format!("ema/{i:04}"))?.1);
            }
        }
        Ok(Checkpoint {
            step: num("step")? as usize,
            shapes,
            model,
            ema: has_ema.then_some(ema),
            adam_step: num("adam_step")?,
            adam_m: m,
            adam_v: v,
            config: meta.get("config").cloned().unwrap_or_default(),
            seed: num("seed")?,
        })
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
            match Self::load(p) {
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
pub fn export(run: &Path, out: &Path, half: bool) -> Result<Exported> {
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
    let cfg = crate::run_config::RunConfig::parse(&ck.config)
        .map_err(|e| ModelError::file(run, format!("stored config: {e}")))?;
    diffkfc_data::dataset::read_normalisation(&dir, Some(cfg.model.feat_dim))?;
    std::fs::create_dir_all(out).map_err(ModelError::io(out))?;
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
