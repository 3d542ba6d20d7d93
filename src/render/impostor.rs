//! Drawing impostors: where [`crate::lod::select::choose`] gives an instance
//! [`crate::lod::select::Choice::Impostor`], the renderer draws one quad for it,
//! textured with a view of the model's hemi-octahedral atlas (`lod:<model>` section,
//! docs/CONVENTIONS.md "Impostors"), all of a model's impostor instances in one instanced draw
//! (`shaders/impostor.wgsl`, 6 vertices per instance, two triangles).
//!
//! - **Quad:** centre `p + R_z(θ)·(s·c)` (the instance transform applied to the impostor centre
//!   `c`), half size `radius·|s|`, in the image plane of the tile drawn (below): its axes are
//!   the tile's own, `right = normalize(Z × w)`, `up = w × right` of the tile's centre direction
//!   `w` (octa.rs `view_axes`, the axes `lod::impostor::texel_ray` cast the texels along), turned
//!   into the world by R_z(θ), so the picture is the tile's orthographic view, neither turned nor
//!   moved; then drawn turned by the smallest rotation that takes `w` to the direction `v`
//!   towards the eye (about `w × v`, no twist about the view axis), so it faces the eye at its
//!   own size. (Until issue 35's second session the quad faced the eye with axes from the eye's
//!   direction `v`: the picture turned by the azimuth between `v` and `w`, up to tens of degrees
//!   near the zenith, and a far bench was drawn rotated and about a metre off. Until its
//!   eleventh the quad lay in the tile's plane itself, foreshortened by cos e, e the angle
//!   between `v` and `w`: a round model's silhouette lost that share of its pixels.)
//! - **Tile:** the nearest view, no blend: `v` is taken into the instance's model frame (undo the
//!   rotation about +Z; the lower hemisphere clamps to the horizon) and the tile whose centre
//!   direction has the largest dot product with it is drawn ([`nearest_tile`]: the cell that
//!   holds its octahedral coordinates and its 8 neighbours, checked against brute force over all
//!   tiles by tests/render_lod.rs). Nearest texel within the tile (no filtering across tiles).
//! - **Parallax:** each fragment shows the texel the eye's ray meets in the tile's depth atlas,
//!   not the one under the quad's point (`shaders/impostor.wgsl` `march`): in the tile's frame
//!   the ray crosses the image plane at `st₀ + k·δ` at depth offset δ, each texel is a column
//!   from its surface one texel of the ray's sideways travel deep (4 for a solid model), stepped
//!   at half a texel, then refined by halving (docs/CONVENTIONS.md "Impostors"). A picture from
//!   one tile put a surface δ in front of or behind the tile's plane δ·sin e off, e the angle
//!   between the eye and the tile (up to about 15°); along the tile's own direction the two agree.
//! - **Alpha:** the atlas alpha (0 or 255) tested at 0.5, the mesh shader's cutoff.
//! - **Light:** the atlas normal (model space) rotated to the world and turned towards the eye;
//!   the texel's material (the normal's alpha names it; the model's first [`IMPOSTOR_MATERIALS`])
//!   by its two layers with the atlas albedo as the bottom layer's colour, under the sun as
//!   direct.wgsl's `direct_schlick` and under the sky as the mesh path's `ambient_layered`
//!   (the sky's irradiance of each side, its radiance in the mirror direction); a material
//!   without layers or beyond the first 16: the sun by Lambert on the atlas albedo
//!   with the shadow-map lookup of the mesh path (`sun_visibility` of direct.wgsl) at the
//!   surface point the depth atlas gives (the quad point moved by the depth along `w`), moved
//!   towards the sun by the sun tile's angular error times the radius plus a depth step and a
//!   texel (the shadow map's impostor, drawn from that tile, sees the point up to that far off:
//!   without it an impostor shadowed itself), times the model's own shadow from the atlas'
//!   view nearest the sun (the point projected into it, its depth along that view against the
//!   first surface there, within a depth step and a texel); the ambient term is the instance's environment (albedo/π · E(n) through
//!   the layers, E the cosine-convolved maps C_H + C_S of the instance to band 2, their radiance
//!   in the mirror direction): the mesh path's PRT without the transfer, which an impostor has
//!   no vertices to carry (no self-occlusion, but the terrain's and the neighbours' light and
//!   shadow); the sky's for a model without PRT.
//! - **Shadows:** impostor instances cast impostor shadows ([`draw_shadow`], the shadow pass's
//!   one hook): a quad facing the sun with the view nearest the sun's direction in the model
//!   frame, alpha-tested, each fragment at the depth of the surface point its depth texel gives
//!   (so the plant shadows itself roughly as its mesh would).
//! - **Depth:** each fragment writes the depth of the point where its ray met the depth atlas (the
//!   tile-plane point moved by the depth along `w`), not the quad's plane through the centre,
//!   under which a model's front and base lay below the ground beside it; instance scale is
//!   taken by its size (a mirroring negative scale is not mirrored).

