//! Per-pixel quantisations of the brightness pattern around a pixel (texture and gradient),
//! whose tile histograms sit beside the colour histogram as further channels.
//!
//! Invariants: both read the luma plane only, with neighbours clamped at the image edge (a
//! border pixel repeats itself), so every pixel has a bin in `0..bins`; integer arithmetic
//! only. Luma is kept unrounded (256 x the 8-bit luma) and every threshold but the dark one
//! compares ratios, so multiplying the image by a gain that clips nothing keeps every bin of
//! every pixel that is not dark before and after (unit tests check a gain of 2 exactly).

/// Bins of the texture channel: dark, then (brighter, darker) neighbour counts with
/// brighter + darker <= 8.
pub const TEXTURE_BINS: usize = 46;
/// Bins of the gradient channel: dark, flat, then 4 magnitude levels x 4 orientations.
pub const GRAD_BINS: usize = 18;

/// Below this luma (x 256; 8-bit luma 24) a pixel is too dark for its pattern to be more than
/// sensor noise: bin 0 of both channels.
const DARK_LUMA: u16 = 24 * 256;

/// Luma of every pixel, row-major, unrounded: 77 r + 150 g + 29 b (BT.601 weights x 256, at
/// most 65 280), so that it is exactly proportional to a gain on the image.
pub fn luma(rgb: &[u8]) -> Vec<u16> {
    rgb.chunks_exact(3)
        .map(|p| 77 * p[0] as u16 + 150 * p[1] as u16 + 29 * p[2] as u16)
        .collect()
}

/// Row `y` of the luma plane widened to u32 and padded with its first and last pixel, so
/// that the neighbours of pixel x are at x, x + 1 and x + 2 of the padded rows above, at and
/// below it (clamped at the image edge) and the loops over a row vectorise.
fn padded_row(l: &[u16], width: usize, y: usize, out: &mut Vec<u32>) {
    let row = &l[y * width..][..width];
    out.clear();
    out.push(row[0] as u32);
    out.extend(row.iter().map(|&v| v as u32));
    out.push(row[width - 1] as u32);
}

/// The padded rows above, at and below `y`, clamped at the top and bottom edges.
fn neighbour_rows(l: &[u16], width: usize, height: usize, y: usize, rows: &mut [Vec<u32>; 3]) {
    padded_row(l, width, y.saturating_sub(1), &mut rows[0]);
    padded_row(l, width, y, &mut rows[1]);
    padded_row(l, width, (y + 1).min(height - 1), &mut rows[2]);
}

/// Index of (brighter, darker) counts in the triangle brighter + darker <= 8, brighter-major.
#[inline]
fn texture_index(up: usize, down: usize) -> usize {
    up * 9 - up * up.saturating_sub(1) / 2 + down
}

/// Texture bin of every pixel plus `offset`: 0 when dark, else 1 + the index of how many of
/// its 8 neighbours are clearly brighter (n >= 1.125 c) and clearly darker (n <= c / 1.125)
/// than the centre c. A flat patch is (0, 0), a straight edge about (3, 0) or (0, 3) on its
/// two sides, a speck (0, 8) or (8, 0), fine texture a mix; rotating the image does not
/// change it. A local binary pattern reduced to its counts, with a tolerance of 12.5 % so
/// that noise on a flat patch stays (0, 0).
pub fn texture_plane(l: &[u16], width: usize, height: usize, offset: u16) -> Vec<u16> {
    let mut out = vec![0u16; l.len()];
    if width == 0 || height == 0 {
        return out;
    }
    let mut table = [0u16; 81];
    for up in 0..=8 {
        for down in 0..=8 - up {
            table[up * 9 + down] = offset + 1 + texture_index(up, down) as u16;
        }
    }
    let mut rows: [Vec<u32>; 3] = Default::default();
    let (mut brighter, mut darker) = (vec![0u8; width], vec![0u8; width]);
    // The 8 neighbours as (padded row, shift): all but the centre (1, 1).
    const NEIGHBOURS: [(usize, usize); 8] = [
        (0, 0),
        (0, 1),
        (0, 2),
        (1, 0),
        (1, 2),
        (2, 0),
        (2, 1),
        (2, 2),
    ];
    for y in 0..height {
        neighbour_rows(l, width, height, y, &mut rows);
        let c = &rows[1][1..=width];
        brighter.fill(0);
        darker.fill(0);
        for &(r, dx) in &NEIGHBOURS {
            let n = &rows[r][dx..dx + width];
            for x in 0..width {
                brighter[x] += u8::from(8 * n[x] >= 9 * c[x]);
                darker[x] += u8::from(9 * n[x] <= 8 * c[x]);
            }
        }
        let out_row = &mut out[y * width..][..width];
        for x in 0..width {
            out_row[x] = if c[x] < DARK_LUMA as u32 {
                offset
            } else {
                table[brighter[x] as usize * 9 + darker[x] as usize]
            };
        }
    }
    out
}

