//! Embree 3 side by side (cargo feature `embree`, Debian's `libembree-dev` 3.13): the model's
//! triangles in an Embree scene with Embree's own BVH, and an intersect filter function with
//! the same alpha test as [`super::ModelBvh`] (colour-map alpha at the interpolated texture
//! coordinate, nearest texel, repeating, opaque at alpha >= 0.5 through [`AlphaMask`]).
//!
//! A minimal self-written binding over the C API (no crate); every `unsafe` of the project's
//! Embree use is in this module. [`EmbreeScene`] implements [`ModelTracer`], so the PRT stage
//! traces on it with `tracer = "embree"` (`bake bench rays --embree` measures it).
//!
//! [`EmbreeSceneBvh`] is the two-level scene of the light-map and environment-map stages on
//! Embree ([`SceneTracer`]): one Embree scene per model (with the alpha filter), an Embree
//! instance (`RTC_GEOMETRY_TYPE_INSTANCE`, geometry ID = instance number) per placed model, and
//! the terrain as user geometry (geometry ID = `instances.len()`) whose callbacks call the
//! [`Heightfield`]'s own intersector, so terrain hits are those of [`super::SceneBvh`]. The
//! ignored instances of `closest_hit_excluding` travel in an extended intersect context and are
//! rejected by the filter function (their triangles are still traversed); `enclosing` is
//! decided on the CPU scene, so both backends ignore the same instances.

use super::scene::surface_of;
use super::{
    AlphaMask, Heightfield, Hit, InstanceTransform, ModelBvh, ModelTracer, Ray, SceneBvh, SceneHit,
    SceneTracer, SurfacePoint,
};
use crate::error::{Error, Result};
use crate::model::Mesh;
use glam::Vec3A;
use std::ffi::c_void;
use std::os::raw::{c_char, c_int, c_uint};
use std::sync::Arc;

type RtcDevice = *mut c_void;
type RtcScene = *mut c_void;
type RtcGeometry = *mut c_void;

const GEOMETRY_TYPE_TRIANGLE: c_int = 0;
const GEOMETRY_TYPE_USER: c_int = 120;
const GEOMETRY_TYPE_INSTANCE: c_int = 121;
const FORMAT_FLOAT3X4_COLUMN_MAJOR: c_int = 0x9234;
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

/// [`IntersectContext`] extended with the instances to ignore (Embree passes the context pointer
/// through to the filter and user-geometry callbacks unchanged).
#[repr(C)]
struct Context {
    base: IntersectContext,
    /// Instances (geometry IDs in the top-level scene) whose hits are rejected: `skip_len`
    /// entries at `skip`, a slice that outlives the query the context is made for.
    skip: *const c_uint,
    skip_len: usize,
}

impl Context {
    /// A context for one query; `skip` must stay alive until the query returns (every query
    /// here builds its context from a borrowed slice and drops it before returning).
    fn new(skip: &[u32]) -> Self {
        Context {
            base: IntersectContext {
                flags: 0,
                filter: None,
                inst_id: [INVALID_ID],
            },
            skip: skip.as_ptr(),
            skip_len: skip.len(),
        }
    }

    /// Whether hits of instance `inst` are rejected.
    fn skips(&self, inst: u32) -> bool {
        // SAFETY: `skip` and `skip_len` come from a slice alive for the query (see `new`).
        self.skip_len > 0
            && unsafe { std::slice::from_raw_parts(self.skip, self.skip_len) }.contains(&inst)
    }
}

/// `struct RTCIntersectFunctionNArguments` (rtcore_geometry.h).
#[repr(C)]
struct IntersectArgs {
    valid: *mut c_int,
    geometry_user_ptr: *mut c_void,
    prim_id: c_uint,
    context: *mut IntersectContext,
    rayhit: *mut c_void,
    n: c_uint,
    geom_id: c_uint,
}

/// `struct RTCBoundsFunctionArguments` (rtcore_geometry.h).
#[repr(C)]
struct BoundsArgs {
    geometry_user_ptr: *mut c_void,
    prim_id: c_uint,
    time_step: c_uint,
    bounds: *mut [f32; 8],
}

