//! Reads a session MCAP chunk by chunk and hands out its messages in (log_time, channel id,
//! sequence) order, decoded into typed [`crate::io::session::SessionMsg`] values by topic
//! role, loading each payload only when it is decoded.
//!
//! Invariants: the whole file is scanned once, linearly, when opened (chunk CRCs checked), so
//! files without a summary or with a cut-off tail still read and damage is found before any
//! output is made. The scan keeps a chunk index, not a message index: per chunk its byte
//! range, the first log time and the count of its indexed messages (the fields of the MCAP
//! summary's ChunkIndex records, built by the scan so that a file without a summary reads
//! alike), and per channel its count and first and last log time. Memory then grows with the
//! number of chunks (about 48 bytes per chunk of 256 KiB in objloc's sessions), not with the
//! messages. [`SessionReader::ordered`] merges the chunks in order, opening a chunk only when
//! the merge reaches its first log time, so it holds the messages of the chunks that overlap
//! in time (one or two in a recorder's file) and a small cache of decompressed chunks that
//! changes how fast, never what, a message reads. The order is total, (log time, channel id,
//! sequence, place in the file), and the same on every run. A reader opened for the roles
//! ([`IndexScope::Roles`]) scans and checks every record alike but indexes only the messages
//! of channels whose topic has a role: a robot's IMU, lidar and diagnostics add nothing to the
//! index and their chunks are not opened again.
//!
//! Layout: [`index`] is the scan, [`ordered`] the merge, [`source`] the file or memory it
//! reads and the chunk cache, [`decode`] the CDR decoding by role, [`summary`] the
//! summary-section reader of `inspect --quick`.

mod decode;
mod index;
mod ordered;
mod source;
mod summary;
#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::{At, Role, SessionError};
use crate::io::msgs::{CompressedImage, RosMessage};
use source::{ChunkCache, Source};

pub use ordered::Ordered;
pub use summary::{SummarySection, read_summary_section};

const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// No single record of a session comes near this; a corrupt length field beyond it is
/// refused instead of allocated.
const RECORD_LENGTH_LIMIT: usize = 256 << 20;

/// Which messages a reader indexes. Either way every record is scanned and checked alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IndexScope {
    /// Every message (`inspect`, which reports on every topic).
    #[default]
    All,
    /// Only messages on the topics of the reader's [`super::Topics`] roles (a replay, training,
    /// eval): other channels are listed in [`SessionReader::channels`] but have no messages.
    Roles,
}

/// A channel as declared in the file, with its schema.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// MCAP channel id, unique within the file.
    pub id: u16,
    /// Topic name, e.g. `/odom`.
    pub topic: String,
    /// Message encoding, `cdr` for ROS 2.
    pub message_encoding: String,
    /// Schema name as written, `pkg/msg/Type` or `pkg/Type`; empty without a schema.
    pub schema_name: String,
    /// Schema encoding, `ros2msg` for the sessions objloc reads; empty without a schema.
    pub schema_encoding: String,
    /// Schema text, e.g. the `ros2msg` definition; empty without a schema.
    pub schema_data: Vec<u8>,
}

/// Where a message's payload is in the file ([`SessionReader::payload_at`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadAt {
    /// Inside a chunk: the chunk record's offset and the message's ordinal among the chunk's
    /// messages.
    Chunk {
        /// Offset of the chunk record (its opcode byte) from the start of the file.
        offset_bytes: u64,
        /// The message's ordinal among its chunk's messages, 0 for the first.
        ordinal: u32,
    },
    /// A message record outside any chunk: its payload's bytes in the file.
    File {
        /// Offset of the payload's first byte from the start of the file.
        offset_bytes: u64,
        /// Length of the payload.
        len_bytes: u64,
    },
}

