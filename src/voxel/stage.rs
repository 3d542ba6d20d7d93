//! The `svo` stage: the sparse voxel octree of the placed scene (its registry line is in
//! `crate::graph::stage::REGISTRY`).

use crate::pack::section::ArrayFormat::{U8, U32};
use crate::stage::kind::{Naming, SectionKind};

use crate::diag::Diagnostic;
use crate::error::Result;
use crate::stage::{
    GEOMETRY, Output, Per, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs, Warning,
};

/// 2: voxel colours from the linear albedo (issue 35).
/// 3: the two-level `svo-scene` section's top level carries filtered attributes (section
/// version 2, issue 39).
/// 4: the terrain's voxels in the top level's aggregates (section version 3, issue 39).
pub const VERSION: u32 = 4;

/// The sparse voxel octree of the placed scene (`svo`): the flattened `svo` where the placed
/// scene fits the memory budget, else the two-level `svo-scene` (one octree per model).
pub struct Svo;
impl Stage for Svo {
    type Options = crate::voxel::voxelize::VoxelizeOptions;
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    /// On in the final pipeline only (the whole placed scene: large scenes make it large).
    fn on_in(&self, preset: Preset) -> bool {
        preset == Preset::Final
    }
    fn options_in(&self, _: Preset) -> Self::Options {
        crate::voxel::voxelize::VoxelizeOptions::surface(256)
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "svo",
            version: VERSION,
            per: Per::Scene,
            writes: &["svo", "svo-scene"],
            actions: &["svo"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: GEOMETRY,
            ..Reads::default()
        }
    }
    /// The options and the scene's source (the section records it), the sections, and the
    /// two-level choice (only when two-level, so the flattened units' keys are as before).
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o).options(&u.scope.source).inputs();
        if crate::voxel::geometry::placed_size(u.view())?.svo_two_level(u.scope.limits) {
            k.options(&"two-level");
        }
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let s = cx.scope;
        let (sec, report, left) =
            crate::voxel::geometry::pack_svo_section(cx.view(), o, s.limits, s.first, s.source)?;
        let mut warnings = Vec::new();
        if left.skipped_triangles > 0 {
            warnings.push(Warning::new(
                &SVO_TRIANGLES_WITHOUT_VOXEL,
                "",
                format!(
                    "{} triangles left no voxel (outside the grid or alpha-tested away)",
                    left.skipped_triangles
                ),
            ));
        }
        if left.open_columns > 0 {
            warnings.push(Warning::new(
                &SVO_MESH_NOT_CLOSED,
                "",
                format!(
                    "solid fill: {} columns crossed the surface an odd number of times \
                     (mesh not closed)",
                    left.open_columns
                ),
            ));
        }
        Ok(Output {
            report,
            sections: vec![sec],
            warnings,
            ..Default::default()
        })
    }
}

/// The section kinds the `svo` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[
    SectionKind {
        kind: crate::voxel::section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("nodes", &[U32], 4),
            ("leaves", &[U8], 1),
            ("voxel_colors", &[U32], 1),
            ("node_colors", &[U32], 1),
            ("voxel_normals", &[U32], 1),
            ("node_normals", &[U32], 1),
        ],
        decode: |v| crate::voxel::section::from_section(v).map(drop),
        views: Some((crate::voxel::section::summary, crate::voxel::section::data)),
        check: None,
    },
    SectionKind {
        kind: crate::voxel::instanced_section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("nodes", &[U32], 4),
            ("leaves", &[U8], 1),
            ("voxel_colors", &[U32], 1),
            ("voxel_normals", &[U32], 1),
            ("node_colors", &[U32], 1),
            ("node_normals", &[U32], 1),
            ("instances", &[U32], 8),
            ("cell_start", &[U32], 1),
            ("cell_instances", &[U32], 1),
            ("top_nodes", &[U32], 4),
            ("top_colors", &[U32], 1),
            ("top_normals", &[U32], 1),
        ],
        decode: |v| crate::voxel::instanced_section::from_section(v).map(drop),
        views: Some((
            crate::voxel::instanced_section::summary,
            crate::voxel::instanced_section::data,
        )),
        check: None,
    },
];

/// `svo.triangles-without-voxel`.
pub const SVO_TRIANGLES_WITHOUT_VOXEL: Diagnostic = Diagnostic::warning(
    "svo.triangles-without-voxel",
    "triangles outside the grid or alpha-tested away left no voxel",
);
/// `svo.mesh-not-closed`.
pub const SVO_MESH_NOT_CLOSED: Diagnostic = Diagnostic::warning(
    "svo.mesh-not-closed",
    "solid fill: columns crossed the surface an odd number of times (the mesh is not closed)",
);

/// The warnings the `svo` stage gives (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[SVO_TRIANGLES_WITHOUT_VOXEL, SVO_MESH_NOT_CLOSED];
