//! Per-model BVH on obvhs (compressed wide BVH8) with alpha-tested triangles.
//!
//! A hit on a texel whose alpha is below 0.5 is no hit: plant leaves are mostly transparent
//! quads (seed 000, 4.5.4). The colour-map alpha is sampled at the interpolated texture
//! coordinate, nearest texel, repeating (the GPU alpha test at 0.5 on the finest mip).
//!
//! Triangles are stored in BVH leaf order ("slots") with precomputed edges for Möller–Trumbore,
//! so a leaf's triangles are contiguous in memory. [`ModelBvh::brute_force_closest_hit`] is the
//! reference implementation (an exhaustive loop over the mesh's triangles with the same triangle
//! and alpha test) the tests compare against.
//!
//! Alpha-aware build: every texel a masked triangle can read (its texture-coordinate box,
//! padded) is classified with a summed-area table. A triangle whose texels are all transparent
//! leaves the BVH; one whose texels are all opaque skips the alpha test. With a split depth
//! d > 0 a mixed triangle becomes up to 4^d boxes of its barycentric midpoint subdivision, with
//! the all-transparent parts dropped (rays through the transparent corners of a leaf quad then
//! miss its boxes). Every box still refers to the whole triangle, so hit and alpha tests, and
//! thus results, are exactly the brute force's; a traversal skips a triangle it has just tested
//! through a neighbouring box. The default depth is 0: on the procedural plant the finer boxes
//! made PRT slower (docs/PERFORMANCE.md).

use super::{Hit, Ray};
use crate::error::{Error, Result};
use crate::model::{Mesh, Rgba8Image};
use glam::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use rayon::prelude::*;

/// obvhs build presets, fastest build first. The default was chosen by `bake bench rays`
/// (docs/PERFORMANCE.md, "Ray tracing and PRT").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BuildPreset {
    Fastest,
    #[default]
    VeryFast,
    Fast,
    Medium,
    Slow,
    VerySlow,
}

impl BuildPreset {
    pub const ALL: [BuildPreset; 6] = [
        BuildPreset::Fastest,
        BuildPreset::VeryFast,
        BuildPreset::Fast,
        BuildPreset::Medium,
        BuildPreset::Slow,
        BuildPreset::VerySlow,
    ];

    pub const fn params(self) -> BvhBuildParams {
        match self {
            BuildPreset::Fastest => BvhBuildParams::fastest_build(),
            BuildPreset::VeryFast => BvhBuildParams::very_fast_build(),
            BuildPreset::Fast => BvhBuildParams::fast_build(),
            BuildPreset::Medium => BvhBuildParams::medium_build(),
            BuildPreset::Slow => BvhBuildParams::slow_build(),
            BuildPreset::VerySlow => BvhBuildParams::very_slow_build(),
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            BuildPreset::Fastest => "fastest",
            BuildPreset::VeryFast => "very-fast",
            BuildPreset::Fast => "fast",
            BuildPreset::Medium => "medium",
            BuildPreset::Slow => "slow",
            BuildPreset::VerySlow => "very-slow",
        }
    }
}

/// One bit per texel: is the texel's alpha at least 0.5 (a ≥ 128 of 255)?
#[derive(Debug, Clone, PartialEq)]
pub struct AlphaMask {
    width: u32,
    height: u32,
    bits: Vec<u64>,
    /// Every texel is opaque: the mask never rejects a hit and is dropped at build time.
    all_opaque: bool,
}

impl AlphaMask {
    /// The alpha-test mask of an RGBA8 image (row 0 at the top, as [`Rgba8Image`] stores it).
    pub fn from_rgba8(img: &Rgba8Image) -> Self {
        let n = img.pixels.len();
        let mut bits = vec![0u64; n.div_ceil(64)];
        for (i, p) in img.pixels.iter().enumerate() {
            if p[3] >= 128 {
                bits[i / 64] |= 1 << (i % 64);
            }
        }
        let all_opaque = img.pixels.iter().all(|p| p[3] >= 128);
        AlphaMask {
            width: img.width.max(1),
            height: img.height.max(1),
            bits,
            all_opaque: all_opaque || n == 0,
        }
    }

    /// Whether the texel under `(u, v)` is opaque: nearest texel, repeating, v = 0 at the top.
    #[inline]
    pub fn opaque_at(&self, u: f32, v: f32) -> bool {
        // `as i64` saturates and maps NaN to 0, so bad coordinates cannot index out of range.
        let x = ((u * self.width as f32).floor() as i64).rem_euclid(self.width as i64) as usize;
        let y = ((v * self.height as f32).floor() as i64).rem_euclid(self.height as i64) as usize;
        let i = y * self.width as usize + x;
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    pub fn is_all_opaque(&self) -> bool {
        self.all_opaque
    }
}

/// A triangle prepared for Möller–Trumbore: `v0`, `e1 = v1 − v0`, `e2 = v2 − v0`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PreTri {
    pub(crate) v0: Vec3A,
    pub(crate) e1: Vec3A,
    pub(crate) e2: Vec3A,
}

/// What a slot (a triangle in leaf order) refers to.
#[derive(Debug, Clone, Copy)]
struct SlotInfo {
    triangle: u32,
    /// Index into `masks`, or `NO_MASK` for opaque triangles.
    mask: u32,
    material: u32,
}

/// Texture coordinates of a slot's triangle: `uv0`, `uv1 − uv0`, `uv2 − uv0`. Kept in slot
/// order beside the triangles so the alpha test of a candidate hit reads memory the traversal
/// has just touched instead of three random vertex loads.
type SlotUv = [[f32; 2]; 3];

const NO_MASK: u32 = u32::MAX;
const NO_SLOT: u32 = u32::MAX;

/// Subdivision depth of the alpha-aware build (up to 4^depth boxes per masked triangle); chosen
/// by `bake bench rays` (docs/PERFORMANCE.md).
pub const ALPHA_SPLIT_DEPTH: u32 = 0;

/// A point on the surface at a hit, with attributes interpolated from the vertices.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    pub position: Vec3A,
    /// Unit normal of the triangle's plane, (p1 − p0) × (p2 − p0) normalized.
    pub geometric_normal: Vec3A,
    /// Interpolated vertex normal, normalized (the geometric normal where it degenerates).
    pub shading_normal: Vec3A,
    pub uv: [f32; 2],
    pub material: u32,
    pub triangle: u32,
}

/// A model's BVH with the geometry it was built from.
#[derive(Debug, Clone)]
pub struct ModelBvh {
    bvh: Option<CwBvh>,
    slots: Vec<PreTri>,
    slot_info: Vec<SlotInfo>,
    slot_uv: Vec<SlotUv>,
    masks: Vec<AlphaMask>,
    positions: Vec<Vec3A>,
    normals: Vec<Vec3A>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<[u32; 3]>,
    triangle_materials: Vec<u32>,
    bounds: (Vec3A, Vec3A),
    skipped: usize,
    /// Mask index per material (`NO_MASK`: opaque), for the brute force.
    material_mask: Vec<u32>,
    /// The first slot of each triangle (`NO_SLOT`: not in the BVH).
    first_slot: Vec<u32>,
}

impl ModelBvh {
    /// Builds the BVH of `mesh`. `masks[m]` is the alpha mask of material `m` (`None` or a
    /// missing entry: opaque). Triangles with non-finite positions are left out and counted in
    /// [`ModelBvh::skipped_triangles`].
    pub fn build(mesh: &Mesh, masks: &[Option<AlphaMask>], preset: BuildPreset) -> Result<Self> {
        Self::build_split(mesh, masks, preset, ALPHA_SPLIT_DEPTH)
    }

