//! The render camera: a Z-up pinhole camera with an infinite reversed-Z projection, the default
//! framing of a scene's area of interest, and the per-pixel ray the sky pass uses.
//!
//! Conventions: right-handed world, Z up; pixel (0, 0) is the top-left pixel; pixel centres are at
//! (x + 0.5, y + 0.5). The projection maps the near plane to depth 1 and infinity to depth 0
//! (reversed Z: far more depth precision with a `Depth32Float` buffer, and no far plane to pick).

use glam::{Mat4, Vec3};

/// Elevation of the default view above the box centre, in degrees.
pub const DEFAULT_ELEVATION_DEG: f32 = 25.0;
/// Where the framed box's centre sits vertically in the default view (NDC, −1 bottom, 1 top).
pub const FRAME_CENTRE_NDC_Y: f32 = -0.3;
/// The framed box's corners stay inside ±this in NDC.
pub const FRAME_MARGIN_NDC: f32 = 0.95;
/// Default vertical field of view, in degrees.
pub const DEFAULT_FOV_Y_DEG: f32 = 45.0;

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    /// Near plane distance in metres (the far plane is at infinity).
    pub near: f32,
    /// Width / height of the image.
    pub aspect: f32,
}

/// The camera's orthonormal frame: forward, right and up (up is as close to +Z as the view allows).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Basis {
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
}

impl Camera {
    /// A camera at `eye` looking at `target`; the near plane scales with the viewing distance.
    pub fn look_at(eye: Vec3, target: Vec3, fov_y_deg: f32, aspect: f32) -> Camera {
        let dist = (target - eye).length();
        Camera {
            eye,
            target,
            fov_y_deg,
            near: (dist * 1e-4).max(1e-3),
            aspect,
        }
    }

