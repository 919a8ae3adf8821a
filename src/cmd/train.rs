//! `objloc train SESSION... -o MODEL.json`: builds tile examples from labelled frames, grows
//! and prunes the probability tree, writes the model and prints the training table; on posed
//! captures, a second round with the frames the first model's located object labels
//! (`train_views`).

use super::{say, say_part, usage_check};

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use objloc_core::learn::dataset::ExampleSet;
use objloc_core::learn::dataset::{
    Augment, LoadedSession, TILE_PX_RANGE, export_features, load_session,
};
use objloc_core::learn::defaults::{TILE_PX, TRAIN_STRIDE_PX, TileHeadChoice, TileHeadDefaults};
use objloc_core::learn::features::FeatureSpec;
use objloc_core::learn::model::Model;
use objloc_core::learn::training::{RegionConfig, TrainConfig, examples, fit_model};
use objloc_core::learn::tree::{ForestParams, TreeParams};

use super::TopicArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Labelled sessions (frames with a label on /labels are used; on posed captures also
    /// frames the located object labels, see --no-more-views).
    #[arg(required = true)]
    sessions: Vec<PathBuf>,
    /// Where to write the model JSON.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
    /// No progress spinner (there is none anyway when stderr is not a terminal).
    #[arg(long, short)]
    quiet: bool,
    /// The tile head's channels, joined by '+': colour rgb332 | hsv | hs (hue and saturation
    /// without brightness), texture (brighter / darker neighbour counts), grad (gradient
    /// magnitude and orientation); e.g. rgb332+texture (docs/tree.md). Default: rgb332 when
    /// every session has /cmd_vel (a ground robot's: on those its maps fuse into the tightest
    /// objects), rgb332+hs otherwise (a posed capture, whose exposure and white balance
    /// change between frames); the choice is printed.
    #[arg(long, value_name = "SPEC")]
    features: Option<FeatureSpec>,
    /// Seed of the split into training, test and pruning thirds.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Tile side in pixels. Default: 8, and for a posed capture (no /cmd_vel) 8 more for every
    /// 880 px of its frames' shorter side past the first (16 at 1080 x 1920); printed.
    #[arg(long = "tile")]
    tile_px: Option<u32>,
    /// Also train on tiles of grids shifted by multiples of this many pixels (= --tile: the
    /// aligned grid only). Default: 4, half the tile where the session chose the tile.
    #[arg(long = "train-stride")]
    train_stride_px: Option<u32>,
    /// Photometric variants of the frames the shifted training grids are cut from: none, or
    /// light (darker, brighter, warmer, cooler; docs/tree.md). Default: none when every
    /// session has /cmd_vel, light otherwise (with shifted grids); the choice is printed.
    #[arg(long, value_enum)]
    augment: Option<Augment>,
    /// Trees in the tile head, their mean its probability: 1 is the paper's tree; more are
    /// each grown on half the training tiles, splitting on the square root of the features
    /// drawn per node (docs/tree.md). Default: 1 when every session has /cmd_vel, 16 otherwise
    /// (a posed capture); printed.
    #[arg(long)]
    trees: Option<u32>,
    /// Share of the training tiles each tree of a forest grows on, in (0, 1] (default 0.5;
    /// 1: every tree sees every tile and only the features drawn differ). Needs a forest.
    #[arg(long = "tree-sample-fraction", value_name = "FRACTION")]
    tree_sample_fraction: Option<f64>,
    /// Features each node of a forest's trees chooses its split among (default: the square
    /// root of the feature count; more than there are: all, so the trees differ only by
    /// their tiles). Needs a forest.
    #[arg(long = "split-features", value_name = "K")]
    split_features: Option<usize>,
    /// Use only labels naming this object (default: every label).
    #[arg(long)]
    object: Option<String>,
    /// m of the leaves' m-estimate (pos + m * base_rate) / (n + m).
    #[arg(long = "m-estimate", default_value_t = TreeParams::default().m_estimate)]
    m_estimate: f64,
    /// Stop growth after this many expansions without a better test log-loss.
    #[arg(long, default_value_t = TreeParams::default().patience)]
    patience: usize,
    /// Also describe each tile by the mean histogram of the tiles within this many tiles of
    /// it (0: the tile alone, as in the paper).
    #[arg(long = "context-tiles", default_value_t = TrainConfig::default().context_tiles)]
    context_tiles: u32,
    /// Pseudo-examples per leaf added to the pruning third at the leaf's training fraction,
    /// so that a handful of pruning examples cannot condense a well-supported split (0: the
    /// bare pruning third, as in the paper).
    #[arg(long = "prune-pseudo", default_value_t = TreeParams::default().prune_pseudo)]
    prune_pseudo: f64,
    /// Weight w of the base rate mixed into every leaf, p = (1 - w) * m-estimate + w * base
    /// rate: bounds the evidence one tile can give against the object (0: none).
    #[arg(long = "base-mix", default_value_t = TreeParams::default().base_mix)]
    base_mix: f64,
    /// The region head's channels (the tree `predict` answers with), as --features.
    #[arg(long = "region-features", default_value = "hsv", value_name = "SPEC")]
    region_features: FeatureSpec,
    /// Neighbourhood radius in tiles of the region head's features (1..=4).
    #[arg(long = "region-context-tiles", default_value_t = RegionConfig::default().context_tiles)]
    region_context_tiles: u32,
    /// Shifted-grid stride in pixels of the region head's training tiles.
    #[arg(long = "region-stride", default_value_t = RegionConfig::default().train_stride_px)]
    region_stride_px: u32,
    /// Train the tile head only (as model version 1 did): `predict` then writes its maps.
    #[arg(long = "no-region")]
    no_region: bool,
    /// Also write the tile head's examples as X.npy, y.npy, split.npy into this directory.
    #[arg(long = "export-features", value_name = "DIR")]
    export_features: Option<PathBuf>,
    /// Do not train a second round on posed captures (sessions without /cmd_vel) with the
    /// frames nobody labelled, each labelled by the object the first model's replay locates
    /// (docs/tree.md, "More views").
    #[arg(long = "no-more-views")]
    no_more_views: bool,
    #[command(flatten)]
    topics: TopicArgs,
    #[command(flatten)]
    pub(crate) rerun: crate::viz::VizArgs,
}

