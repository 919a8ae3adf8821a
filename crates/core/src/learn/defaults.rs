//! The tile head's defaults that depend on the training sessions: a ground robot's (its
//! sessions have /cmd_vel) against a posed capture's, and a capture's tile side against its
//! image size. Invariant: a pure function of the sessions' command counts and frame sizes and
//! of what the user chose, so the same sessions and options train the same model.

use crate::learn::dataset::{Augment, LoadedSession, TILE_PX_RANGE};
use crate::learn::features::FeatureSpec;

/// The tile side of the paper and of every session measured so far, px.
pub const TILE_PX: u32 = 8;
/// The shift between shifted training grids at [`TILE_PX`], px.
pub const TRAIN_STRIDE_PX: u32 = 4;
/// A capture's tile side grows by [`TILE_PX`] for every this many pixels of its frames'
/// shorter side (rounded up): 8 px up to 880 px (every real capture measured: 384-855 px, 48
/// to 107 tiles across), 16 px for a 1080 x 1920 phone frame (68 across), 32 px at 3024 px.
/// Measured (docs/tree.md, "Tile side by image size"): on the fruit capture at twice its size
/// 8 px tiles score 0.014-0.016 less tile AUC and place the objects 0.8-3.4 % of their size
/// further off than 16 px tiles with an 8 px stride, which see what 8 px tiles see at its own
/// size.
pub const CAPTURE_PX_PER_TILE_STEP: u32 = 880;
/// Trees in a capture's tile head (a ground robot's keeps the paper's one). Measured
/// (docs/tree.md, "A forest for captures"): the tile AUC rises on every real capture (apple
/// 0.947 -> 0.964, house 0.918 -> 0.928; perturbed house 0.860 -> 0.909), and the foreign
/// robot sessions taken as perturbed captures go from 7 to 12 of 12 right; 8 trees gain
/// less, 32 no more. On the robots' own sessions a forest was not better on the foreign set
/// (9 -> 8 of 12), so they keep one tree.
pub const CAPTURE_TREES: u32 = 16;

/// What the user chose on the command line (None: left to the sessions).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TileHeadChoice {
    /// `--features`.
    pub features: Option<FeatureSpec>,
    /// `--augment`.
    pub augment: Option<Augment>,
    /// `--tile`.
    pub tile_px: Option<u32>,
    /// `--train-stride`.
    pub train_stride_px: Option<u32>,
    /// `--trees`.
    pub trees: Option<u32>,
}

/// The tile head's channels, light variants, tiles and trees where `train` is not told them, chosen
/// by the training sessions. A ground robot's (every session has /cmd_vel) keeps the paper's
/// rgb332 on frames as recorded in 8 px tiles. A posed capture (phone, arm, structure from
/// motion: a session without /cmd_vel) gets rgb332+hs on light variants of the shifted grids,
/// in tiles that grow with its frames ([`CAPTURE_PX_PER_TILE_STEP`]), classified by a forest
/// ([`CAPTURE_TREES`]). Measured (docs/tree.md,
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
    /// Tile side, px.
    pub tile_px: u32,
    /// Shift between shifted training grids, px.
    pub train_stride_px: u32,
    /// Trees whose mean is the tile head's probability (1: the paper's tree).
    pub trees: u32,
    /// Some session has no /cmd_vel.
    pub capture: bool,
    /// The shorter side of the smallest training frame, px (0 without frames).
    pub short_side_px: u32,
}

impl TileHeadDefaults {
    /// The defaults for `sessions` where `choice` leaves them open. A fitted tile takes half
    /// its side as the stride; a chosen one keeps the stride's default ([`TRAIN_STRIDE_PX`]).
    /// Light variants only where shifted grids exist to carry them.
    pub fn for_sessions(sessions: &[LoadedSession], choice: TileHeadChoice) -> Self {
        let commands: Vec<usize> = sessions.iter().map(|s| s.commands).collect();
        let short_side_px = sessions
            .iter()
            .flat_map(|s| &s.frames)
            .map(|f| f.image.width.min(f.image.height))
            .min()
            .unwrap_or(0);
        Self::of(&commands, short_side_px, choice)
    }

