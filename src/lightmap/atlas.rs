//! A unique light-map atlas for a mesh whose own UVs repeat or overlap (seed 001, done properly).
//!
//! 1. Charts: edge-adjacent triangles (positions welded, so split vertices still connect) are
//!    grown greedily from a seed while their face normal stays within a cone around the seed's
//!    normal; the chart is projected orthographically onto the seed's plane. Every triangle in a
//!    chart faces the seed (n·n₀ ≥ cos θ > 0), so projection never flips one, and a triangle whose
//!    projection would overlap the chart's (a surface curling back) starts a chart of its own.
//! 2. Packing: one texel density (texels per model unit) for the whole mesh, so texel density is
//!    proportional to surface area (up to the projection's cos θ); chart rectangles with a gutter of
//!    `gutter` texels on every side are packed by a shelf packer into a square tile; the density
//!    shrinks until everything fits, the tile doubles if even tiny charts do not fit.
//! 3. Vertices: a mesh vertex used by triangles of two charts needs two atlas coordinates, so the
//!    atlas has its own vertex list (`vertex_source` = the mesh vertex, `uv` in tile space [0, 1]²,
//!    v = 0 at the top row) and its own index list (triangle order = the mesh's).
//! 4. G-buffer: [`rasterize`] covers every texel whose square touches a triangle (conservative:
//!    texel centres within ½√2 texel of the triangle), positions clamped onto the triangle.

use crate::model::Mesh;
use glam::{Vec2, Vec3A};
use std::collections::{HashMap, VecDeque};

/// How the atlas is laid out.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AtlasOptions {
    /// Texels per side of the tile (grown by doubling up to 4096 if the charts do not fit).
    pub tile: u32,
    /// Texels of padding on every side of a chart (≥ 1 for bilinear sampling).
    pub gutter: u32,
    /// Cosine of the normal-cone half angle of a chart.
    pub cone_cos: f32,
    /// Most triangles in one chart (bounds the overlap test's cost).
    pub max_chart_triangles: usize,
}

impl AtlasOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: AtlasOptions = AtlasOptions {
        tile: 64,
        gutter: 2,
        cone_cos: 0.866,
        max_chart_triangles: 256,
    };
}

impl Default for AtlasOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A chart's rectangle in the tile, in texels (gutters included).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChartRect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

/// The atlas of one mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct AtlasLayout {
    pub tile: u32,
    pub gutter: u32,
    /// Texels per model unit.
    pub density: f32,
    pub charts: Vec<ChartRect>,
    /// Chart of every mesh triangle.
    pub triangle_chart: Vec<u32>,
    /// Mesh vertex of every atlas vertex.
    pub vertex_source: Vec<u32>,
    /// Tile-space coordinates of every atlas vertex, [0, 1]², v = 0 at the top row.
    pub uv: Vec<[f32; 2]>,
    /// The mesh's triangles over atlas vertices.
    pub indices: Vec<[u32; 3]>,
}

/// A chart before packing: its triangles and their corners in the projection plane.
struct Chart2d {
    triangles: Vec<u32>,
    corners: Vec<[Vec2; 3]>,
}

/// Unit face normal (zero for a degenerate triangle) and area of every triangle.
fn faces(mesh: &Mesh) -> Vec<(Vec3A, f32)> {
    mesh.indices
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| Vec3A::from(mesh.positions[i as usize]));
            let n = (b - a).cross(c - a);
            let len = n.length();
            if len > 1e-12 && len.is_finite() {
                (n / len, 0.5 * len)
            } else {
                (Vec3A::ZERO, 0.0)
            }
        })
        .collect()
}

