//! `objloc eval SESSION --report REPORT.json [--report ...]`: score fuse reports against the
//! session's /ground_truth/objects, side by side; a session without ground truth is scored
//! against its label rectangles ([`objloc_core::out::rects`]).

use super::say;

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use objloc_core::io::session::{IndexScope, SessionMsg, SessionReader};
use objloc_core::out::eval::{Evaluation, evaluate, true_objects};
use objloc_core::out::report::{REPORT_VERSION, Report, file_sha256};

use super::TopicArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The session the reports were fused from (for its ground truth).
    pub session: PathBuf,
    /// A report from `objloc fuse --report`. Repeat to compare several.
    #[arg(long = "report", required = true, value_name = "REPORT.json")]
    pub reports: Vec<PathBuf>,
    /// Print the evaluations as JSON.
    #[arg(long)]
    pub json: bool,
    /// Without ground truth: score against this object's rectangles (default: the object of
    /// the report's model, found where the report names it or beside the report; the only
    /// object on /labels; else every object when the model names none).
    #[arg(long)]
    pub object: Option<String>,
    /// Score reports fused from another session than SESSION (a warning says so): a capture
    /// imported from a simulated session, scored against the original's ground truth. Without
    /// it such a report is refused, since its numbers would mean nothing.
    #[arg(long)]
    pub any_session: bool,
    /// No progress spinner (there is none anyway when stderr is not a terminal).
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub topics: TopicArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let spinner = super::progress::stage_spinner(args.quiet);
    spinner.set_message(format!("reading {}", args.session.display()));
    let result = evaluate_reports(&args);
    spinner.finish_and_clear();
    result
}

fn evaluate_reports(args: &Args) -> anyhow::Result<()> {
    let reader =
        SessionReader::open_scoped(&args.session, args.topics.topics()?, IndexScope::Roles)
            .context("eval")?;
    super::print_warnings(&reader.warnings);
    let mut gt = None;
    let mut poses = Vec::new();
    for m in reader.messages() {
        match m.context("reading ground truth")?.msg {
            SessionMsg::GroundTruthObjects(g) => gt = Some(g),
            SessionMsg::GroundTruthPose(p) => {
                if let Some(iso) = objloc_core::io::msgs::iso_from_pose(&p.pose) {
                    poses.push((p.header.stamp_ns, iso));
                }
            }
            _ => {}
        }
    }
    let track = objloc_core::types::track::PoseTrack::new(poses);
    let session_sha256 =
        file_sha256(&args.session).with_context(|| format!("eval {}", args.session.display()))?;
    let Some(gt) = gt else {
        return super::eval_rects::run(&reader, args, &session_sha256);
    };
    super::usage_check(args.object.is_none(), || {
        format!(
            "--object chooses the label rectangles to score against; {} has ground truth, which scores every object",
            args.session.display()
        )
    })?;
    let truth = true_objects(&gt);
    let mut evals = Vec::new();
    for path in &args.reports {
        let report = read_report_of(path, args, &session_sha256)?;
        evals.push(evaluate(
            &path.display().to_string(),
            &report,
            &truth,
            &track,
        ));
    }
    print_evals(args, &evals)
}

/// A fuse report of this objloc's version fused from `args.session` (whose file hashes to
/// `session_sha256`): scoring a report against another session's truth or rectangles gives
/// numbers that mean nothing, unless the sessions share their world frame and the user says
/// so (`--any-session`).
pub fn read_report_of(path: &Path, args: &Args, session_sha256: &str) -> anyhow::Result<Report> {
    let report = read_report(path)?;
    if report.session_sha256 != session_sha256 {
        let what = format!(
            "{}: fused from another session ({}, sha256 {}...), not {} (sha256 {}...)",
            path.display(),
            report.session,
            report
                .session_sha256
                .get(..12)
                .unwrap_or(&report.session_sha256),
            args.session.display(),
            session_sha256.get(..12).unwrap_or(session_sha256)
        );
        if !args.any_session {
            bail!("{what}; --any-session scores it anyway");
        }
        eprintln!("warning: {what}: scored as asked (--any-session)");
    }
    Ok(report)
}

