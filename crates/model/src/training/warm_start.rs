//! Starting a run from another run's weights: a model grown by an extension (the per-frame
//! key input, the text's word states) is fine-tuned from one trained without it. Every parameter
//! the checkpoint has, by name (or by position, for checkpoints written before names, whose
//! parameters are a prefix of the grown model's), with the same shape, is taken; the rest keep
//! their initialisation.
//!
//! A model with wider feed-forward blocks (`model.ffn`) starts from a narrower one's weights as
//! the same function: the stored hidden units fill the first columns of the first layer and the
//! first rows of the second, the new units keep their initialisation on the way in and read
//! zero weights on the way out, so they add nothing until training moves them (growth with a
//! zero-initialised output, as Net2Net's function-preserving widening). Only the feed-forward
//! width may differ: any other tensor of another shape is an error.

use std::collections::HashMap;
use std::path::Path;

use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::Denoiser;

/// A warm-started model and what it did not take as stored.
pub struct WarmStart {
    pub model: Denoiser,
    /// Parameters the checkpoint has no tensor for: they keep their initialisation.
    pub fresh: Vec<String>,
    /// Feed-forward parameters taken from a narrower block (their new hidden units added).
    pub widened: Vec<String>,
}

/// How a feed-forward tensor grows with the hidden width: the first layer's weight [d, ffn]
/// and bias [ffn] gain units (initialised as fresh), the second layer's weight [ffn, d] gains
/// input rows that must be zero for the block to compute what it did.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Growth {
    NewUnits,
    ZeroInputs,
}

/// The growth a parameter allows, by its name (decoder `ff1`/`ff2`, keyframe encoder
/// `mlp1`/`mlp2`); None: its shape must match.
fn growth(name: &str) -> Option<Growth> {
    let (module, tensor) = name.rsplit_once('.')?;
    let layer = module.rsplit('.').next()?;
    match (layer, tensor) {
        ("ff1" | "mlp1", "weight" | "bias") => Some(Growth::NewUnits),
        ("ff2" | "mlp2", "weight") => Some(Growth::ZeroInputs),
        _ => None,
    }
}

/// `stored` of shape `from` placed in a tensor of shape `to` along the hidden dimension
/// (`init` holds the parameter's initialisation); None when `from` is not a narrower `to`.
fn widen(
    g: Growth,
    from: &[usize],
    to: &[usize],
    stored: &[f32],
    init: &[f32],
) -> Option<Vec<f32>> {
    match (g, from, to) {
        (Growth::NewUnits, [h0], [h1]) if h0 < h1 => {
            let mut v = init.to_vec();
            v[..*h0].copy_from_slice(stored);
            Some(v)
        }
        (Growth::NewUnits, [d0, h0], [d1, h1]) if d0 == d1 && h0 < h1 => {
            let mut v = init.to_vec();
            for (row, old) in v.chunks_mut(*h1).zip(stored.chunks(*h0)) {
                row[..*h0].copy_from_slice(old);
            }
            Some(v)
        }
        (Growth::ZeroInputs, [h0, d0], [h1, d1]) if d0 == d1 && h0 < h1 => {
            let mut v = vec![0.0; h1 * d1];
            v[..stored.len()].copy_from_slice(stored);
            Some(v)
        }
        _ => None,
    }
}

