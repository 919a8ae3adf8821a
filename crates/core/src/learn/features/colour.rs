//! Per-pixel colour quantisations: each maps an (r, g, b) pixel to one bin, and a tile's
//! histogram of those bins is one channel of its features.
//!
//! Invariants: `bin` returns less than `bins()` for every RGB triple, using only integer and
//! IEEE f32 arithmetic (the same bin on every machine).

use super::TileFeature;

/// Bins of `rgb332` and `hsv` (the paper's "256 colour bins").
pub const HIST_BINS: usize = 256;

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

/// Below this largest channel a pixel is too dark for a hue (`hsv`, `hs`).
const DARK_MAX: u32 = 26;
/// Saturation bin edges of the coloured bins (`hsv`, `hs`); below 0.2 a pixel is grey.
const SAT_EDGES: [f32; 2] = [0.45, 0.7];

/// Hue in sixths of the circle, [0, 6), of a pixel with chroma > 0 (0 red, 2 green, 4 blue).
#[inline]
fn hue6(r: u32, g: u32, b: u32, max: u32, chroma: u32) -> f32 {
    let c = chroma as f32;
    if max == r {
        let h = (g as f32 - b as f32) / c;
        if h < 0.0 { h + 6.0 } else { h }
    } else if max == g {
        (b as f32 - r as f32) / c + 2.0
    } else {
        (r as f32 - g as f32) / c + 4.0
    }
}

/// A coloured pixel's (hue bin of `hue_bins`, saturation bin 0..3), or None when it is dark
/// (max < 26) or grey (saturation chroma / max < 0.2).
#[inline]
fn hue_sat(r: u32, g: u32, b: u32, hue_bins: usize) -> Option<(usize, usize)> {
    let max = r.max(g).max(b);
    let chroma = max - r.min(g).min(b);
    if max < DARK_MAX || chroma * 5 < max {
        return None;
    }
    let hue_bin =
        ((hue6(r, g, b, max, chroma) * (hue_bins as f32 / 6.0)) as usize).min(hue_bins - 1);
    let sat = chroma as f32 / max as f32;
    Some((hue_bin, SAT_EDGES.iter().filter(|&&e| sat >= e).count()))
}

/// Name of the 30-degree sector around a hue in degrees.
fn hue_name(hue_deg: usize) -> &'static str {
    const NAMES: [&str; 12] = [
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
    NAMES[((hue_deg + 15) / 30) % 12]
}

const SAT_NAMES: [&str; 3] = ["low", "medium", "high"];

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
        match hue_sat(r, g, b, HSV_HUE_BINS) {
            None => (max as usize * HSV_GREY_BINS) >> 8,
            Some((hue_bin, sat_bin)) => {
                let val_bin = HSV_VAL_EDGES.iter().filter(|&&e| max >= e).count();
                HSV_GREY_BINS + (hue_bin * HSV_SAT_BINS + sat_bin) * HSV_VAL_BINS + val_bin
            }
        }
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
        let val = ["dark", "dim", "bright", "very bright"][val_bin];
        format!(
            "{} hue {}-{} deg, {} saturation, {val}",
            hue_name(hue_lo + 9),
            hue_lo,
            hue_lo + 18,
            SAT_NAMES[sat_bin]
        )
    }
}

/// Hue and saturation without brightness: a pixel keeps its bin when the light on it (or the
/// camera's exposure) scales all three channels by one gain, so shading and exposure do not
/// move it (only the dark threshold and 8-bit rounding are not invariant).
///
/// Bin 0: dark (max < 26); bin 1: grey (saturation < 0.2); bins 2..74: 2 + hue_bin * 3 +
/// sat_bin, hue_bin = floor(hue / 15 deg) in 0..24, sat_bin as in `hsv`.
#[derive(Debug, Clone, Copy)]
pub struct Hs;

const HS_HUE_BINS: usize = 24;
/// Bins of `hs`: dark, grey, then 24 hues x 3 saturations.
pub const HS_BINS: usize = 2 + HS_HUE_BINS * HSV_SAT_BINS;

