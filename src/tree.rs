//! tree: placeholder.
