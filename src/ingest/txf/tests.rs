use super::*;

/// One binary vertex written by hand: texcoord (s, t, 0), normal, position.
fn vtx(st: [f32; 2], n: [f32; 3], p: [f32; 3]) -> Vec<u8> {
    [st[0], st[1], 0.0, n[0], n[1], n[2], p[0], p[1], p[2]]
        .iter()
        .flat_map(|f| f.to_le_bytes())
        .collect()
}

fn idx(ix: &[u32]) -> Vec<u8> {
    ix.iter().flat_map(|i| i.to_le_bytes()).collect()
}

/// Where a payload goes: right after its tag (`tight`) or after the tag's 0x0A.
fn set_bytes(tc: &str, verts: &[Vec<u8>], ix: &[u32], tight: bool) -> Vec<u8> {
    let nl: &[u8] = if tight { b"" } else { b"\n" };
    let mut b = Vec::new();
    b.extend(format!("<Set>\n<set_number> 7 </set_number>\n<header>\n<tc_combo> {tc} </tc_combo>\n<importance> 1.0 </importance>\n<translucence> 0.25 </translucence>\n<p_min> 0 0 0 </p_min>\n</header>\n<references>\n<header>\n<number_of_references> 0 </number_of_references>\n</header>\n</references>\n").bytes());
    b.extend(format!("<vertex_array>\n<header>\n<number_of_vertices> {} </number_of_vertices>\n</header>\n<data>", verts.len()).bytes());
    b.extend(nl);
    verts.iter().for_each(|v| b.extend(v));
    b.extend(
        format!(
            "\n</data>\n<index>\n<number_of_index_values> {} </number_of_index_values>",
            ix.len()
        )
        .bytes(),
    );
    b.extend(nl);
    b.extend(idx(ix));
    b.extend(b"\n</index>\n</vertex_array>\n");
    // LOD arrays: 2 line vertices with one pair, 1 + 0 + 2 points.
    b.extend(b"<line_array>\n<header>\n<number_of_line_vertices> 2 </number_of_line_vertices>\n</header>\n<data>");
    b.extend(nl);
    b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [9.0, 9.0, 9.0]));
    b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [9.0, 9.0, 8.0]));
    b.extend(b"</data>\n<index>\n<number_of_index_values> 2 </number_of_index_values>");
    b.extend(nl);
    b.extend(idx(&[0, 1]));
    b.extend(b"</index>\n</line_array>\n");
    b.extend(b"<point_array>\n<header>\n<number_of_subpoints> 1 </number_of_subpoints>\n<number_of_regpoints> 0 </number_of_regpoints>\n<number_of_suppoints> 2 </number_of_suppoints>\n</header>\n<data>");
    b.extend(nl);
    for z in 0..3 {
        b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [5.0, 5.0, z as f32]));
    }
    b.extend(b"\n</data>\n</point_array>\n</Set>\n");
    b
}

const HEAD: &str = "<?txf_version='0.91'?>\n<Textures>\n<tex_number>0</tex_number><tex_name>bark.png</tex_name>\n<tex_number>3</tex_number><tex_name>leaf.rgb</tex_name>\n</Textures>\n<Colors>\n<col_number> 0 </col_number> <col_name> Default </col_name>\n<diff> 0.70 0.70 0.70 1.00 </diff>\n<ambi> 0.10 0.10 0.10 1.00 </ambi>\n<spec> 0.00 0.00 0.00 1.00 </spec>\n<emis> 0.00 0.00 0.00 1.00 </emis>\n<shin> 0.00 </shin>\n<col_number> 5 </col_number> <col_name> Leaf </col_name>\n<diff> 0.1 0.5 0.2 0.9 </diff>\n<shin> 12.5 </shin>\n<col_number> 0 </col_number>\n<spec> 0.3 0.3 0.3 1 </spec>\n</Colors>\n<Infos>\n<author> someone </author>\n</Infos>\n";

