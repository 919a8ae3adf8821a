//! A track of poses by time, and the one rule for looking a pose up at a stamp.
//!
//! Invariants: poses are sorted by stamp (ties keep their order); a lookup interpolates
//! between the poses around the stamp, refuses a gap (no pose within [`POSE_TOLERANCE_NS`]
//! on either side, and the two more than [`MAX_INTERPOLATED_INTERVAL_NS`] apart) and reaches
//! at most that tolerance beyond either end.

use crate::types::geometry::{Iso3, interpolate};

/// A frame is posed when the track reaches within this of its stamp on both sides (or one
/// side, at the ends of the track).
pub const POSE_TOLERANCE_NS: i64 = 50_000_000;

/// ... or when the two poses around its stamp are at most this far apart, whatever the
/// distance to either: odometry at 4-5 Hz (a frame between two messages 200 ms apart was
/// refused as in a gap, half the frames of such a bag; tf2 interpolates any interval). A
/// quarter second of a robot's motion is close to a straight line and an even turn; a wider
/// hole is a gap still.
pub const MAX_INTERPOLATED_INTERVAL_NS: i64 = 250_000_000;

/// Where a stamp falls in a sorted list of stamps.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Bracket {
    /// Exactly at entry i.
    At(usize),
    /// Between entries i and i + 1, at fraction s of the way.
    Between(usize, f64),
    /// Within the tolerance before the first or after the last entry i.
    Near(usize),
}

fn bracket(
    stamps: impl Fn(usize) -> i64,
    len: usize,
    stamp_ns: i64,
    gaps: bool,
) -> Option<Bracket> {
    // First index whose stamp is not before `stamp_ns`.
    let (mut lo, mut hi) = (0, len);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if stamps(mid) < stamp_ns {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    let i = lo;
    if i < len && stamps(i) == stamp_ns {
        return Some(Bracket::At(i));
    }
    match (i.checked_sub(1), (i < len).then_some(i)) {
        (Some(a), Some(b)) => {
            let (t0, t1) = (stamps(a), stamps(b));
            if gaps
                && stamp_ns - t0 > POSE_TOLERANCE_NS
                && t1 - stamp_ns > POSE_TOLERANCE_NS
                && t1 - t0 > MAX_INTERPOLATED_INTERVAL_NS
            {
                // A gap: interpolating across it would invent a pose.
                return None;
            }
            Some(Bracket::Between(
                a,
                (stamp_ns - t0) as f64 / (t1 - t0) as f64,
            ))
        }
        (Some(a), None) => (stamp_ns - stamps(a) <= POSE_TOLERANCE_NS).then_some(Bracket::Near(a)),
        (None, Some(b)) => (stamps(b) - stamp_ns <= POSE_TOLERANCE_NS).then_some(Bracket::Near(b)),
        (None, None) => None,
    }
}

/// Whether a track with these (sorted) stamps has a pose at `stamp_ns` by [`PoseTrack::at`].
pub fn covered(stamps: &[i64], stamp_ns: i64) -> bool {
    bracket(|i| stamps[i], stamps.len(), stamp_ns, true).is_some()
}

/// Poses by stamp (nanoseconds), sorted.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseTrack {
    poses: Vec<(i64, Iso3)>,
    /// Stamps (sorted) at which a [`PoseTrack::sampled_at`] track's source had no pose.
    missing: Vec<i64>,
}

impl PoseTrack {
    /// The track of `poses`, sorted by stamp (stable: equal stamps keep their order).
    pub fn new(mut poses: Vec<(i64, Iso3)>) -> Self {
        poses.sort_by_key(|(t, _)| *t);
        Self {
            poses,
            missing: Vec::new(),
        }
    }

    /// This track's lookups at `stamps` alone, kept as a track: at each of those stamps
    /// [`PoseTrack::at`] gives what this track gives, bit for bit (a pose at an exact stamp is
    /// returned, not interpolated; a stamp this track has no pose for has none); between them
    /// it interpolates the samples kept. A replay asks odometry only at its frames' and
    /// commands' stamps, so its tracks need not keep every message: /odom and
    /// /ground_truth/pose at 50 Hz were 64 bytes a message each for the whole replay.
    pub fn sampled_at(&self, stamps: &[i64]) -> Self {
        let mut stamps = stamps.to_vec();
        stamps.sort_unstable();
        stamps.dedup();
        let (mut poses, mut missing) = (Vec::new(), Vec::new());
        for t in stamps {
            match self.at(t) {
                Some(p) => poses.push((t, p)),
                None => missing.push(t),
            }
        }
        Self { poses, missing }
    }

    /// The poses, sorted by stamp.
    pub fn poses(&self) -> &[(i64, Iso3)] {
        &self.poses
    }

