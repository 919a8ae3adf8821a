//! NumPy `.npy` (format 1.0) for float32, float64, uint8 and int64 arrays in C order: the
//! interchange with Python tools. Writing goes through [`crate::io::output::write_atomic`].

use std::path::Path;

use thiserror::Error;

/// Why a `.npy` file could not be written or read.
#[derive(Debug, Error)]
pub enum NpyError {
    /// Reading or writing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file, as displayed in the message.
        path: String,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a `.npy` that [`read_f32`] reads (little-endian float32, C order).
    #[error("{path}: not a .npy file this reader understands: {what}")]
    Format {
        /// The file, as displayed in the message.
        path: String,
        /// What is wrong, e.g. `missing magic` or `bad shape`.
        what: String,
    },
}

/// Element types written by objloc.
pub trait NpyElem: Copy {
    /// NumPy dtype string for the header's `descr`, e.g. `<f4` for little-endian float32.
    const DESCR: &'static str;
    /// Appends the element's bytes, little endian, to `out`.
    fn put(self, out: &mut Vec<u8>);
}
impl NpyElem for f32 {
    const DESCR: &'static str = "<f4";
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}
impl NpyElem for f64 {
    const DESCR: &'static str = "<f8";
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}
impl NpyElem for u8 {
    const DESCR: &'static str = "|u1";
    fn put(self, out: &mut Vec<u8>) {
        out.push(self);
    }
}
impl NpyElem for i8 {
    const DESCR: &'static str = "|i1";
    fn put(self, out: &mut Vec<u8>) {
        out.push(self as u8);
    }
}
impl NpyElem for i64 {
    const DESCR: &'static str = "<i8";
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

/// The `.npy` header (magic, version, length and the padded dict) of an array of `T` with
/// `shape`, C order.
pub fn header<T: NpyElem>(shape: &[usize]) -> Vec<u8> {
    let shape_s = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {shape_s}, }}",
        T::DESCR
    );
    // Magic (6) + version (2) + header length (2) + header + '\n' is a multiple of 64.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out
}

/// Encodes `data` (C order) with `shape` as `.npy` bytes.
pub fn encode<T: NpyElem>(shape: &[usize], data: &[T]) -> Vec<u8> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let mut out = header::<T>(shape);
    out.reserve(data.len() * 8);
    for &v in data {
        v.put(&mut out);
    }
    out
}

/// Writes an array of `shape` (C order) to `path` as `.npy`, atomically, from `parts`: its
/// values in order, a part at a time (e.g. one x-slab each), so that it is never whole in
/// memory. The parts must hold `shape`'s product of values in all.
pub fn write_parts<T: NpyElem>(
    path: &Path,
    shape: &[usize],
    parts: impl Iterator<Item = Vec<T>>,
) -> Result<(), NpyError> {
    crate::io::output::write_atomic_with(path, |w| put_parts(w, shape, parts)).map_err(|source| {
        NpyError::Io {
            path: path.display().to_string(),
            source,
        }
    })
}

/// [`write_parts`] to `path`'s `.partial` file, renamed with the rest of `staged`.
pub fn write_parts_staged<T: NpyElem>(
    staged: &mut crate::io::output::Staged,
    path: &Path,
    shape: &[usize],
    parts: impl Iterator<Item = Vec<T>>,
) -> Result<(), NpyError> {
    staged
        .write_with(path, |w| put_parts(w, shape, parts))
        .map_err(|source| NpyError::Io {
            path: path.display().to_string(),
            source,
        })
}

/// The `.npy` header of `shape` and then the parts' values, checked to fill it.
fn put_parts<T: NpyElem>(
    w: &mut dyn std::io::Write,
    shape: &[usize],
    parts: impl Iterator<Item = Vec<T>>,
) -> std::io::Result<()> {
    let want: usize = shape.iter().product();
    w.write_all(&header::<T>(shape))?;
    let (mut n, mut bytes) = (0, Vec::new());
    for part in parts {
        n += part.len();
        bytes.clear();
        for v in part {
            v.put(&mut bytes);
        }
        w.write_all(&bytes)?;
    }
    if n != want {
        return Err(std::io::Error::other(format!(
            "{n} values for a shape of {want}"
        )));
    }
    Ok(())
}

/// [`write`] to `path`'s `.partial` file, renamed with the rest of `staged`.
pub fn write_staged<T: NpyElem>(
    staged: &mut crate::io::output::Staged,
    path: &Path,
    shape: &[usize],
    data: &[T],
) -> Result<(), NpyError> {
    staged
        .write_with(path, |w| w.write_all(&encode(shape, data)))
        .map_err(|source| NpyError::Io {
            path: path.display().to_string(),
            source,
        })
}

/// Writes `data` (C order) with `shape` to `path` as `.npy`, atomically: through a
/// `.partial` file and a rename.
pub fn write<T: NpyElem>(path: &Path, shape: &[usize], data: &[T]) -> Result<(), NpyError> {
    crate::io::output::write_atomic(path, &encode(shape, data)).map_err(|source| NpyError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Reads a little-endian float32 `.npy` in C order: (shape, data).
pub fn read_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>), NpyError> {
    let p = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| NpyError::Io {
        path: p.clone(),
        source,
    })?;
    let fmt = |what: &str| NpyError::Format {
        path: p.clone(),
        what: what.to_owned(),
    };
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(fmt("missing magic"));
    }
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(
        bytes
            .get(10..10 + hlen)
            .ok_or_else(|| fmt("short header"))?,
    )
    .map_err(|_| fmt("header is not text"))?;
    if !header.contains("'<f4'") || header.contains("'fortran_order': True") {
        return Err(fmt("only little-endian float32 in C order is read"));
    }
    let shape_s = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| fmt("no shape"))?;
    let shape: Vec<usize> = shape_s
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().map_err(|_| fmt("bad shape")))
        .collect::<Result<_, _>>()?;
    let body = &bytes[10 + hlen..];
    let n: usize = shape.iter().product();
    if body.len() != n * 4 {
        return Err(fmt("data length does not match shape"));
    }
    let data = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_aligned_and_roundtrips() {
        let b = encode(&[2, 3], &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        assert_eq!(b.len(), 10 + hlen + 24);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write(&p, &[2, 3], &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        let (shape, data) = read_f32(&p).unwrap();
        assert_eq!(shape, vec![2, 3]);
        assert_eq!(data[5], 6.0);
    }

    #[test]
    fn an_array_written_in_parts_is_the_array_written_whole() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.npy"), dir.path().join("b.npy"));
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
        write(&a, &[2, 3, 4], &data).unwrap();
        write_parts(&b, &[2, 3, 4], data.chunks(12).map(<[f32]>::to_vec)).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        // Too few values: an error, and no file.
        let c = dir.path().join("c.npy");
        assert!(write_parts(&c, &[2, 3, 4], data.chunks(12).take(1).map(<[f32]>::to_vec)).is_err());
        assert!(!c.exists() && !crate::io::output::partial_path(&c).exists());
    }

    #[test]
    fn one_dimensional_shape_has_trailing_comma() {
        let b = encode(&[3], &[1u8, 2, 3]);
        let s = String::from_utf8_lossy(&b[10..]);
        assert!(s.contains("'shape': (3,)"), "{s}");
    }
}
