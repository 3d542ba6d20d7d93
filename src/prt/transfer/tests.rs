//! Tests of the PRT stage against analytic oracles: the clamped cosine, a closed box, a
//! translucent white furnace with a closed-form geometric series, and thread-count independence.

use super::*;
use crate::model::{Material, Rgba8Image, TextureRef};
use std::f64::consts::PI;

/// Appends an axis-aligned quad (two triangles) with the given corners (counter-clockwise seen
/// from the side its normal points to) and material.
fn push_quad(mesh: &mut Mesh, corners: [[f32; 3]; 4], material: u32) {
    let p: Vec<Vec3A> = corners.iter().map(|&c| Vec3A::from(c)).collect();
    let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
    let base = mesh.positions.len() as u32;
    let uvs = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    for (c, uv) in corners.iter().zip(uvs) {
        mesh.positions.push(*c);
        mesh.normals.push(n.to_array());
        mesh.uvs.push(uv);
    }
    mesh.indices.push([base, base + 1, base + 2]);
    mesh.indices.push([base, base + 2, base + 3]);
    mesh.triangle_materials.extend([material, material]);
}

fn mesh_with_materials(n: usize) -> Mesh {
    Mesh {
        materials: vec![Material::default(); n],
        ..Mesh::default()
    }
}

/// The unit square at z = 0, normal +Z.
fn ground(mesh: &mut Mesh, material: u32) {
    push_quad(
        mesh,
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        material,
    );
}

/// The six faces of the cube [lo, hi]³ (normals pointing inwards; PRT does not care).
fn cube(mesh: &mut Mesh, lo: f32, hi: f32, material: u32) {
    let c = |x: bool, y: bool, z: bool| {
        [
            if x { hi } else { lo },
            if y { hi } else { lo },
            if z { hi } else { lo },
        ]
    };
    let (f, t) = (false, true);
    let faces = [
        [c(f, f, f), c(f, t, f), c(t, t, f), c(t, f, f)],
        [c(f, f, t), c(t, f, t), c(t, t, t), c(f, t, t)],
        [c(f, f, f), c(t, f, f), c(t, f, t), c(f, f, t)],
        [c(f, t, f), c(f, t, t), c(t, t, t), c(t, t, f)],
        [c(f, f, f), c(f, f, t), c(f, t, t), c(f, t, f)],
        [c(t, f, f), c(t, t, f), c(t, t, t), c(t, f, t)],
    ];
    for q in faces {
        push_quad(mesh, q, material);
    }
}

fn mat(albedo: f32, translucence: f32) -> PrtMaterial {
    PrtMaterial {
        albedo: [albedo; 3],
        translucence,
    }
}

fn opts(samples: u32, bounces: u32) -> PrtOptions {
    PrtOptions {
        samples,
        bounces,
        ..PrtOptions::default()
    }
}

/// The analytic SH projection of max(0, cos θ)/π about +Z: only m = 0 terms,
/// 2π K_l ∫₀¹ x P_l(x) dx / π, i.e. K_0, (2/3) K_1, (1/4)·2·K_2... written out per band.
fn clamped_cosine_over_pi() -> [f64; 16] {
    let k = |l: f64| ((2.0 * l + 1.0) / (4.0 * PI)).sqrt();
    let mut c = [0.0; 16];
    c[0] = 2.0 * k(0.0) * 0.5; // ∫ x dx = 1/2
    c[2] = 2.0 * k(1.0) / 3.0; // ∫ x² dx = 1/3
    c[6] = 2.0 * k(2.0) * (3.0 / 4.0 - 1.0 / 2.0) / 2.0; // ∫ x (3x²−1)/2 dx = 1/8
    c[12] = 0.0; // ∫ x (5x³−3x)/2 dx = 0
    c
}

