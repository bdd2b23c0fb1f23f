//! `diffkfc model ...` and `diffkfc text-embed`: inspect the network and the text encoder.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use burn::prelude::*;
use burn::tensor::Distribution;
use clap::{Args, Subcommand};
use diffkfc_model::run_config::RunConfig;
use diffkfc_model::text::{self, minilm::MiniLm, TextEncoder};
use diffkfc_model::Condition;

#[derive(Args)]
pub struct ModelArgs {
    #[command(subcommand)]
    command: ModelCommand,
}

#[derive(Subcommand)]
enum ModelCommand {
    /// Parameters per module and in total.
    #[command(after_help = "Example:\n  diffkfc model summary --config configs/paper-humanml3d.json")]
    Summary {
        #[arg(long)]
        config: PathBuf,
    },
    /// Time the forward pass: the keyframe encoder once, the decoder per denoising step.
    /// Prints one JSON line.
    #[command(after_help = "Example:\n  diffkfc model bench --config configs/paper-humanml3d.json --batch 2 --frames 196")]
    Bench {
        #[arg(long)]
        config: PathBuf,
        #[arg(long, default_value_t = 2)]
        batch: usize,
        #[arg(long, default_value_t = 196)]
        frames: usize,
        #[arg(long, default_value_t = 5)]
        repeats: usize,
        #[arg(long, default_value = "flex")]
        device: String,
        /// Also time a whole DDIM sample of this many steps (one motion, 5% keyframes, keyframe
        /// guidance 2.5 and transition guidance 100) and a single guided denoising step.
        #[arg(long)]
        sample_steps: Option<usize>,
    },
}

#[derive(Args)]
pub struct TextEmbedArgs {
    /// The sentence to embed.
    #[arg(long)]
    text: String,
    /// Directory with model.safetensors, config.json and tokenizer.json
    /// (default: $DIFFKFC_TEXT_ENCODER or ~/.cache/diffkfc/text-encoder).
    #[arg(long)]
    encoder_dir: Option<PathBuf>,
}

pub fn run(a: ModelArgs) -> Result<()> {
    match a.command {
        ModelCommand::Summary { config } => {
            let cfg = RunConfig::load(&config).map_err(anyhow::Error::msg)?;
            let model = cfg.model.init(&Device::flex());
            println!("{}: d_model {}, heads {}, ffn {}, decoder layers {}, DMA sizes {:?}", config.display(), cfg.model.d_model, cfg.model.heads, cfg.model.ffn, cfg.model.dec_layers, cfg.model.dma_sizes);
            for (name, n) in model.param_counts() {
                println!("  {name:<42} {n:>12} ({:.2} M)", n as f64 / 1e6);
            }
            println!("  (the frozen text encoder, all-MiniLM-L6-v2, adds 22.7 M that are not trained)");
            Ok(())
        }
        ModelCommand::Bench { config, batch, frames, repeats, device, sample_steps } => {
            let cfg = RunConfig::load(&config).map_err(anyhow::Error::msg)?;
            let dev = crate::device::parse(&device)?;
            let model = cfg.model.init(&dev);
            let d = cfg.model.feat_dim;
            let x = Tensor::<3>::random([batch, frames, d], Distribution::Normal(0.0, 1.0), &dev);
            let k = (frames / 20).max(1);
            let kf_frames: Vec<bool> = (0..batch * frames).map(|i| (i % frames) % (frames / k) == 0).collect();
            let mask: Vec<f32> = kf_frames.iter().flat_map(|&f| std::iter::repeat_n(f as i32 as f32, d)).collect();
            let kf_mask = Tensor::<1>::from_floats(mask.as_slice(), &dev).reshape([batch, frames, d]);
            let cond = Condition { text: Tensor::random([batch, cfg.model.text_dim], Distribution::Normal(0.0, 0.05), &dev), kf: x.clone() * kf_mask.clone(), kf_mask, kf_frames, real: vec![true; batch * frames] };
            let t: Vec<usize> = (0..batch).map(|i| 500 + i).collect();
            let sync = |y: Tensor<3>| y.into_data();
            // Warm up once.
            let enc = model.encode(&cond);
            sync(model.decode(x.clone(), &t, &enc));
            let (mut enc_ms, mut dec_ms) = (Vec::new(), Vec::new());
            for _ in 0..repeats {
                let t0 = Instant::now();
                let enc = model.encode(&cond);
                sync(enc.tokens.clone());
                enc_ms.push(t0.elapsed().as_secs_f64() * 1e3);
                let t1 = Instant::now();
                sync(model.decode(x.clone(), &t, &enc));
                dec_ms.push(t1.elapsed().as_secs_f64() * 1e3);
            }
            let med = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let (e, dd) = (med(&mut enc_ms), med(&mut dec_ms));
            println!(
                "{}",
                serde_json::json!({"case": "forward", "config": config.display().to_string(), "device": device, "batch": batch, "frames": frames,
                    "params": model.num_params(), "encoder_ms": e, "decoder_ms": dd, "forward_ms": e + dd, "repeats": repeats})
            );
            if let Some(steps) = sample_steps {
                use diffkfc_model::sampler::{sample, Options, Request, Sampler};
                let schedule = diffkfc_model::diffusion::Schedule::cosine(cfg.diffusion.steps);
                let mut mask = vec![0f32; frames * d];
                for f in diffkfc_data::keyframes::uniform(frames, diffkfc_data::keyframes::count(frames, 0.05)) {
                    mask[f * d..(f + 1) * d].iter_mut().for_each(|m| *m = 1.0);
                }
                let req = Request { batch: 1, frames, dim: d, text: vec![0.05; cfg.model.text_dim], text_dim: cfg.model.text_dim, kf: mask.clone(), mask, lengths: vec![frames] };
                for (case, sampler) in [("sample_ddim", Sampler::Ddim(steps)), ("sample_single_step", Sampler::Ddim(1))] {
                    let t0 = Instant::now();
                    let out = sample(&model, &schedule, &req, &Options { sampler, ..Options::default() }, |_, _| {});
                    let ms = t0.elapsed().as_secs_f64() * 1e3;
                    let n = match sampler { Sampler::Ddim(k) => k, Sampler::Ddpm => schedule.steps };
                    println!("{}", serde_json::json!({"case": case, "config": config.display().to_string(), "frames": frames, "steps": n,
                        "kf_guidance": 2.5, "transition_guidance": 100.0, "total_ms": ms, "finite": out.iter().all(|v| v.is_finite())}));
                }
            }
            Ok(())
        }
    }
}

pub fn text_embed(a: TextEmbedArgs) -> Result<()> {
    let dir = a.encoder_dir.unwrap_or_else(text::default_dir);
    let enc = MiniLm::load(&dir, &Device::flex())?;
    let ids = enc.token_ids(&a.text).context("--text")?;
    let emb = enc.embed(&[a.text.as_str()]).context("--text")?.remove(0);
    println!("{}", serde_json::json!({"encoder": enc.name(), "text": a.text, "token_ids": ids, "dim": emb.len(), "embedding": emb}));
    Ok(())
}