impl Args {
    fn more_views(&self) -> bool {
        !self.no_more_views
    }
}

/// Most trees `--trees` takes: a forest of 16 costs 1.1x one tree a frame at 1080 x 1920, and
/// 32 gained nothing over 16 (docs/tree.md).
const MAX_TREES: u32 = 256;

/// The training configuration the options ask for, checked before any work; the tile head's
/// channels are rgb332 until the sessions choose them ([`fit_to_sessions`]).
fn config(args: &Args) -> anyhow::Result<TrainConfig> {
    let cfg = TrainConfig {
        features: args.features.unwrap_or(FeatureSpec::RGB332),
        tile_px: args.tile_px.unwrap_or(TILE_PX),
        context_tiles: args.context_tiles,
        train_stride_px: args.train_stride_px.unwrap_or(TRAIN_STRIDE_PX),
        augment: args.augment.unwrap_or(Augment::None),
        seed: args.seed,
        object: args.object.clone(),
        tree: TreeParams {
            m_estimate: args.m_estimate,
            patience: args.patience,
            prune_pseudo: args.prune_pseudo,
            base_mix: args.base_mix,
            ..TreeParams::default()
        },
        forest: forest_params(args, args.trees.unwrap_or(1)),
        region: (!args.no_region).then_some(RegionConfig {
            features: args.region_features,
            context_tiles: args.region_context_tiles,
            train_stride_px: args.region_stride_px,
        }),
    };
    if let Some(n) = args.trees {
        usage_check((1..=MAX_TREES).contains(&n), || {
            format!("--trees {n} must be 1 to {MAX_TREES}")
        })?;
    }
    usage_check(
        cfg.tree.m_estimate.is_finite() && cfg.tree.m_estimate > 0.0,
        || {
            format!(
                "--m-estimate {} must be a positive number",
                cfg.tree.m_estimate
            )
        },
    )?;
    let max_context = objloc_core::learn::model::MAX_CONTEXT_TILES;
    usage_check(cfg.context_tiles <= max_context, || {
        format!(
            "--context-tiles {} is over {max_context}",
            cfg.context_tiles
        )
    })?;
    if let Some(r) = &cfg.region {
        usage_check((1..=max_context).contains(&r.context_tiles), || {
            format!(
                "--region-context-tiles {} must be in 1..={max_context}",
                r.context_tiles
            )
        })?;
    }
    // Before any work, at the tile asked for or 8 px; a tile the sessions fit is never
    // smaller, so what passes here passes there too (checked again after fitting).
    check_tiles(&cfg)?;
    usage_check(
        cfg.tree.prune_pseudo.is_finite() && cfg.tree.prune_pseudo >= 0.0,
        || {
            format!(
                "--prune-pseudo {} must be a number >= 0",
                cfg.tree.prune_pseudo
            )
        },
    )?;
    usage_check((0.0..1.0).contains(&cfg.tree.base_mix), || {
        format!("--base-mix {} must be in [0, 1)", cfg.tree.base_mix)
    })?;
    if let Some(f) = args.tree_sample_fraction {
        usage_check(f > 0.0 && f <= 1.0, || {
            format!("--tree-sample-fraction {f} must be in (0, 1]")
        })?;
    }
    usage_check(args.split_features != Some(0), || {
        "--split-features 0: a node needs at least one feature to split on".to_owned()
    })?;
    Ok(cfg)
}

