//! Checks of the crate's shape that run with `cargo test`: each file of `src/` imports only from
//! its own layer and those below it (the layers are the rows of `docs/architecture.md`'s table,
//! bottom up), no import cycles among the files, `main.rs` only parses and dispatches, and no
//! file grows past the size the code style allows (its own lines outside `#[cfg(test)]` items;
//! a `tests.rs` declared by `#[cfg(test)] mod tests;` is all tests).
//!
//! What counts as an import: every path in shipped code that names something of this crate.
//! That is `use` declarations (`pub use` too, grouped trees, `use` inside functions) and paths
//! written out in code (`crate::audio::wav::read(..)`, `super::JanusError`), when they start with
//! `crate`, `self`, `super`, a child module, or a name another `use` of the same module bound.
//! Code under `#[cfg(test)]` is left out, both test modules and test-only files such as
//! `train/stand_in.rs`. Test helpers may reach across the tree (a trainer test reads
//! `corpus::tests::timit_root`) without tangling what ships.
//!
//! Where an import points: the deepest file that exists for its path
//! (`crate::train::corpus::Corpus` -> `train/corpus.rs`, `crate::codec::opus` ->
//! `codec/opus/mod.rs`). When the named item is only re-exported by that file (`pub use
//! error::AudioError` in `audio/mod.rs`), the import points at the file the re-export names.
//! Without that, a module's facade would be in a cycle with each child that imports through it.
//!
//! `main.rs` is the binary's own crate (it reaches the library as `lipcall::`), so nothing in
//! `src/` can import it and it cannot be part of a cycle; only its size is checked.
//!
//! The scanner is hand-written over a small tokenizer. It skips comments, strings, character
//! literals and lifetimes, so a path in a doc comment or a message is not an import.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Files of data tables, exempt from the size limit.
const DATA_TABLES: &[&str] = &["codec/silk/tables.rs", "codec/speex/lsp_tables.rs"];

const MAX_MAIN_LINES: usize = 150;
const MAX_NON_TEST_LINES: usize = 700;

#[test]
fn no_import_cycles_among_src_files() {
    let krate = Crate::load(&src_dir());
    let graph = krate.import_graph();
    let mut cycles = String::new();
    for component in strongly_connected(&graph) {
        cycles += &describe_cycle(&graph, &component);
    }
    assert!(
        cycles.is_empty(),
        "import cycles among src/ files (each import is `file:line path`):\n{cycles}"
    );
}

/// The layers of `docs/architecture.md`, bottom up: the `src/` folder or file each row of its
/// table names (`src/vocab/` -> `vocab`, `src/input.rs` -> `input`).
fn documented_layers(doc: &str) -> Vec<String> {
    doc.lines()
        .filter_map(|line| line.strip_prefix("| `src/"))
        .filter_map(|rest| rest.split('`').next())
        .map(|name| {
            let name = name.strip_suffix('/').unwrap_or(name);
            name.strip_suffix(".rs").unwrap_or(name).to_owned()
        })
        .collect()
}

/// The layer a file of `src/` belongs to: its top-level module (`net/sip/sdp.rs` -> `net`).
fn layer_of(file: &str) -> &str {
    let top = file.split('/').next().unwrap_or(file);
    top.strip_suffix(".rs").unwrap_or(top)
}

/// Each import from a file into a layer above its own, and each file in no documented layer;
/// `lib.rs` only declares the layers, so it is above them all.
fn layer_violations(graph: &Graph, layers: &[String]) -> Vec<String> {
    let rank = |file: &str| match layer_of(file) {
        "lib" => Some(layers.len()),
        layer => layers.iter().position(|l| l == layer),
    };
    let mut violations = Vec::new();
    for (from, targets) in graph {
        let Some(from_rank) = rank(from) else {
            violations.push(format!(
                "src/{from} is in no layer of docs/architecture.md's table"
            ));
            continue;
        };
        for (to, import) in targets {
            if rank(to).is_some_and(|to_rank| to_rank > from_rank) {
                violations.push(format!(
                    "src/{from}:{} {} -> src/{to} ({} imports from {}, a layer above it)",
                    import.line,
                    import.path,
                    layer_of(from),
                    layer_of(to)
                ));
            }
        }
    }
    violations
}

#[test]
fn no_file_imports_from_a_layer_above_its_own() {
    let doc_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/architecture.md");
    let doc = std::fs::read_to_string(doc_path).expect("read docs/architecture.md");
    let layers = documented_layers(&doc);
    let krate = Crate::load(&src_dir());
    let missing: Vec<&String> = layers
        .iter()
        .filter(|layer| !krate.modules.contains_key(std::slice::from_ref(*layer)))
        .collect();
    assert!(
        missing.is_empty(),
        "docs/architecture.md's table names layers src/ lacks: {missing:?}"
    );
    let violations = layer_violations(&krate.import_graph(), &layers);
    assert!(
        violations.is_empty(),
        "imports against the layer order of docs/architecture.md ({}; a file imports only from \
         its own layer and those below it):\n{}",
        layers.join(" < "),
        violations.join("\n")
    );
}

/// `cargo test --test architecture -- --ignored --nocapture` prints every file's imports of
/// other files: a map for whoever breaks a cycle.
#[test]
#[ignore = "prints the import graph; nothing to check"]
fn print_import_graph() {
    for (from, targets) in Crate::load(&src_dir()).import_graph() {
        for (to, import) in targets {
            println!("src/{from}:{} {} -> src/{to}", import.line, import.path);
        }
    }
}

