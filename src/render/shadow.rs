//! The sun's shadow maps: cascaded orthographic depth views along the sun direction, rendered
//! with the alpha test, read with 3×3 percentage-closer filtering (each tap a bilinear 2×2, so
//! 4×4 texels with the taps' weights summed) in shaders/direct.wgsl, each texel compared on its
//! own against the receiver's plane at the texel's centre (receiver-plane depth) less the depth
//! bias: a slope-scaled bias in its place let the occluders just above a steep receiver through
//! (docs/VALIDATION.md, issue 35).
//!
//! Cascades (the default, [`DEFAULT_CASCADES`]): the camera's view depth from its near plane to
//! the farthest corner of the scene's bounds is cut into slices by the practical split scheme
//! (`d_i = λ·n·(f/n)^(i/N) + (1 − λ)·(n + (f − n)·i/N)`, λ = [`SPLIT_LAMBDA`], the split near
//! `n` at least [`SPLIT_NEAR_FRACTION`] of `f`). Each slice gets the sphere around its eight
//! corners (it depends on the split depths and the lens only, not on where the camera looks),
//! its radius rounded up to a power of 2^(1/8) so it holds while the camera moves a little, and
//! an orthographic light view of that half-extent with a fixed orientation (the sun's) whose
//! centre is snapped to whole texels in light space: a moving camera moves the map by whole
//! texels, and shadow edges do not crawl. The light box reaches from the slice's sphere up to
//! the top of the scene's bounds along the sun, so every caster between the sun and the slice
//! is drawn. A receiver uses the first cascade whose far split is beyond its view depth (no
//! blending between cascades).
//!
//! One cascade is the older single map over the whole scene ([`fit_light`], [`SHADOW_MAP_SIZE`]).
//!
//! Resolution and bias were chosen by measurement against the CPU reference's exact shadow rays
//! (docs/PERFORMANCE.md, issue 4): the normal offset and the depth bias are in texels of the
//! receiver's cascade, so they hold for any scene size.

use super::camera::Camera;
use super::scene::SceneData;
use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3};

/// Texels per side of the single shadow map (one cascade).
pub const SHADOW_MAP_SIZE: u32 = 4096;
/// Texels per side of each cascade when there are several (4 × 2048² holds the memory of one
/// 4096² map).
pub const CASCADE_MAP_SIZE: u32 = 2048;
/// The most cascades (the size of the arrays in [`ShadowParams`]).
pub const MAX_CASCADES: usize = 4;
/// Default number of cascades.
pub const DEFAULT_CASCADES: u32 = 4;
/// Weight of the logarithmic split against the uniform one.
pub const SPLIT_LAMBDA: f32 = 0.9;
/// The split scheme's near distance is at least this fraction of the far one (the camera's
/// near plane is often millimetres; the first cascade still starts there).
pub const SPLIT_NEAR_FRACTION: f32 = 1e-3;
/// Offset of the looked-up point along the normal (towards the sun), in shadow-map texels.
pub const NORMAL_OFFSET_TEXELS: f32 = 0.5;
/// Depth bias, in shadow-map texels (world metres = this × texel size), below the receiver's
/// plane at each texel's centre.
pub const DEPTH_BIAS_TEXELS: f32 = 1.0;

/// What shaders/direct.wgsl reads (group 2, binding 0): repr(C), Pod, 352 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct ShadowParams {
    /// World to each cascade's light clip space (x, y in [−1, 1], depth in [0, 1]).
    pub light_view_proj: [[[f32; 4]; 4]; MAX_CASCADES],
    /// Per cascade: x one texel in uv, y normal offset (m), z depth bias (depth units),
    /// w texel size (m).
    pub cascade: [[f32; 4]; MAX_CASCADES],
    /// The far view depth (m) of each cascade; the last cascade takes everything beyond.
    pub splits: [f32; 4],
    /// xyz the camera's forward direction, w the cascade count (0: no map, all lit).
    pub view: [f32; 4],
}
const _: () = assert!(size_of::<ShadowParams>() == 352);

/// One cascade: its light view and what it covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cascade {
    /// World to the light's clip space.
    pub view_proj: Mat4,
    /// World size of one texel (m).
    pub texel_m: f32,
    /// The camera's view depths this cascade's receivers have (m).
    pub depth: (f32, f32),
    /// The snapped centre in the light's view plane (m, along [`light_view`]'s x and y).
    pub origin: [f32; 2],
    /// Half the side of the light box (m).
    pub half_extent: f32,
}

/// The cascades of a frame and the side of each map in texels.
#[derive(Debug, Clone, PartialEq)]
pub struct Shadows {
    pub cascades: Vec<Cascade>,
    pub size: u32,
}

