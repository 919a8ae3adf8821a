//! Tile features: an image is cut into non-overlapping square tiles (partial edge tiles
//! dropped) and each tile is described by the histograms of one or more per-pixel channels
//! (a colour quantisation, texture, gradient), each as fractions of the tile's pixels.
//!
//! Invariants: every channel maps every pixel to exactly one of its bins, so each channel's
//! counts in a tile sum to `tile_px * tile_px`; a feature spec lists its channels in the
//! fixed order of [`Channel::ALL`] and feature indices run through them in that order;
//! feature value = count / (tile_px * tile_px); tiles of a grid with offset (dx, dy) start
//! at (dx + c * tile_px, dy + r * tile_px) and are listed row-major. Pure integer / IEEE
//! arithmetic: identical on every machine.
//!
//! Layout: this file holds the feature spec, the histograms and the neighbourhood;
//! `colour` the per-pixel colour quantisations, `texture` the texture and gradient channels.

mod colour;
mod texture;

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

pub use colour::{HIST_BINS, HS_BINS, Hs, Hsv, Rgb332};
pub use texture::{GRAD_BINS, TEXTURE_BINS, grad_plane, luma, texture_plane};

/// A per-pixel colour quantisation whose per-tile histogram is one channel of a tile's features.
pub trait TileFeature {
    /// Lowercase name, as the model file and the command line spell it.
    fn name(&self) -> &'static str;
    /// Number of bins; [`TileFeature::bin`] returns less than this.
    fn bins(&self) -> usize;
    /// Bin of one pixel's (r, g, b) colour, in `0..bins()`.
    fn bin(&self, rgb: [u8; 3]) -> usize;
    /// The bin in words, for printing what a tree split tests.
    fn describe_bin(&self, bin: usize) -> String {
        format!("bin {bin}")
    }
}

/// One per-pixel channel of a tile's features.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Channel {
    /// 3 bits red, 3 bits green, 2 bits blue (256 bins; the paper's colour histogram).
    Rgb332,
    /// 16 grey levels, then hue (20) x saturation (3) x value (4) (256 bins).
    Hsv,
    /// Hue (24) x saturation (3) without brightness, plus dark and grey (74 bins): kept
    /// under a change of exposure or shading.
    Hs,
    /// Counts of clearly brighter and darker neighbours (46 bins: dark, then 45 counts): flat, edge, speck, fine
    /// texture; kept under rotation and, up to a constant, under a gain.
    Texture,
    /// Gradient magnitude relative to brightness: dark, flat, then 4 levels x 4 orientations
    /// (18 bins).
    Grad,
}

impl Channel {
    /// Every channel, in the order a feature spec lists them.
    pub const ALL: [Channel; 5] = [
        Channel::Rgb332,
        Channel::Hsv,
        Channel::Hs,
        Channel::Texture,
        Channel::Grad,
    ];

    /// Lowercase name, as the model file and the command line spell it.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Rgb332 => "rgb332",
            Channel::Hsv => "hsv",
            Channel::Hs => "hs",
            Channel::Texture => "texture",
            Channel::Grad => "grad",
        }
    }

    /// Number of bins of this channel.
    pub fn bins(self) -> usize {
        match self {
            Channel::Rgb332 | Channel::Hsv => HIST_BINS,
            Channel::Hs => HS_BINS,
            Channel::Texture => TEXTURE_BINS,
            Channel::Grad => GRAD_BINS,
        }
    }

    /// The colour quantisation of a colour channel (None: texture and gradient).
    pub fn colour(self) -> Option<&'static dyn TileFeature> {
        match self {
            Channel::Rgb332 => Some(&Rgb332),
            Channel::Hsv => Some(&Hsv),
            Channel::Hs => Some(&Hs),
            Channel::Texture | Channel::Grad => None,
        }
    }

    /// A bin of this channel in words.
    pub fn describe_bin(self, bin: usize) -> String {
        match self {
            Channel::Texture => texture::describe_texture(bin),
            Channel::Grad => texture::describe_grad(bin),
            c => c.colour().map_or_else(String::new, |f| f.describe_bin(bin)),
        }
    }
}

/// Which channels describe a tile: a non-empty set, written as their names joined by `+` in
/// the order of [`Channel::ALL`] (`rgb332`, `hsv`, `rgb332+texture`, ...). A model file
/// stores it under `features`; files written before channels existed name one colour
/// quantisation and read as before.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct FeatureSpec {
    /// Bit i set: channel `Channel::ALL[i]` is used. Never 0.
    mask: u8,
}

