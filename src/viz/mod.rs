//! Visual debugging in Rerun: where a command's recording goes (`--save`, `--spawn`,
//! `--connect`, `--stdout`, or by default an `.rrd` beside the report), the default layout,
//! and the shared colour map. [`fuse`] streams the fuser, [`train`] the decision tree.
//!
//! Invariants: a recording is a pure function of the command's inputs. Its recording id is a
//! hash of them ([`recording_id`]); the only timelines are `log_time` (the MCAP log time,
//! ns) and `frame` (a sequence): the SDK's wall-clock `log_time` and `log_tick` are turned off
//! before anything is logged, and the recording-properties chunk (start time) is never sent.
//! Row and chunk ids (TUIDs) are the SDK's own and differ between runs; `rerun rrd compare`
//! ignores them. A saved file is written as `NAME.partial` and renamed when complete.

pub mod fuse;
mod images;
pub mod train;

use std::path::{Path, PathBuf};

use rerun::{RecordingStream, RecordingStreamBuilder};
use thiserror::Error;

/// The Rerun application id of every objloc recording.
use objloc_core::out::view::APP_ID;

/// Timeline of MCAP log times (a timestamp, ns since the epoch of the session's clock).
pub const TIMELINE_LOG_TIME: &str = "log_time";
/// Port of the web viewer `--serve` starts (re_web_viewer_server's default).
pub const WEB_VIEWER_PORT: u16 = 9090;

/// Timeline of fused frames (0, 1, 2, ...).
pub const TIMELINE_FRAME: &str = "frame";

#[derive(Debug, Error)]
pub enum VizError {
    #[error("rerun: {0}")]
    Stream(#[from] rerun::RecordingStreamError),
    #[error("rerun: cannot create {path}: {what}")]
    Create { path: String, what: String },
    #[error("rerun: flushing the recording: {0}")]
    Flush(String),
    #[error("rerun: renaming {from} to {to}: {source}")]
    Rename {
        from: String,
        to: String,
        source: std::io::Error,
    },
    #[error("rerun: {0}")]
    Log(String),
    #[error("rerun: encoding a frame: {0}")]
    Encode(String),
}

/// Where the recording goes, decided from the Rerun flags as given on the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// No Rerun flag given: save to the command's default `.rrd`.
    Default,
    Save(PathBuf),
    Spawn,
    Connect(String),
    Stdout,
    /// `--serve`: a gRPC server and the web viewer on this machine, kept up after the command
    /// has logged everything until it is interrupted.
    Serve {
        bind: String,
        memory_limit: String,
    },
    /// `--no-rerun`: nothing is logged and observers that only feed Rerun are not run (batch
    /// sweeps, timing the replay alone).
    Off,
}

/// The standard Rerun flags ([`rerun::clap::RerunArgs`]) and where they send the recording:
/// RerunArgs' `--spawn` defaults to true and its fields are private, so the choice is read
/// from clap's value sources here (a flag counts only when given on the command line). Flatten it into a command's `Args`:
/// `#[command(flatten)] pub rerun: crate::viz::VizArgs`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VizArgs {
    pub target: Target,
}

fn target_from_matches(m: &clap::ArgMatches) -> Target {
    use clap::parser::ValueSource;
    let given = |id: &str| {
        m.try_get_raw(id).is_ok() && m.value_source(id) == Some(ValueSource::CommandLine)
    };
    if m.try_get_one::<bool>("no_rerun").ok().flatten() == Some(&true) {
        return Target::Off;
    }
    // Same precedence as RerunArgs: stdout, save, (serve), connect, spawn.
    if given("stdout") && m.get_flag("stdout") {
        return Target::Stdout;
    }
    if given("save")
        && let Some(p) = m.get_one::<PathBuf>("save")
    {
        return Target::Save(p.clone());
    }
    if given("serve") && m.get_flag("serve") {
        return Target::Serve {
            bind: m
                .get_one::<String>("bind")
                .cloned()
                .unwrap_or_else(|| "0.0.0.0".into()),
            memory_limit: m
                .get_one::<String>("server_memory_limit")
                .cloned()
                .unwrap_or_else(|| "25%".into()),
        };
    }
    if given("connect") {
        let url = m
            .get_one::<String>("connect")
            .cloned()
            .unwrap_or_else(|| rerun::DEFAULT_CONNECT_URL.to_owned());
        return Target::Connect(url);
    }
    if given("spawn") && m.get_one::<bool>("spawn").copied().unwrap_or(false) {
        return Target::Spawn;
    }
    Target::Default
}

