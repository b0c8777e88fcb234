//! The library's modules depend on each other one way only: no top-level module (`cli`,
//! `server`, `grade`, …) reaches another that reaches it back, directly or through
//! others, and neither do the modules one level down within each (`cli::local`,
//! `cli::distributed`, …); the HTTP layer never reaches the command line.
//!
//! Read from the sources: every `crate::…` and `super::…` path (in `use` trees, braces
//! expanded, and in code), comments left out, names the module it lands in, cut to two
//! levels. A parent and its children are one module for this purpose: a child using
//! what its `mod.rs` declares, and the `mod.rs` gluing its children together, is how a
//! module is built, not a cycle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module's path from the crate root: `["cli", "local"]`.
type ModPath = Vec<String>;

/// Every `.rs` file under `dir`, with the module path it defines.
fn modules(src: &Path) -> Vec<(PathBuf, ModPath)> {
    fn walk(dir: &Path, prefix: &ModPath, out: &mut Vec<(PathBuf, ModPath)>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        let mut entries: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
        entries.sort();
        for p in entries {
            let Some(name) = p.file_stem().and_then(|s| s.to_str()).map(str::to_owned) else {
                continue;
            };
            if p.is_dir() {
                let mut m = prefix.clone();
                m.push(name);
                walk(&p, &m, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                let mut m = prefix.clone();
                if name != "mod" {
                    m.push(name);
                }
                out.push((p, m));
            }
        }
    }
    let mut out = Vec::new();
    walk(src, &Vec::new(), &mut out);
    // The crate root and the binary are not modules of the library's graph.
    out.retain(|(_, m)| !(m.len() == 1 && (m[0] == "lib" || m[0] == "main")));
    out
}

/// The source without comments (line, block and doc comments) and without the contents
/// of string and character literals, so that neither can name a path.
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b'/' if b.get(i + 1) == Some(&b'*') => {
                let mut depth = 0;
                while i < b.len() {
                    if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                        depth += 1;
                        i += 2;
                    } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                        depth -= 1;
                        i += 2;
                        if depth == 0 {
                            break;
                        }
                    } else {
                        i += 1;
                    }
                }
                out.push(' ');
            }
            b'r' if matches!(b.get(i + 1), Some(b'"' | b'#'))
                && !b[..i]
                    .last()
                    .is_some_and(|c| c.is_ascii_alphanumeric() || *c == b'_') =>
            {
                // A raw string: r"…", r#"…"#.
                let mut j = i + 1;
                let mut hashes = 0;
                while b.get(j) == Some(&b'#') {
                    hashes += 1;
                    j += 1;
                }
                if b.get(j) != Some(&b'"') {
                    out.push('r');
                    i += 1;
                    continue;
                }
                j += 1;
                let end: Vec<u8> = std::iter::once(b'"')
                    .chain(std::iter::repeat_n(b'#', hashes))
                    .collect();
                while j < b.len() && !b[j..].starts_with(&end) {
                    j += 1;
                }
                i = j + end.len();
                out.push_str("\"\"");
            }
            b'"' => {
                i += 1;
                while i < b.len() && b[i] != b'"' {
                    i += if b[i] == b'\\' { 2 } else { 1 };
                }
                i += 1;
                out.push_str("\"\"");
            }
            b'\'' => {
                // A character literal ('x', '\n', '\'') or a lifetime ('a): only the
                // former ends in a quote within a few bytes.
                let end = if b.get(i + 1) == Some(&b'\\') {
                    b[i + 2..]
                        .iter()
                        .take(12)
                        .position(|&c| c == b'\'')
                        .map(|k| i + 2 + k)
                } else {
                    let len = text[i + 1..].chars().next().map_or(1, char::len_utf8);
                    (b.get(i + 1 + len) == Some(&b'\'')).then_some(i + 1 + len)
                };
                match end {
                    Some(e) => {
                        out.push_str("' '");
                        i = e + 1;
                    }
                    None => {
                        out.push('\'');
                        i += 1;
                    }
                }
            }
            _ => {
                let len = text[i..].chars().next().map_or(1, char::len_utf8);
                out.push_str(&text[i..i + len]);
                i += len;
            }
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Reads the path (or `use` tree) at the start of `s`, after its `crate`/`super`
/// keyword and `::`, and returns every full path it names, braces expanded.
fn paths_at(s: &str) -> Vec<Vec<String>> {
    fn tree(s: &str, pos: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
        let skip_ws = |pos: &mut usize| {
            while s[*pos..].starts_with(char::is_whitespace) {
                *pos += s[*pos..].chars().next().map_or(1, char::len_utf8);
            }
        };
        let mut path = prefix.to_vec();
        loop {
            skip_ws(pos);
            if s[*pos..].starts_with('{') {
                *pos += 1;
                loop {
                    skip_ws(pos);
                    if s[*pos..].starts_with('}') {
                        *pos += 1;
                        return;
                    }
                    if *pos >= s.len() {
                        return;
                    }
                    let before = *pos;
                    tree(s, pos, &path, out);
                    skip_ws(pos);
                    if s[*pos..].starts_with(',') {
                        *pos += 1;
                    } else if *pos == before {
                        // Not a use tree after all: stop rather than spin.
                        return;
                    }
                }
            }
            let ident: String = s[*pos..].chars().take_while(|&c| is_ident(c)).collect();
            if ident.is_empty() {
                // `*`, or the end of the path.
                if s[*pos..].starts_with('*') {
                    *pos += 1;
                }
                out.push(path);
                return;
            }
            *pos += ident.len();
            if ident != "self" {
                path.push(ident);
            }
            skip_ws(pos);
            if s[*pos..].starts_with("::") {
                *pos += 2;
            } else {
                // `as name`, or the end of the path: the alias names nothing new.
                out.push(path);
                return;
            }
        }
    }
    let mut out = Vec::new();
    tree(s, &mut 0, &[], &mut out);
    out
}