impl FeatureSpec {
    /// The paper's 256-bin colour histogram, rgb332: `objloc train`'s default for a ground
    /// robot's sessions.
    pub const RGB332: FeatureSpec = FeatureSpec { mask: 1 };
    /// The hsv colour histogram alone.
    pub const HSV: FeatureSpec = FeatureSpec { mask: 2 };
    /// rgb332 with the brightness-free hue-saturation histogram beside it: the default for
    /// posed captures (`learn::defaults::TileHeadDefaults`).
    pub const RGB332_HS: FeatureSpec = FeatureSpec { mask: 1 | 4 };

    /// The spec of exactly these channels (None when `channels` is empty).
    pub fn of(channels: &[Channel]) -> Option<FeatureSpec> {
        // The variants are declared in the order of `Channel::ALL`.
        let mask = channels.iter().fold(0u8, |m, &c| m | (1 << c as u8));
        (mask != 0).then_some(FeatureSpec { mask })
    }

    /// The channels, in the order of [`Channel::ALL`].
    pub fn channels(self) -> impl Iterator<Item = Channel> {
        Channel::ALL
            .into_iter()
            .enumerate()
            .filter(move |(i, _)| self.mask & (1 << i) != 0)
            .map(|(_, c)| c)
    }

    /// Features of one tile: the channels' bins added up.
    pub fn bins(self) -> usize {
        self.channels().map(Channel::bins).sum()
    }

    /// The channel a feature index (below [`FeatureSpec::bins`]) belongs to, and its bin there.
    pub fn locate(self, feature: usize) -> Option<(Channel, usize)> {
        let mut start = 0;
        for c in self.channels() {
            if feature < start + c.bins() {
                return Some((c, feature - start));
            }
            start += c.bins();
        }
        None
    }

    /// A feature in words: its channel's description of the bin.
    pub fn describe_bin(self, feature: usize) -> String {
        match self.locate(feature) {
            Some((c, bin)) if self.mask.count_ones() > 1 && c.colour().is_some() => {
                format!("{}: {}", c.name(), c.describe_bin(bin))
            }
            Some((c, bin)) => c.describe_bin(bin),
            None => format!("feature {feature} (out of range)"),
        }
    }

    /// The spec as written in model files and on the command line.
    pub fn name(self) -> String {
        self.channels()
            .map(Channel::name)
            .collect::<Vec<_>>()
            .join("+")
    }
}

impl fmt::Display for FeatureSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

impl fmt::Debug for FeatureSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FeatureSpec({})", self.name())
    }
}

/// A feature spec that does not parse: an unknown or repeated channel name, or none.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "feature spec {0:?} is not known (channels rgb332, hsv, hs, texture, grad, joined by '+', each at most once)"
)]
pub struct UnknownFeatureSpec(pub String);

impl FromStr for FeatureSpec {
    type Err = UnknownFeatureSpec;
    /// Channel names joined by `+`, in any order (stored in the order of [`Channel::ALL`]).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut mask = 0u8;
        for part in s.split('+') {
            let bit = Channel::ALL
                .iter()
                .position(|c| c.name() == part)
                .map(|i| 1u8 << i)
                .filter(|b| mask & b == 0)
                .ok_or_else(|| UnknownFeatureSpec(s.to_owned()))?;
            mask |= bit;
        }
        Ok(FeatureSpec { mask })
    }
}

