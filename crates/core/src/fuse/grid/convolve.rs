//! Convolution of a blocked field in x and y (the motion blur's machinery; its kernels live in
//! [`crate::fuse::motion`]): which blocks a pass computes, and the per-cell sums.
//!
//! Invariants: every output cell is the sum, in the kernel's order, of its samples' weights
//! times their source cells, an unstored block and the world outside the grid reading 0, so
//! a block's result does not depend on which blocks are stored; a pass computes every stored
//! block and every block within the kernel's reach of a non-zero one (any other block sums
//! zeros, and stays 0); cells outside the grid's dims (pads) come out 0; sums are per cell,
//! so results do not depend on the thread count.

use rayon::prelude::*;

use super::blocks::{BLOCK, BLOCK_CELLS, Layout};
use super::{GridError, GridSpec};

/// A blur buffer's element: weights are computed in f64 and converted once per sample.
pub trait Sample:
    Copy
    + Default
    + Send
    + Sync
    + PartialEq
    + PartialOrd
    + std::ops::AddAssign
    + std::ops::Mul<Output = Self>
    + 'static
{
    /// The additive identity.
    const ZERO: Self;
    /// A value computed in f64, converted (rounded, for f32).
    fn from_f64(x: f64) -> Self;
    /// 0 when the magnitude is below `below`, else the value.
    fn flushed(self, below: Self) -> Self;
}

impl Sample for f64 {
    const ZERO: Self = 0.0;
    #[inline]
    fn from_f64(x: f64) -> Self {
        x
    }
    #[inline]
    fn flushed(self, below: Self) -> Self {
        if self.abs() < below { 0.0 } else { self }
    }
}

impl Sample for f32 {
    const ZERO: Self = 0.0;
    #[inline]
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    #[inline]
    fn flushed(self, below: Self) -> Self {
        if self.abs() < below { 0.0 } else { self }
    }
}

/// A blur in x and y as the grid applies it, column by column.
pub trait ColumnKernel: Sync {
    /// The largest distance in cells along x and along y between an output cell and a cell
    /// it reads, when the non-zero cells lie in the box of cells `lo..hi` (x, y). May be
    /// `usize::MAX` (the whole grid).
    fn reach_cells(&self, lo: [usize; 2], hi: [usize; 2]) -> [usize; 2];
    /// Appends the samples of output column (i, j): the source column (outside the grid it
    /// reads 0) and its weight, in the order they are summed; zero weights left out.
    fn samples(&self, i: usize, j: usize, out: &mut Vec<([i64; 2], f64)>);
}

/// One pass of `kernel` over `src` (laid out by `layout`): writes the blocks it computes,
/// ascending, to `blocks`, and their values to `out`, a zero block first and then one block
/// per entry of `blocks`; each value with a magnitude below `flush_below` becomes 0.
/// `budget(slots)` is asked before `out` grows to the blocks computed (plus the zero block):
/// a blur reaching far (a wide turn on a building-sized grid) is refused with its error
/// instead of allocating past the grid's limit.
#[allow(clippy::too_many_arguments)]
pub(crate) fn convolve<T: Sample>(
    spec: &GridSpec,
    layout: &Layout,
    src: &[T],
    kernel: &dyn ColumnKernel,
    flush_below: T,
    budget: &dyn Fn(usize) -> Result<(), GridError>,
    blocks: &mut Vec<u32>,
    out: &mut Vec<T>,
) -> Result<(), GridError> {
    if layout.stores_every_block() {
        // Every block stored (a dense grid): every block is computed.
        *blocks = layout
            .in_block_order()
            .into_iter()
            .map(|(b, _)| b)
            .collect();
    } else {
        let nonzero: Vec<u32> = src
            .par_chunks(BLOCK_CELLS)
            .zip(layout.blocks.par_iter())
            .skip(1)
            .filter(|(cells, _)| cells.iter().any(|&v| v != T::ZERO))
            .map(|(_, &b)| b)
            .collect();
        *blocks = candidates(spec, layout, &nonzero, kernel);
    }
    budget(blocks.len() + 1)?;
    out.clear();
    out.resize((blocks.len() + 1) * BLOCK_CELLS, T::ZERO);
    // Blocks of one block column are adjacent in `blocks`: each column is one task, so the
    // samples of a cell column are computed once for all its blocks.
    let nbz = layout.bdims[2];
    let mut groups: Vec<(usize, &[u32], &mut [T])> = Vec::new();
    let mut rest = &mut out[BLOCK_CELLS..];
    let mut start = 0;
    while start < blocks.len() {
        let col = blocks[start] as usize / nbz;
        let end = start
            + blocks[start..]
                .iter()
                .take_while(|&&b| b as usize / nbz == col)
                .count();
        let (head, tail) = rest.split_at_mut((end - start) * BLOCK_CELLS);
        groups.push((col, &blocks[start..end], head));
        rest = tail;
        start = end;
    }
    groups.into_par_iter().for_each(|(col, bks, dst)| {
        let bcol = [col / layout.bdims[1], col % layout.bdims[1]];
        block_column(spec, layout, src, kernel, flush_below, bcol, bks, dst);
    });
    Ok(())
}

