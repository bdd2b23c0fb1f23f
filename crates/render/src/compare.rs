//! A page comparing sample folders (`diffkfc sample --out`), as `diffkfc render --page` writes
//! it: per folder its GIF, prompt, keyframes and numbers beside its source's, grouped by the
//! model that made them, a link to the folder's own page, the 3D view of all of them side by
//! side (`view.html`), a contact sheet and a training run's loss plot; and the same numbers as
//! a plain-text table for the terminal.

use std::path::{Component, Path, PathBuf};

use serde_json::Value;

use crate::viewer::escape;
use diffkfc_data::DataError;

/// One sample folder: where it is, what it is called on the page, and its results.json.
#[derive(Clone, Debug)]
pub struct Folder {
    pub dir: PathBuf,
    pub label: String,
    pub results: Value,
}

impl Folder {
    /// Read `dir/results.json`.
    pub fn read(dir: &Path, label: String) -> Result<Folder, DataError> {
        let path = dir.join("results.json");
        let text = std::fs::read_to_string(&path)
            .map_err(|err| DataError::Io { path: path.clone(), err })?;
        let results: Value = serde_json::from_str(&text).map_err(|e| DataError::Npy {
            path: path.clone(),
            msg: format!("not a sample folder's results.json: {e}"),
        })?;
        if results["samples"].as_array().is_none_or(|s| s.is_empty()) {
            return Err(DataError::Npy { path, msg: "no samples listed".into() });
        }
        Ok(Folder { dir: dir.to_path_buf(), label, results })
    }

    fn sample(&self) -> &Value {
        &self.results["samples"][0]
    }

    /// The first sample's joint positions file.
    pub fn joints_path(&self) -> PathBuf {
        self.dir.join(self.sample()["joints"].as_str().unwrap_or("sample_00_joints.npy"))
    }

    /// The keyed frames, or a word for keys on every frame.
    pub fn keyframes(&self) -> String {
        let keys = self.results["keyframes"].as_array().cloned().unwrap_or_default();
        let length = self.results["length"].as_u64().unwrap_or(0) as usize;
        if keys.is_empty() {
            "none".into()
        } else if keys.len() == length {
            match self.results["keyframe_joints"].as_array() {
                Some(j) if j.len() < 22 => "all frames, some joints".into(),
                _ => "all frames".into(),
            }
        } else {
            keys.iter().map(|k| k.to_string()).collect::<Vec<_>>().join(", ")
        }
    }

    /// The numbers of the first sample and of its source: (column, sample, source).
    pub fn numbers(&self) -> Vec<(&'static str, Option<f64>, Option<f64>)> {
        let (s, r) = (self.sample(), &self.results);
        let place = s["corrections"].as_array().map(|c| {
            c.iter().filter_map(|c| c["place_m"].as_f64()).fold(0.0, |m, v| v.abs().max(m))
        });
        let lifted = s["foot_lock"]["lifted"]
            .as_f64()
            .zip(r["length"].as_f64())
            .map(|(l, n)| l / (2.0 * n).max(1.0));
        // Steps lowers the pelvis for its stances, the stride warp for its strides.
        let drop = s["foot_lock"]["pelvis_drop_m"]
            .as_f64()
            .filter(|&d| d > 0.0)
            .or_else(|| s["stride"]["pelvis_drop_m"].as_f64());
        vec![
            ("K-Err (m)", s["k_err_m"].as_f64(), None),
            ("K-Err root-rel. (m)", s["k_err_root_relative_m"].as_f64(), None),
            ("K-TranS", s["k_trans"].as_f64(), r["real_k_trans"].as_f64()),
            ("foot skating", s["foot_skating"].as_f64(), r["real_foot_skating"].as_f64()),
            (
                "planted share",
                s["gait"]["planted_share"].as_f64(),
                r["real_gait"]["planted_share"].as_f64(),
            ),
            (
                "stride (m)",
                s["gait"]["stride_amplitude_m"].as_f64(),
                r["real_gait"]["stride_amplitude_m"].as_f64(),
            ),
            (
                "root speed (m/s)",
                s["gait"]["root_speed_mps"].as_f64(),
                r["real_gait"]["root_speed_mps"].as_f64(),
            ),
            ("place correction (m)", place, None),
            ("stride warp factor", s["stride"]["mean_factor"].as_f64(), None),
            ("toe frames lifted", lifted, None),
            ("pelvis drop (m)", drop, None),
        ]
    }