use super::draw::{CAMERA_PASS, DrawCounts, FrameInstances};
use super::pipelines;
use super::scene::ImpostorData;
use super::upload::{GpuScene, Uploader};
use crate::error::Result;
use crate::lod::octa;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// The tile (column, row) of an `n × n` atlas whose centre direction is nearest to `w` (the
/// direction towards the eye in the model frame): among the cell holding `w`'s coordinates
/// ([`octa::tile_of`]) and its 8 neighbours, the largest dot product, the first in row-major
/// order on a tie. `z < 0` is clamped to the horizon, a zero direction looks straight down.
/// `shaders/impostor.wgsl` `nearest_tile` is the same function on the GPU.
pub fn nearest_tile(w: Vec3, n: u32) -> (u32, u32) {
    let mut w = Vec3::new(w.x, w.y, w.z.max(0.0));
    if w.length_squared() < 1e-24 {
        w = Vec3::Z;
    }
    let w = w.normalize();
    let (ci, cj) = octa::tile_of(w, n);
    let mut best = (ci, cj);
    let mut best_dot = -2.0f32;
    for dj in -1i64..=1 {
        for di in -1i64..=1 {
            let (i, j) = (ci as i64 + di, cj as i64 + dj);
            if i < 0 || j < 0 || i >= n as i64 || j >= n as i64 {
                continue;
            }
            let d = octa::tile_direction(i as u32, j as u32, n).dot(w);
            if d > best_dot {
                best_dot = d;
                best = (i as u32, j as u32);
            }
        }
    }
    best
}

/// The direction towards the eye in the model frame of an instance rotated by `rotation_deg`
/// about +Z whose impostor centre is at `centre` in the world.
pub fn model_view_direction(eye: Vec3, centre: Vec3, rotation_deg: f32) -> Vec3 {
    let v = (eye - centre).normalize_or(Vec3::Z);
    let (s, c) = rotation_deg.to_radians().sin_cos();
    Vec3::new(c * v.x + s * v.y, -s * v.x + c * v.y, v.z)
}

/// How many of a model's materials the impostor shader lights by their layers (the atlas
/// normal's alpha names one); texels of later materials are Lambertian on the atlas albedo.
pub const IMPOSTOR_MATERIALS: usize = 16;

/// `shaders/impostor.wgsl` `ImpostorMaterials`: 16 + 16 × 112 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ImpostorMaterials {
    count: [u32; 4],
    m: [super::upload::DirectMaterialParams; IMPOSTOR_MATERIALS],
}
const _: () = assert!(size_of::<ImpostorMaterials>() == 16 + 16 * 112);

/// `shaders/impostor.wgsl` `ImpostorParams`: 32 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ImpostorParams {
    centre_radius: [f32; 4],
    grid_tile: [u32; 4],
}

/// One model's atlas on the GPU (group 1 of the impostor pass).
pub struct ImpostorGpu {
    pub bind_group: wgpu::BindGroup,
}

/// The impostor pass's pipeline and its group 1 layout.
pub struct ImpostorPipeline {
    pub layout: wgpu::BindGroupLayout,
    pub pipeline: wgpu::RenderPipeline,
    /// Depth only, into the sun's shadow map (groups 0 and 1).
    pub shadow: wgpu::RenderPipeline,
}