/// Per-sample variance of Y_i(d) for d ~ cos θ/π about +Z, by midpoint quadrature.
fn cosine_sample_variance() -> [f64; 16] {
    let (nt, np) = (400, 400);
    let mut m1 = [0.0f64; 16];
    let mut m2 = [0.0f64; 16];
    for i in 0..nt {
        let th = (i as f64 + 0.5) / nt as f64 * PI / 2.0;
        for j in 0..np {
            let ph = (j as f64 + 0.5) / np as f64 * 2.0 * PI;
            let d = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
            let w = th.cos() / PI * th.sin() * (PI / 2.0 / nt as f64) * (2.0 * PI / np as f64);
            let y = crate::sh::eval_basis16(d.map(|v| v as f32));
            for k in 0..16 {
                m1[k] += w * y[k] as f64;
                m2[k] += w * (y[k] as f64).powi(2);
            }
        }
    }
    std::array::from_fn(|k| (m2[k] - m1[k] * m1[k]).max(0.0))
}

#[test]
fn unoccluded_vertex_is_clamped_cosine_over_pi_times_albedo() {
    let mut mesh = mesh_with_materials(1);
    ground(&mut mesh, 0);
    let albedo = [0.2f32, 0.5, 0.8];
    let m = [PrtMaterial {
        albedo,
        translucence: 0.0,
    }];
    let expect = clamped_cosine_over_pi();
    let var = cosine_sample_variance();
    let mut errors = Vec::new();
    for n in [64u32, 4096] {
        let t = bake_prt(&mesh, &m, &[], &opts(n, 3)).unwrap();
        let mut sq = 0.0;
        for v in 0..4 {
            for side in 0..2 {
                let got = t.get(v, side, 0);
                for i in 0..16 {
                    // The back side sees the mirror image: odd bands flip sign.
                    let l = (i as f64).sqrt().floor() as i32;
                    let sign = if side == 1 && l % 2 == 1 { -1.0 } else { 1.0 };
                    for c in 0..3 {
                        let e = sign * expect[i] * albedo[c] as f64;
                        let err = (got[i][c] as f64 - e).abs();
                        let bound = 4.0 * albedo[c] as f64 * var[i].sqrt() / (n as f64).sqrt();
                        assert!(
                            err <= bound + 1e-6,
                            "N={n} v{v} side{side} c{i}: {err} > {bound}"
                        );
                        sq += err * err;
                    }
                }
                assert!(
                    t.get(v, side, 1).iter().all(|c| *c == [0.0; 3]),
                    "no bounces"
                );
            }
        }
        errors.push(sq.sqrt());
    }
    assert!(
        errors[1] < errors[0] / 4.0,
        "error must shrink with N: {errors:?}"
    );
}

#[test]
fn enclosed_vertex_receives_nothing_from_the_sky() {
    let mut mesh = mesh_with_materials(2);
    cube(&mut mesh, -1.0, 2.0, 1);
    ground(&mut mesh, 0);
    let m = [mat(0.8, 0.0), mat(0.7, 0.0)];
    let t = bake_prt(&mesh, &m, &[], &opts(256, 4)).unwrap();
    for v in 24..28 {
        for side in 0..2 {
            for set in 0..2 {
                assert!(t.get(v, side, set).iter().all(|c| *c == [0.0; 3]), "v{v}");
            }
        }
    }
    // The cube's own vertices see the sky from outside: the oracle can tell the two apart.
    assert!(t.get(0, 0, 0)[0][0] + t.get(0, 1, 0)[0][0] > 0.0);
}

/// Ground quad plus a blocker quad above it whose colour map has alpha `a` everywhere.
fn blocked(a: u8) -> (Mesh, Vec<Option<AlphaMask>>) {
    let mut mesh = mesh_with_materials(2);
    ground(&mut mesh, 0);
    push_quad(
        &mut mesh,
        [
            [-2.0, -2.0, 0.5],
            [3.0, -2.0, 0.5],
            [3.0, 3.0, 0.5],
            [-2.0, 3.0, 0.5],
        ],
        1,
    );
    mesh.textures.push(TextureRef {
        name: "leaf.png".into(),
        path: "leaf.png".into(),
    });
    mesh.materials[1].color_map = Some(0);
    let img = Rgba8Image {
        width: 4,
        height: 4,
        pixels: vec![[255, 255, 255, a]; 16],
    };
    let masks = alpha_masks(&mesh, &[Some(img)]);
    (mesh, masks)
}

