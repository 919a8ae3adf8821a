//! Tile probabilities of one frame, and what produces them: the one probability-map type of
//! the code base (the classifier's output, the fuser's evidence, `predict`'s maps).
//!
//! Invariants: `p.len() == rows * cols`, row-major (`p[r * cols + c]`); tiles are aligned at
//! pixel (0, 0), so pixels right of or below the last whole tile belong to no tile.

use crate::types::image::Rgb8;

/// Tile probabilities of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TileProbs {
    /// Whole tiles down the image.
    pub rows: usize,
    /// Whole tiles across the image.
    pub cols: usize,
    /// Side of a tile, pixels.
    pub tile_px: u32,
    /// Probability per tile, row-major.
    pub p: Vec<f32>,
}

/// What turns a frame into tile probabilities (the decision tree, or a stand-in in tests).
pub trait FrameClassifier: Sync {
    /// The probabilities of every whole tile of `img`.
    fn classify(&self, img: &Rgb8) -> TileProbs;
    /// Fraction of positive training examples: the default prior of the grid.
    fn base_rate(&self) -> f64;
}

impl TileProbs {
    /// The frame in grey with each tile tinted red by its probability (edge pixels outside
    /// whole tiles stay grey).
    pub fn heatmap(&self, img: &Rgb8) -> Rgb8 {
        let mut data = Vec::with_capacity(img.data.len());
        let t = self.tile_px as usize;
        for y in 0..img.height as usize {
            for x in 0..img.width as usize {
                let i = (y * img.width as usize + x) * 3;
                let [r, g, b] = [img.data[i], img.data[i + 1], img.data[i + 2]];
                // Rec. 601 luma, halved so the red tint stands out.
                let grey = (299 * r as u32 + 587 * g as u32 + 114 * b as u32) / 2000;
                let (tr, tc) = (y / t.max(1), x / t.max(1));
                let p = if tr < self.rows && tc < self.cols {
                    self.p[tr * self.cols + tc].clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let g = grey as f32;
                data.push((g + p * (255.0 - g)).round() as u8);
                data.push((g * (1.0 - p)).round() as u8);
                data.push((g * (1.0 - p)).round() as u8);
            }
        }
        Rgb8 {
            width: img.width,
            height: img.height,
            data,
        }
    }
}
