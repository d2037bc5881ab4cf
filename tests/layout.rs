//! The layout a newcomer can change (issue 11): no function in a crate's `src/` is longer than
//! 150 lines, the crates keep the one-directional order shared → transport → slave → master,
//! and `.ci/run` runs README's two commands as README writes them.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

const MAX_FN_LINES: usize = 150;
const CRATES: [&str; 9] = [
    "shared",
    "shared/telemetry",
    "transport",
    "slave",
    "slave/sim",
    "slave/cli",
    "master",
    "master/sim",
    "master/cli",
];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a line with comments, strings and character literals blanked out, so only
/// real braces count. `in_block` carries an open `/* */` comment across lines.
fn code_of(line: &str, in_block: &mut bool) -> String {
    let chars: Vec<char> = line.chars().collect();
    let mut out = String::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let next = chars.get(i + 1).copied();
        if *in_block {
            if c == '*' && next == Some('/') {
                *in_block = false;
                i += 2;
            } else {
                i += 1;
            }
            continue;
        }
        match (c, next) {
            ('/', Some('/')) => break,
            ('/', Some('*')) => {
                *in_block = true;
                i += 2;
            }
            ('"', _) => {
                i += 1;
                while i < chars.len() && chars[i] != '"' {
                    i += if chars[i] == '\\' { 2 } else { 1 };
                }
                i += 1;
            }
            ('\'', _) => {
                // A char literal ('x', '\n', '{') or a lifetime ('a): skip the literal only.
                if chars.get(i + 2) == Some(&'\'') {
                    i += 3;
                } else if next == Some('\\') {
                    i += 2;
                    while i < chars.len() && chars[i] != '\'' {
                        i += 1;
                    }
                    i += 1;
                } else {
                    i += 1;
                }
            }
            _ => {
                out.push(c);
                i += 1;
            }
        }
    }
    out
}

/// Every `fn` with a body: (name, first line, length in lines).
fn functions(text: &str) -> Vec<(String, usize, usize)> {
    let mut in_block = false;
    let code: Vec<String> = text.lines().map(|l| code_of(l, &mut in_block)).collect();
    let mut found = Vec::new();
    for (start, line) in code.iter().enumerate() {
        let Some(pos) = line.find("fn ") else {
            continue;
        };
        if pos > 0
            && line[..pos]
                .chars()
                .last()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
        {
            continue;
        }
        let name: String = line[pos + 3..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if name.is_empty() {
            continue;
        }
        let mut depth = 0i64;
        let mut nesting = 0i64; // ( and [ of the signature: `[f64; 3]` does not end it
        let mut opened = false;
        let mut end = None;
        'scan: for (j, l) in code.iter().enumerate().skip(start) {
            let from = if j == start { pos } else { 0 };
            for c in l[from..].chars() {
                match c {
                    '(' | '[' => nesting += 1,
                    ')' | ']' => nesting -= 1,
                    ';' if !opened && depth == 0 && nesting == 0 => break 'scan,
                    '{' => {
                        depth += 1;
                        opened = true;
                    }
                    '}' => {
                        depth -= 1;
                        if opened && depth == 0 {
                            end = Some(j);
                            break 'scan;
                        }
                    }
                    _ => {}
                }
            }
        }
        if let Some(end) = end {
            found.push((name, start + 1, end - start + 1));
        }
    }
    found
}

#[test]
fn no_function_in_the_crates_is_longer_than_150_lines() {
    let mut long = Vec::new();
    let mut count = 0;
    for krate in CRATES {
        let mut files = Vec::new();
        rust_files(&repo().join(krate).join("src"), &mut files);
        for f in files {
            let text = std::fs::read_to_string(&f).unwrap();
            for (name, line, len) in functions(&text) {
                count += 1;
                if len > MAX_FN_LINES {
                    long.push(format!("{}:{line} fn {name}: {len} lines", f.display()));
                }
            }
        }
    }
    assert!(count > 300, "the scan found only {count} functions");
    assert!(
        long.is_empty(),
        "functions over {MAX_FN_LINES} lines:\n{}",
        long.join("\n")
    );
}

