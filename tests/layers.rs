//! The layer rule of docs/ARCHITECTURE.md ("Layers"): a top-level module of the library imports
//! only from its own layer or the layers below it, and the import graph between top-level modules
//! has no cycle.
//!
//! The test reads the module tree from `src/lib.rs` (following `mod x;`), blanks comments, string
//! and character literals, drops `#[cfg(test)]` items (test code may reach up for fixtures and
//! dumps), and collects every `crate::x` path (including `use crate::{x, y::z}` groups). The
//! layer order is the `layers` block of docs/ARCHITECTURE.md, highest layer first.
//!
//! A second test keeps clap in the front end: no library file outside `src/cli/` names it (the
//! command-line values of library enums are implemented in `cli/values.rs`).
//!
//! [`KNOWN_UPWARD`] lists the edges that still point up, each with its reason; the test fails on
//! any other upward edge, on a listed edge that has gone (so the list only shrinks), and on any
//! cycle left once the listed edges are removed.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Upward imports still in the tree: (from, to, why it is still there). Empty means the whole
/// graph follows the layer order, and therefore has no cycle.
const KNOWN_UPWARD: &[(&str, &str, &str)] = &[];

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// `src` with comments, string literals and character literals blanked (newlines kept).
fn strip(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = b.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for c in &mut out[from..to.min(b.len())] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
    };
    let mut i = 0;
    while i < b.len() {
        let prev_ident = i > 0 && is_ident(b[i - 1]);
        match b[i] {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                let end = src[i..].find('\n').map_or(b.len(), |e| i + e);
                blank(&mut out, i, end);
                i = end;
            }
            b'/' if b.get(i + 1) == Some(&b'*') => {
                let (mut j, mut depth) = (i + 2, 1);
                while j < b.len() && depth > 0 {
                    if b[j] == b'/' && b.get(j + 1) == Some(&b'*') {
                        depth += 1;
                        j += 2;
                    } else if b[j] == b'*' && b.get(j + 1) == Some(&b'/') {
                        depth -= 1;
                        j += 2;
                    } else {
                        j += 1;
                    }
                }
                blank(&mut out, i, j);
                i = j;
            }
            b'r' if (!prev_ident || (b[i - 1] == b'b' && (i < 2 || !is_ident(b[i - 2])))) && {
                let h = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
                b.get(i + 1 + h) == Some(&b'"')
            } =>
            {
                let h = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
                let close = format!("\"{}", "#".repeat(h));
                let start = i + 2 + h;
                let end = src[start..]
                    .find(&close)
                    .map_or(b.len(), |e| start + e + close.len());
                blank(&mut out, i, end);
                i = end;
            }
            b'"' => {
                let mut j = i + 1;
                while j < b.len() && b[j] != b'"' {
                    if b[j] == b'\\' {
                        j += 1;
                    }
                    j += 1;
                }
                blank(&mut out, i, j + 1);
                i = j + 1;
            }
            b'\'' => {
                // A character literal ('x', '\n', '\u{..}', a multi-byte char) or a lifetime.
                let end = if b.get(i + 1) == Some(&b'\\') {
                    src[i + 2..].find('\'').map(|e| i + 2 + e + 1)
                } else {
                    let ch = src[i + 1..].chars().next();
                    ch.and_then(|c| {
                        let after = i + 1 + c.len_utf8();
                        (b.get(after) == Some(&b'\'')).then_some(after + 1)
                    })
                };
                match end {
                    Some(e) => {
                        blank(&mut out, i, e);
                        i = e;
                    }
                    None => i += 1,
                }
            }
            _ => i += 1,
        }
    }
    String::from_utf8(out).expect("blanking keeps UTF-8")
}

/// The end (exclusive) of the item starting at `from`: the first `;` outside brackets, or the
/// brace block it opens.
fn item_end(b: &[u8], from: usize) -> usize {
    let mut depth = 0i32;
    let mut j = from;
    while j < b.len() {
        match b[j] {
            b'(' | b'[' => depth += 1,
            b')' | b']' => depth -= 1,
            b';' if depth == 0 => return j + 1,
            b'{' if depth == 0 => {
                let mut d = 0i32;
                while j < b.len() {
                    match b[j] {
                        b'{' => d += 1,
                        b'}' => {
                            d -= 1;
                            if d == 0 {
                                return j + 1;
                            }
                        }
                        _ => {}
                    }
                    j += 1;
                }
                return b.len();
            }
            _ => {}
        }
        j += 1;
    }
    b.len()
}