/// `trees` trees, randomised as `--tree-sample-fraction` and `--split-features` ask.
fn forest_params(args: &Args, trees: u32) -> ForestParams {
    let mut forest = ForestParams::with_trees(trees);
    if forest.trees > 1 {
        if let Some(f) = args.tree_sample_fraction {
            forest.sample_fraction = f;
        }
        if let Some(k) = args.split_features {
            forest.split_features = Some(k);
        }
    }
    forest
}

/// A forest's options given to a single tree would be silently ignored: refused instead,
/// once the sessions have chosen the tree count.
fn check_forest_options(args: &Args, cfg: &TrainConfig) -> anyhow::Result<()> {
    let given = [
        (
            "--tree-sample-fraction",
            args.tree_sample_fraction.is_some(),
        ),
        ("--split-features", args.split_features.is_some()),
    ];
    for (flag, is_given) in given {
        usage_check(!is_given || cfg.forest.trees > 1, || {
            format!(
                "{flag} randomises a forest's trees, and this model is one tree: add --trees N (N >= 2)"
            )
        })?;
    }
    Ok(())
}

/// The options that depend on the tile side, checked before the tile head is trained.
fn check_tiles(cfg: &TrainConfig) -> anyhow::Result<()> {
    usage_check(TILE_PX_RANGE.contains(&cfg.tile_px), || {
        format!(
            "--tile {} px is outside {}..={} px",
            cfg.tile_px,
            TILE_PX_RANGE.start(),
            TILE_PX_RANGE.end()
        )
    })?;
    usage_check((1..=cfg.tile_px).contains(&cfg.train_stride_px), || {
        format!(
            "--train-stride {} px must be 1 to the tile size {} px",
            cfg.train_stride_px, cfg.tile_px
        )
    })?;
    if let Some(r) = &cfg.region {
        usage_check((1..=cfg.tile_px).contains(&r.train_stride_px), || {
            format!(
                "--region-stride {} px must be 1 to the tile size {} px",
                r.train_stride_px, cfg.tile_px
            )
        })?;
    }
    // Light variants are cut for the shifted grids only: without them it would do nothing.
    usage_check(
        cfg.augment == Augment::None || cfg.train_stride_px < cfg.tile_px,
        || {
            format!(
                "--augment light varies the shifted training grids, and --train-stride {} px at tile {} px makes none; use a stride below the tile size",
                cfg.train_stride_px, cfg.tile_px
            )
        },
    )
}

