//! The Python venv the interop and Rerun tests run third-party tools from: target/pyenv (or
//! `$OBJLOC_PYENV`), created from tests/py/requirements.txt on first use; `py_json` runs one
//! of the scripts in tests/py with it, `rerun_cli` is its `rerun` command.
//!
//! Invariants: installed exactly once per requirements hash: a stamp file in the venv holds
//! the hash, a file lock beside it keeps two test processes from installing at once, and a
//! `OnceLock` does the same for the threads of one.

use std::ffi::OsStr;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use serde_json::Value;
use sha2::{Digest, Sha256};

use super::repo_dir;

pub const REQUIREMENTS: &str = "tests/py/requirements.txt";
/// Written into the venv after a successful install: the SHA-256 of requirements.txt.
pub const STAMP_FILE: &str = "objloc-requirements.sha256";

pub fn pyenv_dir() -> PathBuf {
    std::env::var_os("OBJLOC_PYENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_dir().join("target").join("pyenv"))
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

pub fn run_checked(cmd: &mut Command) -> Result<Output, String> {
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

/// Creates (or updates) the venv at `dir` so it holds exactly what requirements.txt pins.
/// Skips pip when the stamp in the venv matches the hash of requirements.txt.
pub fn ensure_pyenv(dir: &Path) -> Result<PathBuf, String> {
    let req_path = repo_dir().join(REQUIREMENTS);
    let req = std::fs::read(&req_path).map_err(|e| format!("{}: {e}", req_path.display()))?;
    let want = sha256_hex(&req);
    let parent = dir.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    // Beside the venv, not in it, so it can be taken before the venv exists.
    let lock_path = dir.with_extension("lock");
    let lock = File::create(&lock_path).map_err(|e| format!("{}: {e}", lock_path.display()))?;
    lock.lock()
        .map_err(|e| format!("cannot lock {}: {e}", lock_path.display()))?;

    let python = dir.join("bin").join("python");
    let stamp = dir.join(STAMP_FILE);
    if python.exists() && std::fs::read_to_string(&stamp).ok().as_deref() == Some(want.as_str()) {
        return Ok(python);
    }
    if !python.exists() {
        run_checked(Command::new("python3").arg("-m").arg("venv").arg(dir))?;
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
    std::fs::write(&stamp, &want).map_err(|e| format!("{}: {e}", stamp.display()))?;
    Ok(python)
}

/// The venv's python, creating the venv on first use in this process.
pub fn python() -> &'static Path {
    static PYENV: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    match PYENV.get_or_init(|| ensure_pyenv(&pyenv_dir())) {
        Ok(p) => p,
        Err(e) => panic!("cannot set up the Python venv for the interop tests: {e}"),
    }
}

/// The venv's `rerun` CLI (the rerun-sdk's).
pub fn rerun_cli() -> PathBuf {
    python().with_file_name("rerun")
}

/// Runs `tests/py/<script>` with `args` in the venv, which must succeed, and parses its stdout
/// as JSON.
pub fn py_json<S: AsRef<OsStr>>(script: &str, args: &[S]) -> Value {
    let out = run_checked(
        Command::new(python())
            .arg(repo_dir().join("tests").join("py").join(script))
            .args(args),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{script} printed no JSON ({e}):\n{}",
            String::from_utf8_lossy(&out.stdout)
        )
    })
}
