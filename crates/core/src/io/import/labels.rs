//! Labels of an imported sequence: a CSV of rectangles (`image,x,y,width,height[,object]`,
//! several rows per image for several objects or rectangles) or a folder of masks, each turned
//! into the rectangle around its foreground.
//!
//! Invariants: rows keep their file order per image; a row with an empty box marks a
//! background frame; an empty object column means the importer's `--object`; every error
//! names the file and line (or the mask file).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{ImportError, line_error};
use crate::io::capture::CaptureError;
use crate::io::msgs::RegionOfInterest;

/// One label row: where it came from, the object it names (None: the import's default
/// object) and its rectangle (None: a background row, the frame shows no object).
#[derive(Debug, Clone, PartialEq)]
pub struct LabelRow {
    /// 1-based line of the CSV (0 for a rectangle from a mask).
    pub line: usize,
    /// Object name from the CSV's sixth column, if it has one.
    pub object: Option<String>,
    /// Rectangle in pixels of the image file, or None for a background row.
    pub roi: Option<RegionOfInterest>,
}

/// Label rows by image file name, in file order. A first line starting with `image` is a
/// header.
pub type Labels = BTreeMap<String, Vec<LabelRow>>;

/// Parses a labels CSV: `image,x,y,width,height` with an optional sixth `object` column.
pub fn parse_labels(path: &Path, text: &str) -> Result<Labels, ImportError> {
    let mut out: Labels = BTreeMap::new();
    // Spreadsheets write UTF-8 CSVs with a byte-order mark: it hid the header (`\u{feff}image`
    // is not `image`), which then failed as a row.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') || (line == 1 && is_header(content)) {
            continue;
        }
        let err = |what: String| line_error(path, line, what);
        let fields: Vec<&str> = content.split(',').map(str::trim).collect();
        if fields.len() != 5 && fields.len() != 6 {
            return Err(err(format!(
                "expected 5 or 6 columns `image,x,y,width,height[,object]`, found {}",
                fields.len()
            )));
        }
        if fields[0].is_empty() {
            return Err(err("image name is empty".into()));
        }
        let roi = parse_box(&fields[1..5]).map_err(err)?;
        let object = fields
            .get(5)
            .filter(|o| !o.is_empty())
            .map(|o| (*o).to_owned());
        out.entry(fields[0].to_owned())
            .or_default()
            .push(LabelRow { line, object, roi });
    }
    // An empty file (or a header alone) labels nothing: most likely the wrong file, and a
    // session imported from it would train on nothing without saying so.
    if out.is_empty() {
        return Err(ImportError::File(CaptureError::Invalid {
            path: path.into(),
            what: "no label rows (`image,x,y,width,height[,object]`; an empty box marks a background frame)".into(),
        }));
    }
    Ok(out)
}

/// Whether the first line is a header: its second column is a word (`image,x,...` as objloc
/// writes it, `filename,xmin,...` from another tool), not a number or empty as a row's is
/// (`image_001.png,10,...` is a row).
fn is_header(content: &str) -> bool {
    let x = content.split(',').nth(1).map(str::trim).unwrap_or("");
    x.chars().next().is_some_and(char::is_alphabetic)
}

/// x, y, width, height in pixels, or all four empty (a background row). Labelling tools
/// write sub-pixel boxes (`158.37`): such a box becomes the smallest whole-pixel box holding
/// it, as a mask's does; whole numbers are taken as they are.
fn parse_box(fields: &[&str]) -> Result<Option<RegionOfInterest>, String> {
    if fields.iter().all(|f| f.is_empty()) {
        return Ok(None);
    }
    let mut v = [0.0f64; 4];
    for (k, f) in fields.iter().enumerate() {
        v[k] = f
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("column {} ({f:?}) is not a number of pixels", k + 2))?;
        if v[k] < 0.0 || v[k] > f64::from(u32::MAX) {
            return Err(format!(
                "column {} ({f:?}) is not a number of pixels from 0 to {}",
                k + 2,
                u32::MAX
            ));
        }
    }
    if v[2] == 0.0 || v[3] == 0.0 {
        return Err(format!("box {} x {} is empty", fields[2], fields[3]));
    }
    // Whole numbers give back their own values (exact in f64); the `as` casts saturate.
    let (x0, y0) = (v[0].floor(), v[1].floor());
    Ok(Some(RegionOfInterest {
        x_offset: x0 as u32,
        y_offset: y0 as u32,
        width: ((v[0] + v[2]).ceil() - x0) as u32,
        height: ((v[1] + v[3]).ceil() - y0) as u32,
        do_rectify: false,
    }))
}

