//! The sun's shadow map: an orthographic depth view along the sun direction fitted to the
//! scene's bounds (terrain and every instance), rendered with the alpha test, read with 3×3
//! percentage-closer filtering (each tap a bilinear 2×2 comparison) in shaders/direct.wgsl.
//!
//! Resolution and bias were chosen by measurement against the CPU reference's exact shadow rays
//! (docs/PERFORMANCE.md, issue 4): the normal offset and the depth bias are in world metres,
//! scaled with the map's texel size, so they hold for any scene size.

use super::scene::SceneData;
use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};

/// Texels per side of the shadow map.
pub const SHADOW_MAP_SIZE: u32 = 4096;
/// Offset of the looked-up point along the normal (towards the sun), in shadow-map texels.
pub const NORMAL_OFFSET_TEXELS: f32 = 0.5;
/// Depth bias, in shadow-map texels (world metres = this × texel size).
pub const DEPTH_BIAS_TEXELS: f32 = 1.0;

/// What shaders/direct.wgsl reads (group 2, binding 0): repr(C), Pod, 80 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct ShadowParams {
    /// World to the light's clip space (x, y in [−1, 1], depth in [0, 1]).
    pub light_view_proj: [[f32; 4]; 4],
    /// x: one texel in uv, y: normal offset (m), z: depth bias (depth units), w: 1 = map used.
    pub params: [f32; 4],
}
const _: () = assert!(size_of::<ShadowParams>() == 80);

/// Bounds of everything that casts or receives shadows: the terrain box and every instance's
/// model box turned about Z (the same envelope as `SceneData::focus_bounds`).
pub fn scene_bounds(scene: &SceneData) -> Option<(Vec3, Vec3)> {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    if let Some(t) = &scene.terrain {
        let o = t.meta.origin;
        let e = t.meta.extent;
        lo = lo.min(Vec3::new(o[0], o[1], t.min_height));
        hi = hi.max(Vec3::new(o[0] + e[0], o[1] + e[1], t.max_height));
    }
    if !scene.models.is_empty() {
        let (a, b) = scene.focus_bounds();
        if a.iter().chain(&b).all(|v| v.is_finite()) {
            lo = lo.min(Vec3::from(a));
            hi = hi.max(Vec3::from(b));
        }
    }
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// The light's view-projection fitted to the box `[lo, hi]` seen along `-sun`, and the size
/// of one texel in metres.
pub fn fit_light(lo: Vec3, hi: Vec3, sun: Vec3, size: u32) -> (Mat4, f32) {
    let sun = sun.normalize_or(Vec3::Z);
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let up = if sun.cross(Vec3::Z).length_squared() < 1e-6 {
        Vec3::Y
    } else {
        Vec3::Z
    };
    let view = Mat4::look_at_rh(centre + sun * radius * 2.0, centre, up);
    let (mut vlo, mut vhi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for k in 0..8 {
        let c = Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), hi, lo);
        let p = view.transform_point3(c);
        vlo = vlo.min(p);
        vhi = vhi.max(p);
    }
    // Right-handed view space looks down −Z: near and far are distances, a little padded.
    let pad = radius * 1e-3;
    let proj = Mat4::orthographic_rh(
        vlo.x - pad,
        vhi.x + pad,
        vlo.y - pad,
        vhi.y + pad,
        -vhi.z - pad,
        -vlo.z + pad,
    );
    let texel = ((vhi.x - vlo.x).max(vhi.y - vlo.y) + 2.0 * pad) / size as f32;
    (proj * view, texel)
}

/// The shadow parameters of a scene lit from `sun`; `None` when there is nothing to shadow.
pub fn shadow_params(scene: &SceneData, sun: [f32; 3]) -> Option<ShadowParams> {
    let (lo, hi) = scene_bounds(scene)?;
    let (m, texel) = fit_light(lo, hi, Vec3::from(sun), SHADOW_MAP_SIZE);
    // Depth units per metre along the sun: the length of the matrix's depth row.
    let depth_scale = Vec3::new(m.x_axis.z, m.y_axis.z, m.z_axis.z).length();
    Some(ShadowParams {
        light_view_proj: m.to_cols_array_2d(),
        params: [
            1.0 / SHADOW_MAP_SIZE as f32,
            NORMAL_OFFSET_TEXELS * texel,
            DEPTH_BIAS_TEXELS * texel * depth_scale,
            1.0,
        ],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fitted_view_holds_the_box_in_the_unit_clip_volume() {
        let (lo, hi) = (Vec3::new(-5.0, 2.0, 0.0), Vec3::new(40.0, 20.0, 8.0));
        for sun in [
            Vec3::new(-0.55, 0.53, 0.64),
            Vec3::Z,
            Vec3::new(0.9, 0.0, 0.1),
        ] {
            let (m, texel) = fit_light(lo, hi, sun, 1024);
            assert!(texel > 0.0);
            for k in 0..8 {
                let c = Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), hi, lo);
                let p = m.project_point3(c);
                assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "{sun}: {p}");
                assert!((0.0..=1.0).contains(&p.z), "{sun}: {p}");
            }
            // A point nearer the sun has a smaller depth.
            let c = (lo + hi) * 0.5;
            let near = m.project_point3(c + sun.normalize() * 0.5).z;
            assert!(near < m.project_point3(c).z);
        }
    }
}
