//! The two-level line-space structure against independent oracles: exact obvhs shadow rays over
//! the flattened placed scene (the triangles `geometry::place_instance` makes), the flattened
//! single-level N-tree of the same scene, and a brute force over every instance's placed
//! triangles ([`ExactInstances`]).

use super::*;
use crate::linespace::accuracy::{compare, stratified_points};
use crate::linespace::ntree::build_ntree;
use crate::linespace::query::{AreaLight, ExactShadow};
use crate::model::Mesh;
use crate::rng::Rng;
use crate::voxel::geometry::{Geometry, place_instance, procedural_blob, terrain_mesh};

fn hills() -> Terrain {
    let (w, h) = (33u32, 25u32);
    let heights = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            0.5 * (0.3 * x).sin() + 0.4 * (0.25 * y).cos()
        })
        .collect();
    Terrain {
        width: w,
        height: h,
        heights,
        origin: [-16.0, -12.0],
        extent: [32.0, 24.0],
        color: None,
    }
}

/// A small tree: a trunk box and a few tilted leaf cards around it (thin, open geometry).
fn card_tree() -> Mesh {
    let mut m = Mesh::default();
    let mut quad = |q: [[f32; 3]; 4]| {
        let b = m.positions.len() as u32;
        m.positions.extend(q);
        m.normals.extend([[0.0, 0.0, 1.0]; 4]);
        m.uvs.extend([[0.0; 2]; 4]);
        m.indices.push([b, b + 1, b + 2]);
        m.indices.push([b, b + 2, b + 3]);
    };
    // Trunk: four sides of a 0.2 m square column, 1.5 m high.
    let (r, h) = (0.1f32, 1.5f32);
    let c = [[-r, -r], [r, -r], [r, r], [-r, r]];
    for k in 0..4 {
        let (a, b) = (c[k], c[(k + 1) % 4]);
        quad([
            [a[0], a[1], 0.0],
            [b[0], b[1], 0.0],
            [b[0], b[1], h],
            [a[0], a[1], h],
        ]);
    }
    // Eight leaf cards, 0.9 × 0.4 m, tilted, at two heights.
    for k in 0..8 {
        let phi = k as f32 * std::f32::consts::TAU / 8.0 + 0.3;
        let (s, co) = phi.sin_cos();
        let z = 1.2 + 0.35 * (k % 2) as f32;
        let out = |d: f32, w: f32, dz: f32| [co * d - s * w, s * d + co * w, z + dz];
        quad([
            out(0.05, -0.2, 0.0),
            out(0.95, -0.2, -0.25),
            out(0.95, 0.2, -0.25),
            out(0.05, 0.2, 0.0),
        ]);
    }
    m.triangle_materials = vec![0; m.indices.len()];
    m.materials.push(crate::model::Material::default());
    m
}

fn models() -> Vec<Mesh> {
    let mut blob = procedural_blob(14, 9);
    for p in &mut blob.positions {
        *p = [p[0] * 0.6, p[1] * 0.6, p[2] * 0.6 + 0.7];
    }
    vec![card_tree(), blob]
}

/// Instances over the terrain: rotated, scaled 0.6–1.8, one mirrored (negative scale) and one
/// of zero scale (placed degenerate: it blocks nothing).
fn scatter(t: &Terrain, count: usize, seed: u64) -> Vec<Instance> {
    let mut rng = Rng::new(seed);
    let mut out: Vec<Instance> = (0..count)
        .map(|k| {
            let x = -13.0 + 26.0 * rng.f32();
            let y = -9.0 + 18.0 * rng.f32();
            let z = t.mesh_height_at(x, y) - 0.05;
            Instance::new(
                (k % 2) as u32,
                [x, y, z],
                0.6 + 1.2 * rng.f32(),
                360.0 * rng.f32(),
            )
        })
        .collect();
    out[3].scale = -out[3].scale;
    out[5].scale = 0.0;
    out
}

