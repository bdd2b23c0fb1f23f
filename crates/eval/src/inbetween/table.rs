//! The benchmark's summary: per gap, every method's scores averaged over the clips, and the
//! table a user reads (errors as ratios of interpolation's, realism as ratios of the clip's).

use serde::Serialize;

use super::{ClipScores, GapScores, Scores};

/// The methods in the order the table lists them.
pub const METHODS: [&str; 4] = ["clip", "interpolation", "network", "pipeline"];

/// Each of [`METHODS`]' scores in a clip's gap.
const SCORES_OF: [fn(&GapScores) -> Scores; 4] =
    [|s| s.clip, |s| s.interpolation, |s| s.network, |s| s.pipeline];

/// One gap's mean scores over the clips, per method (in [`METHODS`] order).
#[derive(Clone, Debug, Serialize)]
pub struct GapSummary {
    pub gap: String,
    pub clips: usize,
    pub mean_keys: f64,
    pub methods: Vec<(String, Scores)>,
}

impl GapSummary {
    /// The mean scores of `method` (one of [`METHODS`]).
    pub fn of(&self, method: &str) -> Option<&Scores> {
        self.methods.iter().find(|(m, _)| m == method).map(|(_, s)| s)
    }
}

fn mean(v: &[Scores]) -> Scores {
    let n = v.len().max(1) as f64;
    let sum = |f: fn(&Scores) -> f64| v.iter().map(f).sum::<f64>() / n;
    Scores {
        error_m: sum(|s| s.error_m),
        error_local_m: sum(|s| s.error_local_m),
        key_place_m: sum(|s| s.key_place_m),
        foot_skating: sum(|s| s.foot_skating),
        planted_share: sum(|s| s.planted_share),
        k_trans: sum(|s| s.k_trans),
    }
}

/// Per gap (in the clips' order of gaps), the mean over `clips` of every method's scores.
pub fn summarise(clips: &[ClipScores]) -> Vec<GapSummary> {
    let Some(first) = clips.first() else { return vec![] };
    (0..first.gaps.len())
        .map(|g| {
            let at: Vec<_> = clips.iter().map(|c| &c.gaps[g]).collect();
            let pick = |f: fn(&GapScores) -> Scores| at.iter().map(|s| f(s)).collect::<Vec<_>>();
            GapSummary {
                gap: first.gaps[g].gap.clone(),
                clips: at.len(),
                mean_keys: at.iter().map(|s| s.keys.len() as f64).sum::<f64>() / at.len() as f64,
                methods: METHODS
                    .iter()
                    .zip(SCORES_OF)
                    .map(|(&name, of)| (name.to_string(), mean(&pick(of))))
                    .collect(),
            }
        })
        .collect()
}

fn ratio(a: f64, b: f64) -> String {
    if b > 1e-12 {
        format!("{:.2}x", a / b)
    } else {
        "-".into()
    }
}

/// The Markdown table: one row per gap and method.
pub fn to_markdown(summary: &[GapSummary]) -> String {
    let mut s = String::from(
        "| keys | method | error (m) | / interp. | root-rel. (m) | / interp. | key places (m) | skating | / clip | planted | / clip | K-TranS | / clip |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for g in summary {
        let (Some(interp), Some(clip)) = (g.of("interpolation"), g.of("clip")) else { continue };
        for (name, m) in &g.methods {
            let keys = format!("{} ({:.1} keys)", g.gap, g.mean_keys);
            let errors = if name == "clip" {
                "- | - | - | - | -".to_string()
            } else {
                format!(
                    "{:.3} | {} | {:.3} | {} | {:.3}",
                    m.error_m,
                    ratio(m.error_m, interp.error_m),
                    m.error_local_m,
                    ratio(m.error_local_m, interp.error_local_m),
                    m.key_place_m
                )
            };
            s += &format!(
                "| {keys} | {name} | {errors} | {:.3} | {} | {:.3} | {} | {:.4} | {} |\n",
                m.foot_skating,
                ratio(m.foot_skating, clip.foot_skating),
                m.planted_share,
                ratio(m.planted_share, clip.planted_share),
                m.k_trans,
                ratio(m.k_trans, clip.k_trans),
            );
        }
    }
    s
}
