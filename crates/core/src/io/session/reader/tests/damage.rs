//! How the reader words a cut at a record boundary and a damaged summary (unit tests of its
//! warnings).

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

/// Where the footer record starts in a closed file, and the summary start it holds (the
/// footer: opcode, length, summary_start, summary_offset_start, crc; then the magic).
fn footer_and_summary_start(bytes: &[u8]) -> (usize, u64) {
    let footer = bytes.len() - 8 - (1 + 8 + 8 + 8 + 4);
    let start = u64::from_le_bytes(bytes[footer + 9..footer + 17].try_into().unwrap());
    (footer, start)
}

/// A summary zeroed in a file that still ends with its footer and magic: every message is
/// read, with a warning (the whole file was refused, its data intact).
#[test]
fn a_damaged_summary_keeps_every_message() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let mut bytes = write(&path, small_chunks(), &increasing(300));
    let (footer, summary_start) = footer_and_summary_start(&bytes);
    assert!(summary_start > 0 && (summary_start as usize) < footer);
    bytes[summary_start as usize..footer].fill(0);
    let zeroed = dir.path().join("zeroed.mcap");
    std::fs::write(&zeroed, &bytes).unwrap();
    let reader = SessionReader::open(&zeroed, Topics::default()).unwrap();
    assert_eq!(read_all(&reader), old_order(&std::fs::read(&path).unwrap()));
    // Zero bytes read as empty records of opcode 0 until the footer's: the damage is met
    // somewhere after the summary's start.
    assert!(reader.bytes_intact >= summary_start);
    let w = &reader.warnings[0];
    assert!(
        w.contains(&format!(
            "the summary section after byte {} does not read",
            reader.bytes_intact
        )) && w.ends_with("every message up to the data section's end was read"),
        "{w}"
    );
}

/// A footer whose summary offset points past the file's end (a writer's bug, or damage):
/// every message is read by the scan, and the warning names the offset and the true start
/// (it passed silently outside `inspect --quick`). An intact file has no warning.
#[test]
fn a_footer_pointing_elsewhere_is_said() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("whole.mcap");
    let mut bytes = write(&path, small_chunks(), &increasing(300));
    assert!(
        SessionReader::open(&path, Topics::default())
            .unwrap()
            .warnings
            .is_empty()
    );
    let (footer, summary_start) = footer_and_summary_start(&bytes);
    bytes[footer + 9..footer + 17].copy_from_slice(&1_000_000_000_000u64.to_le_bytes());
    let bad = dir.path().join("bad-footer.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    let reader = SessionReader::open(&bad, Topics::default()).unwrap();
    assert_eq!(read_all(&reader), old_order(&std::fs::read(&path).unwrap()));
    assert_eq!(reader.warnings.len(), 1, "{:?}", reader.warnings);
    let w = &reader.warnings[0];
    assert!(
        w.contains("the footer says the summary starts at byte 1000000000000")
            && w.contains(&format!("but it starts at byte {summary_start}")),
        "{w}"
    );
}