    /// The model that made the folder, and the checkpoint's step.
    pub fn model(&self) -> String {
        let r = &self.results;
        let step = r["checkpoint_step"].as_u64().map_or(String::new(), |s| format!(", step {s}"));
        format!("{}{step}", r["checkpoint"].as_str().unwrap_or("?"))
    }
}

fn num(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

/// "sample (source)" of a number that has a source value.
fn pair(s: Option<f64>, r: Option<f64>, has_source: bool) -> String {
    if has_source {
        format!("{} ({})", num(s), num(r))
    } else {
        num(s)
    }
}

/// Widest line the terminal table prints (a standard terminal shows 100 characters).
pub const TABLE_WIDTH: usize = 100;

/// The numbers of every folder as plain text for the terminal: a line per folder with its
/// prompt and keyframes, then a table with a row per number and a column per folder (a
/// source's value in brackets after the sample's); folders that do not fit in
/// [`TABLE_WIDTH`] characters go on into a second table below. The page shows them all.
pub fn text_table(folders: &[Folder]) -> String {
    let numbers: Vec<_> = folders.iter().map(Folder::numbers).collect();
    let Some(first) = numbers.first() else { return String::new() };
    let clip = |s: String| -> String {
        if s.chars().count() <= TABLE_WIDTH {
            s
        } else {
            s.chars().take(TABLE_WIDTH - 3).collect::<String>() + "..."
        }
    };
    let mut out: Vec<String> = folders
        .iter()
        .map(|f| {
            let text = f.results["text"].as_str().unwrap_or("");
            clip(format!("{}: \"{text}\", keys {}", f.label, f.keyframes()))
        })
        .collect();
    let labels: Vec<String> = first
        .iter()
        .enumerate()
        .map(|(c, (name, ..))| {
            let sourced = numbers.iter().any(|n| n[c].2.is_some());
            if sourced {
                format!("{name} (source)")
            } else {
                name.to_string()
            }
        })
        .collect();
    let label_w = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let cells: Vec<Vec<String>> = numbers
        .iter()
        .map(|n| {
            n.iter()
                .zip(&labels)
                .map(|((_, s, r), l)| pair(*s, *r, l.ends_with("(source)")))
                .collect()
        })
        .collect();
    out.extend(columns(folders, &labels, &cells, label_w));
    out.join("\n")
}

/// The table's rows: a heading row of folder labels and a row per number, the folders that do
/// not fit in [`TABLE_WIDTH`] characters going on into another table below.
fn columns(
    folders: &[Folder],
    labels: &[String],
    cells: &[Vec<String>],
    label_w: usize,
) -> Vec<String> {
    let col_w: Vec<usize> = folders
        .iter()
        .zip(cells)
        .map(|(f, c)| c.iter().chain([&f.label]).map(|v| v.chars().count()).max().unwrap_or(0))
        .collect();
    let mut out = Vec::new();
    let mut start = 0;
    while start < folders.len() {
        let mut end = start + 1;
        let mut width = label_w + 3 + col_w[start];
        while end < folders.len() && width + 3 + col_w[end] <= TABLE_WIDTH {
            width += 3 + col_w[end];
            end += 1;
        }
        let row = |first: &str, vals: Vec<&str>| -> String {
            let mut line = format!("{first:<label_w$}");
            for (v, w) in vals.iter().zip(&col_w[start..end]) {
                line += &format!(" | {v:<w$}");
            }
            line.trim_end().to_string()
        };
        out.push(row("", folders[start..end].iter().map(|f| f.label.as_str()).collect()));
        for (r, l) in labels.iter().enumerate() {
            out.push(row(l, cells[start..end].iter().map(|c| c[r].as_str()).collect()));
        }
        start = end;
    }
    out
}

/// `to` as a path relative to the folder `from` (both made absolute first), with `/` separators.
pub fn relative(from: &Path, to: &Path) -> String {
    let abs = |p: &Path| {
        let p = if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir().unwrap_or_default().join(p)
        };
        p.components().fold(PathBuf::new(), |mut acc, c| {
            match c {
                Component::ParentDir => {
                    acc.pop();
                }
                Component::CurDir => {}
                c => acc.push(c),
            }
            acc
        })
    };
    let (from, to) = (abs(from), abs(to));
    let (f, t): (Vec<_>, Vec<_>) = (from.components().collect(), to.components().collect());
    let common = f.iter().zip(&t).take_while(|(a, b)| a == b).count();
    let mut parts: Vec<String> = vec!["..".into(); f.len() - common];
    parts.extend(t[common..].iter().map(|c| c.as_os_str().to_string_lossy().into_owned()));
    if parts.is_empty() {
        ".".into()
    } else {
        parts.join("/")
    }
}

