//! The module structure: no circle of imports among the modules of the core (`crates/core/src`)
//! or of the runtime (`src/`), and the runtime's layers in order.
//!
//! The check reads the sources (no compiler): every `use` declaration (groups, renames and
//! globs expanded) and every path in the code that starts with `crate::`, `super::`, `self::`
//! or with a name a `use` brought in, resolved from the module the file (or an inline `mod`
//! in it) is. Comments and string literals are skipped; `$crate` (macros) and other crates'
//! paths (`flyd_core::`, `std::`) are not edges.
//!
//! Granularity: a node is a module at most two levels deep, a top-level module (`engine`,
//! `daemon`) or one of its direct submodules (`engine::fitness`, `daemon::control`); deeper
//! modules and inline modules (`mod tests { .. }`) count as the two-level module holding them.
//! A path names the deepest known module it goes through (`crate::engine::Engine` is `engine`,
//! `crate::can::messages::MotionMsg` is `can::messages`). Two graphs must have no circle:
//!
//! - the top-level modules, each with everything under it (`kinematics` -> `can` -> `perception`
//!   -> `engine` -> `kinematics` is a circle);
//! - in each top-level module, its direct submodules (`engine::fitness` <-> `engine::sharing`
//!   is a circle). A module's own file (`mod.rs`, or `calib.rs` beside `calib/`) assembles
//!   and re-exports its submodules: edges between it and its own submodules are the module
//!   tree itself and are not counted.
//!
//! On a circle the test fails and prints it, each edge with the file and line that makes it.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// A module path from the crate root (`["engine", "fitness"]`); empty for the crate root.
type ModPath = Vec<String>;

/// One import: from the two-level module of a file to the module a path names.
#[derive(Debug, Clone)]
struct Edge {
    from: ModPath,
    to: ModPath,
    /// Where: `file:line`.
    at: String,
}

/// A crate's sources: each file's module path and text.
struct Crate {
    files: Vec<(ModPath, String, String)>,
}

