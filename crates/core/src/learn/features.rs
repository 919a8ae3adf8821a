//! Tile features: an image is cut into non-overlapping square tiles (partial edge tiles
//! dropped) and each tile is described by a 256-bin colour histogram of pixel fractions.
//!
//! Invariants: a feature maps every RGB triple to exactly one bin in `0..bins()`, so a tile's
//! histogram counts sum to `tile_px * tile_px`; feature value = count / (tile_px * tile_px);
//! tiles of a grid with offset (dx, dy) start at (dx + c * tile_px, dy + r * tile_px) and are
//! listed row-major. Pure integer / IEEE arithmetic: identical on every machine.

use serde::{Deserialize, Serialize};

/// Number of bins of every built-in feature (the paper's "256 colour bins").
pub const HIST_BINS: usize = 256;

/// A per-pixel colour quantisation whose per-tile histogram is the tile's feature vector.
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

/// The built-in features; the model file names them in lowercase.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
#[value(rename_all = "lowercase")]
pub enum FeatureKind {
    /// 3 bits red, 3 bits green, 2 bits blue.
    Rgb332,
    /// 16 grey levels for unsaturated or dark pixels, then hue (20) x saturation (3) x value (4).
    Hsv,
}

impl FeatureKind {
    /// The implementation of this kind of feature.
    pub fn feature(self) -> &'static dyn TileFeature {
        match self {
            FeatureKind::Rgb332 => &Rgb332,
            FeatureKind::Hsv => &Hsv,
        }
    }
}

impl TileFeature for FeatureKind {
    fn name(&self) -> &'static str {
        self.feature().name()
    }
    fn bins(&self) -> usize {
        self.feature().bins()
    }
    #[inline]
    fn bin(&self, rgb: [u8; 3]) -> usize {
        // Matched here rather than through the vtable: this runs once per pixel.
        match self {
            FeatureKind::Rgb332 => Rgb332.bin(rgb),
            FeatureKind::Hsv => Hsv.bin(rgb),
        }
    }
    fn describe_bin(&self, bin: usize) -> String {
        self.feature().describe_bin(bin)
    }
}

/// `rrrgggbb`: the top 3 bits of red and green and the top 2 of blue.
#[derive(Debug, Clone, Copy)]
pub struct Rgb332;

impl TileFeature for Rgb332 {
    fn name(&self) -> &'static str {
        "rgb332"
    }
    fn bins(&self) -> usize {
        HIST_BINS
    }
    #[inline]
    fn bin(&self, [r, g, b]: [u8; 3]) -> usize {
        ((r as usize >> 5) << 5) | ((g as usize >> 5) << 2) | (b as usize >> 6)
    }
    fn describe_bin(&self, bin: usize) -> String {
        let (r, g, b) = ((bin >> 5) & 7, (bin >> 2) & 7, bin & 3);
        format!(
            "red {}-{}, green {}-{}, blue {}-{}",
            r * 32,
            r * 32 + 31,
            g * 32,
            g * 32 + 31,
            b * 64,
            b * 64 + 63
        )
    }
}

/// Hue-based bins, robust to lighting: brightness changes move a pixel between value bins of
/// the same hue, not to another hue.
///
/// With max = max(r,g,b), min = min(r,g,b), chroma = max - min:
/// - bins 0..16 (grey): max < 26 (too dark for a hue) or chroma * 5 < max (saturation
///   < 0.2); bin = max * 16 / 256.
/// - bins 16..256 (colour): 16 + (hue_bin * 3 + sat_bin) * 4 + val_bin, with hue_bin =
///   floor(hue / 18 deg) in 0..20 (hue 0 = red, 120 = green, 240 = blue), sat_bin in 0..3
///   for saturation [0.2, 0.45), [0.45, 0.7), [0.7, 1], val_bin in 0..4 for max in
///   [26, 84), [84, 141), [141, 198), [198, 255].
#[derive(Debug, Clone, Copy)]
pub struct Hsv;