#[test]
fn transparent_blocker_casts_no_transfer_shadow() {
    let mut free = mesh_with_materials(1);
    ground(&mut free, 0);
    let m = [mat(0.5, 0.3), mat(0.1, 0.3)];
    let o = opts(128, 2);
    let reference = bake_prt(&free, &m, &[], &o).unwrap();
    let (mesh, masks) = blocked(0);
    let clear = bake_prt(&mesh, &m, &masks, &o).unwrap();
    let n = 4 * PER_VERTEX;
    assert_eq!(
        clear.coeffs[..n]
            .iter()
            .flatten()
            .map(|f| f.to_bits())
            .collect::<Vec<_>>(),
        reference.coeffs[..n]
            .iter()
            .flatten()
            .map(|f| f.to_bits())
            .collect::<Vec<_>>(),
        "a fully transparent blocker must change nothing"
    );
    let (mesh, masks) = blocked(255);
    let shadowed = bake_prt(&mesh, &m, &masks, &o).unwrap();
    let front = |t: &Transfer| t.get(0, 0, 0)[0][0];
    assert!(
        front(&shadowed) < 0.5 * front(&reference),
        "an opaque one must shadow"
    );
}

#[test]
fn translucent_white_furnace_follows_the_geometric_series() {
    // A vertex inside a closed convex box whose walls have albedo ρ and translucence t: each
    // wall hit transmits (and the path escapes) with probability t, else reflects back inside,
    // so a path escapes after k scatterings with probability t(1−t)^(k−1) carrying ρ^k. In a
    // uniform white sky (SH c₀ = 2√π) the vertex's radiance is Σ_{k≤B} t(1−t)^(k−1) ρ^k,
    // bounded by tρ/(1−(1−t)ρ) ≤ 1/(1−ρ).
    let (rho, tr) = (0.8f64, 0.25f64);
    let mut mesh = mesh_with_materials(2);
    cube(&mut mesh, -50.0, 50.0, 1);
    push_quad(
        &mut mesh,
        [
            [0.0, 0.0, 0.0],
            [0.01, 0.0, 0.0],
            [0.01, 0.01, 0.0],
            [0.0, 0.01, 0.0],
        ],
        0,
    );
    let m = [mat(1.0, 0.0), mat(rho as f32, tr as f32)];
    let n = 4096u32;
    let limit = tr * rho / (1.0 - (1.0 - tr) * rho);
    let mut previous = 0.0f64;
    for b in [0u32, 1, 2, 4, 8] {
        let t = bake_prt(&mesh, &m, &[], &opts(n, b)).unwrap();
        let p: Vec<f64> = (1..=b)
            .map(|k| tr * (1.0 - tr).powi(k as i32 - 1))
            .collect();
        let mean: f64 = p
            .iter()
            .enumerate()
            .map(|(k, p)| p * rho.powi(k as i32 + 1))
            .sum();
        // Each path contributes a value in [0, 1] (ρ after one scattering, then Russian
        // roulette keeps it alive with probability ρ per hit at throughput 1), so its variance
        // is at most that of a Bernoulli variable of the same mean.
        let sigma = (mean * (1.0 - mean)).max(0.0).sqrt();
        for v in 24..28 {
            for side in 0..2 {
                let all = t.get(v, side, 0)[0][0] as f64 * 2.0 * PI.sqrt();
                let ind = t.get(v, side, 1)[0][0] as f64 * 2.0 * PI.sqrt();
                assert_eq!(all, ind, "every escaping path bounced");
                assert!(
                    (all - mean).abs() <= 4.0 * sigma / (n as f64).sqrt() + 1e-6,
                    "B={b}: {all} vs {mean}"
                );
                assert!(all <= limit + 4.0 * sigma / (n as f64).sqrt() + 1e-6);
                assert!(all <= 1.0 / (1.0 - rho));
            }
        }
        let all = t.get(24, 0, 0)[0][0] as f64;
        assert!(all >= previous, "more bounces never remove energy");
        previous = all;
    }
    assert!(previous > 0.0);
    // Opaque walls (t = 0) let nothing out, whatever the bounces: no energy is created.
    let m = [mat(1.0, 0.0), mat(rho as f32, 0.0)];
    let t = bake_prt(&mesh, &m, &[], &opts(256, 8)).unwrap();
    assert!(t.coeffs[24 * PER_VERTEX..].iter().all(|c| *c == [0.0; 3]));
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let (mesh, tex) = crate::prt::plant::procedural_plant(600, 3);
    let textures = [Some(tex)];
    let m = prt_materials(&mesh, &textures, 0.3);
    let masks = alpha_masks(&mesh, &textures);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| bake_prt(&mesh, &m, &masks, &opts(32, 3)).unwrap())
    };
    let (a, b) = (run(1), run(2));
    let bits =
        |t: &Transfer| -> Vec<u32> { t.coeffs.iter().flatten().map(|f| f.to_bits()).collect() };
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.rays, b.rays);
    assert!(a.coeffs.iter().any(|c| c[1] > 0.0));
}