/// The blocks a pass computes: every stored block and every block within the kernel's reach
/// (in x and y) of one in `nonzero`, ascending.
fn candidates(
    spec: &GridSpec,
    layout: &Layout,
    nonzero: &[u32],
    kernel: &dyn ColumnKernel,
) -> Vec<u32> {
    let stored: Vec<u32> = layout
        .in_block_order()
        .into_iter()
        .map(|(b, _)| b)
        .collect();
    if nonzero.is_empty() {
        return stored;
    }
    let bd = layout.bdims;
    let (mut lo, mut hi) = ([usize::MAX; 3], [0; 3]);
    for &b in nonzero {
        let c = layout.block_coords(b);
        for a in 0..3 {
            lo[a] = lo[a].min(c[a]);
            hi[a] = hi[a].max(c[a] + 1);
        }
    }
    let cell_lo = [lo[0] * BLOCK, lo[1] * BLOCK];
    let cell_hi = [
        (hi[0] * BLOCK).min(spec.dims[0]),
        (hi[1] * BLOCK).min(spec.dims[1]),
    ];
    let reach = kernel.reach_cells(cell_lo, cell_hi);
    let r = reach.map(|c| c.div_ceil(BLOCK));
    let (x0, x1) = (
        lo[0].saturating_sub(r[0]),
        hi[0].saturating_add(r[0]).min(bd[0]),
    );
    let (y0, y1) = (
        lo[1].saturating_sub(r[1]),
        hi[1].saturating_add(r[1]).min(bd[1]),
    );
    let (z0, z1) = (lo[2], hi[2]);
    let (wx, wy, wz) = (x1 - x0, y1 - y0, z1 - z0);
    let mut mark = vec![0u8; wx * wy * wz];
    for &b in nonzero {
        let c = layout.block_coords(b);
        mark[((c[0] - x0) * wy + c[1] - y0) * wz + c[2] - z0] = 1;
    }
    // A box dilation is separable: along y, then along x.
    dilate(&mut mark, wx, wy * wz, wz, r[1].min(wy));
    dilate(&mut mark, 1, wx * wy * wz, wy * wz, r[0].min(wx));
    let mut dilated = Vec::new();
    for x in 0..wx {
        for y in 0..wy {
            for z in 0..wz {
                if mark[(x * wy + y) * wz + z] != 0 {
                    dilated.push(layout.block_index([x0 + x, y0 + y, z0 + z]) as u32);
                }
            }
        }
    }
    merge_sorted(&stored, &dilated)
}

/// Dilates `mark` by `radius` entries along one axis: `mark` is `outer` runs of
/// `outer_stride` entries, each run holding `step` lines (one per offset below `step`) of
/// `outer_stride / step` entries `step` apart; an entry becomes marked when an entry of its
/// line within `radius` of it was.
fn dilate(mark: &mut [u8], outer: usize, outer_stride: usize, step: usize, radius: usize) {
    if radius == 0 || mark.is_empty() {
        return;
    }
    let len = outer_stride / step;
    let mut line = vec![0u8; len];
    for o in 0..outer {
        for inner in 0..step {
            let at = |t: usize| o * outer_stride + t * step + inner;
            for (t, v) in line.iter_mut().enumerate() {
                *v = mark[at(t)];
            }
            // Distance to the nearest mark behind, then ahead.
            let mut since = usize::MAX;
            for t in 0..len {
                since = if line[t] != 0 {
                    0
                } else {
                    since.saturating_add(1)
                };
                if since <= radius {
                    mark[at(t)] = 1;
                }
            }
            since = usize::MAX;
            for t in (0..len).rev() {
                since = if line[t] != 0 {
                    0
                } else {
                    since.saturating_add(1)
                };
                if since <= radius {
                    mark[at(t)] = 1;
                }
            }
        }
    }
}

