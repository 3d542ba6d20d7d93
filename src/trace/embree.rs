//! Embree 3 side by side (cargo feature `embree`, Debian's `libembree-dev` 3.13): the model's
//! triangles in an Embree scene with Embree's own BVH, and an intersect filter function with
//! the same alpha test as [`super::ModelBvh`] (colour-map alpha at the interpolated texture
//! coordinate, nearest texel, repeating, opaque at alpha >= 0.5 through [`AlphaMask`]).
//!
//! A minimal self-written binding over the C API (no crate); every `unsafe` of the project's
//! Embree use is in this module. [`EmbreeScene`] implements [`ModelTracer`], so the PRT stage
//! traces on it with `tracer = "embree"` (`bake bench rays --embree` measures it).

use super::{AlphaMask, Hit, ModelTracer, Ray};
use crate::error::{Error, Result};
use crate::model::Mesh;
use glam::Vec3A;
use std::ffi::c_void;
use std::os::raw::{c_char, c_int, c_uint};

type RtcDevice = *mut c_void;
type RtcScene = *mut c_void;
type RtcGeometry = *mut c_void;

const GEOMETRY_TYPE_TRIANGLE: c_int = 0;
const BUFFER_TYPE_INDEX: c_int = 0;
const BUFFER_TYPE_VERTEX: c_int = 1;
const FORMAT_UINT3: c_int = 0x5003;
const FORMAT_FLOAT3: c_int = 0x9003;
const INVALID_ID: c_uint = u32::MAX;

/// `struct RTCFilterFunctionNArguments` (rtcore_common.h).
#[repr(C)]
struct FilterArgs {
    valid: *mut c_int,
    geometry_user_ptr: *mut c_void,
    context: *mut IntersectContext,
    ray: *mut c_void,
    hit: *mut c_void,
    n: c_uint,
}

type FilterFn = Option<unsafe extern "C" fn(args: *const FilterArgs)>;

/// `struct RTCIntersectContext` with `RTC_MAX_INSTANCE_LEVEL_COUNT == 1` (Debian's build).
#[repr(C)]
struct IntersectContext {
    flags: c_int,
    filter: FilterFn,
    inst_id: [c_uint; 1],
}

/// `struct RTCRay` (rtcore_ray.h), 16-byte aligned: what rtcOccluded1 reads and writes.
#[repr(C, align(16))]
struct RayOnly {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: c_uint,
    id: c_uint,
    flags: c_uint,
}

/// `struct RTCRay` + `struct RTCHit` = `struct RTCRayHit` (rtcore_ray.h), 16-byte aligned.
#[repr(C, align(16))]
struct RayHit {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: c_uint,
    id: c_uint,
    flags: c_uint,
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: c_uint,
    geom_id: c_uint,
    inst_id: [c_uint; 1],
}

#[link(name = "embree3")]
unsafe extern "C" {
    fn rtcNewDevice(config: *const c_char) -> RtcDevice;
    fn rtcReleaseDevice(device: RtcDevice);
    fn rtcNewScene(device: RtcDevice) -> RtcScene;
    fn rtcReleaseScene(scene: RtcScene);
    fn rtcCommitScene(scene: RtcScene);
    fn rtcNewGeometry(device: RtcDevice, ty: c_int) -> RtcGeometry;
    fn rtcSetNewGeometryBuffer(
        geometry: RtcGeometry,
        ty: c_int,
        slot: c_uint,
        format: c_int,
        byte_stride: usize,
        item_count: usize,
    ) -> *mut c_void;
    fn rtcSetGeometryUserData(geometry: RtcGeometry, ptr: *mut c_void);
    fn rtcSetGeometryIntersectFilterFunction(geometry: RtcGeometry, filter: FilterFn);
    fn rtcSetGeometryOccludedFilterFunction(geometry: RtcGeometry, filter: FilterFn);
    fn rtcCommitGeometry(geometry: RtcGeometry);
    fn rtcAttachGeometry(scene: RtcScene, geometry: RtcGeometry) -> c_uint;
    fn rtcReleaseGeometry(geometry: RtcGeometry);
    fn rtcIntersect1(scene: RtcScene, context: *mut IntersectContext, rayhit: *mut RayHit);
    fn rtcOccluded1(scene: RtcScene, context: *mut IntersectContext, ray: *mut RayOnly);
}

/// What the filter function reads: per triangle its corner texture coordinates and mask.
struct AlphaData {
    /// Per triangle: (uv0, uv1 - uv0, uv2 - uv0), as the obvhs tracer interpolates them.
    uv: Vec<[[f32; 2]; 3]>,
    /// Per triangle: index into `masks`, or `u32::MAX` (no alpha test).
    mask: Vec<u32>,
    masks: Vec<AlphaMask>,
}

/// A triangle as [`super::ModelBvh::hit_point`] reads it: corner 0 and the two edges from it.
#[derive(Debug, Clone, Copy)]
struct Corner {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
}