/// Edge neighbours of every triangle over welded positions, sorted.
fn adjacency(mesh: &Mesh) -> Vec<Vec<u32>> {
    let key = |p: [f32; 3]| p.map(|x| if x == 0.0 { 0 } else { x.to_bits() });
    let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
    let ids: Vec<u32> = mesh
        .positions
        .iter()
        .map(|&p| {
            let n = weld.len() as u32;
            *weld.entry(key(p)).or_insert(n)
        })
        .collect();
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (t, tri) in mesh.indices.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (ids[tri[k] as usize], ids[tri[(k + 1) % 3] as usize]);
            if a != b {
                edges
                    .entry((a.min(b), a.max(b)))
                    .or_default()
                    .push(t as u32);
            }
        }
    }
    let mut nb = vec![Vec::new(); mesh.indices.len()];
    for tris in edges.values() {
        for &a in tris {
            nb[a as usize].extend(tris.iter().copied().filter(|&b| b != a));
        }
    }
    for l in &mut nb {
        l.sort_unstable();
        l.dedup();
    }
    nb
}

/// Whether two 2D triangles overlap by more than a touch (separating axis test).
fn overlap(a: &[Vec2; 3], b: &[Vec2; 3]) -> bool {
    let scale = a
        .iter()
        .chain(b)
        .fold(0.0f32, |m, p| m.max(p.abs().max_element()));
    let eps = 1e-5 * scale.max(1e-6);
    for tri in [a, b] {
        for k in 0..3 {
            let e = tri[(k + 1) % 3] - tri[k];
            let axis = Vec2::new(-e.y, e.x);
            if axis.length_squared() == 0.0 {
                continue;
            }
            let axis = axis.normalize();
            let span = |t: &[Vec2; 3]| {
                t.iter()
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
                        let d = p.dot(axis);
                        (lo.min(d), hi.max(d))
                    })
            };
            let (alo, ahi) = span(a);
            let (blo, bhi) = span(b);
            if ahi <= blo + eps || bhi <= alo + eps {
                return false;
            }
        }
    }
    true
}

/// Charts by normal-cone growth over edge neighbours (see the file comment).
fn grow_charts(mesh: &Mesh, opts: &AtlasOptions) -> Vec<Chart2d> {
    let faces = faces(mesh);
    let nb = adjacency(mesh);
    let mut chart_of = vec![u32::MAX; mesh.indices.len()];
    let mut charts = Vec::new();
    for seed in 0..mesh.indices.len() {
        if chart_of[seed] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let n0 = if faces[seed].1 > 0.0 {
            faces[seed].0
        } else {
            Vec3A::Z
        };
        let (tx, bx) = crate::trace::frame(n0);
        let project = |t: usize| {
            mesh.indices[t].map(|i| {
                let p = Vec3A::from(mesh.positions[i as usize]);
                Vec2::new(p.dot(tx), p.dot(bx))
            })
        };
        let mut chart = Chart2d {
            triangles: vec![seed as u32],
            corners: vec![project(seed)],
        };
        chart_of[seed] = id;
        let mut queue: VecDeque<u32> = nb[seed].iter().copied().collect();
        while let Some(t) = queue.pop_front() {
            let t = t as usize;
            if chart_of[t] != u32::MAX
                || chart.triangles.len() >= opts.max_chart_triangles
                || faces[seed].1 == 0.0
                || faces[t].1 == 0.0
                || faces[t].0.dot(n0) < opts.cone_cos
            {
                continue;
            }
            let c = project(t);
            if chart.corners.iter().any(|o| overlap(o, &c)) {
                continue;
            }
            chart_of[t] = id;
            chart.triangles.push(t as u32);
            chart.corners.push(c);
            queue.extend(
                nb[t]
                    .iter()
                    .copied()
                    .filter(|&u| chart_of[u as usize] == u32::MAX),
            );
        }
        charts.push(chart);
    }
    charts
}

