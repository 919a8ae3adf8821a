//! `objloc train` and `objloc predict` end to end on synthetic sessions with known answers: a
//! red box (lit and shaded halves) on a textured background of greens, greys, blues and
//! browns, labelled exactly; background frames with an empty label; unlabelled frames.
//!
//! Invariants: every pixel comes from a fixed hash of its coordinates and the frame index, so
//! the sessions, and hence the models, are the same on every run.

use std::path::{Path, PathBuf};

use objloc_core::io::msgs::{CompressedImage, Header, ObjectLabel, RegionOfInterest};
use objloc_core::io::session::SessionWriter;

use crate::common::pyenv::sha256_hex;
use crate::common::{objloc, ok, one_line_error, p, repo_dir, usage_error};

const W: u32 = 256;
const H: u32 = 240;
const T0_NS: i64 = 1_700_000_000_000_000_000;
const PERIOD_NS: i64 = 100_000_000;

fn hash(mut x: u64) -> u64 {
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A frame with the box at `rect` (x, y, w, h), or none.
fn render(k: u64, rect: Option<(u32, u32, u32, u32)>) -> Vec<u8> {
    const PALETTE: [[u8; 3]; 6] = [
        [60, 130, 60],
        [120, 120, 120],
        [70, 90, 170],
        [140, 100, 60],
        [200, 200, 190],
        [40, 60, 40],
    ];
    let mut data = Vec::with_capacity((W * H * 3) as usize);
    for y in 0..H {
        for x in 0..W {
            let block = hash(k * 7919 + (y / 16) as u64 * 131 + (x / 16) as u64) as usize;
            let mut rgb = PALETTE[block % PALETTE.len()];
            if let Some((rx, ry, rw, rh)) = rect
                && x >= rx
                && x < rx + rw
                && y >= ry
                && y < ry + rh
            {
                // Lit upper half, shaded lower half: same hue, different value.
                rgb = if y < ry + rh / 2 {
                    [210, 35, 40]
                } else {
                    [120, 20, 25]
                };
            }
            let n = hash((k << 40) ^ ((y as u64) << 20) ^ x as u64);
            for (c, v) in rgb.iter_mut().enumerate() {
                let d = ((n >> (8 * c)) % 21) as i32 - 10;
                *v = (*v as i32 + d).clamp(0, 255) as u8;
            }
            data.extend_from_slice(&rgb);
        }
    }
    data
}

fn png(data: &[u8]) -> Vec<u8> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(data, W, H, image::ExtendedColorType::Rgb8)
        .unwrap();
    out
}

enum Kind {
    Object(u32, u32, u32, u32),
    Background,
    Unlabelled,
}

fn write_session(path: &Path, seed: u64, frames: &[Kind]) -> Vec<i64> {
    let mut w = SessionWriter::create(path).unwrap();
    let mut stamps = Vec::new();
    for (k, kind) in frames.iter().enumerate() {
        let stamp = T0_NS + k as i64 * PERIOD_NS;
        stamps.push(stamp);
        let rect = match kind {
            Kind::Object(x, y, w, h) => Some((*x, *y, *w, *h)),
            _ => None,
        };
        let data = png(&render(seed * 1000 + k as u64, rect));
        write_frame(&mut w, stamp, data, rect, !matches!(kind, Kind::Unlabelled));
    }
    w.finish().unwrap();
    stamps
}

/// One PNG frame at `stamp` and, when `labelled`, its label: the rectangle `rect` (x, y,
/// width, height), or none (a background frame).
fn write_frame(
    w: &mut SessionWriter,
    stamp: i64,
    png: Vec<u8>,
    rect: Option<(u32, u32, u32, u32)>,
    labelled: bool,
) {
    let img = CompressedImage {
        header: Header::new(stamp, "camera_optical_frame"),
        format: "png".into(),
        data: png,
    };
    w.write("/camera/image/compressed", stamp, &img).unwrap();
    if labelled {
        let regions = rect
            .map(|(x, y, wd, ht)| RegionOfInterest {
                x_offset: x,
                y_offset: y,
                height: ht,
                width: wd,
                do_rectify: false,
            })
            .into_iter()
            .collect();
        let label = ObjectLabel {
            header: Header::new(stamp, "camera_optical_frame"),
            object: "box".into(),
            regions,
        };
        w.write("/labels", stamp, &label).unwrap();
    }
}

