//! The images a replay logs for a frame: the camera frame as a JPEG (or the session's own
//! file), and the tile probabilities as a hoverable u8 image and a viridis overlay, all at the
//! frame's size so that they lie on each other under the camera's pinhole.
//!
//! Invariants: deterministic (the same pixels give the same bytes); no logging state of
//! their own.

use image::ImageEncoder as _;
use rerun::RecordingStream;

use super::{VizError, log_err};
use objloc_core::fuse::replay::StepImage;
use objloc_core::io::session::EncodedMedia;
use objloc_core::out::view::{overlay_rgba_of_tiles, upscale_tiles};
use objloc_core::types::image::Rgb8;
use objloc_core::types::probs::TileProbs;

/// Tile probabilities in [0, 1] as a hoverable image of the frame's size: u8 steps of 1/255
/// (the viewer shows p as the "depth"), a quarter of f32's bytes for a stream that logs one
/// per frame. Each tile is quantised once and then spread over its pixels (pixels past the
/// last whole tile are 0): the same bytes as quantising every pixel of
/// [`objloc_core::out::view::upscale`], with a 64th of the roundings (`roundf` was 1.1-1.4 %
/// of the CPU samples of a streamed replay; the replay's total CPU time did not move
/// measurably).
pub(crate) fn depth_image(probs: &TileProbs, width: u32, height: u32) -> rerun::DepthImage {
    let quantised: Vec<u8> = probs
        .p
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let layout = [probs.rows, probs.cols, probs.tile_px as usize];
    let bytes = upscale_tiles(&quantised, layout, width, height, 0);
    rerun::DepthImage::from_data_type_and_bytes(bytes, [width, height], rerun::ChannelDatatype::U8)
        .with_meter(255.0)
        .with_colormap(rerun::components::Colormap::Viridis)
        .with_depth_range([0.0, 1.0])
}

/// Logs a frame (`image`, an encoded image of `width` x `height` pixels), its tile
/// probabilities (hoverable f32) and a viridis overlay under `base`.
pub(crate) fn log_frame_and_probs(
    rec: &RecordingStream,
    base: &str,
    image: &rerun::EncodedImage,
    (width, height): (u32, u32),
    probs: &TileProbs,
) -> Result<(), VizError> {
    rec.log(format!("{base}/image"), image).map_err(log_err)?;
    let overlay = overlay_rgba_of_tiles(probs, width, height);
    rec.log(
        format!("{base}/overlay"),
        &encoded_png_rgba(&overlay, width, height)?.with_draw_order(10.0),
    )
    .map_err(log_err)?;
    rec.log(
        format!("{base}/probability"),
        &depth_image(probs, width, height),
    )
    .map_err(log_err)?;
    Ok(())
}

/// A fused frame as Rerun shows it: the session's own PNG or JPEG file when the replay hands
/// it over as recorded (no decoding, no encoding: the frame as it was fused), else JPEG.
pub(crate) fn step_frame(image: &StepImage) -> Result<rerun::EncodedImage, VizError> {
    match image {
        StepImage::Encoded { media, bytes, .. } => {
            let media_type = match media {
                EncodedMedia::Png => rerun::MediaType::PNG,
                EncodedMedia::Jpeg => rerun::MediaType::JPEG,
            };
            Ok(rerun::EncodedImage::from_file_contents(bytes.clone()).with_media_type(media_type))
        }
        StepImage::Decoded(rgb) => encoded_jpeg(rgb),
    }
}

/// JPEG quality of the frames in a recording: the camera image is context, not data (its
/// pixels are in the session), and raw RGB frames made the stream 0.23 MB a frame. Below 90
/// `jpeg-encoder` halves the chroma both ways (4:2:0, as cameras do): a 605 x 806 phone frame
/// encodes in 3.9 ms to 63 kB at 80, against 6.3 ms and 110 kB at 90 (4:4:4), and the
/// encoding runs beside a replay that keeps both cores busy.
const FRAME_JPEG_QUALITY: u8 = 80;

/// A frame as a JPEG-encoded image (deterministic: the same pixels give the same bytes).
pub(crate) fn encoded_jpeg(image: &Rgb8) -> Result<rerun::EncodedImage, VizError> {
    let side = |v: u32| {
        u16::try_from(v)
            .map_err(|_| VizError::Encode(format!("a side of {v} px is beyond JPEG's 65535")))
    };
    let mut bytes = Vec::new();
    jpeg_encoder::Encoder::new(&mut bytes, FRAME_JPEG_QUALITY)
        .encode(
            &image.data,
            side(image.width)?,
            side(image.height)?,
            jpeg_encoder::ColorType::Rgb,
        )
        .map_err(|e| VizError::Encode(e.to_string()))?;
    Ok(rerun::EncodedImage::from_file_contents(bytes).with_media_type(rerun::MediaType::JPEG))
}

/// An RGBA image as PNG (lossless; the overlay is flat per tile, so it compresses well).
fn encoded_png_rgba(rgba: &[u8], width: u32, height: u32) -> Result<rerun::EncodedImage, VizError> {
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(rgba, width, height, image::ExtendedColorType::Rgba8)
        .map_err(|e| VizError::Encode(e.to_string()))?;
    Ok(rerun::EncodedImage::from_file_contents(bytes).with_media_type(rerun::MediaType::PNG))
}
