//! Kind `bittree`: instance positions as a BitTree, with scale, rotation, model and layer stored
//! beside the bits in leaf order.

use super::{BitTree, BitTreeOptions, decode_bittree, encode_bittree};
use crate::error::ParseError;
use crate::model::{Instances, Rect};
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "bittree";
/// Bytes per instance of the explicit layout the thesis compares with (x, y, z, scale, rotation as f32).
pub const EXPLICIT_BYTES: u64 = 20;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BitTreeMeta {
    pub area: Rect,
    pub children: u32,
    pub levels: u32,
    pub count: u64,
    pub bit_len: u64,
    /// Model names, indexed by the `model` array.
    pub models: Vec<String>,
}

/// The area the graph's and `bake bittree`'s BitTree discretizes: the instances' x/y bounds
/// joined with the scene's area of interest where known (`aoi`: the ECO files' GEOREF, which no
/// section records; a pack alone gives `None`), widened by a millimetre so the maximum lies
/// inside. Without instances the bounds are the unit square. One formula for both: with the
/// area of interest inside the instances' bounds, a pack alone gives the graph's area.
pub fn area_of(inst: &Instances, aoi: Option<Rect>) -> Rect {
    let pts: Vec<[f32; 3]> = inst.items.iter().map(|i| i.position).collect();
    let (lo, hi) = crate::model::bounds_of(&pts).unwrap_or(([0.0; 3], [1.0; 3]));
    let (mut x0, mut y0, mut x1, mut y1) = (lo[0], lo[1], hi[0], hi[1]);
    if let Some(a) = aoi {
        x0 = a.origin[0].min(x0);
        y0 = a.origin[1].min(y0);
        x1 = (a.origin[0] + a.extent[0]).max(x1);
        y1 = (a.origin[1] + a.extent[1]).max(y1);
    }
    let pad = 1e-3;
    let (x0, y0, x1, y1) = (x0 - pad, y0 - pad, x1 + pad, y1 + pad);
    Rect {
        origin: [x0, y0],
        extent: [x1 - x0, y1 - y0],
    }
}

