//! Reads a session MCAP into raw messages sorted by (log_time, channel id, sequence), and
//! decodes them into typed [`SessionMsg`] values by topic role.
//!
//! Invariants: the whole file is scanned linearly (chunk CRCs checked), so files without a
//! summary or with a cut-off tail still read; the sort is stable, so the order is total and
//! the same on every run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::McapError;
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::{At, Frame, FramePixels, Role, SessionError, SessionMsg, TimedMsg, Topics};
use crate::io::msgs::{
    CameraInfo, CompressedImage, GroundTruth, Image, ObjectLabel, Odometry, PoseStamped,
    RosMessage, TfMessage, TwistStamped,
};

const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// No single record of a session comes near this; a corrupt length field beyond it is
/// refused instead of allocated.
const RECORD_LENGTH_LIMIT: usize = 256 << 20;

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

/// A message still in CDR.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawMessage {
    /// The [`ChannelInfo::id`] of its channel.
    pub channel_id: u16,
    /// Sequence number from the MCAP message header, counted per channel by the writer.
    pub sequence: u32,
    /// Time the message was recorded, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// Time the message was published, ns since the Unix epoch (the log time if unknown).
    pub publish_time_ns: u64,
    /// The CDR payload, encapsulation header included.
    pub data: Vec<u8>,
}

/// A session file read into memory: its channels and all its messages, sorted by
/// (log time, channel id, sequence), still in CDR until decoded.
#[derive(Debug)]
pub struct SessionReader {
    path: PathBuf,
    topics: Topics,
    /// MCAP header profile, e.g. `ros2`; empty if the file declares none.
    pub profile: String,
    /// MCAP header library: what wrote the file, e.g. `objloc 0.1.0`.
    pub library: String,
    channels: BTreeMap<u16, ChannelInfo>,
    messages: Vec<RawMessage>,
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

impl SessionReader {
    /// Reads the session file at `path`; `topics` gives topics their roles.
    pub fn open(path: &Path, topics: Topics) -> Result<Self, SessionError> {
        let buf = std::fs::read(path).map_err(|source| SessionError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(path, &buf, topics)
    }

    /// Reads a session from memory; `path` is only used to name it in errors.
    pub fn from_bytes(path: &Path, buf: &[u8], topics: Topics) -> Result<Self, SessionError> {
        if buf.len() < MCAP_MAGIC.len() || &buf[..MCAP_MAGIC.len()] != MCAP_MAGIC {
            return Err(SessionError::NotMcap {
                path: path.to_owned(),
                head: buf.iter().take(8).copied().collect(),
            });
        }
        let mut me = Self {
            path: path.to_owned(),
            topics,
            profile: String::new(),
            library: String::new(),
            channels: BTreeMap::new(),
            messages: Vec::new(),
            warnings: Vec::new(),
            bytes_intact: 0,
            backwards: Vec::new(),
            file_len: buf.len() as u64,
        };
        me.scan(buf)?;
        // Stable: equal keys keep file order, so the order is total and reproducible.
        me.messages
            .sort_by_key(|m| (m.log_time_ns, m.channel_id, m.sequence));
        Ok(me)
    }

    fn at_last(&self) -> At {
        let last = self.messages.last();
        At {
            path: self.path.clone(),
            topic: last.and_then(|m| self.channels.get(&m.channel_id).map(|c| c.topic.clone())),
            log_time_ns: last.map(|m| m.log_time_ns),
        }
    }

    fn scan(&mut self, buf: &[u8]) -> Result<(), SessionError> {
        // Prevalidate: a chunk's CRC is checked before any of its records is handed out, so a
        // damaged chunk contributes no message and errors name the last message before it.
        let opts = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(RECORD_LENGTH_LIMIT);
        let mut reader = LinearReader::new_with_options(opts);
        let mut schemas: BTreeMap<u16, (String, String, Vec<u8>)> = BTreeMap::new();
        let mut cursor = 0usize;
        let mut last_time: BTreeMap<u16, u64> = BTreeMap::new();
        loop {
            let event = match reader.next_event() {
                None => break,
                Some(e) => e,
            };
            match event {
                Ok(LinearReadEvent::ReadRequest(n)) => {
                    let n = n.min(buf.len() - cursor);
                    reader.insert(n).copy_from_slice(&buf[cursor..cursor + n]);
                    reader.notify_read(n);
                    cursor += n;
                }
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    let record =
                        mcap::parse_record(opcode, data).map_err(|source| SessionError::Mcap {
                            at: self.at_last(),
                            what: format!(
                                "record (opcode {opcode:#04x}) after this does not parse"
                            ),
                            source,
                        })?;
                    if let Record::Message { header, .. } = &record {
                        let prev = last_time.insert(header.channel_id, header.log_time);
                        if let Some(prev) = prev.filter(|p| *p > header.log_time) {
                            let topic = self
                                .channels
                                .get(&header.channel_id)
                                .map(|c| c.topic.clone())
                                .unwrap_or_default();
                            self.backwards.push((topic, header.log_time, prev));
                        }
                    }
                    self.take_record(record, &mut schemas)?;
                    self.bytes_intact = cursor as u64;
                }
                // Running out of data (`UnexpectedEof`, or `UnexpectedEoc` when a chunk's
                // compressed stream stops short) is truncation only if the file lacks its closing
                // magic. A file that still ends with it was written to the end, so the cause is a
                // damaged length field: reading that as truncation would drop every later chunk
                // under a false warning.
                Err(source @ (McapError::UnexpectedEof | McapError::UnexpectedEoc))
                    if buf.len() >= 2 * MCAP_MAGIC.len() && buf.ends_with(MCAP_MAGIC) =>
                {
                    return Err(SessionError::Mcap {
                        at: self.at_last(),
                        what: format!(
                            "damaged data after byte {} (after the message named here; the file ends with the MCAP magic, so it is not truncated)",
                            self.bytes_intact
                        ),
                        source,
                    });
                }
                Err(McapError::UnexpectedEof | McapError::UnexpectedEoc) => {
                    let at = self.at_last();
                    // The warning names the file: commands print it beside other files' warnings.
                    self.warnings.push(format!(
                        "file is truncated: read {} messages from the first {} of {} bytes of {}; the rest is lost (last intact message: {})",
                        self.messages.len(),
                        self.bytes_intact,
                        self.file_len,
                        self.path.display(),
                        match (at.topic, at.log_time_ns) {
                            (Some(t), Some(ns)) => format!("{t} at {}", super::fmt_ns(ns)),
                            _ => "none".to_owned(),
                        }
                    ));
                    break;
                }
                Err(source) => {
                    return Err(SessionError::Mcap {
                        at: self.at_last(),
                        what: format!(
                            "damaged data after byte {} (after the message named here)",
                            self.bytes_intact
                        ),
                        source,
                    });
                }
            }
        }
        if self.channels.is_empty() && self.messages.is_empty() && self.warnings.is_empty() {
            self.warnings
                .push("file holds no channels and no messages".to_owned());
        }
        Ok(())
    }

