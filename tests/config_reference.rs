//! One configuration reference (issue 30): `docs/configuration.md` is exactly what `h4-master
//! config-reference` writes from the code (the configuration types' schemas, doc comments,
//! defaults and the checks their validation runs), every key of the arm, experiment and
//! session files has a row with a sentence, and the rows carry the ranges the checks state.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::config_reference::{self, FileReference, Row};
use serde_json::Value;

const STALE: &str = "docs/configuration.md is stale: run \
`cargo run --release -p h4-master-cli -- config-reference --out docs/configuration.md`";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The first line (from 1) where `a` and `b` differ, `None` if they are the same text.
fn first_difference(a: &str, b: &str) -> Option<usize> {
    if a == b {
        return None;
    }
    let mut la = a.lines();
    let mut lb = b.lines();
    let mut n = 1;
    // Same lines but different line ends or final newline: the line after the last.
    while let (Some(x), Some(y)) = (la.next(), lb.next()) {
        if x != y {
            return Some(n);
        }
        n += 1;
    }
    Some(n)
}

#[test]
fn the_reference_is_not_stale() {
    let rendered = config_reference::render().unwrap();
    let path = repo().join("docs/configuration.md");
    let current = std::fs::read_to_string(&path).unwrap_or_default();
    if let Some(line) = first_difference(&rendered, &current) {
        panic!("{STALE} (first difference at line {line})");
    }
}

/// Negative control of the staleness check: a copy changed by one character, or by a final
/// newline, is told apart from the rendered text.
#[test]
fn a_changed_copy_is_stale() {
    let rendered = config_reference::render().unwrap();
    assert_eq!(first_difference(&rendered, &rendered), None);
    let changed = rendered.replacen("| 1 – 10000 |", "| 1 – 10001 |", 1);
    assert_ne!(changed, rendered, "the reference has no `1 – 10000` range");
    assert!(first_difference(&rendered, &changed).is_some());
    let longer = format!("{rendered}\n");
    assert!(first_difference(&rendered, &longer).is_some());
    assert!(first_difference(&rendered, "").is_some());
}

fn file<'a>(files: &'a [FileReference], title: &str) -> &'a FileReference {
    files
        .iter()
        .find(|f| f.title == title)
        .unwrap_or_else(|| panic!("no {title} in the reference"))
}

fn row<'a>(f: &'a FileReference, path: &str) -> &'a Row {
    f.rows()
        .find(|r| r.path == path)
        .unwrap_or_else(|| panic!("{}: no row for {path}", f.title))
}

/// Known fields with the ranges their checks state (read in the checks themselves:
/// `master/src/coupling.rs`, `slave/src/controller/params.rs`, `shared/src/config.rs`,
/// `transport/src/impair.rs`), their defaults and types.
#[test]
fn known_fields_have_their_checked_ranges() {
    let files = config_reference::reference().unwrap();
    let rendered = config_reference::render().unwrap();
    let session = file(&files, "Session file");
    let experiment = file(&files, "Experiment file");
    let arm = file(&files, "Arm file");

    let fade = row(session, "coupling.fade_ms");
    assert_eq!(
        (fade.ty.as_str(), fade.unit.as_str(), fade.range.as_str()),
        ("float", "ms", "1 – 10000")
    );
    assert_eq!(fade.default, "`50`");
    assert!(
        rendered.contains("| `coupling.fade_ms` | float | ms | 1 – 10000 | `50` |"),
        "no fade_ms row in the text"
    );

    let kp = row(session, "slave.controller.kp");
    assert_eq!((kp.unit.as_str(), kp.range.as_str()), ("—", "0 – 10"));
    assert_eq!(kp.default, "`0.3`");
    // The same section in the experiment file, under its own path.
    assert_eq!(row(experiment, "controller.kp").range, "0 – 10");

    let k = row(arm, "actuator_stiffness_n_per_mm");
    assert_eq!((k.unit.as_str(), k.range.as_str()), ("N/mm", "1 – 1e6"));
    assert_eq!(k.ty, "[float; 4]");
    assert_eq!(k.default, "`[100, 100, 100, 100]`");

    let loss = row(session, "link.loss");
    assert_eq!(loss.range, "0 – 1 (probability)");

    // A bound set by another section, beside the section's own.
    let guide = row(session, "coupling.guide_setpoint_max_n");
    assert!(guide.range.contains("0 – 1000"), "{}", guide.range);
    assert!(
        guide.range.contains("up to slave.controller.force_limit_n"),
        "{}",
        guide.range
    );

    // A choice, its default; a default that serialisation skips at 0 still shows.
    let material = row(session, "environment.material");
    assert!(material.ty.contains("`\"steel\"`"), "{}", material.ty);
    assert_eq!(material.default, "`\"resin\"`");
    assert_eq!(
        row(experiment, "controller.track_position_gain_per_s").default,
        "`0`"
    );
    assert_eq!(row(session, "coupling.feed_force_gain").default, "`0`");

    // Arrays of tables, optional sections, required keys, rules in words.
    assert_eq!(row(session, "operator.intent[].move_s").default, "`1`");
    assert_eq!(row(session, "operator.intent[].at_s").default, "required");
    assert_eq!(row(session, "cutting.tool.radius_mm").range, "0.5 – 10");
    assert_eq!(
        row(session, "fixtures.depth_floor.z_mm").default,
        "required"
    );
    assert_eq!(
        row(experiment, "force.steps[].setpoint_n").default,
        "required"
    );
    assert!(row(experiment, "track.direction").range.contains("length"));
    assert!(row(arm, "geometry.e_mm").range.contains("|e| < R"));
    assert_eq!(row(arm, "geometry").default, "`\"prototype\"`");
    assert_eq!(
        row(session, "master.geometry.leg_length_mm").default,
        "`300`"
    );
    assert!(
        rendered.contains("only with a [cutting.turntable] section"),
        "no note on fixtures.turntable_sync"
    );
}