/// The mask file of `image` in `masks`: the one whose stem is the image's stem, or starts
/// with it followed by `-`, `_` or `.` (`1.jpg` <-> `1-removebg-preview.png`, `1_mask.png`).
fn mask_for(masks: &[PathBuf], image: &Path) -> Result<Option<PathBuf>, ImportError> {
    let stem = image.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let hits: Vec<&PathBuf> = masks
        .iter()
        .filter(|m| {
            let ms = m.file_stem().and_then(|s| s.to_str()).unwrap_or("");
            ms == stem
                || ms
                    .strip_prefix(stem)
                    .is_some_and(|rest| rest.starts_with(['-', '_', '.']))
        })
        .collect();
    match hits.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some((*one).clone())),
        [a, b, ..] => Err(ImportError::File(CaptureError::Invalid {
            path: image.into(),
            what: format!(
                "two masks match this image: {} and {}",
                a.display(),
                b.display()
            ),
        })),
    }
}

/// Rectangles from masks: for each image with a mask in `dir`, the box around the mask's
/// foreground (alpha > 128 where the mask has alpha, else luminance > 128), scaled to the
/// image's `size` when the mask is smaller or larger, rounded outward and clipped. Images
/// without a mask get no label; a mask without foreground gives a background row.
pub fn labels_from_masks(
    dir: &Path,
    images: &[(PathBuf, (u32, u32))],
) -> Result<Labels, ImportError> {
    let masks = super::list_images(dir)?;
    let mut out = Labels::new();
    for (image, size) in images {
        let Some(mask) = mask_for(&masks, image)? else {
            continue;
        };
        let roi = mask_box(&mask, *size)?;
        let name = super::name_of(image);
        out.entry(name).or_default().push(LabelRow {
            line: 0,
            object: None,
            roi,
        });
    }
    Ok(out)
}

