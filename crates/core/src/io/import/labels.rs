//! Labels of an imported sequence: a CSV of rectangles (`image,x,y,width,height[,object]`,
//! or the columns a header names, `filename,xmin,ymin,xmax,ymax,class` and the like; several
//! rows per image for several objects or rectangles) or a folder of masks, each turned into
//! the rectangle around its foreground.
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
    /// Object name from the CSV's object column, if it has one.
    pub object: Option<String>,
    /// Rectangle in pixels of the image file, or None for a background row.
    pub roi: Option<RegionOfInterest>,
}

/// Label rows by image as the rows name it (`read_labels` resolves the names to the imported
/// files), in file order.
pub type Labels = BTreeMap<String, Vec<LabelRow>>;

/// Header names of each column a labels CSV may have (lower case; `_`, `-` and spaces are
/// ignored, so `file_name` is `filename`). Labelling tools and dataset converters name the
/// same things differently; a header naming none of a role's names is refused.
const IMAGE_NAMES: &[&str] = &[
    "image",
    "imagename",
    "imagepath",
    "img",
    "filename",
    "file",
    "path",
    "frame",
];
const OBJECT_NAMES: &[&str] = &[
    "object",
    "objectname",
    "class",
    "classname",
    "label",
    "labelname",
    "category",
    "categoryname",
    "name",
];
const X_NAMES: &[&str] = &["x", "xmin", "left", "x1", "bboxx"];
const Y_NAMES: &[&str] = &["y", "ymin", "top", "y1", "bboxy"];
const WIDTH_NAMES: &[&str] = &["width", "w", "bboxwidth", "boxwidth"];
const HEIGHT_NAMES: &[&str] = &["height", "h", "bboxheight", "boxheight"];
const XMAX_NAMES: &[&str] = &["xmax", "right", "x2"];
const YMAX_NAMES: &[&str] = &["ymax", "bottom", "y2"];

/// Where a row's values are: objloc's own order (`image,x,y,width,height[,object]`), or the
/// columns a header names.
#[derive(Debug, Clone, PartialEq)]
struct Columns {
    image: usize,
    object: Option<usize>,
    /// Column indices of x, y and then width, height (`corners` false) or the right and
    /// bottom edges (`corners` true: `xmin,ymin,xmax,ymax`).
    edges: [usize; 4],
    corners: bool,
    /// The header's column count (None: objloc's order, 5 or 6 columns).
    count: Option<usize>,
}

impl Columns {
    const OBJLOC: Columns = Columns {
        image: 0,
        object: Some(5),
        edges: [1, 2, 3, 4],
        corners: false,
        count: None,
    };

    /// The columns a header names; an error saying what it lacks. Where a header names both
    /// corners and a width and height (TensorFlow's `filename,width,height,class,xmin,...`,
    /// whose width and height are the image's), the corners are the box.
    fn of_header(fields: &[&str]) -> Result<Columns, String> {
        let names: Vec<String> = fields
            .iter()
            .map(|f| f.to_lowercase().replace(['_', '-', ' '], ""))
            .collect();
        // objloc's own header: its rows may have the object column or not, as before.
        let own = ["image", "x", "y", "width", "height", "object"];
        if (names.len() == 5 || names.len() == 6) && names.iter().zip(own).all(|(n, o)| n == o) {
            return Ok(Columns::OBJLOC);
        }
        let find = |wanted: &[&str]| names.iter().position(|n| wanted.contains(&n.as_str()));
        let found = |role: &str, wanted: &[&str]| {
            find(wanted).ok_or_else(|| {
                format!(
                    "the header ({}) names no {role} column (one of: {})",
                    fields.join(","),
                    wanted.join(", ")
                )
            })
        };
        let image = found("image", IMAGE_NAMES)?;
        let x = found("x (left edge)", X_NAMES)?;
        let y = found("y (top edge)", Y_NAMES)?;
        let (corners, right, bottom) = match (find(XMAX_NAMES), find(YMAX_NAMES)) {
            (Some(r), Some(b)) => (true, r, b),
            _ => (
                false,
                found("width (or xmax)", WIDTH_NAMES)?,
                found("height (or ymax)", HEIGHT_NAMES)?,
            ),
        };
        let object = find(OBJECT_NAMES).filter(|&o| o != image);
        Ok(Columns {
            image,
            object,
            edges: [x, y, right, bottom],
            corners,
            count: Some(fields.len()),
        })
    }
}