/// Where the recording goes without a Rerun flag: beside the model, as `.rrd`.
fn default_recording(args: &Args) -> std::path::PathBuf {
    args.output.with_extension("rrd")
}

/// The tree as a graph and the training frames with their maps, in Rerun (by default beside
/// the model); `labelled`: the sessions' frames as a person labelled them (the others of
/// `sessions` were labelled by the located object).
fn log_to_rerun(
    args: &Args,
    model: &Model,
    sessions: &[LoadedSession],
    labelled: &[LoadedSession],
) -> anyhow::Result<()> {
    let hashes: Vec<&str> = sessions.iter().map(|s| s.sha256.as_str()).collect();
    let id = objloc_core::out::view::recording_id(
        "train",
        &[&hashes.join(","), &serde_json::to_string(model)?],
    );
    let stream = crate::viz::open_stream(
        &args.rerun,
        &default_recording(args),
        &id,
        Some(crate::viz::train_blueprint()),
    )
    .context("train: opening the Rerun recording")?;
    if stream.is_on() {
        crate::viz::train::log_tree(&stream.rec, model)?;
        crate::viz::train::log_training_frames(&stream.rec, model, sessions, labelled)?;
    }
    if let Some(p) = stream.finish()? {
        super::say_recording(&p);
    }
    Ok(())
}

/// Sets what `--features`, `--augment`, `--tile`, `--train-stride` and `--trees` left open to the
/// sessions' defaults ([`TileHeadDefaults`]); the line that says so, None when all were given.
fn fit_to_sessions(
    args: &Args,
    cfg: &mut TrainConfig,
    sessions: &[LoadedSession],
) -> Option<String> {
    let choice = TileHeadChoice {
        features: args.features,
        augment: args.augment,
        tile_px: args.tile_px,
        train_stride_px: args.train_stride_px,
        trees: args.trees,
    };
    if choice.features.is_some()
        && choice.augment.is_some()
        && choice.tile_px.is_some()
        && choice.train_stride_px.is_some()
        && choice.trees.is_some()
    {
        return None;
    }
    let d = TileHeadDefaults::for_sessions(sessions, choice);
    (cfg.features, cfg.augment) = (d.features, d.augment);
    (cfg.tile_px, cfg.train_stride_px) = (d.tile_px, d.train_stride_px);
    cfg.forest = forest_params(args, d.trees);
    let mut chosen = Vec::new();
    if choice.features.is_none() {
        chosen.push(format!("features {}", d.features));
    }
    if choice.augment.is_none() {
        chosen.push(format!("augment {}", d.augment.name()));
    }
    if choice.tile_px.is_none() {
        chosen.push(format!("tile {} px", d.tile_px));
    }
    if choice.train_stride_px.is_none() {
        chosen.push(format!("train stride {} px", d.train_stride_px));
    }
    if choice.trees.is_none() {
        chosen.push(match d.trees {
            1 => "1 tree".to_owned(),
            n => format!("{n} trees"),
        });
    }
    let mut why = if d.capture {
        format!(
            "a training session has no /cmd_vel: a posed capture, whose exposure and white \
             balance change between frames, its frames {} px on the shorter side",
            d.short_side_px
        )
    } else {
        "every training session has /cmd_vel: a ground robot's".to_owned()
    };
    if d.capture && choice.augment.is_none() && d.augment == Augment::None {
        why.push_str(
            "; no light variants at a stride of the tile's size, which cuts no shifted grids",
        );
    }
    Some(format!(
        "{} ({why}; --features, --augment, --tile, --train-stride and --trees set them)",
        chosen.join(", ")
    ))
}