/// An Embree scene of one mesh, alpha-tested like [`super::ModelBvh`].
pub struct EmbreeScene {
    device: RtcDevice,
    scene: RtcScene,
    /// Owned here so the filter's user pointer stays valid while the scene lives.
    _alpha: Box<AlphaData>,
    /// Per triangle (Embree's primID is the mesh's triangle index).
    corners: Vec<Corner>,
    materials: Vec<u32>,
    bounds: (Vec3A, Vec3A),
    skipped: usize,
}

// SAFETY: Embree devices and committed scenes are thread-safe for concurrent rtcIntersect1
// calls (Embree API documentation); the alpha data is only read after construction.
unsafe impl Send for EmbreeScene {}
// SAFETY: as above: after rtcCommitScene the scene is immutable and queries are reentrant.
unsafe impl Sync for EmbreeScene {}

/// Intersect filter: rejects a candidate hit on a transparent texel.
///
/// SAFETY (caller is Embree): `args` points to valid arguments for the duration of the call,
/// `geometry_user_ptr` is the `AlphaData` set in [`EmbreeScene::build`], and for rtcIntersect1
/// `n == 1`, so `hit` points to one `RTCHit` in the layout of [`RayHit`]'s hit half.
unsafe extern "C" fn alpha_filter(args: *const FilterArgs) {
    // SAFETY: see the function comment.
    let a = unsafe { &*args };
    // SAFETY: the user pointer is the boxed AlphaData, alive as long as the scene.
    let data = unsafe { &*(a.geometry_user_ptr as *const AlphaData) };
    let hit = a.hit as *const f32;
    for i in 0..a.n as usize {
        // SAFETY: valid has n entries.
        if unsafe { *a.valid.add(i) } == 0 {
            continue;
        }
        let n = a.n as usize;
        // SAFETY: RTCHitN is SOA: field f of ray i at offset (f * n + i) floats; u is field 3,
        // v field 4, primID field 5, all inside the n-wide hit block.
        let (u, v, prim) = unsafe {
            (
                *hit.add(3 * n + i),
                *hit.add(4 * n + i),
                *(hit.add(5 * n + i) as *const u32),
            )
        };
        let t = prim as usize;
        let m = data.mask.get(t).copied().unwrap_or(u32::MAX);
        if m == u32::MAX {
            continue;
        }
        let [t0, d1, d2] = data.uv[t];
        let s = t0[0] + u * d1[0] + v * d2[0];
        let tt = t0[1] + u * d1[1] + v * d2[1];
        if !data.masks[m as usize].opaque_at(s, tt) {
            // SAFETY: valid has n entries; 0 rejects the candidate.
            unsafe { *a.valid.add(i) = 0 };
        }
    }
}

