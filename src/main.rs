//! The `objloc` binary: parses arguments, dispatches to one subcommand, prints any error on
//! one line with its context chain and exits 1. All logic lives in the library.

// The core's errors carry file, topic, time and numbers (see objloc-core's lib.rs), so the
// commands that pass them on inherit clippy's large-`Err` lint; they are built only on failure.
#![allow(clippy::result_large_err)]

mod cmd;
mod viz;

use clap::Parser;

fn main() -> std::process::ExitCode {
    // Like any Unix filter: `objloc inspect x.mcap | head` ends quietly when the reader goes
    // away, instead of panicking on the write (Rust ignores SIGPIPE by default). Outputs are
    // written to `.partial` files and renamed, so an early end never leaves a finished-looking
    // file.
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    use_main_thread_in_rayon_pool();
    cmd::main(cmd::Cli::parse())
}

/// Makes this thread one of the global pool's workers (as many in all as `RAYON_NUM_THREADS`
/// or the cores): a replay calls the pool tens of times a frame, and from a thread outside
/// it each call is injected into the pool and waited for asleep, while this thread works
/// alongside the others from inside it. Which thread computes what never changes a result
/// (every parallel sum is grouped independently of the threads).
fn use_main_thread_in_rayon_pool() {
    // Fails only if a pool was built before, which nothing here does; the default pool
    // then works as before.
    let _ = rayon::ThreadPoolBuilder::new()
        .use_current_thread()
        .build_global();
}
