//! `objloc record sim|import`: parse options, show progress, call [`objloc_core::sim::record`] or
//! [`objloc_core::io::import::import`].

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use objloc_core::sim::{Kind, SimOptions, SpeedNoise};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    source: Source,
}

#[derive(Debug, clap::Subcommand)]
enum Source {
    /// Render a built-in or file scene from a simulated robot (byte-identical for a seed).
    Sim(SimArgs),
    /// Import a real image sequence with a TUM RGB-D trajectory and optional CSV labels.
    Import(ImportArgs),
}

#[derive(Debug, clap::Args)]
struct SimArgs {
    /// Built-in scene: chair, bottle, two-chairs.
    #[arg(
        long,
        conflicts_with = "scene_file",
        required_unless_present = "scene_file"
    )]
    scene: Option<String>,
    /// Scene JSON file (schema in schemas/scene.md).
    #[arg(long, value_name = "FILE")]
    scene_file: Option<PathBuf>,
    #[arg(long, value_enum)]
    kind: Kind,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Train sessions: number of labelled object views.
    #[arg(long, default_value_t = 3)]
    frames: usize,
    /// Tours: number of stops (one frame each).
    #[arg(long, default_value_t = 8)]
    stops: usize,
    /// Relative sigma of the executed driving and turning speeds, e.g. 0.05,0.03.
    #[arg(long, value_name = "TRANS,ROT", default_value = "0.01,0.006")]
    speed_noise: String,
    /// Systematic turn error: the robot turns (1 + F) times what odometry reports, e.g. 0.03
    /// (a known heading bias, to test pose refinement in `fuse`).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    turn_bias: f64,
    /// Also write each frame (and a copy with label rectangles) as PNG into DIR.
    #[arg(long, value_name = "DIR")]
    dump_frames: Option<PathBuf>,
    /// Output session (written as OUT.partial, renamed when complete).
    #[arg(short, long)]
    output: PathBuf,
}

#[derive(Debug, clap::Args)]
struct ImportArgs {
    /// Directory of images (png, jpeg), taken in file-name order.
    #[arg(long, value_name = "DIR")]
    images: PathBuf,
    /// TUM RGB-D trajectory: `timestamp tx ty tz qx qy qz qw` per line (camera in world).
    #[arg(long, value_name = "FILE")]
    trajectory: PathBuf,
    /// Pinhole intrinsics in pixels.
    #[arg(long, value_name = "FX,FY,CX,CY")]
    camera: String,
    /// CSV `image,x,y,width,height`; a row with an empty box marks a background frame.
    #[arg(long, value_name = "FILE")]
    labels: Option<PathBuf>,
    /// Object name written on /labels.
    #[arg(long, default_value = "object")]
    object: String,
    #[arg(short, long)]
    output: PathBuf,
}

fn floats<const N: usize>(s: &str, what: &str) -> anyhow::Result<[f64; N]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what} {s:?} is not {N} comma-separated numbers"))?;
    v.try_into()
        .map_err(|_| anyhow::anyhow!("{what} {s:?} is not {N} comma-separated numbers"))
}

fn progress_bar() -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(0);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames ({per_sec}, eta {eta})")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.source {
        Source::Sim(a) => run_sim(a),
        Source::Import(a) => run_import(a),
    }
}

fn run_sim(a: SimArgs) -> anyhow::Result<()> {
    let scene = match (&a.scene, &a.scene_file) {
        (Some(name), _) => objloc_core::sim::builtin_scene(name)?,
        (None, Some(file)) => objloc_core::sim::load_scene(file)?,
        (None, None) => anyhow::bail!("give --scene NAME or --scene-file FILE"),
    };
    let [trans, rot] = floats::<2>(&a.speed_noise, "--speed-noise")?;
    let opts = SimOptions {
        frames: a.frames,
        stops: a.stops,
        speed_noise: SpeedNoise {
            trans_rel_sigma: trans,
            rot_rel_sigma: rot,
            rot_rel_bias: a.turn_bias,
        },
        dump_frames: a.dump_frames,
        ..SimOptions::new(a.kind, a.seed)
    };
    let bar = progress_bar();
    bar.set_message(format!("{} {:?}", scene.name, a.kind).to_lowercase());
    let stats = objloc_core::sim::record(&scene, &opts, &a.output, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("record sim {} to {}", scene.name, a.output.display()))?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {} ({} frames, {} messages)",
        stats.path.display(),
        stats.frames,
        stats.messages
    );
    Ok(())
}

fn run_import(a: ImportArgs) -> anyhow::Result<()> {
    let camera = floats::<4>(&a.camera, "--camera")?;
    let opts = objloc_core::io::import::ImportOptions {
        images: a.images,
        trajectory: a.trajectory,
        camera,
        labels: a.labels,
        object: a.object,
    };
    let bar = progress_bar();
    bar.set_message("import");
    let stats = objloc_core::io::import::import(&opts, &a.output, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("record import to {}", a.output.display()))?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {} ({} frames, {} labelled; matched {})",
        stats.path.display(),
        stats.frames,
        stats.labelled,
        if stats.timestamps_from_names {
            "by file-name timestamps"
        } else {
            "in order"
        }
    );
    Ok(())
}
