//! objloc-core: learn to locate an object in 3D from a sequence of camera images, without a
//! viewer (the `objloc` binary adds the command line and the Rerun observers).
//!
//! The folders are the pipeline, and data flows one way through them:
//!
//! * [`types`]: shared values below everything (geometry, images, pose tracks, tile
//!   probabilities, a seeded RNG); imports nothing of the crate.
//! * [`io`]: MCAP sessions <-> typed ROS 2 messages, the pose files of real captures and
//!   their import (TUM, NeRF, COLMAP, LLFF, IDR; labels and masks), the inspector, `.npy` and
//!   atomic output files; imports [`types`].
//! * [`learn`]: tile features, training examples, the decision trees and the model file;
//!   imports [`types`] (labelled frames come in as typed values).
//! * [`fuse`]: the deterministic replay of one session (the only part of it that reads a
//!   session, with its transform tree and the defaults fitted to it) driving the fuser
//!   state: grid, motion blur, pose refinement against the landmarks and the floor, objects;
//!   imports [`types`], [`io`] and [`learn`].
//! * [`out`]: the report and its evaluation against ground truth or label rectangles;
//!   imports all of the above.
//! * [`sim`]: the simulator, a recorder like any other: it writes through [`io`]'s session
//!   writer; imports [`types`] and [`io`].
//!
//! Each folder's `mod.rs` repeats its rule, and the `layout` unit test below enforces them.
//! The fuser core takes typed values and returns state: no files, no clock, no viewer.

// Errors here carry the file, topic, log time and the numbers involved, so some exceed
// clippy's 128-byte budget for `Err`; they are built only on the failure path, where the copy
// costs nothing that matters.
#![allow(clippy::result_large_err)]

pub mod fuse;
pub mod io;
pub mod learn;
pub mod out;
pub mod sim;
pub mod types;

/// The layout's rules, checked on the source tree: which folder may import which (see each
/// folder's `mod.rs`), at most 6 files at the top of each crate's `src/`, and no file over
/// 700 lines of code (blank lines, `//` lines and the trailing test module not counted).
#[cfg(test)]
mod layout {
    use std::path::{Path, PathBuf};

    /// (folder, the crate roots it may name; `fuse/replay` may also read sessions).
    const RULES: [(&str, &[&str]); 6] = [
        ("types", &["types"]),
        ("io", &["types", "io"]),
        ("learn", &["types", "io", "learn"]),
        ("fuse", &["types", "learn", "fuse"]),
        ("out", &["types", "io", "learn", "fuse", "out"]),
        ("sim", &["types", "io", "sim"]),
    ];
    const MAX_TOP_FILES: usize = 6;
    const MAX_CODE_LINES: usize = 700;

    fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                rust_files(&p, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }

    /// The file's code lines: up to its trailing `#[cfg(test)] mod`, without blank and `//`
    /// lines.
    fn code_lines(text: &str) -> Vec<&str> {
        let lines: Vec<&str> = text.lines().collect();
        let end = (0..lines.len())
            .find(|&i| {
                lines[i].trim() == "#[cfg(test)]"
                    && lines
                        .get(i + 1)
                        .is_some_and(|l| l.trim_start().starts_with("mod "))
            })
            .unwrap_or(lines.len());
        lines[..end]
            .iter()
            .copied()
            .filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with("//"))
            .collect()
    }

    fn crate_roots(line: &str) -> Vec<&str> {
        line.match_indices("crate::")
            .map(|(i, _)| {
                let rest = &line[i + 7..];
                let end = rest
                    .find(|c: char| !(c.is_ascii_lowercase() || c == '_'))
                    .unwrap_or(rest.len());
                &rest[..end]
            })
            .collect()
    }

    #[test]
    fn folders_import_only_what_their_mod_rs_allows() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut files = Vec::new();
        rust_files(&src, &mut files);
        let mut bad = Vec::new();
        for f in &files {
            let rel = f.strip_prefix(&src).unwrap();
            let folder = rel
                .components()
                .next()
                .unwrap()
                .as_os_str()
                .to_str()
                .unwrap();
            let Some((_, allowed)) = RULES.iter().find(|(d, _)| *d == folder) else {
                continue;
            };
            let replay = rel.starts_with("fuse/replay");
            let text = std::fs::read_to_string(f).unwrap();
            for (n, line) in code_lines(&text).iter().enumerate() {
                for root in crate_roots(line) {
                    if !(allowed.contains(&root) || (replay && root == "io")) {
                        bad.push(format!("{}: line {n}: crate::{root}", rel.display()));
                    }
                }
            }
        }
        assert!(
            bad.is_empty(),
            "imports against the layout:\n{}",
            bad.join("\n")
        );
    }

    #[test]
    fn few_top_level_files_and_no_long_file() {
        let core = Path::new(env!("CARGO_MANIFEST_DIR"));
        let bin = core.join("../..");
        for src in [core.join("src"), bin.join("src")] {
            let top = std::fs::read_dir(&src)
                .unwrap()
                .filter(|e| e.as_ref().unwrap().path().is_file())
                .count();
            assert!(top <= MAX_TOP_FILES, "{}: {top} files", src.display());
            let mut files = Vec::new();
            rust_files(&src, &mut files);
            for f in files {
                let n = code_lines(&std::fs::read_to_string(&f).unwrap()).len();
                assert!(n <= MAX_CODE_LINES, "{}: {n} lines of code", f.display());
            }
        }
    }
}