/// Bounds of a chart's projected corners.
fn chart_bounds(c: &Chart2d) -> (Vec2, Vec2) {
    c.corners.iter().flatten().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// Rectangle sizes (gutters included) of the charts at a density.
fn rect_sizes(bounds: &[(Vec2, Vec2)], density: f32, gutter: u32) -> Vec<(u32, u32)> {
    bounds
        .iter()
        .map(|(lo, hi)| {
            // One texel of slack on each side of the footprint for conservative coverage.
            let size = (*hi - *lo) * density;
            let w = size.x.ceil().max(0.0) as u32 + 2 + 2 * gutter;
            let h = size.y.ceil().max(0.0) as u32 + 2 + 2 * gutter;
            (w, h)
        })
        .collect()
}

/// Shelf packing, tallest first; `None` if the rectangles do not fit in a `tile`² square.
fn shelf_pack(sizes: &[(u32, u32)], tile: u32) -> Option<Vec<ChartRect>> {
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| sizes[b].1.cmp(&sizes[a].1).then(a.cmp(&b)));
    let mut rects = vec![
        ChartRect {
            x: 0,
            y: 0,
            w: 0,
            h: 0
        };
        sizes.len()
    ];
    let (mut x, mut y, mut shelf_h) = (0u32, 0u32, 0u32);
    for i in order {
        let (w, h) = sizes[i];
        if w > tile {
            return None;
        }
        if x + w > tile {
            y += shelf_h;
            x = 0;
            shelf_h = 0;
        }
        if y + h > tile {
            return None;
        }
        rects[i] = ChartRect { x, y, w, h };
        x += w;
        shelf_h = shelf_h.max(h);
    }
    Some(rects)
}

/// Largest tile side (texels) an atlas may grow to.
pub const MAX_TILE: u32 = 4096;

/// Finds the tile size and density at which the charts fit, if any tile up to [`MAX_TILE`] does.
fn fit(
    bounds: &[(Vec2, Vec2)],
    area: f32,
    opts: &AtlasOptions,
) -> Option<(u32, f32, Vec<ChartRect>)> {
    let mut tile = opts.tile.clamp(4, MAX_TILE);
    loop {
        // Start where the charts would fill about 60 % of the tile, shrink by 8 % steps.
        let mut density = (0.6 * (tile as f32).powi(2) / area.max(1e-12)).sqrt();
        for _ in 0..80 {
            if let Some(r) = shelf_pack(&rect_sizes(bounds, density, opts.gutter), tile) {
                return Some((tile, density, r));
            }
            density *= 0.92;
        }
        if tile >= MAX_TILE {
            return None;
        }
        tile = (tile * 2).min(MAX_TILE);
    }
}

/// Builds the atlas of a mesh; an error if its charts do not fit a [`MAX_TILE`]² tile.
pub fn build_atlas(mesh: &Mesh, opts: &AtlasOptions) -> Result<AtlasLayout, String> {
    let charts = grow_charts(mesh, opts);
    let bounds: Vec<(Vec2, Vec2)> = charts.iter().map(chart_bounds).collect();
    let area: f32 = faces(mesh).iter().map(|f| f.1).sum();
    let (tile, density, rects) = fit(&bounds, area, opts).ok_or_else(|| {
        format!(
            "{} charts do not fit a {MAX_TILE}² light-map tile with {}-texel gutters",
            charts.len(),
            opts.gutter
        )
    })?;
    let mut triangle_chart = vec![0u32; mesh.indices.len()];
    let mut corner_uv = vec![[[0.0f32; 2]; 3]; mesh.indices.len()];
    for (c, chart) in charts.iter().enumerate() {
        let r = rects[c];
        let origin = Vec2::new(
            (r.x + opts.gutter + 1) as f32,
            (r.y + opts.gutter + 1) as f32,
        );
        for (k, &t) in chart.triangles.iter().enumerate() {
            triangle_chart[t as usize] = c as u32;
            corner_uv[t as usize] = chart.corners[k]
                .map(|p| ((origin + (p - bounds[c].0) * density) / tile as f32).to_array());
        }
    }
    let mut atlas_vertex: HashMap<(u32, u32), u32> = HashMap::new();
    let (mut vertex_source, mut uv, mut indices) = (Vec::new(), Vec::new(), Vec::new());
    for (t, tri) in mesh.indices.iter().enumerate() {
        let chart = triangle_chart[t];
        indices.push([0, 1, 2].map(|k| {
            *atlas_vertex.entry((tri[k], chart)).or_insert_with(|| {
                vertex_source.push(tri[k]);
                uv.push(corner_uv[t][k]);
                (uv.len() - 1) as u32
            })
        }));
    }
    Ok(AtlasLayout {
        tile,
        gutter: opts.gutter,
        density,
        charts: rects,
        triangle_chart,
        vertex_source,
        uv,
        indices,
    })
}

