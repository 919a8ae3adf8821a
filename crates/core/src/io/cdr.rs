//! Little-endian CDR (XCDR1, as ROS 2 writes it) with the 4-byte encapsulation header.
//!
//! Invariants: alignment is relative to the first byte after the encapsulation header; every
//! read is bounds-checked against the payload before anything is allocated, so a hostile
//! sequence length (say 4e9) fails with [`CdrError`] instead of allocating. This is why the
//! codec is written here rather than taken from the `cdr` crate, whose `read_vec` resizes the
//! buffer to the declared length before checking it against the input.

use thiserror::Error;

/// Encapsulation header for plain CDR, little endian (`CDR_LE`).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Why a CDR payload could not be decoded; offsets are bytes from the start of the payload.
#[derive(Debug, Error, PartialEq, Eq, Clone)]
pub enum CdrError {
    /// The payload is shorter than the 4-byte encapsulation header.
    #[error("payload of {len} bytes is too short for the 4-byte CDR encapsulation header")]
    NoHeader {
        /// Length of the whole payload, bytes (0 to 3).
        len: usize,
    },
    /// The encapsulation header names a representation other than plain CDR, LE or BE.
    #[error(
        "unsupported CDR encapsulation {kind:#06x} (only CDR_LE 0x0001 and CDR_BE 0x0000 are read)"
    )]
    Encapsulation {
        /// Representation identifier: the header's first two bytes, read big endian.
        kind: u16,
    },
    /// The payload ends inside a field.
    #[error(
        "payload cut short: needed {needed} bytes at offset {offset} for {what}, only {available} left"
    )]
    Short {
        /// The field being read, e.g. `header.stamp.sec`.
        what: &'static str,
        /// Where the field starts, after its alignment padding.
        offset: usize,
        /// Bytes the field needs.
        needed: usize,
        /// Bytes left in the payload from `offset`.
        available: usize,
    },
    /// A sequence or string length prefix declares more elements than the rest of the payload
    /// can hold; refused before anything is allocated.
    #[error(
        "sequence length {declared} for {what} at offset {offset} exceeds the {available} bytes left"
    )]
    Length {
        /// The sequence being read, e.g. `transforms`.
        what: &'static str,
        /// Where the length prefix starts, before its alignment padding.
        offset: usize,
        /// Element count the prefix declares.
        declared: u64,
        /// Bytes left in the payload after the prefix.
        available: usize,
    },
    /// A string is not UTF-8 or its last byte is not the NUL terminator.
    #[error("string at offset {offset} is not valid UTF-8 or lacks its NUL terminator")]
    BadString {
        /// Where the string's bytes start, after its length prefix.
        offset: usize,
    },
    /// A field holds a value its type forbids, e.g. a `builtin_interfaces/Time` nanosec of
    /// 1e9 or more (ROS requires it below one second; read as is, the stamp moved seconds).
    #[error("{what} is {value}, {rule}")]
    OutOfRange {
        /// The field, e.g. `header.stamp.nanosec`.
        what: &'static str,
        /// The value read.
        value: u64,
        /// What the type requires.
        rule: &'static str,
    },
    /// 4 or more bytes are left after the whole message was decoded: the schema does not
    /// match the payload (fewer are taken as padding).
    #[error("{count} bytes left over after decoding {what} (payload {len} bytes)")]
    Trailing {
        /// The message type decoded, e.g. `nav_msgs/msg/Odometry`.
        what: &'static str,
        /// Bytes left over.
        count: usize,
        /// Length of the whole payload, header included, bytes.
        len: usize,
    },
}

