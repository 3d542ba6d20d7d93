//! Ray tracing of the terrain height grid through its min/max quadtree (seed 000 4.5.5), without
//! a triangle BVH.
//!
//! The surface is the one the renderer draws (`render/shaders/terrain.wgsl`) and
//! [`crate::trace::pack_scene::terrain_mesh`] builds: two triangles per grid cell, split along the
//! diagonal from sample (i, j) to (i + 1, j + 1): (i, j) (i+1, j) (i+1, j+1) and
//! (i, j) (i+1, j+1) (i, j+1), with the vertex positions of [`crate::model::Terrain::position`].
//! Not the bilinear patch: a ray must hit exactly what the camera sees. The cell test is the
//! BVH's Möller–Trumbore on the same vertices in the same order, so a hit has the same `t`,
//! triangle number and barycentrics as a hit on the triangle-mesh terrain (up to ties).
//!
//! Traversal: a stack descent from the quadtree root; a node's box is its cells' footprint times
//! `[min, max]` of their heights (which bounds both triangles of every cell: they are convex
//! combinations of the corners). Closest hit visits children nearest entry first and prunes
//! boxes entered beyond the best hit; any hit stops at the first one. Boxes are tested in grid
//! space (cell (i, j) spans [i, i+1] × [j, j+1]) padded by a small margin so that rounding in
//! the box test can never hide a triangle the exact test would hit.

use super::bvh::{PreTri, SurfacePoint, intersect};
use super::{Hit, Ray};
use crate::error::{Error, Result};
use crate::model::Terrain;
use crate::terrain::MinMaxQuadtree;
use glam::Vec3A;
use rayon::prelude::*;

/// Box margin in cells (grid x and y): far above the rounding of the grid mapping, far below a
/// cell, so pruning stays conservative and nearly as tight.
const PAD_CELLS: f32 = 1e-3;

/// A terrain prepared for ray tracing.
#[derive(Debug, Clone)]
pub struct Heightfield {
    width: u32,
    height: u32,
    heights: Vec<f32>,
    origin: [f32; 2],
    extent: [f32; 2],
    /// Sample spacing (x, y), computed as [`Terrain::position`] does.
    step: [f32; 2],
    tree: MinMaxQuadtree,
    /// Height margin of the node boxes (relative to the largest |height|).
    pad_z: f32,
}

/// Where a ray met the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerrainPoint {
    pub position: Vec3A,
    /// Unit normal of the hit triangle (pointing up).
    pub normal: Vec3A,
    /// Continuous grid coordinates: sample (i, j) is at (i, j).
    pub grid: [f32; 2],
    /// The cell (i, j): the square between samples (i, j) and (i + 1, j + 1).
    pub cell: [u32; 2],
}

/// A pending quadtree node: level, position, entry distance of its box.
#[derive(Debug, Clone, Copy, Default)]
struct Node {
    level: u32,
    x: u32,
    y: u32,
    t: f32,
}

/// The ray in grid space (x and y in cells, z unchanged; `t` is the world ray's `t`).
struct GridRay {
    o: Vec3A,
    d: Vec3A,
    inv: Vec3A,
}

impl Heightfield {
    /// Prepares `t` for tracing (builds its min/max quadtree).
    pub fn new(t: &Terrain) -> Result<Self> {
        Self::check(t)?;
        let tree = MinMaxQuadtree::build(&t.heights, t.width, t.height);
        Ok(Self::with_tree(t, tree))
    }

    /// Prepares `t` with a quadtree read from its section; rebuilds it if it does not fit the
    /// grid (a section written for another grid size).
    pub fn with_quadtree(t: &Terrain, tree: MinMaxQuadtree) -> Result<Self> {
        Self::check(t)?;
        let l0 = tree.level(0);
        if (l0.width, l0.height) != (t.width - 1, t.height - 1) {
            return Self::new(t);
        }
        Ok(Self::with_tree(t, tree))
    }

    fn check(t: &Terrain) -> Result<()> {
        if t.width < 2 || t.height < 2 {
            return Err(Error::runtime(format!(
                "terrain of {}×{} samples has no cell to trace",
                t.width, t.height
            )));
        }
        if t.heights.len() as u64 != t.width as u64 * t.height as u64 {
            return Err(Error::runtime(format!(
                "terrain has {} heights for {}×{} samples",
                t.heights.len(),
                t.width,
                t.height
            )));
        }
        if let Some(k) = t.heights.iter().position(|h| !h.is_finite()) {
            let (i, j) = (k as u32 % t.width, k as u32 / t.width);
            return Err(Error::runtime(format!(
                "terrain height at sample ({i}, {j}) is not finite"
            )));
        }
        let ok = |v: f32| v.is_finite() && v > 0.0;
        if !ok(t.extent[0]) || !ok(t.extent[1]) || !t.origin.iter().all(|o| o.is_finite()) {
            return Err(Error::runtime(format!(
                "terrain origin {:?} / extent {:?} is not usable",
                t.origin, t.extent
            )));
        }
        Ok(())
    }

