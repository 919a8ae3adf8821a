//! Blocked storage of the belief grid: cells in blocks of 8 x 8 x 8, a block stored ("given a
//! slot") only where a view or the motion blur has put something in it, and a dense table from
//! every block of the nominal grid to its slot (4 bytes a block: 39 MB for 5e9 cells).
//!
//! Invariants: slot 0 is the zero block: every field reads 0 there and nothing writes it, so
//! an unallocated block reads as zeros without a branch; `table[block]` is the slot of an
//! allocated block and 0 otherwise; `blocks[slot]` is the block of a slot (`blocks[0]` is
//! [`NO_BLOCK`]); `sorted` holds only when `blocks[1..]` ascends. Blocks are numbered in C
//! order, `(bi * nby + bj) * nbz + bk`, and a cell's place in its block is C order too,
//! `(a * 8 + b) * 8 + c`: z is contiguous, eight cells of a column at a time.

/// Cells along each edge of a block.
pub const BLOCK: usize = 8;
/// Cells in a block.
pub const BLOCK_CELLS: usize = BLOCK * BLOCK * BLOCK;
/// The block of slot 0, the zero block: no block of the grid.
pub const NO_BLOCK: u32 = u32::MAX;

/// Where a cell is stored: its block's index and the cell's place in the block.
#[inline]
pub fn cell_offset(i: usize, j: usize, k: usize) -> usize {
    ((i % BLOCK) * BLOCK + j % BLOCK) * BLOCK + k % BLOCK
}

/// Blocks along x, y and z for `dims` cells: each rounded up.
pub fn block_dims(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|n| n.div_ceil(BLOCK))
}

/// Which blocks are stored, and where.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Layout {
    /// Blocks along x, y, z.
    pub(crate) bdims: [usize; 3],
    /// Slot of each block (C order of blocks), 0 when the block is not stored.
    pub(crate) table: Vec<u32>,
    /// Block of each slot; `blocks[0]` is [`NO_BLOCK`].
    pub(crate) blocks: Vec<u32>,
    /// Whether `blocks[1..]` ascends.
    pub(crate) sorted: bool,
}

impl Layout {
    /// No block stored.
    pub(crate) fn empty(bdims: [usize; 3]) -> Self {
        Self {
            bdims,
            table: vec![0; bdims.iter().product()],
            blocks: vec![NO_BLOCK],
            sorted: true,
        }
    }

    /// Every block stored, in block order (block b in slot b + 1).
    pub(crate) fn full(bdims: [usize; 3]) -> Self {
        let n = bdims.iter().product::<usize>() as u32;
        Self {
            bdims,
            table: (1..=n).collect(),
            blocks: std::iter::once(NO_BLOCK).chain(0..n).collect(),
            sorted: true,
        }
    }

    /// Whether every block is stored in block order (block b in slot b + 1), as
    /// [`Layout::full`] lays them out.
    pub(crate) fn is_full(&self) -> bool {
        self.sorted && self.stores_every_block()
    }

    /// Whether every block of the grid has a slot (in any order).
    pub(crate) fn stores_every_block(&self) -> bool {
        self.slots() == self.table.len() + 1
    }

    /// Index of block (bi, bj, bk).
    #[inline]
    pub(crate) fn block_index(&self, b: [usize; 3]) -> usize {
        (b[0] * self.bdims[1] + b[1]) * self.bdims[2] + b[2]
    }

    /// (bi, bj, bk) of a block index.
    #[inline]
    pub(crate) fn block_coords(&self, block: u32) -> [usize; 3] {
        let b = block as usize;
        let [_, nby, nbz] = self.bdims;
        [b / (nby * nbz), (b / nbz) % nby, b % nbz]
    }

    /// Slots, the zero block included.
    pub(crate) fn slots(&self) -> usize {
        self.blocks.len()
    }

    /// Stores `new` (blocks not stored yet, ascending) in new slots after the others.
    pub(crate) fn append(&mut self, new: &[u32]) {
        for &b in new {
            if self
                .blocks
                .last()
                .is_some_and(|&last| last != NO_BLOCK && last > b)
            {
                self.sorted = false;
            }
            self.table[b as usize] = self.blocks.len() as u32;
            self.blocks.push(b);
        }
    }

