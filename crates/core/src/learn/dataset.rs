//! Labelled examples from sessions, as the paper builds them: each frame with a label on
//! /labels (same header stamp) is cut into tiles; a tile is positive when it lies fully
//! inside a labelled rectangle, negative otherwise (an empty label = a background frame, all
//! negative). Frames without a label are not used.
//!
//! Invariants: the tiles of the grid aligned at (0, 0) - the only grid prediction uses - are
//! divided into equal training, test and pruning thirds by a seeded, stratified shuffle
//! (positives and negatives dealt round-robin, so each third gets a third of the rare
//! positives and the thirds differ in size by at most one); tiles of grids shifted by
//! multiples of `train_stride_px` are added to the training third only, so test and pruning
//! measure exactly what prediction sees. Frames are taken in session order, sessions in the
//! order given; the result depends on nothing else.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::io::msgs::RegionOfInterest;
use crate::io::session::{
    At, IndexScope, MessageMeta, SessionError, SessionMsg, SessionReader, Topics,
};
use crate::learn::features::{
    FeatureSpec, bin_planes, feature_count, histograms_of_bins, with_context,
};
use crate::learn::tree::{Examples, Third};
use crate::types::image::Rgb8;

/// Allowed tile sides: a tile must hold at least 4 pixels, and counts fit u16 up to 255.
pub const TILE_PX_RANGE: std::ops::RangeInclusive<u32> = 2..=128;

/// Why examples cannot be built from sessions.
#[derive(Debug, Error)]
pub enum DatasetError {
    /// Boxed: session errors are large and this one travels up every `Result`.
    #[error(transparent)]
    Session(Box<SessionError>),
    /// A frame's image does not decode.
    #[error("{at}: frame does not decode: {source}")]
    Frame {
        /// Where the frame is: the session's path, the topic and the log time.
        at: At,
        /// The decoding error.
        #[source]
        source: crate::io::session::FrameError,
    },
    /// No frame of the session has a label (one naming `object`, when given).
    #[error("{}: no frame has a label on {topic}{}", path.display(), object.as_ref().map(|o| format!(" for object {o:?}")).unwrap_or_default())]
    NoLabelledFrames {
        /// The session file.
        path: PathBuf,
        /// The labels topic that was read.
        topic: String,
        /// The object whose labels were asked for (None: any).
        object: Option<String>,
    },
    /// The tile side is outside [`TILE_PX_RANGE`].
    #[error("tile size {tile_px} px is outside {}..={} px", TILE_PX_RANGE.start(), TILE_PX_RANGE.end())]
    TileSize {
        /// The requested tile side, px.
        tile_px: u32,
    },
    /// The training stride is 0 or larger than the tile.
    #[error("train stride {stride_px} px must be 1 to the tile size {tile_px} px")]
    Stride {
        /// The requested shift between the extra training grids, px.
        stride_px: u32,
        /// The tile side, px.
        tile_px: u32,
    },
}

impl From<SessionError> for DatasetError {
    fn from(e: SessionError) -> Self {
        DatasetError::Session(Box::new(e))
    }
}

/// One frame of a session, decoded, with its label rectangles if it has a label.
#[derive(Debug, Clone)]
pub struct SessionFrame {
    /// Header stamp, ns since the Unix epoch; labels with the same stamp are this frame's.
    pub stamp_ns: i64,
    /// MCAP log time of the frame's message, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// The frame decoded to RGB.
    pub image: Rgb8,
    /// None = no label for this frame; Some(empty) = a background frame.
    pub regions: Option<Vec<RegionOfInterest>>,
    /// Where the label is unsure: a tile outside `regions` that touches one of these is left
    /// out of the examples, neither positive nor negative (a rectangle that may be too small,
    /// from a located object rather than a person). Empty for a person's labels.
    pub unsure: Vec<RegionOfInterest>,
}

/// A label a frame without one of its own is given ([`load_session_with`]): its rectangles,
/// and where round them a tile is neither positive nor negative.
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraLabel {
    /// The rectangles: tiles wholly inside are positive.
    pub regions: Vec<RegionOfInterest>,
    /// Tiles outside `regions` touching these are left out.
    pub unsure: Vec<RegionOfInterest>,
}

