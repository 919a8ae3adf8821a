//! Benchmark (not a test): renders and PNG-encodes chair-tour frames as `objloc record sim`
//! does, and prints the median frames per second over several batches.
//!
//! `cargo bench --bench render [-- FRAMES_PER_BATCH BATCHES]`; RAYON_NUM_THREADS sets the cores.

// A benchmark may unwrap and expect: a failure ends the run with its message.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::time::Instant;

use objloc_core::sim::{
    FrameJitter, Kind, Renderer, SimOptions, builtin_scene, iso_from_pose2, plan_stops,
};
use objloc_core::types::image::encode_png;

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let per_batch: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(40);
    let batches: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(7);
    let scene = builtin_scene("chair").expect("built-in scene");
    let mut opts = SimOptions::new(Kind::Tour, 1);
    opts.stops = per_batch;
    let stops = plan_stops(&scene, &opts).expect("stops");
    let renderer = Renderer::new(&scene, None);
    let mount = objloc_core::sim::base_from_optical(&scene);
    let mut fps = Vec::new();
    let mut bytes = 0usize;
    for b in 0..batches {
        let t = Instant::now();
        for (i, s) in stops.iter().enumerate() {
            let jitter = FrameJitter {
                noise_seed: (b * per_batch + i) as u64,
                ..FrameJitter::NEUTRAL
            };
            let r = renderer.render(&(iso_from_pose2(&s.pose) * mount), &jitter);
            bytes += encode_png(r.width, r.height, &r.rgb).expect("png").len();
        }
        fps.push(per_batch as f64 / t.elapsed().as_secs_f64());
    }
    fps.sort_by(f64::total_cmp);
    println!(
        "render+encode 256x240: median {:.1} frames/s (min {:.1}, max {:.1}) over {batches} batches of {per_batch}, {} threads, mean PNG {} bytes",
        fps[fps.len() / 2],
        fps[0],
        fps[fps.len() - 1],
        rayon::current_num_threads(),
        bytes / (batches * per_batch)
    );
}
