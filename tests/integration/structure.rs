//! The code's structure, read from its own sources: the server's layers (http → engine →
//! store), the engine's rooms and the one direction of their imports, no pair of modules
//! importing each other in the server or the controller, SQL in the store alone (its tests
//! too), and no source file over `MAX_LINES` but the listed ones. A source scan, not a
//! compiler: paths are resolved as written (`crate::…`, `super::…`, grouped `{…}`), and
//! code under `#[cfg(test)]` is left out (a test may reach across; the product may not).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The engine's rooms and the rooms each may use (ARCHITECTURE.md draws the same).
const ROOMS: [(&str, &[&str]); 7] = [
    ("accounts", &[]),
    ("study", &[]),
    ("machine", &["study"]),
    ("procedure", &["study", "machine"]),
    ("results", &["study", "machine"]),
    ("dry_runs", &["study", "machine", "procedure", "results"]),
    ("operations", &["study", "machine", "procedure", "results"]),
];

type Module = Vec<String>;

/// A crate's source files as modules: `src/lib.rs` or `main.rs` is the crate, `a/mod.rs` is
/// `a`, `a/b.rs` is `a::b`.
fn modules(src: &Path) -> BTreeMap<Module, PathBuf> {
    fn walk(dir: &Path, files: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(&path, files);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    let mut files = Vec::new();
    walk(src, &mut files);
    files
        .into_iter()
        .map(|path| {
            let rel = path.strip_prefix(src).unwrap();
            let mut module: Module = vec!["crate".into()];
            module.extend(
                rel.parent()
                    .unwrap()
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned()),
            );
            let stem = rel.file_stem().unwrap().to_string_lossy().into_owned();
            if !["mod", "lib", "main"].contains(&stem.as_str()) {
                module.push(stem);
            }
            (module, path)
        })
        .collect()
}

/// The product's code of a file: comments and `#[cfg(test)]` modules left out.
fn product_code(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        if t.starts_with("#[cfg(test)]")
            && lines
                .peek()
                .is_some_and(|next| next.trim_start().contains("mod "))
        {
            // Skip the test module: up to its closing brace at the same indentation.
            let indent = line.len() - t.len();
            let closing = format!("{}}}", " ".repeat(indent));
            for l in lines.by_ref() {
                if l == closing {
                    break;
                }
            }
            continue;
        }
        if t.starts_with("//") {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Every path a file names that starts at `crate` or `super`, resolved against the file's
/// module (grouped imports give one path per entry).
fn paths(code: &str, module: &Module) -> Vec<Module> {
    let mut found = Vec::new();
    let bytes = code.as_bytes();
    let mut i = 0;
    while i < code.len() {
        let rest = &code[i..];
        let starts = (rest.starts_with("crate::") || rest.starts_with("super::"))
            && (i == 0 || !is_ident(bytes[i - 1] as char));
        if !starts {
            i += rest.chars().next().map_or(1, char::len_utf8);
            continue;
        }
        let mut base: Module = if rest.starts_with("crate::") {
            i += "crate::".len();
            vec!["crate".into()]
        } else {
            let mut m = module.clone();
            while code[i..].starts_with("super::") {
                m.pop();
                i += "super::".len();
            }
            m
        };
        // ident(::ident)* and possibly ::{a, b::c, …}
        loop {
            let rest = &code[i..];
            if rest.starts_with('{') {
                let close = rest.find('}').unwrap_or(rest.len());
                for entry in rest[1..close].split(',') {
                    let first: String = entry.trim().chars().take_while(|&c| is_ident(c)).collect();
                    if !first.is_empty() && first != "self" {
                        let mut p = base.clone();
                        p.push(first);
                        found.push(p);
                    }
                }
                i += close;
                base.clear();
                break;
            }
            let ident: String = rest.chars().take_while(|&c| is_ident(c)).collect();
            if ident.is_empty() {
                break;
            }
            i += ident.len();
            base.push(ident);
            if code[i..].starts_with("::") {
                i += 2;
            } else {
                break;
            }
        }
        if !base.is_empty() {
            found.push(base);
        }
    }
    found
}

/// The module a path lands in: the longest module that prefixes it.
fn target<'a>(path: &Module, modules: &'a BTreeMap<Module, PathBuf>) -> Option<&'a Module> {
    (1..=path.len())
        .rev()
        .find_map(|n| modules.get_key_value(&path[..n]).map(|(k, _)| k))
}

/// Each module's imports of other modules (not of its ancestors or descendants).
fn imports(src: &Path) -> BTreeMap<Module, BTreeSet<Module>> {
    let modules = modules(src);
    let mut graph = BTreeMap::new();
    for (module, file) in &modules {
        let code = product_code(&std::fs::read_to_string(file).unwrap());
        let edges: BTreeSet<Module> = paths(&code, module)
            .iter()
            .filter_map(|p| target(p, &modules))
            .filter(|t| !t.starts_with(module) && !module.starts_with(t))
            .cloned()
            .collect();
        graph.insert(module.clone(), edges);
    }
    graph
}

