//! diffkfc-synth, `diffkfc data synth`: a procedural text-motion dataset in the exact HumanML3D
//! layout.
//!
//! Clips are single actions, sequences ("walks forward, then jumps"), simultaneous upper and
//! lower body ("walks while waving the right hand"), and ambiguous captions realised two ways
//! ("bends over and walks": bend then walk, or walk bent over) where only keyframes can tell.
//! Poses come from a parametric body with leg IK (`body`), locomotion from a footstep planner
//! (`gait`); features from the same `process_file` as real data.

pub mod actions;
pub mod body;
pub mod captions;
pub mod gait;
pub mod manifest;
pub mod variation;
mod write;

pub use write::{mean_std, write_dataset, SynthSummary};

use serde::Serialize;
use serde_json::{json, Value};

use self::actions::{Part, Performance, ACTIONS};
pub use self::body::Body;
use self::body::Pose;
use diffkfc_data::motion::quat;
use diffkfc_data::motion::representation::{self as rep, FOOT_CONTACT_THRESHOLD};
use diffkfc_data::rng::Rng;
use diffkfc_data::T2M;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    Single,
    Sequence,
    Simultaneous,
    Ambiguous,
}

pub const PATTERNS: [Pattern; 4] =
    [Pattern::Single, Pattern::Sequence, Pattern::Simultaneous, Pattern::Ambiguous];

#[derive(Clone, Debug, Serialize)]
pub struct ActionSpan {
    pub action: &'static str,
    pub start: usize,
    pub end: usize,
    pub params: Value,
}

#[derive(Clone, Debug, Serialize)]
pub struct ClipMeta {
    pub id: String,
    pub pattern: Pattern,
    /// For ambiguous clips: which realisation ("sequence" or "simultaneous").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub realisation: Option<&'static str>,
    pub frames: usize,
    pub actions: Vec<ActionSpan>,
    pub captions: Vec<String>,
    pub split: &'static str,
}

/// A generated clip: joint positions (T+1 frames, so features have T) and its description.
pub struct Clip {
    pub joints: rep::Joints,
    pub meta: ClipMeta,
}

/// Ambiguous captions and their two realisations (sequence first, simultaneous second).
struct Ambiguous {
    name: &'static str,
    phrases: &'static [&'static str],
    sequence: [&'static str; 2],
    simultaneous: (&'static str, &'static str),
}

const AMBIGUOUS: &[Ambiguous] = &[
    Ambiguous {
        name: "bend_and_walk",
        phrases: &["bends over and walks", "walks and bends over", "bends down and walks forward"],
        sequence: ["pick_up", "walk_forward"],
        simultaneous: ("walk_forward", "bent"),
    },
    Ambiguous {
        name: "walk_and_wave",
        phrases: &["walks and waves", "walks forward and waves a hand", "waves and walks"],
        sequence: ["walk_forward", "wave"],
        simultaneous: ("walk_forward", "wave"),
    },
    Ambiguous {
        name: "squat_and_raise",
        phrases: &[
            "squats and raises both arms",
            "raises both arms and squats",
            "squats with arms raised",
        ],
        sequence: ["raise_both_arms", "squat"],
        simultaneous: ("squat", "raise_both_arms"),
    },
    Ambiguous {
        name: "turn_and_walk",
        phrases: &["turns and walks", "walks and turns", "turns while walking"],
        sequence: ["turn", "walk_forward"],
        simultaneous: ("walk_circle", ""),
    },
];

/// Lower-body actions that an upper-body action can be overlaid on.
const OVERLAY_BASES: &[&str] = &[
    "walk_forward",
    "walk_backward",
    "walk_sideways",
    "walk_circle",
    "jog",
    "turn",
    "squat",
    "jump_in_place",
];

fn frames_in(r: &mut Rng, range: (usize, usize), cap: usize) -> usize {
    let lo = range.0.min(cap);
    let hi = range.1.min(cap).max(lo);
    lo + r.below(hi - lo + 1)
}

/// Run an action from `start` (upper-body actions over a standing idle).
fn perform(r: &mut Rng, name: &str, start: &Pose, n: usize) -> Performance {
    let a = actions::by_name(name);
    match a.part {
        Part::Lower => (a.gen)(r, start, n),
        Part::Upper => {
            let base = actions::idle(r, start, n);
            overlay(r, base, name)
        }
    }
}