/// SH by eq. 2.18–2.23 with trigonometry: an independent check of the fast polynomial basis.
fn sh_reference(l: i32, m: i32, d: [f64; 3]) -> f64 {
    let theta = d[2].clamp(-1.0, 1.0).acos();
    let phi = d[1].atan2(d[0]);
    let x = theta.cos();
    let am = m.unsigned_abs() as i32;
    let mut pmm = 1.0;
    for i in 1..=am {
        pmm *= -(2.0 * i as f64 - 1.0) * (1.0 - x * x).sqrt();
    }
    let mut plm = pmm;
    if l > am {
        let mut prev = pmm;
        plm = x * (2 * am + 1) as f64 * pmm;
        for ll in am + 2..=l {
            let next =
                (x * (2 * ll - 1) as f64 * plm - (ll + am - 1) as f64 * prev) / (ll - am) as f64;
            prev = plm;
            plm = next;
        }
    }
    let fact = |n: i32| (1..=n).map(|k| k as f64).product::<f64>();
    let k = ((2 * l + 1) as f64 * fact(l - am) / (4.0 * PI * fact(l + am))).sqrt();
    match m.cmp(&0) {
        std::cmp::Ordering::Greater => 2f64.sqrt() * k * (m as f64 * phi).cos() * plm,
        std::cmp::Ordering::Less => 2f64.sqrt() * k * (-m as f64 * phi).sin() * plm,
        std::cmp::Ordering::Equal => k * plm,
    }
}

#[test]
fn sh_basis_matches_the_legendre_definition() {
    let mut rng = Rng::hashed(3);
    for _ in 0..500 {
        let d = cosine_hemisphere(Vec3A::Z, rng.f32(), rng.f32())
            * if rng.f32() < 0.5 { 1.0 } else { -1.0 };
        let fast = crate::sh::eval_basis16(d.to_array());
        for l in 0..4 {
            for m in -l..=l {
                let i = (l * (l + 1) + m) as usize;
                let r = sh_reference(l, m, d.to_array().map(|v| v as f64));
                assert!(
                    (fast[i] as f64 - r).abs() < 1e-5,
                    "l{l} m{m}: {} vs {r}",
                    fast[i]
                );
            }
        }
    }
}

#[test]
fn gpu_layout_puts_band_zero_rgb_fraction_and_mono_bands() {
    let mut t = Transfer {
        vertices: 1,
        samples: 1,
        bounces: 1,
        coeffs: vec![[0.0; 3]; PER_VERTEX],
        rays: 0,
        skipped_vertices: 0,
    };
    for i in 0..COEFFS {
        t.coeffs[i] = [i as f32, i as f32, i as f32]; // side 0, set 0
        t.coeffs[COEFFS + i] = [i as f32 * 0.25; 3]; // side 0, set 1
    }
    t.coeffs[SETS * COEFFS] = [1.0, 0.0, 0.0]; // side 1, set 0, band 0: red only
    let g = pack_gpu(&t);
    assert_eq!(g.len(), 10);
    assert_eq!(g[0], [0.0, 0.0, 0.0, 0.0], "zero band 0 gives fraction 0");
    assert!((g[1][0] - 1.0).abs() < 1e-6 && (g[4][2] - 15.0).abs() < 1e-5 && g[4][3] == 0.0);
    assert_eq!(g[5], [1.0, 0.0, 0.0, 0.0]);
    t.coeffs[0] = [2.0; 3];
    t.coeffs[COEFFS] = [0.5; 3];
    assert!((pack_gpu(&t)[0][3] - 0.25).abs() < 1e-6);
}