struct Case {
    terrain: Terrain,
    models: Vec<Mesh>,
    instances: Vec<Instance>,
}

impl Case {
    fn new(count: usize, seed: u64) -> Case {
        let terrain = hills();
        let instances = scatter(&terrain, count, seed);
        Case {
            terrain,
            models: models(),
            instances,
        }
    }

    fn named(&self) -> Vec<ModelTriangles> {
        self.models
            .iter()
            .enumerate()
            .map(|(i, m)| Some((format!("mesh:{i}"), crate::linespace::world_triangles(m))))
            .collect()
    }

    fn two_level(&self, opts: &NTreeOptions) -> SceneLinespace {
        let shafts = Arc::new(ShaftTable::build(opts.n));
        SceneLinespace::build(
            Some(&self.terrain),
            &self.named(),
            &self.instances,
            opts,
            &shafts,
        )
        .unwrap()
    }

    /// The flattened scene's triangles, as `geometry::pack_geometry` places them.
    fn flattened(&self) -> Vec<[[f32; 3]; 3]> {
        let mut g = terrain_mesh(&self.terrain);
        for i in &self.instances {
            let m = Geometry {
                mesh: self.models[i.model as usize].clone(),
                textures: Vec::new(),
            };
            g.append(place_instance(&m, i));
        }
        crate::linespace::world_triangles(&g.mesh)
    }

    /// [`Self::flattened`] without the zero-scale instance's triangles (each collapsed to one
    /// point: no ray hits them, and obvhs' builder cannot split 80 coincident ones).
    fn flattened_hittable(&self) -> Vec<[[f32; 3]; 3]> {
        let mut t = self.flattened();
        t.retain(|t| !(t[0] == t[1] && t[1] == t[2]));
        t
    }
}

const OPTS: NTreeOptions = NTreeOptions {
    n: 4,
    depth: 3,
    cubic_cells: true,
};

/// Receivers on the terrain and on the instances' models, a light above the scene.
fn setup(c: &Case, count: usize) -> (Vec<[f32; 3]>, AreaLight) {
    let mut rng = Rng::new(11);
    let receivers = (0..count)
        .map(|k| {
            if k % 3 == 2 {
                // Near an instance's leaves (inside its crown).
                let i = &c.instances[k % c.instances.len()];
                [
                    i.position[0] + 0.5 * (rng.f32() - 0.5),
                    i.position[1] + 0.5 * (rng.f32() - 0.5),
                    i.position[2] + 0.6 + 0.8 * rng.f32(),
                ]
            } else {
                let (x, y) = (-14.0 + 28.0 * rng.f32(), -10.0 + 20.0 * rng.f32());
                [x, y, c.terrain.mesh_height_at(x, y)]
            }
        })
        .collect();
    let light = AreaLight {
        corner: [-3.0, -2.0, 6.0],
        edge_u: [5.0, 0.0, 0.0],
        edge_v: [0.0, 4.0, 0.5],
        samples: 4,
    };
    (receivers, light)
}

fn segments(receivers: &[[f32; 3]], points: &[[f32; 3]]) -> Vec<Segment> {
    receivers
        .iter()
        .flat_map(|&p| points.iter().map(move |&q| Segment::between(p, q, 1e-3)))
        .collect()
}

