//! The files of a `sample` folder: features, joints, GIF and BVH per sample, results.json and
//! the 3D page.

use super::*;
use diffkfc_data::io::output_set::{Committed, OutputSet};

/// What a `sample` run hands to its output folder.
pub(super) struct Outputs<'a> {
    pub keys: &'a Keys,
    pub fitted: Vec<Fitted>,
    /// Seconds the sampler took.
    pub secs: f64,
    /// Fields merged into results.json (timelines, body-part prompts).
    pub extra: serde_json::Value,
    /// Timeline segments for the page: start frame and text.
    pub segments: &'a [(usize, String)],
}

/// Every file of a `sample` folder, written as one set: per-sample features, joints, GIF, BVH;
/// the source; results.json and the 3D page.
pub(super) fn write_outputs(a: &SampleArgs, gen: &Job, out: Outputs) -> Result<()> {
    let keys = out.keys;
    let (b, n) = (out.fitted.len(), keys.length);
    let set = OutputSet::begin(&a.out, MARKER, is_output, a.force, "--out")?;
    let dir = set.path().to_path_buf();
    let mut views = Vec::new();
    if let Some(src) = &keys.source {
        npy::write(dir.join("source_joints.npy"), &[src.len(), 22, 3], &rep::joints_to_f32(src))?;
        views.push(source_view(keys, src));
    }
    let mut samples = Vec::new();
    for (i, done) in out.fitted.into_iter().enumerate() {
        let (s, view) = write_sample(&dir, i, done, keys, gen.fit)?;
        samples.push(s);
        views.push(view);
    }
    let mut report = results(a, gen, keys, out.secs, samples);
    if let (Some(r), Some(e)) = (report.as_object_mut(), out.extra.as_object()) {
        r.extend(e.clone());
    }
    diffkfc_data::write_atomic(
        &dir.join("results.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    diffkfc_data::write_atomic(
        &dir.join("index.html"),
        index_html(&report, &views, out.segments).as_bytes(),
    )?;
    let kept = match set.commit()? {
        Committed::Replaced { kept } if !kept.is_empty() => {
            Some(format!("replaced the earlier outputs; kept {}", kept.join(", ")))
        }
        Committed::Replaced { .. } => Some("replaced the earlier outputs".into()),
        Committed::Merged => Some("written beside the folder's other files (--force)".into()),
        Committed::Created => None,
    };
    println!(
        "{}: {b} sample(s) of {n} frames in {:.1} s ({:?}); results.json, index.html",
        a.out.display(),
        out.secs,
        gen.opts.sampler
    );
    if let Some(k) = kept {
        println!("  ({k})");
    }
    for (i, s) in report["samples"].as_array().unwrap().iter().enumerate() {
        println!(
            "  sample_{i:02}: {}, K-TranS {}, foot skating {}",
            k_err_text(s),
            fmt(&s["k_trans"]),
            fmt(&s["foot_skating"])
        );
        for note in [fit_note(s, gen.fit), lock_note(s)].into_iter().flatten() {
            println!("    {note}");
        }
    }
    Ok(())
}

/// The page's view of the keyframe source.
fn source_view(keys: &Keys, src: &rep::Joints) -> ViewMotion {
    ViewMotion {
        label: "source".into(),
        joints: src.clone(),
        keyframes: keys.frames.clone(),
        key_joints: (keys.joints.len() < T2M.num_joints()).then(|| keys.joints.clone()),
        numbers: format!(
            "K-TranS {}, foot skating {:.4}",
            k_trans(src, &keys.frames, 2).map_or("-".into(), |v| format!("{v:.4}")),
            diffkfc_data::motion::plausibility::foot_skating_ratio(&T2M, src)
        ),
        links: vec![("joints".into(), "source_joints.npy".into())],
        ..Default::default()
    }
}

/// Sample `i`'s files in `dir`, its results.json entry and its view on the page.
fn write_sample(
    dir: &Path,
    i: usize,
    done: Fitted,
    keys: &Keys,
    fit: Fit,
) -> Result<(serde_json::Value, ViewMotion)> {
    let (n, d) = (keys.length, T2M.feature_dim());
    let f = &done.features;
    let j = rep::recover_from_ric_f32(&T2M, f);
    let name = format!("sample_{i:02}");
    let stem = dir.join(&name);
    npy::write(stem.with_extension("npy"), &[n, d], f)?;
    npy::write(dir.join(format!("{name}_joints.npy")), &[n, 22, 3], &rep::joints_to_f32(&j))?;
    render::gif(&T2M, &j, &keys.frames, &stem.with_extension("gif"))?;
    let rig = diffkfc_data::io::rig::export(&T2M, &j);
    diffkfc_data::write_atomic(&stem.with_extension("bvh"), rig.to_text().as_bytes())?;
    // The BVH is a rigid rig: it reproduces the motion when the fit made it rigid.
    let (bvh_mean, bvh_max) = diffkfc_data::io::rig::export_error(&T2M, &j, &rig);
    diffkfc_data::io::gltf::write(&stem.with_extension("glb"), &T2M, &j)?;
    let path_file = format!("{name}_root_path.npy");
    if let Some(p) = &done.root_path {
        npy::write(dir.join(&path_file), &[p.len() / 3, 3], p)?;
    }
    let s = json!({
        "features": format!("{name}.npy"),
        "joints": format!("{name}_joints.npy"),
        "gif": format!("{name}.gif"),
        "bvh": format!("{name}.bvh"),
        "glb": format!("{name}.glb"),
        "bvh_error_m": {"mean": bvh_mean, "max": bvh_max},
        "bone_length_std_m": diffkfc_data::postprocess::rigid::bone_length_std(&T2M, &j) * T2M.metres_per_unit,
        "rigid": done.rigid,
        "root_path": done.root_path.is_some().then_some(&path_file),
        "track": done.track,
        "k_err_m": keys.source.as_ref().and_then(|s| k_err_global(&j, s, &keys.frames, &keys.joints)),
        "k_err_root_relative_m": k_err_local(&T2M, f, &keys.values, &keyframes::posed_frames(&T2M, &keys.mask, &keys.frames), &keys.joints),
        "k_trans": k_trans(&j, &keys.frames, 2),
        "foot_skating": diffkfc_data::motion::plausibility::foot_skating_ratio(&T2M, &j),
        "penetration_m": diffkfc_data::motion::plausibility::penetration(&T2M, &j),
        "gait": diffkfc_eval::gait::measure(&T2M, &j),
        "corrections": done.corrections,
        "foot_lock": fit.foot_lock.then_some(&done.feet),
        "stride": done.stride,
    });
    let view = sample_view(&name, &s, done, keys, j);
    Ok((s, view))
}

/// The page's view of one sample (`s`: its results.json entry).
fn sample_view(
    name: &str,
    s: &serde_json::Value,
    done: Fitted,
    keys: &Keys,
    j: rep::Joints,
) -> ViewMotion {
    // The keyed pose: the source's where there is one, else the (fitted) sample's own.
    let key_poses = keys
        .frames
        .iter()
        .filter(|&&k| k < j.len())
        .map(|&k| (k, keys.source.as_ref().and_then(|src| src.get(k)).unwrap_or(&j[k]).clone()))
        .collect();
    ViewMotion {
        label: name.to_string(),
        keyframes: keys.frames.clone(),
        key_joints: (keys.joints.len() < T2M.num_joints()).then(|| keys.joints.clone()),
        key_poses,
        numbers: format!(
            "{}, K-TranS {}, foot skating {}",
            k_err_text(s),
            fmt(&s["k_trans"]),
            fmt(&s["foot_skating"])
        ),
        links: ["gif", "bvh", "glb", "features", "joints"]
            .iter()
            .map(|k| (k.to_string(), s[*k].as_str().unwrap_or("").to_string()))
            .collect(),
        root_path: done.root_path.as_ref().map(|p| {
            p.chunks(3).map(|v| [v[0] as f64, v[1] as f64, v[2] as f64]).collect::<Vec<_>>()
        }),
        planted: done
            .feet
            .spans
            .iter()
            .map(|s| {
                let toe = if s.foot == "left" { T2M.feet_left[1] } else { T2M.feet_right[1] };
                (toe, s.start, s.end)
            })
            .collect(),
        joints: j,
    }
}

/// results.json: the run's inputs and settings, and every sample's entry.
fn results(
    a: &SampleArgs,
    gen: &Job,
    keys: &Keys,
    secs: f64,
    samples: Vec<serde_json::Value>,
) -> serde_json::Value {
    let (opts, fit) = (&gen.opts, gen.fit);
    json!({
        "text": a.text,
        "checkpoint": a.checkpoint.display().to_string(),
        "checkpoint_step": gen.step(),
        "length": keys.length,
        "source": a.from.as_ref().or(a.keyframes.as_ref()).map(|p| p.display().to_string()),
        "keyframes": keys.frames,
        "keyframe_joints": keys.joints,
        "sampler": format!("{:?}", opts.sampler),
        "kf_guidance": opts.kf_guidance,
        "text_guidance": opts.text_guidance,
        "transition_guidance": opts.transition,
        "keyframe_fit": fit.keyframes,
        "foot_lock": fit.foot_lock,
        "feet": fit.foot_lock.then_some(fit.feet),
        "foot_lock_reach_m": fit.lock_reach,
        "root_keys": keys.root.iter().enumerate().filter(|(_, k)| **k != RootKey::default()).map(|(f, k)| json!({"frame": f, "place": k.place, "heading_deg": k.heading.map(f64::to_degrees)})).collect::<Vec<_>>(),
        "keyframe_mode": format!("{:?}", a.keyframe_mode).to_lowercase(),
        "tg_mode": format!("{:?}", a.tg_mode).to_lowercase(),
        "tg_window": opts.window,
        "tg_bases": opts.dct_bases,
        "seed": a.seed,
        "seconds": secs,
        "real_k_trans": keys.source.as_ref().and_then(|s| k_trans(s, &keys.frames, 2)),
        "real_foot_skating": keys.source.as_ref().map(|s| diffkfc_data::motion::plausibility::foot_skating_ratio(&T2M, s)),
        "real_penetration_m": keys.source.as_ref().map(|s| diffkfc_data::motion::plausibility::penetration(&T2M, s)),
        "real_gait": keys.source.as_ref().map(|s| diffkfc_eval::gait::measure(&T2M, s)),
        "samples": samples,
    })
}

/// "track fit: largest correction pose ..., place ... m, heading ... deg" of a sample entry.
fn fit_note(s: &serde_json::Value, fit: Fit) -> Option<String> {
    let most = |k: &str| {
        s["corrections"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|c| c[k].as_f64())
            .map(f64::abs)
            .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))))
    };
    match (most("pose"), most("place_m"), most("heading_deg")) {
        (None, None, None) => None,
        (p, m, h) => Some(format!(
            "{} fit: largest correction pose {}, place {} m, heading {} deg",
            fit.keyframes,
            p.map_or("-".into(), |v| format!("{v:.3}")),
            m.map_or("-".into(), |v| format!("{v:.3}")),
            h.map_or("-".into(), |v| format!("{v:.1}"))
        )),
    }
}