impl AtlasLayout {
    /// The light-map UV of every mesh vertex when no vertex was split (every mesh vertex lies in
    /// one chart): a renderer can then draw the mesh's own index buffer with this second UV set.
    pub fn uv_per_mesh_vertex(&self, mesh_vertices: usize) -> Option<Vec<[f32; 2]>> {
        if self.vertex_source.len() != mesh_vertices {
            return None;
        }
        let mut out = vec![[f32::NAN; 2]; mesh_vertices];
        for (&src, &uv) in self.vertex_source.iter().zip(&self.uv) {
            out.get_mut(src as usize).map(|o| *o = uv)?;
        }
        out.iter().all(|u| !u[0].is_nan()).then_some(out)
    }

    /// The mesh with its vertices split like the atlas' (attributes gathered through
    /// `vertex_source`, the atlas' indices) and the light-map UV of every vertex of it.
    pub fn split_mesh(&self, mesh: &Mesh) -> Result<(Mesh, Vec<[f32; 2]>), String> {
        let n = mesh.positions.len();
        if self.vertex_source.iter().any(|&v| v as usize >= n)
            || self.indices.len() != mesh.indices.len()
        {
            return Err("the atlas does not belong to this mesh".into());
        }
        let gather = |a: &[[f32; 3]]| self.vertex_source.iter().map(|&v| a[v as usize]).collect();
        let out = Mesh {
            positions: gather(&mesh.positions),
            normals: gather(&mesh.normals),
            uvs: self
                .vertex_source
                .iter()
                .map(|&v| mesh.uvs[v as usize])
                .collect(),
            indices: self.indices.clone(),
            ..mesh.clone()
        };
        Ok((out, self.uv.clone()))
    }
}

/// One covered texel of the G-buffer: a surface point in model space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GTexel {
    pub position: Vec3A,
    /// Interpolated vertex normal (unit; the face normal where it degenerates).
    pub normal: Vec3A,
    pub chart: u32,
    /// Distance (texels) from the texel centre to the triangle; 0 inside.
    distance: f32,
}

/// Closest point to `p` on segment ab.
fn closest_on_segment(p: Vec2, a: Vec2, b: Vec2) -> Vec2 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-20)).clamp(0.0, 1.0);
    a + ab * t
}

/// Barycentric coordinates of p in triangle (a, b, c) (2D, non-degenerate).
fn barycentric(p: Vec2, a: Vec2, b: Vec2, c: Vec2) -> [f32; 3] {
    let d = (b - a).perp_dot(c - a);
    let l1 = (p - a).perp_dot(c - a) / d;
    let l2 = (b - a).perp_dot(p - a) / d;
    [1.0 - l1 - l2, l1, l2]
}

/// The texel of the G-buffer that triangle `t` gives at texel centre `q`, if it covers it.
fn texel_of(mesh: &Mesh, layout: &AtlasLayout, t: usize, q: Vec2) -> Option<GTexel> {
    let tile = layout.tile as f32;
    let [a, b, c] = layout.indices[t].map(|v| Vec2::from(layout.uv[v as usize]) * tile);
    // NaN (a mesh with non-finite positions) is rejected too.
    let area2 = (b - a).perp_dot(c - a).abs();
    if area2.is_nan() || area2 < 1e-9 {
        return None;
    }
    let l = barycentric(q, a, b, c);
    let (point, distance) = if l.iter().all(|&x| x >= 0.0) {
        (q, 0.0)
    } else {
        let cands = [
            closest_on_segment(q, a, b),
            closest_on_segment(q, b, c),
            closest_on_segment(q, c, a),
        ];
        let best = cands
            .into_iter()
            .min_by(|x, y| x.distance_squared(q).total_cmp(&y.distance_squared(q)))?;
        (best, best.distance(q))
    };
    if distance.is_nan() || distance > std::f32::consts::FRAC_1_SQRT_2 {
        return None;
    }
    let l = barycentric(point, a, b, c).map(|x| x.clamp(0.0, 1.0));
    let tri = mesh.indices[t].map(|i| i as usize);
    let position = tri.iter().zip(l).fold(Vec3A::ZERO, |s, (&i, w)| {
        s + Vec3A::from(mesh.positions[i]) * w
    });
    let n = tri.iter().zip(l).fold(Vec3A::ZERO, |s, (&i, w)| {
        s + Vec3A::from(mesh.normals[i]) * w
    });
    let [p0, p1, p2] = tri.map(|i| Vec3A::from(mesh.positions[i]));
    let normal = n
        .try_normalize()
        .or_else(|| (p1 - p0).cross(p2 - p0).try_normalize())
        .unwrap_or(Vec3A::Z);
    Some(GTexel {
        position,
        normal,
        chart: layout.triangle_chart[t],
        distance,
    })
}