impl TileFeature for Hs {
    fn name(&self) -> &'static str {
        "hs"
    }
    fn bins(&self) -> usize {
        HS_BINS
    }
    /// Integer comparisons instead of `hsv`'s float hue: the same bins as computing hue and
    /// saturation in f32 (checked for every colour by a unit test), at a third of the cost,
    /// since this runs for every pixel of a frame.
    #[inline]
    fn bin(&self, [r, g, b]: [u8; 3]) -> usize {
        let (r, g, b) = (r as i32, g as i32, b as i32);
        let max = r.max(g).max(b);
        let c = max - r.min(g).min(b);
        if max < DARK_MAX as i32 {
            return 0;
        }
        if c * 5 < max {
            return 1;
        }
        // Hue in quarter sextants: 4 * (sextant + num / c) with num in [-c, c].
        let (sextant, num) = if max == r {
            (if g >= b { 0 } else { 6 }, g - b)
        } else if max == g {
            (2, b - r)
        } else {
            (4, r - g)
        };
        let hue_bin = (4 * sextant + (4 * num).div_euclid(c)).min(HS_HUE_BINS as i32 - 1) as usize;
        // Saturation c / max against 0.45 and 0.7.
        let sat_bin = usize::from(20 * c >= 9 * max) + usize::from(10 * c >= 7 * max);
        2 + hue_bin * HSV_SAT_BINS + sat_bin
    }
    fn describe_bin(&self, bin: usize) -> String {
        match bin {
            0 => "dark (no hue)".to_owned(),
            1 => "grey (saturation below 0.2)".to_owned(),
            _ => {
                let (hue_bin, sat_bin) = ((bin - 2) / HSV_SAT_BINS, (bin - 2) % HSV_SAT_BINS);
                let hue_lo = hue_bin * 15;
                format!(
                    "{} hue {}-{} deg, {} saturation, any brightness",
                    hue_name(hue_lo + 7),
                    hue_lo,
                    hue_lo + 15,
                    SAT_NAMES[sat_bin]
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn hs_bins_by_hand() {
        // Pure red at any brightness: hue 0, saturation 1 (bin 2): 2 + 0 * 3 + 2 = 4.
        assert_eq!(Hs.bin([255, 0, 0]), 4);
        assert_eq!(Hs.bin([100, 0, 0]), 4);
        // Orange (200, 100, 0): hue (100 - 0) / 200 sixths = 30 deg -> bin 2; sat 1 -> 2:
        // 2 + 2 * 3 + 2 = 10. At half the light (100, 50, 0) the same.
        assert_eq!(Hs.bin([200, 100, 0]), 10);
        assert_eq!(Hs.bin([100, 50, 0]), 10);
        // Blue-grey (90, 100, 130): chroma 40, max 130, sat 0.31 -> bin 0; hue (90 - 100) / 40
        // + 4 = 3.75 sixths = 225 deg -> bin 15: 2 + 45 + 0 = 47.
        assert_eq!(Hs.bin([90, 100, 130]), 47);
        // Grey and dark.
        assert_eq!(Hs.bin([128, 128, 128]), 1);
        assert_eq!(Hs.bin([20, 0, 0]), 0);
        assert_eq!(
            Hs.describe_bin(47),
            "blue hue 225-240 deg, low saturation, any brightness"
        );
    }

    /// The integer `hs` against hue and saturation in f32 (as `hsv` computes them), for every
    /// one of the 2^24 colours.
    #[test]
    fn hs_integer_bins_equal_the_float_definition_for_every_colour() {
        for r in 0..=255u8 {
            for g in 0..=255u8 {
                for b in 0..=255u8 {
                    let (ru, gu, bu) = (r as u32, g as u32, b as u32);
                    let want = match hue_sat(ru, gu, bu, HS_HUE_BINS) {
                        Some((hue_bin, sat_bin)) => 2 + hue_bin * HSV_SAT_BINS + sat_bin,
                        None => usize::from(ru.max(gu).max(bu) >= DARK_MAX),
                    };
                    assert_eq!(Hs.bin([r, g, b]), want, "({r}, {g}, {b})");
                }
            }
        }
    }

    #[test]
    fn every_colour_has_a_bin_in_range() {
        for r in (0..=255).step_by(5) {
            for g in (0..=255).step_by(5) {
                for b in (0..=255).step_by(5) {
                    assert!(Hsv.bin([r, g, b]) < HIST_BINS);
                    assert!(Hs.bin([r, g, b]) < HS_BINS);
                }
            }
        }
    }
}