impl ImpostorPipeline {
    pub(super) fn new(
        device: &wgpu::Device,
        globals: &wgpu::BindGroupLayout,
        shadow: &wgpu::BindGroupLayout,
        ambient: &wgpu::BindGroupLayout,
        samples: u32,
        backend: wgpu::Backend,
    ) -> ImpostorPipeline {
        use wgpu::ShaderStages as S;
        let layout = pipelines::layout(
            device,
            "impostor",
            &[
                pipelines::uniform_entry(0, S::VERTEX | S::FRAGMENT),
                pipelines::texture_entry(1, S::FRAGMENT, false),
                pipelines::texture_entry(2, S::FRAGMENT, false),
                pipelines::texture_entry(3, S::FRAGMENT, false),
                pipelines::uniform_entry(4, S::FRAGMENT),
            ],
        );
        let module = pipelines::shader(
            device,
            "impostor",
            &[
                pipelines::COMMON_WGSL,
                pipelines::DIRECT_WGSL,
                pipelines::AMBIENT_WGSL,
                include_str!("shaders/impostor.wgsl"),
            ],
        );
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: size_of::<crate::ingest::instances_section::InstanceRecord>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &pipelines::INSTANCE_ATTRS,
        })];
        let pipeline = pipelines::pipeline(
            device,
            &pipelines::hdr_pass(
                "impostor",
                &module,
                &[Some(globals), Some(&layout), Some(shadow), Some(ambient)],
                &buffers,
                Some(true),
            )
            .multisampled(samples, true)
            .mask_by_sample(backend == wgpu::Backend::Gl),
        );
        let shadow = pipelines::shadow_pipeline(
            device,
            &pipelines::hdr_pass(
                "impostor shadow",
                &module,
                &[Some(globals), Some(&layout)],
                &buffers,
                Some(true),
            ),
            "vs_shadow",
            Some("fs_shadow"),
        );
        ImpostorPipeline {
            layout,
            pipeline,
            shadow,
        }
    }
}

/// Uploads the atlas of a model (`label`: its mesh section): colour (sRGB), normal and depth;
/// `leaves`: the model has alpha-tested materials (the region pass counts it as leaves).
pub(super) fn upload(
    up: &mut Uploader,
    pipe: &ImpostorPipeline,
    label: &str,
    d: &ImpostorData,
    leaves: bool,
    materials: &[super::upload::DirectMaterialParams],
) -> Result<ImpostorGpu> {
    let side = d.meta.side() as u32;
    let chains = atlas_chains(d, side, d.meta.tile);
    let mips = |texels| super::scene::Mips {
        levels: chains.levels.clone(),
        texels,
    };
    let color = up.mips(
        &format!("{label}: impostor colour"),
        &mips(&chains.color),
        wgpu::TextureFormat::Rgba8UnormSrgb,
        4,
    )?;
    let normal = up.mips(
        &format!("{label}: impostor normal"),
        &mips(&chains.normal),
        wgpu::TextureFormat::Rgba8Unorm,
        4,
    )?;
    let depth = up.mips(
        &format!("{label}: impostor depth"),
        &super::scene::Mips {
            levels: chains.levels.clone(),
            texels: &chains.depth,
        },
        wgpu::TextureFormat::R8Unorm,
        1,
    )?;
    let m = &d.meta;
    let params = ImpostorParams {
        centre_radius: [m.centre[0], m.centre[1], m.centre[2], m.radius],
        grid_tile: [m.grid, m.tile, side, u32::from(leaves)],
    };
    let params = up.buffer(
        "impostor params",
        bytemuck::bytes_of(&params),
        wgpu::BufferUsages::UNIFORM,
    );
    let mut mats = ImpostorMaterials::zeroed();
    mats.count[0] = materials.len().min(IMPOSTOR_MATERIALS) as u32;
    for (slot, m) in mats.m.iter_mut().zip(materials) {
        *slot = *m;
    }
    let mats = up.buffer(
        "impostor materials",
        bytemuck::bytes_of(&mats),
        wgpu::BufferUsages::UNIFORM,
    );
    let entry = |binding, resource| wgpu::BindGroupEntry { binding, resource };
    let tex = wgpu::BindingResource::TextureView;
    let bind_group = up.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("impostor"),
        layout: &pipe.layout,
        entries: &[
            entry(0, params.as_entire_binding()),
            entry(1, tex(&color)),
            entry(2, tex(&normal)),
            entry(3, tex(&depth)),
            entry(4, mats.as_entire_binding()),
        ],
    });
    Ok(ImpostorGpu { bind_group })
}