fn train_session(dir: &Path) -> PathBuf {
    let p = dir.join("train.mcap");
    let mut frames = Vec::new();
    for k in 0..12u32 {
        frames.push(Kind::Object(
            20 + k * 17,
            30 + k * 11,
            30 + k % 4 * 6,
            40 + k % 3 * 8,
        ));
    }
    for _ in 0..6 {
        frames.push(Kind::Background);
    }
    frames.push(Kind::Unlabelled);
    write_session(&p, 1, &frames);
    p
}

fn read_npy_header(path: &Path) -> (String, usize) {
    let b = std::fs::read(path).unwrap();
    let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
    (
        String::from_utf8_lossy(&b[10..10 + hlen]).into_owned(),
        b.len() - 10 - hlen,
    )
}

#[test]
fn train_then_predict_finds_the_box() {
    let dir = tempfile::tempdir().unwrap();
    let train = train_session(dir.path());
    let model = dir.path().join("model.json");
    let feats = dir.path().join("feats");
    let out = objloc(
        &[
            "train",
            p(&train),
            "-o",
            p(&model),
            "--export-features",
            p(&feats),
        ],
        &[],
    );
    let text = ok(&out);
    // No Rerun flag: the recording is saved beside the model.
    assert!(model.with_extension("rrd").exists());
    assert!(text.contains("before pruning"), "{text}");
    assert!(text.contains("fraction of pixels in bin"), "{text}");

    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    // A capture's tile head is a forest of 16 trees (version 3): the tree and 15 more.
    assert_eq!(m["version"], 3);
    assert_eq!(m["trees"].as_array().unwrap().len(), 15);
    assert_eq!(m["metadata"]["forest"]["trees"], 16);
    assert_eq!(m["metadata"]["forest"]["sample_fraction"], 0.5);
    assert!(text.contains("forest of 16 trees, each grown on 50 % of the training tiles, splitting on 19 of 330 features"), "{text}");
    // The region head: hsv, the 5 x 5 tiles around, shifted grids every 2 px.
    assert_eq!(m["region"]["features"], "hsv");
    assert_eq!(m["region"]["context_tiles"], 2);
    assert_eq!(m["region"]["tree"]["n_features"], 512);
    assert_eq!(m["region"]["metadata"]["train_stride_px"], 2);
    assert!(m["region"].get("region").is_none());
    assert!(m["region"].get("trees").is_none());
    assert!(text.contains("region head"), "{text}");
    // The session has no /cmd_vel, as a posed capture: the capture's channels and light
    // variants, said on stdout.
    assert!(
        text.contains("features rgb332+hs, augment light, tile 8 px, train stride 4 px, 16 trees (a training session has no /cmd_vel"),
        "{text}"
    );
    assert_eq!(m["features"], "rgb332+hs");
    assert_eq!(m["metadata"]["augment"], "light");
    assert_eq!(m["tile_px"], 8);
    let meta = &m["metadata"];
    // 18 labelled frames x 30 rows x 32 cols = 17280 aligned tiles, in thirds of 5760.
    assert_eq!(meta["examples"]["labelled_frames"], 18);
    assert_eq!(meta["examples"]["test"]["examples"], 5760);
    assert_eq!(meta["examples"]["prune"]["examples"], 5760);
    // Stride 4: 3 shifted grids per frame, each (29 or 30) x (31 or 32) whole tiles:
    // (30*31 + 29*32 + 29*31) * 18 = (930 + 928 + 899) * 18 = 49626.
    assert_eq!(meta["examples"]["train_shifted"]["examples"], 49626);
    assert_eq!(meta["examples"]["train"]["examples"], 5760 + 49626);
    let hash = meta["sessions"][0]["sha256"].as_str().unwrap();
    assert_eq!(hash, sha256_hex(&std::fs::read(&train).unwrap()));
    let auc = meta["test_metrics"]["roc_auc"].as_f64().unwrap();
    assert!(auc > 0.97, "test AUC {auc}");
    let base = m["base_rate"].as_f64().unwrap();
    assert!(base > 0.005 && base < 0.05, "base rate {base}");

    // Exported examples: every example, 256 rgb332 + 74 hs float32 features each.
    let n_examples = 5760 * 3 + 49626;
    let (hx, bytes) = read_npy_header(&feats.join("X.npy"));
    assert!(
        hx.contains(&format!("'shape': ({n_examples}, 330)")),
        "{hx}"
    );
    assert_eq!(bytes, n_examples * 330 * 4);
    let (hs, _) = read_npy_header(&feats.join("split.npy"));
    assert!(hs.contains("'|u1'"), "{hs}");

    // A new session with the box elsewhere and at other sizes.
    let tour = dir.path().join("tour.mcap");
    let stamps = write_session(
        &tour,
        2,
        &[
            Kind::Object(100, 40, 40, 60),
            Kind::Object(10, 150, 36, 48),
            Kind::Background,
            Kind::Unlabelled,
        ],
    );
    let pred = dir.path().join("pred");
    // An earlier run's heatmap of a fifth frame (and a file of the user's): the first goes,
    // the second stays.
    std::fs::create_dir_all(&pred).unwrap();
    std::fs::write(pred.join("heatmap_00004.png"), b"stale").unwrap();
    std::fs::write(pred.join("notes.txt"), b"mine").unwrap();
    let text = ok(&objloc(
        &[
            "predict",
            p(&tour),
            "--model",
            p(&model),
            "--out",
            p(&pred),
            "--heatmaps",
            "--no-rerun",
        ],
        &[],
    ));
    assert!(
        !pred.join("predict.rrd").exists(),
        "--no-rerun wrote an .rrd"
    );
    assert!(pred.join("heatmap_00003.png").exists() && !pred.join("heatmap_00004.png").exists());
    assert_eq!(std::fs::read(pred.join("notes.txt")).unwrap(), b"mine");
    let auc = printed_auc(&text);
    assert!(auc > 0.97, "{text}");
    // An object asked for that no label names is refused, as train and eval refuse it.
    let line = one_line_error(&objloc(
        &[
            "predict",
            p(&tour),
            "--model",
            p(&model),
            "--out",
            p(&dir.path().join("pear")),
            "--object",
            "pear",
            "--no-rerun",
        ],
        &[],
    ));
    assert!(line.contains("names object \"pear\""), "{line}");
    // 3 labelled frames x 960 tiles. Positives: box 1 (x 100..140, y 40..100) holds cols
    // 13..=16 and rows 5..=11 whole: 4 x 7 = 28; box 2 (x 10..46, y 150..198) holds cols
    // 2..=4 and rows 19..=23: 3 x 5 = 15; total 43.
    assert!(text.contains("2880 tiles, 43 positive"), "{text}");
    let (probs, data) = objloc_core::io::npy::read_f32(&pred.join("probs.npy")).unwrap();
    assert_eq!(probs, vec![4, 30, 32]);
    let (tile_shape, tile_data) =
        objloc_core::io::npy::read_f32(&pred.join("tile_probs.npy")).unwrap();
    assert_eq!(tile_shape, vec![4, 30, 32]);
    // The two heads are two trees: their maps differ.
    assert_ne!(tile_data, data);
    // labels.npy: int8, 1 inside a rectangle, 0 outside, -1 for the unlabelled frame 3.
    let (hl, data_bytes) = read_npy_header(&pred.join("labels.npy"));
    assert!(hl.contains("'|i1'") && hl.contains("(4, 30, 32)"), "{hl}");
    let raw = std::fs::read(pred.join("labels.npy")).unwrap();
    let labels = &raw[raw.len() - data_bytes..];
    assert_eq!(labels.len(), 4 * 960);
    let count = |frame: usize, v: u8| {
        labels[frame * 960..(frame + 1) * 960]
            .iter()
            .filter(|&&l| l == v)
            .count()
    };
    assert_eq!(count(0, 1) + count(1, 1) + count(2, 1), 43);
    assert_eq!((count(2, 1), count(3, 0xff)), (0, 960));
    assert_eq!(labels[6 * 32 + 14], 1);
    // Tile (row 6, col 14) is inside box 1 of frame 0; tile (0, 0) is background.
    assert!(data[6 * 32 + 14] > 0.5, "{}", data[6 * 32 + 14]);
    assert!(data[0] < 0.05, "{}", data[0]);
    let (hs, bytes) = read_npy_header(&pred.join("stamps.npy"));
    assert!(hs.contains("'<i8'") && hs.contains("(4,)"), "{hs}");
    let raw = std::fs::read(pred.join("stamps.npy")).unwrap();
    let last = i64::from_le_bytes(raw[raw.len() - 8..].try_into().unwrap());
    assert_eq!((bytes, last), (32, stamps[3]));
    assert!(pred.join("heatmap_00003.png").exists());
}

