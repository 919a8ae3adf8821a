//! The tile head's defaults that depend on the training sessions: a ground robot's (its
//! sessions have /cmd_vel) against a posed capture's. Invariant: a pure function of the
//! sessions' command counts and the grid options, so the same sessions train the same model.

use crate::learn::dataset::Augment;
use crate::learn::features::FeatureSpec;

/// The tile head's channels and light variants where `train` is not told them, chosen by the
/// training sessions: a ground robot's (every session has /cmd_vel) keeps the paper's rgb332 on
/// frames as recorded; a posed capture (phone, arm, structure from motion: a session without
/// /cmd_vel) gets rgb332+hs on light variants of the shifted grids. Measured (docs/tree.md,
/// "Defaults by kind of session"): on the simulated and foreign robot sessions every
/// alternative to rgb332 loses tours; on real captures, where exposure and white balance change
/// between frames, the hue-saturation channel and the light variants lift the tile AUC (apple
/// 0.908 -> 0.945 on a perturbed copy) and cost at most 0.007 of it on the captures as they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileHeadDefaults {
    /// The tile head's channels.
    pub features: FeatureSpec,
    /// The shifted grids' photometric variants.
    pub augment: Augment,
    /// Some session has no /cmd_vel.
    pub capture: bool,
}

impl TileHeadDefaults {
    /// The defaults for sessions with `commands_per_session` /cmd_vel messages each; light
    /// variants only where shifted grids exist to carry them (`train_stride_px < tile_px`).
    pub fn for_sessions(
        commands_per_session: &[usize],
        train_stride_px: u32,
        tile_px: u32,
    ) -> Self {
        let capture = commands_per_session.contains(&0);
        Self {
            features: if capture {
                FeatureSpec::RGB332_HS
            } else {
                FeatureSpec::RGB332
            },
            augment: if capture && train_stride_px < tile_px {
                Augment::Light
            } else {
                Augment::None
            },
            capture,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A robot's set keeps the paper's channels; one capture among the sessions makes the set
    /// a capture's; light variants need shifted grids.
    #[test]
    fn the_tile_head_defaults_follow_the_sessions_commands() {
        let robot = TileHeadDefaults::for_sessions(&[60, 126], 4, 8);
        assert_eq!(
            (robot.features, robot.augment),
            (FeatureSpec::RGB332, Augment::None)
        );
        assert!(!robot.capture);
        let capture = TileHeadDefaults::for_sessions(&[60, 0], 4, 8);
        assert_eq!(capture.features.to_string(), "rgb332+hs");
        assert_eq!(capture.augment, Augment::Light);
        assert!(capture.capture);
        let unshifted = TileHeadDefaults::for_sessions(&[0], 8, 8);
        assert_eq!(unshifted.augment, Augment::None);
    }
}
