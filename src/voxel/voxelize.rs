//! Conservative surface voxelization of triangle meshes, with an optional solid fill.
//!
//! A voxel is occupied when its closed box overlaps a triangle (separating-axis theorem,
//! Akenine-Möller 2001: 3 box normals, the triangle normal and 9 edge cross products). The fast
//! path evaluates the same 13 axes in the precomputed form of Schwarz & Seidel 2010 (plane test
//! plus three 2D edge-function projections) column by column along the triangle's dominant axis;
//! [`tri_box_overlap_reference`] is a direct port of Akenine-Möller's test kept as the oracle.
//!
//! Work is split into 64³-voxel buckets (a Morton prefix): triangles are binned by bounding box,
//! each bucket rasterizes its triangles (in index order) into a 32 KiB local bit set whose 64-bit
//! words are exactly 4³ bricks in Morton order, then accumulates attributes per occupied voxel.
//! Buckets are processed in parallel and concatenated in Morton order, so the output does not
//! depend on the thread count.

use super::{Grid, morton_encode};
use crate::error::{Error, Result};
use crate::model::{Mesh, Rgba8Image};
use rayon::prelude::*;

/// A 4³ block of voxels: Morton key of the brick (voxel key >> 6) and its occupancy mask
/// (bit `s` = voxel with Morton key `key << 6 | s`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Brick {
    pub key: u64,
    pub mask: u64,
}

/// Options of [`mesh_to_voxels`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelizeOptions {
    /// Voxels along the longest axis of the mesh bounds.
    pub resolution: u32,
    /// Also mark voxels whose centre lies inside the (closed) mesh.
    pub solid: bool,
    /// Texel alpha below this is a hole (alpha test, as the renderer does for leaves).
    pub alpha_cutoff: f32,
}

impl Default for VoxelizeOptions {
    /// Surface voxels at 256 along the longest axis (`bake svo`'s default).
    fn default() -> Self {
        Self::surface(256)
    }
}

impl VoxelizeOptions {
    /// Surface voxels at `resolution`, alpha test at 0.5.
    pub const fn surface(resolution: u32) -> Self {
        Self {
            resolution,
            solid: false,
            alpha_cutoff: 0.5,
        }
    }
}

/// Occupied voxels in Morton order with their attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct Voxels {
    pub grid: Grid,
    /// Non-empty bricks in increasing key order.
    pub bricks: Vec<Brick>,
    /// Per occupied voxel (Morton order): linear RGBA, straight alpha.
    pub colors: Vec<[f32; 4]>,
    /// Per occupied voxel: unit normal, or zero for interior (solid-fill) voxels.
    pub normals: Vec<[f32; 3]>,
    /// Triangles dropped because they lie outside the grid or are fully alpha-tested away.
    pub skipped_triangles: usize,
    /// Interior columns whose crossings did not pair up (the mesh is not closed there).
    pub open_columns: usize,
}

impl Voxels {
    /// Number of occupied voxels.
    pub fn count(&self) -> usize {
        self.colors.len()
    }

    /// Morton keys of all occupied voxels, increasing.
    pub fn keys(&self) -> Vec<u64> {
        keys_of_bricks(&self.bricks)
    }
}

/// Expands bricks to voxel Morton keys, increasing.
pub fn keys_of_bricks(bricks: &[Brick]) -> Vec<u64> {
    let mut out = Vec::new();
    for b in bricks {
        let mut m = b.mask;
        while m != 0 {
            out.push(b.key << 6 | m.trailing_zeros() as u64);
            m &= m - 1;
        }
    }
    out
}

/// Groups increasing voxel Morton keys into bricks (the inverse of [`keys_of_bricks`]).
pub fn bricks_of_keys(keys: impl IntoIterator<Item = u64>) -> Vec<Brick> {
    let mut bricks: Vec<Brick> = Vec::new();
    for k in keys {
        match bricks.last_mut() {
            Some(b) if b.key == k >> 6 => b.mask |= 1 << (k & 63),
            _ => bricks.push(Brick {
                key: k >> 6,
                mask: 1 << (k & 63),
            }),
        }
    }
    bricks
}

