//! Atlas light maps of placed meshes against analytic answers: an open-sky plane, the sun's
//! penumbra under a disc, bilinear lookups at every triangle's corners, edges and interior (no
//! gutter reads black), determinism across thread counts, and the section round trip.

use bake::lightmap::atlas::{AtlasOptions, rasterize};
use bake::lightmap::objects::{AtlasLightmap, PlacedMesh, bake_object_lightmap};
use bake::lightmap::{BakeLight, LightmapMode, LightmapOptions, SUN_RADIUS};
use bake::model::{Material, Mesh};
use bake::sh::ShRadiance;
use bake::trace::InstanceTransform;
use glam::Vec3A;
use std::f32::consts::PI;

mod common;
use common::{lens_area, linear_sky, place, scene_bvh as scene};

fn finish(mut m: Mesh) -> Mesh {
    m.uvs = vec![[0.0; 2]; m.positions.len()];
    m.triangle_materials = vec![0; m.indices.len()];
    m.materials = vec![Material::default()];
    m
}

/// A square of side `size` in z = 0 centred at the origin, `n`×`n` quads on shared vertices.
fn grid_plane(size: f32, n: u32) -> Mesh {
    let mut m = Mesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32 - 0.5, j as f32 / n as f32 - 0.5);
            m.positions.push([x * size, y * size, 0.0]);
            m.normals.push([0.0, 0.0, 1.0]);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            m.indices.push([a, a + 1, a + n + 2]);
            m.indices.push([a, a + n + 2, a + n + 1]);
        }
    }
    finish(m)
}

/// A disc of radius r in z = 0 (a triangle fan).
fn disc(r: f32, segments: u32) -> Mesh {
    let mut m = Mesh {
        positions: vec![[0.0; 3]],
        ..Default::default()
    };
    for k in 0..segments {
        let a = k as f32 / segments as f32 * 2.0 * PI;
        m.positions.push([r * a.cos(), r * a.sin(), 0.0]);
    }
    m.indices = (0..segments)
        .map(|k| [0, 1 + k, 1 + (k + 1) % segments])
        .collect();
    m.normals = vec![[0.0, 0.0, 1.0]; m.positions.len()];
    finish(m)
}

/// A unit cube with its own 4 vertices per side (flat normals), like the 3DS boxes.
fn cube() -> Mesh {
    let corner = |i: u32| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32];
    let sides: [([u32; 4], [f32; 3]); 6] = [
        ([0, 2, 3, 1], [0.0, 0.0, -1.0]),
        ([4, 5, 7, 6], [0.0, 0.0, 1.0]),
        ([0, 1, 5, 4], [0.0, -1.0, 0.0]),
        ([2, 6, 7, 3], [0.0, 1.0, 0.0]),
        ([0, 4, 6, 2], [-1.0, 0.0, 0.0]),
        ([1, 3, 7, 5], [1.0, 0.0, 0.0]),
    ];
    let mut m = Mesh::default();
    for (s, n) in sides {
        let b = m.positions.len() as u32;
        for c in s {
            m.positions.push(corner(c));
            m.normals.push(n);
        }
        m.indices.push([b, b + 1, b + 2]);
        m.indices.push([b, b + 2, b + 3]);
    }
    finish(m)
}

/// A UV sphere on shared vertices with smooth normals (charts must split its vertices).
fn sphere(nu: u32, nv: u32) -> Mesh {
    let mut m = Mesh::default();
    for j in 0..=nv {
        let th = PI * j as f32 / nv as f32;
        for i in 0..nu {
            let ph = 2.0 * PI * i as f32 / nu as f32;
            let p = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
            m.positions.push(p);
            m.normals.push(p);
        }
    }
    for j in 0..nv {
        for i in 0..nu {
            let (a, b) = (j * nu + i, j * nu + (i + 1) % nu);
            let (c, d) = (a + nu, b + nu);
            if j > 0 {
                m.indices.push([a, c, b]);
            }
            if j + 1 < nv {
                m.indices.push([b, c, d]);
            }
        }
    }
    finish(m)
}

