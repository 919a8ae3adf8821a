//! Subcommands, one file each; every `run(args)` returns `anyhow::Result<()>` and adds the
//! context (which file, which step) that the library's typed errors leave to the caller.

mod demo;
mod eval;
mod eval_rects;
mod fuse;
mod inspect;
mod predict;
mod progress;
mod record;
mod train;
mod train_views;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;

use clap::{Parser, Subcommand};

use objloc_core::io::session::Topics;

use crate::viz::Target;

/// Whether the command's text goes to stderr instead of stdout: with `--stdout`, stdout is
/// the Rerun recording, and one line of text in it makes the file unreadable to Rerun.
static TEXT_TO_STDERR: AtomicBool = AtomicBool::new(false);

/// The first error writing the command's text, if any: the command goes on (its files are
/// what matter) and then fails with it, instead of panicking half-way as `println!` does.
static TEXT_ERROR: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Writes the command's text where [`say!`] says, keeping the first failure for the exit.
pub(crate) fn write_text(args: std::fmt::Arguments<'_>) {
    use std::io::Write;
    let (result, stream) = if TEXT_TO_STDERR.load(Ordering::Relaxed) {
        (std::io::stderr().lock().write_fmt(args), "stderr")
    } else {
        (std::io::stdout().lock().write_fmt(args), "stdout")
    };
    if let Err(e) = result {
        let _ = TEXT_ERROR.set(format!("writing to {stream}: {e}"));
    }
}

/// `println!` for a command's report to the user: on stdout, unless stdout carries the
/// Rerun recording (`--stdout`), then on stderr. A failed write does not panic as `println!`
/// does (stdout on a full disk): see [`write_text`].
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::cmd::write_text(format_args!("{}\n", format_args!($($arg)*)))
    };
}
pub(crate) use say;

/// [`say!`] without the newline.
macro_rules! say_part {
    ($($arg:tt)*) => {
        $crate::cmd::write_text(format_args!($($arg)*))
    };
}
pub(crate) use say_part;

/// Teach a robot to find an object in 3D from camera images: record and replay ROS 2 MCAP
/// sessions, train a tile classifier, fuse views into a Bayesian 3D grid.
#[derive(Debug, Parser)]
#[command(name = "objloc", version, about, max_term_width = 100)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Summarise a session (or any ROS 2 MCAP): topics, counts, images, labels, warnings.
    Inspect(inspect::Args),
    /// Record a session: from the built-in simulator, or import a real image sequence.
    Record(record::Args),
    /// Train the tile classifier (pruned probability decision trees: one, or a forest for a
    /// posed capture) on labelled sessions.
    Train(train::Args),
    /// Write the classifier's per-tile probability maps for every frame of a session.
    Predict(predict::Args),
    /// Replay a session into a Bayesian 3D grid and locate the objects.
    Fuse(fuse::Args),
    /// Score a fuse report against the session's ground truth.
    Eval(eval::Args),
    /// Train on the shipped chair recordings, fuse the chair tour and report the error.
    Demo(demo::Args),
}

/// Topic-name overrides shared by every command that reads sessions.
#[derive(Debug, Clone, clap::Args)]
pub struct TopicArgs {
    /// Map a session role to another topic name, e.g. `--topic odom=/wheel/odometry`
    /// (roles: compressed_image, image, camera_info, tf_static, odom, cmd_vel, labels,
    /// ground_truth_pose, ground_truth_objects). Repeatable.
    #[arg(long = "topic", value_name = "ROLE=TOPIC")]
    pub overrides: Vec<String>,
}

impl TopicArgs {
    pub fn topics(&self) -> anyhow::Result<Topics> {
        Topics::default()
            .with_overrides(&self.overrides)
            .map_err(|e| UsageError(format!("--topic: {e}")).into())
    }
}

