//! Terrain horizons (`bake::lightmap::horizon`, issue 37) against independent oracles: the O(n²) maximum over the same profile (the hull
//! sweep), rays through the heightfield quadtree (visibility of the sky and of the sun's disc on
//! an analytic bump and on a rough relief), and closed forms (the sky tables).

use bake::lightmap::horizon::*;
use bake::model::Terrain;
use bake::sh::ShRadiance;
use bake::trace::{Heightfield, Ray, Rng};
use glam::Vec3A;

/// A Gaussian bump of height `amp` and radius `r` (metres) on a tilted plane.
fn bump(n: u32, cell: f32, amp: f32, r: f32) -> Terrain {
    let c = (n - 1) as f32 * cell * 0.5;
    let heights = (0..n * n)
        .map(|k| {
            let (x, y) = ((k % n) as f32 * cell - c, (k / n) as f32 * cell - c);
            amp * (-(x * x + y * y) / (r * r)).exp() + 0.05 * x
        })
        .collect();
    Terrain {
        width: n,
        height: n,
        heights,
        origin: [-c, -c],
        extent: [(n - 1) as f32 * cell; 2],
        color: None,
    }
}

/// A rough relief: value noise at three scales (ridges, valleys, steep small features).
fn relief(n: u32, cell: f32, seed: u64) -> Terrain {
    let mut rng = Rng::hashed(seed);
    let mut octave = |g: u32| -> Vec<f32> { (0..(g + 1) * (g + 1)).map(|_| rng.f32()).collect() };
    let layers = [(4u32, 30.0f32), (16, 8.0), (64, 1.5)];
    let tables: Vec<(u32, f32, Vec<f32>)> =
        layers.iter().map(|&(g, a)| (g, a, octave(g))).collect();
    let heights = (0..n * n)
        .map(|k| {
            let (u, v) = (
                (k % n) as f32 / (n - 1) as f32,
                (k / n) as f32 / (n - 1) as f32,
            );
            tables
                .iter()
                .map(|(g, a, t)| {
                    let (x, y) = (u * *g as f32, v * *g as f32);
                    let (i, j) = ((x as u32).min(g - 1), (y as u32).min(g - 1));
                    let (fx, fy) = (x - i as f32, y - j as f32);
                    let (fx, fy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
                    let at = |i: u32, j: u32| t[(j * (g + 1) + i) as usize];
                    let top = at(i, j) + fx * (at(i + 1, j) - at(i, j));
                    let bot = at(i, j + 1) + fx * (at(i + 1, j + 1) - at(i, j + 1));
                    a * (top + fy * (bot - top))
                })
                .sum()
        })
        .collect();
    Terrain {
        width: n,
        height: n,
        heights,
        origin: [100.0, -40.0],
        extent: [(n - 1) as f32 * cell, (n - 1) as f32 * cell * 1.25],
        color: None,
    }
}

/// The slope ahead of texel (i, j) in lattice direction (a, b) by the O(n²) maximum over the
/// same profile points the sweep uses.
fn brute_slope(t: &Terrain, g: &TexelGrid, (a, b): (i32, i32), i: u32, j: u32) -> f32 {
    let step = [g.extent[0] / g.width as f32, g.extent[1] / g.height as f32];
    let (dx, dy) = (a as f32 * step[0], b as f32 * step[1]);
    let len = (dx as f64).hypot(dy as f64);
    let m = ((dx.abs() / g.cell[0]).max(dy.abs() / g.cell[1]) * (1.0 - 1e-4))
        .ceil()
        .max(1.0) as i64;
    let (x0, y0) = g.xy(i, j);
    let z0 = t.mesh_height_at(x0, y0) as f64;
    let mut best = f64::NEG_INFINITY;
    // Every point of the line ahead at the profile's step, up to the terrain's edge.
    let inside = |x: f32, y: f32| {
        x >= g.origin[0]
            && x <= g.origin[0] + g.extent[0]
            && y >= g.origin[1]
            && y <= g.origin[1] + g.extent[1]
    };
    // The texels of the line ahead, then points between them and beyond the last one.
    let f = NEAR / m as f32;
    let z = t.mesh_height_at(x0 + f * dx, y0 + f * dy) as f64;
    best = best.max((z - z0) / (f as f64 * len));
    let (mut ii, mut jj) = (i as i64, (g.height - 1 - j) as i64);
    let mut k = 0i64;
    loop {
        let (x, y) = g.xy(ii as u32, (g.height as i64 - 1 - jj) as u32);
        let (ni, njj) = (ii + a as i64, jj + b as i64);
        let last = !(0..g.width as i64).contains(&ni) || !(0..g.height as i64).contains(&njj);
        let mut f = 1;
        while (last || f < m) && inside(x + f as f32 / m as f32 * dx, y + f as f32 / m as f32 * dy)
        {
            let ff = f as f32 / m as f32;
            let z = t.mesh_height_at(x + ff * dx, y + ff * dy) as f64;
            best = best.max((z - z0) / ((k as f64 + f as f64 / m as f64) * len));
            f += 1;
        }
        if last {
            break;
        }
        k += 1;
        let (x, y) = g.xy(ni as u32, (g.height as i64 - 1 - njj) as u32);
        let z = t.mesh_height_at(x, y) as f64;
        best = best.max((z - z0) / (k as f64 * len));
        let fnear = NEAR / m as f32;
        let z = t.mesh_height_at(x + fnear * dx, y + fnear * dy) as f64;
        best = best.max((z - z0) / ((k as f64 + fnear as f64) * len));
        (ii, jj) = (ni, njj);
    }
    best as f32
}

#[test]
fn lattice_counts() {
    for (d, n) in [(1, 8), (2, 16), (3, 32), (4, 48)] {
        let v = lattice_vectors(d);
        assert_eq!(v.len(), n);
        assert!(v.len() <= MAX_DIRECTIONS);
    }
}

#[test]
fn sweep_equals_the_quadratic_maximum() {
    // The hull sweep is exact for its profile: against the maximum over every point ahead,
    // on grids of other sizes than the terrain's (finer, coarser, anisotropic), all rows and
    // a band of rows.
    let t = relief(41, 2.0, 3);
    for (w, h) in [(41, 41), (23, 57), (80, 33)] {
        let g = TexelGrid::new(&t, w, h);
        for dir in lattice_vectors(3).into_iter().chain([(7, -3), (-16, 5)]) {
            for rows in [0..h, 5..9] {
                let mut got = vec![f32::NAN; rows.len() * w as usize];
                sweep(&t, &g, dir, rows.clone(), |k, s| got[k] = s);
                for (k, s) in got.iter().enumerate() {
                    let (i, j) = (k as u32 % w, rows.start + k as u32 / w);
                    let want = brute_slope(&t, &g, dir, i, j);
                    let ok = (s.is_infinite() && *s == want)
                        || (s - want).abs() <= 1e-4 * (1.0 + want.abs());
                    assert!(ok, "{w}x{h} {dir:?} texel ({i}, {j}): {s} vs {want}");
                }
            }
        }
    }
}

#[test]
fn banded_sweeps_give_each_bands_own_horizons_bit_for_bit() {
    // Bands taken in order, the southward lines kept live from one band to the next, against
    // each band's own sweep per direction (`sweep`, which walks every line from its far end;
    // stored rounded up to 1/32767 as the module says): the same bits in every direction, the
    // sun's included, for bands of 1 to 9 rows, a sub-range of rows and grids finer, coarser and
    // anisotropic against the terrain. `Horizons::compute` is the one-band case.
    let t = relief(41, 2.0, 3);
    let sun = Vec3A::new(0.5, -0.3, 0.45).normalize().to_array();
    let mut dirs = lattice_vectors(3);
    dirs.extend([(7, -3), (-16, 5)]);
    let stored = |s: f32| {
        ((sin_of_slope(s) * 32767.0).ceil().clamp(-32767.0, 32767.0) as i16) as f32 / 32767.0
    };
    for (w, h) in [(41, 41), (23, 57), (80, 33)] {
        let g = TexelGrid::new(&t, w, h);
        for (range, size) in [(0..h, 1), (0..h, 4), (0..h, 9), (5..h - 3, 7), (0..h, h)] {
            let bands: Vec<_> = (range.start..range.end)
                .step_by(size as usize)
                .map(|s| s..(s + size).min(range.end))
                .collect();
            let mut banded = BandedSweeps::new(&g, &dirs, Some(sun), bands.clone());
            for rows in &bands {
                let got = if bands.len() == 1 {
                    Horizons::compute(&t, &g, &dirs, Some(sun), rows.clone())
                } else {
                    banded.horizons(&t, &g)
                };
                let n = rows.len() * w as usize;
                assert_eq!((got.rows.clone(), got.len()), (rows.clone(), n));
                for (d, &dir) in dirs.iter().enumerate() {
                    let mut want = vec![f32::NAN; n];
                    sweep(&t, &g, dir, rows.clone(), |k, s| want[k] = s);
                    for (k, &s) in want.iter().enumerate() {
                        assert_eq!(
                            got.sin(d, k).to_bits(),
                            stored(s).to_bits(),
                            "{w}x{h} bands of {size} in {range:?}, band {rows:?}, {dir:?}, texel {k}",
                        );
                    }
                }
                let sun_dir = sun_lattice(&g, sun);
                assert_eq!(got.sun_lattice, Some(sun_dir));
                let mut want = vec![f32::NAN; n];
                sweep(&t, &g, sun_dir, rows.clone(), |k, s| want[k] = s);
                let bits = |v: &[f32]| v.iter().map(|s| s.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&got.sun_slope),
                    bits(&want),
                    "{w}x{h} sun, band {rows:?}"
                );
            }
        }
    }
}

