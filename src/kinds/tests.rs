//! The registry against docs/FORMAT.md: every kind documented, every documented kind
//! registered (but the stage cache's own), and the naming rules.

use super::*;

/// Kinds docs/FORMAT.md documents that only stage-cache entries hold, never a pack.
const CACHE_ONLY: &[&str] = &["entry", "envmaps-shard"];

/// The kinds of the tables under docs/FORMAT.md's "## Section kinds" heading (up to the next
/// `##` heading): the first code span of each row whose table's header starts `| kind |`.
fn documented_kinds() -> Vec<String> {
    let text = include_str!("../../docs/FORMAT.md");
    let start = text
        .find("\n## Section kinds\n")
        .expect("docs/FORMAT.md has a \"## Section kinds\" heading");
    let rest = &text[start + 1..];
    let end = rest[3..].find("\n## ").map_or(rest.len(), |e| e + 3);
    let mut kinds = Vec::new();
    let mut in_kind_table = false;
    for line in rest[..end].lines() {
        if !line.starts_with('|') {
            in_kind_table = false;
            continue;
        }
        if line.starts_with("| kind |") {
            in_kind_table = true;
            continue;
        }
        let first = line.split('|').nth(1).unwrap_or("");
        if in_kind_table && let Some(k) = first.split('`').nth(1) {
            kinds.push(k.to_string());
        }
    }
    kinds
}

#[test]
fn every_registered_kind_has_its_format_row() {
    let documented = documented_kinds();
    for k in all() {
        assert!(
            documented.iter().any(|d| d == k.kind),
            "kind {:?} is registered but has no row in docs/FORMAT.md, \"Section kinds\"",
            k.kind
        );
    }
}

#[test]
fn every_documented_kind_is_registered() {
    let documented = documented_kinds();
    // The parse found the tables (a renamed heading must not make this pass by finding none).
    assert!(documented.len() >= all().count(), "{documented:?}");
    for d in &documented {
        assert!(
            find(d).is_some() || CACHE_ONLY.contains(&d.as_str()),
            "docs/FORMAT.md documents kind {d:?}, which is not in kinds::all (the central list or a stage's)"
        );
    }
}

#[test]
fn kinds_are_registered_once_with_distinct_array_names() {
    let kinds: Vec<&SectionKind> = all().collect();
    for (i, k) in kinds.iter().enumerate() {
        assert!(
            kinds[..i].iter().all(|o| o.kind != k.kind),
            "{:?} twice",
            k.kind
        );
        for (j, (name, formats, _)) in k.arrays.iter().enumerate() {
            assert!(!formats.is_empty(), "{}.{name}: no format", k.kind);
            assert!(
                k.arrays[..j].iter().all(|(n, _, _)| n != name),
                "{}.{name} twice",
                k.kind
            );
        }
    }
}

#[test]
fn naming_rules_accept_and_refuse() {
    assert!(Naming::Kind.accepts("terrain", "terrain"));
    assert!(!Naming::Kind.accepts("terrain", "terrain:x"));
    assert!(Naming::Qualified.accepts("mesh", "mesh:plant.txf"));
    assert!(!Naming::Qualified.accepts("mesh", "mesh:"));
    assert!(!Naming::Qualified.accepts("mesh", "meshy"));
    assert!(Naming::Prefixed.accepts("lightmap", "lightmap:terrain"));
    assert!(!Naming::Prefixed.accepts("lightmap", "lightmap"));
}

#[test]
fn an_unknown_kind_does_not_decode() {
    let s = crate::pack::SectionBuilder::new("nope", "nope").finish();
    let v = SectionView::parse(&s.payload, 0).unwrap();
    let err = decode("nope", &v).unwrap_err();
    assert!(err.message.contains("unknown kind"), "{err}");
}
