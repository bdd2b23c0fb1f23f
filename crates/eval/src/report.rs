//! Reports of an evaluation: mean and 95% interval over replications per row and metric, as
//! JSON and as Markdown tables laid out like the paper's Table 2 (rows: configurations at one
//! keyframe rate) and Table 4 (rows: keyframe rates).

use serde_json::{json, Value};

use crate::protocol::RowResult;
use crate::text_motion::mean_ci;

/// Metric key, column header (arrow: lower / higher / closer to real is better).
pub const COLUMNS: [(&str, &str); 16] = [
    ("fid", "FID ↓"),
    ("r_top1", "R-Prec top-1 ↑"),
    ("r_top2", "top-2 ↑"),
    ("r_top3", "top-3 ↑"),
    ("mm_dist", "MM-Dist ↓"),
    ("diversity", "Diversity →"),
    ("multimodality", "MModality ↑"),
    ("ade", "ADE ↓"),
    ("k_err", "K-Err ↓"),
    ("k_err_local", "K-Err root-rel. ↓"),
    ("k_trans", "K-TranS →"),
    ("k_trans_real", "K-TranS real"),
    ("foot_skate", "Foot skate ↓"),
    ("penetrate", "Penetrate (m) ↓"),
    ("planted", "Planted →"),
    ("stride", "Stride (m) →"),
];