/// One message: its header and where its CDR payload is, without the payload (32 bytes).
/// [`SessionReader::ordered`] hands them out; a caller keeps the ones it will decode later
/// (a replay its frames').
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageMeta {
    /// Time the message was recorded, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Time the message was published, ns since the Unix epoch (the log time if unknown).
    pub publish_time_ns: u64,
    /// The payload's place: its segment (chunk or unchunked record, numbered in file order)
    /// in the high 32 bits, its ordinal in the chunk in the low 32. Increases in file order.
    loc: u64,
    /// Sequence number from the MCAP message header, counted per channel by the writer.
    pub sequence: u32,
    /// The [`ChannelInfo::id`] of its channel.
    pub channel_id: u16,
}

impl MessageMeta {
    fn segment(&self) -> usize {
        (self.loc >> 32) as usize
    }

    fn ordinal(&self) -> u32 {
        (self.loc & u64::from(u32::MAX)) as u32
    }
}

/// What holds payloads, in file order: a chunk, or one message record outside any chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Segment {
    /// A chunk record (opcode and length included).
    Chunk(ByteSpan),
    /// The payload of an unchunked message record.
    Payload(ByteSpan),
}

/// A segment the ordered merge opens: a chunk with indexed messages, or one unchunked
/// indexed message: 24 bytes, with its [`Segment`] (24) what the reader keeps per chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Opening {
    /// The least log time of the segment's indexed messages: the merge opens the segment
    /// once no message before this time is left.
    start_ns: u64,
    /// The segment's number in [`SessionReader::segments`].
    segment: u32,
    /// How many of its messages are indexed (checked when the chunk is read again).
    indexed: u32,
    /// The channel of the message at `start_ns` (the first in the file among equals): the
    /// topic an error met when the segment is read again names.
    start_channel: u16,
}

/// A channel's indexed messages: their count and least and greatest log time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelStats {
    /// Number of indexed messages on the channel.
    pub count: u64,
    /// Least log time among them, ns since the Unix epoch.
    pub first_log_time_ns: u64,
    /// Greatest log time among them, ns since the Unix epoch.
    pub last_log_time_ns: u64,
}

impl ChannelStats {
    fn one(log_time_ns: u64) -> Self {
        Self {
            count: 1,
            first_log_time_ns: log_time_ns,
            last_log_time_ns: log_time_ns,
        }
    }

    fn add(&mut self, other: &ChannelStats) {
        self.count += other.count;
        self.first_log_time_ns = self.first_log_time_ns.min(other.first_log_time_ns);
        self.last_log_time_ns = self.last_log_time_ns.max(other.last_log_time_ns);
    }
}

/// A byte range of the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ByteSpan {
    offset_bytes: u64,
    len_bytes: u64,
}

/// A session file's chunk index and channels; its messages come out in (log time, channel
/// id, sequence) order from [`SessionReader::ordered`], their payloads read from the file (or
/// memory) when decoded.
#[derive(Debug)]
pub struct SessionReader {
    path: PathBuf,
    topics: super::Topics,
    /// MCAP header profile, e.g. `ros2`; empty if the file declares none.
    pub profile: String,
    /// MCAP header library: what wrote the file, e.g. `objloc 0.1.0`.
    pub library: String,
    channels: BTreeMap<u16, ChannelInfo>,
    scope: IndexScope,
    /// Channels whose messages are not indexed (no role, under [`IndexScope::Roles`]).
    unindexed: std::collections::BTreeSet<u16>,
    /// (channel id, log time) of the last message scanned in file order, indexed or not:
    /// what errors about the records after it name.
    last_scanned: Option<(u16, u64)>,
    /// Indexed messages per channel.
    stats: BTreeMap<u16, ChannelStats>,
    /// The segments with indexed messages, by (first log time, segment): the merge's plan.
    openings: Vec<Opening>,
    /// Indexed messages outside any chunk, in file order (a file written without chunks).
    loose: Vec<MessageMeta>,
    segments: Vec<Segment>,
    chunk_count: usize,
    source: Source,
    cache: ChunkCache,
    /// Non-fatal problems met while reading (a truncated tail, say).
    pub warnings: Vec<String>,
    /// Bytes of the file that were read as intact records.
    pub bytes_intact: u64,
    /// (topic, log time, previous log time) where a channel's log times went backwards in
    /// file order.
    pub backwards: Vec<(String, u64, u64)>,
    /// Size of the file, bytes.
    pub file_len: u64,
}