    /// [`ModelBvh::build`] with the subdivision depth of the alpha-aware build (0: one box per
    /// triangle, fully transparent triangles still dropped).
    pub fn build_split(
        mesh: &Mesh,
        masks: &[Option<AlphaMask>],
        preset: BuildPreset,
        split_depth: u32,
    ) -> Result<Self> {
        mesh.validate()
            .map_err(|m| Error::runtime(format!("cannot build a BVH: {m}")))?;
        let finite = |i: u32| mesh.positions[i as usize].iter().all(|c| c.is_finite());
        let kept: Vec<u32> = (0..mesh.indices.len() as u32)
            .filter(|&t| mesh.indices[t as usize].iter().all(|&i| finite(i)))
            .collect();
        let tris: Vec<obvhs::triangle::Triangle> = kept
            .iter()
            .map(|&t| {
                let [a, b, c] = mesh.indices[t as usize];
                obvhs::triangle::Triangle {
                    v0: mesh.positions[a as usize].into(),
                    v1: mesh.positions[b as usize].into(),
                    v2: mesh.positions[c as usize].into(),
                }
            })
            .collect();
        let mut model = Self::from_mesh(mesh, masks, mesh.indices.len() - kept.len());
        let masked = masks.iter().flatten().any(|m| !m.is_all_opaque());
        // Per kept triangle: all its texels are opaque (no alpha test needed).
        let mut skip_alpha = Vec::new();
        let (bvh, order) = if tris.is_empty() {
            (None, Vec::new())
        } else if masked {
            let (boxes, owner, opaque) = alpha_boxes(&tris, &kept, mesh, masks, split_depth.min(8));
            skip_alpha = opaque;
            let bvh = (!boxes.is_empty()).then(|| {
                obvhs::cwbvh::builder::build_cwbvh(
                    &boxes,
                    preset.params(),
                    &mut std::time::Duration::default(),
                )
            });
            let order = bvh.as_ref().map_or(Vec::new(), |b| {
                b.primitive_indices
                    .iter()
                    .map(|&p| owner[p as usize])
                    .collect()
            });
            (bvh, order)
        } else {
            let b = obvhs::cwbvh::builder::build_cwbvh_from_tris(
                &tris,
                preset.params(),
                &mut std::time::Duration::default(),
            );
            let order = b.primitive_indices.clone();
            (Some(b), order)
        };
        model.fill_slots(&order, &kept, masks, &skip_alpha);
        model.bvh = bvh;
        Ok(model)
    }

    fn from_mesh(mesh: &Mesh, masks: &[Option<AlphaMask>], skipped: usize) -> Self {
        let positions: Vec<Vec3A> = mesh.positions.iter().map(|&p| p.into()).collect();
        let (lo, hi) = mesh.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
        ModelBvh {
            bvh: None,
            slots: Vec::new(),
            slot_info: Vec::new(),
            slot_uv: Vec::new(),
            masks: masks.iter().flatten().cloned().collect(),
            positions,
            normals: mesh.normals.iter().map(|&n| n.into()).collect(),
            uvs: mesh.uvs.clone(),
            indices: mesh.indices.clone(),
            triangle_materials: mesh.triangle_materials.clone(),
            bounds: (lo.into(), hi.into()),
            skipped,
            material_mask: Vec::new(),
            first_slot: vec![NO_SLOT; mesh.indices.len()],
        }
    }

    /// Lays the triangles out in leaf order (`order[slot]` indexes `kept`).
    /// `skip_alpha[k]` (if present): kept triangle k reads only opaque texels.
    fn fill_slots(
        &mut self,
        order: &[u32],
        kept: &[u32],
        masks: &[Option<AlphaMask>],
        skip_alpha: &[bool],
    ) {
        // Material → index into `self.masks` (which holds only the present masks).
        let mut mask_of = Vec::with_capacity(masks.len());
        let mut next = 0u32;
        for m in masks {
            mask_of.push(match m {
                Some(m) if !m.is_all_opaque() => next,
                _ => NO_MASK,
            });
            next += m.is_some() as u32;
        }
        for (slot, &k) in order.iter().enumerate() {
            let t = kept[k as usize];
            let first = &mut self.first_slot[t as usize];
            *first = (*first).min(slot as u32);
            let [a, b, c] = self.indices[t as usize];
            let p = |i: u32| self.positions[i as usize];
            self.slots.push(PreTri {
                v0: p(a),
                e1: p(b) - p(a),
                e2: p(c) - p(a),
            });
            let mat = self.triangle_materials[t as usize];
            let opaque = skip_alpha.get(k as usize).copied().unwrap_or(false);
            self.slot_info.push(SlotInfo {
                triangle: t,
                mask: match opaque {
                    true => NO_MASK,
                    false => mask_of.get(mat as usize).copied().unwrap_or(NO_MASK),
                },
                material: mat,
            });
            let uv = |i: u32| self.uvs[i as usize];
            let (ua, ub, uc) = (uv(a), uv(b), uv(c));
            self.slot_uv.push([
                ua,
                [ub[0] - ua[0], ub[1] - ua[1]],
                [uc[0] - ua[0], uc[1] - ua[1]],
            ]);
        }
        self.material_mask = mask_of;
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// BVH primitives (boxes): one per triangle, more with the alpha-aware build.
    pub fn primitive_count(&self) -> usize {
        self.slots.len()
    }

    /// Whether triangle `t` is in the BVH (not skipped, not fully transparent).
    pub fn contains_triangle(&self, t: u32) -> bool {
        self.first_slot
            .get(t as usize)
            .is_some_and(|&s| s != NO_SLOT)
    }

    /// Triangles left out of the BVH (non-finite positions).
    pub fn skipped_triangles(&self) -> usize {
        self.skipped
    }

    /// Axis-aligned bounds of the model's positions.
    pub fn bounds(&self) -> (Vec3A, Vec3A) {
        self.bounds
    }

    /// Whether a hit on slot `slot` at barycentrics (u, v) is on an opaque texel.
    #[inline]
    fn opaque(&self, slot: usize, info: SlotInfo, u: f32, v: f32) -> bool {
        if info.mask == NO_MASK {
            return true;
        }
        let [t0, d1, d2] = self.slot_uv[slot];
        let s = t0[0] + u * d1[0] + v * d2[0];
        let t = t0[1] + u * d1[1] + v * d2[1];
        self.masks[info.mask as usize].opaque_at(s, t)
    }

    /// Tests slot `slot` against the ray; a hit on a transparent texel is no hit.
    #[inline]
    fn hit_slot(&self, slot: usize, ray: &Ray, tmax: f32) -> Option<Hit> {
        let (t, u, v) = intersect(&self.slots[slot], ray.origin, ray.dir, ray.tmin, tmax)?;
        let info = self.slot_info[slot];
        self.opaque(slot, info, u, v).then_some(Hit {
            t,
            triangle: info.triangle,
            slot: slot as u32,
            u,
            v,
        })
    }

    /// The closest opaque hit along the ray.
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let mut best = None;
        let mut hit = obvhs::ray::RayHit::none();
        let mut last = NO_SLOT;
        bvh.ray_traverse(ray.to_obvhs(), &mut hit, |r, slot| {
            // The same triangle through a neighbouring box of the alpha-aware build: its result
            // (a hit that already shortened the ray, or none) cannot change.
            let tri = self.slot_info[slot].triangle;
            if std::mem::replace(&mut last, tri) == tri {
                return f32::INFINITY;
            }
            match self.hit_slot(slot, ray, r.tmax) {
                Some(h) if h.t < r.tmax => {
                    best = Some(h);
                    h.t
                }
                _ => f32::INFINITY,
            }
        });
        best
    }