#[test]
fn sky_tables_match_closed_forms() {
    // A constant sky L = c: ∫_{s' > s} c (n·d) dω over the whole circle is c·π(1 − s²) n_z,
    // and the x, y parts vanish; a sky L = z (coefficient 2 = √(3/4π) z) gives
    // ∫ z² = 2π(1 − s³)/3 for n = +z.
    let t = bump(9, 1.0, 1.0, 2.0);
    let g = TexelGrid::new(&t, 9, 9);
    let dirs = lattice_vectors(2);
    let y0 = 0.5 / std::f32::consts::PI.sqrt();
    let mut sky = ShRadiance {
        coeffs: [[0.0; 3]; 16],
    };
    sky.coeffs[0] = [1.0 / y0, 2.0 / y0, 0.5 / y0];
    let tables = SkyTables::new(&g, &dirs, &sky);
    for s in [-1.0f32, -0.4, 0.0, 0.3, 0.77, 1.0] {
        for n in [[0.0f32, 0.0, 1.0], [0.6, 0.0, 0.8], [-0.3, 0.5, 0.81]] {
            let e: [f32; 3] = (0..tables.sectors()).fold([0.0; 3], |a, k| {
                let v = tables.integral(k, s, n);
                [a[0] + v[0], a[1] + v[1], a[2] + v[2]]
            });
            let want = std::f32::consts::PI * (1.0 - s * s) * n[2];
            for (c, scale) in [1.0f32, 2.0, 0.5].iter().enumerate() {
                assert!(
                    (e[c] - scale * want).abs() < 2e-4,
                    "s {s} n {n:?}: {e:?} vs {want}"
                );
            }
        }
    }
    let mut z_sky = ShRadiance {
        coeffs: [[0.0; 3]; 16],
    };
    let y1 = (3.0 / (4.0 * std::f32::consts::PI)).sqrt();
    z_sky.coeffs[2] = [1.0 / y1; 3];
    let tables = SkyTables::new(&g, &dirs, &z_sky);
    for s in [-1.0f32, -0.25, 0.5] {
        let e: f32 = (0..tables.sectors())
            .map(|k| tables.integral(k, s, [0.0, 0.0, 1.0])[0])
            .sum();
        let want = 2.0 * std::f32::consts::PI * (1.0 - s * s * s) / 3.0;
        assert!((e - want).abs() < 2e-4, "s {s}: {e} vs {want}");
    }
}

