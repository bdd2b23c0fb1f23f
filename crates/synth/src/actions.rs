//! The action catalogue: each action draws its continuous parameters, produces poses for a
//! number of frames from a start state, and says how to phrase itself.

use serde_json::{json, Value};

use super::body::{self, smooth, Arm, Pose};
use super::gait::{self, Gait, RootState};
use diffkfc_data::rng::Rng;

pub const FPS: f64 = 20.0;
const PI: f64 = std::f64::consts::PI;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// Moves the whole body (legs and root); arms free for an upper-body overlay.
    Lower,
    /// Arms (and a little spine) only: performed standing or over a lower action.
    Upper,
}

/// What one action produced.
pub struct Performance {
    pub poses: Vec<Pose>,
    pub params: Value,
    /// Words substituted into the phrase templates ({side}).
    pub side: Option<&'static str>,
}

pub struct Action {
    pub name: &'static str,
    pub part: Part,
    /// (third person, -ing form) templates; `{side}` becomes "left"/"right".
    pub phrases: &'static [(&'static str, &'static str)],
    /// Preferred duration range in frames when alone.
    pub frames: (usize, usize),
    pub gen: fn(&mut Rng, &Pose, usize) -> Performance,
}

fn side_word(s: usize) -> &'static str {
    if s == 0 {
        "left"
    } else {
        "right"
    }
}

fn state(p: &Pose) -> RootState {
    RootState { x: p.root[0], z: p.root[2], yaw: p.yaw, height: body::standing_height() }
}

/// Locomotion along a path; the shared body of walk, jog, run, side steps, circles, turns.
fn locomotion(
    start: &Pose,
    n: usize,
    speed: f64,
    heading: f64,
    yaw_rate: f64,
    g: Gait,
    bounce: f64,
) -> Vec<Pose> {
    let traj = gait::trajectory(
        state(start),
        n,
        FPS,
        gait::Travel { speed, heading, yaw_rate, bounce, step_rate: g.step_rate },
    );
    gait::locomote(&traj, &g, start.feet, FPS)
}

/// Poses interpolated (smoothstep) between keys at fractions of the duration.
fn keyed(n: usize, keys: &[(f64, Pose)]) -> Vec<Pose> {
    (0..n)
        .map(|t| {
            let x = t as f64 / (n - 1).max(1) as f64;
            let i = keys.iter().rposition(|k| k.0 <= x).unwrap_or(0);
            if i + 1 >= keys.len() {
                return keys[i].1;
            }
            let (a, b) = (&keys[i], &keys[i + 1]);
            Pose::lerp(&a.1, &b.1, smooth((x - a.0) / (b.0 - a.0)))
        })
        .collect()
}

/// Repetition phases: for `reps` cycles over the middle of the clip, a 0..1 bump per cycle.
fn bumps(n: usize, reps: usize, lead: f64) -> Vec<f64> {
    (0..n)
        .map(|t| {
            let x = t as f64 / (n - 1).max(1) as f64;
            let y = ((x - lead) / (1.0 - 2.0 * lead)).clamp(0.0, 1.0) * reps as f64;
            if y <= 0.0 || y >= reps as f64 {
                0.0
            } else {
                (PI * y.fract()).sin().powi(2)
            }
        })
        .collect()
}

mod lower;
mod upper;

pub use lower::idle;
use lower::*;
use upper::*;

