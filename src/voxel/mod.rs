//! Voxels: conservative mesh voxelization ([`voxelize`]), the sparse voxel octree built from it
//! ([`svo`]), CPU ray traversal with a brute-force DDA reference ([`traverse`]), the
//! level-of-detail traversal that stops at the filtered parents ([`lod_trace`], on the GPU
//! [`lod_gpu`]) and the `svo` pack section ([`section`]).
//!
//! Voxel coordinates: a [`Grid`] maps world space (metres, Z up) to voxel units; voxel (i, j, k)
//! covers `origin + [i, i+1) × voxel_size` on each axis. Voxels are keyed by their 64-bit Morton
//! code (bit 3b = x bit b, 3b+1 = y bit b, 3b+2 = z bit b), so grids up to 2²¹ voxels per axis fit.

pub mod compute;
pub mod geometry;
pub mod gpu;
pub mod instanced;
pub mod instanced_gpu;
pub mod instanced_section;
pub mod lod_gpu;
pub mod lod_trace;
pub mod packed;
pub mod section;
pub mod stage;
pub mod svo;
pub mod traverse;
pub mod voxelize;
pub mod voxelize_shade;

use serde::{Deserialize, Serialize};

/// A regular grid of voxels in world space; the axes may have different voxel counts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    /// World position of the grid's minimum corner.
    pub origin: [f32; 3],
    /// Voxel edge length per axis in metres.
    pub voxel_size: [f32; 3],
    /// Voxels per axis.
    pub dims: [u32; 3],
}

/// Largest voxel count per axis (Morton keys hold 21 bits per axis).
pub const MAX_DIM: u32 = 1 << 21;

impl Grid {
    /// A grid with cubic voxels over the bounds `lo..hi`: the longest axis gets `resolution`
    /// voxels, the others as many as they need (at least one). The bounds are padded by a
    /// hundredth of a voxel so geometry on the maximum faces still falls inside.
    pub fn fit(lo: [f32; 3], hi: [f32; 3], resolution: u32) -> Grid {
        let resolution = resolution.clamp(1, MAX_DIM);
        let ext = [0, 1, 2].map(|k| (hi[k] - lo[k]).max(0.0));
        let longest = ext.iter().cloned().fold(0.0f32, f32::max).max(1e-6);
        let size = longest * 1.0002 / resolution as f32;
        let dims = ext.map(|e| {
            let mut d = (e / size).ceil().max(1.0);
            // Keep a margin of 10⁻⁴ of the extent inside the grid on rounding.
            if d * size < e * 1.0001 {
                d += 1.0;
            }
            (d as u32).clamp(1, resolution)
        });
        let origin = [0, 1, 2].map(|k| {
            let pad = (dims[k] as f32 * size - ext[k]) * 0.5;
            lo[k] - pad
        });
        Grid {
            origin,
            voxel_size: [size; 3],
            dims,
        }
    }

    /// World position to voxel units (voxel (i, j, k) covers [i, i+1) × [j, j+1) × [k, k+1)).
    pub fn to_grid(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| (p[k] - self.origin[k]) / self.voxel_size[k])
    }

    /// Voxel units to world position.
    pub fn to_world(&self, g: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| self.origin[k] + g[k] * self.voxel_size[k])
    }

    /// Number of voxels of the whole grid.
    pub fn cells(&self) -> u64 {
        self.dims.iter().map(|&d| d as u64).product()
    }
}

/// Spreads the low 21 bits of `v` to every third bit.
pub fn part1by2(v: u32) -> u64 {
    let mut x = v as u64 & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// Inverse of [`part1by2`].
pub fn compact1by2(v: u64) -> u32 {
    let mut x = v & 0x1249_2492_4924_9249;
    x = (x | x >> 2) & 0x10c3_0c30_c30c_30c3;
    x = (x | x >> 4) & 0x100f_00f0_0f00_f00f;
    x = (x | x >> 8) & 0x001f_0000_ff00_00ff;
    x = (x | x >> 16) & 0x001f_0000_0000_ffff;
    x = (x | x >> 32) & 0x1f_ffff;
    x as u32
}

/// Morton code of voxel (x, y, z).
pub fn morton_encode(c: [u32; 3]) -> u64 {
    part1by2(c[0]) | part1by2(c[1]) << 1 | part1by2(c[2]) << 2
}

/// Voxel of a Morton code.
pub fn morton_decode(m: u64) -> [u32; 3] {
    [compact1by2(m), compact1by2(m >> 1), compact1by2(m >> 2)]
}

#[cfg(test)]
mod unit_tests {
    use super::*;

    #[test]
    fn morton_round_trip_and_order() {
        for c in [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [5, 77, 1 << 20],
            [2097151; 3],
        ] {
            assert_eq!(morton_decode(morton_encode(c)), c);
        }
        assert_eq!(morton_encode([1, 0, 0]), 1);
        assert_eq!(morton_encode([0, 1, 0]), 2);
        assert_eq!(morton_encode([0, 0, 1]), 4);
        assert_eq!(morton_encode([2, 0, 0]), 8);
    }

    #[test]
    fn grid_fit_is_non_cubic_and_covers_bounds() {
        let g = Grid::fit([0.0, 0.0, 0.0], [4.0, 2.0, 1.0], 64);
        assert_eq!(g.dims[0], 64);
        assert_eq!(g.dims, [64, 32, 16]);
        for k in 0..3 {
            assert!(g.origin[k] <= 0.0);
            let top = g.origin[k] + g.dims[k] as f32 * g.voxel_size[k];
            assert!(top >= [4.0, 2.0, 1.0][k]);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
