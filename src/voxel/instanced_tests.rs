//! The two-level SVO against independent oracles: the flattened single-level SVO of the same
//! scene (bit-equal where the two voxelize the same triangles in the same grid), the brute-force
//! minimum over every instance (the top grid loses nothing), and brute-force ray/triangle and
//! point/triangle tests on the placed triangles (the stated bound where a rotated, scaled model's
//! voxels differ from the flattened scene's).

use super::*;
use crate::model::{Mesh, Terrain};
use crate::rng::Rng;
use crate::voxel::geometry::{place_instance, procedural_blob, terrain_mesh};
use crate::voxel::svo::voxels_to_svo;
use crate::voxel::tests::box_mesh;
use crate::voxel::traverse::trace_svo;
use crate::voxel::voxelize::mesh_to_voxels;

fn geo(mesh: Mesh) -> Geometry {
    Geometry {
        mesh,
        textures: Vec::new(),
    }
}

fn wavy_terrain() -> Terrain {
    let (w, h) = (17u32, 13u32);
    let heights = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            0.4 * (0.7 * x).sin() + 0.3 * (0.5 * y).cos()
        })
        .collect();
    Terrain {
        width: w,
        height: h,
        heights,
        origin: [-8.0, -6.0],
        extent: [16.0, 12.0],
        color: None,
    }
}

/// The flattened scene, as `geometry::pack_geometry` builds it.
fn flattened(terrain: Option<&Geometry>, models: &[Geometry], instances: &[Instance]) -> Geometry {
    let mut g = Geometry::default();
    if let Some(t) = terrain {
        g.append(t.clone());
    }
    for i in instances {
        g.append(place_instance(&models[i.model as usize], i));
    }
    g
}

fn named(models: &[Geometry]) -> Vec<Option<(String, Geometry)>> {
    models
        .iter()
        .enumerate()
        .map(|(i, m)| Some((format!("mesh:{i}"), m.clone())))
        .collect()
}

/// World ray → the flattened SVO's voxel ray (the same `t`).
fn flat_trace(svo: &Svo, o: [f32; 3], d: [f32; 3]) -> Option<([u32; 3], f32)> {
    let g = &svo.grid;
    let r = VoxelRay {
        origin: g.to_grid(o),
        dir: [0, 1, 2].map(|k| d[k] / g.voxel_size[k]),
        t_min: 0.0,
        t_max: f32::INFINITY,
    };
    trace_svo(svo, &r).map(|h| (h.voxel, h.t))
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / l)
}

/// Rays from around the scene's box towards random points inside it.
fn rays(rng: &mut Rng, lo: [f32; 3], hi: [f32; 3], n: usize) -> Vec<([f32; 3], [f32; 3])> {
    (0..n)
        .map(|_| {
            let target = [0, 1, 2].map(|k| rng.range(lo[k], hi[k]));
            let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
            let r = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
            let dir = normalize([
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 0.6),
            ]);
            let o = [0, 1, 2].map(|k| c[k] - dir[k] * 1.5 * r + (target[k] - c[k]) * 0.5);
            (o, dir)
        })
        .collect()
}

#[test]
fn one_instance_at_the_identity_is_the_flattened_svo_bit_for_bit() {
    let model = geo(procedural_blob(24, 12));
    let instances = [Instance::new(0, [0.0; 3], 1.0, 0.0)];
    let opts = VoxelizeOptions::surface(48);
    let two = InstancedSvo::build(
        None,
        &named(std::slice::from_ref(&model)),
        &instances,
        &opts,
    )
    .unwrap();
    let flat = flattened(None, std::slice::from_ref(&model), &instances);
    let fv = mesh_to_voxels(&flat.mesh, &flat.textures, &opts).unwrap();
    let fsvo = voxels_to_svo(&fv);
    assert_eq!(two.scene_grid, fsvo.grid);
    assert_eq!(
        two.models[0].svo, fsvo,
        "same grid, same triangles: same octree"
    );
    let mut rng = Rng::new(7);
    let (lo, hi) = flat.mesh.bounds().unwrap();
    let mut hits = 0;
    for (o, d) in rays(&mut rng, lo, hi, 2000) {
        let a = two
            .trace(o, d, [0.0, f32::INFINITY])
            .map(|h| (h.voxel, h.t));
        let b = flat_trace(&fsvo, o, d);
        assert_eq!(a, b, "ray {o:?} {d:?}");
        hits += a.is_some() as usize;
    }
    assert!(hits > 500, "the rays hit the model ({hits})");
}

#[test]
fn the_terrain_is_the_flattened_terrain_bit_for_bit() {
    let terrain = wavy_terrain();
    let t = terrain_mesh(&terrain);
    let opts = VoxelizeOptions::surface(64);
    let two = InstancedSvo::build(Some(&terrain), &[], &[], &opts).unwrap();
    let fsvo = voxels_to_svo(&mesh_to_voxels(&t.mesh, &t.textures, &opts).unwrap());
    assert!(two.terrain);
    assert_eq!(two.models[0].svo, fsvo);
    let (lo, hi) = t.mesh.bounds().unwrap();
    let mut rng = Rng::new(3);
    for (o, d) in rays(&mut rng, lo, hi, 2000) {
        let a = two
            .trace(o, d, [0.0, f32::INFINITY])
            .map(|h| (h.voxel, h.t));
        assert_eq!(a, flat_trace(&fsvo, o, d));
    }
}

/// A few instances of two models, rotated and scaled, on a terrain.
fn scene() -> (Terrain, Vec<Geometry>, Vec<Instance>) {
    let t = wavy_terrain();
    let models = vec![
        geo(procedural_blob(20, 10)),
        geo(box_mesh([-0.4, -0.2, 0.0], [0.4, 0.2, 1.5])),
    ];
    let mut rng = Rng::new(11);
    let instances = (0..14)
        .map(|i| {
            let (x, y) = (rng.range(-7.0, 7.0), rng.range(-5.0, 5.0));
            Instance::new(
                i % 2,
                [x, y, rng.range(0.0, 1.0)],
                rng.range(0.5, 1.8),
                rng.range(-180.0, 180.0),
            )
        })
        .collect();
    (t, models, instances)
}