fn quad() -> Vec<Vec<u8>> {
    vec![
        vtx([0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]),
        vtx([1.0, 0.0], [0.0, -2.0, 0.0], [0.5, 0.0, 0.0]),
        vtx([1.0, 1.0], [0.0, -1.0, 0.0], [0.5, 0.0, 1.0]),
        vtx([0.0, 0.75], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]),
    ]
}

fn tiny(tight: bool) -> Vec<u8> {
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 0, 2, 3], tight));
    b
}

#[test]
fn parses_a_tiny_file_value_by_value() {
    let m = parse(&tiny(true)).unwrap();
    assert_eq!(m.validate(), Ok(()));
    assert_eq!(
        m.positions,
        vec![
            [0.0, 0.0, 0.0],
            [0.5, 0.0, 0.0],
            [0.5, 0.0, 1.0],
            [0.0, 0.0, 1.0]
        ]
    );
    // Normals normalised; v = 1 − t.
    assert_eq!(m.normals, vec![[0.0, -1.0, 0.0]; 4]);
    assert_eq!(m.uvs, vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.25]]);
    assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.triangle_materials, vec![0, 0]);
    assert_eq!(m.objects, vec!["set 7".to_string()]);
    // tc_combo 3 5: texture 3 (leaf.rgb), material 5 (Leaf); only used textures are kept.
    assert_eq!(
        m.textures,
        vec![TextureRef {
            name: "leaf.rgb".into(),
            path: "leaf.rgb".into()
        }]
    );
    let mat = &m.materials[0];
    assert_eq!(mat.diffuse, [0.1, 0.5, 0.2, 0.9]);
    assert_eq!(mat.shininess, 12.5);
    assert_eq!(mat.ambient, Material::default().ambient); // not given: OpenGL default
    assert_eq!(mat.translucence, Some(0.25));
    assert_eq!(mat.color_map, Some(0));
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    // The LOD arrays: one segment between the line array's two vertices, the 1 + 0 + 2 points.
    assert_eq!(m.skeleton.lines, vec![[[9.0, 9.0, 9.0], [9.0, 9.0, 8.0]]]);
    assert_eq!(
        m.skeleton.points,
        vec![[5.0, 5.0, 0.0], [5.0, 5.0, 1.0], [5.0, 5.0, 2.0]]
    );
}

#[test]
fn the_generated_plant_keeps_its_skeleton_and_ring_centres() {
    // The fixture generator's own record of what it wrote is the oracle.
    let model = crate::fixtures::plant::plant_model();
    let m = parse(&crate::fixtures::plant::write_txf(&model)).unwrap();
    let want_lines: Vec<[[f32; 3]; 2]> = model
        .sets
        .iter()
        .flat_map(|s| {
            s.lines.iter().map(|l| {
                [
                    s.line_vertices[l[0] as usize].position,
                    s.line_vertices[l[1] as usize].position,
                ]
            })
        })
        .collect();
    let want_points: Vec<[f32; 3]> = model
        .sets
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.position))
        .collect();
    assert!(!want_lines.is_empty() && !want_points.is_empty());
    assert_eq!(m.skeleton.lines, want_lines);
    assert_eq!(m.skeleton.points, want_points);
}

#[test]
fn col_number_is_a_state_that_later_lines_refer_to() {
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("0 0", &quad(), &[0, 1, 2], true));
    let m = parse(&b).unwrap();
    let mat = &m.materials[0];
    // Material 0 was reopened after material 5: its spec changed, the rest stayed.
    assert_eq!(mat.diffuse, [0.7, 0.7, 0.7, 1.0]);
    assert_eq!(mat.ambient, [0.1, 0.1, 0.1, 1.0]);
    assert_eq!(mat.specular, [0.3, 0.3, 0.3, 1.0]);
    assert_eq!(mat.name, "Default + bark.png");
    assert_eq!(m.textures[0].name, "bark.png");
}

