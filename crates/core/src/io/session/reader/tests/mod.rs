//! Unit tests of the reader: the index order against the sort of the reader that held every
//! payload in memory, payloads through a cache smaller than the file's chunk count (also from
//! several threads), unchunked files, truncation inside a chunk, a damaged chunk when indexed
//! and when read again, and the summary section.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::records::MessageHeader;
use rayon::prelude::*;

use super::*;

mod damage;
mod merge;
use crate::io::msgs::{Header, RosMessage, Twist, TwistStamped};
use crate::io::session::{SessionMsg, Topics};

/// (log time, channel id, sequence, payload) of every message, in file order.
type Written = Vec<(u64, u16, u32, Vec<u8>)>;

/// Writes `msgs` with `opts` on three channels: 0 and 1 carry opaque payloads, 2 is
/// /cmd_vel (payloads must be TwistStamped CDR). Returns the file's bytes.
fn write(path: &Path, opts: mcap::WriteOptions, msgs: &Written) -> Vec<u8> {
    let file = std::fs::File::create(path).unwrap();
    let mut w = opts
        .profile("ros2")
        .library("reader test")
        .create(file)
        .unwrap();
    let opaque = w
        .add_schema("test/msg/Blob", "ros2msg", b"uint8[] data")
        .unwrap();
    let twist = w.add_schema(TwistStamped::TYPE, "ros2msg", b"").unwrap();
    let none = BTreeMap::new();
    let ids = [
        w.add_channel(opaque, "/a", "cdr", &none).unwrap(),
        w.add_channel(opaque, "/b", "cdr", &none).unwrap(),
        w.add_channel(twist, "/cmd_vel", "cdr", &none).unwrap(),
    ];
    for (log_time, channel, sequence, data) in msgs {
        let header = MessageHeader {
            channel_id: ids[usize::from(*channel)],
            sequence: *sequence,
            log_time: *log_time,
            publish_time: *log_time + 7,
        };
        w.write_to_known_channel(&header, data).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    std::fs::read(path).unwrap()
}

/// The next state of a xorshift64 generator (never 0 from a non-zero state).
fn xorshift(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

/// Pseudo-random bytes from `seed` (zstd cannot shrink them much, so chunks fill).
fn noise(seed: u64, len: usize) -> Vec<u8> {
    let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    (0..len)
        .map(|_| (xorshift(&mut state) >> 24) as u8)
        .collect()
}

fn twist_cdr(stamp_ns: i64, v: f64) -> Vec<u8> {
    TwistStamped {
        header: Header::new(stamp_ns, "base_link"),
        twist: Twist {
            linear: [v, 0.0, 0.0],
            angular: [0.0; 3],
        },
    }
    .to_cdr()
}

/// Many messages with strictly increasing log times across 3 channels, 300 bytes each.
fn increasing(n: u64) -> Written {
    (0..n)
        .map(|k| {
            let ch = (k % 3) as u16;
            let t = 1_000_000_000 + k * 1_000_000;
            let data = if ch == 2 {
                twist_cdr(t as i64, k as f64)
            } else {
                noise(k, 300)
            };
            (t, ch, (k / 3) as u32, data)
        })
        .collect()
}

/// The order of the reader that held every payload: mcap's own stream over the bytes (file
/// order), stably sorted by (log time, channel id, sequence).
fn old_order(bytes: &[u8]) -> Vec<ReadBack> {
    let mut all: Vec<_> = mcap::MessageStream::new(bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (
                m.log_time,
                m.channel.id,
                m.sequence,
                m.publish_time,
                m.data.into_owned(),
            )
        })
        .collect();
    all.sort_by_key(|m| (m.0, m.1, m.2));
    all
}

/// (log time, channel id, sequence, publish time, payload) of a message read back.
type ReadBack = (u64, u16, u32, u64, Vec<u8>);

/// Every message of `reader` in index order, with its payload.
fn read_all(reader: &SessionReader) -> Vec<ReadBack> {
    reader
        .collect_index()
        .unwrap()
        .iter()
        .map(|m| {
            let data = reader.payload(m).unwrap();
            (
                m.log_time_ns,
                m.channel_id,
                m.sequence,
                m.publish_time_ns,
                data,
            )
        })
        .collect()
}

/// The topic of channel `id`.
fn topic(reader: &SessionReader, id: u16) -> &str {
    &reader.channels()[&id].topic
}

fn small_chunks() -> mcap::WriteOptions {
    mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(2048))
}