#[test]
fn the_top_grid_finds_the_nearest_of_all_instances() {
    let (t, models, instances) = scene();
    let two = InstancedSvo::build(
        Some(&t),
        &named(&models),
        &instances,
        &VoxelizeOptions::surface(96),
    )
    .unwrap();
    assert!(two.top.cells() > 1, "a grid, not one cell: {:?}", two.top);
    let (lo, hi) = flattened(Some(&terrain_mesh(&t)), &models, &instances)
        .mesh
        .bounds()
        .unwrap();
    let mut rng = Rng::new(5);
    let mut instance_hits = 0;
    for (o, d) in rays(&mut rng, lo, hi, 3000) {
        let got = two.trace(o, d, [0.0, f32::INFINITY]);
        // Oracle: every instance traced on its own, nearest first, ties to the lower number.
        let want = (0..two.instances.len())
            .filter_map(|i| two.trace_instance(i, o, d, [0.0, f32::INFINITY]))
            .min_by(|a, b| a.t.total_cmp(&b.t).then(a.instance.cmp(&b.instance)));
        assert_eq!(got, want, "ray {o:?} {d:?}");
        instance_hits += got.is_some_and(|h| (h.instance as usize) < two.grid_instances()) as usize;
    }
    assert!(
        instance_hits > 300,
        "rays reach the instances ({instance_hits})"
    );
}

fn ray_triangle(o: [f32; 3], d: [f32; 3], tri: [[f32; 3]; 3]) -> Option<f32> {
    let o = o.map(|x| x as f64);
    let d = d.map(|x| x as f64);
    let v = tri.map(|p| p.map(|x| x as f64));
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (e1, e2) = (sub(v[1], v[0]), sub(v[2], v[0]));
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-12 {
        return None;
    }
    let s = sub(o, v[0]);
    let u = dot(s, p) / det;
    let q = cross(s, e1);
    let w = dot(d, q) / det;
    let t = dot(e2, q) / det;
    (u >= 0.0 && w >= 0.0 && u + w <= 1.0 && t >= 0.0).then_some(t as f32)
}

/// Distance from `p` to the triangle (closest point by Ericson's region test, in f64).
fn point_triangle(p: [f32; 3], tri: [[f32; 3]; 3]) -> f32 {
    let p = p.map(|x| x as f64);
    let [a, b, c] = tri.map(|q| q.map(|x| x as f64));
    let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let at = |o: [f64; 3], e: [f64; 3], s: f64| [o[0] + e[0] * s, o[1] + e[1] * s, o[2] + e[2] * s];
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    let q = if d1 <= 0.0 && d2 <= 0.0 {
        a
    } else {
        let bp = sub(p, b);
        let (d3, d4) = (dot(ab, bp), dot(ac, bp));
        let cp = sub(p, c);
        let (d5, d6) = (dot(ab, cp), dot(ac, cp));
        let (vc, vb, va) = (d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4);
        if d3 >= 0.0 && d4 <= d3 {
            b
        } else if d6 >= 0.0 && d5 <= d6 {
            c
        } else if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            at(a, ab, d1 / (d1 - d3))
        } else if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            at(a, ac, d2 / (d2 - d6))
        } else if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            at(b, sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)))
        } else {
            let den = 1.0 / (va + vb + vc);
            let (v, w) = (vb * den, vc * den);
            [0, 1, 2].map(|k| a[k] + ab[k] * v + ac[k] * w)
        }
    };
    let e = sub(p, q);
    dot(e, e).sqrt() as f32
}

/// The stated bound (docs/CONVENTIONS.md, "Instanced SVO"): a rotated, scaled model voxelized in
/// its own frame covers other cells than the flattened scene's voxels, so hits are not equal;
/// both structures report a hit on every ray that meets a triangle, no later than the triangle
/// (the voxel holding the hit point is occupied), and each hit point lies within one diagonal of
/// its voxel from a placed triangle (a voxel is occupied only where a triangle touches it).
#[test]
fn rotated_scaled_instances_keep_the_bound_against_the_triangles_and_the_flattened_svo() {
    let (t, models, instances) = scene();
    assert_traced_as_the_triangles(&t, &models, &instances);
}

/// A mirrored instance (negative scale, docs/CONVENTIONS.md) is traced where its placed
/// triangles are, and its section is written and read back (the section check refused any
/// scale ≤ 0, so such a scene wrote a section it could not read).
#[test]
fn a_mirrored_instance_is_traced_as_its_triangles_and_its_section_round_trips() {
    let (t, models, mut instances) = scene();
    instances[0].scale = -instances[0].scale;
    instances[3].scale = -instances[3].scale;
    assert_traced_as_the_triangles(&t, &models, &instances);
    let two = build48(&t, &models, &instances);
    let (_, back) = round_trip(&two);
    assert_eq!(back, two);
    assert!(back.instances[0].scale < 0.0);
    // Zero and non-finite scales stay refused.
    for bad_scale in [0.0, f32::NAN, f32::INFINITY] {
        let mut bad = two.clone();
        bad.instances[0].scale = bad_scale;
        assert!(super::super::instanced_section::validate(&bad).is_err());
    }
}