    /// Frames the box `[lo, hi]` as a landscape view: from the south, raised by
    /// [`DEFAULT_ELEVATION_DEG`] above the box centre, the view tilted up so the centre sits at
    /// [`FRAME_CENTRE_NDC_Y`] (leaving the upper part of the image to the horizon and sky), at
    /// the shortest distance (bisection) where every corner lies within [`FRAME_MARGIN_NDC`].
    pub fn frame_box(lo: Vec3, hi: Vec3, fov_y_deg: f32, aspect: f32) -> Camera {
        let centre = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-3);
        let e = DEFAULT_ELEVATION_DEG.to_radians();
        let back = Vec3::new(0.0, -e.cos(), e.sin());
        let tan_half = (fov_y_deg.to_radians() * 0.5).tan();
        let pitch = e - (-FRAME_CENTRE_NDC_Y * tan_half).atan();
        let forward = Vec3::new(0.0, pitch.cos(), -pitch.sin());
        let at = |d: f32| {
            let eye = centre + back * d;
            let mut cam = Camera::look_at(eye, eye + forward * d, fov_y_deg, aspect);
            cam.near = ((d - radius) * 0.5).max(d * 1e-3);
            cam
        };
        let fits = |cam: &Camera| {
            let vp = cam.view_proj();
            (0..8).all(|k| {
                let c = Vec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), hi, lo);
                let p = vp * c.extend(1.0);
                let (x, y) = (p.x / p.w, p.y / p.w);
                p.w > 0.0 && x.abs() <= FRAME_MARGIN_NDC && y.abs() <= FRAME_MARGIN_NDC
            })
        };
        let (mut near, mut far) = (
            0.0f32,
            radius / tan_half.min(tan_half * aspect).atan().sin(),
        );
        while !fits(&at(far)) && far < radius * 1e6 {
            far *= 2.0;
        }
        for _ in 0..40 {
            let mid = 0.5 * (near + far);
            if fits(&at(mid)) {
                far = mid;
            } else {
                near = mid;
            }
        }
        at(far)
    }

    /// The camera frame. When looking straight up or down, +Y takes the role of up.
    pub fn basis(&self) -> Basis {
        let forward = (self.target - self.eye).normalize_or(Vec3::NEG_Z);
        let world_up = if forward.cross(Vec3::Z).length_squared() < 1e-8 {
            Vec3::Y
        } else {
            Vec3::Z
        };
        let right = forward.cross(world_up).normalize();
        let up = right.cross(forward);
        Basis { forward, right, up }
    }

    /// World to view.
    pub fn view(&self) -> Mat4 {
        let b = self.basis();
        Mat4::look_at_rh(self.eye, self.eye + b.forward, b.up)
    }

    /// World to clip space (wgpu conventions, reversed infinite Z).
    pub fn view_proj(&self) -> Mat4 {
        let proj = Mat4::perspective_infinite_reverse_rh(
            self.fov_y_deg.to_radians(),
            self.aspect,
            self.near,
        );
        proj * self.view()
    }

    /// Direction (unit) of the ray through the point with normalized device coordinates
    /// (`ndc_x`, `ndc_y`) ∈ [−1, 1]² (+y up). The sky shader computes the same expression.
    pub fn ray(&self, ndc_x: f32, ndc_y: f32) -> Vec3 {
        let b = self.basis();
        let ty = (self.fov_y_deg.to_radians() * 0.5).tan();
        (b.forward + b.right * (ndc_x * ty * self.aspect) + b.up * (ndc_y * ty)).normalize()
    }

    /// [`Camera::ray`] through image point `(px, py)` of a `w` × `h` image, in pixels from the
    /// top-left corner (a pixel's centre is at +0.5).
    pub fn pixel_ray(&self, (px, py): (f32, f32), (w, h): (u32, u32)) -> Vec3 {
        self.ray(px / w as f32 * 2.0 - 1.0, 1.0 - py / h as f32 * 2.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_projects_to_the_image_centre() {
        let cam = Camera::look_at(
            Vec3::new(3.0, -7.0, 4.0),
            Vec3::new(1.0, 2.0, 0.5),
            50.0,
            1.5,
        );
        let p = cam.view_proj().project_point3(cam.target);
        assert!(p.x.abs() < 1e-5 && p.y.abs() < 1e-5, "{p:?}");
        assert!(p.z > 0.0 && p.z < 1.0, "reversed depth in (0, 1): {p:?}");
    }

    #[test]
    fn ray_and_projection_agree() {
        // A point along the ray through an NDC position projects back to that position.
        let cam = Camera::look_at(Vec3::new(0.0, -10.0, 5.0), Vec3::ZERO, 45.0, 4.0 / 3.0);
        for &(x, y) in &[(0.5f32, -0.25f32), (-0.9, 0.9), (0.0, 0.0)] {
            let p = cam.eye + cam.ray(x, y) * 7.0;
            let q = cam.view_proj().project_point3(p);
            assert!(
                (q.x - x).abs() < 1e-4 && (q.y - y).abs() < 1e-4,
                "{x},{y} → {q:?}"
            );
        }
    }

    #[test]
    fn framing_keeps_every_box_corner_in_view() {
        let (lo, hi) = (Vec3::new(-5.0, 2.0, 0.0), Vec3::new(40.0, 20.0, 8.0));
        for aspect in [0.5f32, 1.0, 2.0] {
            let cam = Camera::frame_box(lo, hi, DEFAULT_FOV_Y_DEG, aspect);
            for k in 0..8 {
                let c = Vec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                );
                let p = cam.view_proj().project_point3(c);
                assert!(
                    p.x.abs() <= 1.0 && p.y.abs() <= 1.0 && p.z > 0.0,
                    "{aspect}: {p:?}"
                );
            }
        }
    }

    #[test]
    fn framing_puts_the_box_centre_low_in_the_image() {
        let (lo, hi) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(100.0, 100.0, 5.0));
        let cam = Camera::frame_box(lo, hi, DEFAULT_FOV_Y_DEG, 1.6);
        let p = cam.view_proj().project_point3((lo + hi) * 0.5);
        assert!(
            (p.y - FRAME_CENTRE_NDC_Y).abs() < 1e-3 && p.x.abs() < 1e-4,
            "{p:?}"
        );
        // The eye is above the centre at the default elevation.
        let d = (cam.eye - (lo + hi) * 0.5).normalize();
        assert!((d.z.asin().to_degrees() - DEFAULT_ELEVATION_DEG).abs() < 1e-3);
    }

    #[test]
    fn looking_straight_down_has_a_valid_basis() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO, 45.0, 1.0);
        let b = cam.basis();
        assert!(b.right.is_finite() && (b.right.length() - 1.0).abs() < 1e-5);
        assert!(b.up.dot(b.forward).abs() < 1e-5);
    }
}
