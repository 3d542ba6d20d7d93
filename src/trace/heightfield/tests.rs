//! Heightfield tracing against three oracles: the exhaustive loop over every cell, the
//! triangle-mesh terrain traced by the BVH, and the analytic two-triangle height for vertical
//! rays.

use super::*;
use crate::trace::{BuildPreset, ModelBvh, Rng};

/// A random terrain: rough noise plus a slope, random origin and (anisotropic) extent.
fn terrain(w: u32, h: u32, seed: u64) -> Terrain {
    let mut rng = Rng::hashed(seed);
    let amp = 0.5 + rng.f32() * 20.0;
    let heights = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f32, (k / w) as f32);
            amp * (rng.f32() - 0.5) + 0.3 * x - 0.2 * y + 100.0
        })
        .collect();
    Terrain {
        width: w,
        height: h,
        heights,
        origin: [rng.f32() * 100.0 - 50.0, rng.f32() * 100.0 - 50.0],
        extent: [
            (w - 1) as f32 * (0.5 + rng.f32() * 3.0),
            (h - 1) as f32 * (0.5 + rng.f32() * 3.0),
        ],
        color: None,
    }
}

/// A ray from a random point of the terrain's box (grown by a quarter each side) towards
/// another, so rays come from above, below and the sides.
fn random_ray(t: &Terrain, rng: &mut Rng) -> Ray {
    let (zlo, zhi) = t.height_range();
    let lo = Vec3A::new(t.origin[0], t.origin[1], zlo - 1.0);
    let size = Vec3A::new(t.extent[0], t.extent[1], zhi - zlo + 2.0);
    let mut point = || {
        let f = Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 1.5 - 0.25;
        lo + size * f
    };
    let (a, b) = (point(), point());
    Ray::new(a, (b - a).normalize_or(Vec3A::Z), 0.0)
}

fn same_hit(a: Option<Hit>, b: Option<Hit>, what: &str) {
    match (a, b) {
        (None, None) => {}
        (Some(a), Some(b)) => {
            assert_eq!(a.t, b.t, "{what}: {a:?} vs {b:?}");
            // Equal t on two triangles (a shared edge) is a tie either may win.
            if a.triangle == b.triangle {
                assert_eq!((a.u, a.v), (b.u, b.v), "{what}");
            }
        }
        _ => panic!("{what}: quadtree {a:?} vs reference {b:?}"),
    }
}

/// Grid sizes from a single cell to non-powers of two with ragged quadtree levels.
const SIZES: [(u32, u32); 6] = [(2, 2), (3, 7), (17, 9), (33, 64), (64, 64), (100, 37)];

#[test]
fn closest_and_any_hit_equal_brute_force_on_random_rays() {
    for (s, &(w, h)) in SIZES.iter().enumerate() {
        let t = terrain(w, h, s as u64);
        let hf = Heightfield::new(&t).unwrap();
        let mut rng = Rng::hashed(100 + s as u64);
        let mut hits = 0;
        for _ in 0..1500 {
            let r = random_ray(&t, &mut rng);
            let (a, b) = (hf.closest_hit(&r), hf.brute_force_closest_hit(&r));
            same_hit(a, b, &format!("{w}×{h} {r:?}"));
            assert_eq!(hf.any_hit(&r), b.is_some(), "{w}×{h} {r:?}");
            hits += a.is_some() as u32;
        }
        assert!(hits > 300, "{w}×{h}: too few hits to mean anything: {hits}");
    }
}

#[test]
fn hits_equal_the_triangle_mesh_terrain() {
    // An independent traversal (obvhs' BVH over the renderer's two triangles per cell): the
    // same triangle test on the same vertices must give the same t, bit for bit.
    for (s, &(w, h)) in SIZES.iter().enumerate() {
        let t = terrain(w, h, 20 + s as u64);
        let hf = Heightfield::new(&t).unwrap();
        let mesh = crate::trace::pack_scene::terrain_mesh(&t);
        let bvh = ModelBvh::build(&mesh, &[], BuildPreset::Medium).unwrap();
        let mut rng = Rng::hashed(200 + s as u64);
        for _ in 0..1500 {
            let r = random_ray(&t, &mut rng);
            let (a, b) = (hf.closest_hit(&r), bvh.closest_hit(&r));
            same_hit(a, b, &format!("{w}×{h} {r:?}"));
            let (Some(a), Some(b)) = (a, b) else { continue };
            if a.triangle != b.triangle {
                continue;
            }
            let (sa, sb) = (hf.surface(&a), bvh.surface(&b));
            assert!((sa.position - sb.position).length() < 1e-4);
            assert!((sa.geometric_normal - sb.geometric_normal).length() < 1e-5);
            assert!((sa.shading_normal - sb.shading_normal).length() < 1e-4);
            assert!((sa.uv[0] - sb.uv[0]).abs() < 1e-5 && (sa.uv[1] - sb.uv[1]).abs() < 1e-5);
        }
    }
}

