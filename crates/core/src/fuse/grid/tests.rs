//! The grid's tests: the update against hand-computed cameras and against a plain C-order
//! reference ([`super::reference`]), dense against sparse bit for bit through updates and
//! blurs, what a sparse grid stores, its budget, its hash and its export.

use super::reference::Plain;
use super::*;
use crate::fuse::motion::{BlurMode, Blurrer, Rotate, Translate};
use crate::types::geometry::{camera_mount, iso_from_xy_yaw};
use nalgebra::Point3;

fn sparse(spec: GridSpec, prior: f64) -> Grid {
    Grid::with_storage(spec, prior, GridStorage::Sparse, Budget::default()).unwrap()
}

fn random_evidence(seed: u64, rows: usize, cols: usize, prior: f64) -> TileEvidence {
    random_tiles(seed, rows, cols, 8, prior)
}

fn random_tiles(seed: u64, rows: usize, cols: usize, tile_px: u32, prior: f64) -> TileEvidence {
    let mut rng = crate::types::rng::SplitMix64::new(seed);
    let p: Vec<f32> = (0..rows * cols)
        .map(|_| 0.01 + 0.98 * rng.uniform() as f32)
        .collect();
    TileEvidence::from_probabilities(rows, cols, tile_px, &p, prior)
}

#[test]
fn column_spans_skip_only_cells_outside_the_view() {
    // Cameras inside and outside the grid, level, tilted, looking straight down and
    // straight along z (columns parallel to the image planes): the spanned update of a dense
    // and of a sparse grid must change exactly the cells, by exactly the values, of testing
    // every cell. Tiles of 8 px (a power of two: the update multiplies by the exact 1/8)
    // and of 6 px (it divides), against the reference's division.
    for (tile_px, rows, cols) in [(8, 6, 8), (6, 8, 10)] {
        let ev = random_tiles(7, rows, cols, tile_px, 0.01);
        spans_match_the_reference(&ev);
    }
}

fn spans_match_the_reference(ev: &TileEvidence) {
    let spec = GridSpec::from_bounds([-1.0, -1.0, 0.0], [1.0, 1.0, 1.2], 0.05).unwrap();
    let cam = Camera::with_hfov(64, 48, 1.1);
    let mut rng = crate::types::rng::SplitMix64::new(7);
    let mut poses: Vec<Iso3> = vec![
        Iso3::identity(),
        iso_from_xy_yaw(0.0, 0.0, 0.0) * camera_mount([0.0, 0.0, 0.5], std::f64::consts::FRAC_PI_2),
        iso_from_xy_yaw(-1.5, 0.2, 0.3) * camera_mount([0.1, 0.0, 0.6], 0.25),
    ];
    for _ in 0..40 {
        let (x, y) = (rng.uniform() * 4.0 - 2.0, rng.uniform() * 4.0 - 2.0);
        let yaw = rng.uniform() * std::f64::consts::TAU;
        let pitch = rng.uniform() * 2.0 - 0.6;
        poses.push(
            iso_from_xy_yaw(x, y, yaw) * camera_mount([0.0, 0.0, rng.uniform() * 1.5], pitch),
        );
    }
    let mut seen = 0;
    for (n, odom_from_camera) in poses.iter().enumerate() {
        let cfo = odom_from_camera.inverse();
        // Every third pose with a range limit of 1.2 m.
        let depth = if n % 3 == 2 { 1.2 } else { f64::INFINITY };
        let mut dense = Grid::new(spec, 0.01).unwrap();
        let mut sp = sparse(spec, 0.01);
        let mut slow = Plain::new(spec);
        let k = dense.integrate(&cfo, &cam, ev, depth).unwrap();
        assert_eq!(sp.integrate(&cfo, &cam, ev, depth).unwrap(), k);
        assert_eq!(
            slow.integrate(&cfo, &cam, ev, depth),
            k,
            "pose {odom_from_camera}"
        );
        slow.assert_same(&dense, "dense");
        slow.assert_same(&sp, "sparse");
        seen += usize::from(k > 0);
    }
    // Most poses see part of the grid, or the comparison would be vacuous.
    assert!(
        seen > poses.len() / 2,
        "{seen} of {} poses saw the grid",
        poses.len()
    );
}