/// A TXF written like seed 000 3.1.1's listing (its `<Colors>` block verbatim, a set header
/// with Xfrog's `translucence 0.000000`) maps to Table 3.1's leaf defaults.
#[test]
fn the_seeds_xfrog_default_maps_to_the_leaf_defaults() {
    use crate::material::convert::material_to_schlick;
    use crate::material::schlick::NormalMap;
    let head = "<?txf_version='0.91'?>\n<Textures>\n<tex_number>0</tex_number><tex_name>beispiel.rgb</tex_name>\n</Textures>\n<Colors>\n<col_number> 0 </col_number> <col_name> Default </col_name>\n<diff> 0.70 0.70 0.70 1.00 </diff>\n<ambi> 0.10 0.10 0.10 1.00 </ambi>\n<spec> 0.00 0.00 0.00 1.00 </spec>\n<emis> 0.00 0.00 0.00 1.00 </emis>\n<shin> 0.00 </shin>\n</Colors>\n<Infos>\n</Infos>\n";
    // The set header (text, before any binary payload) with Xfrog's unset translucence.
    let set = |tc: &str, ix: &[u32]| {
        let b = set_bytes(tc, &quad(), ix, false);
        let at = b.windows(5).position(|w| w == b"0.25 ").unwrap();
        [&b[..at], b"0.000000 ".as_slice(), &b[at + 5..]].concat()
    };
    let mut b = head.as_bytes().to_vec();
    b.extend(set("0 0", &[0, 1, 2]));
    b.extend(set("-1 0", &[0, 2, 3]));
    let m = parse(&b).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    assert_eq!(m.materials.len(), 2, "{:?}", m.materials);
    let textured = m.materials.iter().find(|x| x.color_map.is_some()).unwrap();
    let s = material_to_schlick(textured);
    let [top, bottom] = s.layers;
    assert_eq!(
        (
            top.roughness,
            top.isotropy,
            top.diffuse,
            top.glossy,
            top.specular
        ),
        (0.1, 1.0, 0.0, 1.0, 0.0)
    );
    assert_eq!(top.color, [0.075; 3]);
    assert_eq!(
        (bottom.diffuse, bottom.glossy, bottom.specular),
        (1.0, 0.0, 0.0)
    );
    assert_eq!(bottom.color, [1.0; 3]);
    assert_eq!((s.bump_height, s.translucence), (0.001, 0.3));
    assert!(matches!(s.normal_map, NormalMap::FromColor(_)));
    // The untextured set: the stem rule on top (Xfrog's 0.7 grey, the set's τ of 0).
    let untextured = m.materials.iter().find(|x| x.color_map.is_none()).unwrap();
    let s = material_to_schlick(untextured);
    assert_eq!(s.layers[0], top);
    assert_eq!(s.layers[1].color, [0.7; 3]);
    assert_eq!((s.bump_height, s.translucence), (0.0, 0.0));
}

#[test]
fn both_payload_placements_and_indentation_agree() {
    let tight = parse(&tiny(true)).unwrap();
    assert_eq!(parse(&tiny(false)).unwrap(), tight);
    // The thesis layout: indentation and blank lines around tags.
    let text = String::from_utf8(tiny(true)[..HEAD.len()].to_vec()).unwrap();
    let indented = text.replace("<", "\n   <").replacen("\n   <?", "<?", 1);
    let mut b = indented.into_bytes();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 0, 2, 3], true));
    assert_eq!(parse(&b).unwrap(), tight);
}

#[test]
fn payload_starting_with_a_newline_byte_is_placed_by_plausibility() {
    // u's first little-endian byte is 0x0A, and the payload is followed by "\n</data>":
    // both placements close properly; the content decides.
    let u = f32::from_bits(0x3E4C_CC0A);
    assert_eq!(u.to_le_bytes()[0], b'\n');
    let verts = vec![
        vtx([u, 0.5], [0.0, 0.0, 1.0], [1.0, 2.0, 3.0]),
        vtx([0.5, 0.5], [0.0, 0.0, 1.0], [4.0, 5.0, 6.0]),
        vtx([0.5, 1.0], [0.0, 0.0, 1.0], [7.0, 8.0, 9.0]),
    ];
    for tight in [true, false] {
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &verts, &[10 - 10, 1, 2], tight));
        let m = parse(&b).unwrap();
        assert_eq!(m.uvs[0], [u, 0.5], "tight={tight}");
        assert_eq!(m.positions[2], [7.0, 8.0, 9.0]);
    }
}

