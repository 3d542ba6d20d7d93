//! The simplification chain: meshoptimizer's attribute-aware simplifier for the surfaces and
//! an alpha-aware thinning of the leaf cards, one level per error target.
//!
//! Order matters:
//! 1. Vertices used by triangles of several materials are split ([`Prepared::new`]), so every
//!    vertex has one material and meshopt, which keeps the connectivity of its input, never
//!    builds a triangle across a material boundary (the boundaries become seams it preserves).
//! 2. Leaf cards are found before simplification: connected components of alpha-tested
//!    triangles (a material whose colour map has texels below the 0.5 alpha test) of at most
//!    `max_card_triangles` triangles. Each card gets a rank (a hash of its index), its
//!    alpha-weighted area A·α (α: the share of stratified samples of its UV footprint that pass
//!    the alpha test), its area-weighted centroid c and its radius R (largest |p − c|).
//! 3. Per target error e: meshopt (absolute error, no triangle target) on the triangles that
//!    are not cards, at e/2 where the model has cards, at e where it has none; its error e_m is
//!    the surface part of the bound. Cards keep their own triangles (a collapse moves their UVs
//!    and with them the alpha-tested shape, which the positional error does not see).
//! 4. The cards then keep the lowest-ranked prefix holding ≥ 1/g² of the alpha-weighted area,
//!    g = 1 + (e − e_m)/R_max, lengthened until every card it leaves out is within e − e_m of
//!    the kept ones: a point of a removed card lies within its radius R of its centre, the
//!    nearest kept centre is D away, so D + R bounds its distance from the level (the removal
//!    error e_r, the largest D + R; one-sided Hausdorff with centres for surfaces). Every kept
//!    card is scaled about c by g' = sqrt(total/kept) (≤ g), so the alpha-tested area stays
//!    (`coverage` reports it after simplification). A scaled point moves by (g' − 1)|p − c| ≤
//!    (g' − 1)·R, so the level's error is max(e_m + (g' − 1)·R_max of the kept cards, e_r).
//!    Coarser levels keep prefixes of the same ranking: their cards are subsets of the finer
//!    levels'. g is at most [`MAX_CARD_SCALE`] (4).
//!
//! Targets: e_l = `base_error` · `ratio`^(l−1) · radius (l = 1, 2, …; defaults 0.25 % of the
//! bounding radius, ratio 4: 0.25 %, 1 %, 4 %, 16 %, 64 %). A level is kept only when it has at
//! most `min_reduction` (0.8) of the previous level's triangles; the chain stops at `levels`
//! levels or at `max_error` (the impostor's error, where there is one): a level whose error
//! reaches it is dropped.

use super::section::{LodArrays, LodLevel, material_ranges};
use crate::model::{Mesh, Rgba8Image};
use crate::trace::bvh::AlphaMask;
use serde::{Deserialize, Serialize};

/// Largest enlargement of a kept card (so at least 1/16 of the alpha-weighted card area is kept
/// in every level: fewer, larger cards stop looking like foliage).
pub const MAX_CARD_SCALE: f32 = 4.0;

/// Options of the `lod` stage (the `[lod]` table of a pipeline).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LodOptions {
    /// Most mesh levels after level 0.
    pub levels: u32,
    /// First target error, relative to the bounding radius.
    pub base_error: f32,
    /// Ratio between consecutive targets.
    pub ratio: f32,
    /// A level must have at most this share of the previous level's triangles.
    pub min_reduction: f32,
    /// meshopt attribute weights of the unit normal and of the UVs (position error is in model
    /// units; the weights scale the attributes' error into the same units).
    pub normal_weight: f32,
    pub uv_weight: f32,
    /// Largest connected component of alpha-tested triangles treated as a leaf card.
    pub max_card_triangles: u32,
    /// Bake the impostor atlas (hemi-octahedral views, `impostor_grid`² of `impostor_tile`²
    /// texels).
    pub impostor: bool,
    pub impostor_grid: u32,
    pub impostor_tile: u32,
}

