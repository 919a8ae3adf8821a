//! Sorting the flat cell indices the object search collects: an LSD radix sort, for the
//! hundreds of thousands of cells of an object that fills a capture's grid, sorted after
//! every frame.
//!
//! Invariants: the result is the ascending order of the input's values, the same as
//! `sort_unstable` gives (equal values are indistinguishable), so callers' results do not
//! depend on which sort ran; no allocation below [`RADIX_MIN_LEN`] values.

/// Below this many values `sort_unstable` is as fast and needs no buffer.
pub const RADIX_MIN_LEN: usize = 4096;

/// Bits of the value each pass sorts by: a 2 048-entry count table stays in L1.
const DIGIT_BITS: u32 = 11;

/// Sorts `values` ascending: a radix sort on as many 11-bit digits as the largest value
/// needs (a 7 M-cell grid's indices: 3 passes), `sort_unstable` for short slices.
pub fn sort_indices(values: &mut Vec<usize>) {
    if values.len() < RADIX_MIN_LEN {
        values.sort_unstable();
        return;
    }
    let max = values.iter().copied().max().unwrap_or(0);
    let bits = usize::BITS - max.leading_zeros();
    let mut from = std::mem::take(values);
    let mut to = vec![0usize; from.len()];
    let mask = (1usize << DIGIT_BITS) - 1;
    let mut shift = 0;
    while shift < bits {
        let mut start = vec![0usize; 1 << DIGIT_BITS];
        for &v in &from {
            start[(v >> shift) & mask] += 1;
        }
        let mut sum = 0;
        for s in &mut start {
            (*s, sum) = (sum, sum + *s);
        }
        // Stable: values with the same digit keep the order the earlier passes gave them.
        for &v in &from {
            let d = (v >> shift) & mask;
            to[start[d]] = v;
            start[d] += 1;
        }
        std::mem::swap(&mut from, &mut to);
        shift += DIGIT_BITS;
    }
    *values = from;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scrambled(n: usize, modulus: usize) -> Vec<usize> {
        // A full-period LCG over 2^64, reduced: repeats, gaps and every digit exercised.
        let mut x: u64 = 12345;
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (x >> 17) as usize % modulus
            })
            .collect()
    }

    #[test]
    fn radix_order_is_sort_unstables_for_every_width() {
        for (n, modulus) in [
            (RADIX_MIN_LEN, 7),
            (10_000, 1 << 11),
            (10_001, (1 << 11) + 1),
            (50_000, 7_000_000),
            (20_000, usize::MAX),
        ] {
            let mut a = scrambled(n, modulus);
            let mut b = a.clone();
            sort_indices(&mut a);
            b.sort_unstable();
            assert_eq!(a, b, "n {n}, values below {modulus}");
        }
    }

    /// Values up to `usize::MAX` need every digit, the last pass a partial one (shift 55).
    #[test]
    fn values_up_to_the_largest_sort_as_sort_unstable_does() {
        let mut a: Vec<usize> = scrambled(RADIX_MIN_LEN + 100, 1 << 40)
            .into_iter()
            .enumerate()
            .map(|(i, v)| match i % 4 {
                0 => usize::MAX - v,
                1 => v << 23,
                _ => v,
            })
            .collect();
        a[7] = usize::MAX;
        let mut b = a.clone();
        sort_indices(&mut a);
        b.sort_unstable();
        assert_eq!(a, b);
        assert_eq!(a.last(), Some(&usize::MAX));
    }

    #[test]
    fn short_and_zero_inputs() {
        let mut v = vec![3, 1, 2];
        sort_indices(&mut v);
        assert_eq!(v, [1, 2, 3]);
        let mut zeros = vec![0; RADIX_MIN_LEN + 5];
        sort_indices(&mut zeros);
        assert_eq!(zeros, vec![0; RADIX_MIN_LEN + 5]);
        let mut empty: Vec<usize> = Vec::new();
        sort_indices(&mut empty);
        assert!(empty.is_empty());
    }
}