    fn take_record(
        &mut self,
        record: Record<'_>,
        schemas: &mut BTreeMap<u16, (String, String, Vec<u8>)>,
    ) -> Result<(), SessionError> {
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
            Record::Message { header, data } => {
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
                self.messages.push(RawMessage {
                    channel_id: header.channel_id,
                    sequence: header.sequence,
                    log_time_ns: header.log_time,
                    publish_time_ns: header.publish_time,
                    data: data.into_owned(),
                });
            }
            _ => {}
        }
        Ok(())
    }

    /// The file read, as named to [`SessionReader::open`] or [`SessionReader::from_bytes`].
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The topic names of the session roles this reader decodes by.
    pub fn topics(&self) -> &Topics {
        &self.topics
    }

    /// Every channel declared in the file, by id.
    pub fn channels(&self) -> &BTreeMap<u16, ChannelInfo> {
        &self.channels
    }

    /// All messages in (log_time, channel id, sequence) order.
    pub fn raw_messages(&self) -> &[RawMessage] {
        &self.messages
    }

    /// Number of messages on `topic`.
    pub fn count(&self, topic: &str) -> usize {
        let ids: Vec<u16> = self
            .channels
            .values()
            .filter(|c| c.topic == topic)
            .map(|c| c.id)
            .collect();
        self.messages
            .iter()
            .filter(|m| ids.contains(&m.channel_id))
            .count()
    }

    /// The channel of `raw`; present for every message (checked when read).
    fn channel(&self, raw: &RawMessage) -> Result<&ChannelInfo, SessionError> {
        self.channels
            .get(&raw.channel_id)
            .ok_or_else(|| SessionError::Invalid {
                at: self.at(None, raw.log_time_ns),
                what: format!("unknown channel {}", raw.channel_id),
            })
    }