#[test]
fn model_is_identical_for_any_thread_count_and_stride_one_grid_has_no_shifted_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let train = train_session(dir.path());
    let mut bytes = Vec::new();
    for threads in ["1", "2"] {
        let model = dir.path().join(format!("m{threads}.json"));
        ok(&objloc(
            &[
                "train",
                p(&train),
                "-o",
                p(&model),
                "--features",
                "rgb332",
                "--train-stride",
                "8",
                "--seed",
                "3",
            ],
            &[("RAYON_NUM_THREADS", threads)],
        ));
        bytes.push(std::fs::read(&model).unwrap());
    }
    assert_eq!(bytes[0], bytes[1]);
    let m: serde_json::Value = serde_json::from_slice(&bytes[0]).unwrap();
    // A capture's forest: its trees grown in parallel, the same bytes on 1 and 2 threads.
    assert_eq!(m["trees"].as_array().unwrap().len(), 15);
    assert_eq!(m["features"], "rgb332");
    assert_eq!(m["metadata"]["seed"], 3);
    assert_eq!(m["metadata"]["examples"]["train_shifted"]["examples"], 0);
    assert_eq!(m["metadata"]["examples"]["train"]["examples"], 5760);
}

#[test]
fn bad_inputs_fail_with_one_line_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.json");
    // Missing session file.
    let missing = dir.path().join("nope.mcap");
    let out = objloc(&["train", p(&missing), "-o", p(&model)], &[]);
    let line = one_line_error(&out);
    assert!(line.contains("nope.mcap"), "{line}");
    assert!(!model.exists());

    // Tree and feature options out of range, refused before any work as usage errors.
    for (flag, value, expect) in [
        ("--context-tiles", "9", "--context-tiles 9 is over 4"),
        (
            "--region-context-tiles",
            "0",
            "--region-context-tiles 0 must be in 1..=4",
        ),
        (
            "--region-stride",
            "9",
            "--region-stride 9 px must be 1 to the tile size 8 px",
        ),
        ("--base-mix", "1.5", "--base-mix 1.5 must be in [0, 1)"),
        ("--trees", "0", "--trees 0 must be 1 to 256"),
        (
            "--tree-sample-fraction",
            "1.5",
            "--tree-sample-fraction 1.5 must be in (0, 1]",
        ),
        (
            "--split-features",
            "0",
            "--split-features 0: a node needs at least one feature to split on",
        ),
        ("--tile", "0", "--tile 0 px is outside 2..=128 px"),
        (
            "--train-stride",
            "0",
            "--train-stride 0 px must be 1 to the tile size 8 px",
        ),
        (
            "--m-estimate",
            "0",
            "--m-estimate 0 must be a positive number",
        ),
        // Light variants need shifted grids: at stride 8 (the tile) there are none.
        (
            "--train-stride",
            "8",
            "--augment light varies the shifted training grids, and --train-stride 8 px at tile 8 px makes none; use a stride below the tile size",
        ),
    ] {
        let augment: &[&str] = if flag == "--train-stride" {
            &["--augment", "light"]
        } else {
            &[]
        };
        let session = unread_session(dir.path());
        let mut args = vec!["train", p(&session), "-o", p(&model), flag, value];
        args.extend_from_slice(augment);
        let out = objloc(&args, &[]);
        assert_eq!(usage_error(&out), format!("error: {expect}"));
        assert!(!model.exists());
    }

    // A forest's option on a single tree would change nothing: refused once the sessions
    // are read (a capture's default is a forest), with nothing written.
    let one_tree = train_session(dir.path());
    let out = objloc(
        &[
            "train",
            p(&one_tree),
            "-o",
            p(&model),
            "--trees",
            "1",
            "--split-features",
            "8",
        ],
        &[],
    );
    assert_eq!(
        usage_error(&out),
        "error: --split-features randomises a forest's trees, and this model is one tree: add --trees N (N >= 2)"
    );
    assert!(!model.exists());

    // A session whose frames carry no label at all.
    let unlabelled = dir.path().join("unlabelled.mcap");
    write_session(&unlabelled, 3, &[Kind::Unlabelled, Kind::Unlabelled]);
    let out = objloc(&["train", p(&unlabelled), "-o", p(&model)], &[]);
    let line = one_line_error(&out);
    assert!(line.contains("no labelled frames"), "{line}");
    assert!(!model.exists());

    // Only background frames: no positive tile to learn from. Training tiles: a third of
    // 2 x 960 aligned plus 2 x 2757 shifted = 640 + 5514.
    let bg = dir.path().join("bg.mcap");
    write_session(&bg, 4, &[Kind::Background, Kind::Background]);
    let out = objloc(&["train", p(&bg), "-o", p(&model)], &[]);
    let line = one_line_error(&out);
    assert!(
        line.contains("none of the 6154 training tiles is positive"),
        "{line}"
    );

    // Models of another version or feature spec are refused, naming the file (the paper's
    // channels, which the edits below name).
    let train = train_session(dir.path());
    ok(&objloc(
        &[
            "train",
            p(&train),
            "-o",
            p(&model),
            "--features",
            "rgb332",
            "--trees",
            "1",
        ],
        &[],
    ));
    let text = std::fs::read_to_string(&model).unwrap();
    let forest = dir.path().join("forest.json");
    ok(&objloc(
        &[
            "train",
            p(&train),
            "-o",
            p(&forest),
            "--features",
            "rgb332",
            "--trees",
            "3",
            "--no-region",
        ],
        &[],
    ));
    let forest_text = std::fs::read_to_string(&forest).unwrap();
    let cases = [
        (
            "v4.json",
            "\"version\": 2",
            "\"version\": 4",
            "model version 4 is not supported (this objloc reads versions 2 and 3)",
        ),
        (
            "feat.json",
            "\"features\": \"rgb332\"",
            "\"features\": \"lab\"",
            "feature spec \"lab\" is not known",
        ),
        (
            "tile.json",
            "\"tile_px\": 8",
            "\"tile_px\": 0",
            "tile size 0 px",
        ),
        (
            // A tree of tile histograms read as if it also wanted neighbourhood ones.
            "ctx.json",
            "\"context_tiles\": 0",
            "\"context_tiles\": 1",
            "tree 0 has 256 features but feature spec \"rgb332\" (context 1 tiles) has 512",
        ),
        (
            // The region head's maps must line up with the tile head's.
            "rtile.json",
            "\"features\": \"hsv\",\n    \"tile_px\": 8",
            "\"features\": \"hsv\",\n    \"tile_px\": 16",
            "region head: tile size 16 px differs from the model's 8 px",
        ),
        (
            "one-v3.json",
            "\"version\": 2",
            "\"version\": 3",
            "version 3 is a forest's, but the model holds one tree",
        ),
        (
            // A forest written as version 2, which an objloc before forests would have read
            // as its first tree alone.
            "forest-v2.json",
            "\"version\": 3",
            "\"version\": 2",
            "version 2 is a single tree's, but the model holds 2 more",
        ),
    ];
    for (name, from, to, expect) in cases {
        let source = if name.starts_with("forest") {
            &forest_text
        } else {
            &text
        };
        assert!(source.contains(from), "{name}");
        let bad = dir.path().join(name);
        std::fs::write(&bad, source.replacen(from, to, 1)).unwrap();
        let out_dir = dir.path().join("out");
        let out = objloc(
            &[
                "predict",
                p(&train),
                "--model",
                p(&bad),
                "--out",
                p(&out_dir),
            ],
            &[],
        );
        let line = one_line_error(&out);
        assert!(line.contains(name) && line.contains(expect), "{line}");
        assert!(!out_dir.exists());
    }
    // A fuse report given as the model is named as what it is (it was told to retrain).
    let report = dir.path().join("r.json");
    std::fs::write(&report, "{\"report_version\": 5, \"objects\": []}").unwrap();
    let out_dir = dir.path().join("out");
    let line = one_line_error(&objloc(
        &[
            "predict",
            p(&train),
            "--model",
            p(&report),
            "--out",
            p(&out_dir),
        ],
        &[],
    ));
    assert!(line.contains("is a fuse report, not a model"), "{line}");
}