/// World position of every covered texel of tile slot `s` (from the G-buffer).
fn covered_positions(
    mesh: &Mesh,
    map: &AtlasLightmap,
    tr: &InstanceTransform,
    s: usize,
) -> Vec<(Vec3A, [f32; 3])> {
    let g = rasterize(mesh, &map.layout);
    let tile = map.layout.tile;
    let (x0, y0) = (
        (s as u32 % map.columns) * tile,
        (s as u32 / map.columns) * tile,
    );
    g.iter()
        .enumerate()
        .filter_map(|(k, t)| {
            let t = t.as_ref()?;
            let (x, y) = (k as u32 % tile + x0, k as u32 / tile + y0);
            Some((
                tr.point_to_world(t.position),
                map.texels[(y * map.width + x) as usize],
            ))
        })
        .collect()
}

#[test]
fn open_sky_plane_atlas_gets_the_analytic_irradiance() {
    // E = πa + 2πb/3 + E_s·cos θ_s on every covered texel, on both instances' tiles.
    let plane = grid_plane(2.0, 4);
    let inst = vec![
        place(0, [0.0, 0.0, 5.0], 30.0),
        place(0, [10.0, 3.0, 1.0], 200.0),
    ];
    let bvh = scene(&[&plane], inst.clone());
    let (a, b) = (0.7, 0.4);
    let s = Vec3A::new(0.3, 0.2, 0.9).normalize();
    let light = BakeLight {
        sky: linear_sky(a, b),
        sun: Some((s.to_array(), [100.0, 90.0, 80.0])),
    };
    let expect = |k: usize| PI * a + 2.0 * PI * b / 3.0 + [100.0, 90.0, 80.0][k] * s.z;
    for mode in [LightmapMode::Physical, LightmapMode::Thesis] {
        let opts = LightmapOptions {
            samples: 256,
            sun_samples: 8,
            mode,
            ..Default::default()
        };
        let p = PlacedMesh {
            mesh: &plane,
            instances: &[0, 1],
        };
        let map = bake_object_lightmap(&bvh, &[[0.5; 3]; 2], &light, p, 1, &opts).unwrap();
        assert_eq!(map.layout.charts.len(), 1, "a flat grid is one chart");
        let mut n = 0;
        for (slot, tr) in inst.iter().enumerate() {
            for (_, e) in covered_positions(&plane, &map, tr, slot) {
                for k in 0..3 {
                    assert!(
                        (e[k] - expect(k)).abs() < 0.01 * expect(k),
                        "{mode:?}: {e:?} vs {}",
                        expect(k)
                    );
                }
                n += 1;
            }
        }
        assert_eq!(n as u64, map.covered);
        assert!(n > 500, "{n} texels covered");
        // Without the direct sun (the renderer's ambient part): the sky's πa + 2πb/3 alone.
        let sky = PI * a + 2.0 * PI * b / 3.0;
        for (i, _) in map.coverage.iter().enumerate().filter(|(_, c)| **c == 1) {
            let e = map.indirect[i];
            assert!(
                e.iter().all(|&v| (v - sky).abs() < 0.01 * sky),
                "{mode:?}: indirect {e:?} vs {sky}"
            );
        }
    }
}

