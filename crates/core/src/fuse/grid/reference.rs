//! A plain reference of the grid for tests: every cell in one C-order array, the update
//! testing every cell, the blur summing every cell's samples. The blocked grid, dense or
//! sparse, must hold exactly its values.

use nalgebra::{Point3, Vector3};

use super::convolve::{ColumnKernel, Sample};
use super::{FLUSH_EVIDENCE, Grid, GridSpec, TileEvidence};
use crate::types::geometry::{Camera, Iso3};

/// Evidence and views of every cell, C order.
#[derive(Debug, Clone)]
pub(super) struct Plain {
    pub(super) spec: GridSpec,
    pub(super) evidence: Vec<f32>,
    pub(super) views: Vec<u16>,
}

impl Plain {
    pub(super) fn new(spec: GridSpec) -> Self {
        Self {
            spec,
            evidence: vec![0.0; spec.cells()],
            views: vec![0; spec.cells()],
        }
    }

    /// The update, every cell tested on its own; returns the cells updated.
    pub(super) fn integrate(
        &mut self,
        camera_from_odom: &Iso3,
        cam: &Camera,
        ev: &TileEvidence,
        max_depth_m: f64,
    ) -> usize {
        let spec = self.spec;
        let tile = f64::from(ev.tile_px);
        let step_k = camera_from_odom.rotation.to_rotation_matrix()
            * Vector3::new(0.0, 0.0, spec.voxel_size_m);
        let mut n = 0;
        for idx in 0..spec.cells() {
            let [i, j, k] = spec.ijk(idx);
            let c0 = spec.center(i, j, 0);
            let p = camera_from_odom * Point3::new(c0[0], c0[1], c0[2]) + step_k * k as f64;
            if p.z <= 1e-9 || p.z > max_depth_m {
                continue;
            }
            let inv_z = 1.0 / p.z;
            let u = cam.fx * p.x * inv_z + cam.cx;
            let v = cam.fy * p.y * inv_z + cam.cy;
            if !(u >= 0.0 && u < ev.cols as f64 * tile && v >= 0.0 && v < ev.rows as f64 * tile) {
                continue;
            }
            let (c, r) = ((u / tile) as usize, (v / tile) as usize);
            self.evidence[idx] += ev.delta[r * ev.cols + c];
            self.views[idx] += 1;
            n += 1;
        }
        n
    }

    /// One log-odds blur pass: each cell the sum of its samples (0 outside), flushed.
    pub(super) fn blur(&mut self, kernel: &dyn ColumnKernel) {
        let [nx, ny, nz] = self.spec.dims;
        let mut out = vec![0.0f32; self.evidence.len()];
        let mut samples = Vec::new();
        for i in 0..nx {
            for j in 0..ny {
                samples.clear();
                kernel.samples(i, j, &mut samples);
                for k in 0..nz {
                    let mut acc = 0.0f32;
                    for &([ci, cj], w) in &samples {
                        let v = if ci >= 0 && cj >= 0 && (ci as usize) < nx && (cj as usize) < ny {
                            self.evidence[self.spec.index(ci as usize, cj as usize, k)]
                        } else {
                            0.0
                        };
                        acc += f32::from_f64(w) * v;
                    }
                    out[self.spec.index(i, j, k)] = acc.flushed(FLUSH_EVIDENCE);
                }
            }
        }
        self.evidence = out;
    }

    /// Panics unless `grid` holds exactly these values, bit for bit, in every cell.
    pub(super) fn assert_same(&self, grid: &Grid, what: &str) {
        for idx in 0..self.spec.cells() {
            assert_eq!(
                grid.evidence_at(idx).to_bits(),
                self.evidence[idx].to_bits(),
                "{what}: cell {:?}: {} against {}",
                self.spec.ijk(idx),
                grid.evidence_at(idx),
                self.evidence[idx]
            );
            assert_eq!(
                grid.views_at(idx),
                self.views[idx],
                "{what}: views of {idx}"
            );
        }
    }
}