/// The two-level SVO of `instances` against the placed triangles (every surface hit found, no
/// later than the surface, within a voxel diagonal of it) and the flattened SVO.
fn assert_traced_as_the_triangles(t: &Terrain, models: &[Geometry], instances: &[Instance]) {
    let opts = VoxelizeOptions::surface(96);
    let two = InstancedSvo::build(Some(t), &named(models), instances, &opts).unwrap();
    let flat = flattened(Some(&terrain_mesh(t)), models, instances);
    let fsvo = voxels_to_svo(&mesh_to_voxels(&flat.mesh, &flat.textures, &opts).unwrap());
    assert_eq!(
        two.scene_grid, fsvo.grid,
        "the scene gets the flattened resolution"
    );
    let v = fsvo.grid.voxel_size[0];
    for m in &two.models {
        assert!(m.svo.grid.voxel_size[0] > 0.0);
    }
    for r in &two.instances {
        let vm = two.models[r.model as usize].svo.grid.voxel_size[0] * r.scale.abs();
        assert!(
            vm <= v * (1.0 + 1e-5),
            "an instance's voxel {vm} is no wider than {v}"
        );
    }
    let tris: Vec<[[f32; 3]; 3]> = flat
        .mesh
        .indices
        .iter()
        .map(|t| t.map(|i| flat.mesh.positions[i as usize]))
        .collect();
    let diag = 3f32.sqrt() * v;
    let (lo, hi) = flat.mesh.bounds().unwrap();
    let mut rng = Rng::new(9);
    let (mut both, mut same_voxel_t, mut surface_hits) = (0, 0, 0);
    let mut worst = 0.0f32;
    for (o, d) in rays(&mut rng, lo, hi, 1500) {
        let exact = tris
            .iter()
            .filter_map(|&tri| ray_triangle(o, d, tri))
            .fold(f32::INFINITY, f32::min);
        let a = two.trace(o, d, [0.0, f32::INFINITY]);
        let b = flat_trace(&fsvo, o, d);
        let slack = 1e-4 * (1.0 + exact.abs());
        if exact.is_finite() {
            surface_hits += 1;
            let a = a.unwrap_or_else(|| panic!("two-level misses a surface hit: {o:?} {d:?}"));
            let b = b.unwrap_or_else(|| panic!("flattened misses a surface hit: {o:?} {d:?}"));
            assert!(
                a.t <= exact + slack,
                "two-level {} after the surface {exact}",
                a.t
            );
            assert!(
                b.1 <= exact + slack,
                "flattened {} after the surface {exact}",
                b.1
            );
        }
        for t_hit in a.map(|h| h.t).into_iter().chain(b.map(|h| h.1)) {
            let p = [0, 1, 2].map(|k| o[k] + d[k] * t_hit);
            let dist = tris
                .iter()
                .map(|&tri| point_triangle(p, tri))
                .fold(f32::INFINITY, f32::min);
            worst = worst.max(dist / diag);
            assert!(
                dist <= diag * 1.001 + 1e-4,
                "hit {dist} m from the surface > {diag}"
            );
        }
        if let (Some(a), Some(b)) = (a, b) {
            both += 1;
            same_voxel_t += ((a.t - b.1).abs() <= v) as usize;
        }
    }
    assert!(surface_hits > 300, "rays meet the surface ({surface_hits})");
    // Not an assertion of equality: the share of rays whose hits lie within a voxel of each
    // other, to see that the two structures are the same scene (most rays).
    assert!(
        same_voxel_t * 10 >= both * 8,
        "{same_voxel_t} of {both} hits within a voxel side (worst distance {worst} diagonals)"
    );
}

#[test]
fn memory_is_the_models_not_the_instances() {
    let model = geo(procedural_blob(20, 10));
    let opts = VoxelizeOptions::surface(64);
    let few: Vec<Instance> = (0..4)
        .map(|i| Instance::new(0, [i as f32 * 3.0, 0.0, 0.0], 1.0, 30.0 * i as f32))
        .collect();
    let many: Vec<Instance> = (0..400)
        .map(|i| {
            Instance::new(
                0,
                [(i % 20) as f32 * 3.0, (i / 20) as f32 * 3.0, 0.0],
                1.0,
                i as f32,
            )
        })
        .collect();
    let a = InstancedSvo::build(None, &named(std::slice::from_ref(&model)), &few, &opts).unwrap();
    let b = InstancedSvo::build(None, &named(std::slice::from_ref(&model)), &many, &opts).unwrap();
    // One octree either way; instances cost their 32-byte records and grid references.
    assert_eq!(a.models.len(), 1);
    assert_eq!(b.models.len(), 1);
    assert_eq!(b.instances.len(), 400);
    let refs = b.cell_instances.len();
    assert!(refs < 400 * 9, "{refs} grid references for 400 instances");
}

/// The scene's two-level SVO at resolution 48.
fn build48(t: &Terrain, models: &[Geometry], instances: &[Instance]) -> InstancedSvo {
    InstancedSvo::build(
        Some(t),
        &named(models),
        instances,
        &VoxelizeOptions::surface(48),
    )
    .unwrap()
}

/// `two` written as an `svo-scene` section (source "scene:x.eco") and read back.
fn round_trip(two: &InstancedSvo) -> (super::super::instanced_section::SvoSceneMeta, InstancedSvo) {
    let sec = super::super::instanced_section::to_section("svo-scene", "scene:x.eco", two, false);
    let view = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    super::super::instanced_section::from_section(&view).unwrap()
}

#[test]
fn the_section_round_trips() {
    let (t, models, instances) = scene();
    let two = build48(&t, &models, &instances);
    let (meta, back) = round_trip(&two);
    assert_eq!(meta.source, "scene:x.eco");
    assert_eq!(back, two);
    // A broken record is refused.
    let mut bad = two.clone();
    bad.instances[0].model = 99;
    assert!(super::super::instanced_section::validate(&bad).is_err());
    let mut bad = two.clone();
    bad.cell_instances[0] = 999;
    assert!(super::super::instanced_section::validate(&bad).is_err());
    // Aggregates that do not match the grid, or whose sub-cells are not numbered in order.
    let mut bad = two.clone();
    bad.aggregates.nodes.pop();
    assert!(super::super::instanced_section::validate(&bad).is_err());
    let mut bad = two.clone();
    let c = (0..bad.top.cells())
        .find(|&c| bad.aggregates.mask(c) != 0)
        .unwrap();
    bad.aggregates.nodes[c][1] ^= 1 << 31;
    assert!(super::super::instanced_section::validate(&bad).is_err());
    let mut bad = two.clone();
    bad.aggregates.colors.pop();
    assert!(super::super::instanced_section::validate(&bad).is_err());
}

#[test]
fn the_terrain_in_tiles_is_the_whole_terrain_bit_for_bit() {
    let mut t = wavy_terrain();
    // A colour map, so that colours differ between voxels.
    t.color = Some(crate::model::Rgba8Image {
        width: 8,
        height: 8,
        pixels: (0..64u32)
            .map(|i| {
                [
                    (i * 37 % 256) as u8,
                    (i * 11 % 256) as u8,
                    (i * 5) as u8,
                    255,
                ]
            })
            .collect(),
    });
    let g = terrain_mesh(&t);
    for res in [16, 64, 200] {
        let opts = VoxelizeOptions::surface(res);
        let (lo, hi) = g.mesh.bounds().unwrap();
        assert_eq!(terrain_bounds(&t), Some((lo, hi)));
        let grid = Grid::fit(lo, hi, res);
        let whole = mesh_to_voxels_in(&g.mesh, &g.textures, &grid, &opts).unwrap();
        for tile_cells in [1, 4, 30] {
            let tiled = terrain_voxels(&t, &grid, &opts, tile_cells).unwrap();
            assert_eq!(
                tiled.bricks, whole.bricks,
                "resolution {res}, tiles of {tile_cells}"
            );
            assert_eq!(tiled.colors, whole.colors);
            assert_eq!(tiled.normals, whole.normals);
        }
    }
}

