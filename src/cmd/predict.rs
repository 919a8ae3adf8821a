//! `objloc predict SESSION --model MODEL.json --out DIR [--heatmaps]`: per-frame tile
//! probability maps as probs.npy (the region head's, when the model has one) and tile_probs.npy
//! (the tile head's: what `fuse` integrates), labels.npy / stamps.npy, optional heat maps, and
//! tile ROC AUC against the session's labels when it has any.

use super::say;

use std::path::PathBuf;

use anyhow::Context;
use objloc_core::learn::dataset::{LoadedSession, load_session};
use objloc_core::learn::model::Model;

use super::TopicArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The session whose frames to classify.
    session: PathBuf,
    /// A model written by `objloc train`.
    #[arg(long)]
    model: PathBuf,
    /// Output directory (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Also write a PNG heat map per frame (of probs.npy's maps).
    #[arg(long)]
    heatmaps: bool,
    /// Score only against labels naming this object (default: the model's object, if any).
    #[arg(long)]
    object: Option<String>,
    /// No progress bar (there is none anyway when stderr is not a terminal).
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    topics: TopicArgs,
    #[command(flatten)]
    pub(crate) rerun: crate::viz::VizArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let topics = args.topics.topics()?;
    let model = Model::load(&args.model).context("predict: loading the model")?;
    let asked = args.object.clone();
    let object = args.object.or_else(|| model.metadata.object.clone());
    let session = load_session(&args.session, topics, object.as_deref(), false)
        .context("predict: reading the session")?;
    super::print_warnings(&session.warnings);
    // An object asked for by name that no label names is a mistake, as in train and eval
    // (one the model names is not: its maps are still wanted, without a score).
    if let Some(o) = asked.filter(|o| !session.label_objects.contains(o)) {
        anyhow::bail!(
            "predict: no label in {} names object {o:?}; the labels name: {}",
            args.session.display(),
            super::names_or_none(&session.label_objects)
        );
    }
    let heads = if model.region.is_some() { 2 } else { 1 };
    let unit = if heads == 2 {
        "frames x 2 heads"
    } else {
        "frames"
    };
    let bar = super::progress::counted_bar("predict", unit, args.quiet);
    super::progress::set_counts(&bar, 0, session.frames.len() * heads);
    let pred = model
        .predict_session(&session, &|| bar.inc(1))
        .context("predict: classifying frames")?;
    bar.finish_and_clear();
    pred.write(&args.out, &session, args.heatmaps)
        .context("predict: writing outputs")?;
    log_to_rerun(&args.rerun, &args.out, &model, &session)?;
    let (rows, cols) = pred.maps.first().map_or((0, 0), |m| (m.rows, m.cols));
    say!(
        "{} frames of {rows} x {cols} tiles written to {}",
        pred.maps.len(),
        args.out.display()
    );
    let (Some(m), Some(tile)) = (&pred.labelled, &pred.tile_labelled) else {
        match object
            .as_deref()
            .filter(|o| !session.label_objects.contains(*o))
        {
            Some(o) => say!(
                "no label names object {o:?} (the session's labels name: {}): no tile AUC",
                super::names_or_none(&session.label_objects)
            ),
            None => say!("no labelled frames: no tile AUC"),
        }
        return Ok(());
    };
    let auc = |m: &objloc_core::learn::tree::Metrics| {
        m.roc_auc
            .map_or_else(|| "n/a (one class only)".to_owned(), |a| format!("{a:.4}"))
    };
    // The tile head's line first, so that the last line is always probs.npy's score.
    if model.region.is_some() {
        say!(
            "tile head (tile_probs.npy, the fuser's evidence): tile ROC AUC {}, log-loss {:.5}, accuracy {:.5}",
            auc(tile),
            tile.log_loss,
            tile.accuracy
        );
    }
    say!(
        "{} (probs.npy): labelled frames {}: {} tiles, {} positive; tile ROC AUC {}, log-loss {:.5}, accuracy {:.5}",
        if model.region.is_some() {
            "region head"
        } else {
            "tile head"
        },
        pred.labelled_frames,
        m.n,
        m.positives,
        auc(m),
        m.log_loss,
        m.accuracy
    );
    Ok(())
}

/// The frames with their labels and maps, in Rerun (by default `predict.rrd` beside the
/// outputs in `out`).
fn log_to_rerun(
    rerun: &crate::viz::VizArgs,
    out: &std::path::Path,
    model: &Model,
    session: &LoadedSession,
) -> anyhow::Result<()> {
    let id = objloc_core::out::view::recording_id(
        "predict",
        &[&session.sha256, &serde_json::to_string(model)?],
    );
    let stream = crate::viz::open_stream(
        rerun,
        &out.join("predict.rrd"),
        &id,
        Some(crate::viz::train_blueprint()),
    )?;
    if stream.is_on() {
        crate::viz::train::log_training_frames(
            &stream.rec,
            model,
            std::slice::from_ref(session),
            std::slice::from_ref(session),
        )?;
    }
    if let Some(p) = stream.finish()? {
        super::say_recording(&p);
    }
    Ok(())
}
