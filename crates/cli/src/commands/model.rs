//! `diffkfc model ...` and `diffkfc text-embed`: inspect the network and the text encoder.

use std::path::PathBuf;

use anyhow::{Context, Result};
use burn::prelude::*;
use clap::{Args, Subcommand};
use diffkfc_model::run::config::RunConfig;
use diffkfc_model::text::{self, minilm::MiniLm, TextEncoder};

#[derive(Args)]
pub struct ModelArgs {
    #[command(subcommand)]
    command: ModelCommand,
}

#[derive(Subcommand)]
enum ModelCommand {
    /// Parameters per module and in total.
    #[command(
        after_help = "Example:\n  diffkfc model summary --config configs/paper-humanml3d.json"
    )]
    Summary {
        /// A run config (configs/*.json) or a run/model directory's config.json.
        #[arg(long)]
        config: PathBuf,
    },
    /// A trained run as a model directory for `--checkpoint`: model.safetensors (the EMA
    /// weights, f16 by default; no optimiser state), config.json, Mean.npy/Std.npy, and the
    /// run's metrics.jsonl and loss.svg.
    #[command(
        after_help = "Example:\n  diffkfc model export --checkpoint work/runs/tiny --out models/my-model\n  diffkfc sample --checkpoint models/my-model --text \"a person walks forward\""
    )]
    Export {
        /// Run directory (its newest checkpoint) or one ckpt-*.safetensors file.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Model directory to write (created; an exported model's files are replaced). A folder
        /// holding other files or another kind of diffkfc output is refused unless --force.
        #[arg(long)]
        out: PathBuf,
        /// Write the model into a --out folder that holds other files.
        #[arg(long)]
        force: bool,
        /// Weight precision: f16 (half the size) or f32.
        #[arg(long, default_value = "f16", value_parser = ["f16", "f32"])]
        dtype: String,
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
            let cfg = RunConfig::load(&config)?;
            let model = cfg.model.init(&Device::flex());
            println!(
                "{}: d_model {}, heads {}, ffn {}, decoder layers {}, DMA sizes {:?}",
                config.display(),
                cfg.model.d_model,
                cfg.model.heads,
                cfg.model.ffn,
                cfg.model.dec_layers,
                cfg.model.dma_sizes
            );
            for (name, n) in model.param_counts() {
                println!("  {name:<42} {n:>12} ({:.2} M)", n as f64 / 1e6);
            }
            println!(
                "  (the frozen text encoder, all-MiniLM-L6-v2, adds 22.7 M that are not trained)"
            );
            Ok(())
        }
        ModelCommand::Export { checkpoint, out, dtype, force } => {
            let e =
                diffkfc_model::run::checkpoint::export(&checkpoint, &out, dtype == "f16", force)?;
            println!(
                "{}: step {} as {dtype}, {:.2} MB; wrote {}",
                out.display(),
                e.step,
                e.bytes as f64 / 1e6,
                e.files
                    .iter()
                    .filter_map(|f| f.file_name())
                    .map(|n| n.to_string_lossy().into_owned())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            Ok(())
        }
    }
}

pub fn text_embed(a: TextEmbedArgs) -> Result<()> {
    let dir = a.encoder_dir.unwrap_or_else(text::default_dir);
    let enc = MiniLm::load(&dir, &Device::flex())?;
    let ids = enc.token_ids(&a.text).context("--text")?;
    let emb = enc.embed(&[a.text.as_str()]).context("--text")?.remove(0);
    println!(
        "{}",
        serde_json::json!({"encoder": enc.name(), "text": a.text, "token_ids": ids, "dim": emb.len(), "embedding": emb})
    );
    Ok(())
}
