//! Starting a run from another run's weights: a model grown by an extension (the root path
//! hint, the per-frame key input) is fine-tuned from one trained without it. Every parameter
//! the checkpoint has, by name (or by position, for checkpoints written before names, whose
//! parameters are a prefix of the grown model's), with the same shape, is taken; the rest keep
//! their initialisation.

use std::collections::HashMap;
use std::path::Path;

use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::Denoiser;

/// `model` with the checkpoint's weights (its EMA when it has one), and the names of the
/// parameters left as initialised. Errors when a tensor the model shares by name has another
/// shape, or when nothing matches (not a checkpoint of this kind of model).
pub fn warm_start(
    model: Denoiser,
    ck: &Checkpoint,
    path: &Path,
) -> Result<(Denoiser, Vec<String>)> {
    let names = params::names(&model);
    let stored = ck.ema.as_ref().unwrap_or(&ck.model);
    let keys: Vec<String> = if ck.names.is_empty() {
        names.iter().take(stored.len()).cloned().collect()
    } else {
        ck.names.clone()
    };
    let at: HashMap<&str, usize> = keys.iter().enumerate().map(|(i, n)| (n.as_str(), i)).collect();
    let mut values = params::values(&model);
    let mut fresh = Vec::new();
    for (name, (shape, v)) in names.iter().zip(values.iter_mut()) {
        match at.get(name.as_str()) {
            Some(&i) if &ck.shapes[i] == shape => *v = stored[i].clone(),
            Some(&i) => {
                return Err(ModelError::file(
                    path,
                    format!("tensor {name} has shape {:?}; the model's is {shape:?}", ck.shapes[i]),
                ))
            }
            None => fresh.push(name.clone()),
        }
    }
    if fresh.len() == names.len() {
        return Err(ModelError::file(path, "no tensor matches the model's parameters"));
    }
    let vals: Vec<Vec<f32>> = values.into_iter().map(|(_, v)| v).collect();
    Ok((params::load(model, &vals), fresh))
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
        let grown_by = [
            (base.clone().with_root_path(true), ["path_in.weight", "path_in.bias"]),
            (base.clone().with_key_input(true), ["key_in.weight", "key_in.bias"]),
        ];
        for (cfg, new) in grown_by {
            for named in [true, false] {
                let ck = checkpoint_of(&old, named);
                let (grown, fresh) = warm_start(cfg.init(&dev), &ck, Path::new("ck")).unwrap();
                assert_eq!(fresh, new, "named {named}");
                let got = params::host(grown.forward(x.clone(), &[10, 500], &cond));
                assert_eq!(got, want, "named {named}: the zero projection {new:?} changes nothing");
            }
        }
        // Tensors of another width are an error naming the tensor, not a silent skip.
        let narrow = DiffKfcConfig::tiny().with_d_model(32).init(&dev);
        let err = warm_start(base.init(&dev), &checkpoint_of(&narrow, true), Path::new("ck"))
            .expect_err("shape mismatch")
            .to_string();
        assert!(err.contains("ck") && err.contains("shape"), "{err}");
    }

    #[test]
    fn the_hint_and_key_input_reach_the_decoder_only_where_keys_are() {
        let dev = Device::flex();
        let grown = [
            (DiffKfcConfig::tiny().with_root_path(true), "path_in.weight"),
            (DiffKfcConfig::tiny().with_key_input(true), "key_in.weight"),
        ];
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