/// "foot lock: N frames moved; ..." of a sample entry.
fn lock_note(s: &serde_json::Value) -> Option<String> {
    let frames = s["foot_lock"]["frames"].as_u64()?;
    Some(format!(
        "foot lock: {frames} frames moved; spans left: {} dragged, {} out of reach, {} worse held",
        s["foot_lock"]["dragged"], s["foot_lock"]["out_of_reach"], s["foot_lock"]["worse"]
    ))
}

/// The folder's page: the 3D view of the source and every sample, the settings above it.
fn index_html(r: &serde_json::Value, views: &[ViewMotion], segments: &[(usize, String)]) -> String {
    let intro = format!(
        "<p>{} frames &middot; {} &middot; {} &middot; keyframe guidance {} &middot; text guidance {} &middot; transition guidance {} &middot; fit {} &middot; <a href=results.json>results.json</a>{}</p>",
        r["length"],
        keyframe_list(&r["keyframes"]),
        escape(r["sampler"].as_str().unwrap_or("")),
        r["kf_guidance"],
        r["text_guidance"],
        r["transition_guidance"],
        escape(&r["keyframe_fit"].to_string()),
        r["source"].as_str().map(|s| format!(" &middot; source {}", escape(s))).unwrap_or_default()
    );
    viewer::page(&T2M, r["text"].as_str().unwrap_or("diffkfc"), &intro, views, segments)
}