/// Texel sizes of one cascade, as `RenderStats` reports them.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CascadeStats {
    /// View depth range of the receivers (m; the last one's far end is the scene's farthest
    /// corner).
    pub near_m: f32,
    pub far_m: f32,
    pub texel_m: f32,
}

impl Shadows {
    /// What the shaders read.
    pub fn params(&self, forward: Vec3) -> ShadowParams {
        let mut p = ShadowParams::zeroed();
        for (i, c) in self.cascades.iter().enumerate().take(MAX_CASCADES) {
            let m = c.view_proj;
            // Depth units per metre along the sun: the length of the matrix's depth row.
            let depth_scale = Vec3::new(m.x_axis.z, m.y_axis.z, m.z_axis.z).length();
            p.light_view_proj[i] = m.to_cols_array_2d();
            p.cascade[i] = [
                1.0 / self.size as f32,
                NORMAL_OFFSET_TEXELS * c.texel_m,
                DEPTH_BIAS_TEXELS * c.texel_m * depth_scale,
                c.texel_m,
            ];
            p.splits[i] = c.depth.1;
        }
        let n = self.cascades.len().min(MAX_CASCADES);
        p.view = [forward.x, forward.y, forward.z, n as f32];
        p
    }

    pub fn stats(&self) -> Vec<CascadeStats> {
        self.cascades
            .iter()
            .map(|c| CascadeStats {
                near_m: c.depth.0,
                far_m: c.depth.1,
                texel_m: c.texel_m,
            })
            .collect()
    }
}

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

/// The shadow maps of a scene lit from `sun` seen by `cam`, `count` cascades (1: one map over
/// the whole scene); `None` when there is nothing to shadow.
pub fn shadows(scene: &SceneData, cam: &Camera, sun: [f32; 3], count: u32) -> Option<Shadows> {
    let (lo, hi) = scene_bounds(scene)?;
    Some(shadows_of_box(lo, hi, cam, Vec3::from(sun), count))
}

/// The shadow maps of [`shadows`] for the casters and receivers in `[lo, hi]`.
pub fn shadows_of_box(lo: Vec3, hi: Vec3, cam: &Camera, sun: Vec3, count: u32) -> Shadows {
    let sun = sun.normalize_or(Vec3::Z);
    if count <= 1 {
        let (m, texel) = fit_light(lo, hi, sun, SHADOW_MAP_SIZE);
        let cascade = Cascade {
            view_proj: m,
            texel_m: texel,
            depth: (cam.near, view_far(cam, lo, hi)),
            origin: [0.0; 2],
            half_extent: texel * SHADOW_MAP_SIZE as f32 * 0.5,
        };
        return Shadows {
            cascades: vec![cascade],
            size: SHADOW_MAP_SIZE,
        };
    }
    let n = (count as usize).min(MAX_CASCADES);
    let far = view_far(cam, lo, hi);
    let split_near = cam.near.max(far * SPLIT_NEAR_FRACTION);
    let mut d = split_depths(split_near, far, n, SPLIT_LAMBDA);
    d[0] = cam.near;
    let top = (0..8)
        .map(|k| corner(lo, hi, k).dot(sun))
        .fold(f32::MIN, f32::max);
    let mut cascades = Vec::new();
    for w in d.windows(2) {
        let c = fit_cascade(cam, (w[0], w[1]), sun, top, CASCADE_MAP_SIZE);
        // A cascade whose box holds the whole scene is the last one: the scene's own box is
        // finer, and every receiver beyond it lies inside.
        if let Some(whole) = fit_whole_scene(&c, lo, hi, sun, (w[0], far)) {
            cascades.push(whole);
            break;
        }
        cascades.push(c);
    }
    Shadows {
        cascades,
        size: CASCADE_MAP_SIZE,
    }
}

