//! sim: placeholder.
