//! Soak benchmark (`cargo bench --bench soak`): records a long simulated chair tour
//! (`OBJLOC_SOAK_STOPS` stops, 200 by default) in a temp dir, trains on the shipped
//! chair-train recording, replays the tour through `objloc_core::fuse::replay::replay` with an observer
//! that reads this process's RSS (`/proc/self/status` VmRSS and VmHWM) every 50 frames, and
//! prints frames/s, the peak RSS and the RSS at frame 50, 100, 150, ... so that growth across
//! frames shows.
//!
//! Invariants: the session is the simulator's (seeded), so every run replays the same bytes;
//! the timings are wall clock (this is a benchmark, not part of the replay path).

// A benchmark may unwrap and expect: a failure ends the run with its message.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::path::Path;
use std::time::Instant;

use objloc_core::fuse::grid::Grid;
use objloc_core::fuse::replay::{
    FrameStep, FuseOptions, Observer, ObserverError, SessionData, replay,
};
use objloc_core::io::session::{SessionReader, Topics};
use objloc_core::learn::dataset::load_session;
use objloc_core::learn::training::{TrainConfig, examples, fit_model};
use objloc_core::sim::{Kind, SimOptions, builtin_scene, record};

const EVERY_FRAMES: usize = 50;

/// (VmRSS, VmHWM) of this process in MiB; zeros where /proc is missing.
fn rss_mib() -> (f64, f64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
            .map_or(0.0, |kb| kb / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// RSS after every `EVERY_FRAMES` fused frames: (frames, VmRSS MiB, VmHWM MiB).
#[derive(Default)]
struct RssProbe {
    samples: Vec<(usize, f64, f64)>,
}

impl Observer for RssProbe {
    fn on_frame(
        &mut self,
        _data: &SessionData,
        step: &FrameStep,
        _grid: &Grid,
    ) -> Result<(), ObserverError> {
        let frames = step.index + 1;
        if frames.is_multiple_of(EVERY_FRAMES) {
            let (rss, hwm) = rss_mib();
            self.samples.push((frames, rss, hwm));
        }
        Ok(())
    }
}

fn main() -> anyhow::Result<()> {
    let stops: usize = match std::env::var("OBJLOC_SOAK_STOPS") {
        Ok(v) => v.parse()?,
        Err(_) => 200,
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::temp_dir().join(format!("objloc-soak-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let tour = dir.join("tour.mcap");

    let t = Instant::now();
    let mut opts = SimOptions::new(Kind::Tour, 1);
    opts.stops = stops;
    let stats = record(&builtin_scene("chair")?, &opts, &tour, &mut |_, _| {})?;
    let bytes = std::fs::metadata(&tour)?.len();
    println!(
        "recorded {} frames, {} messages, {:.1} MiB in {:.1} s",
        stats.frames,
        stats.messages,
        bytes as f64 / 1048576.0,
        t.elapsed().as_secs_f64()
    );

    let train = load_session(
        &root.join("recordings/chair-train.mcap"),
        Topics::default(),
        None,
        true,
    )?;
    let cfg = TrainConfig::default();
    let sessions = [train];
    let set = examples(&sessions, &cfg)?;
    let model = fit_model(&sessions, &set, &cfg)?;
    drop(set);
    drop(sessions);

    let (rss0, _) = rss_mib();
    let reader = SessionReader::open(&tour, Topics::default())?;
    let (rss_open, _) = rss_mib();
    let mut probe = RssProbe::default();
    let t = Instant::now();
    let outcome = replay(&reader, &model, &FuseOptions::default(), &mut [&mut probe])?;
    let secs = t.elapsed().as_secs_f64();
    let (rss_end, hwm) = rss_mib();
    let g = &outcome.grid.spec;
    println!(
        "replayed {} of {} frames in {secs:.2} s: {:.1} frames/s (grid {} x {} x {}, {} objects, {} warnings)",
        outcome.frames_fused,
        outcome.data.frames.len(),
        outcome.frames_fused as f64 / secs,
        g.dims[0],
        g.dims[1],
        g.dims[2],
        outcome.objects.len(),
        outcome.warnings.len()
    );
    println!(
        "RSS: {rss0:.1} MiB before opening the session, {rss_open:.1} MiB after (session held in memory: {:.1} MiB file), {rss_end:.1} MiB after the replay; peak (VmHWM) {hwm:.1} MiB",
        bytes as f64 / 1048576.0
    );
    println!("frame   VmRSS MiB   VmHWM MiB");
    for (frames, rss, hwm) in &probe.samples {
        println!("{frames:5}   {rss:9.1}   {hwm:9.1}");
    }
    if let (Some(first), Some(last)) = (probe.samples.first(), probe.samples.last()) {
        println!(
            "RSS change from frame {} to frame {}: {:+.1} MiB",
            first.0,
            last.0,
            last.1 - first.1
        );
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
