//! SGI image reader (in progress).