/// A session read for training or prediction.
#[derive(Debug, Clone)]
pub struct LoadedSession {
    /// The file the session was read from.
    pub path: PathBuf,
    /// Hex SHA-256 of the file's bytes.
    pub sha256: String,
    /// Its decoded frames in session order (with `labelled_only`, only those with a label).
    pub frames: Vec<SessionFrame>,
    /// Every object a label with a rectangle names, whichever `object` was asked for: what
    /// to tell a user whose `--object` names none of them.
    pub label_objects: std::collections::BTreeSet<String>,
    /// Messages on the command topic (/cmd_vel): a ground robot's session has them, a posed
    /// capture (phone, arm, structure from motion) has none.
    pub commands: usize,
    /// What the reader found wrong but could read past (a truncated file, a message with
    /// a bad stamp), one line each naming the file: the command prints them, as fuse does.
    pub warnings: Vec<String>,
}

/// Reads a session's frames and labels. `object`: use only labels naming it (None: all).
/// `labelled_only`: skip decoding frames without a label (training needs only those).
pub fn load_session(
    path: &Path,
    topics: Topics,
    object: Option<&str>,
    labelled_only: bool,
) -> Result<LoadedSession, DatasetError> {
    load_session_with(path, topics, object, labelled_only, &BTreeMap::new())
}

/// [`load_session`], with `extra` rectangles (by header stamp) taken as the labels of the
/// frames that have none of their own: a labeller's rectangle, and a background label, always
/// win. With `object`, a frame whose labels all name other objects counts as having none.
pub fn load_session_with(
    path: &Path,
    topics: Topics,
    object: Option<&str>,
    labelled_only: bool,
    extra: &BTreeMap<i64, ExtraLabel>,
) -> Result<LoadedSession, DatasetError> {
    let sha256 = file_sha256(path)?;
    let reader = SessionReader::open_scoped(path, topics, IndexScope::Roles)?;
    reader.require_frames()?;
    // Frames are kept as their messages' places in the reader and decoded once selected: the encoded
    // frames of a long session are never all in memory at once.
    let mut frames: Vec<(MessageMeta, u64, String, i64)> = Vec::new();
    let mut labels: BTreeMap<i64, Vec<RegionOfInterest>> = BTreeMap::new();
    let mut label_objects = std::collections::BTreeSet::new();
    let mut commands = 0;
    for meta in reader.ordered() {
        let meta = meta?;
        let Some(m) = reader.decode(&meta)? else {
            continue;
        };
        if let SessionMsg::Label(l) = &m.msg
            && !l.regions.is_empty()
        {
            label_objects.insert(l.object.clone());
        }
        match m.msg {
            SessionMsg::Frame(f) => frames.push((meta, m.log_time_ns, m.topic, f.stamp_ns)),
            SessionMsg::CmdVel(_) => commands += 1,
            // Several labels for one frame (several objects, or a background label next to
            // an object label) add up their rectangles.
            SessionMsg::Label(l)
                if object.is_none_or(|o| o == l.object) || l.regions.is_empty() =>
            {
                labels
                    .entry(l.header.stamp_ns)
                    .or_default()
                    .extend(l.regions);
            }
            _ => {}
        }
    }
    let mut unsure: BTreeMap<i64, Vec<RegionOfInterest>> = BTreeMap::new();
    for (&stamp_ns, label) in extra {
        if let std::collections::btree_map::Entry::Vacant(e) = labels.entry(stamp_ns) {
            e.insert(label.regions.clone());
            unsure.insert(stamp_ns, label.unsure.clone());
        }
    }
    let selected: Vec<Selected> = frames
        .into_iter()
        .filter_map(|(meta, t, topic, stamp_ns)| {
            let regions = labels.get(&stamp_ns).cloned();
            (!labelled_only || regions.is_some()).then_some((meta, t, topic, stamp_ns, regions))
        })
        .collect();
    let frames = decode_selected(&reader, selected, &unsure)?;
    let mut warnings = reader.warnings.clone();
    warnings.extend(rectangle_warnings(&reader, &frames));
    Ok(LoadedSession {
        path: path.to_owned(),
        sha256,
        frames,
        label_objects,
        commands,
        warnings,
    })
}