/// Gradient bin of every pixel plus `offset`, from central differences of luma gx = l(x+1) -
/// l(x-1), gy = l(y+1) - l(y-1) and m = |gx| + |gy| against the centre's luma c: bin 0 dark,
/// 1 flat (8 m < c), else 2 + level * 4 + orientation with level 0..4 for m / c in [1/8,
/// 1/4), [1/4, 1/2), [1/2, 1), [1, ...), orientation 0 for a vertical edge (|gy| < 0.414
/// |gx|), 2 for a horizontal one (|gx| < 0.414 |gy|), 1 for a `/` edge (gx, gy of one sign;
/// y down) and 3 for a `\` edge.
pub fn grad_plane(l: &[u16], width: usize, height: usize, offset: u16) -> Vec<u16> {
    let mut out = vec![0u16; l.len()];
    if width == 0 || height == 0 {
        return out;
    }
    let mut rows: [Vec<u32>; 3] = Default::default();
    for y in 0..height {
        neighbour_rows(l, width, height, y, &mut rows);
        let out_row = &mut out[y * width..][..width];
        for x in 0..width {
            let c = rows[1][x + 1];
            let gx = rows[1][x + 2] as i32 - rows[1][x] as i32;
            let gy = rows[2][x + 1] as i32 - rows[0][x + 1] as i32;
            out_row[x] = offset + grad_bin(c, gx, gy);
        }
    }
    out
}

/// The gradient bin of a pixel of luma `c` with central differences `gx`, `gy`.
#[inline]
fn grad_bin(c: u32, gx: i32, gy: i32) -> u16 {
    let (ax, ay) = (gx.unsigned_abs(), gy.unsigned_abs());
    let m = ax + ay;
    if c < DARK_LUMA as u32 {
        return 0;
    }
    if 8 * m < c {
        return 1;
    }
    // The number of the thresholds c / 4, c / 2, c that m reaches.
    let level = u16::from(4 * m >= c) + u16::from(2 * m >= c) + u16::from(m >= c);
    // tan(22.5 deg) = 0.4142 ~ 12 / 29.
    let orientation = if 29 * ay < 12 * ax {
        0
    } else if 29 * ax < 12 * ay {
        2
    } else if (gx > 0) == (gy > 0) {
        1
    } else {
        3
    };
    2 + level * 4 + orientation
}

/// A texture bin in words.
pub fn describe_texture(bin: usize) -> String {
    if bin == 0 {
        return "texture: dark (luma below 24)".to_owned();
    }
    let (mut up, mut start) = (0, 0);
    let k = bin - 1;
    while up < 8 && k >= start + (9 - up) {
        start += 9 - up;
        up += 1;
    }
    let down = k - start;
    if up == 0 && down == 0 {
        return "texture: flat (no neighbour 12.5 % brighter or darker)".to_owned();
    }
    format!("texture: {up} of 8 neighbours brighter, {down} darker")
}