/// The test scene's two-level SVO at `resolution` (for the GPU test).
pub(crate) fn test_scene(resolution: u32) -> InstancedSvo {
    let (t, models, instances) = scene();
    InstancedSvo::build(
        Some(&t),
        &named(&models),
        &instances,
        &VoxelizeOptions::surface(resolution),
    )
    .unwrap()
}

/// The oracle's region of a world point: its own floor and bit interleave (x, y, z of bit 0,
/// then of bit 1), as docs/FORMAT.md states the slot.
fn oracle_region(top: &TopGrid, p: [f32; 3]) -> (usize, u32) {
    let u = [0, 1, 2].map(|k| (p[k] - top.origin[k]) / top.cell);
    let c = [0, 1, 2].map(|k| u[k].floor().clamp(0.0, top.dims[k] as f32 - 1.0));
    let sub = [0, 1, 2].map(|k| ((u[k] - c[k]) * 4.0).floor().clamp(0.0, 3.0) as u32);
    let cell = c[0] as usize
        + top.dims[0] as usize * (c[1] as usize + top.dims[1] as usize * c[2] as usize);
    let mut s = 0;
    for bit in 0..2 {
        for (k, v) in sub.iter().enumerate() {
            s |= (v >> bit & 1) << (3 * bit + k as u32);
        }
    }
    (cell, s)
}

/// Brute force: every instance's and the terrain's every voxel (found by probing each
/// coordinate of its model's grid), placed, binned by centre; sums of volume·α, volume·rgb
/// (premultiplied) and volume·α·normal (turned) per (cell, slot).
fn brute_force_sums(s: &InstancedSvo) -> std::collections::BTreeMap<(usize, u32), [f64; 7]> {
    let mut out = std::collections::BTreeMap::new();
    for r in &s.instances {
        let svo = &s.models[r.model as usize].svo;
        let g = svo.grid;
        let vol = (r.scale as f64 * g.voxel_size[0] as f64).powi(3);
        for z in 0..g.dims[2] {
            for y in 0..g.dims[1] {
                for x in 0..g.dims[0] {
                    let Some(i) = svo.voxel_index([x, y, z]) else {
                        continue;
                    };
                    let c = crate::voxel::svo::unpack_rgba8(svo.voxel_colors[i]);
                    let n = r.dir_to_world(crate::voxel::svo::unpack_normal(svo.voxel_normals[i]));
                    let centre = r.to_world(g.to_world([x, y, z].map(|v| v as f32 + 0.5)));
                    let e: &mut [f64; 7] = out.entry(oracle_region(&s.top, centre)).or_default();
                    let a = vol * c[3] as f64;
                    e[0] += a;
                    for k in 0..3 {
                        e[1 + k] += vol * c[k] as f64;
                        e[4 + k] += a * n[k] as f64;
                    }
                }
            }
        }
    }
    out
}

/// The stored aggregate (colour, normal) against sums: premultiplied colour within half a step
/// of RGBA8 (plus rounding), normal within 10⁻³ rad of the sum's direction.
fn assert_aggregate(what: &str, color: u32, normal: u32, sums: &[f64; 7], vol: f64) {
    let got = crate::voxel::svo::unpack_rgba8(color);
    let alpha = (sums[0] / vol).min(1.0);
    let want = if sums[0] > 0.0 {
        [
            sums[1] / sums[0] * alpha,
            sums[2] / sums[0] * alpha,
            sums[3] / sums[0] * alpha,
            alpha,
        ]
    } else {
        [0.0; 4]
    };
    for k in 0..4 {
        assert!(
            (got[k] as f64 - want[k]).abs() <= 0.5 / 255.0 + 1e-5,
            "{what}: colour {got:?}, brute force {want:?}"
        );
    }
    let l = (sums[4] * sums[4] + sums[5] * sums[5] + sums[6] * sums[6]).sqrt();
    if l > 1e-9 * sums[0].max(1e-30) {
        let n = crate::voxel::svo::unpack_normal(normal);
        let dot: f64 = (0..3).map(|k| n[k] as f64 * sums[4 + k] / l).sum();
        assert!(
            dot > 1.0 - 1e-6,
            "{what}: normal {n:?}, brute force {:?}",
            &sums[4..]
        );
    }
}

#[test]
fn the_top_aggregates_are_the_brute_force_average_of_the_placed_voxels() {
    let s = test_scene(96);
    let sums = brute_force_sums(&s);
    let a = &s.aggregates;
    let cells = s.top.cells();
    assert_eq!(a.nodes.len(), cells);
    let side = s.top.cell as f64;
    let mut occupied = 0;
    for c in 0..cells {
        let subs: Vec<(&(usize, u32), &[f64; 7])> = sums.range((c, 0)..(c, 64)).collect();
        let want_mask = subs.iter().fold(0u64, |m, ((_, sl), _)| m | 1 << sl);
        assert_eq!(a.mask(c), want_mask, "cell {c}: occupied sub-cells");
        let mut cell_sum = [0.0f64; 7];
        for ((_, sl), e) in &subs {
            for k in 0..7 {
                cell_sum[k] += e[k];
            }
            let i = a.sub_attr(c, *sl);
            assert_aggregate(
                &format!("cell {c} slot {sl}"),
                a.colors[i],
                a.normals[i],
                e,
                (side / 4.0).powi(3),
            );
        }
        assert_aggregate(
            &format!("cell {c}"),
            a.colors[c],
            a.normals[c],
            &cell_sum,
            side.powi(3),
        );
        occupied += subs.len();
    }
    assert_eq!(a.colors.len(), cells + occupied);
    // Rotated, scaled instances; sub-cells of every coverage, some enough to stop on.
    assert!(occupied > 50, "{occupied} occupied sub-cells");
    let stoppable = a.colors[cells..]
        .iter()
        .filter(|&&c| crate::voxel::lod_trace::can_stop(c))
        .count();
    assert!(
        stoppable > 10 && stoppable < occupied,
        "{stoppable} of {occupied} sub-cells can stop"
    );
}