/// A frame selected for loading: its message, log time, topic, stamp and rectangles.
type Selected = (MessageMeta, u64, String, i64, Option<Vec<RegionOfInterest>>);

/// The selected frames decoded, in session order (decoding dominates loading: in parallel,
/// rayon's collect keeping the order), each with its unsure band from `unsure`.
fn decode_selected(
    reader: &SessionReader,
    selected: Vec<Selected>,
    unsure: &BTreeMap<i64, Vec<RegionOfInterest>>,
) -> Result<Vec<SessionFrame>, DatasetError> {
    selected
        .into_par_iter()
        .map(|(meta, log_time_ns, topic, stamp_ns, regions)| {
            let frame = match reader.decode(&meta)?.map(|m| m.msg) {
                Some(SessionMsg::Frame(f)) => f,
                _ => {
                    return Err(SessionError::Invalid {
                        at: reader.at(Some(&topic), log_time_ns),
                        what: "not a frame any more (the file changed while it was read?)".into(),
                    }
                    .into());
                }
            };
            let image = frame.decode_rgb8().map_err(|source| DatasetError::Frame {
                at: reader.at(Some(&topic), log_time_ns),
                source,
            })?;
            Ok(SessionFrame {
                stamp_ns,
                log_time_ns,
                image,
                regions,
                unsure: unsure.get(&stamp_ns).cloned().unwrap_or_default(),
            })
        })
        .collect::<Result<Vec<_>, DatasetError>>()
}

/// One warning per label rectangle that is empty or reaches past its frame, naming where.
fn rectangle_warnings(reader: &SessionReader, frames: &[SessionFrame]) -> Vec<String> {
    let mut warnings = Vec::new();
    let labels_topic = reader.topics().labels.clone();
    for f in frames {
        for r in f.regions.iter().flatten() {
            if let Some(why) = rectangle_problem(r, f.image.width, f.image.height) {
                let at = reader.at(Some(&labels_topic), f.log_time_ns);
                warnings.push(format!(
                    "{at}: rectangle at ({}, {}) of {} x {} px {why}",
                    r.x_offset, r.y_offset, r.width, r.height
                ));
            }
        }
    }
    warnings
}

/// What is wrong with a label rectangle on a `width` x `height` frame, if anything: empty,
/// or reaching past the image (its tiles are clipped to it, which silently turned a garbage
/// rectangle 2^32 px wide into a quarter of the image's tiles as positives).
fn rectangle_problem(r: &RegionOfInterest, width: u32, height: u32) -> Option<String> {
    let (x_end, y_end) = (
        u64::from(r.x_offset) + u64::from(r.width),
        u64::from(r.y_offset) + u64::from(r.height),
    );
    if r.width == 0 || r.height == 0 {
        Some("is empty: it labels no tile".into())
    } else if x_end > u64::from(width) || y_end > u64::from(height) {
        Some(format!(
            "reaches past the {width} x {height} image: only its part inside labels tiles"
        ))
    } else {
        None
    }
}

/// Hex SHA-256 of the file at `path`, read in blocks (the file is never all in memory).
fn file_sha256(path: &Path) -> Result<String, SessionError> {
    std::fs::File::open(path)
        .and_then(crate::types::digest::sha256_hex_of_reader)
        .map_err(|source| SessionError::Io {
            path: path.to_owned(),
            source,
        })
}

/// Whether the tile at pixel (x, y) with side `tile_px` lies fully inside one rectangle.
pub fn tile_inside(regions: &[RegionOfInterest], x: u32, y: u32, tile_px: u32) -> bool {
    regions.iter().any(|r| {
        x >= r.x_offset
            && y >= r.y_offset
            && x as u64 + tile_px as u64 <= r.x_offset as u64 + r.width as u64
            && y as u64 + tile_px as u64 <= r.y_offset as u64 + r.height as u64
    })
}

