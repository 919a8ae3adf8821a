//! objects: placeholder.