/// Per-triangle setup of the Schwarz–Seidel form of the 13-axis test, for unit voxels.
#[derive(Debug, Clone, Copy)]
pub struct TriSetup {
    /// Inclusive voxel bounding box (may extend outside the grid).
    pub lo: [i64; 3],
    pub hi: [i64; 3],
    n: [f32; 3],
    d1: f32,
    d2: f32,
    /// `edge_n[k][e]`: normal of edge e in the projection that drops axis k, on the axes
    /// ((k+1)%3, (k+2)%3); `edge_d[k][e]` its offset including the critical corner.
    edge_n: [[[f32; 2]; 3]; 3],
    edge_d: [[f32; 3]; 3],
    /// Axis of the largest normal component: voxels are walked in columns along it.
    dominant: usize,
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl TriSetup {
    /// Sets up a triangle given in voxel units.
    pub fn new(v: [[f32; 3]; 3]) -> TriSetup {
        Self::with_box(v, 1.0)
    }

    /// As [`Self::new`] against voxels grown by `eps` on every side (a conservative margin for
    /// callers that must not lose a voxel to rounding).
    pub fn padded(v: [[f32; 3]; 3], eps: f32) -> TriSetup {
        Self::with_box(v.map(|p| p.map(|x| x + eps)), 1.0 + 2.0 * eps)
    }

    /// The test against boxes [p, p + dp] (Schwarz & Seidel's Δp).
    fn with_box(v: [[f32; 3]; 3], dp: f32) -> TriSetup {
        let n = cross(sub(v[1], v[0]), sub(v[2], v[0]));
        let c = n.map(|x| if x > 0.0 { dp } else { 0.0 });
        let d1 = dot(n, sub(c, v[0]));
        let d2 = dot(n, sub(c.map(|x| dp - x), v[0]));
        let mut edge_n = [[[0.0; 2]; 3]; 3];
        let mut edge_d = [[0.0; 3]; 3];
        for k in 0..3 {
            let (a, b) = ((k + 1) % 3, (k + 2) % 3);
            let sign = if n[k] >= 0.0 { 1.0 } else { -1.0 };
            for e in 0..3 {
                let p = v[e];
                let q = v[(e + 1) % 3];
                let ne = [-(q[b] - p[b]) * sign, (q[a] - p[a]) * sign];
                edge_n[k][e] = ne;
                edge_d[k][e] =
                    -(ne[0] * p[a] + ne[1] * p[b]) + (dp * ne[0]).max(0.0) + (dp * ne[1]).max(0.0);
            }
        }
        let lo = [0, 1, 2].map(|k| {
            let m = v[0][k].min(v[1][k]).min(v[2][k]);
            ceil_i64(m - dp)
        });
        let hi = [0, 1, 2].map(|k| floor_i64(v[0][k].max(v[1][k]).max(v[2][k])));
        let a = n.map(f32::abs);
        let dominant = if a[0] >= a[1] && a[0] >= a[2] {
            0
        } else if a[1] >= a[2] {
            1
        } else {
            2
        };
        TriSetup {
            lo,
            hi,
            n,
            d1,
            d2,
            edge_n,
            edge_d,
            dominant,
        }
    }

    fn edges_pass(&self, k: usize, pa: f32, pb: f32) -> bool {
        (0..3).all(|e| {
            let ne = self.edge_n[k][e];
            ne[0] * pa + ne[1] * pb + self.edge_d[k][e] >= 0.0
        })
    }

    fn plane_pass(&self, p: [f32; 3]) -> bool {
        let np = dot(self.n, p);
        (np + self.d1) * (np + self.d2) <= 0.0
    }

    /// Whether the closed unit voxel with minimum corner `p` overlaps the triangle.
    pub fn overlaps(&self, p: [i64; 3]) -> bool {
        if (0..3).any(|k| p[k] < self.lo[k] || p[k] > self.hi[k]) {
            return false;
        }
        let f = p.map(|x| x as f32);
        self.plane_pass(f) && (0..3).all(|k| self.edges_pass(k, f[(k + 1) % 3], f[(k + 2) % 3]))
    }

    /// Calls `visit` for every overlapped voxel inside the inclusive range `lo..=hi`, walking
    /// columns along the dominant axis so the plane bounds each column's extent.
    pub fn for_each_voxel(&self, lo: [i64; 3], hi: [i64; 3], mut visit: impl FnMut([i64; 3])) {
        let c = self.dominant;
        let (a, b) = ((c + 1) % 3, (c + 2) % 3);
        let lo = [0, 1, 2].map(|k| lo[k].max(self.lo[k]));
        let hi = [0, 1, 2].map(|k| hi[k].min(self.hi[k]));
        for ia in lo[a]..=hi[a] {
            for ib in lo[b]..=hi[b] {
                let (fa, fb) = (ia as f32, ib as f32);
                if !self.edges_pass(c, fa, fb) {
                    continue;
                }
                let (c0, c1) = self.column_range(a, b, c, fa, fb, lo[c], hi[c]);
                for ic in c0..=c1 {
                    let mut p = [0i64; 3];
                    p[a] = ia;
                    p[b] = ib;
                    p[c] = ic;
                    let f = p.map(|x| x as f32);
                    if self.plane_pass(f)
                        && self.edges_pass(a, f[(a + 1) % 3], f[(a + 2) % 3])
                        && self.edges_pass(b, f[(b + 1) % 3], f[(b + 2) % 3])
                    {
                        visit(p);
                    }
                }
            }
        }
    }

    /// Range of voxels along axis c whose box can meet the plane in column (fa, fb); widened by
    /// one voxel on each side against rounding (the exact plane test runs per voxel anyway).
    #[allow(clippy::too_many_arguments)]
    fn column_range(
        &self,
        a: usize,
        b: usize,
        c: usize,
        fa: f32,
        fb: f32,
        lo: i64,
        hi: i64,
    ) -> (i64, i64) {
        let nc = self.n[c];
        if nc == 0.0 {
            return (lo, hi);
        }
        let s = self.n[a] * fa + self.n[b] * fb;
        let r1 = -(s + self.d1) / nc;
        let r2 = -(s + self.d2) / nc;
        let (r0, r1) = (r1.min(r2), r1.max(r2));
        let c0 = (floor_i64(r0) - 1).max(lo);
        let c1 = (ceil_i64(r1) + 1).min(hi);
        (c0, c1)
    }
}

/// Akenine-Möller's triangle/box overlap test (2001), closed: touching counts as overlap.
/// `center`, `half`: the box; `tri`: the vertices. The slow oracle of [`TriSetup`].
pub fn tri_box_overlap_reference(center: [f64; 3], half: [f64; 3], tri: [[f64; 3]; 3]) -> bool {
    let v = tri.map(|p| [p[0] - center[0], p[1] - center[1], p[2] - center[2]]);
    let e = [0, 1, 2].map(|i| {
        let (p, q) = (v[i], v[(i + 1) % 3]);
        [q[0] - p[0], q[1] - p[1], q[2] - p[2]]
    });
    let proj = |axis: [f64; 3]| -> bool {
        let p = v.map(|x| axis[0] * x[0] + axis[1] * x[1] + axis[2] * x[2]);
        let r = half[0] * axis[0].abs() + half[1] * axis[1].abs() + half[2] * axis[2].abs();
        let (mn, mx) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        mn > r || mx < -r
    };
    // 9 edge cross-product axes a_ij = u_i × e_j.
    for ej in e {
        for ui in 0..3 {
            let mut u = [0.0; 3];
            u[ui] = 1.0;
            let axis = [
                u[1] * ej[2] - u[2] * ej[1],
                u[2] * ej[0] - u[0] * ej[2],
                u[0] * ej[1] - u[1] * ej[0],
            ];
            if proj(axis) {
                return false;
            }
        }
    }
    // Box normals: the triangle's AABB against the box.
    for k in 0..3 {
        let mn = v[0][k].min(v[1][k]).min(v[2][k]);
        let mx = v[0][k].max(v[1][k]).max(v[2][k]);
        if mn > half[k] || mx < -half[k] {
            return false;
        }
    }
    // Triangle normal.
    let n = [
        e[0][1] * e[1][2] - e[0][2] * e[1][1],
        e[0][2] * e[1][0] - e[0][0] * e[1][2],
        e[0][0] * e[1][1] - e[0][1] * e[1][0],
    ];
    !proj(n)
}

/// Side of a bucket in voxels (a 6-bit-per-axis Morton prefix).
const BUCKET_SHIFT: u32 = 6;
const BUCKET: i64 = 1 << BUCKET_SHIFT;
const BUCKET_WORDS: usize = 1 << (3 * BUCKET_SHIFT - 6);
// [`local_index`] spreads 6-bit coordinates.
const _: () = assert!(BUCKET_SHIFT == 6);

/// Bins triangles (voxel units) into 64³ buckets: sorted (bucket Morton key, triangle) pairs.
fn bin_triangles(grid: &Grid, setups: &[TriSetup]) -> Vec<(u64, u32)> {
    let dims = grid.dims.map(|d| d as i64);
    let mut pairs: Vec<(u64, u32)> = setups
        .par_iter()
        .enumerate()
        .flat_map_iter(|(t, s)| {
            let lo = [0, 1, 2].map(|k| s.lo[k].max(0));
            let hi = [0, 1, 2].map(|k| s.hi[k].min(dims[k] - 1));
            let empty = (0..3).any(|k| lo[k] > hi[k]);
            let (bl, bh) = if empty {
                ([1; 3], [0; 3])
            } else {
                (lo.map(|x| x / BUCKET), hi.map(|x| x / BUCKET))
            };
            let mut out = Vec::new();
            for z in bl[2]..=bh[2] {
                for y in bl[1]..=bh[1] {
                    for x in bl[0]..=bh[0] {
                        out.push((morton_encode([x as u32, y as u32, z as u32]), t as u32));
                    }
                }
            }
            out
        })
        .collect();
    pairs.par_sort_unstable();
    pairs
}

/// Groups sorted pairs into (bucket key, triangles) runs.
fn group_buckets(pairs: &[(u64, u32)]) -> Vec<(u64, &[(u64, u32)])> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=pairs.len() {
        if i == pairs.len() || pairs[i].0 != pairs[start].0 {
            out.push((pairs[start].0, &pairs[start..i]));
            start = i;
        }
    }
    out
}

