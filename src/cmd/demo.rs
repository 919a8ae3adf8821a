//! `objloc demo`: the README's first command. Trains on the shipped chair training session,
//! fuses the chair tour, prints the located chair and its error against ground truth, and
//! writes the model, report and grid under `out/demo/`; then fuses the drift tour with and
//! without pose refinement and compares the two.

use super::{say, say_part};

use std::path::{Path, PathBuf};

use anyhow::Context;

use objloc_core::learn::dataset::load_session;
use objloc_core::learn::training::{TrainConfig, examples, fit_model};
use objloc_core::out::eval::{Evaluation, evaluate, true_objects};

use super::TopicArgs;
use super::fuse::{FuseArgs, Fused, fuse, print_summary, write_outputs};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Labelled session to train on.
    #[arg(long, default_value = "recordings/chair-train.mcap")]
    pub train: PathBuf,
    /// Session to fuse.
    #[arg(long, default_value = "recordings/chair-tour.mcap")]
    pub tour: PathBuf,
    /// Session fused a second time with and without pose refinement (`--no-refine-poses`),
    /// to show drift correction (skipped when it does not exist).
    #[arg(long, default_value = "recordings/chair-tour-drift.mcap")]
    pub drift_tour: PathBuf,
    /// Where the model, report and grid go.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    #[command(flatten)]
    pub fuse: FuseArgs,
    #[command(flatten)]
    pub topics: TopicArgs,
    #[command(flatten)]
    pub rerun: crate::viz::VizArgs,
}

/// A shipped recording, found from the working directory or, failing that, the source tree
/// (so the demo also runs from elsewhere).
fn locate(p: &Path) -> PathBuf {
    if p.exists() || p.is_absolute() {
        return p.to_owned();
    }
    let in_tree = Path::new(env!("CARGO_MANIFEST_DIR")).join(p);
    if in_tree.exists() {
        in_tree
    } else {
        p.to_owned()
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let train_path = locate(&args.train);
    let tour_path = locate(&args.tour);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let topics = args.topics.topics()?;

    say!("== training on {}", train_path.display());
    let cfg = TrainConfig::default();
    let session = load_session(&train_path, topics.clone(), None, true)
        .with_context(|| format!("demo: reading {}", train_path.display()))?;
    let sessions = [session];
    let set = examples(&sessions, &cfg).context("demo: building examples")?;
    let model = fit_model(&sessions, &set, &cfg).context("demo: fitting the tree")?;
    let model_path = args.out.join("chair-model.json");
    model.save(&model_path).context("demo: writing the model")?;
    say_part!("{}", model.summary_table());

    say!("== fusing {}", tour_path.display());
    let report_path = args.out.join("report.json");
    let mut f = fuse(
        &tour_path,
        &model_path,
        &args.fuse,
        &args.topics,
        &args.rerun,
        &crate::viz::rrd_beside(&report_path),
    )
    .context("demo: fuse")?;
    let grid_path = args.out.join("grid.npy");
    write_outputs(&mut f, Some(&report_path), Some(&grid_path))?;
    print_summary(&f);

    if let Some(e) = evaluation(&f, &report_path) {
        say!("== against ground truth");
        for m in &e.matches {
            say!("{}", m.describe());
        }
        for n in &e.missed {
            say!("{n}: not found");
        }
        if !e.spurious.is_empty() {
            say!("{} spurious object(s)", e.spurious.len());
        }
        let errs: Vec<String> = e
            .per_frame
            .iter()
            .map(|f| {
                f.mean_error_m
                    .map(|x| format!("{x:.3}"))
                    .unwrap_or_else(|| "-".into())
            })
            .collect();
        say!("error after each frame (m): {}", errs.join(" "));
        if let Some(t) = &e.trajectory {
            if f.report.options.refine_poses {
                say!(
                    "trajectory: /odom ATE {:.3} m over {} frames (max {:.3} m), refined {:.3} m",
                    t.odometry_ate_m,
                    t.frames,
                    t.odometry_max_m,
                    t.fused_ate_m
                );
            } else {
                say!(
                    "odometry drift: ATE {:.3} m over {} frames (max {:.3} m): what limits the error above",
                    t.odometry_ate_m,
                    t.frames,
                    t.odometry_max_m
                );
            }
        }
    }
    say!(
        "wrote {}, {}, {}",
        model_path.display(),
        report_path.display(),
        grid_path.display()
    );

    let drift_path = locate(&args.drift_tour);
    if drift_path.exists() {
        drift(&args, &drift_path, &model_path)?;
    }
    Ok(())
}

/// The drift tour's robot noise (5 % of 0.3 m/s driving, 3 % of 0.5 rad/s turning), which
/// pose refinement needs as its motion model.
const DRIFT_SIGMA_V_MPS: f64 = 0.015;
const DRIFT_SIGMA_W_RADPS: f64 = 0.015;

/// Fuses the drift tour with odometry alone and with refined poses, and compares them.
fn drift(args: &Args, path: &Path, model_path: &Path) -> anyhow::Result<()> {
    say!(
        "== fusing {} (speed noise 5 %/3 %) with --no-refine-poses and with pose refinement",
        path.display()
    );
    let mut rows = Vec::new();
    for refine in [false, true] {
        let name = if refine {
            "drift-refined"
        } else {
            "drift-odometry"
        };
        let report_path = args.out.join(format!("{name}.json"));
        let fuse_args = FuseArgs {
            refine_poses: refine,
            no_refine_poses: !refine,
            sigma_v: DRIFT_SIGMA_V_MPS,
            sigma_w: DRIFT_SIGMA_W_RADPS,
            ..args.fuse.clone()
        };
        let mut f = fuse(
            path,
            model_path,
            &fuse_args,
            &args.topics,
            &args.rerun,
            &crate::viz::rrd_beside(&report_path),
        )
        .with_context(|| format!("demo: fuse {name}"))?;
        write_outputs(&mut f, Some(&report_path), None)?;
        if let Some(e) = evaluation(&f, &report_path) {
            rows.push((name, e));
        }
    }
    say!(
        "  {:<16} {:>8} {:>9} {:>10} {:>9}",
        "poses",
        "objects",
        "max err",
        "odom ATE",
        "ATE"
    );
    let metres = |x: Option<f64>| x.map(|x| format!("{x:.3} m")).unwrap_or_else(|| "-".into());
    for (name, e) in &rows {
        say!(
            "  {:<16} {:>8} {:>9} {:>10} {:>9}",
            name,
            e.matches.len() + e.spurious.len(),
            metres(e.max_error_m()),
            metres(e.trajectory.as_ref().map(|t| t.odometry_ate_m)),
            metres(e.trajectory.as_ref().map(|t| t.fused_ate_m)),
        );
    }
    say!(
        "wrote {} and {}",
        args.out.join("drift-odometry.json").display(),
        args.out.join("drift-refined.json").display()
    );
    Ok(())
}

/// The fuse scored against the session's ground truth, when it has some.
fn evaluation(f: &Fused, report_path: &Path) -> Option<Evaluation> {
    let gt = f.outcome.data.ground_truth.as_ref()?;
    let truth = true_objects(gt);
    Some(evaluate(
        &report_path.display().to_string(),
        &f.report,
        &truth,
        &f.outcome.data.ground_truth_poses,
    ))
}