impl EmbreeScene {
    /// Builds the scene of `mesh`; `masks[m]` is the alpha mask of material `m` (as for
    /// [`super::ModelBvh::build`]). Triangles with non-finite corners are left to Embree,
    /// which skips them.
    pub fn build(mesh: &Mesh, masks: &[Option<AlphaMask>]) -> Result<Self> {
        let mut kept_masks = Vec::new();
        let mut mat_mask = Vec::new();
        for m in masks {
            match m {
                Some(m) if !m.is_all_opaque() => {
                    mat_mask.push(kept_masks.len() as u32);
                    kept_masks.push(m.clone());
                }
                _ => mat_mask.push(u32::MAX),
            }
        }
        let uv_of = |i: u32| mesh.uvs.get(i as usize).copied().unwrap_or([0.0; 2]);
        let mut uv = Vec::with_capacity(mesh.indices.len());
        let mut mask = Vec::with_capacity(mesh.indices.len());
        for (t, &[a, b, c]) in mesh.indices.iter().enumerate() {
            let (ua, ub, uc) = (uv_of(a), uv_of(b), uv_of(c));
            uv.push([
                ua,
                [ub[0] - ua[0], ub[1] - ua[1]],
                [uc[0] - ua[0], uc[1] - ua[1]],
            ]);
            let mat = mesh.triangle_materials.get(t).copied().unwrap_or(0) as usize;
            mask.push(mat_mask.get(mat).copied().unwrap_or(u32::MAX));
        }
        if mesh
            .indices
            .iter()
            .flatten()
            .any(|&i| i as usize >= mesh.positions.len())
        {
            return Err(Error::runtime("embree: a triangle index is out of range"));
        }
        let p = |i: u32| Vec3A::from(mesh.positions[i as usize]);
        let corners: Vec<Corner> = mesh
            .indices
            .iter()
            .map(|&[a, b, c]| Corner {
                v0: p(a),
                e1: p(b) - p(a),
                e2: p(c) - p(a),
            })
            .collect();
        let skipped = mesh
            .indices
            .iter()
            .filter(|t| !t.iter().all(|&i| p(i).is_finite()))
            .count();
        let (lo, hi) = mesh.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
        let materials = (0..mesh.indices.len())
            .map(|t| mesh.triangle_materials.get(t).copied().unwrap_or(0))
            .collect();
        let alpha = Box::new(AlphaData {
            uv,
            mask,
            masks: kept_masks,
        });
        // SAFETY: plain C API calls in the documented order; buffers returned by
        // rtcSetNewGeometryBuffer hold item_count items of byte_stride bytes (Embree pads
        // them), and we write exactly that many; the user pointer outlives the scene.
        unsafe {
            let device = rtcNewDevice(std::ptr::null());
            if device.is_null() {
                return Err(Error::runtime("embree: rtcNewDevice failed"));
            }
            let scene = rtcNewScene(device);
            let geom = rtcNewGeometry(device, GEOMETRY_TYPE_TRIANGLE);
            let nv = mesh.positions.len();
            let nt = mesh.indices.len();
            let vb = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_VERTEX, 0, FORMAT_FLOAT3, 12, nv)
                as *mut [f32; 3];
            let ib = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, nt)
                as *mut [u32; 3];
            if (vb.is_null() && nv > 0) || (ib.is_null() && nt > 0) {
                rtcReleaseGeometry(geom);
                rtcReleaseScene(scene);
                rtcReleaseDevice(device);
                return Err(Error::runtime("embree: buffer allocation failed"));
            }
            std::ptr::copy_nonoverlapping(mesh.positions.as_ptr(), vb, nv);
            std::ptr::copy_nonoverlapping(mesh.indices.as_ptr(), ib, nt);
            rtcSetGeometryUserData(geom, &*alpha as *const AlphaData as *mut c_void);
            rtcSetGeometryIntersectFilterFunction(geom, Some(alpha_filter));
            rtcSetGeometryOccludedFilterFunction(geom, Some(alpha_filter));
            rtcCommitGeometry(geom);
            rtcAttachGeometry(scene, geom);
            rtcReleaseGeometry(geom);
            rtcCommitScene(scene);
            Ok(EmbreeScene {
                device,
                scene,
                _alpha: alpha,
                corners,
                materials,
                bounds: (lo.into(), hi.into()),
                skipped,
            })
        }
    }

    /// Triangles Embree leaves out (non-finite corners), as [`super::ModelBvh::skipped_triangles`].
    pub fn skipped_triangles(&self) -> usize {
        self.skipped
    }

    /// Whether an alpha-tested hit lies on the ray segment (rtcOccluded1, stops at the first).
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let mut r = RayOnly {
            org: ray.origin.to_array(),
            tnear: ray.tmin,
            dir: ray.dir.to_array(),
            time: 0.0,
            tfar: ray.tmax,
            mask: u32::MAX,
            id: 0,
            flags: 0,
        };
        let mut ctx = IntersectContext {
            flags: 0,
            filter: None,
            inst_id: [INVALID_ID],
        };
        // SAFETY: the scene is committed and alive; ctx and r are valid, r 16-byte aligned.
        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut r) };
        // Embree sets tfar to -inf when the ray is occluded.
        r.tfar == f32::NEG_INFINITY
    }

    /// Closest alpha-tested hit (`slot` is the triangle index; Embree has no slots).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let mut rh = RayHit {
            org: ray.origin.to_array(),
            tnear: ray.tmin,
            dir: ray.dir.to_array(),
            time: 0.0,
            tfar: ray.tmax,
            mask: u32::MAX,
            id: 0,
            flags: 0,
            ng: [0.0; 3],
            u: 0.0,
            v: 0.0,
            prim_id: INVALID_ID,
            geom_id: INVALID_ID,
            inst_id: [INVALID_ID],
        };
        let mut ctx = IntersectContext {
            flags: 0,
            filter: None,
            inst_id: [INVALID_ID],
        };
        // SAFETY: the scene is committed and alive; ctx and rh are valid, rh 16-byte aligned.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        (rh.geom_id != INVALID_ID).then_some(Hit {
            t: rh.tfar,
            triangle: rh.prim_id,
            slot: rh.prim_id,
            u: rh.u,
            v: rh.v,
        })
    }
}

impl ModelTracer for EmbreeScene {
    #[inline]
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        EmbreeScene::closest_hit(self, ray)
    }
    #[inline]
    fn any_hit(&self, ray: &Ray) -> bool {
        EmbreeScene::any_hit(self, ray)
    }
    /// The same arithmetic as [`super::ModelBvh::hit_point`] on the same corners.
    #[inline]
    fn hit_point(&self, hit: &Hit) -> (Vec3A, Vec3A, u32) {
        let c = &self.corners[hit.triangle as usize];
        let position = c.v0 + c.e1 * hit.u + c.e2 * hit.v;
        let ng = c.e1.cross(c.e2).normalize_or_zero();
        (position, ng, self.materials[hit.triangle as usize])
    }
    fn bounds(&self) -> (Vec3A, Vec3A) {
        self.bounds
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: created in build, released once here.
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}
