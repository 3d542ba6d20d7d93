//! Mesh building: the placed objects merged into one mesh with the file's materials, normals
//! from the smoothing groups.

use super::*;

/// Merges the objects into one mesh with the file's materials.
pub(super) fn build_mesh(f: File3ds, warn: &mut Warnings) -> Result<Mesh, ParseError> {
    let (world, order) = node_worlds(&f.nodes);
    let has_hierarchy = !f.nodes[0].children.is_empty();
    let mut materials: Vec<Material> = Vec::with_capacity(f.materials.len() + 1);
    let mut textures: Vec<TextureRef> = Vec::new();
    for raw in &f.materials {
        let mut m = raw.material.clone();
        if let Some(name) = &raw.texture {
            let i = match textures.iter().position(|t| &t.name == name) {
                Some(i) => i,
                None => {
                    textures.push(TextureRef {
                        name: name.clone(),
                        path: PathBuf::from(name),
                    });
                    textures.len() - 1
                }
            };
            m.color_map = Some(i as u32);
        }
        materials.push(m);
    }
    let default_material = materials.len() as u32;
    let mut used_default = false;
    let mut mesh = Mesh::default();
    for o in &f.objects {
        let placement = if has_hierarchy {
            let node = order
                .iter()
                .copied()
                .find(|&n| n != 0 && f.nodes[n].name == o.name);
            if node.is_none() && !o.faces.is_empty() {
                warn.push(format!(
                    "object {:?} is not in the keyframer hierarchy; kept as stored",
                    o.name
                ));
            }
            node.map(|n| (world[n], f.nodes[n].pivot))
        } else {
            None
        };
        let t = object_transform(&f, o, placement, warn);
        let part = object_mesh(o, t, &materials, default_material, warn);
        used_default |= part.triangle_materials.contains(&default_material);
        if !part.indices.is_empty() {
            mesh.objects.push(o.name.clone());
            mesh.append(part);
        }
    }
    if mesh.indices.is_empty() {
        return Err(ParseError::new(
            "file",
            format!(
                "no triangles: {} objects, none with faces that refer to existing vertices",
                f.objects.len()
            ),
        ));
    }
    if used_default {
        materials.push(Material {
            name: "default".into(),
            ..Material::default()
        });
    }
    mesh.materials = materials;
    mesh.textures = textures;
    Ok(mesh)
}

/// One object's triangles: transformed, with smoothing-group normals and flipped v.
pub(super) fn object_mesh(
    o: &Object,
    t: Mat4,
    materials: &[Material],
    default_material: u32,
    warn: &mut Warnings,
) -> Mesh {
    let nv = o.positions.len();
    let positions: Vec<Vec3> = o
        .positions
        .iter()
        .map(|p| t.transform_point3(Vec3::from_array(*p)))
        .collect();
    let mut faces = Vec::with_capacity(o.faces.len());
    let mut dropped = 0;
    for (i, face) in o.faces.iter().enumerate() {
        if face.iter().any(|&v| v as usize >= nv) {
            dropped += 1;
            continue;
        }
        let m = o
            .face_materials
            .get(i)
            .copied()
            .flatten()
            .unwrap_or(default_material);
        faces.push((i, *face, m));
    }
    if dropped > 0 {
        warn.push(format!(
            "object {:?}: {dropped} of {} faces refer to vertices past {nv}; dropped",
            o.name,
            o.faces.len()
        ));
    }
    let textured = faces.iter().any(|f| {
        materials
            .get(f.2 as usize)
            .is_some_and(|m| m.color_map.is_some())
    });
    if textured && o.uvs.len() < nv {
        warn.push(format!(
            "object {:?}: {} texture coordinates (0x4140) for {nv} vertices; missing ones are (0, 0)",
            o.name,
            o.uvs.len()
        ));
    }
    // A mirroring transform reverses the winding: flip the cross product back.
    let sign = t.determinant().signum();
    let face_normals: Vec<Vec3> = faces
        .iter()
        .map(|(_, f, _)| {
            let [a, b, c] = f.map(|v| positions[v as usize]);
            (b - a).cross(c - a) * sign
        })
        .collect();
    let normals = smooth_normals(&positions, &faces, &face_normals, &o.smoothing);
    // Output vertices: one per (stored vertex, normal). Each stored vertex keeps a short chain
    // of the output vertices made from it (no hashing: this is the reader's hot loop).
    let mut mesh = Mesh::default();
    let mut head = vec![u32::MAX; nv];
    let mut next: Vec<u32> = Vec::with_capacity(faces.len() * 3);
    for (k, (_, f, m)) in faces.iter().enumerate() {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let v = f[c] as usize;
            let n = normals[3 * k + c].to_array();
            let mut at = head[v];
            while at != u32::MAX && mesh.normals[at as usize] != n {
                at = next[at as usize];
            }
            if at == u32::MAX {
                let uv = o.uvs.get(v).copied().unwrap_or([0.0, 1.0]);
                at = mesh.positions.len() as u32;
                mesh.positions.push(positions[v].to_array());
                mesh.normals.push(n);
                mesh.uvs.push([uv[0], 1.0 - uv[1]]);
                next.push(head[v]);
                head[v] = at;
            }
            tri[c] = at;
        }
        mesh.indices.push(tri);
        mesh.triangle_materials.push(*m);
    }
    mesh
}