impl LodOptions {
    pub const DEFAULT: LodOptions = LodOptions {
        levels: 5,
        base_error: 0.0025,
        ratio: 4.0,
        min_reduction: 0.8,
        normal_weight: 0.5,
        uv_weight: 1.0,
        max_card_triangles: 64,
        impostor: true,
        impostor_grid: 8,
        impostor_tile: 64,
    };
    /// The preview pipeline: fewer, coarser levels and a smaller atlas.
    pub const fn preview() -> LodOptions {
        LodOptions {
            levels: 3,
            impostor_tile: 32,
            ..Self::DEFAULT
        }
    }
    /// The final pipeline: the default chain with a finer atlas.
    pub const fn final_quality() -> LodOptions {
        LodOptions {
            impostor_tile: 128,
            ..Self::DEFAULT
        }
    }
}

impl LodOptions {
    /// The ranges every option must lie in (a message naming the option otherwise).
    pub fn check(&self) -> Result<(), String> {
        let ok = [
            (
                self.base_error > 0.0 && self.base_error.is_finite(),
                "lod.base_error: expected > 0",
            ),
            (
                self.ratio > 1.0 && self.ratio.is_finite(),
                "lod.ratio: expected > 1",
            ),
            (
                self.min_reduction > 0.0 && self.min_reduction <= 1.0,
                "lod.min_reduction: expected in (0, 1]",
            ),
            (
                self.normal_weight >= 0.0 && self.uv_weight >= 0.0,
                "lod.normal_weight, lod.uv_weight: expected ≥ 0",
            ),
            (self.levels <= 16, "lod.levels: expected at most 16"),
            (
                (1..=64).contains(&self.impostor_grid)
                    && (1..=1024).contains(&self.impostor_tile)
                    && self.impostor_grid * self.impostor_tile <= 8192,
                "lod.impostor_grid 1..=64, lod.impostor_tile 1..=1024, their product at most 8192",
            ),
        ];
        match ok.iter().find(|(good, _)| !good) {
            Some((_, m)) => Err(m.to_string()),
            None => Ok(()),
        }
    }
}

impl Default for LodOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One leaf card of the prepared mesh.
#[derive(Debug, Clone)]
struct Card {
    rank: u64,
    /// Alpha-weighted area A·α.
    weight: f64,
    alpha: f64,
    centre: [f32; 3],
    radius: f32,
}

/// The mesh with material-split vertices, the cards and their bookkeeping.
pub struct Prepared {
    positions: Vec<[f32; 3]>,
    /// Normal (3) and UV (2) per vertex, for meshopt.
    attributes: Vec<f32>,
    /// Mesh vertex of every prepared vertex.
    source: Vec<u32>,
    vertex_material: Vec<u32>,
    indices: Vec<u32>,
    /// Card of every vertex (`u32::MAX`: none).
    vertex_card: Vec<u32>,
    cards: Vec<Card>,
    card_weight: f64,
}

/// One simplified level, vertices local to it.
#[derive(Debug, Clone, Default)]
pub struct Level {
    pub positions: Vec<[f32; 3]>,
    pub vertex_source: Vec<u32>,
    pub indices: Vec<[u32; 3]>,
    pub materials: Vec<u32>,
    pub error: f32,
    pub cards: u32,
    pub coverage: f32,
}