#[test]
fn plane_under_an_opaque_disc_gets_the_analytic_shadow_and_penumbra() {
    // Sun overhead, disc of radius R at height h: the visible fraction of the sun's disc
    // (angular radius SUN_RADIUS, projected radius a = h·tan) at distance ρ from the axis is
    // 1 − lens(ρ; a, R)/(π a²). Penumbra width 2a ≈ 0.19 m, resolved by ~20 texels.
    let (radius, h) = (0.5f32, 20.0f32);
    let plane = grid_plane(2.0, 8);
    let occluder = disc(radius, 256);
    let inst = vec![place(0, [0.0; 3], 0.0), place(1, [0.0, 0.0, h], 0.0)];
    let bvh = scene(&[&plane, &occluder], inst.clone());
    let light = BakeLight {
        sky: ShRadiance::default(),
        sun: Some(([0.0, 0.0, 1.0], [1000.0; 3])),
    };
    let opts = LightmapOptions {
        samples: 1,
        sun_samples: 256,
        atlas: AtlasOptions {
            tile: 256,
            ..Default::default()
        },
        ..Default::default()
    };
    let map = bake_object_lightmap(
        &bvh,
        &[[0.0; 3]; 2],
        &light,
        PlacedMesh {
            mesh: &plane,
            instances: &[0],
        },
        3,
        &opts,
    )
    .unwrap();
    let a = (h * SUN_RADIUS.tan()) as f64;
    let (mut umbra, mut penumbra, mut lit) = (0, 0, 0);
    for (p, e) in covered_positions(&plane, &map, &inst[0], 0) {
        let rho = (p.x as f64).hypot(p.y as f64);
        let want = 1.0 - lens_area(rho, a, radius as f64) / (std::f64::consts::PI * a * a);
        let vis = e[0] as f64 / 1000.0;
        assert!(
            (vis - want).abs() < 0.04,
            "ρ = {rho:.3}: visible {vis:.3}, analytic {want:.3}"
        );
        match want {
            w if w < 0.01 => umbra += 1,
            w if w > 0.99 => lit += 1,
            _ => penumbra += 1,
        }
    }
    assert!(
        umbra > 100 && penumbra > 100 && lit > 100,
        "{umbra} {penumbra} {lit}"
    );
}

/// Barycentric test points of a triangle: corners, points on the edges, interior points.
fn test_points() -> Vec<[f32; 3]> {
    let mut pts = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for k in 1..8 {
        let t = k as f32 / 8.0;
        pts.extend([[t, 1.0 - t, 0.0], [0.0, t, 1.0 - t], [1.0 - t, 0.0, t]]);
    }
    let mut x = 0x9E37_79B9u32;
    for _ in 0..24 {
        let mut r = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as f32 / u32::MAX as f32
        };
        let (u, v) = (r(), r());
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        pts.push([1.0 - u - v, u, v]);
    }
    pts
}

/// Samples the atlas bilinearly at test points of every triangle of every tile; `want` is the
/// analytic irradiance at the point's normal. Returns the worst ratio sample / analytic.
fn worst_ratio(
    mesh: &Mesh,
    map: &AtlasLightmap,
    tr: &[InstanceTransform],
    want: impl Fn(Vec3A) -> f32,
) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
    for (s, tr) in tr.iter().enumerate() {
        for (t, tri) in mesh.indices.iter().enumerate() {
            for l in test_points() {
                let n = tri.iter().zip(l).fold(Vec3A::ZERO, |a, (&v, w)| {
                    a + Vec3A::from(mesh.normals[v as usize]) * w
                });
                let n = tr.normal_to_world(n.normalize());
                let e = map.sample(map.triangle_uv(s, t, l));
                let r = e[0] / want(n);
                lo = lo.min(r);
                hi = hi.max(r);
            }
        }
    }
    (lo, hi)
}

