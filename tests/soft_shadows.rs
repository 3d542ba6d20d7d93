//! `bake render --soft-shadows` on a scene with a blocker: a plate hovering over a flat terrain
//! under a quad light. Checked per pixel against independent oracles: exact obvhs shadow rays
//! from the same receivers to the same light samples (the line space may only darken), the CPU
//! line-space query (the GPU computes the same fraction), and the image itself (terrain in the
//! umbra looks as with the ambient term alone; lit terrain is brighter). Runs on any wgpu adapter, lavapipe included.

use bake::linespace::query::{AreaLight, ExactShadow, QueryStats, Segment};
use bake::model::Terrain;
use bake::pack::{Pack, PackWriter};
use bake::render::soft_shadow::SoftShadows;
use bake::render::{Lighting, RenderOptions, Terms, render_pack};
use bake::terrain::source_section as terrain;

mod common;

/// Flat terrain over [0, 20]² at z = 0, the plate at (10, 10, 3), and the N-tree of both
/// (`common::plate_pack`).
fn build_pack() -> Pack {
    let pack = common::plate_pack(true);
    let geo = bake::voxel::geometry::pack_geometry(&pack).unwrap();
    let tris = bake::linespace::world_triangles(&geo.mesh);
    assert!(tris.len() >= 4, "terrain and plate triangles");
    pack
}

fn light() -> AreaLight {
    AreaLight {
        corner: [8.0, 8.0, 9.0],
        edge_u: [4.0, 0.0, 0.0],
        edge_v: [0.0, 4.0, 0.0],
        samples: 4,
    }
}

fn options(soft: bool) -> RenderOptions {
    RenderOptions {
        width: 96,
        height: 80,
        eye: Some([10.0, -6.0, 14.0]),
        target: Some([10.0, 10.0, 0.0]),
        fov_y_deg: 60.0,
        exposure: Some(1.0),
        lighting: Some(Lighting {
            sun_direction: [0.0, 0.0, 1.0],
            sun_irradiance: [3.0, 3.0, 3.0],
            ambient: [0.3, 0.3, 0.3],
            sun_solid_angle: 0.0,
        }),
        soft_shadows: soft.then_some(SoftShadows {
            area_light: Some(light()),
            samples: 4,
            refine: Default::default(),
            compare_exact: false,
        }),
        ..RenderOptions::default()
    }
}

#[test]
fn soft_shadows_have_a_penumbra_and_are_never_brighter_than_exact_shadow_rays() {
    let pack = build_pack();
    let out = render_pack(&pack, &options(true)).unwrap();
    let ambient_only = RenderOptions {
        terms: Terms::Ambient,
        ..options(false)
    };
    let plain = render_pack(&pack, &ambient_only).unwrap();
    assert!(plain.soft_shadows.is_none());
    let s = out.soft_shadows.as_ref().expect("the soft-shadow pass ran");
    assert_eq!((s.width, s.height), (96, 80));
    assert_eq!(s.light, light());
    let geo = bake::voxel::geometry::pack_geometry(&pack).unwrap();
    let tris = bake::linespace::world_triangles(&geo.mesh);
    let exact = ExactShadow::new(&tris);
    let (tree_meta, tree) =
        bake::linespace::section::from_section(&pack.view_named("linespace").unwrap()).unwrap();
    assert_eq!(tree_meta.n, 4);
    let k = 16;
    let (mut penumbra, mut umbra, mut darker, mut lit) = (0, 0, 0, 0);
    let mut stats = QueryStats::default();
    for (i, (p, &v)) in s.world.iter().zip(&s.visibility).enumerate() {
        if p[3] < 0.5 {
            assert_eq!(v, 1.0, "pixel {i}: no receiver is lit");
            continue;
        }
        let p = [p[0], p[1], p[2]];
        let lit_exact = (0..k)
            .filter(|&j| !exact.occluded(&Segment::between(p, s.light.sample(j), s.offset)))
            .count();
        let exact_fraction = lit_exact as f32 / k as f32;
        assert!(
            v <= exact_fraction + 1e-6,
            "pixel {i} at {p:?}: line space {v} brighter than exact {exact_fraction}"
        );
        let cpu = tree.shadow(p, &s.light, s.offset, &mut stats);
        assert!((v - cpu).abs() <= 1e-6, "pixel {i}: GPU {v}, CPU {cpu}");
        if v > 0.0 && v < 1.0 {
            penumbra += 1;
        }
        let (a, b) = (out.image.pixels[i], plain.image.pixels[i]);
        if v == 0.0 {
            umbra += 1;
            // Terrain in the umbra (not the plate's top) gets no sun: the ambient term alone.
            if p[2] < 0.5 {
                assert!(
                    a[0].abs_diff(b[0]) <= 1,
                    "pixel {i}: {a:?} vs ambient {b:?}"
                );
                darker += 1;
            }
        } else if v == 1.0 && p[2] < 0.5 {
            assert!(a[0] > b[0] + 10, "pixel {i}: lit {a:?} vs ambient {b:?}");
            lit += 1;
        }
    }
    assert!(penumbra >= 20, "only {penumbra} penumbra pixels");
    assert!(
        umbra >= 20 && darker >= 20,
        "umbra {umbra}, darker {darker}"
    );
    assert!(lit >= 20, "lit {lit}");
    assert_eq!(s.stats.penumbra_pixels, penumbra as u64);
}

/// `--shadow-compare`: the GPU pass against exact ray-traced visibility of the same receivers
/// and samples. The thesis' refinement is darker somewhere and never brighter; the exact
/// refinement matches the ray-traced pass on every pixel.
#[test]
fn soft_shadow_comparison_with_exact_rays_is_one_sided_per_refinement() {
    use bake::linespace::ntree::Refine;
    let pack = build_pack();
    let mut errors = Vec::new();
    for refine in [Refine::Shaft, Refine::Cells, Refine::Exact] {
        let mut opts = options(true);
        opts.soft_shadows = Some(SoftShadows {
            area_light: Some(light()),
            samples: 4,
            refine,
            compare_exact: true,
        });
        let out = render_pack(&pack, &opts).unwrap();
        let s = out.soft_shadows.unwrap();
        let c = s.comparison.expect("the comparison ran");
        assert_eq!(c.refine, refine);
        assert_eq!(c.samples, 16);
        assert_eq!(c.receivers, s.stats.receivers);
        assert_eq!(c.brighter_pixels, 0, "{refine:?}: {c:?}");
        assert!(c.linespace_seconds > 0.0 && c.exact_seconds > 0.0);
        errors.push(c.mean_abs_error);
    }
    assert!(
        errors[0] >= errors[1] && errors[1] >= errors[2],
        "{errors:?}"
    );
    assert!(errors[0] > 0.0, "{errors:?}");
    assert_eq!(errors[2], 0.0);
}

#[test]
fn soft_shadows_need_a_linespace_section() {
    let mut w = PackWriter::new();
    let t = Terrain {
        width: 2,
        height: 2,
        heights: vec![0.0; 4],
        origin: [0.0, 0.0],
        extent: [1.0, 1.0],
        color: None,
    };
    w.insert(terrain::to_section("terrain", "test", &t, None));
    let pack = Pack::from_bytes(&w.to_bytes().unwrap(), "flat.bake").unwrap();
    let err = render_pack(&pack, &options(true)).unwrap_err();
    assert!(err.to_string().contains("linespace"), "{err}");
}
