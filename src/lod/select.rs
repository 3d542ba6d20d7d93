//! The LOD selection rule: which representation of a model an instance is drawn with.
//!
//! One pure function of the view ([`choose`]), used by the renderer, `bake dump` and the tests
//! alike. With `k = H / (2·tan(fov_y/2))` the pixels per model unit at distance 1 ([`pixels_per_unit`]),
//! instance scale `s`, distance `d` from the eye to the instance's bounding-sphere centre and a
//! pixel threshold `tau`, a representation of geometric error `e` (model units) is acceptable when
//! its projected error `e·s·k/d` is at most `tau`. [`choose`] draws the skeleton (the model's own
//! line and point arrays, where the `lod` section has them) when the model's bounding sphere
//! (radius `R`) projects to at most `P` pixels, `R·s·k/d ≤ P` (`P` = the section's
//! `skeleton.pixels`, [`SKELETON_PIXELS`] by default: the skeleton is a size cutoff, not an error
//! bound, so it is kept for models that cover a pixel or two), else the impostor when the
//! impostor's own error passes, else the coarsest mesh level that passes (level 0, error 0, always
//! passes). No hysteresis: an image depends only on the view.
//!
//! The test is evaluated as `e·s·k ≤ tau·d`, so `d = 0` and `e = 0` are well defined (level 0).
//! The distance at which a representation becomes acceptable is [`switch_distance`]: `e·s·k/tau`.

use super::section::LodMeta;

/// The reference view of `bake dump`'s switch distances: 1280×720 (its height), the renderer's
/// default vertical field of view (`render::camera::DEFAULT_FOV_Y_DEG`, checked by a test), tau 1.
pub const REFERENCE_HEIGHT: u32 = 720;
pub const REFERENCE_FOV_Y_DEG: f32 = 45.0;
pub const DEFAULT_TAU: f32 = 1.0;
/// The projected bounding radius (pixels) at and below which a model with a skeleton is drawn
/// as its skeleton: one pixel, where the impostor's quad is 2 × 2 pixels.
pub const SKELETON_PIXELS: f32 = 1.0;

/// What an instance is drawn with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// Mesh level `0..levels.len()` (0 = the full mesh).
    Mesh(usize),
    /// The impostor atlas.
    Impostor,
    /// The skeleton's segments and points.
    Skeleton,
}

/// Pixels per model unit at distance 1 for an image `height` pixels high with vertical field of
/// view `fov_y_deg`: `k = H / (2·tan(fov_y/2))`.
pub fn pixels_per_unit(height: u32, fov_y_deg: f32) -> f32 {
    height as f32 / (2.0 * (fov_y_deg.to_radians() * 0.5).tan())
}

/// `k` of the reference view (1280×720, 45°).
pub fn reference_k() -> f32 {
    pixels_per_unit(REFERENCE_HEIGHT, REFERENCE_FOV_Y_DEG)
}

/// Whether a representation of geometric error `error` passes at distance `distance`.
fn passes(error: f32, scale: f32, distance: f32, k: f32, tau: f32) -> bool {
    error * scale.abs() * k <= tau * distance.max(0.0)
}

/// The representation to draw: see the module documentation. `meta.levels` must be non-empty
/// with non-decreasing errors (the section reader checks both); an empty list gives `Mesh(0)`.
pub fn choose(meta: &LodMeta, scale: f32, distance: f32, k: f32, tau: f32) -> Choice {
    if let Some(sk) = &meta.skeleton
        && passes(meta.radius, scale, distance, k, sk.pixels)
    {
        return Choice::Skeleton;
    }
    if let Some(imp) = &meta.impostor
        && passes(imp.error, scale, distance, k, tau)
    {
        return Choice::Impostor;
    }
    let coarsest = meta
        .levels
        .iter()
        .rposition(|l| passes(l.error, scale, distance, k, tau));
    Choice::Mesh(coarsest.unwrap_or(0))
}