/// Builds the examples and fits the tile head (and the region head, when configured).
fn fit(
    sessions: &[LoadedSession],
    cfg: &TrainConfig,
    named: &dyn Fn() -> String,
) -> anyhow::Result<(Model, ExampleSet, std::time::Duration, std::time::Duration)> {
    let t1 = Instant::now();
    // A session set can fail as a whole (no positive tile in any of them): name the files.
    let set = examples(sessions, cfg)
        .with_context(|| format!("train: building examples from {}", named()))?;
    let mut t_features = t1.elapsed();
    let t2 = Instant::now();
    let mut model = fit_model(sessions, &set, cfg).context("train: fitting the tile head")?;
    let mut t_fit = t2.elapsed();
    if let Some(region_cfg) = cfg.region_config() {
        let t3 = Instant::now();
        let region_set = examples(sessions, &region_cfg).with_context(|| {
            format!(
                "train: building the region head's examples from {}",
                named()
            )
        })?;
        t_features += t3.elapsed();
        let t4 = Instant::now();
        let region = fit_model(sessions, &region_set, &region_cfg)
            .context("train: fitting the region head")?;
        t_fit += t4.elapsed();
        model.region = Some(Box::new(region));
    }
    Ok((model, set, t_features, t_fit))
}

/// The second round's configuration: the first's, with the region head's training grids
/// shifted by half a tile instead of its 2 px. The region head answers `predict`, not the
/// fuser, and on 19 frames its 2 px grids (64 a frame at a 16 px tile) were most of the round's
/// time and memory: 30.4 s and 1.29 GB for three labelled 1441 x 1920 frames, 13.7 s and 374 MB
/// so, with its tile AUC 0.991 either way (docs/tree.md, "More views").
fn round_config(cfg: &TrainConfig) -> TrainConfig {
    TrainConfig {
        region: cfg.region.map(|r| RegionConfig {
            train_stride_px: r.train_stride_px.max(cfg.tile_px / 2),
            ..r
        }),
        ..cfg.clone()
    }
}