#[test]
fn index_order_is_the_old_order_with_equal_log_times_across_channels() {
    let dir = tempfile::tempdir().unwrap();
    // Written out of order: equal log times on all three channels, a channel going back in
    // time, and two messages with the same (log time, channel, sequence), whose file order the
    // stable sort must keep (their payloads tell them apart).
    let t = 5_000_000_000u64;
    let msgs: Written = vec![
        (t + 2, 1, 0, b"b0".to_vec()),
        (t, 1, 1, b"b1".to_vec()),
        (t, 0, 0, b"a0".to_vec()),
        (t, 2, 0, twist_cdr(t as i64, 0.5)),
        (t + 1, 0, 1, b"a1".to_vec()),
        (t, 0, 0, b"a0-again".to_vec()),
        (t + 1, 2, 1, twist_cdr(t as i64 + 1, 0.25)),
        (t - 3, 1, 2, b"b2".to_vec()),
    ];
    let path = dir.path().join("ties.mcap");
    let bytes = write(&path, mcap::WriteOptions::new().chunk_size(Some(64)), &msgs);
    let reader = SessionReader::open(&path, Topics::default()).unwrap();
    assert!(reader.chunk_count() >= 3, "{} chunks", reader.chunk_count());
    let got = read_all(&reader);
    assert_eq!(got, old_order(&bytes));
    // The same messages outside chunks sort the same.
    let flat = dir.path().join("ties-flat.mcap");
    let flat_bytes = write(&flat, mcap::WriteOptions::new().use_chunks(false), &msgs);
    let flat_reader = SessionReader::open(&flat, Topics::default()).unwrap();
    assert_eq!(flat_reader.chunk_count(), 0);
    assert_eq!(read_all(&flat_reader), got);
    assert_eq!(old_order(&flat_bytes), got);
    let payloads: Vec<&[u8]> = got.iter().map(|m| m.4.as_slice()).collect();
    assert_eq!(&payloads[..1], &[b"b2".as_slice()]);
    // At log time t: /a, /b, /cmd_vel (channel ids in that order); /a's two sequence-0
    // messages in file order.
    assert_eq!(payloads[1], b"a0");
    assert_eq!(payloads[2], b"a0-again");
    assert_eq!(payloads[3], b"b1");
    assert_eq!(topic(&reader, got[4].1), "/cmd_vel");
    assert_eq!(
        got.iter().map(|m| m.0).collect::<Vec<_>>()[..4],
        [t - 3, t, t, t]
    );
    // In file order: /b went back from t + 2 to t, /a from t + 1 to t, /b from t to t - 3.
    assert_eq!(
        reader.backwards,
        vec![
            ("/b".to_owned(), t, t + 2),
            ("/a".to_owned(), t, t + 1),
            ("/b".to_owned(), t - 3, t)
        ]
    );
    // The role topic decodes through the lazy payload.
    let cmd = reader
        .messages()
        .map(Result::unwrap)
        .map(|m| match m.msg {
            SessionMsg::CmdVel(c) => c.twist.linear[0],
            other => panic!("{other:?}"),
        })
        .collect::<Vec<_>>();
    assert_eq!(cmd, vec![0.5, 0.25]);
}

#[test]
fn a_cache_smaller_than_the_chunk_count_reads_what_memory_reads() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("many.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let in_memory = SessionReader::from_bytes(&path, &bytes, Topics::default()).unwrap();
    let reader = SessionReader::open(&path, Topics::default())
        .unwrap()
        .with_chunk_cache(2);
    assert!(
        reader.chunk_count() >= 20,
        "{} chunks",
        reader.chunk_count()
    );
    assert_eq!(reader.chunk_count(), in_memory.chunk_count());
    let index = reader.collect_index().unwrap();
    assert_eq!(index, in_memory.collect_index().unwrap());
    let expected = old_order(&bytes);
    assert_eq!(expected.len(), 300);
    assert_eq!(read_all(&in_memory), expected);
    // Jumping between chunks (stride 37 through 300 messages) evicts all the time.
    let n = index.len();
    for k in 0..n {
        let i = (k * 37) % n;
        assert_eq!(
            reader.payload(&index[i]).unwrap(),
            expected[i].4,
            "message {i}"
        );
    }
    // From several threads at once, in reverse: the same bytes.
    let parallel: Vec<Vec<u8>> = (0..n)
        .into_par_iter()
        .rev()
        .map(|i| reader.payload(&index[i]).unwrap())
        .collect();
    assert!(parallel.iter().rev().zip(&expected).all(|(a, b)| *a == b.4));
    fn sync<T: Sync + Send>(_: &T) {}
    sync(&reader);
    assert_eq!(std::mem::size_of::<MessageMeta>(), 32);
}

