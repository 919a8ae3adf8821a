//! motion: placeholder.
