//! `diffkfc render`: GIF of a motion, a contact sheet of several, a 3D page of several, or a
//! page comparing sample folders (`--page`).

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use diffkfc_data::motion::representation::Joints;
use diffkfc_data::T2M;
use diffkfc_render as render;
use diffkfc_render::viewer::{self, ViewMotion};

use diffkfc_data::io::motion_file::load_motion;

use crate::args::BvhInputArgs;

#[derive(Args)]
#[command(
    after_help = "Examples:\n  diffkfc render out/walk/sample_00_joints.npy -o walk.gif\n  diffkfc render out/a/sample_00.npy out/b/sample_00.npy --sheet -o sheet.png\n  diffkfc render --page out/walk out/jump --run runs/tiny -o out/index.html"
)]
pub struct RenderArgs {
    /// Motion files: features (T,263) or joint positions (T,22,3) .npy, or BVH files; with
    /// --page, sample folders (`diffkfc sample --out`).
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// A page comparing sample folders: each folder's GIF, prompt, keyframes and numbers beside
    /// its source's (grouped by model, linked to the folder's own page), the 3D view of all of
    /// them (view.html) and a contact sheet (sheet.png) written beside -o; the numbers are also
    /// printed as a table.
    #[arg(long)]
    page: bool,
    /// With --page: a training run whose loss plot (loss.svg) the page shows.
    #[arg(long, requires = "page", value_name = "RUN")]
    run: Option<PathBuf>,
    /// Output .gif (one input), .png (with --sheet), or .html: an interactive 3D page of all
    /// inputs side by side (orbit, play/pause, frame slider, keyframes on a timeline).
    #[arg(short, long)]
    output: PathBuf,
    /// Frames drawn highlighted (comma-separated), e.g. 0,40,80.
    #[arg(long, value_delimiter = ',')]
    keyframes: Vec<usize>,
    /// A PNG contact sheet of all inputs (each a strobe of poses) instead of a GIF.
    #[arg(long)]
    sheet: bool,
    /// Cells per row of the contact sheet.
    #[arg(long, default_value_t = 4)]
    columns: usize,
    /// Labels of the inputs, one --label per input in order (default: the file names, or the
    /// folder names where file names repeat): shown on the 3D page; a sheet numbers its cells
    /// and lists each cell's label on stdout.
    #[arg(long = "label")]
    labels: Vec<String>,
    /// Title of the .html page.
    #[arg(long, default_value = "diffkfc motions")]
    title: String,
    #[command(flatten)]
    bvh: BvhInputArgs,
}

/// The output's extension says what is drawn; anything else would write a GIF or PNG under a
/// name that says otherwise.
fn check_output(a: &RenderArgs) -> Result<()> {
    let ext = a.output.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    if a.page {
        if ext.as_deref() != Some("html") || a.sheet {
            bail!("-o: {} must end in .html with --page (and --sheet does not apply: the page has its sheet)", a.output.display());
        }
        return Ok(());
    }
    let want = if a.sheet { ["png", "html"] } else { ["gif", "html"] };
    if !ext.as_deref().is_some_and(|e| want.contains(&e)) {
        bail!(
            "-o: {} must end in .{} or .html{}",
            a.output.display(),
            want[0],
            if a.sheet {
                " (a --sheet is a PNG)"
            } else {
                " (a GIF of one motion; --sheet for a PNG)"
            }
        );
    }
    if !(1..=64).contains(&a.columns) {
        bail!("--columns: {} must be 1 to 64", a.columns);
    }
    let inputs: Vec<&std::path::Path> = a.inputs.iter().map(PathBuf::as_path).collect();
    crate::args::refuse_overwriting_input(&inputs, &a.output)?;
    Ok(())
}

pub fn run(a: RenderArgs) -> Result<()> {
    check_output(&a)?;
    if a.page {
        return crate::commands::page::run(
            &a.inputs,
            &a.labels,
            a.run.as_deref(),
            &a.title,
            &a.output,
        );
    }
    let bvh = a.bvh.options()?;
    let motions =
        a.inputs.iter().map(|p| load_motion(p, &T2M, &bvh)).collect::<Result<Vec<_>, _>>()?;
    if !a.labels.is_empty() && a.labels.len() != a.inputs.len() {
        bail!(
            "--label: {} label(s) for {} input(s); give one per input",
            a.labels.len(),
            a.inputs.len()
        );
    }
    let names = default_labels(&a.inputs);
    let label = |i: usize| a.labels.get(i).cloned().unwrap_or_else(|| names[i].clone());
    for (i, j) in motions.iter().enumerate() {
        if let Some(k) = a.keyframes.iter().find(|&&k| k >= j.len()) {
            bail!(
                "--keyframes: frame {k} is beyond {} ({} frames)",
                a.inputs[i].display(),
                j.len()
            );
        }
    }
    if a.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("html")) {
        write_view(&a, motions, &label)?;
    } else if a.sheet {
        let clips: Vec<_> = motions.into_iter().map(|j| (j, a.keyframes.clone())).collect();
        render::sheet(&T2M, &clips, a.columns, 240, &a.output)?;
        println!("{}: contact sheet of {} motion(s)", a.output.display(), clips.len());
        for i in 0..clips.len() {
            println!("  cell {i}: {}", label(i));
        }
    } else {
        if motions.len() != 1 {
            bail!(
                "render: {} inputs given; a GIF shows one motion (use --sheet for several)",
                motions.len()
            );
        }
        let j = &motions[0];
        render::gif(&T2M, j, &a.keyframes, &a.output)?;
        println!("{}: {} frames at 20 fps", a.output.display(), j.len());
    }
    Ok(())
}

/// The 3D page of `motions` (`-o x.html`), each with its keys' poses and its foot skating.
fn write_view(a: &RenderArgs, motions: Vec<Joints>, label: &dyn Fn(usize) -> String) -> Result<()> {
    let views: Vec<ViewMotion> = motions
        .into_iter()
        .enumerate()
        .map(|(i, j)| ViewMotion {
            label: label(i),
            keyframes: a.keyframes.clone(),
            key_poses: a.keyframes.iter().map(|&k| (k, j[k].clone())).collect(),
            numbers: format!(
                "{} frames, foot skating {:.4}",
                j.len(),
                diffkfc_data::motion::plausibility::foot_skating_ratio(&T2M, &j)
            ),
            joints: j,
            ..Default::default()
        })
        .collect();
    diffkfc_data::write_atomic(
        &a.output,
        viewer::page(&T2M, &a.title, "", &views, &[]).as_bytes(),
    )?;
    println!("{}: 3D page of {} motion(s)", a.output.display(), views.len());
    Ok(())
}

/// Each input's name where no --label is given: its file name without the extension, or, where
/// two inputs share one (sample_00_joints of several sample folders), its folder's name.
pub(crate) fn default_labels(inputs: &[PathBuf]) -> Vec<String> {
    let name = |p: &std::path::Path| p.file_stem().map(|s| s.to_string_lossy().into_owned());
    let stems: Vec<String> = inputs.iter().map(|p| name(p).unwrap_or_default()).collect();
    let shared = |s: &String| stems.iter().filter(|t| *t == s).count() > 1;
    inputs
        .iter()
        .zip(&stems)
        .map(|(p, s)| match p.parent().and_then(name) {
            Some(dir) if shared(s) && !dir.is_empty() => dir,
            _ => s.clone(),
        })
        .collect()
}