/// The G-buffer of a tile (row-major, `tile`²): the surface point of every covered texel.
/// Where triangles compete for a texel the nearest wins (the lower triangle index on ties).
pub fn rasterize(mesh: &Mesh, layout: &AtlasLayout) -> Vec<Option<GTexel>> {
    let n = layout.tile as usize;
    let mut g: Vec<Option<GTexel>> = vec![None; n * n];
    for t in 0..layout.indices.len() {
        let pts = layout.indices[t].map(|v| Vec2::from(layout.uv[v as usize]) * n as f32);
        let lo = pts[0].min(pts[1]).min(pts[2]) - Vec2::ONE;
        let hi = pts[0].max(pts[1]).max(pts[2]) + Vec2::ONE;
        let r = layout.charts[layout.triangle_chart[t] as usize];
        let x0 = (lo.x.floor().max(r.x as f32)) as usize;
        let y0 = (lo.y.floor().max(r.y as f32)) as usize;
        let x1 = (hi.x.ceil() as usize).min((r.x + r.w) as usize).min(n);
        let y1 = (hi.y.ceil() as usize).min((r.y + r.h) as usize).min(n);
        for y in y0..y1 {
            for x in x0..x1 {
                let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                if let Some(s) = texel_of(mesh, layout, t, q) {
                    let slot = &mut g[y * n + x];
                    if slot.is_none_or(|o| s.distance < o.distance) {
                        *slot = Some(s);
                    }
                }
            }
        }
    }
    g
}

/// Fills the gutters: `rounds` times, every empty texel inside a chart's rectangle that has
/// filled 8-neighbours in the same rectangle takes their mean (double-buffered, so the result
/// does not depend on the visiting order). Returns how many texels were filled.
pub fn dilate(
    texels: &mut [[f32; 3]],
    filled: &mut [bool],
    layout: &AtlasLayout,
    rounds: u32,
) -> u64 {
    let n = layout.tile as i64;
    let mut count = 0;
    for _ in 0..rounds {
        let (prev, prev_filled) = (texels.to_vec(), filled.to_vec());
        for r in &layout.charts {
            for y in r.y as i64..(r.y + r.h) as i64 {
                for x in r.x as i64..(r.x + r.w) as i64 {
                    let i = (y * n + x) as usize;
                    if prev_filled[i] {
                        continue;
                    }
                    let (mut s, mut k) = ([0.0f32; 3], 0);
                    for (dx, dy) in NEIGHBOURS {
                        let (u, v) = (x + dx, y + dy);
                        let inside = u >= r.x as i64
                            && v >= r.y as i64
                            && u < (r.x + r.w) as i64
                            && v < (r.y + r.h) as i64;
                        if inside && prev_filled[(v * n + u) as usize] {
                            let t = prev[(v * n + u) as usize];
                            s = [s[0] + t[0], s[1] + t[1], s[2] + t[2]];
                            k += 1;
                        }
                    }
                    if k > 0 {
                        texels[i] = s.map(|c| c / k as f32);
                        filled[i] = true;
                        count += 1;
                    }
                }
            }
        }
    }
    count
}

