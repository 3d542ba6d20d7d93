//! The sky stage: HDR sky images to a float cube map, the sun extracted from it, the sun-free sky
//! projected to spherical harmonics; and a built-in analytic clear sky for scenes without one.

pub mod cube;
pub mod sun;
