//! The fuser state: grid, blur scratch and options; takes typed values, returns state.

use crate::fuse::grid::{
    Budget, Grid, GridError, GridSpec, MAX_GRID_BYTES, TileEvidence, logit, max_depth_m,
};
use crate::fuse::motion::{BlurMode, Blurrer, Segment};
use crate::types::geometry::{Camera, Iso3, yaw_of};
use crate::types::probs::TileProbs;

use super::*;

/// The fuser state: grid, blur scratch and options. Takes typed values, returns state.
pub struct Fuser {
    /// The belief being fused into.
    pub grid: Grid,
    /// How to fuse: blur mode, speed noise, clamp, object rule, refinement.
    pub options: FuseOptions,
    blurrer: Blurrer,
    /// Pose variance accumulated since the first frame (for [`BlurMode::Observation`]):
    /// heading, rad^2, and position, m^2.
    heading_var_rad2: f64,
    position_var_m2: f64,
    evidence: Vec<f32>,
    /// Cells the last [`Fuser::integrate`] updated.
    pub last_cells_updated: usize,
}

impl Fuser {
    /// A fuser with a fresh grid at `prior`, stored as `options.grid_storage` says;
    /// [`GridError::Prior`] or [`GridError::Clamp`] when `prior` or `options.clamp` is not a
    /// valid probability (range), [`GridError::TooLarge`] for a dense grid that does not fit.
    pub fn new(spec: GridSpec, prior: f64, options: FuseOptions) -> Result<Self, GridError> {
        let budget = Budget {
            max_bytes: MAX_GRID_BYTES,
            f64_blur: options.blur != BlurMode::LogOdds,
        };
        let mut grid = Grid::with_storage(spec, prior, options.grid_storage, budget)?;
        if let Some((lo, hi)) = options.clamp {
            if !(lo > 0.0 && hi < 1.0 && lo < hi) {
                return Err(GridError::Clamp { lo, hi });
            }
            grid.clamp = Some((logit(lo) as f32, logit(hi) as f32));
        }
        Ok(Self {
            grid,
            options,
            blurrer: Blurrer::default(),
            heading_var_rad2: 0.0,
            position_var_m2: 0.0,
            evidence: Vec::new(),
            last_cells_updated: 0,
        })
    }

    /// Blurs the belief by one command segment; `odom_from_base` is the pose at its start.
    /// [`GridError::Allocation`] when a sparse grid cannot store the blocks it reaches.
    pub fn blur(&mut self, seg: &Segment, odom_from_base: &Iso3) -> Result<(), GridError> {
        let t = seg.duration_s();
        if self.options.blur == BlurMode::Observation {
            // The belief stays; the uncertainty is carried to the next frame's evidence.
            if seg.v_mps != 0.0 {
                self.position_var_m2 += (self.options.sigma_v_mps * t).powi(2);
            }
            if seg.w_radps != 0.0 {
                self.heading_var_rad2 += (self.options.sigma_w_radps * t).powi(2);
            }
            return Ok(());
        }
        if seg.v_mps != 0.0 {
            let yaw = yaw_of(odom_from_base);
            self.blurrer.translate(
                &mut self.grid,
                [yaw.cos(), yaw.sin()],
                self.options.sigma_v_mps * t,
                self.options.blur,
            )?;
        }
        if seg.w_radps != 0.0 {
            let c = odom_from_base.translation.vector;
            self.blurrer.rotate(
                &mut self.grid,
                [c.x, c.y],
                self.options.sigma_w_radps * t,
                self.options.blur,
            )?;
        }
        Ok(())
    }

    /// Drops the pose uncertainty accumulated for [`BlurMode::Observation`]: the next frame's
    /// pose has been measured against the belief.
    pub fn forget_motion(&mut self) {
        self.heading_var_rad2 = 0.0;
        self.position_var_m2 = 0.0;
    }

    /// Integrates one frame's tile probabilities seen from `odom_from_camera`, no deeper than
    /// the range limit (`options.max_footprint_voxels`); returns the cells updated.
    /// `odom_from_base` is the robot's pose, the centre of heading uncertainty.
    /// [`GridError::Allocation`] when a sparse grid cannot store the blocks it reaches.
    pub fn integrate(
        &mut self,
        odom_from_camera: &Iso3,
        odom_from_base: &Iso3,
        camera: &Camera,
        probs: &TileProbs,
    ) -> Result<usize, GridError> {
        let ev = TileEvidence::from_probabilities(
            probs.rows,
            probs.cols,
            probs.tile_px,
            &probs.p,
            self.grid.prior,
        );
        let camera_from_odom = odom_from_camera.inverse();
        let depth = max_depth_m(
            camera,
            probs.tile_px,
            self.grid.spec.voxel_size_m,
            self.options.max_footprint_voxels,
        );
        if self.options.blur != BlurMode::Observation {
            return self.grid.integrate(&camera_from_odom, camera, &ev, depth);
        }
        let n =
            self.grid
                .frame_evidence(&camera_from_odom, camera, &ev, depth, &mut self.evidence)?;
        let c = odom_from_base.translation.vector;
        self.blurrer.spread_evidence(
            &mut self.grid,
            &mut self.evidence,
            [c.x, c.y],
            self.heading_var_rad2.sqrt(),
            self.position_var_m2.sqrt(),
        )?;
        self.grid.add_evidence(&self.evidence);
        Ok(n)
    }
}
