//! Where payloads come from after the index pass: the open file (or the bytes in memory), read
//! by offset, and a small cache of decompressed chunks shared by the threads that decode.
//!
//! Invariants: a chunk read again must be the record the index pass saw: its opcode and
//! length are checked, its CRC and decompression are mcap's, and every message's header must
//! match the index, or the read is an error naming the file, topic and log time. The cache
//! holds at most its capacity of chunks, each as its messages' payloads; which chunks it
//! keeps changes only speed, never a result. A poisoned lock is recovered: the cache is
//! consistent after every statement (a panic cannot leave half an entry).

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::sync::{Arc, Mutex, PoisonError};

use mcap::records::{Record, op};
use mcap::sans_io::linear_reader::LinearReadEvent;

use super::super::{At, SessionError};
use super::index::{OPCODE_LEN_BYTES, chunk_reader, feed_parts};
use super::{ByteSpan, MessageMeta, Segment, SessionReader};

/// The bytes of a session: an open file or a copy in memory.
#[derive(Debug)]
pub(super) enum Source {
    /// The file the index was read from; one reader at a time seeks it.
    File(Mutex<File>),
    /// The whole file in memory ([`SessionReader::from_bytes`]).
    Memory(Vec<u8>),
}

impl Source {
    pub(super) fn file(file: File) -> Self {
        Source::File(Mutex::new(file))
    }

    /// `len_bytes` bytes from `offset_bytes`; an I/O error if the source holds fewer.
    fn read_at(&self, offset_bytes: u64, len_bytes: u64) -> std::io::Result<Vec<u8>> {
        let short = || {
            std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "file is shorter than when it was indexed",
            )
        };
        let len = usize::try_from(len_bytes).map_err(|_| short())?;
        match self {
            Source::Memory(bytes) => {
                let start = usize::try_from(offset_bytes).map_err(|_| short())?;
                bytes
                    .get(start..start.checked_add(len).ok_or_else(short)?)
                    .map(<[u8]>::to_vec)
                    .ok_or_else(short)
            }
            Source::File(file) => {
                let mut file = file.lock().unwrap_or_else(PoisonError::into_inner);
                file.seek(SeekFrom::Start(offset_bytes))?;
                let mut buf = vec![0u8; len];
                file.read_exact(&mut buf)?;
                Ok(buf)
            }
        }
    }
}

/// One decompressed chunk: its messages' headers and payloads, by ordinal.
#[derive(Debug)]
pub(super) struct ChunkPayloads {
    /// Every payload of the chunk, one after another.
    bytes: Vec<u8>,
    /// Per ordinal: the message's header and its payload's place in `bytes`.
    pub(super) messages: Vec<ChunkMessage>,
}

/// A message of a decompressed chunk.
#[derive(Debug, Clone, Copy)]
pub(super) struct ChunkMessage {
    pub(super) channel_id: u16,
    pub(super) sequence: u32,
    pub(super) log_time_ns: u64,
    pub(super) publish_time_ns: u64,
    start: usize,
    end: usize,
}

/// The most recently used decompressed chunks, least recent first.
#[derive(Debug)]
pub(super) struct ChunkCache {
    capacity: usize,
    entries: Mutex<Vec<(usize, Arc<ChunkPayloads>)>>,
}

impl ChunkCache {
    /// Room for `capacity` chunks (at least one).
    pub(super) fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            entries: Mutex::new(Vec::new()),
        }
    }

    /// Four chunks, or two per decoding thread when there are more: the replay decodes a few
    /// consecutive frames at once, each thread a neighbouring chunk.
    pub(super) fn default_capacity() -> usize {
        4.max(2 * rayon::current_num_threads())
    }

    fn get(&self, chunk: usize) -> Option<Arc<ChunkPayloads>> {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        let i = entries.iter().position(|(c, _)| *c == chunk)?;
        let entry = entries.remove(i);
        let payloads = Arc::clone(&entry.1);
        entries.push(entry);
        Some(payloads)
    }

    fn put(&self, chunk: usize, payloads: Arc<ChunkPayloads>) {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        // Two threads may have decompressed the same chunk: keep one copy.
        entries.retain(|(c, _)| *c != chunk);
        entries.push((chunk, payloads));
        let excess = entries.len().saturating_sub(self.capacity);
        entries.drain(..excess);
    }
}