/// An atlas' mip chains (`[width, height, first, count]` per level, then the texels of every
/// level one after another): level 0 is the atlas; a texel of level L stands for the 2^L × 2^L
/// block of level-0 texels below it, down to one texel per tile (the levels while the tile side
/// halves evenly, so no texel mixes two views). Its alpha is the block's coverage,
/// round(255 · the share of level-0 texels whose alpha passes ½ (≥ 128)); its colour the mean
/// of those texels' linear colours (sRGB-encoded again), its normal their mean normal (not
/// renormalized: its length says how far the block's normals spread) with the material (the
/// normal's alpha) most of those texels have (the lowest of the tied; every material from
/// [`IMPOSTOR_MATERIALS`] on counted as one, written 255), its depth code their least (the
/// surface nearest the tile's eye: a mean would put the surface inside the model, in its own
/// shadow); a block without coverage is zero but for its depth code, 255 as an empty level-0
/// texel's (`bake_impostor`): the shader's ray march (`shaders/impostor.wgsl` `march`) reads
/// code 255 as no surface at every level.
pub struct AtlasChains {
    pub levels: Vec<[u32; 4]>,
    pub color: Vec<[u8; 4]>,
    pub normal: Vec<[u8; 4]>,
    pub depth: Vec<u8>,
}

/// The sums of one block's covered level-0 texels.
#[derive(Clone, Copy, Default)]
struct BlockSum {
    n: u32,
    rgb: [f64; 3],
    normal: [f64; 3],
    depth: u8,
    /// Covered level-0 texels per material (the last entry: every material from
    /// [`IMPOSTOR_MATERIALS`] on, which the shader lights alike).
    materials: [u32; IMPOSTOR_MATERIALS + 1],
}

impl BlockSum {
    /// The material of most covered texels (the first of the tied); 255 for the last bucket.
    fn material(&self) -> u8 {
        let mut best = 0;
        for (k, &c) in self.materials.iter().enumerate() {
            if c > self.materials[best] {
                best = k;
            }
        }
        if best == IMPOSTOR_MATERIALS {
            255
        } else {
            best as u8
        }
    }
}