/// The modules each module's file names, cut to two levels.
fn graph(src: &Path) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
    let files = modules(src);
    let known: BTreeSet<ModPath> = files.iter().map(|(_, m)| m.clone()).collect();
    // The longest known module a path lies in, cut to two levels.
    let landing = |path: &[String]| -> ModPath {
        let mut m: ModPath = Vec::new();
        for seg in path.iter().take(2) {
            let mut next = m.clone();
            next.push(seg.clone());
            if !known.contains(&next) {
                break;
            }
            m = next;
        }
        m
    };
    let mut edges: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
    for (file, module) in &files {
        let text = std::fs::read_to_string(file).expect("the source is readable");
        let code = code_only(&text);
        let from: ModPath = module.iter().take(2).cloned().collect();
        let targets = edges.entry(from.clone()).or_default();
        for (at, _) in code.match_indices("::") {
            let head_start = code[..at]
                .char_indices()
                .rev()
                .take_while(|&(_, c)| is_ident(c))
                .last()
                .map_or(at, |(k, _)| k);
            let head = &code[head_start..at];
            let before = code[..head_start].chars().next_back();
            if before.is_some_and(|c| is_ident(c) || c == ':') {
                continue;
            }
            let base: ModPath = match head {
                "crate" => Vec::new(),
                // `super` of `a::b` (its file `a/b.rs` or `a/b/mod.rs`) is `a`.
                "super" => module[..module.len().saturating_sub(1)].to_vec(),
                _ => continue,
            };
            for p in paths_at(&code[at + 2..]) {
                // `super::super::x`.
                let mut full = base.clone();
                for seg in p {
                    if seg == "super" {
                        full.pop();
                    } else {
                        full.push(seg);
                    }
                }
                let to = landing(&full);
                if !to.is_empty() && to != from {
                    targets.insert(to);
                }
            }
        }
    }
    edges
}

/// Whether `a` and `b` are a parent and its child (or the same module).
fn related(a: &ModPath, b: &ModPath) -> bool {
    a.starts_with(b) || b.starts_with(a)
}

