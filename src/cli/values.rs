//! Command-line values of the library's option enums: their `clap::ValueEnum`, written here so
//! the library carries no clap derives. Names are the kebab-case variant names (what the
//! derive gave), help the variant's doc line.

use crate::gpu::BackendChoice;
use crate::lightmap::LightmapMode;
use crate::linespace::ntree::Refine;
use crate::prt::transfer::{PrtSides, PrtTracer};
use crate::render::Terms;
use crate::render::ambient::PrtLayout;
use crate::render::svo_view::SvoShow;
use crate::texture::linear::TransferFunction;
use crate::trace::BuildPreset;
use clap::builder::PossibleValue;

macro_rules! value_enum {
    ($ty:ident { $($variant:ident => $name:literal $(: $help:literal)?),+ $(,)? }) => {
        impl clap::ValueEnum for $ty {
            fn value_variants<'a>() -> &'a [Self] {
                &[$($ty::$variant),+]
            }
            fn to_possible_value(&self) -> Option<PossibleValue> {
                Some(match self {
                    $($ty::$variant => PossibleValue::new($name)$(.help($help))?,)+
                })
            }
        }
    };
}

value_enum!(BackendChoice {
    Auto => "auto": "Vulkan, then GL (BAKE_BACKEND=vulkan|gl picks one)",
    Vulkan => "vulkan",
    Gl => "gl",
});

value_enum!(PrtSides {
    Auto => "auto": "The back side only for double-sided materials (glTF doubleSided; every other input)",
    Both => "both": "Front and back of every vertex",
    Front => "front": "The front side only (the back transfer is zero)",
});

value_enum!(Terms {
    All => "all",
    Direct => "direct": "The sun alone: E_sun · visibility · BRDF · cos",
    Ambient => "ambient": "Sky and indirect light alone",
});

value_enum!(PrtLayout {
    Full => "full": "The full-precision transfer (2 sides × 2 sets × 16 RGB per vertex)",
    Packed => "packed": "The thesis' 5 vec4 per side",
});

// By hand for the US spelling's alias.
impl clap::ValueEnum for SvoShow {
    fn value_variants<'a>() -> &'a [Self] {
        &[SvoShow::Colour, SvoShow::Normal, SvoShow::Level]
    }
    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(match self {
            SvoShow::Colour => PossibleValue::new("colour")
                .alias("color")
                .help("The filtered colour, lit"),
            SvoShow::Normal => PossibleValue::new("normal").help("The filtered normal as RGB"),
            SvoShow::Level => PossibleValue::new("level")
                .help("The level each pixel stopped at, as a palette colour"),
        })
    }
}

value_enum!(Refine {
    Shaft => "shaft": "The thesis: a full shaft is a hit (cheapest; over-occludes by up to a shaft's width)",
    Cells => "cells": "Walk the leaves the segment crosses: a hit when one of them holds geometry (over-occludes by up to a leaf cell; reads occupancy bits only)",
    Exact => "exact": "Walk the leaves the segment crosses and test their triangles exactly (no over-occlusion; reads the triangles)",
    Near => "near": "`Shaft`, except in nodes the segment enters within one deepest-node side of its start, where `Exact` decides: the receiver's own surface continuing into the next node is what makes the thesis' rule speckle (docs/PERFORMANCE.md, issue 15)",
});

value_enum!(TransferFunction {
    Srgb => "srgb": "The sRGB curve (what PNG/JPEG files without a profile mean)",
    Gamma22 => "gamma22": "A pure power law with exponent 2.2",
    Linear => "linear": "Already linear (normal maps, data textures)",
});

value_enum!(LightmapMode {
    Physical => "physical",
    Thesis => "thesis",
});

value_enum!(PrtTracer {
    Cpu => "cpu": "obvhs on the CPU threads (bit-reproducible everywhere)",
    Embree => "embree": "Embree 3 (a bake built with the cargo feature embree)",
    Gpu => "gpu": "a wgpu compute shader (deterministic per device, not bit-equal to the CPU)",
});

value_enum!(BuildPreset {
    Fastest => "fastest",
    VeryFast => "very-fast",
    Fast => "fast",
    Medium => "medium",
    Slow => "slow",
    VerySlow => "very-slow",
});

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// The names are the ones the library's own serde and `name` spellings use.
    #[test]
    fn names_match_the_library_spellings() {
        for p in BuildPreset::ALL {
            let v = p.to_possible_value().unwrap();
            assert_eq!(v.get_name(), p.name());
        }
        assert_eq!(BuildPreset::value_variants().len(), BuildPreset::ALL.len());
        assert_eq!(
            TransferFunction::from_str("gamma22", false).unwrap(),
            TransferFunction::Gamma22
        );
        assert_eq!(Refine::from_str("near", false).unwrap(), Refine::Near);
        for (name, show) in [
            ("colour", SvoShow::Colour),
            ("color", SvoShow::Colour),
            ("level", SvoShow::Level),
        ] {
            assert_eq!(SvoShow::from_str(name, false).unwrap(), show);
        }
        let v = SvoShow::Normal.to_possible_value().unwrap();
        assert_eq!(serde_json::json!(SvoShow::Normal), v.get_name());
    }
}