/// Skips whitespace and outer attributes from `i`.
fn skip_attrs(b: &[u8], mut i: usize) -> usize {
    loop {
        while i < b.len() && b[i].is_ascii_whitespace() {
            i += 1;
        }
        if b.get(i) == Some(&b'#') && b.get(i + 1) == Some(&b'[') {
            let mut depth = 0;
            while i < b.len() {
                match b[i] {
                    b'[' => depth += 1,
                    b']' => {
                        depth -= 1;
                        if depth == 0 {
                            i += 1;
                            break;
                        }
                    }
                    _ => {}
                }
                i += 1;
            }
        } else {
            return i;
        }
    }
}

/// Blanks every `#[cfg(test)]` item of stripped source.
fn drop_test_items(src: &str) -> String {
    let mut out = src.as_bytes().to_vec();
    let attr = "#[cfg(test)]";
    let mut from = 0;
    while let Some(k) = src[from..].find(attr).map(|k| from + k) {
        let item = skip_attrs(out.as_slice(), k + attr.len());
        let end = item_end(out.as_slice(), item);
        for c in &mut out[k..end] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
        from = end.max(k + attr.len());
    }
    String::from_utf8(out).expect("blanking keeps UTF-8")
}

/// The identifier starting at `i`, if any.
fn ident_at(b: &[u8], i: usize) -> Option<&str> {
    if i >= b.len() {
        return None;
    }
    let len = b[i..].iter().take_while(|&&c| is_ident(c)).count();
    (len > 0 && !b[i].is_ascii_digit()).then(|| std::str::from_utf8(&b[i..i + len]).unwrap())
}

/// `mod name;` declarations (non-inline child modules).
fn child_modules(code: &str) -> Vec<String> {
    let b = code.as_bytes();
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(k) = code[from..].find("mod ").map(|k| from + k) {
        from = k + 4;
        if k > 0 && is_ident(b[k - 1]) {
            continue;
        }
        let mut i = k + 4;
        while i < b.len() && b[i].is_ascii_whitespace() {
            i += 1;
        }
        let Some(name) = ident_at(b, i) else { continue };
        let mut j = i + name.len();
        while j < b.len() && b[j].is_ascii_whitespace() {
            j += 1;
        }
        if b.get(j) == Some(&b';') {
            out.push(name.to_string());
        }
    }
    out
}

/// The first segments of every `crate::` path in `code`.
fn crate_paths(code: &str) -> BTreeSet<String> {
    let b = code.as_bytes();
    let mut out = BTreeSet::new();
    let mut from = 0;
    while let Some(k) = code[from..].find("crate::").map(|k| from + k) {
        from = k + 7;
        if k > 0 && (is_ident(b[k - 1]) || b[k - 1] == b'$' || b[k - 1] == b':') {
            continue;
        }
        let i = k + 7;
        if let Some(name) = ident_at(b, i) {
            out.insert(name.to_string());
        } else if b.get(i) == Some(&b'{') {
            let (mut j, mut depth, mut expect) = (i + 1, 1, true);
            while j < b.len() && depth > 0 {
                match b[j] {
                    b'{' => depth += 1,
                    b'}' => depth -= 1,
                    b',' if depth == 1 => expect = true,
                    c if c.is_ascii_whitespace() => {}
                    _ if depth == 1 && expect => {
                        if let Some(name) = ident_at(b, j) {
                            out.insert(name.to_string());
                            j += name.len();
                            expect = false;
                            continue;
                        }
                        expect = false;
                    }
                    _ => {}
                }
                j += 1;
            }
        }
    }
    out
}