#[test]
fn sectors_partition_the_circle() {
    let t = relief(17, 1.0, 1);
    let g = TexelGrid::new(&t, 30, 17);
    let sky = ShRadiance {
        coeffs: [[0.0; 3]; 16],
    };
    let dirs = lattice_vectors(3);
    let tables = SkyTables::new(&g, &dirs, &sky);
    for (k, &(a, b)) in dirs.iter().enumerate() {
        // Each direction lies in its own sector.
        let p = g.azimuth(a, b);
        assert_eq!(tables.sector_of(p.cos() as f32, p.sin() as f32), k);
    }
    let mut seen = vec![0u32; dirs.len()];
    for i in 0..3600 {
        let p = i as f32 / 3600.0 * std::f32::consts::TAU;
        seen[tables.sector_of(p.cos(), p.sin())] += 1;
    }
    assert!(seen.iter().all(|&c| c > 0), "{seen:?}");
}

/// The fraction of the cosine-weighted sky (L = 1) that the terrain leaves visible at texel
/// (i, j): by the horizons (the tables' closed form, as the light map integrates it) and by a
/// deterministic quadrature of rays through the heightfield (`na` azimuths × `ne` cos²-strata).
fn visibility_pair(
    t: &Terrain,
    hf: &Heightfield,
    g: &TexelGrid,
    tables: &SkyTables,
    hz: &Horizons,
    (i, j): (u32, u32),
) -> (f32, f32) {
    let (x, y) = g.xy(i, j);
    let n = bake::lightmap::height_normal(t, x, y);
    let nv = Vec3A::from(n);
    let k = ((j - hz.rows.start) * g.width + i) as usize;
    let by_horizon: f32 = (0..tables.sectors())
        .map(|s| {
            let e = tables.effective(s, hz.sin(s, k), n);
            tables.integral(s, e, n)[0]
        })
        .sum::<f32>()
        / std::f32::consts::PI;
    let o = Vec3A::new(x, y, t.mesh_height_at(x, y)) + nv * 1e-3;
    let (tx, bx) = bake::trace::frame(nv);
    let (na, ne) = (720u32, 96u32);
    let mut seen = 0u64;
    for a in 0..na {
        for e in 0..ne {
            // Cosine-weighted: u uniform gives sin²θ = u.
            let u = (e as f32 + 0.5) / ne as f32;
            let r = u.sqrt();
            let phi = (a as f32 + 0.5) / na as f32 * std::f32::consts::TAU;
            let d =
                (tx * (r * phi.cos()) + bx * (r * phi.sin()) + nv * (1.0 - u).sqrt()).normalize();
            if !hf.any_hit(&Ray::new(o, d, 1e-4)) {
                seen += 1;
            }
        }
    }
    (by_horizon, seen as f32 / (na * ne) as f32)
}