    /// [`TileHeadDefaults::for_sessions`] from each session's /cmd_vel message count and the
    /// shorter side of the smallest frame.
    pub fn of(commands_per_session: &[usize], short_side_px: u32, choice: TileHeadChoice) -> Self {
        let capture = commands_per_session.contains(&0);
        let fitted_tile = if capture {
            (TILE_PX * short_side_px.div_ceil(CAPTURE_PX_PER_TILE_STEP).max(1))
                .min(*TILE_PX_RANGE.end())
        } else {
            TILE_PX
        };
        let tile_px = choice.tile_px.unwrap_or(fitted_tile);
        let train_stride_px = choice.train_stride_px.unwrap_or(match choice.tile_px {
            None => tile_px / 2,
            Some(_) => TRAIN_STRIDE_PX,
        });
        let features = choice.features.unwrap_or(if capture {
            FeatureSpec::RGB332_HS
        } else {
            FeatureSpec::RGB332
        });
        let augment = choice
            .augment
            .unwrap_or(if capture && train_stride_px < tile_px {
                Augment::Light
            } else {
                Augment::None
            });
        let trees = choice
            .trees
            .unwrap_or(if capture { CAPTURE_TREES } else { 1 });
        Self {
            features,
            augment,
            tile_px,
            train_stride_px,
            trees,
            capture,
            short_side_px,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OPEN: TileHeadChoice = TileHeadChoice {
        features: None,
        augment: None,
        tile_px: None,
        train_stride_px: None,
        trees: None,
    };

    /// A robot's set keeps the paper's channels and tiles whatever its frames' size; one
    /// capture among the sessions makes the set a capture's; light variants need shifted
    /// grids.
    #[test]
    fn the_tile_head_defaults_follow_the_sessions_commands() {
        let robot = TileHeadDefaults::of(&[60, 126], 1080, OPEN);
        assert_eq!(
            (
                robot.features,
                robot.augment,
                robot.tile_px,
                robot.train_stride_px
            ),
            (FeatureSpec::RGB332, Augment::None, 8, 4)
        );
        assert_eq!(robot.trees, 1);
        assert!(!robot.capture);
        let capture = TileHeadDefaults::of(&[60, 0], 605, OPEN);
        assert_eq!(capture.features.to_string(), "rgb332+hs");
        assert_eq!(capture.augment, Augment::Light);
        assert_eq!((capture.tile_px, capture.train_stride_px), (8, 4));
        assert_eq!(capture.trees, CAPTURE_TREES);
        assert!(capture.capture);
        let unshifted = TileHeadDefaults::of(
            &[0],
            605,
            TileHeadChoice {
                train_stride_px: Some(8),
                ..OPEN
            },
        );
        assert_eq!(unshifted.augment, Augment::None);
    }

    /// A capture's tile is 8 px up to 880 px of shorter side and 8 px more for each further
    /// 880 (started), half of it the stride; a chosen tile keeps the stride of 4 px unless it
    /// is chosen too.
    #[test]
    fn a_captures_tile_grows_with_its_frames() {
        let tile = |short| {
            let d = TileHeadDefaults::of(&[0], short, OPEN);
            (d.tile_px, d.train_stride_px)
        };
        assert_eq!(tile(240), (8, 4));
        assert_eq!(tile(855), (8, 4));
        assert_eq!(tile(880), (8, 4));
        assert_eq!(tile(881), (16, 8));
        assert_eq!(tile(1080), (16, 8));
        assert_eq!(tile(3024), (32, 16));
        assert_eq!(tile(100_000), (128, 64));
        let chosen = TileHeadDefaults::of(
            &[0],
            1080,
            TileHeadChoice {
                tile_px: Some(12),
                ..OPEN
            },
        );
        assert_eq!((chosen.tile_px, chosen.train_stride_px), (12, 4));
    }
}
