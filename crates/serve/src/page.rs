//! The editor's page: one HTML document with its scripts (the viewer's shared scene code, the
//! pose math, the view and the editor) and the skeleton facts they need, served at `/`.

use diffkfc_data::motion::{quat, representation as rep};
use diffkfc_data::{Skeleton, T2M};
use diffkfc_model::sampling::sampler::DEFAULT_STEPS;
use diffkfc_render::viewer::{escape, SCENE_JS};
use serde_json::json;

use crate::api::Limits;

const POSE_JS: &str = include_str!("page/pose.js");
const VIEW_JS: &str = include_str!("page/view.js");
const EDITOR_JS: &str = include_str!("page/editor.js");
const STYLE: &str = include_str!("page/editor.css");
const BODY: &str = include_str!("page/editor.html");

/// The prompt the page opens with.
pub const DEFAULT_TEXT: &str = "a person walks forward.";

/// Joint `name` of `skel` (the t2m names; the editor serves t2m models).
fn at(skel: &Skeleton, name: &str) -> usize {
    skel.joint_index(name)
        .unwrap_or_else(|| panic!("the {} skeleton has no joint {name}", skel.name))
}

/// What the page's scripts read: the skeleton (parents, sides, named joints, the IK chains of
/// the draggable joints) and the request bounds.
fn info(limits: &Limits, step: usize) -> serde_json::Value {
    let s = &T2M;
    let side: Vec<&str> = s
        .joint_names
        .iter()
        .map(|n| {
            if n.starts_with("l_") {
                "left"
            } else if n.starts_with("r_") {
                "right"
            } else {
                "centre"
            }
        })
        .collect();
    let names = [
        "head",
        "l_hip",
        "r_hip",
        "l_knee",
        "r_knee",
        "l_ankle",
        "r_ankle",
        "l_foot",
        "r_foot",
        "l_shoulder",
        "r_shoulder",
    ];
    let index: serde_json::Map<String, serde_json::Value> =
        names.iter().map(|n| (n.to_string(), json!(at(s, n)))).collect();
    let chain = |a: &str, b: &str, c: &str| json!([at(s, a), at(s, b), at(s, c)]);
    let mut chains = serde_json::Map::new();
    for side in ["l", "r"] {
        let n = |j: &str| format!("{side}_{j}");
        chains.insert(
            at(s, &n("wrist")).to_string(),
            chain(&n("shoulder"), &n("elbow"), &n("wrist")),
        );
        chains.insert(at(s, &n("ankle")).to_string(), chain(&n("hip"), &n("knee"), &n("ankle")));
    }
    let effectors = ["pelvis", "l_wrist", "r_wrist", "l_ankle", "r_ankle"].map(|n| at(s, n));
    let carry = json!({ at(s, "l_ankle").to_string(): [at(s, "l_foot")], at(s, "r_ankle").to_string(): [at(s, "r_foot")] });
    json!({
        "fps": s.fps,
        "parents": s.parents(),
        "names": s.joint_names,
        "side": side,
        "index": index,
        "effectors": effectors,
        "chains": chains,
        "carry": carry,
        "rest": rest_pose(s),
        "limits": limits,
        "step": step,
    })
}

/// The skeleton standing in its rest pose, pelvis 0.93 m above the origin.
fn rest_pose(s: &Skeleton) -> Vec<[f64; 3]> {
    let offsets = s.target_offsets().unwrap_or_default();
    let rot = vec![vec![quat::IDENTITY; s.num_joints()]];
    let pose = rep::forward_kinematics(s, &rot, &[[0.0, 0.93, 0.0]], &offsets);
    pose[0].iter().map(|p| p.map(|v| (v * 1e4).round() / 1e4)).collect()
}

/// The whole page for a model at training step `step`.
pub fn html(limits: &Limits, step: usize) -> String {
    let data = info(limits, step).to_string().replace("</", "<\\/");
    format!(
        "<!doctype html>\n<html lang=en><meta charset=utf-8><title>diffkfc editor</title>\n<style>{STYLE}</style>\n{body}\n<script type=\"application/json\" id=\"editor-info\">{data}</script>\n<script>{SCENE_JS}</script>\n<script>{POSE_JS}</script>\n<script>{VIEW_JS}</script>\n<script>{EDITOR_JS}</script>\n</html>\n",
        body = BODY
            .replace("{DEFAULT_TEXT}", &escape(DEFAULT_TEXT))
            .replace("{STEPS}", &DEFAULT_STEPS.to_string())
            .replace("{STEP}", &step.to_string()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The page names every element its script looks up, and its data parses.
    #[test]
    fn page_has_every_element_the_script_uses() {
        let page = html(&Limits::for_model(196, 1000), 7);
        let used = |pat: &str| -> Vec<String> {
            EDITOR_JS.split(pat).skip(1).map(|s| s.split('"').next().unwrap().to_string()).collect()
        };
        let mut ids = used("$(\"");
        ids.extend(used("on(\""));
        ids.extend(["bvh", "features", "joints"].map(|f| format!("export-{f}")));
        for id in ids.iter().filter(|id| !id.is_empty() && !id.ends_with('-')) {
            assert!(
                page.contains(&format!("id={id}")) || page.contains(&format!("id=\"{id}\"")),
                "no element #{id}"
            );
        }
        let data =
            page.split("id=\"editor-info\">").nth(1).unwrap().split("</script>").next().unwrap();
        let v: serde_json::Value = serde_json::from_str(&data.replace("<\\/", "</")).unwrap();
        assert_eq!(v["parents"].as_array().unwrap().len(), 22);
        assert_eq!(v["chains"]["20"], json!([16, 18, 20]));
        assert!((v["rest"][0][1].as_f64().unwrap() - 0.93).abs() < 1e-9);
        // The steps field starts at the samplers' default, every placeholder filled.
        assert!(page.contains(&format!("id=steps type=number value={DEFAULT_STEPS} ")));
        assert!(!page.contains("{STEPS}") && !page.contains("{STEP}"));
    }
}
