//! The layout a newcomer can change (issue 11): no function in a crate's `src/` is longer than
//! 150 lines, the crates keep the one-directional order shared → transport → slave → master,
//! and `.ci/run` runs README's two commands as README writes them.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

const MAX_FN_LINES: usize = 150;
const CRATES: [&str; 4] = ["shared", "transport", "slave", "master"];

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

#[test]
fn crates_depend_in_one_direction() {
    // shared → transport → slave → master: no crate names a later one.
    for (i, krate) in CRATES.iter().enumerate() {
        let manifest = std::fs::read_to_string(repo().join(krate).join("Cargo.toml")).unwrap();
        // Dependency lines only: comments may name other crates.
        let code: Vec<&str> = manifest
            .lines()
            .map(|l| l.split('#').next().unwrap_or(""))
            .collect();
        for later in &CRATES[i + 1..] {
            assert!(
                !code.iter().any(|l| l.contains(&format!("h4-{later}"))),
                "{krate}/Cargo.toml depends on h4-{later}"
            );
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
