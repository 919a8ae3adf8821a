//! Benchmark of the training step and per-frame prediction: `cargo bench --bench train`.
//! Uses recordings/chair-train.mcap when it exists, otherwise 21 synthetic 256x240 frames
//! (3 with a labelled red box, 18 background), and prints medians.
//!
//! Invariants: the synthetic frames are a fixed function of pixel coordinates, so every run
//! times the same work.

// A benchmark may unwrap and expect: a failure ends the run with its message.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::path::Path;
use std::time::{Duration, Instant};

use objloc_core::io::msgs::RegionOfInterest;
use objloc_core::io::session::Topics;
use objloc_core::learn::dataset::{LoadedSession, SessionFrame, load_session};
use objloc_core::learn::features::FeatureSpec;
use objloc_core::learn::training::{TrainConfig, examples, fit_model};
use objloc_core::types::image::Rgb8;

const RUNS: usize = 15;

fn hash(mut x: u64) -> u64 {
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn synthetic() -> LoadedSession {
    let (w, h) = (256u32, 240u32);
    let palette = [
        [60u8, 130, 60],
        [120, 120, 120],
        [70, 90, 170],
        [140, 100, 60],
    ];
    let frames = (0..21u64)
        .map(|k| {
            let rect = (k < 3).then_some((40 + 50 * k as u32, 60, 48, 80));
            let mut data = Vec::with_capacity((w * h * 3) as usize);
            for y in 0..h {
                for x in 0..w {
                    let block = hash(k * 7919 + (y / 16) as u64 * 131 + (x / 16) as u64);
                    let mut rgb = palette[block as usize % palette.len()];
                    if let Some((rx, ry, rw, rh)) = rect
                        && (rx..rx + rw).contains(&x)
                        && (ry..ry + rh).contains(&y)
                    {
                        rgb = [200, 30, 40];
                    }
                    let n = hash((k << 40) ^ ((y as u64) << 20) ^ x as u64);
                    for (c, v) in rgb.iter_mut().enumerate() {
                        *v = (*v as i32 + ((n >> (8 * c)) % 21) as i32 - 10).clamp(0, 255) as u8;
                    }
                    data.extend_from_slice(&rgb);
                }
            }
            SessionFrame {
                stamp_ns: k as i64,
                log_time_ns: k,
                image: Rgb8 {
                    width: w,
                    height: h,
                    data,
                },
                regions: Some(
                    rect.map(|(x, y, rw, rh)| RegionOfInterest {
                        x_offset: x,
                        y_offset: y,
                        height: rh,
                        width: rw,
                        do_rectify: false,
                    })
                    .into_iter()
                    .collect(),
                ),
                unsure: Vec::new(),
            }
        })
        .collect();
    LoadedSession {
        path: "synthetic".into(),
        sha256: String::new(),
        frames,
        label_objects: ["object".to_owned()].into(),
        commands: 0,
        warnings: Vec::new(),
    }
}

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn main() {
    let path = Path::new("recordings/chair-train.mcap");
    let session = if path.exists() {
        match load_session(path, Topics::default(), None, true) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(1);
            }
        }
    } else {
        synthetic()
    };
    let sessions = vec![session];
    let labelled = sessions[0].frames.len();
    let default = TrainConfig::default();
    let Some(region) = default.region_config() else {
        eprintln!("error: the default configuration has no region head");
        std::process::exit(1);
    };
    // The tile head with either quantisation, then the default model's region head; a default
    // `objloc train` fits the rgb332 tile head and the region head.
    let heads = [
        (
            "tile head, hsv",
            TrainConfig {
                features: FeatureSpec::HSV,
                ..default.clone()
            },
        ),
        ("tile head, rgb332 (default)", default.clone()),
        (
            "region head (default: hsv + 2 tiles around, stride 2)",
            region,
        ),
    ];
    let mut default_total = 0.0;
    for (name, cfg) in heads {
        let (mut t_ex, mut t_fit, mut t_pred) = (Vec::new(), Vec::new(), Vec::new());
        let mut summary = String::new();
        for _ in 0..RUNS {
            let t0 = Instant::now();
            let set = match examples(&sessions, &cfg) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("error: {e}");
                    std::process::exit(1);
                }
            };
            t_ex.push(t0.elapsed());
            let t1 = Instant::now();
            let model = match fit_model(&sessions, &set, &cfg) {
                Ok(m) => m,
                Err(e) => {
                    eprintln!("error: {e}");
                    std::process::exit(1);
                }
            };
            t_fit.push(t1.elapsed());
            let frame = &sessions[0].frames[0].image;
            let t2 = Instant::now();
            let map = std::hint::black_box(model.predict(std::hint::black_box(frame)));
            t_pred.push(t2.elapsed());
            summary = format!(
                "{} examples, {} nodes, {} tiles per frame",
                set.examples.len(),
                model.tree.nodes.len(),
                map.p.len()
            );
        }
        let (ex, fit, pred) = (median(t_ex), median(t_fit), median(t_pred));
        if name != "tile head, hsv" {
            default_total += ex + fit;
        }
        println!(
            "{name} ({labelled} labelled frames of {}, {summary}): median of {RUNS}: examples {ex:.1} ms, fit {fit:.1} ms, train total {:.1} ms; predict {pred:.3} ms/frame",
            if path.exists() {
                path.display().to_string()
            } else {
                "synthetic".into()
            },
            ex + fit
        );
    }
    println!(
        "default model (rgb332 tile head + region head): train total {default_total:.1} ms (sum of the medians)"
    );
    predict_at_camera_resolution(&sessions);
}

/// The tile head of each feature spec trained on the session, then timed on one 1080 x 1920
/// frame (the session's first frame scaled up by pixel repetition, so it holds the same
/// colours and edges): what a phone frame costs to classify, single-threaded.
fn predict_at_camera_resolution(sessions: &[LoadedSession]) {
    let src = &sessions[0].frames[0].image;
    let (w, h) = (1080u32, 1920u32);
    let mut data = Vec::with_capacity((w * h * 3) as usize);
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = (x * src.width / w, y * src.height / h);
            let i = ((sy * src.width + sx) * 3) as usize;
            data.extend_from_slice(&src.data[i..i + 3]);
        }
    }
    let frame = Rgb8 {
        width: w,
        height: h,
        data,
    };
    for spec in [
        "rgb332",
        "hsv",
        "rgb332+hs",
        "rgb332+texture",
        "rgb332+grad",
        "rgb332+hs+texture+grad",
    ] {
        let Ok(features) = spec.parse::<FeatureSpec>() else {
            eprintln!("error: feature spec {spec}");
            std::process::exit(1);
        };
        let cfg = TrainConfig {
            features,
            region: None,
            ..TrainConfig::default()
        };
        let model = match examples(sessions, &cfg) {
            Ok(set) => fit_model(sessions, &set, &cfg),
            Err(e) => Err(e),
        };
        let model = match model {
            Ok(m) => m,
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(1);
            }
        };
        let pool = match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
            Ok(p) => p,
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(1);
            }
        };
        let t: Vec<Duration> = (0..RUNS)
            .map(|_| {
                let t0 = Instant::now();
                pool.install(|| std::hint::black_box(model.predict(std::hint::black_box(&frame))));
                t0.elapsed()
            })
            .collect();
        println!(
            "tile head {spec}: predict a 1080 x 1920 frame {:.1} ms (median of {RUNS}, one thread, {} nodes)",
            median(t),
            model.tree.nodes.len()
        );
    }
}
