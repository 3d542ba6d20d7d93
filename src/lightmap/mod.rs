//! Light maps (seed 001, done properly): irradiance per texel of a surface placed once, here the
//! terrain in its own grid coordinates (texel (i, j) covers the cell around x = x₀ + (i + ½)·extent/W,
//! row 0 north like the colour map).
//!
//! `physical` mode (default), per texel:
//! - direct sun: E_sun · max(0, n·s) times the visible fraction of the sun's disc (true angular
//!   radius 0.00465 rad), estimated with `sun_samples` stratified points on the disc and shadow rays
//!   through the whole scene (terrain and instances, alpha-tested);
//! - sky: cosine-weighted hemisphere directions (a Hammersley set with a per-texel Cranley–Patterson
//!   rotation), E ≈ π/N Σ L(d)·V(d) with L the sun-free sky;
//! - one diffuse bounce: a direction that hits a surface brings ρ/π·(E_sun,direct + E_sky,unoccluded)
//!   of that surface (ρ its mean albedo).
//!
//! Terrain texels (`visibility = "horizons"`, the default since issue 37): the same terms, with
//! the terrain's own occlusion from horizon sweeps ([`horizon`], [`texel_horizon_parts`]): the
//! sky above the horizons integrated exactly (no noise where only the terrain occludes), the
//! sun's disc against the texel's horizon towards the sun, and rays only for the instances (the
//! terrain skipped) and for directions below the horizons (the bounce), as a control variate.
//! `visibility = "rays"` keeps the estimator above for every ray (the reference and baseline);
//! object atlases always use it.
//!
//! `thesis` mode reproduces seed 001's estimator for comparison: one fixed Hammersley set for every
//! texel, no visibility (neither for the sky nor the sun), no bounce.
//!
//! The terrain atlas is its grid, so it has no charts and no gutters. Meshes placed at most
//! `max_instances` times (the 3DS objects) get a generated atlas with one tile per instance
//! ([`atlas`], [`objects`], [`atlas_section`]).

pub mod atlas;
pub mod atlas_section;
pub mod filter;
pub mod horizon;
pub mod objects;
pub mod section;
pub mod stage;

use crate::sh::{ShIrradiance, ShRadiance};
use crate::trace::pack_scene::TraceScene;
use crate::trace::{Ray, SceneTracer, SunBeam, Tracer};
use glam::Vec3A;
use rayon::prelude::*;

/// The sun's angular radius in radians (seed 000, eq. 3.1).
pub const SUN_RADIUS: f32 = 0.004_65;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum LightmapMode {
    Physical,
    Thesis,
}

/// How the terrain light map finds the terrain's own occlusion (`physical` mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LightmapVisibility {
    /// Horizon sweeps ([`horizon`]): the sky above the horizons integrated exactly, the sun's
    /// disc against its horizon; rays only for the instances and the bounce.
    #[default]
    Horizons,
    /// Every hemisphere and sun ray traced through the whole scene (the estimator before
    /// issue 37; kept as the reference and the baseline).
    Rays,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LightmapOptions {
    /// Texels per side (the terrain grid size by default).
    pub resolution: Option<u32>,
    /// At most this many texels per side (the preview caps a 4097² terrain's map at 1025²).
    pub max_resolution: Option<u32>,
    pub samples: u32,
    pub sun_samples: u32,
    pub mode: LightmapMode,
    /// Models placed at most this many times get an atlas light map (one tile per instance).
    pub max_instances: u32,
    pub atlas: atlas::AtlasOptions,
    /// Ray-tracing backend of the terrain and object light maps ([`Tracer`]: `cpu` | `embree`).
    pub tracer: Tracer,
    /// The terrain's self-occlusion by horizons (default) or by rays.
    pub visibility: LightmapVisibility,
    /// Horizon directions: every primitive lattice vector with max(|a|, |b|) ≤ this (1, 2, 3,
    /// 4: 8, 16, 32, 48 directions).
    pub horizon_lattice: u32,
    /// Relative range of the bilateral filter of the terrain map's part without the direct sun
    /// ([`filter::filter_indirect`], issue 37 item 4); 0 (the default): no filter.
    pub filter_range: f32,
    /// Radius in texels of that filter (a (2r+1)² window).
    pub filter_radius: u32,
    /// The terrain map's hemisphere rays (the horizon estimator's traced correction: the
    /// instances and the bounce) at every texel (1, the final preset) or at every S-th texel of
    /// every S-th row (S from 2 to 8; 2 the default), a texel between taking the bilinear blend
    /// of the traced texels around it (their mean at step 2) unless they disagree beyond their
    /// noise, where it is traced itself; the
    /// direct sun and the sky above the horizons stay per texel (issue 37; docs/PERFORMANCE.md).
    /// The ray estimator (`visibility = "rays"`, `thesis` mode) traces every texel whatever
    /// this says. In the unit's key only when not 1 (keys of maps traced at every texel are
    /// those from before the option). The step a map is traced at is this or, where
    /// `trace_spacing` asks for more, that ([`LightmapOptions::trace_step_for`]).
    pub trace_step: u32,
    /// The traced texels at least this many metres apart (0: no bound): on a map of texels
    /// `s` metres wide the step is widened to ⌊trace_spacing / s⌋ texels where that exceeds
    /// `trace_step`, at most 8. The correction the lattice interpolates is the instances'
    /// occlusion and the bounce, which vary over the size of the objects on the terrain, not
    /// of its texels: the default 3.5 m keeps a 1.54 m-texel map at step 2 and traces a
    /// 1 m-texel map at step 3 (issue 37; docs/PERFORMANCE.md). In the unit's key only when
    /// not 0.
    pub trace_spacing: f32,
}

impl LightmapOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: LightmapOptions = LightmapOptions {
        resolution: None,
        max_resolution: None,
        samples: 64,
        sun_samples: 16,
        mode: LightmapMode::Physical,
        max_instances: 16,
        atlas: atlas::AtlasOptions::DEFAULT,
        tracer: Tracer::Cpu,
        visibility: LightmapVisibility::Horizons,
        horizon_lattice: 3,
        filter_range: 0.0,
        filter_radius: 2,
        trace_step: 2,
        trace_spacing: 3.5,
    };

    /// The step of the traced lattice on a map whose texels are `texel` metres wide (their
    /// larger side): `trace_step`, widened to ⌊trace_spacing / texel⌋ where that is larger,
    /// at most 8.
    pub fn trace_step_for(&self, texel: f32) -> u32 {
        let by_metres = if self.trace_spacing > 0.0 && texel > 0.0 {
            (self.trace_spacing / texel).floor() as u32
        } else {
            0
        };
        self.trace_step.max(by_metres).clamp(1, 8)
    }

    /// Options this binary cannot run (a tracer it was built without).
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(self.filter_range.is_finite() && self.filter_range >= 0.0) || self.filter_radius > 8 {
            return Err(format!(
                "lightmap.filter_range = {}, lightmap.filter_radius = {} (a range ≥ 0, 0 for no filter; a radius of at most 8 texels)",
                self.filter_range, self.filter_radius
            ));
        }
        if !(self.trace_spacing.is_finite() && (0.0..=1000.0).contains(&self.trace_spacing)) {
            return Err(format!(
                "lightmap.trace_spacing = {} (metres between traced texels, 0 to 1000; 0: no bound)",
                self.trace_spacing
            ));
        }
        if !(1..=8).contains(&self.trace_step) {
            return Err(format!(
                "lightmap.trace_step = {} (1: hemisphere rays at every texel; S from 2 to 8: at every S-th texel of every S-th row)",
                self.trace_step
            ));
        }
        if !(1..=4).contains(&self.horizon_lattice) {
            return Err(format!(
                "lightmap.horizon_lattice = {} (1 to 4: 8, 16, 32 or 48 horizon directions)",
                self.horizon_lattice
            ));
        }
        self.tracer.available_as("lightmap.tracer")
    }
}