/// [`AtlasChains`] of an atlas of `side`² texels in tiles of `tile`².
pub fn atlas_chains(d: &ImpostorData, side: u32, tile: u32) -> AtlasChains {
    let top = tile.trailing_zeros().min(side.trailing_zeros());
    let mut out = AtlasChains {
        levels: Vec::new(),
        color: Vec::new(),
        normal: Vec::new(),
        depth: Vec::new(),
    };
    let mut sums: Vec<BlockSum> = (0..d.color.len())
        .map(|i| {
            let (c, nm) = (d.color[i], d.normal[i]);
            if c[3] < 128 {
                return BlockSum::default();
            }
            let lin = |k: usize| f64::from(crate::color::srgb_to_linear(f32::from(c[k]) / 255.0));
            let unit = |k: usize| f64::from(nm[k]) / 255.0 * 2.0 - 1.0;
            BlockSum {
                n: 1,
                rgb: [lin(0), lin(1), lin(2)],
                normal: [unit(0), unit(1), unit(2)],
                depth: d.depth[i],
                materials: std::array::from_fn(|k| {
                    u32::from(k == usize::from(nm[3]).min(IMPOSTOR_MATERIALS))
                }),
            }
        })
        .collect();
    let mut w = side;
    for level in 0..=top {
        let per_block = 1u64 << (2 * level);
        out.levels.push([w, w, out.color.len() as u32, w * w]);
        if level == 0 {
            // Level 0 as the atlas holds it.
            out.color.extend_from_slice(&d.color);
            out.normal.extend_from_slice(&d.normal);
            out.depth.extend_from_slice(&d.depth);
        } else {
            for b in &sums {
                if b.n == 0 {
                    out.color.push([0; 4]);
                    out.normal.push([0; 4]);
                    out.depth.push(u8::MAX);
                    continue;
                }
                let n = f64::from(b.n);
                let enc =
                    |l: f64| (crate::color::linear_to_srgb((l / n) as f32) * 255.0).round() as u8;
                let cov = ((u64::from(b.n) * 255 * 2 + per_block) / (2 * per_block)) as u8;
                out.color
                    .push([enc(b.rgb[0]), enc(b.rgb[1]), enc(b.rgb[2]), cov]);
                let q = |k: usize| ((b.normal[k] / n * 0.5 + 0.5) * 255.0).round() as u8;
                out.normal.push([q(0), q(1), q(2), b.material()]);
                out.depth.push(b.depth);
            }
        }
        if level == top {
            break;
        }
        let h = w / 2;
        sums = (0..h * h)
            .map(|i| {
                let (x, y) = (2 * (i % h), 2 * (i / h));
                let kids = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)]
                    .map(|(x, y)| sums[(y * w + x) as usize]);
                let mut s = BlockSum {
                    depth: u8::MAX,
                    ..BlockSum::default()
                };
                for k in kids {
                    s.n += k.n;
                    for c in 0..3 {
                        s.rgb[c] += k.rgb[c];
                        s.normal[c] += k.normal[c];
                    }
                    if k.n > 0 {
                        s.depth = s.depth.min(k.depth);
                    }
                    for (m, c) in s.materials.iter_mut().zip(k.materials) {
                        *m += c;
                    }
                }
                s
            })
            .collect();
        w = h;
    }
    out
}

/// The impostors of shadow pass `p` (bucket pass index): per model with an atlas, its impostor
/// bucket as one instanced draw of sun-facing quads, alpha-tested, at the depth the depth atlas
/// gives. Group 0 (the sun's view) is the shadow pass's. Returns the triangles drawn.
pub(super) fn draw_shadow(
    pass: &mut wgpu::RenderPass,
    pipe: &ImpostorPipeline,
    scene: &GpuScene,
    frame: &FrameInstances,
    p: usize,
) -> u64 {
    let mut triangles = 0;
    let mut bound = false;
    for (k, m) in scene.models.iter().enumerate() {
        let Some(imp) = &m.impostor else {
            continue;
        };
        let range = frame.buckets[k].range(p, m.levels.len());
        if range.is_empty() {
            continue;
        }
        if !bound {
            pass.set_pipeline(&pipe.shadow);
            bound = true;
        }
        pass.set_bind_group(1, &imp.bind_group, &[]);
        pass.set_vertex_buffer(0, frame.buffers[k].slice(..));
        pass.draw(0..6, range.clone());
        triangles += 2 * range.len() as u64;
    }
    triangles
}