/// Whether the tile at pixel (x, y) with side `tile_px` overlaps one rectangle.
pub fn tile_touches(regions: &[RegionOfInterest], x: u32, y: u32, tile_px: u32) -> bool {
    let (x, y, t) = (u64::from(x), u64::from(y), u64::from(tile_px));
    regions.iter().any(|r| {
        let (rx, ry) = (u64::from(r.x_offset), u64::from(r.y_offset));
        x < rx + u64::from(r.width) && rx < x + t && y < ry + u64::from(r.height) && ry < y + t
    })
}

/// Tile labels of the aligned grid of a `rows` x `cols` probability map, row-major.
pub fn tile_labels(
    regions: &[RegionOfInterest],
    rows: usize,
    cols: usize,
    tile_px: u32,
) -> Vec<bool> {
    let mut out = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            out.push(tile_inside(
                regions,
                c as u32 * tile_px,
                r as u32 * tile_px,
                tile_px,
            ));
        }
    }
    out
}

/// How labelled frames are cut into examples (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExampleParams {
    /// The channels of the tile histograms.
    pub features: FeatureSpec,
    /// Side of a square tile, px; must lie in [`TILE_PX_RANGE`].
    pub tile_px: u32,
    /// Shift between the extra training grids; = tile_px for the aligned grid only.
    pub train_stride_px: u32,
    /// Seed of the stratified shuffle of the aligned-grid tiles into thirds.
    pub seed: u64,
    /// Radius in tiles of the neighbourhood histogram appended to each tile's
    /// ([`crate::learn::features::with_context`]); 0 = the tile alone.
    pub context_tiles: u32,
    /// Photometric variants of the frames the shifted grids are cut from.
    pub augment: Augment,
}

/// Augmentation of the training third: how the frames of the shifted grids are altered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
#[value(rename_all = "lowercase")]
pub enum Augment {
    /// Every grid is cut from the frame as recorded.
    #[default]
    None,
    /// Each shifted grid is cut from the frame under one of [`LIGHT_VARIANTS`] (darker,
    /// brighter, warmer, cooler or as recorded, cycling over frames and grids), so the tree
    /// sees the object under more exposures and white balances than three frames hold.
    Light,
}

impl Augment {
    /// The name `train --augment` and the model file use.
    pub fn name(self) -> &'static str {
        match self {
            Augment::None => "none",
            Augment::Light => "light",
        }
    }
}

/// Per-channel gains (r, g, b) in 1/256 of the light variants: as recorded, 0.75 (darker),
/// 1.3 (brighter, clipped at 255), red x 1.125 and blue x 0.875 (warmer), and the reverse
/// (cooler).
pub const LIGHT_VARIANTS: [[u32; 3]; 5] = [
    [256, 256, 256],
    [192, 192, 192],
    [333, 333, 333],
    [288, 256, 224],
    [224, 256, 288],
];

/// `img` with each channel multiplied by its gain in 1/256, rounded down and clipped at 255.
pub fn apply_gains(img: &Rgb8, gains: [u32; 3]) -> Rgb8 {
    let data = img
        .data
        .chunks_exact(3)
        .flat_map(|p| {
            let g = |c: usize| ((p[c] as u32 * gains[c]) >> 8).min(255) as u8;
            [g(0), g(1), g(2)]
        })
        .collect();
    Rgb8 {
        data,
        ..img.clone()
    }
}

/// The light variant grid `grid` (0 = aligned) of labelled frame `frame` is cut from: the
/// aligned grid (test and pruning thirds) always as recorded.
fn light_variant(augment: Augment, frame: usize, grid: usize) -> usize {
    match augment {
        Augment::None => 0,
        Augment::Light if grid == 0 => 0,
        Augment::Light => (frame + grid) % LIGHT_VARIANTS.len(),
    }
}