/// The foreground box of one mask file in the pixels of an image of `size`.
fn mask_box(mask: &Path, size: (u32, u32)) -> Result<Option<RegionOfInterest>, ImportError> {
    let img = image::open(mask).map_err(|e| {
        ImportError::File(CaptureError::Invalid {
            path: mask.into(),
            what: format!("mask does not decode: {e}"),
        })
    })?;
    let has_alpha = img.color().has_alpha();
    let rgba = img.into_rgba8();
    let (mw, mh) = rgba.dimensions();
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0u32, 0u32);
    for (x, y, p) in rgba.enumerate_pixels() {
        let v = if has_alpha {
            p[3]
        } else {
            ((u32::from(p[0]) * 299 + u32::from(p[1]) * 587 + u32::from(p[2]) * 114) / 1000) as u8
        };
        if v > 128 {
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
        }
    }
    if x0 == u32::MAX {
        return Ok(None);
    }
    // Pixel edges scale with the image: mask edge e lies at e * W / w in the image.
    let sx = f64::from(size.0) / f64::from(mw);
    let sy = f64::from(size.1) / f64::from(mh);
    let lo = |e: u32, s: f64| (f64::from(e) * s).floor() as u32;
    let hi = |e: u32, s: f64, max: u32| ((f64::from(e) * s).ceil() as u32).min(max);
    let (bx0, by0) = (lo(x0, sx), lo(y0, sy));
    let (bx1, by1) = (hi(x1, sx, size.0), hi(y1, sy, size.1));
    Ok(Some(RegionOfInterest {
        x_offset: bx0,
        y_offset: by0,
        width: (bx1 - bx0).max(1),
        height: (by1 - by0).max(1),
        do_rectify: false,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spreadsheet's CSV: a byte-order mark before the header, CRLF line ends.
    #[test]
    fn a_byte_order_mark_and_crlf_are_read_as_a_plain_csv() {
        let p = Path::new("l.csv");
        let plain = parse_labels(p, "image,x,y,width,height\na.png,1,2,30,40\n").unwrap();
        let excel =
            parse_labels(p, "\u{feff}image,x,y,width,height\r\na.png,1,2,30,40\r\n").unwrap();
        assert_eq!(excel, plain);
    }

    #[test]
    fn labels_parse_boxes_objects_and_background_rows() {
        let p = Path::new("l.csv");
        let l = parse_labels(
            p,
            "image,x,y,width,height\na.png,1,2,30,40\nb.png,,,,\na.png,5,5,2,2,mug\n",
        )
        .unwrap();
        assert_eq!(l["a.png"].len(), 2);
        let a0 = &l["a.png"][0];
        assert_eq!(a0.roi.map(|r| (r.x_offset, r.height)), Some((1, 40)));
        assert_eq!(a0.object, None);
        assert_eq!(l["a.png"][1].object.as_deref(), Some("mug"));
        assert_eq!(
            l["b.png"],
            vec![LabelRow {
                line: 3,
                object: None,
                roi: None
            }]
        );
        let e = parse_labels(p, "a.png,1,2,0,4\n").unwrap_err();
        assert_eq!(e.to_string(), "l.csv:1: box 0 x 4 is empty");
        // Another tool's header is a header too; a first row whose image is named image_...
        // is a row.
        let l = parse_labels(p, "filename,xmin,ymin,w,h\na.png,1,2,3,4\n").unwrap();
        assert_eq!(l.len(), 1);
        let l = parse_labels(p, "image_1.png,1,2,3,4\nimage_2.png,,,,\n").unwrap();
        assert_eq!(l.len(), 2);
        // A labelling tool's sub-pixel box: the whole-pixel box holding it.
        let l = parse_labels(p, "a.png,10.6,2.25,30.1,3.5\n").unwrap();
        let r = l["a.png"][0].roi.unwrap();
        assert_eq!((r.x_offset, r.y_offset, r.width, r.height), (10, 2, 31, 4));
        for (row, what) in [
            (
                "a.png,-1,2,3,4",
                "column 2 (\"-1\") is not a number of pixels from 0 to 4294967295",
            ),
            (
                "a.png,1,x,3,4",
                "column 3 (\"x\") is not a number of pixels",
            ),
            (
                "a.png,1,2,NaN,4",
                "column 4 (\"NaN\") is not a number of pixels",
            ),
        ] {
            let e = parse_labels(p, row).unwrap_err().to_string();
            assert!(e.starts_with(&format!("l.csv:1: {what}")), "{e}");
        }
        let e = parse_labels(p, "a.png,1,2,3\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:1: expected 5 or 6 columns `image,x,y,width,height[,object]`, found 4"
        );
        for empty in ["", "image,x,y,width,height\n", "# nothing yet\n\n"] {
            let e = parse_labels(p, empty).unwrap_err();
            assert!(e.to_string().starts_with("l.csv: no label rows"), "{e}");
        }
    }

    #[test]
    fn a_mask_becomes_the_box_around_its_foreground_scaled_outward() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().to_path_buf();
        // A 10 x 8 mask with alpha on columns 2..=4 and rows 1..=2, for a 25 x 16 image.
        let mut m = image::RgbaImage::new(10, 8);
        for x in 2..=4 {
            for y in 1..=2 {
                m.put_pixel(x, y, image::Rgba([0, 0, 0, 255]));
            }
        }
        let mask = dir.join("7-removebg-preview.png");
        m.save(&mask).unwrap();
        image::RgbaImage::new(10, 8)
            .save(dir.join("70-removebg.png"))
            .unwrap();
        let images = vec![(dir.join("7.jpg"), (25, 16)), (dir.join("8.jpg"), (25, 16))];
        let l = labels_from_masks(&dir, &images).unwrap();
        // Edges 2, 5 scale by 2.5 to 5, 12.5 -> 13; rows 1, 3 by 2 to 2, 6.
        let r = l["7.jpg"][0].roi.unwrap();
        assert_eq!((r.x_offset, r.y_offset, r.width, r.height), (5, 2, 8, 4));
        assert!(!l.contains_key("8.jpg"));
    }
}
