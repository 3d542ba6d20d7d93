//! A procedural alpha-tested plant for tests and benchmarks: a trunk cylinder and a crown of
//! randomly placed and oriented leaf quads (4 vertices, 2 triangles each) textured with a
//! lens-shaped leaf whose texels outside the leaf have alpha 0 (about 43% of each quad is
//! transparent), the way Xfrog plants model leaves.
//!
//! The crown grows with the leaf count so the leaf-area density stays near 3 m² per m³ (a
//! dense real tree), which keeps ray behaviour (escape rate, bounces) independent of size.

use crate::model::{Material, Mesh, Rgba8Image, TextureRef};
use crate::trace::Rng;
use glam::Vec3A;

/// Leaf quad length and width, metres.
const LEAF: (f32, f32) = (0.16, 0.08);
/// Side of the generated leaf texture, texels.
const TEX: u32 = 64;

/// A plant of about `triangles` triangles (trunk: 32 of them) and its leaf texture
/// (`mesh.textures[0]`, colour map of material 0).
pub fn procedural_plant(triangles: usize, seed: u64) -> (Mesh, Rgba8Image) {
    let mut rng = Rng::hashed(seed);
    let leaves = triangles.saturating_sub(32).div_ceil(2).max(1);
    let opaque_area = LEAF.0 * LEAF.1 * 0.573 * leaves as f32;
    let radius = (opaque_area / 3.0 * 3.0 / (4.0 * std::f32::consts::PI)).cbrt();
    let centre = Vec3A::new(0.0, 0.0, 1.2 * radius + 0.5);
    let mut mesh = Mesh {
        materials: vec![leaf_material(), bark_material()],
        textures: vec![TextureRef {
            name: "leaf.png".into(),
            path: "leaf.png".into(),
        }],
        objects: vec!["procedural plant".into()],
        ..Mesh::default()
    };
    trunk(&mut mesh, 0.06 * radius.max(0.5), centre.z);
    for _ in 0..leaves {
        let p = loop {
            let q = Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
            if q.length_squared() <= 1.0 {
                break centre + q * radius;
            }
        };
        leaf(&mut mesh, p, &mut rng);
    }
    (mesh, leaf_texture())
}

fn leaf_material() -> Material {
    Material {
        name: "leaf".into(),
        diffuse: [1.0, 1.0, 1.0, 1.0],
        color_map: Some(0),
        translucence: Some(0.3),
        ..Material::default()
    }
}

fn bark_material() -> Material {
    Material {
        name: "bark".into(),
        diffuse: [0.45, 0.35, 0.25, 1.0],
        translucence: Some(0.0),
        ..Material::default()
    }
}

/// One leaf quad at `p` with a random orientation, normals tilted upwards on average.
fn leaf(mesh: &mut Mesh, p: Vec3A, rng: &mut Rng) {
    let n = Vec3A::new(
        rng.f32() * 2.0 - 1.0,
        rng.f32() * 2.0 - 1.0,
        rng.f32() * 1.5 - 0.25,
    )
    .try_normalize()
    .unwrap_or(Vec3A::Z);
    let (t, b) = crate::trace::frame(n);
    let a = rng.f32() * std::f32::consts::TAU;
    let (s, c) = a.sin_cos();
    let (u, v) = (t * c + b * s, b * c - t * s);
    let (hl, hw) = (LEAF.0 * 0.5, LEAF.1 * 0.5);
    let corners = [
        p - u * hl - v * hw,
        p + u * hl - v * hw,
        p + u * hl + v * hw,
        p - u * hl + v * hw,
    ];
    let uvs = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    let base = mesh.positions.len() as u32;
    for (q, uv) in corners.iter().zip(uvs) {
        mesh.positions.push(q.to_array());
        mesh.normals.push(n.to_array());
        mesh.uvs.push(uv);
    }
    mesh.indices.push([base, base + 1, base + 2]);
    mesh.indices.push([base, base + 2, base + 3]);
    mesh.triangle_materials.extend([0, 0]);
}

/// A 16-sided open cylinder from z = 0 to `height` (32 triangles, material 1).
fn trunk(mesh: &mut Mesh, r: f32, height: f32) {
    let base = mesh.positions.len() as u32;
    for k in 0..=16 {
        let a = k as f32 / 16.0 * std::f32::consts::TAU;
        let (s, c) = a.sin_cos();
        for z in [0.0, height] {
            mesh.positions.push([r * c, r * s, z]);
            mesh.normals.push([c, s, 0.0]);
            mesh.uvs.push([k as f32 / 16.0, z / height.max(1e-6)]);
        }
    }
    for k in 0..16 {
        let i = base + 2 * k;
        mesh.indices.push([i, i + 2, i + 3]);
        mesh.indices.push([i, i + 3, i + 1]);
        mesh.triangle_materials.extend([1, 1]);
    }
}

/// A lens-shaped green leaf on a transparent background (u along the leaf, v = 0 at the top).
fn leaf_texture() -> Rgba8Image {
    let mut pixels = Vec::with_capacity((TEX * TEX) as usize);
    for j in 0..TEX {
        for i in 0..TEX {
            let x = (i as f32 + 0.5) / TEX as f32;
            let y = (j as f32 + 0.5) / TEX as f32;
            let half_width = 0.45 * (std::f32::consts::PI * x).sin();
            let inside = (y - 0.5).abs() < half_width;
            let vein = (y - 0.5).abs() < 0.02;
            pixels.push(match (inside, vein) {
                (true, true) => [150, 190, 90, 255],
                (true, false) => [70, 130, 40, 255],
                (false, _) => [0, 0, 0, 0],
            });
        }
    }
    Rgba8Image {
        width: TEX,
        height: TEX,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plant_has_the_requested_size_and_a_partly_transparent_leaf() {
        let (mesh, tex) = procedural_plant(1000, 1);
        assert_eq!(mesh.validate(), Ok(()));
        assert!((mesh.indices.len() as i64 - 1000).abs() <= 2);
        let opaque = tex.pixels.iter().filter(|p| p[3] >= 128).count() as f32;
        let frac = opaque / tex.pixels.len() as f32;
        assert!((frac - 0.573).abs() < 0.03, "{frac}");
        // Deterministic for a seed.
        assert_eq!(procedural_plant(1000, 1).0, mesh);
    }
}
