//! features: placeholder.
