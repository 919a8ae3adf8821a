//! eval: placeholder.