/// What the page shows beside the folders: its title, and the files written next to it
/// (relative links), each optional.
pub struct PageParts<'a> {
    pub title: &'a str,
    pub view: Option<&'a str>,
    pub sheet: Option<&'a str>,
    /// (loss plot, the run it belongs to).
    pub loss: Option<(&'a str, &'a str)>,
}

/// The page, in folder `at` (links are relative to it): sections by model, a figure and a
/// table row per folder.
pub fn page(at: &Path, folders: &[Folder], parts: &PageParts) -> String {
    let mut models: Vec<String> = Vec::new();
    for f in folders {
        if !models.contains(&f.model()) {
            models.push(f.model());
        }
    }
    let mut body = String::new();
    if let Some(v) = parts.view {
        body += &format!("<p><iframe src='{v}' style='width:100%;height:900px;border:0' title='3D view'></iframe><br><a href='{v}'>the 3D view on its own page</a>; each folder's page has its own view with the source motion and the keyframes.</p>");
    }
    for m in &models {
        let group: Vec<&Folder> = folders.iter().filter(|f| &f.model() == m).collect();
        body += &format!("<h2>Model {}</h2>", escape(m));
        body += &section(at, &group);
    }
    if let Some((loss, run)) = parts.loss {
        body += &format!("<h2>Training run {}</h2><p><a href='{loss}'>Training and validation loss</a><br><img src='{loss}' width=480 alt='loss plot'></p>", escape(run));
    }
    if let Some(s) = parts.sheet {
        let cells: Vec<String> = folders
            .iter()
            .enumerate()
            .map(|(i, f)| format!("{i} = {}", escape(&f.label)))
            .collect();
        body += &format!("<p><img src='{s}' width=720 alt='contact sheet'><br>Contact sheet (cell numbers in the corners): {}; six poses spread over each motion, light to dark, keyframes in orange.</p>", cells.join(", "));
    }
    format!(
        "<!doctype html><meta charset=utf-8><title>{t}</title><style>body{{font-family:sans-serif;max-width:1240px}}figure{{display:inline-block;margin:8px;width:320px}}td,th{{padding:4px 8px;border-bottom:1px solid #ddd}}</style><h1>{t}</h1>{body}<p>Keyframe poses are orange in the animations; each folder's index.html shows all its samples beside the source, and its results.json has the numbers (a source's value in brackets).</p>\n",
        t = escape(parts.title)
    )
}