    /// Whether any opaque hit lies on the ray segment (stops at the first one).
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let mut last = NO_SLOT;
        !bvh.ray_traverse_miss(ray.to_obvhs(), |r, slot| {
            let tri = self.slot_info[slot].triangle;
            if std::mem::replace(&mut last, tri) == tri {
                return f32::INFINITY;
            }
            self.hit_slot(slot, ray, r.tmax)
                .map_or(f32::INFINITY, |h| h.t)
        })
    }

    /// [`ModelBvh::any_hit`] of every ray at once, by one walk of the BVH per [`PACKET`] rays:
    /// `blocked[i] == self.any_hit(&rays[i])`, bit for bit (for every input, the alpha test,
    /// `tmin`, `tmax` and obvhs' node `EPSILON` included). Meant for rays that visit the same
    /// nodes (the sun-disc rays of one texel, [`super::beam::SunBeam`]); any rays are answered
    /// right.
    ///
    /// The walk carries, per node, the mask of the open rays that reached it. At a node every
    /// such ray makes its own child test, `CwBvhNode::intersect_ray` on the very obvhs ray
    /// `any_hit` traverses with (`Ray::to_obvhs`); a child is entered with the rays whose test
    /// reached it and a leaf's primitive is tested for those rays alone, with the test
    /// `any_hit`'s callback makes (the slot's triangle and alpha test up to the ray's `tmax`, a
    /// hit when its `t < tmax`). So each ray tests exactly the primitives its own traversal
    /// reaches, and `any_hit` is "some reached primitive is hit" (its traversal never shortens
    /// the ray, it only stops at the first hit). A ray retires at its first hit and is carried
    /// no further; the walk ends when every ray is retired or no node is left.
    ///
    /// One octant code (`oct_inv4`) serves all rays, even of different direction octants: in
    /// obvhs' CWBVH8 it only permutes the inner children's bit positions in a node's hit mask
    /// (the byte `24 + (slot ^ oct)`) and the decoding undoes that permutation with the same
    /// code; whether a child box is hit depends on the ray's own direction (its slab signs) and
    /// not on the code; leaf children's primitive bits do not involve it. The code only orders
    /// the walk (nearest child first for the rays of that octant), which an any-hit answer does
    /// not depend on. Both walks assume obvhs' bound on the BVH's depth (below its traversal
    /// stack of 32, which `CwBvh::validate` asserts); the packet's own stack has no bound.
    ///
    /// `any_hit` skips a primitive whose triangle is the one it tested last (a triangle in
    /// several boxes of the alpha-aware build); that is an optimisation only (the retest would
    /// give the same miss: a hit would have ended the walk), and the walk here skips the same
    /// way per ray, for the rays that tested that triangle just before.
    ///
    /// Panics if the two slices' lengths differ.
    pub fn any_hits_packet(&self, rays: &[Ray], blocked: &mut [bool]) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        for (rays, blocked) in rays.chunks(PACKET).zip(blocked.chunks_mut(PACKET)) {
            self.packet_walk(rays, blocked);
        }
    }

    /// One walk of [`ModelBvh::any_hits_packet`] for at most [`PACKET`] rays.
    fn packet_walk(&self, rays: &[Ray], blocked: &mut [bool]) {
        blocked.fill(false);
        let Some(bvh) = self.bvh.as_ref() else {
            return;
        };
        let n = rays.len();
        if n == 0 || bvh.nodes.is_empty() {
            return;
        }
        debug_assert!(n <= PACKET);
        let mut obvhs_rays = [rays[0].to_obvhs(); PACKET];
        for (o, r) in obvhs_rays.iter_mut().zip(rays) {
            *o = r.to_obvhs();
        }
        let oct = octant_inv4(rays[0].dir);
        let mut open: u32 = if n == PACKET {
            u32::MAX
        } else {
            (1u32 << n) - 1
        };
        // (node, the rays that reached it); the root is reached by every ray.
        let mut stack = PacketStack::default();
        stack.push((0, open));
        // The triangle tested last and the rays that tested it (all missed it).
        let (mut last, mut last_rays) = (NO_SLOT, 0u32);
        while let Some((index, reached)) = stack.pop() {
            let reached = reached & open;
            if reached == 0 {
                continue;
            }
            let node = &bvh.nodes[index as usize];
            let boxes = NodeBoxes::new(node, oct);
            // Per inner child bit (hit-mask bits 24..32) and per primitive bit (0..24): the
            // rays whose own test reached it.
            let mut child_rays = [0u32; 8];
            let mut prim_rays = [0u32; 24];
            let (mut children, mut prims) = (0u32, 0u32);
            for i in Bits(reached) {
                let h = boxes.hits(node, &obvhs_rays[i as usize], oct);
                for j in Bits(h >> 24) {
                    child_rays[j as usize] |= 1 << i;
                }
                for j in Bits(h & 0x00ff_ffff) {
                    prim_rays[j as usize] |= 1 << i;
                }
                children |= h >> 24;
                prims |= h & 0x00ff_ffff;
            }
            // The node's primitives first, as obvhs' walk tests them before the children.
            for j in Bits(prims) {
                let slot = (node.primitive_base_idx + j) as usize;
                let tri = self.slot_info[slot].triangle;
                let mut test = prim_rays[j as usize] & open;
                if tri == last {
                    test &= !last_rays;
                    last_rays |= test;
                } else {
                    (last, last_rays) = (tri, test);
                }
                for i in Bits(test) {
                    let r = &rays[i as usize];
                    let t = self
                        .hit_slot(slot, r, r.tmax)
                        .map_or(f32::INFINITY, |h| h.t);
                    if t < r.tmax {
                        blocked[i as usize] = true;
                        open &= !(1 << i);
                    }
                }
                if open == 0 {
                    return;
                }
            }
            // The children, the highest hit-mask bit on top (obvhs' order for this octant).
            for j in Bits(children) {
                let slot_index = j ^ (oct & 0xff);
                let relative = (node.imask as u32 & !(u32::MAX << slot_index)).count_ones();
                stack.push((node.child_base_idx + relative, child_rays[j as usize]));
            }
        }
    }

    /// Reference closest hit: every triangle of the mesh, in order, with the same triangle and
    /// alpha test, independent of the BVH and of which triangles its build kept.
    pub fn brute_force_closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for (t, &[a, b, c]) in self.indices.iter().enumerate() {
            let p = |i: u32| self.positions[i as usize];
            if !(p(a).is_finite() && p(b).is_finite() && p(c).is_finite()) {
                continue;
            }
            let tri = PreTri {
                v0: p(a),
                e1: p(b) - p(a),
                e2: p(c) - p(a),
            };
            let tmax = best.map_or(ray.tmax, |h| h.t);
            let Some((th, u, v)) = intersect(&tri, ray.origin, ray.dir, ray.tmin, tmax) else {
                continue;
            };
            let mat = self.triangle_materials[t] as usize;
            let mask = self.material_mask.get(mat).copied().unwrap_or(NO_MASK);
            if mask != NO_MASK {
                let uv = |i: u32| self.uvs[i as usize];
                let (ua, ub, uc) = (uv(a), uv(b), uv(c));
                let s = ua[0] + u * (ub[0] - ua[0]) + v * (uc[0] - ua[0]);
                let tt = ua[1] + u * (ub[1] - ua[1]) + v * (uc[1] - ua[1]);
                if !self.masks[mask as usize].opaque_at(s, tt) {
                    continue;
                }
            }
            if best.is_none_or(|h| th < h.t) {
                best = Some(Hit {
                    t: th,
                    triangle: t as u32,
                    slot: self.first_slot[t],
                    u,
                    v,
                });
            }
        }
        best
    }

    /// Closest hits of many rays over rayon, in input order.
    pub fn closest_hits(&self, rays: &[Ray]) -> Vec<Option<Hit>> {
        rays.par_iter().map(|r| self.closest_hit(r)).collect()
    }

    /// Any-hit results of many rays over rayon, in input order.
    pub fn any_hits(&self, rays: &[Ray]) -> Vec<bool> {
        rays.par_iter().map(|r| self.any_hit(r)).collect()
    }

    /// The mesh this BVH was built from (positions, texture coordinates, triangles and their
    /// materials; no normals) and the alpha mask of every material, for another backend
    /// (`trace::embree`) to build the same alpha-tested model.
    pub fn source(&self) -> (Mesh, Vec<Option<AlphaMask>>) {
        let mesh = Mesh {
            positions: self.positions.iter().map(|p| p.to_array()).collect(),
            uvs: self.uvs.clone(),
            indices: self.indices.clone(),
            triangle_materials: self.triangle_materials.clone(),
            ..Mesh::default()
        };
        let masks = self
            .material_mask
            .iter()
            .map(|&m| (m != NO_MASK).then(|| self.masks[m as usize].clone()))
            .collect();
        (mesh, masks)
    }

    /// Whether material `m` is alpha-tested (its mask has transparent texels).
    pub fn alpha_tested(&self, m: u32) -> bool {
        self.material_mask
            .get(m as usize)
            .is_some_and(|&k| k != NO_MASK)
    }

    /// The first BVH slot of triangle `t` (`u32::MAX`: not in the BVH).
    pub fn slot_of(&self, t: u32) -> u32 {
        self.first_slot.get(t as usize).copied().unwrap_or(NO_SLOT)
    }

    /// Position, unit geometric normal and material at a hit, from the slot data only (the
    /// fast path for path tracing; [`ModelBvh::surface`] interpolates every attribute).
    #[inline]
    pub fn hit_point(&self, hit: &Hit) -> (Vec3A, Vec3A, u32) {
        let p = &self.slots[hit.slot as usize];
        let position = p.v0 + p.e1 * hit.u + p.e2 * hit.v;
        let ng = p.e1.cross(p.e2).normalize_or_zero();
        (position, ng, self.slot_info[hit.slot as usize].material)
    }

    /// Position, normals, texture coordinate and material at a hit.
    pub fn surface(&self, hit: &Hit) -> SurfacePoint {
        let [a, b, c] = self.indices[hit.triangle as usize];
        let (a, b, c) = (a as usize, b as usize, c as usize);
        let w = 1.0 - hit.u - hit.v;
        let (p0, p1, p2) = (self.positions[a], self.positions[b], self.positions[c]);
        let ng = (p1 - p0).cross(p2 - p0).normalize_or_zero();
        let ns = (self.normals[a] * w + self.normals[b] * hit.u + self.normals[c] * hit.v)
            .try_normalize()
            .unwrap_or(ng);
        let (ta, tb, tc) = (self.uvs[a], self.uvs[b], self.uvs[c]);
        SurfacePoint {
            position: p0 * w + p1 * hit.u + p2 * hit.v,
            geometric_normal: ng,
            shading_normal: ns,
            uv: [
                w * ta[0] + hit.u * tb[0] + hit.v * tc[0],
                w * ta[1] + hit.u * tb[1] + hit.v * tc[1],
            ],
            material: self.triangle_materials[hit.triangle as usize],
            triangle: hit.triangle,
        }
    }

    /// The BVH as flat u32 words for a GPU tracer ([`GpuBvhData`]), or `None` for an empty
    /// model (nothing to hit).
    pub fn gpu_data(&self) -> Option<GpuBvhData> {
        let bvh = self.bvh.as_ref()?;
        let mut nodes = Vec::with_capacity(bvh.nodes.len() * GPU_NODE_WORDS);
        for n in &bvh.nodes {
            nodes.extend([n.p.x.to_bits(), n.p.y.to_bits(), n.p.z.to_bits()]);
            nodes.push(u32::from_le_bytes([n.e[0], n.e[1], n.e[2], n.imask]));
            nodes.extend([n.child_base_idx, n.primitive_base_idx]);
            for bytes in [
                &n.child_meta,
                &n.child_min_x,
                &n.child_max_x,
                &n.child_min_y,
                &n.child_max_y,
                &n.child_min_z,
                &n.child_max_z,
            ] {
                let w = u64::from_le_bytes(*bytes);
                nodes.extend([w as u32, (w >> 32) as u32]);
            }
        }
        let mut slots = Vec::with_capacity(self.slots.len() * GPU_SLOT_WORDS);
        for ((t, info), uv) in self.slots.iter().zip(&self.slot_info).zip(&self.slot_uv) {
            for v in [t.v0, t.e1, t.e2] {
                slots.extend(v.to_array().map(f32::to_bits));
            }
            slots.extend(uv.as_flattened().iter().map(|c| c.to_bits()));
            slots.extend([info.triangle, info.mask, info.material, 0, 0]);
        }
        // Each mask's bits as u32 words (bit i of the mask is bit i % 32 of word i / 32, as in
        // the u64 words on a little-endian machine), concatenated.
        let mut masks = Vec::with_capacity(self.masks.len() * 4);
        let mut bits = Vec::new();
        for m in &self.masks {
            masks.extend([m.width, m.height, bits.len() as u32, 0]);
            for &w in &m.bits {
                bits.extend([w as u32, (w >> 32) as u32]);
            }
        }
        // Levels of internal nodes below the root: a node's internal children (one per set bit
        // of `imask`) are stored contiguously from `child_base_idx`.
        let mut depth = 0u32;
        let mut todo = vec![(0usize, 1u32)];
        while let Some((i, level)) = todo.pop() {
            depth = depth.max(level);
            let n = &bvh.nodes[i];
            for c in 0..n.imask.count_ones() as usize {
                todo.push((n.child_base_idx as usize + c, level + 1));
            }
        }
        Some(GpuBvhData {
            nodes,
            slots,
            masks,
            mask_bits: bits,
            depth,
        })
    }

    /// Raw obvhs traversal with obvhs' own triangle test and no alpha: the baseline the
    /// `bench rays` efficiency is measured against. Returns the hit distance.
    pub fn raw_closest_t(&self, tris: &[obvhs::triangle::Triangle], ray: &Ray) -> f32 {
        let Some(bvh) = self.bvh.as_ref() else {
            return f32::INFINITY;
        };
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray.to_obvhs(), &mut hit, |r, slot| tris[slot].intersect(r));
        hit.t
    }

    /// The triangles in slot order as obvhs triangles (for [`ModelBvh::raw_closest_t`]).
    pub fn raw_triangles(&self) -> Vec<obvhs::triangle::Triangle> {
        self.slots
            .iter()
            .map(|p| obvhs::triangle::Triangle {
                v0: p.v0.to_array().into(),
                v1: (p.v0 + p.e1).to_array().into(),
                v2: (p.v0 + p.e2).to_array().into(),
            })
            .collect()
    }
}

