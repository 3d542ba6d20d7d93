//! Mesh building: the sets merged into one mesh, one material per distinct set material, with
//! normals repaired and texture wrap-around fixed.

use super::*;

/// What makes a set's material distinct: material id, texture id, translucence bits.
pub(super) type MaterialKey = (Option<i64>, Option<i64>, Option<u32>);

pub(super) fn build_mesh(mut file: TxfFile) -> Result<Mesh, ParseError> {
    let mut mesh = Mesh {
        warnings: file.warnings.clone(),
        ..Mesh::default()
    };
    let mut materials: HashMap<MaterialKey, u32> = HashMap::new();
    let mut textures: HashMap<i64, u32> = HashMap::new();
    for mut set in std::mem::take(&mut file.sets) {
        let name = set
            .number
            .map_or(format!("set at byte {}", set.offset), |n| {
                format!("set {n}")
            });
        let key = (set.mat, set.tex, set.translucence.map(f32::to_bits));
        let m = match materials.get(&key) {
            Some(&m) => m,
            None => {
                let mat = set_material(&file, &set, &name, &mut textures, &mut mesh);
                mesh.materials.push(mat);
                let m = mesh.materials.len() as u32 - 1;
                materials.insert(key, m);
                m
            }
        };
        let repaired = repair_normals(&mut set.vertices, &set.triangles);
        if repaired > 0 {
            mesh.warnings.push(format!(
                "{name}: {repaired} zero or invalid normals replaced by face normals"
            ));
        }
        fix_wrap_around(&mut set.vertices, &mut set.triangles);
        append_set(&mut mesh, &set, m);
        mesh.skeleton.lines.append(&mut set.lines);
        mesh.skeleton.points.append(&mut set.points);
        mesh.objects.push(name);
    }
    Ok(mesh)
}

/// The material of a set: its `<Colors>` entry (or the OpenGL default), texture and translucence.
pub(super) fn set_material(
    file: &TxfFile,
    set: &SetData,
    name: &str,
    textures: &mut HashMap<i64, u32>,
    mesh: &mut Mesh,
) -> Material {
    let mut mat = match set.mat.and_then(|id| file.colors.get(&id)) {
        Some(col) => {
            let mut m = col.material.clone();
            m.name = col.name.clone();
            m
        }
        None => {
            let why = set.mat.map_or("no tc_combo".into(), |id| {
                format!("material {id} is not in <Colors>")
            });
            mesh.warnings
                .push(format!("{name}: {why}; using the OpenGL default material"));
            Material {
                name: "default".into(),
                ..Material::default()
            }
        }
    };
    mat.translucence = set.translucence;
    mat.color_map = match set.tex.filter(|&t| t >= 0) {
        None => None,
        Some(t) => match (textures.get(&t), file.textures.get(&t)) {
            (Some(&i), _) => Some(i),
            (None, Some(tex_name)) => {
                mesh.textures.push(TextureRef {
                    name: tex_name.clone(),
                    path: tex_name.into(),
                });
                let i = mesh.textures.len() as u32 - 1;
                textures.insert(t, i);
                Some(i)
            }
            (None, None) => {
                mesh.warnings.push(format!(
                    "{name}: texture {t} is not in <Textures>; untextured"
                ));
                None
            }
        },
    };
    if let Some(i) = mat.color_map {
        mat.name = format!("{} + {}", mat.name, mesh.textures[i as usize].name);
    }
    mat
}

pub(super) fn append_set(mesh: &mut Mesh, set: &SetData, material: u32) {
    let base = mesh.positions.len() as u32;
    for v in &set.vertices {
        mesh.positions.push(v.position);
        mesh.normals.push(v.normal);
        mesh.uvs.push([v.tc[0], 1.0 - v.tc[1]]);
    }
    mesh.indices
        .extend(set.triangles.iter().map(|t| t.map(|i| i + base)));
    mesh.triangle_materials
        .extend(std::iter::repeat_n(material, set.triangles.len()));
}

pub(super) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(super) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(super) fn normalized(v: [f32; 3]) -> Option<[f32; 3]> {
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (len.is_finite() && len > 1e-12).then(|| v.map(|x| x / len))
}