pub static ACTIONS: &[Action] = &[
    Action {
        name: "walk_forward",
        part: Part::Lower,
        frames: (60, 196),
        gen: walk,
        phrases: &[
            ("walks forward", "walking forward"),
            ("walks straight ahead", "walking straight ahead"),
            ("takes a few steps forward", "taking a few steps forward"),
            ("moves forward", "moving forward"),
            ("strolls forward", "strolling forward"),
            ("marches ahead", "marching ahead"),
        ],
    },
    Action {
        name: "walk_backward",
        part: Part::Lower,
        frames: (60, 160),
        gen: walk_backward,
        phrases: &[
            ("walks backward", "walking backward"),
            ("steps backwards", "stepping backwards"),
            ("moves back a few steps", "moving back a few steps"),
            ("retreats backwards", "retreating backwards"),
        ],
    },
    Action {
        name: "walk_sideways",
        part: Part::Lower,
        frames: (60, 140),
        gen: walk_sideways,
        phrases: &[
            ("walks sideways to the {side}", "walking sideways to the {side}"),
            ("side steps to the {side}", "side stepping to the {side}"),
            ("shuffles to the {side}", "shuffling to the {side}"),
        ],
    },
    Action {
        name: "walk_circle",
        part: Part::Lower,
        frames: (100, 196),
        gen: walk_circle,
        phrases: &[
            ("walks in a circle", "walking in a circle"),
            ("walks around in a circle", "walking around in a circle"),
            ("circles around", "circling around"),
        ],
    },
    Action {
        name: "jog",
        part: Part::Lower,
        frames: (60, 160),
        gen: jog,
        phrases: &[
            ("jogs forward", "jogging forward"),
            ("jogs", "jogging"),
            ("runs slowly forward", "running slowly forward"),
        ],
    },
    Action {
        name: "run",
        part: Part::Lower,
        frames: (50, 140),
        gen: run,
        phrases: &[
            ("runs forward", "running forward"),
            ("sprints ahead", "sprinting ahead"),
            ("runs quickly", "running quickly"),
            ("dashes forward", "dashing forward"),
        ],
    },
    Action {
        name: "jump_in_place",
        part: Part::Lower,
        frames: (50, 120),
        gen: jump_in_place,
        phrases: &[
            ("jumps in place", "jumping in place"),
            ("jumps up and down", "jumping up and down"),
            ("hops up on the spot", "hopping up on the spot"),
            ("bounces up and down", "bouncing up and down"),
        ],
    },
    Action {
        name: "jump_forward",
        part: Part::Lower,
        frames: (50, 120),
        gen: jump_forward,
        phrases: &[
            ("jumps forward", "jumping forward"),
            ("leaps forward", "leaping forward"),
            ("does a long jump", "doing a long jump"),
        ],
    },
    Action {
        name: "hop_one_leg",
        part: Part::Lower,
        frames: (60, 140),
        gen: hop,
        phrases: &[
            ("hops on the {side} leg", "hopping on the {side} leg"),
            ("hops on one foot", "hopping on one foot"),
            ("jumps on the {side} foot", "jumping on the {side} foot"),
        ],
    },
    Action {
        name: "squat",
        part: Part::Lower,
        frames: (60, 160),
        gen: squat,
        phrases: &[
            ("squats down", "squatting down"),
            ("does squats", "doing squats"),
            ("crouches down and stands back up", "crouching down and standing back up"),
        ],
    },
    Action {
        name: "sit_stand",
        part: Part::Lower,
        frames: (90, 196),
        gen: sit,
        phrases: &[
            ("sits down and stands up", "sitting down and standing up"),
            ("sits down then gets back up", "sitting down then getting back up"),
            ("lowers into a chair and rises again", "lowering into a chair and rising again"),
        ],
    },
    Action {
        name: "kneel",
        part: Part::Lower,
        frames: (80, 180),
        gen: kneel,
        phrases: &[
            ("kneels down on the {side} knee", "kneeling down on the {side} knee"),
            ("kneels down", "kneeling down"),
            ("goes down on one knee", "going down on one knee"),
        ],
    },
    Action {
        name: "kick",
        part: Part::Lower,
        frames: (50, 120),
        gen: kick,
        phrases: &[
            ("kicks with the {side} leg", "kicking with the {side} leg"),
            ("kicks the {side} foot forward", "kicking the {side} foot forward"),
            ("does a {side} kick", "doing a {side} kick"),
        ],
    },
    Action {
        name: "turn",
        part: Part::Lower,
        frames: (50, 110),
        gen: turn,
        phrases: &[
            ("turns to the {side}", "turning to the {side}"),
            ("turns around to the {side}", "turning around to the {side}"),
            ("rotates towards the {side}", "rotating towards the {side}"),
            ("pivots to face the {side}", "pivoting to face the {side}"),
        ],
    },
    Action {
        name: "spin",
        part: Part::Lower,
        frames: (50, 100),
        gen: spin,
        phrases: &[
            ("spins around", "spinning around"),
            ("twirls in a full circle", "twirling in a full circle"),
            ("spins to the {side}", "spinning to the {side}"),
        ],
    },
    Action {
        name: "pick_up",
        part: Part::Lower,
        frames: (70, 160),
        gen: pick_up,
        phrases: &[
            ("bends over and picks something up", "bending over and picking something up"),
            (
                "picks up an object from the floor with the {side} hand",
                "picking up an object from the floor with the {side} hand",
            ),
            ("reaches down to the ground", "reaching down to the ground"),
            (
                "leans down to grab an item off the floor",
                "leaning down to grab an item off the floor",
            ),
        ],
    },
    Action {
        name: "stretch",
        part: Part::Lower,
        frames: (80, 180),
        gen: stretch,
        phrases: &[
            ("stretches", "stretching"),
            ("stretches the arms above the head", "stretching the arms above the head"),
            ("does a stretching exercise", "doing a stretching exercise"),
        ],
    },
    Action {
        name: "dance",
        part: Part::Lower,
        frames: (80, 196),
        gen: dance,
        phrases: &[
            ("dances", "dancing"),
            ("does a dance step", "doing a dance step"),
            ("sways side to side to music", "swaying side to side to music"),
            ("grooves to a rhythm", "grooving to a rhythm"),
        ],
    },
    Action {
        name: "wave",
        part: Part::Upper,
        frames: (50, 140),
        gen: wave,
        phrases: &[
            ("waves the {side} hand", "waving the {side} hand"),
            ("waves hello with the {side} hand", "waving hello with the {side} hand"),
            ("raises the {side} hand and waves", "raising the {side} hand and waving"),
            ("greets somebody with a wave", "greeting somebody with a wave"),
        ],
    },
    Action {
        name: "raise_arm",
        part: Part::Upper,
        frames: (50, 120),
        gen: raise_arm,
        phrases: &[
            ("raises the {side} arm", "raising the {side} arm"),
            ("lifts the {side} arm up", "lifting the {side} arm up"),
            ("puts the {side} arm in the air", "putting the {side} arm in the air"),
        ],
    },
    Action {
        name: "raise_both_arms",
        part: Part::Upper,
        frames: (50, 140),
        gen: raise_both,
        phrases: &[
            ("raises both arms", "raising both arms"),
            ("lifts both hands above the head", "lifting both hands above the head"),
            ("puts both arms up", "putting both arms up"),
        ],
    },
    Action {
        name: "clap",
        part: Part::Upper,
        frames: (50, 120),
        gen: clap,
        phrases: &[
            ("claps the hands", "clapping the hands"),
            ("claps", "clapping"),
            ("applauds", "applauding"),
        ],
    },
    Action {
        name: "punch",
        part: Part::Upper,
        frames: (50, 120),
        gen: punch,
        phrases: &[
            ("punches with the {side} hand", "punching with the {side} hand"),
            ("throws a punch", "throwing a punch"),
            ("boxes with the {side} fist", "boxing with the {side} fist"),
            ("strikes the air with a fist", "striking the air with a fist"),
        ],
    },
];

pub fn by_name(name: &str) -> &'static Action {
    ACTIONS.iter().find(|a| a.name == name).expect("known action")
}