    fn with_tree(t: &Terrain, tree: MinMaxQuadtree) -> Self {
        let top = tree.node(tree.levels() - 1, 0, 0);
        let zmax = top[0].abs().max(top[1].abs()).max(1.0);
        Heightfield {
            width: t.width,
            height: t.height,
            heights: t.heights.clone(),
            origin: t.origin,
            extent: t.extent,
            step: [
                t.extent[0] / (t.width - 1) as f32,
                t.extent[1] / (t.height - 1) as f32,
            ],
            tree,
            pad_z: zmax * 1e-5,
        }
    }

    /// Grid size in samples.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The quadtree the traversal descends.
    pub fn quadtree(&self) -> &MinMaxQuadtree {
        &self.tree
    }

    /// The heights, row-major (`width × height`).
    pub fn heights(&self) -> &[f32] {
        &self.heights
    }

    /// Sample (0, 0)'s x, y and the sample spacing (x, y), as the traversal maps the grid.
    pub fn grid(&self) -> ([f32; 2], [f32; 2]) {
        (self.origin, self.step)
    }

    /// The node boxes' height margin.
    pub fn pad_z(&self) -> f32 {
        self.pad_z
    }

    /// World bounds of the surface.
    pub fn bounds(&self) -> (Vec3A, Vec3A) {
        let [lo, hi] = self.tree.node(self.tree.levels() - 1, 0, 0);
        let o = Vec3A::new(self.origin[0], self.origin[1], lo);
        (o, o + Vec3A::new(self.extent[0], self.extent[1], hi - lo))
    }

    #[inline]
    fn sample(&self, i: u32, j: u32) -> f32 {
        self.heights[(j * self.width + i) as usize]
    }

    /// World position of sample (i, j), exactly as [`Terrain::position`] computes it.
    #[inline]
    fn position(&self, i: u32, j: u32) -> Vec3A {
        Vec3A::new(
            self.origin[0] + i as f32 * self.step[0],
            self.origin[1] + j as f32 * self.step[1],
            self.sample(i, j),
        )
    }

    /// The two triangles of cell (i, j), as the triangle-mesh terrain lays them out.
    #[inline]
    fn cell_triangles(&self, i: u32, j: u32) -> [PreTri; 2] {
        let a = self.position(i, j);
        let b = self.position(i + 1, j);
        let c = self.position(i, j + 1);
        let d = self.position(i + 1, j + 1);
        [
            PreTri {
                v0: a,
                e1: b - a,
                e2: d - a,
            },
            PreTri {
                v0: a,
                e1: d - a,
                e2: c - a,
            },
        ]
    }

    /// The closer hit of cell (i, j)'s two triangles with t in [tmin, tmax].
    #[inline]
    fn hit_cell(&self, i: u32, j: u32, ray: &Ray, tmax: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let first = 2 * (j * (self.width - 1) + i);
        for (k, tri) in self.cell_triangles(i, j).iter().enumerate() {
            let limit = best.map_or(tmax, |b| b.t);
            if let Some((t, u, v)) = intersect(tri, ray.origin, ray.dir, ray.tmin, limit)
                && best.is_none_or(|b| t < b.t)
            {
                let triangle = first + k as u32;
                best = Some(Hit {
                    t,
                    triangle,
                    slot: triangle,
                    u,
                    v,
                });
            }
        }
        best
    }

    fn grid_ray(&self, ray: &Ray) -> GridRay {
        let o = Vec3A::new(
            (ray.origin.x - self.origin[0]) / self.step[0],
            (ray.origin.y - self.origin[1]) / self.step[1],
            ray.origin.z,
        );
        let d = Vec3A::new(
            ray.dir.x / self.step[0],
            ray.dir.y / self.step[1],
            ray.dir.z,
        );
        GridRay {
            o,
            d,
            inv: d.recip(),
        }
    }

    /// Entry distance of node (k, x, y)'s padded box, if the ray meets it within [tmin, tmax].
    #[inline]
    fn enter(&self, g: &GridRay, k: u32, x: u32, y: u32, tmin: f32, tmax: f32) -> Option<f32> {
        self.span(g, k, x, y, tmin, tmax).map(|s| s.0)
    }

