//! Embree (feature `embree`, Debian's libembree-dev) against the obvhs tracer on the same rays:
//! the procedural alpha-tested plant, rays from outside towards its crown and from its vertices
//! into the hemispheres (the PRT's first rays). Both must agree on hit or miss, on the triangle
//! and on the distance; the alpha test must change the answer for many rays on both sides.
#![cfg(feature = "embree")]

use bake::trace::embree::EmbreeScene;
use bake::trace::{BuildPreset, ModelBvh, Ray, Rng};
use glam::Vec3A;

fn rays(mesh: &bake::model::Mesh) -> Vec<Ray> {
    let (lo, hi) = mesh.bounds().unwrap();
    let (lo, hi) = (Vec3A::from(lo), Vec3A::from(hi));
    let centre = (lo + hi) * 0.5;
    let r = (hi - lo).length();
    let mut rng = Rng::hashed(7);
    let mut out = Vec::new();
    // From a sphere around the plant towards a random point inside its bounds.
    for _ in 0..4000 {
        let d =
            Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5).normalize_or(Vec3A::Z);
        let target = lo + (hi - lo) * Vec3A::new(rng.f32(), rng.f32(), rng.f32());
        let origin = centre + d * r;
        out.push(Ray::new(origin, (target - origin).normalize(), 0.0));
    }
    // From vertices, offset along the normal, in random directions of its hemisphere.
    for v in (0..mesh.positions.len()).step_by(7).take(2000) {
        let n = Vec3A::from(mesh.normals[v]).normalize_or(Vec3A::Z);
        let p = Vec3A::from(mesh.positions[v]) + n * (1e-4 * r);
        let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5).normalize_or(n);
        let d = if d.dot(n) < 0.0 { -d } else { d };
        out.push(Ray::new(p, d, 0.0));
    }
    out
}

/// (rays where hit/miss differ, rays where both hit different triangles at different
/// distances, hits) of Embree against obvhs.
fn compare(e: &EmbreeScene, b: &ModelBvh, rays: &[Ray]) -> (usize, usize, usize) {
    let (mut differ, mut far, mut hits) = (0, 0, 0);
    for r in rays {
        match (e.closest_hit(r), b.closest_hit(r)) {
            (Some(x), Some(y)) => {
                hits += 1;
                if x.triangle != y.triangle && (x.t - y.t).abs() > 1e-4 * x.t.max(y.t) {
                    far += 1;
                }
            }
            (None, None) => {}
            _ => differ += 1,
        }
    }
    (differ, far, hits)
}

#[test]
fn embree_and_obvhs_agree_on_the_alpha_tested_plant() {
    let (mesh, tex) = bake::prt::plant::procedural_plant(5000, 1);
    let masks = bake::trace::materials::alpha_masks(&mesh, &[Some(tex)]);
    assert!(
        masks.iter().any(|m| m.is_some()),
        "the plant has alpha-tested leaves"
    );
    let rays = rays(&mesh);
    let embree = EmbreeScene::build(&mesh, &masks).unwrap();
    let obvhs = ModelBvh::build(&mesh, &masks, BuildPreset::default()).unwrap();
    let (differ, far, hits) = compare(&embree, &obvhs, &rays);
    eprintln!(
        "{} rays: {hits} hits, {differ} hit/miss differ, {far} other hits",
        rays.len()
    );
    assert!(hits > rays.len() / 5, "too few hits to compare: {hits}");
    assert!(
        differ * 1000 <= rays.len(),
        "{differ} of {} rays differ",
        rays.len()
    );
    assert!(far * 1000 <= hits, "{far} of {hits} hits are elsewhere");

    // Without the alpha test both see the opaque cards: many rays change on both sides alike.
    let opaque_e = EmbreeScene::build(&mesh, &[]).unwrap();
    let opaque_b = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
    let (d0, f0, _) = compare(&opaque_e, &opaque_b, &rays);
    assert!(
        d0 * 1000 <= rays.len() && f0 * 1000 <= rays.len(),
        "{d0} {f0}"
    );
    let changed = rays
        .iter()
        .filter(|r| {
            embree.closest_hit(r).map(|h| h.triangle) != opaque_e.closest_hit(r).map(|h| h.triangle)
        })
        .count();
    assert!(
        changed * 20 > rays.len(),
        "the alpha test changes only {changed} rays"
    );
}