#[test]
fn no_bilinear_lookup_inside_a_triangle_reads_a_black_gutter() {
    // Constant sky L (over the whole sphere) and a sun: a convex object sees the sky over its
    // whole hemisphere, so E = πL + E_s·max(0, n·s) everywhere. Every lookup at a corner, an edge
    // or inside a triangle must read that (the cube exactly: its gutters copy its own face), never
    // the black between charts.
    let s = Vec3A::new(0.4, -0.3, 0.8).normalize();
    let (l, es) = (1.0f32, 10.0f32);
    let light = BakeLight {
        sky: linear_sky(l, 0.0),
        sun: Some((s.to_array(), [es; 3])),
    };
    let want = |n: Vec3A| PI * l + es * n.dot(s).max(0.0);
    let opts = LightmapOptions {
        samples: 128,
        sun_samples: 4,
        atlas: AtlasOptions {
            tile: 32,
            ..Default::default()
        },
        ..Default::default()
    };
    let (box_mesh, ball) = (cube(), sphere(24, 12));
    let inst = vec![
        place(0, [0.0; 3], 0.0),
        place(0, [5.0, 0.0, 0.0], 45.0),
        place(1, [0.0, 8.0, 0.0], 10.0),
        place(1, [8.0, 8.0, 0.0], 100.0),
    ];
    let bvh = scene(&[&box_mesh, &ball], inst.clone());
    let albedo = [[0.5; 3]; 4];
    let cube_map = bake_object_lightmap(
        &bvh,
        &albedo,
        &light,
        PlacedMesh {
            mesh: &box_mesh,
            instances: &[0, 1],
        },
        5,
        &opts,
    )
    .unwrap();
    assert_eq!(cube_map.layout.charts.len(), 6);
    let (lo, hi) = worst_ratio(&box_mesh, &cube_map, &inst[..2], want);
    assert!(
        lo > 0.97 && hi < 1.03,
        "cube: sample/analytic in [{lo}, {hi}]"
    );
    // The sphere (many charts, split vertices) under the sky alone: its facets tilt against its
    // smooth normals by up to ~8°, so a few hemisphere rays hit the neighbouring facets (and sun
    // rays near the terminator would too, hence no sun); a black texel in a lookup would pull
    // the ratio towards 0.
    let sky_only = BakeLight { sun: None, ..light };
    let ball_map = bake_object_lightmap(
        &bvh,
        &albedo,
        &sky_only,
        PlacedMesh {
            mesh: &ball,
            instances: &[2, 3],
        },
        6,
        &opts,
    )
    .unwrap();
    assert!(ball_map.layout.charts.len() > 6);
    assert!(
        ball_map.layout.uv.len() > ball.positions.len(),
        "chart borders split vertices"
    );
    let (lo, hi) = worst_ratio(&ball, &ball_map, &inst[2..], |_| PI * l);
    eprintln!(
        "sphere: {} charts, tile {}, ratio [{lo}, {hi}]",
        ball_map.layout.charts.len(),
        ball_map.layout.tile
    );
    assert!(
        lo > 0.9 && hi < 1.02,
        "sphere: sample/analytic in [{lo}, {hi}]"
    );
}

#[test]
fn atlas_bake_is_identical_across_thread_counts() {
    let ball = sphere(16, 8);
    let ground = grid_plane(10.0, 2);
    let inst = vec![
        place(0, [0.0, 0.0, 1.2], 0.0),
        place(1, [0.0; 3], 0.0),
        place(0, [3.0, 0.0, 1.0], 50.0),
    ];
    let bvh = scene(&[&ball, &ground], inst);
    let light = BakeLight {
        sky: linear_sky(0.5, 0.3),
        sun: Some((Vec3A::new(0.3, 0.1, 0.9).normalize().to_array(), [50.0; 3])),
    };
    let opts = LightmapOptions {
        samples: 16,
        sun_samples: 4,
        atlas: AtlasOptions {
            tile: 32,
            ..Default::default()
        },
        ..Default::default()
    };
    let bake = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            bake_object_lightmap(
                &bvh,
                &[[0.4; 3]; 3],
                &light,
                PlacedMesh {
                    mesh: &ball,
                    instances: &[0, 2],
                },
                9,
                &opts,
            )
            .unwrap()
        })
    };
    let (one, three) = (bake(1), bake(3));
    let bits = |m: &AtlasLightmap| {
        m.texels
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&three));
    assert_eq!(one.layout, three.layout);
    // The ground shadows the sphere's lower half and the sphere bounces light: not all equal.
    assert!(one.texels.iter().any(|t| t[0] != one.texels[0][0]));
}