#[test]
fn main_rs_only_parses_and_dispatches() {
    let lines = std::fs::read_to_string(src_dir().join("main.rs"))
        .expect("read src/main.rs")
        .lines()
        .count();
    assert!(
        lines <= MAX_MAIN_LINES,
        "src/main.rs has {lines} lines; it parses and dispatches only (at most {MAX_MAIN_LINES}): \
         move argument structs, validation and work into the command's module"
    );
}

/// The long flags of `lipcall <command> --help`, in the order shown.
fn listed_flags(command: &str) -> Vec<String> {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lipcall"))
        .args([command, "--help"])
        .output()
        .expect("run lipcall");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|line| line.trim_start().strip_prefix("--"))
        .filter_map(|rest| rest.split([' ', '\t']).next().map(str::to_owned))
        .collect()
}

/// `--janus` is declared beside the flattened call arguments (`commands::janus::SendCommand`)
/// and placed after the address by its display order; the help keeps the order it always had,
/// `--mumble` among the first and its own flags after the rest.
#[test]
fn send_and_receive_help_keep_their_flag_order() {
    assert_eq!(
        listed_flags("send"),
        [
            "to",
            "janus",
            "key-file",
            "mumble",
            "key-hex-file",
            "name",
            "room",
            "codec",
            "bandwidth",
            "frame-ms",
            "quality",
            "pt",
            "no-rtcp",
            "ssrc",
            "seconds",
            "janus-secret-file",
            "janus-token-file",
            "stun",
            "turn",
            "turn-user",
            "turn-password-file",
            "turn-only",
            "channel",
            "password-file",
            "tcp-only",
        ]
    );
    assert_eq!(
        listed_flags("receive"),
        [
            "listen",
            "janus",
            "mumble",
            "wav",
            "rate",
            "weights",
            "features",
            "key-file",
            "key-hex-file",
            "seconds",
            "peer-timeout",
            "clock-tolerance",
            "relay",
            "room",
            "name",
            "pt",
            "janus-secret-file",
            "janus-token-file",
            "stun",
            "turn",
            "turn-user",
            "turn-password-file",
            "turn-only",
            "channel",
            "password-file",
            "tcp-only",
        ]
    );
}

#[test]
fn no_file_over_the_size_limit() {
    let sources = sources(&src_dir());
    let over = files_over_the_size_limit(&sources);
    assert!(
        over.is_empty(),
        "files over {MAX_NON_TEST_LINES} lines of non-test code (split them by concern):\n{}",
        over.join("\n")
    );
    let stale: Vec<&str> = DATA_TABLES
        .iter()
        .copied()
        .filter(|listed| !sources.contains_key(*listed))
        .collect();
    assert!(
        stale.is_empty(),
        "DATA_TABLES names files that are gone; remove them: {stale:?}"
    );
}

/// `src/main.rs` and every file the library compiles outside tests, with its non-test lines,
/// where they pass the limit. A `tests.rs` declared by `#[cfg(test)] mod tests;` is compiled
/// only for tests, so none of it counts.
fn files_over_the_size_limit(sources: &BTreeMap<String, String>) -> Vec<String> {
    let krate = Crate::from_sources(sources.clone());
    let checked = krate.files.keys().map(String::as_str).chain(["main.rs"]);
    checked
        .filter(|file| !DATA_TABLES.contains(file))
        .filter_map(|file| {
            let lines = non_test_lines(sources.get(file)?);
            (lines > MAX_NON_TEST_LINES)
                .then(|| format!("src/{file}: {lines} lines of non-test code"))
        })
        .collect()
}

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `src`, by path under it, with its text.
fn sources(src: &Path) -> BTreeMap<String, String> {
    let mut paths = Vec::new();
    rust_files(src, src, &mut paths);
    paths
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(src.join(&p)).expect("read a source file");
            (p, text)
        })
        .collect()
}

/// Lines of `text` outside the items under `#[cfg(test)]`, wherever those sit: a test module at
/// the end, a `mod tests;` declaration near the top, a test-only helper inside an `impl`.
fn non_test_lines(text: &str) -> usize {
    let tokens = tokenize(text);
    if (0..tokens.len().min(64)).any(|i| is_cfg_test(&tokens, i, true)) {
        return 0;
    }
    let mut test_lines = BTreeSet::new();
    let mut i = 0;
    while i < tokens.len() {
        if is_cfg_test(&tokens, i, false) {
            let (end, _) = skip_attributed(&tokens, i + 7);
            let end = end.clamp(i + 7, tokens.len());
            test_lines.extend(tokens[i].line..=tokens[end - 1].line);
            i = end;
        } else {
            i += 1;
        }
    }
    text.lines().count().saturating_sub(test_lines.len())
}

// ---- Tokens ------------------------------------------------------------------------------------

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    /// `::`
    PathSep,
    Punct(char),
    /// A string, character or number literal; its text never matters here.
    Literal,
}

#[derive(Clone, Debug)]
struct Token {
    tok: Tok,
    line: usize,
}

