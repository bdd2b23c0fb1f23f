//! Bounded fuzzing of run configs (`diffkfc_data::testing::fuzz`): mutated copies of the shipped configs
//! parse or give a clean error, and whatever parses is valid enough to build a model from
//! (the checks that keep zero sizes and absurd values out).

use std::path::Path;

use diffkfc_data::testing::fuzz::{cases, fuzz};
use diffkfc_model::run::config::RunConfig;

#[test]
fn configs_never_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let seeds: Vec<Vec<u8>> = ["tiny", "small", "paper-humanml3d"]
        .iter()
        .map(|n| std::fs::read(dir.join(format!("{n}.json"))).unwrap())
        .collect();
    fuzz("config", &seeds, cases() / 4, &|b| {
        let Ok(text) = std::str::from_utf8(b) else {
            return false;
        };
        match RunConfig::parse(text) {
            Ok(c) => {
                // What `train` and `model summary` compute first from a config.
                assert!(
                    c.model.d_model % c.model.heads == 0
                        && c.training.batch_size > 0
                        && c.diffusion.steps > 0
                );
                true
            }
            Err(_) => false,
        }
    });
}