#[test]
fn atlas_section_round_trips_and_rejects_inconsistent_arrays() {
    use bake::lightmap::atlas_section::{AtlasMeta, from_section, to_section};
    use bake::pack::section::SectionView;
    let m = cube();
    let bvh = scene(&[&m], vec![place(0, [0.0; 3], 0.0); 3]);
    let light = BakeLight {
        sky: linear_sky(1.0, 0.0),
        sun: None,
    };
    let opts = LightmapOptions {
        samples: 4,
        atlas: AtlasOptions {
            tile: 16,
            ..Default::default()
        },
        ..Default::default()
    };
    let map = bake_object_lightmap(
        &bvh,
        &[[0.5; 3]; 3],
        &light,
        PlacedMesh {
            mesh: &m,
            instances: &[0, 1, 2],
        },
        0,
        &opts,
    )
    .unwrap();
    assert_eq!(
        (map.columns, map.width, map.height),
        (2, 2 * map.layout.tile, 2 * map.layout.tile)
    );
    let meta = AtlasMeta {
        surface: "mesh:cube".into(),
        mesh_vertices: m.positions.len() as u32,
        instances: map.instances.clone(),
        tile: map.layout.tile,
        columns: map.columns,
        width: map.width,
        height: map.height,
        gutter: map.layout.gutter,
        density: map.layout.density,
        texels_covered: map.covered,
        gutter_texels: map.gutter_texels,
        mode: LightmapMode::Physical,
        samples: 4,
        sun_samples: 16,
    };
    let sec = to_section("lightmap:mesh:cube", &meta, &map);
    let v = SectionView::parse(&sec.payload, 0).unwrap();
    let (meta2, map2) = from_section(&v).unwrap();
    assert_eq!((meta2, &map2), (meta.clone(), &map));
    // Generic readers: the metadata decodes as the terrain's LightmapMeta, and `lightmap_uv`
    // holds atlas UVs per instance and mesh vertex (the cube's vertices are not split).
    let generic: bake::lightmap::section::LightmapMeta = v.meta().unwrap();
    assert_eq!(
        (generic.surface.as_str(), generic.width, generic.height),
        ("mesh:cube", map.width, map.height)
    );
    let uv: Vec<[f32; 2]> = v.array_vec("lightmap_uv").unwrap();
    assert_eq!(uv.len(), 3 * m.positions.len());
    for s in 0..3 {
        for (t, tri) in m.indices.iter().enumerate() {
            for (k, &vtx) in tri.iter().enumerate() {
                let mut l = [0.0; 3];
                l[k] = 1.0;
                let want = map.triangle_uv(s, t, l);
                let got = uv[s * m.positions.len() + vtx as usize];
                assert!((got[0] - want[0]).abs() < 1e-6 && (got[1] - want[1]).abs() < 1e-6);
            }
        }
    }
    let js = bake::lightmap::section::summary(&v).unwrap();
    assert_eq!(js["charts"], 6);
    assert_eq!(js["texels_covered"], map.covered);
    // Every covered texel sees the whole sky: mean πL over covered texels.
    let mean = js["mean_irradiance"][0].as_f64().unwrap();
    assert!((mean - std::f64::consts::PI).abs() < 0.02, "{mean}");
    // A meta promising a bigger atlas than the arrays hold is an error, not a panic.
    let bad = AtlasMeta {
        height: meta.height * 2,
        ..meta.clone()
    };
    let sec = to_section("x", &bad, &map);
    assert!(from_section(&SectionView::parse(&sec.payload, 0).unwrap()).is_err());
    let bad = AtlasMeta {
        mesh_vertices: 20,
        ..meta.clone()
    };
    let sec = to_section("x", &bad, &map);
    assert!(from_section(&SectionView::parse(&sec.payload, 0).unwrap()).is_err());
    let bad = AtlasMeta { columns: 0, ..meta };
    let sec = to_section("x", &bad, &map);
    assert!(from_section(&SectionView::parse(&sec.payload, 0).unwrap()).is_err());
}