/// In `exact` mode the two-level answer is the flattened scene's exact answer on every segment:
/// against obvhs over the placed triangles, against the flattened N-tree, and against the
/// brute force over instances; rotated, scaled and mirrored instances included.
#[test]
fn exact_two_level_equals_flattened_exact_visibility() {
    let c = Case::new(40, 5);
    let two = c.two_level(&OPTS);
    assert_eq!(
        two.instances.len(),
        39,
        "the zero-scale instance is skipped"
    );
    assert_eq!(two.models.len(), 2);
    let flat_tris = c.flattened();
    let exact = ExactShadow::new(&c.flattened_hittable());
    let flat = build_ntree(&flat_tris, &OPTS, &Arc::new(ShaftTable::build(OPTS.n))).unwrap();
    let brute = ExactInstances::new(&two);
    let (receivers, light) = setup(&c, 150);
    let points = stratified_points(&light, 6, 2);
    let segs = segments(&receivers, &points);
    let mut stats = QueryStats::default();
    let (mut blocked, mut vs_obvhs, mut vs_flat, mut vs_brute) = (0, 0, 0, 0);
    for s in &segs {
        let a = two.segment_occluded(s, &mut stats);
        let e = exact.occluded(s);
        blocked += e as usize;
        vs_obvhs += (a != e) as usize;
        vs_flat += (a != flat.segment_occluded(s, &mut QueryStats::default())) as usize;
        vs_brute += (a != brute.occluded(s)) as usize;
    }
    assert!(
        blocked > segs.len() / 10 && blocked < segs.len() * 9 / 10,
        "{blocked} of {}",
        segs.len()
    );
    assert_eq!((vs_obvhs, vs_flat, vs_brute), (0, 0, 0), "{stats:?}");
    assert!(stats.linespace_lookups > 0 && stats.exact_triangle_tests > 0);
}

/// Soft shadows against exact area-light visibility to the same light points: one-sided in
/// every mode, no error in `exact`, small in `near`.
#[test]
fn soft_shadows_are_never_brighter_than_exact_visibility() {
    let c = Case::new(40, 9);
    let mut two = c.two_level(&OPTS);
    let exact = ExactShadow::new(&c.flattened_hittable());
    let (receivers, light) = setup(&c, 120);
    let points = stratified_points(&light, 8, 4);
    let ex: Vec<f32> = receivers
        .iter()
        .map(|&p| {
            let lit = points
                .iter()
                .filter(|&&q| !exact.occluded(&Segment::between(p, q, 1e-3)))
                .count();
            lit as f32 / points.len() as f32
        })
        .collect();
    for refine in [Refine::Shaft, Refine::Cells, Refine::Near, Refine::Exact] {
        two.set_refine(refine);
        assert_eq!(two.refine(), refine);
        let ls: Vec<f32> = receivers
            .iter()
            .map(|&p| {
                let mut st = QueryStats::default();
                let lit = points
                    .iter()
                    .filter(|&&q| !two.segment_occluded(&Segment::between(p, q, 1e-3), &mut st))
                    .count();
                lit as f32 / points.len() as f32
            })
            .collect();
        let r = compare(
            &crate::linespace::accuracy::Visibilities {
                linespace: ls,
                exact: ex.clone(),
                linespace_seconds: 0.0,
                exact_seconds: 0.0,
                stats: QueryStats::default(),
            },
            points.len(),
        );
        assert_eq!(r.brighter_than_exact, 0, "{refine:?}: {r:?}");
        assert!(r.mean_exact > 0.2 && r.mean_exact < 0.95, "{r:?}");
        match refine {
            Refine::Exact => assert_eq!(r.differing, 0, "{r:?}"),
            Refine::Near => assert!(r.mean_abs_error <= 0.05, "{r:?}"),
            _ => {}
        }
    }
}

#[test]
fn section_round_trips_and_answers_the_same() {
    let c = Case::new(25, 3);
    let two = c.two_level(&OPTS);
    let sec = super::super::instanced_section::to_section("linespace-scene", "scene.eco", &two);
    let v = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    let (meta, back) = super::super::instanced_section::from_section(&v).unwrap();
    assert_eq!(meta.source, "scene.eco");
    assert_eq!(back, two);
    let (receivers, light) = setup(&c, 30);
    let points = stratified_points(&light, 4, 1);
    for s in segments(&receivers, &points) {
        let mut st = QueryStats::default();
        assert_eq!(
            back.segment_occluded(&s, &mut st),
            two.segment_occluded(&s, &mut st)
        );
    }
    let j = super::super::instanced_section::summary(&v).unwrap();
    assert_eq!(j["instances"], 24);
    assert_eq!(j["models"], 2);
}

