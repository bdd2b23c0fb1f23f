//! An interactive 3D page of motions side by side (viewer.js: our own canvas renderer, no
//! libraries, opens from disk): orbit camera, play/pause, a frame slider, keyframes marked on a
//! timeline and drawn in orange at their frames, the numbers under each motion.

use serde_json::{json, Value};

use diffkfc_data::motion::representation::Joints;
use diffkfc_data::motion::skeleton::Skeleton;

const SCRIPT: &str = include_str!("viewer.js");
/// The camera, grid and figure drawing shared with the keyframe editor's page.
pub const SCENE_JS: &str = include_str!("scene.js");

/// One motion on the page.
#[derive(Clone, Debug, Default)]
pub struct ViewMotion {
    pub label: String,
    pub joints: Joints,
    /// Frames marked on the timeline.
    pub keyframes: Vec<usize>,
    /// Joints the keyframes observe (None: all).
    pub key_joints: Option<Vec<usize>>,
    /// Keyed poses drawn in orange near their frames: (frame, pose).
    pub key_poses: Vec<(usize, Vec<[f64; 3]>)>,
    /// A line of numbers shown under the view.
    pub numbers: String,
    /// Files to link under the view: (text, relative path).
    pub links: Vec<(String, String)>,
    /// The root path the motion was asked to follow (the track fit's first stage), drawn on the
    /// ground as a dashed line.
    pub root_path: Option<Vec<[f64; 3]>>,
    /// Planted spans: (toe joint, first frame, last frame), marked on the timeline and under
    /// the toe while it is planted.
    pub planted: Vec<(usize, usize, usize)>,
}

/// Text made safe inside HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn flat(frames: &[Vec<[f64; 3]>]) -> Vec<f64> {
    frames.iter().flatten().flatten().map(|v| (v * 1000.0).round() / 1000.0).collect()
}

/// A whole HTML page: `title`, an HTML `intro` (already escaped), the view and a card per motion;
/// `segments` (start frame, text) of a timeline are marked on the timeline and named in the view.
pub fn page(
    skel: &Skeleton,
    title: &str,
    intro: &str,
    motions: &[ViewMotion],
    segments: &[(usize, String)],
) -> String {
    let data = view_data(skel, motions, segments);
    let cards: String = motions.iter().map(card).collect();
    format!(
        r#"<!doctype html>
<html lang=en><meta charset=utf-8><title>{title}</title>
<style>
body{{font-family:system-ui,sans-serif;margin:16px;color:#0f172a;max-width:1200px}}
#view{{width:100%;height:520px;border:1px solid #cbd5e1;border-radius:6px;touch-action:none;cursor:grab}}
#timeline{{width:100%;height:{tl}px;display:block;cursor:pointer}}
.controls{{display:flex;gap:12px;align-items:center;margin:6px 0}}
#frame{{flex:1}}
.cards{{display:flex;flex-wrap:wrap;gap:10px}}
.card{{border:1px solid #e2e8f0;border-radius:6px;padding:8px 10px;font-size:14px;min-width:220px}}
.legend span{{display:inline-block;width:12px;height:4px;margin:0 4px 2px 10px;vertical-align:middle}}
#status{{color:#64748b;font-size:12px}}
</style>
<h1>{title}</h1>
{intro}
<canvas id=view></canvas>
<div class=controls><button id=play>pause</button><input id=frame type=range min=0 value=0 step=1><span id=frame-label></span>
<label><input id=follow type=checkbox checked> follow</label></div>
<canvas id=timeline></canvas>
<p class=legend>drag to orbit, wheel to zoom, space to play/pause, arrows step frames;<span style="background:#2563eb"></span>left<span style="background:#dc2626"></span>right<span style="background:#f97316"></span>keyed pose (near its frame; ticks on the timeline)<span style="background:#7c3aed"></span>root path followed<span style="background:#16a34a"></span>planted foot <output id=status></output></p>
<div class=cards>{cards}</div>
<script type="application/json" id="motion-data">{data}</script>
<script>{SCENE_JS}</script>
<script>{SCRIPT}</script>
</html>
"#,
        title = escape(title),
        tl = 8 + 10 * motions.len(),
        data = data.to_string().replace("</", "<\\/"),
    )
}

/// The page's data: the skeleton's tree and sides, the timeline's segments, every motion.
fn view_data(skel: &Skeleton, motions: &[ViewMotion], segments: &[(usize, String)]) -> Value {
    let side = |p: &str| -> Vec<usize> {
        (0..skel.num_joints()).filter(|&j| skel.joint_names[j].starts_with(p)).collect()
    };
    let head = skel.joint_names.iter().position(|n| *n == "head").unwrap_or(skel.num_joints() - 1);
    json!({
        "fps": skel.fps,
        "parents": skel.parents(),
        "left": side("l_"),
        "right": side("r_"),
        "head": head,
        "segments": segments,
        "motions": motions.iter().map(|m| json!({
            "label": m.label,
            "frames": m.joints.len(),
            "joints": flat(&m.joints),
            "keyframes": m.keyframes,
            "key_joints": m.key_joints,
            "key_poses": m.key_poses.iter().map(|(f, p)| json!([f, flat(std::slice::from_ref(p))])).collect::<Vec<_>>(),
            "root_path": m.root_path.as_ref().map(|p| p.iter().flat_map(|v| [v[0], v[2]]).map(|v| (v * 1000.0).round() / 1000.0).collect::<Vec<_>>()),
            "planted": m.planted,
        })).collect::<Vec<_>>(),
    })
}

/// A motion's card under the view: its label, numbers and links.
fn card(m: &ViewMotion) -> String {
    let links: Vec<String> = m
        .links
        .iter()
        .map(|(t, href)| format!("<a href=\"{}\">{}</a>", escape(href), escape(t)))
        .collect();
    format!(
        "<div class=card><b>{}</b><br>{}<br>{}</div>",
        escape(&m.label),
        escape(&m.numbers),
        links.join(" &middot; ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::T2M;

    /// Text from users (prompts, labels) cannot end the data script or inject markup, and the
    /// embedded data parses back to the motion.
    #[test]
    fn page_embeds_the_motion_and_escapes_text() {
        let pose = vec![[0.1234567, 0.9, -0.5]; 22];
        let m = ViewMotion {
            label: "</script><b>x".into(),
            joints: vec![pose.clone(), pose],
            keyframes: vec![1],
            ..Default::default()
        };
        let html = page(&T2M, "a <walk>", "", &[m], &[(0, "</script>".into())]);
        assert!(
            !html.contains("</script><b>")
                && html.contains("&lt;/script&gt;&lt;b&gt;x")
                && html.contains("<h1>a &lt;walk&gt;</h1>")
        );
        let data = html
            .split("id=\"motion-data\">")
            .nth(1)
            .unwrap()
            .split("</script>")
            .next()
            .unwrap()
            .replace("<\\/", "</");
        let v: serde_json::Value = serde_json::from_str(&data).unwrap();
        assert_eq!(v["motions"][0]["frames"], 2);
        assert_eq!(v["motions"][0]["joints"].as_array().unwrap().len(), 2 * 22 * 3);
        assert_eq!(v["motions"][0]["joints"][0], 0.123);
        assert_eq!(v["parents"].as_array().unwrap().len(), 22);
    }
}