/// The graph the rule is about: between top-level modules, and between siblings one
/// level down.
fn layers(edges: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
    let mut out: BTreeMap<ModPath, BTreeSet<ModPath>> = BTreeMap::new();
    for (from, tos) in edges {
        for to in tos {
            if related(from, to) {
                continue;
            }
            if from[0] != to[0] {
                out.entry(vec![from[0].clone()])
                    .or_default()
                    .insert(vec![to[0].clone()]);
            } else if from.len() == 2 && to.len() == 2 {
                out.entry(from.clone()).or_default().insert(to.clone());
            }
        }
    }
    out
}

/// Every cycle's modules, one list per strongly connected component larger than one.
fn cycles(g: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> Vec<Vec<String>> {
    let nodes: BTreeSet<&ModPath> = g.keys().chain(g.values().flatten()).collect();
    let reach = |start: &ModPath| -> BTreeSet<ModPath> {
        let mut seen = BTreeSet::new();
        let mut stack = vec![start.clone()];
        while let Some(n) = stack.pop() {
            for next in g.get(&n).into_iter().flatten() {
                if seen.insert(next.clone()) {
                    stack.push(next.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&ModPath, BTreeSet<ModPath>> =
        nodes.iter().map(|&n| (n, reach(n))).collect();
    let mut found: BTreeSet<Vec<String>> = BTreeSet::new();
    for &n in &nodes {
        if !reached[n].contains(n) {
            continue;
        }
        let component: Vec<String> = nodes
            .iter()
            .filter(|&&m| reached[n].contains(m) && reached[m].contains(n))
            .map(|m| m.join("::"))
            .collect();
        found.insert(component);
    }
    found.into_iter().collect()
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

#[test]
fn no_module_reaches_one_that_reaches_it_back() {
    let g = layers(&graph(&src()));
    let found = cycles(&g);
    let listed: Vec<String> = g
        .iter()
        .map(|(from, tos)| {
            let tos: Vec<String> = tos.iter().map(|t| t.join("::")).collect();
            format!("  {} → {}", from.join("::"), tos.join(", "))
        })
        .collect();
    assert!(
        found.is_empty(),
        "modules that import each other, directly or through others: {found:?}\n\
         the imports between modules:\n{}",
        listed.join("\n")
    );
}

#[test]
fn the_server_never_reaches_the_command_line() {
    let edges = graph(&src());
    let reaching: Vec<String> = edges
        .iter()
        .filter(|(from, tos)| from[0] == "server" && tos.iter().any(|t| t[0] == "cli"))
        .map(|(from, _)| from.join("::"))
        .collect();
    assert!(
        reaching.is_empty(),
        "these import the command line: {reaching:?}"
    );
}

#[test]
fn the_reader_finds_paths_in_use_trees_and_code_but_not_in_comments_or_strings() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let src = dir.path();
    std::fs::create_dir_all(src.join("a")).expect("writable");
    std::fs::create_dir_all(src.join("b")).expect("writable");
    let write = |p: &str, s: &str| std::fs::write(src.join(p), s).expect("writable");
    write("lib.rs", "pub mod a; pub mod b; pub mod c;");
    write("a/mod.rs", "mod x; mod y; use crate::c::Thing;");
    write(
        "a/x.rs",
        "use super::{y::{self, Y}, Z};\n// crate::b::nothing\nconst S: &str = \"crate::b::n\";",
    );
    write("a/y.rs", "fn f() { crate::b::g(); }");
    write("b/mod.rs", "use crate::a::{\n    x::X,\n};");
    write(
        "c.rs",
        "/* super::b */ fn f<'a>(c: char) -> bool { c == '\"' }",
    );
    let g = graph(src);
    let of = |m: &str| -> Vec<String> {
        let key: ModPath = m.split("::").map(str::to_owned).collect();
        g.get(&key)
            .into_iter()
            .flatten()
            .map(|t| t.join("::"))
            .collect()
    };
    assert_eq!(of("a"), ["c"]);
    assert_eq!(of("a::x"), ["a", "a::y"]);
    assert_eq!(of("a::y"), ["b"]);
    assert_eq!(of("b"), ["a::x"]);
    assert!(of("c").is_empty());
    // a → c, a::y → b, b → a::x: the top-level modules a and b reach each other.
    assert_eq!(cycles(&layers(&g)), [vec!["a".to_owned(), "b".to_owned()]]);
}