#[test]
fn every_check_names_a_key_and_every_row_has_a_sentence() {
    let files = config_reference::reference().unwrap();
    assert_eq!(files.len(), 3);
    for f in &files {
        assert!(
            f.unmatched.is_empty(),
            "{}: checks on fields the file does not have: {:?}",
            f.title,
            f.unmatched
        );
        let mut n = 0;
        for r in f.rows() {
            let s = r.sentence.trim();
            assert!(
                !s.is_empty() && s != "—",
                "{}: {} has no sentence",
                f.title,
                r.path
            );
            assert!(!r.ty.is_empty(), "{}: {} has no type", f.title, r.path);
            n += 1;
        }
        assert!(n > 10, "{}: only {n} rows", f.title);
    }
}

/// The schema `s` refers to.
fn resolve<'a>(root: &'a Value, s: &'a Value) -> &'a Value {
    match s.get("$ref").and_then(Value::as_str) {
        Some(r) => match r.strip_prefix("#/$defs/") {
            Some(name) => resolve(root, &root["$defs"][name]),
            None => root,
        },
        None => s,
    }
}

/// Every leaf key of a schema by its dotted path (`[]` for each table of an array of
/// tables), walked independently of the generator: objects by their properties, `anyOf` /
/// `oneOf` alternatives, arrays whose items are objects; anything else is a leaf.
fn leaves(root: &Value, s: &Value, path: &str, out: &mut Vec<String>, depth: usize) {
    assert!(depth < 40, "{path}: too deep");
    let s = resolve(root, s);
    let alternatives: Vec<&Value> = ["anyOf", "oneOf"]
        .iter()
        .filter_map(|k| s.get(*k).and_then(Value::as_array))
        .flatten()
        .collect();
    if !alternatives.is_empty() {
        let mut value_alternative = false;
        for a in alternatives {
            let a = resolve(root, a);
            if a.get("type").and_then(Value::as_str) == Some("null") {
                continue;
            }
            if a.get("properties").is_some() || a.get("anyOf").is_some() || a.get("oneOf").is_some()
            {
                leaves(root, a, path, out, depth + 1);
            } else {
                value_alternative = true;
            }
        }
        if value_alternative && !out.iter().any(|p| p == path) {
            out.push(path.to_string());
        }
        return;
    }
    if let Some(props) = s.get("properties").and_then(Value::as_object) {
        for (name, p) in props {
            let child = if path.is_empty() {
                name.clone()
            } else {
                format!("{path}.{name}")
            };
            leaves(root, p, &child, out, depth + 1);
        }
        return;
    }
    if let Some(items) = s.get("items") {
        let items = resolve(root, items);
        if items.get("properties").is_some() {
            leaves(root, items, &format!("{path}[]"), out, depth + 1);
            return;
        }
    }
    out.push(path.to_string());
}

/// No key is silently missing: every leaf of the three schemas has its row in the text.
#[test]
fn every_leaf_of_the_schemas_is_in_the_document() {
    use h4_master_sim::session::SessionConfig;
    use h4_shared::config::ArmConfig;
    use h4_slave_sim::experiment::ExperimentConfig;
    let rendered = config_reference::render().unwrap();
    let schemas = [
        ("Arm file", schemars::schema_for!(ArmConfig).to_value()),
        (
            "Experiment file",
            schemars::schema_for!(ExperimentConfig).to_value(),
        ),
        (
            "Session file",
            schemars::schema_for!(SessionConfig).to_value(),
        ),
    ];
    for (title, schema) in &schemas {
        let mut paths = Vec::new();
        leaves(schema, schema, "", &mut paths, 0);
        assert!(paths.len() > 10, "{title}: only {paths:?}");
        let missing: Vec<&String> = paths
            .iter()
            .filter(|p| !rendered.contains(&format!("| `{p}` |")))
            .collect();
        assert!(missing.is_empty(), "{title}: no row for {missing:?}");
    }
    // Negative control: the walk finds keys the reference must have, and a made-up one is
    // not in the text.
    let mut session = Vec::new();
    leaves(&schemas[2].1, &schemas[2].1, "", &mut session, 0);
    for known in [
        "coupling.fade_ms",
        "operator.intent[].push_n",
        "slave.arm.geometry",
        "slave.arm.geometry.e_mm",
        "cutting.turntable.bandwidth_hz",
        "fixtures.corridor.path_mm",
    ] {
        assert!(
            session.iter().any(|p| p == known),
            "the walk misses {known}"
        );
    }
    assert!(!rendered.contains("| `coupling.no_such_key` |"));
}