/// Sky visibility by horizons against rays on a terrain, at sample texels; returns the mean
/// and largest absolute difference (fractions of the unoccluded cosine-weighted sky).
fn visibility_errors(t: &Terrain, w: u32, lattice: u32, texels: &[(u32, u32)]) -> (f32, f32) {
    let hf = Heightfield::new(t).unwrap();
    let g = TexelGrid::new(t, w, w);
    let dirs = lattice_vectors(lattice);
    let y0 = 0.5 / std::f32::consts::PI.sqrt();
    let mut sky = ShRadiance {
        coeffs: [[0.0; 3]; 16],
    };
    sky.coeffs[0] = [1.0 / y0; 3];
    let tables = SkyTables::new(&g, &dirs, &sky);
    let hz = Horizons::compute(t, &g, &dirs, None, 0..w);
    let (mut sum, mut max) = (0.0f32, 0.0f32);
    for &ij in texels {
        let (h, r) = visibility_pair(t, &hf, &g, &tables, &hz, ij);
        sum += (h - r).abs();
        max = max.max((h - r).abs());
    }
    (sum / texels.len() as f32, max)
}

#[test]
fn sky_visibility_on_a_bump_matches_rays() {
    // A 12 m bump of 10 m radius on a gentle slope; texels on its flanks, at its foot and
    // far away. Bound: |V_horizon − V_rays| ≤ 0.02 at every texel with 32 directions (the
    // horizon is constant per sector of ≤ 18°: an error of the order of the horizon's change
    // across a sector), mean ≤ 0.006.
    let t = bump(97, 0.5, 12.0, 10.0);
    let texels: Vec<(u32, u32)> = [
        (48, 30),
        (48, 66),
        (30, 48),
        (60, 60),
        (20, 20),
        (70, 40),
        (5, 90),
        (48, 20),
        (35, 35),
    ]
    .to_vec();
    let (mean, max) = visibility_errors(&t, 97, 3, &texels);
    assert!(max <= 0.02 && mean <= 0.006, "mean {mean}, max {max}");
}

#[test]
fn sky_visibility_on_a_relief_matches_rays() {
    // A rough relief (30 m hills, 8 m valleys, 1.5 m bumps over 128 m): 24 random texels.
    // Bound: ≤ 0.03 at every texel, ≤ 0.01 mean, with 32 directions; with 8 directions the
    // error is larger (the test also shows the convergence in K).
    let t = relief(129, 1.0, 11);
    let mut rng = Rng::hashed(5);
    let texels: Vec<(u32, u32)> = (0..24)
        .map(|_| ((rng.f32() * 128.0) as u32, (rng.f32() * 128.0) as u32))
        .collect();
    let (mean32, max32) = visibility_errors(&t, 129, 3, &texels);
    let (mean8, _) = visibility_errors(&t, 129, 1, &texels);
    assert!(
        max32 <= 0.03 && mean32 <= 0.01,
        "32 dirs: mean {mean32}, max {max32}"
    );
    assert!(mean32 < mean8, "32 dirs {mean32} vs 8 dirs {mean8}");
}

#[test]
fn sun_fraction_matches_disc_rays() {
    // The visible fraction of the sun's disc from the sun sweep against 316 rays over the
    // disc through the heightfield (from 1 mm along the normal, texels facing the sun), for
    // low suns (the disc often straddles a ridge). Bound: the mean difference within 0.015, at
    // most 2 % of the texels off by more than 0.1. Measured: 0.012 and about 1 %: texels on a
    // fold of the drawn triangles (rays blocked within 5 cm, closer than the profile's first
    // point) and discs grazing a ridge (the lattice direction is up to ≈ 0.2° off the sun's
    // azimuth).
    let t = relief(129, 1.0, 11);
    let hf = Heightfield::new(&t).unwrap();
    let g = TexelGrid::new(&t, 129, 129);
    let mut rng = Rng::hashed(9);
    let (mut sum, mut n, mut bad) = (0.0f32, 0, 0);
    for sun in [[0.6f32, 0.35, 0.2], [-0.3, -0.9, 0.12], [0.1, 0.7, 0.7]] {
        let s = Vec3A::from(sun).normalize();
        let hz = Horizons::compute(&t, &g, &[], Some(s.to_array()), 0..129);
        let (tx, bx) = bake::trace::frame(s);
        for _ in 0..200 {
            let (i, j) = ((rng.f32() * 128.0) as u32, (rng.f32() * 128.0) as u32);
            let k = (j * 129 + i) as usize;
            let f = sun_fraction(hz.sun_slope[k], s.to_array());
            let (x, y) = g.xy(i, j);
            // As the light map: only texels facing the sun, rays from 1 mm along the normal.
            let nv = Vec3A::from(bake::lightmap::height_normal(&t, x, y));
            if nv.dot(s) <= 0.0 {
                continue;
            }
            let o = Vec3A::new(x, y, t.mesh_height_at(x, y)) + nv * 1e-3;
            let (mut vis, mut total) = (0u32, 0u32);
            for a in 0..20 {
                for b in 0..20 {
                    let (u, v) = (
                        (a as f32 + 0.5) / 20.0 * 2.0 - 1.0,
                        (b as f32 + 0.5) / 20.0 * 2.0 - 1.0,
                    );
                    if u * u + v * v > 1.0 {
                        continue;
                    }
                    total += 1;
                    let r = bake::lightmap::SUN_RADIUS;
                    let d = (s + tx * (r * u) + bx * (r * v)).normalize();
                    vis += (!hf.any_hit(&Ray::new(o, d, 1e-4))) as u32;
                }
            }
            let want = vis as f32 / total as f32;
            if (f - want).abs() > 0.1 {
                bad += 1;
            }
            sum += f - want;
            n += 1;
        }
    }
    let mean = sum / n as f32;
    assert!(n > 300, "{n} texels facing the sun");
    assert!(
        mean.abs() <= 0.015 && bad * 50 <= n,
        "mean {mean}, {bad} of {n} texels off by more than 0.1"
    );
}