/// Put an upper-body action's arms (and twist) on top of a base segment's poses.
fn overlay(r: &mut Rng, base: Performance, upper: &str) -> Performance {
    let n = base.poses.len();
    let up = (actions::by_name(upper).gen)(r, &base.poses[0], n);
    let poses = base
        .poses
        .iter()
        .zip(&up.poses)
        .map(|(b, u)| {
            // The upper action was computed on the base's first pose; take only its arms.
            let mut p = *b;
            let rest = base.poses[0].arms;
            for (k, rest) in rest.iter().enumerate() {
                let changed = (u.arms[k].flex - rest.flex).abs()
                    + (u.arms[k].abd - rest.abd).abs()
                    + (u.arms[k].elbow - rest.elbow).abs();
                let w = (changed * 4.0).min(1.0);
                p.arms[k] = body::Arm::lerp(b.arms[k], u.arms[k], w);
            }
            p.twist += u.twist;
            p
        })
        .collect();
    Performance { poses, params: json!({"base": base.params, "upper": up.params}), side: up.side }
}

/// Concatenate two segments, cross-fading the first `blend` frames of the second from the
/// last pose of the first.
fn concat(a: &[Pose], b: &[Pose], blend: usize) -> Vec<Pose> {
    let last = *a.last().unwrap();
    let mut out = a.to_vec();
    for (i, p) in b.iter().enumerate() {
        let w = body::smooth((i + 1) as f64 / (blend + 1) as f64);
        out.push(if i < blend { Pose::lerp(&last, p, w) } else { *p });
    }
    out
}

fn end_pose(p: &Pose) -> Pose {
    // The next action starts from where this one ended, standing.
    let mut s = Pose::standing(p.root[0], p.root[2], p.yaw);
    s.feet = p.feet;
    s
}

/// Generate clip `index` of a dataset with `seed`: the first attempt whose features
/// reproduce its motion (HumanML3D's smoothed facing direction cannot represent a body that
/// ends facing opposite to its start within a few seconds; such draws are redrawn).
pub fn clip(body: Body, seed: u64, index: usize) -> (Clip, Vec<f32>) {
    clip_of(&SynthSpec { clips: index + 1, seed, body, vary: 0.0 }, index)
}

/// Clip `index` of the set `spec`: see [`clip`].
pub fn clip_of(spec: &SynthSpec, index: usize) -> (Clip, Vec<f32>) {
    let mut last = None;
    for attempt in 0..16u64 {
        let c = clip_attempt(spec, index, attempt);
        let feats = rep::features_from_joints(&T2M, &c.joints, FOOT_CONTACT_THRESHOLD)
            .expect("synthetic joints are valid");
        let rec = rep::recover_from_ric(&T2M, &feats.iter().map(|&v| v as f64).collect::<Vec<_>>());
        if representable(&c.joints, &rec) {
            return (c, feats);
        }
        last = Some((c, feats));
    }
    last.expect("at least one attempt")
}

/// Whether recovered joints move like the input (frame-to-frame displacement lengths agree;
/// they are invariant to the canonical placement).
fn representable(input: &rep::Joints, rec: &rep::Joints) -> bool {
    rec.windows(2).zip(input.windows(2)).all(|(r, i)| {
        (0..22).all(|j| {
            let a = quat::norm(quat::sub(r[1][j], r[0][j]));
            let b = quat::norm(quat::sub(i[1][j], i[0][j]));
            (a - b).abs() < 1e-3
        })
    })
}

fn clip_attempt(spec: &SynthSpec, index: usize, attempt: u64) -> Clip {
    let mut r = Rng::derive(spec.seed, 7 + (attempt << 8), index as u64);
    // 3.14, not PI: the synthetic set's bytes are fixed by its seed, and PI would change them.
    #[allow(clippy::approx_constant)]
    let start = Pose::standing(r.range(-1.0, 1.0), r.range(-1.0, 1.0), r.range(-3.14, 3.14));
    let pattern = PATTERNS[[0, 0, 0, 1, 1, 2, 2, 3][r.below(8)]];
    let mut d = match pattern {
        Pattern::Single => single(&mut r, &start),
        Pattern::Sequence | Pattern::Ambiguous => sequence_or_ambiguous(&mut r, &start, pattern),
        Pattern::Simultaneous => simultaneous(&mut r, &start),
    };
    if spec.vary > 0.0 {
        // Its own stream, so a set without variation keeps its bytes.
        let mut v = Rng::derive(spec.seed, 9 + (attempt << 8), index as u64);
        d.poses = variation::apply(&mut v, spec.vary, &d.poses, &mut d.spans, MAX_CLIP_FRAMES + 1);
    }
    finish(spec.body, index, pattern, d)
}

