//! Reading NumPy arrays as pose files hold them: `.npy` of little-endian float32 or float64
//! in C order, and `.npz` archives of them (stored, not compressed, as `np.savez` writes).
//!
//! Invariants: sizes are checked against the data before anything is allocated from them; a
//! compressed or encrypted archive entry is refused, not misread.

use std::path::Path;

use super::CaptureError;

/// A float array: shape and values (float32 widened to f64), C order.
pub(super) struct Array {
    pub(super) shape: Vec<usize>,
    pub(super) data: Vec<f64>,
}

/// Parses `.npy` bytes (`what` names them in errors).
pub(super) fn parse_npy(path: &Path, what: &str, bytes: &[u8]) -> Result<Array, CaptureError> {
    let err = |w: &str| CaptureError::Entry {
        path: path.into(),
        entry: what.into(),
        what: w.into(),
    };
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(err("not a .npy array (no magic)"));
    }
    let (hlen, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        _ if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(err("short header")),
    };
    let header = bytes
        .get(start..start + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| err("header is not text"))?;
    let size = if header.contains("'<f8'") {
        8
    } else if header.contains("'<f4'") {
        4
    } else {
        return Err(err("only little-endian float32 or float64 arrays are read"));
    };
    if header.contains("'fortran_order': True") {
        return Err(err("Fortran-order arrays are not read"));
    }
    let shape: Vec<usize> = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| err("no shape"))?
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().map_err(|_| err("bad shape")))
        .collect::<Result<_, _>>()?;
    let body = &bytes[start + hlen..];
    let n = shape.iter().try_fold(1usize, |a, &b| a.checked_mul(b));
    if n.and_then(|n| n.checked_mul(size)) != Some(body.len()) {
        return Err(err("data length does not match the shape"));
    }
    let data = if size == 8 {
        body.chunks_exact(8)
            .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect()
    } else {
        body.chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect()
    };
    Ok(Array { shape, data })
}

fn le16(b: &[u8], at: usize) -> Option<usize> {
    b.get(at..at + 2)
        .map(|s| usize::from(u16::from_le_bytes([s[0], s[1]])))
}

fn le32(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at + 4)
        .map(|s| u64::from(u32::from_le_bytes([s[0], s[1], s[2], s[3]])))
}

fn le64(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at + 8)
        .and_then(|s| s.try_into().ok())
        .map(u64::from_le_bytes)
}

