//! Tests of the voxel module against brute-force oracles: Akenine-Möller's triangle/box test over
//! every voxel, point-in-solid for the fill, a leaf-set walk for the octree, and a flat DDA for
//! ray traversal.

use super::svo::{unpack_rgba8, voxels_to_svo};
use super::traverse::{VoxelRay, trace_dda, trace_svo, voxel_entry_t};
use super::voxelize::*;
use super::*;
use crate::model::{Material, Mesh, Rgba8Image};
use std::collections::HashSet;

pub use crate::rng::Rng;

fn brute_force(grid: &Grid, tris: &[[[f32; 3]; 3]]) -> HashSet<[u32; 3]> {
    let mut out = HashSet::new();
    for z in 0..grid.dims[2] {
        for y in 0..grid.dims[1] {
            for x in 0..grid.dims[0] {
                let c = [x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5];
                if tris
                    .iter()
                    .any(|t| tri_box_overlap_reference(c, [0.5; 3], t.map(|p| p.map(|v| v as f64))))
                {
                    out.insert([x, y, z]);
                }
            }
        }
    }
    out
}

fn random_tris(rng: &mut Rng, n: usize, dims: [u32; 3], size: f32) -> Vec<[[f32; 3]; 3]> {
    (0..n)
        .map(|_| {
            let c = dims.map(|d| rng.range(-2.0, d as f32 + 2.0));
            std::array::from_fn(|_| [0, 1, 2].map(|k| c[k] + rng.range(-size, size)))
        })
        .collect()
}

/// A grid in voxel units (origin 0, unit voxels).
fn unit_grid(dims: [u32; 3]) -> Grid {
    Grid {
        origin: [0.0; 3],
        voxel_size: [1.0; 3],
        dims,
    }
}

fn bricks_to_set(bricks: &[Brick]) -> HashSet<[u32; 3]> {
    keys_of_bricks(bricks)
        .into_iter()
        .map(morton_decode)
        .collect()
}

#[test]
fn voxelization_equals_brute_force_akenine_moller() {
    let mut rng = Rng::new(7);
    for (dims, size) in [([12, 12, 12], 4.0), ([70, 9, 13], 12.0), ([5, 17, 3], 1.0)] {
        let grid = unit_grid(dims);
        let tris = random_tris(&mut rng, 40, dims, size);
        let setups: Vec<_> = tris.iter().map(|t| TriSetup::new(*t)).collect();
        let fast = bricks_to_set(&rasterize_bricks(&grid, &setups, &|_, _| true));
        let slow = brute_force(&grid, &tris);
        assert_eq!(fast.len(), slow.len(), "dims {dims:?}");
        assert_eq!(fast, slow, "dims {dims:?}");
        assert!(!fast.is_empty());
    }
}

#[test]
fn axis_aligned_and_degenerate_triangles_are_conservative() {
    let grid = unit_grid([8, 8, 8]);
    // A triangle in the plane z = 3 (a voxel face): both layers touch it.
    let flat = [[1.5, 1.5, 3.0], [5.5, 1.5, 3.0], [1.5, 5.5, 3.0]];
    // A degenerate sliver (two equal vertices) and a point-like triangle.
    let sliver = [[0.2, 0.3, 0.25], [7.7, 7.6, 7.3], [0.2, 0.3, 0.25]];
    let point = [[6.5, 1.5, 6.5]; 3];
    for t in [flat, sliver, point] {
        let s = TriSetup::new(t);
        let fast = bricks_to_set(&rasterize_bricks(&grid, &[s], &|_, _| true));
        let slow = brute_force(&grid, &[t]);
        assert!(slow.is_subset(&fast), "{t:?}: fast misses voxels");
        assert!(!fast.is_empty());
    }
}

/// Two triangles covering the square [0,1]² at height `z`, with UVs across it.
fn quad_mesh(z: f32, material: u32) -> Mesh {
    Mesh {
        positions: vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        triangle_materials: vec![material; 2],
        materials: vec![Material::default(); (material + 1) as usize],
        ..Default::default()
    }
}