    /// Entry and exit distances of node (k, x, y)'s padded box within [tmin, tmax].
    #[inline]
    fn span(
        &self,
        g: &GridRay,
        k: u32,
        x: u32,
        y: u32,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, f32)> {
        let l0 = self.tree.level(0);
        let x0 = (x << k) as f32;
        let y0 = (y << k) as f32;
        let x1 = ((x + 1) << k).min(l0.width) as f32;
        let y1 = ((y + 1) << k).min(l0.height) as f32;
        let [zlo, zhi] = self.tree.node(k as usize, x, y);
        let lo = Vec3A::new(x0 - PAD_CELLS, y0 - PAD_CELLS, zlo - self.pad_z);
        let hi = Vec3A::new(x1 + PAD_CELLS, y1 + PAD_CELLS, zhi + self.pad_z);
        let t0 = (lo - g.o) * g.inv;
        let t1 = (hi - g.o) * g.inv;
        // min/max ignore a NaN operand (0·∞ for a ray lying in a slab plane of the padded box,
        // which touches no surface), so the box is then missed or bounded by the other axes.
        let near = t0.min(t1).max_element().max(tmin);
        let far = t0.max(t1).min_element().min(tmax);
        (near <= far).then_some((near, far))
    }

    /// The children of node `n` the ray enters before `tmax`, pushed farthest first.
    #[inline]
    fn push_children(&self, g: &GridRay, n: Node, ray: &Ray, tmax: f32, stack: &mut Stack) {
        let k = n.level - 1;
        let l = self.tree.level(k as usize);
        let mut kids = [Node::default(); 4];
        let mut m = 0;
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (x, y) = (2 * n.x + dx, 2 * n.y + dy);
            if x < l.width
                && y < l.height
                && let Some(t) = self.enter(g, k, x, y, ray.tmin, tmax)
            {
                kids[m] = Node { level: k, x, y, t };
                m += 1;
            }
        }
        let kids = &mut kids[..m];
        kids.sort_unstable_by(|a, b| b.t.total_cmp(&a.t));
        for &c in kids.iter() {
            stack.push(c);
        }
    }

    /// Where a descent starts: the smallest node whose cells cover the footprint of the ray's
    /// segment inside the terrain's box (every cell the ray can hit lies under it), so short
    /// segments (rays leaving the surface upwards, shadow rays) skip the upper levels.
    fn root(&self, g: &GridRay, ray: &Ray) -> Option<Node> {
        let top = (self.tree.levels() - 1) as u32;
        let (t0, t1) = self.span(g, top, 0, 0, ray.tmin, ray.tmax)?;
        let root = Node {
            level: top,
            x: 0,
            y: 0,
            t: t0,
        };
        let (a, b) = (g.o + g.d * t0, g.o + g.d * t1);
        if !(a.is_finite() && b.is_finite()) {
            return Some(root);
        }
        let l0 = self.tree.level(0);
        // `as u32` saturates (negative → 0); the margin reaches the cell on the other side of a
        // cell edge the segment ends on.
        let cell = |v: f32, n: u32| (v as u32).min(n - 1);
        let pad = 2.0 * PAD_CELLS;
        let (x0, x1) = (
            cell(a.x.min(b.x) - pad, l0.width),
            cell(a.x.max(b.x) + pad, l0.width),
        );
        let (y0, y1) = (
            cell(a.y.min(b.y) - pad, l0.height),
            cell(a.y.max(b.y) + pad, l0.height),
        );
        let mut k = 0;
        while k < top && (x0 >> k != x1 >> k || y0 >> k != y1 >> k) {
            k += 1;
        }
        Some(Node {
            level: k,
            x: x0 >> k,
            y: y0 >> k,
            t: t0,
        })
    }

    /// The closest hit along the ray. The hit's `triangle` (= `slot`) numbers the triangles as
    /// [`crate::trace::pack_scene::terrain_mesh`] does: 2·(j·(W − 1) + i) + k for cell (i, j).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let g = self.grid_ray(ray);
        let mut stack = Stack::new();
        stack.push(self.root(&g, ray)?);
        let mut best: Option<Hit> = None;
        let mut tmax = ray.tmax;
        while let Some(n) = stack.pop() {
            if n.t > tmax {
                continue;
            }
            if n.level == 0 {
                if let Some(h) = self.hit_cell(n.x, n.y, ray, tmax)
                    && h.t <= tmax
                {
                    // Equal t on a shared edge: keep the first found, as the brute force does
                    // within a cell.
                    if best.is_none_or(|b| h.t < b.t) {
                        tmax = h.t;
                        best = Some(h);
                    }
                }
                continue;
            }
            self.push_children(&g, n, ray, tmax, &mut stack);
        }
        best
    }

    /// Whether the terrain blocks the ray segment (stops at the first hit found).
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let g = self.grid_ray(ray);
        let mut stack = Stack::new();
        let Some(root) = self.root(&g, ray) else {
            return false;
        };
        stack.push(root);
        while let Some(n) = stack.pop() {
            if n.level == 0 {
                if self.hit_cell(n.x, n.y, ray, ray.tmax).is_some() {
                    return true;
                }
                continue;
            }
            let k = n.level - 1;
            let l = self.tree.level(k as usize);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (x, y) = (2 * n.x + dx, 2 * n.y + dy);
                if x < l.width
                    && y < l.height
                    && let Some(t) = self.enter(&g, k, x, y, ray.tmin, ray.tmax)
                {
                    stack.push(Node { level: k, x, y, t });
                }
            }
        }
        false
    }

    /// Reference closest hit: every cell in row-major order, no quadtree.
    pub fn brute_force_closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for j in 0..self.height - 1 {
            for i in 0..self.width - 1 {
                let tmax = best.map_or(ray.tmax, |b| b.t);
                if let Some(h) = self.hit_cell(i, j, ray, tmax)
                    && best.is_none_or(|b| h.t < b.t)
                {
                    best = Some(h);
                }
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

    /// Cell and triangle (0: the one with edge (i, j)–(i+1, j)) of a hit.
    fn cell_of(&self, hit: &Hit) -> (u32, u32, u32) {
        let cw = self.width - 1;
        let cell = hit.triangle / 2;
        (cell % cw, cell / cw, hit.triangle % 2)
    }

    /// Position, triangle normal and grid coordinates of a hit.
    pub fn hit_point(&self, hit: &Hit) -> TerrainPoint {
        let (i, j, k) = self.cell_of(hit);
        let tri = self.cell_triangles(i, j)[k as usize];
        let position = tri.v0 + tri.e1 * hit.u + tri.e2 * hit.v;
        // Triangle 0 is (0,0) (1,0) (1,1), triangle 1 is (0,0) (1,1) (0,1) in cell units.
        let (fx, fy) = if k == 0 {
            (hit.u + hit.v, hit.v)
        } else {
            (hit.u, hit.u + hit.v)
        };
        TerrainPoint {
            position,
            normal: tri.e1.cross(tri.e2).normalize_or(Vec3A::Z),
            grid: [i as f32 + fx, j as f32 + fy],
            cell: [i, j],
        }
    }

    /// The surface at a hit with the attributes of the triangle-mesh terrain: shading normal
    /// interpolated from the per-sample normals, texture coordinate `(x/(W−1), 1 − y/(H−1))`.
    pub fn surface(&self, hit: &Hit) -> SurfacePoint {
        let (i, j, k) = self.cell_of(hit);
        let p = self.hit_point(hit);
        let corners = if k == 0 {
            [(i, j), (i + 1, j), (i + 1, j + 1)]
        } else {
            [(i, j), (i + 1, j + 1), (i, j + 1)]
        };
        let w = [1.0 - hit.u - hit.v, hit.u, hit.v];
        let ns = corners
            .iter()
            .zip(w)
            .fold(Vec3A::ZERO, |acc, (&(a, b), w)| {
                acc + Vec3A::from(self.sample_normal(a, b)) * w
            })
            .try_normalize()
            .unwrap_or(p.normal);
        let (cw, ch) = ((self.width - 1) as f32, (self.height - 1) as f32);
        SurfacePoint {
            position: p.position,
            geometric_normal: p.normal,
            shading_normal: ns,
            uv: [p.grid[0] / cw, 1.0 - p.grid[1] / ch],
            material: 0,
            triangle: hit.triangle,
        }
    }

    /// Normal at sample (i, j) by central differences (one-sided at the edges), as the renderer
    /// computes it.
    pub fn sample_normal(&self, i: u32, j: u32) -> [f32; 3] {
        let (i0, i1) = (i.saturating_sub(1), (i + 1).min(self.width - 1));
        let (j0, j1) = (j.saturating_sub(1), (j + 1).min(self.height - 1));
        let dzdx = (self.sample(i1, j) - self.sample(i0, j)) / (self.step[0] * (i1 - i0) as f32);
        let dzdy = (self.sample(i, j1) - self.sample(i, j0)) / (self.step[1] * (j1 - j0) as f32);
        glam::Vec3::new(-dzdx, -dzdy, 1.0).normalize().to_array()
    }
}

/// A fixed-capacity traversal stack: a descent pushes at most 4 nodes per level and a grid of
/// u32 cells has at most 33 levels, so 4·33 entries never overflow.
struct Stack {
    items: [Node; 4 * 33],
    len: usize,
}

impl Stack {
    fn new() -> Self {
        Stack {
            items: [Node::default(); 4 * 33],
            len: 0,
        }
    }
    #[inline]
    fn push(&mut self, n: Node) {
        self.items[self.len] = n;
        self.len += 1;
    }
    #[inline]
    fn pop(&mut self) -> Option<Node> {
        self.len = self.len.checked_sub(1)?;
        Some(self.items[self.len])
    }
}

#[cfg(test)]
mod tests;
