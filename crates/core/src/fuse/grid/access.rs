//! Building a grid and reading it: cells by index, stored blocks in parallel or in order, the
//! grid's hash, its highest log-odds and the region it exports.
//!
//! Invariants: every read treats a cell of an unstored block as evidence 0 seen by no view,
//! and leaves out the cells of a block outside the grid's dims, so what consumers see does
//! not depend on which blocks are stored.

use super::*;

impl Grid {
    /// A dense grid at the prior everywhere, no views, no clamp, the default [`Budget`];
    /// [`GridError::Prior`] unless [`MIN_PRIOR`] <= `prior` <= 1 - [`MIN_PRIOR`].
    pub fn new(spec: GridSpec, prior: f64) -> Result<Self, GridError> {
        Self::with_storage(spec, prior, GridStorage::Dense, Budget::default())
    }

    /// A grid at the prior everywhere with `storage` ([`GridStorage::Auto`] decided here)
    /// within `budget`: a dense grid that would not fit is refused ([`GridError::TooLarge`]).
    pub fn with_storage(
        spec: GridSpec,
        prior: f64,
        storage: GridStorage,
        budget: Budget,
    ) -> Result<Self, GridError> {
        super::check_prior(prior)?;
        let storage = storage.resolve(&spec);
        let bdims = block_dims(spec.dims);
        let nblocks: usize = bdims.iter().product();
        let slots = if storage == GridStorage::Dense {
            nblocks + 1
        } else {
            1
        };
        let needed = bytes_for(nblocks, slots, budget.bytes_per_cell(storage));
        if needed > budget.max_bytes as f64 {
            let [nx, ny, nz] = spec.dims.map(|d| d as u64);
            let limit_mib = budget.max_bytes >> 20;
            return Err(if storage == GridStorage::Dense {
                GridError::TooLarge {
                    nx,
                    ny,
                    nz,
                    needed_mib: mib(needed),
                    limit_mib,
                }
            } else {
                GridError::BlockTable {
                    nx,
                    ny,
                    nz,
                    needed_mib: mib(needed),
                    limit_mib,
                }
            });
        }
        let layout = if storage == GridStorage::Dense {
            Layout::full(bdims)
        } else {
            Layout::empty(bdims)
        };
        Ok(Self {
            spec,
            prior,
            clamp: None,
            storage,
            budget,
            layout,
            evidence: vec![0.0; slots * BLOCK_CELLS],
            views: vec![0; slots * BLOCK_CELLS],
        })
    }

    /// Dense or sparse.
    pub fn storage(&self) -> GridStorage {
        self.storage
    }

    /// The prior as log-odds, f32 like the cells: the log-odds of a cell no frame has reached.
    pub fn prior_log_odds(&self) -> f32 {
        logit(self.prior) as f32
    }

    /// Cells in stored blocks (whole blocks, pads included).
    pub fn stored_cells(&self) -> usize {
        (self.layout.slots() - 1) * BLOCK_CELLS
    }

    /// Bytes the grid holds at its [`Budget`]'s cost a cell, the table of blocks included.
    pub fn stored_bytes(&self) -> u64 {
        bytes_for(
            self.layout.table.len(),
            self.layout.slots(),
            self.budget.bytes_per_cell(self.storage),
        ) as u64
    }

    /// Where cell `idx` is stored, None when its block is not.
    #[inline]
    fn locate(&self, idx: usize) -> Option<usize> {
        let [i, j, k] = self.spec.ijk(idx);
        let slot = self.slot_at(i, j, k);
        (slot != 0).then(|| slot * BLOCK_CELLS + cell_offset(i, j, k))
    }

    /// The slot of the block holding cell (i, j, k), 0 when it is not stored; with
    /// [`BlockCells::slot`], for consumers that keep their own state per stored block.
    #[inline]
    pub fn slot_at(&self, i: usize, j: usize, k: usize) -> usize {
        let b = self.layout.block_index([i / BLOCK, j / BLOCK, k / BLOCK]);
        self.layout.table[b] as usize
    }

    /// Slots, the unstored block's (0) included: the length of a per-slot table.
    pub fn slots(&self) -> usize {
        self.layout.slots()
    }

    /// Evidence of cell `idx` (flat index): its log-odds above the prior's.
    pub fn evidence_at(&self, idx: usize) -> f32 {
        self.locate(idx).map_or(0.0, |s| self.evidence[s])
    }

    /// Log-odds of cell `idx`: `prior_log_odds() + evidence_at(idx)`.
    pub fn log_odds_at(&self, idx: usize) -> f32 {
        self.prior_log_odds() + self.evidence_at(idx)
    }