/// Whether each material is alpha-tested: its colour map has a texel below the alpha test.
pub fn alpha_masks(mesh: &Mesh, textures: &[Option<Rgba8Image>]) -> Vec<Option<AlphaMask>> {
    mesh.materials
        .iter()
        .map(|m| {
            let img = m
                .color_map
                .and_then(|i| textures.get(i as usize))?
                .as_ref()?;
            img.pixels
                .iter()
                .any(|p| p[3] < 128)
                .then(|| AlphaMask::from_rgba8(img))
        })
        .collect()
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn length(a: [f32; 3]) -> f32 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Area of a triangle.
pub fn area(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> f32 {
    let (u, v) = (sub(b, a), sub(c, a));
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    0.5 * length(n)
}

/// The stratified barycentric samples of the alpha estimate: the 16 cell centres of a 4×4 grid
/// over the unit square, those with x + y > 1 folded into the triangle as (1 − x, 1 − y).
fn alpha_samples() -> Vec<[f32; 2]> {
    (0..16)
        .map(|k| {
            let (x, y) = (((k % 4) as f32 + 0.5) / 4.0, ((k / 4) as f32 + 0.5) / 4.0);
            if x + y > 1.0 {
                [1.0 - x, 1.0 - y]
            } else {
                [x, y]
            }
        })
        .collect()
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

impl Prepared {
    /// Splits vertices shared between materials and finds the leaf cards.
    pub fn new(mesh: &Mesh, masks: &[Option<AlphaMask>], opts: &LodOptions) -> Prepared {
        let mut map = std::collections::HashMap::new();
        let mut p = Prepared {
            positions: Vec::new(),
            attributes: Vec::new(),
            source: Vec::new(),
            vertex_material: Vec::new(),
            indices: Vec::with_capacity(mesh.indices.len() * 3),
            vertex_card: Vec::new(),
            cards: Vec::new(),
            card_weight: 0.0,
        };
        for (t, tri) in mesh.indices.iter().enumerate() {
            let m = mesh.triangle_materials[t];
            for &v in tri {
                let next = p.source.len() as u32;
                let id = *map.entry((v, m)).or_insert(next);
                if id == next {
                    let n = mesh.normals[v as usize];
                    let uv = mesh.uvs[v as usize];
                    p.positions.push(mesh.positions[v as usize]);
                    p.attributes.extend([n[0], n[1], n[2], uv[0], uv[1]]);
                    p.source.push(v);
                    p.vertex_material.push(m);
                }
                p.indices.push(id);
            }
        }
        p.vertex_card = vec![u32::MAX; p.source.len()];
        p.find_cards(mesh, masks, opts);
        p
    }

    fn find_cards(&mut self, mesh: &Mesh, masks: &[Option<AlphaMask>], opts: &LodOptions) {
        let n = self.source.len();
        let tested = |v: u32| {
            masks
                .get(self.vertex_material[v as usize] as usize)
                .is_some_and(|m| m.is_some())
        };
        let mut parent: Vec<u32> = (0..n as u32).collect();
        for t in self.indices.chunks_exact(3) {
            if tested(t[0]) {
                let r = find(&mut parent, t[0]);
                for &v in &t[1..] {
                    let s = find(&mut parent, v);
                    parent[s as usize] = r;
                }
            }
        }
        // Triangles per component, in first-seen order (deterministic).
        let mut comp_tris: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        let mut order = Vec::new();
        for (k, t) in self.indices.chunks_exact(3).enumerate() {
            if tested(t[0]) {
                let r = find(&mut parent, t[0]);
                let e = comp_tris.entry(r).or_default();
                if e.is_empty() {
                    order.push(r);
                }
                e.push(k);
            }
        }
        let samples = alpha_samples();
        for r in order {
            let tris = &comp_tris[&r];
            if tris.len() > opts.max_card_triangles as usize {
                continue;
            }
            let id = self.cards.len() as u32;
            let (mut a_sum, mut pass, mut total) = (0.0f64, 0.0f64, 0.0f64);
            let mut c = [0.0f64; 3];
            for &k in tris {
                let t: [u32; 3] = [0, 1, 2].map(|j| self.indices[3 * k + j]);
                let pos = t.map(|v| self.positions[v as usize]);
                let a = area(pos[0], pos[1], pos[2]) as f64;
                a_sum += a;
                for d in 0..3 {
                    c[d] += a * (pos[0][d] + pos[1][d] + pos[2][d]) as f64 / 3.0;
                }
                let mask = masks[self.vertex_material[t[0] as usize] as usize].as_ref();
                let uv = t.map(|v| mesh.uvs[self.source[v as usize] as usize]);
                for s in &samples {
                    let w = [1.0 - s[0] - s[1], s[0], s[1]];
                    let u = w[0] * uv[0][0] + w[1] * uv[1][0] + w[2] * uv[2][0];
                    let v = w[0] * uv[0][1] + w[1] * uv[1][1] + w[2] * uv[2][1];
                    total += a;
                    if mask.is_none_or(|m| m.opaque_at(u, v)) {
                        pass += a;
                    }
                }
                for v in t {
                    self.vertex_card[v as usize] = id;
                }
            }
            let centre = if a_sum > 0.0 {
                c.map(|x| (x / a_sum) as f32)
            } else {
                self.positions[self.indices[3 * tris[0]] as usize]
            };
            let alpha = if total > 0.0 { pass / total } else { 0.0 };
            let radius = tris
                .iter()
                .flat_map(|&k| &self.indices[3 * k..3 * k + 3])
                .map(|&v| length(sub(self.positions[v as usize], centre)))
                .fold(0.0f32, f32::max);
            self.cards.push(Card {
                rank: crate::rng::mix64(0x1eaf_c0de ^ id as u64),
                weight: a_sum * alpha,
                alpha,
                centre,
                radius,
            });
            self.card_weight += a_sum * alpha;
        }
    }

    /// Number of leaf cards found.
    pub fn card_count(&self) -> usize {
        self.cards.len()
    }

    /// The level for target error `target` (model units).
    pub fn level(&self, target: f32, opts: &LodOptions) -> Level {
        let half = if self.cards.is_empty() {
            target
        } else {
            0.5 * target
        };
        let is_card = |t: &[u32]| (self.vertex_card[t[0] as usize] as usize) < self.cards.len();
        let (mut solid, mut card_idx) = (Vec::new(), Vec::new());
        for t in self.indices.chunks_exact(3) {
            if is_card(t) {
                card_idx.extend_from_slice(t)
            } else {
                solid.extend_from_slice(t)
            }
        }
        // Leaf cards keep their own triangles: meshopt's collapses move their UVs, which
        // changes the alpha-tested shape far more than the positional error says (on the 20,000
        // instance view of tests/render_lod.rs, simplified cards gave 6.2 steps of MAD at τ 1
        // against 0.04 without). Thinning is what reduces them.
        let (mut out, e_m) = self.meshopt(&solid, half, opts);
        out.extend_from_slice(&card_idx);
        let (keep, g, e_r) = self.choose_cards(&out, target - e_m);
        self.assemble(&out, &keep, g, e_m, e_r)
    }

    /// meshopt's attribute-aware simplification of `indices` within `target` (absolute), and
    /// the error it reports.
    fn meshopt(&self, indices: &[u32], target: f32, opts: &LodOptions) -> (Vec<u32>, f32) {
        if indices.is_empty() || target <= 0.0 {
            return (indices.to_vec(), 0.0);
        }
        let w = [
            opts.normal_weight,
            opts.normal_weight,
            opts.normal_weight,
            opts.uv_weight,
            opts.uv_weight,
        ];
        let locks = vec![false; self.positions.len()];
        let mut e = 0.0f32;
        let out = meshopt::simplify_with_attributes_and_locks_decoder(
            indices,
            &self.positions,
            &self.attributes,
            &w,
            5 * size_of::<f32>(),
            &locks,
            0,
            target,
            meshopt::SimplifyOptions::ErrorAbsolute,
            Some(&mut e),
        );
        (out, e)
    }

    /// Which cards stay (by card index), their common scale g' (the alpha-weighted area of the
    /// kept cards after simplification, times g'², is the full mesh's) and the removal error
    /// of the cards left out ([`removal_error`]).
    fn choose_cards(&self, out: &[u32], budget: f32) -> (Vec<bool>, f32, f32) {
        let mut present = vec![false; self.cards.len()];
        let mut simplified = vec![0.0f64; self.cards.len()];
        for t in out.chunks_exact(3) {
            let c = self.vertex_card[t[0] as usize] as usize;
            if c < self.cards.len() {
                present[c] = true;
                let p = [0, 1, 2].map(|j| self.positions[t[j] as usize]);
                simplified[c] += area(p[0], p[1], p[2]) as f64 * self.cards[c].alpha;
            }
        }
        let r_max = self.cards.iter().map(|c| c.radius).fold(0.0f32, f32::max);
        let g_target = if r_max > 0.0 {
            (1.0 + budget.max(0.0) / r_max).min(MAX_CARD_SCALE)
        } else {
            1.0
        };
        let total = self.card_weight;
        let have: f64 = simplified.iter().sum();
        if total <= 0.0 || have <= 0.0 {
            return (present, 1.0, 0.0);
        }
        let mut keep = vec![false; self.cards.len()];
        // Cards with no alpha-tested texels under their samples stay as they are.
        for c in 0..self.cards.len() {
            keep[c] = present[c] && simplified[c] <= 0.0;
        }
        let mut ranked: Vec<usize> = (0..self.cards.len())
            .filter(|&c| simplified[c] > 0.0)
            .collect();
        ranked.sort_by_key(|&c| (self.cards[c].rank, c));
        let need = total / (g_target as f64 * g_target as f64);
        // The shortest prefix holding `need`, then lengthened (binary search: the removal error
        // only falls as the prefix grows) until the cards it leaves out are within the budget.
        let mut prefix = vec![0.0f64; ranked.len() + 1];
        for (i, &c) in ranked.iter().enumerate() {
            prefix[i + 1] = prefix[i] + simplified[c];
        }
        let by_area = prefix
            .partition_point(|&w| w < need)
            .min(ranked.len())
            .max(1);
        let with = |k: usize| {
            let mut keep = keep.clone();
            for &c in &ranked[..k] {
                keep[c] = true;
            }
            keep
        };
        let removal = |keep: &[bool]| {
            let removed: Vec<bool> = (0..keep.len()).map(|c| present[c] && !keep[c]).collect();
            removal_error(&self.cards, keep, &removed)
        };
        let removed_within = |k: usize| removal(&with(k)) <= budget;
        let (mut lo, mut hi) = (by_area, ranked.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            if removed_within(mid) {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        let keep = with(lo);
        let e_r = removal(&keep);
        let kept = prefix[lo].max(f64::MIN_POSITIVE);
        (keep, ((total / kept).sqrt() as f32).max(1.0), e_r)
    }

    fn assemble(&self, out: &[u32], keep: &[bool], g: f32, e_m: f32, e_r: f32) -> Level {
        let mut tris: Vec<(u32, usize)> = Vec::new();
        for (k, t) in out.chunks_exact(3).enumerate() {
            let c = self.vertex_card[t[0] as usize];
            if c == u32::MAX || keep[c as usize] {
                tris.push((self.vertex_material[t[0] as usize], k));
            }
        }
        tris.sort();
        let mut local = vec![u32::MAX; self.positions.len()];
        let mut lv = Level::default();
        let (mut r_kept, mut cov, mut cov0) = (0.0f32, 0.0f64, 0.0f64);
        for &(m, k) in &tris {
            let t = &out[3 * k..3 * k + 3];
            let mut idx = [0u32; 3];
            for (j, &v) in t.iter().enumerate() {
                if local[v as usize] == u32::MAX {
                    local[v as usize] = lv.positions.len() as u32;
                    let mut p = self.positions[v as usize];
                    if let Some(card) = self.cards.get(self.vertex_card[v as usize] as usize) {
                        let d = sub(p, card.centre);
                        r_kept = r_kept.max(length(d));
                        p = [0, 1, 2].map(|i| card.centre[i] + g * d[i]);
                    }
                    lv.positions.push(p);
                    lv.vertex_source.push(self.source[v as usize]);
                }
                idx[j] = local[v as usize];
            }
            if let Some(card) = self.cards.get(self.vertex_card[t[0] as usize] as usize) {
                let p = idx.map(|i| lv.positions[i as usize]);
                cov += area(p[0], p[1], p[2]) as f64 * card.alpha;
            }
            lv.indices.push(idx);
            lv.materials.push(m);
        }
        for c in self.cards.iter().filter(|c| c.weight > 0.0) {
            cov0 += c.weight;
        }
        lv.cards = keep.iter().filter(|&&k| k).count() as u32;
        lv.error = (e_m + (g - 1.0) * r_kept).max(e_r);
        lv.coverage = if cov0 > 0.0 { (cov / cov0) as f32 } else { 1.0 };
        lv
    }
}

/// The error of the cards a level leaves out: a point of a removed card lies within its radius
/// R of its centre, and the nearest kept card's centre is D away, so the point is about D + R
/// from the level's foliage (one-sided Hausdorff distance, with card centres standing in for
/// their surfaces). The level's error is at least the largest D + R over the removed cards (0
/// when none is removed; [`Prepared::choose_cards`] always keeps at least one card).
fn removal_error(cards: &[Card], keep: &[bool], removed: &[bool]) -> f32 {
    let kept: Vec<[f32; 3]> = cards
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(c, _)| c.centre)
        .collect();
    let tree = crate::kdtree::KdTree::build(&kept);
    let mut nearest = Vec::with_capacity(1);
    let mut worst = 0.0f32;
    for (c, _) in cards.iter().zip(removed).filter(|(_, r)| **r) {
        tree.nearest(c.centre, 1, &mut nearest);
        let d = nearest.first().map_or(f32::INFINITY, |&(d2, _)| d2.sqrt());
        worst = worst.max(d + c.radius);
    }
    worst
}

/// The whole chain below level 0: levels at the targets of the module documentation, up to
/// `max_error` (exclusive) when given. Errors are non-decreasing.
pub fn simplify_chain(
    mesh: &Mesh,
    masks: &[Option<AlphaMask>],
    radius: f32,
    max_error: Option<f32>,
    opts: &LodOptions,
) -> (Vec<Level>, usize) {
    let prep = Prepared::new(mesh, masks, opts);
    let mut levels: Vec<Level> = Vec::new();
    let mut prev_tris = mesh.indices.len();
    let mut prev_error = 0.0f32;
    for l in 0..opts.levels.max(1) * 3 {
        if levels.len() >= opts.levels as usize || prev_tris <= 2 {
            break;
        }
        let target = opts.base_error * opts.ratio.powi(l as i32) * radius;
        if max_error.is_some_and(|m| target >= m) || target.is_nan() || target <= 0.0 {
            break;
        }
        let mut lv = prep.level(target, opts);
        if lv.indices.is_empty() {
            break;
        }
        if lv.indices.len() as f32 > opts.min_reduction * prev_tris as f32 {
            continue;
        }
        lv.error = lv.error.max(prev_error);
        // A level no finer than the impostor would never be drawn.
        if max_error.is_some_and(|m| lv.error >= m) {
            break;
        }
        prev_error = lv.error;
        prev_tris = lv.indices.len();
        levels.push(lv);
    }
    (levels, prep.card_count())
}

/// Appends the levels to a section's arrays and metadata (after level 0).
pub fn append_levels(levels: &[Level], meta_levels: &mut Vec<LodLevel>, a: &mut LodArrays) {
    for lv in levels {
        let first_vertex = a.positions.len() as u32;
        let first_triangle = a.indices.len() as u32;
        a.positions.extend_from_slice(&lv.positions);
        a.vertex_source.extend_from_slice(&lv.vertex_source);
        a.indices.extend_from_slice(&lv.indices);
        a.triangle_materials.extend_from_slice(&lv.materials);
        meta_levels.push(LodLevel {
            first_vertex,
            vertex_count: lv.positions.len() as u32,
            first_triangle,
            triangle_count: lv.indices.len() as u32,
            error: lv.error,
            ranges: material_ranges(first_triangle, &lv.materials),
            cards: lv.cards,
            coverage: lv.coverage,
        });
    }
}

impl Level {
    /// The level as a mesh of its own: positions, the source vertices' normals and UVs, the
    /// mesh's materials and textures.
    pub fn to_mesh(&self, mesh: &Mesh) -> Mesh {
        Mesh {
            positions: self.positions.clone(),
            normals: self
                .vertex_source
                .iter()
                .map(|&s| mesh.normals[s as usize])
                .collect(),
            uvs: self
                .vertex_source
                .iter()
                .map(|&s| mesh.uvs[s as usize])
                .collect(),
            indices: self.indices.clone(),
            triangle_materials: self.materials.clone(),
            materials: mesh.materials.clone(),
            textures: mesh.textures.clone(),
            objects: mesh.objects.clone(),
            warnings: Vec::new(),
            skeleton: Default::default(),
        }
    }
}