/// A gradient bin in words.
pub fn describe_grad(bin: usize) -> String {
    match bin {
        0 => "gradient: dark (luma below 24)".to_owned(),
        1 => "gradient: flat (below 1/8 of brightness)".to_owned(),
        _ => {
            let (level, orientation) = ((bin - 2) / 4, (bin - 2) % 4);
            let range = ["1/8-1/4", "1/4-1/2", "1/2-1", "over 1"][level];
            let edge = ["vertical", "/", "horizontal", "\\"][orientation];
            format!("gradient: {range} of brightness, {edge} edge")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unrounded luma planes from 8-bit grey levels.
    fn grey(v: &[u8]) -> Vec<u16> {
        v.iter().map(|&x| x as u16 * 256).collect()
    }

    /// The definitions pixel by pixel, neighbours clamped with index arithmetic: what the
    /// row-wise planes must equal.
    fn reference(l: &[u16], w: usize, h: usize) -> (Vec<u16>, Vec<u16>) {
        let at = |x: i64, y: i64| {
            l[(y.clamp(0, h as i64 - 1) as usize) * w + x.clamp(0, w as i64 - 1) as usize] as u32
        };
        let (mut tex, mut grad) = (Vec::new(), Vec::new());
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let c = at(x, y);
                let n: Vec<u32> = [
                    (-1, -1),
                    (0, -1),
                    (1, -1),
                    (-1, 0),
                    (1, 0),
                    (-1, 1),
                    (0, 1),
                    (1, 1),
                ]
                .iter()
                .map(|&(dx, dy)| at(x + dx, y + dy))
                .collect();
                let up = n.iter().filter(|&&v| 8 * v >= 9 * c).count();
                let down = n.iter().filter(|&&v| 9 * v <= 8 * c).count();
                tex.push(if c < DARK_LUMA as u32 {
                    0
                } else {
                    1 + texture_index(up, down) as u16
                });
                let gx = at(x + 1, y) as i32 - at(x - 1, y) as i32;
                let gy = at(x, y + 1) as i32 - at(x, y - 1) as i32;
                grad.push(grad_bin(c, gx, gy));
            }
        }
        (tex, grad)
    }

    #[test]
    fn planes_equal_the_pixel_by_pixel_definition() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        for (w, h) in [(1, 1), (1, 7), (9, 1), (2, 2), (23, 17)] {
            let l: Vec<u16> = (0..w * h)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    // Grey levels in clusters, so that flat, dark and textured pixels all occur.
                    ((state >> 40) % 6) as u16 * 40 * 256 + (state % 700) as u16
                })
                .collect();
            let (tex, grad) = reference(&l, w, h);
            assert_eq!(texture_plane(&l, w, h, 0), tex, "{w} x {h}");
            assert_eq!(grad_plane(&l, w, h, 0), grad, "{w} x {h}");
            assert!(tex.iter().any(|&b| b > 1) || w * h < 4);
        }
    }

    #[test]
    fn luma_by_hand() {
        // 77 * 200 + 150 * 100 + 29 * 50 = 15400 + 15000 + 1450 = 31850.
        assert_eq!(
            luma(&[200, 100, 50, 255, 255, 255, 0, 0, 0]),
            vec![31850, 65280, 0]
        );
    }

    #[test]
    fn texture_index_covers_the_triangle_once() {
        let mut seen = [false; TEXTURE_BINS];
        seen[0] = true;
        for up in 0..=8 {
            for down in 0..=8 - up {
                let i = 1 + texture_index(up, down);
                assert!(!seen[i], "({up}, {down}) -> {i} twice");
                seen[i] = true;
                if (up, down) != (0, 0) {
                    assert_eq!(
                        describe_texture(i),
                        format!("texture: {up} of 8 neighbours brighter, {down} darker")
                    );
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(texture_index(1, 0), 9);
        assert_eq!(texture_index(8, 0), 44);
    }

    /// A 4 x 3 grey image with a vertical edge between columns 1 and 2: 40 40 120 120 on
    /// every row.
    fn edge() -> Vec<u16> {
        grey(&[40u8, 40, 120, 120].repeat(3))
    }

    #[test]
    fn texture_of_an_edge_by_hand() {
        let t = texture_plane(&edge(), 4, 3, 0);
        // Pixel (1, 1), 40: neighbours left 40, right 120, up 40, down 40, up-left 40,
        // up-right 120, down-left 40, down-right 120: 3 at least 1.125 x 40, none darker.
        assert_eq!(t[5], 1 + texture_index(3, 0) as u16);
        // Pixel (2, 1), 120: left, up-left, down-left 40 <= 120 / 1.125: 3 darker.
        assert_eq!(t[6], 1 + texture_index(0, 3) as u16);
        // Pixel (0, 0): every neighbour, clamped at the edge, is 40: flat.
        assert_eq!(t[0], 1);
        // A dark image (grey 20 < 24) is bin 0 whatever its pattern.
        assert_eq!(texture_plane(&grey(&[20, 2, 20, 2]), 2, 2, 0), vec![0; 4]);
        assert_eq!(
            describe_texture(1 + texture_index(3, 0)),
            "texture: 3 of 8 neighbours brighter, 0 darker"
        );
    }

    #[test]
    fn gradient_of_an_edge_by_hand() {
        let g = grad_plane(&edge(), 4, 3, 100);
        // Pixel (1, 1): gx = 120 - 40 = 80, gy = 0: m = 80 >= c = 40: level 3, vertical
        // edge: 100 + 2 + 12 + 0.
        assert_eq!(g[5], 114);
        // Pixel (2, 1): gx = 120 - 40 = 80 against c = 120: in [60, 120) -> level 2.
        assert_eq!(g[6], 110);
        // Pixel (0, 1): gx = 40 - 40 = 0: flat.
        assert_eq!(g[4], 101);
        assert_eq!(
            describe_grad(14),
            "gradient: over 1 of brightness, vertical edge"
        );
        // A diagonal: gx = gy = 30 at centre 50 (m = 60 >= 50: level 3) is a `/` edge
        // (brighter towards the bottom right, y down): 2 + 12 + 1 = 15.
        let l = grey(&[50, 50, 80, 50, 50, 80, 80, 80, 80]);
        assert_eq!(grad_plane(&l, 3, 3, 0)[4], 15);
    }

    #[test]
    fn a_gain_of_two_keeps_every_texture_and_gradient_bin() {
        // A patch with edges, a speck, gentle slopes and flat parts, grey levels 40..127 so
        // that doubling neither clips nor crosses the dark threshold.
        let l = grey(&[
            40, 40, 40, 60, 62, //
            40, 90, 40, 60, 64, //
            40, 40, 41, 60, 66, //
            100, 100, 110, 120, 127, //
        ]);
        let doubled: Vec<u16> = l.iter().map(|&v| v * 2).collect();
        let (tex, tex2) = (texture_plane(&l, 5, 4, 0), texture_plane(&doubled, 5, 4, 0));
        let (grad, grad2) = (grad_plane(&l, 5, 4, 0), grad_plane(&doubled, 5, 4, 0));
        assert_eq!(tex, tex2);
        assert_eq!(grad, grad2);
        // And the patch is not trivial: the speck at (1, 1) has 8 darker neighbours, and
        // there are flat pixels and gradients of several levels.
        assert_eq!(tex[6], 1 + texture_index(0, 8) as u16);
        assert!(tex.contains(&1) && grad.contains(&1));
        let mut levels: Vec<u16> = grad
            .iter()
            .filter(|&&b| b >= 2)
            .map(|&b| (b - 2) / 4)
            .collect();
        levels.sort_unstable();
        levels.dedup();
        assert!(levels.len() >= 3, "{levels:?}");
    }
}