impl ExampleParams {
    /// Checks that `tile_px` lies in [`TILE_PX_RANGE`] and `train_stride_px` in 1..=`tile_px`.
    pub fn validate(&self) -> Result<(), DatasetError> {
        if !TILE_PX_RANGE.contains(&self.tile_px) {
            return Err(DatasetError::TileSize {
                tile_px: self.tile_px,
            });
        }
        if self.train_stride_px == 0 || self.train_stride_px > self.tile_px {
            return Err(DatasetError::Stride {
                stride_px: self.train_stride_px,
                tile_px: self.tile_px,
            });
        }
        Ok(())
    }
}

pub use crate::types::rng::SplitMix64;

/// Thirds for `labels`: stratified, seeded; sizes differ by at most one.
pub fn assign_thirds(labels: &[bool], seed: u64) -> Vec<Third> {
    let mut rng = SplitMix64(seed);
    let mut pos: Vec<usize> = (0..labels.len()).filter(|&i| labels[i]).collect();
    let mut neg: Vec<usize> = (0..labels.len()).filter(|&i| !labels[i]).collect();
    rng.shuffle(&mut pos);
    rng.shuffle(&mut neg);
    let mut out = vec![Third::Train; labels.len()];
    const ORDER: [Third; 3] = [Third::Train, Third::Test, Third::Prune];
    for (k, &i) in pos.iter().chain(&neg).enumerate() {
        out[i] = ORDER[k % 3];
    }
    out
}

/// Examples with where they came from.
#[derive(Debug, Clone)]
pub struct ExampleSet {
    /// The aligned-grid tiles (indices `0..aligned`) then the shifted-grid tiles.
    pub examples: Examples,
    /// Number of aligned-grid tiles; only they are in the test and pruning thirds.
    pub aligned: usize,
    /// Frames with a label (background frames included) the examples were cut from.
    pub labelled_frames: usize,
}

/// The examples of all labelled frames of `sessions`.
pub fn build_examples(
    sessions: &[LoadedSession],
    params: &ExampleParams,
) -> Result<ExampleSet, DatasetError> {
    params.validate()?;
    let feature = params.features;
    let t = params.tile_px;
    let frames: Vec<(&Rgb8, &[RegionOfInterest], &[RegionOfInterest])> = sessions
        .iter()
        .flat_map(|s| &s.frames)
        .filter_map(|f| {
            f.regions
                .as_deref()
                .map(|r| (&f.image, r, f.unsure.as_slice()))
        })
        .collect();
    let offsets: Vec<(u32, u32)> = {
        let steps: Vec<u32> = (0..t).step_by(params.train_stride_px as usize).collect();
        steps
            .iter()
            .flat_map(|&dy| steps.iter().map(move |&dx| (dx, dy)))
            .collect()
    };
    // Per frame, per grid offset: (sparse histograms, labels). Parallel over frames, ordered
    // collect; sparse here, in parallel, because the dense histograms of every shifted grid
    // would take hundreds of MB and their scan was a tenth of the training time.
    let per_frame: Vec<Vec<(SparseTiles, Vec<Option<bool>>)>> = frames
        .par_iter()
        .enumerate()
        .map(|(fi, (img, regions, unsure))| frame_grids(img, regions, unsure, fi, &offsets, params))
        .collect();
    let denom = (t * t) as u16;
    let bins = feature_count(feature, params.context_tiles);
    let mut ex = Examples::new(bins, denom);
    // Aligned grid first (offset index 0 is (0, 0)); its thirds are assigned together.
    let aligned_labels: Vec<bool> = per_frame
        .iter()
        .flat_map(|grids| grids[0].1.iter().flatten().copied())
        .collect();
    let thirds = assign_thirds(&aligned_labels, params.seed);
    let mut k = 0;
    for grids in &per_frame {
        let (tiles, labels) = &grids[0];
        for (i, y) in labels.iter().enumerate() {
            if let Some(y) = *y {
                ex.push_sparse(tiles.tile(i), y, thirds[k]);
                k += 1;
            }
        }
    }
    let aligned = ex.len();
    for grids in &per_frame {
        for (tiles, labels) in &grids[1..] {
            for (i, y) in labels.iter().enumerate() {
                if let Some(y) = *y {
                    ex.push_sparse(tiles.tile(i), y, Third::Train);
                }
            }
        }
    }
    Ok(ExampleSet {
        examples: ex,
        aligned,
        labelled_frames: frames.len(),
    })
}

