//! Helpers for unit tests across the crate (compiled for tests only).

/// `f`'s result computed in a rayon pool of `threads` threads: for tests that a result does
/// not depend on the thread count.
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}