/// Prints warnings on stderr, each kind once: warnings that differ only in their log time
/// (a /cmd_vel of NaN in every message gave 42 identical lines) are one line with the first
/// time and how many more there were.
pub(crate) fn print_warnings<'a>(warnings: impl IntoIterator<Item = &'a String>) {
    // In order of first appearance; the map only finds a kind (a long replay can warn
    // thousands of times).
    let mut kinds: Vec<(&String, usize)> = Vec::new();
    let mut index: std::collections::BTreeMap<String, usize> = std::collections::BTreeMap::new();
    for w in warnings {
        let next = kinds.len();
        match *index.entry(without_log_time(w)).or_insert(next) {
            k if k < next => kinds[k].1 += 1,
            _ => kinds.push((w, 0)),
        }
    }
    for (first, more) in kinds {
        match more {
            0 => eprintln!("warning: {first}"),
            n => eprintln!("warning: {first} (and {n} more like it at later times)"),
        }
    }
}

/// `w` without the time in its "at log time T s".
fn without_log_time(w: &str) -> String {
    const AT: &str = "at log time ";
    match w.find(AT) {
        Some(i) => {
            let rest = &w[i + AT.len()..];
            let end = rest.find(" s").map_or(rest.len(), |e| e + 2);
            format!("{}{AT}{}", &w[..i], &rest[end..])
        }
        None => w.to_owned(),
    }
}

/// A command line that parsed but cannot be run as asked: a flag's value out of its range,
/// or a flag without the one it qualifies. It exits 2, as clap's own usage errors do, so that
/// every mistake in the command line (not in the files it names) has the same exit code.
#[derive(Debug)]
pub(crate) struct UsageError(pub String);

impl std::fmt::Display for UsageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UsageError {}

/// `Err(UsageError(message()))` unless `ok`.
pub(crate) fn usage_check(ok: bool, message: impl FnOnce() -> String) -> anyhow::Result<()> {
    if ok {
        Ok(())
    } else {
        Err(UsageError(message()).into())
    }
}

/// `p` as the file system resolves it, to compare outputs with inputs: canonical where it
/// exists, else its longest existing ancestor's canonical path with the rest applied
/// lexically. A directory not made yet is no symlink, so `new/../s.mcap` is `s.mcap`: with
/// only the parent canonicalised, `--report new/../s.mcap` passed as another file and
/// replaced the session with the report.
fn resolved(p: &Path) -> PathBuf {
    use std::path::Component;
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    let parts: Vec<Component> = p.components().collect();
    for k in (0..parts.len()).rev() {
        let head: PathBuf = parts[..k].iter().collect();
        let head = if head.as_os_str().is_empty() {
            PathBuf::from(".")
        } else {
            head
        };
        if let Ok(mut c) = head.canonicalize() {
            for part in &parts[k..] {
                match part {
                    Component::ParentDir => {
                        c.pop();
                    }
                    Component::CurDir => {}
                    other => c.push(other.as_os_str()),
                }
            }
            return c;
        }
    }
    p.to_path_buf()
}

/// Before any work: refuses an output that is one of the inputs (it would be overwritten,
/// silently: `fuse S.mcap --report S.mcap` replaced the session with its report) or another
/// output (the one written last would replace the other: `train -o m.json --save m.json`
/// left a recording where the model was said to be), as a usage error naming both flags;
/// then creates the outputs' directories, so that a missing one is not found only after the
/// replay (the recording's saver created them, the report's writer did not).
pub(crate) fn prepare_outputs(
    inputs: &[(&str, &Path)],
    outputs: &[(&str, &Path)],
) -> anyhow::Result<()> {
    let ins: Vec<PathBuf> = inputs.iter().map(|(_, p)| resolved(p)).collect();
    let outs: Vec<PathBuf> = outputs.iter().map(|(_, p)| resolved(p)).collect();
    for (k, ((flag, path), r)) in outputs.iter().zip(&outs).enumerate() {
        let shown = path.display();
        if let Some(i) = ins.iter().position(|x| x == r) {
            let (input, _) = inputs[i];
            return Err(UsageError(format!(
                "{flag} {shown} is the {input}: writing it would destroy it"
            ))
            .into());
        }
        if let Some(j) = outs[..k].iter().position(|x| x == r) {
            let (other, _) = outputs[j];
            let hint = if *flag == crate::viz::DEFAULT_RECORDING {
                " (--save FILE or --no-rerun puts the recording elsewhere)"
            } else {
                ""
            };
            return Err(UsageError(format!(
                "{flag} {shown} is also {other}: one would overwrite the other{hint}"
            ))
            .into());
        }
    }
    for (flag, path) in outputs {
        if let Err(e) = objloc_core::io::output::destination(path) {
            return Err(UsageError(format!("{flag} {}: {e}", path.display())).into());
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| {
                format!("{flag} {}: creating {}", path.display(), dir.display())
            })?;
        }
    }
    Ok(())
}