/// The most rays one walk of [`ModelBvh::any_hits_packet`] carries (a bit each in a `u32`).
pub const PACKET: usize = 32;

/// obvhs' octant code of a direction (`ray_get_octant_inv4`, private there): per byte, 4 if
/// x ≥ 0, plus 2 if y ≥ 0, plus 1 if z ≥ 0 (NaN counts as ≥ 0).
#[inline]
fn octant_inv4(d: Vec3A) -> u32 {
    (if d.x < 0.0 { 0 } else { 0x0404_0404 })
        | (if d.y < 0.0 { 0 } else { 0x0202_0202 })
        | (if d.z < 0.0 { 0 } else { 0x0101_0101 })
}

/// A CWBVH8 node's child boxes decoded once for all rays of a packet: the hit mask
/// `CwBvhNode::intersect_ray(ray, oct_inv4)` returns, for one ray after another, without
/// decoding the node's quantized planes (`u8` → `f32`, obvhs' costliest step) per ray.
///
/// On x86-64 (SSE2) [`NodeBoxes::hits`] is obvhs' `intersect_ray_simd` with the decoding hoisted
/// out: the same `f32` planes (a `u8` converts exactly), the same per-ray operations in the same
/// order and the same intrinsics (`mul`, then `add`, no FMA; `max`/`min` with the same operand
/// order, so NaN picks the same lane; `EPSILON` and `tmax` clamps; `cmple`), then each hit
/// child's `child_bits << bit_index` OR-ed in: the same `u32`, bit for bit, which
/// `node_boxes_equal_obvhs_node_test` checks against obvhs itself. Elsewhere it calls obvhs.
struct NodeBoxes {
    /// Per axis, the children's low and high planes in node units, children 0–3 and 4–7.
    #[cfg(target_arch = "x86_64")]
    lo: [[std::arch::x86_64::__m128; 2]; 3],
    #[cfg(target_arch = "x86_64")]
    hi: [[std::arch::x86_64::__m128; 2]; 3],
    /// Per child, the bits a hit sets in the mask (0 for an empty slot).
    #[cfg(target_arch = "x86_64")]
    bits: [u32; 8],
}

impl NodeBoxes {
    /// obvhs' EPSILON (`cwbvh::node`, private there): the node test's lowest `t`.
    #[cfg(target_arch = "x86_64")]
    const EPSILON: f32 = 0.0001;

    #[inline]
    #[cfg_attr(not(target_arch = "x86_64"), allow(unused_variables))]
    fn new(node: &obvhs::cwbvh::node::CwBvhNode, oct_inv4: u32) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::_mm_set_ps;
            // SAFETY: SSE2 is part of every x86-64 target.
            let q = |v: &[u8; 8], i: usize| unsafe {
                _mm_set_ps(
                    v[i * 4 + 3] as f32,
                    v[i * 4 + 2] as f32,
                    v[i * 4 + 1] as f32,
                    v[i * 4] as f32,
                )
            };
            let two = |v: &[u8; 8]| [q(v, 0), q(v, 1)];
            let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
            let byte = |x: u64, b: usize| ((x >> (b * 8)) as u32) & 0xff;
            NodeBoxes {
                lo: [
                    two(&node.child_min_x),
                    two(&node.child_min_y),
                    two(&node.child_min_z),
                ],
                hi: [
                    two(&node.child_max_x),
                    two(&node.child_max_y),
                    two(&node.child_max_z),
                ],
                bits: std::array::from_fn(|c| byte(child_bits8, c) << byte(bit_index8, c)),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        NodeBoxes {}
    }

