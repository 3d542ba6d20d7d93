//! The keyframer: the node hierarchy of 0xB010 as assimp builds it, the first key of each
//! track, and the transform that places each object (mesh matrix undone, node applied).

use super::*;

/// The 0x4160 matrix: four columns of three floats (x axis, y axis, z axis, translation).
pub(super) fn mesh_matrix(m: &[f32; 12]) -> Mat4 {
    Mat4::from_cols(
        Vec3::new(m[0], m[1], m[2]).extend(0.0),
        Vec3::new(m[3], m[4], m[5]).extend(0.0),
        Vec3::new(m[6], m[7], m[8]).extend(0.0),
        Vec3::new(m[9], m[10], m[11]).extend(1.0),
    )
}

/// 0xB010: a node's name and hierarchy position, placed in the tree the way assimp's
/// `ParseHierarchyChunk` does (its heuristic decides parents, so we reproduce it exactly).
pub(super) fn kf_name(f: &mut File3ds, kind: u16, cur: &mut Cur) -> Result<(), ParseError> {
    let name = cur.cstr();
    if let Some(found) = find_node(&f.nodes, 0, &name)
        && kind != KF_OBJECT
    {
        f.current = found;
        return Ok(());
    }
    cur.skip(4, "node flags")?;
    // assimp adds 1 in 16 bits: "no parent" (0xFFFF) becomes 0.
    let hierarchy = cur.u16("node hierarchy")?.wrapping_add(1) as i32;
    let node = f.nodes.len();
    f.nodes.push(Node {
        name,
        hierarchy_pos: hierarchy,
        ..Node::default()
    });
    let current = f.current;
    if current != 0 && f.nodes[current].hierarchy_pos == hierarchy {
        let parent = f.nodes[current].parent.unwrap_or(0);
        attach(f, parent, node);
        f.last_index += 1;
    } else if hierarchy >= f.last_index {
        attach(f, current, node);
        f.last_index = hierarchy;
    } else {
        let mut at = Some(current);
        let parent = loop {
            match at {
                None => break 0,
                Some(a) if f.nodes[a].hierarchy_pos == hierarchy => {
                    break f.nodes[a].parent.unwrap_or(a);
                }
                Some(a) => at = f.nodes[a].parent,
            }
        };
        attach(f, parent, node);
        f.last_index += 1;
    }
    f.current = node;
    Ok(())
}

pub(super) fn attach(f: &mut File3ds, parent: usize, child: usize) {
    f.nodes[child].parent = Some(parent);
    f.nodes[parent].children.push(child);
}

/// Depth-first search by name from `at` (names compare case-sensitively, as in assimp).
pub(super) fn find_node(nodes: &[Node], at: usize, name: &str) -> Option<usize> {
    let mut stack = vec![at];
    while let Some(n) = stack.pop() {
        if nodes[n].name == name {
            return Some(n);
        }
        stack.extend(nodes[n].children.iter().rev());
    }
    None
}

/// Reads a key track (`u16 flags, 8 bytes, count, keys`) and returns its earliest key (first
/// among equal frames), which is the one assimp uses for the node transform. Nothing is
/// allocated: every key is checked against the chunk as it is read.
pub(super) fn first_key<T>(
    cur: &mut Cur,
    u16_count: bool,
    mut value: impl FnMut(&mut Cur) -> Result<T, ParseError>,
) -> Result<Option<(u32, T)>, ParseError> {
    cur.skip(10, "track header")?;
    let n = if u16_count {
        let n = cur.u16("key count")? as u32;
        cur.skip(2, "key count")?;
        n
    } else {
        cur.u32("key count")?
    };
    let mut best: Option<(u32, T)> = None;
    for _ in 0..n {
        let frame = cur.u32("key frame")?;
        let flags = cur.u16("key flags")?;
        // Tension, continuity, bias, ease to, ease from: 4 bytes each when flagged.
        cur.skip(4 * (flags & 0x1F).count_ones() as usize, "key spline data")?;
        let v = value(cur)?;
        if best.as_ref().is_none_or(|(t, _)| frame < *t) {
            best = Some((frame, v));
        }
    }
    Ok(best)
}

/// A node's own transform from its first keys (assimp `AddNodeToGraph`).
pub(super) fn node_transform(n: &Node) -> Mat4 {
    let mut m = if let Some((_, angle, axis)) = n.rot {
        let axis = if axis == Vec3::ZERO { Vec3::Y } else { axis };
        // assimp negates w of the axis-angle quaternion: a rotation by -angle.
        Mat4::from_mat3(Mat3::from_axis_angle(axis.normalize(), -angle))
    } else if let Some((_, roll)) = n.roll {
        Mat4::from_rotation_z(-roll.to_radians())
    } else {
        Mat4::IDENTITY
    };
    if let Some((_, s)) = n.scale {
        let s = Vec3::select(s.cmpeq(Vec3::ZERO), Vec3::ONE, s);
        m.x_axis *= s.x;
        m.y_axis *= s.y;
        m.z_axis *= s.z;
        m.x_axis.w = 0.0;
        m.y_axis.w = 0.0;
        m.z_axis.w = 0.0;
    }
    if let Some((_, p)) = n.pos {
        m.w_axis += p.extend(0.0);
    }
    m
}

/// World transforms of all nodes, and the depth-first order in which assimp visits them.
pub(super) fn node_worlds(nodes: &[Node]) -> (Vec<Mat4>, Vec<usize>) {
    let mut world = vec![Mat4::IDENTITY; nodes.len()];
    let mut order = Vec::with_capacity(nodes.len());
    let mut stack = vec![(0usize, Mat4::IDENTITY)];
    while let Some((n, parent)) = stack.pop() {
        world[n] = parent * node_transform(&nodes[n]);
        order.push(n);
        for &c in nodes[n].children.iter().rev() {
            stack.push((c, world[n]));
        }
    }
    (world, order)
}

/// The transform taking an object's stored vertices to model space (see the file comment).
pub(super) fn object_transform(
    f: &File3ds,
    o: &Object,
    placement: Option<(Mat4, Vec3)>,
    warn: &mut Warnings,
) -> Mat4 {
    let scale = if f.master_scale != 0.0 && f.master_scale.is_finite() {
        Mat4::from_scale(Vec3::splat(1.0 / f.master_scale))
    } else {
        Mat4::IDENTITY
    };
    let Some((world, pivot)) = placement else {
        return scale;
    };
    let m = o.matrix.unwrap_or(Mat4::IDENTITY);
    let det = m.determinant();
    let inv = if det != 0.0 && det.is_finite() {
        m.inverse()
    } else {
        warn.push(format!(
            "object {:?}: mesh matrix (0x4160) is singular; vertices used as stored",
            o.name
        ));
        Mat4::IDENTITY
    };
    let flip = if det < 0.0 {
        Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))
    } else {
        Mat4::IDENTITY
    };
    scale * world * Mat4::from_translation(-pivot) * flip * inv
}