/// An analytic case: one instance at the identity of a model that fills its grid (a solid
/// box), every voxel colour c and normal +Z: every sub-cell inside is covered exactly once.
#[test]
fn a_solid_box_fills_its_cells_with_its_colour() {
    let model = geo(box_mesh([0.0; 3], [4.0, 4.0, 4.0]));
    let opts = VoxelizeOptions {
        solid: true,
        ..VoxelizeOptions::surface(32)
    };
    let instances = [Instance::new(0, [0.0; 3], 1.0, 0.0)];
    let s = InstancedSvo::build(
        None,
        &named(std::slice::from_ref(&model)),
        &instances,
        &opts,
    )
    .unwrap();
    let voxels = s.models[0].svo.voxel_colors.len();
    let g = s.models[0].svo.grid;
    assert_eq!(
        voxels as u32,
        g.dims.iter().product::<u32>(),
        "solid: every voxel"
    );
    // Total coverage volume: Σ over the stored regions of α·volume is the box's volume where
    // no region is over-full (α < 1 only at the box's boundary cells; α = 1 inside).
    let side = s.top.cell as f64;
    let cells = s.top.cells();
    let sub_vol = (side / 4.0).powi(3);
    let covered: f64 = (0..cells)
        .flat_map(|c| {
            let m = s.aggregates.mask(c);
            (0..64u32)
                .filter(move |sl| m >> sl & 1 == 1)
                .map(move |sl| (c, sl))
        })
        .map(|(c, sl)| {
            let col =
                crate::voxel::svo::unpack_rgba8(s.aggregates.colors[s.aggregates.sub_attr(c, sl)]);
            col[3] as f64 * sub_vol
        })
        .sum();
    let grid_vol = (0..3)
        .map(|k| g.dims[k] as f64 * g.voxel_size[k] as f64)
        .product::<f64>();
    // One instance: one top cell, the instance's box grown by 10⁻⁶; its 4³ sub-cells each hold
    // (dims/4)³ whole voxels of volume v³: coverage 1, and every voxel's colour.
    assert_eq!(s.top.dims, [1, 1, 1]);
    assert_eq!(s.aggregates.mask(0), u64::MAX, "every sub-cell occupied");
    let want = (g.dims[0] as f64 / 4.0).powi(3) * (g.voxel_size[0] as f64).powi(3) / sub_vol;
    assert!((want - 1.0).abs() < 1e-4, "{want}");
    let voxel = s.models[0].svo.voxel_colors[0];
    assert!(
        s.models[0].svo.voxel_colors.iter().all(|&c| c == voxel),
        "one colour"
    );
    for e in 0..65 {
        let c = s.aggregates.colors[e];
        assert_eq!(c >> 24, 255, "entry {e}: full coverage");
        assert_eq!(c, voxel, "entry {e}: the voxels' colour");
    }
    assert!(
        (covered - grid_vol).abs() <= grid_vol * 0.02,
        "covered {covered} m³ of {grid_vol}"
    );
}

/// A ray in top-grid units, as the oracle builds it.
fn oracle_top_ray(s: &InstancedSvo, o: [f32; 3], d: [f32; 3]) -> VoxelRay {
    VoxelRay {
        origin: [0, 1, 2].map(|k| (o[k] - s.top.origin[k]) / s.top.cell),
        dir: d.map(|x| x / s.top.cell),
        t_min: 0.0,
        t_max: f32::INFINITY,
    }
}

/// An occupied inner cell: (level, minimum corner in voxels, side in voxels, the stored filtered
/// colour, its index into `node_colors`).
pub(crate) type InnerCell = (u32, [u32; 3], u32, u32, u32);

/// Every occupied inner cell of an octree, found from its voxels (probing each coordinate of
/// the grid), not by a walk. The stored values are looked up by descending the cell's Morton
/// key.
pub(crate) fn inner_cells(svo: &Svo) -> Vec<InnerCell> {
    let l = svo.levels;
    let mut keys = std::collections::BTreeSet::new();
    let g = svo.grid;
    for z in 0..g.dims[2] {
        for y in 0..g.dims[1] {
            for x in 0..g.dims[0] {
                if svo.voxel_index([x, y, z]).is_some() {
                    for level in 0..l {
                        let side = 4u32.pow(l - level);
                        keys.insert((level, [x, y, z].map(|v| v / side * side)));
                    }
                }
            }
        }
    }
    keys.into_iter()
        .map(|(level, corner)| {
            let key = crate::voxel::morton_encode(corner);
            let mut attr = 0usize;
            let mut node = 0usize;
            for k in 0..level as usize {
                let slot = ((key >> (6 * (l as usize - 1 - k))) & 63) as u32;
                let child = svo.child(&svo.nodes[node], slot) as usize;
                attr = if k + 1 == svo.inner_levels() {
                    svo.nodes.len() + child
                } else {
                    child
                };
                node = child;
            }
            let side = 4u32.pow(l - level);
            (level, corner, side, svo.node_colors[attr], attr as u32)
        })
        .collect()
}