#[test]
fn the_build_is_the_same_on_one_and_two_threads() {
    let c = Case::new(30, 8);
    let bytes = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                super::super::instanced_section::to_section(
                    "linespace-scene",
                    "s",
                    &c.two_level(&OPTS),
                )
                .payload
            })
    };
    assert_eq!(bytes(1), bytes(2));
}

#[test]
fn a_terrain_without_cells_blocks_nothing() {
    let mut c = Case::new(6, 4);
    c.terrain = Terrain {
        width: 1,
        height: 5,
        heights: vec![0.0; 5],
        ..c.terrain.clone()
    };
    let two = c.two_level(&OPTS);
    assert!(two.terrain.is_none());
    assert_eq!(two.instances.len(), 5);
}

#[test]
fn a_non_finite_transform_is_refused_naming_the_instance() {
    let mut c = Case::new(10, 1);
    c.instances[7].rotation_deg = f32::NAN;
    let shafts = Arc::new(ShaftTable::build(OPTS.n));
    let e = SceneLinespace::build(Some(&c.terrain), &c.named(), &c.instances, &OPTS, &shafts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("instance 7") && e.contains("not finite"), "{e}");
}

#[test]
fn a_corrupt_section_is_an_error_not_a_panic() {
    let c = Case::new(8, 2);
    let two = c.two_level(&OPTS);
    let mut bad = two.clone();
    bad.instances[0].model = 9;
    let sec = super::super::instanced_section::to_section("linespace-scene", "s", &bad);
    let v = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    let e = super::super::instanced_section::from_section(&v).unwrap_err();
    assert!(e.to_string().contains("instance 0"), "{e}");
    let mut bad = two.clone();
    let t = bad.top.as_mut().unwrap();
    t.tri_indices[0] = 1000;
    let sec = super::super::instanced_section::to_section("linespace-scene", "s", &bad);
    let v = crate::pack::section::SectionView::parse(&sec.payload, 0).unwrap();
    let e = super::super::instanced_section::from_section(&v).unwrap_err();
    assert!(e.to_string().contains("top tree"), "{e}");
}

/// The model depth against a brute-force count of the grown boxes' cells: the deepest depth
/// whose count is within the budget.
#[test]
fn model_depth_is_the_deepest_within_the_pair_budget() {
    let opts = NTreeOptions {
        n: 4,
        depth: 4,
        cubic_cells: true,
    };
    // One large triangle over a 1 m model: coarse; 4,096 tiny ones: as deep as allowed.
    let big = vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]];
    let tiny: Vec<[[f32; 3]; 3]> = (0..4096)
        .map(|i| {
            let o = [
                (i % 16) as f32 / 16.0,
                (i / 16 % 16) as f32 / 16.0,
                (i / 256) as f32 / 16.0,
            ];
            [o, [o[0] + 1e-3, o[1], o[2]], [o[0], o[1] + 1e-3, o[2]]]
        })
        .collect();
    for (tris, margin) in [(&big, 0.0), (&tiny, 0.0), (&tiny, 0.05)] {
        let d = model_depth(tris, &opts, margin);
        let (lo, hi) = bounds(tris.iter().flatten().copied()).unwrap();
        let (origin, size) = crate::linespace::ntree::root_box_of(
            lo.map(|x| x - margin),
            hi.map(|x| x + margin),
            true,
        );
        let count = |d: u32| -> u64 {
            let leaf = size.map(|s| s / 4u32.pow(d) as f32);
            tris.iter()
                .map(|t| {
                    (0..3)
                        .map(|k| {
                            let c = |x: f32| ((x - origin[k]) / leaf[k]).floor() as i64;
                            let (a, b) = t
                                .iter()
                                .fold((f32::MAX, f32::MIN), |(a, b), p| (a.min(p[k]), b.max(p[k])));
                            (c(b + margin) - c(a - margin) + 1) as u64
                        })
                        .product::<u64>()
                })
                .sum()
        };
        let budget = MODEL_PAIRS_PER_TRIANGLE * tris.len() as u64;
        assert!(d == 1 || count(d) <= budget, "{d}");
        assert!(d == opts.depth || count(d + 1) > budget, "{d}");
    }
    assert!(model_depth(&big, &opts, 0.0) < 4);
    assert_eq!(model_depth(&tiny, &opts, 0.0), 4);
}