/// Writes one CDR payload. Start with [`CdrWriter::new`], finish with [`CdrWriter::finish`].
#[derive(Debug, Default)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl CdrWriter {
    /// An empty payload: just the `CDR_LE` encapsulation header.
    pub fn new() -> Self {
        let mut buf = Vec::with_capacity(256);
        buf.extend_from_slice(&CDR_LE_HEADER);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - 4;
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// Appends a `uint8` (one byte, no alignment).
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// Appends a `bool` as one byte, 0 or 1.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }
    /// Appends a `uint32`, little endian, aligned to 4 bytes.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends an `int32`, little endian, aligned to 4 bytes.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a `float64`, little endian, aligned to 8 bytes.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// Sequence or string length prefix. Lengths beyond u32 cannot be expressed in CDR; the
    /// messages this crate writes are far below that (images of at most a few MB).
    pub fn len(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }
    /// Appends a `string`: a length that counts the NUL terminator, the UTF-8 bytes, NUL.
    pub fn string(&mut self, s: &str) {
        self.len(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// Appends a `uint8[]` sequence: its length, then the bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        self.len(b.len());
        self.buf.extend_from_slice(b);
    }
    /// Appends a fixed-size `float64[N]` array: the values only, no length prefix.
    pub fn f64_array(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }
    /// Appends a `float64[]` sequence: its length, then the values.
    pub fn f64_seq(&mut self, v: &[f64]) {
        self.len(v.len());
        self.f64_array(v);
    }
    /// The finished payload, encapsulation header included.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Reads one CDR payload, checking every length against what is left.
#[derive(Debug)]
pub struct CdrReader<'a> {
    data: &'a [u8],
    pos: usize,
    big_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// Starts reading `payload`; fails unless it begins with a `CDR_LE` or `CDR_BE`
    /// encapsulation header.
    pub fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        if payload.len() < 4 {
            return Err(CdrError::NoHeader { len: payload.len() });
        }
        let kind = u16::from_be_bytes([payload[0], payload[1]]);
        let big_endian = match kind {
            0x0001 => false,
            0x0000 => true,
            _ => return Err(CdrError::Encapsulation { kind }),
        };
        Ok(Self {
            data: &payload[4..],
            pos: 0,
            big_endian,
        })
    }

    /// Offset in the whole payload (header included), for error messages.
    pub fn offset(&self) -> usize {
        self.pos + 4
    }

    /// Bytes not yet read, alignment padding still to skip included.
    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    fn align(&mut self, n: usize) {
        let pad = (n - self.pos % n) % n;
        self.pos = (self.pos + pad).min(self.data.len());
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        if self.remaining() < n {
            return Err(CdrError::Short {
                what,
                offset: self.offset(),
                needed: n,
                available: self.remaining(),
            });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn fixed<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N);
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, what)?);
        if self.big_endian {
            a.reverse();
        }
        Ok(a)
    }

    /// Reads a `uint8`; `what` names the field in errors.
    pub fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }
    /// Reads a `bool`: one byte, any non-zero value is true.
    pub fn bool(&mut self, what: &'static str) -> Result<bool, CdrError> {
        Ok(self.u8(what)? != 0)
    }
    /// Reads a `uint32`, aligned to 4 bytes, in the payload's byte order.
    pub fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.fixed(what)?))
    }
    /// Reads an `int32`, aligned to 4 bytes, in the payload's byte order.
    pub fn i32(&mut self, what: &'static str) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.fixed(what)?))
    }
    /// Reads a `float64`, aligned to 8 bytes, in the payload's byte order.
    pub fn f64(&mut self, what: &'static str) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.fixed(what)?))
    }

    /// A sequence length whose elements take at least `elem_size` bytes each: refused when
    /// the rest of the payload cannot hold them, before the caller allocates.
    pub fn seq_len(&mut self, elem_size: usize, what: &'static str) -> Result<usize, CdrError> {
        let offset = self.offset();
        let declared = self.u32(what)?;
        let need = u64::from(declared) * elem_size.max(1) as u64;
        if need > self.remaining() as u64 {
            return Err(CdrError::Length {
                what,
                offset,
                declared: u64::from(declared),
                available: self.remaining(),
            });
        }
        Ok(declared as usize)
    }

    /// Reads a `string`: UTF-8 ending in NUL (not returned); a length of 0 reads as empty.
    pub fn string(&mut self, what: &'static str) -> Result<String, CdrError> {
        let n = self.seq_len(1, what)?;
        let offset = self.offset();
        let raw = self.take(n, what)?;
        // ROS 2 strings carry a NUL terminator counted in the length; an empty string may
        // be written by some tools with length 0.
        let body = match raw.split_last() {
            Some((0, body)) => body,
            Some(_) => return Err(CdrError::BadString { offset }),
            None => raw,
        };
        String::from_utf8(body.to_vec()).map_err(|_| CdrError::BadString { offset })
    }

    /// Reads a `uint8[]` sequence, borrowed from the payload.
    pub fn bytes(&mut self, what: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.seq_len(1, what)?;
        self.take(n, what)
    }

    /// Reads a fixed-size `float64[N]` array (no length prefix).
    pub fn f64_array<const N: usize>(&mut self, what: &'static str) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// Reads a `float64[]` sequence; a length the rest of the payload cannot hold is refused.
    pub fn f64_seq(&mut self, what: &'static str) -> Result<Vec<f64>, CdrError> {
        let n = self.seq_len(8, what)?;
        (0..n).map(|_| self.f64(what)).collect()
    }

    /// Trailing bytes beyond alignment padding mean the schema does not match the payload.
    pub fn finish(self, what: &'static str) -> Result<(), CdrError> {
        // Writers may pad the payload to a multiple of 4 (rmw_fastrtps does).
        let left = self.remaining();
        if left >= 4 {
            return Err(CdrError::Trailing {
                what,
                count: left,
                len: self.data.len() + 4,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_is_relative_to_payload_start() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(1.5);
        let b = w.finish();
        // header (4) + u8 (1) + 7 bytes padding + f64 (8)
        assert_eq!(b.len(), 4 + 16);
        assert_eq!(&b[..4], &CDR_LE_HEADER);
        assert_eq!(b[4], 7);
        assert_eq!(&b[5..12], &[0; 7]);
        assert_eq!(&b[12..], &1.5f64.to_le_bytes());
        let mut r = CdrReader::new(&b).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.f64("b").unwrap(), 1.5);
        r.finish("t").unwrap();
    }

    #[test]
    fn string_has_nul_and_length_counts_it() {
        let mut w = CdrWriter::new();
        w.string("odom");
        let b = w.finish();
        assert_eq!(&b[4..8], &5u32.to_le_bytes());
        assert_eq!(&b[8..], b"odom\0");
        let mut r = CdrReader::new(&b).unwrap();
        assert_eq!(r.string("s").unwrap(), "odom");
    }

    #[test]
    fn absurd_sequence_length_is_refused_before_allocating() {
        let mut b = CDR_LE_HEADER.to_vec();
        b.extend_from_slice(&u32::MAX.to_le_bytes());
        b.extend_from_slice(&[1, 2, 3]);
        let mut r = CdrReader::new(&b).unwrap();
        let e = r.bytes("data").unwrap_err();
        assert_eq!(
            e,
            CdrError::Length {
                what: "data",
                offset: 4,
                declared: u32::MAX as u64,
                available: 3
            }
        );
    }

    #[test]
    fn short_payload_names_the_field() {
        let b = [0, 1, 0, 0, 1, 2];
        let mut r = CdrReader::new(&b).unwrap();
        let e = r.u32("stamp.sec").unwrap_err();
        assert!(e.to_string().contains("stamp.sec"), "{e}");
    }

    #[test]
    fn big_endian_payload_reads() {
        let b = [0, 0, 0, 0, 0, 0, 0, 42];
        let mut r = CdrReader::new(&b).unwrap();
        assert_eq!(r.u32("x").unwrap(), 42);
    }
}