/// The step the terrain's map is traced at ([`LightmapOptions::trace_step_for`] of its
/// texels' larger side); 1 without a terrain.
pub fn terrain_trace_step(scene: &TraceScene, opts: &LightmapOptions) -> u32 {
    match (scene.terrain.as_ref(), terrain_lightmap_size(scene, opts)) {
        (Some(t), Some((w, h))) => {
            let [sx, sy] = horizon::TexelGrid::new(t, w, h).step();
            opts.trace_step_for(sx.max(sy))
        }
        _ => 1,
    }
}

impl Default for LightmapOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The light that reaches the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakeLight {
    /// Sun-free sky radiance.
    pub sky: ShRadiance,
    /// Unit direction to the sun and its irradiance (RGB), if any.
    pub sun: Option<([f32; 3], [f32; 3])>,
}

/// A light map: irradiance (linear RGB, W/m² for radiance in W/(m² sr)) per texel, row 0 north.
#[derive(Debug, Clone, PartialEq)]
pub struct Lightmap {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<[f32; 3]>,
}

/// Bakes the terrain light map of a scene.
pub fn bake_terrain_lightmap(
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
) -> crate::error::Result<Option<Lightmap>> {
    Ok(bake_terrain_lightmap_parts(scene, light, opts)?.map(|(m, _)| m))
}

/// [`bake_terrain_lightmap`] and the direct-sun part of every texel (equal to
/// [`terrain_direct_sun`]'s, from the same pass).
pub fn bake_terrain_lightmap_parts(
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
) -> crate::error::Result<Option<(Lightmap, Vec<[f32; 3]>)>> {
    let Some((w, h)) = terrain_lightmap_size(scene, opts) else {
        return Ok(None);
    };
    let Some((texels, direct)) = bake_terrain_lightmap_rows(scene, light, opts, 0..h)? else {
        return Ok(None);
    };
    Ok(Some((
        Lightmap {
            width: w,
            height: h,
            texels,
        },
        direct,
    )))
}

/// Texels per side of the terrain's light map (`None` without a terrain).
pub fn terrain_lightmap_size(scene: &TraceScene, opts: &LightmapOptions) -> Option<(u32, u32)> {
    let t = scene.terrain.as_ref()?;
    let res = opts
        .resolution
        .unwrap_or(t.width.max(t.height))
        .min(opts.max_resolution.unwrap_or(u32::MAX))
        .max(1);
    Some((res, res))
}

/// Texels of some rows of a light map and their direct-sun part.
pub type TexelRows = (Vec<[f32; 3]>, Vec<[f32; 3]>);

/// The texels (irradiance, direct-sun part) of rows `rows` of the terrain light map, exactly as
/// the whole map holds them (each texel is seeded by its index): a shard of the light map.
/// Traced on `opts.tracer` (an error only where that backend cannot be built).
pub fn bake_terrain_lightmap_rows(
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
    rows: std::ops::Range<u32>,
) -> crate::error::Result<Option<TexelRows>> {
    let (Some(t), Some((w, h))) = (scene.terrain.as_ref(), terrain_lightmap_size(scene, opts))
    else {
        return Ok(None);
    };
    let bvh = scene.tracer(opts.tracer)?;
    let rows = rows.start.min(h)..rows.end.min(h);
    let sky_irr = light.sky.to_irradiance();
    if opts.mode == LightmapMode::Physical && opts.visibility == LightmapVisibility::Horizons {
        return Ok(Some(horizon_rows(scene, bvh, light, opts, rows)));
    }
    let (texels, direct): (Vec<[f32; 3]>, Vec<[f32; 3]>) = (rows.start * w..rows.end * w)
        .into_par_iter()
        .map(|k| {
            let (i, j) = (k % w, k / w);
            let x = t.origin[0] + (i as f32 + 0.5) / w as f32 * t.extent[0];
            // Row 0 is north (y = y₀ + extent).
            let y = t.origin[1] + (1.0 - (j as f32 + 0.5) / h as f32) * t.extent[1];
            let p = Vec3A::new(x, y, t.mesh_height_at(x, y));
            let n = Vec3A::from(height_normal(t, x, y));
            texel_irradiance_parts(bvh, &scene.albedo, light, &sky_irr, p, n, k as u64, opts)
        })
        .unzip();
    Ok(Some((texels, direct)))
}

/// Texels of one band of [`horizon_rows`]: the horizons of K directions (2 bytes each) stay
/// below about 128 MB.
fn band_rows(width: u32, directions: usize) -> u32 {
    ((128u64 << 20) / (2 * width.max(1) as u64 * directions.max(1) as u64)).clamp(16, 1 << 20)
        as u32
}

/// What the instance-only rays of the horizon estimator need: the terrain's instance number
/// (skipped) and the top of the highest instance (rays stop when they rise above it).
#[derive(Debug, Clone, Copy)]
pub struct Reach {
    terrain: u32,
    top: Option<f32>,
}

impl Reach {
    pub fn of(scene: &TraceScene) -> Reach {
        let models = scene.bvh.models();
        let top = scene
            .bvh
            .instances()
            .iter()
            .map(|i| i.translation[2] + i.scale * models[i.model as usize].bounds().1.z)
            .reduce(f32::max);
        Reach {
            terrain: scene.bvh.instances().len() as u32,
            top,
        }
    }

    /// The ray from `o` along `d` up to the top of the instances; `None` without instances.
    fn instance_ray(&self, o: Vec3A, d: Vec3A) -> Option<Ray> {
        let top = self.top?;
        let tmax = if d.z > 0.0 {
            ((top - o.z) / d.z).max(0.0) + 1e-3
        } else {
            f32::INFINITY
        };
        Some(Ray {
            tmax,
            ..Ray::new(o, d, 1e-4)
        })
    }

    /// The closest instance hit (the terrain skipped) of [`Self::instance_ray`]; `None`
    /// without instances.
    fn instance_hit(
        &self,
        bvh: &dyn SceneTracer,
        o: Vec3A,
        d: Vec3A,
    ) -> Option<crate::trace::SceneHit> {
        bvh.closest_hit_excluding(&self.instance_ray(o, d)?, &[self.terrain])
    }

    /// Whether [`Self::instance_hit`] finds a hit, stopping at the first one found (the same
    /// ray and bounds: the sun's disc rays need no closest hit).
    fn instance_blocked(&self, bvh: &dyn SceneTracer, o: Vec3A, d: Vec3A) -> bool {
        self.instance_ray(o, d)
            .is_some_and(|ray| bvh.any_hit_excluding(&ray, &[self.terrain]))
    }
}

/// The horizon estimator on rows `rows` (see [`texel_horizon_parts`]), in bands of rows.
fn horizon_rows(
    scene: &TraceScene,
    bvh: &dyn SceneTracer,
    light: &BakeLight,
    opts: &LightmapOptions,
    rows: std::ops::Range<u32>,
) -> TexelRows {
    horizon_rows_noise(scene, bvh, light, opts, rows, false, true).0
}

/// The terrain light map's rows `rows` by the horizon estimator with each texel's noise
/// estimate: the variance of its traced correction's RGB mean (see [`texel_horizon_parts`]),
/// for the benchmark's noise-aware filter (`bake bench lightmap --filters noise:R:K`). `None`
/// without a terrain; an error for another estimator than `physical` with `horizons`.
pub(crate) fn bake_terrain_lightmap_rows_noise(
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
    rows: std::ops::Range<u32>,
) -> crate::error::Result<Option<(TexelRows, Vec<f32>)>> {
    let Some((_, h)) = terrain_lightmap_size(scene, opts) else {
        return Ok(None);
    };
    if opts.mode != LightmapMode::Physical || opts.visibility != LightmapVisibility::Horizons {
        return Err(crate::error::Error::usage(
            "a noise estimate needs the physical mode with horizons".to_string(),
        ));
    }
    let bvh = scene.tracer(opts.tracer)?;
    let rows = rows.start.min(h)..rows.end.min(h);
    let (t, noise) = horizon_rows_noise(scene, bvh, light, opts, rows, true, true);
    Ok(Some((t, noise)))
}

