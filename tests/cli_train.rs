//! End-to-end: `diffkfc train` writes checkpoints, metrics and a loss curve, resumes, survives
//! SIGKILL, and rejects bad input with one-line errors.

mod common;
use common::*;
use std::path::Path;
use std::process::{Child, Command, Stdio};

use diffkfc_model::run::checkpoint::Checkpoint;

const CFG: &str = r#"{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0]},
  "training": {"batch_size": 4, "max_steps": 6, "checkpoint_every": 2, "keep_checkpoints": 2,
               "val_every": 3, "val_batches": 1, "log_every": 1}}"#;

fn setup(name: &str) -> (Scratch, std::path::PathBuf) {
    let d = scratch(name);
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "20", "--seed", "9"])
        .status
        .success());
    std::fs::write(d.join("cfg.json"), CFG).unwrap();
    (d, data)
}

/// `train --config cfg --data data --out run --max-steps 100000 [extra]` in the background
/// (for at most two minutes).
fn spawn_train(cfg: &Path, data: &Path, run: &Path, extra: &[&str], stderr: Stdio) -> Child {
    Command::new(env!("CARGO_BIN_EXE_diffkfc"))
        .args(["train", "--config", s(cfg), "--data", s(data), "--out", s(run)])
        // A budget, so that a child left running by a failed assertion ends by itself.
        .args(["--max-steps", "100000", "--time-budget", "120s"])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .unwrap()
}

/// `train ... --resume --max-steps steps` to its end.
fn resume_to(cfg: &Path, data: &Path, run: &Path, steps: u64) -> std::process::Output {
    let steps = steps.to_string();
    diffkfc(&[
        "train",
        "--config",
        s(cfg),
        "--data",
        s(data),
        "--out",
        s(run),
        "--resume",
        "--max-steps",
        &steps,
    ])
}

fn signal(pid: u32, name: &str) {
    assert!(Command::new("kill")
        .args([&format!("-{name}"), &pid.to_string()])
        .status()
        .unwrap()
        .success());
}

fn steps(run: &Path) -> Vec<u64> {
    // Training steps (validation-only lines carry no "loss").
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v.get("loss").is_some())
        .map(|v| v["step"].as_u64().unwrap())
        .collect()
}

/// Two training steps of the test config with `model_key` added to its model section, into
/// `d/name`, with `extra` arguments.
fn train_variant(
    d: &Path,
    data: &Path,
    name: &str,
    model_key: &str,
    extra: &[&str],
) -> (std::path::PathBuf, std::process::Output) {
    let cfg = d.join(format!("{name}.json"));
    let with = format!("\"preset\": \"tiny\", {model_key}");
    std::fs::write(&cfg, CFG.replace("\"preset\": \"tiny\"", &with)).unwrap();
    let out = d.join(name);
    let mut args = vec!["train", "--config", s(&cfg), "--data", s(data), "--out", s(&out)];
    args.extend(["--max-steps", "2"]);
    args.extend(extra);
    let o = diffkfc(&args);
    (out, o)
}

