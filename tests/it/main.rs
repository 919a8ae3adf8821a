//! objloc at the process boundary, as one test binary: the built `objloc` is run as a user
//! runs it, and what it prints, exits with and writes is checked. Exit codes and one-line
//! errors on bad input and damaged files (truncated, bit-flipped, hostile MCAPs and model
//! files, killed runs that must leave no finished-looking output); interop with tools we did
//! not write (Python mcap and mcap-ros2-support, rosbags, real rosbag2 bags, the rerun-sdk's
//! RRD reader and `rerun rrd verify | compare`); determinism across runs and thread counts;
//! the shipped recordings regenerating byte for byte; and the accuracy targets of training,
//! fusion and pose refinement on the shipped and generated sessions.
//!
//! One module per subject; `common` holds the helpers they share (running the binary, the
//! fixture session, the Python venv in target/pyenv).

// Tests may unwrap and expect: a panic with its message is how a test reports a failure.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]
// A scenario test reads top to bottom, its steps and their checks in order.
#![allow(clippy::too_many_lines)]

mod common;

mod fuse;
mod interop;
mod realdata;
mod record;
mod refine;
mod reliability;
mod session_errors;
mod train;
mod viz;