/// One labelled frame's examples on every shifted grid (`offsets`, in order): the sparse
/// histograms of its tiles and their labels ([`grid_labels`]); `fi` picks the light variant
/// of each grid.
fn frame_grids(
    img: &Rgb8,
    regions: &[RegionOfInterest],
    unsure: &[RegionOfInterest],
    fi: usize,
    offsets: &[(u32, u32)],
    params: &ExampleParams,
) -> Vec<(SparseTiles, Vec<Option<bool>>)> {
    let (feature, t) = (params.features, params.tile_px);
    // The bins of each light variant this frame's grids use, computed once.
    let mut planes: Vec<Option<Vec<Vec<u16>>>> = vec![None; LIGHT_VARIANTS.len()];
    for k in 0..offsets.len() {
        let v = light_variant(params.augment, fi, k);
        if planes[v].is_none() {
            planes[v] = Some(if v == 0 {
                bin_planes(img, feature)
            } else {
                bin_planes(&apply_gains(img, LIGHT_VARIANTS[v]), feature)
            });
        }
    }
    offsets
        .iter()
        .enumerate()
        .map(|(k, &(dx, dy))| {
            let planes = planes[light_variant(params.augment, fi, k)]
                .as_deref()
                .unwrap_or_default();
            let h = with_context(
                histograms_of_bins(planes, img.width, img.height, feature.bins(), t, dx, dy),
                params.context_tiles,
            );
            let labels = grid_labels(regions, unsure, (h.rows, h.cols), (dx, dy), t);
            (SparseTiles::from_dense(&h.counts, h.bins), labels)
        })
        .collect()
}

/// The labels of a grid of `rows` x `cols` tiles of side `t` starting at pixel (dx, dy), row
/// by row: positive wholly inside `regions`, left out (None) where otherwise touching
/// `unsure`, negative elsewhere.
fn grid_labels(
    regions: &[RegionOfInterest],
    unsure: &[RegionOfInterest],
    (rows, cols): (usize, usize),
    (dx, dy): (u32, u32),
    t: u32,
) -> Vec<Option<bool>> {
    let mut labels = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            let (x, y) = (dx + c as u32 * t, dy + r as u32 * t);
            let inside = tile_inside(regions, x, y, t);
            labels.push((inside || !tile_touches(unsure, x, y, t)).then_some(inside));
        }
    }
    labels
}

/// The non-zero (feature, count) entries of a grid's tiles, in feature order.
struct SparseTiles {
    entries: Vec<(u16, u16)>,
    /// Tile i's entries are `entries[ends[i - 1]..ends[i]]` (from 0 for tile 0).
    ends: Vec<usize>,
}

impl SparseTiles {
    fn from_dense(counts: &[u16], bins: usize) -> Self {
        let mut entries = Vec::new();
        let mut ends = Vec::with_capacity(counts.len() / bins.max(1));
        for tile in counts.chunks_exact(bins) {
            crate::learn::tree::push_nonzero(tile, &mut entries);
            ends.push(entries.len());
        }
        Self { entries, ends }
    }

    fn tile(&self, i: usize) -> &[(u16, u16)] {
        let start = if i == 0 { 0 } else { self.ends[i - 1] };
        &self.entries[start..self.ends[i]]
    }
}