/// The union of two ascending lists, ascending, without repeats.
fn merge_sorted(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len().max(b.len()));
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        let next = match (a.get(i), b.get(j)) {
            (Some(&x), Some(&y)) if x == y => {
                i += 1;
                j += 1;
                x
            }
            (Some(&x), Some(&y)) if x < y => {
                i += 1;
                x
            }
            (Some(&x), None) => {
                i += 1;
                x
            }
            (_, Some(&y)) => {
                j += 1;
                y
            }
            (None, None) => break,
        };
        out.push(next);
    }
    out
}

/// The blocks `bks` (one block column, `bcol`) of one pass into `dst`, block after block.
#[allow(clippy::too_many_arguments)]
fn block_column<T: Sample>(
    spec: &GridSpec,
    layout: &Layout,
    src: &[T],
    kernel: &dyn ColumnKernel,
    flush_below: T,
    bcol: [usize; 2],
    bks: &[u32],
    dst: &mut [T],
) {
    let [nx, ny, nz] = spec.dims;
    let [_, nby, nbz] = layout.bdims;
    let full = layout.is_full();
    let mut samples = Vec::new();
    let mut taps: Vec<(usize, usize, T)> = Vec::new();
    for a in 0..BLOCK {
        for b in 0..BLOCK {
            let (i, j) = (bcol[0] * BLOCK + a, bcol[1] * BLOCK + b);
            let col = (a * BLOCK + b) * BLOCK;
            if i >= nx || j >= ny {
                continue;
            }
            samples.clear();
            kernel.samples(i, j, &mut samples);
            // A tap outside the grid reads zeros and adds w * 0 = +0, which leaves a sum
            // unchanged (a sum is never -0: it starts at +0), so it is left out.
            taps.clear();
            taps.extend(
                samples
                    .iter()
                    .filter(|&&([ci, cj], _)| {
                        ci >= 0 && cj >= 0 && (ci as usize) < nx && (cj as usize) < ny
                    })
                    .map(|&([ci, cj], w)| {
                        let (ci, cj) = (ci as usize, cj as usize);
                        let row = ((ci / BLOCK) * nby + cj / BLOCK) * nbz;
                        (
                            row,
                            ((ci % BLOCK) * BLOCK + cj % BLOCK) * BLOCK,
                            T::from_f64(w),
                        )
                    }),
            );
            for (q, &block) in bks.iter().enumerate() {
                let bk = block as usize % nbz;
                let mut acc = [T::ZERO; BLOCK];
                for &(row, off, w) in &taps {
                    // Every block stored in block order: block b in slot b + 1.
                    let slot = if full {
                        row + bk + 1
                    } else {
                        layout.table[row + bk] as usize
                    };
                    let s = &src[slot * BLOCK_CELLS + off..slot * BLOCK_CELLS + off + BLOCK];
                    for (x, &v) in acc.iter_mut().zip(s) {
                        *x += w * v;
                    }
                }
                let lanes = (nz - bk * BLOCK).min(BLOCK);
                let out = &mut dst[q * BLOCK_CELLS + col..q * BLOCK_CELLS + col + BLOCK];
                for (l, (o, &x)) in out.iter_mut().zip(&acc).enumerate() {
                    *o = if l < lanes {
                        x.flushed(flush_below)
                    } else {
                        T::ZERO
                    };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merge_is_a_sorted_union() {
        assert_eq!(merge_sorted(&[1, 4, 9], &[2, 4, 10]), vec![1, 2, 4, 9, 10]);
        assert_eq!(merge_sorted(&[], &[3]), vec![3]);
        assert_eq!(merge_sorted(&[3], &[]), vec![3]);
    }

    #[test]
    fn dilation_marks_within_the_radius_on_both_axes() {
        // 7 x 5 x 2 (x, y, z): a mark at (3, 2, 1), radius 1 in y then 2 in x; z is not
        // dilated.
        let (wx, wy, wz) = (7, 5, 2);
        let mut m = vec![0u8; wx * wy * wz];
        m[(3 * wy + 2) * wz + 1] = 1;
        dilate(&mut m, wx, wy * wz, wz, 1);
        dilate(&mut m, 1, wx * wy * wz, wy * wz, 2);
        for x in 0..wx {
            for y in 0..wy {
                let want = (1..=5).contains(&x) && (1..=3).contains(&y);
                assert_eq!(m[(x * wy + y) * wz + 1] != 0, want, "{x} {y}");
                assert_eq!(m[(x * wy + y) * wz], 0, "{x} {y}");
            }
        }
    }
}