/// [`horizon_rows`], with the texels' noise estimates when `noise` (else an empty list).
///
/// With `opts.trace_step` = 2 the traced correction (the hemisphere rays: instances and the
/// bounce) is traced only at the texels of even row and even column (and the last row and
/// column), each with `samples` rays, and every texel takes the mean of the 1, 2 or 4 traced
/// texels around it (bilinear at the half-way points); the direct sun and the exact sky above
/// the horizons stay per texel. A row range is widened by one row at an odd end so that its
/// texels read the same traced rows as the whole map's.
fn horizon_rows_noise(
    scene: &TraceScene,
    bvh: &dyn SceneTracer,
    light: &BakeLight,
    opts: &LightmapOptions,
    rows: std::ops::Range<u32>,
    noise: bool,
    beam: bool,
) -> (TexelRows, Vec<f32>) {
    let (mut texels, mut direct, mut variance) = (Vec::new(), Vec::new(), Vec::new());
    horizon_rows_into(scene, bvh, light, opts, rows, beam, &mut |band| {
        for (e, d, v) in band {
            texels.push(e);
            direct.push(d);
            if noise {
                variance.push(v);
            }
        }
    });
    ((texels, direct), variance)
}

/// One band's texels from [`horizon_rows_into`], in row-major order: (irradiance, its direct-sun
/// part, the variance of its traced correction).
type BandTexels = Vec<([f32; 3], [f32; 3], f32)>;

/// The horizon estimator of [`horizon_rows_noise`], handing each band's texels to `sink` as it
/// is done (bands in row order), so that a whole map need not be held beside its section. With
/// `beam` the CPU tracer's sun-disc rays go through a [`SunBeam`] (the same answers; without:
/// through the top level, the path before it, kept for the test that compares the two).
#[allow(clippy::too_many_arguments)]
fn horizon_rows_into(
    scene: &TraceScene,
    bvh: &dyn SceneTracer,
    light: &BakeLight,
    opts: &LightmapOptions,
    rows: std::ops::Range<u32>,
    beam: bool,
    sink: &mut dyn FnMut(BandTexels),
) {
    let t = scene.terrain.as_ref().expect("a terrain");
    let (w, h) = terrain_lightmap_size(scene, opts).expect("a terrain");
    let grid = horizon::TexelGrid::new(t, w, h);
    let dirs = horizon::lattice_vectors(opts.horizon_lattice);
    let tables = horizon::SkyTables::new(&grid, &dirs, &light.sky);
    let sky_irr = light.sky.to_irradiance();
    let reach = Reach::of(scene);
    let sun_beam = if beam {
        sun_beam(scene, light, opts.tracer)
    } else {
        None
    };
    let step = terrain_trace_step(scene, opts);
    let coarse = (step > 1).then_some(TraceLattice { w, h, step });
    // The rows whose horizons are swept: `rows`, and with a trace step the traced rows next to
    // an odd first or last row.
    let swept = match &coarse {
        Some(c) if !rows.is_empty() => {
            c.rows_around(rows.start).0..c.rows_around(rows.end - 1).1 + 1
        }
        _ => rows.clone(),
    };
    let bands = bands_of(
        swept,
        band_rows(w, dirs.len()),
        coarse.as_ref().map(|c| (h, c.step)),
    );
    let sun = light.sun.map(|s| s.0);
    // More than one band: each southward line walked once, kept from one band to the next.
    let mut banded =
        (bands.len() > 1).then(|| horizon::BandedSweeps::new(&grid, &dirs, sun, bands.clone()));
    let rays = HemisphereRays {
        bvh,
        albedo: &scene.albedo,
        light,
        sky_irr: &sky_irr,
        tables: &tables,
        reach,
    };
    // With a trace step: the traced texels' corrections and variances, by traced row (the
    // band's and the last one before it).
    let mut traced: Vec<(u32, Vec<TracedTexel>)> = Vec::new();
    for band in &bands {
        let (start, end) = (band.start, band.end);
        // Only the last traced row of the bands before is read again (by an odd first row).
        if traced.len() > 1 {
            traced.drain(..traced.len() - 1);
        }
        let hz = match banded.as_mut() {
            Some(banded) => banded.horizons(t, &grid),
            None => horizon::Horizons::compute(t, &grid, &dirs, sun, start..end),
        };
        let surface = |k: usize| {
            let (i, j) = (k as u32 % w, start + k as u32 / w);
            let (x, y) = grid.xy(i, j);
            let p = Vec3A::new(x, y, t.mesh_height_at(x, y));
            let n = Vec3A::from(height_normal(t, x, y));
            let env = HorizonTexel {
                tables: &tables,
                horizons: &hz,
                index: k,
                reach,
                sun_beam: sun_beam.as_ref(),
            };
            (p, n, (j * w + i) as u64, env)
        };
        let Some(lattice) = &coarse else {
            sink(
                (0..hz.len())
                    .into_par_iter()
                    .map(|k| {
                        let (p, n, texel, env) = surface(k);
                        texel_horizon_parts(&rays, &env, p, n, texel, opts)
                    })
                    .collect(),
            );
            continue;
        };
        // The correction of the traced texels of the band's traced rows.
        let columns = lattice.columns();
        for j in (start..end).filter(|&j| TraceLattice::is_traced(j, h, lattice.step)) {
            let row = columns
                .par_iter()
                .map(|&i| {
                    let k = ((j - start) * w + i) as usize;
                    let (p, n, texel, env) = surface(k);
                    let s_eff = effective_horizons(&env, n);
                    let mut c = [0.0f64; 3];
                    let v = rays.correction(&s_eff, p + n * 1e-3, n, texel, opts.samples, &mut c);
                    (c.map(|x| x as f32), v)
                })
                .collect();
            traced.push((j, row));
        }
        // Every texel of `rows` in the band: its exact part, and the mean of the traced
        // corrections around it, or its own where those disagree.
        let row_of = |j: u32| {
            let k = traced.partition_point(|(r, _)| *r < j);
            debug_assert_eq!(traced[k].0, j, "traced row {j} swept");
            &traced[k].1
        };
        let own = start.max(rows.start)..end.min(rows.end);
        let first = ((own.start.min(end) - start) * w) as usize;
        let done: BandTexels = (first..first + (own.len() as u32 * w) as usize)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k as u32 % w, start + k as u32 / w);
                let (p, n, texel, env) = surface(k);
                let origin = p + n * 1e-3;
                let (mut e, d, s_eff) =
                    texel_horizon_exact(bvh, light, &env, origin, n, texel, opts);
                let (r0, r1) = lattice.rows_around(j);
                let (c0, c1) = lattice.columns_around(i);
                let (ia, ib) = (lattice.index(c0), lattice.index(c1));
                let (a, b) = (row_of(r0), row_of(r1));
                let (u, t) = (
                    TraceLattice::weight(i, (c0, c1)),
                    TraceLattice::weight(j, (r0, r1)),
                );
                let at = |((c, v), wt): (TracedTexel, f32)| (c, v, wt);
                let mut corners = vec![at((a[ia], (1.0 - t) * (1.0 - u)))];
                if ib != ia {
                    corners.push(at((a[ib], (1.0 - t) * u)));
                }
                if r1 != r0 {
                    corners.push(at((b[ia], t * (1.0 - u))));
                    if ib != ia {
                        corners.push(at((b[ib], t * u)));
                    }
                }
                let var = match TraceLattice::blend(&corners, e) {
                    Some((c, var)) => {
                        for ch in 0..3 {
                            e[ch] += c[ch] as f64;
                        }
                        var
                    }
                    None => rays.correction(&s_eff, origin, n, texel, opts.samples, &mut e),
                };
                (e.map(|v| v as f32), d, var)
            })
            .collect();
        sink(done);
    }
}

