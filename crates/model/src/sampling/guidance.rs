//! Classifier-free guidance over keyframes (paper Eq. 3: X = X(C, none) + s (X(C, kf) - X(C, none)))
//! and over the text (MDM's). Training drops all keyframes of some samples
//! (`diffkfc_data::dataset::batch`), and, where `training.text_drop_prob` is set, the text of
//! some, so that the keyframe-free and text-free branches are learned; sampling runs the branches
//! in one batched forward and combines them here.

use burn::prelude::*;

use crate::error::ModelError;
use crate::run::config::RunConfig;
use crate::Condition;

/// Largest keyframe guidance scale accepted (at 100 the sampler already diverges).
pub const MAX_GUIDANCE: f64 = 100.0;
/// Largest transition or place guidance strength accepted.
pub const MAX_STRENGTH: f64 = 1e5;

/// A guidance value outside its range, named as the user gave it (a flag or a request field).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{name}: {value} must be a number from 0 to {max}{hint}")]
pub struct OutOfRange {
    pub name: String,
    pub value: f64,
    pub max: f64,
    /// What values mean, appended to the message.
    pub hint: String,
}

/// A guidance scale or strength `v` named `name` (a flag or a request field) in 0..=`max`;
/// `hint` ends the message (what values mean).
pub fn check_range(name: &str, v: f64, max: f64, hint: &str) -> Result<(), OutOfRange> {
    if v.is_finite() && (0.0..=max).contains(&v) {
        Ok(())
    } else {
        Err(OutOfRange { name: name.into(), value: v, max, hint: hint.into() })
    }
}

/// The text guidance scale a model trained with text drop samples with by default (MDM's).
pub const DEFAULT_TEXT_GUIDANCE: f64 = 2.5;

/// The text guidance scale to sample `cfg`'s model with: `given` (named `name`, a flag or
/// request field), or by default [`DEFAULT_TEXT_GUIDANCE`] for a model trained with text drop
/// (`training.text_drop_prob` > 0) and 1 (off) for one without. A scale other than 1 is refused
/// for a model trained without text drop: it never learned the text-free branch.
pub fn text_guidance(name: &str, given: Option<f64>, cfg: &RunConfig) -> Result<f64, ModelError> {
    let trained = cfg.training.text_drop_prob > 0.0;
    match given {
        Some(s) if is_scaled(s) && !trained => Err(ModelError::Config(format!(
            "{name}: {s} needs a model trained with text drop (training.text_drop_prob > 0); this one was trained without it, so it has no text-free branch: leave it at 1"
        ))),
        Some(s) => Ok(s),
        None => Ok(if trained { DEFAULT_TEXT_GUIDANCE } else { 1.0 }),
    }
}

/// Whether sampling with keyframe guidance scale `s` runs the keyframe-free branch: only when
/// there are keyframes, the keyframe branch is used (not MDM-inp) and s is not 1 (where the
/// combination is the conditional branch alone).
pub fn is_guided(s: f64, any_keys: bool, inpaint: bool) -> bool {
    any_keys && !inpaint && is_scaled(s)
}

fn is_scaled(s: f64) -> bool {
    (s - 1.0).abs() > 1e-12
}

/// The branches of one guided prediction: the conditional one, and the keyframe-free and
/// text-free ones where their scales are not 1. Combined as
/// X = X(c) + (s_kf - 1) (X(c) - X(c, no keys)) + (s_text - 1) (X(c) - X(c, no text)),
/// which is Eq. 3 (and MDM's text guidance) when only one scale is set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guidance {
    kf: Option<f64>,
    text: Option<f64>,
}

impl Guidance {
    /// Keyframe scale `kf` (used as [`is_guided`] says) and text scale `text` (used unless 1).
    pub fn new(kf: f64, text: f64, any_keys: bool, inpaint: bool) -> Guidance {
        Guidance {
            kf: is_guided(kf, any_keys, inpaint).then_some(kf),
            text: is_scaled(text).then_some(text),
        }
    }

    /// Samples per request row in each decoder call: 1 to 3.
    pub fn branches(&self) -> usize {
        1 + usize::from(self.kf.is_some()) + usize::from(self.text.is_some())
    }

    /// The batch of all branches, [c; c without keyframes; c without text] (those used).
    pub fn condition(&self, c: &Condition) -> Condition {
        let mut out = c.clone();
        if self.kf.is_some() {
            out = stack(&out, &c.without_keyframes());
        }
        if self.text.is_some() {
            out = stack(&out, &c.without_text());
        }
        out
    }

    /// The guided prediction from the output of a [`Guidance::condition`] batch,
    /// [branches * B, N, D] -> [B, N, D].
    pub fn combine(&self, out: Tensor<3>) -> Tensor<3> {
        let [bk, n, d] = out.dims();
        let b = bk / self.branches();
        let part = |k: usize| out.clone().slice([k * b..(k + 1) * b, 0..n, 0..d]);
        let c = part(0);
        let mut x = c.clone();
        for (k, s) in [self.kf, self.text].into_iter().flatten().enumerate() {
            x = x + (c.clone() - part(k + 1)) * (s - 1.0);
        }
        x
    }
}