/// A scene of a few frames with blurs between them: a dense grid, a sparse one and the plain
/// reference hold the same values bit for bit after every step, and the two hash alike. The
/// grid is 60 x 55 x 14 cells, so its far blocks are partly outside it.
#[test]
fn sparse_and_dense_match_the_reference_through_updates_and_blurs() {
    let spec = GridSpec::from_bounds([-1.5, -1.45, 0.0], [1.5, 1.3, 0.7], 0.05).unwrap();
    assert_eq!(spec.dims, [60, 55, 14]);
    let prior = 0.02;
    let cam = Camera::with_hfov(64, 48, 1.0);
    let mut dense = Grid::new(spec, prior).unwrap();
    let mut sp = sparse(spec, prior);
    let mut plain = Plain::new(spec);
    let (mut bd, mut bs) = (Blurrer::default(), Blurrer::default());
    let poses = [
        iso_from_xy_yaw(-1.2, 0.1, 0.1) * camera_mount([0.0, 0.0, 0.4], 0.3),
        iso_from_xy_yaw(0.2, -1.3, 1.5) * camera_mount([0.0, 0.0, 0.5], 0.2),
        iso_from_xy_yaw(1.1, 0.9, -2.4) * camera_mount([0.0, 0.0, 0.3], 0.25),
        iso_from_xy_yaw(-0.1, 0.05, 0.7) * camera_mount([0.0, 0.0, 0.35], 0.4),
    ];
    for (n, pose) in poses.iter().enumerate() {
        let ev = random_evidence(n as u64 + 1, 6, 8, prior);
        let cfo = pose.inverse();
        let depth = if n == 1 { f64::INFINITY } else { 0.9 };
        dense.integrate(&cfo, &cam, &ev, depth).unwrap();
        sp.integrate(&cfo, &cam, &ev, depth).unwrap();
        plain.integrate(&cfo, &cam, &ev, depth);
        plain.assert_same(&dense, &format!("dense after frame {n}"));
        plain.assert_same(&sp, &format!("sparse after frame {n}"));
        let c = pose.translation.vector;
        let kernels: [Box<dyn convolve::ColumnKernel>; 2] = [
            Box::new(Translate::new(&spec, [0.8, -0.6], 0.06 + 0.02 * n as f64).unwrap()),
            Box::new(Rotate::new(&spec, [c.x, c.y], 0.05).unwrap()),
        ];
        for (m, kernel) in kernels.iter().enumerate() {
            plain.blur(kernel.as_ref());
            bd.log_odds_blur(&mut dense, kernel.as_ref()).unwrap();
            bs.log_odds_blur(&mut sp, kernel.as_ref()).unwrap();
            plain.assert_same(&dense, &format!("dense after frame {n} blur {m}"));
            plain.assert_same(&sp, &format!("sparse after frame {n} blur {m}"));
        }
        assert_eq!(dense.sha256_hex(), sp.sha256_hex(), "frame {n}");
    }
    // The sparse grid stores less than the dense one and is laid out in block order after a
    // blur.
    assert!(
        sp.stored_cells() < dense.stored_cells(),
        "{}",
        sp.stored_cells()
    );
    assert!(sp.layout.sorted);
    // The other blur modes keep dense and sparse alike too.
    for mode in [BlurMode::Probability, BlurMode::LogOdds] {
        bd.rotate(&mut dense, [0.3, 0.2], 0.08, mode).unwrap();
        bs.rotate(&mut sp, [0.3, 0.2], 0.08, mode).unwrap();
        assert_eq!(dense.sha256_hex(), sp.sha256_hex(), "{mode:?}");
    }
    let mut ed = Vec::new();
    let mut es = Vec::new();
    let cfo = poses[0].inverse();
    let ev = random_evidence(9, 6, 8, prior);
    dense
        .frame_evidence(&cfo, &cam, &ev, f64::INFINITY, &mut ed)
        .unwrap();
    sp.frame_evidence(&cfo, &cam, &ev, f64::INFINITY, &mut es)
        .unwrap();
    bd.spread_evidence(&mut dense, &mut ed, [-1.2, 0.1], 0.04, 0.03)
        .unwrap();
    bs.spread_evidence(&mut sp, &mut es, [-1.2, 0.1], 0.04, 0.03)
        .unwrap();
    dense.add_evidence(&ed);
    sp.add_evidence(&es);
    assert_eq!(dense.sha256_hex(), sp.sha256_hex(), "observation");
    for idx in 0..spec.cells() {
        assert_eq!(
            dense.evidence_at(idx).to_bits(),
            sp.evidence_at(idx).to_bits()
        );
    }
}

