//! The report files an evaluation leaves in its --out folder: `report.json` (every number)
//! and `report.md` (the tables), written atomically, the tables echoed to the terminal.

use std::path::Path;

use anyhow::Result;

/// `report.json` and `report.md` in `out` (written atomically), the table on stdout.
pub(crate) fn write(out: &Path, json: &serde_json::Value, md: &str) -> Result<()> {
    diffkfc_data::write_atomic(
        &out.join("report.json"),
        serde_json::to_string_pretty(json)?.as_bytes(),
    )?;
    diffkfc_data::write_atomic(&out.join("report.md"), md.as_bytes())?;
    println!(
        "{md}\nwrote {} and {}",
        out.join("report.json").display(),
        out.join("report.md").display()
    );
    Ok(())
}