    /// `node.intersect_ray(ray, oct_inv4)` (`self` decoded from `node` with that code).
    #[inline]
    fn hits(
        &self,
        node: &obvhs::cwbvh::node::CwBvhNode,
        ray: &obvhs::ray::Ray,
        oct_inv4: u32,
    ) -> u32 {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            let _ = oct_inv4;
            // obvhs' `extent * inv_direction` and `(p − origin) * inv_direction`, lane by
            // lane (IEEE operations: the same bits as its vector ones).
            let (e, inv, o) = (node.compute_extent(), ray.inv_direction, ray.origin);
            let dir_inv = [e.x * inv.x, e.y * inv.y, e.z * inv.z];
            let origin = [
                (node.p.x - o.x) * inv.x,
                (node.p.y - o.y) * inv.y,
                (node.p.z - o.z) * inv.z,
            ];
            let neg = [ray.direction.x, ray.direction.y, ray.direction.z].map(|d| d < 0.0);
            let mut hit = 0u32;
            // SAFETY: SSE2 is part of every x86-64 target.
            unsafe {
                let dir_inv = dir_inv.map(|v| _mm_set1_ps(v));
                let origin = origin.map(|v| _mm_set1_ps(v));
                for i in 0..2 {
                    let t = |a: usize| {
                        let (near, far) = if neg[a] {
                            (self.hi[a][i], self.lo[a][i])
                        } else {
                            (self.lo[a][i], self.hi[a][i])
                        };
                        (
                            _mm_add_ps(_mm_mul_ps(near, dir_inv[a]), origin[a]),
                            _mm_add_ps(_mm_mul_ps(far, dir_inv[a]), origin[a]),
                        )
                    };
                    let ((tmin_x, tmax_x), (tmin_y, tmax_y), (tmin_z, tmax_z)) = (t(0), t(1), t(2));
                    let tmin = _mm_max_ps(tmin_x, _mm_max_ps(tmin_y, tmin_z));
                    let tmax = _mm_min_ps(tmax_x, _mm_min_ps(tmax_y, tmax_z));
                    let tmin = _mm_max_ps(tmin, _mm_set1_ps(Self::EPSILON));
                    let tmax = _mm_min_ps(tmax, _mm_set1_ps(ray.tmax));
                    let mask = _mm_movemask_ps(_mm_cmple_ps(tmin, tmax)) as u32;
                    for j in Bits(mask) {
                        hit |= self.bits[i * 4 + j as usize];
                    }
                }
            }
            hit
        }
        #[cfg(not(target_arch = "x86_64"))]
        node.intersect_ray(ray, oct_inv4)
    }
}

/// The packet walk's stack of (node, rays): 64 entries in place (no allocation per walk), then
/// a vector, so that it has no bound.
struct PacketStack {
    inline: [(u32, u32); 64],
    len: usize,
    spill: Vec<(u32, u32)>,
}

impl Default for PacketStack {
    fn default() -> Self {
        PacketStack {
            inline: [(0, 0); 64],
            len: 0,
            spill: Vec::new(),
        }
    }
}

impl PacketStack {
    #[inline]
    fn push(&mut self, v: (u32, u32)) {
        if self.len < self.inline.len() {
            self.inline[self.len] = v;
            self.len += 1;
        } else {
            self.spill.push(v);
        }
    }

    /// The last entry pushed (the spill holds only entries pushed after the full array's).
    #[inline]
    fn pop(&mut self) -> Option<(u32, u32)> {
        self.spill.pop().or_else(|| {
            self.len = self.len.checked_sub(1)?;
            Some(self.inline[self.len])
        })
    }
}

/// The set bits of a `u32`, lowest first.
struct Bits(u32);

impl Iterator for Bits {
    type Item = u32;

    #[inline]
    fn next(&mut self) -> Option<u32> {
        (self.0 != 0).then(|| {
            let j = self.0.trailing_zeros();
            self.0 &= self.0 - 1;
            j
        })
    }
}

/// u32 words per node in [`GpuBvhData::nodes`].
pub const GPU_NODE_WORDS: usize = 20;
/// u32 words per slot in [`GpuBvhData::slots`].
pub const GPU_SLOT_WORDS: usize = 20;

/// A [`ModelBvh`] flattened for a GPU tracer (all little-endian u32 words; floats as their bits).
///
/// - `nodes`: per obvhs `CwBvhNode`, 20 words: `p` (3 f32); `e[0..3]` and `imask` as the four
///   bytes of one word; `child_base_idx`; `primitive_base_idx`; then `child_meta`,
///   `child_min_x`, `child_max_x`, `child_min_y`, `child_max_y`, `child_min_z`, `child_max_z`,
///   8 bytes each as two words (byte i of the array is byte i % 4 of word i / 4).
/// - `slots`: per BVH primitive (obvhs' `primitive_id` is the slot), 20 words: `v0`, `e1 = v1 −
///   v0`, `e2 = v2 − v0` (9 f32); `uv0`, `uv1 − uv0`, `uv2 − uv0` (6 f32); the mesh triangle,
///   the mask index (`u32::MAX`: no alpha test), the material, two zero words.
/// - `masks`: per alpha mask, 4 words: width, height, first word in `mask_bits`, 0.
/// - `mask_bits`: every mask's texels, one bit each, row 0 at the top ([`AlphaMask`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GpuBvhData {
    pub nodes: Vec<u32>,
    pub slots: Vec<u32>,
    pub masks: Vec<u32>,
    pub mask_bits: Vec<u32>,
    /// Node levels on the longest path from the root (the root alone: 1): a stack traversal
    /// pushes at most one entry per level.
    pub depth: u32,
}

/// Opaque-texel counts of a mask over texel rectangles (a summed-area table), for classifying
/// sub-triangles at build time in O(1).
struct OpaqueCount {
    w: i64,
    h: i64,
    /// `sat[y·(w+1) + x]`: opaque texels in [0, x) × [0, y).
    sat: Vec<u32>,
}

/// What a region of a masked triangle shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Coverage {
    Transparent,
    Opaque,
    Mixed,
}

impl OpaqueCount {
    fn new(m: &AlphaMask) -> Self {
        let (w, h) = (m.width as usize, m.height as usize);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                let i = y * w + x;
                row += (m.bits[i / 64] >> (i % 64) & 1) as u32;
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        OpaqueCount {
            w: w as i64,
            h: h as i64,
            sat,
        }
    }

    fn rect(&self, (x0, x1): (i64, i64), (y0, y1): (i64, i64)) -> u64 {
        let at = |x: i64, y: i64| self.sat[(y * (self.w + 1) + x) as usize] as u64;
        at(x1, y1) + at(x0, y0) - at(x0, y1) - at(x1, y0)
    }

    /// The texel ranges (half-open, within the texture) an inclusive, unwrapped range covers.
    fn wrap(a: i64, b: i64, n: i64) -> [(i64, i64); 2] {
        let len = b - a + 1;
        if len >= n {
            return [(0, n), (0, 0)];
        }
        let start = a.rem_euclid(n);
        if start + len <= n {
            [(start, start + len), (0, 0)]
        } else {
            [(start, n), (0, start + len - n)]
        }
    }

    /// Coverage of the sub-triangle with barycentric corners `bary` (weights of vertices 1 and
    /// 2) of a triangle with texture coordinates `uv`.
    fn coverage_of(&self, uv: &[[f32; 2]; 3], bary: [[f32; 2]; 3]) -> Coverage {
        let at = |b: [f32; 2], k: usize| {
            uv[0][k] + b[0] * (uv[1][k] - uv[0][k]) + b[1] * (uv[2][k] - uv[0][k])
        };
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for b in bary {
            for k in 0..2 {
                lo[k] = lo[k].min(at(b, k));
                hi[k] = hi[k].max(at(b, k));
            }
        }
        // Margin: a hit's interpolated coordinate may round a little outside the corners' box.
        let pad = [1e-3 / self.w as f32, 1e-3 / self.h as f32];
        self.coverage(
            [lo[0] - pad[0], lo[1] - pad[1]],
            [hi[0] + pad[0], hi[1] + pad[1]],
        )
    }