/// The bands of at most `band` rows that tile `rows`. With a trace step (`traced_of`: the
/// map's height and the step S) every band but the last ends on a traced row (up to S − 1 rows
/// shorter where it would not; a band has at least S + 1 rows), so every row of a band finds
/// the traced rows around it in the band or in the last traced row of the band before (the
/// last band ends on the range's end, a traced row).
fn bands_of(
    rows: std::ops::Range<u32>,
    band: u32,
    traced_of: Option<(u32, u32)>,
) -> Vec<std::ops::Range<u32>> {
    let mut bands = Vec::new();
    let mut s = rows.start;
    let least = traced_of.map_or(2, |(_, step)| step + 1);
    while s < rows.end {
        let mut e = (s + band.max(least)).min(rows.end);
        if let Some((h, step)) = traced_of
            && e < rows.end
        {
            while e - 1 > s && !TraceLattice::is_traced(e - 1, h, step) {
                e -= 1;
            }
        }
        bands.push(s..e);
        s = e;
    }
    bands
}

/// A traced texel's correction (RGB) and the variance of its rays' mean.
type TracedTexel = ([f32; 3], f32);

/// The traced texels of a map with `lightmap.trace_step` = S > 1: every S-th row and column
/// (from 0) and the last row and column.
struct TraceLattice {
    w: u32,
    h: u32,
    step: u32,
}

impl TraceLattice {
    /// Whether row (or column) `j` of `n` is traced at step `step`.
    fn is_traced(j: u32, n: u32, step: u32) -> bool {
        j.is_multiple_of(step) || j + 1 == n
    }

    /// The traced rows around row `j`: itself twice, or the traced rows before and after it.
    fn rows_around(&self, j: u32) -> (u32, u32) {
        Self::around(j, self.h, self.step)
    }

    /// The traced columns around column `i`.
    fn columns_around(&self, i: u32) -> (u32, u32) {
        Self::around(i, self.w, self.step)
    }

    fn around(j: u32, n: u32, step: u32) -> (u32, u32) {
        if Self::is_traced(j, n, step) {
            (j, j)
        } else {
            let a = j / step * step;
            (a, (a + step).min(n - 1))
        }
    }

    /// The weight of the second of the traced rows (or columns) `(a, b)` around `j`: 0 at `a`,
    /// 1 at `b` (bilinear; ½ half-way, exactly).
    fn weight(j: u32, (a, b): (u32, u32)) -> f32 {
        if b == a {
            0.0
        } else {
            (j - a) as f32 / (b - a) as f32
        }
    }

    /// The traced columns, in order.
    fn columns(&self) -> Vec<u32> {
        (0..self.w)
            .filter(|&i| Self::is_traced(i, self.w, self.step))
            .collect()
    }

    /// A traced column's place in [`Self::columns`].
    fn index(&self, i: u32) -> usize {
        (i as usize).div_ceil(self.step as usize)
    }

    /// The correction of a texel from the 1, 2 or 4 distinct traced texels around it
    /// (`corners`: correction, variance and bilinear weight, the weights summing to 1) and the
    /// variance of that interpolation; `None` where they disagree: some corner lies further
    /// from the corners' plain mean than 3 standard deviations of its own noise plus 5 % of
    /// the texel's exact part `exact` (RGB means), so the texel is traced itself.
    fn blend(uniq: &[([f32; 3], f32, f32)], exact: [f64; 3]) -> Option<([f32; 3], f32)> {
        let m = uniq.len() as f32;
        let mut mean = [0.0f32; 3];
        let mut blended = [0.0f32; 3];
        let mut var = 0.0f32;
        for (c, v, wt) in uniq {
            for ch in 0..3 {
                mean[ch] += c[ch] / m;
                blended[ch] += c[ch] * wt;
            }
            var += v * (wt * wt);
        }
        let grey = |c: [f32; 3]| (c[0] + c[1] + c[2]) / 3.0;
        let tolerance = 0.05 * ((exact[0] + exact[1] + exact[2]) / 3.0) as f32;
        let agree = uniq
            .iter()
            .all(|(c, v, _)| (grey(*c) - grey(mean)).abs() <= 3.0 * v.sqrt() + tolerance);
        agree.then_some((blended, var))
    }
}

/// A texel's horizons and what [`texel_horizon_parts`] reads beside them.
pub struct HorizonTexel<'a> {
    pub tables: &'a horizon::SkyTables,
    pub horizons: &'a horizon::Horizons,
    /// The texel's index within the horizons' rows.
    pub index: usize,
    pub reach: Reach,
    /// The instances binned along the sun ([`SunBeam`]): the sun-disc rays' any-hit queries
    /// without the top level (the same answers); `None`: through the tracer's top level.
    pub sun_beam: Option<&'a SunBeam<'a>>,
}

/// The light map's estimator with the terrain's self-occlusion from horizons (`physical` mode,
/// visibility `horizons`), returning (irradiance, direct-sun part) like
/// [`texel_irradiance_parts`], with the same terms:
/// - direct sun: E_sun · max(0, n·s) · V, V = (visible fraction of the sun's disc above the
///   texel's horizon towards the sun, [`horizon::sun_fraction`]) × (fraction of `sun_samples`
///   disc rays that no instance blocks; the terrain is skipped, the rays stop above the highest
///   instance);
/// - sky and one bounce, as a control variate: g(d) = L(d) on the directions above the sector
///   horizons (raised to the tangent plane), zero below; its integral `∫ g (n·d) dω` is exact
///   ([`horizon::SkyTables`]), and `samples` cosine-distributed rays (the same Hammersley set
///   and per-texel rotation as the ray estimator) estimate `∫ (f − g) (n·d) dω`, f the radiance
///   the ray estimator takes (sky if the ray escapes, the hit's bounce radiance otherwise). A ray
///   above the horizon is traced against the instances only (the terrain does not block it, up
///   to the horizons' discretization in azimuth); where none blocks it f − g is
///   max(L, 0) − L (zero unless the SH sky is negative there). A ray below the horizon is traced
///   through the whole scene. Where nothing but the terrain occludes, the sky term has no noise.
fn texel_horizon_parts(
    rays: &HemisphereRays,
    env: &HorizonTexel,
    p: Vec3A,
    n: Vec3A,
    texel: u64,
    opts: &LightmapOptions,
) -> ([f32; 3], [f32; 3], f32) {
    let origin = p + n * 1e-3;
    let (mut e, direct, s_eff) =
        texel_horizon_exact(rays.bvh, rays.light, env, origin, n, texel, opts);
    let variance = rays.correction(&s_eff, origin, n, texel, opts.samples, &mut e);
    (e.map(|v| v as f32), direct, variance)
}

