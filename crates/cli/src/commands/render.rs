//! `diffkfc render`: GIF of a motion, or a contact sheet of several.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use diffkfc_data::{render, T2M};

use super::data::{load_motion, BvhInputArgs};

#[derive(Args)]
pub struct RenderArgs {
    /// Motion files: features (T,263) or joint positions (T,22,3) .npy, or BVH files.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output .gif (one input) or .png (with --sheet).
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
    #[command(flatten)]
    bvh: BvhInputArgs,
}

pub fn run(a: RenderArgs) -> Result<()> {
    let bvh = a.bvh.options()?;
    let motions = a.inputs.iter().map(|p| load_motion(p, &T2M, &bvh)).collect::<Result<Vec<_>>>()?;
    if a.sheet {
        let clips: Vec<_> = motions.into_iter().map(|j| (j, a.keyframes.clone())).collect();
        render::sheet(&T2M, &clips, a.columns, 240, &a.output)?;
        println!("{}: contact sheet of {} motion(s)", a.output.display(), clips.len());
    } else {
        if motions.len() != 1 {
            bail!("render: {} inputs given; a GIF shows one motion (use --sheet for several)", motions.len());
        }
        let j = &motions[0];
        if let Some(k) = a.keyframes.iter().find(|&&k| k >= j.len()) {
            bail!("--keyframes: frame {k} is beyond the motion ({} frames)", j.len());
        }
        render::gif(&T2M, j, &a.keyframes, &a.output)?;
        println!("{}: {} frames at 20 fps", a.output.display(), j.len());
    }
    Ok(())
}