#[test]
fn fixture_scene_bakes_an_atlas_for_its_objects_but_not_its_plants() {
    // 12 benches (≤ 16 instances) get one atlas with 12 tiles; the 88 plants get none. The seat's
    // top (n = +z, mostly sunlit) must be far brighter than its underside (n = −z, facing the
    // ground): E_top ≥ ½·E_sun·cos θ_s, E_bottom < ½·E_top.
    use bake::ingest::instances_section as instances;
    use bake::lightmap::atlas_section::{KIND, from_section, is_atlas};
    let dir = tempfile::tempdir().unwrap();
    let pack = bake::bench::lightmap::fixture_pack(dir.path()).unwrap();
    let opts = LightmapOptions {
        samples: 16,
        sun_samples: 4,
        ..Default::default()
    };
    // The registered `atlas` unit over the pack, as `bake lightmap` runs it.
    let p = bake::graph::Pipeline {
        lightmap: opts,
        ..Default::default()
    };
    let candidates = bake::graph::stage::pack_sections(&pack, "atlas").unwrap();
    let sections =
        bake::graph::stage::pack_unit("atlas", pack.path(), &candidates, &p, None, None, &|_| {})
            .unwrap()
            .sections;
    let atlases: Vec<_> = sections.iter().filter(|s| s.kind == KIND).collect();
    assert_eq!(atlases.len(), sections.len());
    assert_eq!(atlases.len(), 1);
    let v = bake::pack::section::SectionView::parse(&atlases[0].payload, 0).unwrap();
    assert!(is_atlas(&v));
    let (meta, map) = from_section(&v).unwrap();
    assert_eq!(atlases[0].name, format!("lightmap:{}", meta.surface));
    let (imeta, inst) = instances::from_section(&pack.view_named("instances").unwrap()).unwrap();
    assert_eq!(meta.instances.len(), 12);
    let model = inst.items[meta.instances[0] as usize].model as usize;
    assert!(imeta.mesh_sections[model].contains("object.3ds"));
    assert!(
        meta.instances
            .iter()
            .all(|&i| inst.items[i as usize].model as usize == model)
    );
    let (_, mesh) =
        bake::mesh::section::from_section(&pack.view_named(&meta.surface).unwrap()).unwrap();
    assert_eq!(meta.mesh_vertices as usize, mesh.positions.len());
    let light = bake::lightmap::scene_lighting(&pack).unwrap();
    let (s, e_sun) = light.sun.unwrap();
    let (mut top, mut bottom) = (Vec::new(), Vec::new());
    for slot in 0..meta.instances.len() {
        for (t, tri) in mesh.indices.iter().enumerate() {
            let [a, b, c] = tri.map(|i| Vec3A::from(mesh.positions[i as usize]));
            let n = (b - a).cross(c - a).normalize();
            if a.z.min(b.z).min(c.z) < 0.39 {
                continue;
            }
            let e = map.sample(map.triangle_uv(slot, t, [1.0 / 3.0; 3]))[1];
            // The seat's top is at z = 0.45, its underside at 0.40 (the legs' tops at 0.40
            // touch it and are dark, so they are left out).
            if n.z > 0.99 && a.z > 0.44 {
                top.push(e);
            } else if n.z < -0.99 {
                bottom.push(e);
            }
        }
    }
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
    let (et, eb) = (mean(&top), mean(&bottom));
    assert!(!top.is_empty() && !bottom.is_empty());
    assert!(
        et > 0.5 * e_sun[1] * s[2],
        "top {et}, sun {}",
        e_sun[1] * s[2]
    );
    assert!(eb < 0.5 * et, "bottom {eb}, top {et}");
}