impl clap::FromArgMatches for VizArgs {
    fn from_arg_matches(m: &clap::ArgMatches) -> Result<Self, clap::Error> {
        // Parsed for validation only: its fields are private; the target is read below.
        rerun::clap::RerunArgs::from_arg_matches(m)?;
        Ok(Self {
            target: target_from_matches(m),
        })
    }
    fn update_from_arg_matches(&mut self, m: &clap::ArgMatches) -> Result<(), clap::Error> {
        self.target = target_from_matches(m);
        Ok(())
    }
}

impl clap::Args for VizArgs {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        // RerunArgs carries `#[clap(author, version, about)]`, which would replace the
        // subcommand's own about text; keep ours.
        let about = cmd.get_about().cloned();
        // RerunArgs spells `--stdout` also `-o`, which our commands use for their output
        // file: two args with one short flag make clap's debug build panic and leave the
        // release build's choice to declaration order. `--stdout` stays.
        let cmd = rerun::clap::RerunArgs::augment_args(cmd)
            .mut_arg("stdout", |a| a.short(None))
            .next_help_heading("Rerun")
            .arg(
                clap::Arg::new("no_rerun")
                    .long("no-rerun")
                    .action(clap::ArgAction::SetTrue)
                    .conflicts_with_all(["stdout", "save", "serve", "connect", "spawn"])
                    .help("Log nothing to Rerun (no .rrd is written)"),
            );
        match about {
            Some(a) => cmd.about(a),
            None => cmd,
        }
    }
    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

/// An open recording (disabled under `--no-rerun`: see [`VizStream::is_on`]); call
/// [`VizStream::finish`] at the end.
pub struct VizStream {
    pub rec: RecordingStream,
    /// (partial, final) when saving to a file.
    file: Option<(PathBuf, PathBuf)>,
    /// Serving the web viewer: [`VizStream::finish`] keeps the process up.
    serving: bool,
}

impl std::fmt::Debug for VizStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VizStream")
            .field("file", &self.file)
            .finish()
    }
}

/// Chunks cut by row count alone, never by time or size: the default batcher cuts chunks on a
/// 200 ms timer, so two identical replays would be chunked differently and `rerun rrd compare`
/// would call them different. Nor by size: the SDK's size of a row is not a function of its
/// values alone (the same grid rows were cut after 4 rows in one run and 5 in another, at 1, 2
/// and 3 threads). One chunk per `log` call (what objloc did before) also compares equal, but
/// the SDK's memory grew by about 130 kB a frame with it (a 1000-frame replay peaked at 190 MB
/// against 86 MB for 200 frames; the Rust SDK's memory growth with small chunks is
/// rerun-io/rerun#12623). Rows wait in the batcher until their chunk is cut, so fewer rows a
/// chunk cost less memory: the 200- and 1000-stop tours peak at 98 and 126 MB with 8, 134 and
/// 164 MB with 16, 254 and 375 MB with 64 (docs/scale.md).
fn deterministic_batches() -> rerun::log::ChunkBatcherConfig {
    rerun::log::ChunkBatcherConfig {
        flush_tick: std::time::Duration::MAX,
        flush_num_bytes: u64::MAX,
        flush_num_rows: 8,
        ..rerun::log::ChunkBatcherConfig::DEFAULT
    }
}