/// A closed ring of 5 segments: u = 0.0, 0.2, … 0.8, the closing quad reuses the u = 0
/// vertices (bottom 0..5, top 5..10).
fn ring() -> (Vec<Vec<u8>>, Vec<u32>) {
    let mut verts = Vec::new();
    for z in [0.0f32, 1.0] {
        for k in 0..5 {
            let a = k as f32 * std::f32::consts::TAU / 5.0;
            let n = [a.cos(), a.sin(), 0.0];
            verts.push(vtx(
                [k as f32 * 0.2, z],
                n,
                [0.1 * a.cos(), 0.1 * a.sin(), z],
            ));
        }
    }
    let mut ix = Vec::new();
    for k in 0..5u32 {
        let k1 = (k + 1) % 5;
        ix.extend([k, k1, 5 + k1, k, 5 + k1, 5 + k]);
    }
    (verts, ix)
}

#[test]
fn wrap_around_duplicates_the_start_vertices() {
    let (verts, ix) = ring();
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("0 0", &verts, &ix, true));
    let m = parse(&b).unwrap();
    assert_eq!(m.validate(), Ok(()));
    assert_eq!(
        m.positions.len(),
        12,
        "two duplicates (bottom and top start vertex)"
    );
    assert_eq!(m.indices.len(), 10);
    // The shared start vertices keep u = 0 and are still used by the first segment.
    assert_eq!(m.uvs[0][0], 0.0);
    assert_eq!(m.uvs[5][0], 0.0);
    assert_eq!(&m.indices[0..2], &[[0, 1, 6], [0, 6, 5]]);
    // The closing segment (k = 4): 4, 0→dup, 5→dup ; 4, 5→dup, 9.
    let (d0, d5) = (10u32, 11u32);
    assert_eq!(&m.indices[8..10], &[[4, d0, d5], [4, d5, 9]]);
    assert_eq!(m.uvs[d0 as usize], [1.0, 1.0]);
    assert_eq!(m.uvs[d5 as usize], [1.0, 0.0]);
    assert_eq!(m.positions[d0 as usize], m.positions[0]);
    assert_eq!(m.normals[d5 as usize], m.normals[5]);
    // Every triangle now spans u = 0.2.
    for t in &m.indices {
        let us = t.map(|i| m.uvs[i as usize][0]);
        assert!((u_span(us) - 0.2).abs() < 1e-6, "{us:?}");
    }
}

#[test]
fn leaf_quads_spanning_the_texture_are_not_wrapped() {
    // Two triangles spanning u 0..1, and a fan around a centre with margins 0.05/0.95.
    let fan = vec![
        vtx([0.05, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        vtx([0.95, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        vtx([0.95, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]),
        vtx([0.05, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        vtx([0.5, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0]),
    ];
    for (verts, ix) in [
        (quad(), vec![0, 1, 2, 0, 2, 3]),
        (fan.clone(), vec![0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4]),
        (fan, vec![0, 1, 2, 0, 2, 3]),
    ] {
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &verts, &ix, true));
        let m = parse(&b).unwrap();
        assert_eq!(m.positions.len(), verts.len());
    }
}

#[test]
fn zero_normals_become_face_normals_with_a_warning() {
    let verts = vec![
        vtx([0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        vtx([0.0, 0.0], [f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0]),
        vtx([0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 1.0, 0.0]),
    ];
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &verts, &[0, 1, 2], true));
    let m = parse(&b).unwrap();
    assert_eq!(m.normals, vec![[0.0, 0.0, 1.0]; 3]);
    assert_eq!(m.warnings.len(), 1);
    assert!(
        m.warnings[0].contains("2 zero or invalid normals"),
        "{:?}",
        m.warnings
    );
}

fn err_of(b: &[u8]) -> ParseError {
    parse(b).expect_err("must fail")
}

#[test]
fn bad_inputs_name_the_place() {
    let e = err_of(b"<Textures>\n</Textures>\n");
    assert_eq!(e.place, "line 1");
    // Index out of range names the set.
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 4], true));
    let e = err_of(&b);
    assert!(
        e.message.contains("set 7") && e.message.contains("vertex 4"),
        "{e}"
    );
    // A line segment past its array's vertices names the array and the segment.
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 2], true));
    let at = b.windows(8).rposition(|w| w == &idx(&[0, 1])[..]).unwrap();
    b[at + 4..at + 8].copy_from_slice(&7u32.to_le_bytes());
    let e = err_of(&b);
    assert!(
        e.message.contains("line_array") && e.message.contains("vertices 0 and 7"),
        "{e}"
    );
    // Not a multiple of 3.
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 3], true));
    assert!(err_of(&b).message.contains("multiple of 3"));
    // A bad number in the text, on its line.
    let text = HEAD.replace("<shin> 12.5 </shin>", "<shin> twelve </shin>");
    let e = err_of(text.as_bytes());
    assert_eq!(e.place, "line 15", "{e}");
    // Unterminated tag; stray closing tag; binary where text is expected.
    assert!(
        err_of(b"<?txf_version='0.91'?>\n<Set\n")
            .message
            .contains("unterminated")
    );
    assert!(
        err_of(b"<?txf_version='0.91'?>\n</Set>\n")
            .message
            .contains("expected a block")
    );
    assert!(
        err_of(b"<?txf_version='0.91'?>\n\xff\xfe\n")
            .message
            .contains("binary")
    );
}