impl Crate {
    /// Every `.rs` file under `root` (the crate's `src`), `lib.rs` the crate root; `main.rs`
    /// is another crate (the binary) and skipped, with the modules it declares (`mod x;`).
    fn read(root: &Path) -> Self {
        let mut paths = Vec::new();
        walk(root, &mut paths);
        paths.sort();
        let binary: Vec<PathBuf> = fs::read_to_string(root.join("main.rs"))
            .unwrap_or_default()
            .lines()
            .filter_map(|l| l.strip_prefix("mod ")?.strip_suffix(';'))
            .flat_map(|m| [PathBuf::from(format!("{m}.rs")), PathBuf::from(m)])
            .collect();
        let mut files = Vec::new();
        for path in paths {
            let rel = path.strip_prefix(root).expect("under the root");
            if rel == Path::new("main.rs") || binary.iter().any(|b| rel.starts_with(b)) {
                continue;
            }
            let text = fs::read_to_string(&path).expect("a readable source file");
            files.push((module_of(rel), rel.display().to_string(), text));
        }
        Self { files }
    }
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).expect("a readable directory") {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            walk(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `engine/fitness.rs` -> `engine::fitness`, `engine/mod.rs` and `engine.rs` -> `engine`,
/// `lib.rs` -> the root.
fn module_of(rel: &Path) -> ModPath {
    let mut segments: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let last = segments.pop().expect("a file name");
    let stem = last.trim_end_matches(".rs");
    if !(stem == "mod" || (segments.is_empty() && stem == "lib")) {
        segments.push(stem.to_owned());
    }
    segments
}

/// The source with comments and the contents of string and character literals blanked
/// (newlines kept, so lines still count).
fn strip(src: &str) -> String {
    let b: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    let blank = |c: char| if c == '\n' { '\n' } else { ' ' };
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                out.push(' ');
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    out.push(blank(b[i]));
                    i += 1;
                }
            }
        } else if c == 'r'
            && (next == Some('"') || next == Some('#'))
            && (i == 0 || !is_ident(b[i - 1]))
        {
            // A raw string r"..", r#".."#: ends at a quote followed by as many hashes.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            out.push('"');
            for _ in i + 1..=j {
                out.push(' ');
            }
            i = j + 1;
            while i < b.len() {
                if b[i] == '"' && (0..hashes).all(|k| b.get(i + 1 + k) == Some(&'#')) {
                    out.push('"');
                    for _ in 0..hashes {
                        out.push(' ');
                    }
                    i += 1 + hashes;
                    break;
                }
                out.push(blank(b[i]));
                i += 1;
            }
        } else if c == '"' {
            out.push('"');
            i += 1;
            while i < b.len() && b[i] != '"' {
                if b[i] == '\\' {
                    out.push(' ');
                    i += 1;
                }
                if i < b.len() {
                    out.push(blank(b[i]));
                    i += 1;
                }
            }
            out.push('"');
            i += 1;
        } else if c == '\'' {
            // A character literal ('x', '\n', '\''), or a lifetime ('a: kept as it is).
            if next == Some('\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != '\'' {
                    j += 1;
                }
                for _ in i..=j.min(b.len() - 1) {
                    out.push(' ');
                }
                i = j + 1;
            } else if b.get(i + 2) == Some(&'\'') {
                out.push_str("   ");
                i += 3;
            } else {
                out.push(c);
                i += 1;
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Tokens: identifiers, `::`, and single punctuation characters, each with its line.
fn tokens(src: &str) -> Vec<(String, usize)> {
    let b: Vec<char> = src.chars().collect();
    let mut out = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c == '\n' {
            line += 1;
            i += 1;
        } else if c.is_whitespace() {
            i += 1;
        } else if is_ident(c) {
            let start = i;
            while i < b.len() && is_ident(b[i]) {
                i += 1;
            }
            out.push((b[start..i].iter().collect(), line));
        } else if c == ':' && b.get(i + 1) == Some(&':') {
            out.push(("::".to_owned(), line));
            i += 2;
        } else {
            out.push((c.to_string(), line));
            i += 1;
        }
    }
    out
}

/// The paths of a `use` tree starting at `tokens[*i]`, each with the name it binds (`None`
/// for a glob), until the `;` (consumed).
fn use_tree(
    tokens: &[(String, usize)],
    i: &mut usize,
    prefix: &[String],
) -> Vec<(Vec<String>, Option<String>)> {
    let mut out = Vec::new();
    let mut path = prefix.to_vec();
    while *i < tokens.len() {
        let t = tokens[*i].0.as_str();
        match t {
            "::" => *i += 1,
            "{" => {
                *i += 1;
                loop {
                    out.extend(use_tree(tokens, i, &path));
                    match tokens.get(*i).map(|t| t.0.as_str()) {
                        Some(",") => *i += 1,
                        Some("}") => {
                            *i += 1;
                            break;
                        }
                        _ => break,
                    }
                    if tokens.get(*i).map(|t| t.0.as_str()) == Some("}") {
                        *i += 1;
                        break;
                    }
                }
                return out;
            }
            "*" => {
                *i += 1;
                out.push((path.clone(), None));
                return out;
            }
            "as" => {
                *i += 1;
                let alias = tokens[*i].0.clone();
                *i += 1;
                out.push((path.clone(), Some(alias)));
                return out;
            }
            "," | "}" | ";" => {
                if path.len() > prefix.len() {
                    let name = if path.last().is_some_and(|l| l == "self") {
                        path.pop();
                        path.last().cloned()
                    } else {
                        path.last().cloned()
                    };
                    out.push((path.clone(), name));
                }
                return out;
            }
            _ => {
                path.push(t.to_owned());
                *i += 1;
            }
        }
    }
    out
}

/// A path as written in module `here` made absolute; `None` if it is another crate's.
fn absolute(
    path: &[String],
    here: &ModPath,
    aliases: &BTreeMap<String, Vec<String>>,
) -> Option<Vec<String>> {
    let first = path.first()?;
    let mut out: Vec<String>;
    let rest: &[String];
    match first.as_str() {
        "crate" => {
            out = Vec::new();
            rest = &path[1..];
        }
        "self" => {
            out = here.clone();
            rest = &path[1..];
        }
        "super" => {
            out = here.clone();
            let mut k = 0;
            while path.get(k).is_some_and(|s| s == "super") {
                out.pop()?;
                k += 1;
            }
            rest = &path[k..];
        }
        name => {
            out = aliases.get(name)?.clone();
            rest = &path[1..];
        }
    }
    out.extend(rest.iter().cloned());
    Some(out)
}

/// Where a token is: the brace depth and the inline `mod`s open there (each with the depth
/// its body starts at).
#[derive(Default)]
struct Scope {
    stack: Vec<(String, usize)>,
    depth: usize,
}

impl Scope {
    /// Follows token `i`: braces, and `mod name {` opening an inline module.
    fn step(&mut self, toks: &[(String, usize)], i: usize) {
        match toks[i].0.as_str() {
            "{" => self.depth += 1,
            "}" => {
                self.depth = self.depth.saturating_sub(1);
                if self.stack.last().is_some_and(|&(_, d)| d == self.depth) {
                    self.stack.pop();
                }
            }
            "mod" if toks.get(i + 2).is_some_and(|t| t.0 == "{") => {
                self.stack.push((toks[i + 1].0.clone(), self.depth));
            }
            _ => {}
        }
    }
}

/// The imports of one file, from its module `file_mod`: (absolute path, line).
fn imports(file_mod: &ModPath, src: &str) -> Vec<(Vec<String>, usize)> {
    let toks = tokens(&strip(src));
    // Pass 1: the `use` declarations, each in the module (inline `mod`s included) it is in.
    let mut out = Vec::new();
    let mut aliases: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut scope = Scope::default();
    let mut use_spans = Vec::new();
    let mut i = 0;
    let here = |stack: &[(String, usize)]| {
        let mut m = file_mod.clone();
        m.extend(stack.iter().map(|(n, _)| n.clone()));
        m
    };
    while i < toks.len() {
        let t = toks[i].0.as_str();
        let prev = if i > 0 { toks[i - 1].0.as_str() } else { "" };
        scope.step(&toks, i);
        match t {
            "use" if prev != "$" && !is_ident_str(prev) || prev == "pub" || prev == ")" => {
                let start = i;
                let line = toks[i].1;
                i += 1;
                let module = here(&scope.stack);
                for (path, name) in use_tree(&toks, &mut i, &[]) {
                    if let Some(abs) = absolute(&path, &module, &aliases) {
                        if let Some(name) = name {
                            aliases.insert(name, abs.clone());
                        }
                        out.push((abs, line));
                    }
                }
                use_spans.push((start, i));
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    // Pass 2: paths in the code (`crate::a::b`, `super::x`, `alias::y`), outside `use`s.
    let mut scope = Scope::default();
    let mut spans = use_spans.into_iter().peekable();
    let mut i = 0;
    while i < toks.len() {
        if let Some(&(start, end)) = spans.peek()
            && i == start
        {
            i = end;
            spans.next();
            continue;
        }
        let t = toks[i].0.as_str();
        scope.step(&toks, i);
        let starts_path = is_ident_str(t)
            && toks.get(i + 1).is_some_and(|t| t.0 == "::")
            && !(i > 0 && (toks[i - 1].0 == "::" || toks[i - 1].0 == "$"));
        if starts_path && (t == "crate" || t == "super" || t == "self" || aliases.contains_key(t)) {
            let line = toks[i].1;
            let mut path = vec![t.to_owned()];
            let mut j = i + 1;
            while toks.get(j).is_some_and(|t| t.0 == "::")
                && toks.get(j + 1).is_some_and(|t| is_ident_str(&t.0))
            {
                path.push(toks[j + 1].0.clone());
                j += 2;
            }
            if let Some(abs) = absolute(&path, &here(&scope.stack), &aliases) {
                out.push((abs, line));
            }
            i = j;
            continue;
        }
        i += 1;
    }
    out
}

fn is_ident_str(s: &str) -> bool {
    s.chars().next().is_some_and(is_ident)
}

/// The edges of a crate between its two-level modules.
fn edges(krate: &Crate) -> Vec<Edge> {
    let known: BTreeSet<ModPath> = krate.files.iter().map(|(m, _, _)| m.clone()).collect();
    let node = |m: &[String]| -> ModPath {
        // The deepest known module on the path, cut to two levels.
        let mut best: &[String] = &[];
        for k in 1..=m.len() {
            if known.contains(&m[..k]) {
                best = &m[..k];
            }
        }
        best.iter().take(2).cloned().collect()
    };
    let mut out = Vec::new();
    for (module, file, text) in &krate.files {
        let from: ModPath = module.iter().take(2).cloned().collect();
        for (path, line) in imports(module, text) {
            let to = node(&path);
            if to.is_empty() || to == from {
                continue;
            }
            out.push(Edge {
                from: from.clone(),
                to,
                at: format!("{file}:{line}"),
            });
        }
    }
    out
}

/// A directed graph: for each node, its successors with the place of one edge that makes each.
type Graph = BTreeMap<String, BTreeMap<String, String>>;

/// The two kinds of graphs the rule is checked on (see the module's documentation): the
/// top-level modules, and each top-level module's direct submodules.
fn graphs(edges: &[Edge]) -> Vec<(String, Graph)> {
    let mut top = Graph::new();
    let mut within: BTreeMap<String, Graph> = BTreeMap::new();
    for e in edges {
        let (from_top, to_top) = (&e.from[0], &e.to[0]);
        if from_top != to_top {
            top.entry(from_top.clone())
                .or_default()
                .entry(to_top.clone())
                .or_insert_with(|| e.at.clone());
        } else if e.from.len() == 2 && e.to.len() == 2 {
            within
                .entry(from_top.clone())
                .or_default()
                .entry(e.from.join("::"))
                .or_default()
                .entry(e.to.join("::"))
                .or_insert_with(|| e.at.clone());
        }
    }
    let mut out = vec![("top-level modules".to_owned(), top)];
    out.extend(
        within
            .into_iter()
            .map(|(m, g)| (format!("the submodules of `{m}`"), g)),
    );
    out
}

/// A circle in the graph, if there is one: its nodes in order, the first repeated at the end.
fn find_cycle(graph: &Graph) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        Open,
        Done,
    }
    fn visit(
        n: &str,
        graph: &Graph,
        marks: &mut BTreeMap<String, Mark>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        marks.insert(n.to_owned(), Mark::Open);
        path.push(n.to_owned());
        for next in graph.get(n).into_iter().flat_map(|s| s.keys()) {
            match marks.get(next.as_str()) {
                Some(Mark::Open) => {
                    let start = path.iter().position(|p| p == next).expect("on the path");
                    let mut cycle = path[start..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Some(Mark::Done) => {}
                None => {
                    if let Some(c) = visit(next, graph, marks, path) {
                        return Some(c);
                    }
                }
            }
        }
        path.pop();
        marks.insert(n.to_owned(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for n in graph.keys() {
        if !marks.contains_key(n.as_str())
            && let Some(c) = visit(n, graph, &mut marks, &mut Vec::new())
        {
            return Some(c);
        }
    }
    None
}

/// The strongly connected components of more than one node (Tarjan), each sorted.
fn components(graph: &Graph) -> Vec<Vec<String>> {
    struct State<'g> {
        graph: &'g Graph,
        index: BTreeMap<&'g str, usize>,
        low: BTreeMap<&'g str, usize>,
        stack: Vec<&'g str>,
        on_stack: BTreeSet<&'g str>,
        out: Vec<Vec<String>>,
    }
    fn connect<'g>(s: &mut State<'g>, n: &'g str) {
        let i = s.index.len();
        s.index.insert(n, i);
        s.low.insert(n, i);
        s.stack.push(n);
        s.on_stack.insert(n);
        for next in s.graph.get(n).into_iter().flat_map(|m| m.keys()) {
            let next = next.as_str();
            if !s.index.contains_key(next) {
                connect(s, next);
                let low = s.low[n].min(s.low[next]);
                s.low.insert(n, low);
            } else if s.on_stack.contains(next) {
                let low = s.low[n].min(s.index[next]);
                s.low.insert(n, low);
            }
        }
        if s.low[n] == s.index[n] {
            let mut component = Vec::new();
            while let Some(m) = s.stack.pop() {
                s.on_stack.remove(m);
                component.push(m.to_owned());
                if m == n {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.out.push(component);
            }
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for n in graph.keys() {
        if !s.index.contains_key(n.as_str()) {
            connect(&mut s, n);
        }
    }
    s.out
}

/// Every circle found, one for each set of modules that reach each other, written out edge by
/// edge with where each edge is made, then every edge inside that set.
fn circles(krate: &Crate) -> Vec<String> {
    let mut out = Vec::new();
    for (name, graph) in graphs(&edges(krate)) {
        for component in components(&graph) {
            let inside: Graph = component
                .iter()
                .map(|n| {
                    let next = graph.get(n).into_iter().flatten();
                    let next = next.filter(|(m, _)| component.contains(m));
                    (
                        n.clone(),
                        next.map(|(m, at)| (m.clone(), at.clone())).collect(),
                    )
                })
                .collect();
            let cycle = find_cycle(&inside).expect("a component has a circle");
            let mut text = format!("a circle among {name}: {}\n", cycle.join(" -> "));
            for pair in cycle.windows(2) {
                let at = &graph[&pair[0]][&pair[1]];
                text.push_str(&format!("  {} -> {} ({at})\n", pair[0], pair[1]));
            }
            text.push_str("  every edge among these modules:\n");
            for (from, next) in &inside {
                for (to, at) in next {
                    text.push_str(&format!("    {from} -> {to} ({at})\n"));
                }
            }
            out.push(text);
        }
    }
    out
}

/// The edges of the top-level graph that go up the layers (`layers[0]` the lowest: a module
/// imports only from its own layer or lower ones), and the modules no layer names.
fn upward(krate: &Crate, layers: &[&[&str]]) -> Vec<String> {
    let level = |m: &str| layers.iter().position(|l| l.contains(&m));
    let mut out = Vec::new();
    let modules: BTreeSet<String> = krate
        .files
        .iter()
        .filter_map(|(m, _, _)| m.first().cloned())
        .collect();
    for m in modules {
        if level(&m).is_none() {
            out.push(format!("`{m}` is in no layer: add it to the table"));
        }
    }
    let (_, top) = graphs(&edges(krate)).swap_remove(0);
    for (from, next) in &top {
        for (to, at) in next {
            if let (Some(a), Some(b)) = (level(from), level(to))
                && b > a
            {
                out.push(format!(
                    "{from} (layer {a}) imports {to} (layer {b}) at {at}"
                ));
            }
        }
    }
    out
}

/// The core's layers, lowest first. Values and their arithmetic; frames and the decision; the
/// engine; the files that set it up (calib: a rig file says the engine's depth range) and the
/// sensor checks; what reads the engine's flies (perception) or a rig (rectification, ground
/// truth), and the policies the daemon and the replays share (policy); the CAN protocol on
/// top: its messages are built from the domain types and its monitor checks the vehicle's
/// frames, and nothing below imports it.
const CORE_LAYERS: &[&[&str]] = &[
    &[
        "chain",
        "clock",
        "geometry",
        "isa",
        "kinematics",
        "macros",
        "pairing",
        "path",
        "road_plane",
        "status",
        "test_support",
        "textfile",
        "toml_key",
    ],
    &["decision", "frame"],
    &["engine"],
    &["calib", "sensor"],
    &[
        "dataset",
        "faults",
        "frame_step",
        "perception",
        "policy",
        "rectification",
    ],
    &["can"],
];

/// The runtime's layers, lowest first: the clock, named threads and the camera abstraction;
/// the CAN transports and V4L2 capture; the hw-mock cameras and vehicle; the configuration
/// and the recorder; the daemon (and the logs, configured from the configuration); the
/// commands (replay, bench); the evaluation over replays.
const RUNTIME_LAYERS: &[&[&str]] = &[
    &["os_clock", "source", "thread"],
    &["bus", "capture"],
    &["mock"],
    &["config", "record"],
    &["daemon", "logging"],
    &["bench", "path_bench", "replay"],
    &["eval"],
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_core_has_no_import_circle() {
    let krate = Crate::read(&root().join("crates/core/src"));
    let found = circles(&krate);
    assert!(found.is_empty(), "crates/core/src:\n{}", found.join("\n"));
}

#[test]
fn the_runtime_has_no_import_circle() {
    let krate = Crate::read(&root().join("src"));
    let found = circles(&krate);
    assert!(found.is_empty(), "src:\n{}", found.join("\n"));
}

#[test]
fn the_cores_modules_import_only_from_below() {
    let found = upward(&Crate::read(&root().join("crates/core/src")), CORE_LAYERS);
    assert!(found.is_empty(), "crates/core/src:\n{}", found.join("\n"));
}

#[test]
fn the_runtimes_modules_import_only_from_below() {
    let found = upward(&Crate::read(&root().join("src")), RUNTIME_LAYERS);
    assert!(found.is_empty(), "src:\n{}", found.join("\n"));
}

// The checker itself, on tiny synthetic crates: it must see a circle when there is one.

fn synthetic(files: &[(&str, &str)]) -> Crate {
    Crate {
        files: files
            .iter()
            .map(|(rel, text)| {
                (
                    module_of(Path::new(rel)),
                    (*rel).to_owned(),
                    (*text).to_owned(),
                )
            })
            .collect(),
    }
}

#[test]
fn a_circle_between_top_level_modules_is_found_and_printed() {
    let krate = synthetic(&[
        ("lib.rs", "pub mod a;\npub mod b;\npub mod c;\n"),
        ("a.rs", "use crate::b::Thing;\n"),
        ("b/mod.rs", "pub mod inner;\n"),
        (
            "b/inner.rs",
            "// use crate::a::Ignored;\nfn f() { let _ = crate::c::g(); }\n",
        ),
        ("c.rs", "use crate::{x, a::{self, Other as O}};\n"),
    ]);
    let found = circles(&krate);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].contains("a -> b -> c -> a"), "{}", found[0]);
    assert!(found[0].contains("b/inner.rs:2"), "{}", found[0]);
}

#[test]
fn a_circle_between_submodules_is_found_but_not_one_with_the_parent() {
    let krate = synthetic(&[
        ("lib.rs", "pub mod engine;\n"),
        (
            "engine/mod.rs",
            "mod fitness;\nmod sharing;\nuse fitness::Kernel;\npub struct Engine;\n",
        ),
        (
            "engine/fitness.rs",
            "use super::Engine;\nuse super::sharing::Grid;\n",
        ),
        (
            "engine/sharing.rs",
            "pub struct Grid;\n#[cfg(test)]\nmod tests {\n    use super::super::fitness;\n}\n",
        ),
    ]);
    let found = circles(&krate);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0].contains("engine::fitness -> engine::sharing -> engine::fitness"),
        "{}",
        found[0]
    );
}

#[test]
fn a_tree_has_no_circle() {
    let krate = synthetic(&[
        ("lib.rs", "pub mod a;\npub mod b;\n"),
        (
            "a.rs",
            "use crate::b;\nfn f() { b::g(); let s = \"crate::a::x\"; let c = '\"'; }\n",
        ),
        (
            "b.rs",
            "macro_rules! m { () => { $crate::a::f() } }\nuse std::fmt;\n",
        ),
    ]);
    assert_eq!(circles(&krate), Vec::<String>::new());
}

/// The graphs the rule is checked on, printed (`cargo test --test structure -- --ignored
/// --nocapture`): each edge with one place that makes it.
#[test]
#[ignore = "prints the import graphs; run by hand"]
fn print_the_import_graphs() {
    for (name, dir) in [("core", "crates/core/src"), ("runtime", "src")] {
        for (graph_name, graph) in graphs(&edges(&Crate::read(&root().join(dir)))) {
            println!("{name}: {graph_name}");
            for (from, next) in &graph {
                for (to, at) in next {
                    println!("  {from} -> {to} ({at})");
                }
            }
        }
    }
}

#[test]
fn an_import_from_a_higher_layer_is_found() {
    let krate = synthetic(&[
        ("lib.rs", "pub mod low;\npub mod high;\npub mod new;\n"),
        ("low.rs", "fn f() { crate::high::g() }\n"),
        ("high.rs", "use crate::low::f;\n"),
        ("new.rs", ""),
    ]);
    let found = upward(&krate, &[&["low"], &["high"]]);
    assert_eq!(
        found,
        [
            "`new` is in no layer: add it to the table",
            "low (layer 0) imports high (layer 1) at low.rs:1",
        ]
    );
}
