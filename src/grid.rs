//! grid: placeholder.