impl TryFrom<String> for FeatureSpec {
    type Error = UnknownFeatureSpec;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<FeatureSpec> for String {
    fn from(f: FeatureSpec) -> String {
        f.name()
    }
}

/// The per-pixel bins of every channel of `spec`, one plane (row-major, `width * height`)
/// per channel, as feature indices: a channel's bins are offset by the bins of the channels
/// before it. Computed once per frame and shared by the shifted grids of training, since a
/// colour conversion per pixel per grid was a fifth of the training time.
pub fn bin_planes(img: &crate::types::image::Rgb8, spec: FeatureSpec) -> Vec<Vec<u16>> {
    debug_assert!(spec.bins() <= u16::MAX as usize + 1);
    let (w, h) = (img.width as usize, img.height as usize);
    let needs_luma = spec.channels().any(|c| c.colour().is_none());
    let l = if needs_luma {
        luma(&img.data)
    } else {
        Vec::new()
    };
    let mut offset = 0u16;
    let mut planes = Vec::new();
    for c in spec.channels() {
        planes.push(match c {
            Channel::Texture => texture_plane(&l, w, h, offset),
            Channel::Grad => grad_plane(&l, w, h, offset),
            Channel::Rgb332 => colour_plane(img, &Rgb332, offset),
            Channel::Hsv => colour_plane(img, &Hsv, offset),
            Channel::Hs => colour_plane(img, &Hs, offset),
        });
        offset += c.bins() as u16;
    }
    planes
}

/// The bin of every pixel of `img` under one colour quantisation, plus `offset`.
fn colour_plane<F: TileFeature>(img: &crate::types::image::Rgb8, f: &F, offset: u16) -> Vec<u16> {
    img.data
        .chunks_exact(3)
        .map(|p| offset + f.bin([p[0], p[1], p[2]]) as u16)
        .collect()
}

/// Per-tile histograms of one grid: `counts[t * bins + b]` = pixels of tile t in bin b.
#[derive(Debug, Clone, PartialEq)]
pub struct TileHistograms {
    /// Whole tiles down the image (rows of the grid).
    pub rows: usize,
    /// Whole tiles across the image (columns of the grid).
    pub cols: usize,
    /// Side of a square tile, px.
    pub tile_px: u32,
    /// Counts per tile: the feature's bins, doubled by [`with_context`] with a neighbourhood.
    pub bins: usize,
    /// Pixel counts, `rows * cols * bins`, tiles row-major; the bins of a tile's own histogram sum
    /// to `tile_px * tile_px`.
    pub counts: Vec<u16>,
}

impl TileHistograms {
    /// The `bins` counts of tile `t` (row-major index).
    pub fn tile(&self, t: usize) -> &[u16] {
        &self.counts[t * self.bins..(t + 1) * self.bins]
    }
}

/// Number of whole tiles along a side of `len_px` for a grid starting at `offset_px`.
pub fn whole_tiles(len_px: u32, offset_px: u32, tile_px: u32) -> usize {
    if tile_px == 0 || offset_px >= len_px {
        return 0;
    }
    ((len_px - offset_px) / tile_px) as usize
}

/// Features a tree reads for `kind` with a neighbourhood of `context_tiles` (see
/// [`with_context`]): the tile's bins, doubled when there is a neighbourhood.
pub fn feature_count(spec: FeatureSpec, context_tiles: u32) -> usize {
    spec.bins() * if context_tiles > 0 { 2 } else { 1 }
}

/// Appends to every tile's histogram the mean histogram of the tiles within `radius` tiles
/// of it (a (2 radius + 1)^2 window of the same grid, clipped at the image edge), rounded to
/// whole counts of one tile, so both halves share the tile's denominator: `bins` doubles and
/// feature `bins + b` is "fraction of pixels in bin b around the tile". `radius` 0 returns
/// the histograms unchanged.
///
/// Why: labels are rectangles, and an object such as a chair is mostly holes, so many
/// positive tiles show only the background seen through it; what tells them apart from the
/// same background elsewhere is the object around them (docs/tree.md).
pub fn with_context(h: TileHistograms, radius: u32) -> TileHistograms {
    if radius == 0 {
        return h;
    }
    let (rows, cols, bins) = (h.rows, h.cols, h.bins);
    let r = radius as usize;
    // Separable sliding-window sums in u32 (a window of 81 tiles of 255^2 pixels overflows
    // u16): along each row, then down each column, adding the tile that enters the window
    // and removing the one that leaves, over whole bin slices so the loops vectorise.
    // Training builds these for every shifted grid, so this is a hot path.
    let add = |acc: &mut [u32], v: &[u16]| acc.iter_mut().zip(v).for_each(|(a, &c)| *a += c as u32);
    let sub = |acc: &mut [u32], v: &[u16]| acc.iter_mut().zip(v).for_each(|(a, &c)| *a -= c as u32);
    let mut across = vec![0u32; rows * cols * bins];
    let mut acc = vec![0u32; bins];
    for y in 0..rows {
        acc.fill(0);
        for xx in 0..r.min(cols) {
            add(&mut acc, h.tile(y * cols + xx));
        }
        for x in 0..cols {
            if x + r < cols {
                add(&mut acc, h.tile(y * cols + x + r));
            }
            if x > r {
                sub(&mut acc, h.tile(y * cols + x - r - 1));
            }
            across[(y * cols + x) * bins..(y * cols + x + 1) * bins].copy_from_slice(&acc);
        }
    }
    let out_bins = 2 * bins;
    let mut counts = vec![0u16; rows * cols * out_bins];
    let at = |yy: usize, x: usize| (yy * cols + x) * bins..(yy * cols + x + 1) * bins;
    for x in 0..cols {
        let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(cols));
        acc.fill(0);
        for yy in 0..r.min(rows) {
            acc.iter_mut()
                .zip(&across[at(yy, x)])
                .for_each(|(a, &c)| *a += c);
        }
        for y in 0..rows {
            if y + r < rows {
                acc.iter_mut()
                    .zip(&across[at(y + r, x)])
                    .for_each(|(a, &c)| *a += c);
            }
            if y > r {
                acc.iter_mut()
                    .zip(&across[at(y - r - 1, x)])
                    .for_each(|(a, &c)| *a -= c);
            }
            let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(rows));
            let n = ((y1 - y0) * (x1 - x0)) as u32;
            let out = &mut counts[(y * cols + x) * out_bins..(y * cols + x + 1) * out_bins];
            let (own, around) = out.split_at_mut(bins);
            own.copy_from_slice(h.tile(y * cols + x));
            // Rounded mean (s + n/2) / n, at most one tile's pixel count so it fits u16;
            // divided by multiplying with ceil(2^32 / n), exact here because the dividend
            // (<= 81 * 255^2 + 40) is below 2^32 / n (n <= 81), and a division per bin was
            // the slowest step of training.
            let m = (1u64 << 32).div_ceil(n as u64);
            for (o, &s) in around.iter_mut().zip(&acc) {
                *o = (((s + n / 2) as u64 * m) >> 32) as u16;
            }
        }
    }
    TileHistograms {
        rows,
        cols,
        tile_px: h.tile_px,
        bins: out_bins,
        counts,
    }
}