    /// Whether the track has no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The pose at `stamp_ns`: interpolated between the poses around it; `None` across a gap
    /// (no pose within [`POSE_TOLERANCE_NS`] on either side, and the two around it more than
    /// [`MAX_INTERPOLATED_INTERVAL_NS`] apart) or further than the tolerance beyond the
    /// track's ends.
    pub fn at(&self, stamp_ns: i64) -> Option<Iso3> {
        if self.missing.binary_search(&stamp_ns).is_ok() {
            return None;
        }
        self.resolve(bracket(
            |i| self.poses[i].0,
            self.poses.len(),
            stamp_ns,
            true,
        )?)
    }

    /// Like [`PoseTrack::at`] but interpolating across gaps of any length: for trajectories
    /// that are sparse by design (one pose per keyframe).
    pub fn interpolated(&self, stamp_ns: i64) -> Option<Iso3> {
        self.resolve(bracket(
            |i| self.poses[i].0,
            self.poses.len(),
            stamp_ns,
            false,
        )?)
    }

    fn resolve(&self, b: Bracket) -> Option<Iso3> {
        Some(match b {
            Bracket::At(i) | Bracket::Near(i) => self.poses[i].1,
            Bracket::Between(i, s) => interpolate(&self.poses[i].1, &self.poses[i + 1].1, s),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::geometry::iso_from_xy_yaw;

    #[test]
    fn pose_interpolates_and_refuses_gaps() {
        let track = PoseTrack::new(vec![
            (100_000_000, iso_from_xy_yaw(1.0, 0.0, 0.0)),
            (0, iso_from_xy_yaw(0.0, 0.0, 0.0)),
            (1_100_000_000, iso_from_xy_yaw(2.0, 0.0, 0.0)),
        ]);
        let x = |p: Option<Iso3>| p.map(|p| p.translation.x);
        assert!((x(track.at(25_000_000)).unwrap() - 0.25).abs() < 1e-12);
        // 40 ms after a pose, within tolerance: interpolated across the long interval.
        assert!((x(track.at(140_000_000)).unwrap() - 1.04).abs() < 1e-12);
        // 0.5 s from both ends: a gap, no pose; unless gaps are allowed.
        assert!(track.at(600_000_000).is_none());
        assert!((x(track.interpolated(600_000_000)).unwrap() - 1.5).abs() < 1e-12);
        // Within 50 ms past the end: the last pose; beyond: none, gaps or not.
        assert_eq!(x(track.at(1_140_000_000)), Some(2.0));
        assert!(track.at(1_160_000_000).is_none() && track.interpolated(1_160_000_000).is_none());
        assert!(track.at(-60_000_000).is_none());
        assert!(covered(&[0, 100_000_000], 120_000_000) && !covered(&[0], 60_000_000));
        assert!(PoseTrack::default().at(0).is_none());
        // Odometry at 5 Hz: a frame halfway between two messages 200 ms apart is posed; 300
        // ms apart is a gap.
        let five_hz = PoseTrack::new(vec![
            (0, iso_from_xy_yaw(0.0, 0.0, 0.0)),
            (200_000_000, iso_from_xy_yaw(0.2, 0.0, 0.0)),
            (500_000_000, iso_from_xy_yaw(0.5, 0.0, 0.0)),
        ]);
        assert!((x(five_hz.at(100_000_000)).unwrap() - 0.1).abs() < 1e-12);
        assert!(five_hz.at(350_000_000).is_none());
        assert!(
            covered(&[0, 200_000_000], 100_000_000) && !covered(&[0, 300_000_000], 150_000_000)
        );
    }

    #[test]
    fn a_sampled_track_answers_its_stamps_as_the_full_one() {
        let full = PoseTrack::new(
            (0..40)
                .map(|k| {
                    (
                        k * 20_000_000,
                        iso_from_xy_yaw(0.1 * k as f64, 0.0, 0.03 * k as f64),
                    )
                })
                .chain([(2_000_000_000, iso_from_xy_yaw(9.0, 0.0, 0.0))])
                .collect(),
        );
        // Between samples, on a sample, in the 1.2 s gap before the last pose, past the end.
        let stamps = [
            333_000_000,
            400_000_000,
            1_500_000_000,
            5_000_000_000,
            17_000_000,
        ];
        let sampled = full.sampled_at(&stamps);
        for t in stamps {
            assert_eq!(sampled.at(t), full.at(t), "{t}");
        }
        assert!(sampled.at(1_500_000_000).is_none() && full.at(1_500_000_000).is_none());
        // Interpolated once from the full track, then returned as it was: bit for bit.
        assert_eq!(
            sampled.at(333_000_000).map(|p| p.translation.x.to_bits()),
            full.at(333_000_000).map(|p| p.translation.x.to_bits())
        );
        assert_eq!(sampled.poses().len(), 3);
    }
}