#[test]
fn disc_fraction_limits() {
    assert_eq!(disc_fraction(-1.0, 0.0, 0.1), 1.0);
    assert_eq!(disc_fraction(1.0, 0.0, 0.1), 0.0);
    assert!((disc_fraction(0.3, 0.3, 0.1) - 0.5).abs() < 1e-6);
    // Area above a chord at half the radius: (π/3 − √3/4)/π.
    let want = (std::f32::consts::PI / 3.0 - 3f32.sqrt() / 4.0) / std::f32::consts::PI;
    assert!((disc_fraction(0.05, 0.0, 0.1) - want).abs() < 1e-5);
}

/// The fixture scene's pack (65² terrain with trees and benches, HDR sky and sun).
fn fixture() -> (bake::pack::Pack, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let pack = bake::bench::lightmap::fixture_pack(dir.path()).unwrap();
    (pack, dir)
}

/// The fixture scene, its light, and its terrain map at the reference's 1,024 hemisphere and
/// 64 sun rays (ray visibility): irradiance and direct part.
#[allow(clippy::type_complexity)]
fn fixture_with_reference() -> (
    tempfile::TempDir,
    bake::trace::pack_scene::TraceScene,
    bake::lightmap::BakeLight,
    (Vec<[f32; 3]>, Vec<[f32; 3]>),
) {
    let (pack, dir) = fixture();
    let scene = bake::trace::pack_scene::trace_scene(&pack).unwrap();
    let light = bake::lightmap::scene_lighting(&pack).unwrap();
    let reference = bake::lightmap::LightmapOptions {
        samples: 1024,
        sun_samples: 64,
        visibility: bake::lightmap::LightmapVisibility::Rays,
        ..Default::default()
    };
    let maps = terrain_map(&scene, &light, &reference);
    (dir, scene, light, maps)
}

fn terrain_map(
    scene: &bake::trace::pack_scene::TraceScene,
    light: &bake::lightmap::BakeLight,
    opts: &bake::lightmap::LightmapOptions,
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let (m, d) = bake::lightmap::bake_terrain_lightmap_parts(scene, light, opts)
        .unwrap()
        .unwrap();
    (m.texels, d)
}

/// `f` on a rayon pool of `threads` threads.
fn on_threads<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// The light-map stage's terrain section for `opts`, alone in an in-memory pack.
fn terrain_section_pack(
    scene: &bake::trace::pack_scene::TraceScene,
    light: &bake::lightmap::BakeLight,
    opts: &bake::lightmap::LightmapOptions,
) -> bake::pack::Pack {
    let s = bake::lightmap::terrain_sections(scene, light, opts).unwrap();
    let mut w = bake::pack::PackWriter::new();
    w.insert(s.into_iter().next().unwrap());
    bake::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap()
}

/// RMS over texels and channels of (a − b), and mean of a − b, relative to the mean of b.
fn rms_and_bias(a: &[[f32; 3]], b: &[[f32; 3]]) -> (f64, f64) {
    let n = (a.len() * 3) as f64;
    let mean: f64 = b.iter().flatten().map(|&v| v as f64).sum::<f64>() / n;
    let (mut sq, mut sum) = (0.0, 0.0);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        let d = (*x - *y) as f64;
        sq += d * d;
        sum += d;
    }
    ((sq / n).sqrt() / mean, sum / n / mean)
}

fn indirect(m: &[[f32; 3]], d: &[[f32; 3]]) -> Vec<[f32; 3]> {
    m.iter()
        .zip(d)
        .map(|(e, s)| std::array::from_fn(|c| e[c] - s[c]))
        .collect()
}

