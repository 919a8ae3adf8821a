//! How the reader words a cut or damage at a record boundary or before the first message
//! (unit tests of the reader's warnings and errors).

use std::path::Path;

use super::*;

/// A cut on a record boundary (a recording that was never closed) loses no data anyone knows
/// of: the warning says what is missing instead of "the rest is lost".
#[test]
fn a_cut_between_records_says_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let bytes = write(&path, small_chunks(), &increasing(300));
    let c = &chunk_indexes(&bytes)[2];
    let cut = c.chunk_start_offset as usize;
    let cut_path = dir.path().join("cut.mcap");
    std::fs::write(&cut_path, &bytes[..cut]).unwrap();
    let reader = SessionReader::open(&cut_path, Topics::default()).unwrap();
    assert_eq!(reader.bytes_intact, cut as u64);
    let w = &reader.warnings[0];
    assert!(
        w.contains(&format!("from the first {cut} of {cut} bytes"))
            && w.contains("it ends after a whole record, without the summary and footer")
            && !w.contains("the rest is lost"),
        "{w}"
    );
}

/// Damage in the first chunk names no message, and says so (it read "after the message
/// named here" with none named).
#[test]
fn damage_before_any_message_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let mut bytes = write(&path, small_chunks(), &increasing(300));
    let c = &chunk_indexes(&bytes)[0];
    let at = (c.chunk_start_offset + c.chunk_length - c.compressed_size / 2) as usize;
    bytes[at] ^= 0x40;
    let e =
        SessionReader::from_bytes(Path::new("flip.mcap"), &bytes, Topics::default()).unwrap_err();
    let SessionError::Mcap { at, what, .. } = &e else {
        panic!("{e}");
    };
    assert_eq!((at.topic.as_ref(), at.log_time_ns), (None, None));
    assert!(what.ends_with("(before the first message)"), "{what}");
}
