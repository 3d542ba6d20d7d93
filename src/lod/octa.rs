//! The hemi-octahedral view mapping of the impostor atlas (docs/CONVENTIONS.md, "Impostors").
//!
//! ```text
//!  tile (0,0) ── horizon ── (N−1,0)     x' = 2u − 1, y' = 2v − 1 (u, v: tile centre in [0,1]²)
//!      │       ╲   ╱          │         a = (x' + y')/2, b = (x' − y')/2
//!   horizon   zenith       horizon      ω = normalize(a, b, 1 − |a| − |b|)   (towards the eye)
//!      │       ╱   ╲          │         the border of the atlas is the horizon (z = 0),
//!  (0,N−1) ── horizon ── (N−1,N−1)      its centre the zenith (looking straight down)
//! ```
//!
//! Each view is orthographic along −ω through the impostor's centre, its square spanning
//! ±radius along `right` and `up` ([`view_axes`]).

use glam::Vec3;

/// The direction towards the eye of the view at hemi-octahedral coordinates (u, v) ∈ [0, 1]².
pub fn direction(u: f32, v: f32) -> Vec3 {
    let x = 2.0 * u - 1.0;
    let y = 2.0 * v - 1.0;
    let a = 0.5 * (x + y);
    let b = 0.5 * (x - y);
    Vec3::new(a, b, 1.0 - a.abs() - b.abs()).normalize()
}

/// The direction of tile (i, j) (column, row from the top) of an N × N grid.
pub fn tile_direction(i: u32, j: u32, n: u32) -> Vec3 {
    direction((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32)
}

/// (u, v) ∈ [0, 1]² of a direction (z clamped to ≥ 0: the lower hemisphere maps to the horizon).
pub fn coordinates(w: Vec3) -> (f32, f32) {
    let w = Vec3::new(w.x, w.y, w.z.max(0.0));
    let l1 = w.x.abs() + w.y.abs() + w.z;
    if l1 <= 0.0 {
        return (0.5, 0.5);
    }
    let (a, b) = (w.x / l1, w.y / l1);
    (0.5 * (a + b + 1.0), 0.5 * (a - b + 1.0))
}

/// The tile (i, j) that shows direction `w` (the tile whose cell holds its coordinates).
pub fn tile_of(w: Vec3, n: u32) -> (u32, u32) {
    let (u, v) = coordinates(w);
    let cell = |t: f32| ((t * n as f32).floor().max(0.0) as u32).min(n - 1);
    (cell(u), cell(v))
}

/// The view's screen axes (right, up) for the direction towards the eye `w` (unit):
/// right = normalize(Z × w), or +X within 10⁻⁶ of ±Z; up = w × right.
pub fn view_axes(w: Vec3) -> (Vec3, Vec3) {
    let c = Vec3::Z.cross(w);
    let right = if c.length() > 1e-6 {
        c.normalize()
    } else {
        Vec3::X
    };
    (right, w.cross(right))
}

/// Depth code of a point at offset `delta` = (centre − x)·w along the view direction.
pub fn depth_code(delta: f32, radius: f32) -> u8 {
    (255.0 * (delta + radius) / (2.0 * radius))
        .round()
        .clamp(0.0, 255.0) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn landmarks_by_hand() {
        assert!((direction(0.5, 0.5) - Vec3::Z).length() < 1e-6);
        // The corners and the edge midpoints are on the horizon.
        assert!((direction(1.0, 0.5) - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-6);
        assert!((direction(1.0, 1.0) - Vec3::X).length() < 1e-6);
        assert!((direction(0.0, 0.0) + Vec3::X).length() < 1e-6);
        assert!((direction(1.0, 0.0) - Vec3::Y).length() < 1e-6);
        assert!((direction(0.0, 1.0) + Vec3::Y).length() < 1e-6);
        // Halfway from the centre to (1, 1): a = 0.5, b = 0, z = 0.5.
        assert!((direction(0.75, 0.75) - Vec3::new(1.0, 0.0, 1.0).normalize()).length() < 1e-6);
    }

    #[test]
    fn inverse_round_trips_and_tiles() {
        let n = 8;
        for j in 0..n {
            for i in 0..n {
                let w = tile_direction(i, j, n);
                assert!(w.z >= 0.0 && (w.length() - 1.0).abs() < 1e-5);
                let (u, v) = coordinates(w);
                assert!((u - (i as f32 + 0.5) / 8.0).abs() < 1e-5);
                assert!((v - (j as f32 + 0.5) / 8.0).abs() < 1e-5);
                assert_eq!(tile_of(w, n), (i, j));
            }
        }
        assert_eq!(tile_of(Vec3::new(0.0, 0.0, -1.0), 8), (4, 4));
        assert_eq!(tile_of(Vec3::X, 8), (7, 7));
    }

    #[test]
    fn axes_are_right_handed_and_upright() {
        let (r, u) = view_axes(Vec3::X);
        assert!((r - Vec3::Y).length() < 1e-6 && (u - Vec3::Z).length() < 1e-6);
        let (r, u) = view_axes(Vec3::Z);
        assert!((r - Vec3::X).length() < 1e-6 && (u - Vec3::Y).length() < 1e-6);
        for k in 0..64 {
            let w = tile_direction(k % 8, k / 8, 8);
            let (r, u) = view_axes(w);
            assert!(r.dot(w).abs() < 1e-5 && u.dot(w).abs() < 1e-5 && r.dot(u).abs() < 1e-5);
            // right × up = w: a right-handed screen with the eye on +w.
            assert!((r.cross(u) - w).length() < 1e-5);
            assert!(u.z >= -1e-6, "up points down in tile {k}");
        }
    }

    #[test]
    fn depth_codes() {
        assert_eq!(depth_code(-2.0, 2.0), 0);
        assert_eq!(depth_code(0.0, 2.0), 128);
        assert_eq!(depth_code(2.0, 2.0), 255);
        assert_eq!(depth_code(9.0, 2.0), 255);
    }
}