fn tokenize(text: &str) -> Vec<Token> {
    let chars: Vec<char> = text.chars().collect();
    let at = |k: usize| chars.get(k).copied().unwrap_or('\0');
    let is_ident_start = |c: char| c.is_alphabetic() || c == '_';
    let is_ident_char = |c: char| c.is_alphanumeric() || c == '_';
    let mut tokens = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let start_line = line;
        let mut push = |tok| {
            tokens.push(Token {
                tok,
                line: start_line,
            })
        };
        if c == '\n' {
            line += 1;
            i += 1;
        } else if c.is_whitespace() {
            i += 1;
        } else if c == '/' && at(i + 1) == '/' {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            while i < chars.len() {
                if chars[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if chars[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    line += usize::from(chars[i] == '\n');
                    i += 1;
                }
            }
        } else if c == '"' {
            i = skip_quoted(&chars, i + 1, &mut line);
            push(Tok::Literal);
        } else if c == '\'' {
            if at(i + 1) == '\\' {
                i += 3;
                while i < chars.len() && chars[i] != '\'' {
                    i += 1;
                }
                i += 1;
                push(Tok::Literal);
            } else if at(i + 2) == '\'' {
                i += 3;
                push(Tok::Literal);
            } else {
                // A lifetime or label: no path can start with one.
                i += 1;
                while is_ident_char(at(i)) {
                    i += 1;
                }
            }
        } else if is_ident_start(c) {
            let start = i;
            while is_ident_char(at(i)) {
                i += 1;
            }
            let word: String = chars[start..i].iter().collect();
            let raw_string = at(i) == '"' || (at(i) == '#' && matches!(at(i + 1), '"' | '#'));
            if matches!(word.as_str(), "r" | "br" | "cr") && raw_string {
                let mut hashes = 0;
                while at(i) == '#' {
                    hashes += 1;
                    i += 1;
                }
                i += 1;
                loop {
                    if i >= chars.len() {
                        break;
                    }
                    if chars[i] == '"' && (1..=hashes).all(|h| at(i + h) == '#') {
                        i += 1 + hashes;
                        break;
                    }
                    line += usize::from(chars[i] == '\n');
                    i += 1;
                }
                push(Tok::Literal);
            } else if word == "r" && at(i) == '#' && is_ident_start(at(i + 1)) {
                let start = i + 1;
                i += 1;
                while is_ident_char(at(i)) {
                    i += 1;
                }
                push(Tok::Ident(chars[start..i].iter().collect()));
            } else if matches!(word.as_str(), "b" | "c") && at(i) == '"' {
                i = skip_quoted(&chars, i + 1, &mut line);
                push(Tok::Literal);
            } else if word == "b" && at(i) == '\'' {
                i += if at(i + 1) == '\\' { 2 } else { 1 };
                while i < chars.len() && chars[i] != '\'' {
                    i += 1;
                }
                i += 1;
                push(Tok::Literal);
            } else {
                push(Tok::Ident(word));
            }
        } else if c.is_ascii_digit() {
            while is_ident_char(at(i)) || (at(i) == '.' && at(i + 1).is_ascii_digit()) {
                i += 1;
            }
            push(Tok::Literal);
        } else if c == ':' && at(i + 1) == ':' {
            i += 2;
            push(Tok::PathSep);
        } else {
            i += 1;
            push(Tok::Punct(c));
        }
    }
    tokens
}

/// Index after the closing quote of a string whose body starts at `i`.
fn skip_quoted(chars: &[char], mut i: usize, line: &mut usize) -> usize {
    while i < chars.len() {
        match chars[i] {
            '\\' => i += 1,
            '"' => return i + 1,
            '\n' => *line += 1,
            _ => {}
        }
        i += 1;
    }
    i
}

// ---- One file's imports ------------------------------------------------------------------------

/// A path of this file that may name something of the crate, as written.
#[derive(Clone, Debug, PartialEq)]
struct Reference {
    /// The inline module (within the file) the path is written in; empty at the file's top.
    scope: Vec<String>,
    segments: Vec<String>,
    line: usize,
}

/// A name a `use` declaration brings into its module.
#[derive(Clone, Debug, PartialEq)]
struct Binding {
    scope: Vec<String>,
    name: String,
    segments: Vec<String>,
}

#[derive(Debug, Default)]
struct FileScan {
    /// `use` paths and paths written in code, outside `#[cfg(test)]`.
    references: Vec<Reference>,
    bindings: Vec<Binding>,
    /// Child modules declared by `mod name;` or `mod name { .. }`, by inline scope.
    children: BTreeMap<Vec<String>, BTreeSet<String>>,
    /// `#[cfg(test)] mod name;` at the file's top: files that only tests compile.
    test_children: BTreeSet<String>,
    /// The whole file is `#![cfg(test)]`.
    test_only: bool,
}

fn is_punct(tokens: &[Token], i: usize, c: char) -> bool {
    tokens.get(i).is_some_and(|t| t.tok == Tok::Punct(c))
}

fn ident(tokens: &[Token], i: usize) -> Option<&str> {
    match tokens.get(i).map(|t| &t.tok) {
        Some(Tok::Ident(name)) => Some(name),
        _ => None,
    }
}

/// Whether `#[cfg(test)]` (or, with `inner`, `#![cfg(test)]`) starts at `i`.
fn is_cfg_test(tokens: &[Token], i: usize, inner: bool) -> bool {
    let at = i + usize::from(inner);
    is_punct(tokens, i, '#')
        && (!inner || is_punct(tokens, i + 1, '!'))
        && is_punct(tokens, at + 1, '[')
        && ident(tokens, at + 2) == Some("cfg")
        && is_punct(tokens, at + 3, '(')
        && ident(tokens, at + 4) == Some("test")
        && is_punct(tokens, at + 5, ')')
        && is_punct(tokens, at + 6, ']')
}

