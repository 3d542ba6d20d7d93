//! Section kinds written by the ingest stage: how the in-memory model maps to pack sections,
//! and each kind's `dump` view. Later stages keep their kinds in their own modules.

pub mod instances;
pub mod mesh;
pub mod sky;
pub mod terrain;
pub mod texture;

/// Section name of a model's mesh.
pub fn mesh_section_name(model: &str) -> String {
    format!("mesh:{model}")
}

/// Section name of a texture referred to by `owner` (a model name, or "terrain").
pub fn texture_section_name(owner: &str, texture: &str) -> String {
    format!("texture:{owner}/{texture}")
}

/// Truncates a section name to what the table holds, keeping it unique with a hash suffix.
pub fn fit_name(name: String) -> String {
    if name.len() <= crate::pack::NAME_LEN {
        return name;
    }
    let hash = blake3::hash(name.as_bytes()).to_hex();
    let mut cut = crate::pack::NAME_LEN - 9;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}~{}", &name[..cut], &hash[..8])
}