fn name(m: &Module) -> String {
    m.join("::")
}

/// Pairs and longer loops of modules that import each other.
fn cycles(graph: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<String> {
    let mut found = Vec::new();
    for start in graph.keys() {
        // Depth-first from `start`, reporting each loop once (from its smallest module).
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        let mut seen = BTreeSet::new();
        while let Some((at, trail)) = stack.pop() {
            for next in graph.get(&at).into_iter().flatten() {
                if next == start {
                    found.push(
                        trail
                            .iter()
                            .chain([start])
                            .map(name)
                            .collect::<Vec<_>>()
                            .join(" → "),
                    );
                } else if next > start && seen.insert(next.clone()) {
                    let mut t = trail.clone();
                    t.push(next.clone());
                    stack.push((next.clone(), t));
                }
            }
        }
    }
    found
}

fn crate_src(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(name)
        .join("src")
}

#[test]
fn the_engines_rooms_import_one_way_only() {
    let graph = imports(&crate_src("server"));
    let room_of = |m: &Module| -> Option<String> {
        (m.len() > 2 && m[1] == "engine" && ROOMS.iter().any(|(r, _)| *r == m[2]))
            .then(|| m[2].clone())
    };
    let mut wrong = Vec::new();
    for (module, edges) in &graph {
        let Some(room) = room_of(module) else {
            continue;
        };
        let allowed = ROOMS.iter().find(|(r, _)| *r == room).unwrap().1;
        for t in edges {
            if let Some(other) = room_of(t)
                && other != room
                && !allowed.contains(&other.as_str())
            {
                wrong.push(format!(
                    "{} imports {} (room {room} may use {allowed:?})",
                    name(module),
                    name(t)
                ));
            }
        }
    }
    // Every room is listed, and nothing sits loose in the engine but its shared root.
    let engine: BTreeSet<String> = graph
        .keys()
        .filter(|m| m.len() > 2 && m[1] == "engine")
        .map(|m| m[2].clone())
        .collect();
    for loose in engine.iter().filter(|m| !ROOMS.iter().any(|(r, _)| r == m)) {
        wrong.push(format!("engine::{loose} is in no room"));
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn the_servers_layers_import_downwards_only() {
    let src = crate_src("server");
    let graph = imports(&src);
    let mut wrong = Vec::new();
    for (module, edges) in &graph {
        let layer = module.get(1).map(String::as_str);
        for t in edges {
            let to = t.get(1).map(String::as_str);
            let bad = match layer {
                Some("store") => matches!(to, Some("engine" | "http")),
                Some("engine") => to == Some("http"),
                _ => false,
            };
            if bad {
                wrong.push(format!("{} imports {}", name(module), name(t)));
            }
        }
    }
    // No HTTP below the http layer.
    for (module, file) in modules(&src) {
        if matches!(module.get(1).map(String::as_str), Some("engine" | "store"))
            && product_code(&std::fs::read_to_string(&file).unwrap()).contains("axum")
        {
            wrong.push(format!("{} names axum", name(&module)));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn no_two_modules_import_each_other() {
    let mut found = Vec::new();
    for krate in ["server", "controller", "protocol"] {
        found.extend(
            cycles(&imports(&crate_src(krate)))
                .into_iter()
                .map(|c| format!("{krate}: {c}")),
        );
    }
    assert!(found.is_empty(), "import cycles:\n{}", found.join("\n"));
}

/// What names SQL in Rust source: sqlx's statement builders and the statements' own words
/// opening a string literal.
const SQL_MARKERS: [&str; 10] = [
    "sqlx::query",
    "sqlx::raw_sql",
    "query_as(",
    "query_scalar(",
    "\"SELECT ",
    "\"INSERT INTO",
    "\"UPDATE ",
    "\"DELETE FROM",
    "\"CREATE TABLE",
    "\"PRAGMA",
];

#[test]
fn sql_is_written_in_the_store_alone_tests_included() {
    let src = crate_src("server");
    let mut wrong = Vec::new();
    for (module, file) in modules(&src) {
        if module.get(1).map(String::as_str) == Some("store") {
            continue;
        }
        // The whole file, its tests too: a test that needs the database goes beside the
        // store, as the error mapping's do.
        let text = std::fs::read_to_string(&file).unwrap();
        for marker in SQL_MARKERS {
            if text.contains(marker) {
                wrong.push(format!("{} names {marker}", name(&module)));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// The longest a source file may be: past it a file holds more than one idea.
const MAX_LINES: usize = 600;

/// The files allowed past `MAX_LINES`, each with why (paths from the workspace root).
const LONG_FILES: [(&str, &str); 17] = [
    (
        "controller/src/identification/fit.rs",
        "the body's fit: its model, global search, jackknife intervals and identifiability verdict are one procedure on one set of weighted points",
    ),
    (
        "controller/src/identification/tests.rs",
        "the identification's checks over shared simulated records and pilots in the study's setting",
    ),
    (
        "server/src/store/audit_chain.rs",
        "the hash chain, its signed checkpoints and their verification are one format; split, the rules that must agree byte for byte would sit apart",
    ),
    (
        "controller/src/runtime/rt_loop.rs",
        "the real-time tick and its safety ordering (E-stop first, then staleness, then the rig) read as one sequence",
    ),
    (
        "server/src/engine/results/export/columns.rs",
        "the exports' contract: every column with its unit and meaning, one table the codebook is made from",
    ),
    (
        "server/src/engine/procedure/stations.rs",
        "a station's protocol state machine: pairing, phases and their guards change together",
    ),
    (
        "server/src/engine/operations/protocol_package.rs",
        "the ethics package: one document assembled in its order",
    ),
    (
        "server/src/serve.rs",
        "the server's start-up: listeners, TLS, sites and supervision wired in their order",
    ),
    (
        "server/src/engine/dry_runs/calibration/fit.rs",
        "the simulated-moments fit, its bootstrap and its profiles share one problem's state",
    ),
    (
        "server/src/engine/dry_runs/calibration/fit_tests.rs",
        "the calibration's recovery, coverage and refusals over shared small studies and pilots",
    ),
    (
        "tests/src/server.rs",
        "the integration tests' server harness: processes, API client and waits used by every scenario",
    ),
    (
        "tests/src/soak/station.rs",
        "the soak's simulated station: one client's whole protocol",
    ),
    (
        "tests/src/soak/verify.rs",
        "the soak's checks of everything stored, one pass over the database",
    ),
    (
        "tests/integration/server_api.rs",
        "the API's scenarios, sharing one study set-up",
    ),
    (
        "tests/integration/erasure.rs",
        "erasure's scenarios across every table and export",
    ),
    (
        "tests/integration/store_dialects.rs",
        "the same store checks on SQLite and PostgreSQL",
    ),
    (
        "tests/integration/backups.rs",
        "backup, restore and their checks, one file's life cycle",
    ),
];

#[test]
fn no_source_file_is_longer_than_the_limit_but_the_listed() {
    let root = crate_src("server").join("../..");
    let mut files = Vec::new();
    for dir in [
        "controller/src",
        "protocol/src",
        "server/src",
        "tests/src",
        "tests/integration",
    ] {
        fn walk(dir: &Path, files: &mut Vec<PathBuf>) {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    walk(&path, files);
                } else if path.extension().is_some_and(|e| e == "rs" || e == "js") {
                    files.push(path);
                }
            }
        }
        walk(&root.join(dir), &mut files);
    }
    let mut wrong = Vec::new();
    for file in files {
        let rel = file
            .strip_prefix(&root)
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let lines = std::fs::read_to_string(&file).unwrap().lines().count();
        let listed = LONG_FILES.iter().any(|(path, _)| *path == rel);
        if lines > MAX_LINES && !listed {
            wrong.push(format!(
                "{rel}: {lines} lines (at most {MAX_LINES}, or listed with why)"
            ));
        }
        if listed && lines <= MAX_LINES {
            wrong.push(format!(
                "{rel}: {lines} lines, listed as long: take it off the list"
            ));
        }
    }
    for (path, _) in LONG_FILES {
        if !root.join(path).exists() {
            wrong.push(format!("{path}: listed as long, and gone"));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// The scanner itself: resolution of relative and grouped paths, and loops found.
#[test]
fn the_scanner_resolves_paths_and_finds_loops() {
    let m = |s: &str| -> Module { s.split("::").map(String::from).collect() };
    let here = m("crate::engine::study::schedule");
    let got = paths(
        "use super::williams::Design;\nuse crate::engine::{machine::bench, results};\nlet x = super::super::COMPUTE;",
        &here,
    );
    assert_eq!(
        got,
        vec![
            m("crate::engine::study::williams::Design"),
            m("crate::engine::machine"),
            m("crate::engine::results"),
            m("crate::engine::COMPUTE"),
        ]
    );
    let code =
        product_code("use a;\n// use b;\n#[cfg(test)]\nmod tests {\n    use c;\n}\nuse d;\n");
    assert_eq!(code, "use a;\nuse d;\n");
    let graph: BTreeMap<Module, BTreeSet<Module>> = [
        (m("crate::a"), [m("crate::b")].into()),
        (m("crate::b"), [m("crate::c")].into()),
        (m("crate::c"), [m("crate::a")].into()),
        (m("crate::d"), [m("crate::a")].into()),
    ]
    .into();
    assert_eq!(
        cycles(&graph),
        vec!["crate::a → crate::b → crate::c → crate::a".to_string()]
    );
}