#[test]
fn the_scanner_measures_functions() {
    // Negative control: the scanner sees a long function and ignores braces in strings,
    // characters and comments.
    let mut text = String::from("fn long() {\n    let s = \"{{{\"; // {\n    let c = '{';\n");
    for _ in 0..160 {
        text.push_str("    x += 1;\n");
    }
    text.push_str("}\nfn short<'a>(x: &'a str) -> &'a str { x }\ntrait T { fn decl(&self); }\n");
    text.push_str("fn arr(v: [f64; 3]) -> f64 {\n    v[0]\n}\n");
    let f = functions(&text);
    assert_eq!(f[0], ("long".to_string(), 1, 164));
    assert_eq!(f[1], ("short".to_string(), 165, 1));
    assert_eq!(f[2], ("arr".to_string(), 167, 3));
    assert_eq!(f.len(), 3);
}

/// The workspace's packages in their one direction: each may depend (normally, directly or
/// not) on earlier ones only; the product crates (`h4-slave`, `h4-master`) on no simulation
/// or command-line crate, and the master's product crate not on the slave's. Checked on
/// `cargo metadata`'s resolved graph.
#[test]
fn crates_depend_in_one_direction() {
    const ORDER: [&str; 10] = [
        "h4-shared",
        "h4-part",
        "h4-telemetry",
        "h4-transport",
        "h4-slave",
        "h4-master",
        "h4-slave-sim",
        "h4-master-sim",
        "h4-slave-cli",
        "h4-master-cli",
    ];
    let meta = cargo_metadata();
    for (i, krate) in ORDER.iter().enumerate() {
        let deps = normal_closure(&meta, krate);
        for later in &ORDER[i + 1..] {
            assert!(
                !deps.contains(*later),
                "{krate} depends on {later}: {deps:?}"
            );
        }
    }
    let master = normal_closure(&meta, "h4-master");
    assert!(
        !master.contains("h4-slave"),
        "h4-master depends on h4-slave"
    );
    // Negative control: the walk finds the dependencies that are there.
    let cli = normal_closure(&meta, "h4-master-cli");
    for krate in ["h4-master", "h4-master-sim", "h4-slave", "h4-slave-sim"] {
        assert!(
            cli.contains(krate),
            "the walk misses {krate} under h4-master-cli"
        );
    }
}

