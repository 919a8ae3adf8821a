//! `objloc fuse SESSION --model MODEL.json`: replay a session into the Bayesian 3D grid, print
//! the located objects, write the report (JSON) and the grid (.npy).

use super::say;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;

use crate::viz::{
    self, VizArgs,
    fuse::{FuseViz, VizOptions},
};
use objloc_core::fuse::grid::{GridStorage, MAX_EXPORT_BYTES};
use objloc_core::fuse::motion::BlurMode;
use objloc_core::fuse::objects::ObjectParams;
use objloc_core::fuse::replay::{
    FuseOptions, Locate, Outcome, PoseSource, ReplayError, SessionFit, replay,
};
use objloc_core::io::session::{IndexScope, SessionReader};
use objloc_core::learn::model::Model;
use objloc_core::out::report::{Report, file_sha256};

use super::TopicArgs;
use super::progress::ReplayProgress;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The session to replay.
    pub session: PathBuf,
    /// The trained classifier (from `objloc train`).
    #[arg(long, value_name = "MODEL.json")]
    pub model: PathBuf,
    #[command(flatten)]
    pub fuse: FuseArgs,
    /// Write the report (JSON, schema in schemas/report.schema.json).
    #[arg(long, value_name = "OUT.json")]
    pub report: Option<PathBuf>,
    /// Write the posterior probabilities as a float32 .npy: the whole grid, shape (nx, ny,
    /// nz), when it is stored dense; the box of its stored blocks when sparse (the report's
    /// grid.export and stdout say where it lies).
    #[arg(long, value_name = "OUT.npy")]
    pub grid: Option<PathBuf>,
    #[command(flatten)]
    pub topics: TopicArgs,
    #[command(flatten)]
    pub rerun: VizArgs,
}