/// `model` with the checkpoint's weights (its EMA when it has one), and the names of the
/// parameters left as initialised or widened. Errors when a tensor the model shares by name
/// has another shape (other than a narrower feed-forward block), or when nothing matches (not a
/// checkpoint of this kind of model).
pub fn warm_start(model: Denoiser, ck: &Checkpoint, path: &Path) -> Result<WarmStart> {
    let names = params::names(&model);
    let stored = ck.ema.as_ref().unwrap_or(&ck.model);
    let keys: Vec<String> = if ck.names.is_empty() {
        names.iter().take(stored.len()).cloned().collect()
    } else {
        ck.names.clone()
    };
    let at: HashMap<&str, usize> = keys.iter().enumerate().map(|(i, n)| (n.as_str(), i)).collect();
    let mut values = params::values(&model);
    let (mut fresh, mut widened) = (Vec::new(), Vec::new());
    for (name, (shape, v)) in names.iter().zip(values.iter_mut()) {
        let Some(&i) = at.get(name.as_str()) else {
            fresh.push(name.clone());
            continue;
        };
        if &ck.shapes[i] == shape {
            *v = stored[i].clone();
            continue;
        }
        match growth(name).and_then(|g| widen(g, &ck.shapes[i], shape, &stored[i], v)) {
            Some(w) => {
                *v = w;
                widened.push(name.clone());
            }
            None => {
                return Err(ModelError::Refused(format!(
                    "--init {}: tensor {name} has shape {:?}; the model's is {shape:?} (only \
                     feed-forward blocks may differ, and only wider in the model)",
                    path.display(),
                    ck.shapes[i]
                )))
            }
        }
    }
    if fresh.len() == names.len() {
        return Err(ModelError::file(path, "no tensor matches the model's parameters"));
    }
    let vals: Vec<Vec<f32>> = values.into_iter().map(|(_, v)| v).collect();
    Ok(WarmStart { model: params::load(model, &vals), fresh, widened })
}