const ITEM_KEYWORDS: &[&str] = &[
    "fn",
    "impl",
    "struct",
    "enum",
    "union",
    "mod",
    "use",
    "const",
    "static",
    "type",
    "trait",
    "macro_rules",
    "extern",
    "unsafe",
    "async",
];

/// Skips the item (or statement, field, match arm) an attribute that ended before `start`
/// applies to. Returns the index after it and, for `mod name;`, the module's name.
fn skip_attributed(tokens: &[Token], start: usize) -> (usize, Option<String>) {
    let mut k = start;
    // Further attributes and the visibility come before the item's keyword.
    while k < tokens.len() {
        if is_punct(tokens, k, '#') && is_punct(tokens, k + 1, '[') {
            k = skip_balanced(tokens, k + 1);
        } else if ident(tokens, k) == Some("pub") {
            k += 1;
            if is_punct(tokens, k, '(') {
                k = skip_balanced(tokens, k);
            }
        } else {
            break;
        }
    }
    let keyword = ident(tokens, k).unwrap_or("");
    let declared_module = (keyword == "mod" && is_punct(tokens, k + 2, ';'))
        .then(|| ident(tokens, k + 1).map(str::to_owned))
        .flatten();
    let item = ITEM_KEYWORDS.contains(&keyword);
    let mut depth = 0usize;
    let mut j = start;
    while j < tokens.len() {
        match tokens[j].tok {
            Tok::Punct('{' | '(' | '[') => depth += 1,
            Tok::Punct(close @ ('}' | ')' | ']')) => {
                if depth == 0 {
                    return (j, declared_module);
                }
                depth -= 1;
                if depth == 0 && close == '}' {
                    return (j + 1, declared_module);
                }
            }
            Tok::Punct(';') if depth == 0 => return (j + 1, declared_module),
            Tok::Punct(',') if depth == 0 && !item => return (j + 1, declared_module),
            _ => {}
        }
        j += 1;
    }
    (j, declared_module)
}

/// Index after the bracket group that opens at `open`.
fn skip_balanced(tokens: &[Token], open: usize) -> usize {
    let mut depth = 0usize;
    for (j, token) in tokens.iter().enumerate().skip(open) {
        match token.tok {
            Tok::Punct('{' | '(' | '[') => depth += 1,
            Tok::Punct('}' | ')' | ']') => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return j + 1;
                }
            }
            _ => {}
        }
    }
    tokens.len()
}

/// One leaf of a `use` tree: its full path and the name it binds (none for `_` and globs).
#[derive(Debug, PartialEq)]
struct UseLeaf {
    segments: Vec<String>,
    binds: Option<String>,
}

/// Parses the `use` tree at `i` under `prefix`; returns the index after it.
fn parse_use_tree(
    tokens: &[Token],
    mut i: usize,
    prefix: &[String],
    out: &mut Vec<UseLeaf>,
) -> usize {
    let mut path = prefix.to_vec();
    if tokens.get(i).is_some_and(|t| t.tok == Tok::PathSep) {
        // `use ::name` is another crate.
        path.push("::".into());
        i += 1;
    }
    loop {
        match tokens.get(i).map(|t| &t.tok) {
            Some(Tok::Ident(name)) => {
                path.push(name.clone());
                i += 1;
                if tokens.get(i).is_some_and(|t| t.tok == Tok::PathSep) {
                    i += 1;
                    continue;
                }
                if path.last().is_some_and(|s| s == "self") {
                    path.pop();
                }
                let mut binds = path.last().cloned();
                if ident(tokens, i) == Some("as") {
                    binds = ident(tokens, i + 1)
                        .filter(|a| *a != "_")
                        .map(str::to_owned);
                    i += 2;
                }
                out.push(UseLeaf {
                    segments: path,
                    binds,
                });
                return i;
            }
            Some(Tok::Punct('*')) => {
                out.push(UseLeaf {
                    segments: path,
                    binds: None,
                });
                return i + 1;
            }
            Some(Tok::Punct('{')) => {
                i += 1;
                loop {
                    if is_punct(tokens, i, '}') || i >= tokens.len() {
                        return i + 1;
                    }
                    if is_punct(tokens, i, ',') {
                        i += 1;
                        continue;
                    }
                    let before = i;
                    i = parse_use_tree(tokens, i, &path, out);
                    if i == before {
                        i += 1;
                    }
                }
            }
            _ => return i,
        }
    }
}