const NEIGHBOURS: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube, 4 vertices per side (like the 3DS boxes), or welded (8 shared vertices).
    pub(crate) fn cube(welded: bool) -> Mesh {
        let mut m = Mesh::default();
        let corner = |i: u32| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32];
        let sides: [[u32; 4]; 6] = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        if welded {
            m.positions = (0..8).map(corner).collect();
            m.normals = m.positions.clone();
        }
        for s in sides {
            let v = if welded {
                s
            } else {
                let b = m.positions.len() as u32;
                for c in s {
                    m.positions.push(corner(c));
                }
                [b, b + 1, b + 2, b + 3]
            };
            m.indices.push([v[0], v[1], v[2]]);
            m.indices.push([v[0], v[2], v[3]]);
        }
        if !welded {
            m.normals = vec![[0.0, 0.0, 1.0]; m.positions.len()];
        }
        m.uvs = vec![[0.0; 2]; m.positions.len()];
        m.triangle_materials = vec![0; m.indices.len()];
        m.materials = vec![Default::default()];
        m
    }

    fn tri_uv(l: &AtlasLayout, t: usize) -> [Vec2; 3] {
        l.indices[t].map(|v| Vec2::from(l.uv[v as usize]) * l.tile as f32)
    }

    #[test]
    fn cube_sides_become_six_charts_and_welded_vertices_split() {
        for welded in [false, true] {
            let m = cube(welded);
            let l = build_atlas(&m, &AtlasOptions::default()).unwrap();
            assert_eq!(l.charts.len(), 6, "welded {welded}");
            // 4 atlas vertices per side either way: the welded cube's 8 vertices split.
            assert_eq!(l.uv.len(), 24);
            for (a, &s) in l.vertex_source.iter().enumerate() {
                let t = l
                    .indices
                    .iter()
                    .position(|t| t.contains(&(a as u32)))
                    .unwrap();
                let k = l.indices[t].iter().position(|&v| v == a as u32).unwrap();
                assert_eq!(m.indices[t][k], s);
            }
        }
    }

    #[test]
    fn charts_are_isometric_and_do_not_overlap() {
        // Texel area of every triangle / world area = density² (flat sides: no projection loss).
        let m = cube(false);
        let l = build_atlas(&m, &AtlasOptions::default()).unwrap();
        for (t, f) in faces(&m).iter().enumerate() {
            let [a, b, c] = tri_uv(&l, t);
            let area = 0.5 * (b - a).perp_dot(c - a);
            assert!(area > 0.0, "triangle {t} flipped");
            assert!((area / f.1 / l.density.powi(2) - 1.0).abs() < 1e-3);
        }
        for i in 0..m.indices.len() {
            for j in 0..i {
                assert!(!overlap(&tri_uv(&l, i), &tri_uv(&l, j)), "{i} and {j}");
            }
        }
        // Rectangles are disjoint and inside the tile.
        for (i, a) in l.charts.iter().enumerate() {
            assert!(a.x + a.w <= l.tile && a.y + a.h <= l.tile);
            for b in &l.charts[..i] {
                let apart =
                    a.x + a.w <= b.x || b.x + b.w <= a.x || a.y + a.h <= b.y || b.y + b.h <= a.y;
                assert!(apart);
            }
        }
    }

    #[test]
    fn conservative_raster_covers_every_texel_a_triangle_touches() {
        // Brute force: a texel square touches a triangle iff some of 9×9 points of the square
        // lies inside (approximately); every such texel must be covered.
        let m = cube(true);
        let l = build_atlas(
            &m,
            &AtlasOptions {
                tile: 32,
                ..Default::default()
            },
        )
        .unwrap();
        let g = rasterize(&m, &l);
        let n = l.tile as usize;
        let mut touched = 0;
        for t in 0..m.indices.len() {
            let [a, b, c] = tri_uv(&l, t);
            for y in 0..n {
                for x in 0..n {
                    let hit = (0..81).any(|k| {
                        let q = Vec2::new(
                            x as f32 + (k % 9) as f32 / 8.0,
                            y as f32 + (k / 9) as f32 / 8.0,
                        );
                        barycentric(q, a, b, c).iter().all(|&w| w >= 1e-4)
                    });
                    if hit {
                        touched += 1;
                        assert!(g[y * n + x].is_some(), "texel ({x}, {y}) of triangle {t}");
                    }
                }
            }
        }
        assert!(touched > 6 * 4);
    }

    #[test]
    fn charts_that_fit_no_tile_are_an_error() {
        // Six charts of at least 2 + 2·1000 texels: four fit a 4096² tile, six do not.
        let opts = AtlasOptions {
            gutter: 1000,
            ..Default::default()
        };
        let e = build_atlas(&cube(false), &opts).unwrap_err();
        assert!(e.contains("6 charts"), "{e}");
    }

    #[test]
    fn non_finite_positions_give_no_texels() {
        let mut m = cube(false);
        m.positions[0] = [f32::NAN, 0.0, 0.0];
        let l = build_atlas(&m, &AtlasOptions::default()).unwrap();
        let g = rasterize(&m, &l);
        assert!(g.iter().flatten().all(|t| t.position.is_finite()));
        assert!(g.iter().flatten().count() > 0);
    }

    #[test]
    fn split_mesh_keeps_every_triangle_and_per_vertex_uvs_only_without_splits() {
        let flat = cube(false);
        let l = build_atlas(&flat, &AtlasOptions::default()).unwrap();
        let per_vertex = l.uv_per_mesh_vertex(flat.positions.len()).unwrap();
        for (t, tri) in flat.indices.iter().enumerate() {
            for (k, &v) in tri.iter().enumerate() {
                assert_eq!(per_vertex[v as usize], l.uv[l.indices[t][k] as usize]);
            }
        }
        let welded = cube(true);
        let l = build_atlas(&welded, &AtlasOptions::default()).unwrap();
        assert!(l.uv_per_mesh_vertex(welded.positions.len()).is_none());
        let (m, uv) = l.split_mesh(&welded).unwrap();
        assert_eq!((m.positions.len(), uv.len()), (24, 24));
        m.validate().unwrap();
        for (t, tri) in welded.indices.iter().enumerate() {
            for (k, &v) in tri.iter().enumerate() {
                assert_eq!(
                    m.positions[m.indices[t][k] as usize],
                    welded.positions[v as usize]
                );
            }
        }
        assert!(l.split_mesh(&Mesh::default()).is_err());
    }

    #[test]
    fn overlapping_projection_starts_a_new_chart() {
        // Two coplanar, edge-connected triangles folded on top of each other (a zero-thickness
        // fold would be excluded by the cone; here the second is a flat triangle lying over the
        // first, sharing an edge, facing the same way).
        let mut m = Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.2, 0.2, 0.01],
            ],
            indices: vec![[0, 1, 2], [0, 1, 3]],
            ..Default::default()
        };
        m.normals = vec![[0.0, 0.0, 1.0]; 4];
        m.uvs = vec![[0.0; 2]; 4];
        let l = build_atlas(&m, &AtlasOptions::default()).unwrap();
        assert_eq!(l.charts.len(), 2);
        assert!(!overlap(&tri_uv(&l, 0), &tri_uv(&l, 1)));
    }

    #[test]
    fn dilation_fills_the_gutter_from_its_own_chart() {
        let m = cube(false);
        let l = build_atlas(&m, &AtlasOptions::default()).unwrap();
        let g = rasterize(&m, &l);
        let mut texels: Vec<[f32; 3]> = g
            .iter()
            .map(|t| t.map_or([0.0; 3], |t| [t.chart as f32 + 1.0; 3]))
            .collect();
        let mut filled: Vec<bool> = g.iter().map(|t| t.is_some()).collect();
        let n = dilate(&mut texels, &mut filled, &l, l.gutter + 1);
        assert!(n > 0);
        for (c, r) in l.charts.iter().enumerate() {
            for y in r.y..r.y + r.h {
                for x in r.x..r.x + r.w {
                    let i = (y * l.tile + x) as usize;
                    assert!(filled[i], "chart {c} texel ({x}, {y})");
                    assert_eq!(texels[i], [c as f32 + 1.0; 3]);
                }
            }
        }
    }
}