/// Replaces the first `from` in binary-laden bytes.
fn replace_once(b: &[u8], from: &str, to: &str) -> Vec<u8> {
    let at = b
        .windows(from.len())
        .position(|w| w == from.as_bytes())
        .expect("pattern present");
    [&b[..at], to.as_bytes(), &b[at + from.len()..]].concat()
}

#[test]
fn huge_counts_fail_before_allocating() {
    let mut b = HEAD.as_bytes().to_vec();
    b.extend(set_bytes("3 5", &quad(), &[0, 1, 2], true));
    let tag = "<number_of_vertices> 4 ";
    for n in ["4000000000", "18446744073709551615"] {
        let e = err_of(&replace_once(
            &b,
            tag,
            &format!("<number_of_vertices> {n} "),
        ));
        assert!(
            e.place.starts_with("byte ") && e.message.contains("only"),
            "{n}: {e}"
        );
    }
    let e = err_of(&replace_once(
        &b,
        tag,
        "<number_of_vertices> 99999999999999999999999 ",
    ));
    assert!(e.message.contains("expected a number"), "{e}");
    // The same for indices: 10^9 indices need 4·10^9 bytes.
    let e = err_of(&replace_once(
        &b,
        "<number_of_index_values> 3 ",
        "<number_of_index_values> 1000000000 ",
    ));
    assert!(e.message.contains("needs 4000000000 bytes"), "{e}");
    // Point counts that overflow when summed.
    let e = err_of(&replace_once(
        &b,
        "<number_of_subpoints> 1 ",
        "<number_of_subpoints> 18446744073709551615 ",
    ));
    assert!(e.message.contains("overflow"), "{e}");
}

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    let b = tiny(false);
    let find = |p: &[u8]| b.windows(p.len()).position(|w| w == p).unwrap();
    let (set_start, set_end) = (find(b"<Set>"), find(b"</Set>") + 6);
    for n in 0..b.len() {
        // A prefix that ends between blocks is a valid (smaller) file; any cut inside
        // the set must fail.
        if let Ok(m) = parse(&b[..n]) {
            assert!(n <= set_start || n >= set_end, "cut at {n} parsed");
            assert!(m.indices.is_empty() || n >= set_end);
        }
    }
    // Garbled bytes: an error, or a mesh that satisfies the model's invariants.
    for at in 0..b.len() {
        for x in [0x5a, 0x01, 0x80] {
            let mut g = b.clone();
            g[at] ^= x;
            if let Ok(m) = parse(&g) {
                assert_eq!(m.validate(), Ok(()), "flip {x:#x} at {at}");
            }
        }
    }
}