fn scan(text: &str) -> FileScan {
    let tokens = tokenize(text);
    let mut found = FileScan::default();
    if (0..tokens.len().min(64)).any(|i| is_cfg_test(&tokens, i, true)) {
        found.test_only = true;
        return found;
    }
    // Inline modules open around the current token, with the bracket depth inside each.
    let mut inline: Vec<(String, usize)> = Vec::new();
    let mut depth = 0usize;
    let mut i = 0;
    while i < tokens.len() {
        let scope: Vec<String> = inline.iter().map(|(name, _)| name.clone()).collect();
        if is_cfg_test(&tokens, i, false) {
            let (end, test_module) = skip_attributed(&tokens, i + 7);
            if let (Some(name), true) = (test_module, scope.is_empty() && depth == 0) {
                found.test_children.insert(name);
            }
            i = end;
            continue;
        }
        match &tokens[i].tok {
            Tok::Punct('{' | '(' | '[') => depth += 1,
            Tok::Punct('}' | ')' | ']') => {
                depth = depth.saturating_sub(1);
                while inline.last().is_some_and(|(_, inside)| *inside > depth) {
                    inline.pop();
                }
            }
            Tok::Ident(word) if word == "mod" => {
                if let Some(name) = ident(&tokens, i + 1) {
                    found
                        .children
                        .entry(scope.clone())
                        .or_default()
                        .insert(name.to_owned());
                    if is_punct(&tokens, i + 2, '{') {
                        inline.push((name.to_owned(), depth + 1));
                    }
                    i += 2;
                    continue;
                }
            }
            Tok::Ident(word) if word == "use" => {
                let line = tokens[i].line;
                let mut leaves = Vec::new();
                let mut end = parse_use_tree(&tokens, i + 1, &[], &mut leaves);
                while end < tokens.len() && !is_punct(&tokens, end, ';') {
                    end += 1;
                }
                for leaf in leaves {
                    if let Some(name) = leaf.binds {
                        found.bindings.push(Binding {
                            scope: scope.clone(),
                            name,
                            segments: leaf.segments.clone(),
                        });
                    }
                    found.references.push(Reference {
                        scope: scope.clone(),
                        segments: leaf.segments,
                        line,
                    });
                }
                i = end + 1;
                continue;
            }
            Tok::Ident(first) => {
                let starts_path = i == 0 || tokens[i - 1].tok != Tok::PathSep;
                if starts_path
                    && tokens.get(i + 1).is_some_and(|t| t.tok == Tok::PathSep)
                    && ident(&tokens, i + 2).is_some()
                {
                    let mut segments = vec![first.clone()];
                    let mut j = i + 1;
                    while tokens.get(j).is_some_and(|t| t.tok == Tok::PathSep) {
                        let Some(next) = ident(&tokens, j + 1) else {
                            break;
                        };
                        segments.push(next.to_owned());
                        j += 2;
                    }
                    found.references.push(Reference {
                        scope,
                        segments,
                        line: tokens[i].line,
                    });
                    i = j;
                    continue;
                }
            }
            _ => {}
        }
        i += 1;
    }
    found
}

// ---- The crate's files and the graph -----------------------------------------------------------

struct Crate {
    /// Every file the library compiles outside tests, by path under `src/`, with its scan.
    files: BTreeMap<String, FileScan>,
    /// Module path (`["train", "corpus"]`) to its file.
    modules: BTreeMap<Vec<String>, String>,
}

/// An import of one file by another: where it is written and what it says.
#[derive(Clone, Debug)]
struct Import {
    line: usize,
    path: String,
}

type Graph = BTreeMap<String, BTreeMap<String, Import>>;

