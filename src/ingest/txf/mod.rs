//! TXF plant models (Xfrog via the University of Konstanz player; seed 000, 3.1.1).
//! Phases, one file each: `tokens.rs` (the tokenizer), `blocks.rs` (blocks and binary arrays),
//! `mesh.rs` (one mesh from the sets).
//!
//! A TXF file is XML-like text with binary blocks. Line 1 is `<?txf_version='0.91'?>`, then
//! blocks `<Textures>`, `<Colors>`, `<Infos>` and `<Set>`. The format is not context-free:
//! `<tex_number>` and `<col_number>` set a current id that the following `<tex_name>`,
//! `<diff>`, `<ambi>`, `<spec>`, `<emis>`, `<shin>` refer to. Whitespace around tags is accepted.
//!
//! A `<Set>` has a `<header>` whose `<tc_combo> TEX MAT </tc_combo>` picks texture and material
//! (and `<translucence>`; a negative texture id means untextured, an id missing from
//! `<Textures>` or `<Colors>` gives a warning and no texture or the OpenGL default material),
//! `<references>` (skipped as text), and geometry: `<vertex_array>` with
//! `number_of_vertices` vertices of 36 bytes `{f32 texcoord[3]; f32 normal[3]; f32 position[3]}`
//! (little-endian) in `<data>`, then `<index>` with `number_of_index_values` u32 indices
//! (3 per triangle); `<line_array>` (`number_of_line_vertices`, index pairs) and `<point_array>`
//! (`number_of_subpoints + number_of_regpoints + number_of_suppoints` vertices) are Xfrog's LOD
//! representations: kept as the mesh's [`crate::model::Skeleton`] (segments between the line
//! array's vertices, the point array's vertices; positions only), which the `lod` stage keeps as
//! the farthest representation. A segment index out of its array's range is an error.
//!
//! **Binary payloads.** The thesis does not say whether a payload starts right after its tag
//! (`<data>` or `</number_of_index_values>`) or after that tag's 0x0A. Both are accepted: the
//! payload length comes from the header counts (never from a search for the closing tag), and
//! a placement is valid when the closing tag follows the payload (after optional whitespace).
//! When both are valid (the payload starts with 0x0A and is followed by whitespace) the one
//! whose content is plausible wins (vertices with finite values and a third texcoord of 0,
//! indices in range), ties going to the after-newline placement.
//!
//! **Texture coordinates.** TXF coordinates are OpenGL's (t = 0 at the bottom row of the
//! image); the model has v = 0 at the top row, so `uv = (s, 1 − t)`.
//!
//! **Wrap-around fix.** On closed cylinders u rises around the model (0.0, 0.2, … 0.8) and the
//! closing triangles reuse the start vertices with u = 0.0; those triangles must see 1 + u.
//! Per set, a triangle is a *candidate* when its u span exceeds 0.5 and adding 1 to its low
//! vertices (u < u_max − 0.5) brings the span to at most 0.5. A candidate is fixed when its
//! shifted span is closer than its original span to the median span of the non-candidate
//! triangles that share a vertex with it (its neighbours along the cylinder have the segment
//! span). Leaf quads whose triangles span the whole texture have no such narrow neighbours
//! and are left alone. A fixed triangle gets duplicates of its low vertices with u + 1 (one
//! duplicate per original vertex, shared by the set's fixed triangles); the shared vertex is
//! never moved.
//!
//! **Normals.** Zero or non-finite normals are replaced by the area-weighted face normals of
//! the set's triangles, with a warning; the others are normalised.

use crate::error::{Error, ParseError, Result};
use crate::model::{Material, Mesh, TextureRef};
use std::collections::HashMap;
use std::path::Path;

mod blocks;
mod mesh;
#[cfg(test)]
mod tests;
mod tokens;

use blocks::*;
use mesh::*;
use tokens::*;

/// Bytes of one binary vertex.
pub const VERTEX_BYTES: usize = 36;

/// Reads a TXF file; texture names are resolved against the file's folder.
pub fn load(path: &Path) -> Result<Mesh> {
    let bytes = crate::error::read_file(path)?;
    let mut mesh = parse(&bytes).map_err(|e| Error::invalid(path, e))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    for t in &mut mesh.textures {
        t.path = dir.join(&t.name);
    }
    Ok(mesh)
}

/// Parses TXF bytes into one mesh; texture paths are left as the names written.
pub fn parse(bytes: &[u8]) -> Result<Mesh, ParseError> {
    let mut c = Cursor { b: bytes, pos: 0 };
    let mut file = TxfFile::default();
    read_version(&mut c, &mut file.warnings)?;
    loop {
        let (tok, at) = c.next()?;
        match tok {
            Tok::Eof => break,
            Tok::Open("Textures") => read_textures(&mut c, &mut file)?,
            Tok::Open("Colors") => read_colors(&mut c, &mut file)?,
            Tok::Open("Infos") => c.skip_element("Infos")?,
            Tok::Open("Set") => {
                let set = read_set(&mut c, at)?;
                file.sets.push(set);
            }
            Tok::Open(other) => {
                file.warnings
                    .push(format!("{}: unknown block <{other}> skipped", c.place(at)));
                c.skip_element(other)?;
            }
            t => {
                return Err(c.unexpected(at, &t, "a block <Textures>, <Colors>, <Infos> or <Set>"));
            }
        }
    }
    build_mesh(file)
}