/// The noise-free part of [`texel_horizon_parts`] at one texel (`origin` raised off the
/// surface): the direct sun and the sky above the effective horizons, summed in f64, the direct
/// part alone, and the effective horizons (the bounds of the traced correction).
fn texel_horizon_exact(
    bvh: &dyn SceneTracer,
    light: &BakeLight,
    env: &HorizonTexel,
    origin: Vec3A,
    n: Vec3A,
    texel: u64,
    opts: &LightmapOptions,
) -> ([f64; 3], [f32; 3], [f32; horizon::MAX_DIRECTIONS]) {
    let hz = env.horizons;
    let mut e = [0.0f64; 3];
    let mut direct = [0.0f32; 3];
    if let Some((s, irr)) = light.sun {
        let sv = Vec3A::from(s);
        let cos = n.dot(sv);
        if cos > 0.0 {
            let slope = hz
                .sun_slope
                .get(env.index)
                .copied()
                .unwrap_or(f32::NEG_INFINITY);
            let mut vis = horizon::sun_fraction(slope, s);
            if vis > 0.0 && env.reach.top.is_some() {
                vis *= instance_sun_visibility(
                    bvh,
                    &env.reach,
                    env.sun_beam,
                    origin,
                    sv,
                    opts.sun_samples,
                    texel,
                );
            }
            direct = irr.map(|e| e * cos * vis);
            for k in 0..3 {
                e[k] += direct[k] as f64;
            }
        }
    }
    // The exact part: the sky above the effective horizons.
    let na = n.to_array();
    let s_eff = effective_horizons(env, n);
    for (k, &se) in s_eff.iter().enumerate().take(env.tables.sectors()) {
        let v = env.tables.integral(k, se, na);
        for c in 0..3 {
            e[c] += v[c] as f64;
        }
    }
    (e, direct, s_eff)
}

/// A texel's horizons per sector raised to its tangent plane ([`horizon::SkyTables::effective`]).
fn effective_horizons(env: &HorizonTexel, n: Vec3A) -> [f32; horizon::MAX_DIRECTIONS] {
    let na = n.to_array();
    let downhill = horizon::SkyTables::downhill(na);
    let mut s_eff = [0.0f32; horizon::MAX_DIRECTIONS];
    for (k, se) in s_eff.iter_mut().enumerate().take(env.tables.sectors()) {
        *se = env
            .tables
            .effective_at(k, env.horizons.sin(k, env.index), na, downhill);
    }
    s_eff
}

/// What the traced correction of the horizon estimator reads ([`texel_horizon_parts`]).
#[derive(Clone, Copy)]
struct HemisphereRays<'a> {
    bvh: &'a dyn SceneTracer,
    albedo: &'a [[f32; 3]],
    light: &'a BakeLight,
    sky_irr: &'a ShIrradiance,
    tables: &'a horizon::SkyTables,
    reach: Reach,
}

impl HemisphereRays<'_> {
    /// The traced correction ∫ (f − g) (n·d) dω at a texel with effective horizons `s_eff`,
    /// added ray by ray into `e` (f64), by `samples` cosine-distributed rays; returns the
    /// variance of the rays' RGB mean (an estimate of the texel's noise; the rays are
    /// stratified, so it is an upper bound).
    fn correction(
        &self,
        s_eff: &[f32; horizon::MAX_DIRECTIONS],
        origin: Vec3A,
        n: Vec3A,
        texel: u64,
        samples: u32,
        e: &mut [f64; 3],
    ) -> f32 {
        let (bvh, light) = (self.bvh, self.light);
        let nsamp = samples.max(1);
        let (mut s1, mut s2) = (0.0f64, 0.0f64);
        let (tx, bx) = crate::trace::frame(n);
        let shift = cp_rotation(texel);
        for k in 0..nsamp {
            let d = cosine_direction(k, nsamp, shift, (tx, bx, n));
            let sector = self
                .tables
                .sector_of(d.x, d.y)
                .min(horizon::MAX_DIRECTIONS - 1);
            let c = if d.z > s_eff[sector] {
                let l = light.sky.eval(d.to_array());
                match self.reach.instance_hit(bvh, origin, d) {
                    None => l.map(|v| v.max(0.0) - v),
                    Some(hit) => {
                        let b = bounce_radiance(bvh, self.albedo, light, self.sky_irr, &hit, d);
                        [0, 1, 2].map(|c| b[c] - l[c])
                    }
                }
            } else {
                match bvh.closest_hit(&Ray::new(origin, d, 1e-4)) {
                    None => light.sky.eval(d.to_array()).map(|v| v.max(0.0)),
                    Some(hit) => bounce_radiance(bvh, self.albedo, light, self.sky_irr, &hit, d),
                }
            };
            for ch in 0..3 {
                e[ch] += (c[ch] * std::f32::consts::PI / nsamp as f32) as f64;
            }
            let x = (c[0] + c[1] + c[2]) as f64 / 3.0 * std::f64::consts::PI;
            s1 += x;
            s2 += x * x;
        }
        let nf = nsamp as f64;
        let variance = if nsamp > 1 {
            ((s2 - s1 * s1 / nf) / (nf * (nf - 1.0))).max(0.0)
        } else {
            0.0
        };
        variance as f32
    }
}

/// Ray k of `n` cosine-distributed hemisphere rays about the frame (tx, bx, normal): the
/// Hammersley point shifted by the texel's rotation `shift` (Cranley–Patterson).
fn cosine_direction(
    k: u32,
    n: u32,
    shift: (f32, f32),
    (tx, bx, nz): (Vec3A, Vec3A, Vec3A),
) -> Vec3A {
    let (u1, u2) = hammersley(k, n);
    let (u1, u2) = ((u1 + shift.0).fract(), (u2 + shift.1).fract());
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let local = Vec3A::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
    (tx * local.x + bx * local.y + nz * local.z).normalize()
}

/// Fraction of the sun's disc that no instance blocks (the terrain skipped): the disc points
/// of [`sun_visibility`], traced up to the top of the instances, through `beam` where there is
/// one (the same answers as the tracer's top level, without it).
fn instance_sun_visibility(
    bvh: &dyn SceneTracer,
    reach: &Reach,
    beam: Option<&SunBeam>,
    p: Vec3A,
    s: Vec3A,
    samples: u32,
    texel: u64,
) -> f32 {
    let Some(beam) = beam else {
        return disc_visibility(s, samples, texel, |d| !reach.instance_blocked(bvh, p, d));
    };
    let disc = Disc::new(s, samples, texel);
    let n = samples.max(1);
    let mut visible = 0;
    // In chunks of 16 (the default count): a small stack array to fill per texel.
    const CHUNK: u32 = 16;
    let mut rays = [Ray::new(p, s, 0.0); CHUNK as usize];
    let mut blocked = [false; CHUNK as usize];
    for start in (0..n).step_by(CHUNK as usize) {
        let end = (start + CHUNK).min(n);
        let mut traced = 0;
        for k in start..end {
            match reach.instance_ray(p, disc.direction(k)) {
                Some(r) => {
                    rays[traced] = r;
                    traced += 1;
                }
                // No instances: nothing blocks.
                None => visible += 1,
            }
        }
        beam.any_hits(&rays[..traced], &mut blocked[..traced]);
        visible += blocked[..traced].iter().filter(|&&b| !b).count();
    }
    visible as f32 / n as f32
}

/// The beam of the scene's instances along the sun for the CPU tracer's sun-disc rays
/// ([`instance_sun_visibility`]); `None` on another tracer, without a sun or instances, or for
/// a sun too low for one ([`SunBeam::new`]).
fn sun_beam<'a>(scene: &'a TraceScene, light: &BakeLight, tracer: Tracer) -> Option<SunBeam<'a>> {
    if tracer != Tracer::Cpu {
        return None;
    }
    SunBeam::new(&scene.bvh, Vec3A::from(light.sun?.0))
}

/// Normal of the bilinear height field at (x, y) by central differences over one grid step.
pub fn height_normal(t: &crate::model::Terrain, x: f32, y: f32) -> [f32; 3] {
    let sx = t.extent[0] / (t.width - 1).max(1) as f32;
    let sy = t.extent[1] / (t.height - 1).max(1) as f32;
    let dzdx = (t.height_at(x + 0.5 * sx, y) - t.height_at(x - 0.5 * sx, y)) / sx;
    let dzdy = (t.height_at(x, y + 0.5 * sy) - t.height_at(x, y - 0.5 * sy)) / sy;
    glam::Vec3::new(-dzdx, -dzdy, 1.0).normalize().to_array()
}