    /// Coverage of every texel that nearest sampling (repeating) can read for texture
    /// coordinates in the box [lo, hi].
    fn coverage(&self, lo: [f32; 2], hi: [f32; 2]) -> Coverage {
        if !(lo.iter().chain(&hi).all(|c| c.is_finite())) {
            return Coverage::Mixed;
        }
        let texel = |c: f32, n: i64| (c * n as f32).floor() as i64;
        let xs = Self::wrap(texel(lo[0], self.w), texel(hi[0], self.w), self.w);
        let ys = Self::wrap(texel(lo[1], self.h), texel(hi[1], self.h), self.h);
        let (mut opaque, mut area) = (0u64, 0u64);
        for &x in &xs {
            for &y in &ys {
                opaque += self.rect(x, y);
                area += ((x.1 - x.0) * (y.1 - y.0)) as u64;
            }
        }
        match opaque {
            0 => Coverage::Transparent,
            n if n == area => Coverage::Opaque,
            _ => Coverage::Mixed,
        }
    }
}

/// Primitive boxes of the alpha-aware build and, per box, its triangle (index into `kept`).
fn alpha_boxes(
    tris: &[obvhs::triangle::Triangle],
    kept: &[u32],
    mesh: &Mesh,
    masks: &[Option<AlphaMask>],
    depth: u32,
) -> (Vec<obvhs::aabb::Aabb>, Vec<u32>, Vec<bool>) {
    let counts: Vec<Option<OpaqueCount>> = masks
        .iter()
        .map(|m| {
            m.as_ref()
                .filter(|m| !m.is_all_opaque())
                .map(OpaqueCount::new)
        })
        .collect();
    let per_tri: Vec<(Vec<obvhs::aabb::Aabb>, bool)> = kept
        .par_iter()
        .zip(tris)
        .map(|(&t, tri)| {
            let mat = mesh.triangle_materials[t as usize] as usize;
            let Some(count) = counts.get(mat).and_then(|c| c.as_ref()) else {
                return (vec![tri.aabb()], false);
            };
            let p = [tri.v0, tri.v1, tri.v2].map(|v| Vec3A::from(v.to_array()));
            let uv = mesh.indices[t as usize].map(|i| mesh.uvs[i as usize]);
            let corners = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
            if count.coverage_of(&uv, corners) == Coverage::Opaque {
                return (vec![tri.aabb()], true);
            }
            let mut out = Vec::new();
            split_opaque(&p, &uv, count, corners, depth, &mut out);
            (out, false)
        })
        .collect();
    let mut boxes = Vec::new();
    let mut owner = Vec::new();
    let mut opaque = Vec::with_capacity(per_tri.len());
    for (k, (b, o)) in per_tri.into_iter().enumerate() {
        owner.extend(std::iter::repeat_n(k as u32, b.len()));
        boxes.extend(b);
        opaque.push(o);
    }
    (boxes, owner, opaque)
}

/// Adds the boxes of the sub-triangle with barycentric corners `bary` (weights of p1 and p2)
/// that can show opaque texels: dropped if every texel it may read is transparent, one box if
/// all are opaque or `depth` is spent, else its four midpoint children.
fn split_opaque(
    p: &[Vec3A; 3],
    uv: &[[f32; 2]; 3],
    count: &OpaqueCount,
    bary: [[f32; 2]; 3],
    depth: u32,
    out: &mut Vec<obvhs::aabb::Aabb>,
) {
    let cov = count.coverage_of(uv, bary);
    if cov == Coverage::Transparent {
        return;
    }
    if cov == Coverage::Opaque || depth == 0 {
        let q = bary.map(|b| p[0] + (p[1] - p[0]) * b[0] + (p[2] - p[0]) * b[1]);
        let (mn, mx) = (q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2]));
        // Margin: the hit point of the whole triangle may round a little outside this box.
        let pad = (mx - mn).max_element() * 1e-4 + mx.abs().max(mn.abs()).max_element() * 1e-6;
        out.push(obvhs::aabb::Aabb::new(
            (mn - pad).to_array().into(),
            (mx + pad).to_array().into(),
        ));
        return;
    }
    let mid = |a: [f32; 2], b: [f32; 2]| [(a[0] + b[0]) * 0.5, (a[1] + b[1]) * 0.5];
    let [a, b, c] = bary;
    let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
    for child in [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]] {
        split_opaque(p, uv, count, child, depth - 1, out);
    }
}

