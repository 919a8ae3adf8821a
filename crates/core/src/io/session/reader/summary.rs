//! The summary section of an MCAP file, read without touching its data: the header (first
//! record), the channels, the Statistics record and the chunk indexes, found from the footer
//! by seeking. What `objloc inspect --quick` reports.
//!
//! Invariants: reads the file's first record and its summary section only, whatever the
//! file's size; a file without a summary section (or without Statistics) is `Ok(None)`, a
//! summary that does not read is an error, so the caller can fall back to the full scan.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Seek;
use std::path::Path;

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};

use super::super::{At, SessionError};
use super::{ChannelInfo, RECORD_LENGTH_LIMIT, read_full};

/// What a file's summary section says about it.
#[derive(Debug, Clone, PartialEq)]
pub struct SummarySection {
    /// MCAP header profile, e.g. `ros2`; empty if the file declares none.
    pub profile: String,
    /// MCAP header library: what wrote the file.
    pub library: String,
    /// Size of the file, bytes.
    pub file_len: u64,
    /// The channels the summary declares, by id, with their schemas.
    pub channels: BTreeMap<u16, ChannelInfo>,
    /// Messages in the file, on every channel (Statistics).
    pub message_count: u64,
    /// Messages per channel id (Statistics); a channel missing here has none.
    pub channel_message_counts: BTreeMap<u16, u64>,
    /// Earliest and latest message log time, ns since the Unix epoch; `None` without messages.
    pub time_range_ns: Option<(u64, u64)>,
    /// Chunks in the file (Statistics).
    pub chunk_count: u32,
    /// Each chunk's place and the log times of its messages, from the chunk indexes, in the
    /// summary's order: (chunk start, bytes; first and last message log time, ns).
    pub chunks: Vec<(u64, u64, u64)>,
}

/// Reads the summary section of the MCAP file at `path`; `Ok(None)` when the file has none
/// or its summary lacks the Statistics record.
pub fn read_summary_section(path: &Path) -> Result<Option<SummarySection>, SessionError> {
    let io = |source| SessionError::Io {
        path: path.to_owned(),
        source,
    };
    let mcap_err = |what: &str| {
        let what = what.to_owned();
        move |source| SessionError::Mcap {
            at: At {
                path: path.to_owned(),
                topic: None,
                log_time_ns: None,
            },
            what,
            cause: source,
        }
    };
    let mut file = File::open(path).map_err(io)?;
    let file_len = file.metadata().map_err(io)?.len();
    let (profile, library) =
        read_header(&mut file).map_err(mcap_err("the header record does not read"))?;
    let opts = SummaryReaderOptions::default()
        .with_file_size(file_len)
        .with_record_length_limit(RECORD_LENGTH_LIMIT);
    let mut reader = SummaryReader::new_with_options(opts);
    while let Some(event) = reader.next_event() {
        match event.map_err(mcap_err("the summary section does not read"))? {
            SummaryReadEvent::ReadRequest(n) => {
                let got = read_full(&mut file, reader.insert(n)).map_err(io)?;
                reader.notify_read(got);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to).map_err(io)?;
                reader.notify_seeked(pos);
            }
        }
    }
    let Some(summary) = reader.finish() else {
        return Ok(None);
    };
    let Some(stats) = summary.stats else {
        return Ok(None);
    };
    let channels = summary
        .channels
        .values()
        .map(|c| {
            let (schema_name, schema_encoding, schema_data) = match &c.schema {
                Some(s) => (s.name.clone(), s.encoding.clone(), s.data.to_vec()),
                None => Default::default(),
            };
            let info = ChannelInfo {
                id: c.id,
                topic: c.topic.clone(),
                message_encoding: c.message_encoding.clone(),
                schema_name,
                schema_encoding,
                schema_data,
            };
            (c.id, info)
        })
        .collect();
    Ok(Some(SummarySection {
        profile,
        library,
        file_len,
        channels,
        message_count: stats.message_count,
        channel_message_counts: stats.channel_message_counts,
        time_range_ns: (stats.message_count > 0)
            .then_some((stats.message_start_time, stats.message_end_time)),
        chunk_count: stats.chunk_count,
        chunks: summary
            .chunk_indexes
            .iter()
            .map(|c| {
                (
                    c.chunk_start_offset,
                    c.message_start_time,
                    c.message_end_time,
                )
            })
            .collect(),
    }))
}

/// The profile and library of the file's Header record (its first record).
fn read_header(file: &mut File) -> Result<(String, String), mcap::McapError> {
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_record_length_limit(RECORD_LENGTH_LIMIT),
    );
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(n) => {
                // The header is small; no request beyond a record's length is served.
                let got = read_full(file, reader.insert(n.min(RECORD_LENGTH_LIMIT)))?;
                reader.notify_read(got);
            }
            LinearReadEvent::Record { data, opcode } => {
                return match mcap::parse_record(opcode, data)? {
                    Record::Header(h) => Ok((h.profile, h.library)),
                    // A file must open with its Header record.
                    _ => Err(mcap::McapError::BadMagic),
                };
            }
        }
    }
    Err(mcap::McapError::UnexpectedEof)
}