/// [`train_variant`] started from `run`'s weights (`--init`), into `d/<projection>`: it must
/// succeed and name the projection's two tensors as the ones initialised.
fn train_grown(
    d: &Path,
    data: &Path,
    run: &Path,
    model_key: &str,
    projection: &str,
) -> std::path::PathBuf {
    let (grown, o) = train_variant(d, data, projection, model_key, &["--init", s(run)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = format!("{}{}", stdout(&o), stderr(&o));
    let fresh = format!("initialised: {projection}.weight, {projection}.bias");
    assert!(said.contains(&fresh), "{said}");
    grown
}

/// The first sample in `out` is 40 frames of 263 finite HumanML3D features.
fn assert_finite_sample(out: &Path) {
    let feats = diffkfc_data::io::npy::read_f32(out.join("sample_00.npy")).unwrap().data;
    assert_eq!(feats.len(), 40 * 263);
    assert!(feats.iter().all(|v| v.is_finite()));
}

/// A keyframe file of a 40-frame motion with the one keyframe `key` (JSON), as `d/name`.
fn write_keys(d: &Path, name: &str, key: &str) -> std::path::PathBuf {
    let keys = d.join(name);
    std::fs::write(&keys, format!(r#"{{"length": 40, "keyframes": [{key}]}}"#)).unwrap();
    keys
}

/// `sample` of "a person walks." from `ckpt` with the keyframe file `keys` into `out`.
fn sample_keyed(ckpt: &Path, keys: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["sample", "--checkpoint", s(ckpt), "--text", "a person walks."];
    args.extend(["--keyframes", s(keys), "--out", s(out)]);
    args.extend(extra);
    diffkfc(&args)
}

#[test]
fn train_resume_and_outputs() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("train");
    let run = d.join("run");
    let cfg = d.join("cfg.json");
    let o = diffkfc(&[
        "train",
        "--config",
        s(&cfg),
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--max-steps",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("steps 0..4"), "{}", stdout(&o));
    for f in [
        "config.json",
        "metrics.jsonl",
        "loss.svg",
        "ckpt-00000004.safetensors",
        "ckpt-00000002.safetensors",
    ] {
        assert!(run.join(f).exists(), "{f} missing");
    }
    assert_eq!(steps(&run), vec![1, 2, 3, 4]);
    let svg = std::fs::read_to_string(run.join("loss.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("<path"));
    // Without --resume an existing run is refused; with it, training continues.
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run)]),
        &["--resume"],
    );
    let o =
        diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run), "--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("steps 4..6"), "{}", stdout(&o));
    assert_eq!(steps(&run), vec![1, 2, 3, 4, 5, 6]);
    // Another training recipe is not an exact resume: refused, naming what differs.
    let other = d.join("other-lr.json");
    std::fs::write(&other, CFG.replace("\"batch_size\": 4", "\"batch_size\": 4, \"lr\": 0.01"))
        .unwrap();
    let o = resume_to(&other, &data, &run, 8);
    assert_one_line_error(&o, &["--resume", "training.lr 0.0001 -> 0.01", "--init"]);
    // Two checkpoints kept.
    assert!(
        !run.join("ckpt-00000002.safetensors").exists()
            && run.join("ckpt-00000006.safetensors").exists()
    );
    // A model grown by the per-frame key input starts from this run's weights (--init): every
    // shared tensor taken, the input's projection initialised; its run samples with a keyframe.
    let ki = train_grown(&d, &data, &run, "\"key_input\": true", "key_in");
    assert_eq!(steps(&ki), vec![1, 2]);
    let keys = write_keys(&d, "ki-keys.json", r#"{"frame": 20, "root": [0.3, 0.9, 1.0]}"#);
    let ki_out = d.join("ki-sample");
    let o = sample_keyed(&ki, &keys, &ki_out, &["--steps", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_finite_sample(&ki_out);
    // Wider feed-forward blocks start from the run's weights (named as widened); narrower
    // ones are refused, naming the tensor.
    let (wide, o) = train_variant(&d, &data, "wide", "\"ffn\": 256", &["--init", s(&run)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("widened") && stderr(&o).contains("layers.0.ff2.weight"));
    assert_eq!(steps(&wide), vec![1, 2]);
    let (_, o) = train_variant(&d, &data, "narrow", "\"ffn\": 64", &["--init", s(&run)]);
    assert_one_line_error(&o, &["--init", "mlp1.weight", "shape"]);
    // A run trained with text drop samples with text guidance (2.5 by default), alone and
    // beside keyframe guidance (three branches); one trained without it is refused by sample
    // and eval, and samples without it by default.
    let cfg_td = d.join("text-drop.json");
    std::fs::write(
        &cfg_td,
        CFG.replace(r#""training": {"#, r#""training": {"text_drop_prob": 0.5, "#),
    )
    .unwrap();
    let td = d.join("text-drop");
    let o = diffkfc(&[
        "train",
        "--config",
        s(&cfg_td),
        "--data",
        s(&data),
        "--out",
        s(&td),
        "--max-steps",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let td_out = d.join("td-sample");
    // Pose keys from a clip, so that keyframe guidance has its branch.
    let clip =
        std::fs::read_dir(data.join("new_joint_vecs")).unwrap().next().unwrap().unwrap().path();
    for extra in [&[][..], &["--text-guidance", "2.5", "--kf-guidance", "2"]] {
        let mut args = vec!["sample", "--checkpoint", s(&td), "--text", "a person walks."];
        args.extend(["--from", s(&clip), "--keyframe-rate", "0.1", "--steps", "2"]);
        args.extend(["--out", s(&td_out), "--force"]);
        let o = diffkfc(&[&args[..], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
        let feats = diffkfc_data::io::npy::read_f32(td_out.join("sample_00.npy")).unwrap().data;
        assert!(!feats.is_empty() && feats.iter().all(|v| v.is_finite()));
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(td_out.join("results.json")).unwrap())
                .unwrap();
        assert_eq!(r["text_guidance"], 2.5);
    }
    let o = sample_keyed(&run, &keys, &td_out, &["--steps", "2", "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = std::fs::read_to_string(td_out.join("results.json")).unwrap();
    assert_eq!(serde_json::from_str::<serde_json::Value>(&r).unwrap()["text_guidance"], 1.0);
    let refused = ["--text-guidance: 2", "text_drop_prob"];
    assert_one_line_error(
        &sample_keyed(&run, &keys, &td_out, &["--text-guidance", "2", "--force"]),
        &refused,
    );
    let o = diffkfc(&[
        "eval",
        "--checkpoint",
        s(&run),
        "--evaluator",
        s(&d.join("no-evaluator")),
        "--data",
        s(&data),
        "--text-guidance",
        "2",
    ]);
    assert_one_line_error(&o, &refused);
    // A retired option turned on is refused, naming the key; at its neutral value it loads.
    let (_, o) = train_variant(&d, &data, "abs", "\"absolute_root\": true", &[]);
    assert_one_line_error(&o, &["model.absolute_root: true", "no longer supported"]);
    // A time budget stops cleanly with a checkpoint.
    let run2 = d.join("budget");
    let o = diffkfc(&[
        "train",
        "--config",
        s(&cfg),
        "--data",
        s(&data),
        "--out",
        s(&run2),
        "--max-steps",
        "100000",
        "--time-budget",
        "3s",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("time budget reached"), "{}", stdout(&o));
    let last = *steps(&run2).last().unwrap();
    assert!(run2.join(format!("ckpt-{last:08}.safetensors")).exists());
}

/// A model grown with word states by `--init` and trained on them alone (`training.trainable`):
/// the word tensors are named as initialised, every other weight stays the source's bit for
/// bit, the word attention moves, and the grown model samples (its text input with words).
#[test]
fn word_states_grown_trained_alone_and_sampled() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("train-words");
    let (run, o) = train_variant(&d, &data, "base", "\"temporal_kernel\": 3", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cfg = d.join("words.json");
    let grown_cfg = CFG
        .replace(
            "\"preset\": \"tiny\"",
            "\"preset\": \"tiny\", \"temporal_kernel\": 3, \"text_words\": 8",
        )
        .replace(r#""training": {"#, r#""training": {"trainable": ["word"], "lr": 0.01, "#);
    std::fs::write(&cfg, grown_cfg).unwrap();
    let words = d.join("words");
    let mut args = vec!["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&words)];
    args.extend(["--max-steps", "2", "--init", s(&run)]);
    let o = diffkfc(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = stderr(&o);
    assert!(
        said.contains("layers.0.words.output.weight") && said.contains("word_in.proj"),
        "{said}"
    );
    let latest = |dir: &Path| Checkpoint::latest(dir).unwrap().unwrap();
    let (base, grown) = (latest(&run), latest(&words));
    let source = base.ema.as_ref().unwrap_or(&base.model);
    for (i, n) in grown.names.iter().enumerate() {
        match base.names.iter().position(|b| b == n) {
            Some(j) => assert!(grown.model[i] == source[j], "{n} moved"),
            None => assert!(n.contains("word"), "{n}"),
        }
    }
    let out_w = grown.names.iter().position(|n| n == "layers.0.words.output.weight").unwrap();
    assert!(grown.model[out_w].iter().any(|&v| v != 0.0), "the word attention did not train");
    let keys = write_keys(&d, "keys.json", r#"{"frame": 30, "root": [0.5, 0.9, 2.0]}"#);
    let out = d.join("words-sample");
    let o = sample_keyed(&words, &keys, &out, &["--steps", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_finite_sample(&out);
    // A pattern naming no parameter is refused before any step.
    std::fs::write(
        &cfg,
        CFG.replace(r#""training": {"#, r#""training": {"trainable": ["wrod"], "#),
    )
    .unwrap();
    let o =
        diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&d.join("bad"))]);
    assert_one_line_error(&o, &["training.trainable", "wrod"]);
}

#[test]
fn sigkill_then_resume() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("kill");
    let run = d.join("run");
    let cfg = d.join("cfg.json");
    std::fs::write(&cfg, CFG.replace("\"checkpoint_every\": 2", "\"checkpoint_every\": 1"))
        .unwrap();
    let mut child = spawn_train(&cfg, &data, &run, &[], Stdio::null());
    let t0 = std::time::Instant::now();
    while !run.join("ckpt-00000003.safetensors").exists() && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let o = resume_to(&cfg, &data, &run, 12);
    assert!(o.status.success(), "{}", stderr(&o));
    let st = steps(&run);
    assert_eq!(*st.last().unwrap(), 12);
    // Every step appears once, in order: the resumed run rewrote what followed its checkpoint.
    assert_eq!(st, (1..=12).collect::<Vec<u64>>());
}

/// A run killed before its first checkpoint: `--resume` starts it at step 0, from the `--init`
/// it was started with, and says so.
#[test]
fn resume_before_the_first_checkpoint_starts_the_run() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("restart");
    let cfg = d.join("cfg.json");
    let base = d.join("base");
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&base)]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::write(&cfg, CFG.replace("\"checkpoint_every\": 2", "\"checkpoint_every\": 100000"))
        .unwrap();
    let run = d.join("run");
    let mut child = spawn_train(&cfg, &data, &run, &["--init", s(&base)], Stdio::null());
    let t0 = std::time::Instant::now();
    while steps_or_none(&run).is_none_or(|s| s.is_empty()) && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL, before any checkpoint
    child.wait().unwrap();
    assert!(Checkpoint::list(&run).is_empty());
    let o = resume_to(&cfg, &data, &run, 3);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("holds no checkpoint yet; starting it at step 0 from --init"), "{err}");
    assert!(err.contains("base"), "{err}");
    assert_eq!(steps(&run), vec![1, 2, 3]);
    // A folder that is not a run is still refused.
    let mine = d.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), "mine").unwrap();
    assert_one_line_error(&resume_to(&cfg, &data, &mine, 3), &["--resume", "not a diffkfc run"]);
}

/// `train --recipe`: the sets drawn, each stage from the one before, the model exported; run
/// again, nothing is redone; a bad recipe is one line naming the stage.
#[test]
fn a_recipe_trains_its_stages_and_exports_the_model() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("recipe");
    let recipe = d.join("r.json");
    let base = CFG.replace("\"max_steps\": 6", "\"max_steps\": 3");
    let text = format!(
        r#"{{"model": "t", "data": {{"s": {{"body": "legacy", "clips": 20, "seed": 9}}}},
          "stages": [{{"name": "one", "data": "s", "config": {base}}},
                     {{"name": "two", "data": "s", "stop_at": 2,
                       "config": {{"training": {{"lr": 1e-4}}}}}}]}}"#
    );
    std::fs::write(&recipe, &text).unwrap();
    let out = d.join("out");
    let o = diffkfc(&["train", "--recipe", s(&recipe), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(steps(&out.join("01-one")), vec![1, 2, 3]);
    assert_eq!(steps(&out.join("02-two")), vec![1, 2]);
    let init = std::fs::read_to_string(out.join("02-two/init-from.txt")).unwrap();
    assert!(init.ends_with("01-one"), "{init}");
    let stored: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("02-two/config.json")).unwrap())
            .unwrap();
    assert_eq!(stored["training"]["lr"], 1e-4);
    assert!(
        out.join("model/model.safetensors").exists() && out.join("data-s/manifest.json").exists()
    );
    let again = diffkfc(&["train", "--recipe", s(&recipe), "--out", s(&out)]);
    assert!(again.status.success(), "{}", stderr(&again));
    assert!(stderr(&again).contains("stage 02-two: done (step 2)"), "{}", stderr(&again));
    std::fs::write(&recipe, text.replace("1e-4", "-1")).unwrap();
    assert_one_line_error(
        &diffkfc(&["train", "--recipe", s(&recipe), "--out", s(&d.join("o2"))]),
        &["--recipe", "stages[1] (two): training.lr"],
    );
}

/// The shipped recipes parse, and their last stage is the shipped model's config.
#[test]
fn shipped_recipes_end_in_the_shipped_models() {
    use diffkfc_model::run::{config::RunConfig, recipe::Recipe};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    for model in ["mid-synth", "tiny-synth"] {
        let text =
            std::fs::read_to_string(root.join(format!("configs/{model}.recipe.json"))).unwrap();
        let r = Recipe::parse(&text).unwrap();
        assert_eq!(r.model, model);
        let last = r.stages().unwrap().pop().unwrap();
        let ours = RunConfig::parse(&last.config.to_string()).unwrap();
        let shipped = RunConfig::load(&root.join(format!("models/{model}/config.json"))).unwrap();
        assert_eq!(ours.model, shipped.model, "{model}");
        assert_eq!(ours.training, shipped.training, "{model}");
        assert_eq!(ours.keyframes, shipped.keyframes, "{model}");
    }
}

#[test]
fn bad_train_arguments() {
    let d = scratch("trainbad");
    let cfg = d.join("cfg.json");
    std::fs::write(&cfg, CFG).unwrap();
    assert_one_line_error(&diffkfc(&["train", "--config", s(&cfg)]), &["--data"]);
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&d.join("nothing"))]),
        &["nothing", "not found"],
    );
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--time-budget", "soon"]),
        &["soon"],
    );
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&d), "--init", "no/such/run"]),
        &["--init", "no/such/run", "does not exist"],
    );
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--optimiser-state", "gpu"]),
        &["--optimiser-state", "gpu", "host or device"],
    );
    // Data-parallel training needs CUDA devices (Burn 0.22 all-reduces only there): said
    // before anything is written.
    let dp = d.join("dp");
    let train_on = |devices: &str| {
        diffkfc(&[
            "train",
            "--config",
            s(&cfg),
            "--data",
            s(&d),
            "--out",
            s(&dp),
            "--devices",
            devices,
        ])
    };
    assert_one_line_error(&train_on("flex,flex"), &["--devices flex,flex", "CUDA devices only"]);
    assert_one_line_error(
        &train_on("cuda:0,cuda:1"),
        &["--devices cuda:0,cuda:1", "this build lacks it"],
    );
    assert_one_line_error(&train_on("cuda:one"), &["cuda:one", "must be a number"]);
    assert!(!dp.exists());
    let o = diffkfc(&["train", "--config", s(&cfg), "--device", "flex", "--devices", "flex,flex"]);
    assert!(!o.status.success() && stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
    // Nothing to train, or an impossible pair of flags.
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&d), "--max-steps", "0"]),
        &["--max-steps", "0 trains nothing"],
    );
    let o = diffkfc(&["train", "--config", s(&cfg), "--resume", "--init", s(&d)]);
    assert!(!o.status.success() && stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
    // --resume of a run that is not there is an error, not a new run.
    let missing = d.join("no-such-run");
    assert_one_line_error(
        &diffkfc(&[
            "train",
            "--config",
            s(&cfg),
            "--data",
            s(&d),
            "--out",
            s(&missing),
            "--resume",
        ]),
        &["--resume", "no-such-run", "does not exist"],
    );
    assert!(!missing.exists());
    // A user's folder and an exported model are never a run's --out.
    let mine = d.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("config.json"), "my notes").unwrap();
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&d), "--out", s(&mine)]),
        &["--out", "not a diffkfc run", "config.json", "--force"],
    );
    assert_eq!(std::fs::read_to_string(mine.join("config.json")).unwrap(), "my notes");
    let model = d.join("model");
    std::fs::create_dir_all(&model).unwrap();
    std::fs::write(model.join("model.safetensors"), "weights").unwrap();
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&d), "--out", s(&model), "--force"]),
        &["--out", "exported model", "--init"],
    );
    // Past max_steps a cosine schedule is at lr 0: refused rather than trained for nothing.
    let cos = d.join("cos.json");
    std::fs::write(
        &cos,
        CFG.replace("\"max_steps\": 6", "\"max_steps\": 6, \"cosine_decay\": true"),
    )
    .unwrap();
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cos), "--data", s(&d), "--max-steps", "7"]),
        &["--max-steps", "7", "training.max_steps 6"],
    );
    // A batch of about 12 GB under a process limit of 8 GB (`ulimit -v`) is refused whatever
    // the machine has free (it used to abort in the allocator after a minute).
    use diffkfc_model::training::memory;
    let tiny = diffkfc_model::run::config::RunConfig::parse(CFG).unwrap();
    let batch =
        ((12e9 - memory::fixed_bytes(&tiny)) / memory::per_sample_bytes(&tiny, 196)) as usize;
    let limited = d.join("limited.json");
    std::fs::write(&limited, CFG.replace("\"batch_size\": 4", &format!("\"batch_size\": {batch}")))
        .unwrap();
    let line = format!(
        "ulimit -v 8000000; exec {} train --config {} --data {}",
        env!("CARGO_BIN_EXE_diffkfc"),
        s(&limited),
        s(&d)
    );
    let o = Command::new("sh").args(["-c", &line]).output().unwrap();
    assert_one_line_error(&o, &["training.batch_size", &batch.to_string(), "ulimit", "fits"]);
    // A batch the machine cannot hold is refused before anything is loaded (it used to grow
    // until the kernel killed it).
    if diffkfc_model::training::memory::available_bytes().is_some_and(|b| b > 50e9) {
        eprintln!("SKIPPED: more than 50 GB free, a 16000 batch may fit here");
        return;
    }
    let big = d.join("big.json");
    std::fs::write(&big, CFG.replace("\"batch_size\": 4", "\"batch_size\": 16000")).unwrap();
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&big), "--data", s(&d)]),
        &["training.batch_size", "16000", "GB", "fits"],
    );
}