/// Most feature frames of a clip (+1 position frame -> at most 195 feature frames, < 196).
const MAX_CLIP_FRAMES: usize = 195;

/// A clip's motion, its action spans, its captions and, for ambiguous captions, which
/// realisation it shows.
struct Draft {
    poses: Vec<Pose>,
    spans: Vec<ActionSpan>,
    caps: Vec<String>,
    realisation: Option<&'static str>,
}

/// One of action `name`'s phrases, its plain or its -ing form.
fn pick_phrase(r: &mut Rng, name: &str, side: Option<&str>, ing: bool) -> String {
    let (p, g) = *r.pick(actions::by_name(name).phrases);
    captions::fill(if ing { g } else { p }, side)
}

/// Half the time, say coarsely what the parameters are ("slowly", "twice").
fn modify(r: &mut Rng, phrase: String, params: &Value) -> String {
    let m = captions::modifiers(params);
    if !m.is_empty() && r.chance(0.5) {
        format!("{phrase} {}", r.pick(&m))
    } else {
        phrase
    }
}

/// One action.
fn single(r: &mut Rng, start: &Pose) -> Draft {
    let a = r.pick(ACTIONS);
    let n = frames_in(r, a.frames, MAX_CLIP_FRAMES).max(40);
    let seg = perform(r, a.name, start, n);
    let spans = vec![ActionSpan { action: a.name, start: 0, end: n, params: seg.params.clone() }];
    let caps = (0..3)
        .map(|_| {
            let p = pick_phrase(r, a.name, seg.side, false);
            let p = modify(r, p, &seg.params);
            captions::sentence(r, &p)
        })
        .collect();
    Draft { poses: seg.poses, spans, caps, realisation: None }
}

/// Two actions one after the other, or an ambiguous caption shown as a sequence or as both
/// at once.
fn sequence_or_ambiguous(r: &mut Rng, start: &Pose, pattern: Pattern) -> Draft {
    let (names, amb) = if pattern == Pattern::Sequence {
        let a = r.pick(ACTIONS).name;
        let mut b = r.pick(ACTIONS).name;
        while b == a {
            b = r.pick(ACTIONS).name;
        }
        ([a, b], None)
    } else {
        let amb = r.pick(AMBIGUOUS);
        (amb.sequence, Some(amb))
    };
    let simultaneous = amb.is_some() && r.chance(0.5);
    let (poses, mut spans, realisation) = if let (Some(amb), true) = (amb, simultaneous) {
        let (poses, spans) = ambiguous_at_once(r, start, amb);
        (poses, spans, Some("simultaneous"))
    } else {
        let n1 = frames_in(r, (45, 100), 100);
        let n2 = frames_in(r, (45, 95), MAX_CLIP_FRAMES - n1);
        let s1 = perform(r, names[0], start, n1);
        let s2 = perform(r, names[1], &end_pose(s1.poses.last().unwrap()), n2);
        let spans = vec![
            ActionSpan { action: names[0], start: 0, end: n1, params: s1.params.clone() },
            ActionSpan { action: names[1], start: n1, end: n1 + n2, params: s2.params.clone() },
        ];
        let poses = concat(&s1.poses, &s2.poses, 8);
        if amb.is_none() {
            let caps = (0..3).map(|_| sequence_caption(r, names, &s1, &s2)).collect();
            return Draft { poses, spans, caps, realisation: None };
        }
        (poses, spans, Some("sequence"))
    };
    let amb = amb.expect("an ambiguous caption");
    let caps = (0..3)
        .map(|_| {
            let p = r.pick(amb.phrases).to_string();
            captions::sentence(r, &p)
        })
        .collect();
    spans.insert(0, ActionSpan { action: amb.name, start: 0, end: poses.len(), params: json!({}) });
    Draft { poses, spans, caps, realisation }
}