/// The rule inside instance `i`, by brute force: of every occupied inner cell of its model the
/// ray crosses (slab tests in the instance's voxel units, the entry clamped to the grid's),
/// those whose world side (side × |scale| × the model's voxel side) is at most cone·t at the
/// entry and whose coverage can stop; the nearest (the coarser on a tie) if it is entered no
/// later than the first voxel, else that voxel (the voxel walk, tested against the triangles).
pub(crate) fn brute_force_instance(
    s: &InstancedSvo,
    cells: &[InnerCell],
    i: usize,
    o: [f32; 3],
    d: [f32; 3],
    cone: f32,
) -> Option<SceneHit> {
    let voxel = s.trace_instance(i, o, d, [0.0, f32::INFINITY]);
    let r = s.ray_in(i, o, d, [0.0, f32::INFINITY]);
    let inst = &s.instances[i];
    let svo = &s.models[inst.model as usize].svo;
    let unit = inst.scale.abs() * svo.grid.voxel_size[0];
    let (g0, g1) = box_interval(&r, [0.0; 3], svo.grid.dims.map(|x| x as f32));
    let (t0, t1) = (g0.max(0.0), g1);
    let mut node: Option<NodeHit> = None;
    if t0 <= t1 && cone > 0.0 {
        for &(level, corner, side, color, attr) in cells {
            let lo = corner.map(|c| c as f32);
            let (e, x) = box_interval(&r, lo, lo.map(|v| v + side as f32));
            let tc = e.max(t0);
            let crossed = tc < x.min(t1) || (level == 0 && tc <= t1);
            if crossed
                && side as f32 * unit <= cone * tc
                && crate::voxel::lod_trace::can_stop(color)
                && node.is_none_or(|n| tc < n.t || (tc == n.t && level < n.level))
            {
                node = Some(NodeHit {
                    instance: i as u32,
                    level,
                    cell: corner,
                    attr,
                    t: tc,
                });
            }
        }
    }
    match (node, voxel) {
        (Some(n), Some(v)) if n.t > v.t => Some(SceneHit::Voxel(v)),
        (Some(n), _) => Some(SceneHit::Node(n)),
        (None, v) => v.map(SceneHit::Voxel),
    }
}

/// The cut-off rule applied by brute force: every cell of the grid and every occupied sub-cell
/// the ray crosses (slab tests, no DDA), the nearest whose side is at most cone·t at its entry
/// and whose aggregate can stop (a sub-cell only where its cell does not); against the nearest
/// answer of all instances and the terrain, each by [`brute_force_instance`].
fn brute_force_lod(
    s: &InstancedSvo,
    cells: &[Vec<InnerCell>],
    o: [f32; 3],
    d: [f32; 3],
    cone: f32,
) -> Option<SceneHit> {
    let want = (0..s.instances.len())
        .filter_map(|i| {
            let m = s.instances[i].model as usize;
            brute_force_instance(s, &cells[m], i, o, d, cone)
        })
        .min_by(|a, b| {
            a.t()
                .total_cmp(&b.t())
                .then(a.instance().cmp(&b.instance()))
        });
    let r = oracle_top_ray(s, o, d);
    let (g0, g1) = box_interval(&r, [0.0; 3], s.top.dims.map(|x| x as f32));
    let (t0, t1) = (g0.max(0.0), g1);
    let mut agg: Option<AggregateHit> = None;
    let mut consider = |h: AggregateHit| {
        if agg.is_none_or(|a| h.t < a.t) {
            agg = Some(h);
        }
    };
    if t0 <= t1 && (!s.cell_instances.is_empty() || cone > 0.0) {
        let a = &s.aggregates;
        for z in 0..s.top.dims[2] {
            for y in 0..s.top.dims[1] {
                for x in 0..s.top.dims[0] {
                    let cc = [x, y, z].map(|v| v as f32);
                    let c = s.top.index([x as i64, y as i64, z as i64]);
                    let (e, x1) = box_interval(&r, cc, cc.map(|v| v + 1.0));
                    let tc = e.max(t0);
                    if tc >= x1.min(t1) {
                        continue;
                    }
                    if s.top.cell <= cone * tc && crate::voxel::lod_trace::can_stop(a.colors[c]) {
                        consider(AggregateHit {
                            level: 0,
                            attr: c as u32,
                            t: tc,
                        });
                        continue;
                    }
                    for sl in 0..64u32 {
                        if a.mask(c) >> sl & 1 == 0 {
                            continue;
                        }
                        let sub = [
                            sl & 1 | (sl >> 2 & 2),
                            sl >> 1 & 1 | (sl >> 3 & 2),
                            sl >> 2 & 1 | (sl >> 4 & 2),
                        ];
                        let lo = [0, 1, 2].map(|k| cc[k] + sub[k] as f32 * 0.25);
                        let (e, x1) = box_interval(&r, lo, lo.map(|v| v + 0.25));
                        let ts = e.max(t0);
                        let attr = a.sub_attr(c, sl);
                        if ts < x1.min(t1)
                            && s.top.cell / 4.0 <= cone * ts
                            && crate::voxel::lod_trace::can_stop(a.colors[attr])
                        {
                            consider(AggregateHit {
                                level: 1,
                                attr: attr as u32,
                                t: ts,
                            });
                        }
                    }
                }
            }
        }
    }
    match (want, agg) {
        (Some(w), Some(a)) if a.t < w.t() => Some(SceneHit::Aggregate(a)),
        (None, Some(a)) => Some(SceneHit::Aggregate(a)),
        (w, _) => w,
    }
}

#[test]
fn the_lod_walk_is_the_cut_off_rule_applied_by_brute_force() {
    let s = test_scene(96);
    let g = s.scene_grid;
    let (lo, hi) = (g.origin, g.to_world(g.dims.map(|d| d as f32)));
    let base = crate::voxel::instanced_gpu::lod_cone(&s);
    let model_cells: Vec<_> = s.models.iter().map(|m| inner_cells(&m.svo)).collect();
    let mut rng = Rng::new(21);
    let rays = rays(&mut rng, lo, hi, 1500);
    for scale in [0.0, 0.1, 0.2, 0.3, 0.5, 1.0, 4.0] {
        let cone = base * scale;
        let (mut cells, mut subs, mut voxels) = (0, 0, 0);
        let (mut nodes, mut terrain_nodes) = (0, 0);
        for &(o, d) in &rays {
            let got = s.trace_lod(o, d, [0.0, f32::INFINITY], cone);
            let want = brute_force_lod(&s, &model_cells, o, d, cone);
            assert_eq!(got, want, "cone {cone}, ray {o:?} {d:?}");
            match got {
                Some(SceneHit::Aggregate(a)) if a.level == 0 => cells += 1,
                Some(SceneHit::Aggregate(_)) => subs += 1,
                Some(SceneHit::Node(n)) if n.instance as usize == s.grid_instances() => {
                    terrain_nodes += 1
                }
                Some(SceneHit::Node(_)) => nodes += 1,
                Some(SceneHit::Voxel(_)) => voxels += 1,
                None => {}
            }
        }
        let what = format!(
            "cone ×{scale}: {cells} cells, {subs} sub-cells, {nodes} instance nodes, \
             {terrain_nodes} terrain nodes, {voxels} voxels"
        );
        // Every kind of answer occurs: the voxels near, the models' nodes (instances and the
        // terrain) farther, the aggregates far.
        match scale {
            0.0 => assert_eq!(cells + subs + nodes + terrain_nodes, 0, "{what}"),
            0.1 => assert!(nodes > 300 && voxels > 300, "{what}"),
            0.2 => assert!(nodes > 300 && terrain_nodes > 100 && subs > 0, "{what}"),
            0.5 => assert!(subs > 300 && nodes > 30 && terrain_nodes > 30, "{what}"),
            4.0 => assert!(cells > 300 && nodes > 0, "{what}"),
            _ => {}
        }
    }
}

