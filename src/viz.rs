//! viz: placeholder.