#[test]
fn colour_comes_from_the_texture_and_alpha_test_removes_holes() {
    let mut mesh = quad_mesh(0.5, 0);
    mesh.materials[0].diffuse = [1.0, 1.0, 1.0, 1.0];
    mesh.materials[0].color_map = Some(0);
    // Left half opaque red, right half transparent.
    let tex = Rgba8Image {
        width: 2,
        height: 1,
        pixels: vec![[255, 0, 0, 255], [0, 255, 0, 0]],
    };
    let grid = Grid {
        origin: [0.0, 0.0, 0.0],
        voxel_size: [0.125; 3],
        dims: [8, 8, 8],
    };
    let v = mesh_to_voxels_in(&mesh, &[Some(tex)], &grid, &VoxelizeOptions::surface(8)).unwrap();
    assert!(v.count() > 0);
    for (k, c) in v.keys().iter().zip(&v.colors) {
        let p = morton_decode(*k);
        assert!(
            p[0] < 4,
            "voxel {p:?} in the transparent half survived the alpha test"
        );
        assert!(
            (c[0] - 1.0).abs() < 1e-6 && c[1] == 0.0 && c[3] == 1.0,
            "{c:?}"
        );
    }
    for n in &v.normals {
        assert!((n[2] - 1.0).abs() < 1e-6);
    }
    // Without the alpha channel's holes both halves voxelize (z = 0.5 lies on a voxel face).
    let mut tex2 = Rgba8Image {
        width: 2,
        height: 1,
        pixels: vec![[255, 0, 0, 255], [0, 255, 0, 255]],
    };
    tex2.pixels[1][3] = 255;
    let full =
        mesh_to_voxels_in(&mesh, &[Some(tex2)], &grid, &VoxelizeOptions::surface(8)).unwrap();
    assert_eq!(full.count(), 8 * 8 * 2);
}

/// A closed axis-aligned box mesh from `lo` to `hi`, outward-facing.
pub fn box_mesh(lo: [f32; 3], hi: [f32; 3]) -> Mesh {
    let p = |i: usize| {
        [
            if i & 1 == 1 { hi[0] } else { lo[0] },
            if i & 2 == 2 { hi[1] } else { lo[1] },
            if i & 4 == 4 { hi[2] } else { lo[2] },
        ]
    };
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut indices = Vec::new();
    for q in quads {
        indices.push([q[0], q[1], q[2]]);
        indices.push([q[0], q[2], q[3]]);
    }
    let n = indices.len();
    Mesh {
        positions: (0..8).map(p).collect(),
        normals: vec![[0.0, 0.0, 1.0]; 8],
        uvs: vec![[0.0; 2]; 8],
        indices,
        triangle_materials: vec![0; n],
        materials: vec![Material::default()],
        ..Default::default()
    }
}

#[test]
fn solid_fill_adds_exactly_the_interior_voxel_centres() {
    let mesh = box_mesh([1.3, 2.2, 0.7], [9.6, 7.1, 5.4]);
    let grid = unit_grid([12, 10, 8]);
    let mut opts = VoxelizeOptions::surface(12);
    let surface = mesh_to_voxels_in(&mesh, &[], &grid, &opts).unwrap();
    opts.solid = true;
    let solid = mesh_to_voxels_in(&mesh, &[], &grid, &opts).unwrap();
    assert_eq!(solid.open_columns, 0);
    let got = bricks_to_set(&solid.bricks);
    let mut want = bricks_to_set(&surface.bricks);
    for z in 0..8 {
        for y in 0..10 {
            for x in 0..12 {
                let c = [x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5];
                if c[0] > 1.3 && c[0] < 9.6 && c[1] > 2.2 && c[1] < 7.1 && c[2] > 0.7 && c[2] < 5.4
                {
                    want.insert([x, y, z]);
                }
            }
        }
    }
    assert_eq!(got, want);
    assert_eq!(solid.colors.len(), got.len());
}