/// The section's bytes do not depend on the number of threads (the aggregates are summed in
/// fixed chunks of instances).
#[test]
fn the_section_is_byte_identical_on_one_and_two_threads() {
    let t = wavy_terrain();
    let models = vec![
        geo(procedural_blob(12, 6)),
        geo(box_mesh([-0.3, -0.2, 0.0], [0.3, 0.2, 1.0])),
    ];
    let mut rng = Rng::new(4);
    let instances: Vec<Instance> = (0..1200)
        .map(|i| {
            Instance::new(
                i % 2,
                [
                    rng.range(-7.5, 7.5),
                    rng.range(-5.5, 5.5),
                    rng.range(0.0, 0.5),
                ],
                rng.range(0.1, 0.4),
                rng.range(-180.0, 180.0),
            )
        })
        .collect();
    let bytes = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let s = InstancedSvo::build(
                Some(&t),
                &named(&models),
                &instances,
                &VoxelizeOptions::surface(64),
            )
            .unwrap();
            super::super::instanced_section::to_section("svo-scene", "scene:x.eco", &s, false)
                .payload
        })
    };
    let (one, two) = (bytes(1), bytes(2));
    assert!(one == two, "1 and 2 threads differ");
}

/// A version 1 section (metadata ending at `solid`, no `top_*` arrays) is refused with a
/// message that names it and says to rebuild, not a decoding error.
#[test]
fn a_version_1_section_is_refused_with_a_message_to_rebuild() {
    use super::super::instanced_section::{SvoSceneModel, from_section, to_section};
    #[derive(serde::Serialize, serde::Deserialize)]
    struct V1 {
        source: String,
        scene_grid: Grid,
        models: Vec<SvoSceneModel>,
        terrain: bool,
        top: TopGrid,
        solid: bool,
    }
    let two = test_scene(32);
    let now = to_section("svo-scene", "scene:x.eco", &two, false);
    let view = crate::pack::section::SectionView::parse(&now.payload, 0).unwrap();
    let (meta, _) = from_section(&view).unwrap();
    let old = V1 {
        source: meta.source,
        scene_grid: meta.scene_grid,
        models: meta.models,
        terrain: meta.terrain,
        top: meta.top,
        solid: meta.solid,
    };
    let mut b = crate::pack::SectionBuilder::new("svo-scene", "svo-scene");
    b.meta(&old);
    for name in [
        "voxel_colors",
        "voxel_normals",
        "node_colors",
        "node_normals",
        "cell_start",
        "cell_instances",
    ] {
        let a: Vec<u32> = view.array_vec(name).unwrap();
        b.array(name, crate::pack::ArrayFormat::U32, 1, &a);
    }
    let sec = b.finish();
    let v = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    let e = from_section(&v).unwrap_err().to_string();
    assert!(e.contains("version 1") && e.contains("rebuild"), "{e}");
}

/// Rotated, scaled and mirrored instances of one model: inside each, the walk is the rule
/// applied by brute force (bit-equal) for cones from the voxels to the root; a node's normal is
/// the stored one turned by the instance's rotation (against R_z(θ) in f64).
#[test]
fn the_cut_off_inside_rotated_scaled_instances_is_the_rule_applied_by_brute_force() {
    let model = geo(procedural_blob(24, 12));
    let placements = [(0.37, 0.0), (1.0, 37.0), (2.5, -120.0), (-1.3, 75.0)];
    let instances: Vec<Instance> = placements
        .iter()
        .enumerate()
        .map(|(k, &(s, deg))| Instance::new(0, [6.0 * k as f32, 0.0, 0.0], s, deg))
        .collect();
    let s = InstancedSvo::build(
        None,
        &named(std::slice::from_ref(&model)),
        &instances,
        &VoxelizeOptions::surface(96),
    )
    .unwrap();
    let cells = inner_cells(&s.models[0].svo);
    let svo = &s.models[0].svo;
    let mut rng = Rng::new(5);
    let mut per_level = vec![0usize; svo.levels as usize + 1];
    for (i, &(_, deg)) in placements.iter().enumerate() {
        let (lo, hi) = instance_box(&s.instances[i], &svo.grid);
        let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
        for (o, d) in rays(&mut rng, lo, hi, 400) {
            // From a sixth of a voxel to the whole model per unit of distance.
            for cone in [0.0, 0.002, 0.01, 0.03, 0.1, 0.3, 1.0].map(|c| c * diag / 4.0) {
                let got = s.trace_instance_lod(i, o, d, [0.0, f32::INFINITY], cone);
                let want = brute_force_instance(&s, &cells, i, o, d, cone);
                assert_eq!(got, want, "instance {i}, cone {cone}, ray {o:?} {d:?}");
                match got {
                    Some(SceneHit::Node(n)) => {
                        per_level[n.level as usize] += 1;
                        let (_, world) = s.node_attributes(&n).unwrap();
                        let m = crate::voxel::svo::unpack_normal(svo.node_normals[n.attr as usize]);
                        let (sn, cs) = (deg as f64).to_radians().sin_cos();
                        let want = [
                            cs * m[0] as f64 - sn * m[1] as f64,
                            sn * m[0] as f64 + cs * m[1] as f64,
                            m[2] as f64,
                        ];
                        for k in 0..3 {
                            assert!(
                                (world[k] as f64 - want[k]).abs() < 1e-5,
                                "{world:?} {want:?}"
                            );
                        }
                    }
                    Some(SceneHit::Voxel(_)) => per_level[svo.levels as usize] += 1,
                    _ => {}
                }
            }
        }
    }
    // Voxels, bricks and the levels above them all answer some rays.
    let l = svo.levels as usize;
    assert!(
        per_level[l] > 300 && per_level[l - 1] > 100 && per_level[l - 2] > 30,
        "{per_level:?}"
    );
}