/// The renderer's surface height at grid coordinates (fx, fy) (analytic, per triangle).
fn two_triangle_height(t: &Terrain, fx: f32, fy: f32) -> f32 {
    let (i, j) = (
        (fx.floor() as u32).min(t.width - 2),
        (fy.floor() as u32).min(t.height - 2),
    );
    let (x, y) = (fx - i as f32, fy - j as f32);
    let [h00, h10, h01, h11] = [
        t.sample(i, j),
        t.sample(i + 1, j),
        t.sample(i, j + 1),
        t.sample(i + 1, j + 1),
    ];
    if x >= y {
        h00 + x * (h10 - h00) + y * (h11 - h10)
    } else {
        h00 + y * (h01 - h00) + x * (h11 - h01)
    }
}

#[test]
fn vertical_rays_from_above_and_below_hit_the_two_triangle_surface() {
    let t = terrain(40, 23, 3);
    let hf = Heightfield::new(&t).unwrap();
    let (zlo, zhi) = t.height_range();
    let mut rng = Rng::hashed(4);
    for _ in 0..2000 {
        let (fx, fy) = (rng.f32() * 39.0, rng.f32() * 22.0);
        let x = t.origin[0] + fx * t.extent[0] / 39.0;
        let y = t.origin[1] + fy * t.extent[1] / 22.0;
        let z = two_triangle_height(&t, fx, fy);
        let tol = 1e-3 * (1.0 + z.abs());
        // The light map's sample height (`Terrain::mesh_height_at`) is this surface.
        assert!((t.mesh_height_at(x, y) - z).abs() < tol);
        for (oz, dz) in [(zhi + 5.0, -1.0), (zlo - 5.0, 1.0)] {
            let r = Ray::new(Vec3A::new(x, y, oz), Vec3A::new(0.0, 0.0, dz), 0.0);
            let h = hf
                .closest_hit(&r)
                .expect("a vertical ray over the grid hits it");
            let p = hf.hit_point(&h);
            assert!((p.position.z - z).abs() < tol, "{} vs {z}", p.position.z);
            assert!((r.at(h.t).z - z).abs() < tol);
            assert!((p.grid[0] - fx).abs() < 1e-3 && (p.grid[1] - fy).abs() < 1e-3);
            assert_eq!(p.cell, [fx as u32, fy as u32]);
            assert!(p.normal.z > 0.0 && (p.normal.length() - 1.0).abs() < 1e-5);
            // The segment that stops short of the surface misses it.
            let short = Ray {
                tmax: h.t * 0.999 - 1e-3,
                ..r
            };
            assert!(hf.closest_hit(&short).is_none() && !hf.any_hit(&short));
        }
    }
}

#[test]
fn grazing_rays_along_grid_lines_and_diagonals_equal_brute_force() {
    let t = terrain(31, 29, 9);
    let hf = Heightfield::new(&t).unwrap();
    let (sx, sy) = (t.extent[0] / 30.0, t.extent[1] / 28.0);
    let mut rng = Rng::hashed(10);
    let mut hits = 0;
    for _ in 0..3000 {
        let (i, j) = ((rng.f32() * 30.0) as u32, (rng.f32() * 28.0) as u32);
        let p = Vec3A::from(t.position(i, j));
        // Along a row, a column, a cell diagonal or its mirror: rays through vertices and edges.
        let dirs = [
            Vec3A::new(sx, 0.0, 0.0),
            Vec3A::new(0.0, sy, 0.0),
            Vec3A::new(sx, sy, 0.0),
            Vec3A::new(-sx, sy, 0.0),
        ];
        let d = dirs[(rng.next_u64() % 4) as usize];
        // Nearly horizontal, just above, on or just below the sample.
        let dz = (rng.f32() - 0.5) * 1e-3;
        let lift = [1e-4, 0.0, -1e-4][(rng.next_u64() % 3) as usize];
        let r = Ray::new(p + Vec3A::Z * lift, (d + Vec3A::Z * dz).normalize(), 0.0);
        let back = Ray::new(r.origin, -r.dir, 0.0);
        for r in [r, back] {
            let b = hf.brute_force_closest_hit(&r);
            same_hit(hf.closest_hit(&r), b, &format!("{r:?}"));
            assert_eq!(hf.any_hit(&r), b.is_some(), "{r:?}");
            hits += b.is_some() as u32;
        }
    }
    assert!(hits > 1000, "{hits}");
    // Exactly horizontal over a flat terrain at its own height: the ray lies in the surface
    // (every triangle test degenerates); no hit, no panic, both agree.
    let flat = Terrain {
        heights: vec![5.0; (31 * 29) as usize],
        ..t
    };
    let hf = Heightfield::new(&flat).unwrap();
    let r = Ray::new(Vec3A::new(0.3, 0.7, 5.0), Vec3A::X, 0.0);
    assert_eq!(hf.closest_hit(&r), hf.brute_force_closest_hit(&r));
    assert_eq!(hf.any_hit(&r), hf.closest_hit(&r).is_some());
}

