//! dataset: placeholder.