pub fn main(cli: Cli) -> std::process::ExitCode {
    let rerun = match &cli.command {
        Command::Train(a) => Some(&a.rerun),
        Command::Predict(a) => Some(&a.rerun),
        Command::Fuse(a) => Some(&a.rerun),
        Command::Demo(a) => Some(&a.rerun),
        Command::Inspect(_) | Command::Record(_) | Command::Eval(_) => None,
    };
    if rerun.is_some_and(|r| r.target == Target::Stdout) {
        TEXT_TO_STDERR.store(true, Ordering::Relaxed);
    }
    let result = match cli.command {
        Command::Inspect(a) => inspect::run(a),
        Command::Record(a) => record::run(a),
        Command::Train(a) => train::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Fuse(a) => fuse::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Demo(a) => demo::run(a),
    };
    // The command's files are written; its text could not be: say so, and fail.
    let result = result.and_then(|()| match TEXT_ERROR.get() {
        Some(e) => Err(anyhow::anyhow!("{e}")),
        None => Ok(()),
    });
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // The whole context chain on one line; a cause whose text its parent's message
            // already ends with (thiserror messages that embed their source) is not repeated.
            let mut line = String::new();
            for cause in e.chain() {
                let text = cause.to_string().replace('\n', " ");
                if !line.ends_with(&text) {
                    if !line.is_empty() {
                        line.push_str(": ");
                    }
                    line.push_str(&text);
                }
            }
            eprintln!("error: {line}");
            let usage = e.chain().any(|c| c.downcast_ref::<UsageError>().is_some());
            std::process::ExitCode::from(if usage { 2 } else { 1 })
        }
    }
}

/// Says where a command's Rerun recording went and how to open it.
pub(crate) fn say_recording(path: &std::path::Path) {
    say!(
        "rerun recording: {} (open it with: {})",
        path.display(),
        crate::viz::open_command(path)
    );
}

/// Object names for a message: `apple, banana`, or `none`.
pub(crate) fn names_or_none(names: &std::collections::BTreeSet<String>) -> String {
    if names.is_empty() {
        "none".to_owned()
    } else {
        names.iter().cloned().collect::<Vec<_>>().join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::without_log_time;

    /// Warnings that differ only in their time are one kind; others stay apart.
    #[test]
    fn warnings_differing_only_in_time_are_one_kind() {
        let w = |t: &str, what: &str| format!("s.mcap: topic /cmd_vel at log time {t} s: {what}");
        let a = without_log_time(&w("1700000001.500000000", "twist is not finite"));
        assert_eq!(
            a,
            "s.mcap: topic /cmd_vel at log time : twist is not finite"
        );
        assert_eq!(
            a,
            without_log_time(&w("1700000002.000000000", "twist is not finite"))
        );
        assert_ne!(
            a,
            without_log_time(&w("1700000001.500000000", "pose is not finite"))
        );
        assert_eq!(without_log_time("no time here"), "no time here");
    }
}