#[test]
fn rays_starting_on_the_surface() {
    let t = terrain(50, 50, 12);
    let hf = Heightfield::new(&t).unwrap();
    let mut rng = Rng::hashed(13);
    let mut away_hits = 0;
    for _ in 0..2000 {
        let (fx, fy) = (rng.f32() * 49.0, rng.f32() * 49.0);
        let o = Vec3A::new(
            t.origin[0] + fx * t.extent[0] / 49.0,
            t.origin[1] + fy * t.extent[1] / 49.0,
            two_triangle_height(&t, fx, fy),
        );
        let d =
            Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5).normalize_or(Vec3A::Z);
        for tmin in [0.0, 1e-3] {
            let r = Ray::new(o, d, tmin);
            let b = hf.brute_force_closest_hit(&r);
            same_hit(hf.closest_hit(&r), b, &format!("{r:?}"));
            assert_eq!(hf.any_hit(&r), b.is_some());
            if tmin > 0.0 && b.is_some() {
                away_hits += 1;
            }
        }
        // Into the ground from just above: the surface it starts on is hit at once.
        let lift = 1e-4 * (1.0 + o.z.abs());
        let r = Ray::new(o + Vec3A::Z * lift, Vec3A::NEG_Z, 0.0);
        let h = hf.closest_hit(&r).expect("a ray into the ground hits it");
        assert!(h.t < 1e-3 * (1.0 + o.z.abs()), "{h:?}");
    }
    // The terrain is rough: some rays leaving it meet another hill.
    assert!(away_hits > 50, "{away_hits}");
}

#[test]
fn batched_queries_match_single_queries() {
    let t = terrain(64, 40, 5);
    let hf = Heightfield::new(&t).unwrap();
    let mut rng = Rng::hashed(6);
    let rays: Vec<Ray> = (0..500).map(|_| random_ray(&t, &mut rng)).collect();
    let single: Vec<_> = rays.iter().map(|r| hf.closest_hit(r)).collect();
    assert_eq!(hf.closest_hits(&rays), single);
    let any: Vec<_> = rays.iter().map(|r| hf.any_hit(r)).collect();
    assert_eq!(hf.any_hits(&rays), any);
}

#[test]
fn stored_quadtree_is_used_and_a_mismatched_one_rebuilt() {
    let t = terrain(20, 12, 7);
    let own = Heightfield::new(&t).unwrap();
    let tree = MinMaxQuadtree::build(&t.heights, 20, 12);
    let stored = Heightfield::with_quadtree(&t, tree).unwrap();
    let other = MinMaxQuadtree::build(&[0.0; 4], 2, 2);
    let rebuilt = Heightfield::with_quadtree(&t, other).unwrap();
    let mut rng = Rng::hashed(8);
    for _ in 0..300 {
        let r = random_ray(&t, &mut rng);
        assert_eq!(stored.closest_hit(&r), own.closest_hit(&r));
        assert_eq!(rebuilt.closest_hit(&r), own.closest_hit(&r));
    }
}

#[test]
fn unusable_terrains_are_rejected() {
    let t = terrain(4, 4, 1);
    let line = Terrain {
        width: 1,
        height: 16,
        ..t.clone()
    };
    assert!(Heightfield::new(&line).is_err());
    let mut nan = t.clone();
    nan.heights[5] = f32::NAN;
    let e = Heightfield::new(&nan).unwrap_err().to_string();
    assert!(e.contains("(1, 1)"), "{e}");
    let flat = Terrain {
        extent: [0.0, 3.0],
        ..t.clone()
    };
    assert!(Heightfield::new(&flat).is_err());
    let short = Terrain {
        heights: vec![0.0; 3],
        ..t
    };
    assert!(Heightfield::new(&short).is_err());
}