/// Per face corner: the normalized sum of the normals of the faces that touch the same position
/// and share a smoothing group bit with the corner's face (the face itself always counts).
pub(super) fn smooth_normals(
    positions: &[Vec3],
    faces: &[(usize, [u16; 3], u32)],
    face_normals: &[Vec3],
    smoothing: &[u32],
) -> Vec<Vec3> {
    let group = |k: usize| smoothing.get(faces[k].0).copied().unwrap_or(0);
    let pid = position_ids(positions);
    // Faces per position id, as compressed rows (counting sort).
    let npos = pid.iter().map(|&p| p as usize + 1).max().unwrap_or(0);
    let mut start = vec![0u32; npos + 1];
    for (k, (_, f, _)) in faces.iter().enumerate() {
        if group(k) != 0 {
            for &v in f {
                start[pid[v as usize] as usize + 1] += 1;
            }
        }
    }
    for i in 0..npos {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut rows = vec![0u32; start[npos] as usize];
    for (k, (_, f, _)) in faces.iter().enumerate() {
        if group(k) != 0 {
            for &v in f {
                let p = pid[v as usize] as usize;
                rows[fill[p] as usize] = k as u32;
                fill[p] += 1;
            }
        }
    }
    let mut out = Vec::with_capacity(faces.len() * 3);
    for (k, (_, f, _)) in faces.iter().enumerate() {
        let g = group(k);
        for &v in f {
            let mut n = face_normals[k];
            if g != 0 {
                let p = pid[v as usize] as usize;
                n = rows[start[p] as usize..start[p + 1] as usize]
                    .iter()
                    .filter(|&&j| group(j as usize) & g != 0)
                    .map(|&j| face_normals[j as usize])
                    .sum();
            }
            out.push(n.try_normalize().unwrap_or(Vec3::Z));
        }
    }
    out
}

/// For each vertex, an id shared by all vertices at exactly the same position (3DS duplicates
/// vertices along texture seams; smoothing must see through that).
pub(super) fn position_ids(positions: &[Vec3]) -> Vec<u32> {
    let key = |i: u32| positions[i as usize].to_array().map(f32::to_bits);
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_unstable_by_key(|&i| key(i));
    let mut ids = vec![0u32; positions.len()];
    let mut id = 0;
    for w in 0..order.len() {
        if w > 0 && key(order[w]) != key(order[w - 1]) {
            id += 1;
        }
        ids[order[w] as usize] = id;
    }
    ids
}
