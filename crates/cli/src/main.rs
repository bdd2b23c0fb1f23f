//! `diffkfc`: train, sample and evaluate DiffKFC (text + keyframes -> human motion).

mod args;
mod commands;
mod device;
mod progress;
mod signals;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "diffkfc",
    version,
    about = "Text-driven human motion diffusion with keyframes collaborated (DiffKFC, AAAI 2024)",
    after_help = "Examples:\n  diffkfc data features joints.npy -o features.npy\n  diffkfc data joints features.npy -o joints.npy\n\nRun `diffkfc <command> --help` for each command's options."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Datasets and motion files: convert between joint positions and HumanML3D features.
    #[command(
        after_help = "Examples:\n  diffkfc data features joints.npy -o features.npy\n  diffkfc data joints features.npy -o joints.npy"
    )]
    Data(commands::data::DataArgs),
    /// Draw motions: an animated GIF of one motion, a PNG contact sheet of several, or a 3D page.
    #[command(
        after_help = "Examples:\n  diffkfc render work/synth/new_joint_vecs/000000.npy -o walk.gif --keyframes 0,40,80\n  diffkfc render a.npy b.npy c.npy --sheet -o sheet.png"
    )]
    Render(commands::render::RenderArgs),
    /// Train DiffKFC: diffusion with keyframe masking, checkpoints, exact resume.
    #[command(
        after_help = "Examples:\n  diffkfc train --config configs/tiny.json --data work/synth --out runs/tiny --time-budget 10m\n  diffkfc train --config configs/tiny.json --data work/synth --out runs/tiny --resume"
    )]
    Train(commands::train::TrainArgs),
    /// Generate motion from text and keyframes with keyframe and transition guidance.
    #[command(
        after_help = "Examples (after scripts/quickstart.sh, which writes work/synth):\n  diffkfc sample --checkpoint models/mid-synth --text \"a person walks forward and waves\" --num-samples 2\n  diffkfc sample --checkpoint models/mid-synth --text \"a person walks forward\" --from work/synth/new_joint_vecs/000001.npy --frames 0,40,80\n  diffkfc sample --checkpoint models/mid-synth --text \"a person dances\" --from mixamo_dance.bvh --frames all --joints lower_body\n  diffkfc sample --checkpoint models/mid-synth --text \"a person squats\" --keyframes keys.json --out out/squat\n\nkeys.json (poses in metres, places and headings in the output's frame: frame 0 at the origin facing +Z):\n  {\"length\": 120, \"keyframes\": [\n    {\"frame\": 0, \"joints\": [[x, y, z], ... 22 joints]},\n    {\"frame\": 60, \"joints\": [[x, y, z], ...], \"root\": [0.0, 0.9, 2.0], \"heading\": 90},\n    {\"frame\": 119, \"root\": [1.5, 0.9, 3.0]}]}"
    )]
    Sample(commands::sample::SampleArgs),
    /// Keyframe files: suggest keyframes from a text (or a motion) to edit and in-fill.
    #[command(
        after_help = "Example:\n  diffkfc keyframes suggest --checkpoint models/mid-synth --text \"a person jumps forward.\" --count 4 -o keys.json"
    )]
    Keyframes(commands::sample::suggest::KeyframesArgs),
    /// The keyframe editor in the browser: pose keys, drag them in time and space, type a
    /// prompt and see the motion between them regenerate at once.
    Serve(commands::serve::ServeArgs),
    /// The Blender add-on as a zip to install: a sidebar panel that sends the active
    /// armature's keyed poses and a prompt to `diffkfc serve` and writes the motion back.
    #[command(after_help = "Example:\n  diffkfc blender-addon -o diffkfc_blender.zip")]
    BlenderAddon(commands::blender_addon::BlenderAddonArgs),
    /// Evaluate a checkpoint: FID, R-precision, Diversity, ADE, K-Err, K-TranS (Tables 2 and 4);
    /// `eval train-evaluator` trains the text-motion evaluator first.
    #[command(after_help = commands::eval::AFTER_HELP)]
    Eval(commands::eval::EvalArgs),
    /// The network: parameter counts; a trained run exported as a model directory.
    #[command(
        after_help = "Example:\n  diffkfc model summary --config configs/paper-humanml3d.json"
    )]
    Model(commands::model::ModelArgs),
    /// Benchmarks: training step, sampling call, DDIM sample, data loading (JSON lines), and
    /// side by side with the PyTorch reference.
    #[command(after_help = commands::bench::AFTER_HELP)]
    Bench(commands::bench::BenchArgs),
    /// Print a sentence's token ids and text embedding as JSON (checks the text encoder).
    #[command(
        after_help = "Example:\n  diffkfc text-embed --text \"a person walks forward and waves his left hand.\""
    )]
    TextEmbed(commands::model::TextEmbedArgs),
}

/// Keep freed tensor buffers in the heap: glibc's defaults hand blocks of a few MB back to the
/// kernel (mmap/munmap, trimming), and every later allocation pays page faults and zeroing.
/// Measured on the paper sampling call: 274 -> 255 ms; training step 5.22 -> 5.14 s.
/// One arena: rayon's workers otherwise free into per-thread arenas whose heaps glibc shrinks
/// (`perf stat`: 283 k page faults per paper training step -> ~0; step 5.0 -> 4.1-4.2 s).
fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; called before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
}

/// A closed stdout (`diffkfc ... | head -1`) ends the process quietly, as it ends `cat` or
/// `ls`, instead of a panic in `println!`; every output file is written to a temporary name and
/// renamed, so ending mid-way leaves complete files only.
fn quiet_on_closed_pipe() {
    #[cfg(unix)]
    // SAFETY: restores the default action of one signal; called before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() {
    tune_allocator();
    quiet_on_closed_pipe();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(), // --help, --version
        Err(e) => {
            // Usage errors in one line, like every other error of the tool.
            let text = e.to_string();
            let mut lines = text.lines();
            let mut first = lines
                .next()
                .unwrap_or("invalid arguments")
                .trim_start_matches("error: ")
                .to_string();
            // "required arguments were not provided:" lists them on the following indented lines.
            if first.ends_with(':') {
                let items: Vec<&str> =
                    lines.take_while(|l| l.starts_with("  ")).map(str::trim).collect();
                first = format!("{first} {}", items.join(", "));
            }
            eprintln!("error: {first} (see --help)");
            std::process::exit(2);
        }
    };
    let result = match cli.command {
        Command::Data(args) => commands::data::run(args),
        Command::Render(args) => commands::render::run(args),
        Command::Model(args) => commands::model::run(args),
        Command::Bench(args) => commands::bench::run(args),
        Command::Train(args) if args.recipe.is_some() => commands::recipe::run(args),
        Command::Train(args) => commands::train::run(args),
        Command::Sample(args) => commands::sample::run(args),
        Command::Keyframes(args) => commands::sample::suggest::run(args),
        Command::Serve(args) => commands::serve::run(args),
        Command::BlenderAddon(args) => commands::blender_addon::run(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::TextEmbed(args) => commands::model::text_embed(args),
    };
    if let Err(e) = result {
        // One line, no backtrace: the cause chain joined with ": ".
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