/// The distance from which a representation of error `error` is acceptable: `error·s·k/tau`
/// (0 for the full mesh).
pub fn switch_distance(error: f32, scale: f32, k: f32, tau: f32) -> f32 {
    error * scale.abs() * k / tau
}

/// The distance from which a model of bounding radius `radius` and instance scale `scale` is
/// drawn as its skeleton: `radius·s·k/pixels`.
pub fn skeleton_switch_distance(radius: f32, pixels: f32, scale: f32, k: f32) -> f32 {
    radius * scale.abs() * k / pixels
}

/// Switch distances of every mesh level, then of the impostor if there is one, at instance
/// scale 1 in the reference view with `tau`.
pub fn reference_switch_distances(meta: &LodMeta, tau: f32) -> (Vec<f32>, Option<f32>) {
    let k = reference_k();
    let levels = meta
        .levels
        .iter()
        .map(|l| switch_distance(l.error, 1.0, k, tau))
        .collect();
    let imp = meta
        .impostor
        .as_ref()
        .map(|i| switch_distance(i.error, 1.0, k, tau));
    (levels, imp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lod::section::{ImpostorMeta, LodLevel};

    fn meta(errors: &[f32], impostor: Option<f32>) -> LodMeta {
        LodMeta {
            mesh_section: "mesh:t.txf".into(),
            mesh_vertices: 3,
            centre: [0.0; 3],
            radius: 1.0,
            levels: errors
                .iter()
                .map(|&e| LodLevel {
                    error: e,
                    ..LodLevel::default()
                })
                .collect(),
            impostor: impostor.map(|e| ImpostorMeta {
                error: e,
                ..ImpostorMeta::default()
            }),
            ..LodMeta::default()
        }
    }

    #[test]
    fn pixels_per_unit_by_hand() {
        // 90°: tan 45° = 1, so k = H/2.
        assert!((pixels_per_unit(720, 90.0) - 360.0).abs() < 1e-3);
        // 45°: tan 22.5° = 0.41421356, k = 720 / 0.82842712 = 869.1169.
        assert!((reference_k() - 869.1169).abs() < 1e-2);
    }

    #[test]
    fn the_reference_fov_is_the_renderers_default() {
        assert_eq!(
            REFERENCE_FOV_Y_DEG,
            crate::render::camera::DEFAULT_FOV_Y_DEG
        );
    }

    /// Errors 0, 0.01, 0.1 with k = 360 (90°, 720 px), tau 1, scale 2: switch distances
    /// 0.01·2·360 = 7.2 and 0.1·2·360 = 72; an impostor of error 0.5 switches at 360.
    #[test]
    fn switch_distances_by_hand() {
        let m = meta(&[0.0, 0.01, 0.1], Some(0.5));
        let k = 360.0;
        let c = |d: f32| choose(&m, 2.0, d, k, 1.0);
        assert_eq!(c(0.0), Choice::Mesh(0));
        assert_eq!(c(7.19), Choice::Mesh(0));
        assert_eq!(c(7.21), Choice::Mesh(1));
        assert_eq!(c(71.9), Choice::Mesh(1));
        assert_eq!(c(72.1), Choice::Mesh(2));
        assert_eq!(c(359.0), Choice::Mesh(2));
        assert_eq!(c(361.0), Choice::Impostor);
        assert!((switch_distance(0.01, 2.0, k, 1.0) - 7.2).abs() < 1e-4);
        assert!((switch_distance(0.5, 2.0, k, 1.0) - 360.0).abs() < 1e-3);
        // A looser tau (2 px) halves every distance; a negative scale counts by its size.
        let c2 = |d: f32| choose(&m, -2.0, d, k, 2.0);
        assert_eq!(c2(3.7), Choice::Mesh(1));
        assert_eq!(c2(36.1), Choice::Mesh(2));
        assert_eq!(c2(180.5), Choice::Impostor);
    }

    #[test]
    fn without_an_impostor_the_last_level_stays() {
        let m = meta(&[0.0, 0.2], None);
        assert_eq!(choose(&m, 1.0, 1e9, 1000.0, 1.0), Choice::Mesh(1));
        assert_eq!(choose(&m, 1.0, -5.0, 1000.0, 1.0), Choice::Mesh(0));
        assert_eq!(
            choose(&meta(&[], None), 1.0, 10.0, 1.0, 1.0),
            Choice::Mesh(0)
        );
    }

    /// The rule against brute force: the chosen level is the largest index whose projected error
    /// is ≤ tau, at many random views.
    #[test]
    fn choice_matches_brute_force() {
        let m = meta(&[0.0, 0.003, 0.02, 0.05, 0.3], Some(0.8));
        let mut r = crate::rng::Rng::new(7);
        for _ in 0..2000 {
            let d = r.f32() * 2000.0;
            let s = 0.1 + r.f32() * 4.0;
            let k = 100.0 + r.f32() * 2000.0;
            let tau = 0.25 + r.f32() * 4.0;
            let px = |e: f32| e * s * k / d.max(1e-30);
            let want = if px(0.8) <= tau {
                Choice::Impostor
            } else {
                let mut best = 0;
                for (i, l) in m.levels.iter().enumerate() {
                    if px(l.error) <= tau {
                        best = i;
                    }
                }
                Choice::Mesh(best)
            };
            let got = choose(&m, s, d, k, tau);
            // Rounding can differ only at a switch distance itself.
            if got != want {
                let near = m
                    .levels
                    .iter()
                    .map(|l| l.error)
                    .chain([0.8])
                    .any(|e| (px(e) - tau).abs() < 1e-4 * tau);
                assert!(near, "d {d} s {s} k {k} tau {tau}: {got:?} vs {want:?}");
            }
        }
    }

    /// Radius 1, k = 360, scale 2: the model covers 1 px of radius at d = 720, 0.5 px at 1440.
    #[test]
    fn the_skeleton_is_a_size_cutoff_before_the_impostor() {
        let mut m = meta(&[0.0, 0.01, 0.1], Some(0.5));
        m.skeleton = Some(crate::lod::section::SkeletonMeta {
            segments: 1,
            points: 0,
            albedo: [0, 0, 0, 255],
            pixels: 1.0,
        });
        let k = 360.0;
        assert_eq!(choose(&m, 2.0, 719.0, k, 1.0), Choice::Impostor);
        assert_eq!(choose(&m, 2.0, 721.0, k, 1.0), Choice::Skeleton);
        assert_eq!(
            choose(&m, -2.0, 721.0, k, 8.0),
            Choice::Skeleton,
            "independent of tau"
        );
        assert!((skeleton_switch_distance(1.0, 1.0, 2.0, k) - 720.0).abs() < 1e-3);
        // A 4-pixel cutoff moves it 4× closer, past the impostor's own switch (360).
        m.skeleton.as_mut().unwrap().pixels = 4.0;
        assert_eq!(choose(&m, 2.0, 181.0, k, 1.0), Choice::Skeleton);
        assert_eq!(choose(&m, 2.0, 179.0, k, 1.0), Choice::Mesh(2));
        // Against brute force: projected radius R·s·k/d.
        let mut r = crate::rng::Rng::new(3);
        for _ in 0..1000 {
            let (d, s, kk) = (
                r.f32() * 5000.0,
                0.1 + r.f32() * 3.0,
                100.0 + r.f32() * 2000.0,
            );
            let px = s * kk / d.max(1e-30);
            let got = choose(&m, s, d, kk, 1.0) == Choice::Skeleton;
            if (px - 4.0).abs() > 1e-4 {
                assert_eq!(got, px <= 4.0, "d {d} s {s} k {kk}");
            }
        }
    }

    #[test]
    fn reference_distances_of_the_dump() {
        let m = meta(&[0.0, 0.01], Some(0.1));
        let (l, i) = reference_switch_distances(&m, 1.0);
        assert_eq!(l[0], 0.0);
        assert!((l[1] - 8.691169).abs() < 1e-3);
        assert!((i.unwrap() - 86.91169).abs() < 1e-2);
    }
}