#[test]
fn an_unchunked_file_reads_from_file_offsets() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("flat.mcap");
    let msgs = increasing(12);
    let bytes = write(&path, mcap::WriteOptions::new().use_chunks(false), &msgs);
    let reader = SessionReader::open(&path, Topics::default()).unwrap();
    assert_eq!(reader.chunk_count(), 0);
    assert_eq!(reader.collect_index().unwrap().len(), 12);
    assert!(reader.warnings.is_empty(), "{:?}", reader.warnings);
    // Every record up to the footer; the closing magic is not a record.
    assert_eq!(reader.bytes_intact, bytes.len() as u64 - 8);
    for (meta, (t, _, seq, data)) in reader.collect_index().unwrap().iter().zip(&msgs) {
        let Some(PayloadAt::File {
            offset_bytes,
            len_bytes,
        }) = reader.payload_at(meta)
        else {
            panic!("{meta:?} in a chunk");
        };
        let at = offset_bytes as usize;
        assert_eq!(&bytes[at..at + len_bytes as usize], data.as_slice());
        assert_eq!(
            (meta.log_time_ns, meta.publish_time_ns, meta.sequence),
            (*t, t + 7, *seq)
        );
    }
    assert_eq!(read_all(&reader), old_order(&bytes));
    let speeds: Vec<f64> = reader
        .messages()
        .map(|m| match m.unwrap().msg {
            SessionMsg::CmdVel(c) => c.twist.linear[0],
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(speeds, vec![2.0, 5.0, 8.0, 11.0]);
}

/// The chunk indexes of `bytes`, in file order.
fn chunk_indexes(bytes: &[u8]) -> Vec<mcap::records::ChunkIndex> {
    let mut c = mcap::Summary::read(bytes).unwrap().unwrap().chunk_indexes;
    c.sort_by_key(|c| c.chunk_start_offset);
    c
}

#[test]
fn a_cut_inside_a_chunk_warns_and_keeps_the_chunks_before_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let chunks = chunk_indexes(&bytes);
    let k = chunks.len() / 2;
    let c = &chunks[k];
    let cut = (c.chunk_start_offset + c.chunk_length / 2) as usize;
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, &bytes[..cut]).unwrap();
    let reader = SessionReader::open(&cut_path, Topics::default()).unwrap();
    // Strictly increasing log times: chunk k's first message is the first one lost.
    let kept: Vec<_> = old_order(&bytes)
        .into_iter()
        .filter(|m| m.0 < c.message_start_time)
        .collect();
    assert!(!kept.is_empty());
    assert_eq!(reader.chunk_count(), k);
    assert_eq!(read_all(&reader), kept);
    // The last intact records are chunk k - 1's message indexes, just before chunk k.
    assert_eq!(reader.bytes_intact, c.chunk_start_offset);
    assert_eq!(reader.file_len, cut as u64);
    let last = kept.last().unwrap();
    assert_eq!(
        reader.warnings,
        vec![format!(
            "file is truncated: read {} messages from the first {} of {cut} bytes of {}; the rest is lost (last intact message: {} at {})",
            kept.len(),
            c.chunk_start_offset,
            cut_path.display(),
            topic(&reader, last.1),
            crate::io::session::fmt_ns(last.0)
        )]
    );
}