/// The rule is scale-free: an instance twice as large seen from twice as far (a power of two,
/// exact in f32) stops on the same node at twice the t.
#[test]
fn twice_the_scale_from_twice_the_distance_stops_on_the_same_node() {
    let model = geo(procedural_blob(24, 12));
    let instances = [Instance::new(0, [0.0; 3], 2.0, 0.0)];
    let mut s = InstancedSvo::build(
        None,
        &named(std::slice::from_ref(&model)),
        &instances,
        &VoxelizeOptions::surface(64),
    )
    .unwrap();
    let svo = s.models[0].svo.clone();
    let (lo, hi) = instance_box(&s.instances[0], &svo.grid);
    let mut rng = Rng::new(8);
    let (mut nodes, mut compared) = (0, 0);
    for (o, d) in rays(&mut rng, lo, hi, 600) {
        for cone in [0.003f32, 0.01, 0.03, 0.1] {
            s.instances[0].scale = 1.0;
            let one = s.trace_instance_lod(0, o, d, [0.0, f32::INFINITY], cone);
            s.instances[0].scale = 2.0;
            let two = s.trace_instance_lod(0, o.map(|x| 2.0 * x), d, [0.0, f32::INFINITY], cone);
            match (one, two) {
                (Some(SceneHit::Node(a)), Some(SceneHit::Node(b))) => {
                    assert_eq!((a.level, a.cell, a.attr), (b.level, b.cell, b.attr));
                    assert_eq!(2.0 * a.t, b.t);
                    nodes += 1;
                }
                (Some(SceneHit::Voxel(a)), Some(SceneHit::Voxel(b))) => {
                    assert_eq!(a.voxel, b.voxel);
                    assert_eq!(2.0 * a.t, b.t);
                }
                (None, None) => {}
                (a, b) => panic!("scale 1: {a:?}, scale 2: {b:?}"),
            }
            compared += 1;
        }
    }
    assert!(nodes > 300, "{nodes} node stops of {compared}");
}

/// A version 2 section (the same arrays, the terrain not in the aggregates) is refused with a
/// message that names its version and says to rebuild.
#[test]
fn a_version_2_section_is_refused_with_a_message_to_rebuild() {
    use super::super::instanced_section::{from_section, to_section};
    let s = test_scene(32);
    let now = to_section("svo-scene", "scene:x.eco", &s, false);
    let view = crate::pack::section::SectionView::parse(&now.payload, 0).unwrap();
    let (meta, _) = from_section(&view).unwrap();
    // The section written again with the metadata's version set to `version`.
    let with_version = |version: u32| {
        let mut m = meta.clone();
        m.version = version;
        let mut b = crate::pack::SectionBuilder::new("svo-scene", "svo-scene");
        b.meta(&m);
        let nodes: Vec<[u32; 4]> = view.array_vec("nodes").unwrap();
        let leaves: &[u8] = view.array("leaves").unwrap();
        let instances: Vec<[u32; 8]> = view.array_vec("instances").unwrap();
        let top_nodes: Vec<[u32; 4]> = view.array_vec("top_nodes").unwrap();
        let u32s = |name: &str| -> Vec<u32> { view.array_vec(name).unwrap() };
        let u = crate::pack::ArrayFormat::U32;
        b.array("nodes", u, 4, &nodes)
            .array("leaves", crate::pack::ArrayFormat::U8, 1, leaves);
        for name in [
            "voxel_colors",
            "voxel_normals",
            "node_colors",
            "node_normals",
        ] {
            b.array(name, u, 1, &u32s(name));
        }
        b.array("instances", u, 8, &instances);
        for name in ["cell_start", "cell_instances"] {
            b.array(name, u, 1, &u32s(name));
        }
        b.array("top_nodes", u, 4, &top_nodes);
        for name in ["top_colors", "top_normals"] {
            b.array(name, u, 1, &u32s(name));
        }
        b.finish()
    };
    let ok = with_version(3);
    let v = crate::pack::section::SectionView::parse(&ok.payload, 0).unwrap();
    assert_eq!(
        from_section(&v).unwrap().1,
        s,
        "the copy at version 3 is read back"
    );
    let sec = with_version(2);
    let v = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    let e = from_section(&v).unwrap_err().to_string();
    assert!(e.contains("version 2") && e.contains("rebuild"), "{e}");
}

/// The terrain alone (no instances): its voxels fill the top level's aggregates, so a wide cone
/// stops on the ground's aggregate; the aggregate's coverage-weighted colour is the terrain
/// voxels' mean (brute force) and cone 0 still reaches the terrain's voxels.
#[test]
fn a_far_view_of_bare_terrain_stops_on_the_grounds_aggregate() {
    let t = wavy_terrain();
    let s = InstancedSvo::build(Some(&t), &[], &[], &VoxelizeOptions::surface(64)).unwrap();
    assert_eq!((s.grid_instances(), s.terrain), (0, true));
    let sums = brute_force_sums(&s);
    assert!(!sums.is_empty());
    let a = &s.aggregates;
    let occupied: usize = (0..s.top.cells())
        .map(|c| a.mask(c).count_ones() as usize)
        .sum();
    assert_eq!(
        occupied,
        sums.len(),
        "every sub-cell holding a terrain voxel centre"
    );
    let g = s.scene_grid;
    let hi = g.to_world(g.dims.map(|d| d as f32));
    let centre = [0, 1, 2].map(|k| 0.5 * (g.origin[k] + hi[k]));
    // Straight down from far above the middle.
    let o = [centre[0] + 0.1, centre[1] + 0.2, hi[2] + 200.0];
    let d = [0.0, 0.0, -1.0];
    let far = s.trace_lod(o, d, [0.0, f32::INFINITY], 1.0);
    let Some(SceneHit::Aggregate(h)) = far else {
        panic!("{far:?}")
    };
    assert!(crate::voxel::lod_trace::can_stop(a.colors[h.attr as usize]));
    match s.trace_lod(o, d, [0.0, f32::INFINITY], 0.0) {
        Some(SceneHit::Voxel(v)) => {
            assert_eq!(v.instance, 0);
            assert!(v.t >= h.t, "{v:?} before {h:?}");
        }
        other => panic!("{other:?}"),
    }
}
