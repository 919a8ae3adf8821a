//! What the test modules share: running the binary and reading what it printed or wrote
//! (`objloc`, `ok`, `one_line_error`, `objloc_bounded`), path and JSON helpers, the chair model
//! trained by the binary, the fixture session (`fixture`) and the Python venv (`pyenv`).
//!
//! Invariants: the binary always runs from the repository root (relative paths such as
//! `recordings/chair-tour.mcap` mean the shipped files); a run that must not hang is bounded
//! by `HANG_LIMIT` and killed past it; nothing here reads the code under test.

pub mod fixture;
pub mod pyenv;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use serde_json::Value;

/// Says that a test is skipped and why, on the process's real stderr: the harness captures
/// `eprintln!` and shows a passing test's output to nobody, so CI's log would not say which
/// data a machine lacked.
pub fn say_skipped(why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "skipped: {why}");
}

/// `objloc record sim --scene-file scene --kind kind --seed seed -o out` and `extra` flags
/// (say `-q`, `--speed-noise 0,0`), which must succeed.
pub fn record_scene_file(scene: &Path, kind: &str, seed: &str, out: &Path, extra: &[&str]) {
    let mut args = vec![
        "record",
        "sim",
        "--scene-file",
        p(scene),
        "--kind",
        kind,
        "--seed",
        seed,
        "-o",
        p(out),
    ];
    args.extend_from_slice(extra);
    ok(&objloc(&args, &[]));
}

/// The repository root (the root package's manifest directory).
pub fn repo_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the objloc binary with `args` and the extra environment `envs` from the repository
/// root, and returns what it did (stdin is closed).
pub fn objloc<S: AsRef<OsStr>>(args: &[S], envs: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_objloc"));
    cmd.current_dir(repo_dir()).args(args);
    for (k, v) in envs {
        cmd.env(k, v);
    }
    cmd.output().expect("run objloc")
}

/// Asserts the run succeeded (printing its exit status and both streams if not) and returns
/// its stdout.
pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A failure: exit 1, one `error:` line on stderr (besides `warning:` lines), no panic.
/// Returns that line.
pub fn one_line_error(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.starts_with("warning:")).collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    lines[0].to_owned()
}

/// A command-line mistake found after parsing (a value out of range, a flag without the one
/// it qualifies): exit 2 like clap's own usage errors, one `error:` line, no panic. Returns
/// that line.
pub fn usage_error(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    lines[0].to_owned()
}

/// A path as a command-line argument (temporary paths are UTF-8).
pub fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 temp path")
}

/// The JSON file at `path`.
pub fn json(path: &Path) -> Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Trains the chair model from recordings/chair-train.mcap with the binary, default options:
/// `dir/chair.json`, its Rerun recording saved as `dir/chair.rrd`. Returns the model's path.
pub fn train(dir: &Path) -> PathBuf {
    let model = dir.join("chair.json");
    ok(&objloc(
        &[
            "train",
            "recordings/chair-train.mcap",
            "-o",
            p(&model),
            "--save",
            p(&dir.join("chair.rrd")),
        ],
        &[],
    ));
    model
}

/// Longer than any healthy run of the damaged-input tests takes, even on a loaded two-core
/// machine.
pub const HANG_LIMIT: Duration = Duration::from_secs(60);

/// A run of the binary bounded by `HANG_LIMIT` (`objloc_bounded`).
pub struct Run {
    /// The arguments, joined by spaces, for messages.
    pub args: String,
    /// The exit code; `None` for a signal.
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

/// Runs objloc with `args` from the repository root, failing the test (and killing the
/// process) if it does not end within `HANG_LIMIT`.
pub fn objloc_bounded<S: AsRef<OsStr>>(args: &[S]) -> Run {
    let child = Command::new(env!("CARGO_BIN_EXE_objloc"))
        .current_dir(repo_dir())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("objloc starts");
    let shown: Vec<String> = args
        .iter()
        .map(|a| a.as_ref().to_string_lossy().into_owned())
        .collect();
    let shown = shown.join(" ");
    let pid = child.id();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(HANG_LIMIT) {
        Ok(out) => {
            let out = out.expect("objloc output is collected");
            Run {
                args: shown,
                code: out.status.code(),
                stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
                stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
            }
        }
        Err(_) => {
            let _ = Command::new("kill").arg("-9").arg(pid.to_string()).status();
            panic!("objloc {shown} hung for {HANG_LIMIT:?}");
        }
    }
}
