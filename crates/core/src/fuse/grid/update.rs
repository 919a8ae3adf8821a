//! Changing a grid: a frame's update (storing the blocks it reaches first), a frame's
//! evidence set aside and added later (the observation blur), and taking over the output of
//! a blur pass ([`convolve::convolve`]).
//!
//! Invariants: blocks are stored before anything is written to them, and only when the
//! budget allows (else [`GridError::Allocation`] and the grid unchanged); a blur's output
//! blocks that were not stored and came out all zero are not stored; the blocks' order after
//! a blur is ascending, which does not change any value.

use super::blocks::gather;
use super::*;

impl Grid {
    /// The paper's update for one frame: every cell whose centre lies in front of the camera
    /// no deeper than `max_depth_m` (see [`max_depth_m`]; infinite for no limit) and projects
    /// into tile (r, c) gets `evidence += delta[r, c]` (then the clamp, if any).
    ///
    /// Centre projection, not any-overlap: a cell belongs to exactly one tile's pyramid, so
    /// each frame counts once per cell, as the Markov assumption of the update requires. With
    /// any-overlap a cell straddling a tile edge would take the evidence of two or more tiles
    /// of the same image, counting one observation several times, and cells near the camera
    /// (larger than a tile's footprint) would collect the evidence of many tiles.
    ///
    /// Stores the blocks of the cells it updates first. Returns the number of cells updated.
    pub fn integrate(
        &mut self,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &TileEvidence,
        max_depth_m: f64,
    ) -> Result<usize, GridError> {
        let proj = self.project(camera_from_odom, camera, ev, max_depth_m)?;
        let clamp = self.evidence_clamp();
        Ok(
            proj.apply(&self.layout, &mut self.evidence, &mut self.views, |e, d| {
                let mut v = *e + d;
                if let Some((a, b)) = clamp {
                    v = v.clamp(a, b);
                }
                *e = v;
            }),
        )
    }

    /// One frame's evidence without applying it: `out` gets one value per stored cell (laid
    /// out like the grid), the tile's delta for cells in the frame's pyramids and 0
    /// elsewhere. Stores the blocks it reaches and counts the view like [`Grid::integrate`].
    pub fn frame_evidence(
        &mut self,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &TileEvidence,
        max_depth_m: f64,
        out: &mut Vec<f32>,
    ) -> Result<usize, GridError> {
        let proj = self.project(camera_from_odom, camera, ev, max_depth_m)?;
        out.clear();
        out.resize(self.evidence.len(), 0.0);
        Ok(proj.apply(&self.layout, out, &mut self.views, |o, d| *o = d))
    }

    /// The frame's projector, with the blocks its update reaches stored.
    fn project<'a>(
        &mut self,
        camera_from_odom: &Iso3,
        camera: &Camera,
        ev: &'a TileEvidence,
        max_depth_m: f64,
    ) -> Result<Projector<'a>, GridError> {
        let proj = Projector::new(
            &self.spec,
            camera_from_odom,
            camera,
            ev,
            max_depth_m,
            self.budget.max_bytes,
        )?;
        self.store(&proj.new_blocks(&self.layout))?;
        Ok(proj)
    }

    /// Adds per-cell evidence (log likelihood ratios, laid out like the grid), then applies
    /// the clamp if any.
    pub fn add_evidence(&mut self, evidence: &[f32]) {
        let clamp = self.evidence_clamp();
        self.evidence
            .par_iter_mut()
            .zip(evidence.par_iter())
            .for_each(|(l, &e)| {
                if e != 0.0 {
                    let mut v = *l + e;
                    if let Some((a, b)) = clamp {
                        v = v.clamp(a, b);
                    }
                    *l = v;
                }
            });
    }

    /// The clamp as bounds on the evidence.
    fn evidence_clamp(&self) -> Option<(f32, f32)> {
        let p = self.prior_log_odds();
        self.clamp.map(|(a, b)| (a - p, b - p))
    }

    /// Makes a blur's output the grid's evidence: `values` holds the zero block and then one
    /// block per entry of `blocks` (ascending: every stored block and perhaps more). Blocks
    /// not stored before that came out all zero are dropped; the rest are stored in that
    /// order. Afterwards `values` holds the old evidence (scratch for the next blur).
    pub(crate) fn adopt_evidence(
        &mut self,
        blocks: &mut Vec<u32>,
        values: &mut Vec<f32>,
    ) -> Result<(), GridError> {
        if let Some(old) = self.keep_and_relayout(blocks, values)? {
            self.views = gather(&self.views, &old);
        }
        std::mem::swap(&mut self.evidence, values);
        Ok(())
    }

    /// Lays the grid out like a blur pass's output `values` over `blocks` (see
    /// [`Grid::adopt_evidence`]) and moves its evidence and views along, leaving `values`
    /// as it is: for passes over a field other than the evidence (the observation blur's
    /// likelihood ratios).
    pub(crate) fn adopt_layout<T: convolve::Sample>(
        &mut self,
        blocks: &mut Vec<u32>,
        values: &mut Vec<T>,
    ) -> Result<(), GridError> {
        if let Some(old) = self.keep_and_relayout(blocks, values)? {
            self.views = gather(&self.views, &old);
            self.evidence = gather(&self.evidence, &old);
        }
        Ok(())
    }

    /// Drops from `blocks` and `values` the unstored blocks that are all zero, checks the
    /// budget and re-lays the grid out over the rest; returns each new slot's old slot, or
    /// None when the layout is the same.
    fn keep_and_relayout<T: convolve::Sample>(
        &mut self,
        blocks: &mut Vec<u32>,
        values: &mut Vec<T>,
    ) -> Result<Option<Vec<u32>>, GridError> {
        let keep: Vec<bool> = blocks
            .par_iter()
            .zip(values[BLOCK_CELLS..].par_chunks(BLOCK_CELLS))
            .map(|(&b, v)| self.layout.table[b as usize] != 0 || v.iter().any(|&x| x != T::ZERO))
            .collect();
        if keep.iter().any(|k| !k) {
            let mut to = 0;
            for (from, &k) in keep.iter().enumerate() {
                if k {
                    if to != from {
                        blocks[to] = blocks[from];
                        values.copy_within(
                            (from + 1) * BLOCK_CELLS..(from + 2) * BLOCK_CELLS,
                            (to + 1) * BLOCK_CELLS,
                        );
                    }
                    to += 1;
                }
            }
            blocks.truncate(to);
            values.truncate((to + 1) * BLOCK_CELLS);
        }
        if self.layout.is_exactly(blocks) {
            return Ok(None);
        }
        self.check_budget(blocks.len() + 1)?;
        Ok(Some(self.layout.relayout(blocks)))
    }
}