type IntersectFn = Option<unsafe extern "C" fn(args: *const IntersectArgs)>;
type BoundsFn = Option<unsafe extern "C" fn(args: *const BoundsArgs)>;

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
    fn rtcAttachGeometryByID(scene: RtcScene, geometry: RtcGeometry, id: c_uint);
    fn rtcSetGeometryInstancedScene(geometry: RtcGeometry, scene: RtcScene);
    fn rtcSetGeometryTransform(
        geometry: RtcGeometry,
        time_step: c_uint,
        format: c_int,
        xfm: *const c_void,
    );
    fn rtcSetGeometryUserPrimitiveCount(geometry: RtcGeometry, count: c_uint);
    fn rtcSetGeometryBoundsFunction(geometry: RtcGeometry, f: BoundsFn, user: *mut c_void);
    fn rtcSetGeometryIntersectFunction(geometry: RtcGeometry, f: IntersectFn);
    fn rtcSetGeometryOccludedFunction(geometry: RtcGeometry, f: IntersectFn);
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

/// An Embree device, released when the last scene built on it is gone.
struct Device(RtcDevice);

impl Device {
    fn new() -> Result<Arc<Device>> {
        // SAFETY: a plain C call; a null config selects the defaults.
        let d = unsafe { rtcNewDevice(std::ptr::null()) };
        if d.is_null() {
            return Err(Error::runtime("embree: rtcNewDevice failed"));
        }
        Ok(Arc::new(Device(d)))
    }
}

// SAFETY: Embree devices are thread-safe (Embree API documentation).
unsafe impl Send for Device {}
// SAFETY: as above.
unsafe impl Sync for Device {}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: created in Device::new, released once here, after every scene on it (they
        // hold the Arc).
        unsafe { rtcReleaseDevice(self.0) };
    }
}

/// An Embree scene of one mesh, alpha-tested like [`super::ModelBvh`].
pub struct EmbreeScene {
    device: Arc<Device>,
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
    // SAFETY: every query of this module passes a `Context` (see EmbreeSceneBvh and
    // EmbreeScene's queries), which starts with the plain context.
    let ctx = unsafe { &*(a.context as *const Context) };
    for i in 0..a.n as usize {
        // SAFETY: valid has n entries.
        if unsafe { *a.valid.add(i) } == 0 {
            continue;
        }
        let n = a.n as usize;
        // SAFETY: instID[0] is field 7 of the SOA hit block (rtcore_ray.h, RTCHitN).
        let inst = unsafe { *(hit.add(7 * n + i) as *const u32) };
        if ctx.skips(inst) {
            // SAFETY: valid has n entries; 0 rejects the candidate.
            unsafe { *a.valid.add(i) = 0 };
            continue;
        }
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
        Self::build_on(&Device::new()?, mesh, masks)
    }

    /// [`EmbreeScene::build`] on a shared device (the models of an [`EmbreeSceneBvh`]).
    fn build_on(device: &Arc<Device>, mesh: &Mesh, masks: &[Option<AlphaMask>]) -> Result<Self> {
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
            let scene = rtcNewScene(device.0);
            let geom = rtcNewGeometry(device.0, GEOMETRY_TYPE_TRIANGLE);
            let nv = mesh.positions.len();
            let nt = mesh.indices.len();
            let vb = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_VERTEX, 0, FORMAT_FLOAT3, 12, nv)
                as *mut [f32; 3];
            let ib = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, nt)
                as *mut [u32; 3];
            if (vb.is_null() && nv > 0) || (ib.is_null() && nt > 0) {
                rtcReleaseGeometry(geom);
                rtcReleaseScene(scene);
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
                device: device.clone(),
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
        let mut r = RayOnly::of(ray);
        let mut ctx = Context::new(&[]);
        // SAFETY: the scene is committed and alive; ctx and r are valid, r 16-byte aligned.
        unsafe { rtcOccluded1(self.scene, &mut ctx.base, &mut r) };
        // Embree sets tfar to -inf when the ray is occluded.
        r.tfar == f32::NEG_INFINITY
    }

    /// Closest alpha-tested hit (`slot` is the triangle index; Embree has no slots).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let mut rh = RayHit::of(ray);
        let mut ctx = Context::new(&[]);
        // SAFETY: the scene is committed and alive; ctx and rh are valid, rh 16-byte aligned.
        unsafe { rtcIntersect1(self.scene, &mut ctx.base, &mut rh) };
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
        // SAFETY: created in build, released once here (the device after it, with the Arc).
        unsafe { rtcReleaseScene(self.scene) };
        let _ = &self.device;
    }
}