/// The light box of the whole scene `[lo, hi]` (its rectangle in the light's view plane, made
/// square, at the cascade's map size) in place of cascade `c`, when `c`'s box holds that
/// rectangle; it covers the view depths `depth`. The scene does not move, so neither does the map.
fn fit_whole_scene(
    c: &Cascade,
    lo: Vec3,
    hi: Vec3,
    sun: Vec3,
    depth: (f32, f32),
) -> Option<Cascade> {
    let view = light_view(sun);
    let (mut a, mut b) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for k in 0..8 {
        let p = view.transform_point3(corner(lo, hi, k));
        a = a.min(p);
        b = b.max(p);
    }
    let [x, y] = c.origin;
    let h = c.half_extent;
    let inside = a.x >= x - h && b.x <= x + h && a.y >= y - h && b.y <= y + h;
    if !inside {
        return None;
    }
    let size = c.half_extent * 2.0 / c.texel_m;
    let half = 0.5 * (b.x - a.x).max(b.y - a.y) * (1.0 + 1e-3) + 1e-3;
    let (cx, cy) = (0.5 * (a.x + b.x), 0.5 * (a.y + b.y));
    let pad = half * 1e-3;
    let proj = Mat4::orthographic_rh(
        cx - half,
        cx + half,
        cy - half,
        cy + half,
        -b.z - pad,
        -a.z + pad,
    );
    Some(Cascade {
        view_proj: proj * view,
        texel_m: 2.0 * half / size,
        depth,
        origin: [cx, cy],
        half_extent: half,
    })
}

/// Corner `k` of the box `[lo, hi]` (bit 0: x, bit 1: y, bit 2: z from `hi`).
fn corner(lo: Vec3, hi: Vec3, k: usize) -> Vec3 {
    Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), hi, lo)
}

/// The far end of the view: the distance from the eye to the farthest corner of `[lo, hi]`
/// (at least twice the near plane). A distance, not a depth, so it does not change as the
/// camera turns.
fn view_far(cam: &Camera, lo: Vec3, hi: Vec3) -> f32 {
    let f = (0..8)
        .map(|k| corner(lo, hi, k).distance(cam.eye))
        .fold(0.0, f32::max);
    f.max(cam.near * 2.0)
}

/// The practical split scheme: `count + 1` view depths from `near` to `far`, each the blend
/// `λ·log + (1 − λ)·uniform`.
pub fn split_depths(near: f32, far: f32, count: usize, lambda: f32) -> Vec<f32> {
    (0..=count)
        .map(|i| {
            let t = i as f32 / count as f32;
            let log = near * (far / near).powf(t);
            let uniform = near + (far - near) * t;
            if i == count {
                far
            } else {
                lambda * log + (1.0 - lambda) * uniform
            }
        })
        .collect()
}

/// The eight corners of the camera's view between depths `d0` and `d1` (near ones first).
pub fn slice_corners(cam: &Camera, d0: f32, d1: f32) -> [Vec3; 8] {
    let b = cam.basis();
    let ty = (cam.fov_y_deg.to_radians() * 0.5).tan();
    let tx = ty * cam.aspect;
    std::array::from_fn(|k| {
        let d = if k < 4 { d0 } else { d1 };
        let sx = if k & 1 == 0 { -1.0 } else { 1.0 };
        let sy = if k & 2 == 0 { -1.0 } else { 1.0 };
        cam.eye + b.forward * d + b.right * (sx * tx * d) + b.up * (sy * ty * d)
    })
}

/// The light's view: a fixed orientation along −`sun` through the world origin; view x and y
/// span the map, view z is the height along the sun.
pub fn light_view(sun: Vec3) -> Mat4 {
    let up = if sun.cross(Vec3::Z).length_squared() < 1e-6 {
        Vec3::Y
    } else {
        Vec3::Z
    };
    Mat4::look_at_rh(Vec3::ZERO, -sun, up)
}