/// A CSV field without the double quotes a spreadsheet may put around it.
fn unquoted(f: &str) -> &str {
    let f = f.trim();
    f.strip_prefix('"')
        .and_then(|g| g.strip_suffix('"'))
        .unwrap_or(f)
        .trim()
}

/// Parses a labels CSV: `image,x,y,width,height` with an optional sixth `object` column, or
/// the columns a first-line header names (`filename,xmin,ymin,xmax,ymax,class` and the like:
/// [`Columns::of_header`]).
pub fn parse_labels(path: &Path, text: &str) -> Result<Labels, ImportError> {
    let mut out: Labels = BTreeMap::new();
    // Spreadsheets write UTF-8 CSVs with a byte-order mark: it hid the header (`\u{feff}image`
    // is not `image`), which then failed as a row.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut columns = Columns::OBJLOC;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let err = |what: String| line_error(path, line, what);
        let fields: Vec<&str> = content.split(',').map(unquoted).collect();
        if line == 1 && is_header(&fields) {
            columns = Columns::of_header(&fields).map_err(err)?;
            continue;
        }
        let (image, object, roi) = parse_row(&columns, &fields).map_err(err)?;
        out.entry(image.to_owned())
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

/// One row's image, object (None: the import's default) and box (None: background).
fn parse_row<'a>(
    c: &Columns,
    mut fields: &[&'a str],
) -> Result<(&'a str, Option<String>, Option<RegionOfInterest>), String> {
    // Empty fields past the last column: a spreadsheet's trailing commas.
    while fields.len() > c.count.unwrap_or(6) && fields.last() == Some(&"") {
        fields = &fields[..fields.len() - 1];
    }
    if fields.len() == 1 && fields[0].contains([';', '\t']) {
        return Err(format!(
            "one column where {} are due: objloc reads fields separated by commas, not semicolons or tabs",
            c.count.map_or("5 or 6".to_owned(), |n| n.to_string())
        ));
    }
    match c.count {
        None if fields.len() != 5 && fields.len() != 6 => {
            return Err(format!(
                "expected 5 or 6 columns `image,x,y,width,height[,object]`, found {}",
                fields.len()
            ));
        }
        // One column more than a header without an object column names: the object, as
        // objloc's own sixth column (rows of `image,x,y,w,h` with objects were read so when
        // any header was skipped).
        Some(n) if fields.len() != n && !(c.object.is_none() && fields.len() == n + 1) => {
            return Err(format!(
                "expected {n} columns as the header names, found {}",
                fields.len()
            ));
        }
        _ => {}
    }
    let image = fields[c.image];
    if image.is_empty() {
        return Err("image name is empty".into());
    }
    let edges = c.edges.map(|k| (k, fields[k]));
    let roi = parse_box(edges, c.corners)?;
    let extra = c.count.filter(|&n| fields.len() == n + 1);
    let object = c
        .object
        .or(extra)
        .and_then(|k| fields.get(k))
        .filter(|o| !o.is_empty())
        .map(|o| (*o).to_owned());
    Ok((image, object, roi))
}

/// Whether the first line is a header: its second column is neither empty nor a number, as
/// a row's x is (`image,x,...` as objloc writes it, `filename,xmin,...` or
/// `filename,width,...` from other tools; `image_001.png,10,...` is a row, and so is
/// `a.png,nan,...`, refused as one).
fn is_header(fields: &[&str]) -> bool {
    fields
        .get(1)
        .is_some_and(|x| !x.is_empty() && x.parse::<f64>().is_err())
}

/// A value within a millionth of a pixel of a whole number is that number: a box's right edge
/// computed as `x + width` from a tool's fractions (`630.8405677794293 + 9.15943222057076`)
/// lands an ulp past the image's edge, and rounding it outward would leave the image.
fn snapped(v: f64) -> f64 {
    let r = v.round();
    if (v - r).abs() <= 1e-6 { r } else { v }
}

/// The box of a row from its four `(column, text)` values: x, y and width, height, or with
/// `corners` the right and bottom edges; None when all four are empty (a background row).
/// Labelling tools write sub-pixel boxes (`158.37`): such a box becomes the smallest
/// whole-pixel box holding it, as a mask's does; whole numbers are taken as they are.
fn parse_box(
    fields: [(usize, &str); 4],
    corners: bool,
) -> Result<Option<RegionOfInterest>, String> {
    if fields.iter().all(|(_, f)| f.is_empty()) {
        return Ok(None);
    }
    let mut v = [0.0f64; 4];
    for (k, (col, f)) in fields.iter().enumerate() {
        v[k] = f
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("column {} ({f:?}) is not a number of pixels", col + 1))?;
        // A left or top edge less than a pixel before the image is a labeller's rounding at
        // the border (`-0.4`): the border.
        let above_least = if k < 2 { v[k] > -1.0 } else { v[k] >= 0.0 };
        if !above_least || v[k] > f64::from(u32::MAX) {
            return Err(format!(
                "column {} ({f:?}) is not a number of pixels in the image",
                col + 1
            ));
        }
    }
    let (right, bottom) = if corners {
        (v[2], v[3])
    } else {
        (v[0] + v[2], v[1] + v[3])
    };
    let (x0, y0) = (
        snapped(v[0]).floor().max(0.0),
        snapped(v[1]).floor().max(0.0),
    );
    let (x1, y1) = (snapped(right).ceil(), snapped(bottom).ceil());
    if right <= v[0] || bottom <= v[1] {
        let [(_, a), (_, b), (_, c), (_, d)] = fields;
        return Err(if corners {
            format!("box from ({a}, {b}) to ({c}, {d}) is empty")
        } else {
            format!("box {c} x {d} is empty")
        });
    }
    // Whole numbers give back their own values (exact in f64); the `as` casts saturate. A
    // box narrower than a millionth of a pixel is the pixel it lies in.
    Ok(Some(RegionOfInterest {
        x_offset: x0 as u32,
        y_offset: y0 as u32,
        width: (x1 - x0).max(1.0) as u32,
        height: (y1 - y0).max(1.0) as u32,
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
        // objloc's own header takes rows with and without the object column.
        let l = parse_labels(
            p,
            "image,x,y,width,height\na.png,1,2,3,4,mug\nb.png,1,2,3,4\n",
        )
        .unwrap();
        assert_eq!(l["a.png"][0].object.as_deref(), Some("mug"));
        // A labelling tool's sub-pixel box: the whole-pixel box holding it.
        let l = parse_labels(p, "a.png,10.6,2.25,30.1,3.5\n").unwrap();
        let r = l["a.png"][0].roi.unwrap();
        assert_eq!((r.x_offset, r.y_offset, r.width, r.height), (10, 2, 31, 4));
        for (row, what) in [
            (
                "a.png,-1,2,3,4",
                "column 2 (\"-1\") is not a number of pixels in the image",
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

    /// Other tools' headers: corners instead of a size, TensorFlow's image size beside the
    /// corners, quoted fields; a header naming no box is refused on its line.
    #[test]
    fn a_header_names_the_columns_rows_are_read_by() {
        let p = Path::new("l.csv");
        let boxes = |l: &Labels, name: &str| -> Vec<(u32, u32, u32, u32, Option<String>)> {
            l[name]
                .iter()
                .map(|r| {
                    let b = r.roi.unwrap();
                    (b.x_offset, b.y_offset, b.width, b.height, r.object.clone())
                })
                .collect()
        };
        let l = parse_labels(
            p,
            "filename,xmin,ymin,xmax,ymax,class\na.png,10,20,40,60,mug\n",
        )
        .unwrap();
        assert_eq!(
            boxes(&l, "a.png"),
            vec![(10, 20, 30, 40, Some("mug".into()))]
        );
        let tf = "filename,width,height,class,xmin,ymin,xmax,ymax\n\"a.png\",640,480,kettle,10,20,40,60\n";
        let l = parse_labels(p, tf).unwrap();
        assert_eq!(
            boxes(&l, "a.png"),
            vec![(10, 20, 30, 40, Some("kettle".into()))]
        );
        let l = parse_labels(p, "Image_Name,Left,Top,Width,Height\nb.png,1,2,3,4\n").unwrap();
        assert_eq!(boxes(&l, "b.png"), vec![(1, 2, 3, 4, None)]);
        let e = parse_labels(p, "filename,a,b,c,d\nb.png,1,2,3,4\n").unwrap_err();
        assert!(
            e.to_string().starts_with(
                "l.csv:1: the header (filename,a,b,c,d) names no x (left edge) column"
            ),
            "{e}"
        );
        // A header without an object column, rows with one: the last column is the object.
        let l = parse_labels(p, "image,x,y,w,h\nb.png,1,2,3,4,cup\n").unwrap();
        assert_eq!(boxes(&l, "b.png"), vec![(1, 2, 3, 4, Some("cup".into()))]);
        let e = parse_labels(p, "filename,xmin,ymin,xmax,ymax\nb.png,1,2,3\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:2: expected 5 columns as the header names, found 4"
        );
        let e = parse_labels(p, "filename,xmin,ymin,xmax,ymax\nb.png,5,2,3,4\n").unwrap_err();
        assert_eq!(e.to_string(), "l.csv:2: box from (5, 2) to (3, 4) is empty");
        // Trailing commas are no columns; semicolons are said to be no separator.
        let l = parse_labels(p, "a.png,1,2,3,4,mug,,\nb.png,,,,\n").unwrap();
        assert_eq!(l["a.png"][0].object.as_deref(), Some("mug"));
        assert_eq!(l["b.png"][0].roi, None);
        let e = parse_labels(p, "a.png;1;2;3;4\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:1: one column where 5 or 6 are due: objloc reads fields separated by commas, not semicolons or tabs"
        );
        // A first line whose x is `nan` is a row, refused as one.
        let e = parse_labels(p, "a.png,nan,1,2,3\n").unwrap_err();
        assert!(
            e.to_string().starts_with("l.csv:1: column 2 (\"nan\")"),
            "{e}"
        );
    }

    /// A box converted from a tool's fractions whose right edge is the image's lands an ulp
    /// past it (630.8405677794293 + 9.15943222057076 = 640.0000000000001): it stays at 640.
    #[test]
    fn a_box_edge_an_ulp_past_a_whole_pixel_is_that_pixel() {
        let (x, w) = (630.8405677794293f64, 9.15943222057076);
        assert!(
            std::hint::black_box(x) + w > 640.0,
            "the sum no longer lands past the edge"
        );
        let l = parse_labels(
            Path::new("l.csv"),
            "a.png,630.8405677794293,10,9.15943222057076,20\n",
        )
        .unwrap();
        let r = l["a.png"][0].roi.unwrap();
        assert_eq!(
            (r.x_offset, r.y_offset, r.width, r.height),
            (630, 10, 10, 20)
        );
        // A left edge less than a pixel before the image is the border; the right edge stays.
        let l = parse_labels(Path::new("l.csv"), "a.png,-0.4,-0.0,3.3,2\n").unwrap();
        let r = l["a.png"][0].roi.unwrap();
        assert_eq!((r.x_offset, r.y_offset, r.width, r.height), (0, 0, 3, 2));
        let l = parse_labels(Path::new("l.csv"), "a.png,10,10,0.0000000001,2\n").unwrap();
        assert_eq!(l["a.png"][0].roi.unwrap().width, 1);
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