impl RayOnly {
    fn of(ray: &Ray) -> Self {
        RayOnly {
            org: ray.origin.to_array(),
            tnear: ray.tmin,
            dir: ray.dir.to_array(),
            time: 0.0,
            tfar: ray.tmax,
            mask: u32::MAX,
            id: 0,
            flags: 0,
        }
    }
}

impl RayHit {
    fn of(ray: &Ray) -> Self {
        RayHit {
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
        }
    }
}

/// What the terrain's user geometry reads.
struct TerrainData {
    heightfield: Arc<Heightfield>,
    /// The terrain's instance number (= its geometry ID in the top-level scene).
    instance: u32,
}

/// Bounds of the terrain's one primitive: the heightfield's box, padded like the CPU top level.
///
/// SAFETY (caller is Embree): `args` is valid for the call, its user pointer is the boxed
/// `TerrainData` of [`EmbreeSceneBvh::build`], `bounds` points to one `RTCBounds` (8 floats).
unsafe extern "C" fn terrain_bounds(args: *const BoundsArgs) {
    // SAFETY: see the function comment.
    let (a, d) = unsafe {
        let a = &*args;
        (a, &*(a.geometry_user_ptr as *const TerrainData))
    };
    let (lo, hi) = d.heightfield.bounds();
    let pad = (hi - lo).max_element() * 1e-5 + 1e-6;
    let (lo, hi) = (lo - pad, hi + pad);
    // SAFETY: bounds_o points to one RTCBounds.
    unsafe { *a.bounds = [lo.x, lo.y, lo.z, 0.0, hi.x, hi.y, hi.z, 0.0] };
}

/// Reads ray `i` of an N-wide SOA ray block (`RTCRayN`: org xyz, tnear, dir xyz, time, tfar).
///
/// SAFETY: `f` points to an SOA block of at least 9 fields of `n` lanes, `i < n`.
unsafe fn soa_ray(f: *const f32, n: usize, i: usize) -> Ray {
    // SAFETY: see the function comment.
    let at = |k: usize| unsafe { *f.add(k * n + i) };
    Ray {
        origin: Vec3A::new(at(0), at(1), at(2)),
        dir: Vec3A::new(at(4), at(5), at(6)),
        tmin: at(3),
        tmax: at(8),
    }
}

/// The terrain's closest hit: the heightfield's own intersector on the world ray (the terrain
/// is not instanced), so its hits are [`super::SceneBvh`]'s; none for the ignored instance.
///
/// SAFETY (caller is Embree, from rtcIntersect1 of [`EmbreeSceneBvh`]): `args` is valid for
/// the call, its user pointer is the boxed `TerrainData`, `context` is a [`Context`], `rayhit`
/// an SOA `RTCRayHitN` of `n` lanes (ray fields 0-11, hit fields 12-19).
unsafe extern "C" fn terrain_intersect(args: *const IntersectArgs) {
    // SAFETY: see the function comment.
    let (a, d, ctx) = unsafe {
        let a = &*args;
        (
            a,
            &*(a.geometry_user_ptr as *const TerrainData),
            &*(a.context as *const Context),
        )
    };
    if ctx.skips(d.instance) {
        return;
    }
    let n = a.n as usize;
    let f = a.rayhit as *mut f32;
    for i in 0..n {
        // SAFETY: valid has n entries; f is an n-lane SOA ray-hit block.
        let ray = unsafe {
            if *a.valid.add(i) == 0 {
                continue;
            }
            soa_ray(f, n, i)
        };
        if let Some(h) = d.heightfield.closest_hit(&ray)
            && h.t <= ray.tmax
        {
            // SAFETY: fields 8 (tfar) and 12-19 (Ng, u, v, primID, geomID, instID[0]) of lane
            // i lie inside the block.
            unsafe {
                *f.add(8 * n + i) = h.t;
                *f.add(12 * n + i) = 0.0;
                *f.add(13 * n + i) = 0.0;
                *f.add(14 * n + i) = 1.0;
                *f.add(15 * n + i) = h.u;
                *f.add(16 * n + i) = h.v;
                *(f.add(17 * n + i) as *mut u32) = h.triangle;
                *(f.add(18 * n + i) as *mut u32) = a.geom_id;
                *(f.add(19 * n + i) as *mut u32) = ctx.base.inst_id[0];
            }
        }
    }
}