/// `cargo tree -p <package> -e normal`: the packages one package pulls in when built alone
/// (its own features, not the workspace's union), names only.
fn tree_alone(package: &str) -> std::collections::BTreeSet<String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args([
            "tree", "-e", "normal", "--prefix", "none", "--format", "{p}", "-p", package,
        ])
        .arg("--manifest-path")
        .arg(repo().join("Cargo.toml"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect()
}

/// The product crates build without the simulator and the UI stack (`cargo tree -p h4-slave`
/// shows no plotters, mcap, foxglove or indicatif): the servers hand their records to a
/// sink the command-line crates build.
#[test]
fn the_product_crates_build_without_the_simulator_or_the_ui_stack() {
    const NOT_IN_PRODUCT: [&str; 6] = [
        "plotters",
        "mcap",
        "foxglove",
        "indicatif",
        "h4-slave-sim",
        "h4-master-sim",
    ];
    for product in ["h4-slave", "h4-master"] {
        let tree = tree_alone(product);
        assert!(tree.contains("h4-shared"), "{product}: {tree:?}");
        for krate in NOT_IN_PRODUCT {
            assert!(!tree.contains(krate), "{product} pulls in {krate}");
        }
    }
    assert!(!tree_alone("h4-master").contains("h4-slave"));
    // Negative control: the command-line crates have them.
    for cli in ["h4-slave-cli", "h4-master-cli"] {
        let tree = tree_alone(cli);
        for krate in ["plotters", "mcap", "foxglove", "indicatif"] {
            assert!(tree.contains(krate), "the tree of {cli} misses {krate}");
        }
    }
}

/// `.ci/run` runs README's two commands exactly as README writes them (a changed README
/// command that CI no longer runs fails here), and the main job's summary goes where git
/// ignores it.
#[test]
fn ci_runs_the_readme_commands() {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let ci = std::fs::read_to_string(repo().join(".ci/run")).unwrap();
    let commands: Vec<&str> = readme
        .split("## The two commands")
        .nth(1)
        .and_then(|rest| rest.split("\n## ").next())
        .unwrap_or("")
        .split("```sh\n")
        .skip(1)
        .filter_map(|block| block.split("```").next())
        .map(str::trim)
        .collect();
    assert_eq!(commands.len(), 2, "{commands:?}");
    for c in &commands {
        assert!(
            ci.lines().any(|l| l.trim() == *c),
            ".ci/run does not run `{c}`"
        );
    }
    let main = commands[0];
    let out = main
        .split("--summary ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .unwrap();
    let dir = out.split('/').next().unwrap();
    let ignore = std::fs::read_to_string(repo().join(".gitignore")).unwrap();
    assert!(
        out.contains('/') && ignore.lines().any(|l| l.trim() == format!("{dir}/")),
        "the main job's summary {out} is not under a directory .gitignore names"
    );
}

/// The packages a workspace package depends on, directly or not, through normal (not dev or
/// build) dependencies, from `cargo metadata`'s resolved graph: names only.
fn normal_closure(meta: &serde_json::Value, package: &str) -> std::collections::BTreeSet<String> {
    let packages = meta["packages"].as_array().unwrap();
    let name_of = |id: &str| -> String {
        packages
            .iter()
            .find(|p| p["id"] == id)
            .map(|p| p["name"].as_str().unwrap().to_string())
            .unwrap()
    };
    let nodes = meta["resolve"]["nodes"].as_array().unwrap();
    let root = packages
        .iter()
        .find(|p| p["name"] == package && p["source"].is_null())
        .unwrap_or_else(|| panic!("no workspace package {package}"))["id"]
        .as_str()
        .unwrap()
        .to_string();
    let mut seen = std::collections::BTreeSet::new();
    let mut todo = vec![root];
    let mut names = std::collections::BTreeSet::new();
    while let Some(id) = todo.pop() {
        if !seen.insert(id.clone()) {
            continue;
        }
        let node = nodes.iter().find(|n| n["id"] == id.as_str()).unwrap();
        for dep in node["deps"].as_array().unwrap() {
            let normal = dep["dep_kinds"]
                .as_array()
                .unwrap()
                .iter()
                .any(|k| k["kind"].is_null());
            if normal {
                let dep_id = dep["pkg"].as_str().unwrap().to_string();
                names.insert(name_of(&dep_id));
                todo.push(dep_id);
            }
        }
    }
    names
}

fn cargo_metadata() -> serde_json::Value {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--manifest-path"])
        .arg(repo().join("Cargo.toml"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The core (`h4-shared`: kinematics, compliance, wire, passivity, configuration types) builds
/// without the I/O and UI stack; telemetry sits beside it. Checked on the resolved dependency
/// graph, so a crate pulled in through another one counts too.
#[test]
fn the_core_builds_without_the_io_stack() {
    const IO_STACK: [&str; 6] = ["mcap", "foxglove", "indicatif", "clap", "tokio", "plotters"];
    let meta = cargo_metadata();
    let core = normal_closure(&meta, "h4-shared");
    for krate in IO_STACK {
        assert!(
            !core.contains(krate),
            "h4-shared depends on {krate}: {core:?}"
        );
    }
    // Negative control: the same walk finds the stack where it is.
    let telemetry = normal_closure(&meta, "h4-telemetry");
    for krate in [
        "mcap",
        "foxglove",
        "indicatif",
        "clap",
        "tokio",
        "h4-shared",
    ] {
        assert!(
            telemetry.contains(krate),
            "the walk misses {krate} under h4-telemetry: {telemetry:?}"
        );
    }
}

/// The top-level modules of a crate's `src/` and the sibling modules each names
/// (`crate::<module>`): module → names.
fn module_imports(src: &Path) -> std::collections::BTreeMap<String, Vec<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut graph = std::collections::BTreeMap::<String, Vec<String>>::new();
    for f in files {
        let rel = f.strip_prefix(src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = top.trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        let names = graph.entry(module.clone()).or_default();
        for (i, _) in text.match_indices("crate::") {
            let name: String = text[i + 7..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() && name != module && !names.contains(&name) {
                names.push(name);
            }
        }
    }
    graph
}

/// A cycle in `graph`, if there is one (the modules along it).
fn import_cycle(graph: &std::collections::BTreeMap<String, Vec<String>>) -> Option<Vec<String>> {
    fn visit(
        m: &str,
        graph: &std::collections::BTreeMap<String, Vec<String>>,
        path: &mut Vec<String>,
        done: &mut std::collections::BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|p| p == m) {
            return Some(path[at..].to_vec());
        }
        if done.contains(m) {
            return None;
        }
        path.push(m.to_string());
        for n in graph.get(m).into_iter().flatten() {
            if let Some(c) = visit(n, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(m.to_string());
        None
    }
    let mut done = std::collections::BTreeSet::new();
    graph
        .keys()
        .find_map(|m| visit(m, graph, &mut Vec::new(), &mut done))
}

/// The core's and telemetry's modules import each other in one direction (no circle such as
/// rt → process → rt).
#[test]
fn core_and_telemetry_modules_import_in_one_direction() {
    for krate in ["shared", "shared/telemetry"] {
        let graph = module_imports(&repo().join(krate).join("src"));
        assert!(graph.len() > 4, "{krate}: only {graph:?}");
        assert_eq!(import_cycle(&graph), None, "{krate}: {graph:?}");
    }
    // Negative control: the search finds a circle.
    let mut g = std::collections::BTreeMap::new();
    g.insert("a".to_string(), vec!["b".to_string()]);
    g.insert("b".to_string(), vec!["c".to_string()]);
    g.insert("c".to_string(), vec!["a".to_string()]);
    assert_eq!(
        import_cycle(&g),
        Some(vec!["a".to_string(), "b".to_string(), "c".to_string()])
    );
}

/// What docs/architecture.md names that does not exist: each crate's modules (the Modules
/// table: `src/<module>.rs` or `src/<module>/mod.rs` under the crate's folder of the first
/// table), each type it names (defined as a struct, enum, trait or type in the workspace's
/// sources), and every path it names (a backticked token with a `/`).
fn architecture_misses(doc: &str) -> Vec<String> {
    let mut folder_of = std::collections::BTreeMap::new();
    let mut misses = Vec::new();
    let ticks = |cell: &str| -> Vec<String> {
        cell.split('`')
            .skip(1)
            .step_by(2)
            .map(|t| t.trim().to_string())
            .collect()
    };
    let mut text = String::new();
    for c in CRATES {
        let mut files = Vec::new();
        rust_files(&repo().join(c).join("src"), &mut files);
        for f in files {
            text.push_str(&std::fs::read_to_string(f).unwrap_or_default());
        }
    }
    let mut krate = String::new();
    for line in doc.lines().filter(|l| l.starts_with('|')) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 4 {
            continue;
        }
        let (a, b) = (ticks(cells[1]), ticks(cells[2]));
        // The crates table: | `folder/` | `crate` | role |
        if a.len() == 1 && a[0].ends_with('/') && b.len() == 1 && b[0].starts_with("h4-") {
            folder_of.insert(b[0].clone(), a[0].trim_end_matches('/').to_string());
            continue;
        }
        // The modules table: | `crate` (or empty: the row above's) | `modules` | what |
        match a.first() {
            Some(c) if c.starts_with("h4-") => krate = c.clone(),
            Some(_) => continue,
            None if cells[1].is_empty() && !krate.is_empty() => {}
            None => continue,
        }
        let Some(folder) = folder_of.get(&krate) else {
            continue;
        };
        let src = repo().join(folder).join("src");
        for m in &b {
            let is_module = m.chars().all(|c| c.is_ascii_lowercase() || c == '_');
            if is_module
                && !src.join(format!("{m}.rs")).exists()
                && !src.join(m).join("mod.rs").exists()
            {
                misses.push(format!("{krate}: no module {m} in {}", src.display()));
            }
        }
        for t in ticks(cells[3]).iter().chain(&b) {
            let is_type = t.len() > 1
                && t.chars().next().is_some_and(|c| c.is_ascii_uppercase())
                && t.chars().all(|c| c.is_ascii_alphanumeric());
            if is_type
                && !["struct", "enum", "trait", "type"]
                    .iter()
                    .any(|k| text.contains(&format!("{k} {t}")))
            {
                misses.push(format!("{krate}: no type {t}"));
            }
        }
    }
    for line in doc.lines() {
        for t in ticks(line) {
            let looks_like_path = t.contains('/')
                && !t.contains(' ')
                && !t.contains("::")
                && (t.ends_with('/') || t.rsplit('/').next().is_some_and(|f| f.contains('.')));
            if looks_like_path
                && !repo().join(&t).exists()
                && !repo().join("docs").join(&t).exists()
            {
                misses.push(format!("no path {t}"));
            }
        }
    }
    if folder_of.is_empty() {
        misses.push("no crates table".to_string());
    }
    misses
}

/// docs/architecture.md matches the code: every module, type and path it names exists.
/// Negative control: a module, a type and a path that do not exist are caught.
#[test]
fn the_architecture_names_only_what_exists() {
    let doc = std::fs::read_to_string(repo().join("docs/architecture.md")).unwrap();
    let misses = architecture_misses(&doc);
    assert!(misses.is_empty(), "docs/architecture.md: {misses:#?}");
    let bad =
        format!("{doc}\n| `h4-slave` | `no_such_module` | `NoSuchType` in `slave/no/such.rs` |\n");
    let misses = architecture_misses(&bad);
    assert_eq!(misses.len(), 3, "{misses:#?}");
}
