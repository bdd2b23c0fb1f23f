//! `diffkfc blender-addon`: the Blender add-on (`blender/diffkfc_blender`, built into the
//! binary) as the zip Blender's "Install add-on" takes.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, ZipWriter};

#[derive(Args)]
pub struct BlenderAddonArgs {
    /// The zip to write.
    #[arg(short, long, default_value = "diffkfc_blender.zip")]
    out: PathBuf,
}

/// The add-on's files, as Blender finds them in the zip.
const FILES: [(&str, &str); 2] = [
    (
        "diffkfc_blender/__init__.py",
        include_str!("../../../../blender/diffkfc_blender/__init__.py"),
    ),
    ("diffkfc_blender/rig.py", include_str!("../../../../blender/diffkfc_blender/rig.py")),
];

/// The add-on as zip bytes.
fn zipped() -> Result<Vec<u8>> {
    let mut z = ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = SimpleFileOptions::default().compression_method(CompressionMethod::Stored);
    for (name, text) in FILES {
        z.start_file(name, opts)?;
        z.write_all(text.as_bytes())?;
    }
    Ok(z.finish()?.into_inner())
}

pub fn run(a: BlenderAddonArgs) -> Result<()> {
    diffkfc_data::write_atomic(&a.out, &zipped()?)
        .with_context(|| format!("--out {}", a.out.display()))?;
    println!(
        "{}: the diffkfc add-on; in Blender: Edit > Preferences > Add-ons > Install..., enable \"diffkfc\", then the 3D view's sidebar (N) > diffkfc",
        a.out.display()
    );
    Ok(())
}