fn module_path(file: &str) -> Vec<String> {
    let trimmed = file.strip_suffix(".rs").unwrap_or(file);
    let mut parts: Vec<String> = trimmed.split('/').map(str::to_owned).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

fn rust_files(dir: &Path, root: &Path, out: &mut Vec<String>) {
    let entries = std::fs::read_dir(dir).expect("read a src/ directory");
    for entry in entries {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            rust_files(&path, root, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let relative = path.strip_prefix(root).expect("under src/");
            out.push(relative.to_string_lossy().replace('\\', "/"));
        }
    }
}

impl Crate {
    fn load(src: &Path) -> Crate {
        let mut sources = sources(src);
        sources.remove("main.rs");
        Crate::from_sources(sources)
    }

    /// The library's files as the compiler sees them: reached from `lib.rs` through `mod`
    /// declarations that are not `#[cfg(test)]`.
    fn from_sources(sources: BTreeMap<String, String>) -> Crate {
        let scans: BTreeMap<String, FileScan> = sources
            .iter()
            .map(|(p, text)| (p.clone(), scan(text)))
            .collect();
        let by_module: BTreeMap<Vec<String>, &String> =
            scans.keys().map(|p| (module_path(p), p)).collect();
        let mut modules = BTreeMap::new();
        let mut pending = vec![Vec::<String>::new()];
        while let Some(module) = pending.pop() {
            let Some(&file) = by_module.get(&module) else {
                continue;
            };
            let scan = &scans[file];
            if scan.test_only {
                continue;
            }
            modules.insert(module.clone(), file.clone());
            for child in scan.children.get(&Vec::new()).into_iter().flatten() {
                if !scan.test_children.contains(child) {
                    let mut child_path = module.clone();
                    child_path.push(child.clone());
                    pending.push(child_path);
                }
            }
        }
        let compiled: BTreeSet<&String> = modules.values().collect();
        let files = scans
            .into_iter()
            .filter(|(p, _)| compiled.contains(p))
            .collect();
        Crate { files, modules }
    }

    /// The absolute module path a path of `file` (written in its inline `scope`) stands for, or
    /// `None` when it names another crate, a local item or something not known.
    fn absolute(
        &self,
        file: &str,
        scope: &[String],
        segments: &[String],
        hops: usize,
    ) -> Option<Vec<String>> {
        if hops > 8 {
            return None;
        }
        let scan = &self.files[file];
        let mut base = module_path(file);
        base.extend(scope.iter().cloned());
        let (first, rest) = segments.split_first()?;
        let mut path = match first.as_str() {
            "crate" => Vec::new(),
            "self" => base,
            "super" => {
                let mut path = base;
                path.pop()?;
                let mut rest = rest;
                while rest.first().is_some_and(|s| s == "super") {
                    path.pop()?;
                    rest = &rest[1..];
                }
                path.extend(rest.iter().cloned());
                return Some(path);
            }
            name if scan.children.get(scope).is_some_and(|c| c.contains(name)) => {
                let mut path = base;
                path.push(name.to_owned());
                path
            }
            name => {
                let binding = scan
                    .bindings
                    .iter()
                    .find(|b| b.scope == scope && b.name == name && b.segments != segments)?;
                self.absolute(file, scope, &binding.segments, hops + 1)?
            }
        };
        path.extend(rest.iter().cloned());
        Some(path)
    }

    /// The file an absolute path points at: the deepest file that exists for it, or the file
    /// that file's re-export of the named item leads to.
    fn file_of(&self, path: &[String], hops: usize) -> String {
        let mut consumed = 0;
        while consumed < path.len() && self.modules.contains_key(&path[..=consumed]) {
            consumed += 1;
        }
        let file = self.modules[&path[..consumed]].clone();
        if let Some(name) = path.get(consumed)
            && hops < 8
        {
            let re_export = self.files[&file]
                .bindings
                .iter()
                .find(|b| b.scope.is_empty() && &b.name == name);
            if let Some(binding) = re_export
                && let Some(mut target) = self.absolute(&file, &[], &binding.segments, 0)
            {
                target.extend(path[consumed + 1..].iter().cloned());
                return self.file_of(&target, hops + 1);
            }
        }
        file
    }

    fn import_graph(&self) -> Graph {
        let mut graph = Graph::new();
        for (file, scan) in &self.files {
            let edges = graph.entry(file.clone()).or_default();
            for reference in &scan.references {
                let Some(path) = self.absolute(file, &reference.scope, &reference.segments, 0)
                else {
                    continue;
                };
                let target = self.file_of(&path, 0);
                if target != *file {
                    edges.entry(target).or_insert_with(|| Import {
                        line: reference.line,
                        path: reference.segments.join("::"),
                    });
                }
            }
        }
        graph
    }
}

/// Tarjan's strongly connected components with more than one file: each is one tangle of cycles.
fn strongly_connected(graph: &Graph) -> Vec<BTreeSet<String>> {
    struct State<'g> {
        graph: &'g Graph,
        index: BTreeMap<&'g str, usize>,
        low: BTreeMap<&'g str, usize>,
        stack: Vec<&'g str>,
        on_stack: BTreeSet<&'g str>,
        components: Vec<BTreeSet<String>>,
    }
    fn visit<'g>(s: &mut State<'g>, node: &'g str) {
        let n = s.index.len();
        s.index.insert(node, n);
        s.low.insert(node, n);
        s.stack.push(node);
        s.on_stack.insert(node);
        for next in s.graph.get(node).into_iter().flat_map(|e| e.keys()) {
            if !s.index.contains_key(next.as_str()) {
                visit(s, next);
                let low = s.low[node].min(s.low[next.as_str()]);
                s.low.insert(node, low);
            } else if s.on_stack.contains(next.as_str()) {
                let low = s.low[node].min(s.index[next.as_str()]);
                s.low.insert(node, low);
            }
        }
        if s.low[node] == s.index[node] {
            let mut component = BTreeSet::new();
            while let Some(member) = s.stack.pop() {
                s.on_stack.remove(member);
                component.insert(member.to_owned());
                if member == node {
                    break;
                }
            }
            if component.len() > 1 {
                s.components.push(component);
            }
        }
    }
    let mut state = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        components: Vec::new(),
    };
    for node in graph.keys() {
        if !state.index.contains_key(node.as_str()) {
            visit(&mut state, node);
        }
    }
    state.components.sort();
    state.components
}

/// One shortest cycle through the component's first file, then every import inside it.
fn describe_cycle(graph: &Graph, component: &BTreeSet<String>) -> String {
    let start = component.first().expect("a component has files");
    let mut came_from: BTreeMap<&str, &str> = BTreeMap::new();
    let mut queue = std::collections::VecDeque::from([start.as_str()]);
    let mut closing = None;
    while let Some(node) = queue.pop_front() {
        for next in graph[node].keys().filter(|n| component.contains(*n)) {
            if next == start {
                closing = Some(node);
                break;
            }
            if !came_from.contains_key(next.as_str()) {
                came_from.insert(next, node);
                queue.push_back(next);
            }
        }
        if closing.is_some() {
            break;
        }
    }
    let mut back = Vec::new();
    let mut node = closing.expect("a component holds a cycle through each file");
    while node != start {
        back.push(node);
        node = came_from[node];
    }
    let mut cycle = vec![start.as_str()];
    cycle.extend(back.into_iter().rev());
    cycle.push(start);
    let mut text = format!("cycle: src/{}\n", cycle.join(" -> src/"));
    for from in component {
        for (to, import) in graph[from].iter().filter(|(to, _)| component.contains(*to)) {
            let _ = writeln!(
                text,
                "  src/{from}:{} {} -> src/{to}",
                import.line, import.path
            );
        }
    }
    text
}

// ---- Tests of the scanner and the resolver -----------------------------------------------------