/// Irradiance at one surface point.
#[allow(clippy::too_many_arguments)]
pub fn texel_irradiance(
    bvh: &dyn SceneTracer,
    albedo: &[[f32; 3]],
    light: &BakeLight,
    sky_irr: &ShIrradiance,
    p: Vec3A,
    n: Vec3A,
    texel: u64,
    opts: &LightmapOptions,
) -> [f32; 3] {
    texel_irradiance_parts(bvh, albedo, light, sky_irr, p, n, texel, opts).0
}

/// [`texel_irradiance`] and its direct-sun part `E_sun · max(0, n·s) · V` (what
/// [`terrain_direct_sun`] recomputes), from one pass.
#[allow(clippy::too_many_arguments)]
fn texel_irradiance_parts(
    bvh: &dyn SceneTracer,
    albedo: &[[f32; 3]],
    light: &BakeLight,
    sky_irr: &ShIrradiance,
    p: Vec3A,
    n: Vec3A,
    texel: u64,
    opts: &LightmapOptions,
) -> ([f32; 3], [f32; 3]) {
    let thesis = opts.mode == LightmapMode::Thesis;
    let origin = p + n * 1e-3;
    let mut e = [0.0f64; 3];
    let mut direct = [0.0f32; 3];
    if let Some((s, irr)) = light.sun {
        let s = Vec3A::from(s);
        let cos = n.dot(s);
        if cos > 0.0 {
            let vis = if thesis {
                1.0
            } else {
                sun_visibility(bvh, origin, s, opts.sun_samples, texel)
            };
            direct = irr.map(|e| e * cos * vis);
            for k in 0..3 {
                e[k] += direct[k] as f64;
            }
        }
    }
    let nsamp = opts.samples.max(1);
    let (tx, bx) = crate::trace::frame(n);
    let shift = if thesis {
        (0.0, 0.0)
    } else {
        cp_rotation(texel)
    };
    for k in 0..nsamp {
        let d = cosine_direction(k, nsamp, shift, (tx, bx, n));
        let l = if thesis {
            light.sky.eval(d.to_array())
        } else {
            match bvh.closest_hit(&Ray::new(origin, d, 1e-4)) {
                None => light.sky.eval(d.to_array()),
                Some(hit) => bounce_radiance(bvh, albedo, light, sky_irr, &hit, d),
            }
        };
        for c in 0..3 {
            e[c] += (l[c].max(0.0) * std::f32::consts::PI / nsamp as f32) as f64;
        }
    }
    (e.map(|v| v as f32), direct)
}

/// Outgoing diffuse radiance of a hit surface lit by the sun (shadowed) and the unoccluded sky.
fn bounce_radiance(
    bvh: &dyn SceneTracer,
    albedo: &[[f32; 3]],
    light: &BakeLight,
    sky_irr: &ShIrradiance,
    hit: &crate::trace::SceneHit,
    d: Vec3A,
) -> [f32; 3] {
    let surf = bvh.surface(hit);
    let mut n = surf.shading_normal;
    if n.dot(d) > 0.0 {
        n = -n;
    }
    let rho = albedo
        .get(hit.instance as usize)
        .copied()
        .unwrap_or([0.3; 3]);
    let mut e = sky_irr.eval(n.to_array()).map(|v| v.max(0.0));
    if let Some((s, irr)) = light.sun {
        let s = Vec3A::from(s);
        let cos = n.dot(s);
        if cos > 0.0 && !bvh.any_hit(&Ray::new(surf.position + n * 1e-3, s, 1e-4)) {
            for k in 0..3 {
                e[k] += irr[k] * cos;
            }
        }
    }
    [0, 1, 2].map(|k| rho[k] / std::f32::consts::PI * e[k])
}

/// Fraction of the sun's disc visible from p: stratified points on the disc, one shadow ray each.
pub fn sun_visibility(bvh: &dyn SceneTracer, p: Vec3A, s: Vec3A, samples: u32, texel: u64) -> f32 {
    disc_visibility(s, samples, texel, |d| !bvh.any_hit(&Ray::new(p, d, 1e-4)))
}

/// The share of `samples` stratified points on the sun's disc around `s` (rotated per texel)
/// whose direction `open` says is unblocked.
fn disc_visibility(s: Vec3A, samples: u32, texel: u64, open: impl Fn(Vec3A) -> bool) -> f32 {
    let n = samples.max(1);
    let disc = Disc::new(s, samples, texel);
    let visible = (0..n).filter(|&k| open(disc.direction(k))).count();
    visible as f32 / n as f32
}

/// The `samples` stratified points on the sun's disc around `s` of one texel
/// ([`disc_visibility`]).
struct Disc {
    s: Vec3A,
    tx: Vec3A,
    bx: Vec3A,
    shift: (f32, f32),
    n: u32,
}

impl Disc {
    fn new(s: Vec3A, samples: u32, texel: u64) -> Disc {
        let (tx, bx) = crate::trace::frame(s);
        Disc {
            s,
            tx,
            bx,
            shift: cp_rotation(texel ^ 0x5u64 << 60),
            n: samples.max(1),
        }
    }

    /// Direction k of the disc's points.
    fn direction(&self, k: u32) -> Vec3A {
        let (u1, u2) = hammersley(k, self.n);
        let (u1, u2) = ((u1 + self.shift.0).fract(), (u2 + self.shift.1).fract());
        // Uniform on the disc of angular radius SUN_RADIUS (small-angle: a flat disc).
        let r = SUN_RADIUS * u1.sqrt();
        let phi = std::f32::consts::TAU * u2;
        (self.s + self.tx * (r * phi.cos()) + self.bx * (r * phi.sin())).normalize()
    }
}

/// Point k of the N-point Hammersley set in [0, 1)².
pub fn hammersley(k: u32, n: u32) -> (f32, f32) {
    (
        (k as f32 + 0.5) / n as f32,
        (k.reverse_bits() as f64 / 4_294_967_296.0) as f32,
    )
}