/// Two conditions stacked along the batch: [a; b].
impl Guidance {
    /// [`Guidance::combine`] on host values: the branches' outputs stacked branch after branch,
    /// each `len / branches` long -> the guided output (the same operations, the same bits).
    pub fn combine_host(&self, out: &[f32]) -> Vec<f32> {
        let per = out.len() / self.branches();
        let c = &out[..per];
        let mut x = c.to_vec();
        for (k, s) in [self.kf, self.text].into_iter().flatten().enumerate() {
            let part = &out[(k + 1) * per..(k + 2) * per];
            let s = (s - 1.0) as f32;
            x.iter_mut().zip(c).zip(part).for_each(|((x, c), p)| *x += (c - p) * s);
        }
        x
    }
}

fn stack(a: &Condition, b: &Condition) -> Condition {
    Condition {
        text: Tensor::cat(vec![a.text.clone(), b.text.clone()], 0),
        kf: Tensor::cat(vec![a.kf.clone(), b.kf.clone()], 0),
        kf_mask: Tensor::cat(vec![a.kf_mask.clone(), b.kf_mask.clone()], 0),
        root: Tensor::cat(vec![a.root.clone(), b.root.clone()], 0),
        root_mask: Tensor::cat(vec![a.root_mask.clone(), b.root_mask.clone()], 0),
        kf_frames: a.kf_frames.iter().chain(&b.kf_frames).copied().collect(),
        real: a.real.iter().chain(&b.real).copied().collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host(t: Tensor<3>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    /// Branch outputs [c; u_kf; u_text] of one request row each, as a decoder would return them.
    fn outputs(rows: &[[f32; 2]]) -> Tensor<3> {
        let flat: Vec<f32> = rows.iter().flatten().copied().collect();
        Tensor::<1>::from_floats(flat.as_slice(), &Device::flex()).reshape([rows.len(), 1, 2])
    }

    #[test]
    fn branches_combine_as_the_guidance_formulas() {
        let (c, uk, ut) = ([1.0, 2.0], [0.5, 1.0], [3.0, -1.0]);
        // Neither scale: the conditional branch alone.
        let none = Guidance::new(1.0, 1.0, true, false);
        assert_eq!(none.branches(), 1);
        assert_eq!(host(none.combine(outputs(&[c]))), c);
        // Keyframe guidance alone is Eq. 3: u + s (c - u).
        let kf = Guidance::new(2.5, 1.0, true, false);
        assert_eq!(kf.branches(), 2);
        assert_eq!(host(kf.combine(outputs(&[c, uk]))), [0.5 + 2.5 * 0.5, 1.0 + 2.5 * 1.0]);
        // Without keys (or for MDM-inp) only the text branch is added: MDM's u + s (c - u).
        let text = Guidance::new(2.5, 3.0, false, false);
        assert_eq!(text, Guidance::new(2.5, 3.0, true, true));
        assert_eq!(text.branches(), 2);
        assert_eq!(host(text.combine(outputs(&[c, ut]))), [3.0 + 3.0 * -2.0, -1.0 + 3.0 * 3.0]);
        // Both: each guidance term added to the conditional prediction.
        let both = Guidance::new(2.0, 3.0, true, false);
        assert_eq!(both.branches(), 3);
        let want = [1.0 + 1.0 * 0.5 + 2.0 * -2.0, 2.0 + 1.0 * 1.0 + 2.0 * 3.0];
        assert_eq!(host(both.combine(outputs(&[c, uk, ut]))), want);
        // The host form (the sampling path's) gives the same bits.
        for (g, rows) in
            [(none, vec![c]), (kf, vec![c, uk]), (text, vec![c, ut]), (both, vec![c, uk, ut])]
        {
            let flat: Vec<f32> = rows.iter().flatten().copied().collect();
            assert_eq!(g.combine_host(&flat), host(g.combine(outputs(&rows))));
        }
    }

    #[test]
    fn text_guidance_needs_a_model_trained_with_text_drop() {
        let name = "--text-guidance";
        let without = RunConfig::parse(r#"{"model": "tiny"}"#).unwrap();
        assert_eq!(text_guidance(name, None, &without).unwrap(), 1.0);
        assert_eq!(text_guidance(name, Some(1.0), &without).unwrap(), 1.0);
        let e = text_guidance(name, Some(2.5), &without).unwrap_err().to_string();
        assert!(e.contains("--text-guidance: 2.5") && e.contains("text_drop_prob"), "{e}");
        let with =
            RunConfig::parse(r#"{"model": "tiny", "training": {"text_drop_prob": 0.1}}"#).unwrap();
        assert_eq!(text_guidance(name, None, &with).unwrap(), DEFAULT_TEXT_GUIDANCE);
        assert_eq!(text_guidance(name, Some(1.0), &with).unwrap(), 1.0);
        assert_eq!(text_guidance(name, Some(4.0), &with).unwrap(), 4.0);
    }
}