#[test]
fn voxelization_is_independent_of_thread_count() {
    let mut rng = Rng::new(3);
    let tris = random_tris(&mut rng, 300, [100, 60, 80], 10.0);
    let mut mesh = Mesh::default();
    for t in &tris {
        let b = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(t);
        mesh.normals.extend_from_slice(&[[0.0, 0.0, 1.0]; 3]);
        mesh.uvs.extend_from_slice(&[[0.0; 2]; 3]);
        mesh.indices.push([b, b + 1, b + 2]);
        mesh.triangle_materials.push(0);
    }
    mesh.materials.push(Material::default());
    let opts = VoxelizeOptions::surface(100);
    let a = mesh_to_voxels(&mesh, &[], &opts).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = pool.install(|| mesh_to_voxels(&mesh, &[], &opts).unwrap());
    assert_eq!(a, b);
}

/// Random voxel sets: a noisy sphere shell and scattered voxels, in a non-cubic grid.
pub(crate) fn random_voxels(rng: &mut Rng, dims: [u32; 3]) -> Voxels {
    let mut keys = Vec::new();
    let c = dims.map(|d| d as f32 / 2.0);
    let r = c[0].min(c[1]).min(c[2]) * 0.8;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let d = [
                    x as f32 + 0.5 - c[0],
                    y as f32 + 0.5 - c[1],
                    z as f32 + 0.5 - c[2],
                ];
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if (l - r).abs() < 0.9 || rng.f32() < 0.002 {
                    keys.push(morton_encode([x, y, z]));
                }
            }
        }
    }
    keys.sort_unstable();
    let bricks = bricks_of_keys(keys.iter().copied());
    let colors = (0..keys.len())
        .map(|_| [rng.f32(), rng.f32(), rng.f32(), rng.f32()])
        .collect();
    let normals = (0..keys.len()).map(|_| [0.0, 0.0, 1.0]).collect();
    Voxels {
        grid: unit_grid(dims),
        bricks,
        colors,
        normals,
        skipped_triangles: 0,
        open_columns: 0,
    }
}

#[test]
fn leaf_set_round_trips_through_the_octree() {
    let mut rng = Rng::new(11);
    for dims in [[37, 20, 45], [4, 4, 4], [130, 17, 9]] {
        let v = random_voxels(&mut rng, dims);
        let svo = voxels_to_svo(&v);
        section::validate(&svo).unwrap();
        assert_eq!(svo.leaf_bricks(), v.bricks, "dims {dims:?}");
        let keys = v.keys();
        for (i, &k) in keys.iter().enumerate() {
            assert_eq!(svo.voxel_index(morton_decode(k)), Some(i));
            assert_eq!(
                svo.voxel_colors[i],
                super::svo::pack_rgba8(premul(v.colors[i]))
            );
        }
        let set: HashSet<u64> = keys.iter().copied().collect();
        for _ in 0..2000 {
            let c = dims.map(|d| (rng.next_u64() % d as u64) as u32);
            assert_eq!(
                svo.voxel_index(c).is_some(),
                set.contains(&morton_encode(c))
            );
        }
    }
}

fn premul(c: [f32; 4]) -> [f32; 4] {
    [c[0] * c[3], c[1] * c[3], c[2] * c[3], c[3]]
}