/// Fusion options shared by `fuse` and `demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct FuseArgs {
    /// Grid bounds in odom, metres. Default for a ground robot (a session with /cmd_vel): the
    /// box around the camera positions, 0.25 m margin, at least 4 m in x and y, z from 0 to
    /// 0.5 m above the camera. Without /cmd_vel (hand-held, arm, SfM captures): the region
    /// the cameras look at, where their optical axes converge, in the session's units.
    #[arg(long, value_name = "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", value_parser = parse_bounds, allow_hyphen_values = true)]
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Cell edge length, metres. Default: 0.04 (the paper's) for a ground robot; with bounds
    /// from where the cameras look, 1/200 of their longest side.
    #[arg(long, value_name = "M")]
    pub voxel: Option<f64>,
    /// Prior probability of a cell. Default: the model's base rate (fraction of positive
    /// training tiles), against which its probabilities are calibrated.
    #[arg(long, value_name = "P")]
    pub prior: Option<f64>,
    /// Translational speed noise sigma_v, m/s (a speed, not a fraction): how far the driven
    /// speed strays from the commanded one. A robot that drives 5 % off at 0.3 m/s has 0.015;
    /// typed as 0.05 the search looks more than three times as far as the robot can err.
    #[arg(long = "sigma-v", default_value_t = FuseOptions::default().sigma_v_mps, value_name = "M/S", value_parser = parse_noise)]
    pub sigma_v: f64,
    /// Rotational speed noise sigma_w, rad/s (a turn rate, not a fraction): 3 % at 0.3 rad/s
    /// is 0.009.
    #[arg(long = "sigma-w", default_value_t = FuseOptions::default().sigma_w_radps, value_name = "RAD/S", value_parser = parse_noise)]
    pub sigma_w: f64,
    /// What the motion blur averages: log-odds (default, measured best), probability (the
    /// paper), or observation (docs/fuser.md).
    #[arg(long, value_enum, default_value_t = BlurMode::LogOdds)]
    pub blur: BlurMode,
    /// Clamp cell probabilities to [LO, HI] after each update (off by default).
    #[arg(long, value_name = "LO,HI", value_parser = parse_clamp)]
    pub clamp: Option<(f64, f64)>,
    /// Frame poses from `odometry` (/odom) or `ground-truth` (/ground_truth/pose, simulated
    /// sessions: separates odometry error from classifier error).
    #[arg(long, value_enum, default_value_t = PoseSource::Odometry)]
    pub poses: PoseSource,
    /// Localise each frame against the objects and the floor seen so far before fusing it,
    /// searching around the odometry prediction under the motion model (--sigma-v/--sigma-w:
    /// set them to your robot's speed noise). The default for a ground robot's session (with
    /// /cmd_vel); a session without commands (a hand-held or arm camera) is refined only when
    /// asked with this flag. See docs/fuser.md.
    #[arg(long, overrides_with = "no_refine_poses")]
    pub refine_poses: bool,
    /// Fuse every frame at its /odom pose, as the paper does (no pose refinement).
    #[arg(long, overrides_with = "refine_poses")]
    pub no_refine_poses: bool,
    /// Localise against the objects only, not also against the floor (for a camera that
    /// does not see a flat floor around the robot).
    #[arg(long, conflicts_with = "no_refine_poses")]
    pub no_floor: bool,
    /// Keep the filter's poses: no second solution of every pose over the whole replay.
    /// By default a refined replay's poses are solved again together (every frame's
    /// detections of every object under the motion model, frames the floor placed held
    /// there) and kept when their grid finds as many objects (docs/fuser.md, "A smoother
    /// over the whole replay"). Harmless beside --no-refine-poses (nothing is smoothed then),
    /// so that one set of extra flags serves every mode of a comparison.
    #[arg(long)]
    pub no_smooth: bool,
    /// Where an object's location comes from: the centre of its `extent` in the grid, or
    /// the centre triangulated from its `detections`' boxes. Default: the extent for a
    /// ground robot's session (with /cmd_vel), the detections otherwise (docs/realdata.md).
    #[arg(long, value_enum, value_name = "FROM")]
    pub locate: Option<Locate>,
    /// Frames that must have seen a cell before it can belong to an object.
    #[arg(long, default_value_t = ObjectParams::default().min_views)]
    pub min_views: u16,
    /// Evidence (log-odds above the prior) an object must reach somewhere, as a fraction of
    /// the grid's highest.
    #[arg(long, default_value_t = ObjectParams::default().seed_fraction, value_parser = parse_fraction)]
    pub seed_fraction: f32,
    /// Evidence every cell of an object must have, as a fraction of the grid's highest.
    #[arg(long, default_value_t = ObjectParams::default().grow_fraction, value_parser = parse_fraction)]
    pub grow_fraction: f32,
    /// Also search the final grid for instances weaker than the grid's peak rule finds, apart
    /// from the objects found (a twin on the floor that fewer frames saw; docs/fuser.md,
    /// Objects). The default for a ground robot's session (with /cmd_vel); a capture without
    /// commands is searched only when asked with this flag.
    #[arg(long, overrides_with = "no_weaker_instances")]
    pub weaker_instances: bool,
    /// Report only the objects of the grid's peak rule: no search for weaker instances.
    #[arg(long, overrides_with = "weaker_instances")]
    pub no_weaker_instances: bool,
    /// Range limit of a frame's update: it stops at the depth where a tile's footprint
    /// exceeds this many cells (`off`: no limit). Beyond it one tile's value covers a wall of
    /// cells and locates nothing, and a building-sized grid would store every cell in view.
    #[arg(long, value_name = "CELLS|off", default_value_t = Footprint(FuseOptions::default().max_footprint_voxels), value_parser = parse_footprint)]
    pub max_footprint: Footprint,
    /// How the grid is stored: dense (every cell), sparse (only the blocks of 8 x 8 x 8 cells
    /// the views and the blur reach) or auto (dense up to 33.5 million cells, sparse beyond).
    /// The grid's values do not depend on it.
    #[arg(long, value_enum, default_value_t = GridStorage::Auto)]
    pub grid_storage: GridStorage,
    /// No progress bar (there is none anyway when stderr is not a terminal).
    #[arg(long, short)]
    pub quiet: bool,
}

fn parse_floats(s: &str, n: usize) -> Result<Vec<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "expected {n} finite comma-separated numbers, got {s:?}"
        ));
    }
    Ok(v)
}

/// `--max-footprint`: a number of cells, or no limit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint(pub Option<f64>);

impl std::fmt::Display for Footprint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(n) => write!(f, "{n}"),
            None => write!(f, "off"),
        }
    }
}

/// A positive, finite number of cells, or `off`.
fn parse_footprint(s: &str) -> Result<Footprint, String> {
    if s.trim() == "off" {
        return Ok(Footprint(None));
    }
    let v: f64 = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!(
            "expected a number of cells above 0, or off, got {s}"
        ));
    }
    Ok(Footprint(Some(v)))
}