/// The cascade of the view slice `[d0, d1]`: the slice's bounding sphere (centre on the view
/// axis where the near and far corners are equally far, clamped to the far plane), its radius
/// grown for the snapping and rounded up to a power of 2^(1/8), the centre snapped to whole
/// texels of the light's view plane; depth from the sphere's bottom to `top` (the highest
/// point of the scene along the sun) or the sphere's top, whichever is higher.
pub fn fit_cascade(cam: &Camera, (d0, d1): (f32, f32), sun: Vec3, top: f32, size: u32) -> Cascade {
    let ty = (cam.fov_y_deg.to_radians() * 0.5).tan();
    let k2 = ty * ty * (1.0 + cam.aspect * cam.aspect);
    let z = ((d0 + d1) * (1.0 + k2) * 0.5).min(d1);
    let r = ((z - d0).powi(2) + d0 * d0 * k2)
        .max((d1 - z).powi(2) + d1 * d1 * k2)
        .sqrt()
        .max(1e-3);
    // Snapping moves the centre by up to half a texel (r/size) per axis.
    let grown = r / (1.0 - 1.0 / size as f32);
    let half = 2f32.powf((grown.log2() * 8.0).ceil() / 8.0);
    let texel = 2.0 * half / size as f32;
    let view = light_view(sun);
    let c = view.transform_point3(cam.eye + cam.basis().forward * z);
    let (x, y) = ((c.x / texel).round() * texel, (c.y / texel).round() * texel);
    let pad = half * 1e-3;
    let z_top = top.max(c.z + half) + pad;
    let z_bottom = c.z - half - pad;
    let proj = Mat4::orthographic_rh(x - half, x + half, y - half, y + half, -z_top, -z_bottom);
    Cascade {
        view_proj: proj * view,
        texel_m: texel,
        depth: (d0, d1),
        origin: [x, y],
        half_extent: half,
    }
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

    fn cameras() -> Vec<Camera> {
        vec![
            Camera::look_at(
                Vec3::new(45.5, 49.5, 9.0),
                Vec3::new(45.0, 53.0, 4.3),
                45.0,
                4.0 / 3.0,
            ),
            Camera::look_at(
                Vec3::new(0.0, 0.0, 30.0),
                Vec3::new(500.0, 800.0, 0.0),
                60.0,
                16.0 / 9.0,
            ),
            // Straight down, and a tall narrow image.
            Camera::look_at(
                Vec3::new(10.0, -4.0, 120.0),
                Vec3::new(10.0, -4.0, 0.0),
                30.0,
                0.5,
            ),
        ]
    }

    fn suns() -> [Vec3; 3] {
        [
            Vec3::new(-0.55, 0.53, 0.64).normalize(),
            Vec3::Z,
            Vec3::new(0.9, 0.0, 0.1).normalize(),
        ]
    }

    #[test]
    fn the_splits_blend_the_logarithmic_and_uniform_schemes() {
        // λ = 0: uniform steps; λ = 1: a constant ratio; both run from near to far.
        let u = split_depths(2.0, 10.0, 4, 0.0);
        let l = split_depths(1.0, 81.0, 4, 1.0);
        for i in 0..4 {
            assert!((u[i + 1] - u[i] - 2.0).abs() < 1e-5, "{u:?}");
            assert!((l[i + 1] / l[i] - 3.0).abs() < 1e-4, "{l:?}");
        }
        let d = split_depths(0.5, 4000.0, 4, SPLIT_LAMBDA);
        assert_eq!((d[0], d[4]), (0.5, 4000.0));
        for (i, w) in d.windows(2).enumerate() {
            assert!(w[0] < w[1], "{d:?}");
            // Between the uniform and the logarithmic split of the same step.
            let t = (i + 1) as f32 / 4.0;
            let (lg, un) = (0.5 * 8000f32.powf(t), 0.5 + 3999.5 * t);
            assert!(w[1] >= lg.min(un) - 1e-2 && w[1] <= lg.max(un) + 1e-2);
        }
    }

    /// Every point of each frustum slice (its corners, its centre and points between them, as
    /// [`slice_corners`] and the camera's own ray give them) lies inside its cascade's light
    /// box, and so does every point above it towards the sun up to the scene's top.
    #[test]
    fn every_point_of_each_slice_lies_inside_its_cascade() {
        for cam in cameras() {
            for sun in suns() {
                let d = split_depths(cam.near.max(4.0), 4000.0, 4, SPLIT_LAMBDA);
                let top = 200.0;
                for w in d.windows(2) {
                    let c = fit_cascade(&cam, (w[0], w[1]), sun, top, 2048);
                    let corners = slice_corners(&cam, w[0], w[1]);
                    // The corners agree with the camera's projection (an independent path).
                    let vp = cam.view_proj();
                    for (k, p) in corners.iter().enumerate() {
                        let q = vp.project_point3(*p);
                        let want = [(k & 1) as f32 * 2.0 - 1.0, (k & 2) as f32 - 1.0];
                        assert!((q.x - want[0]).abs() < 1e-3 && (q.y - want[1]).abs() < 1e-3);
                    }
                    let mut points = corners.to_vec();
                    for a in 0..8 {
                        for b in a + 1..8 {
                            points.push(corners[a].lerp(corners[b], 0.37));
                        }
                    }
                    for p in &points {
                        let q = c.view_proj.project_point3(*p);
                        assert!(q.x.abs() <= 1.0 && q.y.abs() <= 1.0, "{sun} {w:?}: {q}");
                        assert!((0.0..=1.0).contains(&q.z), "{sun} {w:?}: {q}");
                        // A caster between the sun and the point, at the scene's top.
                        let lift = (top - p.dot(sun)).max(0.0);
                        let r = c.view_proj.project_point3(*p + sun * lift);
                        assert!(r.x.abs() <= 1.0 && r.y.abs() <= 1.0, "{r}");
                        assert!(r.z >= 0.0 && r.z <= q.z + 1e-6, "{r} above {q}");
                    }
                }
            }
        }
    }

    /// Moving the camera keeps the texel size and moves the snapped origin, and the texel grid
    /// a fixed world point falls on, by whole texels.
    #[test]
    fn the_snapped_origin_moves_in_whole_texels_when_the_camera_translates() {
        let sun = suns()[0];
        let base = cameras()[1];
        let fixed = Vec3::new(123.4, 567.8, 3.0);
        let size = 2048;
        let (d0, d1) = (4.0, 40.0);
        let c0 = fit_cascade(&base, (d0, d1), sun, 200.0, size);
        let mut moved_texels = 0.0;
        for k in 1..20 {
            let t = Vec3::new(0.37, -0.21, 0.05) * k as f32;
            let cam = Camera {
                eye: base.eye + t,
                target: base.target + t,
                ..base
            };
            let c = fit_cascade(&cam, (d0, d1), sun, 200.0, size);
            assert_eq!(c.half_extent, c0.half_extent);
            assert_eq!(c.texel_m, c0.texel_m);
            for a in 0..2 {
                let n = (c.origin[a] - c0.origin[a]) / c.texel_m;
                assert!((n - n.round()).abs() < 1e-3, "{k}: {n} texels");
                moved_texels += n.abs();
            }
            // The fixed point's texel coordinate (light x, y) shifts by whole texels too.
            let (p0, p) = (
                c0.view_proj.project_point3(fixed),
                c.view_proj.project_point3(fixed),
            );
            for a in 0..2 {
                let shift = (p[a] - p0[a]) * 0.5 * size as f32;
                assert!((shift - shift.round()).abs() < 0.02, "{k}: {shift}");
            }
        }
        // The camera did move the maps.
        assert!(moved_texels > 100.0, "{moved_texels}");
    }

    #[test]
    fn the_near_cascade_is_much_finer_than_one_map_over_the_scene() {
        let cam = cameras()[1];
        let (lo, hi) = (
            Vec3::new(-2000.0, -2000.0, 0.0),
            Vec3::new(2000.0, 2000.0, 150.0),
        );
        let (_, single) = fit_light(lo, hi, suns()[0], SHADOW_MAP_SIZE);
        let far = view_far(&cam, lo, hi);
        let d = split_depths(
            cam.near.max(far * SPLIT_NEAR_FRACTION),
            far,
            4,
            SPLIT_LAMBDA,
        );
        let near = fit_cascade(&cam, (cam.near, d[1]), suns()[0], hi.z, CASCADE_MAP_SIZE);
        let last = fit_cascade(&cam, (d[3], d[4]), suns()[0], hi.z, CASCADE_MAP_SIZE);
        assert!(near.texel_m * 10.0 < single, "{} vs {single}", near.texel_m);
        assert!(last.texel_m > near.texel_m);
        // The slice's sphere: radius at least half the far plane's diagonal.
        let c = slice_corners(&cam, cam.near, d[1]);
        assert!(near.half_extent >= 0.5 * c[4].distance(c[7]));
    }

    /// A camera far from a small scene: a cascade whose box would hold the whole scene is
    /// replaced by the scene's own box and ends the list; every scene corner lies inside it.
    #[test]
    fn a_cascade_holding_the_whole_scene_is_the_last_and_fits_the_scene() {
        let (lo, hi) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(100.0, 80.0, 20.0));
        // The default framing: the near plane halfway to the scene.
        let cam = Camera::frame_box(lo, hi, 45.0, 1.5);
        for sun in suns() {
            let s = shadows_of_box(lo, hi, &cam, sun, 4);
            assert!(s.cascades.len() < 4, "{sun}: {}", s.cascades.len());
            let last = s.cascades.last().unwrap();
            assert_eq!(last.depth.1, view_far(&cam, lo, hi));
            let sphere = fit_cascade(&cam, last.depth, sun, f32::MIN, CASCADE_MAP_SIZE);
            assert!(
                last.texel_m <= sphere.texel_m,
                "{} {}",
                last.texel_m,
                sphere.texel_m
            );
            for k in 0..8 {
                let q = last.view_proj.project_point3(corner(lo, hi, k));
                assert!(
                    q.x.abs() <= 1.0 && q.y.abs() <= 1.0 && (0.0..=1.0).contains(&q.z),
                    "{q}"
                );
            }
            // Close up, all four are kept.
            let near = Camera::look_at(
                Vec3::new(50.0, 30.0, 22.0),
                Vec3::new(50.0, 40.0, 18.0),
                45.0,
                1.5,
            );
            assert_eq!(shadows_of_box(lo, hi, &near, sun, 4).cascades.len(), 4);
        }
    }
}