    /// A location in this file for errors: `topic`, if given, at log time `log_time_ns`.
    pub fn at(&self, topic: Option<&str>, log_time_ns: u64) -> At {
        At {
            path: self.path.clone(),
            topic: topic.map(str::to_owned),
            log_time_ns: Some(log_time_ns),
        }
    }

    /// The role of a channel's topic, after checking its encoding and schema fit that role.
    pub fn channel_role(
        &self,
        channel: &ChannelInfo,
        log_time_ns: u64,
    ) -> Result<Option<Role>, SessionError> {
        let Some(role) = self.topics.role_of(&channel.topic) else {
            return Ok(None);
        };
        let at = || self.at(Some(&channel.topic), log_time_ns);
        if channel.message_encoding != "cdr" {
            return Err(SessionError::Encoding {
                at: at(),
                found: channel.message_encoding.clone(),
            });
        }
        if channel.schema_encoding != "ros2msg" {
            return Err(SessionError::SchemaEncoding {
                at: at(),
                found: channel.schema_encoding.clone(),
            });
        }
        if normalize_type(&channel.schema_name) != role.message_type() {
            return Err(SessionError::WrongType {
                at: at(),
                expected: role.message_type(),
                found: channel.schema_name.clone(),
            });
        }
        Ok(Some(role))
    }

    /// Decodes one message; `Ok(None)` for topics that play no role in a session.
    pub fn decode(&self, raw: &RawMessage) -> Result<Option<TimedMsg>, SessionError> {
        let channel = self.channel(raw)?;
        let Some(role) = self.channel_role(channel, raw.log_time_ns)? else {
            return Ok(None);
        };
        let err = |source| SessionError::Decode {
            at: self.at(Some(&channel.topic), raw.log_time_ns),
            type_name: role.message_type().to_owned(),
            source,
        };
        let d = &raw.data;
        let msg = match role {
            Role::CompressedImage => {
                let m = CompressedImage::from_cdr(d).map_err(err)?;
                SessionMsg::Frame(Frame {
                    stamp_ns: m.header.stamp_ns,
                    frame_id: m.header.frame_id,
                    pixels: FramePixels::Encoded {
                        format: m.format,
                        data: m.data,
                    },
                })
            }
            Role::Image => {
                let m = Image::from_cdr(d).map_err(err)?;
                SessionMsg::Frame(Frame {
                    stamp_ns: m.header.stamp_ns,
                    frame_id: m.header.frame_id.clone(),
                    pixels: FramePixels::Raw(m),
                })
            }
            Role::CameraInfo => {
                SessionMsg::CameraInfo(Box::new(CameraInfo::from_cdr(d).map_err(err)?))
            }
            Role::TfStatic => SessionMsg::TfStatic(TfMessage::from_cdr(d).map_err(err)?),
            Role::Tf => SessionMsg::Tf(TfMessage::from_cdr(d).map_err(err)?),
            Role::Odom => SessionMsg::Odom(Box::new(Odometry::from_cdr(d).map_err(err)?)),
            Role::CmdVel => SessionMsg::CmdVel(TwistStamped::from_cdr(d).map_err(err)?),
            Role::Labels => SessionMsg::Label(ObjectLabel::from_cdr(d).map_err(err)?),
            Role::GroundTruthPose => {
                SessionMsg::GroundTruthPose(PoseStamped::from_cdr(d).map_err(err)?)
            }
            Role::GroundTruthObjects => {
                SessionMsg::GroundTruthObjects(GroundTruth::from_cdr(d).map_err(err)?)
            }
        };
        Ok(Some(TimedMsg {
            log_time_ns: raw.log_time_ns,
            topic: channel.topic.clone(),
            msg,
        }))
    }

    /// Every message with a role, decoded, in replay order.
    pub fn messages(&self) -> impl Iterator<Item = Result<TimedMsg, SessionError>> + '_ {
        self.messages
            .iter()
            .filter_map(|raw| self.decode(raw).transpose())
    }

    /// Fails unless at least one message is on the topic of `role`.
    pub fn require(&self, role: Role) -> Result<(), SessionError> {
        let topic = self.topics.get(role);
        if self.count(topic) == 0 {
            return Err(SessionError::MissingTopic {
                path: self.path.clone(),
                topic: topic.to_owned(),
                type_name: role.message_type(),
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
            });
        }
        Ok(())
    }
}