#[test]
fn a_corrupted_byte_in_a_chunk_is_an_error_naming_the_message_before_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let chunks = chunk_indexes(&bytes);
    // A bit flipped in the middle of chunk k's compressed records (its CRC covers them).
    let flipped = |k: usize| {
        let c = &chunks[k];
        let mut b = bytes.clone();
        b[(c.chunk_start_offset + c.chunk_length - c.compressed_size / 2) as usize] ^= 0x40;
        SessionReader::from_bytes(Path::new("flip.mcap"), &b, Topics::default()).unwrap_err()
    };
    // In chunk 0 no message precedes the damage, and the error says so (it read "after the
    // message named here" with none named).
    let SessionError::Mcap { at, what, .. } = &flipped(0) else {
        panic!("not an MCAP error");
    };
    assert_eq!((at.topic.as_ref(), at.log_time_ns), (None, None));
    assert!(what.ends_with("(before the first message)"), "{what}");
    let c = &chunks[1];
    let e = flipped(1);
    let SessionError::Mcap { at, what, .. } = &e else {
        panic!("{e}");
    };
    let last_of_chunk_0 = old_order(&std::fs::read(&path).unwrap())
        .into_iter()
        .rfind(|m| m.0 <= chunks[0].message_end_time)
        .unwrap();
    assert_eq!(at.log_time_ns, Some(last_of_chunk_0.0));
    let whole = SessionReader::open(&path, Topics::default()).unwrap();
    assert_eq!(at.topic.as_deref(), Some(topic(&whole, last_of_chunk_0.1)));
    assert_eq!(
        what,
        &format!(
            "damaged data after byte {} (after the message named here)",
            c.chunk_start_offset
        )
    );
    let line = e.to_string();
    assert!(line.starts_with("flip.mcap: topic /"), "{line}");
    assert!(
        line.to_lowercase().contains("crc") || line.contains("zstd"),
        "{line}"
    );
    // A file whose summary reads: the damaged chunk's message times from its chunk index
    // (damage in the first chunk named no time at all).
    let mut b = bytes.clone();
    let c0 = &chunks[0];
    b[(c0.chunk_start_offset + c0.chunk_length - c0.compressed_size / 2) as usize] ^= 0x40;
    let damaged = dir.path().join("flip.mcap");
    std::fs::write(&damaged, &b).unwrap();
    let e = SessionReader::open(&damaged, Topics::default()).unwrap_err();
    let SessionError::Mcap { what, .. } = &e else {
        panic!("{e}");
    };
    assert_eq!(
        what,
        &format!(
            "damaged data after byte {} (before the first message; the summary's chunk index puts messages logged from {} to {} in the chunk there)",
            c0.chunk_start_offset,
            crate::io::session::fmt_ns(c0.message_start_time),
            crate::io::session::fmt_ns(c0.message_end_time)
        )
    );
}

#[test]
fn a_chunk_damaged_after_indexing_is_an_error_naming_file_topic_and_log_time() {
    use std::io::{Seek, SeekFrom, Write};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("changing.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let chunks = chunk_indexes(&bytes);
    let reader = SessionReader::open(&path, Topics::default())
        .unwrap()
        .with_chunk_cache(1);
    let index = reader.collect_index().unwrap();
    // Damage chunk 2 in place (same file, same inode), after the index was built.
    let c = &chunks[2];
    let at = c.chunk_start_offset + c.chunk_length - c.compressed_size / 2;
    let mut f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    f.seek(SeekFrom::Start(at)).unwrap();
    f.write_all(&[bytes[at as usize] ^ 0x01]).unwrap();
    drop(f);
    let meta = *index
        .iter()
        .find(|m| m.log_time_ns == c.message_start_time)
        .unwrap();
    assert_eq!(
        reader.payload_at(&meta),
        Some(PayloadAt::Chunk {
            offset_bytes: c.chunk_start_offset,
            ordinal: 0
        })
    );
    let e = reader.payload(&meta).unwrap_err().to_string();
    let topic = topic(&reader, meta.channel_id);
    assert!(
        e.starts_with(&format!(
            "{}: topic {topic} at log time {}: the chunk at byte {} read when the file was opened but not now",
            path.display(),
            crate::io::session::fmt_ns(meta.log_time_ns),
            c.chunk_start_offset
        )),
        "{e}"
    );
    assert!(e.to_lowercase().contains("crc"), "{e}");
    // Chunks left alone still read.
    let first = index[0];
    assert_eq!(reader.payload(&first).unwrap(), old_order(&bytes)[0].4);
    // The merge reads chunk 2 again on its way: an error naming the file, the topic and log
    // time of the chunk's first message, and the chunk, once, after the messages before it.
    let mut ordered = reader.ordered();
    let before = ordered.by_ref().take_while(Result::is_ok).count();
    assert!(before > 0 && before < index.len(), "{before}");
    assert!(ordered.next().is_none());
    let e = reader.ordered().find_map(Result::err).unwrap().to_string();
    assert!(
        e.starts_with(&format!(
            "{}: topic {topic} at log time {}: ",
            path.display(),
            crate::io::session::fmt_ns(c.message_start_time)
        )) && e.contains(&format!("the chunk at byte {}", c.chunk_start_offset)),
        "{e}"
    );
}

#[test]
fn the_summary_section_gives_counts_without_reading_messages() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.mcap");
    let msgs = increasing(300);
    let bytes = write(&path, small_chunks(), &msgs);
    let s = read_summary_section(&path).unwrap().unwrap();
    assert_eq!(s.message_count, 300);
    assert_eq!(s.profile, "ros2");
    assert_eq!(s.library, "reader test");
    assert_eq!(s.file_len, bytes.len() as u64);
    assert_eq!(s.chunk_count as usize, chunk_indexes(&bytes).len());
    assert_eq!(s.time_range_ns, Some((msgs[0].0, msgs[299].0)));
    let by_topic: BTreeMap<&str, u64> = s
        .channels
        .values()
        .map(|c| (c.topic.as_str(), s.channel_message_counts[&c.id]))
        .collect();
    assert_eq!(
        by_topic,
        BTreeMap::from([("/a", 100), ("/b", 100), ("/cmd_vel", 100)])
    );
    // No summary section: None; a truncated file: the footer is not there, an error.
    let bare = dir.path().join("bare.mcap");
    write(
        &bare,
        small_chunks()
            .emit_summary_records(false)
            .emit_summary_offsets(false)
            .emit_statistics(false)
            .emit_chunk_indexes(false),
        &msgs,
    );
    assert_eq!(read_summary_section(&bare).unwrap(), None);
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).unwrap();
    assert!(read_summary_section(&cut).is_err());
}