/// Writes `X.npy` (float32, n x bins, pixel fractions), `y.npy` (uint8 0/1) and `split.npy`
/// (uint8: 0 train, 1 test, 2 prune) into `dir` (created if missing).
pub fn export_features(set: &ExampleSet, dir: &Path) -> Result<(), crate::io::npy::NpyError> {
    let ex = &set.examples;
    std::fs::create_dir_all(dir).map_err(|source| crate::io::npy::NpyError::Io {
        path: dir.display().to_string(),
        source,
    })?;
    let mut x = Vec::with_capacity(ex.len() * ex.n_features);
    for i in 0..ex.len() {
        x.extend(ex.dense_values(i));
    }
    crate::io::npy::write(&dir.join("X.npy"), &[ex.len(), ex.n_features], &x)?;
    let y: Vec<u8> = ex.labels.iter().map(|&l| l as u8).collect();
    crate::io::npy::write(&dir.join("y.npy"), &[ex.len()], &y)?;
    let split: Vec<u8> = ex.thirds.iter().map(|&t| t as u8).collect();
    crate::io::npy::write(&dir.join("split.npy"), &[ex.len()], &split)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The names `Augment::name` prints are those `train --augment` parses and the model
    /// file holds.
    #[test]
    fn augment_names_match_the_command_line_and_the_model_file() {
        for v in [Augment::None, Augment::Light] {
            assert_eq!(
                <Augment as clap::ValueEnum>::from_str(v.name(), false),
                Ok(v)
            );
            assert_eq!(
                serde_json::to_string(&v).unwrap(),
                format!("\"{}\"", v.name())
            );
        }
    }

    fn roi(x: u32, y: u32, w: u32, h: u32) -> RegionOfInterest {
        RegionOfInterest {
            x_offset: x,
            y_offset: y,
            height: h,
            width: w,
            do_rectify: false,
        }
    }

    /// Extra rectangles label only frames without a label of their own (the shipped chair
    /// training session: 3 frames with a chair, 18 background frames).
    #[test]
    fn extra_rectangles_never_replace_a_labellers() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/chair-train.mcap");
        let base = load_session(&path, Topics::default(), Some("chair"), true).unwrap();
        assert_eq!(base.frames.len(), 21);
        let extra: BTreeMap<i64, ExtraLabel> = base
            .frames
            .iter()
            .map(|f| {
                let label = ExtraLabel {
                    regions: vec![roi(1, 2, 3, 4)],
                    unsure: vec![roi(0, 0, 9, 9)],
                };
                (f.stamp_ns, label)
            })
            .collect();
        let with =
            load_session_with(&path, Topics::default(), Some("chair"), true, &extra).unwrap();
        let regions = |s: &LoadedSession| {
            s.frames
                .iter()
                .map(|f| f.regions.clone())
                .collect::<Vec<_>>()
        };
        assert_eq!(regions(&with), regions(&base));
        assert!(with.frames.iter().all(|f| f.unsure.is_empty()));
        // Labelled for another object: the chair frames have no label of the mug's, so the
        // extra rectangle labels them; the background frames stay background.
        let mug = load_session_with(&path, Topics::default(), Some("mug"), true, &extra).unwrap();
        assert_eq!(mug.frames.len(), 21);
        let added = mug
            .frames
            .iter()
            .filter(|f| f.regions.as_deref() == Some(&[roi(1, 2, 3, 4)][..]))
            .count();
        let background = mug
            .frames
            .iter()
            .filter(|f| f.regions.as_deref() == Some(&[][..]))
            .count();
        assert_eq!((added, background), (3, 18));
        // Only the frames the extra label labels carry its unsure band.
        let banded = mug.frames.iter().filter(|f| !f.unsure.is_empty()).count();
        assert_eq!(banded, 3);
    }

    /// A tile outside the rectangles that touches an unsure band is left out; one wholly
    /// inside stays positive, one clear of the band stays negative.
    #[test]
    fn tiles_in_an_unsure_band_are_left_out() {
        let img = Rgb8 {
            width: 32,
            height: 16,
            data: vec![128; 32 * 16 * 3],
        };
        let frame = |unsure: Vec<RegionOfInterest>| SessionFrame {
            stamp_ns: 0,
            log_time_ns: 0,
            image: img.clone(),
            regions: Some(vec![roi(0, 0, 8, 8)]),
            unsure,
        };
        let session = |unsure| LoadedSession {
            path: "s.mcap".into(),
            sha256: String::new(),
            frames: vec![frame(unsure)],
            label_objects: Default::default(),
            commands: 0,
            warnings: Vec::new(),
        };
        let params = ExampleParams {
            features: crate::learn::features::FeatureSpec::RGB332,
            tile_px: 8,
            train_stride_px: 8,
            seed: 0,
            context_tiles: 0,
            augment: Augment::None,
        };
        // 4 x 2 tiles of 8 px: tile (0, 0) positive, 7 negative.
        let all = build_examples(&[session(Vec::new())], &params).unwrap();
        assert_eq!(
            (
                all.examples.len(),
                all.examples.labels.iter().filter(|&&y| y).count()
            ),
            (8, 1)
        );
        // A band over x 0..12, y 0..16 touches tiles (0, 0), (1, 0), (0, 1), (1, 1): the
        // positive stays, the three negatives go.
        let banded = build_examples(&[session(vec![roi(0, 0, 12, 16)])], &params).unwrap();
        assert_eq!(
            (
                banded.examples.len(),
                banded.examples.labels.iter().filter(|&&y| y).count()
            ),
            (5, 1)
        );
    }

    #[test]
    fn tile_must_be_fully_inside() {
        let r = [roi(4, 4, 12, 8)];
        assert!(tile_inside(&r, 4, 4, 8));
        assert!(tile_inside(&r, 8, 4, 8)); // ends at x 16 = 4 + 12
        assert!(!tile_inside(&r, 9, 4, 8));
        assert!(!tile_inside(&r, 0, 0, 8));
        assert!(!tile_inside(&[], 4, 4, 8));
        // 8 px tiles of a 24 x 16 map start at multiples of 8: none fits in y 4..12.
        assert_eq!(tile_labels(&r, 2, 3, 8), vec![false; 6]);
        assert_eq!(
            tile_labels(&[roi(8, 0, 16, 8)], 2, 3, 8),
            vec![false, true, true, false, false, false]
        );
    }

    #[test]
    fn splitmix_reference_values() {
        // Reference outputs of SplitMix64 seeded with 0 (Vigna's splitmix64.c).
        let mut r = SplitMix64(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn thirds_are_equal_and_stratified() {
        let labels: Vec<bool> = (0..30).map(|i| i % 10 == 0).collect();
        let th = assign_thirds(&labels, 7);
        for third in [Third::Train, Third::Test, Third::Prune] {
            let n = th.iter().filter(|&&t| t == third).count();
            let pos = (0..30).filter(|&i| th[i] == third && labels[i]).count();
            assert_eq!((n, pos), (10, 1));
        }
        assert_eq!(th, assign_thirds(&labels, 7));
        assert_ne!(th, assign_thirds(&labels, 8));
    }

    #[test]
    fn light_variants_scale_channels_and_spare_the_aligned_grid() {
        let img = Rgb8 {
            width: 2,
            height: 1,
            data: vec![200, 100, 40, 10, 20, 255],
        };
        // Darker x 0.75: 150 75 30, 7 15 191 (rounded down).
        assert_eq!(
            apply_gains(&img, LIGHT_VARIANTS[1]).data,
            vec![150, 75, 30, 7, 15, 191]
        );
        // Brighter x 333 / 256: 200 -> 260 clipped to 255, 100 -> 130, 40 -> 52, 10 -> 13,
        // 20 -> 26, 255 -> 255.
        assert_eq!(
            apply_gains(&img, LIGHT_VARIANTS[2]).data,
            vec![255, 130, 52, 13, 26, 255]
        );
        // Warmer: red x 1.125 (200 -> 225), blue x 0.875 (40 -> 35, 255 -> 223).
        assert_eq!(
            apply_gains(&img, LIGHT_VARIANTS[3]).data,
            vec![225, 100, 35, 11, 20, 223]
        );
        for frame in 0..4 {
            assert_eq!(light_variant(Augment::Light, frame, 0), 0);
            assert_eq!(light_variant(Augment::None, frame, 3), 0);
        }
        // Three frames of four grids use every variant.
        let used: std::collections::BTreeSet<usize> = (0..3)
            .flat_map(|f| (0..4).map(move |g| light_variant(Augment::Light, f, g)))
            .collect();
        assert_eq!(used.len(), LIGHT_VARIANTS.len());
    }
}