#[test]
fn horizon_light_map_matches_the_ray_reference() {
    // The whole terrain light map of the fixture scene (65² texels, trees and benches on a
    // relief): the horizon estimator against the ray estimator at 1,024 hemisphere and 64 sun
    // rays (the reference), beside the ray estimator at the same ray count. Bounds: the
    // horizon map's mean within 1 % of the reference's (total and sky-and-bounce part), its
    // per-texel RMS below the ray estimator's at the same count.
    use bake::lightmap::{LightmapOptions, LightmapVisibility};
    let (pack, _dir) = fixture();
    let scene = bake::trace::pack_scene::trace_scene(&pack).unwrap();
    let light = bake::lightmap::scene_lighting(&pack).unwrap();
    let opts = |samples, sun_samples, visibility| LightmapOptions {
        samples,
        sun_samples,
        visibility,
        trace_step: 1,
        trace_spacing: 0.0,
        ..Default::default()
    };
    let (rm, rd) = terrain_map(&scene, &light, &opts(1024, 64, LightmapVisibility::Rays));
    let r_ind = indirect(&rm, &rd);
    let (hm, hd) = terrain_map(&scene, &light, &opts(16, 4, LightmapVisibility::Horizons));
    let (pm, pd) = terrain_map(&scene, &light, &opts(16, 4, LightmapVisibility::Rays));
    let (h_rms, h_bias) = rms_and_bias(&hm, &rm);
    let (p_rms, p_bias) = rms_and_bias(&pm, &rm);
    let (hi_rms, hi_bias) = rms_and_bias(&indirect(&hm, &hd), &r_ind);
    let (pi_rms, pi_bias) = rms_and_bias(&indirect(&pm, &pd), &r_ind);
    eprintln!(
        "16 rays: horizons total rms {h_rms:.4} bias {h_bias:.4}, indirect rms {hi_rms:.4} bias {hi_bias:.4}; \
         rays total rms {p_rms:.4} bias {p_bias:.4}, indirect rms {pi_rms:.4} bias {pi_bias:.4}"
    );
    assert!(
        h_bias.abs() <= 0.01 && hi_bias.abs() <= 0.01,
        "{h_bias} {hi_bias}"
    );
    assert!(
        hi_rms < pi_rms,
        "indirect: horizons {hi_rms} vs rays {pi_rms}"
    );
    assert!(h_rms < p_rms, "total: horizons {h_rms} vs rays {p_rms}");
}

#[test]
fn horizon_light_map_is_the_same_on_one_and_two_threads_and_in_row_shards() {
    use bake::lightmap::{LightmapOptions, LightmapVisibility};
    let (pack, _dir) = fixture();
    let scene = bake::trace::pack_scene::trace_scene(&pack).unwrap();
    let light = bake::lightmap::scene_lighting(&pack).unwrap();
    let opts = LightmapOptions {
        samples: 8,
        sun_samples: 2,
        visibility: LightmapVisibility::Horizons,
        ..Default::default()
    };
    let run = |threads| on_threads(threads, || terrain_map(&scene, &light, &opts));
    let (one, two) = (run(1), run(2));
    assert!(one == two, "1 and 2 threads differ");
    let mut texels = Vec::new();
    for rows in [0..7, 7..40, 40..65] {
        let (t, _) = bake::lightmap::bake_terrain_lightmap_rows(&scene, &light, &opts, rows)
            .unwrap()
            .unwrap();
        texels.extend(t);
    }
    assert!(texels == two.0, "row shards differ from the whole map");
    // The recomputed direct part (what the renderer strips from packs without `indirect`).
    let meta = bake::lightmap::section::LightmapMeta {
        surface: "terrain".into(),
        width: 65,
        height: 65,
        mode: bake::lightmap::LightmapMode::Physical,
        samples: 8,
        sun_samples: 2,
    };
    let direct =
        bake::lightmap::terrain_direct_sun(&scene, &light, &meta, LightmapVisibility::Horizons);
    assert!(direct == two.1);
}

#[test]
fn the_stage_section_written_band_by_band_holds_the_whole_maps_texels() {
    // The light-map stage writes the horizon estimator's texels straight into its section's
    // `irradiance` and `indirect` arrays (issue 37: the map is not held beside them). Their
    // contents must be the texels of the map baked whole, bit for bit: irradiance as RGBA with
    // A = 1, indirect max(0, E − direct); at every texel (step 1) and at every second (step 2).
    use bake::lightmap::{LightmapOptions, LightmapVisibility};
    let (pack, _dir) = fixture();
    let scene = bake::trace::pack_scene::trace_scene(&pack).unwrap();
    let light = bake::lightmap::scene_lighting(&pack).unwrap();
    for step in [1, 2] {
        let opts = LightmapOptions {
            samples: 8,
            sun_samples: 2,
            visibility: LightmapVisibility::Horizons,
            trace_step: step,
            ..Default::default()
        };
        let (texels, direct) = terrain_map(&scene, &light, &opts);
        let section = terrain_section_pack(&scene, &light, &opts);
        let v = section.view_named("lightmap:terrain").unwrap();
        let irradiance: Vec<[f32; 4]> = v.array_vec("irradiance").unwrap();
        let indirect: Vec<[f32; 4]> = v.array_vec("indirect").unwrap();
        assert_eq!(irradiance.len(), 65 * 65);
        assert_eq!(indirect.len(), 65 * 65);
        let mut lit = 0;
        for (k, (e, d)) in texels.iter().zip(&direct).enumerate() {
            let want_e = [e[0], e[1], e[2], 1.0];
            let want_i = [0, 1, 2, 3].map(|c| if c == 3 { 1.0 } else { (e[c] - d[c]).max(0.0) });
            assert_eq!(
                irradiance[k].map(f32::to_bits),
                want_e.map(f32::to_bits),
                "texel {k}"
            );
            assert_eq!(
                indirect[k].map(f32::to_bits),
                want_i.map(f32::to_bits),
                "texel {k}"
            );
            lit += (d[0] > 0.0) as usize;
        }
        // Not a map of zeros: the fixture's sun lights most texels.
        assert!(
            lit > 65 * 65 / 2,
            "step {step}: {lit} texels lit by the sun"
        );
    }
}