/// The figures and the table of one model's folders.
fn section(at: &Path, group: &[&Folder]) -> String {
    let mut figs = String::new();
    let mut rows = String::new();
    for f in group {
        let rel = relative(at, &f.dir);
        let text = escape(f.results["text"].as_str().unwrap_or(""));
        let gif = f.sample()["gif"].as_str().unwrap_or("sample_00.gif");
        figs += &format!("<figure><img src='{rel}/{gif}' width=320 alt='{text}'><figcaption>{} — {text}</figcaption></figure>", escape(&f.label));
        let cells: String = f
            .numbers()
            .iter()
            .map(|(_, s, r)| format!("<td>{}</td>", pair(*s, *r, r.is_some())))
            .collect();
        rows += &format!(
            "<tr><td><a href='{rel}/index.html'>{}</a></td><td>{text}</td><td>{}</td>{cells}</tr>",
            escape(&f.label),
            escape(&f.keyframes())
        );
    }
    let head: String =
        group[0]
            .numbers()
            .iter()
            .map(|(c, _, r)| {
                if r.is_some() {
                    format!("<th>{c} (source)</th>")
                } else {
                    format!("<th>{c}</th>")
                }
            })
            .collect();
    format!("{figs}<table><tr><th>folder (its page)</th><th>prompt</th><th>keyframes</th>{head}</tr>{rows}</table>")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths() {
        assert_eq!(relative(Path::new("/a/out"), Path::new("/a/out/1-keys")), "1-keys");
        assert_eq!(relative(Path::new("/a/out"), Path::new("/a/other/x")), "../other/x");
        assert_eq!(relative(Path::new("/a/out/"), Path::new("/a/./out")), ".");
    }

    fn folder(label: &str, checkpoint: &str) -> Folder {
        let results = serde_json::json!({
            "text": "a person <walks>.", "checkpoint": checkpoint, "checkpoint_step": 7, "length": 40,
            "keyframes": [0, 20], "real_k_trans": 0.011, "real_foot_skating": 0.04,
            "real_gait": {"planted_share": 0.6, "stride_amplitude_m": 0.17, "root_speed_mps": 0.8},
            "samples": [{"gif": "sample_00.gif", "joints": "sample_00_joints.npy", "k_err_m": 0.0, "k_trans": 0.009,
                         "foot_skating": 0.2, "gait": {"planted_share": 0.3, "stride_amplitude_m": 0.1, "root_speed_mps": 0.5},
                         "corrections": [{"place_m": -0.25}, {"place_m": 0.1}],
                         "foot_lock": {"lifted": 24, "pelvis_drop_m": 0.045}}],
        });
        Folder { dir: PathBuf::from(format!("/w/out/{label}")), label: label.into(), results }
    }

    #[test]
    fn table_and_page_show_every_folder_with_its_source() {
        let fs = [folder("1-keys", "models/a"), folder("2-demo", "runs/b")];
        let t = text_table(&fs);
        // A line per folder, the heading row, a row per number.
        assert_eq!(t.lines().count(), 2 + 1 + fs[0].numbers().len(), "{t}");
        assert!(t.lines().all(|l| l.chars().count() <= TABLE_WIDTH), "{t}");
        assert!(t.contains("foot skating (source)") && t.contains("0.200 (0.040)"), "{t}");
        assert!(t.contains("0, 20") && t.contains("0.250"), "{t}");
        // Seven folders do not fit in one table: the rest go on below, every line still short.
        let many: Vec<Folder> =
            (0..7).map(|i| folder(&format!("{i}-body-part-edit"), "m")).collect();
        let t7 = text_table(&many);
        assert!(t7.lines().all(|l| l.chars().count() <= TABLE_WIDTH), "{t7}");
        assert!(t7.lines().filter(|l| l.starts_with("K-Err (m)")).count() >= 2, "{t7}");
        assert!(t7.contains("6-body-part-edit"), "{t7}");
        // Steps' lifted toe frames as a share of both toes' frames (24 of 2 x 40), its drop.
        assert!(t.contains("toe frames lifted") && t.contains("0.300"), "{t}");
        assert!(t.contains("pelvis drop (m)") && t.contains("0.045"), "{t}");
        assert!(!t.contains('<') || t.contains("<walks>"), "plain text, no HTML: {t}");
        let parts = PageParts {
            title: "T",
            view: Some("view.html"),
            sheet: Some("sheet.png"),
            loss: Some(("loss.svg", "runs/b")),
        };
        let html = page(Path::new("/w/out"), &fs, &parts);
        assert!(
            html.contains("<h2>Model models/a, step 7</h2>")
                && html.contains("<h2>Model runs/b, step 7</h2>")
        );
        assert!(
            html.contains("src='1-keys/sample_00.gif'")
                && html.contains("href='2-demo/index.html'")
        );
        assert!(html.contains("a person &lt;walks&gt;.") && !html.contains("<walks>"));
        assert!(html.contains("0 = 1-keys, 1 = 2-demo") && html.contains("src='loss.svg'"));
    }
}