/// What the reader that held every payload read from `bytes`: its messages in file order and
/// `bytes_intact`, whether it warned of truncation; `Err` where it refused the file. Its scan,
/// kept here as the reference: mcap's reader handing out the records inside chunks.
fn old_scan(bytes: &[u8]) -> Result<(Vec<ReadBack>, u64, bool), String> {
    use mcap::McapError;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let opts = LinearReaderOptions::default()
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(RECORD_LENGTH_LIMIT);
    let mut reader = LinearReader::new_with_options(opts);
    let (mut cursor, mut intact, mut out) = (0usize, 0u64, Vec::new());
    let ends = bytes.len() >= 16 && bytes.ends_with(MCAP_MAGIC);
    while let Some(event) = reader.next_event() {
        match event {
            Ok(LinearReadEvent::ReadRequest(n)) => {
                let n = n.min(bytes.len() - cursor);
                reader.insert(n).copy_from_slice(&bytes[cursor..cursor + n]);
                reader.notify_read(n);
                cursor += n;
            }
            Ok(LinearReadEvent::Record { data, opcode }) => {
                let record = mcap::parse_record(opcode, data).map_err(|e| e.to_string())?;
                if let mcap::records::Record::Message { header, data } = record {
                    let h = header;
                    out.push((
                        h.log_time,
                        h.channel_id,
                        h.sequence,
                        h.publish_time,
                        data.to_vec(),
                    ));
                }
                intact = cursor as u64;
            }
            Err(McapError::UnexpectedEof | McapError::UnexpectedEoc) if !ends => {
                return Ok((out, intact, true));
            }
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok((out, intact, false))
}

#[test]
fn every_cut_reads_as_the_reader_that_held_every_payload_read_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(90));
    let (mut partial, mut refused) = (0, 0);
    for cut in (8..=bytes.len())
        .step_by(53)
        .chain([bytes.len() - 8, bytes.len() - 1])
    {
        let cut_bytes = &bytes[..cut];
        let old = old_scan(cut_bytes);
        let new = SessionReader::from_bytes(Path::new("cut.mcap"), cut_bytes, Topics::default());
        match (old, new) {
            (Ok((mut msgs, intact, truncated)), Ok(r)) => {
                msgs.sort_by_key(|m| (m.0, m.1, m.2));
                assert_eq!(read_all(&r), msgs, "cut at {cut}");
                assert_eq!(r.bytes_intact, intact, "cut at {cut}");
                let warned = r
                    .warnings
                    .iter()
                    .any(|w| w.starts_with("file is truncated"));
                assert_eq!(warned, truncated, "cut at {cut}: {:?}", r.warnings);
                partial += usize::from(truncated);
            }
            (Err(_), Err(_)) => refused += 1,
            (old, new) => panic!(
                "cut at {cut}: old {:?}, new {:?}",
                old.map(|o| o.1),
                new.map(|r| r.bytes_intact)
            ),
        }
    }
    assert!(partial > 20, "{partial} partial, {refused} refused");
}