/// Occupied voxels of a triangle soup (voxel units), as bricks: the geometry-only entry point
/// (used by the N-tree). `keep(t, voxel)` may reject a triangle's voxel (alpha test).
pub fn rasterize_bricks(
    grid: &Grid,
    setups: &[TriSetup],
    keep: &(dyn Fn(usize, [i64; 3]) -> bool + Sync),
) -> Vec<Brick> {
    let pairs = bin_triangles(grid, setups);
    let buckets = group_buckets(&pairs);
    buckets
        .par_iter()
        .flat_map_iter(|(key, tris)| {
            let words = bucket_words(grid, *key, tris, setups, keep);
            bricks_of_words(*key, &words)
        })
        .collect()
}

/// Inclusive voxel range of a bucket, clipped to the grid.
fn bucket_range(grid: &Grid, key: u64) -> ([i64; 3], [i64; 3]) {
    let b = super::morton_decode(key).map(|x| x as i64 * BUCKET);
    let hi = [0, 1, 2].map(|k| (b[k] + BUCKET - 1).min(grid.dims[k] as i64 - 1));
    (b, hi)
}

/// `floor` as an integer without a libm call (the baseline x86-64 target has no `roundss`);
/// saturates like `as`.
fn floor_i64(x: f32) -> i64 {
    let i = x as i64;
    if (i as f32) > x { i - 1 } else { i }
}

