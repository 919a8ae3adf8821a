//! The index pass: one linear read of the file that keeps, per chunk, its byte range, the
//! first log time and count of its indexed messages, and per channel its message count and
//! first and last log time; channels and schemas are taken as met.
//!
//! Invariants: the outer MCAP reader hands out whole top-level records (chunks undecoded) and
//! requests exactly the bytes it needs, so the bytes fed to it when it yields a record end that
//! record: the record starts `9 + body length` bytes earlier. Each chunk is opened by a second
//! reader with its CRC checked before any of its records is yielded (mcap's decompression
//! and checks, nothing of ours). A chunk enters the index whole or not at all: when the file
//! runs out inside one, its messages are dropped with the truncation warning, so every indexed
//! payload can be read again. Errors keep the wording of the reader that held every payload.

use std::collections::BTreeMap;
use std::io::Read;

use mcap::McapError;
use mcap::records::{Record, op};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::super::{At, SessionError};
use super::{
    ByteSpan, ChannelInfo, ChannelStats, IndexScope, MessageMeta, Opening, RECORD_LENGTH_LIMIT,
    Segment, SessionReader, read_full,
};

/// MCAP records start with an opcode (1 byte) and a 64-bit length (8 bytes).
pub(super) const OPCODE_LEN_BYTES: u64 = 1 + 8;

/// Largest read handed to the outer reader at once: its buffer grows by this much at most
/// per read, whatever length a (possibly corrupt) record claims.
const READ_BLOCK_BYTES: usize = 1 << 20;

/// Schemas by id: (name, encoding, data).
type Schemas = BTreeMap<u16, (String, String, Vec<u8>)>;

/// The indexed messages of the chunk being scanned, committed when it ends whole.
#[derive(Default)]
struct Tally {
    start_ns: Option<u64>,
    start_channel: u16,
    count: u32,
    stats: BTreeMap<u16, ChannelStats>,
}

impl Tally {
    fn add(&mut self, meta: &MessageMeta) {
        if self.start_ns.is_none_or(|t| meta.log_time_ns < t) {
            self.start_ns = Some(meta.log_time_ns);
            self.start_channel = meta.channel_id;
        }
        self.count += 1;
        let one = ChannelStats::one(meta.log_time_ns);
        self.stats
            .entry(meta.channel_id)
            .and_modify(|s| s.add(&one))
            .or_insert(one);
    }
}

/// What the scan carries from record to record.
#[derive(Default)]
struct ScanState {
    schemas: Schemas,
    /// Each channel's last log time in file order, for the backwards check.
    last_time: BTreeMap<u16, u64>,
    /// Bytes handed to the outer reader so far.
    fed_bytes: u64,
    /// Whether the file ends with the MCAP magic (written to the end: not truncated).
    ends_with_magic: bool,
    /// Messages met, indexed or not.
    scanned: u64,
    /// The message count of the summary's Statistics record, when the file has one.
    stated: Option<u64>,
    /// Whether the data section's end record was read: what follows is the summary, which
    /// indexes the data but holds none of it.
    data_end: bool,
    /// Where the first record after the data section's end begins: the summary's start, or
    /// the footer's own when the file has no summary (the footer must then say 0).
    after_data_end_bytes: Option<u64>,
    /// What is wrong with the footer's summary offset, said unless the summary's message
    /// count already tells that records were cut out (which moves the summary too).
    footer_warning: Option<String>,
}

/// Whether a scan step lets the scan go on.
enum Step {
    Go,
    /// The file is truncated; the warning is recorded.
    Stop,
}

/// The reader of one chunk record's inner records: mcap decompresses it and checks its CRC
/// before yielding any of them.
pub(super) fn chunk_reader() -> LinearReader {
    LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(RECORD_LENGTH_LIMIT),
    )
}

/// Serves `reader`'s request for `n` bytes from `parts` (read in order from `*cursor`);
/// nothing left tells it the input has ended.
pub(super) fn feed_parts(
    reader: &mut LinearReader,
    parts: [&[u8]; 2],
    cursor: &mut usize,
    n: usize,
) {
    let (first, second) = (parts[0], parts[1]);
    let rest = if *cursor < first.len() {
        &first[*cursor..]
    } else {
        &second[(*cursor - first.len()).min(second.len())..]
    };
    let n = n.min(rest.len());
    reader.insert(n).copy_from_slice(&rest[..n]);
    reader.notify_read(n);
    *cursor += n;
}