#[test]
fn parents_hold_the_premultiplied_mean_of_their_cells() {
    let mut rng = Rng::new(5);
    let v = random_voxels(&mut rng, [40, 40, 40]);
    let svo = voxels_to_svo(&v);
    let mut at = 0;
    for (b, &mask) in svo.bricks.iter().enumerate() {
        let k = mask.count_ones() as usize;
        let mut want = [0.0f32; 4];
        for c in &v.colors[at..at + k] {
            let p = premul(*c);
            for j in 0..4 {
                want[j] += p[j] / 64.0;
            }
        }
        let got = unpack_rgba8(svo.node_colors[svo.nodes.len() + b]);
        for j in 0..4 {
            assert!(
                (got[j] - want[j]).abs() <= 0.5 / 255.0 + 1e-6,
                "brick {b}: {got:?} vs {want:?}"
            );
        }
        at += k;
    }
    // The root's alpha is the occupied fraction of its 4^L cube.
    let root = unpack_rgba8(svo.node_colors[0]);
    let side = 4f64.powi(svo.levels as i32);
    let want: f64 = v.colors.iter().map(|c| c[3] as f64).sum::<f64>() / side.powi(3);
    assert!((root[3] as f64 - want).abs() <= 0.5 / 255.0 + 1e-6);
}

#[test]
fn svo_traversal_equals_brute_force_dda() {
    let mut rng = Rng::new(21);
    for dims in [[37, 20, 45], [64, 64, 64], [130, 17, 9]] {
        let v = random_voxels(&mut rng, dims);
        let svo = voxels_to_svo(&v);
        let set: HashSet<[u32; 3]> = bricks_to_set(&v.bricks);
        let (mut hits, mut ties) = (0, 0);
        for i in 0..3000 {
            let r = random_ray(&mut rng, dims, i % 3 == 0);
            let a = trace_svo(&svo, &r);
            let b = trace_dda(dims, |c| set.contains(&c), &r);
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) if a == b => hits += 1,
                (Some(a), Some(b)) => {
                    // Only a ray through a shared edge or corner may pick either voxel.
                    assert!((a.t - b.t).abs() < 1e-4, "{r:?}: {a:?} vs {b:?}");
                    assert_eq!(voxel_entry_t(&r, a.voxel), a.t);
                    ties += 1;
                }
                _ => panic!("{r:?}: octree {a:?}, dda {b:?}"),
            }
        }
        assert!(hits > 500, "too few hits ({hits}) to mean anything");
        assert!(ties < 10, "{ties} ties");
    }
}

fn random_ray(rng: &mut Rng, dims: [u32; 3], inside: bool) -> VoxelRay {
    let o = if inside {
        dims.map(|d| rng.range(0.0, d as f32))
    } else {
        dims.map(|d| rng.range(-20.0, d as f32 + 20.0))
    };
    let target = dims.map(|d| rng.range(0.0, d as f32));
    let mut dir = [0, 1, 2].map(|k| target[k] - o[k]);
    // Some rays parallel to an axis or a plane.
    if rng.f32() < 0.1 {
        dir[(rng.next_u64() % 3) as usize] = 0.0;
    }
    VoxelRay {
        origin: o,
        dir,
        t_min: 0.0,
        t_max: if rng.f32() < 0.2 {
            rng.range(0.0, 1.0)
        } else {
            f32::INFINITY
        },
    }
}

#[test]
fn section_round_trips_and_dump_lists_the_voxels() {
    let mut rng = Rng::new(2);
    let v = random_voxels(&mut rng, [20, 9, 14]);
    let svo = voxels_to_svo(&v);
    let sec = section::to_section("svo", "test", &svo, false);
    let mut w = crate::pack::PackWriter::new();
    w.insert(sec);
    let bytes = w.to_bytes().unwrap();
    let pack = crate::pack::Pack::from_bytes(&bytes, "mem").unwrap();
    let view = pack.view_named("svo").unwrap();
    let (_, back) = section::from_section(&view).unwrap();
    assert_eq!(back, svo);
    let s = section::summary(&view).unwrap();
    assert_eq!(s["voxels"], v.count());
    assert_eq!(s["resolution"], serde_json::json!([20, 9, 14]));
    let d = section::data(&view).unwrap();
    let listed: HashSet<[u32; 3]> = serde_json::from_value(d["voxels"].clone()).unwrap();
    assert_eq!(listed, bricks_to_set(&v.bricks));
}