/// The camera pass's impostors: per model with an atlas, its impostor bucket (index = its mesh
/// level count) as one instanced draw. Groups 0 and 2 are the scene pass's.
pub(super) fn draw(
    pass: &mut wgpu::RenderPass,
    pipe: &ImpostorPipeline,
    scene: &GpuScene,
    frame: &FrameInstances,
    counts: &mut DrawCounts,
) {
    let mut bound = false;
    for (k, m) in scene.models.iter().enumerate() {
        let Some(imp) = &m.impostor else {
            continue;
        };
        let range = frame.buckets[k].range(CAMERA_PASS, m.levels.len());
        if range.is_empty() {
            continue;
        }
        if !bound {
            pass.set_pipeline(&pipe.pipeline);
            bound = true;
        }
        // The model's ambient group (its instance maps, read by `vs_main`); the terrain's (the
        // sky) where the model has none.
        if let Some(a) = &scene.ambient {
            let group = a.models.get(k).and_then(|l| l.first()?.first());
            pass.set_bind_group(3, group.unwrap_or(&a.terrain), &[]);
        }
        pass.set_bind_group(1, &imp.bind_group, &[]);
        pass.set_vertex_buffer(0, frame.buffers[k].slice(..));
        pass.draw(0..6, range.clone());
        let n = range.len() as u64;
        counts.draw_calls += 1;
        counts.triangles += 2 * n;
        counts.instances += n;
        counts.impostor_instances += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every level of the chains against brute force over the level-0 block below each texel.
    #[test]
    fn the_atlas_chains_are_the_blocks_coverage_mean_colour_normal_nearest_depth_and_main_material()
    {
        let (grid, tile) = (2u32, 8u32);
        let side = grid * tile;
        let n = (side * side) as usize;
        let mut h = 0x9e37_79b9u32;
        let mut next = || {
            h = crate::render::coverage::lowbias32(h.wrapping_add(0x6d2b_79f5));
            h
        };
        let mut d = ImpostorData {
            meta: crate::lod::section::ImpostorMeta {
                layout: crate::lod::section::HEMI_OCTAHEDRAL.into(),
                grid,
                tile,
                centre: [0.0; 3],
                radius: 1.0,
                error: 0.1,
            },
            color: Vec::with_capacity(n),
            normal: Vec::with_capacity(n),
            depth: Vec::with_capacity(n),
        };
        for _ in 0..n {
            let r = next();
            let covered = r % 3 != 0;
            let b = r.to_le_bytes();
            d.color
                .push([b[0], b[1], b[2], if covered { 255 } else { b[3] % 128 }]);
            d.normal.push([b[1], b[2], b[3], (next() % 4) as u8]);
            d.depth.push(next() as u8);
        }
        let c = atlas_chains(&d, side, tile);
        // Levels down to one texel per tile: 16², 8², 4², 2².
        assert_eq!(c.levels.len(), 4);
        for (level, &[w, hh, first, count]) in c.levels.iter().enumerate() {
            assert_eq!((w, hh, count), (side >> level, side >> level, w * w));
            let b = 1u32 << level;
            for y in 0..w {
                for x in 0..w {
                    let at = (first + y * w + x) as usize;
                    let block: Vec<usize> = (0..b * b)
                        .map(|k| ((y * b + k / b) * side + x * b + k % b) as usize)
                        .filter(|&i| d.color[i][3] >= 128)
                        .collect();
                    if level == 0 {
                        assert_eq!(c.color[at], d.color[at]);
                        continue;
                    }
                    let cov = (255.0 * block.len() as f64 / f64::from(b * b)).round() as u8;
                    assert_eq!(c.color[at][3], cov, "level {level} ({x}, {y})");
                    if block.is_empty() {
                        assert_eq!(
                            (c.color[at], c.normal[at], c.depth[at]),
                            ([0; 4], [0; 4], 255)
                        );
                        continue;
                    }
                    let m = block.len() as f64;
                    for k in 0..3 {
                        let lin: f64 = block
                            .iter()
                            .map(|&i| {
                                f64::from(crate::color::srgb_to_linear(
                                    f32::from(d.color[i][k]) / 255.0,
                                ))
                            })
                            .sum::<f64>()
                            / m;
                        let want = crate::color::linear_to_srgb(lin as f32) * 255.0;
                        assert!((f32::from(c.color[at][k]) - want).abs() <= 0.5 + 1e-3);
                        let nm: f64 = block
                            .iter()
                            .map(|&i| f64::from(d.normal[i][k]) / 255.0 * 2.0 - 1.0)
                            .sum::<f64>()
                            / m;
                        let want = (nm * 0.5 + 0.5) * 255.0;
                        assert!((f64::from(c.normal[at][k]) - want).abs() <= 0.5 + 1e-9);
                    }
                    let nearest = block.iter().map(|&i| d.depth[i]).min().unwrap();
                    assert_eq!(c.depth[at], nearest);
                    // The material most of the block's covered texels have (the lowest of the tied).
                    let mut count = [0usize; 4];
                    for &i in &block {
                        count[usize::from(d.normal[i][3])] += 1;
                    }
                    let most = (0..4)
                        .max_by_key(|&k| (count[k], std::cmp::Reverse(k)))
                        .unwrap();
                    assert_eq!(
                        usize::from(c.normal[at][3]),
                        most,
                        "level {level} ({x}, {y})"
                    );
                }
            }
        }
    }
}
