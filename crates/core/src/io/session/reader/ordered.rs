//! The ordered merge: a session's indexed messages in (log time, channel id, sequence) order,
//! read chunk by chunk through the chunk index the scan built.
//!
//! Invariants: a segment is opened (its chunk decompressed, through the cache) only when no
//! pending message has a log time below the segment's first one, so every message handed out
//! precedes, in the total order (log time, channel id, sequence, place in the file), every
//! message still unopened: the order is exactly that of sorting every message, whatever the
//! file's layout. What is held at once is the messages of the chunks whose time ranges
//! overlap the current time, 32 bytes each; a file whose chunks all span the whole session
//! (one chunk per topic, say) makes that every message, as a full index would. A chunk read
//! again must hold as many indexed messages as the scan counted, or the merge stops with an
//! error naming the file and the topic and log time of the segment's first message.

use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

use super::super::{At, SessionError};
use super::{MessageMeta, Opening, Segment, SessionReader};

/// A message in the merge's order.
#[derive(Debug, PartialEq, Eq)]
struct ByOrder(MessageMeta);

impl ByOrder {
    fn key(&self) -> (u64, u16, u32, u64) {
        let m = &self.0;
        (m.log_time_ns, m.channel_id, m.sequence, m.loc)
    }
}

impl Ord for ByOrder {
    fn cmp(&self, other: &Self) -> Ordering {
        self.key().cmp(&other.key())
    }
}

impl PartialOrd for ByOrder {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// The indexed messages of a [`SessionReader`] in replay order, without their payloads
/// ([`SessionReader::ordered`]). After an error it yields nothing more.
#[derive(Debug)]
pub struct Ordered<'a> {
    reader: &'a SessionReader,
    /// The next segment of the reader's plan to open.
    next_opening: usize,
    pending: BinaryHeap<Reverse<ByOrder>>,
    failed: bool,
}

impl SessionReader {
    /// Every indexed message (all, or those of the roles: [`super::IndexScope`]) in
    /// (log time, channel id, sequence) order, equal keys in file order; chunks are read as
    /// the merge reaches them.
    pub fn ordered(&self) -> Ordered<'_> {
        Ordered {
            reader: self,
            next_opening: 0,
            pending: BinaryHeap::new(),
            failed: false,
        }
    }
}

impl Iterator for Ordered<'_> {
    type Item = Result<MessageMeta, SessionError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        while let Some(&o) = self.reader.openings.get(self.next_opening) {
            // `<=`: a message at the same log time may still precede by channel or sequence.
            let due = self
                .pending
                .peek()
                .is_none_or(|Reverse(m)| o.start_ns <= m.0.log_time_ns);
            if !due {
                break;
            }
            self.next_opening += 1;
            if let Err(e) = self.open(o) {
                self.failed = true;
                return Some(Err(e));
            }
        }
        self.pending.pop().map(|Reverse(m)| Ok(m.0))
    }
}

impl Ordered<'_> {
    /// Messages read from opened chunks and not yet handed out: what the merge holds now.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Adds the indexed messages of the segment `o` to the pending ones.
    fn open(&mut self, o: Opening) -> Result<(), SessionError> {
        let r = self.reader;
        let at = || At {
            path: r.path.clone(),
            topic: r.channels.get(&o.start_channel).map(|c| c.topic.clone()),
            log_time_ns: Some(o.start_ns),
        };
        let segment_loc = u64::from(o.segment) << 32;
        match r.segments.get(o.segment as usize).copied() {
            Some(Segment::Payload(_)) => {
                let i = r
                    .loose
                    .binary_search_by_key(&segment_loc, |m| m.loc)
                    .map_err(|_| SessionError::Invalid {
                        at: at(),
                        what: format!("segment {} is not an indexed message", o.segment),
                    })?;
                self.pending.push(Reverse(ByOrder(r.loose[i])));
            }
            Some(Segment::Chunk(span)) => {
                let payloads = r.chunk_payloads(o.segment as usize, span, at)?;
                let before = self.pending.len();
                for (ordinal, m) in payloads.messages.iter().enumerate() {
                    if r.unindexed.contains(&m.channel_id) {
                        continue;
                    }
                    self.pending.push(Reverse(ByOrder(MessageMeta {
                        log_time_ns: m.log_time_ns,
                        publish_time_ns: m.publish_time_ns,
                        loc: segment_loc | ordinal as u64,
                        sequence: m.sequence,
                        channel_id: m.channel_id,
                    })));
                }
                let found = self.pending.len() - before;
                if found != o.indexed as usize {
                    return Err(SessionError::Invalid {
                        at: at(),
                        what: format!(
                            "the chunk at byte {} holds {found} messages to read, {} when the file was opened (the file changed since?)",
                            span.offset_bytes, o.indexed
                        ),
                    });
                }
            }
            None => {
                return Err(SessionError::Invalid {
                    at: at(),
                    what: format!("no segment {} in the file's index", o.segment),
                });
            }
        }
        Ok(())
    }
}