/// SIGTERM (what schedulers and `timeout` send) stops like Ctrl-C: a checkpoint at the step
/// reached and exit status 143; a resume with another model is refused before any run file is
/// rewritten; a run that goes non-finite stops with an error and keeps its finite checkpoints.
#[test]
fn sigterm_mismatched_resume_and_nan_guard() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("term");
    let run = d.join("run");
    let cfg = d.join("cfg.json");
    std::fs::write(&cfg, CFG.replace("\"checkpoint_every\": 2", "\"checkpoint_every\": 1000"))
        .unwrap();
    let child = spawn_train(&cfg, &data, &run, &[], Stdio::piped());
    let t0 = std::time::Instant::now();
    while steps_or_none(&run).is_none_or(|s| s.len() < 3) && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // A second training on the same run is refused while the first holds it.
    assert_one_line_error(
        &diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run)]),
        &["--out", "being written by another training", "pid"],
    );
    signal(child.id(), "TERM");
    let out = child.wait_with_output().unwrap();
    // 128 + 15: what shells and schedulers read as "terminated".
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(err.contains("SIGTERM: checkpoint written at step"), "{err}");
    let last = *steps(&run).last().unwrap();
    assert!(
        run.join(format!("ckpt-{last:08}.safetensors")).exists(),
        "no checkpoint at step {last}"
    );

    // Another model: refused, and config.json / Mean.npy stay the run's own.
    let before = (
        std::fs::read(run.join("config.json")).unwrap(),
        std::fs::read(run.join("Mean.npy")).unwrap(),
    );
    let other = d.join("other.json");
    std::fs::write(&other, CFG.replace("\"dec_layers\": 1", "\"dec_layers\": 2")).unwrap();
    assert_one_line_error(
        &diffkfc(&[
            "train",
            "--config",
            s(&other),
            "--data",
            s(&data),
            "--out",
            s(&run),
            "--resume",
        ]),
        &["--resume", "another model"],
    );
    assert_eq!(
        before,
        (
            std::fs::read(run.join("config.json")).unwrap(),
            std::fs::read(run.join("Mean.npy")).unwrap()
        )
    );

    // A second signal exits at once; the run still resumes from a whole checkpoint.
    let child = spawn_train(&cfg, &data, &run, &["--resume"], Stdio::null());
    let t0 = std::time::Instant::now();
    while steps_or_none(&run).is_none_or(|s| s.last().is_none_or(|&l| l < last + 2))
        && t0.elapsed().as_secs() < 120
    {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    signal(child.id(), "TERM");
    signal(child.id(), "INT");
    let code = child.wait_with_output().unwrap().status.code();
    // 130: the second signal ended it at once; 143: the first finished its checkpoint before
    // the second arrived.
    assert!(matches!(code, Some(130 | 143)), "{code:?}");
    let o = resume_to(&cfg, &data, &run, last + 10);
    assert!(o.status.success(), "{}", stderr(&o));

    // An absurd learning rate: an error naming the step, exit non-zero, finite checkpoints kept.
    let nan = d.join("nan.json");
    std::fs::write(
        &nan,
        CFG.replace("\"batch_size\": 4", "\"batch_size\": 4, \"lr\": 1e30, \"grad_clip\": 0")
            .replace("\"checkpoint_every\": 2", "\"checkpoint_every\": 1"),
    )
    .unwrap();
    let run3 = d.join("nan");
    let o = diffkfc(&[
        "train",
        "--config",
        s(&nan),
        "--data",
        s(&data),
        "--out",
        s(&run3),
        "--max-steps",
        "50",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not finite"), "{}", stderr(&o));
    for e in std::fs::read_dir(&run3).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "safetensors") {
            let bytes = std::fs::read(&p).unwrap();
            let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
            for (name, t) in st.tensors() {
                assert!(
                    t.data()
                        .chunks_exact(4)
                        .all(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite()),
                    "{}: {name}",
                    p.display()
                );
            }
        }
    }
}

fn steps_or_none(run: &Path) -> Option<Vec<u64>> {
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).ok()?;
    Some(
        text.lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter(|v| v.get("loss").is_some())
            .filter_map(|v| v["step"].as_u64())
            .collect(),
    )
}
