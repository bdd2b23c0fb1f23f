//! Caption text and HumanML3D-style `word/POS` tokens from a small built-in lexicon.

use diffkfc_data::rng::Rng;

pub const SUBJECTS: &[&str] = &[
    "a person",
    "someone",
    "a man",
    "a woman",
    "the person",
    "a figure",
    "a guy",
    "a girl",
    "an individual",
    "a human",
    "the man",
    "the woman",
    "a character",
    "the character",
    "an athlete",
    "a dancer",
    "a performer",
    "a kid",
    "a boy",
    "an adult",
    "the actor",
    "a young man",
    "an old man",
    "a tall person",
];

/// Adverbial modifiers chosen from an action's parameters, so that text says coarsely what
/// the parameters say exactly ("slowly" for a slow walk, "twice" for two jumps).
pub fn modifiers(params: &serde_json::Value) -> Vec<&'static str> {
    let mut m = Vec::new();
    if let Some(v) = params.get("speed").and_then(|v| v.as_f64()) {
        m.extend_from_slice(match v {
            v if v < 0.6 => &["slowly", "carefully", "cautiously"][..],
            v if v < 1.0 => &["slowly", "leisurely", "calmly", "casually"][..],
            v if v < 1.4 => &["at a normal pace", "steadily", "normally"][..],
            v if v < 2.8 => &["quickly", "briskly", "at a fast pace", "energetically"][..],
            _ => &["very fast", "at full speed", "rapidly"][..],
        });
    }
    if let Some(r) = params.get("reps").and_then(|v| v.as_u64()) {
        m.extend_from_slice(match r {
            1 => &["once", "one time"][..],
            2 => &["twice", "two times"][..],
            3 => &["three times", "a few times"][..],
            _ => &["several times", "repeatedly", "many times"][..],
        });
    }
    if let Some(h) = params.get("height").and_then(|v| v.as_f64()) {
        if params.get("distance").is_some() || params.get("reps").is_some() {
            m.extend_from_slice(if h > 0.25 {
                &["high", "powerfully"][..]
            } else {
                &["lightly", "gently"][..]
            });
        }
    }
    m
}

/// Verb lemmas and their surface forms used by the phrase templates.
const VERBS: &[(&str, &[&str])] = &[
    ("walk", &["walks", "walking"]),
    ("take", &["takes", "taking"]),
    ("move", &["moves", "moving"]),
    ("step", &["steps", "stepping"]),
    ("shuffle", &["shuffles", "shuffling"]),
    ("side", &[]),
    ("circle", &["circles", "circling"]),
    ("jog", &["jogs", "jogging"]),
    ("run", &["runs", "running"]),
    ("sprint", &["sprints", "sprinting"]),
    ("jump", &["jumps", "jumping"]),
    ("hop", &["hops", "hopping"]),
    ("leap", &["leaps", "leaping"]),
    ("do", &["does", "doing"]),
    ("squat", &["squats", "squatting"]),
    ("crouch", &["crouches", "crouching"]),
    ("stand", &["stands", "standing"]),
    ("sit", &["sits", "sitting"]),
    ("get", &["gets", "getting"]),
    ("lower", &["lowers", "lowering"]),
    ("rise", &["rises", "rising"]),
    ("kneel", &["kneels", "kneeling"]),
    ("go", &["goes", "going"]),
    ("kick", &["kicks", "kicking"]),
    ("turn", &["turns", "turning"]),
    ("rotate", &["rotates", "rotating"]),
    ("spin", &["spins", "spinning"]),
    ("twirl", &["twirls", "twirling"]),
    ("bend", &["bends", "bending"]),
    ("pick", &["picks", "picking"]),
    ("reach", &["reaches", "reaching"]),
    ("stretch", &["stretches", "stretching"]),
    ("dance", &["dances", "dancing"]),
    ("sway", &["sways", "swaying"]),
    ("wave", &["waves", "waving"]),
    ("raise", &["raises", "raising"]),
    ("lift", &["lifts", "lifting"]),
    ("put", &["puts", "putting"]),
    ("clap", &["claps", "clapping"]),
    ("applaud", &["applauds", "applauding"]),
    ("punch", &["punches", "punching"]),
    ("throw", &["throws", "throwing"]),
    ("box", &["boxes", "boxing"]),
    ("perform", &["performs", "performing"]),
    ("strike", &["strikes", "striking"]),
    ("bounce", &["bounces", "bouncing"]),
    ("march", &["marches", "marching"]),
    ("stroll", &["strolls", "strolling"]),
    ("dash", &["dashes", "dashing"]),
    ("kneel", &["kneels", "kneeling"]),
    ("grab", &["grabs", "grabbing"]),
    ("greet", &["greets", "greeting"]),
    ("salute", &["salutes", "saluting"]),
    ("lean", &["leans", "leaning"]),
    ("retreat", &["retreats", "retreating"]),
    ("pivot", &["pivots", "pivoting"]),
    ("groove", &["grooves", "grooving"]),
    ("hit", &["hits", "hitting"]),
    ("extend", &["extends", "extending"]),
    ("touch", &["touches", "touching"]),
];