fn parse_bounds(s: &str) -> Result<([f64; 3], [f64; 3]), String> {
    let v = parse_floats(s, 6)?;
    Ok(([v[0], v[1], v[2]], [v[3], v[4], v[5]]))
}

/// Probability bounds 0 < LO < HI < 1 (a bound at 0 or 1 is no clamp in log-odds).
fn parse_clamp(s: &str) -> Result<(f64, f64), String> {
    let v = parse_floats(s, 2)?;
    let (lo, hi) = (v[0], v[1]);
    if !(0.0 < lo && lo < hi && hi < 1.0) {
        return Err(format!(
            "expected probabilities 0 < LO < HI < 1, got {lo} and {hi}"
        ));
    }
    Ok((lo, hi))
}

/// A speed noise: finite and not negative (0 declares that motion is exact).
fn parse_noise(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("expected a finite speed noise >= 0, got {s}"));
    }
    Ok(v)
}

/// A fraction of the grid's peak evidence in (0, 1]: at 0 or below every cell at the prior
/// would qualify, whether stored or not.
fn parse_fraction(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if !(v > 0.0 && v <= 1.0) {
        return Err(format!("expected a fraction in (0, 1], got {s}"));
    }
    Ok(v)
}

impl FuseArgs {
    pub fn options(&self) -> FuseOptions {
        FuseOptions {
            bounds_m: self.bounds,
            voxel_size_m: self.voxel.unwrap_or(FuseOptions::default().voxel_size_m),
            prior: self.prior,
            sigma_v_mps: self.sigma_v,
            sigma_w_radps: self.sigma_w,
            blur: self.blur,
            clamp: self.clamp,
            objects: ObjectParams {
                min_views: self.min_views,
                seed_fraction: self.seed_fraction,
                grow_fraction: self.grow_fraction,
                weaker_instances: !self.no_weaker_instances,
                ..ObjectParams::default()
            },
            poses: self.poses,
            refine_poses: !self.no_refine_poses,
            refine_floor: !self.no_floor,
            locate: self.locate.unwrap_or_default(),
            fit: SessionFit {
                bounds: self.bounds.is_none(),
                voxel: self.voxel.is_none(),
                refinement: !self.refine_poses && !self.no_refine_poses,
                locate: self.locate.is_none(),
                weaker_instances: !self.weaker_instances && !self.no_weaker_instances,
            },
            max_footprint_voxels: self.max_footprint.0,
            grid_storage: self.grid_storage,
            smooth_poses: !self.no_smooth,
        }
        .normalised()
    }
}

/// A finished fuse: what `fuse` and `demo` print and write.
pub struct Fused {
    pub outcome: Outcome,
    pub report: Report,
    /// How far from the camera a frame's update reaches (`--max-footprint`), metres; None
    /// without a limit.
    pub update_range_m: Option<f64>,
    /// The saved recording, whole but not yet renamed: it goes into place with the report
    /// and the grid ([`write_outputs`]), or not at all.
    pub staged: objloc_core::io::output::Staged,
}