#[test]
fn duplicate_vertices_are_welded_and_share_their_transfer() {
    // The ground quad twice (TXF files repeat positions across sets), the copy with another
    // material: welded only where position, normal and material agree.
    let mut mesh = mesh_with_materials(2);
    ground(&mut mesh, 0);
    ground(&mut mesh, 0);
    ground(&mut mesh, 1);
    assert_eq!(weld_vertices(&mesh), [0, 1, 2, 3, 0, 1, 2, 3, 8, 9, 10, 11]);
    assert_eq!(weld_key_count(&mesh), 8);
    let m = [mat(0.5, 0.0), mat(0.5, 0.0)];
    let t = bake_prt(&mesh, &m, &[], &opts(64, 2)).unwrap();
    assert_eq!(t.vertices, 12);
    for v in 0..4 {
        for side in 0..2 {
            assert_eq!(t.get(v, side, 0), t.get(v + 4, side, 0));
        }
    }
    // Unoccluded paths are one ray each: 8 vertices traced, not 12.
    assert_eq!(t.rays, 8 * 2 * 64);
}

fn bits(t: &Transfer) -> Vec<u32> {
    t.coeffs.iter().flatten().map(|f| f.to_bits()).collect()
}

fn with_sides(samples: u32, bounces: u32, sides: PrtSides) -> PrtOptions {
    PrtOptions {
        sides,
        ..opts(samples, bounces)
    }
}

#[test]
fn one_sided_unoccluded_quad_has_the_front_cosine_and_a_zero_back() {
    // The ground quad twice: material 0 one-sided, material 1 double-sided. Unoccluded, so the
    // front is ρ·max(0, cos θ)/π about +Z, the double-sided back the same about −Z, the
    // one-sided back zero under `auto`, and each path is one ray.
    let mut mesh = mesh_with_materials(2);
    mesh.materials[0].double_sided = false;
    ground(&mut mesh, 0);
    ground(&mut mesh, 1);
    let m = [mat(0.5, 0.0), mat(0.5, 0.0)];
    let n = 1024;
    let auto = bake_prt(&mesh, &m, &[], &with_sides(n, 2, PrtSides::Auto)).unwrap();
    let both = bake_prt(&mesh, &m, &[], &with_sides(n, 2, PrtSides::Both)).unwrap();
    let front = bake_prt(&mesh, &m, &[], &with_sides(n, 2, PrtSides::Front)).unwrap();
    assert_eq!(PrtOptions::default().sides, PrtSides::Auto);
    // Rays: 4 one-sided vertices × 1 side + 4 double-sided × 2 sides; `front` exactly half.
    assert_eq!(auto.rays, (4 + 8) * n as u64);
    assert_eq!(both.rays, 16 * n as u64);
    assert_eq!(front.rays, 8 * n as u64);
    let cc = clamped_cosine_over_pi();
    for v in 0..8 {
        // The front side is the same bytes whatever the back does (per-side seeds).
        for set in 0..SETS {
            assert_eq!(auto.get(v, 0, set), both.get(v, 0, set), "vertex {v}");
            assert_eq!(front.get(v, 0, set), both.get(v, 0, set), "vertex {v}");
            assert!(front.get(v, 1, set).iter().all(|c| *c == [0.0; 3]));
        }
        let f = auto.get(v, 0, 0);
        assert!((f[0][0] as f64 - 0.5 * cc[0]).abs() < 0.01, "{:?}", f[0]);
        assert!((f[2][0] as f64 - 0.5 * cc[2]).abs() < 0.01, "{:?}", f[2]);
        let back = auto.get(v, 1, 0);
        if v < 4 {
            assert!(
                back.iter().all(|c| *c == [0.0; 3]),
                "one-sided back {back:?}"
            );
        } else {
            assert_eq!(back, both.get(v, 1, 0));
            // About −Z: band 0 as the front, the z coefficient negated.
            assert!(
                (back[0][0] as f64 - 0.5 * cc[0]).abs() < 0.01,
                "{:?}",
                back[0]
            );
            assert!(
                (back[2][0] as f64 + 0.5 * cc[2]).abs() < 0.01,
                "{:?}",
                back[2]
            );
        }
    }
}

