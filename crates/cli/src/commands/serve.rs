//! `diffkfc serve`: the keyframe editor in the browser (`diffkfc_serve`).

use std::net::IpAddr;
use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use diffkfc_serve::{Engine, ServeOptions};

use crate::signals::StopSignal;

#[derive(Args, Clone, Debug)]
#[command(
    after_help = "Example:\n  diffkfc serve --checkpoint models/mid-synth\n  then open http://127.0.0.1:7860/ in a browser"
)]
pub struct ServeArgs {
    /// Run directory, model directory or checkpoint file of the model to edit with.
    #[arg(long)]
    checkpoint: PathBuf,
    /// Port to listen on (0: any free port, printed).
    #[arg(long, default_value_t = 7860)]
    port: u16,
    /// Address to listen on. Only this machine can reach 127.0.0.1; any other address lets
    /// other machines drive the editor (a warning is printed).
    #[arg(long, default_value = "127.0.0.1")]
    host: IpAddr,
    /// Another name the browser may use for this server (the Host header is checked against
    /// the listening address and localhost); repeatable.
    #[arg(long, value_name = "NAME")]
    allow_host: Vec<String>,
    /// Generations that may wait behind the running one; more get "busy" (503).
    #[arg(long, default_value_t = 16)]
    queue: usize,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

pub fn run(a: ServeArgs) -> Result<()> {
    if !a.host.is_loopback() {
        eprintln!(
            "warning: --host {}: the editor is reachable from other machines, and anyone who reaches it can make this machine generate; browsers must use this address{} (others: --allow-host NAME)",
            a.host,
            if a.host.is_unspecified() { ", which they cannot: name the machine's address or name with --allow-host" } else { "" }
        );
    }
    if a.queue == 0 || a.queue > 1024 {
        anyhow::bail!("--queue: {} must be 1 to 1024", a.queue);
    }
    let device = crate::device::parse(&a.device)?;
    let stop = StopSignal::install()?;
    let opts = ServeOptions {
        host: a.host,
        port: a.port,
        allow_hosts: a.allow_host.clone(),
        queue: a.queue,
    };
    let ck = a.checkpoint.clone();
    let running = diffkfc_serve::start(&opts, move || Engine::load(&ck, &device))?;
    println!(
        "diffkfc editor: http://{}/ (model {}); Ctrl+C stops",
        running.addr,
        a.checkpoint.display()
    );
    while !stop.requested() {
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    eprintln!("{}: stopping the editor", stop.name());
    running.stop()?;
    std::process::exit(stop.exit_code().unwrap_or(0));
}
