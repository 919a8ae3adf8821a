//! Decoded images: 8-bit RGB frames, row-major, and their PNG encoding.
//!
//! Invariants: `data.len() == width * height * 3`.

/// A decoded 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Rgb8 {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel bytes, row-major, R G B per pixel; `len() == width * height * 3`.
    pub data: Vec<u8>,
}

impl Rgb8 {
    /// The (r, g, b) of pixel (x, y): x across, y down from the top-left; panics outside the image.
    #[inline]
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// PNG bytes of an RGB8 frame (fast deflate: frames are noisy and barely compress anyway).
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(rgb.len());
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| e.to_string())?;
    Ok(out)
}