/// Loads the model and session, replays, and builds the report.
pub fn fuse(
    session: &Path,
    model_path: &Path,
    args: &FuseArgs,
    topics: &TopicArgs,
    rerun: &VizArgs,
    default_rrd: &Path,
) -> anyhow::Result<Fused> {
    // Checked before any file is read: a contradiction in the flags, not in the inputs.
    check_grid_flags(args)?;
    super::usage_check(
        !(args.refine_poses && args.sigma_v <= 0.0 && args.sigma_w <= 0.0),
        || {
            "--refine-poses searches under the motion model, and --sigma-v 0 --sigma-w 0 declare odometry exact: give a speed noise above 0, or drop --refine-poses".into()
        },
    )?;
    let t0 = Instant::now();
    let model = Model::load(model_path).context("loading the model")?;
    let reader = SessionReader::open_scoped(session, topics.topics()?, IndexScope::Roles)
        .context("reading the session")?;
    let session_sha256 = file_sha256(session).with_context(|| session.display().to_string())?;
    let model_sha256 = file_sha256(model_path).with_context(|| model_path.display().to_string())?;
    let t_load = t0.elapsed();
    let options = args.options();
    let t1 = Instant::now();
    let id = objloc_core::out::view::recording_id(
        "fuse",
        &[
            &session_sha256,
            &model_sha256,
            &serde_json::to_string(&options)?,
        ],
    );
    let stream = viz::open_stream(rerun, default_rrd, &id, Some(viz::fuse_blueprint()))?;
    let result = if stream.is_on() {
        match replay_streamed(&reader, &model, &options, &stream, args.quiet) {
            Err(Streaming::Log(e)) => {
                stream.abandon();
                return Err(e);
            }
            Err(Streaming::Replay(e)) => Err(e),
            Ok(o) => Ok(o),
        }
    } else {
        replay(
            &reader,
            &model,
            &options,
            &mut [&mut ReplayProgress::new(args.quiet)],
        )
    };
    let outcome = match result {
        Ok(o) => o,
        Err(e) => {
            stream.abandon();
            return Err(anyhow::Error::new(e).context("fusing"));
        }
    };
    let mut staged = objloc_core::io::output::Staged::default();
    if let Some((partial, path)) = stream.finish_staged()? {
        staged.adopt(partial, path);
    }
    let t_replay = t1.elapsed();
    let mut timing = BTreeMap::new();
    timing.insert("load".to_owned(), t_load.as_secs_f64() * 1e3);
    timing.insert("replay".to_owned(), t_replay.as_secs_f64() * 1e3);
    let report = Report::new(
        &outcome,
        &outcome.options,
        &session.display().to_string(),
        session_sha256,
        &model_path.display().to_string(),
        model_sha256,
        timing,
    );
    let update_range_m = outcome.options.max_footprint_voxels.map(|n| {
        objloc_core::fuse::grid::max_depth_m(
            &outcome.data.camera,
            model.tile_px,
            outcome.grid.spec.voxel_size_m,
            Some(n),
        )
    });
    Ok(Fused {
        outcome,
        report,
        update_range_m,
        staged,
    })
}

/// Why a streamed replay failed: the replay itself, or the logging to Rerun after it.
enum Streaming {
    Replay(ReplayError),
    Log(anyhow::Error),
}

/// The replay with the Rerun observer, then the final objects logged and the logging thread
/// drained. The observer's thread holds a handle on the recording: it must have logged
/// everything before the stream is closed. A failed replay drops it (and the caller abandons
/// the stream); a logging error fails the command.
fn replay_streamed(
    reader: &SessionReader,
    model: &Model,
    options: &FuseOptions,
    stream: &viz::VizStream,
    quiet: bool,
) -> Result<Outcome, Streaming> {
    let mut observer = FuseViz::new(stream.rec.clone(), VizOptions::default());
    let mut progress = ReplayProgress::new(quiet);
    let outcome = replay(reader, model, options, &mut [&mut observer, &mut progress])
        .map_err(Streaming::Replay)?;
    observer
        .final_objects(&outcome.objects)
        .and_then(|()| observer.finish())
        .map_err(|e| {
            Streaming::Log(anyhow::Error::new(e).context("streaming the replay to Rerun"))
        })?;
    Ok(outcome)
}

/// The grid's flags, checked by the grid's own rules before any file is read, as usage
/// errors: the grid refused them later, and the message then named the session as if it
/// were to blame.
fn check_grid_flags(args: &FuseArgs) -> anyhow::Result<()> {
    use objloc_core::fuse::grid::{MIN_PRIOR, check_bounds, check_prior, check_voxel};
    let usage = |what: String| anyhow::Error::new(super::UsageError(what));
    if let Some(v) = args.voxel {
        check_voxel(v).map_err(|_| {
            usage(format!(
                "--voxel {v} must be a positive number (the session's units)"
            ))
        })?;
    }
    if let Some((lo, hi)) = args.bounds {
        check_bounds(lo, hi).map_err(|_| {
            usage(format!(
                "--bounds: min {lo:?} must be below max {hi:?} on every axis"
            ))
        })?;
    }
    if let Some(prior) = args.prior {
        check_prior(prior).map_err(|_| {
            usage(format!(
                "--prior {prior} must lie within [{MIN_PRIOR:e}, 1 - {MIN_PRIOR:e}]"
            ))
        })?;
    }
    Ok(())
}