const TAGS: &[(&str, &str)] = &[
    ("a", "DET"),
    ("an", "DET"),
    ("the", "DET"),
    ("both", "DET"),
    ("someone", "PRON"),
    ("something", "PRON"),
    ("to", "ADP"),
    ("in", "ADP"),
    ("on", "ADP"),
    ("with", "ADP"),
    ("from", "ADP"),
    ("of", "ADP"),
    ("above", "ADP"),
    ("towards", "ADP"),
    ("into", "ADP"),
    ("over", "ADP"),
    ("around", "ADV"),
    ("forward", "ADV"),
    ("backward", "ADV"),
    ("backwards", "ADV"),
    ("sideways", "ADV"),
    ("ahead", "ADV"),
    ("slowly", "ADV"),
    ("quickly", "ADV"),
    ("then", "ADV"),
    ("down", "ADV"),
    ("up", "ADV"),
    ("back", "ADV"),
    ("again", "ADV"),
    ("first", "ADV"),
    ("straight", "ADV"),
    ("hello", "INTJ"),
    ("left", "ADJ"),
    ("right", "ADJ"),
    ("full", "ADJ"),
    ("long", "ADJ"),
    ("few", "ADJ"),
    ("one", "NUM"),
    ("and", "CCONJ"),
    ("while", "SCONJ"),
    ("before", "SCONJ"),
    ("after", "SCONJ"),
    ("same", "ADJ"),
    ("time", "NOUN"),
    ("slowly", "ADV"),
    ("carefully", "ADV"),
    ("cautiously", "ADV"),
    ("leisurely", "ADV"),
    ("calmly", "ADV"),
    ("casually", "ADV"),
    ("steadily", "ADV"),
    ("normally", "ADV"),
    ("briskly", "ADV"),
    ("energetically", "ADV"),
    ("rapidly", "ADV"),
    ("very", "ADV"),
    ("fast", "ADV"),
    ("once", "ADV"),
    ("twice", "ADV"),
    ("repeatedly", "ADV"),
    ("high", "ADV"),
    ("powerfully", "ADV"),
    ("lightly", "ADV"),
    ("gently", "ADV"),
    ("two", "NUM"),
    ("three", "NUM"),
    ("several", "ADJ"),
    ("many", "ADJ"),
    ("normal", "ADJ"),
    ("young", "ADJ"),
    ("old", "ADJ"),
    ("tall", "ADJ"),
    ("his", "PRON"),
    ("her", "PRON"),
    ("their", "PRON"),
    ("at", "ADP"),
    ("by", "ADP"),
    ("across", "ADP"),
];

/// `word/POS` tokens of a caption (verbs lemmatised, as HumanML3D's spaCy pass writes them).
pub fn tokens(caption: &str) -> Vec<(String, String)> {
    caption
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(|w| {
            let w = w.to_lowercase();
            if let Some((lemma, _)) =
                VERBS.iter().find(|(l, forms)| *l == w || forms.contains(&w.as_str()))
            {
                return (lemma.to_string(), "VERB".to_string());
            }
            let tag = TAGS.iter().find(|(t, _)| *t == w).map(|(_, p)| *p).unwrap_or("NOUN");
            (w, tag.to_string())
        })
        .collect()
}

/// Substitute `{side}` in a template.
pub fn fill(template: &str, side: Option<&str>) -> String {
    template.replace("{side}", side.unwrap_or("right"))
}

/// A sentence from a subject and a predicate, with a final period.
pub fn sentence(rng: &mut Rng, predicate: &str) -> String {
    format!("{} {predicate}.", rng.pick(SUBJECTS))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_and_lemmas() {
        let t = tokens("A person walks forward, then waves the left hand.");
        let s: Vec<String> = t.iter().map(|(w, p)| format!("{w}/{p}")).collect();
        assert_eq!(
            s.join(" "),
            "a/DET person/NOUN walk/VERB forward/ADV then/ADV wave/VERB the/DET left/ADJ hand/NOUN"
        );
    }
}
