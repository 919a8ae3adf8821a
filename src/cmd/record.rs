//! `objloc record sim|import`: parse options, show progress, call [`objloc_core::sim::record`] or
//! [`objloc_core::io::import::import`].

use std::path::PathBuf;

use super::{UsageError, say, usage_check};
use anyhow::Context;
use indicatif::ProgressBar;

use objloc_core::io::import::{Matching, PoseFile};
use objloc_core::sim::{Kind, SimOptions, SpeedNoise};
use objloc_core::types::lens::Distortion;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    source: Source,
}

#[derive(Debug, clap::Subcommand)]
enum Source {
    /// Render a built-in or file scene from a simulated robot (byte-identical for a seed).
    Sim(SimArgs),
    /// Import a real posed image sequence (TUM trajectory, NeRF, COLMAP, LLFF or IDR poses)
    /// with optional labels (CSV or masks).
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
    /// No progress bar (there is none anyway when stderr is not a terminal).
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Debug, clap::Args)]
#[command(group(
    clap::ArgGroup::new("poses")
        .required(true)
        .args(["trajectory", "nerf", "colmap", "llff", "idr"])
))]
struct ImportArgs {
    /// Directory of images (png, jpeg). TUM: names that are decimal seconds within the
    /// trajectory are the images' stamps, else image i (in natural name order: frame_2 before
    /// frame_10) takes line i; COLMAP: the folder the model's image names are relative to;
    /// LLFF and IDR: one image per pose row, by name.
    #[arg(long, value_name = "DIR", required_unless_present = "nerf")]
    images: Option<PathBuf>,
    /// TUM RGB-D trajectory: `timestamp tx ty tz qx qy qz qw` per line (camera in world).
    #[arg(long, value_name = "FILE", requires = "camera")]
    trajectory: Option<PathBuf>,
    /// With --trajectory: pinhole intrinsics in pixels.
    #[arg(long, value_name = "FX,FY,CX,CY", requires = "trajectory")]
    camera: Option<String>,
    /// With --trajectory: OpenCV radial-tangential lens distortion (plumb_bob).
    #[arg(
        long,
        value_name = "K1,K2,P1,P2[,K3]",
        requires = "trajectory",
        allow_hyphen_values = true
    )]
    distortion: Option<String>,
    /// NeRF / instant-ngp / nerfstudio transforms.json (OpenGL camera axes; image paths
    /// relative to it).
    #[arg(long, value_name = "FILE")]
    nerf: Option<PathBuf>,
    /// COLMAP model folder: cameras.txt + images.txt, or cameras.bin + images.bin.
    #[arg(long, value_name = "DIR")]
    colmap: Option<PathBuf>,
    /// LLFF poses_bounds.npy (rows in the images' string order).
    #[arg(long, value_name = "FILE")]
    llff: Option<PathBuf>,
    /// IDR / NeuS / DTU cameras.npz (world_mat_i for the i-th image by name).
    #[arg(long, value_name = "FILE")]
    idr: Option<PathBuf>,
    /// With --idr: the images are this region of the calibrated image, scaled to their size.
    #[arg(long, value_name = "X,Y,W,H", requires = "idr")]
    crop: Option<String>,
    /// CSV `image,x,y,width,height[,object]`, or the columns a header names
    /// (`filename,xmin,ymin,xmax,ymax,class` and the like: docs/realdata.md); a row with an
    /// empty box marks a background frame; several rows per image for several objects.
    #[arg(long, value_name = "FILE", conflicts_with = "masks")]
    labels: Option<PathBuf>,
    /// Folder of masks (`<stem>.png`, `<stem>-...png`, `<stem>_...png` for image `<stem>.*`):
    /// each labels its image with the rectangle around its foreground (alpha, else luminance).
    #[arg(long, value_name = "DIR")]
    masks: Option<PathBuf>,
    /// Object name written on /labels for rows (and masks) that name none.
    #[arg(long, default_value = "object")]
    object: String,
    /// The session to write (ROS 2 MCAP; written as OUTPUT.partial and renamed when complete).
    #[arg(short, long)]
    output: PathBuf,
    /// No progress bar (there is none anyway when stderr is not a terminal).
    #[arg(short, long)]
    quiet: bool,
}