/// "keyframes at frames 0, 40, 80", or a count and range where there are many.
fn keyframe_list(k: &serde_json::Value) -> String {
    let f: Vec<u64> = k.as_array().into_iter().flatten().filter_map(|v| v.as_u64()).collect();
    match (f.first(), f.last()) {
        (Some(a), Some(b)) if f.len() > 12 => format!("{} keyframes (frames {a} to {b})", f.len()),
        (Some(_), _) => format!(
            "keyframes at frames {}",
            f.iter().map(u64::to_string).collect::<Vec<_>>().join(", ")
        ),
        _ => "no keyframes".into(),
    }
}

/// K-Err as a sentence: global only where there is a source motion to compare with.
fn k_err_text(s: &serde_json::Value) -> String {
    match (s["k_err_m"].as_f64(), s["k_err_root_relative_m"].as_f64()) {
        (Some(g), Some(l)) => format!("K-Err {g:.4} m (root-relative {l:.4} m)"),
        (None, Some(l)) => format!("K-Err root-relative {l:.4} m (global: no source motion)"),
        (Some(g), None) => format!("K-Err {g:.4} m"),
        (None, None) => "no posed keyframes (K-Err: -)".into(),
    }
}

fn fmt(v: &serde_json::Value) -> String {
    v.as_f64().map(|x| format!("{x:.4}")).unwrap_or_else(|| "-".into())
}

/// The file that marks a folder as `sample`'s.
const MARKER: &str = diffkfc_data::io::ownership::Output::Samples.marker();

/// The names a `sample` folder's files have.
fn is_output(name: &str) -> bool {
    if ["results.json", "index.html", "source_joints.npy"].contains(&name) {
        return true;
    }
    let Some(rest) = name.strip_prefix("sample_") else {
        return false;
    };
    let (num, tail) = rest.split_at(rest.find(|c: char| !c.is_ascii_digit()).unwrap_or(rest.len()));
    !num.is_empty()
        && [".npy", "_joints.npy", ".gif", ".bvh", ".glb", "_root_path.npy"].contains(&tail)
}

/// `--out` may take this run's outputs (checked before any work).
pub(super) fn check_out(a: &SampleArgs) -> Result<()> {
    // With --prompts each prompt has its own folder below --out.
    if a.prompts.is_none() {
        OutputSet::check(&a.out, MARKER, is_output, a.force, "--out")?;
    }
    Ok(())
}