    /// The stored blocks, ascending, each with its slot.
    pub(crate) fn in_block_order(&self) -> Vec<(u32, u32)> {
        let mut v: Vec<(u32, u32)> = self.blocks[1..]
            .iter()
            .enumerate()
            .map(|(s, &b)| (b, s as u32 + 1))
            .collect();
        if !self.sorted {
            v.sort_unstable();
        }
        v
    }

    /// Whether `blocks` (ascending) are exactly the stored blocks in slot order.
    pub(crate) fn is_exactly(&self, blocks: &[u32]) -> bool {
        self.sorted && self.blocks[1..] == *blocks
    }

    /// Stores exactly `blocks` (ascending), in that order from slot 1; returns for each new
    /// slot its old slot (0 for a block not stored before, and for the zero block).
    pub(crate) fn relayout(&mut self, blocks: &[u32]) -> Vec<u32> {
        let mut old = Vec::with_capacity(blocks.len() + 1);
        old.push(0);
        old.extend(blocks.iter().map(|&b| self.table[b as usize]));
        for &b in &self.blocks[1..] {
            self.table[b as usize] = 0;
        }
        for (s, &b) in blocks.iter().enumerate() {
            self.table[b as usize] = s as u32 + 1;
        }
        self.blocks.clear();
        self.blocks.push(NO_BLOCK);
        self.blocks.extend_from_slice(blocks);
        self.sorted = true;
        old
    }
}

/// `field` re-laid out for new slots that were `old[s]` (see [`Layout::relayout`]): block by
/// block, the zero block where a slot is new.
pub(crate) fn gather<T: Copy + Default + Send + Sync>(field: &[T], old: &[u32]) -> Vec<T> {
    use rayon::prelude::*;
    let mut out = vec![T::default(); old.len() * BLOCK_CELLS];
    out.par_chunks_mut(BLOCK_CELLS)
        .zip(old.par_iter())
        .for_each(|(dst, &s)| {
            let s = s as usize * BLOCK_CELLS;
            dst.copy_from_slice(&field[s..s + BLOCK_CELLS]);
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_and_block_numbers_are_c_order() {
        assert_eq!(cell_offset(0, 0, 0), 0);
        assert_eq!(cell_offset(9, 2, 17), (8 + 2) * 8 + 1);
        assert_eq!(block_dims([13, 8, 1]), [2, 1, 1]);
        let l = Layout::empty([3, 4, 5]);
        let b = l.block_index([2, 1, 3]);
        assert_eq!(b, (2 * 4 + 1) * 5 + 3);
        assert_eq!(l.block_coords(b as u32), [2, 1, 3]);
    }

    #[test]
    fn append_relayout_and_gather_keep_each_block_with_its_cells() {
        let mut l = Layout::empty([2, 2, 2]);
        l.append(&[5, 6]);
        l.append(&[1]);
        assert!(!l.sorted);
        assert_eq!((l.table[5], l.table[6], l.table[1]), (1, 2, 3));
        assert_eq!(l.in_block_order(), vec![(1, 3), (5, 1), (6, 2)]);
        // Cells of slot s hold s (the zero block 0).
        let field: Vec<u16> = (0..4).flat_map(|s| [s as u16; BLOCK_CELLS]).collect();
        let old = l.relayout(&[1, 2, 6]);
        assert_eq!(old, vec![0, 3, 0, 2]);
        assert!(l.sorted && l.is_exactly(&[1, 2, 6]));
        assert_eq!(
            (l.table[1], l.table[2], l.table[5], l.table[6]),
            (1, 2, 0, 3)
        );
        let g = gather(&field, &old);
        let firsts: Vec<u16> = g.chunks(BLOCK_CELLS).map(|c| c[0]).collect();
        assert_eq!(firsts, vec![0, 3, 0, 2]);
        assert_eq!(Layout::full([1, 1, 3]).table, vec![1, 2, 3]);
    }
}