#[test]
fn sides_on_the_plant_keep_the_front_bytes_and_halve_the_rays() {
    // The alpha-tested plant, its leaf material one-sided: `auto` traces the leaves' front
    // only (bytes equal to `both` there), the bark's two sides (bytes equal to `both`), and
    // is the same on any thread count; with every material one-sided it is `front`.
    let (mut mesh, tex) = crate::prt::plant::procedural_plant(600, 3);
    let textures = [Some(tex)];
    let m = prt_materials(&mesh, &textures, 0.3);
    let masks = alpha_masks(&mesh, &textures);
    let bake = |mesh: &Mesh, sides, threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| bake_prt(mesh, &m, &masks, &with_sides(32, 3, sides)).unwrap())
    };
    let both = bake(&mesh, PrtSides::Both, 2);
    // Every input but glTF is double-sided: `auto` is `both` on the plant as generated.
    assert!(mesh.materials.iter().all(|m| m.double_sided));
    assert_eq!(bits(&bake(&mesh, PrtSides::Auto, 2)), bits(&both));
    mesh.materials[0].double_sided = false;
    let (auto1, auto2) = (
        bake(&mesh, PrtSides::Auto, 1),
        bake(&mesh, PrtSides::Auto, 2),
    );
    assert_eq!(bits(&auto1), bits(&auto2));
    assert_eq!(auto1.rays, auto2.rays);
    let ctx_material = |v: usize| {
        mesh.indices
            .iter()
            .zip(&mesh.triangle_materials)
            .find(|(t, _)| t.contains(&(v as u32)))
            .map(|(_, &m)| m)
    };
    let (mut leaf, mut bark) = (0, 0);
    for v in 0..mesh.positions.len() {
        for set in 0..SETS {
            assert_eq!(auto1.get(v, 0, set), both.get(v, 0, set), "front of {v}");
        }
        match ctx_material(v) {
            Some(0) => {
                leaf += 1;
                for set in 0..SETS {
                    assert!(auto1.get(v, 1, set).iter().all(|c| *c == [0.0; 3]));
                }
            }
            Some(_) => {
                bark += 1;
                for set in 0..SETS {
                    assert_eq!(auto1.get(v, 1, set), both.get(v, 1, set), "back of {v}");
                }
            }
            None => {}
        }
    }
    assert!(leaf > 0 && bark > 0, "{leaf} leaf, {bark} bark vertices");
    assert!(
        both.coeffs.iter().any(|c| c[0] != 0.0) && auto1.rays < both.rays,
        "{} vs {} rays",
        auto1.rays,
        both.rays
    );
    // Every material one-sided: `auto` = `front`, about half the rays of `both`.
    for mat in &mut mesh.materials {
        mat.double_sided = false;
    }
    let all_one = bake(&mesh, PrtSides::Auto, 2);
    let front = bake(&mesh, PrtSides::Front, 2);
    assert_eq!(bits(&all_one), bits(&front));
    assert_eq!(all_one.rays, front.rays);
    let ratio = front.rays as f64 / both.rays as f64;
    assert!((0.35..0.65).contains(&ratio), "front/both rays {ratio:.3}");
}

#[test]
fn adaptive_sampling_spends_nothing_on_sides_not_traced() {
    let (mut mesh, tex) = crate::prt::plant::procedural_plant(300, 3);
    for mat in &mut mesh.materials {
        mat.double_sided = false;
    }
    let textures = [Some(tex)];
    let m = prt_materials(&mesh, &textures, 0.3);
    let masks = alpha_masks(&mesh, &textures);
    let bvh = ModelBvh::build(&mesh, &masks, Default::default()).unwrap();
    let verts: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    let o = with_sides(64, 3, PrtSides::Auto);
    let t = bake_prt_adaptive(&bvh, &mesh, &m, &o, &verts, Adaptive::for_samples(64));
    for v in 0..verts.len() {
        for set in 0..SETS {
            assert!(t.get(v, 1, set).iter().all(|c| *c == [0.0; 3]));
        }
    }
    assert!(t.coeffs.iter().any(|c| c[0] != 0.0));
}
