//! `diffkfc render`: GIF of a motion, a contact sheet of several, or a 3D page of several.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use diffkfc_data::render::viewer::{self, ViewMotion};
use diffkfc_data::{render, T2M};

use diffkfc_data::io::motion_file::load_motion;

use crate::args::BvhInputArgs;

#[derive(Args)]
pub struct RenderArgs {
    /// Motion files: features (T,263) or joint positions (T,22,3) .npy, or BVH files.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
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
    /// Labels of the inputs, one --label per input in order (default: the file names): shown on
    /// the 3D page; a sheet numbers its cells and lists each cell's label on stdout.
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
    let label = |i: usize| {
        a.labels.get(i).cloned().unwrap_or_else(|| {
            a.inputs[i].file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
        })
    };
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