/// The terrain's occlusion test (the heightfield's any-hit); Embree's convention marks an
/// occluded ray with tfar = −∞.
///
/// SAFETY: as [`terrain_intersect`], with an SOA `RTCRayN` (fields 0-11).
unsafe extern "C" fn terrain_occluded(args: *const IntersectArgs) {
    // SAFETY: see the function comment.
    let (a, d) = unsafe {
        let a = &*args;
        (a, &*(a.geometry_user_ptr as *const TerrainData))
    };
    let n = a.n as usize;
    let f = a.rayhit as *mut f32;
    for i in 0..n {
        // SAFETY: valid has n entries; f is an n-lane SOA ray block.
        let ray = unsafe {
            if *a.valid.add(i) == 0 {
                continue;
            }
            soa_ray(f, n, i)
        };
        if d.heightfield.any_hit(&ray) {
            // SAFETY: field 8 (tfar) of lane i lies inside the block.
            unsafe { *f.add(8 * n + i) = f32::NEG_INFINITY };
        }
    }
}

/// The two-level scene of a [`SceneBvh`] on Embree: one Embree scene per model (the same
/// alpha test as [`EmbreeScene`]), one Embree instance per placed model (geometry ID = the
/// instance number, the transform `translation + scale·Rz(rotation)`), and the heightfield
/// terrain as user geometry calling [`Heightfield::closest_hit`] / [`Heightfield::any_hit`].
/// Surfaces are computed from the CPU scene's model data ([`super::scene::surface_of`]), so a
/// hit on the same triangle at the same barycentrics gives the same surface on both backends.
pub struct EmbreeSceneBvh {
    top: RtcScene,
    /// Instanced by `top`; released after it.
    models: Vec<EmbreeScene>,
    cpu_models: Vec<Arc<ModelBvh>>,
    instances: Vec<InstanceTransform>,
    /// The CPU scene it was built from: [`SceneTracer::enclosing`] is decided there, so both
    /// backends skip the same instances.
    cpu: SceneBvh,
    /// The terrain's user data, alive as long as `top`.
    terrain: Option<Box<TerrainData>>,
    _device: Arc<Device>,
}

// SAFETY: as for EmbreeScene: after rtcCommitScene the scenes are immutable, queries are
// reentrant, and the callbacks' user data (the masks, the heightfield) is only read.
unsafe impl Send for EmbreeSceneBvh {}
// SAFETY: as above.
unsafe impl Sync for EmbreeSceneBvh {}

/// Column-major 3×4 `[scale·Rz | translation]` of an instance (what
/// [`InstanceTransform::point_to_world`] applies).
fn instance_matrix(inst: &InstanceTransform) -> [f32; 12] {
    let m = glam::Mat3A::from_rotation_z(inst.rotation_deg.to_radians()) * inst.scale;
    let (c0, c1, c2) = (m.x_axis, m.y_axis, m.z_axis);
    let t = inst.translation;
    [
        c0.x, c0.y, c0.z, c1.x, c1.y, c1.z, c2.x, c2.y, c2.z, t[0], t[1], t[2],
    ]
}