/// Histograms of the grid of whole tiles starting at pixel (`dx`, `dy`).
/// `tile_px` must be at least 1 and at most 255 (counts are u16).
pub fn tile_histograms(
    img: &crate::types::image::Rgb8,
    spec: FeatureSpec,
    tile_px: u32,
    dx: u32,
    dy: u32,
) -> TileHistograms {
    histograms_of_bins(
        &bin_planes(img, spec),
        img.width,
        img.height,
        spec.bins(),
        tile_px,
        dx,
        dy,
    )
}

/// [`tile_histograms`] from the [`bin_planes`] of a `width` x `height` frame with `bins`
/// features in all.
pub fn histograms_of_bins(
    planes: &[Vec<u16>],
    width: u32,
    height: u32,
    bins: usize,
    tile_px: u32,
    dx: u32,
    dy: u32,
) -> TileHistograms {
    let rows = whole_tiles(height, dy, tile_px);
    let cols = whole_tiles(width, dx, tile_px);
    // No whole tile in one direction is none at all (and a frame narrower than the offset
    // would otherwise slice past its rows' end).
    let (rows, cols) = if rows == 0 || cols == 0 {
        (0, 0)
    } else {
        (rows, cols)
    };
    let mut counts = vec![0u16; rows * cols * bins];
    let w = width as usize;
    let t = tile_px as usize;
    for r in 0..rows {
        for yy in 0..t {
            let y = dy as usize + r * t + yy;
            let start = y * w + dx as usize;
            for plane in planes {
                let row_bins = &plane[start..start + cols * t];
                for c in 0..cols {
                    let hist = &mut counts[(r * cols + c) * bins..(r * cols + c + 1) * bins];
                    for &b in &row_bins[c * t..(c + 1) * t] {
                        hist[b as usize] += 1;
                    }
                }
            }
        }
    }
    TileHistograms {
        rows,
        cols,
        tile_px,
        bins,
        counts,
    }
}