/// The opcode and length that precede a chunk record's body of `body_len` bytes.
pub(super) fn chunk_prefix(body_len: usize) -> [u8; 9] {
    let mut prefix = [0u8; 9];
    prefix[0] = op::CHUNK;
    prefix[1..].copy_from_slice(&(body_len as u64).to_le_bytes());
    prefix
}

impl SessionReader {
    /// The last message indexed so far (file order), for errors about what follows it.
    /// Where the damage lies against the messages read: after the one [`Self::at_last`]
    /// names, or before the first (then no message is named).
    fn after_what(&self) -> &'static str {
        if self.last_scanned.is_some() {
            "after the message named here"
        } else {
            "before the first message"
        }
    }

    /// What the summary's chunk index says of the chunk at `offset_bytes` (where damage was
    /// met): the log times of its messages, which the scan could not read. Empty when the
    /// file's summary does not read or does not index such a chunk.
    fn damaged_chunk_times(&self, offset_bytes: u64) -> String {
        let Ok(Some(summary)) = super::summary::read_summary_section(&self.path) else {
            return String::new();
        };
        summary
            .chunks
            .iter()
            .find(|&&(start, _, _)| start == offset_bytes)
            .map_or_else(String::new, |&(_, first, last)| {
                format!(
                    "; the summary's chunk index puts messages logged from {} to {} in the chunk there",
                    super::super::fmt_ns(first),
                    super::super::fmt_ns(last)
                )
            })
    }

    fn at_last(&self) -> At {
        // The last message scanned, indexed or not: under IndexScope::Roles the last indexed
        // one can lie far before the damage.
        match self.last_scanned {
            Some((channel_id, log_time_ns)) => At {
                topic: self.channels.get(&channel_id).map(|c| c.topic.clone()),
                ..self.at(None, log_time_ns)
            },
            None => At {
                path: self.path.clone(),
                topic: None,
                log_time_ns: None,
            },
        }
    }

    /// The one pass over `input`, the whole file from its first byte.
    pub(super) fn scan(
        &mut self,
        input: &mut impl Read,
        ends_with_magic: bool,
    ) -> Result<(), SessionError> {
        let opts = LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_record_length_limit(RECORD_LENGTH_LIMIT);
        let mut reader = LinearReader::new_with_options(opts);
        let mut st = ScanState {
            ends_with_magic,
            ..ScanState::default()
        };
        while let Some(event) = reader.next_event() {
            let step = match event {
                Ok(LinearReadEvent::ReadRequest(n)) => {
                    let left = self.file_len.saturating_sub(st.fed_bytes);
                    let n = n
                        .min(READ_BLOCK_BYTES)
                        .min(usize::try_from(left).unwrap_or(n));
                    let got =
                        read_full(input, reader.insert(n)).map_err(|source| SessionError::Io {
                            path: self.path.clone(),
                            source,
                        })?;
                    reader.notify_read(got);
                    st.fed_bytes += got as u64;
                    Step::Go
                }
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    // Saturating: a wrong offset is caught when the chunk is read again (its
                    // opcode and length are checked there), never a panic here.
                    let offset_bytes = st
                        .fed_bytes
                        .saturating_sub(OPCODE_LEN_BYTES + data.len() as u64);
                    if opcode == op::CHUNK {
                        self.take_chunk(data, offset_bytes, &mut st)?
                    } else {
                        match self.parse(opcode, data) {
                            Ok(record) => {
                                if st.data_end && st.after_data_end_bytes.is_none() {
                                    st.after_data_end_bytes = Some(offset_bytes);
                                }
                                if let Record::Footer(f) = &record {
                                    st.footer_warning = self.footer_problem(f, offset_bytes, &st);
                                }
                                self.take_top_level(record, offset_bytes, data.len(), &mut st)?;
                                self.bytes_intact = st.fed_bytes;
                                st.data_end |= opcode == op::DATA_END;
                                Step::Go
                            }
                            Err(e) if st.data_end && st.ends_with_magic => {
                                self.summary_damaged(&e.to_string())
                            }
                            Err(e) => return Err(e),
                        }
                    }
                }
                // A file cut inside its summary is truncated, and said so as any other.
                Err(source) if st.data_end && st.ends_with_magic => {
                    self.summary_damaged(&source.to_string())
                }
                Err(source) => {
                    let ran_out = self.runs_out(&source, &st);
                    self.failed(source, ran_out, &st)?
                }
            };
            if let Step::Stop = step {
                break;
            }
        }
        // A file written to the end whose summary counts other messages than it holds has
        // lost (or gained) records since: a chunk cut out leaves no other trace in a scan.
        let counted = st
            .stated
            .filter(|&n| n != st.scanned && self.warnings.is_empty());
        if let Some(n) = counted {
            self.warnings.push(format!(
                "{}: its summary counts {n} messages, the file holds {}: records are missing or were added after the summary was written",
                self.path.display(),
                st.scanned
            ));
        }
        // Records cut out move the summary too: the count says what happened.
        if let Some(w) = st.footer_warning.take().filter(|_| counted.is_none()) {
            self.warnings.push(w);
        }
        if self.channels.is_empty() && self.stats.is_empty() && self.warnings.is_empty() {
            self.warnings
                .push("file holds no channels and no messages".to_owned());
        }
        Ok(())
    }

    /// The footer's summary offset must point where the summary begins (0 without one):
    /// this scan does not need it, but `inspect --quick` and other tools seek by it, so a
    /// wrong one is said (a footer pointing past the end read silently before).
    fn footer_problem(
        &self,
        footer: &mcap::records::Footer,
        footer_bytes: u64,
        st: &ScanState,
    ) -> Option<String> {
        if !st.data_end {
            return None; // no data end record: where the summary would begin is not known
        }
        let expected = match st.after_data_end_bytes {
            Some(at) if at != footer_bytes => at,
            _ => 0,
        };
        (footer.summary_start != expected).then(|| {
            format!(
                "{}: the footer says the summary starts at byte {}, but {}; tools that seek by it (inspect --quick, mcap info) will fail, and this scan read every message without it",
                self.path.display(),
                footer.summary_start,
                if expected == 0 {
                    "the file has no summary (it should say 0)".to_owned()
                } else {
                    format!("it starts at byte {expected}")
                }
            )
        })
    }

    /// One record's fields, or an error naming the last message before it.
    fn parse<'a>(&self, opcode: u8, data: &'a [u8]) -> Result<Record<'a>, SessionError> {
        mcap::parse_record(opcode, data).map_err(|source| SessionError::Mcap {
            at: self.at_last(),
            what: match self.last_scanned {
                Some(_) => {
                    format!("a record (opcode {opcode:#04x}) after this message does not parse")
                }
                None => {
                    format!("a record (opcode {opcode:#04x}) before any message does not parse")
                }
            },
            cause: source,
        })
    }

    /// A record outside any chunk; a message's payload is located by its file offset.
    fn take_top_level(
        &mut self,
        record: Record<'_>,
        offset_bytes: u64,
        body_len: usize,
        st: &mut ScanState,
    ) -> Result<(), SessionError> {
        if let Record::Statistics(stats) = &record {
            st.stated = Some(stats.message_count);
        }
        if let Record::Message { header, data } = &record {
            // The payload is the tail of the record's body, after the message header.
            let span = ByteSpan {
                offset_bytes: offset_bytes + OPCODE_LEN_BYTES + (body_len - data.len()) as u64,
                len_bytes: data.len() as u64,
            };
            let segment = self.next_segment()?;
            if let Some(meta) = self.take_message(header, segment, st)? {
                let mut tally = Tally::default();
                tally.add(&meta);
                self.commit(tally, segment);
                self.loose.push(meta);
            }
            self.segments.push(Segment::Payload(span));
            return Ok(());
        }
        self.take_record(record, st)
    }

    /// Indexes the chunk record with body `body` at `offset_bytes`, or, when it does not
    /// read, errors or (in a truncated file) warns and stops.
    fn take_chunk(
        &mut self,
        body: &[u8],
        offset_bytes: u64,
        st: &mut ScanState,
    ) -> Result<Step, SessionError> {
        let segment = self.next_segment()?;
        let mut tally = Tally::default();
        let kept_backwards = self.backwards.len();
        let (kept_bytes, kept_last, kept_scanned) =
            (self.bytes_intact, self.last_scanned, st.scanned);
        let prefix = chunk_prefix(body.len());
        let mut reader = chunk_reader();
        let mut cursor = 0;
        let mut ordinal = 0u32;
        while let Some(event) = reader.next_event() {
            match event {
                Ok(LinearReadEvent::ReadRequest(n)) => {
                    feed_parts(&mut reader, [&prefix, body], &mut cursor, n);
                }
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    match self.parse(opcode, data)? {
                        Record::Message { header, .. } => {
                            let loc = segment | u64::from(ordinal);
                            if let Some(meta) = self.take_message(&header, loc, st)? {
                                tally.add(&meta);
                            }
                            ordinal =
                                ordinal
                                    .checked_add(1)
                                    .ok_or_else(|| SessionError::Invalid {
                                        at: self.at_last(),
                                        what: "a chunk holds more than 2^32 messages".into(),
                                    })?;
                        }
                        other => self.take_record(other, st)?,
                    }
                    self.bytes_intact = st.fed_bytes;
                }
                Err(source) => {
                    let ran_out = Self::chunk_runs_out(&source);
                    if ran_out && !st.ends_with_magic {
                        // Only whole chunks are indexed (the tally is dropped), so every indexed
                        // payload reads again.
                        self.backwards.truncate(kept_backwards);
                        self.bytes_intact = kept_bytes;
                        self.last_scanned = kept_last;
                        st.scanned = kept_scanned;
                    }
                    return self.failed(source, ran_out, st);
                }
            }
        }
        self.commit(tally, segment);
        self.segments.push(Segment::Chunk(ByteSpan {
            offset_bytes,
            len_bytes: OPCODE_LEN_BYTES + body.len() as u64,
        }));
        self.chunk_count += 1;
        Ok(Step::Go)
    }

    /// Adds a whole segment's indexed messages to the channels' stats and the merge's plan.
    fn commit(&mut self, tally: Tally, segment_loc: u64) {
        let Some(start_ns) = tally.start_ns else {
            return;
        };
        for (channel_id, s) in &tally.stats {
            self.stats
                .entry(*channel_id)
                .and_modify(|t| t.add(s))
                .or_insert(*s);
        }
        self.openings.push(Opening {
            start_ns,
            // `next_segment` checked that the number fits in 32 bits.
            segment: (segment_loc >> 32) as u32,
            indexed: tally.count,
            start_channel: tally.start_channel,
        });
    }

    /// The `loc` of the next segment's first message (its number in the high 32 bits).
    fn next_segment(&self) -> Result<u64, SessionError> {
        let n = u32::try_from(self.segments.len()).map_err(|_| SessionError::Invalid {
            at: self.at_last(),
            what: "the file holds more than 2^32 chunks and unchunked messages".into(),
        })?;
        Ok(u64::from(n) << 32)
    }

    /// Whether the outer reader's error `e` means it ran out of data: `UnexpectedEof`, or a
    /// chunk claiming more bytes than the file has left. A recorder killed mid-chunk leaves
    /// such a chunk: mcap's writer puts a placeholder length (2^64 - 1) before the chunk's
    /// data and fills it in when the chunk is complete.
    fn runs_out(&self, e: &McapError, st: &ScanState) -> bool {
        match e {
            McapError::UnexpectedEof | McapError::UnexpectedEoc => true,
            McapError::RecordTooLarge { opcode, len } => {
                *opcode == op::CHUNK && *len > self.file_len.saturating_sub(st.fed_bytes)
            }
            _ => false,
        }
    }

    /// Whether an error inside a chunk means the chunk ran out of data (`UnexpectedEof`, or
    /// `UnexpectedEoc` when its compressed stream stops short).
    fn chunk_runs_out(e: &McapError) -> bool {
        matches!(e, McapError::UnexpectedEof | McapError::UnexpectedEoc)
    }

    /// Damage after the data section's end record: every message was read, only the
    /// summary (an index of the data) is lost. A warning, and the scan stops; a zeroed summary
    /// refused the whole file.
    fn summary_damaged(&mut self, what: &str) -> Step {
        self.warnings.push(format!(
            "{}: the summary section after byte {} does not read ({what}); every message up to the data section's end was read",
            self.path.display(),
            self.bytes_intact
        ));
        Step::Stop
    }

    /// The scan's reaction to a reader error: a warning and stop for truncation, else the
    /// error naming the last message before the damage. Running out of data (`ran_out`) is
    /// truncation only if the file lacks its closing magic.
    fn failed(
        &mut self,
        source: McapError,
        ran_out: bool,
        st: &ScanState,
    ) -> Result<Step, SessionError> {
        match source {
            // A file that still ends with the magic was written to the end, so the cause is a
            // damaged length field: reading that as truncation would drop every later chunk
            // under a false warning.
            source if ran_out && st.ends_with_magic => Err(SessionError::Mcap {
                at: self.at_last(),
                what: format!(
                    "damaged data after byte {} ({}; the file ends with the MCAP magic, so it is not truncated{})",
                    self.bytes_intact,
                    self.after_what(),
                    self.damaged_chunk_times(self.bytes_intact)
                ),
                cause: source,
            }),
            _ if ran_out => {
                let at = self.at_last();
                // The warning names the file: commands print it beside other files' warnings.
                let last = match (at.topic, at.log_time_ns) {
                    (Some(t), Some(ns)) => format!("{t} at {}", super::super::fmt_ns(ns)),
                    _ => "none".to_owned(),
                };
                // Cut right after a whole record (a recording that was never closed): what is
                // missing is the summary, not data anyone knows of.
                let lost = if self.bytes_intact >= self.file_len {
                    "it ends after a whole record, without the summary and footer of a closed recording"
                } else {
                    "the rest is lost"
                };
                self.warnings.push(format!(
                    "file is truncated: read {} messages from the first {} of {} bytes of {}; {lost} (last intact message: {last})",
                    st.scanned,
                    self.bytes_intact,
                    self.file_len,
                    self.path.display(),
                ));
                Ok(Step::Stop)
            }
            source => Err(SessionError::Mcap {
                at: self.at_last(),
                what: format!(
                    "damaged data after byte {} ({}{})",
                    self.bytes_intact,
                    self.after_what(),
                    self.damaged_chunk_times(self.bytes_intact)
                ),
                cause: source,
            }),
        }
    }

    /// Scans one message: its channel must be known; a log time before the channel's
    /// previous one (in file order) is noted. Returns its meta when it is indexed.
    fn take_message(
        &mut self,
        header: &mcap::records::MessageHeader,
        loc: u64,
        st: &mut ScanState,
    ) -> Result<Option<MessageMeta>, SessionError> {
        st.scanned += 1;
        let prev = st.last_time.insert(header.channel_id, header.log_time);
        if let Some(prev) = prev.filter(|p| *p > header.log_time) {
            let topic = self
                .channels
                .get(&header.channel_id)
                .map(|c| c.topic.clone())
                .unwrap_or_default();
            self.backwards.push((topic, header.log_time, prev));
        }
        if !self.channels.contains_key(&header.channel_id) {
            return Err(SessionError::Invalid {
                at: At {
                    path: self.path.clone(),
                    topic: None,
                    log_time_ns: Some(header.log_time),
                },
                what: format!("message refers to unknown channel {}", header.channel_id),
            });
        }
        self.last_scanned = Some((header.channel_id, header.log_time));
        if self.unindexed.contains(&header.channel_id) {
            return Ok(None);
        }
        Ok(Some(MessageMeta {
            channel_id: header.channel_id,
            sequence: header.sequence,
            log_time_ns: header.log_time,
            publish_time_ns: header.publish_time,
            loc,
        }))
    }

    /// Takes a header, schema or channel record; other records (indexes, statistics,
    /// attachments) are not needed.
    fn take_record(&mut self, record: Record<'_>, st: &mut ScanState) -> Result<(), SessionError> {
        let schemas = &mut st.schemas;
        match record {
            Record::Header(h) => {
                self.profile = h.profile;
                self.library = h.library;
            }
            Record::Schema { header, data } => {
                schemas.insert(header.id, (header.name, header.encoding, data.into_owned()));
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding, schema_data) = if c.schema_id == 0 {
                    Default::default()
                } else {
                    schemas
                        .get(&c.schema_id)
                        .cloned()
                        .ok_or_else(|| SessionError::Invalid {
                            at: At {
                                path: self.path.clone(),
                                topic: Some(c.topic.clone()),
                                log_time_ns: None,
                            },
                            what: format!(
                                "channel {} refers to unknown schema {}",
                                c.id, c.schema_id
                            ),
                        })?
                };
                // Whether indexed follows the channel's latest declaration, as its topic does.
                let indexed =
                    self.scope == IndexScope::All || self.topics.role_of(&c.topic).is_some();
                // The merge reads the final declaration: a channel whose messages would be
                // indexed on one side of a declaration and not on the other is refused (the
                // MCAP spec asks every declaration of an id to be the same).
                let was_indexed = !self.unindexed.contains(&c.id);
                if indexed != was_indexed && st.last_time.contains_key(&c.id) {
                    let before = self.channels.get(&c.id).map_or("", |o| o.topic.as_str());
                    return Err(SessionError::Invalid {
                        at: At {
                            path: self.path.clone(),
                            topic: Some(c.topic.clone()),
                            log_time_ns: st.last_time.get(&c.id).copied(),
                        },
                        what: format!(
                            "channel {} is declared again on another topic ({before} before) after messages on it",
                            c.id
                        ),
                    });
                }
                if indexed {
                    self.unindexed.remove(&c.id);
                } else {
                    self.unindexed.insert(c.id);
                }
                self.channels.insert(
                    c.id,
                    ChannelInfo {
                        id: c.id,
                        topic: c.topic,
                        message_encoding: c.message_encoding,
                        schema_name,
                        schema_encoding,
                        schema_data,
                    },
                );
            }
            _ => {}
        }
        Ok(())
    }
}