/// The definitions printed with every report (the paper gives the keyframe metrics in words).
pub const DEFINITIONS: &str = "\
- FID, R-Precision (batches of 32), MM-Dist, Diversity (300 pairs), MultiModality (30 generations per text, 10 pairs): Guo et al. 2022 on the evaluator's 512-d embeddings; FID against the real test motions.
- Text rank (report.json only, `per_item.text_rank`, in the order of `meta.items`' clips and captions): per motion, how many of its R-precision batch's other texts lie nearer than its own (0 is best; top-3 counts ranks 0-2).
- FID's mean term (report.json only, `fid_mean_term`): |mu_generated - mu_real|^2, the part of FID from where the two sets sit; the rest of FID is the covariance term (how they spread).
- ADE: per item, the smallest over the samples of the mean L2 joint error (global positions, metres) against the ground truth on non-keyframe frames.
- K-Err: mean L2 joint error at keyframe frames between the given keyframe and the generated pose (global; root-rel.: joint heights/RIC positions in the facing-normalised root frame).
- K-TranS: mean |x[j+1] - 2x[j] + x[j-1]| (metres per frame^2) over frames within 2 of a keyframe, averaged over joints and keyframes; the real motion gives the reference (closer is better).
- Foot skate: among frames with a toe below 5 cm, the share moving horizontally faster than 0.5 m/s.
- Penetrate: per frame, how far the lowest joint is below the floor (height 0; nothing when above), the mean over frames (metres; PhysDiff's measure).
- Planted: the share of frames on which a toe is within 5 cm of the motion's floor (the lowest toe height) and moves slower than 0.15 m/s horizontally, the mean of the two toes; the real motion gives the reference.
- Stride: per toe, the standard deviation over frames of its offset from the pelvis along the travel direction (the root's velocity over 9 frames, or the facing direction where slower than 0.1 m/s), mean of the two toes (metres); the real motion gives the reference.
- Keyframe metrics average over every generated sample; text-motion metrics use the first sample of each item.";

fn row_name(r: &RowResult) -> String {
    r.setting.as_ref().map_or_else(|| "Real motion".to_string(), |s| s.name.clone())
}

fn cell(r: &RowResult, key: &str) -> String {
    match r.values.get(key).filter(|v| !v.is_empty()) {
        Some(v) => {
            let (m, ci) = mean_ci(v);
            if v.len() > 1 {
                format!("{m:.3} ± {ci:.3}")
            } else {
                format!("{m:.3}")
            }
        }
        None => "-".into(),
    }
}

fn rate_label(rate: f64) -> String {
    format!("{}%", (rate * 1000.0).round() / 10.0)
}

/// Columns that some row of `rows` has.
fn present<'c>(rows: &[&RowResult], skip: &[&str]) -> Vec<(&'c str, &'c str)> {
    COLUMNS
        .iter()
        .copied()
        .filter(|(k, _)| {
            !skip.contains(k) && rows.iter().any(|r| r.values.get(k).is_some_and(|v| !v.is_empty()))
        })
        .collect()
}

fn table(first: &str, rows: &[(String, &RowResult)], skip: &[&str]) -> String {
    let refs: Vec<&RowResult> = rows.iter().map(|(_, r)| *r).collect();
    let cols = present(&refs, skip);
    let mut s = format!(
        "| {first} | {} |\n|---|{}\n",
        cols.iter().map(|c| c.1).collect::<Vec<_>>().join(" | "),
        "---|".repeat(cols.len())
    );
    for (label, r) in rows {
        s += &format!(
            "| {label} | {} |\n",
            cols.iter().map(|(k, _)| cell(r, k)).collect::<Vec<_>>().join(" | ")
        );
    }
    s
}

/// Table 2: the real row and every setting at `rate`.
pub fn table2(rows: &[RowResult], rate: f64) -> Option<String> {
    let at: Vec<(String, &RowResult)> =
        rows.iter().filter(|r| r.rate == rate).map(|r| (row_name(r), r)).collect();
    (at.iter().any(|(_, r)| r.setting.is_some())).then(|| table("Method", &at, &["k_trans_real"]))
}

/// Table 4: the rows of the setting named `name` at each rate, with the real K-TranS.
pub fn table4(rows: &[RowResult], name: &str) -> Option<String> {
    let mut at: Vec<(String, &RowResult)> = rows
        .iter()
        .filter(|r| r.setting.as_ref().is_some_and(|s| s.name == name))
        .map(|r| (rate_label(r.rate), r))
        .collect();
    at.sort_by(|a, b| a.1.rate.total_cmp(&b.1.rate));
    (at.len() > 1).then(|| table("Keyframe rate", &at, &[]))
}

pub fn to_json(rows: &[RowResult], meta: Value) -> Value {
    let rows: Vec<Value> = rows
        .iter()
        .map(|r| {
            let metrics: serde_json::Map<String, Value> = r
                .values
                .iter()
                .filter(|(_, v)| !v.is_empty())
                .map(|(k, v)| {
                    let (m, ci) = mean_ci(v);
                    (k.to_string(), json!({"mean": m, "ci95": ci, "replications": v}))
                })
                .collect();
            json!({
                "name": row_name(r),
                "real": r.setting.is_none(),
                "keyframe_rate": r.rate,
                "keyframe_mode": r.setting.as_ref().map(|s| if s.inpaint { "inpaint" } else { "diffkfc" }),
                "transition_guidance": r.setting.as_ref().map(|s| s.transition),
                "metrics": metrics,
                "per_item": r.per_item,
            })
        })
        .collect();
    json!({"meta": meta, "definitions": DEFINITIONS, "rows": rows})
}

/// The Markdown report: a header with the run's settings, Table 2 at `main_rate`, Table 4 of
/// `sweep_name` when it has several rates, and the metric definitions.
pub fn to_markdown(rows: &[RowResult], header: &str, main_rate: f64, sweep_name: &str) -> String {
    let mut s = format!("# diffkfc evaluation\n\n{header}\n");
    if let Some(t) = table2(rows, main_rate) {
        s += &format!("\n## Table 2 layout: methods at {} keyframes\n\n{t}", rate_label(main_rate));
    }
    if let Some(t) = table4(rows, sweep_name) {
        s += &format!("\n## Table 4 layout: {sweep_name} by keyframe rate\n\n{t}");
    }
    s + &format!("\nMean ± 95% interval (1.96 std / sqrt(replications)).\n\n## Definitions\n\n{DEFINITIONS}\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{Setting, Values};

    fn row(name: Option<&str>, rate: f64, fid: &[f64]) -> RowResult {
        let mut values = Values::new();
        values.insert("fid", fid.to_vec());
        RowResult {
            per_item: Default::default(),
            setting: name.map(|n| Setting {
                name: n.into(),
                rate,
                inpaint: false,
                transition: 100.0,
                suggested: false,
            }),
            rate,
            values,
        }
    }

    #[test]
    fn tables_layout() {
        let rows = vec![
            row(None, 0.05, &[0.01, 0.03]),
            row(Some("DiffKFC"), 0.05, &[1.0, 3.0]),
            row(Some("DiffKFC"), 0.0, &[2.0]),
            row(Some("MDM-inp"), 0.05, &[4.0]),
        ];
        let t2 = table2(&rows, 0.05).unwrap();
        assert!(t2.contains("| Real motion | 0.020 ± 0.014 |"), "{t2}");
        assert!(
            t2.contains("| DiffKFC | 2.000 ± 1.386 |") && t2.contains("| MDM-inp | 4.000 |"),
            "{t2}"
        );
        let t4 = table4(&rows, "DiffKFC").unwrap();
        assert!(t4.find("| 0% |").unwrap() < t4.find("| 5% |").unwrap(), "{t4}");
        assert!(table4(&rows, "MDM-inp").is_none());
        let j = to_json(&rows, json!({}));
        assert_eq!(j["rows"][1]["metrics"]["fid"]["mean"], 2.0);
    }
}