/// Writes the report and grid where asked; the grid's size is checked before anything is
/// written.
pub fn write_outputs(
    f: &mut Fused,
    report: Option<&Path>,
    grid: Option<&Path>,
) -> anyhow::Result<()> {
    // Every file before any line of text: a reader that goes away (`fuse ... | head -1`)
    // ends the command on its next line (SIGPIPE), which must not lose a file. All are
    // renamed into place together once all are written.
    let mut staged = std::mem::take(&mut f.staged);
    let recording = staged.targets().next().map(Path::to_path_buf);
    if let Some(p) = report {
        staged
            .write_with(p, |w| f.report.write_json(w))
            .with_context(|| format!("writing the report {}", p.display()))?;
    }
    let mut said = None;
    if let Some(p) = grid {
        let g = &f.outcome.grid;
        let region = g
            .export_region(MAX_EXPORT_BYTES)
            .with_context(|| format!("--grid {}", p.display()))?;
        write_grid(g, &region, p, &mut staged)
            .with_context(|| format!("writing the grid {}", p.display()))?;
        said = (region.dims != g.spec.dims).then(|| export_line(f, &region, p));
    }
    staged.commit().context("renaming the outputs into place")?;
    if let Some(p) = recording {
        super::say_recording(&p);
    }
    if let Some(line) = said {
        say!("{line}");
    }
    Ok(())
}

/// What stdout says of a grid exported as its stored region only.
fn export_line(f: &Fused, region: &objloc_core::fuse::grid::Region, p: &Path) -> String {
    let g = &f.outcome.grid;
    let [a, b, c] = region.dims;
    let e = f.report.grid.export.as_ref();
    let o = e.map_or([0.0; 3], |e| e.origin_m);
    let [i, j, k] = region.first_cell;
    format!(
        "grid {}: cells {i}..{}, {j}..{}, {k}..{} of the {} x {} x {} grid (the stored blocks), shape ({a}, {b}, {c}), min corner ({:.3}, {:.3}, {:.3}) m",
        p.display(),
        i + a,
        j + b,
        k + c,
        g.spec.dims[0],
        g.spec.dims[1],
        g.spec.dims[2],
        o[0],
        o[1],
        o[2]
    )
}

/// Bytes of x-slabs [`write_grid`] holds at a time (at least one slab, at most eight).
const EXPORT_BATCH_BYTES: usize = 64 << 20;

/// The probabilities of `region` of `grid` to `path` as float32 `.npy`, x-slab by x-slab
/// (up to eight, and up to [`EXPORT_BATCH_BYTES`], made at a time in parallel), never whole
/// in memory unless one slab is the whole region.
fn write_grid(
    grid: &objloc_core::fuse::grid::Grid,
    region: &objloc_core::fuse::grid::Region,
    path: &Path,
    staged: &mut objloc_core::io::output::Staged,
) -> anyhow::Result<()> {
    use rayon::prelude::*;
    let first = region.first_cell[0];
    let slabs: Vec<usize> = (first..first + region.dims[0]).collect();
    let slab_bytes = (region.dims[1] * region.dims[2] * 4).max(1);
    let batch = (EXPORT_BATCH_BYTES / slab_bytes).clamp(1, 8);
    let parts = slabs.chunks(batch).flat_map(|chunk| {
        chunk
            .par_iter()
            .map(|&i| grid.probability_slab(region, i))
            .collect::<Vec<_>>()
    });
    objloc_core::io::npy::write_parts_staged(staged, path, &region.dims, parts)?;
    Ok(())
}