/// "A, then B" and its variants for two actions performed one after the other.
fn sequence_caption(r: &mut Rng, names: [&str; 2], s1: &Performance, s2: &Performance) -> String {
    let p1 = pick_phrase(r, names[0], s1.side, false);
    let p1 = modify(r, p1, &s1.params);
    let (p2, g2) =
        (pick_phrase(r, names[1], s2.side, false), pick_phrase(r, names[1], s2.side, true));
    let pred = match r.below(4) {
        0 => format!("{p1}, then {p2}"),
        1 => format!("{p1} and then {p2}"),
        2 => format!("first {p1}, then {p2}"),
        _ => format!("{p1} before {g2}"),
    };
    captions::sentence(r, &pred)
}

/// An ambiguous caption's simultaneous realisation: its lower-body action with its upper-body
/// one (or a bent spine) on top.
fn ambiguous_at_once(r: &mut Rng, start: &Pose, amb: &Ambiguous) -> (Vec<Pose>, Vec<ActionSpan>) {
    let (lower, upper) = amb.simultaneous;
    let n = frames_in(r, (100, 195), MAX_CLIP_FRAMES);
    let base = (actions::by_name(lower).gen)(r, start, n);
    let seg = match upper {
        "" => base,
        "bent" => {
            let bend = r.range(0.6, 0.9);
            let poses = base
                .poses
                .iter()
                .map(|p| Pose { pitch: p.pitch + bend, head_pitch: -0.3, ..*p })
                .collect();
            Performance {
                poses,
                params: json!({"base": base.params, "spine_bend": bend}),
                side: None,
            }
        }
        u => overlay(r, base, u),
    };
    let mut spans =
        vec![ActionSpan { action: lower, start: 0, end: n, params: seg.params.clone() }];
    if !upper.is_empty() && upper != "bent" {
        spans.push(ActionSpan {
            action: upper,
            start: 0,
            end: n,
            params: seg.params["upper"].clone(),
        });
    }
    (seg.poses, spans)
}

/// A lower-body action with an upper-body one at the same time.
fn simultaneous(r: &mut Rng, start: &Pose) -> Draft {
    let lower = *r.pick(OVERLAY_BASES);
    let uppers: Vec<&str> =
        ACTIONS.iter().filter(|a| a.part == Part::Upper).map(|a| a.name).collect();
    let upper = *r.pick(&uppers);
    let n = frames_in(r, actions::by_name(lower).frames, MAX_CLIP_FRAMES).max(60);
    let base = (actions::by_name(lower).gen)(r, start, n);
    let base_side = base.side;
    let seg = overlay(r, base, upper);
    let spans = vec![
        ActionSpan { action: lower, start: 0, end: n, params: seg.params["base"].clone() },
        ActionSpan { action: upper, start: 0, end: n, params: seg.params["upper"].clone() },
    ];
    let caps = (0..3)
        .map(|_| {
            let (l, lg) =
                (pick_phrase(r, lower, base_side, false), pick_phrase(r, lower, base_side, true));
            let (u, ug) =
                (pick_phrase(r, upper, seg.side, false), pick_phrase(r, upper, seg.side, true));
            let pred = match r.below(3) {
                0 => format!("{l} while {ug}"),
                1 => format!("{u} while {lg}"),
                _ => format!("{l} and {u} at the same time"),
            };
            captions::sentence(r, &pred)
        })
        .collect();
    Draft { poses: seg.poses, spans, caps, realisation: None }
}

fn finish(body: Body, index: usize, pattern: Pattern, d: Draft) -> Clip {
    let Draft { poses, spans: actions, caps: captions, realisation } = d;
    let joints: rep::Joints = body::joints_seq(body, &poses);
    let frames = joints.len() - 1;
    Clip {
        joints,
        meta: ClipMeta {
            id: format!("{index:06}"),
            pattern,
            realisation,
            frames,
            actions,
            captions,
            split: "train",
        },
    }
}

/// Most clips a set may have: three times HumanML3D's 29 232 (about 12 GB of files).
pub const MAX_CLIPS: usize = 100_000;

/// What a synthetic set is: the same spec gives the same bytes.
#[derive(Clone, Copy, Debug)]
pub struct SynthSpec {
    pub clips: usize,
    pub seed: u64,
    pub body: Body,
    /// Variation beyond the actions' own parameters ([`variation`]); 0 for none.
    pub vary: f64,
}

impl SynthSpec {
    /// `clips` clips of `seed` drawn by the legacy body.
    pub fn legacy(clips: usize, seed: u64) -> SynthSpec {
        SynthSpec { clips, seed, body: Body::Legacy, vary: 0.0 }
    }
}