/// A per-texel Cranley–Patterson shift, from a hash of the texel index.
fn cp_rotation(texel: u64) -> (f32, f32) {
    let h = crate::trace::mix64(texel.wrapping_add(0x1234_5678));
    (
        (h >> 40) as f32 / (1u64 << 24) as f32,
        ((h >> 16) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32,
    )
}

/// The scene's light from its `sh` (sun-free sky) and `sun` sections.
pub fn scene_lighting(pack: &crate::pack::Pack) -> crate::error::Result<BakeLight> {
    let bad = |e| crate::error::Error::invalid(pack.path(), e);
    let (_, sky, _) =
        crate::sky::section::sh_from_section(&pack.view_named(crate::sky::SH_SECTION)?)
            .map_err(bad)?;
    let sun = match pack.find(crate::sky::SUN_SECTION) {
        Some(e) => {
            let s = crate::sky::section::sun_from_section(&pack.view(e)?).map_err(bad)?;
            Some((s.direction, s.irradiance))
        }
        None => None,
    };
    Ok(BakeLight { sky, sun })
}

/// (Tests.) The light-map stage on a pack: a `lightmap` section for the terrain.
#[cfg(test)]
pub(crate) fn lightmap_sections(
    pack: &crate::pack::Pack,
    opts: &LightmapOptions,
) -> crate::error::Result<Vec<crate::pack::Section>> {
    let light = scene_lighting(pack)?;
    let scene = crate::trace::pack_scene::trace_scene(pack)?;
    terrain_sections(&scene, &light, opts)
}

/// The terrain's `lightmap` section over the scene and its light (empty without a terrain): the
/// registered `lightmap` unit.
///
/// The horizon estimator without a filter (the default) writes each band's texels straight into
/// the section's two arrays, so the map (16.8 M × 24 bytes, 403 MB at 4097²) is never held
/// beside them: the default bake's peak at 200,000 instances fell from 2.51 to 2.27 GB (issue 37,
/// docs/PERFORMANCE.md). The bytes are those of [`terrain_sections_of`] over
/// [`bake_terrain_lightmap_parts`].
pub fn terrain_sections(
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
) -> crate::error::Result<Vec<crate::pack::Section>> {
    let streamed = opts.mode == LightmapMode::Physical
        && opts.visibility == LightmapVisibility::Horizons
        && !filters(opts);
    let step = terrain_trace_step(scene, opts);
    if streamed && let Some((w, h)) = terrain_lightmap_size(scene, opts) {
        let bvh = scene.tracer(opts.tracer)?;
        let section = terrain_section_filled(w, h, opts, step, |irradiance, indirect| {
            let mut at = 0;
            horizon_rows_into(scene, bvh, light, opts, 0..h, true, &mut |band| {
                let len = band.len();
                for (k, (e, d, _)) in band.into_iter().enumerate() {
                    irradiance[at + k] = section::rgba(e);
                    indirect[at + k] = section::rgba(section::indirect_of(e, d));
                }
                at += len;
            });
        });
        return Ok(vec![section]);
    }
    let Some((map, direct)) = bake_terrain_lightmap_parts(scene, light, opts)? else {
        return Ok(Vec::new());
    };
    Ok(terrain_sections_of(&map, &direct, opts, step))
}

/// Whether the options filter the map's part without the direct sun.
fn filters(opts: &LightmapOptions) -> bool {
    opts.filter_range > 0.0 && opts.filter_radius > 0
}

/// The terrain light map's section from its texels and their direct-sun part, traced at step
/// `step` ([`terrain_trace_step`]).
pub(crate) fn terrain_sections_of(
    map: &Lightmap,
    direct: &[[f32; 3]],
    opts: &LightmapOptions,
    step: u32,
) -> Vec<crate::pack::Section> {
    let map = match filters(opts) {
        true => std::borrow::Cow::Owned(Lightmap {
            width: map.width,
            height: map.height,
            texels: filter::filter_indirect(
                &map.texels,
                direct,
                map.width as usize,
                opts.filter_radius as usize,
                opts.filter_range,
            ),
        }),
        false => std::borrow::Cow::Borrowed(map),
    };
    assert_eq!(map.texels.len(), direct.len(), "one direct part per texel");
    vec![terrain_section_filled(
        map.width,
        map.height,
        opts,
        step,
        |irradiance, indirect| {
            for (k, (&e, &d)) in map.texels.iter().zip(direct).enumerate() {
                irradiance[k] = section::rgba(e);
                indirect[k] = section::rgba(section::indirect_of(e, d));
            }
        },
    )]
}

/// The terrain light map's section of `w × h` texels traced at step `step`, its metadata from
/// `opts`, whose `irradiance` and `indirect` arrays (RGBA, A = 1) `fill` writes in place.
fn terrain_section_filled(
    w: u32,
    h: u32,
    opts: &LightmapOptions,
    step: u32,
    fill: impl FnOnce(&mut [[f32; 4]], &mut [[f32; 4]]),
) -> crate::pack::Section {
    let meta = section::TerrainLightmapMeta {
        surface: "terrain".into(),
        width: w,
        height: h,
        mode: opts.mode,
        samples: opts.samples,
        sun_samples: opts.sun_samples,
        visibility: opts.visibility,
    };
    let filtered = filters(opts);
    let n = w as usize * h as usize;
    // A filter and a trace step are stated after the fields every reader reads as a prefix;
    // the metadata of a map with neither stays as before.
    let with_filter = |radius, range| section::TerrainLightmapMetaFiltered {
        base: meta.clone(),
        filter_radius: radius,
        filter_range: range,
    };
    let name = "lightmap:terrain";
    if step > 1 {
        let (radius, range) = match filtered {
            true => (opts.filter_radius, opts.filter_range),
            false => (0, 0.0),
        };
        let meta = section::TerrainLightmapMetaStepped {
            filtered: with_filter(radius, range),
            trace_step: step,
        };
        section::to_section_filled(name, &meta, n, fill)
    } else if filtered {
        let meta = with_filter(opts.filter_radius, opts.filter_range);
        section::to_section_filled(name, &meta, n, fill)
    } else {
        section::to_section_filled(name, &meta, n, fill)
    }
}

/// The direct-sun part of every texel of a terrain light map, exactly as
/// [`bake_terrain_lightmap`] and [`texel_irradiance`] add it (same texel positions, normals, ray
/// origins, disc samples and per-texel seeds): `E_sun · max(0, n·s) · V`, V = 1 in thesis mode.
/// The renderer's ambient term is the light map without it (the direct term draws the sun).
/// Traced on the CPU scene (the section does not say which backend baked it; an Embree-baked
/// map's own direct part, stored beside it, differs from this one only by rare float-level
/// hit differences).
pub fn terrain_direct_sun(
    scene: &TraceScene,
    light: &BakeLight,
    meta: &section::LightmapMeta,
    visibility: LightmapVisibility,
) -> Vec<[f32; 3]> {
    let (w, h) = (meta.width, meta.height);
    let (Some(t), Some((s, irr))) = (scene.terrain.as_ref(), light.sun) else {
        return vec![[0.0; 3]; (w * h) as usize];
    };
    let horizons =
        meta.mode == LightmapMode::Physical && visibility == LightmapVisibility::Horizons;
    let grid = horizon::TexelGrid::new(t, w, h);
    let sun_slope = if horizons {
        horizon::Horizons::compute(t, &grid, &[], Some(s), 0..h).sun_slope
    } else {
        Vec::new()
    };
    let reach = Reach::of(scene);
    let beam = sun_beam(scene, light, Tracer::Cpu);
    let sv = Vec3A::from(s);
    (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (i, j) = (k % w, k / w);
            let (x, y) = grid.xy(i, j);
            let n = Vec3A::from(height_normal(t, x, y));
            let cos = n.dot(sv);
            if cos <= 0.0 {
                return [0.0; 3];
            }
            let o = Vec3A::new(x, y, t.mesh_height_at(x, y)) + n * 1e-3;
            let vis = match meta.mode {
                LightmapMode::Thesis => 1.0,
                LightmapMode::Physical if horizons => {
                    let mut v = horizon::sun_fraction(sun_slope[k as usize], s);
                    if v > 0.0 && reach.top.is_some() {
                        v *= instance_sun_visibility(
                            &scene.bvh,
                            &reach,
                            beam.as_ref(),
                            o,
                            sv,
                            meta.sun_samples,
                            k as u64,
                        );
                    }
                    v
                }
                LightmapMode::Physical => {
                    sun_visibility(&scene.bvh, o, sv, meta.sun_samples, k as u64)
                }
            };
            irr.map(|e| e * cos * vis)
        })
        .collect()
}