fn ceil_i64(x: f32) -> i64 {
    let i = x as i64;
    if (i as f32) < x { i + 1 } else { i }
}

/// Bits of a 6-bit coordinate spread to every third bit.
const SPREAD6: [u32; 64] = {
    let mut t = [0u32; 64];
    let mut i = 0;
    while i < 64 {
        let mut b = 0;
        while b < 6 {
            t[i] |= ((i as u32 >> b) & 1) << (3 * b);
            b += 1;
        }
        i += 1;
    }
    t
};

/// Local Morton index of a voxel inside its bucket.
fn local_index(p: [i64; 3]) -> usize {
    let m = (BUCKET - 1) as usize;
    (SPREAD6[p[0] as usize & m] | SPREAD6[p[1] as usize & m] << 1 | SPREAD6[p[2] as usize & m] << 2)
        as usize
}

fn bucket_words(
    grid: &Grid,
    key: u64,
    tris: &[(u64, u32)],
    setups: &[TriSetup],
    keep: &(dyn Fn(usize, [i64; 3]) -> bool + Sync),
) -> Vec<u64> {
    let (lo, hi) = bucket_range(grid, key);
    let mut words = vec![0u64; BUCKET_WORDS];
    for &(_, t) in tris {
        setups[t as usize].for_each_voxel(lo, hi, |p| {
            let i = local_index(p);
            if words[i >> 6] >> (i & 63) & 1 == 0 && keep(t as usize, p) {
                words[i >> 6] |= 1 << (i & 63);
            }
        });
    }
    words
}

fn bricks_of_words(bucket: u64, words: &[u64]) -> Vec<Brick> {
    let shift = 3 * BUCKET_SHIFT - 6;
    words
        .iter()
        .enumerate()
        .filter(|(_, w)| **w != 0)
        .map(|(i, &mask)| Brick {
            key: bucket << shift | i as u64,
            mask,
        })
        .collect()
}