/// Segments that enter instances beyond the `near` zone (a low light far to the east, receivers
/// at the western edge: the forest crossed sideways): there the model trees' own rules decide,
/// still never brighter than exact, and `exact` still without error.
#[test]
fn beyond_the_near_zone_the_model_rules_stay_one_sided() {
    let c = Case::new(60, 21);
    let mut two = c.two_level(&OPTS);
    let near = two.near_distance();
    assert!(near > 0.0 && near < 12.0, "{near}");
    let exact = ExactShadow::new(&c.flattened_hittable());
    let mut rng = Rng::new(5);
    let receivers: Vec<[f32; 3]> = (0..80)
        .map(|_| {
            let (x, y) = (-15.5 + 2.0 * rng.f32(), -9.0 + 18.0 * rng.f32());
            [x, y, c.terrain.mesh_height_at(x, y) + 0.3]
        })
        .collect();
    let light = AreaLight {
        corner: [40.0, -6.0, 1.5],
        edge_u: [0.0, 12.0, 0.0],
        edge_v: [0.0, 0.0, 3.0],
        samples: 1,
    };
    let points = stratified_points(&light, 6, 7);
    let segs = segments(&receivers, &points);
    let truth: Vec<bool> = segs.iter().map(|s| exact.occluded(s)).collect();
    let blocked = truth.iter().filter(|b| **b).count();
    assert!(
        blocked > segs.len() / 10 && blocked < segs.len(),
        "{blocked}"
    );
    let mut wrong = Vec::new();
    for refine in [Refine::Shaft, Refine::Cells, Refine::Near, Refine::Exact] {
        two.set_refine(refine);
        let (mut brighter, mut darker) = (0, 0);
        for (s, &t) in segs.iter().zip(&truth) {
            let a = two.segment_occluded(s, &mut QueryStats::default());
            brighter += (t && !a) as usize;
            darker += (a && !t) as usize;
        }
        assert_eq!(brighter, 0, "{refine:?}");
        wrong.push(darker);
    }
    assert_eq!(wrong[3], 0, "exact: {wrong:?}");
    assert!(
        wrong[0] >= wrong[2] && wrong[2] > 0,
        "the near path beyond its zone: {wrong:?}"
    );
}

