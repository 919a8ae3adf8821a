//! Writes a session MCAP: profile `ros2`, CDR messages, `ros2msg` schemas, chunked with zstd,
//! with summary, statistics and indexes.
//!
//! Invariants: the file is written under a `.partial` name and renamed only by
//! [`SessionWriter::finish`], so a file with the final name is always complete; chunks go to
//! the OS as soon as they fill (no user-space buffer), so a recorder killed mid-run leaves a
//! `.partial` file that reads back up to its last complete chunk.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};

use mcap::{WriteOptions, Writer};

use super::{At, SessionError};
use crate::io::msgs::RosMessage;
use crate::io::output::destination;

/// Chunk size: a few 256x240 PNG frames, so a crash loses at most a second or so of a sim.
const CHUNK_SIZE_BYTES: u64 = 256 * 1024;

/// Writes one session MCAP; the file gets its final name only in [`SessionWriter::finish`].
pub struct SessionWriter {
    path: PathBuf,
    partial: PathBuf,
    writer: Writer<File>,
    channels: BTreeMap<String, (u16, u32)>,
}

impl SessionWriter {
    /// Starts a session file for `path`, written under its `.partial` name until
    /// [`SessionWriter::finish`].
    pub fn create(path: &Path) -> Result<Self, SessionError> {
        let (partial, target) = destination(path).map_err(|source| SessionError::Io {
            path: path.to_owned(),
            source,
        })?;
        let io = |source| SessionError::Io {
            path: partial.clone(),
            source,
        };
        let file = File::create(&partial).map_err(io)?;
        let writer = WriteOptions::new()
            .profile("ros2")
            .library(format!("objloc {}", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(CHUNK_SIZE_BYTES))
            .create(file)
            .map_err(|source| SessionError::Mcap {
                at: At {
                    path: partial.clone(),
                    topic: None,
                    log_time_ns: None,
                },
                what: "cannot start the MCAP file".into(),
                cause: source,
            })?;
        Ok(Self {
            path: target,
            partial,
            writer,
            channels: BTreeMap::new(),
        })
    }

    fn mcap_err(
        &self,
        topic: &str,
        log_time_ns: u64,
        what: &str,
    ) -> impl FnOnce(mcap::McapError) -> SessionError + use<> {
        let at = At {
            path: self.partial.clone(),
            topic: Some(topic.to_owned()),
            log_time_ns: Some(log_time_ns),
        };
        let what = what.to_owned();
        move |source| SessionError::Mcap {
            at,
            what,
            cause: source,
        }
    }

    /// Writes `msg` on `topic` with log_time = publish_time = `stamp_ns` (its header stamp).
    pub fn write<M: RosMessage>(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        msg: &M,
    ) -> Result<(), SessionError> {
        let log_time_ns = u64::try_from(stamp_ns).map_err(|_| SessionError::Invalid {
            at: At {
                path: self.partial.clone(),
                topic: Some(topic.to_owned()),
                log_time_ns: None,
            },
            what: format!("stamp {stamp_ns} ns is before 1970 and cannot be a log time"),
        })?;
        let channel_id = match self.channels.get(topic) {
            Some((id, _)) => *id,
            None => {
                let schema = M::schema_text();
                let err = self.mcap_err(topic, log_time_ns, "cannot add schema");
                let schema_id = self
                    .writer
                    .add_schema(M::TYPE, "ros2msg", schema.as_bytes())
                    .map_err(err)?;
                let err = self.mcap_err(topic, log_time_ns, "cannot add channel");
                let id = self
                    .writer
                    .add_channel(schema_id, topic, "cdr", &BTreeMap::new())
                    .map_err(err)?;
                self.channels.insert(topic.to_owned(), (id, 0));
                id
            }
        };
        let entry = self.channels.get_mut(topic).map(|(_, seq)| {
            let s = *seq;
            *seq += 1;
            s
        });
        let sequence = entry.unwrap_or(0);
        let data = msg.to_cdr();
        let err = self.mcap_err(topic, log_time_ns, "cannot write message");
        self.writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: log_time_ns,
                    publish_time: log_time_ns,
                },
                &data,
            )
            .map_err(err)
    }

    /// Writes the summary and indexes, then renames the file to its final name.
    pub fn finish(mut self) -> Result<PathBuf, SessionError> {
        self.writer.finish().map_err(|source| SessionError::Mcap {
            at: At {
                path: self.partial.clone(),
                topic: None,
                log_time_ns: None,
            },
            what: "cannot finish the MCAP file".into(),
            cause: source,
        })?;
        let file = self.writer.into_inner();
        file.sync_all().map_err(|source| SessionError::Io {
            path: self.partial.clone(),
            source,
        })?;
        drop(file);
        std::fs::rename(&self.partial, &self.path).map_err(|source| SessionError::Io {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.path)
    }
}