/// `pkg/Type` and `pkg/msg/Type` name the same ROS 2 message.
pub fn normalize_type(name: &str) -> String {
    match name.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        _ => name.to_owned(),
    }
}

/// Reads up to `buf.len()` bytes, fewer only at the end of the input.
fn read_full(input: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match input.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

impl SessionReader {
    /// Indexes every message of the session file at `path` in one pass through a buffered
    /// reader; `topics` gives topics their roles. The file stays open: payloads are read from
    /// it on decoding.
    pub fn open(path: &Path, topics: super::Topics) -> Result<Self, SessionError> {
        Self::open_scoped(path, topics, IndexScope::All)
    }

    /// [`SessionReader::open`], indexing the messages `scope` asks for.
    pub fn open_scoped(
        path: &Path,
        topics: super::Topics,
        scope: IndexScope,
    ) -> Result<Self, SessionError> {
        let io = |source| SessionError::Io {
            path: path.to_owned(),
            source,
        };
        let mut file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let mut head = [0u8; 8];
        let head_len = read_full(&mut file, &mut head).map_err(io)?;
        let mut tail = [0u8; 8];
        let tail_len = if file_len >= 2 * MCAP_MAGIC.len() as u64 {
            file.seek(SeekFrom::Start(file_len - MCAP_MAGIC.len() as u64))
                .map_err(io)?;
            read_full(&mut file, &mut tail).map_err(io)?
        } else {
            0
        };
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        let mut me = Self::empty(path, topics, file_len, Source::Memory(Vec::new()));
        me.scope = scope;
        me.check_head(&head[..head_len])?;
        let ends_with_magic = tail_len == MCAP_MAGIC.len() && tail == *MCAP_MAGIC;
        // The `take` keeps the scan to the length seen at opening, as one read of the whole
        // file would: a file still being written is indexed as it was then.
        let mut input = std::io::BufReader::with_capacity(1 << 16, &file).take(file_len);
        me.scan(&mut input, ends_with_magic)?;
        // The same open file serves the payloads: renaming or replacing the path later does
        // not change what is read.
        me.source = Source::file(file);
        me.finish();
        me.check_named_topics()?;
        Ok(me)
    }

    /// Each role whose topic the user named must be in the file, of the role's type, and no
    /// other role's: `--topic cmd_vel=/nonexistent` (or `=/odom`) read as a session without
    /// commands, which turned a robot's session into a capture's without a word.
    fn check_named_topics(&self) -> Result<(), SessionError> {
        for &role in &self.topics.named {
            let topic = self.topics.get(role);
            let err = |what: String| SessionError::NamedTopic {
                path: self.path.clone(),
                role: role.key(),
                topic: topic.to_owned(),
                what,
            };
            let mut channels = self
                .channels
                .values()
                .filter(|c| c.topic == topic)
                .peekable();
            if channels.peek().is_none() {
                let mut names: Vec<&str> =
                    self.channels.values().map(|c| c.topic.as_str()).collect();
                names.sort_unstable();
                names.dedup();
                return Err(err(format!(
                    "the file has no such topic (it has: {})",
                    names.join(", ")
                )));
            }
            if let Some(c) =
                channels.find(|c| normalize_type(&c.schema_name) != role.message_type())
            {
                return Err(err(format!(
                    "it carries {}; the {} role needs {}",
                    c.schema_name,
                    role.key(),
                    role.message_type()
                )));
            }
            if let Some(other) = Role::ALL
                .into_iter()
                .find(|&r| r != role && self.topics.get(r) == topic)
            {
                return Err(err(format!("that is the {} topic too", other.key())));
            }
        }
        Ok(())
    }

    /// Indexes a session held in memory (the bytes are copied: payloads are read from them
    /// on decoding); `path` is only used to name it in errors.
    pub fn from_bytes(
        path: &Path,
        buf: &[u8],
        topics: super::Topics,
    ) -> Result<Self, SessionError> {
        let mut me = Self::empty(path, topics, buf.len() as u64, Source::Memory(buf.to_vec()));
        me.check_head(&buf[..buf.len().min(MCAP_MAGIC.len())])?;
        let ends_with_magic = buf.len() >= 2 * MCAP_MAGIC.len() && buf.ends_with(MCAP_MAGIC);
        let mut input = buf;
        me.scan(&mut input, ends_with_magic)?;
        me.finish();
        me.check_named_topics()?;
        Ok(me)
    }

    /// The same index, read with a cache of at most `chunks` decompressed chunks (at least 1).
    /// The cache changes only how often a chunk is decompressed again, never what is read.
    pub fn with_chunk_cache(mut self, chunks: usize) -> Self {
        self.cache = ChunkCache::new(chunks);
        self
    }

    fn empty(path: &Path, topics: super::Topics, file_len: u64, source: Source) -> Self {
        Self {
            path: path.to_owned(),
            topics,
            profile: String::new(),
            library: String::new(),
            channels: BTreeMap::new(),
            scope: IndexScope::All,
            unindexed: std::collections::BTreeSet::new(),
            last_scanned: None,
            stats: BTreeMap::new(),
            openings: Vec::new(),
            loose: Vec::new(),
            segments: Vec::new(),
            chunk_count: 0,
            source,
            cache: ChunkCache::new(ChunkCache::default_capacity()),
            warnings: Vec::new(),
            bytes_intact: 0,
            backwards: Vec::new(),
            file_len,
        }
    }

    /// Fails unless `head`, the file's first (up to 8) bytes, is the MCAP magic.
    fn check_head(&self, head: &[u8]) -> Result<(), SessionError> {
        if head != MCAP_MAGIC {
            return Err(SessionError::NotMcap {
                path: self.path.clone(),
                head: head.to_vec(),
            });
        }
        Ok(())
    }

    /// Orders the merge's plan by first log time (ties in file order).
    fn finish(&mut self) {
        self.openings
            .sort_unstable_by_key(|o| (o.start_ns, o.segment));
        self.openings.shrink_to_fit();
        self.loose.shrink_to_fit();
        self.segments.shrink_to_fit();
    }

    /// The file read, as named to [`SessionReader::open`] or [`SessionReader::from_bytes`].
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The topic names of the session roles this reader decodes by.
    pub fn topics(&self) -> &super::Topics {
        &self.topics
    }

    /// Every channel declared in the file, by id.
    pub fn channels(&self) -> &BTreeMap<u16, ChannelInfo> {
        &self.channels
    }

    /// Every indexed message (all, or those of the roles: [`IndexScope`]) in a vector, in the
    /// order of [`SessionReader::ordered`]: 32 bytes a message, for tests and small files.
    pub fn collect_index(&self) -> Result<Vec<MessageMeta>, SessionError> {
        self.ordered().collect()
    }

    /// Number of indexed messages.
    pub fn message_count(&self) -> u64 {
        self.stats.values().map(|s| s.count).sum()
    }

    /// The indexed messages of channel `channel_id`: count, first and last log time; `None`
    /// when it has none.
    pub fn channel_stats(&self, channel_id: u16) -> Option<ChannelStats> {
        self.stats.get(&channel_id).copied()
    }

    /// Least and greatest log time of the indexed messages; `None` without any.
    pub fn time_range_ns(&self) -> Option<(u64, u64)> {
        let first = self.stats.values().map(|s| s.first_log_time_ns).min()?;
        let last = self.stats.values().map(|s| s.last_log_time_ns).max()?;
        Some((first, last))
    }

    /// Number of chunks the file holds (before any damage that ended the scan).
    pub fn chunk_count(&self) -> usize {
        self.chunk_count
    }

    /// Where the payload of `meta` (a message this reader handed out) is in the file.
    pub fn payload_at(&self, meta: &MessageMeta) -> Option<PayloadAt> {
        Some(match *self.segments.get(meta.segment())? {
            Segment::Chunk(span) => PayloadAt::Chunk {
                offset_bytes: span.offset_bytes,
                ordinal: meta.ordinal(),
            },
            Segment::Payload(span) => PayloadAt::File {
                offset_bytes: span.offset_bytes,
                len_bytes: span.len_bytes,
            },
        })
    }

    /// Number of messages on `topic` in the index (0 for a topic without a role under
    /// [`IndexScope::Roles`]).
    pub fn count(&self, topic: &str) -> usize {
        let n: u64 = self
            .channels
            .values()
            .filter(|c| c.topic == topic)
            .filter_map(|c| self.stats.get(&c.id))
            .map(|s| s.count)
            .sum();
        usize::try_from(n).unwrap_or(usize::MAX)
    }

    /// A location in this file for errors: `topic`, if given, at log time `log_time_ns`.
    pub fn at(&self, topic: Option<&str>, log_time_ns: u64) -> At {
        At {
            path: self.path.clone(),
            topic: topic.map(str::to_owned),
            log_time_ns: Some(log_time_ns),
        }
    }

    /// The location of `meta` for errors: its topic (when its channel is known) and log time.
    fn at_meta(&self, meta: &MessageMeta) -> At {
        let topic = self
            .channels
            .get(&meta.channel_id)
            .map(|c| c.topic.as_str());
        self.at(topic, meta.log_time_ns)
    }

    /// Fails unless at least one message is on the topic of `role`.
    pub fn require(&self, role: Role) -> Result<(), SessionError> {
        let topic = self.topics.get(role);
        if self.count(topic) == 0 {
            return Err(SessionError::MissingTopic {
                path: self.path.clone(),
                topic: topic.to_owned(),
                type_name: role.message_type(),
                why: self.why_missing(&[role]),
            });
        }
        Ok(())
    }

    /// Fails unless frames (compressed or raw) are present.
    pub fn require_frames(&self) -> Result<(), SessionError> {
        if self.count(&self.topics.compressed_image) + self.count(&self.topics.image) == 0 {
            return Err(SessionError::MissingTopic {
                path: self.path.clone(),
                topic: format!("{} or {}", self.topics.compressed_image, self.topics.image),
                type_name: CompressedImage::TYPE,
                why: self.why_missing(&[Role::CompressedImage, Role::Image]),
            });
        }
        Ok(())
    }

    /// The topics whose schema is `type_name` (`pkg/msg/Type`, or `pkg/Type` as ROS 1 and
    /// some writers name it), in channel order: where a role's messages may be under
    /// another name.
    pub fn topics_carrying(&self, type_name: &str) -> Vec<&str> {
        let short = type_name.replace("/msg/", "/");
        self.channels
            .values()
            .filter(|c| c.schema_name == type_name || c.schema_name == short)
            .map(|c| c.topic.as_str())
            .collect()
    }

    /// The end of the error of a missing topic in one of `roles`: the topics that carry the
    /// role's type under another name (`--topic` can name them), and what the reader warned
    /// of (a file cut short in its first chunk said only that a topic was missing).
    fn why_missing(&self, roles: &[Role]) -> String {
        let mut why = String::new();
        for role in roles {
            let wanted = role.message_type();
            let others = self.topics_carrying(wanted);
            if let Some(first) = others.first() {
                why.push_str(&format!(
                    "; the file has {wanted} on {} (--topic {}={first})",
                    others.join(", "),
                    role.key()
                ));
            }
        }
        if let Some(w) = self.warnings.first() {
            why.push_str(&format!("; {w}"));
        }
        why
    }
}
