//! How the reader words a cut at a record boundary (a unit test of its truncation warning).

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