#[test]
fn a_chunk_left_with_the_writers_placeholder_length_is_a_truncation() {
    // A recorder killed while a chunk fills leaves the chunk's length (and sizes) as mcap's
    // writer's placeholder 2^64 - 1; the file ends without its magic.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let chunks = chunk_indexes(&bytes);
    let c = &chunks[3];
    let start = c.chunk_start_offset as usize;
    let mut cut = bytes[..start + c.chunk_length as usize / 2].to_vec();
    // Record length, uncompressed size and CRC, compressed size: as the writer starts a chunk.
    let name_len = u32::from_le_bytes(cut[start + 37..start + 41].try_into().unwrap()) as usize;
    let compressed_size_at = start + 41 + name_len;
    for (at, len) in [
        (start + 1, 8),
        (start + 25, 8),
        (start + 33, 4),
        (compressed_size_at, 8),
    ] {
        cut[at..at + len].fill(0xff);
    }
    let reader =
        SessionReader::from_bytes(Path::new("killed.mcap"), &cut, Topics::default()).unwrap();
    assert_eq!(reader.chunk_count(), 3);
    assert_eq!(reader.bytes_intact, c.chunk_start_offset);
    let kept: Vec<_> = old_order(&bytes)
        .into_iter()
        .filter(|m| m.0 < c.message_start_time)
        .collect();
    assert_eq!(read_all(&reader), kept);
    assert_eq!(reader.warnings.len(), 1);
    assert!(
        reader.warnings[0].starts_with(&format!(
            "file is truncated: read {} messages from the first {} of {} bytes of killed.mcap",
            kept.len(),
            c.chunk_start_offset,
            cut.len()
        )),
        "{:?}",
        reader.warnings
    );
    // The reader that held every payload read the same.
    let (old, intact, truncated) = old_scan(&cut).unwrap();
    assert_eq!(
        (old.len(), intact, truncated),
        (kept.len(), c.chunk_start_offset, true)
    );
    // Ending with the magic, the same length is damage, not truncation.
    cut.extend_from_slice(MCAP_MAGIC);
    let e = SessionReader::from_bytes(Path::new("killed.mcap"), &cut, Topics::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("the file ends with the MCAP magic, so it is not truncated"),
        "{e}"
    );
}

/// Opened for the roles, the reader indexes the /cmd_vel channel (a role) and not /a and /b
/// (none): exactly the messages and payloads of the full index on that channel, in the same
/// order; the other channels are still listed, and a damaged chunk is still found.
#[test]
fn a_reader_for_the_roles_indexes_only_their_channels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("roles.mcap");
    write(&path, small_chunks(), &increasing(600));
    let all = SessionReader::open(&path, Topics::default()).unwrap();
    let roles = SessionReader::open_scoped(&path, Topics::default(), IndexScope::Roles).unwrap();
    assert_eq!(roles.channels(), all.channels());
    let twist_id = *all
        .channels()
        .iter()
        .find(|(_, c)| c.topic == "/cmd_vel")
        .unwrap()
        .0;
    let want: Vec<ReadBack> = read_all(&all)
        .into_iter()
        .filter(|m| m.1 == twist_id)
        .collect();
    assert_eq!(want.len(), 200);
    assert_eq!(read_all(&roles), want);
    assert_eq!(roles.count("/cmd_vel"), 200);
    assert_eq!(roles.count("/a"), 0);
    assert_eq!(all.count("/a"), 200);
}