/// Without a range limit a frame can reach every column of the grid, and planning its update
/// costs 8 bytes a column: over the budget that is a one-line error naming the columns, and
/// the grid is unchanged; with a range limit the same frame fits.
#[test]
fn a_frame_whose_plan_exceeds_the_budget_is_refused() {
    let spec = GridSpec::from_bounds([-2.0, -2.0, 0.0], [2.0, 2.0, 1.0], 0.05).unwrap();
    // 80 x 80 columns: 51 200 bytes of spans, over a budget of 40 000 bytes.
    let budget = Budget {
        max_bytes: 40_000,
        f64_blur: false,
    };
    let mut g = Grid::with_storage(spec, 0.01, GridStorage::Sparse, budget).unwrap();
    let cam = Camera::with_hfov(64, 48, 1.0);
    let pose = iso_from_xy_yaw(-1.5, 0.0, 0.0) * camera_mount([0.0, 0.0, 0.5], 0.0);
    let ev = random_evidence(5, 6, 8, 0.01);
    let e = g
        .integrate(&pose.inverse(), &cam, &ev, f64::INFINITY)
        .unwrap_err();
    assert!(
        matches!(e, GridError::Columns { columns: 6400, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("--max-footprint"), "{e}");
    assert_eq!(g.stored_cells(), 0);
    g.integrate(&pose.inverse(), &cam, &ev, 0.3).unwrap();
    assert!(g.stored_cells() > 0);
}

/// Turns wider than a radian (sigma 0.3 and 0.6 rad: 4 sigma up to 2.4 rad, where the reach
/// was once unbounded) about a centre off the evidence: the sparse grid's candidate blocks
/// cover every cell the rotation reaches, so it equals the reference and the dense grid, and
/// it stores less than the whole grid.
#[test]
fn a_wide_turn_keeps_sparse_and_dense_alike() {
    let spec = GridSpec::from_bounds([-1.6, -1.6, 0.0], [1.6, 1.6, 0.4], 0.05).unwrap();
    for sigma in [0.3, 0.6] {
        let mut dense = Grid::new(spec, 0.02).unwrap();
        let mut sp = sparse(spec, 0.02);
        let mut plain = Plain::new(spec);
        for (i, j) in [(40, 33), (41, 33), (40, 34)] {
            let idx = spec.index(i, j, 3);
            dense.set_cell(idx, 9.0, 5).unwrap();
            sp.set_cell(idx, 9.0, 5).unwrap();
            plain.evidence[idx] = 9.0;
            plain.views[idx] = 5;
        }
        let kernel = Rotate::new(&spec, [-0.4, 0.2], sigma).unwrap();
        plain.blur(&kernel);
        Blurrer::default()
            .log_odds_blur(&mut dense, &kernel)
            .unwrap();
        Blurrer::default().log_odds_blur(&mut sp, &kernel).unwrap();
        plain.assert_same(&dense, &format!("dense, sigma {sigma}"));
        plain.assert_same(&sp, &format!("sparse, sigma {sigma}"));
        assert_eq!(dense.sha256_hex(), sp.sha256_hex());
        assert!(sp.stored_cells() < dense.stored_cells(), "sigma {sigma}");
    }
}

/// A blur whose reach needs more blocks than the budget allows stops with the budget's
/// error before its buffers grow, and leaves the grid as it was.
#[test]
fn a_blur_over_the_budget_is_refused_before_allocating() {
    let spec = GridSpec::from_bounds([-2.0, -2.0, 0.0], [2.0, 2.0, 0.4], 0.05).unwrap();
    // 10 x 10 x 1 blocks: room for the table, the zero block and 4 more.
    let budget = Budget {
        max_bytes: 100 * 4 + 5 * 4 + 5 * 512 * SPARSE_BYTES_PER_CELL,
        f64_blur: false,
    };
    let mut g = Grid::with_storage(spec, 0.02, GridStorage::Sparse, budget).unwrap();
    g.set_cell(spec.index(40, 40, 2), 9.0, 5).unwrap();
    let before = g.clone();
    let kernel = Translate::new(&spec, [1.0, 0.0], 0.5).unwrap();
    let e = Blurrer::default()
        .log_odds_blur(&mut g, &kernel)
        .unwrap_err();
    assert!(matches!(e, GridError::Allocation { .. }), "{e:?}");
    assert_eq!(g.sha256_hex(), before.sha256_hex());
    assert_eq!(g.stored_cells(), before.stored_cells());
}

/// Evidence in the last cell of a block, blurred along x: the cells it reaches in the next
/// block hold the reference's values, and the sparse grid stores that block.
#[test]
fn a_blur_crosses_block_boundaries() {
    let spec = GridSpec::from_bounds([0.0; 3], [1.0, 0.5, 0.5], 0.05).unwrap();
    assert_eq!(spec.dims, [20, 10, 10]);
    let mut sp = sparse(spec, 0.01);
    let mut plain = Plain::new(spec);
    let hot = spec.index(7, 3, 9);
    sp.set_cell(hot, 12.0, 3).unwrap();
    plain.evidence[hot] = 12.0;
    plain.views[hot] = 3;
    assert_eq!(sp.stored_cells(), BLOCK_CELLS);
    let kernel = Translate::new(&spec, [1.0, 0.0], 0.1).unwrap();
    let mut b = Blurrer::default();
    b.log_odds_blur(&mut sp, &kernel).unwrap();
    plain.blur(&kernel);
    plain.assert_same(&sp, "after the blur");
    // Sigma 2 cells, samples to 8 cells each side: cell 7 reaches cells 0..=15 along x,
    // blocks 0 and 1 in x of the same (y, z) block.
    assert!(sp.evidence_at(spec.index(15, 3, 9)) > 0.0);
    assert!(sp.evidence_at(spec.index(8, 3, 9)) > 0.0);
    assert_eq!(sp.stored_cells(), 2 * BLOCK_CELLS);
    // Nothing left the column: z = 9 only, y = 3 only.
    assert_eq!(sp.evidence_at(spec.index(8, 3, 8)), 0.0);
    assert_eq!(sp.evidence_at(spec.index(8, 4, 9)), 0.0);
}

#[test]
fn a_sparse_grid_stores_exactly_the_blocks_a_view_touches() {
    let spec = GridSpec::from_bounds([-2.0, -2.0, 0.0], [2.0, 2.0, 1.0], 0.05).unwrap();
    let cam = Camera::with_hfov(64, 48, 0.6);
    let ev = random_evidence(3, 6, 8, 0.01);
    let pose = iso_from_xy_yaw(-1.9, -1.9, 0.7) * camera_mount([0.0, 0.0, 0.5], 0.1);
    let mut sp = sparse(spec, 0.01);
    let mut plain = Plain::new(spec);
    let n = sp.integrate(&pose.inverse(), &cam, &ev, 1.5).unwrap();
    assert_eq!(plain.integrate(&pose.inverse(), &cam, &ev, 1.5), n);
    let mut touched: Vec<usize> = (0..spec.cells())
        .filter(|&i| plain.views[i] > 0)
        .map(|i| {
            let [a, b, c] = spec.ijk(i);
            sp.layout.block_index([a / BLOCK, b / BLOCK, c / BLOCK])
        })
        .collect();
    touched.sort_unstable();
    touched.dedup();
    let stored: Vec<usize> = sp
        .layout
        .in_block_order()
        .iter()
        .map(|&(b, _)| b as usize)
        .collect();
    assert_eq!(stored, touched);
    // A narrow view 1.5 m deep from a corner: a small part of the grid's 300 blocks.
    assert!(stored.len() > 5 && stored.len() < 100, "{}", stored.len());
    plain.assert_same(&sp, "sparse");
}

/// A camera 0.5 m up at the origin looking along +x, fx = 16 and 8-pixel tiles: a tile's
/// footprint is depth / 2, so a limit of 10 cells of 0.1 m stops the update at 2 m.
#[test]
fn the_range_limit_stops_the_update_at_the_footprints_depth() {
    let cam = Camera {
        width: 16,
        height: 16,
        fx: 16.0,
        fy: 16.0,
        cx: 8.0,
        cy: 8.0,
    };
    let depth = max_depth_m(&cam, 8, 0.1, Some(10.0));
    assert!((depth - 2.0).abs() < 1e-12, "{depth}");
    assert_eq!(max_depth_m(&cam, 8, 0.1, None), f64::INFINITY);
    let spec = GridSpec::from_bounds([0.0, -2.0, 0.0], [4.0, 2.0, 1.0], 0.1).unwrap();
    let cfo = camera_mount([0.0, 0.0, 0.5], 0.0).inverse();
    let ev = TileEvidence::from_probabilities(2, 2, 8, &[0.9; 4], 0.01);
    for storage in [GridStorage::Dense, GridStorage::Sparse] {
        let mut g = Grid::with_storage(spec, 0.01, storage, Budget::default()).unwrap();
        g.integrate(&cfo, &cam, &ev, depth).unwrap();
        // Along the optical axis (y = 0.05, z = 0.45 centres): the cell ending at 2.0 m is
        // updated, the next one (centre 2.05) is not, nor anything beyond.
        let axis = |i: usize| spec.index(i, 20, 4);
        assert_eq!(g.views_at(axis(19)), 1);
        assert_eq!(g.views_at(axis(20)), 0);
        for idx in 0..spec.cells() {
            let c = spec.center(spec.ijk(idx)[0], 0, 0);
            if g.views_at(idx) > 0 {
                assert!(c[0] <= 2.0, "{:?}", spec.ijk(idx));
            }
        }
        // Without the limit the frustum runs to the grid's far face.
        let mut all = Grid::with_storage(spec, 0.01, storage, Budget::default()).unwrap();
        all.integrate(&cfo, &cam, &ev, f64::INFINITY).unwrap();
        assert_eq!(all.views_at(spec.index(39, 20, 4)), 1);
    }
}

#[test]
fn thread_count_does_not_change_the_result() {
    let run = |threads| {
        crate::types::testing::with_threads(threads, || {
            let spec = GridSpec::from_bounds([0.0, -0.5, 0.0], [2.0, 0.5, 1.0], 0.05).unwrap();
            let mut g = sparse(spec, 0.01);
            let cam = Camera::with_hfov(64, 48, 1.0);
            let pose = camera_mount([-0.5, 0.1, 0.6], 0.2).inverse();
            let p: Vec<f32> = (0..48).map(|i| 0.001 + i as f32 / 50.0).collect();
            let ev = TileEvidence::from_probabilities(6, 8, 8, &p, 0.01);
            let mut b = Blurrer::default();
            g.integrate(&pose, &cam, &ev, f64::INFINITY).unwrap();
            b.rotate(&mut g, [0.5, 0.0], 0.1, BlurMode::LogOdds)
                .unwrap();
            g.integrate(&pose, &cam, &ev, 1.0).unwrap();
            b.translate(&mut g, [0.6, 0.8], 0.1, BlurMode::LogOdds)
                .unwrap();
            (g.sha256_hex(), g.stored_cells(), g.max_log_odds())
        })
    };
    let one = run(1);
    assert_eq!(one, run(3));
    assert!(one.1 > 0);
}

#[test]
fn spec_dims_and_refusals_name_the_sizes() {
    let s = GridSpec::from_bounds([0.0; 3], [4.0, 4.0, 4.0], 0.04).unwrap();
    assert_eq!(s.dims, [100, 100, 100]);
    assert_eq!(s.index(1, 2, 3), (100 + 2) * 100 + 3);
    assert_eq!(s.ijk(s.index(7, 8, 9)), [7, 8, 9]);
    // 10^12 cells: 1.95e9 blocks, a 7 451 MiB table.
    match GridSpec::from_bounds([0.0; 3], [100.0, 100.0, 100.0], 0.01).unwrap_err() {
        GridError::BlockTable { nx, needed_mib, .. } => {
            assert_eq!(nx, 10_000);
            assert_eq!(needed_mib, (1250u64.pow(3) * 4).div_ceil(1 << 20));
        }
        other => panic!("{other:?}"),
    }
    // The volume: 100 x 100 x 4 m at 2 cm, 5e9 cells in 9.77e6 blocks (a 37 MiB
    // table): sparse by default, and refused dense.
    let big = GridSpec::from_bounds([-50.0, -50.0, 0.0], [50.0, 50.0, 4.0], 0.02).unwrap();
    assert_eq!(big.dims, [5000, 5000, 200]);
    assert_eq!(GridStorage::Auto.resolve(&big), GridStorage::Sparse);
    assert_eq!(GridStorage::Auto.resolve(&s), GridStorage::Dense);
    let g = Grid::with_storage(big, 0.01, GridStorage::Auto, Budget::default()).unwrap();
    assert_eq!(g.stored_bytes(), 625 * 625 * 25 * 4 + 4 + 512 * 19);
    match Grid::with_storage(big, 0.01, GridStorage::Dense, Budget::default()).unwrap_err() {
        GridError::TooLarge { needed_mib, .. } => {
            let blocks = 625u64 * 625 * 25;
            assert_eq!(
                needed_mib,
                (blocks * 8 + 4 + (blocks + 1) * 5120).div_ceil(1 << 20)
            );
        }
        other => panic!("{other:?}"),
    }
    assert!(GridSpec::from_bounds([0.0; 3], [1.0, f64::NAN, 1.0], 0.1).is_err());
    assert!(GridSpec::from_bounds([0.0; 3], [1.0; 3], 0.0).is_err());
}

#[test]
fn a_sparse_grid_over_its_budget_stops_with_the_numbers() {
    let spec = GridSpec::from_bounds([-2.0, -2.0, 0.0], [2.0, 2.0, 1.0], 0.05).unwrap();
    // 80 x 80 x 20 cells in 10 x 10 x 3 blocks: room for the table, the zero block and 9
    // more at 19 bytes a cell.
    let budget = Budget {
        max_bytes: 300 * 4 + 10 * 4 + 10 * 512 * SPARSE_BYTES_PER_CELL,
        f64_blur: false,
    };
    let mut g = Grid::with_storage(spec, 0.01, GridStorage::Sparse, budget).unwrap();
    let cam = Camera::with_hfov(64, 48, 1.0);
    let pose = iso_from_xy_yaw(-1.5, 0.0, 0.0) * camera_mount([0.0, 0.0, 0.5], 0.0);
    let ev = random_evidence(5, 6, 8, 0.01);
    let before = g.clone();
    let e = g
        .integrate(&pose.inverse(), &cam, &ev, f64::INFINITY)
        .unwrap_err();
    let GridError::Allocation {
        cells,
        limit_mib,
        nx,
        ..
    } = &e
    else {
        panic!("{e:?}");
    };
    assert!(*cells > 9 * 512 && *nx == 80 && *limit_mib == 0, "{e}");
    assert!(e.to_string().contains("80 x 80 x 20 cells"), "{e}");
    assert_eq!(g.stored_cells(), before.stored_cells());
}

#[test]
fn hash_max_and_export_do_not_depend_on_what_is_stored() {
    let spec = GridSpec::from_bounds([0.0; 3], [1.0, 0.6, 0.5], 0.05).unwrap();
    let mut dense = Grid::new(spec, 0.1).unwrap();
    let mut sp = sparse(spec, 0.1);
    assert_eq!(dense.sha256_hex(), sp.sha256_hex());
    assert_eq!(sp.occupied_region().dims, [0, 0, 0]);
    assert_eq!(dense.max_log_odds(), dense.prior_log_odds());
    assert_eq!(sp.max_log_odds(), sp.prior_log_odds());
    // All evidence negative or 0: the highest cell is one at the prior, stored or not.
    for g in [&mut dense, &mut sp] {
        g.set_cell(spec.index(9, 3, 2), -2.0, 1).unwrap();
        assert_eq!(g.max_log_odds(), g.prior_log_odds());
        g.set_cell(spec.index(19, 11, 9), 3.5, 2).unwrap();
    }
    assert_eq!(dense.sha256_hex(), sp.sha256_hex());
    assert_eq!(sp.max_log_odds(), sp.prior_log_odds() + 3.5);
    // Two blocks stored, (1, 0, 0) and (2, 1, 1): the region is their box, cut at the grid.
    let r = sp.occupied_region();
    assert_eq!(r.first_cell, [8, 0, 0]);
    assert_eq!(r.dims, [12, 12, 10]);
    assert_eq!(dense.occupied_region().dims, spec.dims);
    let slab = sp.probability_slab(&r, 19);
    assert_eq!(slab.len(), 12 * 10);
    let p = sigmoid(f64::from(sp.prior_log_odds() + 3.5)) as f32;
    assert_eq!(slab[11 * 10 + 9], p);
    assert_eq!(slab[0], sigmoid(f64::from(sp.prior_log_odds())) as f32);
    assert_eq!(dense.probability_slab(&r, 19), slab);
    // 12 x 12 x 10 float32 cells are 5 760 bytes: refused under that, with the numbers.
    assert_eq!(sp.export_region(5760), Ok(r));
    let e = sp.export_region(5759).unwrap_err();
    assert!(
        matches!(
            e,
            GridError::Export {
                dims: [12, 12, 10],
                needed_mib: 1,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string().starts_with("the grid's stored region is 12 x 12 x 10 cells ([8, 0, 0] on, of the 20 x 12 x 10 grid), 1 MiB as float32, over the export limit of 0 MiB"),
        "{e}"
    );
}

/// One frame, one tile at p = 0.9, a known camera: exactly the cells of that tile's pyramid
/// change, by exactly logit(0.9) - logit(prior).
#[test]
fn one_tile_updates_exactly_its_pyramid() {
    let spec = GridSpec::from_bounds([0.0, -0.5, 0.0], [2.0, 0.5, 1.0], 0.1).unwrap();
    // 2^-7: exactly representable in f32, so tiles at the prior add exactly 0.
    let prior = 0.0078125;
    let mut g = sparse(spec, prior);
    // Camera at the origin 0.5 m up, looking along +x (level): optical z = odom +x.
    let camera_from_odom = camera_mount([0.0, 0.0, 0.5], 0.0).inverse();
    // 2 x 2 tiles of 8 px: image 16 x 16, principal point at the centre, fx = 16 (each tile
    // spans 0.5 in normalised coordinates).
    let cam = Camera {
        width: 16,
        height: 16,
        fx: 16.0,
        fy: 16.0,
        cx: 8.0,
        cy: 8.0,
    };
    // Only tile (row 0, col 1) = up and right carries p = 0.9; the others the prior.
    let p = [prior as f32, 0.9, prior as f32, prior as f32];
    let ev = TileEvidence::from_probabilities(2, 2, 8, &p, prior);
    let n = g
        .integrate(&camera_from_odom, &cam, &ev, f64::INFINITY)
        .unwrap();
    assert!(n > 0);
    // logit(0.9) - logit(2^-7) = 2.1972246 + 4.8441871, with 0.9 as the f32 the tree returns.
    let expected = (logit(f64::from(0.9f32)) - logit(prior)) as f32;
    assert!((expected - 7.041_412).abs() < 1e-5, "{expected}");
    let mut changed = 0;
    for idx in 0..spec.cells() {
        let c = spec.center(spec.ijk(idx)[0], spec.ijk(idx)[1], spec.ijk(idx)[2]);
        // In optical coordinates: z = x_odom, x = -y_odom, y = -(z_odom - 0.5).
        let (zc, xc, yc) = (c[0], -c[1], -(c[2] - 0.5));
        let u = 16.0 * xc / zc + 8.0;
        let v = 16.0 * yc / zc + 8.0;
        let in_tile = (8.0..16.0).contains(&u) && (0.0..8.0).contains(&v);
        if in_tile {
            changed += 1;
            assert_eq!(
                g.evidence_at(idx),
                expected,
                "cell {:?} u={u} v={v}",
                spec.ijk(idx)
            );
        } else {
            // Other tiles were at the prior: delta exactly 0.
            assert_eq!(
                g.evidence_at(idx),
                0.0,
                "cell {:?} u={u} v={v}",
                spec.ijk(idx)
            );
        }
    }
    assert!(changed > 10, "{changed}");
    // Hand check of one cell: centre (1.05, -0.25, 0.75) -> u = 16*0.25/1.05+8 = 11.8,
    // v = 16*(-0.25)/1.05+8 = 4.19: in tile (0, 1).
    let idx = spec.index(10, 2, 7);
    let c = spec.center(10, 2, 7);
    assert!(
        (c[0] - 1.05).abs() < 1e-12 && (c[1] + 0.25).abs() < 1e-12 && (c[2] - 0.75).abs() < 1e-12
    );
    assert_eq!(g.log_odds_at(idx), g.prior_log_odds() + expected);
    assert_eq!(g.views_at(idx), 1);
    // A cell behind the camera is untouched, and a grid behind it stores nothing.
    let behind = GridSpec::from_bounds([-1.0, -0.5, 0.0], [-0.1, 0.5, 1.0], 0.1).unwrap();
    let mut gb = sparse(behind, prior);
    assert_eq!(
        gb.integrate(&camera_from_odom, &cam, &ev, f64::INFINITY)
            .unwrap(),
        0
    );
    assert_eq!(gb.stored_cells(), 0);
}

/// Two views of a point: the cell holding the point is in both pyramids, and every cell in
/// both lies near the point.
#[test]
fn two_views_intersect_at_the_point() {
    let spec = GridSpec::from_bounds([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 0.05).unwrap();
    let mut g = Grid::new(spec, 0.0078125).unwrap();
    // Aimed half a tile (1/16 rad) left of the point and 0.13 m below it, so the point
    // projects into the middle of a tile in both views.
    let target = Point3::new(0.21, 0.11, 0.53);
    let cam = Camera {
        width: 64,
        height: 64,
        fx: 64.0,
        fy: 64.0,
        cx: 32.0,
        cy: 32.0,
    };
    for (x, y) in [(-2.0f64, 0.1f64), (0.2, -2.0)] {
        let yaw = (target.y - y).atan2(target.x - x) + 0.0625;
        let odom_from_camera = iso_from_xy_yaw(x, y, yaw) * camera_mount([0.0, 0.0, 0.4], 0.0);
        let camera_from_odom = odom_from_camera.inverse();
        let (u, v) = cam.project(&(camera_from_odom * target)).unwrap();
        assert!((u - 36.0).abs() < 1.0 && (v - 28.0).abs() < 1.0, "{u} {v}");
        let (r, c) = ((v / 8.0) as usize, (u / 8.0) as usize);
        let mut p = vec![0.0078125f32; 64];
        p[r * 8 + c] = 0.95;
        let ev = TileEvidence::from_probabilities(8, 8, 8, &p, 0.0078125);
        g.integrate(&camera_from_odom, &cam, &ev, f64::INFINITY)
            .unwrap();
    }
    let once = (logit(f64::from(0.95f32)) - logit(0.0078125)) as f32;
    let hit = once + once;
    let t = spec.index(24, 22, 10);
    let c = spec.center(24, 22, 10);
    assert!(
        (c[0] - 0.225).abs() < 1e-12
            && (c[1] - 0.125).abs() < 1e-12
            && (c[2] - 0.525).abs() < 1e-12
    );
    assert_eq!(g.evidence_at(t), hit);
    let both: Vec<[f64; 3]> = (0..spec.cells())
        .filter(|&i| g.evidence_at(i) == hit)
        .map(|i| {
            let [a, b, c] = spec.ijk(i);
            spec.center(a, b, c)
        })
        .collect();
    // Each tile spans 1/8 rad, about 0.28 m at 2.2 m: the shared cells stay within one tile
    // footprint of the point.
    for c in &both {
        let d = ((c[0] - 0.21).powi(2) + (c[1] - 0.11).powi(2) + (c[2] - 0.53).powi(2)).sqrt();
        assert!(d < 0.3, "{c:?} is {d} m from the point");
    }
}

/// The shortcut above SIGMOID_ONE_FROM gives what the formula gives, bit for bit: from 38 on
/// the formula is exactly 1.0.
#[test]
fn sigmoid_is_its_formula_bit_for_bit_about_the_shortcut() {
    let formula = |l: f64| 1.0 / (1.0 + (-l).exp());
    for l in [38.0, 39.5, 39.999, 40.0, 40.001, 55.0, 1e6, f64::INFINITY] {
        assert_eq!(formula(l).to_bits(), 1.0f64.to_bits(), "{l}");
        assert_eq!(sigmoid(l).to_bits(), formula(l).to_bits(), "{l}");
    }
    for l in [-40.0, -1.0, 0.0, 1.0, 20.0, 36.0] {
        assert_eq!(sigmoid(l).to_bits(), formula(l).to_bits(), "{l}");
    }
    assert!(sigmoid(f64::NAN).is_nan());
}