/// The pose source the options name (clap has checked that exactly one is given).
fn pose_file(a: &ImportArgs) -> anyhow::Result<PoseFile> {
    check_qualifiers(a)?;
    let images = || {
        a.images
            .clone()
            .ok_or_else(|| UsageError("give --images DIR".into()))
    };
    Ok(if let Some(trajectory) = &a.trajectory {
        let camera = a
            .camera
            .as_deref()
            .ok_or_else(|| UsageError("--trajectory needs --camera FX,FY,CX,CY".into()))?;
        PoseFile::Tum {
            trajectory: trajectory.clone(),
            images: images()?,
            camera: camera_flag(camera)?,
            distortion: match &a.distortion {
                Some(d) => distortion(d)?,
                None => Distortion::default(),
            },
        }
    } else if let Some(transforms) = &a.nerf {
        PoseFile::Nerf {
            transforms: transforms.clone(),
        }
    } else if let Some(model) = &a.colmap {
        PoseFile::Colmap {
            model: model.clone(),
            images: images()?,
        }
    } else if let Some(poses_bounds) = &a.llff {
        PoseFile::Llff {
            poses_bounds: poses_bounds.clone(),
            images: images()?,
        }
    } else if let Some(cameras) = &a.idr {
        PoseFile::Idr {
            cameras: cameras.clone(),
            images: images()?,
            crop: a.crop.as_deref().map(crop_flag).transpose()?,
        }
    } else {
        return Err(
            UsageError("give one of --trajectory, --nerf, --colmap, --llff, --idr".into()).into(),
        );
    })
}

/// The flags that qualify one pose source, refused with any other: clap's `requires` lets
/// them through when another member of the pose-file group is given, and they were then
/// silently ignored.
fn check_qualifiers(a: &ImportArgs) -> anyhow::Result<()> {
    const TUM_ONLY: &str =
        "is only for --trajectory: the other pose files carry the camera's intrinsics and lens";
    // (flag, given, allowed with the pose source given, why not)
    let qualifiers = [
        (
            "--camera",
            a.camera.is_some(),
            a.trajectory.is_some(),
            TUM_ONLY,
        ),
        (
            "--distortion",
            a.distortion.is_some(),
            a.trajectory.is_some(),
            TUM_ONLY,
        ),
        (
            "--crop",
            a.crop.is_some(),
            a.idr.is_some(),
            "is only for --idr: the other pose files give the intrinsics of the images as they are",
        ),
        (
            "--images",
            a.images.is_some(),
            a.nerf.is_none(),
            "is not for --nerf: transforms.json names each image, relative to itself",
        ),
    ];
    for (flag, given, allowed, why) in qualifiers {
        usage_check(!given || allowed, || format!("{flag} {why}"))?;
    }
    Ok(())
}

/// `--camera FX,FY,CX,CY`: positive focal lengths, a finite principal point.
fn camera_flag(s: &str) -> anyhow::Result<[f64; 4]> {
    let v = floats::<4>(s, "--camera")?;
    usage_check(
        v[0] > 0.0 && v[1] > 0.0 && v.iter().all(|x| x.is_finite()),
        || format!("--camera {s:?}: FX and FY must be positive, CX and CY finite (pixels)"),
    )?;
    Ok(v)
}

/// `--crop X,Y,W,H`: a region of positive size at non-negative offsets.
fn crop_flag(s: &str) -> anyhow::Result<[f64; 4]> {
    let v = floats::<4>(s, "--crop")?;
    usage_check(
        v[0] >= 0.0 && v[1] >= 0.0 && v[2] > 0.0 && v[3] > 0.0 && v.iter().all(|x| x.is_finite()),
        || format!("--crop {s:?}: X and Y must be 0 or more, W and H positive (pixels)"),
    )?;
    Ok(v)
}

/// `K1,K2,P1,P2[,K3]` as a distortion.
fn distortion(s: &str) -> anyhow::Result<Distortion> {
    let v = match floats::<5>(s, "--distortion") {
        Ok(v) => v,
        Err(_) => {
            let [k1, k2, p1, p2] = floats::<4>(s, "--distortion")
                .map_err(|_| UsageError(format!("--distortion {s:?} is not K1,K2,P1,P2[,K3]")))?;
            [k1, k2, p1, p2, 0.0]
        }
    };
    // Checked here, as --camera is, by the rule CameraInfo `d` follows: a NaN was refused
    // later, and as the trajectory's --camera.
    if !objloc_core::io::msgs::lens_coefficients_plausible(&v) {
        return Err(UsageError(format!(
            "--distortion {s:?}: every coefficient must be finite and at most {} in size",
            objloc_core::io::msgs::MAX_DISTORTION_COEFFICIENT
        ))
        .into());
    }
    Ok(Distortion::from_plumb_bob(&v))
}

