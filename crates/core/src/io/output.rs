//! Output files are written whole or not at all: to `NAME.partial` beside the target, then
//! renamed, so a killed process never leaves a file that looks finished.
//!
//! Invariant: a rename never replaces anything but a regular file. A symbolic link is
//! followed (its target is replaced, the link stays); a device, a pipe or a directory is
//! refused before anything is written (renamed over, `/dev/null` would become a file).

use std::io::Write;
use std::path::{Path, PathBuf};

/// `out.json` -> `out.json.partial`, beside the file `path` names (a link's target), so the
/// rename is atomic.
pub fn partial_path(path: &Path) -> PathBuf {
    let path = final_path(path);
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".partial");
    path.with_file_name(name)
}

/// The file an output path names: a symbolic link's target (the link stays and its file is
/// replaced), else the path itself.
pub fn final_path(path: &Path) -> PathBuf {
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    if !is_link {
        return path.to_path_buf();
    }
    std::fs::canonicalize(path).unwrap_or_else(|_| {
        // A dangling link: the file it names, relative to the link's directory.
        let dir = path.parent().unwrap_or(Path::new(""));
        std::fs::read_link(path).map_or_else(|_| path.to_path_buf(), |t| dir.join(t))
    })
}

/// Where an output is written and then renamed to: (`.partial`, final file). An existing
/// path that is not a regular file (a device such as `/dev/null`, a pipe, a directory) is
/// refused: the rename would replace it.
pub fn destination(path: &Path) -> std::io::Result<(PathBuf, PathBuf)> {
    let target = final_path(path);
    if let Ok(m) = std::fs::metadata(&target)
        && !m.is_file()
    {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a device, a pipe or a directory): an output is written whole beside it and renamed over it, which would replace it; give a file path",
        ));
    }
    Ok((partial_path(path), target))
}

/// Writes `bytes` to `path` through a `.partial` file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes what `fill` writes to `path` through a buffered `.partial` file and a rename, for
/// outputs made piece by piece (never whole in memory); on any error the partial file is
/// removed.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    // One output staged alone: written whole, renamed, or removed on any error.
    let mut staged = Staged::default();
    staged.write_with(path, fill)?;
    staged.commit().map(|_| ())
}

/// The outputs of one command, each written whole to its `.partial` file and renamed into
/// place together by [`Staged::commit`] once every one is written: a command that fails or is
/// killed part way leaves none of them under its final name (a report stayed beside a grid
/// that failed to write, and a recording beside a report that did). Dropped uncommitted, it
/// removes the partial files.
#[derive(Debug, Default)]
pub struct Staged {
    /// (partial file, final file), in the order they were staged.
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
    /// Writes what `fill` writes to `path`'s `.partial` file (see [`write_atomic_with`]),
    /// to be renamed at [`Staged::commit`].
    pub fn write_with(
        &mut self,
        path: &Path,
        fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        let (partial, target) = destination(path)?;
        // Staged before it is written: a failure part way removes it with the others.
        self.files.push((partial.clone(), target));
        let mut w = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&partial)?);
        fill(&mut w)?;
        let f = w
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)?;
        f.sync_all()
    }

    /// The final paths staged so far, in order.
    pub fn targets(&self) -> impl Iterator<Item = &Path> {
        self.files.iter().map(|(_, t)| t.as_path())
    }

    /// A file written whole elsewhere (`partial`, to become `target`), renamed with the rest.
    pub fn adopt(&mut self, partial: PathBuf, target: PathBuf) {
        self.files.push((partial, target));
    }

    /// Renames every staged file into place, in the order staged; their final paths.
    pub fn commit(mut self) -> std::io::Result<Vec<PathBuf>> {
        let files = std::mem::take(&mut self.files);
        let mut done = Vec::with_capacity(files.len());
        for (k, (partial, target)) in files.iter().enumerate() {
            if let Err(e) = std::fs::rename(partial, target) {
                // The rest stay partial, and are removed: only whole sets are final.
                for (p, _) in &files[k..] {
                    let _ = std::fs::remove_file(p);
                }
                return Err(e);
            }
            done.push(target.clone());
        }
        Ok(done)
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (partial, _) in &self.files {
            // Best effort: the command is already failing with its own error.
            let _ = std::fs::remove_file(partial);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_leaves_no_partial() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.json");
        write_atomic(&p, b"{}").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"{}");
        assert!(!partial_path(&p).exists());
        assert_eq!(partial_path(&p).file_name().unwrap(), "a.json.partial");
    }

    /// Staged outputs appear together at the commit; a failure part way, or a drop before
    /// the commit, leaves none of them and no partial file.
    #[test]
    fn staged_outputs_appear_together_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.json"), dir.path().join("b.npy"));
        let mut staged = Staged::default();
        staged.write_with(&a, |w| w.write_all(b"{}")).unwrap();
        staged.write_with(&b, |w| w.write_all(b"npy")).unwrap();
        assert!(!a.exists() && !b.exists() && partial_path(&a).exists());
        assert_eq!(staged.commit().unwrap(), [a.clone(), b.clone()]);
        assert_eq!(std::fs::read(&b).unwrap(), b"npy");
        assert!(!partial_path(&a).exists() && !partial_path(&b).exists());
        // The second fails while being written: neither is left, nor a partial file.
        let (c, d) = (dir.path().join("c.json"), dir.path().join("d.npy"));
        let mut staged = Staged::default();
        staged.write_with(&c, |w| w.write_all(b"{}")).unwrap();
        let e = staged.write_with(&d, |_| Err(std::io::Error::other("disk full")));
        assert!(e.is_err());
        drop(staged);
        for p in [&c, &d] {
            assert!(!p.exists() && !partial_path(p).exists(), "{}", p.display());
        }
    }

    /// A link is written through (it stays a link), a device is refused and left as it was.
    #[cfg(unix)]
    #[test]
    fn links_are_followed_and_devices_refused() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("t.json");
        let link = dir.path().join("l.json");
        std::fs::write(&target, b"old").unwrap();
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        assert!(!partial_path(&link).exists());
        let e = write_atomic(Path::new("/dev/null"), b"x").unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        use std::os::unix::fs::FileTypeExt;
        assert!(
            std::fs::metadata("/dev/null")
                .unwrap()
                .file_type()
                .is_char_device()
        );
        let e = write_atomic(dir.path(), b"x").unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }
}