/// Opens the recording where `args` say (`default_rrd` when no Rerun flag was given), with a
/// deterministic `recording_id`, the default timelines off, and `blueprint` as the default
/// layout.
pub fn open_stream(
    args: &VizArgs,
    default_rrd: &Path,
    recording_id: &str,
    blueprint: Option<rerun::blueprint::Blueprint>,
) -> Result<VizStream, VizError> {
    let mut builder = RecordingStreamBuilder::new(APP_ID)
        .recording_id(recording_id)
        .send_properties(false)
        .batcher_config(deterministic_batches())
        .enabled(true);
    if let Some(bp) = blueprint {
        builder = builder.with_blueprint(bp);
    }
    let (rec, file) = match &args.target {
        Target::Off => (RecordingStream::disabled(), None),
        Target::Default | Target::Save(_) => {
            let path = match &args.target {
                Target::Save(p) => p.clone(),
                _ => default_rrd.to_owned(),
            };
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).map_err(|e| VizError::Create {
                    path: dir.display().to_string(),
                    what: e.to_string(),
                })?;
            }
            let (partial, path) =
                objloc_core::io::output::destination(&path).map_err(|e| VizError::Create {
                    path: path.display().to_string(),
                    what: e.to_string(),
                })?;
            let rec = builder.save(&partial).map_err(|e| VizError::Create {
                path: partial.display().to_string(),
                what: e.to_string(),
            })?;
            (rec, Some((partial, path)))
        }
        Target::Spawn => (builder.spawn()?, None),
        Target::Connect(url) => (builder.connect_grpc_opts(url.clone())?, None),
        Target::Stdout => (builder.stdout()?, None),
        Target::Serve { bind, memory_limit } => {
            let options = rerun::ServerOptions {
                memory_limit: rerun::MemoryLimit::parse(memory_limit)
                    .map_err(|e| VizError::Log(format!("bad --server-memory-limit: {e}")))?,
                ..rerun::ServerOptions::default()
            };
            let rec = builder.serve_grpc_opts(bind, rerun::DEFAULT_SERVER_PORT, options)?;
            rerun::serve_web_viewer(rerun::web_viewer::WebViewerConfig {
                bind_ip: bind.clone(),
                // The viewer's default port (9090); the type itself is not exported.
                web_port: Default::default(),
                open_browser: true,
                connect_to: vec![format!(
                    "rerun+http://localhost:{}/proxy",
                    rerun::DEFAULT_SERVER_PORT
                )],
                ..Default::default()
            })
            .map_err(|e| VizError::Log(format!("cannot serve the web viewer: {e}")))?
            .detach();
            (rec, None)
        }
    };
    let serving = matches!(args.target, Target::Serve { .. });
    rec.set_log_time_enabled(false);
    rec.set_log_tick_enabled(false);
    Ok(VizStream { rec, file, serving })
}

impl VizStream {
    /// False under `--no-rerun`: logging is a no-op, so callers skip the work that only
    /// feeds the viewer.
    pub fn is_on(&self) -> bool {
        self.rec.is_enabled()
    }

    /// Closes the recording of a command that failed: a saved file is removed, so nothing
    /// half-written is left that looks like a result.
    pub fn abandon(self) {
        drop(self.rec);
        if let Some((partial, _)) = self.file {
            // Best effort: the command is already failing with its own error.
            let _ = std::fs::remove_file(partial);
        }
    }

    /// Flushes and closes the recording; a saved file is renamed into place and its path
    /// returned.
    pub fn finish(self) -> Result<Option<PathBuf>, VizError> {
        match self.finish_staged()? {
            Some((partial, path)) => {
                std::fs::rename(&partial, &path).map_err(|source| VizError::Rename {
                    from: partial.display().to_string(),
                    to: path.display().to_string(),
                    source,
                })?;
                Ok(Some(path))
            }
            None => Ok(None),
        }
    }

    /// Flushes and closes the recording; a saved file is left whole as its `.partial` file,
    /// returned with its final path, for the command to rename with its other outputs.
    pub fn finish_staged(self) -> Result<Option<(PathBuf, PathBuf)>, VizError> {
        self.rec
            .flush_blocking()
            .map_err(|e| VizError::Flush(e.to_string()))?;
        if self.serving {
            // As rerun's own `--serve`: the viewer needs the server alive after the last log.
            eprintln!(
                "serving the web viewer at http://localhost:{} (data: rerun+http://localhost:{}/proxy); press Ctrl-C when done",
                WEB_VIEWER_PORT,
                rerun::DEFAULT_SERVER_PORT
            );
            loop {
                std::thread::park();
            }
        }
        // Dropping the last handle closes the file sink, which writes the footer and joins
        // its writer thread; only then is the file complete.
        drop(self.rec);
        Ok(self.file)
    }
}

