//! Finding clips in a synthetic set's manifest.json by split, actions, pattern and length
//! (`diffkfc data clips`): the quick start and the design panel pick their held-out walks so.

use std::path::Path;

use serde_json::Value;

use diffkfc_data::DataError;

/// What a clip must be.
#[derive(Clone, Debug, Default)]
pub struct ClipQuery {
    pub split: Option<String>,
    /// Actions the clip must contain (all of them).
    pub actions: Vec<String>,
    /// The clip has no action besides `actions`.
    pub only: bool,
    pub pattern: Option<String>,
    pub min_frames: usize,
    pub exclude: Vec<String>,
}

impl ClipQuery {
    fn matches(&self, c: &Value) -> bool {
        let acts: Vec<&str> = c["actions"]
            .as_array()
            .map(|a| a.iter().filter_map(|x| x["action"].as_str()).collect())
            .unwrap_or_default();
        let id = c["id"].as_str().unwrap_or("");
        self.split.as_deref().is_none_or(|s| c["split"].as_str() == Some(s))
            && self.actions.iter().all(|a| acts.contains(&a.as_str()))
            && (!self.only || acts.iter().all(|a| self.actions.iter().any(|b| b == a)))
            && self.pattern.as_deref().is_none_or(|p| c["pattern"].as_str() == Some(p))
            && c["frames"].as_u64().unwrap_or(0) as usize >= self.min_frames
            && !self.exclude.iter().any(|e| e == id)
    }
}

/// The ids of the clips of `dir/manifest.json` that match, in the manifest's order.
pub fn find_clips(dir: &Path, q: &ClipQuery) -> Result<Vec<String>, DataError> {
    let path = dir.join("manifest.json");
    let text =
        std::fs::read_to_string(&path).map_err(|err| DataError::Io { path: path.clone(), err })?;
    let m: Value = serde_json::from_str(&text)
        .map_err(|e| DataError::Npy { path: path.clone(), msg: format!("not JSON: {e}") })?;
    let clips = m["clips"]
        .as_array()
        .ok_or_else(|| DataError::Npy { path: path.clone(), msg: "no 'clips' list".into() })?;
    Ok(clips
        .iter()
        .filter(|c| q.matches(c))
        .filter_map(|c| c["id"].as_str().map(str::to_string))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queries_select_by_split_actions_pattern_and_length() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        let clip = |id: &str, split: &str, acts: &[&str], pattern: &str, frames: usize| {
            serde_json::json!({"id": id, "split": split, "pattern": pattern, "frames": frames,
                "actions": acts.iter().map(|a| serde_json::json!({"action": a})).collect::<Vec<_>>()})
        };
        let m = serde_json::json!({"clips": [
            clip("a", "train", &["walk_forward"], "single", 150),
            clip("b", "test", &["walk_forward", "wave"], "simultaneous", 150),
            clip("c", "test", &["walk_forward"], "single", 90),
            clip("d", "test", &["walk_forward"], "single", 130),
            clip("e", "test", &["jump", "sit"], "sequence", 120),
        ]});
        std::fs::write(d.join("manifest.json"), m.to_string()).unwrap();
        let q = |f: &dyn Fn(&mut ClipQuery)| {
            let mut q = ClipQuery { split: Some("test".into()), ..Default::default() };
            f(&mut q);
            find_clips(d, &q).unwrap()
        };
        assert_eq!(q(&|q| q.actions = vec!["walk_forward".into()]), ["b", "c", "d"]);
        assert_eq!(q(&|q| q.actions = vec!["walk_forward".into(), "wave".into()]), ["b"]);
        assert_eq!(
            q(&|q| {
                q.actions = vec!["walk_forward".into()];
                q.only = true;
                q.min_frames = 100;
            }),
            ["d"]
        );
        assert_eq!(q(&|q| q.pattern = Some("sequence".into())), ["e"]);
        assert_eq!(q(&|q| q.exclude = vec!["b".into(), "c".into(), "d".into()]), ["e"]);
    }
}