/// The light maps of the placed meshes: a `lightmap` section `lightmap:<mesh section>` (an atlas,
/// [`atlas_section`]) for every model placed at most `opts.max_instances` times, over the scene
/// and its light (the registered `atlas` unit).
pub fn object_sections(
    pack: &crate::pack::Pack,
    scene: &TraceScene,
    light: &BakeLight,
    opts: &LightmapOptions,
) -> crate::error::Result<Vec<crate::pack::Section>> {
    let bad = |e| crate::error::Error::invalid(pack.path(), e);
    let (imeta, _) = crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
        .map_err(bad)?;
    let bvh = scene.tracer(opts.tracer)?;
    let models: Vec<u32> = scene.instances.items.iter().map(|i| i.model).collect();
    let placed = objects::placed_models(&models, imeta.mesh_sections.len(), opts.max_instances);
    let mut out = Vec::new();
    for (m, instances) in placed {
        let name = &imeta.mesh_sections[m as usize];
        let (_, mesh) = crate::mesh::section::from_section(&pack.view_named(name)?).map_err(bad)?;
        if mesh.indices.is_empty() {
            continue;
        }
        let p = objects::PlacedMesh {
            mesh: &mesh,
            instances: &instances,
        };
        // Seeds above the terrain's texel indices (< 2³²), one stream family per model.
        let seed = crate::trace::mix64((m as u64 + 1) << 40);
        let map = objects::bake_object_lightmap(bvh, &scene.albedo, light, p, seed, opts)
            .map_err(|e| crate::error::Error::runtime(format!("light map of {name}: {e}")))?;
        let meta = atlas_section::AtlasMeta {
            surface: name.clone(),
            width: map.width,
            height: map.height,
            mode: opts.mode,
            samples: opts.samples,
            sun_samples: opts.sun_samples,
            mesh_vertices: mesh.positions.len() as u32,
            instances: map.instances.clone(),
            tile: map.layout.tile,
            columns: map.columns,
            gutter: map.layout.gutter,
            density: map.layout.density,
            texels_covered: map.covered,
            gutter_texels: map.gutter_texels,
        };
        out.push(atlas_section::to_section(
            &format!("lightmap:{name}"),
            &meta,
            &map,
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod stepped_tests {
    #[test]
    fn the_trace_spacing_widens_the_step_by_whole_texels_up_to_eight() {
        let o = |trace_step, trace_spacing| super::LightmapOptions {
            trace_step,
            trace_spacing,
            ..Default::default()
        };
        let d = super::LightmapOptions::DEFAULT;
        // The default: 3.5 m. The fixture's 65² map of 100 m (1.54 m texels) stays at step 2,
        // the theses' scale's 1 m texels (1024 m in 1025 texels) take step 3, the preview's
        // 1025² map of a 4096 m terrain (4 m texels) step 2.
        assert_eq!(d.trace_step_for(100.0 / 65.0), 2);
        assert_eq!(d.trace_step_for(1024.0 / 1025.0), 3);
        assert_eq!(d.trace_step_for(4096.0 / 1025.0), 2);
        assert_eq!(d.trace_step_for(0.01), 8, "at most 8");
        // No bound in metres: the step as given; a step of 1 widened only by a spacing.
        assert_eq!(o(2, 0.0).trace_step_for(0.01), 2);
        assert_eq!(o(1, 0.0).trace_step_for(0.5), 1);
        assert_eq!(o(1, 2.0).trace_step_for(0.5), 4);
        assert_eq!(o(5, 2.0).trace_step_for(0.5), 5);
        for bad in [-1.0, f32::NAN, f32::INFINITY, 1001.0] {
            assert!(o(2, bad).check().is_err(), "{bad}");
        }
    }

    #[test]
    fn stepped_bands_tile_the_rows_and_end_on_traced_rows() {
        for (rows, band, h) in [
            (0..4097, 511, 4097),
            (0..4097, 512, 4097),
            (7..300, 16, 301),
            (1..64, 17, 64),
            (0..65, 512, 65),
        ] {
            for traced in [None, Some((h, 2)), Some((h, 4)), Some((h, 8))] {
                let bands = super::bands_of(rows.clone(), band, traced);
                assert_eq!(bands.first().unwrap().start, rows.start);
                assert_eq!(bands.last().unwrap().end, rows.end);
                for w in bands.windows(2) {
                    assert_eq!(w[0].end, w[1].start);
                }
                for b in &bands[..bands.len() - 1] {
                    assert!(!b.is_empty() && b.len() as u32 <= band, "{b:?}");
                    if let Some((h, step)) = traced {
                        assert!(
                            super::TraceLattice::is_traced(b.end - 1, h, step),
                            "{b:?} of {rows:?}"
                        );
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod beam_tests {
    use super::*;

    /// A generated scene (`bake fixtures --instances 3000 --models 3 --terrain 129`: alpha-leaved
    /// trees on rolling hills, the fixture's sky and sun at 40°) ingested with its sky.
    fn generated() -> (TraceScene, BakeLight) {
        let dir = tempfile::tempdir().unwrap();
        let p = crate::fixtures::large::LargeScene {
            instances: 3000,
            models: 3,
            terrain: 129,
        };
        for (name, bytes) in crate::fixtures::large::large_files(&p) {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let (mut w, _) = crate::pipeline::ingest_to_pack(
            &dir.path().join("scene.eco"),
            &crate::ingest::IngestOptions::default(),
        )
        .unwrap();
        let sky = crate::ingest::skyimage::load(&dir.path().join("sky.hdr")).unwrap();
        for s in crate::sky::scene_sky_sections(
            Some(&sky),
            &Default::default(),
            &crate::sky::SkyOptions::default(),
        )
        .unwrap()
        {
            w.insert(s);
        }
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "generated").unwrap();
        let scene = crate::trace::pack_scene::trace_scene(&pack).unwrap();
        let light = scene_lighting(&pack).unwrap();
        (scene, light)
    }

    fn bits(v: &[[f32; 3]]) -> Vec<[u32; 3]> {
        v.iter().map(|t| t.map(f32::to_bits)).collect()
    }

    #[test]
    fn sun_beam_light_map_is_bit_identical_to_the_top_level_path() {
        let (scene, light) = generated();
        let (s, _) = light.sun.expect("the fixture sky has a sun");
        let sv = Vec3A::from(s);
        let beam = sun_beam(&scene, &light, Tracer::Cpu).expect("a beam");
        let reach = Reach::of(&scene);
        let t = scene.terrain.as_ref().unwrap();
        // Texel by texel: the disc's visibility through the beam and through the top level,
        // over a 257² grid of points raised off the terrain (the light map's ray origins).
        let (mut partial, mut dark) = (0, 0);
        let n = 257u32;
        for k in 0..n * n {
            let (i, j) = (k % n, k / n);
            let x = t.origin[0] + (i as f32 + 0.5) / n as f32 * t.extent[0];
            let y = t.origin[1] + (j as f32 + 0.5) / n as f32 * t.extent[1];
            let nrm = Vec3A::from(height_normal(t, x, y));
            let o = Vec3A::new(x, y, t.mesh_height_at(x, y)) + nrm * 1e-3;
            let new = instance_sun_visibility(&scene.bvh, &reach, Some(&beam), o, sv, 16, k as u64);
            let old = instance_sun_visibility(&scene.bvh, &reach, None, o, sv, 16, k as u64);
            assert_eq!(
                new.to_bits(),
                old.to_bits(),
                "texel {k}: {new} against {old}"
            );
            partial += (new > 0.0 && new < 1.0) as u32;
            dark += (new == 0.0) as u32;
        }
        // Not a vacuous agreement: trees shadow many texels, some only in part.
        assert!(
            partial > 500 && dark > 5000,
            "{partial} partial, {dark} dark"
        );
        // The whole map (at every texel and with a trace step), and the direct-sun part the
        // renderer recomputes, bit for bit against the top level's.
        for trace_step in [1, 2] {
            let opts = LightmapOptions {
                samples: 4,
                trace_step,
                ..Default::default()
            };
            let (w, h) = terrain_lightmap_size(&scene, &opts).unwrap();
            let (new, new_direct) = bake_terrain_lightmap_rows(&scene, &light, &opts, 0..h)
                .unwrap()
                .unwrap();
            let ((old, old_direct), _) =
                horizon_rows_noise(&scene, &scene.bvh, &light, &opts, 0..h, false, false);
            assert_eq!(bits(&new), bits(&old), "trace_step {trace_step}");
            assert_eq!(bits(&new_direct), bits(&old_direct));
            let meta = section::LightmapMeta {
                surface: "terrain".to_string(),
                width: w,
                height: h,
                mode: LightmapMode::Physical,
                samples: opts.samples,
                sun_samples: opts.sun_samples,
            };
            let recomputed =
                terrain_direct_sun(&scene, &light, &meta, LightmapVisibility::Horizons);
            assert_eq!(bits(&recomputed), bits(&old_direct));
        }
    }
}
