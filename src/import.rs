//! import: placeholder.