impl SessionReader {
    /// The CDR payload of `meta`, read from its chunk (through the cache) or the file.
    pub fn payload(&self, meta: &MessageMeta) -> Result<Vec<u8>, SessionError> {
        self.with_payload(meta, <[u8]>::to_vec)
    }

    /// Runs `f` on the payload of `meta` without copying it out of its cached chunk.
    pub(super) fn with_payload<T>(
        &self,
        meta: &MessageMeta,
        f: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, SessionError> {
        let segment = self.segments.get(meta.segment()).copied();
        match segment {
            Some(Segment::Payload(span)) => {
                let bytes = self.read_span(span)?;
                Ok(f(&bytes))
            }
            Some(Segment::Chunk(span)) => {
                let payloads = self.chunk_payloads(meta.segment(), span, || self.at_meta(meta))?;
                let ordinal = meta.ordinal();
                let found = payloads.messages.get(ordinal as usize).filter(|m| {
                    (m.channel_id, m.sequence, m.log_time_ns)
                        == (meta.channel_id, meta.sequence, meta.log_time_ns)
                });
                let Some(&ChunkMessage { start, end, .. }) = found else {
                    return Err(SessionError::Invalid {
                        at: self.at_meta(meta),
                        what: format!(
                            "message {ordinal} of the chunk at byte {} is not the one indexed (the file changed since it was opened?)",
                            span.offset_bytes
                        ),
                    });
                };
                Ok(f(&payloads.bytes[start..end]))
            }
            None => Err(SessionError::Invalid {
                at: self.at_meta(meta),
                what: "message is not in this reader's index".into(),
            }),
        }
    }

    /// The chunk numbered `segment` (at `span`) decompressed, from the cache or read again;
    /// `at` names it in errors.
    pub(super) fn chunk_payloads(
        &self,
        segment: usize,
        span: ByteSpan,
        at: impl Fn() -> At,
    ) -> Result<Arc<ChunkPayloads>, SessionError> {
        if let Some(p) = self.cache.get(segment) {
            return Ok(p);
        }
        let p = Arc::new(self.load_chunk(span, at)?);
        self.cache.put(segment, Arc::clone(&p));
        Ok(p)
    }

    /// The bytes of `span`, read from the source again.
    fn read_span(&self, span: ByteSpan) -> Result<Vec<u8>, SessionError> {
        self.source
            .read_at(span.offset_bytes, span.len_bytes)
            .map_err(|source| SessionError::Io {
                path: self.path.clone(),
                source,
            })
    }

    /// Reads the chunk record at `span` again and decompresses it; `at` names it in errors.
    fn load_chunk(
        &self,
        span: ByteSpan,
        at: impl Fn() -> At,
    ) -> Result<ChunkPayloads, SessionError> {
        let record = self.read_span(span)?;
        let body_len = span.len_bytes - OPCODE_LEN_BYTES;
        if record.first() != Some(&op::CHUNK)
            || record.get(1..9) != Some(&body_len.to_le_bytes()[..])
        {
            return Err(SessionError::Invalid {
                at: at(),
                what: format!(
                    "no chunk record of {} bytes at byte {} any more (the file changed since it was opened?)",
                    span.len_bytes, span.offset_bytes
                ),
            });
        }
        let mcap_err = |source| SessionError::Mcap {
            at: at(),
            what: format!(
                "the chunk at byte {} read when the file was opened but not now",
                span.offset_bytes
            ),
            cause: source,
        };
        let mut reader = chunk_reader();
        let mut cursor = 0;
        let mut out = ChunkPayloads {
            bytes: Vec::new(),
            messages: Vec::new(),
        };
        while let Some(event) = reader.next_event() {
            match event.map_err(mcap_err)? {
                LinearReadEvent::ReadRequest(n) => {
                    feed_parts(&mut reader, [&record, &[]], &mut cursor, n);
                }
                LinearReadEvent::Record { data, opcode } => {
                    if let Record::Message { header, data } =
                        mcap::parse_record(opcode, data).map_err(mcap_err)?
                    {
                        let start = out.bytes.len();
                        out.bytes.extend_from_slice(&data);
                        out.messages.push(ChunkMessage {
                            channel_id: header.channel_id,
                            sequence: header.sequence,
                            log_time_ns: header.log_time,
                            publish_time_ns: header.publish_time,
                            start,
                            end: out.bytes.len(),
                        });
                    }
                }
            }
        }
        Ok(out)
    }
}
