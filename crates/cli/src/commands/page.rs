//! `diffkfc render --page`: one page comparing sample folders (`diffkfc_render::compare`),
//! with the 3D view of all of them, a contact sheet and a run's loss plot written beside it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use diffkfc_data::io::motion_file::load_motion;
use diffkfc_data::io::rig::ImportOptions;
use diffkfc_data::T2M;
use diffkfc_render as render;
use diffkfc_render::compare::{self, Folder, PageParts};
use diffkfc_render::viewer::{self, ViewMotion};

/// Read the folders, write view.html, sheet.png (and loss.svg from `run`) beside `out`, then
/// `out` itself; print the table.
pub fn run(
    dirs: &[PathBuf],
    labels: &[String],
    run: Option<&Path>,
    title: &str,
    out: &Path,
) -> Result<()> {
    let folders = read_folders(dirs, labels)?;
    let at = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(at).with_context(|| format!("-o: creating {}", at.display()))?;
    write_view_and_sheet(&folders, title, at)?;
    let loss = match run {
        Some(r) => {
            let svg = r.join("loss.svg");
            let bytes =
                std::fs::read(&svg).with_context(|| format!("--run: reading {}", svg.display()))?;
            diffkfc_data::write_atomic(&at.join("loss.svg"), &bytes)?;
            true
        }
        None => false,
    };
    let run_name = run.map(|r| r.display().to_string()).unwrap_or_default();
    let parts = PageParts {
        title,
        view: Some("view.html"),
        sheet: Some("sheet.png"),
        loss: loss.then_some(("loss.svg", run_name.as_str())),
    };
    diffkfc_data::write_atomic(out, compare::page(at, &folders, &parts).as_bytes())?;
    println!("{}", compare::text_table(&folders));
    println!(
        "{}: page of {} folder(s) (view.html, sheet.png{} beside it)",
        out.display(),
        folders.len(),
        if loss { ", loss.svg" } else { "" }
    );
    Ok(())
}

/// The sample folders, each labelled by its --label or else its name.
fn read_folders(dirs: &[PathBuf], labels: &[String]) -> Result<Vec<Folder>> {
    if !labels.is_empty() && labels.len() != dirs.len() {
        bail!(
            "--label: {} label(s) for {} folder(s); give one per folder",
            labels.len(),
            dirs.len()
        );
    }
    let name = |d: &PathBuf| {
        d.file_name().map_or_else(|| d.display().to_string(), |n| n.to_string_lossy().into_owned())
    };
    let folders = dirs
        .iter()
        .enumerate()
        .map(|(i, d)| Folder::read(d, labels.get(i).cloned().unwrap_or_else(|| name(d))))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(folders)
}

/// view.html (the 3D view of every folder's motion, keys marked) and sheet.png in `at`.
fn write_view_and_sheet(folders: &[Folder], title: &str, at: &Path) -> Result<()> {
    let motions = folders
        .iter()
        .map(|f| {
            let j = load_motion(&f.joints_path(), &T2M, &ImportOptions::default())?;
            Ok((j, keyframes(f)))
        })
        .collect::<Result<Vec<_>>>()?;
    let views: Vec<ViewMotion> = folders
        .iter()
        .zip(&motions)
        .map(|(f, (j, keys))| ViewMotion {
            label: f.label.clone(),
            joints: j.clone(),
            keyframes: keys.clone(),
            numbers: f.results["text"].as_str().unwrap_or("").to_string(),
            ..Default::default()
        })
        .collect();
    diffkfc_data::write_atomic(
        &at.join("view.html"),
        viewer::page(&T2M, title, "", &views, &[]).as_bytes(),
    )?;
    render::sheet(&T2M, &motions, motions.len().min(4), 240, &at.join("sheet.png"))?;
    Ok(())
}

/// The keyed frames of a folder's results.json.
fn keyframes(f: &Folder) -> Vec<usize> {
    f.results["keyframes"].as_array().map_or_else(Vec::new, |k| {
        k.iter().filter_map(|v| v.as_u64().map(|v| v as usize)).collect()
    })
}