#[test]
fn the_filtered_light_map_is_closer_to_the_reference_and_states_its_filter() {
    // The fixture scene's whole terrain map at 16 hemisphere and 4 sun rays with
    // `lightmap.filter_range = 0.3` (the part without the direct sun bilateral-filtered, 5 × 5)
    // against the same map unfiltered, both against the 1,024-ray reference: the filtered map's
    // per-texel RMS lower by a measured factor, its mean within 1 % of the reference's (the
    // filter's bias). The stage's section holds exactly the filtered texels, states the filter
    // after the prefix every reader reads, and does not depend on the thread count.
    use bake::lightmap::LightmapOptions;
    let (_dir, scene, light, (rm, rd)) = fixture_with_reference();
    let plain = LightmapOptions {
        samples: 16,
        sun_samples: 4,
        trace_step: 1,
        trace_spacing: 0.0,
        ..Default::default()
    };
    let filtered = LightmapOptions {
        filter_range: 0.3,
        filter_radius: 2,
        ..plain
    };
    assert!(filtered.check().is_ok());
    let (pm, pd) = terrain_map(&scene, &light, &plain);
    let section = |o: &LightmapOptions| terrain_section_pack(&scene, &light, o);
    let fp = on_threads(1, || section(&filtered));
    let fp2 = on_threads(2, || section(&filtered));
    let v = fp.view_named("lightmap:terrain").unwrap();
    let (meta, fm) = bake::lightmap::section::from_section(&v).unwrap();
    assert_eq!((meta.width, meta.samples), (65, 16));
    let full: bake::lightmap::section::TerrainLightmapMetaFiltered = v.meta().unwrap();
    assert_eq!((full.filter_radius, full.filter_range), (2, 0.3));
    let summary = bake::lightmap::section::summary(&v).unwrap();
    assert_eq!(summary["filter_radius"], 2);
    assert!((summary["filter_range"].as_f64().unwrap() - 0.3).abs() < 1e-6);
    // An unfiltered map's summary states no filter.
    let up = section(&plain);
    let us = bake::lightmap::section::summary(&up.view_named("lightmap:terrain").unwrap()).unwrap();
    assert!(us.get("filter_range").is_none(), "{us}");
    let want = bake::lightmap::filter::filter_indirect(&pm, &pd, 65, 2, 0.3);
    assert!(
        fm.texels == want,
        "the section holds other texels than the filter's"
    );
    let v2 = fp2.view_named("lightmap:terrain").unwrap();
    assert!(bake::lightmap::section::from_section(&v2).unwrap().1.texels == fm.texels);
    let (p_rms, _) = rms_and_bias(&pm, &rm);
    let (f_rms, f_bias) = rms_and_bias(&fm.texels, &rm);
    let r_ind = indirect(&rm, &rd);
    let (pi_rms, _) = rms_and_bias(&indirect(&pm, &pd), &r_ind);
    let (fi_rms, fi_bias) = rms_and_bias(&indirect(&fm.texels, &pd), &r_ind);
    eprintln!(
        "16 + 4 rays: unfiltered rms {p_rms:.4}, indirect {pi_rms:.4}; filtered rms {f_rms:.4} bias {f_bias:.4}, indirect {fi_rms:.4} bias {fi_bias:.4}"
    );
    assert!(
        fi_rms < 0.85 * pi_rms,
        "indirect: filtered {fi_rms} vs unfiltered {pi_rms}"
    );
    assert!(
        f_rms <= p_rms,
        "total: filtered {f_rms} vs unfiltered {p_rms}"
    );
    assert!(
        f_bias.abs() <= 0.01 && fi_bias.abs() <= 0.01,
        "bias {f_bias} {fi_bias}"
    );
    // Bad options are refused.
    for (range, radius) in [(-0.1, 2), (f32::NAN, 2), (0.3, 9)] {
        let o = LightmapOptions {
            filter_range: range,
            filter_radius: radius,
            ..plain
        };
        assert!(o.check().is_err(), "{range} {radius}");
    }
}