/// Normalises the normals; replaces zero or non-finite ones by the area-weighted normals of the
/// adjacent triangles (+Z when there are none). Returns how many were replaced.
pub(super) fn repair_normals(vertices: &mut [Vertex], triangles: &[[u32; 3]]) -> usize {
    let bad: Vec<bool> = vertices
        .iter()
        .map(|v| normalized(v.normal).is_none())
        .collect();
    let count = bad.iter().filter(|&&b| b).count();
    if count > 0 {
        let mut acc = vec![[0.0f32; 3]; vertices.len()];
        for t in triangles {
            let [a, b, c] = t.map(|i| vertices[i as usize].position);
            let n = cross(sub(b, a), sub(c, a)); // length = 2 × area: area weighting
            for &i in t {
                let s = &mut acc[i as usize];
                (0..3).for_each(|k| s[k] += n[k]);
            }
        }
        for (i, v) in vertices.iter_mut().enumerate().filter(|(i, _)| bad[*i]) {
            v.normal = normalized(acc[i]).unwrap_or([0.0, 0.0, 1.0]);
        }
    }
    for v in vertices.iter_mut() {
        v.normal = normalized(v.normal).unwrap_or(v.normal);
    }
    count
}

/// u span of a triangle.
pub(super) fn u_span(us: [f32; 3]) -> f32 {
    us.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
        - us.iter().fold(f32::INFINITY, |a, &b| a.min(b))
}

/// The u values after adding 1 to the low ones (u < u_max − 0.5).
pub(super) fn shifted(us: [f32; 3]) -> [f32; 3] {
    let max = us.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    us.map(|u| if u < max - 0.5 { u + 1.0 } else { u })
}

/// The texture-coordinate wrap-around fix (see the module doc). Returns the triangles fixed.
pub(super) fn fix_wrap_around(vertices: &mut Vec<Vertex>, triangles: &mut [[u32; 3]]) -> usize {
    let us = |t: &[u32; 3], v: &[Vertex]| t.map(|i| v[i as usize].tc[0]);
    let spans: Vec<f32> = triangles.iter().map(|t| u_span(us(t, vertices))).collect();
    let candidate: Vec<bool> = triangles
        .iter()
        .zip(&spans)
        .map(|(t, &s)| s > 0.5 && u_span(shifted(us(t, vertices))) <= 0.5)
        .collect();
    if !candidate.iter().any(|&c| c) {
        return 0;
    }
    // Triangles around each vertex (only the narrow ones matter).
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); vertices.len()];
    for (ti, t) in triangles
        .iter()
        .enumerate()
        .filter(|(ti, _)| !candidate[*ti])
    {
        for &i in t {
            around[i as usize].push(ti as u32);
        }
    }
    let fix: Vec<usize> = (0..triangles.len())
        .filter(|&ti| candidate[ti])
        .filter(|&ti| {
            let mut near: Vec<f32> = triangles[ti]
                .iter()
                .flat_map(|&i| around[i as usize].iter().map(|&n| spans[n as usize]))
                .collect();
            if near.is_empty() {
                return false;
            }
            near.sort_by(f32::total_cmp);
            let median = near[near.len() / 2];
            let after = u_span(shifted(us(&triangles[ti], vertices)));
            (after - median).abs() < (spans[ti] - median).abs()
        })
        .collect();
    let mut duplicate: HashMap<u32, u32> = HashMap::new();
    for &ti in &fix {
        let tri = triangles[ti];
        let max = tri
            .iter()
            .map(|&i| vertices[i as usize].tc[0])
            .fold(f32::NEG_INFINITY, f32::max);
        for slot in 0..3 {
            let i = tri[slot];
            if vertices[i as usize].tc[0] < max - 0.5 {
                let d = *duplicate.entry(i).or_insert_with(|| {
                    let mut v = vertices[i as usize];
                    v.tc[0] += 1.0;
                    vertices.push(v);
                    vertices.len() as u32 - 1
                });
                triangles[ti][slot] = d;
            }
        }
    }
    fix.len()
}