/// The command that opens a saved recording in the viewer.
pub fn open_command(path: &Path) -> String {
    format!("rerun {}", path.display())
}

/// `path` with its extension replaced by `.rrd` (the default recording beside a report).
/// How a message names the recording a command saves when no Rerun flag is given.
pub const DEFAULT_RECORDING: &str = "the default recording";

impl VizArgs {
    /// The file the recording will be written to, when it goes to a file (`--save`, or the
    /// command's default `.rrd`), with the words that name it in a message: what a command
    /// checks against its inputs and outputs.
    pub fn file(&self, default_rrd: &Path) -> Option<(&'static str, PathBuf)> {
        match &self.target {
            Target::Default => Some((DEFAULT_RECORDING, default_rrd.to_path_buf())),
            Target::Save(p) => Some(("--save", p.clone())),
            _ => None,
        }
    }
}

pub fn rrd_beside(path: &Path) -> PathBuf {
    path.with_extension("rrd")
}

pub(crate) fn log_err(e: impl std::fmt::Display) -> VizError {
    VizError::Log(e.to_string())
}

/// The default layout of a fuse recording: the 3D world and the camera (frame with the
/// probability overlay) side by side, the three projections and the plots below.
pub fn fuse_blueprint() -> rerun::blueprint::Blueprint {
    use rerun::blueprint::{
        Blueprint, Horizontal, Spatial2DView, Spatial3DView, TimeSeriesView, Vertical,
    };
    let world = Spatial3DView::new("world")
        .with_origin("/world")
        .with_contents(["$origin/**", "- /world/robot/camera/probability"]);
    let camera = Spatial2DView::new("camera + tile probabilities")
        .with_origin("/world/robot/camera")
        .with_contents(["$origin/image", "$origin/overlay"]);
    let probs = Spatial2DView::new("tile probabilities (hover)")
        .with_origin("/world/robot/camera")
        .with_contents(["$origin/probability"]);
    let px = Spatial2DView::new("mean posterior along x").with_origin("/projections/x");
    let py = Spatial2DView::new("mean posterior along y").with_origin("/projections/y");
    let pz = Spatial2DView::new("mean posterior along z").with_origin("/projections/z");
    // Probabilities, entropy and errors share one axis; the counts (hundreds of thousands of
    // cells) get their own, or they flatten everything else.
    let plots = TimeSeriesView::new("plots").with_origin("/plots");
    let counts = TimeSeriesView::new("counts").with_origin("/counts");
    Blueprint::new(
        Vertical::new([
            Horizontal::new([
                world.into(),
                Vertical::new([camera.into(), probs.into()]).into(),
            ])
            .with_column_shares([0.6, 0.4])
            .into(),
            Horizontal::new([
                px.into(),
                py.into(),
                pz.into(),
                Vertical::new([plots.into(), counts.into()]).into(),
            ])
            .into(),
        ])
        .with_row_shares([0.65, 0.35]),
    )
    .with_auto_views(false)
}

/// The default layout of a train recording: the tree graph and the training frames.
pub fn train_blueprint() -> rerun::blueprint::Blueprint {
    use rerun::blueprint::{Blueprint, GraphView, Horizontal, Spatial2DView, Vertical};
    Blueprint::new(Horizontal::new([
        GraphView::new("decision tree").with_origin("/tree").into(),
        Vertical::new([
            Spatial2DView::new("training frame")
                .with_origin("/train/frame")
                .with_contents(["$origin/image", "$origin/labels", "$origin/overlay"])
                .into(),
            Horizontal::new([
                Spatial2DView::new("tile head: the fuser's evidence (hover)")
                    .with_origin("/train/frame")
                    .with_contents(["$origin/probability"])
                    .into(),
                Spatial2DView::new("region head: predict's maps (hover)")
                    .with_origin("/train/frame")
                    .with_contents(["$origin/region_probability"])
                    .into(),
            ])
            .into(),
        ])
        .into(),
    ]))
    .with_auto_views(false)
}