/// The file of child module `name` declared in `parent` (`x.rs` or `x/mod.rs`).
fn child_file(parent: &Path, name: &str) -> PathBuf {
    let dir = match parent.file_name().and_then(|f| f.to_str()) {
        Some("mod.rs" | "lib.rs") => parent.parent().unwrap().to_path_buf(),
        _ => parent.with_extension(""),
    };
    let flat = dir.join(format!("{name}.rs"));
    if flat.exists() {
        flat
    } else {
        dir.join(name).join("mod.rs")
    }
}

/// Import edges between top-level modules: from → (to → the files that import it).
type Edges = BTreeMap<String, BTreeMap<String, BTreeSet<String>>>;

fn import_graph(src: &Path) -> (Vec<String>, Edges) {
    let lib = src.join("lib.rs");
    let code = drop_test_items(&strip(&std::fs::read_to_string(&lib).unwrap()));
    let tops = child_modules(&code);
    let mut edges = Edges::new();
    for top in &tops {
        let mut stack = vec![child_file(&lib, top)];
        while let Some(file) = stack.pop() {
            let text = std::fs::read_to_string(&file)
                .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            let code = drop_test_items(&strip(&text));
            for child in child_modules(&code) {
                stack.push(child_file(&file, &child));
            }
            let rel = file.strip_prefix(src).unwrap().display().to_string();
            for to in crate_paths(&code) {
                if &to != top && tops.contains(&to) {
                    edges
                        .entry(top.clone())
                        .or_default()
                        .entry(to)
                        .or_default()
                        .insert(rel.clone());
                }
            }
        }
    }
    (tops, edges)
}

/// The layers of docs/ARCHITECTURE.md, lowest first: each a list of modules.
fn layers(doc: &str) -> Vec<(String, Vec<String>)> {
    let start = doc
        .find("```layers\n")
        .expect("docs/ARCHITECTURE.md has a ```layers block");
    let body = &doc[start + 10..];
    let body = &body[..body.find("```").expect("the layers block ends")];
    let mut out: Vec<(String, Vec<String>)> = body
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (name, mods) = l.split_once(':').expect("a layer line is `name: a, b, c`");
            let mods = mods.split(',').map(|m| m.trim().to_string()).collect();
            (name.trim().to_string(), mods)
        })
        .collect();
    out.reverse();
    out
}