#[test]
fn channels_and_light_augmentation_train_save_load_and_predict() {
    let dir = tempfile::tempdir().unwrap();
    let train = train_session(dir.path());
    let model = dir.path().join("m.json");
    // Channel names in any order are stored in the fixed order.
    let text = ok(&objloc(
        &[
            "train",
            p(&train),
            "-o",
            p(&model),
            "--features",
            "texture+rgb332+hs",
            "--augment",
            "light",
            "--no-region",
            "--no-rerun",
        ],
        &[],
    ));
    assert!(text.contains("features rgb332+hs+texture"), "{text}");
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert_eq!(m["features"], "rgb332+hs+texture");
    // 256 colour bins, 74 hue-saturation bins, 46 texture bins.
    assert_eq!(m["tree"]["n_features"], 376);
    assert_eq!(m["metadata"]["augment"], "light");
    // The same shifted-grid tiles as without augmentation: only their frames' light differs.
    assert_eq!(
        m["metadata"]["examples"]["train_shifted"]["examples"],
        49626
    );
    let tour = dir.path().join("tour.mcap");
    write_session(
        &tour,
        2,
        &[Kind::Object(100, 40, 40, 60), Kind::Object(10, 150, 36, 48)],
    );
    let out = dir.path().join("pred");
    let text = ok(&objloc(
        &[
            "predict",
            p(&tour),
            "--model",
            p(&model),
            "--out",
            p(&out),
            "--no-rerun",
        ],
        &[],
    ));
    let auc = printed_auc(&text);
    assert!(auc > 0.97, "{text}");
    // A spec that names an unknown or repeated channel is a command-line error.
    for bad in ["rgb332+lab", "hs+hs"] {
        let out = objloc(
            &["train", p(&train), "-o", p(&model), "--features", bad],
            &[],
        );
        assert_eq!(out.status.code(), Some(2), "{bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(&format!("feature spec \"{bad}\" is not known")),
            "{err}"
        );
    }
    // A file whose spec and tree disagree is refused, naming both.
    let text = std::fs::read_to_string(&model).unwrap();
    let bad = dir.path().join("bad.json");
    std::fs::write(
        &bad,
        text.replacen(
            "\"features\": \"rgb332+hs+texture\"",
            "\"features\": \"rgb332+texture\"",
            1,
        ),
    )
    .unwrap();
    let out = objloc(
        &[
            "predict",
            p(&tour),
            "--model",
            p(&bad),
            "--out",
            p(&out),
            "--no-rerun",
        ],
        &[],
    );
    let line = one_line_error(&out);
    assert!(
        line.contains(
            "tree 0 has 376 features but feature spec \"rgb332+texture\" (context 0 tiles) has 302"
        ),
        "{line}"
    );
}