/// The human summary of a fuse.
pub fn print_summary(f: &Fused) {
    let r = &f.report;
    // A ground robot's odom is metric; a capture without /cmd_vel (SfM, NeRF, LLFF poses)
    // is in whatever unit its poses are, and the numbers should not pretend otherwise.
    let m = if r.fitted.is_empty() {
        " m"
    } else {
        " (session units)"
    };
    let (lo, hi) = (f.outcome.grid.spec.origin_m, f.outcome.grid.spec.max_m());
    say!(
        "fused {} of {} frames into {} x {} x {} cells of {}{m} over ({:.2}, {:.2}, {:.2})..({:.2}, {:.2}, {:.2}) (prior {:.5}, grid sha256 {})",
        r.frames,
        r.frames_in_session,
        r.grid.dims[0],
        r.grid.dims[1],
        r.grid.dims[2],
        objloc_core::out::report::significant(r.grid.voxel_size_m, 5),
        lo[0],
        lo[1],
        lo[2],
        hi[0],
        hi[1],
        hi[2],
        r.grid.prior,
        &r.grid.sha256[..16]
    );
    if r.grid.storage == Some(GridStorage::Sparse) {
        let g = &f.outcome.grid;
        // Blocks of 8^3 cells are stored whole, so those at the grid's far edges hold cells
        // beyond it: a grid touched nearly everywhere stores more cells than it has.
        say!(
            "sparse grid: {} cells stored in blocks of 512 ({:.1} % of the grid's {} cells; blocks at its far edges reach past it), {} MiB",
            r.grid.stored_cells,
            100.0 * r.grid.stored_cells as f64 / g.spec.cells().max(1) as f64,
            g.spec.cells(),
            g.stored_bytes().div_ceil(1 << 20)
        );
    }
    if r.objects.is_empty() {
        say!("no object found");
        // A fine voxel shortens the range (a tile's footprint grows with depth): 0.005 m
        // cells stop a frame's update about a metre from the camera.
        if let (Some(d), Some(n)) = (f.update_range_m, r.options.max_footprint_voxels) {
            say!(
                "  a frame's update stops {d:.2}{m} from the camera (--max-footprint {n} cells of {}{m}): an object further away needs a larger --voxel or --max-footprint (or off)",
                objloc_core::out::report::significant(r.grid.voxel_size_m, 5),
            );
        }
    }
    for (i, o) in r.objects.iter().enumerate() {
        print_object(i, o, r.grid.voxel_size_m, m);
    }
    for c in &r.fitted {
        say!("fitted to the session: {c}");
    }
    if r.options.refine_poses {
        print_refinement(r);
    }
    super::print_warnings(&r.warnings);
}

/// One located object's lines: where it is, and where that location comes from (`m` is the
/// unit suffix, " m" or " (session units)").
fn print_object(i: usize, o: &objloc_core::fuse::objects::Object, voxel_size_m: f64, m: &str) {
    say!(
        "object {i}: at ({:.3}, {:.3}, {:.3}){m} (mass centroid ({:.3}, {:.3}, {:.3})), box ({:.2}, {:.2}, {:.2})..({:.2}, {:.2}, {:.2}), {} cells, peak p {:.4}, mean p {:.4}",
        o.centroid_m[0],
        o.centroid_m[1],
        o.centroid_m[2],
        o.mass_centroid_m[0],
        o.mass_centroid_m[1],
        o.mass_centroid_m[2],
        o.bbox_min_m[0],
        o.bbox_min_m[1],
        o.bbox_min_m[2],
        o.bbox_max_m[0],
        o.bbox_max_m[1],
        o.bbox_max_m[2],
        o.cells,
        o.peak_probability,
        o.mean_probability
    );
    if let Some(f) = o.weaker_instance {
        say!(
            "  a weaker instance: its evidence peaks at {f:.2} of the grid's highest (found apart from the objects above it, every frame that saw it agreeing: less certain than they are)"
        );
    }
    let grid_name = o.grid_location_name(voxel_size_m);
    if let (Some(d), Some(e)) = (&o.from_detections, &o.extent_centre_m) {
        say!(
            "  located from {} frames' detection boxes (rays {:.1} deg apart at most, rms miss {:.4}{m}); the {grid_name} was ({:.3}, {:.3}, {:.3})",
            d.rays,
            d.spread_deg,
            d.rms_miss_m,
            e[0],
            e[1],
            e[2]
        );
        if let Some(f) = d.first_choice_centre_m {
            say!(
                "  its rays chosen again {} time(s) around where they met: the first choice, around the {grid_name}, gave ({:.3}, {:.3}, {:.3})",
                d.rechosen,
                f[0],
                f[1],
                f[2]
            );
        }
    } else if let Some(why) = &o.not_from_detections {
        // The extent's centre is the weaker estimate where nothing closes the hull below
        // the object: the user should know this location is not the triangulated one.
        say!(
            "  located at the {grid_name}, the weaker estimate where no floor closes the hull below the object (on the real captures 15-20 % of its size off; docs/realdata.md): its detections do not triangulate: {why}"
        );
    }
}