/// `train`'s second round (see `train_views`): the model fitted again with the frames the
/// located object labels, when it holds; `lines` gets what stdout says.
fn second_round(
    model: &Model,
    sessions: &[LoadedSession],
    cfg: &TrainConfig,
    topics: &objloc_core::io::session::Topics,
    object: Option<&str>,
    lines: &mut Vec<String>,
) -> anyhow::Result<Option<(Model, ExampleSet, Vec<LoadedSession>)>> {
    let (again, rounds, said) = super::train_views::more_views(model, sessions, topics, object)
        .context("train: reading the sessions again")?;
    lines.extend(said);
    if !again
        .iter()
        .zip(sessions)
        .any(|(a, s)| a.frames.len() > s.frames.len())
    {
        return Ok(None);
    }
    let named = || {
        again
            .iter()
            .map(|s| s.path.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (m, x, _, _) = fit(&again, &round_config(cfg), &named)?;
    Ok(
        match super::train_views::second_round_holds(&m, sessions, &rounds, topics)
            .context("train: replaying the sessions with the second round's model")?
        {
            Ok(closer) => {
                lines.push(format!(
                    "the second round's model finds one object, its centre inside every labelled rectangle {closer}: it is written"
                ));
                Some((m, x, again))
            }
            Err(why) => {
                lines.push(format!(
                    "the second round's model is not kept ({why}): the first round's is written"
                ));
                None
            }
        },
    )
}

/// Whether every pixel of `image` has red = green = blue (a monochrome camera, or grey
/// files).
fn is_grey(image: &objloc_core::types::image::Rgb8) -> bool {
    image
        .data
        .chunks_exact(3)
        .all(|p| p[0] == p[1] && p[1] == p[2])
}

/// The training sessions, their labelled frames decoded; an error naming the labels' objects
/// when `--object` names none of them.
fn load_sessions(
    args: &Args,
    topics: &objloc_core::io::session::Topics,
) -> anyhow::Result<Vec<LoadedSession>> {
    let sessions = args
        .sessions
        .iter()
        .map(|p| load_session(p, topics.clone(), args.object.as_deref(), true))
        .collect::<Result<Vec<_>, _>>()
        .context("train: reading sessions")?;
    super::print_warnings(sessions.iter().flat_map(|s| &s.warnings));
    if args.object.is_none() {
        let names: std::collections::BTreeSet<&String> =
            sessions.iter().flat_map(|s| &s.label_objects).collect();
        if names.len() > 1 {
            let listed: Vec<&str> = names.iter().map(|n| n.as_str()).collect();
            eprintln!(
                "warning: the labels name {} objects ({}), trained as one: the model fires on all of them and its objects carry no name (--object NAME trains one)",
                names.len(),
                listed.join(", ")
            );
        }
    }
    let mut frames = sessions.iter().flat_map(|s| &s.frames).peekable();
    if frames.peek().is_some() && frames.all(|f| is_grey(&f.image)) {
        eprintln!(
            "note: every training frame is grey (red = green = blue in every pixel): the tile head can tell the object from the rest by brightness and its spread alone, which few scenes allow (the fruit capture made grey located the apple 22 % of its size off, against 3 % in colour)"
        );
    }
    if let Some(o) = &args.object
        && !sessions.iter().any(|s| s.label_objects.contains(o))
    {
        let names: std::collections::BTreeSet<String> = sessions
            .iter()
            .flat_map(|s| s.label_objects.iter().cloned())
            .collect();
        anyhow::bail!(
            "train: no label in {} names object {o:?}; the labels name: {} (labels imported without an object column are named by `record import --object NAME`, else \"object\")",
            args.sessions
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            super::names_or_none(&names)
        );
    }
    Ok(sessions)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let topics = args.topics.topics()?;
    let mut cfg = config(&args)?;
    let recording = args.rerun.file(&default_recording(&args));
    let mut outputs = vec![("-o", args.output.as_path())];
    outputs.extend(recording.as_ref().map(|(what, p)| (*what, p.as_path())));
    let inputs: Vec<(&str, &std::path::Path)> = args
        .sessions
        .iter()
        .map(|p| ("session", p.as_path()))
        .collect();
    super::prepare_outputs(&inputs, &outputs)?;
    let stage = super::progress::stage_spinner(args.quiet);
    stage.set_message("train: reading sessions");
    let t0 = Instant::now();
    let sessions = load_sessions(&args, &topics)?;
    let chosen = fit_to_sessions(&args, &mut cfg, &sessions);
    check_tiles(&cfg)?;
    check_forest_options(&args, &cfg)?;
    let t_load = t0.elapsed();
    stage.set_message("train: tile features");
    let named = || {
        args.sessions
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (mut model, mut set, t_features, t_fit) = fit(&sessions, &cfg, &named)?;
    let mut more = Vec::new();
    let mut t_more = None;
    // What Rerun shows: the frames the model was fitted on (the second round's, when kept).
    let mut shown = None;
    let captures = sessions.iter().filter(|s| s.commands == 0).count();
    if args.more_views() && captures > 0 && captures < sessions.len() {
        more.push(
            "no second round: some training sessions are a ground robot's (/cmd_vel), some posed captures".into(),
        );
    }
    if args.more_views() && captures == sessions.len() {
        stage.set_message("train: a second round on the object's other views");
        let t3 = Instant::now();
        let object = args.object.as_deref();
        if let Some((m, x, s)) = second_round(&model, &sessions, &cfg, &topics, object, &mut more)?
        {
            (model, set, shown) = (m, x, Some(s));
        }
        t_more = Some(t3.elapsed());
    }
    stage.finish_and_clear();
    model
        .save(&args.output)
        .context("train: writing the model")?;
    if let Some(dir) = &args.export_features {
        export_features(&set, dir).context("train: exporting features")?;
    }
    if let Some(line) = &chosen {
        say!("{line}");
    }
    for line in &more {
        say!("{line}");
    }
    say_part!("{}", model.summary_table());
    log_to_rerun(
        &args,
        &model,
        shown.as_deref().unwrap_or(&sessions),
        &sessions,
    )?;
    say!(
        "time: load+decode {:.3} s, features {:.3} s, fit time {:.4} s{}{}",
        t_load.as_secs_f64(),
        t_features.as_secs_f64(),
        t_fit.as_secs_f64(),
        if model.region.is_some() {
            " (both heads)"
        } else {
            ""
        },
        t_more.map_or(String::new(), |t| format!(
            ", second round (replays and refit) {:.3} s",
            t.as_secs_f64()
        ))
    );
    say!("model written to {}", args.output.display());
    Ok(())
}
