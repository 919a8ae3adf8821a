//! Unit tests of the ordered merge: its order against the sort of every message on files
//! whose chunks follow, overlap or span each other, and what it holds at once.

use super::*;

/// Log times drawn from `seed` within a window that slides with the message number, so
/// neighbouring chunks overlap in time by `spread_ns`, rounded to 4 ms, across 3 channels
/// (log times and sequence numbers repeat, to exercise the later keys).
fn jittered(n: u64, spread_ns: u64, seed: u64) -> Written {
    let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    (0..n)
        .map(|k| {
            let state = xorshift(&mut state);
            // Rounded to 4 ms, so that several messages (across channels, chunks and equal
            // sequence numbers) share a log time and the later keys decide.
            let t =
                1_000_000_000 + (k * 1_000_000 + state % spread_ns.max(1)) / 4_000_000 * 4_000_000;
            let ch = (state >> 40) as u16 % 3;
            let data = if ch == 2 {
                twist_cdr(t as i64, k as f64)
            } else {
                noise(k, 40 + (state >> 50) as usize % 200)
            };
            (t, ch, (k / 7) as u32, data)
        })
        .collect()
}

/// The merge over chunks gives exactly the order of sorting every message, whether chunks
/// follow each other in time, overlap their neighbours or span most of the session, with
/// chunked and unchunked files alike.
#[test]
fn the_merge_is_the_sort_of_every_message_however_chunks_overlap() {
    let dir = tempfile::tempdir().unwrap();
    for (seed, spread_ns) in [(1, 0), (2, 3_000_000), (3, 40_000_000), (4, 900_000_000)] {
        let msgs = jittered(400, spread_ns, seed);
        for (name, opts) in [
            ("small", small_chunks()),
            ("tiny", mcap::WriteOptions::new().chunk_size(Some(300))),
            ("flat", mcap::WriteOptions::new().use_chunks(false)),
        ] {
            let path = dir.path().join(format!("{name}-{seed}.mcap"));
            let bytes = write(&path, opts, &msgs);
            let reader = SessionReader::open(&path, Topics::default()).unwrap();
            assert!(name == "flat" || reader.chunk_count() >= 10, "{name}");
            assert_eq!(
                read_all(&reader),
                old_order(&bytes),
                "{name}, spread {spread_ns}"
            );
            assert_eq!(reader.message_count(), 400);
        }
    }
}

/// The merge holds the messages of the chunks that overlap the current time, not the file's:
/// on chunks that follow each other in time, never more than two chunks' worth.
/// The most messages the merge held at once over `reader` (the one handed out included),
/// and how many it handed out.
fn most_held(reader: &SessionReader) -> (usize, usize) {
    let mut ordered = reader.ordered();
    let (mut held, mut n) = (0, 0);
    while let Some(m) = ordered.next() {
        m.unwrap();
        held = held.max(ordered.pending() + 1);
        n += 1;
    }
    (held, n)
}

#[test]
fn the_merge_holds_a_few_chunks_not_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("long.mcap");
    let bytes = write(&path, small_chunks(), &increasing(3000));
    let reader = SessionReader::open(&path, Topics::default()).unwrap();
    assert_eq!(chunk_indexes(&bytes).len(), reader.chunk_count());
    assert!(
        reader.chunk_count() >= 100,
        "{} chunks",
        reader.chunk_count()
    );
    let most_in_a_chunk = reader.openings.iter().map(|o| o.indexed).max().unwrap() as usize;
    let (held, n) = most_held(&reader);
    assert_eq!(n, 3000);
    assert!(
        held <= 2 * most_in_a_chunk,
        "held {held}, a chunk ~{most_in_a_chunk}"
    );
    // With every chunk spanning the whole session the merge must hold everything, as a full
    // index would: the bound is a property of the file, not a cap that drops messages.
    let spread = jittered(600, 1_000_000_000_000, 5);
    let wide = dir.path().join("wide.mcap");
    write(&wide, small_chunks(), &spread);
    let reader = SessionReader::open(&wide, Topics::default()).unwrap();
    let (held, n) = most_held(&reader);
    assert_eq!(n, 600);
    assert!(held > 300, "held {held}");
}

/// An MCAP record: opcode, little-endian length, body.
fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
    let mut r = vec![opcode];
    r.extend_from_slice(&(body.len() as u64).to_le_bytes());
    r.extend_from_slice(body);
    r
}

/// An MCAP string: u32 length, bytes.
fn string(s: &str) -> Vec<u8> {
    let mut b = (s.len() as u32).to_le_bytes().to_vec();
    b.extend_from_slice(s.as_bytes());
    b
}

/// Channel `id` on `topic` (schema 1, cdr, no metadata).
fn channel(id: u16, topic: &str) -> Vec<u8> {
    let mut b = id.to_le_bytes().to_vec();
    b.extend_from_slice(&1u16.to_le_bytes());
    b.extend(string(topic));
    b.extend(string("cdr"));
    b.extend_from_slice(&0u32.to_le_bytes());
    record(0x04, &b)
}

/// A message on channel `id` at `log_time`.
fn message(id: u16, log_time: u64, data: &[u8]) -> Vec<u8> {
    let mut b = id.to_le_bytes().to_vec();
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&log_time.to_le_bytes());
    b.extend_from_slice(&log_time.to_le_bytes());
    b.extend_from_slice(data);
    record(0x05, &b)
}

/// A channel declared again on another topic, after messages on it, would be indexed on one
/// side of the declaration and not on the other: a reader for the roles refuses it, naming
/// the channel and both topics (the merge reads the final declaration). Declared again on the
/// same topic, or read with every channel indexed, it reads as before.
#[test]
fn a_channel_declared_again_on_another_topic_is_refused_for_the_roles() {
    let dir = tempfile::tempdir().unwrap();
    let file = |name: &str, second_topic: &str| {
        let mut b = MCAP_MAGIC.to_vec();
        b.extend(record(0x01, &[string("ros2"), string("test")].concat()));
        let mut schema = 1u16.to_le_bytes().to_vec();
        schema.extend(string(TwistStamped::TYPE));
        schema.extend(string("ros2msg"));
        schema.extend_from_slice(&0u32.to_le_bytes());
        b.extend(record(0x03, &schema));
        b.extend(channel(1, "/other"));
        b.extend(message(1, 1_000, &twist_cdr(1_000, 0.5)));
        b.extend(channel(1, second_topic));
        b.extend(message(1, 2_000, &twist_cdr(2_000, 0.25)));
        b.extend(record(0x0F, &0u32.to_le_bytes()));
        b.extend(record(0x02, &[0u8; 20]));
        b.extend_from_slice(MCAP_MAGIC);
        let path = dir.path().join(name);
        std::fs::write(&path, b).unwrap();
        path
    };
    let open = |p: &Path, scope| SessionReader::open_scoped(p, Topics::default(), scope);
    let flip = file("flip.mcap", "/cmd_vel");
    let e = open(&flip, IndexScope::Roles).unwrap_err().to_string();
    assert!(
        e.contains("topic /cmd_vel")
            && e.contains("channel 1 is declared again on another topic (/other before)"),
        "{e}"
    );
    let all = open(&flip, IndexScope::All).unwrap();
    assert_eq!(all.collect_index().unwrap().len(), 2);
    let same = file("same.mcap", "/other");
    let roles = open(&same, IndexScope::Roles).unwrap();
    assert_eq!(roles.collect_index().unwrap().len(), 0);
    assert_eq!(open(&same, IndexScope::All).unwrap().message_count(), 2);
}