fn strings(parts: &[&str]) -> Vec<String> {
    parts.iter().map(|s| s.to_string()).collect()
}

fn use_paths(text: &str) -> Vec<String> {
    scan(text)
        .references
        .iter()
        .map(|r| r.segments.join("::"))
        .collect()
}

#[test]
fn scanner_reads_grouped_nested_and_renamed_uses() {
    let text = "use crate::{a::B, c::{self, D, e::F as G}, h::*};\npub use crate::x::Y;";
    assert_eq!(
        use_paths(text),
        [
            "crate::a::B",
            "crate::c",
            "crate::c::D",
            "crate::c::e::F",
            "crate::h",
            "crate::x::Y"
        ]
    );
    let bound: Vec<_> = scan(text).bindings.into_iter().map(|b| b.name).collect();
    assert_eq!(bound, ["B", "c", "D", "G", "Y"]);
}

#[test]
fn scanner_reads_uses_in_functions_and_paths_in_code() {
    let text = "fn f() {\n    use crate::a::B;\n    let x = crate::c::d(1);\n    y.z::<u8>();\n}";
    let found = scan(text);
    assert_eq!(use_paths(text), ["crate::a::B", "crate::c::d"]);
    assert_eq!(found.references[1].line, 3);
}

#[test]
fn scanner_skips_comments_strings_and_test_code() {
    let text = r####"
        // use crate::a::B;
        /* use crate::b::C; /* nested */ crate::c::D */
        /// crate::d::E in a doc comment
        const S: &str = "crate::e::F";
        const R: &str = r#"use crate::f::G; "# ;
        const C: char = '"';
        fn lifetime<'a>(x: &'a str) -> &'a str { x }
        #[cfg(test)]
        mod tests {
            use crate::g::H;
        }
        #[cfg(test)]
        use crate::h::I;
        #[cfg(test)]
        pub(crate) mod stand_in;
        use crate::kept::J;
    "####;
    let found = scan(text);
    assert_eq!(use_paths(text), ["crate::kept::J"]);
    assert_eq!(
        found.test_children,
        BTreeSet::from(["stand_in".to_string()])
    );
    assert!(found.children.is_empty(), "{:?}", found.children);
}

#[test]
fn scanner_keeps_a_cfg_test_field_from_swallowing_the_rest() {
    let text = "struct S {\n    #[cfg(test)]\n    probe: u8\n}\nuse crate::after::T;";
    assert_eq!(use_paths(text), ["crate::after::T"]);
}

fn tiny_crate(files: &[(&str, &str)]) -> Crate {
    Crate::from_sources(
        files
            .iter()
            .map(|(p, t)| (p.to_string(), t.to_string()))
            .collect(),
    )
}

fn edges(krate: &Crate) -> Vec<String> {
    let mut out = Vec::new();
    for (from, targets) in krate.import_graph() {
        for to in targets.keys() {
            out.push(format!("{from} -> {to}"));
        }
    }
    out
}

#[test]
fn resolver_points_at_the_deepest_existing_file() {
    let krate = tiny_crate(&[
        ("lib.rs", "pub mod a; pub mod b;"),
        ("a/mod.rs", "pub mod inner; pub fn top() {}"),
        (
            "a/inner.rs",
            "pub struct Deep; pub mod nested { pub struct N; }",
        ),
        (
            "b.rs",
            "use crate::a::inner::Deep;\nuse crate::a::inner::nested::N;\nfn f() { crate::a::top() }",
        ),
    ]);
    assert_eq!(edges(&krate), ["b.rs -> a/inner.rs", "b.rs -> a/mod.rs"]);
    let path = strings(&["a", "inner", "nested", "N"]);
    assert_eq!(krate.file_of(&path, 0), "a/inner.rs");
}

#[test]
fn resolver_follows_super_self_children_and_bindings() {
    let krate = tiny_crate(&[
        ("lib.rs", "pub mod a;"),
        (
            "a/mod.rs",
            "mod one; mod two; mod three; pub struct Shared;",
        ),
        ("a/one.rs", "use super::two;\nfn f() { two::g(); }"),
        (
            "a/two.rs",
            "pub fn g() { self::h() } fn h() {} use super::super::a::Shared;",
        ),
        (
            "a/three.rs",
            "use super::{self as parent};\nfn f() { let _ = parent::Shared; }",
        ),
    ]);
    assert_eq!(
        edges(&krate),
        [
            "a/one.rs -> a/two.rs",
            "a/three.rs -> a/mod.rs",
            "a/two.rs -> a/mod.rs"
        ]
    );
}

#[test]
fn resolver_follows_a_facade_re_export_to_the_defining_file() {
    let krate = tiny_crate(&[
        ("lib.rs", "pub mod audio;"),
        (
            "audio/mod.rs",
            "mod error; mod capture; pub use error::AudioError; pub use capture::Capture;",
        ),
        ("audio/error.rs", "pub enum AudioError {}"),
        (
            "audio/capture.rs",
            "use crate::audio::AudioError; pub struct Capture;",
        ),
    ]);
    assert_eq!(
        edges(&krate),
        [
            "audio/capture.rs -> audio/error.rs",
            "audio/mod.rs -> audio/capture.rs",
            "audio/mod.rs -> audio/error.rs"
        ]
    );
    assert!(strongly_connected(&krate.import_graph()).is_empty());
}