fn printed_auc(text: &str) -> f64 {
    text.rsplit("tile ROC AUC ")
        .next()
        .filter(|_| text.contains("tile ROC AUC "))
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no AUC in {text}"))
}

/// The AUC of the tile head (tile_probs.npy) that `predict` prints before probs.npy's.
fn printed_tile_head_auc(text: &str) -> f64 {
    text.split("tile head (tile_probs.npy, the fuser's evidence): tile ROC AUC ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no tile head AUC in {text}"))
}

#[test]
fn the_region_head_meets_the_tour_auc_target_the_tile_head_cannot() {
    // The chair's rectangles hold the background seen through it; the tile alone cannot
    // tell it from the same background elsewhere, its neighbourhood can (docs/tree.md).
    // Issue #4's target: tile AUC >= 0.95 on the shipped tours, default options.
    let dir = tempfile::tempdir().unwrap();
    let root = repo_dir();
    let rec = |name: &str| root.join("recordings").join(name);
    let mut aucs = Vec::new();
    for (train, tours) in [
        (
            "chair-train.mcap",
            &[
                "chair-tour.mcap",
                "two-chairs-tour.mcap",
                "chair-tour-drift.mcap",
            ][..],
        ),
        ("bottle-train.mcap", &["bottle-tour.mcap"][..]),
    ] {
        let model = dir.path().join(train.replace(".mcap", ".json"));
        ok(&objloc(
            &["train", p(&rec(train)), "-o", p(&model), "--no-rerun"],
            &[],
        ));
        for tour in tours {
            let text = ok(&objloc(
                &[
                    "predict",
                    p(&rec(tour)),
                    "--model",
                    p(&model),
                    "--out",
                    p(&dir.path().join(tour)),
                    "--no-rerun",
                ],
                &[],
            ));
            aucs.push((*tour, printed_tile_head_auc(&text), printed_auc(&text)));
        }
    }
    // Measured (tile head, region head): chair 0.900, 0.982; two chairs 0.900, 0.960; drift
    // 0.874, 0.971; bottle 0.999, 0.9995.
    for &(tour, tile, region) in &aucs {
        assert!(region >= 0.95, "{tour}: {aucs:?}");
        if tour != "bottle-tour.mcap" {
            assert!(tile < 0.92, "{tour}: {aucs:?}");
        }
    }
}