impl EmbreeSceneBvh {
    /// Builds the Embree twin of `scene` (same models, instances, terrain and instance
    /// numbering).
    pub fn build(scene: &SceneBvh) -> Result<Self> {
        let device = Device::new()?;
        let cpu_models = scene.models().to_vec();
        let models = cpu_models
            .iter()
            .map(|m| {
                let (mesh, masks) = m.source();
                EmbreeScene::build_on(&device, &mesh, &masks)
            })
            .collect::<Result<Vec<_>>>()?;
        let instances = scene.instances().to_vec();
        let terrain = scene.terrain().map(|h| {
            Box::new(TerrainData {
                heightfield: h.clone(),
                instance: instances.len() as u32,
            })
        });
        // SAFETY: plain C API calls in the documented order; every instanced scene is committed
        // and kept alive in `models`, the transform is 12 floats read during the call, and the
        // terrain's user pointer (boxed) outlives `top`.
        let top = unsafe {
            let top = rtcNewScene(device.0);
            for (k, inst) in instances.iter().enumerate() {
                let g = rtcNewGeometry(device.0, GEOMETRY_TYPE_INSTANCE);
                rtcSetGeometryInstancedScene(g, models[inst.model as usize].scene);
                let xfm = instance_matrix(inst);
                rtcSetGeometryTransform(
                    g,
                    0,
                    FORMAT_FLOAT3X4_COLUMN_MAJOR,
                    xfm.as_ptr() as *const c_void,
                );
                rtcCommitGeometry(g);
                rtcAttachGeometryByID(top, g, k as u32);
                rtcReleaseGeometry(g);
            }
            if let Some(t) = &terrain {
                let g = rtcNewGeometry(device.0, GEOMETRY_TYPE_USER);
                let user = &**t as *const TerrainData as *mut c_void;
                rtcSetGeometryUserPrimitiveCount(g, 1);
                rtcSetGeometryUserData(g, user);
                rtcSetGeometryBoundsFunction(g, Some(terrain_bounds), user);
                rtcSetGeometryIntersectFunction(g, Some(terrain_intersect));
                rtcSetGeometryOccludedFunction(g, Some(terrain_occluded));
                rtcCommitGeometry(g);
                rtcAttachGeometryByID(top, g, t.instance);
                rtcReleaseGeometry(g);
            }
            rtcCommitScene(top);
            top
        };
        Ok(EmbreeSceneBvh {
            top,
            models,
            cpu_models,
            instances,
            cpu: scene.clone(),
            terrain,
            _device: device,
        })
    }

    /// The instance number of the terrain, if the scene has one.
    pub fn terrain_instance(&self) -> Option<u32> {
        self.terrain.as_ref().map(|t| t.instance)
    }
}

impl SceneTracer for EmbreeSceneBvh {
    fn instances(&self) -> &[InstanceTransform] {
        &self.instances
    }

    fn closest_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> Option<SceneHit> {
        let mut rh = RayHit::of(ray);
        let mut ctx = Context::new(skip);
        // SAFETY: the scene is committed and alive; ctx and rh are valid, rh 16-byte aligned;
        // the callbacks read ctx as the Context it is.
        unsafe { rtcIntersect1(self.top, &mut ctx.base, &mut rh) };
        if rh.geom_id == INVALID_ID {
            return None;
        }
        let instance = if rh.inst_id[0] != INVALID_ID {
            rh.inst_id[0]
        } else {
            rh.geom_id
        };
        let slot = match self.instances.get(instance as usize) {
            Some(i) => self.cpu_models[i.model as usize].slot_of(rh.prim_id),
            None => rh.prim_id,
        };
        Some(SceneHit {
            instance,
            hit: Hit {
                t: rh.tfar,
                triangle: rh.prim_id,
                slot,
                u: rh.u,
                v: rh.v,
            },
        })
    }

    fn any_hit(&self, ray: &Ray) -> bool {
        let mut r = RayOnly::of(ray);
        let mut ctx = Context::new(&[]);
        // SAFETY: as in closest_hit_excluding.
        unsafe { rtcOccluded1(self.top, &mut ctx.base, &mut r) };
        r.tfar == f32::NEG_INFINITY
    }

    fn enclosing(&self, p: Vec3A, own: u32) -> Vec<u32> {
        self.cpu.enclosing(p, own)
    }

    fn instance_encloses(&self, k: u32, p: Vec3A) -> bool {
        self.cpu.instance_encloses(k, p)
    }

    fn instance_bounds(&self, k: u32) -> (Vec3A, Vec3A) {
        self.cpu.instance_bounds(k)
    }

    fn surface(&self, hit: &SceneHit) -> SurfacePoint {
        surface_of(
            &self.cpu_models,
            &self.instances,
            self.terrain.as_ref().map(|t| &*t.heightfield),
            hit,
        )
    }
}

impl Drop for EmbreeSceneBvh {
    fn drop(&mut self) {
        // SAFETY: created in build, released once here, before the instanced model scenes,
        // the terrain's user data and the device (dropped with the fields afterwards).
        unsafe { rtcReleaseScene(self.top) };
        let _ = (&self.models, &self.terrain);
    }
}