fn floats<const N: usize>(s: &str, what: &str) -> anyhow::Result<[f64; N]> {
    let bad = || UsageError(format!("{what} {s:?} is not {N} comma-separated numbers"));
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    Ok(v.try_into().map_err(|_| bad())?)
}

fn progress_bar(quiet: bool) -> ProgressBar {
    super::progress::frames_bar("", quiet)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.source {
        Source::Sim(a) => run_sim(a),
        Source::Import(a) => run_import(a),
    }
}

fn run_sim(a: SimArgs) -> anyhow::Result<()> {
    let scene = match (&a.scene, &a.scene_file) {
        (Some(name), _) => {
            objloc_core::sim::builtin_scene(name).map_err(|e| UsageError(e.to_string()))?
        }
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
    let bar = progress_bar(a.quiet);
    bar.set_message(format!("{} {:?}", scene.name, a.kind).to_lowercase());
    let stats = objloc_core::sim::record(&scene, &opts, &a.output, &mut |done, total| {
        super::progress::set_counts(&bar, done, total);
    })
    .map_err(|e| match e {
        // Counts beyond what the scene allows (--frames 99 of 8 views): the command line's.
        objloc_core::sim::SimError::Options(what) => UsageError(what).into(),
        e => anyhow::Error::new(e),
    })
    .with_context(|| format!("record sim {} to {}", scene.name, a.output.display()))?;
    bar.finish_and_clear();
    say!(
        "wrote {} ({} frames, {} messages)",
        stats.path.display(),
        stats.frames,
        stats.messages
    );
    Ok(())
}

fn run_import(a: ImportArgs) -> anyhow::Result<()> {
    let inputs: Vec<(&str, &std::path::Path)> = [
        ("--trajectory", a.trajectory.as_deref()),
        ("--nerf", a.nerf.as_deref()),
        ("--llff", a.llff.as_deref()),
        ("--idr", a.idr.as_deref()),
        ("--labels", a.labels.as_deref()),
    ]
    .into_iter()
    .filter_map(|(flag, p)| p.map(|p| (flag, p)))
    .collect();
    super::prepare_outputs(&inputs, &[("-o", &a.output)])?;
    let opts = objloc_core::io::import::ImportOptions {
        poses: pose_file(&a)?,
        labels: a.labels,
        masks: a.masks,
        object: a.object,
    };
    let bar = progress_bar(a.quiet);
    bar.set_message("import");
    let stats = objloc_core::io::import::import(&opts, &a.output, &mut |done, total| {
        super::progress::set_counts(&bar, done, total);
    })
    .with_context(|| format!("record import to {}", a.output.display()))?;
    bar.finish_and_clear();
    // The result on stdout like every command's; notes on stderr with the warnings.
    // Only a TUM trajectory is matched to the images (the other formats name each image).
    let matched = match &stats.tum_matching {
        Some(Matching::FileNameStamps | Matching::FileNameStampsWithout(_)) => {
            "; matched by file-name timestamps"
        }
        Some(_) => "; matched in order",
        None => "",
    };
    say!(
        "wrote {} ({} frames, {} labelled{matched})",
        stats.path.display(),
        stats.frames,
        stats.labelled,
    );
    if let Some(Matching::InOrderNotStamps(why)) = &stats.tum_matching {
        eprintln!("note: {why}");
    }
    if let Some(Matching::FileNameStampsWithout(names)) = &stats.tum_matching {
        let rows = match stats.label_rows_left_out {
            0 => String::new(),
            n => format!(", and their {n} label row(s)"),
        };
        eprintln!(
            "note: {} image(s) lie beyond the trajectory's first or last pose and are left out{rows} (unposed frames, as structure-from-motion leaves the ends of a sequence): {}",
            names.len(),
            names_listed(names)
        );
    }
    for note in &stats.notes {
        eprintln!("note: {note}");
    }
    if stats.distorted > 0 {
        say!(
            "{} frames carry lens distortion (CameraInfo d, plumb_bob); the replay rectifies them",
            stats.distorted
        );
    }
    if let Some((n, first, turn)) = &stats.exif_turned {
        eprintln!(
            "note: {n} of {} images carry an EXIF orientation that asks a viewer to turn them ({first}: {turn}); objloc uses the pixels as stored, as structure-from-motion tools do, so the labels and intrinsics must be for the stored images, not for ones a viewer turned",
            stats.frames
        );
    }
    Ok(())
}

/// Up to five names, then how many more.
fn names_listed(names: &[String]) -> String {
    let shown = names.iter().take(5).cloned().collect::<Vec<_>>().join(", ");
    match names.len() {
        n if n > 5 => format!("{shown} and {} more", n - 5),
        _ => shown,
    }
}
