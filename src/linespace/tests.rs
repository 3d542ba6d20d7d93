//! Invariants of the N-tree and its line spaces against brute-force oracles: a full-matrix build
//! with the separating-axis shaft test, random segments between patches, exact shadow rays.

use super::dense::{DenseNTree, build_dense};
use super::layout::{FACES, Layout, get};
use super::ntree::{NTree, NTreeOptions, Refine, build_ntree};
use super::query::{AreaLight, ExactShadow, QueryStats, Segment};
use super::shaft::{ChildMasks, ShaftCells, ShaftTable, patch_box, shaft_meets_cell_sat};
use crate::voxel::tests::Rng;
use crate::voxel::voxelize::tri_box_overlap_reference;
use std::sync::Arc;

fn random_tris(rng: &mut Rng, count: usize, size: f32) -> Vec<[[f32; 3]; 3]> {
    (0..count)
        .map(|_| {
            let c = [
                rng.range(0.0, 10.0),
                rng.range(0.0, 10.0),
                rng.range(0.0, 10.0),
            ];
            std::array::from_fn(|_| [0, 1, 2].map(|k| c[k] + rng.range(-size, size)))
        })
        .collect()
}

/// Two big triangles spanning the scene's bounds, so added geometry keeps the root box.
fn frame() -> Vec<[[f32; 3]; 3]> {
    vec![
        [[-1.0, -1.0, -1.0], [11.0, -1.0, -1.0], [11.0, 11.0, -1.0]],
        [[-1.0, 11.0, 11.0], [11.0, 11.0, 11.0], [-1.0, -1.0, 11.0]],
    ]
}

fn build(tris: &[[[f32; 3]; 3]], n: u32, depth: u32) -> NTree {
    build_ntree(
        tris,
        &NTreeOptions {
            n,
            depth,
            cubic_cells: true,
        },
        &Arc::new(ShaftTable::build(n)),
    )
    .unwrap()
}

fn dense(tris: &[[[f32; 3]; 3]], n: u32, depth: u32) -> DenseNTree {
    build_dense(
        tris,
        &NTreeOptions {
            n,
            depth,
            cubic_cells: true,
        },
        &ChildMasks::build(n),
    )
    .unwrap()
}

/// Every inner node: (group, level, world minimum corner, world size).
fn inner_nodes(t: &NTree) -> Vec<(u32, u32, [f32; 3], [f32; 3])> {
    let side = t.leaf_size.map(|s| s * t.n.pow(t.depth) as f32);
    let mut out = vec![(0, 0, t.origin, side)];
    let mut i = 0;
    while i < out.len() {
        let (g, l, o, s) = out[i];
        let cs = s.map(|x| x / t.n as f32);
        for slot in 0..t.n3() {
            if l + 1 < t.depth && t.filled(g, slot) {
                let c = [
                    slot as u32 % t.n,
                    slot as u32 / t.n % t.n,
                    slot as u32 / (t.n * t.n),
                ];
                let co = [0, 1, 2].map(|k| o[k] + c[k] as f32 * cs[k]);
                out.push((t.child(g, slot), l + 1, co, cs));
            }
        }
        i += 1;
    }
    out
}

/// Filled children of group g.
fn filled(t: &NTree, g: u32) -> Vec<[i64; 3]> {
    (0..t.n3())
        .filter(|&s| t.filled(g, s))
        .map(|s| {
            let n = t.n as usize;
            [s % n, s / n % n, s / (n * n)].map(|x| x as i64)
        })
        .collect()
}