/// A fuse report of this objloc's version.
pub fn read_report(path: &Path) -> anyhow::Result<Report> {
    {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
        let version = value
            .get("report_version")
            .and_then(serde_json::Value::as_u64);
        if version != Some(u64::from(REPORT_VERSION)) {
            bail!(
                "{}: report version {}, this objloc reads version {REPORT_VERSION}: re-run `objloc fuse` to rewrite it",
                path.display(),
                version.map_or_else(|| "missing".to_string(), |v| v.to_string())
            );
        }
        let report: Report = serde_json::from_value(value)
            .with_context(|| format!("{}: not an objloc fuse report", path.display()))?;
        report.check().with_context(|| path.display().to_string())?;
        Ok(report)
    }
}

fn print_evals(args: &Args, evals: &[Evaluation]) -> anyhow::Result<()> {
    if args.json {
        say!("{}", serde_json::to_string_pretty(&evals)?);
    } else {
        for e in evals {
            print_eval(e);
        }
        if evals.len() > 1 {
            say!("comparison:");
            say!(
                "  {:<40} {:>21} {:>8} {:>7} {:>9} {:>9} {:>9} {:>9}",
                "report",
                "poses",
                "matched",
                "missed",
                "spurious",
                "max err",
                "odom ATE",
                "ATE"
            );
            let metres =
                |x: Option<f64>| x.map(|x| format!("{x:.3} m")).unwrap_or_else(|| "-".into());
            for e in evals {
                say!(
                    "  {:<40} {:>21} {:>8} {:>7} {:>9} {:>9} {:>9} {:>9}",
                    e.report,
                    e.poses,
                    e.matches.len(),
                    e.missed.len(),
                    e.spurious.len(),
                    metres(e.max_error_m()),
                    metres(
                        e.trajectory
                            .as_ref()
                            .filter(|_| !at_truth(e))
                            .map(|t| t.odometry_ate_m)
                    ),
                    metres(e.trajectory.as_ref().map(|t| t.fused_ate_m)),
                );
            }
        }
    }
    Ok(())
}

/// Whether the report was fused at the session's true poses (`--poses ground-truth`): its
/// "odometry" is then the truth, and /odom's error is not in it.
fn at_truth(e: &Evaluation) -> bool {
    e.poses.starts_with("ground-truth")
}

fn print_eval(e: &Evaluation) {
    say!("{}:", e.report);
    for m in &e.matches {
        say!("  {}", m.describe());
    }
    for name in &e.missed {
        say!("  missed: {name}");
    }
    for c in &e.spurious {
        say!(
            "  spurious object at ({:.3}, {:.3}, {:.3})",
            c[0],
            c[1],
            c[2]
        );
    }
    say!("  voxel IoU of the thresholded belief: {:.3}", e.voxel_iou);
    if let Some(t) = e.trajectory.as_ref().filter(|_| at_truth(e)) {
        say!(
            "  trajectory at {} frames: given the true poses (/odom not used); poses fused with ({}): ATE {:.3} m",
            t.frames,
            e.poses,
            t.fused_ate_m
        );
    } else if let Some(t) = &e.trajectory {
        say!(
            "  trajectory at {} frames: /odom ATE {:.3} m (max {:.3} m); poses fused with ({}): ATE {:.3} m",
            t.frames,
            t.odometry_ate_m,
            t.odometry_max_m,
            e.poses,
            t.fused_ate_m
        );
    }
    if let Some(why) = &e.rolled_back {
        say!("  ROLLED BACK to /odom: {why}");
    }
    say!("  after each frame:");
    for f in &e.per_frame {
        say!(
            "    frame {:>3}: {} object(s), {} matched, mean error {}{}",
            f.index,
            f.objects,
            f.matched,
            f.mean_error_m
                .map(|x| format!("{x:.3} m"))
                .unwrap_or_else(|| "-".into()),
            f.refinement
                .map(|v| format!(
                    ", pose {}{}",
                    v.label(),
                    if f.detections_only {
                        " (detections alone)"
                    } else {
                        ""
                    }
                ))
                .unwrap_or_default()
        );
    }
}