#[test]
fn resolver_ignores_other_crates_and_test_only_files() {
    let krate = tiny_crate(&[
        ("lib.rs", "pub mod a; pub mod b; #[cfg(test)] mod helpers;"),
        (
            "a.rs",
            "use std::fmt; use ::serde::Serialize; use clap::Parser; fn f() { Self::g() }",
        ),
        ("b.rs", "pub fn g() {}"),
        ("helpers.rs", "use crate::a::f; use crate::b::g;"),
    ]);
    assert_eq!(edges(&krate), Vec::<String>::new());
    assert!(!krate.files.contains_key("helpers.rs"));
}

#[test]
fn cycles_are_found_and_named_file_by_file() {
    let krate = tiny_crate(&[
        ("lib.rs", "pub mod a; pub mod b; pub mod c; pub mod d;"),
        ("a.rs", "use crate::b::B; pub struct A;"),
        ("b.rs", "use crate::c::C; pub struct B;"),
        ("c.rs", "pub struct C; fn f() { let _ = crate::a::A; }"),
        ("d.rs", "use crate::a::A;"),
    ]);
    let graph = krate.import_graph();
    let components = strongly_connected(&graph);
    let expected: BTreeSet<String> = strings(&["a.rs", "b.rs", "c.rs"]).into_iter().collect();
    assert_eq!(components, [expected]);
    let text = describe_cycle(&graph, &components[0]);
    assert!(
        text.starts_with("cycle: src/a.rs -> src/b.rs -> src/c.rs -> src/a.rs\n"),
        "{text}"
    );
    assert!(
        text.contains("src/c.rs:1 crate::a::A -> src/a.rs"),
        "{text}"
    );
}

// ---- Tests of the size count and the layer order -----------------------------------------------

#[test]
fn non_test_lines_leave_out_each_cfg_test_item_wherever_it_sits() {
    let text = "mod a;\n#[cfg(test)]\nmod tests;\n\nfn f() {}\nimpl S {\n    #[cfg(test)]\n    \
                fn probe(&self) {\n        todo!()\n    }\n    fn kept(&self) {}\n}\n\
                #[cfg(test)]\nmod more {\n    fn t() {}\n}\n";
    assert_eq!(text.lines().count(), 16);
    // Left out: `mod tests;` (2), `probe` (4) and `more` (4).
    assert_eq!(non_test_lines(text), 6);
    assert_eq!(non_test_lines("#![cfg(test)]\nfn f() {}\n"), 0);
}

#[test]
fn size_limit_counts_a_files_own_code_and_not_its_cfg_test_tests_rs() {
    let code = "fn f() {}\n".repeat(MAX_NON_TEST_LINES);
    let sources: BTreeMap<String, String> = [
        (
            "lib.rs",
            "pub mod big; pub mod small; pub mod loose;".to_owned(),
        ),
        (
            "big/mod.rs",
            format!("#[cfg(test)]\nmod tests;\n{code}fn over() {{}}\n"),
        ),
        ("big/tests.rs", code.repeat(3)),
        (
            "small/mod.rs",
            format!("{code}#[cfg(test)]\nmod tests {{\n{code}}}\n"),
        ),
        ("loose/mod.rs", "mod tests;\n".to_owned()),
        ("loose/tests.rs", format!("{code}fn over() {{}}\n")),
        ("main.rs", "fn main() {}\n".to_owned()),
    ]
    .into_iter()
    .map(|(p, t)| (p.to_owned(), t))
    .collect();
    assert_eq!(
        files_over_the_size_limit(&sources),
        [
            "src/big/mod.rs: 701 lines of non-test code",
            "src/loose/tests.rs: 701 lines of non-test code"
        ]
    );
}

#[test]
fn layers_come_from_the_table_and_each_upward_import_is_named() {
    let doc = "| folder | concern |\n|---|---|\n| `src/vocab/` | words |\n\
               | `src/input.rs` | files |\n| `src/net/` | transport |\n| `src/app/` | the app |\n\
               | `tests/`, `benches/` | tests |\n";
    let layers = documented_layers(doc);
    assert_eq!(layers, ["vocab", "input", "net", "app"]);
    let krate = tiny_crate(&[
        (
            "lib.rs",
            "pub mod vocab; pub mod input; pub mod net; pub mod app; pub mod stray;",
        ),
        (
            "vocab/mod.rs",
            "pub struct Word;\npub use crate::app::settings::load;",
        ),
        ("input.rs", "use crate::vocab::Word; pub fn read() {}"),
        ("net/mod.rs", "pub mod peer; pub use crate::vocab::Word;"),
        (
            "net/peer.rs",
            "use super::Word;\nfn f() { crate::app::settings::load(); crate::input::read(); }",
        ),
        (
            "app/mod.rs",
            "pub mod settings; use crate::net::peer; use crate::vocab::load;",
        ),
        ("app/settings.rs", "pub fn load() {}"),
        ("stray.rs", "use crate::vocab::Word;"),
    ]);
    assert_eq!(
        layer_violations(&krate.import_graph(), &layers),
        [
            "src/net/peer.rs:2 crate::app::settings::load -> src/app/settings.rs \
             (net imports from app, a layer above it)",
            "src/stray.rs is in no layer of docs/architecture.md's table",
            "src/vocab/mod.rs:2 crate::app::settings::load -> src/app/settings.rs \
             (vocab imports from app, a layer above it)",
        ]
    );
}