/// Calls `f` with the histogram of every whole tile of the aligned grid, row-major (the
/// tiles of [`histograms_of_bins`] at offset (0, 0)), counted in one buffer that is cleared
/// after each tile: prediction needs each histogram once, and the dense histograms of a
/// 1080 x 1920 frame (16 MB at 256 bins) cost more to allocate and zero than to count.
pub fn for_each_tile_histogram(
    planes: &[Vec<u16>],
    width: u32,
    height: u32,
    bins: usize,
    tile_px: u32,
    mut f: impl FnMut(&[u16]),
) {
    let rows = whole_tiles(height, 0, tile_px);
    let cols = whole_tiles(width, 0, tile_px);
    let (w, t) = (width as usize, tile_px as usize);
    let mut hist = vec![0u16; bins];
    for r in 0..rows {
        for c in 0..cols {
            let pixels = |yy: usize| (r * t + yy) * w + c * t..(r * t + yy) * w + (c + 1) * t;
            for plane in planes {
                for yy in 0..t {
                    for &b in &plane[pixels(yy)] {
                        hist[b as usize] += 1;
                    }
                }
            }
            f(&hist);
            // Only the bins this tile touched are non-zero.
            for plane in planes {
                for yy in 0..t {
                    for &b in &plane[pixels(yy)] {
                        hist[b as usize] = 0;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::image::Rgb8;

    /// The sliding sums and the division by multiplication against the plain definition:
    /// every window summed tile by tile, divided with `/`, on an uneven grid with counts up
    /// to a whole 255-pixel tile, for every radius a model may use.
    #[test]
    fn context_matches_the_plain_window_mean_for_every_radius() {
        let (rows, cols, bins) = (7, 11, 3);
        // A fixed pseudo-random sequence (xorshift), counts in 0..=255^2.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let counts: Vec<u16> = (0..rows * cols * bins)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                match state % 4 {
                    0 => 65025,
                    1 => 0,
                    _ => (state >> 8) as u16 % 65026,
                }
            })
            .collect();
        let h = TileHistograms {
            rows,
            cols,
            tile_px: 255,
            bins,
            counts,
        };
        for radius in 1..=4usize {
            let c = with_context(h.clone(), radius as u32);
            for y in 0..rows {
                for x in 0..cols {
                    let (y0, y1) = (y.saturating_sub(radius), (y + radius + 1).min(rows));
                    let (x0, x1) = (x.saturating_sub(radius), (x + radius + 1).min(cols));
                    let n = ((y1 - y0) * (x1 - x0)) as u32;
                    let mut want = h.tile(y * cols + x).to_vec();
                    for b in 0..bins {
                        let sum: u32 = (y0..y1)
                            .flat_map(|yy| (x0..x1).map(move |xx| (yy, xx)))
                            .map(|(yy, xx)| h.tile(yy * cols + xx)[b] as u32)
                            .sum();
                        want.push(((sum + n / 2) / n) as u16);
                    }
                    assert_eq!(
                        c.tile(y * cols + x),
                        &want[..],
                        "radius {radius} at ({y}, {x})"
                    );
                }
            }
        }
    }

    #[test]
    fn context_appends_the_rounded_mean_of_the_window_clipped_at_the_edge() {
        // A 2 x 3 grid of tiles of 4 pixels, 2 bins: bin 0 counts 0, 1, 2 / 3, 4, 4.
        let tiles = [[0u16, 4], [1, 3], [2, 2], [3, 1], [4, 0], [4, 0]];
        let h = TileHistograms {
            rows: 2,
            cols: 3,
            tile_px: 2,
            bins: 2,
            counts: tiles.iter().flatten().copied().collect(),
        };
        assert_eq!(with_context(h.clone(), 0), h);
        let c = with_context(h, 1);
        assert_eq!((c.rows, c.cols, c.bins), (2, 3, 4));
        // Tile (0,0): window (0..2, 0..2) = bin-0 counts 0, 1, 3, 4: sum 8, mean 2 (bin 1:
        // 8 / 4 = 2). Tile (0,1): all six tiles, bin 0 sum 14 -> 14/6 = 2.33 -> 2, bin 1 sum 10
        // -> 1.67 -> 2. Tile (1,2): (0..2, 1..3) = 1, 2, 4, 4: sum 11 -> 2.75 -> 3; bin 1: 5 ->
        // 1.25 -> 1.
        assert_eq!(c.tile(0), &[0, 4, 2, 2]);
        assert_eq!(c.tile(1), &[1, 3, 2, 2]);
        assert_eq!(c.tile(5), &[4, 0, 3, 1]);
    }

    #[test]
    fn histograms_count_whole_tiles_only() {
        // 10 x 5 image, tile 4: 2 columns, 1 row; left half red, rest black.
        let mut data = vec![0u8; 10 * 5 * 3];
        for y in 0..5 {
            for x in 0..4 {
                data[(y * 10 + x) * 3] = 255;
            }
        }
        let img = Rgb8 {
            width: 10,
            height: 5,
            data,
        };
        let h = tile_histograms(&img, FeatureSpec::RGB332, 4, 0, 0);
        assert_eq!((h.rows, h.cols), (1, 2));
        assert_eq!(h.tile(0)[Rgb332.bin([255, 0, 0])], 16);
        assert_eq!(h.tile(1)[0], 16);
        // Shifted by 1: tiles start at x = 1 and 5; the first has 3 red columns.
        let h = tile_histograms(&img, FeatureSpec::RGB332, 4, 1, 1);
        assert_eq!((h.rows, h.cols), (1, 2));
        assert_eq!(h.tile(0)[Rgb332.bin([255, 0, 0])], 12);
        assert_eq!(whole_tiles(10, 12, 4), 0);
    }

    /// A frame narrower than the grid's offset (3 x 96 px, tile 8, shifted by 4 in x: rows
    /// of tiles but no column) has no tiles, without slicing past its pixels (it panicked).
    #[test]
    fn a_frame_narrower_than_the_offset_has_no_tiles() {
        let img = Rgb8 {
            width: 3,
            height: 96,
            data: vec![128u8; 3 * 96 * 3],
        };
        for (dx, dy) in [(4, 0), (4, 4), (0, 0)] {
            let h = tile_histograms(&img, FeatureSpec::RGB332, 8, dx, dy);
            assert_eq!((h.rows, h.cols), (0, 0), "offset ({dx}, {dy})");
            assert!(h.counts.is_empty());
        }
    }

    #[test]
    fn streamed_histograms_equal_the_grid_of_histograms() {
        // A 19 x 13 image of a colour ramp (partial tiles at the right and bottom), tile 4.
        let data: Vec<u8> = (0..19 * 13)
            .flat_map(|i: u32| {
                [
                    (i * 7 % 256) as u8,
                    (i * 13 % 256) as u8,
                    (i * 29 % 256) as u8,
                ]
            })
            .collect();
        let img = Rgb8 {
            width: 19,
            height: 13,
            data,
        };
        let spec: FeatureSpec = "rgb332+texture+grad".parse().unwrap();
        let planes = bin_planes(&img, spec);
        let grid = histograms_of_bins(&planes, 19, 13, spec.bins(), 4, 0, 0);
        let mut streamed = Vec::new();
        for_each_tile_histogram(&planes, 19, 13, spec.bins(), 4, |h| {
            streamed.extend_from_slice(h)
        });
        assert_eq!((grid.rows, grid.cols), (3, 4));
        assert_eq!(streamed, grid.counts);
    }

    #[test]
    fn specs_parse_print_and_locate_their_features() {
        assert_eq!("rgb332".parse(), Ok(FeatureSpec::RGB332));
        assert_eq!("hsv".parse(), Ok(FeatureSpec::HSV));
        let spec: FeatureSpec = "texture+rgb332".parse().unwrap();
        assert_eq!(spec.name(), "rgb332+texture");
        assert_eq!(spec.bins(), 256 + 46);
        assert_eq!(
            spec,
            FeatureSpec::of(&[Channel::Texture, Channel::Rgb332]).unwrap()
        );
        for bad in ["", "lab", "rgb332+rgb332", "rgb332+", "RGB332"] {
            assert_eq!(
                bad.parse::<FeatureSpec>(),
                Err(UnknownFeatureSpec(bad.to_owned()))
            );
        }
        assert_eq!(serde_json::to_string(&spec).unwrap(), "\"rgb332+texture\"");
        assert_eq!(
            serde_json::from_str::<FeatureSpec>("\"hsv\"").unwrap(),
            FeatureSpec::HSV
        );
        assert_eq!(spec.locate(255), Some((Channel::Rgb332, 255)));
        assert_eq!(spec.locate(256), Some((Channel::Texture, 0)));
        assert_eq!(spec.locate(302), None);
        assert_eq!(
            spec.describe_bin(5),
            "rgb332: red 0-31, green 32-63, blue 64-127"
        );
        assert_eq!(
            FeatureSpec::RGB332.describe_bin(5),
            "red 0-31, green 32-63, blue 64-127"
        );
        assert_eq!(spec.describe_bin(256), "texture: dark (luma below 24)");
    }

    /// A 4 x 4 tile, columns 0-1 red 200 and columns 2-3 red 100 (luma 60 and 30), every
    /// channel counted by hand (see the comments for each).
    #[test]
    fn every_channel_of_a_tiny_image_by_hand() {
        let data: Vec<u8> = (0..16)
            .flat_map(|i| if i % 4 < 2 { [200, 0, 0] } else { [100, 0, 0] })
            .collect();
        let img = Rgb8 {
            width: 4,
            height: 4,
            data,
        };
        let spec: FeatureSpec = "rgb332+hs+texture+grad".parse().unwrap();
        assert_eq!(spec.bins(), 256 + 74 + 46 + 18);
        let h = tile_histograms(&img, spec, 4, 0, 0);
        let nonzero: Vec<(usize, u16)> = h
            .tile(0)
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(f, &c)| (f, c))
            .collect();
        assert_eq!(
            nonzero,
            vec![
                // rgb332: red 100 -> 3 << 5 = 96, red 200 -> 6 << 5 = 192; 8 pixels each.
                (96, 8),
                (192, 8),
                // hs: both hue 0, saturation 1 -> bin 4, at 256 + 4.
                (260, 16),
                // texture at 330: luma 77 x 200 = 15400 and 77 x 100 = 7700; columns 0 and
                // 3 flat (bin 1); column 1 has 3 neighbours of 7700 <= 15400 / 1.125 to its
                // right: 1 + index (0, 3) = 4; column 2 has 3 of 15400 >= 1.125 x 7700 to its
                // left: 1 + index (3, 0) = 25.
                (331, 8),
                (334, 4),
                (355, 4),
                // grad at 376: columns 0 and 3 flat (bin 1: clamped differences 0); column 1:
                // m = |7700 - 15400| against c = 15400: [1/2, 1) -> level 2, vertical edge,
                // bin 2 + 8 = 10; column 2: m = 7700 against c = 7700: level 3, bin 14.
                (377, 8),
                (386, 4),
                (390, 4),
            ]
        );
    }

    /// The gain-invariant channels of a textured, coloured tile do not move when the light
    /// doubles; its rgb332 histogram does.
    #[test]
    fn a_gain_of_two_keeps_the_hs_texture_and_grad_histograms() {
        let palette = [[90u8, 40, 20], [30, 60, 100], [110, 100, 20], [60, 60, 64]];
        let data: Vec<u8> = (0..64usize)
            .flat_map(|i| {
                let (x, y) = (i % 8, i / 8);
                // Blocks of 3 x 3 with a speck at (5, 2).
                let k = if (x, y) == (5, 2) {
                    2
                } else {
                    (x / 3 + 2 * (y / 3)) % 4
                };
                palette[k]
            })
            .collect();
        let img = Rgb8 {
            width: 8,
            height: 8,
            data,
        };
        let bright = Rgb8 {
            data: img.data.iter().map(|&v| v * 2).collect(),
            ..img.clone()
        };
        let spec: FeatureSpec = "hs+texture+grad".parse().unwrap();
        let (h, h2) = (
            tile_histograms(&img, spec, 8, 0, 0),
            tile_histograms(&bright, spec, 8, 0, 0),
        );
        assert_eq!(h.tile(0), h2.tile(0));
        // Not a trivial tile: three hues and grey, flat parts and edges, nothing dark.
        let t = h.tile(0);
        assert_eq!(t[..74].iter().filter(|&&c| c > 0).count(), 4);
        assert_eq!((t[74], t[74 + 46]), (0, 0));
        assert!(t[75] > 0 && t[74 + 47] > 0);
        assert!(t[76..74 + 46].iter().any(|&c| c > 0));
        assert!(t[74 + 48..].iter().any(|&c| c > 0));
        let (r, r2) = (
            tile_histograms(&img, FeatureSpec::RGB332, 8, 0, 0),
            tile_histograms(&bright, FeatureSpec::RGB332, 8, 0, 0),
        );
        assert_ne!(r.tile(0), r2.tile(0));
    }
}