/// The scan is the same for both scopes: a byte flipped inside a chunk that holds only /a
/// and /b messages (neither indexed for the roles) is the same error, naming the same last
/// message before it (the last scanned, not the last indexed); a chunk cut out is the same
/// warning, with the messages scanned.
#[test]
fn a_reader_for_the_roles_checks_and_names_what_it_does_not_index() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("roles.mcap");
    // 60 /cmd_vel messages, then 300 on /a and /b, then 60 more /cmd_vel.
    let msgs: Written = (0..420u64)
        .map(|k| {
            let t = 1_000_000_000 + k * 1_000_000;
            if (60..360).contains(&k) {
                (t, (k % 2) as u16, k as u32, noise(k, 300))
            } else {
                (t, 2, k as u32, twist_cdr(t as i64, k as f64))
            }
        })
        .collect();
    let bytes = write(&path, small_chunks(), &msgs);
    let chunks = chunk_indexes(&bytes);
    let inner = chunks
        .iter()
        .find(|c| c.message_start_time > 1_100_000_000 && c.message_end_time < 1_300_000_000)
        .expect("a chunk of /a and /b messages only")
        .clone();
    let open = |p: &Path, scope| SessionReader::open_scoped(p, Topics::default(), scope);
    let mut bad = bytes.clone();
    let mid = usize::try_from(inner.chunk_start_offset + inner.chunk_length / 2).unwrap();
    bad[mid] ^= 0x5a;
    let bad_path = dir.path().join("bad.mcap");
    std::fs::write(&bad_path, &bad).unwrap();
    let all = open(&bad_path, IndexScope::All).unwrap_err().to_string();
    let roles = open(&bad_path, IndexScope::Roles).unwrap_err().to_string();
    assert_eq!(roles, all);
    assert!(
        all.contains("topic /a") || all.contains("topic /b"),
        "{all}"
    );
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, without_chunk(&bytes, &inner)).unwrap();
    let all = open(&cut_path, IndexScope::All).unwrap();
    let roles = open(&cut_path, IndexScope::Roles).unwrap();
    assert_eq!(roles.collect_index().unwrap().len(), 120);
    assert_eq!(roles.message_count(), 120);
    let all_held = all.collect_index().unwrap().len();
    assert!(all_held < 420);
    assert_eq!(all.message_count(), all_held as u64);
    assert_eq!(roles.warnings, all.warnings);
    assert_eq!(roles.warnings.len(), 1, "{:?}", roles.warnings);
    assert!(
        roles.warnings[0].contains(&format!(
            "its summary counts 420 messages, the file holds {}",
            all_held
        )),
        "{:?}",
        roles.warnings
    );
}

/// A record that does not parse is a one-line error: the MCAP parser's innermost error,
/// without its styled backtrace (escapes, box drawing, the crate's source paths), and not
/// repeated by an error chain. The file: the magic, a Header record whose profile string
/// claims 16 bytes and has none, the magic (found by fuzzing, 2026-12-04).
#[test]
fn a_record_that_does_not_parse_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad-header.mcap");
    let mut bytes = MCAP_MAGIC.to_vec();
    bytes.push(0x01);
    bytes.extend_from_slice(&4u64.to_le_bytes());
    bytes.extend_from_slice(&[0x10, 0, 0, 0]);
    bytes.extend_from_slice(MCAP_MAGIC);
    std::fs::write(&path, &bytes).unwrap();
    let e = SessionReader::open(&path, Topics::default()).unwrap_err();
    assert!(std::error::Error::source(&e).is_none(), "{e:?}");
    let chain = e.to_string();
    assert!(
        chain.ends_with(
            "bad-header.mcap: a record (opcode 0x01) before any message does not parse: record \
             parse failed: not enough bytes in reader"
        ),
        "{chain}"
    );
    assert!(!chain.contains(['\n', '\u{1b}', '━']), "{chain}");
}

/// A chunk cut out of a file that is otherwise whole leaves the scan nothing to trip on; the
/// summary's message count tells: a warning naming both counts. The whole file has none.
#[test]
fn a_chunk_cut_out_is_told_by_the_summarys_count() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(600));
    assert!(
        SessionReader::open(&path, Topics::default())
            .unwrap()
            .warnings
            .is_empty()
    );
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, without_chunk(&bytes, &chunk_indexes(&bytes)[2])).unwrap();
    let reader = SessionReader::open(&cut_path, Topics::default()).unwrap();
    let held = reader.collect_index().unwrap().len();
    assert!(held < 600, "{held}");
    assert_eq!(
        reader.warnings,
        vec![format!(
            "{}: its summary counts 600 messages, the file holds {held}: records are missing or were added after the summary was written",
            cut_path.display()
        )]
    );
}

/// The file's bytes with `chunk`'s record cut out (the summary left as it was).
fn without_chunk(bytes: &[u8], chunk: &mcap::records::ChunkIndex) -> Vec<u8> {
    let start = usize::try_from(chunk.chunk_start_offset).unwrap();
    let end = start + usize::try_from(chunk.chunk_length).unwrap();
    let mut cut = bytes[..start].to_vec();
    cut.extend_from_slice(&bytes[end..]);
    cut
}