/// The fixture's map traced at `step` (16 + 4 rays; no bound in metres), checked as every
/// stepped map is: 1 and 2 threads and the row shards `shards` give the same bits, the direct
/// sun is the every-texel map's, every traced texel (row and column multiples of `step`, the
/// last ones too) carries the every-texel map's own estimate (equal to f32 rounding); and,
/// against the 1,024-ray reference (ray visibility), its mean within 1 % (total and without the
/// direct sun) and its per-texel RMS below the every-texel map's at the same number of
/// hemisphere rays (16 / step² per texel). Returns the options and the stepped map.
fn stepped_map_checked(
    step: u32,
    shards: &[std::ops::Range<u32>],
) -> (
    bake::lightmap::LightmapOptions,
    bake::lightmap::LightmapOptions,
    Vec<[f32; 3]>,
) {
    use bake::lightmap::LightmapOptions;
    let (_dir, scene, light, (rm, rd)) = fixture_with_reference();
    let plain = LightmapOptions {
        samples: 16,
        sun_samples: 4,
        trace_step: 1,
        trace_spacing: 0.0,
        ..Default::default()
    };
    let stepped = LightmapOptions {
        trace_step: step,
        ..plain
    };
    assert!(stepped.check().is_ok());
    let (pm, pd) = terrain_map(&scene, &light, &plain);
    let run = |threads| on_threads(threads, || terrain_map(&scene, &light, &stepped));
    let ((sm, sd), two) = (run(1), run(2));
    assert!(sm == two.0 && sd == two.1, "1 and 2 threads differ");
    assert!(sd == pd, "the direct sun is per texel in both");
    let mut texels = Vec::new();
    for rows in shards {
        let (t, _) =
            bake::lightmap::bake_terrain_lightmap_rows(&scene, &light, &stepped, rows.clone())
                .unwrap()
                .unwrap();
        texels.extend(t);
    }
    assert!(texels == sm, "row shards differ from the whole map");
    let traced = |k: usize| k.is_multiple_of(step as usize) || k == 64;
    for j in (0..65).filter(|&j| traced(j)) {
        for i in (0..65).filter(|&i| traced(i)) {
            let k = j * 65 + i;
            for c in 0..3 {
                let (a, b) = (sm[k][c], pm[k][c]);
                assert!(
                    (a - b).abs() <= 1e-5 * b.abs().max(1.0),
                    "texel ({i}, {j}): {a} vs {b}"
                );
            }
        }
    }
    let (qm, qd) = terrain_map(
        &scene,
        &light,
        &LightmapOptions {
            samples: 16 / (step * step).min(16),
            ..plain
        },
    );
    let r_ind = indirect(&rm, &rd);
    let (q_rms, _) = rms_and_bias(&qm, &rm);
    let (s_rms, s_bias) = rms_and_bias(&sm, &rm);
    let (qi_rms, _) = rms_and_bias(&indirect(&qm, &qd), &r_ind);
    let (si_rms, si_bias) = rms_and_bias(&indirect(&sm, &sd), &r_ind);
    eprintln!(
        "step {step}: every texel at the same rays: rms {q_rms:.4}, indirect {qi_rms:.4}; \
         stepped: rms {s_rms:.4} bias {s_bias:.4}, indirect {si_rms:.4} bias {si_bias:.4}"
    );
    assert!(
        s_bias.abs() <= 0.01 && si_bias.abs() <= 0.01,
        "bias {s_bias} {si_bias}"
    );
    assert!(
        s_rms < q_rms && si_rms < qi_rms,
        "stepped {s_rms} / {si_rms} vs every texel at the same rays {q_rms} / {qi_rms}"
    );
    (plain, stepped, sm)
}

#[test]
fn the_light_map_traced_at_every_second_texel_keeps_the_reference_and_shards() {
    // `lightmap.trace_step = 2`: the hemisphere rays only at the texels of even row and column
    // (a quarter of them), the others taking the mean of the traced texels around them; the
    // direct sun and the sky above the horizons per texel. The checks of
    // `stepped_map_checked` (row shards with odd and even ends); the section states the step;
    // other estimators ignore it; steps outside 1..=8 are refused.
    use bake::lightmap::{LightmapOptions, LightmapVisibility};
    let (plain, stepped, sm) = stepped_map_checked(2, &[0..7, 7..40, 40..41, 41..65]);
    let (_dir, scene, light, _) = fixture_with_reference();
    let p = terrain_section_pack(&scene, &light, &stepped);
    let v = p.view_named("lightmap:terrain").unwrap();
    let (meta, m) = bake::lightmap::section::from_section(&v).unwrap();
    assert_eq!((meta.width, meta.samples), (65, 16));
    assert!(m.texels == sm);
    let summary = bake::lightmap::section::summary(&v).unwrap();
    assert_eq!(summary["trace_step"], 2, "{summary}");
    assert!(summary.get("filter_range").is_none(), "{summary}");
    let rays = |trace_step| LightmapOptions {
        visibility: LightmapVisibility::Rays,
        samples: 4,
        trace_step,
        ..plain
    };
    assert!(terrain_map(&scene, &light, &rays(2)) == terrain_map(&scene, &light, &rays(1)));
    for step in [0, 9] {
        let o = LightmapOptions {
            trace_step: step,
            ..plain
        };
        assert!(o.check().is_err(), "{o:?}");
    }
}

#[test]
fn the_light_map_traced_at_every_fourth_texel_interpolates_bilinearly_and_shards() {
    // `lightmap.trace_step = 4`: the hemisphere rays at every fourth texel of every fourth row
    // (and the last row and column), a texel between taking the bilinear blend of the traced
    // texels around it unless they disagree beyond their noise. The checks of
    // `stepped_map_checked`, with row shards whose ends fall between traced rows.
    stepped_map_checked(4, &[0..3, 3..9, 9..10, 10..37, 37..64, 64..65]);
}