/// Strongly connected components with more than one module (Tarjan).
fn cycles(nodes: &[String], edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct T<'a> {
        edges: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<String, usize>,
        low: BTreeMap<String, usize>,
        stack: Vec<String>,
        on: BTreeSet<String>,
        out: Vec<Vec<String>>,
    }
    fn visit(t: &mut T, v: &str) {
        let n = t.index.len();
        t.index.insert(v.into(), n);
        t.low.insert(v.into(), n);
        t.stack.push(v.into());
        t.on.insert(v.into());
        for w in t.edges.get(v).into_iter().flatten() {
            if !t.index.contains_key(w) {
                visit(t, w);
                let l = t.low[v].min(t.low[w]);
                t.low.insert(v.into(), l);
            } else if t.on.contains(w) {
                let l = t.low[v].min(t.index[w]);
                t.low.insert(v.into(), l);
            }
        }
        if t.low[v] == t.index[v] {
            let mut scc = Vec::new();
            loop {
                let w = t.stack.pop().unwrap();
                t.on.remove(&w);
                let done = w == v;
                scc.push(w);
                if done {
                    break;
                }
            }
            if scc.len() > 1 {
                scc.sort();
                t.out.push(scc);
            }
        }
    }
    let mut t = T {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in nodes {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out
}

#[test]
fn the_scanner_sees_paths_and_skips_comments_strings_and_tests() {
    let src = r##"
//! see [`crate::doc_link`]
use crate::{alpha::X, beta, gamma::{d, e}};
fn f() { let s = "crate::in_string"; let r = r#"crate::raw"#; let c = '"'; crate::delta::g(); }
fn l<'a>(x: &'a str) -> &'a str { crate::epsilon::h(x) }
/* crate::block /* nested */ crate::still_comment */
#[cfg(test)]
mod tests { use crate::zeta; }
#[cfg(test)]
use crate::eta;
mod child;
#[cfg(test)]
mod test_child;
"##;
    let code = drop_test_items(&strip(src));
    let found: Vec<String> = crate_paths(&code).into_iter().collect();
    assert_eq!(found, ["alpha", "beta", "delta", "epsilon", "gamma"]);
    assert_eq!(child_modules(&code), ["child"]);
    let edges = BTreeMap::from([
        ("a".to_string(), BTreeSet::from(["b".to_string()])),
        ("b".to_string(), BTreeSet::from(["c".to_string()])),
        ("c".to_string(), BTreeSet::from(["a".to_string()])),
    ]);
    let nodes = ["a", "b", "c", "d"].map(String::from);
    assert_eq!(cycles(&nodes, &edges), [["a", "b", "c"]]);
}

#[test]
fn top_level_modules_follow_the_layer_order_without_cycles() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (tops, edges) = import_graph(&root.join("src"));
    let doc = std::fs::read_to_string(root.join("docs/ARCHITECTURE.md")).unwrap();
    let layers = layers(&doc);
    let mut rank = BTreeMap::new();
    for (i, (_, mods)) in layers.iter().enumerate() {
        for m in mods {
            assert!(
                rank.insert(m.clone(), i).is_none(),
                "`{m}` is in two layers"
            );
        }
    }
    let mut problems = Vec::new();
    for m in &tops {
        if !rank.contains_key(m) {
            problems.push(format!(
                "module `{m}` is in no layer of docs/ARCHITECTURE.md"
            ));
        }
    }
    for m in rank.keys() {
        if !tops.contains(m) {
            problems.push(format!("layer module `{m}` is not a module of src/lib.rs"));
        }
    }
    let known: BTreeMap<(&str, &str), &str> = KNOWN_UPWARD
        .iter()
        .map(|&(a, b, why)| ((a, b), why))
        .collect();
    let mut kept = BTreeMap::<String, BTreeSet<String>>::new();
    for (from, tos) in &edges {
        for (to, files) in tos {
            let (Some(&rf), Some(&rt)) = (rank.get(from), rank.get(to)) else {
                continue;
            };
            let listed = known.contains_key(&(from.as_str(), to.as_str()));
            if rt > rf && !listed {
                problems.push(format!(
                    "upward import {from} ({}) -> {to} ({}) in {files:?}",
                    layers[rf].0, layers[rt].0
                ));
            }
            if !listed {
                kept.entry(from.clone()).or_default().insert(to.clone());
            }
        }
    }
    for &(from, to, why) in KNOWN_UPWARD {
        let present = edges.get(from).is_some_and(|t| t.contains_key(to));
        if !present {
            problems.push(format!(
                "{from} -> {to} is gone: remove it from KNOWN_UPWARD ({why})"
            ));
        }
    }
    for scc in cycles(&tops, &kept) {
        let inside: Vec<String> = scc
            .iter()
            .flat_map(|a| {
                edges[a]
                    .iter()
                    .filter(|(b, _)| scc.contains(b))
                    .map(move |(b, files)| format!("  {a} -> {b} in {files:?}"))
            })
            .collect();
        problems.push(format!("import cycle {scc:?}:\n{}", inside.join("\n")));
    }
    assert!(
        problems.is_empty(),
        "the layer rule (docs/ARCHITECTURE.md) is broken:\n{}",
        problems.join("\n")
    );
}

#[test]
fn clap_lives_only_in_the_cli() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut stack = vec![src.clone()];
    let mut found = Vec::new();
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let rel = path.strip_prefix(&src).unwrap().to_path_buf();
            if path.is_dir() {
                if rel != Path::new("cli") {
                    stack.push(path);
                }
            } else if path.extension().is_some_and(|e| e == "rs") && rel != Path::new("main.rs") {
                let code = drop_test_items(&strip(&std::fs::read_to_string(&path).unwrap()));
                let b = code.as_bytes();
                let mut from = 0;
                while let Some(k) = code[from..].find("clap").map(|k| from + k) {
                    from = k + 4;
                    let before = k > 0 && is_ident(b[k - 1]);
                    let after = b.get(k + 4).is_some_and(|&c| is_ident(c));
                    if !before && !after {
                        found.push(rel.display().to_string());
                        break;
                    }
                }
            }
        }
    }
    assert!(found.is_empty(), "clap outside src/cli/: {found:?}");
}