/// Möller–Trumbore ray/triangle test (both faces). Returns (t, u, v) for t in [tmin, tmax].
/// Comparisons are written so that NaN never passes.
#[inline(always)]
pub(crate) fn intersect(
    tri: &PreTri,
    o: Vec3A,
    d: Vec3A,
    tmin: f32,
    tmax: f32,
) -> Option<(f32, f32, f32)> {
    let p = d.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0;
    let u = s.dot(p) * inv;
    // Written so that NaN fails the test too.
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = d.dot(q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = tri.e2.dot(q) * inv;
    (t >= tmin && t <= tmax).then_some((t, u, v))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::Material;
    use crate::trace::Rng;

    /// A mesh of `n` random triangles in the unit cube, one material.
    fn random_mesh(n: usize, seed: u64) -> Mesh {
        let mut rng = Rng::hashed(seed);
        let mut mesh = Mesh {
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        for t in 0..n {
            let c = [rng.f32(), rng.f32(), rng.f32()];
            for _ in 0..3 {
                let p = [
                    c[0] + (rng.f32() - 0.5) * 0.2,
                    c[1] + (rng.f32() - 0.5) * 0.2,
                    c[2] + (rng.f32() - 0.5) * 0.2,
                ];
                mesh.positions.push(p);
                mesh.normals.push([0.0, 0.0, 1.0]);
                mesh.uvs.push([rng.f32(), rng.f32()]);
            }
            let i = 3 * t as u32;
            mesh.indices.push([i, i + 1, i + 2]);
            mesh.triangle_materials.push(0);
        }
        mesh
    }

    fn random_ray(rng: &mut Rng) -> Ray {
        let o = Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 1.4 - 0.2;
        let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
        Ray::new(o, d.normalize_or(Vec3A::Z), 0.0)
    }

    /// A checkerboard mask: alpha 255 and 0 alternating over 8×8 texels.
    pub(crate) fn checker() -> AlphaMask {
        let mut img = Rgba8Image {
            width: 8,
            height: 8,
            pixels: vec![[255; 4]; 64],
        };
        for (i, p) in img.pixels.iter_mut().enumerate() {
            if (i % 8 + i / 8) % 2 == 1 {
                p[3] = 0;
            }
        }
        AlphaMask::from_rgba8(&img)
    }

    fn same_hit(a: Option<Hit>, b: Option<Hit>) {
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                assert_eq!(a.t, b.t);
                // Equal t from two triangles is a tie either may win.
                if a.triangle != b.triangle {
                    assert_eq!(a.t, b.t);
                } else {
                    assert_eq!((a.u, a.v), (b.u, b.v));
                }
            }
            _ => panic!("bvh {a:?} vs brute force {b:?}"),
        }
    }

    #[test]
    fn bvh_closest_hit_equals_brute_force_for_every_preset() {
        let mesh = random_mesh(400, 3);
        for preset in BuildPreset::ALL {
            let bvh = ModelBvh::build(&mesh, &[], preset).unwrap();
            let mut rng = Rng::hashed(11);
            let mut hits = 0;
            for _ in 0..2000 {
                let r = random_ray(&mut rng);
                let (a, b) = (bvh.closest_hit(&r), bvh.brute_force_closest_hit(&r));
                hits += a.is_some() as u32;
                same_hit(a, b);
                assert_eq!(bvh.any_hit(&r), b.is_some());
            }
            assert!(hits > 200, "too few hits to mean anything: {hits}");
        }
    }

    #[test]
    fn alpha_tested_bvh_equals_brute_force() {
        let mesh = random_mesh(300, 5);
        let bvh = ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::default()).unwrap();
        let opaque = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        let mut rng = Rng::hashed(9);
        let mut differ = 0;
        for _ in 0..2000 {
            let r = random_ray(&mut rng);
            let a = bvh.closest_hit(&r);
            same_hit(a, bvh.brute_force_closest_hit(&r));
            assert_eq!(bvh.any_hit(&r), a.is_some());
            if let Some(h) = a {
                let s = bvh.surface(&h);
                assert!(checker().opaque_at(s.uv[0], s.uv[1]));
            }
            differ += (a != opaque.closest_hit(&r)) as u32;
        }
        assert!(differ > 50, "the mask changed nothing: {differ}");
    }

    #[test]
    fn batched_queries_match_single_queries() {
        let mesh = random_mesh(200, 8);
        let bvh = ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::Fast).unwrap();
        let mut rng = Rng::hashed(2);
        let rays: Vec<Ray> = (0..500).map(|_| random_ray(&mut rng)).collect();
        let single: Vec<_> = rays.iter().map(|r| bvh.closest_hit(r)).collect();
        assert_eq!(bvh.closest_hits(&rays), single);
        let any: Vec<_> = rays.iter().map(|r| bvh.any_hit(r)).collect();
        assert_eq!(bvh.any_hits(&rays), any);
    }

    /// A packet of 1..=`max` rays from one origin: within the sun's disc (0.00465 rad) of one
    /// direction, or of any directions (mixed octants); now and then a direction with a zero
    /// component; `tmin` 0 or small, `tmax` infinite, finite or just short of the box.
    fn packet(rng: &mut Rng, lo: Vec3A, hi: Vec3A, max: usize) -> Vec<Ray> {
        let size = hi - lo;
        let u = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
        let mut o = match rng.f32() {
            // Inside the mesh's box.
            x if x < 0.35 => lo + size * u,
            // Outside it, around it.
            x if x < 0.7 => lo - size * 0.5 + size * 2.0 * u,
            // On a face of the box (rays along the face graze it).
            _ => lo + size * u,
        };
        let face = (rng.f32() * 3.0) as usize % 3;
        let on_face = rng.f32() < 0.3;
        if on_face {
            o[face] = if rng.f32() < 0.5 { lo[face] } else { hi[face] };
        }
        let axis = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
        let mut axis = axis.normalize_or(Vec3A::Z);
        if on_face {
            // Along the face: no component across it.
            axis[face] = 0.0;
            axis = axis.normalize_or(Vec3A::X);
        }
        let parallel = rng.f32() < 0.6;
        let n = 1 + (rng.f32() * max as f32) as usize % max;
        (0..n)
            .map(|j| {
                let d = if j % 5 == 2 {
                    axis
                } else if parallel {
                    let (t, b) = crate::trace::frame(axis);
                    let r = 0.00465 * rng.f32().sqrt();
                    let phi = std::f32::consts::TAU * rng.f32();
                    (axis + t * (r * phi.cos()) + b * (r * phi.sin())).normalize()
                } else {
                    Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5)
                        .normalize_or(Vec3A::Y)
                };
                let tmin = [0.0, 1e-4, 1e-3][j % 3];
                let tmax = match (j / 3) % 3 {
                    0 => f32::INFINITY,
                    1 => size.length() * (0.05 + rng.f32()),
                    _ => size.length() * 3.0,
                };
                Ray {
                    tmin,
                    tmax,
                    ..Ray::new(o, d, 0.0)
                }
            })
            .collect()
    }

    /// Every ray of `packets` random packets through [`ModelBvh::any_hits_packet`] against
    /// `any_hit` and brute force; returns (hits, rays, packets with both answers).
    fn check_packets(bvh: &ModelBvh, seed: u64, packets: usize, max: usize) -> [usize; 3] {
        let (mut lo, mut hi) = bvh.bounds();
        let pad = (hi - lo) * 0.01;
        (lo, hi) = (lo - pad, hi + pad);
        let mut rng = Rng::hashed(seed);
        let mut counts = [0; 3];
        for _ in 0..packets {
            let rays = packet(&mut rng, lo, hi, max);
            let mut got = vec![true; rays.len()];
            bvh.any_hits_packet(&rays, &mut got);
            for (r, &g) in rays.iter().zip(&got) {
                assert_eq!(g, bvh.any_hit(r), "any_hit: {r:?}");
                assert_eq!(g, bvh.brute_force_closest_hit(r).is_some(), "brute: {r:?}");
            }
            let h = got.iter().filter(|&&g| g).count();
            counts[0] += h;
            counts[1] += rays.len();
            counts[2] += (h > 0 && h < rays.len()) as usize;
        }
        counts
    }

    #[test]
    fn packet_stack_is_last_in_first_out_past_its_array() {
        let mut s = PacketStack::default();
        let mut model = Vec::new();
        let mut rng = Rng::hashed(3);
        for k in 0..2000u32 {
            if rng.f32() < 0.6 {
                s.push((k, !k));
                model.push((k, !k));
            } else {
                assert_eq!(s.pop(), model.pop());
            }
        }
        assert!(model.len() > 64, "{}", model.len());
        while let Some(v) = model.pop() {
            assert_eq!(s.pop(), Some(v));
        }
        assert_eq!(s.pop(), None);
    }

    #[test]
    fn node_boxes_equal_obvhs_node_test() {
        // Every node of two BVHs against rays of every kind (from inside and outside, zero
        // direction components, short, infinite and negative tmax) under every octant code:
        // the hoisted decoding gives obvhs' own hit mask, bit for bit.
        let (plant, tex) = crate::prt::plant::procedural_plant(1500, 7);
        let masks = vec![Some(AlphaMask::from_rgba8(&tex)), None];
        let models = [
            ModelBvh::build(&plant, &masks, BuildPreset::VeryFast).unwrap(),
            ModelBvh::build(&random_mesh(200, 3), &[], BuildPreset::Slow).unwrap(),
        ];
        let mut rng = Rng::hashed(5);
        let (mut nonzero, mut tests) = (0, 0);
        for m in &models {
            let bvh = m.bvh.as_ref().unwrap();
            let (lo, hi) = m.bounds();
            for _ in 0..100 {
                let mut rays = packet(&mut rng, lo, hi, 8);
                rays.push(Ray {
                    tmax: -1.0,
                    ..rays[0]
                });
                for node in &bvh.nodes {
                    for oct in 0..8u32 {
                        let oct = oct * 0x0101_0101;
                        let boxes = NodeBoxes::new(node, oct);
                        for r in &rays {
                            let r = r.to_obvhs();
                            let want = node.intersect_ray(&r, oct);
                            assert_eq!(boxes.hits(node, &r, oct), want, "{r:?} {node:?}");
                            nonzero += (want != 0) as usize;
                            tests += 1;
                        }
                    }
                }
            }
        }
        assert!(
            nonzero > tests / 100 && nonzero < tests,
            "{nonzero} of {tests}"
        );
    }

    #[test]
    fn packet_any_hit_equals_any_hit_and_brute_force() {
        // Random triangles, opaque and alpha-tested (checker), and the procedural plant's
        // leaf cards with its own texture, whole and split into boxes (depth 2: a triangle
        // in several leaves, the repeat-triangle skip at work).
        let mesh = random_mesh(300, 21);
        let (plant, tex) = crate::prt::plant::procedural_plant(1500, 6);
        let plant_masks = vec![Some(AlphaMask::from_rgba8(&tex)), None];
        let cases = [
            (
                "opaque",
                ModelBvh::build(&mesh, &[], BuildPreset::default()),
            ),
            (
                "checker",
                ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::Fast),
            ),
            (
                "plant",
                ModelBvh::build(&plant, &plant_masks, BuildPreset::VeryFast),
            ),
            (
                "plant split",
                ModelBvh::build_split(&plant, &plant_masks, BuildPreset::VeryFast, 2),
            ),
        ];
        for (k, (name, bvh)) in cases.into_iter().enumerate() {
            let bvh = bvh.unwrap();
            let [hits, rays, mixed] = check_packets(&bvh, 40 + k as u64, 1500, 16);
            // Both answers, and packets that split, occur often: a walk that answered all
            // rays alike, or none, would fail.
            assert!(
                hits > rays / 20 && hits < rays * 9 / 10 && mixed > 100,
                "{name}: {hits} hits of {rays} rays, {mixed} mixed packets"
            );
            // More rays than one walk carries: the packets run in chunks.
            let [_, rays, _] = check_packets(&bvh, 50 + k as u64, 40, 70);
            assert!(rays > 40 * 20, "{rays}");
        }
        // No BVH at all: every ray open.
        let empty = ModelBvh::build(&Mesh::default(), &[], BuildPreset::default()).unwrap();
        let mut got = [true; 3];
        empty.any_hits_packet(&[Ray::new(Vec3A::ZERO, Vec3A::Z, 0.0); 3], &mut got);
        assert_eq!(got, [false; 3]);
    }

    #[test]
    fn surface_interpolates_attributes() {
        let mesh = Mesh {
            positions: vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            indices: vec![[0, 1, 2]],
            triangle_materials: vec![0],
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        let bvh = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        let r = Ray::new(Vec3A::new(0.5, 0.25, 3.0), Vec3A::new(0.0, 0.0, -2.0), 0.0);
        let h = bvh.closest_hit(&r).unwrap();
        assert!((h.t - 1.5).abs() < 1e-6, "t is in units of dir");
        let s = bvh.surface(&h);
        assert!((s.position - Vec3A::new(0.5, 0.25, 0.0)).length() < 1e-6);
        assert!((s.uv[0] - 0.25).abs() < 1e-6 && (s.uv[1] - 0.125).abs() < 1e-6);
        assert_eq!(s.geometric_normal, Vec3A::Z);
        let expect = Vec3A::new(0.25, 0.0, 0.75).normalize();
        assert!((s.shading_normal - expect).length() < 1e-6);
        let (p, ng, m) = bvh.hit_point(&h);
        assert!((p - s.position).length() < 1e-6 && ng == s.geometric_normal && m == 0);
        // A segment ending before the triangle misses it.
        let short = Ray { tmax: 1.4, ..r };
        assert!(bvh.closest_hit(&short).is_none() && !bvh.any_hit(&short));
    }

    #[test]
    fn empty_and_non_finite_meshes_do_not_panic() {
        let empty = ModelBvh::build(&Mesh::default(), &[], BuildPreset::default()).unwrap();
        let r = Ray::new(Vec3A::ZERO, Vec3A::Z, 0.0);
        assert!(empty.closest_hit(&r).is_none() && !empty.any_hit(&r));
        let mut mesh = random_mesh(3, 1);
        mesh.positions[0] = [f32::NAN, 0.0, 0.0];
        let bvh = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        assert_eq!(bvh.skipped_triangles(), 1);
    }

    #[test]
    fn alpha_aware_build_equals_brute_force_on_a_plant() {
        // The procedural plant: leaf quads whose texture is 43% transparent around a lens.
        let (mesh, tex) = crate::prt::plant::procedural_plant(1500, 4);
        let masks = vec![Some(AlphaMask::from_rgba8(&tex)), None];
        let opaque = ModelBvh::build(&mesh, &[], BuildPreset::VeryFast).unwrap();
        let (lo, hi) = opaque.bounds();
        let mut counts = Vec::new();
        for depth in 0..=3 {
            let bvh = ModelBvh::build_split(&mesh, &masks, BuildPreset::VeryFast, depth).unwrap();
            counts.push(bvh.primitive_count());
            let mut rng = Rng::hashed(30 + depth as u64);
            let (mut hits, mut differ) = (0, 0);
            for _ in 0..3000 {
                let f = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
                let o = lo + (hi - lo) * f;
                let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
                let r = Ray::new(o, d.normalize_or(Vec3A::Z), 0.0);
                let a = bvh.closest_hit(&r);
                same_hit(a, bvh.brute_force_closest_hit(&r));
                assert_eq!(bvh.any_hit(&r), a.is_some());
                hits += a.is_some() as u32;
                differ += (a.map(|h| h.t) != opaque.closest_hit(&r).map(|h| h.t)) as u32;
            }
            assert!(
                hits > 500 && differ > 100,
                "depth {depth}: {hits} hits, {differ} differ"
            );
        }
        // Depth 0 keeps every leaf triangle whole (each touches opaque texels); deeper builds
        // drop transparent corners and split the rest.
        assert_eq!(counts[0], mesh.indices.len());
        assert!(counts[1] > counts[0] && counts[3] > counts[2], "{counts:?}");
    }

    #[test]
    fn coverage_equals_a_texel_loop() {
        let mut rng = Rng::hashed(17);
        let (w, h) = (13u32, 7u32);
        let img = Rgba8Image {
            width: w,
            height: h,
            pixels: (0..w * h)
                .map(|_| [0, 0, 0, if rng.f32() < 0.8 { 255 } else { 0 }])
                .collect(),
        };
        let mask = AlphaMask::from_rgba8(&img);
        let count = OpaqueCount::new(&mask);
        let (mut seen_t, mut seen_o, mut seen_m) = (0, 0, 0);
        for _ in 0..5000 {
            let size = [rng.f32() * 0.4, rng.f32() * 0.6];
            let lo = [rng.f32() * 4.0 - 2.0, rng.f32() * 4.0 - 2.0];
            let hi = [lo[0] + size[0] * size[0], lo[1] + size[1] * size[1] * 3.0];
            // Reference: every texel nearest sampling can read in the box, looped over.
            let (x0, x1) = ((lo[0] * 13.0).floor() as i64, (hi[0] * 13.0).floor() as i64);
            let (y0, y1) = ((lo[1] * 7.0).floor() as i64, (hi[1] * 7.0).floor() as i64);
            let (mut any_o, mut any_t) = (false, false);
            for x in x0..=x1.min(x0 + 13) {
                for y in y0..=y1.min(y0 + 7) {
                    let u = (x.rem_euclid(13) as f32 + 0.5) / 13.0;
                    let v = (y.rem_euclid(7) as f32 + 0.5) / 7.0;
                    if mask.opaque_at(u, v) {
                        any_o = true;
                    } else {
                        any_t = true;
                    }
                }
            }
            let expect = match (any_o, any_t) {
                (true, false) => Coverage::Opaque,
                (false, true) => Coverage::Transparent,
                _ => Coverage::Mixed,
            };
            assert_eq!(count.coverage(lo, hi), expect, "{lo:?} {hi:?}");
            seen_t += (expect == Coverage::Transparent) as u32;
            seen_o += (expect == Coverage::Opaque) as u32;
            seen_m += (expect == Coverage::Mixed) as u32;
        }
        assert!(
            seen_t > 100 && seen_o > 100 && seen_m > 100,
            "{seen_t} {seen_o} {seen_m}"
        );
    }

    #[test]
    fn transparent_triangles_leave_the_bvh_and_opaque_ones_stay_whole() {
        // Checker texels: (0, 0) opaque, (1, 0) transparent. Triangle 0 samples only texel
        // (1, 0), triangle 1 only texel (0, 0).
        let mesh = Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 1.0],
                [0.0, 1.0, 1.0],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 6],
            uvs: vec![
                [0.13, 0.01],
                [0.24, 0.01],
                [0.13, 0.12],
                [0.01, 0.01],
                [0.12, 0.01],
                [0.01, 0.12],
            ],
            indices: vec![[0, 1, 2], [3, 4, 5]],
            triangle_materials: vec![0, 0],
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        let bvh = ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::default()).unwrap();
        assert!(!bvh.contains_triangle(0) && bvh.contains_triangle(1));
        assert_eq!(
            bvh.primitive_count(),
            1,
            "an all-opaque triangle is one box"
        );
        let up = Ray::new(Vec3A::new(0.2, 0.2, -1.0), Vec3A::Z, 0.0);
        let h = bvh.closest_hit(&up).unwrap();
        assert_eq!((h.triangle, h.t), (1, 2.0));
        assert_eq!(bvh.brute_force_closest_hit(&up), Some(h));
    }

    #[test]
    fn alpha_mask_samples_nearest_texel_with_repeat() {
        let m = checker();
        assert!(m.opaque_at(0.01, 0.01));
        assert!(!m.opaque_at(0.14, 0.01));
        assert!(m.opaque_at(1.01, -0.99), "repeats in both directions");
        assert!(m.opaque_at(f32::NAN, 0.0), "NaN maps to texel 0, no panic");
        assert!(!m.is_all_opaque());
    }
}