/// Per parameter of `model` (visit order), whether training holds it fixed: every parameter
/// whose name contains none of `trainable` (`training.trainable`; empty: none is held). A
/// pattern that names no parameter is an error, not a run that trains nothing.
pub fn frozen(model: &Denoiser, trainable: &[String]) -> Result<Vec<bool>> {
    let names = params::names(model);
    if trainable.is_empty() {
        return Ok(vec![false; names.len()]);
    }
    if let Some(p) = trainable.iter().find(|p| !names.iter().any(|n| n.contains(p.as_str()))) {
        return Err(ModelError::Config(format!(
            "training.trainable: '{p}' names no parameter of this model"
        )));
    }
    Ok(names.iter().map(|n| !trainable.iter().any(|p| n.contains(p.as_str()))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::sampler::Request;
    use crate::DiffKfcConfig;
    use burn::prelude::*;
    use diffkfc_data::motion::root_key::{RootKey, ROOT_CHANNELS};

    fn checkpoint_of(m: &Denoiser, named: bool) -> Checkpoint {
        let (shapes, model) = params::values(m).into_iter().unzip();
        let names = if named { params::names(m) } else { Vec::new() };
        Checkpoint::weights(7, shapes, model, String::new(), 0, names)
    }

    /// Two motions of 30 frames, the first with keyed places far ahead.
    fn request() -> Request {
        let mut req = Request::text_only(30, 263, vec![0.1; 2 * 384], 384, vec![30, 24]);
        for (f, z) in [(10usize, 3.0), (29, 6.0)] {
            let (v, m) = RootKey { place: Some([0.5, z]), heading: None }.channels();
            let r = f * ROOT_CHANNELS..(f + 1) * ROOT_CHANNELS;
            req.root[r.clone()].copy_from_slice(&v);
            req.root_mask[r].copy_from_slice(&m);
        }
        req
    }

    #[test]
    fn a_grown_model_starts_as_its_source_by_name_or_position() {
        let dev = Device::flex();
        let base = DiffKfcConfig::tiny().with_temporal_kernel(3);
        let old = base.init(&dev);
        let cond = request().condition(&dev);
        let x = Tensor::<3>::random([2, 30, 263], burn::tensor::Distribution::Default, &dev);
        let want = params::host(old.forward(x.clone(), &[10, 500], &cond));
        let grown_by = [(base.clone().with_key_input(true), ["key_in.weight", "key_in.bias"])];
        for (cfg, new) in grown_by {
            for named in [true, false] {
                let ck = checkpoint_of(&old, named);
                let w = warm_start(cfg.init(&dev), &ck, Path::new("ck")).unwrap();
                assert_eq!(w.fresh, new, "named {named}");
                assert!(w.widened.is_empty());
                let got = params::host(w.model.forward(x.clone(), &[10, 500], &cond));
                assert_eq!(got, want, "named {named}: the zero projection {new:?} changes nothing");
            }
        }
        // Tensors of another width are an error naming the tensor, not a silent skip.
        let narrow = DiffKfcConfig::tiny().with_d_model(32).init(&dev);
        let err = warm_start(base.init(&dev), &checkpoint_of(&narrow, true), Path::new("ck"))
            .err()
            .expect("shape mismatch")
            .to_string();
        assert!(err.contains("ck") && err.contains("shape"), "{err}");
    }

    /// `request()` with word states: the pooled 0.1 embedding, then `words[i]` word rows of
    /// value `v` for motion i (zero rows after them).
    fn with_words(words: [usize; 2], w: usize, v: f32) -> Request {
        let mut req = request();
        req.text = (0..2)
            .flat_map(|i| {
                let mut t = vec![0.1; 384];
                t.extend((0..w * 384).map(|k| {
                    if k / 384 < words[i] {
                        v + k as f32 * 1e-4
                    } else {
                        0.0
                    }
                }));
                t
            })
            .collect();
        req.text_dim = 384 * (1 + w);
        req
    }

    #[test]
    fn word_tokens_start_silent_and_then_read_the_words() {
        let dev = Device::flex();
        let base = DiffKfcConfig::tiny().with_temporal_kernel(3).with_key_input(true);
        let old = base.init(&dev);
        let x = Tensor::<3>::random([2, 30, 263], burn::tensor::Distribution::Default, &dev);
        let want = params::host(old.forward(x.clone(), &[10, 500], &request().condition(&dev)));
        let cfg = base.clone().with_text_words(4);
        let w = warm_start(cfg.init(&dev), &checkpoint_of(&old, true), Path::new("ck")).unwrap();
        assert!(!w.fresh.is_empty() && w.fresh.iter().all(|n| n.contains("word")), "{:?}", w.fresh);
        let run = |m: &Denoiser, r: &Request| {
            params::host(m.forward(x.clone(), &[10, 500], &r.condition(&dev)))
        };
        let got = run(&w.model, &with_words([3, 1], 4, 0.2));
        assert_eq!(got, want, "the zero-output word attention changes nothing");
        // Output projections moved: the words now reach the output, padding slots do not.
        let names = params::names(&w.model);
        let vals: Vec<Vec<f32>> = params::values(&w.model)
            .into_iter()
            .zip(&names)
            .map(
                |((_, v), n)| {
                    if n.contains("words.output.weight") {
                        vec![0.05; v.len()]
                    } else {
                        v
                    }
                },
            )
            .collect();
        let m1 = params::load(w.model, &vals);
        let a = run(&m1, &with_words([3, 1], 4, 0.2));
        let b = run(&m1, &with_words([3, 1], 4, -0.3));
        let n = 30 * 263;
        assert!(a[..n].iter().zip(&b[..n]).any(|(a, b)| (a - b).abs() > 1e-3), "other words");
        let c = run(&m1, &with_words([2, 1], 4, 0.2));
        assert!(a[..n].iter().zip(&c[..n]).any(|(a, b)| (a - b).abs() > 1e-3), "one word fewer");
        assert_eq!(a[n..], c[n..], "the other motion's words are unchanged");
        // Dropped text (all zero) still attends to slot 0: finite.
        assert!(run(&m1, &with_words([0, 0], 4, 0.0)).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn trainable_patterns_hold_the_rest_fixed() {
        let m = DiffKfcConfig::tiny().with_text_words(4).init(&Device::flex());
        let names = params::names(&m);
        let all = frozen(&m, &[]).unwrap();
        assert!(all.len() == names.len() && all.iter().all(|f| !f));
        let words = frozen(&m, &["word".to_string()]).unwrap();
        for (n, f) in names.iter().zip(&words) {
            assert_eq!(*f, !n.contains("word"), "{n}");
        }
        // Two layers' attention (4 linears, weight and bias each) and the projection.
        assert_eq!(words.iter().filter(|f| !**f).count(), 2 * 8 + 2);
        let e = frozen(&m, &["wrod".to_string()]).err().unwrap().to_string();
        assert!(e.contains("training.trainable") && e.contains("wrod"), "{e}");
    }

    #[test]
    fn a_wider_feed_forward_starts_as_the_narrow_model() {
        let dev = Device::flex();
        let base = DiffKfcConfig::tiny().with_temporal_kernel(3).with_key_input(true);
        let old = base.init(&dev);
        let cond = request().condition(&dev);
        let x = Tensor::<3>::random([2, 30, 263], burn::tensor::Distribution::Default, &dev);
        let want = params::host(old.forward(x.clone(), &[10, 500], &cond));
        let wide = base.clone().with_ffn(3 * base.ffn);
        let w = warm_start(wide.init(&dev), &checkpoint_of(&old, true), Path::new("ck")).unwrap();
        assert!(w.fresh.is_empty(), "{:?}", w.fresh);
        // Two decoder layers and the encoder's blocks, three tensors each.
        let blocks = base.dec_layers + base.dma_sizes.len();
        assert_eq!(w.widened.len(), 3 * blocks, "{:?}", w.widened);
        assert!(w.widened.iter().all(|n| n.contains("ff") || n.contains("mlp")));
        let got = params::host(w.model.forward(x.clone(), &[10, 500], &cond));
        let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "the new units change the output by {worst}");
        // The new units are live on the way in (initialised, not zero), so training moves them.
        let names = params::names(&w.model);
        let vals = params::values(&w.model);
        let (i, _) = names.iter().enumerate().find(|(_, n)| n.ends_with("ff1.weight")).unwrap();
        let (shape, v) = &vals[i];
        assert_eq!(shape, &vec![base.d_model, 3 * base.ffn]);
        assert!(v.chunks(shape[1]).any(|row| row[base.ffn..].iter().any(|&a| a != 0.0)));
        // A narrower block cannot take a wider one's weights.
        let back = warm_start(old.clone(), &checkpoint_of(&w.model, true), Path::new("ck"));
        let err = back.err().expect("narrowing is refused").to_string();
        assert!(err.contains("mlp1.weight") && err.contains("shape"), "{err}");
    }

    #[test]
    fn the_key_input_reaches_the_decoder_only_where_keys_are() {
        let dev = Device::flex();
        let grown = [(DiffKfcConfig::tiny().with_key_input(true), "key_in.weight")];
        for (cfg, weight) in grown {
            let m0 = cfg.init(&dev);
            // The projection's weights made nonzero (its bias stays zero).
            let names = params::names(&m0);
            let vals: Vec<Vec<f32>> = params::values(&m0)
                .into_iter()
                .zip(&names)
                .map(|((_, v), n)| if n == weight { vec![0.3; v.len()] } else { v })
                .collect();
            let m1 = params::load(m0.clone(), &vals);
            let x = Tensor::<3>::zeros([2, 30, 263], &dev);
            let run = |m: &Denoiser, r: &Request| {
                params::host(m.forward(x.clone(), &[10, 10], &r.condition(&dev)))
            };
            let keyed = request();
            let n = 30 * 263;
            let (a, b) = (run(&m0, &keyed), run(&m1, &keyed));
            assert!(
                a[..n].iter().zip(&b[..n]).any(|(a, b)| (a - b).abs() > 1e-3),
                "{weight}: keyed places"
            );
            // The second motion has no key: nothing read, the same output.
            assert_eq!(a[n..], b[n..], "{weight}");
            let plain = Request::text_only(30, 263, vec![0.1; 2 * 384], 384, vec![30, 24]);
            assert_eq!(run(&m0, &plain), run(&m1, &plain), "{weight}");
        }
    }
}
