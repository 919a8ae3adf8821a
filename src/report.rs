//! report: placeholder.