/// Encodes a scene's instances. Rotation is quantized to 65536 steps per turn (0.0055°).
pub fn to_section(
    name: &str,
    inst: &Instances,
    area: Rect,
    opts: &BitTreeOptions,
) -> Result<Section, String> {
    let pts: Vec<[f32; 2]> = inst
        .items
        .iter()
        .map(|i| [i.position[0], i.position[1]])
        .collect();
    let (tree, order) = encode_bittree(&pts, area, opts).map_err(|e| e.to_string())?;
    let mut scale = Vec::with_capacity(order.len());
    let mut rotation = Vec::with_capacity(order.len());
    let mut model = Vec::with_capacity(order.len());
    let mut layer = Vec::with_capacity(order.len());
    let mut residual = Vec::with_capacity(order.len());
    let cells = (side_of(tree.children) as f64).powi(tree.levels as i32);
    for &k in &order {
        let i = &inst.items[k as usize];
        residual.push(encode_residual(
            [i.position[0], i.position[1]],
            &area,
            cells,
        ));
        scale.push(i.scale);
        rotation.push((i.rotation_deg.rem_euclid(360.0) / 360.0 * 65536.0).round() as u32 as u16);
        model.push(
            u16::try_from(i.model).map_err(|_| format!("instance {k}: more than 65536 models"))?,
        );
        layer.push(
            u16::try_from(i.layer)
                .map_err(|_| format!("instance {k}: layer {} outside 0..65535", i.layer))?,
        );
    }
    let meta = BitTreeMeta {
        area,
        children: tree.children,
        levels: tree.levels,
        count: tree.count,
        bit_len: tree.bit_len,
        models: inst.models.clone(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("bits", ArrayFormat::U8, 1, &tree.bits)
        .array("scale", ArrayFormat::F32, 1, &scale)
        .array("rotation", ArrayFormat::U16, 1, &rotation)
        .array("model", ArrayFormat::U16, 1, &model)
        .array("layer", ArrayFormat::U16, 1, &layer)
        .array("residual", ArrayFormat::U16, 2, &residual);
    if !tree.shared.is_empty() {
        b.array("shared", ArrayFormat::U32, 1, &tree.shared);
    }
    Ok(b.finish())
}

/// Steps of the `residual` array across a leaf cell, per axis.
pub const RESIDUAL_STEPS: f64 = 65536.0;

fn side_of(children: u32) -> u32 {
    match children {
        4 => 2,
        16 => 4,
        _ => 8,
    }
}

/// The position of `p` within its leaf cell of a `cells` × `cells` grid over `area`, in
/// [`RESIDUAL_STEPS`] steps per axis (clamped into the area like the cell itself).
fn encode_residual(p: [f32; 2], area: &Rect, cells: f64) -> [u16; 2] {
    [0, 1].map(|k| {
        let t = ((p[k] - area.origin[k]) as f64 / area.extent[k] as f64).clamp(0.0, 1.0) * cells;
        let c = t.floor().min(cells - 1.0);
        ((t - c) * RESIDUAL_STEPS)
            .floor()
            .clamp(0.0, RESIDUAL_STEPS - 1.0) as u16
    })
}

/// The decoded position of a point whose leaf cell has centre `centre` and size `cell`, from its
/// residual: the middle of its residual step, within `cell / 2¹⁷` of the encoded position.
fn decode_residual(centre: [f32; 2], cell: [f64; 2], q: [u16; 2]) -> [f32; 2] {
    [0, 1].map(|k| {
        let lo = centre[k] as f64 - 0.5 * cell[k];
        (lo + (q[k] as f64 + 0.5) / RESIDUAL_STEPS * cell[k]) as f32
    })
}

/// Decoded instances: (x, y) positions (the leaf cell's centre moved by the instance's residual,
/// within `cell / 2¹⁷` of the encoded position; the cell centre for a section without a
/// `residual` array), scale, rotation in degrees, model, layer.
pub struct Decoded {
    pub meta: BitTreeMeta,
    pub positions: Vec<[f32; 2]>,
    pub scale: Vec<f32>,
    pub rotation_deg: Vec<f32>,
    pub model: Vec<u16>,
    pub layer: Vec<u16>,
}

pub fn from_section(v: &SectionView) -> Result<Decoded, ParseError> {
    let meta: BitTreeMeta = v.meta()?;
    let bits: Vec<u8> = v.array_vec("bits")?;
    // Absent when every instance has its own leaf (so packs without coincident instances keep
    // the bytes they had before the array existed).
    let shared: Vec<u32> = if v.info("shared").is_some() {
        v.array_vec("shared")?
    } else {
        Vec::new()
    };
    let tree = BitTree {
        area: meta.area,
        children: meta.children,
        levels: meta.levels,
        count: meta.count,
        bits,
        bit_len: meta.bit_len,
        shared,
    };
    if ![4, 16, 64].contains(&tree.children) || tree.levels > 63 {
        return Err(ParseError::new(
            "bittree section",
            format!("{} children, {} levels", tree.children, tree.levels),
        ));
    }
    let mut positions =
        decode_bittree(&tree).map_err(|e| ParseError::new("bittree section", e.to_string()))?;
    if v.info("residual").is_some() {
        let residual: Vec<[u16; 2]> = v.array_vec("residual")?;
        if residual.len() != positions.len() {
            return Err(ParseError::new(
                "bittree section",
                format!(
                    "{} residuals for {} instances",
                    residual.len(),
                    positions.len()
                ),
            ));
        }
        let cells = (side_of(tree.children) as f64).powi(tree.levels as i32);
        let cell = [0, 1].map(|k| tree.area.extent[k] as f64 / cells);
        for (p, q) in positions.iter_mut().zip(&residual) {
            *p = decode_residual(*p, cell, *q);
        }
    }
    let scale: Vec<f32> = v.array_vec("scale")?;
    let rotation: Vec<u16> = v.array_vec("rotation")?;
    let model: Vec<u16> = v.array_vec("model")?;
    let layer: Vec<u16> = v.array_vec("layer")?;
    let n = positions.len();
    if [scale.len(), rotation.len(), model.len(), layer.len()]
        .iter()
        .any(|&l| l != n)
    {
        return Err(ParseError::new(
            "bittree section",
            "attribute arrays differ in length from the leaf count",
        ));
    }
    let rotation_deg = rotation
        .iter()
        .map(|&r| r as f32 * 360.0 / 65536.0)
        .collect();
    Ok(Decoded {
        meta,
        positions,
        scale,
        rotation_deg,
        model,
        layer,
    })
}

fn stored_bytes(v: &SectionView) -> u64 {
    v.arrays.iter().map(|a| a.byte_len()).sum()
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta: BitTreeMeta = v.meta()?;
    let side = match meta.children {
        4 => 2.0,
        16 => 4.0,
        _ => 8.0,
    };
    let cells = f64::powi(side, meta.levels as i32);
    let bytes = stored_bytes(v);
    let per = if meta.count > 0 {
        bytes as f64 / meta.count as f64
    } else {
        0.0
    };
    Ok(json!({
        "instances": meta.count, "children": meta.children, "levels": meta.levels, "bytes": bytes,
        "shared_leaf_instances": v.info("shared").map_or(0, |a| a.count),
        "position_bytes": meta.bit_len.div_ceil(8),
        "cell_size": [meta.area.extent[0] as f64 / cells, meta.area.extent[1] as f64 / cells],
        "residual_bytes": v.info("residual").map_or(0, |a| a.byte_len()),
        "position_error_max": if v.info("residual").is_some() {
            json!([meta.area.extent[0] as f64 / cells / (2.0 * RESIDUAL_STEPS),
                   meta.area.extent[1] as f64 / cells / (2.0 * RESIDUAL_STEPS)])
        } else {
            json!([meta.area.extent[0] as f64 / cells / 2.0, meta.area.extent[1] as f64 / cells / 2.0])
        },
        "bytes_per_instance": per, "explicit_bytes": meta.count * EXPLICIT_BYTES,
        "ratio_to_explicit": if meta.count > 0 { bytes as f64 / (meta.count * EXPLICIT_BYTES) as f64 } else { 0.0 },
    }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let d = from_section(v)?;
    let list: Vec<Value> = (0..d.positions.len())
        .map(|k| json!({"position": d.positions[k], "scale": d.scale[k], "rotation_deg": d.rotation_deg[k],
                        "model": d.meta.models.get(d.model[k] as usize), "layer": d.layer[k]}))
        .collect();
    Ok(json!({ "instances": list }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Instance;
    use crate::pack::PackWriter;

    /// Drawn = lit (issue 35): with coarse leaf cells (2 levels of 16 children over 64 m: 4 m
    /// cells, many instances per leaf) every decoded position lies within cell/2¹⁷ of its
    /// instance, in leaf order; without the residual it was the cell centre, up to 2.8 m away.
    #[test]
    fn residuals_put_every_decoded_instance_within_a_residual_step_of_its_position() {
        let mut rng = crate::rng::Rng::new(11);
        let items: Vec<Instance> = (0..2000)
            .map(|k| Instance {
                model: k % 5,
                position: [3.0 + rng.f32() * 64.0, -7.0 + rng.f32() * 64.0, 0.0],
                scale: 1.0,
                rotation_deg: 0.0,
                layer: 0,
            })
            .collect();
        let inst = Instances {
            models: (0..5).map(|k| format!("m{k}")).collect(),
            items: items.clone(),
        };
        let area = Rect {
            origin: [3.0, -7.0],
            extent: [64.0, 64.0],
        };
        let opts = BitTreeOptions {
            children: 16,
            max_levels: 2,
        };
        let mut w = PackWriter::new();
        w.insert(to_section("bittree", &inst, area, &opts).unwrap());
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
        let d = from_section(&pack.view_named("bittree").unwrap()).unwrap();
        assert_eq!(d.meta.levels, 2);
        let xy: Vec<[f32; 2]> = items
            .iter()
            .map(|i| [i.position[0], i.position[1]])
            .collect();
        let order = crate::bittree::leaf_order(&xy, &area, 16, 2);
        let cell = 64.0 / 16.0;
        let bound = cell / 131072.0 + 1e-5;
        let mut worst = 0.0f32;
        for (k, &i) in order.iter().enumerate() {
            let (got, want) = (d.positions[k], xy[i as usize]);
            worst = worst.max((got[0] - want[0]).abs().max((got[1] - want[1]).abs()));
            assert_eq!(d.model[k] as u32, items[i as usize].model);
        }
        assert!(worst <= bound, "worst {worst} m, bound {bound} m");
        let s = summary(&pack.view_named("bittree").unwrap()).unwrap();
        assert_eq!(s["residual_bytes"], 2000 * 4);
        assert!(s["position_error_max"][0].as_f64().unwrap() <= 0.01);
    }

    #[test]
    fn section_round_trip_keeps_attributes_in_leaf_order() {
        let mut rng = crate::rng::Rng::new(5);
        let items: Vec<Instance> = (0..300)
            .map(|k| Instance {
                model: k % 3,
                position: [rng.f32() * 40.0, rng.f32() * 40.0, 0.0],
                scale: 0.5 + rng.f32(),
                rotation_deg: rng.f32() * 360.0,
                layer: (k % 2) as i32,
            })
            .collect();
        let inst = Instances {
            models: vec!["a".into(), "b".into(), "c".into()],
            items: items.clone(),
        };
        let area = Rect {
            origin: [0.0, 0.0],
            extent: [40.0, 40.0],
        };
        let mut w = PackWriter::new();
        w.insert(to_section("bittree", &inst, area, &BitTreeOptions::default()).unwrap());
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
        let d = from_section(&pack.view_named("bittree").unwrap()).unwrap();
        let cell = 40.0 / 4f32.powi(d.meta.levels as i32);
        // Match each decoded instance to its original by attributes + position within the cell.
        for k in 0..d.positions.len() {
            let p = d.positions[k];
            let orig = items
                .iter()
                .find(|i| {
                    (i.position[0] - p[0]).abs() <= cell * 0.5001
                        && (i.position[1] - p[1]).abs() <= cell * 0.5001
                })
                .expect("an original within half a cell");
            assert_eq!(orig.scale, d.scale[k]);
            assert_eq!(orig.model, d.model[k] as u32);
            assert_eq!(orig.layer, d.layer[k] as i32);
            assert!(
                (orig.rotation_deg - d.rotation_deg[k]).abs() < 0.006
                    || (orig.rotation_deg - d.rotation_deg[k]).abs() > 359.99
            );
        }
        let s = summary(&pack.view_named("bittree").unwrap()).unwrap();
        assert_eq!(s["instances"], 300);
        assert_eq!(s["shared_leaf_instances"], 0);
        assert!(s["bytes"].as_u64().unwrap() < 300 * EXPLICIT_BYTES);
        assert!(pack.view_named("bittree").unwrap().info("shared").is_none());

        // Coincident instances: the `shared` array carries them; each decodes at its twin's cell
        // with its own attributes.
        let mut twins = inst.clone();
        for k in [3usize, 3, 150] {
            let mut i = twins.items[k];
            i.scale += 10.0;
            twins.items.push(i);
        }
        let mut w = PackWriter::new();
        w.insert(to_section("bittree", &twins, area, &BitTreeOptions::default()).unwrap());
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
        let d = from_section(&pack.view_named("bittree").unwrap()).unwrap();
        assert_eq!(d.positions.len(), 303);
        let s = summary(&pack.view_named("bittree").unwrap()).unwrap();
        assert_eq!(s["shared_leaf_instances"], 3);
        let cell = 40.0 / 4f32.powi(d.meta.levels as i32);
        for (k, orig) in twins.items.iter().enumerate().skip(300) {
            let j = d.scale.iter().position(|&x| x == orig.scale).unwrap();
            let p = d.positions[j];
            assert!((orig.position[0] - p[0]).abs() <= cell * 0.5001, "{k}");
            assert!((orig.position[1] - p[1]).abs() <= cell * 0.5001, "{k}");
        }
    }
}
