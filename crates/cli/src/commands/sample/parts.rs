//! `sample --text-lower ... --text-upper ...`: body-part prompts (`diffkfc_model::sampling::parts`):
//! a whole motion from the lower body's text (with the user's keyframes, if any), then the upper
//! body from its own text with that lower body keyed on every frame. The second pass runs at
//! keyframe guidance `--part-guidance` (0 by default: with the lower body keyed on every frame,
//! the keyframe branch brings back the first motion's own arms and drowns the text).

use super::*;
use crate::args::MAX_GUIDANCE;
use diffkfc_model::sampling::parts::upper_body_keys;

pub(super) fn run(a: SampleArgs) -> Result<()> {
    let (Some(lower), Some(upper)) = (a.text_lower.clone(), a.text_upper.clone()) else {
        bail!("--text-lower and --text-upper go together");
    };
    for (t, flag) in [(&lower, "--text-lower"), (&upper, "--text-upper")] {
        if t.trim().is_empty() {
            bail!("{flag}: empty prompt");
        }
    }
    check_flags(&a)?;
    if !(a.part_guidance.is_finite() && (0.0..=MAX_GUIDANCE).contains(&a.part_guidance)) {
        bail!("--part-guidance: {} must be a number from 0 to {MAX_GUIDANCE}", a.part_guidance);
    }
    let keys = request_keys(&a)?;
    let mut gen = Job::load(&a)?;
    let (n, b) = (keys.length, a.num_samples);
    let req = gen.request(
        &gen.embed(&lower, "--text-lower")?,
        n,
        b,
        &[(&keys.values, &keys.mask, &keys.root)],
    );
    let (first, secs1) = gen.generate(&req, &a)?;

    let items: Vec<(Vec<f32>, Vec<f32>, Vec<RootKey>)> = first
        .iter()
        .map(|f| upper_body_keys(&T2M, &f.features, &keys.values, &keys.mask, n))
        .collect();
    let refs: Vec<(&[f32], &[f32], &[RootKey])> =
        items.iter().map(|(v, m, r)| (v.as_slice(), m.as_slice(), r.as_slice())).collect();
    let req = gen.request(&gen.embed(&upper, "--text-upper")?, n, b, &refs);
    gen.opts.kf_guidance = a.part_guidance;
    let (second, secs2) = gen.generate(&req, &a)?;
    let extra = json!({"text_lower": lower, "text_upper": upper, "parts_order": ["lower_body", "upper_body"], "part_guidance": a.part_guidance});
    let mut a = a;
    a.text = format!("lower body: {lower} / upper body: {upper}");
    write_outputs(
        &a,
        &gen,
        Outputs { keys: &keys, fitted: second, secs: secs1 + secs2, extra, segments: &[] },
    )
}