/// Transforms a mesh's triangles into voxel units and sets them up.
pub fn setup_triangles(grid: &Grid, mesh: &Mesh) -> Vec<TriSetup> {
    mesh.indices
        .par_iter()
        .map(|t| TriSetup::new(t.map(|i| grid.to_grid(mesh.positions[i as usize]))))
        .collect()
}

/// Voxelizes a mesh. `textures[i]` is the decoded image of `mesh.textures[i]` (None: untextured).
pub fn mesh_to_voxels(
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    opts: &VoxelizeOptions,
) -> Result<Voxels> {
    mesh.validate().map_err(Error::Runtime)?;
    let (lo, hi) = mesh
        .bounds()
        .ok_or_else(|| Error::Runtime("the mesh has no vertices to voxelize".into()))?;
    let grid = Grid::fit(lo, hi, opts.resolution);
    mesh_to_voxels_in(mesh, textures, &grid, opts)
}

/// Voxelizes a mesh into a given grid (parts outside the grid are clipped).
pub fn mesh_to_voxels_in(
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    grid: &Grid,
    opts: &VoxelizeOptions,
) -> Result<Voxels> {
    let setups = setup_triangles(grid, mesh);
    let shade = super::voxelize_shade::Shader::new(mesh, textures, grid, opts.alpha_cutoff);
    let pairs = bin_triangles(grid, &setups);
    let buckets = group_buckets(&pairs);
    let parts: Vec<BucketOut> = buckets
        .par_iter()
        .map(|(key, tris)| shade_bucket(grid, *key, tris, &setups, &shade))
        .collect();
    let mut v = Voxels {
        grid: *grid,
        bricks: Vec::new(),
        colors: Vec::new(),
        normals: Vec::new(),
        skipped_triangles: 0,
        open_columns: 0,
    };
    for p in parts {
        v.bricks.extend(p.bricks);
        v.colors.extend(p.colors);
        v.normals.extend(p.normals);
    }
    let mut used = vec![false; setups.len()];
    for &(_, t) in &pairs {
        used[t as usize] = true;
    }
    v.skipped_triangles = used.iter().filter(|u| !**u).count()
        + (0..setups.len())
            .filter(|&t| used[t] && !shade.triangle_visible(t))
            .count();
    if opts.solid {
        super::voxelize_shade::fill_interior(&mut v, mesh, &shade)?;
    }
    Ok(v)
}

struct BucketOut {
    bricks: Vec<Brick>,
    colors: Vec<[f32; 4]>,
    normals: Vec<[f32; 3]>,
}

/// Occupancy, then per-voxel attributes accumulated over the bucket's triangles in index order.
fn shade_bucket(
    grid: &Grid,
    key: u64,
    tris: &[(u64, u32)],
    setups: &[TriSetup],
    shade: &super::voxelize_shade::Shader,
) -> BucketOut {
    let keep = |t: usize, p: [i64; 3]| shade.alpha_passes(t, p);
    let words = bucket_words(grid, key, tris, setups, &keep);
    // rank[w] = occupied voxels before word w.
    let mut rank = Vec::with_capacity(words.len());
    let mut total = 0usize;
    for w in &words {
        rank.push(total);
        total += w.count_ones() as usize;
    }
    let mut acc = vec![[0.0f32; 8]; total];
    let (lo, hi) = bucket_range(grid, key);
    for &(_, t) in tris {
        setups[t as usize].for_each_voxel(lo, hi, |p| {
            if let Some((c, n)) = shade.sample(t as usize, p) {
                let i = local_index(p);
                let below = words[i >> 6] & ((1u64 << (i & 63)) - 1);
                let a = &mut acc[rank[i >> 6] + below.count_ones() as usize];
                for k in 0..4 {
                    a[k] += c[k];
                }
                for k in 0..3 {
                    a[4 + k] += n[k];
                }
                a[7] += 1.0;
            }
        });
    }
    BucketOut {
        bricks: bricks_of_words(key, &words),
        colors: acc
            .iter()
            .map(|a| [0, 1, 2, 3].map(|k| a[k] / a[7].max(1.0)))
            .collect(),
        normals: acc
            .iter()
            .map(|a| super::voxelize_shade::normalize([a[4], a[5], a[6]]))
            .collect(),
    }
}