#[test]
fn linespaces_are_bit_exact_against_a_brute_force_full_matrix() {
    let mut rng = Rng::new(17);
    let tris = random_tris(&mut rng, 12, 2.0);
    let t = build(&tris, 3, 2);
    let d = dense(&tris, 3, 2);
    let layout = Layout::new(3);
    let pp = 9u32;
    for (g, _, _, _) in inner_nodes(&t) {
        let kids = filled(&t, g);
        let full = layout.expand_full(d.linespace(g));
        for fa in 0..FACES {
            for pa in 0..pp {
                for fb in 0..FACES {
                    for pb in 0..pp {
                        let (a, b) = (patch_box(3, fa, pa), patch_box(3, fb, pb));
                        let want = kids.iter().any(|&c| shaft_meets_cell_sat(&a, &b, c));
                        let got = get(&full, layout.full_index(fa, pa, fb, pb));
                        assert_eq!(got, want, "group {g}: {fa}:{pa} → {fb}:{pb}");
                        if let Some(b) = layout.bit(fa, pa, fb, pb) {
                            assert_eq!(t.linespace_bit(g, b), want, "compact, group {g}");
                        }
                        // Symmetry and same-face emptiness of the full matrix.
                        assert_eq!(got, get(&full, layout.full_index(fb, pb, fa, pa)));
                        if fa == fb {
                            assert!(!got);
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn filled_cells_match_the_akenine_moller_test() {
    let mut rng = Rng::new(4);
    let tris = random_tris(&mut rng, 30, 1.5);
    let t = build(&tris, 4, 2);
    for (g, level, o, s) in inner_nodes(&t) {
        if level != 1 {
            continue;
        }
        let cs = s.map(|x| x / 4.0);
        for slot in 0..64usize {
            let c = [slot % 4, slot / 4 % 4, slot / 16].map(|x| x as f32);
            let center = [0, 1, 2].map(|k| (o[k] + (c[k] + 0.5) * cs[k]) as f64);
            // Strictly inside or clearly outside: compare with a box slightly smaller and larger.
            let half_in = cs.map(|x| x as f64 * (0.5 - 1e-3));
            let half_out = cs.map(|x| x as f64 * (0.5 + 2e-3));
            let over = |h: [f64; 3]| {
                tris.iter()
                    .any(|tr| tri_box_overlap_reference(center, h, tr.map(|p| p.map(|v| v as f64))))
            };
            let got = t.filled(g, slot);
            if over(half_in) {
                assert!(got, "group {g} slot {slot} misses a triangle");
            }
            if !over(half_out) {
                assert!(!got, "group {g} slot {slot} filled without a triangle");
            }
        }
    }
}

#[test]
fn linespaces_grow_monotonically_with_added_geometry() {
    let mut rng = Rng::new(8);
    let mut tris = frame();
    tris.extend(random_tris(&mut rng, 10, 1.0));
    let a = build(&tris, 4, 2);
    tris.extend(random_tris(&mut rng, 10, 1.0));
    let b = build(&tris, 4, 2);
    assert_eq!(a.origin, b.origin);
    let nodes_b = inner_nodes(&b);
    for (ga, la, oa, _) in inner_nodes(&a) {
        let (gb, ..) = nodes_b
            .iter()
            .find(|(_, lb, ob, _)| *lb == la && *ob == oa)
            .expect("a node of the smaller scene is missing");
        let lost = (0..a.layout().bits())
            .find(|&bit| a.linespace_bit(ga, bit) && !b.linespace_bit(*gb, bit));
        assert_eq!(lost, None, "node {ga} lost a bit");
    }
}

/// Ray/triangle hit parameter on segment p + t·d, t ∈ [0, 1] (f64 Möller–Trumbore).
fn hit_t(p: [f64; 3], d: [f64; 3], tri: &[[f32; 3]; 3]) -> Option<f64> {
    let v = tri.map(|q| q.map(|x| x as f64));
    let e1 = [0, 1, 2].map(|k| v[1][k] - v[0][k]);
    let e2 = [0, 1, 2].map(|k| v[2][k] - v[0][k]);
    let cr = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dt = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let h = cr(d, e2);
    let det = dt(e1, h);
    if det.abs() < 1e-15 {
        return None;
    }
    let s = [0, 1, 2].map(|k| p[k] - v[0][k]);
    let u = dt(s, h) / det;
    let q = cr(s, e1);
    let w = dt(d, q) / det;
    let t = dt(e2, q) / det;
    (u >= 0.0 && w >= 0.0 && u + w <= 1.0 && (0.0..=1.0).contains(&t)).then_some(t)
}

#[test]
fn segments_between_patches_that_hit_geometry_land_in_set_bits() {
    let mut rng = Rng::new(99);
    let tris = random_tris(&mut rng, 25, 2.0);
    let t = build(&tris, 4, 2);
    let layout = Layout::new(4);
    let (mut checked, mut hits) = (0, 0);
    for (g, _, o, s) in inner_nodes(&t) {
        for _ in 0..3000 {
            let (fa, fb) = ((rng.next_u64() % 6) as usize, (rng.next_u64() % 6) as usize);
            if fa == fb {
                continue;
            }
            let (pa, pb) = ((rng.next_u64() % 16) as u32, (rng.next_u64() % 16) as u32);
            let point = |f: usize, p: u32, rng: &mut Rng| {
                let b = patch_box(4, f, p);
                [0, 1, 2].map(|k| {
                    let x = b.lo[k] as f64 + (b.hi[k] - b.lo[k]) as f64 * rng.f32() as f64;
                    o[k] as f64 + x * s[k] as f64 / 4.0
                })
            };
            let (a, b) = (point(fa, pa, &mut rng), point(fb, pb, &mut rng));
            let d = [0, 1, 2].map(|k| b[k] - a[k]);
            checked += 1;
            if tris.iter().any(|tr| hit_t(a, d, tr).is_some()) {
                hits += 1;
                let bit = layout.bit(fa, pa, fb, pb).unwrap();
                assert!(
                    t.linespace_bit(g, bit),
                    "node {g}: {fa}:{pa} → {fb}:{pb} hits geometry but reads empty"
                );
            }
        }
    }
    assert!(hits > 100 && hits < checked, "{hits} of {checked}");
}

#[test]
fn linespace_shadow_is_never_brighter_than_exact_shadow_rays() {
    let mut rng = Rng::new(123);
    for (n, depth) in [(4, 2), (3, 3), (10, 2)] {
        let mut tris = random_tris(&mut rng, 200, 0.8);
        tris.push([[-2.0, -2.0, -0.5], [12.0, -2.0, -0.5], [12.0, 12.0, -0.5]]);
        tris.push([[-2.0, -2.0, -0.5], [12.0, 12.0, -0.5], [-2.0, 12.0, -0.5]]);
        let mut t = build(&tris, n, depth);
        t.refine = [Refine::Shaft, Refine::Cells, Refine::Exact, Refine::Near][(n % 4) as usize];
        let exact = ExactShadow::new(&tris);
        let light = AreaLight {
            corner: [2.0, 3.0, 14.0],
            edge_u: [4.0, 0.0, 0.0],
            edge_v: [0.0, 3.0, 1.0],
            samples: 4,
        };
        let mut stats = QueryStats::default();
        let (mut lit, mut blocked, mut over) = (0, 0, 0);
        for i in 0..600 {
            let tri = &tris[rng.next_u64() as usize % tris.len()];
            let (mut a, mut b) = (rng.f32(), rng.f32());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let p = [0, 1, 2]
                .map(|k| tri[0][k] + a * (tri[1][k] - tri[0][k]) + b * (tri[2][k] - tri[0][k]));
            // Some receivers in free space, some far outside the root box.
            let p = match i % 10 {
                0 => [
                    rng.range(-5.0, 15.0),
                    rng.range(-5.0, 15.0),
                    rng.range(-5.0, 15.0),
                ],
                _ => p,
            };
            for s in 0..16 {
                let seg = Segment::between(p, light.sample(s), 1e-3);
                let e = exact.occluded(&seg);
                assert_eq!(
                    e,
                    exact.occluded_brute_force(&seg),
                    "BVH and brute force disagree"
                );
                let l = t.segment_occluded(&seg, &mut stats);
                assert!(
                    !e || l,
                    "n {n} depth {depth}: {seg:?} is shadowed but the line space says lit"
                );
                match (e, l) {
                    (false, false) => lit += 1,
                    (true, _) => blocked += 1,
                    (false, true) => over += 1,
                }
            }
        }
        assert!(
            lit > 1000 && blocked > 500,
            "n {n}: lit {lit}, blocked {blocked}, over {over}"
        );
        assert!(stats.linespace_lookups > 0);
    }
}

#[test]
fn section_round_trips() {
    let mut rng = Rng::new(1);
    let t = build(&random_tris(&mut rng, 20, 1.0), 4, 2);
    let mut w = crate::pack::PackWriter::new();
    w.insert(super::section::to_section("linespace", "test", &t));
    let bytes = w.to_bytes().unwrap();
    let pack = crate::pack::Pack::from_bytes(&bytes, "mem").unwrap();
    let view = pack.view_named("linespace").unwrap();
    let (_, back) = super::section::from_section(&view).unwrap();
    assert_eq!(back, t);
    let s = super::section::summary(&view).unwrap();
    assert_eq!(s["n"], 4);
    assert_eq!(s["bits_per_linespace"], 15 * 256);
    assert_eq!(s["inner_nodes"], t.inner_nodes());
}

/// Random segments of a scene: receivers on the triangles and some in free space, to the
/// samples of a tilted quad light.
fn scene_segments(rng: &mut Rng, tris: &[[[f32; 3]; 3]], count: usize) -> Vec<Segment> {
    let light = AreaLight {
        corner: [2.0, 3.0, 14.0],
        edge_u: [4.0, 0.0, 0.0],
        edge_v: [0.0, 3.0, 1.0],
        samples: 4,
    };
    let mut out = Vec::new();
    for i in 0..count {
        let tri = &tris[rng.next_u64() as usize % tris.len()];
        let (mut a, mut b) = (rng.f32(), rng.f32());
        if a + b > 1.0 {
            (a, b) = (1.0 - a, 1.0 - b);
        }
        let p = match i % 10 {
            0 => [0, 1, 2].map(|_| rng.range(-5.0, 15.0)),
            _ => [0, 1, 2]
                .map(|k| tri[0][k] + a * (tri[1][k] - tri[0][k]) + b * (tri[2][k] - tri[0][k])),
        };
        out.extend((0..16).map(|s| Segment::between(p, light.sample(s), 1e-3)));
    }
    out
}

#[test]
fn shaft_table_equals_the_transposed_child_masks() {
    for n in 2..=5 {
        assert_eq!(
            ShaftCells::build(n),
            ShaftCells::from_masks(&ChildMasks::build(n)),
            "n {n}"
        );
    }
}

#[test]
fn compact_line_spaces_read_every_bit_of_the_dense_pool() {
    let mut rng = Rng::new(31);
    for (n, depth, stride) in [(3, 2, 1), (4, 2, 1), (5, 2, 7), (10, 2, 997)] {
        let tris = random_tris(&mut rng, 40, 1.5);
        let t = build(&tris, n, depth);
        let d = dense(&tris, n, depth);
        let mut ones = 0;
        for g in 0..t.inner_nodes() as u32 {
            for b in (0..t.layout().bits()).step_by(stride) {
                let want = get(d.linespace(g), b);
                assert_eq!(t.linespace_bit(g, b), want, "n {n} group {g} bit {b}");
                ones += want as usize;
            }
        }
        assert!(ones > 0, "n {n}: no full shaft to compare");
    }
}

#[test]
fn compact_children_equal_the_dense_node_pool() {
    let mut rng = Rng::new(12);
    for (n, depth) in [(3, 3), (4, 2), (10, 2), (2, 5)] {
        let mut tris = random_tris(&mut rng, 60, 1.0);
        tris.extend(frame());
        let t = build(&tris, n, depth);
        let d = dense(&tris, n, depth);
        assert_eq!(t.level_groups, d.level_groups);
        let deepest = t.level_groups[depth as usize - 1];
        let mut leaves = 0;
        for g in 0..t.inner_nodes() as u32 {
            for slot in 0..t.n3() {
                let e = d.entry(g, slot);
                assert_eq!(
                    t.filled(g, slot),
                    e.geometry(),
                    "n {n} group {g} slot {slot}"
                );
                if !e.geometry() {
                    continue;
                }
                assert_eq!(e.children(), g < deepest);
                if e.children() {
                    assert_eq!(t.child(g, slot), e.group(), "group {g} slot {slot}");
                } else {
                    let (a, k) = e.leaf_triangles();
                    let want = &d.tri_indices[a as usize..(a + k) as usize];
                    assert_eq!(t.leaf_triangles(t.child(g, slot)), want);
                    leaves += 1;
                }
            }
        }
        assert_eq!(leaves, t.leaves());
        assert_eq!(t.tri_indices, d.tri_indices);
        // The compact form is smaller than the dense pools (both exclude the triangles).
        let (nodes, ls) = d.bytes();
        assert!(8 * t.occupancy.len() + 4 * t.first_child.len() < nodes + ls);
    }
}

#[test]
fn shaft_table_queries_equal_dense_pool_queries_in_every_refine_mode() {
    let mut rng = Rng::new(77);
    let mut tris = random_tris(&mut rng, 150, 0.8);
    tris.extend(frame());
    let mut t = build(&tris, 4, 3);
    let d = dense(&tris, 4, 3);
    let segs = scene_segments(&mut rng, &tris, 300);
    for refine in [Refine::Shaft, Refine::Cells, Refine::Exact, Refine::Near] {
        t.refine = refine;
        let mut reference = t.clone();
        reference.dense_linespaces = Some(Arc::new(d.linespaces.clone()));
        let (mut stats, mut ref_stats) = (QueryStats::default(), QueryStats::default());
        let compact: Vec<bool> = segs
            .iter()
            .map(|s| t.segment_occluded(s, &mut stats))
            .collect();
        let pool: Vec<bool> = segs
            .iter()
            .map(|s| reference.segment_occluded(s, &mut ref_stats))
            .collect();
        assert_eq!(compact, pool, "{refine:?}");
        assert_eq!(stats, ref_stats);
        assert!(pool.iter().any(|h| *h) && pool.iter().any(|h| !*h));
    }
    let other = Arc::new(ShaftTable::build(3));
    assert!(
        build_ntree(
            &tris,
            &NTreeOptions {
                n: 4,
                depth: 3,
                cubic_cells: true
            },
            &other
        )
        .is_err()
    );
}

#[test]
fn exact_refinement_gives_the_exact_answers() {
    let mut rng = Rng::new(5);
    let mut tris = random_tris(&mut rng, 200, 0.8);
    tris.extend(frame());
    let mut t = build(&tris, 5, 2);
    t.refine = Refine::Exact;
    let exact = ExactShadow::new(&tris);
    let segs = scene_segments(&mut rng, &tris, 400);
    let mut stats = QueryStats::default();
    let differ = segs
        .iter()
        .filter(|s| t.segment_occluded(s, &mut stats) != exact.occluded_brute_force(s))
        .count();
    assert_eq!(differ, 0);
    assert!(stats.linespace_lookups > 0);
}

#[test]
fn corrupt_sections_are_rejected_with_a_message() {
    let mut rng = Rng::new(1);
    let t = build(&random_tris(&mut rng, 20, 1.0), 4, 2);
    let bytes_of = |t: &NTree| {
        let mut w = crate::pack::PackWriter::new();
        w.insert(super::section::to_section("linespace", "test", t));
        w.to_bytes().unwrap()
    };
    let mut bad_child = t.clone();
    bad_child.first_child[0] = 1 << 30;
    let mut bad_leaf = t.clone();
    *bad_leaf.leaf_tris.last_mut().unwrap() += 1;
    let mut bad_table = t.clone();
    bad_table.shafts = Arc::new(ShaftTable::build(3));
    for (what, t) in [
        ("children", bad_child),
        ("leaf_tris", bad_leaf),
        ("shaft_cells", bad_table),
    ] {
        let bytes = bytes_of(&t);
        let pack = crate::pack::Pack::from_bytes(&bytes, "mem").unwrap();
        let view = pack.view_named("linespace").unwrap();
        let err = super::section::from_section(&view).unwrap_err().to_string();
        assert!(err.contains(what), "{err}");
    }
}