/// A session path for option checks that fail before any session is read.
fn unread_session(dir: &Path) -> PathBuf {
    dir.join("never-read.mcap")
}

/// A capture's tiles grow with its frames: two 900 x 900 frames (shorter side past 880 px),
/// a red box on grey in one and grey alone in the other, train in 16 px tiles with 8 px
/// shifts, said on stdout and stored in the model; `--tile` keeps the tile and the 4 px
/// stride.
#[test]
fn a_large_captures_tiles_grow_with_its_frames() {
    use image::ImageEncoder;
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("large.mcap");
    let side = 900u32;
    let mut w = SessionWriter::create(&session).unwrap();
    for (k, rect) in [Some((300u32, 250u32, 240u32, 320u32)), None]
        .into_iter()
        .enumerate()
    {
        let stamp = T0_NS + k as i64 * PERIOD_NS;
        let mut data = Vec::with_capacity((side * side * 3) as usize);
        for y in 0..side {
            for x in 0..side {
                let inside = rect.is_some_and(|(rx, ry, rw, rh)| {
                    (rx..rx + rw).contains(&x) && (ry..ry + rh).contains(&y)
                });
                data.extend_from_slice(if inside {
                    &[200, 40, 30]
                } else {
                    &[120, 120, 120]
                });
            }
        }
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&data, side, side, image::ExtendedColorType::Rgb8)
            .unwrap();
        write_frame(&mut w, stamp, png, rect, true);
    }
    w.finish().unwrap();
    let model = dir.path().join("m.json");
    let text = ok(&objloc(
        &["train", p(&session), "-o", p(&model), "--no-rerun"],
        &[],
    ));
    assert!(
        text.contains(
            "tile 16 px, train stride 8 px, 16 trees (a training session has no /cmd_vel"
        ) && text.contains("its frames 900 px on the shorter side"),
        "{text}"
    );
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert_eq!(m["tile_px"], 16);
    assert_eq!(m["metadata"]["train_stride_px"], 8);
    ok(&objloc(
        &[
            "train",
            p(&session),
            "-o",
            p(&model),
            "--no-rerun",
            "--tile",
            "12",
        ],
        &[],
    ));
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert_eq!(m["tile_px"], 12);
    assert_eq!(m["metadata"]["train_stride_px"], 4);
}