    /// Views of cell `idx`.
    pub fn views_at(&self, idx: usize) -> u16 {
        self.locate(idx).map_or(0, |s| self.views[s])
    }

    /// Sets cell `idx` (flat index) to `evidence` seen by `views` frames, storing its block
    /// when needed (for tests and tools; the replay goes through the updates).
    pub fn set_cell(&mut self, idx: usize, evidence: f32, views: u16) -> Result<(), GridError> {
        let [i, j, k] = self.spec.ijk(idx);
        if self.slot_at(i, j, k) == 0 {
            let b = self.layout.block_index([i / BLOCK, j / BLOCK, k / BLOCK]);
            self.store(&[b as u32])?;
        }
        let s = self.slot_at(i, j, k) * BLOCK_CELLS + cell_offset(i, j, k);
        self.evidence[s] = evidence;
        self.views[s] = views;
        Ok(())
    }

    /// Stores `new` (unstored blocks, ascending) as zeros; [`GridError::Allocation`] when the
    /// grid would exceed its budget.
    pub(crate) fn store(&mut self, new: &[u32]) -> Result<(), GridError> {
        if new.is_empty() {
            return Ok(());
        }
        self.check_budget(self.layout.slots() + new.len())?;
        self.layout.append(new);
        let n = self.layout.slots() * BLOCK_CELLS;
        self.evidence.resize(n, 0.0);
        self.views.resize(n, 0);
        Ok(())
    }

    /// [`GridError::Allocation`] when `slots` slots would exceed the budget.
    pub(crate) fn check_budget(&self, slots: usize) -> Result<(), GridError> {
        let needed = bytes_for(
            self.layout.table.len(),
            slots,
            self.budget.bytes_per_cell(self.storage),
        );
        if needed <= self.budget.max_bytes as f64 {
            return Ok(());
        }
        let [nx, ny, nz] = self.spec.dims.map(|d| d as u64);
        Err(GridError::Allocation {
            nx,
            ny,
            nz,
            cells: ((slots - 1) * BLOCK_CELLS) as u64,
            needed_mib: mib(needed),
            limit_mib: self.budget.max_bytes >> 20,
        })
    }