/// GPU = CPU on the two-level structure (ls_scene.wgsl): every segment of random receivers
/// (on placed triangles, on the terrain, anywhere) in every refinement mode equals
/// [`SceneLinespace::segment_occluded`], and without line spaces the brute-force exact
/// visibility over instances; the shadow kernel's counts equal the CPU's. Mirrored and
/// zero-scale instances included; a scene without terrain too.
#[test]
fn gpu_two_level_queries_equal_the_cpu_in_every_refine_mode() {
    use crate::gpu::{BackendChoice, init_gpu};
    use crate::linespace::instanced_gpu::validate_scene_linespace;
    let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
    let c = Case::new(40, 5);
    let mut s = c.two_level(&OPTS);
    let mut blocked = Vec::new();
    for refine in [Refine::Shaft, Refine::Cells, Refine::Exact, Refine::Near] {
        s.set_refine(refine);
        let a = validate_scene_linespace(&gpu, &s, 240, 4, 3).unwrap();
        assert!(a.agrees(), "{refine:?}: {a:?}");
        assert_eq!(a.segments, 240 * 16);
        assert!(a.penumbra > 5, "{refine:?}: {a:?}");
        blocked.push(a.occluded);
    }
    // Coarser modes block no fewer segments; the exact mode blocks some, not all.
    assert!(
        blocked[0] >= blocked[1] && blocked[1] >= blocked[2],
        "{blocked:?}"
    );
    assert!(
        blocked[2] > 200 && blocked[2] < 240 * 16 - 200,
        "{blocked:?}"
    );

    // A low sun over the hills: segments the terrain blocks (the quadtree walk).
    let dev = crate::linespace::gpu::NTreeGpu::for_scene(&gpu, &s).unwrap();
    let (receivers, _) = setup(&c, 300);
    let low: Vec<Segment> = receivers
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            let phi = k as f32 * 0.7;
            let sun = [40.0 * phi.cos(), 40.0 * phi.sin(), 3.0];
            Segment::between(p, [0, 1, 2].map(|a| p[a] + sun[a]), 1e-3)
        })
        .collect();
    let mut stats = QueryStats::default();
    let terrain_blocked = low.iter().filter(|q| s.terrain_occluded(q)).count();
    assert!(terrain_blocked > 30, "{terrain_blocked}");
    let cpu: Vec<bool> = low
        .iter()
        .map(|q| s.segment_occluded(q, &mut stats))
        .collect();
    assert_eq!(dev.segments_occluded(&low, true).unwrap(), cpu);
    let exact = ExactInstances::new(&s);
    let cpu_exact: Vec<bool> = low.iter().map(|q| exact.occluded(q)).collect();
    assert_eq!(dev.segments_occluded(&low, false).unwrap(), cpu_exact);

    let shafts = Arc::new(ShaftTable::build(OPTS.n));
    let mut bare = SceneLinespace::build(None, &c.named(), &c.instances, &OPTS, &shafts).unwrap();
    bare.set_refine(Refine::Near);
    let a = validate_scene_linespace(&gpu, &bare, 150, 3, 4).unwrap();
    assert!(a.agrees(), "no terrain: {a:?}");
    assert!(a.occluded > 20, "no terrain: {a:?}");
}

/// `near_edge` (what `bake validate` forgives the GPU): a segment through a placed triangle's
/// edge is near it, one through its middle or far from every triangle is not.
#[test]
fn near_edge_finds_segments_that_graze_a_placed_triangle() {
    let c = Case::new(6, 2);
    let s = c.two_level(&OPTS);
    let exact = ExactInstances::new(&s);
    let r = s.instances[0];
    let t = s.models[r.model as usize].tree.triangles[0].map(|p| r.to_world(p));
    let mid = |a: [f32; 3], b: [f32; 3], wa: f32| [0, 1, 2].map(|k| wa * a[k] + (1.0 - wa) * b[k]);
    // Along the triangle's normal, from 1 cm below its plane to 1 cm above.
    let e1 = [0, 1, 2].map(|k| t[1][k] - t[0][k]);
    let e2 = [0, 1, 2].map(|k| t[2][k] - t[0][k]);
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let nl = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = n.map(|x| x / nl);
    let through = |p: [f32; 3]| Segment {
        from: [0, 1, 2].map(|k| p[k] - 0.01 * n[k]),
        dir: n.map(|x| 0.02 * x),
        t_min: 0.0,
        t_max: 1.0,
    };
    let edge_point = mid(t[0], t[1], 0.5);
    let centre = [0, 1, 2].map(|k| (t[0][k] + t[1][k] + t[2][k]) / 3.0);
    assert!(exact.near_edge(&through(edge_point), 1e-4));
    assert!(!exact.near_edge(&through(centre), 1e-4));
    let far = [1e3, 1e3, 1e3];
    assert!(!exact.near_edge(&through(far), 1e-4));
}