const HSV_GREY_BINS: usize = 16;
const HSV_HUE_BINS: usize = 20;
const HSV_SAT_BINS: usize = 3;
const HSV_VAL_BINS: usize = 4;
const HSV_DARK_MAX: u32 = 26;
const HSV_SAT_EDGES: [f32; 2] = [0.45, 0.7];
const HSV_VAL_EDGES: [u32; 3] = [84, 141, 198];

impl TileFeature for Hsv {
    fn name(&self) -> &'static str {
        "hsv"
    }
    fn bins(&self) -> usize {
        HIST_BINS
    }
    #[inline]
    fn bin(&self, [r, g, b]: [u8; 3]) -> usize {
        let (r, g, b) = (r as u32, g as u32, b as u32);
        let max = r.max(g).max(b);
        let min = r.min(g).min(b);
        let chroma = max - min;
        if max < HSV_DARK_MAX || chroma * 5 < max {
            return (max as usize * HSV_GREY_BINS) >> 8;
        }
        // Hue in sixths of the circle, [0, 6).
        let c = chroma as f32;
        let h6 = if max == r {
            let h = (g as f32 - b as f32) / c;
            if h < 0.0 { h + 6.0 } else { h }
        } else if max == g {
            (b as f32 - r as f32) / c + 2.0
        } else {
            (r as f32 - g as f32) / c + 4.0
        };
        let hue_bin = ((h6 * (HSV_HUE_BINS as f32 / 6.0)) as usize).min(HSV_HUE_BINS - 1);
        let sat = c / max as f32;
        let sat_bin = HSV_SAT_EDGES.iter().filter(|&&e| sat >= e).count();
        let val_bin = HSV_VAL_EDGES.iter().filter(|&&e| max >= e).count();
        HSV_GREY_BINS + (hue_bin * HSV_SAT_BINS + sat_bin) * HSV_VAL_BINS + val_bin
    }
    fn describe_bin(&self, bin: usize) -> String {
        if bin < HSV_GREY_BINS {
            let lo = bin * 16;
            return format!("grey or dark, brightness {}-{}", lo, lo + 15);
        }
        let k = bin - HSV_GREY_BINS;
        let (hue_bin, sat_bin, val_bin) = (
            k / (HSV_SAT_BINS * HSV_VAL_BINS),
            (k / HSV_VAL_BINS) % HSV_SAT_BINS,
            k % HSV_VAL_BINS,
        );
        let hue_lo = hue_bin * 18;
        let names = [
            "red",
            "orange",
            "yellow",
            "yellow-green",
            "green",
            "green",
            "cyan",
            "azure",
            "blue",
            "violet",
            "magenta",
            "rose",
        ];
        // Name of the 30-degree sector around the bin's centre hue.
        let name = names[((hue_lo + 9 + 15) / 30) % 12];
        let sat = ["low", "medium", "high"][sat_bin];
        let val = ["dark", "dim", "bright", "very bright"][val_bin];
        format!(
            "{name} hue {}-{} deg, {sat} saturation, {val}",
            hue_lo,
            hue_lo + 18
        )
    }
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
pub fn feature_count(kind: FeatureKind, context_tiles: u32) -> usize {
    kind.bins() * if context_tiles > 0 { 2 } else { 1 }
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

/// The bin of every pixel of `img`, row-major: computed once per frame and shared by the
/// shifted grids of training, since a colour conversion per pixel per grid was a fifth of
/// the training time.
pub fn bin_image(img: &crate::types::image::Rgb8, feature: &dyn TileFeature) -> Vec<u16> {
    debug_assert!(feature.bins() <= u16::MAX as usize + 1);
    img.data
        .chunks_exact(3)
        .map(|p| feature.bin([p[0], p[1], p[2]]) as u16)
        .collect()
}

/// Histograms of the grid of whole tiles starting at pixel (`dx`, `dy`).
/// `tile_px` must be at least 1 and at most 255 (counts are u16).
pub fn tile_histograms(
    img: &crate::types::image::Rgb8,
    feature: &dyn TileFeature,
    tile_px: u32,
    dx: u32,
    dy: u32,
) -> TileHistograms {
    histograms_of_bins(
        &bin_image(img, feature),
        img.width,
        img.height,
        feature.bins(),
        tile_px,
        dx,
        dy,
    )
}

/// [`tile_histograms`] from a [`bin_image`] of a `width` x `height` frame.
pub fn histograms_of_bins(
    pixel_bins: &[u16],
    width: u32,
    height: u32,
    bins: usize,
    tile_px: u32,
    dx: u32,
    dy: u32,
) -> TileHistograms {
    let rows = whole_tiles(height, dy, tile_px);
    let cols = whole_tiles(width, dx, tile_px);
    let mut counts = vec![0u16; rows * cols * bins];
    let w = width as usize;
    let t = tile_px as usize;
    for r in 0..rows {
        for yy in 0..t {
            let y = dy as usize + r * t + yy;
            let start = y * w + dx as usize;
            let row_bins = &pixel_bins[start..start + cols * t];
            for c in 0..cols {
                let hist = &mut counts[(r * cols + c) * bins..(r * cols + c + 1) * bins];
                for &b in &row_bins[c * t..(c + 1) * t] {
                    hist[b as usize] += 1;
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
    fn rgb332_bins_by_hand() {
        assert_eq!(Rgb332.bin([0, 0, 0]), 0);
        assert_eq!(Rgb332.bin([255, 255, 255]), 255);
        // red 200 -> 6, green 100 -> 3, blue 130 -> 2: 6<<5 | 3<<2 | 2 = 206.
        assert_eq!(Rgb332.bin([200, 100, 130]), 206);
        assert_eq!(
            Rgb332.describe_bin(206),
            "red 192-223, green 96-127, blue 128-191"
        );
    }

    #[test]
    fn hsv_bins_by_hand() {
        // Pure red, bright: hue 0, sat 1 (bin 2), max 255 (bin 3): 16 + (0*3+2)*4 + 3 = 27.
        assert_eq!(Hsv.bin([255, 0, 0]), 27);
        // Darker red keeps its hue and saturation: max 100 -> val bin 1: 16 + 8 + 1 = 25.
        assert_eq!(Hsv.bin([100, 0, 0]), 25);
        // Pure blue: hue 240 -> bin 13; 16 + (13*3+2)*4 + 3 = 183.
        assert_eq!(Hsv.bin([0, 0, 255]), 183);
        // Grey 128: chroma 0 -> grey bin 128*16/256 = 8.
        assert_eq!(Hsv.bin([128, 128, 128]), 8);
        // Too dark for a hue: max 20 < 26 -> grey bin 1.
        assert_eq!(Hsv.bin([20, 0, 0]), 1);
        // Saturation exactly 0.2 (chroma 40, max 200) is colour: hue 0, sat bin 0, val bin 3.
        assert_eq!(Hsv.bin([200, 160, 160]), 16 + 3);
        assert!(
            Hsv.describe_bin(27)
                .starts_with("red hue 0-18 deg, high saturation")
        );
        assert_eq!(Hsv.describe_bin(8), "grey or dark, brightness 128-143");
    }

    #[test]
    fn every_colour_has_a_bin_in_range() {
        for r in (0..=255).step_by(5) {
            for g in (0..=255).step_by(5) {
                for b in (0..=255).step_by(5) {
                    assert!(Hsv.bin([r, g, b]) < 256);
                }
            }
        }
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
        let h = tile_histograms(&img, &Rgb332, 4, 0, 0);
        assert_eq!((h.rows, h.cols), (1, 2));
        assert_eq!(h.tile(0)[Rgb332.bin([255, 0, 0])], 16);
        assert_eq!(h.tile(1)[0], 16);
        // Shifted by 1: tiles start at x = 1 and 5; the first has 3 red columns.
        let h = tile_histograms(&img, &Rgb332, 4, 1, 1);
        assert_eq!((h.rows, h.cols), (1, 2));
        assert_eq!(h.tile(0)[Rgb332.bin([255, 0, 0])], 12);
        assert_eq!(whole_tiles(10, 12, 4), 0);
    }
}
