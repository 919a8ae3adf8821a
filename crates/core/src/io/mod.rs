//! Input and output at the edge: MCAP sessions <-> typed ROS 2 messages ([`session`], [`cdr`],
//! [`msgs`]), importers of real captures ([`import`]), the session inspector ([`inspect`]),
//! `.npy` arrays and files written atomically ([`npy`], [`output`]). The only folder that
//! touches MCAP.
//!
//! May import: [`crate::types`].

pub mod capture;
pub mod cdr;
pub mod import;
pub mod inspect;
pub mod msgs;
pub mod npy;
pub mod output;
pub mod session;