/// The entries of a `.npz` (a zip of `.npy` files) by name, read through its central
/// directory (zip64 sizes included).
pub(super) fn parse_npz(path: &Path, bytes: &[u8]) -> Result<Vec<(String, Array)>, CaptureError> {
    let err = |w: String| CaptureError::Invalid {
        path: path.into(),
        what: w,
    };
    let eocd = (0..bytes.len().saturating_sub(21))
        .rev()
        .take(65_557)
        .find(|&i| bytes[i..].starts_with(&[0x50, 0x4b, 0x05, 0x06]))
        .ok_or_else(|| err("not a zip archive (no end of central directory)".into()))?;
    let entries = le16(bytes, eocd + 10).ok_or_else(|| err("short directory".into()))?;
    let mut at = le32(bytes, eocd + 16).ok_or_else(|| err("short directory".into()))? as usize;
    let mut out = Vec::with_capacity(entries);
    for _ in 0..entries {
        let bad = || err(format!("malformed directory entry at byte {at}"));
        if !bytes
            .get(at..)
            .is_some_and(|b| b.starts_with(&[0x50, 0x4b, 0x01, 0x02]))
        {
            return Err(bad());
        }
        let method = le16(bytes, at + 10).ok_or_else(bad)?;
        let flags = le16(bytes, at + 8).ok_or_else(bad)?;
        let mut size = le32(bytes, at + 24).ok_or_else(bad)?;
        let (nlen, xlen, clen) = (
            le16(bytes, at + 28).ok_or_else(bad)?,
            le16(bytes, at + 30).ok_or_else(bad)?,
            le16(bytes, at + 32).ok_or_else(bad)?,
        );
        let mut offset = le32(bytes, at + 42).ok_or_else(bad)?;
        let name_b = bytes.get(at + 46..at + 46 + nlen).ok_or_else(bad)?;
        let name = String::from_utf8_lossy(name_b).into_owned();
        // zip64: the sizes and offset that overflowed 32 bits, in this order.
        let extra = bytes
            .get(at + 46 + nlen..at + 46 + nlen + xlen)
            .ok_or_else(bad)?;
        let mut x = 0;
        while x + 4 <= extra.len() {
            let (id, len) = (le16(extra, x).unwrap_or(0), le16(extra, x + 2).unwrap_or(0));
            if id == 1 {
                let mut k = x + 4;
                if size == 0xFFFF_FFFF {
                    size = le64(extra, k).ok_or_else(bad)?;
                    k += 8;
                }
                if le32(bytes, at + 20) == Some(0xFFFF_FFFF) {
                    k += 8;
                }
                if offset == 0xFFFF_FFFF {
                    offset = le64(extra, k).ok_or_else(bad)?;
                }
            }
            x += 4 + len;
        }
        if method != 0 || flags & 1 != 0 {
            return Err(err(format!(
                "entry {name:?} is compressed or encrypted (method {method}); save it with np.savez, not savez_compressed"
            )));
        }
        let lh = offset as usize;
        let lnl = le16(bytes, lh + 26).ok_or_else(bad)?;
        let lxl = le16(bytes, lh + 28).ok_or_else(bad)?;
        let start = lh + 30 + lnl + lxl;
        let data = bytes.get(start..start + size as usize).ok_or_else(bad)?;
        let key = name.strip_suffix(".npy").unwrap_or(&name).to_owned();
        out.push((key.clone(), parse_npy(path, &key, data)?));
        at += 46 + nlen + xlen + clen;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy_f4(shape: &str, values: &[f32]) -> Vec<u8> {
        let mut header =
            format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({shape}), }}");
        while (10 + header.len() + 1) % 64 != 0 {
            header.push(' ');
        }
        header.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend((header.len() as u16).to_le_bytes());
        b.extend(header.as_bytes());
        for v in values {
            b.extend(v.to_le_bytes());
        }
        b
    }

    /// A stored zip of two arrays, built by hand: local headers, then the central directory.
    #[test]
    fn npz_entries_are_read_through_the_central_directory() {
        let files = [
            ("a.npy", npy_f4("2,", &[1.5, -2.0])),
            ("b.npy", npy_f4("1, 1", &[7.0])),
        ];
        let mut zip = Vec::new();
        let mut central = Vec::new();
        for (name, data) in &files {
            let offset = zip.len() as u32;
            let mut local = vec![0x50, 0x4b, 0x03, 0x04, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0];
            local.extend(0u32.to_le_bytes()); // crc (not checked)
            local.extend((data.len() as u32).to_le_bytes());
            local.extend((data.len() as u32).to_le_bytes());
            local.extend((name.len() as u16).to_le_bytes());
            local.extend(0u16.to_le_bytes());
            local.extend(name.as_bytes());
            zip.extend(&local);
            zip.extend(data);
            let mut c = vec![0x50, 0x4b, 0x01, 0x02, 20, 0, 20, 0, 0, 0, 0, 0, 0, 0, 0, 0];
            c.extend(0u32.to_le_bytes());
            c.extend((data.len() as u32).to_le_bytes());
            c.extend((data.len() as u32).to_le_bytes());
            c.extend((name.len() as u16).to_le_bytes());
            c.extend([0u8; 12]);
            c.extend(offset.to_le_bytes());
            c.extend(name.as_bytes());
            central.extend(c);
        }
        let dir_at = zip.len() as u32;
        zip.extend(&central);
        zip.extend([0x50, 0x4b, 0x05, 0x06, 0, 0, 0, 0, 2, 0, 2, 0]);
        zip.extend((central.len() as u32).to_le_bytes());
        zip.extend(dir_at.to_le_bytes());
        zip.extend(0u16.to_le_bytes());
        let got = parse_npz(Path::new("x.npz"), &zip).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(got[0].0, "a");
        assert_eq!(got[0].1.data, vec![1.5, -2.0]);
        assert_eq!(got[1].1.shape, vec![1, 1]);
        assert!(parse_npz(Path::new("x.npz"), &zip[..zip.len() - 30]).is_err());
    }
}