    fn block_cells(&self, slot: usize) -> BlockCells<'_> {
        let b = self.layout.block_coords(self.layout.blocks[slot]);
        let first_cell = b.map(|x| x * BLOCK);
        let range = slot * BLOCK_CELLS..(slot + 1) * BLOCK_CELLS;
        BlockCells {
            slot,
            first_cell,
            extent: std::array::from_fn(|a| BLOCK.min(self.spec.dims[a] - first_cell[a])),
            evidence: &self.evidence[range.clone()],
            views: &self.views[range],
        }
    }

    /// The stored blocks, in parallel (in slot order).
    pub fn par_blocks(&self) -> impl IndexedParallelIterator<Item = BlockCells<'_>> + '_ {
        (1..self.layout.slots())
            .into_par_iter()
            .map(|s| self.block_cells(s))
    }

    /// The stored blocks in block order (ascending (bi, bj, bk)).
    pub fn blocks_in_order(&self) -> impl Iterator<Item = BlockCells<'_>> + '_ {
        self.layout
            .in_block_order()
            .into_iter()
            .map(|(_, s)| self.block_cells(s as usize))
    }

    /// Whether every cell of the grid lies in a stored block.
    pub fn is_fully_stored(&self) -> bool {
        self.layout.stores_every_block()
    }

    /// Highest log-odds of any cell: `prior_log_odds()` plus the highest evidence (cells of
    /// unstored blocks have 0). f32 addition is monotonic, so this is the highest of the
    /// cells' own log-odds.
    pub fn max_log_odds(&self) -> f32 {
        let stored = self
            .par_blocks()
            .map(|b| {
                if b.extent == [BLOCK; 3] {
                    // Eight running maxima: the compiler vectorises them.
                    let mut lanes = [f32::NEG_INFINITY; 8];
                    for e8 in b.evidence.chunks_exact(8) {
                        for k in 0..8 {
                            lanes[k] = lanes[k].max(e8[k]);
                        }
                    }
                    lanes.into_iter().fold(f32::NEG_INFINITY, f32::max)
                } else {
                    let mut m = f32::NEG_INFINITY;
                    for_each_cell(&b, |o, _| m = m.max(b.evidence[o]));
                    m
                }
            })
            .reduce(|| f32::NEG_INFINITY, f32::max);
        let max_e = if self.is_fully_stored() {
            stored
        } else {
            stored.max(0.0)
        };
        self.prior_log_odds() + max_e
    }

    /// SHA-256, hex, of the grid's contents: for each block (ascending block index) holding
    /// a non-zero evidence or view, the block index (u64), its 512 evidence values (f32) and
    /// its 512 views (u16), all little-endian, cells in block order (pads 0). Blocks without
    /// either are left out, so a dense and a sparse grid with the same cells hash alike.
    pub fn sha256_hex(&self) -> String {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        let mut bytes = Vec::with_capacity(8 + BLOCK_CELLS * 6);
        for (block, slot) in self.layout.in_block_order() {
            let r = slot as usize * BLOCK_CELLS..(slot as usize + 1) * BLOCK_CELLS;
            let (e, v) = (&self.evidence[r.clone()], &self.views[r]);
            if e.iter().all(|&x| x == 0.0) && v.iter().all(|&x| x == 0) {
                continue;
            }
            bytes.clear();
            bytes.extend_from_slice(&u64::from(block).to_le_bytes());
            bytes.extend(e.iter().flat_map(|x| x.to_le_bytes()));
            bytes.extend(v.iter().flat_map(|x| x.to_le_bytes()));
            h.update(&bytes);
        }
        crate::types::digest::hex(&h.finalize())
    }

    /// The box of the stored blocks' cells inside the grid (the whole grid when dense; an
    /// empty region when nothing is stored): what `fuse --grid` exports.
    pub fn occupied_region(&self) -> Region {
        let (mut lo, mut hi) = ([usize::MAX; 3], [0; 3]);
        for &b in &self.layout.blocks[1..] {
            let c = self.layout.block_coords(b);
            for a in 0..3 {
                lo[a] = lo[a].min(c[a] * BLOCK);
                hi[a] = hi[a].max(((c[a] + 1) * BLOCK).min(self.spec.dims[a]));
            }
        }
        if self.layout.slots() == 1 {
            return Region {
                first_cell: [0; 3],
                dims: [0; 3],
            };
        }
        Region {
            first_cell: lo,
            dims: std::array::from_fn(|a| hi[a] - lo[a]),
        }
    }

    /// The region to export ([`Grid::occupied_region`]), or [`GridError::Export`] when its
    /// float32 `.npy` would exceed `limit_bytes`: checked before anything is written.
    pub fn export_region(&self, limit_bytes: u64) -> Result<Region, GridError> {
        let region = self.occupied_region();
        let bytes = region.dims.iter().map(|&d| d as f64).product::<f64>() * 4.0;
        if bytes <= limit_bytes as f64 {
            return Ok(region);
        }
        let [nx, ny, nz] = self.spec.dims.map(|d| d as u64);
        Err(GridError::Export {
            first_cell: region.first_cell,
            dims: region.dims,
            nx,
            ny,
            nz,
            needed_mib: mib(bytes),
            limit_mib: limit_bytes >> 20,
        })
    }

    /// Posterior probabilities (f32) of the cells of x-slab `i` (a cell index of the grid)
    /// within `region`, C order: `region.dims[1] * region.dims[2]` values.
    pub fn probability_slab(&self, region: &Region, i: usize) -> Vec<f32> {
        let prior = self.prior_log_odds();
        let [_, j0, k0] = region.first_cell;
        let mut out = Vec::with_capacity(region.dims[1] * region.dims[2]);
        for j in j0..j0 + region.dims[1] {
            for k in k0..k0 + region.dims[2] {
                let slot = self.slot_at(i, j, k);
                let e = self.evidence[slot * BLOCK_CELLS + cell_offset(i, j, k)];
                out.push(sigmoid(f64::from(prior + e)) as f32);
            }
        }
        out
    }
}

/// Calls `f(offset, [a, b, c])` for every cell of `b` inside the grid, in block order.
#[inline]
pub fn for_each_cell(b: &BlockCells<'_>, mut f: impl FnMut(usize, [usize; 3])) {
    for a in 0..b.extent[0] {
        for c in 0..b.extent[1] {
            let base = (a * BLOCK + c) * BLOCK;
            for d in 0..b.extent[2] {
                f(base + d, [a, c, d]);
            }
        }
    }
}

/// Bytes of a grid with `table` blocks and `slots` slots at `per_cell` bytes a cell.
fn bytes_for(table: usize, slots: usize, per_cell: f64) -> f64 {
    (table as f64 + slots as f64) * 4.0 + slots as f64 * BLOCK_CELLS as f64 * per_cell
}