/// What refinement did: the frames per verdict, how far the poses moved off /odom, whether
/// the floor was dropped, and a rollback with its reason.
fn print_refinement(r: &Report) {
    use objloc_core::fuse::refine::Verdict;
    let mut counts: Vec<(Verdict, usize)> = Vec::new();
    let (mut max_m, mut max_deg) = (0.0f64, 0.0f64);
    for f in &r.per_frame {
        if let Some(c) = f.correction {
            match counts.iter_mut().find(|(v, _)| *v == c.outcome) {
                Some((_, n)) => *n += 1,
                None => counts.push((c.outcome, 1)),
            }
        }
        let d =
            (f.position_m[0] - f.odom_position_m[0]).hypot(f.position_m[1] - f.odom_position_m[1]);
        let a = objloc_core::types::geometry::wrap_angle(f.yaw_rad - f.odom_yaw_rad).to_degrees();
        max_m = max_m.max(d);
        max_deg = max_deg.max(a.abs());
    }
    let verdicts: Vec<String> = counts
        .iter()
        .map(|(v, n)| format!("{n} {}", v.label()))
        .collect();
    let against = if r.options.refine_floor {
        "the objects and the floor"
    } else {
        "the objects"
    };
    say!(
        "poses refined against {against}: {} of {} frames: {}; at most {max_m:.3} m and {max_deg:.1} deg from odometry",
        r.per_frame.len().saturating_sub(1),
        r.per_frame.len(),
        verdicts.join(", "),
    );
    if let Some(c) = r.refinement.as_ref() {
        say!(
            "refinement check: rays meet with mean chi-square {:.2} at the refined poses, {:.2} at /odom{}",
            c.refined_rays.mean_chi2,
            c.odometry_rays.mean_chi2,
            c.floor_disagreement
                .map(|[a, b]| format!("; floor disagreement {a:.3} refined, {b:.3} /odom"))
                .unwrap_or_default()
        );
        if !c.rolled_back && !c.detections_only.is_empty() {
            say!(
                "UNVERIFIED: {} of {} frames were corrected against the detections alone (frames {}), the rays this check compares; nothing independent shows them better than /odom (compare with --no-refine-poses)",
                c.detections_only.len(),
                r.per_frame.len(),
                frame_list(&c.detections_only),
            );
        }
        if c.rolled_back {
            say!(
                "ROLLED BACK to /odom: {}",
                c.reason
                    .as_deref()
                    .unwrap_or("the refined poses explained the frames worse")
            );
        }
        if let Some(sm) = &c.smoothing {
            say!(
                "smoothed over the whole replay{}: {} ({} detections; frames moved at most {:.3}{} and {:.1} deg from the {} poses)",
                if sm.kept { "" } else { " (NOT KEPT)" },
                sm.reason,
                sm.observations,
                sm.max_move_m,
                if r.fitted.is_empty() {
                    " m"
                } else {
                    " (session units)"
                },
                sm.max_turn_deg,
                if c.rolled_back { "/odom" } else { "refined" },
            );
        }
    }
}

/// Frame indices for a line of stdout: all of them up to 10, else the first 8 and a count.
fn frame_list(frames: &[usize]) -> String {
    let shown: Vec<String> = frames
        .iter()
        .take(if frames.len() > 10 { 8 } else { 10 })
        .map(|i| i.to_string())
        .collect();
    match frames.len() - shown.len() {
        0 => shown.join(", "),
        more => format!("{}, and {more} more", shown.join(", ")),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The recording goes beside the report, or beside the session when there is none.
    let default_rrd = match &args.report {
        Some(r) => viz::rrd_beside(r),
        None => {
            let stem = args
                .session
                .file_stem()
                .unwrap_or_default()
                .to_string_lossy();
            PathBuf::from(format!("{stem}-fuse.rrd"))
        }
    };
    let recording = args.rerun.file(&default_rrd);
    let mut outputs: Vec<(&str, &Path)> = [
        ("--report", args.report.as_deref()),
        ("--grid", args.grid.as_deref()),
    ]
    .into_iter()
    .filter_map(|(flag, p)| p.map(|p| (flag, p)))
    .collect();
    outputs.extend(recording.as_ref().map(|(what, p)| (*what, p.as_path())));
    super::prepare_outputs(
        &[("session", &args.session), ("--model", &args.model)],
        &outputs,
    )?;
    let mut f = fuse(
        &args.session,
        &args.model,
        &args.fuse,
        &args.topics,
        &args.rerun,
        &default_rrd,
    )
    .context("fuse")?;
    write_outputs(&mut f, args.report.as_deref(), args.grid.as_deref())?;
    print_summary(&f);
    let t = &f.report.timing_ms;
    say!(
        "time: load {:.1} ms, replay {:.1} ms",
        t.get("load").copied().unwrap_or(0.0),
        t.get("replay").copied().unwrap_or(0.0)
    );
    Ok(())
}
