//! The configuration reference, `docs/configuration.md` (`h4-master config-reference`):
//! every field of the arm, experiment and session files, each with its type, unit, range,
//! default and the first sentence of its doc comment, all taken from the code:
//!
//! * the fields, their types, doc comments and defaults from the configuration types' JSON
//!   schemas (`schemars`, which follows their serde attributes: `rename_all`, `default`,
//!   `skip`, `untagged`);
//! * units and ranges from the checks the validation itself runs
//!   ([`h4_shared::config::record_ranges`]): on the defaults first, then on shipped files
//!   and on built-in examples that set the optional sections (`cutting`, `fixtures`,
//!   `cut_target`, …); a field takes the checks of the first file that checks it.
//!
//! `tests/config_reference.rs` fails when `docs/configuration.md` is not what [`render`]
//! writes.

use std::collections::BTreeMap;

use h4_shared::config::{Allowed, ArmConfig, RangeRecord, Validate, parse, record_ranges};
use h4_slave_sim::experiment::ExperimentConfig;
use serde::de::DeserializeOwned;
use serde_json::Value;

use crate::session::SessionConfig;

/// The command that writes the reference, as the generated file names it.
pub const COMMAND: &str =
    "cargo run --release -p h4-master-cli -- config-reference --out docs/configuration.md";

/// The hand-written part of the reference: how files are read and overridden.
const PREAMBLE: &str = "\
All configuration is TOML, read with `h4_shared::config::load`: unknown fields are rejected,
every value is range-checked, and errors name the field and the allowed range
(`actuator_stiffness_n_per_mm[2] = 0.5 is out of range: allowed 1 to 1000000 N/mm`). Every
command that takes a file also takes `--set key.path=value` (repeatable) to override any field;
the value is read as TOML (`--set workspace.theta_max_rad=0.5`,
`--set actuator_stiffness_n_per_mm=[80,80,80,80]`), and a bare word is a string
(`--set geometry=alt`).
";

/// The three kinds of file and how the tables read.
const GUIDE: &str = "\
Three kinds of file:

* **Arm file** (`config/arms/*.toml`, `h4_shared::config::ArmConfig`): one arm's geometry,
  actuator stiffness, workspace limits and identified tool. An experiment file's `[arm]` and a
  session file's `[slave.arm]` are the same section.
* **Experiment file** (`config/experiments/*.toml`, `config/slave/*.toml`,
  `h4_slave_sim::experiment::ExperimentConfig`): the slave's world (arm, surface, sensor,
  plant, controller, cutting, fixtures) with an experiment's set-point, motion, summary and
  targets (`h4-slave experiment`, `h4-slave run --config`; `docs/slave-experiments.md`).
* **Session file** (`config/sessions/*.toml`, `h4_master_sim::session::SessionConfig`): a
  whole teleoperation session, link, master, operator, slave and detector (`h4-master sim`,
  `run`, `loopback`, `matrix`; `docs/sessions.md`).

One table per section of a file; each row is one key by its dotted path (`[]`: in each table
of an array of tables):

* **type**: `float`, `integer`, `bool`, `string`, the values a choice takes, or an array
  (`[float; 3]`: exactly three); `(optional)`: the key may be left out, the field is then unset.
* **unit** and **range**: as the field's check states them when a file is validated. A bound
  that depends on another field shows that field's value in the defaults (or in the shipped
  file that sets the section); several checks on one field are separated by `;`; `—`: the
  value is not range-checked.
* **default**: the value a missing key takes; `required`: the key must be given whenever its
  section is; `none`: unset.
* **description**: the first sentence of the field's doc comment.

A file sets only the keys that differ from these defaults.
";

/// The smallest session file: the required keys and the one intent segment the operator's
/// check needs; every section at its defaults.
const SESSION_DEFAULTS: &str = "\
seed = 0
duration_s = 1.0

[[operator.intent]]
at_s = 0.0
target_mm = [0.0, 0.0, 0.0]
";

/// The optional sections of a slave world (for the checks they run when present).
const WORLD_OPTIONAL_SECTIONS: &str = "
[cutting]
coefficients = { k_tc_n_per_mm2 = 120.0, k_rc_n_per_mm2 = 50.0, k_ac_n_per_mm2 = 25.0 }

[cutting.turntable]

[fixtures.depth_floor]
z_mm = -252.0

[fixtures.corridor]
path_mm = [[-10.0, 0.0], [10.0, 0.0]]
half_width_mm = 1.0

[fixtures.region]
min_mm = [-10.0, -6.0]
max_mm = [10.0, 6.0]

[fixtures.turntable_sync]
speed_rad_per_s = 0.5

[fixtures.mesh]
allowance_mm = 0.3

[cut_target]
kind = \"pocket\"
centre_mm = [0.0, 0.0]
size_mm = [20.0, 12.0]
depth_mm = 2.0
";

/// A session that sets every optional value and section (checked last: it only adds fields
/// nothing before it checked).
const SESSION_OPTIONAL: &str = "\
seed = 0
duration_s = 1.0

[environment]
stiffness_n_per_mm = 100.0

[slave.controller]
force_axis = [0.0, 0.0, 1.0]

[[operator.intent]]
at_s = 0.0
target_mm = [0.0, 0.0, 0.0]
";

/// The smallest experiment file: the required keys; every other section at its defaults.
const EXPERIMENT_DEFAULTS: &str = "\
seed = 0
duration_s = 1.0

[surface]
shape = \"plane\"
material = \"resin\"

[force]
setpoint_n = 10.0

[track]
speed_mm_per_s = 1.0
";

/// An experiment that sets every optional value and section (checked last).
const EXPERIMENT_OPTIONAL: &str = "\
seed = 0
duration_s = 10.0

[surface]
shape = \"plane\"
material = \"resin\"
stiffness_n_per_mm = 200.0
damping_ratio = 0.3
friction_coefficient = 0.15

[force]
setpoint_n = 10.0
steps = [{ time_s = 1.0, setpoint_n = 15.0 }]

[track]
speed_mm_per_s = 1.0

[controller]
force_axis = [0.0, 0.0, 1.0]
";

/// The session files validated for the ranges, in order: the defaults, the shipped files
/// with the optional sections (cutting, turntable, fixtures, cut target), then the rest.
fn session_sources() -> Vec<(&'static str, String)> {
    vec![
        ("the session defaults", SESSION_DEFAULTS.to_string()),
        (
            "config/sessions/wall-push.toml",
            include_str!("../../../config/sessions/wall-push.toml").to_string(),
        ),
        (
            "config/sessions/cut-pocket.toml",
            include_str!("../../../config/sessions/cut-pocket.toml").to_string(),
        ),
        (
            "config/sessions/cut-profile.toml",
            include_str!("../../../config/sessions/cut-profile.toml").to_string(),
        ),
        (
            "config/sessions/cut-slot-guided.toml",
            include_str!("../../../config/sessions/cut-slot-guided.toml").to_string(),
        ),
        (
            "the optional session sections",
            format!("{SESSION_OPTIONAL}{WORLD_OPTIONAL_SECTIONS}"),
        ),
    ]
}

/// The experiment files validated for the ranges, in order.
fn experiment_sources() -> Vec<(&'static str, String)> {
    vec![
        ("the experiment defaults", EXPERIMENT_DEFAULTS.to_string()),
        (
            "config/experiments/fig6d.toml",
            include_str!("../../../config/experiments/fig6d.toml").to_string(),
        ),
        (
            "the optional experiment sections",
            format!("{EXPERIMENT_OPTIONAL}{WORLD_OPTIONAL_SECTIONS}"),
        ),
    ]
}

/// One documented key: a row of the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Dotted path in the file (`coupling.fade_ms`; `operator.intent[].at_s` in each table
    /// of an array of tables).
    pub path: String,
    /// `float`, `integer`, `bool`, `string`, the choices, an array.
    pub ty: String,
    /// The unit its check states (`—`: none).
    pub unit: String,
    /// What its checks allow (`1 – 10000`; `—`: not checked).
    pub range: String,
    /// The default as TOML (`` `50` ``), `required`, `none` or `—`.
    pub default: String,
    /// The first sentence of its doc comment.
    pub sentence: String,
}

/// One table of a file: the top level, `[slave.controller]`, `[[operator.intent]]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    /// Its dotted path (empty: the top level).
    pub path: String,
    /// An array of tables (`[[operator.intent]]`).
    pub array: bool,
    /// Its keys.
    pub rows: Vec<Row>,
    /// Checks on the section as a whole (`only with a [cutting.turntable] section`).
    pub notes: Vec<String>,
}

impl Table {
    /// The table's heading: `[coupling]`, `[[operator.intent]]`, `top level`.
    pub fn heading(&self) -> String {
        if self.path.is_empty() {
            "top level".to_string()
        } else if self.array {
            format!("[[{}]]", self.path)
        } else {
            format!("[{}]", self.path)
        }
    }
}

/// One kind of file: its tables, and the checks whose field names no key.
#[derive(Clone, Debug, PartialEq)]
pub struct FileReference {
    /// `Arm file`, `Experiment file`, `Session file`.
    pub title: &'static str,
    /// Its tables, in the order of the type's fields.
    pub tables: Vec<Table>,
    /// Fields named by a check that no key or table of the schema has (a check naming a
    /// field the file does not have); empty when every check found its key.
    pub unmatched: Vec<String>,
}

impl FileReference {
    /// Every row of every table.
    pub fn rows(&self) -> impl Iterator<Item = &Row> {
        self.tables.iter().flat_map(|t| t.rows.iter())
    }
}

/// The reference of the three kinds of file: arm, experiment, session.
pub fn reference() -> Result<Vec<FileReference>, String> {
    let arm_default = ArmConfig::default();
    let (checked, arm_records) = record_ranges(|| arm_default.validate());
    checked.map_err(|e| format!("ArmConfig::default(): {e}"))?;
    let arm_defaults = serde_json::to_value(arm_default).map_err(|e| e.to_string())?;
    let arm_schema = schemars::schema_for!(ArmConfig).to_value();
    let experiment_schema = schemars::schema_for!(ExperimentConfig).to_value();
    let session_schema = schemars::schema_for!(SessionConfig).to_value();
    Ok(vec![
        file_reference(
            "Arm file",
            &arm_schema,
            Some(&arm_defaults),
            vec![arm_records],
        ),
        file_reference(
            "Experiment file",
            &experiment_schema,
            None,
            records_of::<ExperimentConfig>(&experiment_sources())?,
        ),
        file_reference(
            "Session file",
            &session_schema,
            None,
            records_of::<SessionConfig>(&session_sources())?,
        ),
    ])
}

/// The whole of `docs/configuration.md`.
pub fn render() -> Result<String, String> {
    let files = reference()?;
    let mut out = String::new();
    out.push_str("# Configuration\n\n");
    out.push_str(
        "<!-- Generated by `h4-master config-reference` from the code: do not edit by hand. -->\n\n",
    );
    out.push_str(&format!(
        "This file is generated from the configuration types by `h4-master config-reference`: \
         their schemas, doc comments and defaults, and the checks their validation runs. Do not \
         edit it by hand; after changing a configuration type, a default or a check, regenerate \
         it with `{COMMAND}` (`tests/config_reference.rs` fails while it is stale).\n\n"
    ));
    out.push_str(PREAMBLE);
    out.push('\n');
    out.push_str(GUIDE);
    for file in &files {
        for table in &file.tables {
            if table.rows.is_empty() && table.notes.is_empty() {
                continue;
            }
            out.push_str(&format!("\n## {}: {}\n\n", file.title, table.heading()));
            for note in &table.notes {
                out.push_str(&format!(
                    "Checked on the whole section: {}.\n\n",
                    cell(note)
                ));
            }
            if table.rows.is_empty() {
                continue;
            }
            out.push_str("| key | type | unit | range | default | description |\n");
            out.push_str("|---|---|---|---|---|---|\n");
            for row in &table.rows {
                out.push_str(&format!(
                    "| `{}` | {} | {} | {} | {} | {} |\n",
                    row.path,
                    cell(&row.ty),
                    cell(&row.unit),
                    cell(&row.range),
                    cell(&row.default),
                    cell(&row.sentence),
                ));
            }
        }
    }
    Ok(out)
}

/// Validates each source with recording on; a source that does not validate is an error (the
/// records would stop at its first failing check).
fn records_of<T: DeserializeOwned + Validate>(
    sources: &[(&'static str, String)],
) -> Result<Vec<Vec<RangeRecord>>, String> {
    sources
        .iter()
        .map(|(name, text)| {
            let (parsed, records) = record_ranges(|| parse::<T>(text, name, &[]));
            parsed.map(|_| records).map_err(|e| format!("{name}: {e}"))
        })
        .collect()
}

/// The checks by field (indices collapsed): a field takes the checks of the first source
/// that checks it.
fn merge(sources: Vec<Vec<RangeRecord>>) -> BTreeMap<String, Vec<RangeRecord>> {
    let mut merged: BTreeMap<String, Vec<RangeRecord>> = BTreeMap::new();
    for source in sources {
        let mut this: BTreeMap<String, Vec<RangeRecord>> = BTreeMap::new();
        for record in source {
            this.entry(record.collapsed_field())
                .or_default()
                .push(record);
        }
        for (path, records) in this {
            merged.entry(path).or_insert(records);
        }
    }
    merged
}

/// The reference of one kind of file from its schema, its defaults (if the type has them)
/// and the checks its sources ran.
fn file_reference(
    title: &'static str,
    schema: &Value,
    defaults: Option<&Value>,
    sources: Vec<Vec<RangeRecord>>,
) -> FileReference {
    let mut walk = Walk {
        root: schema,
        tables: Vec::new(),
    };
    walk.object(schema, "", false, defaults, 0);
    let mut checks = merge(sources);
    let mut tables = Vec::with_capacity(walk.tables.len());
    for t in walk.tables {
        let notes: Vec<String> = checks
            .remove(&t.key)
            .or_else(|| checks.remove(&t.path))
            .map(|records| describe_checks(&records).1)
            .into_iter()
            .filter(|n| n != "—")
            .collect();
        let rows = t
            .leaves
            .into_iter()
            .map(|leaf| {
                let (unit, range) = match checks.remove(&leaf.path) {
                    Some(records) => describe_checks(&records),
                    None => ("—".to_string(), "—".to_string()),
                };
                Row {
                    default: describe_default(&leaf),
                    sentence: first_sentence(&leaf.description),
                    path: leaf.path,
                    ty: leaf.ty,
                    unit,
                    range,
                }
            })
            .collect();
        tables.push(Table {
            path: t.path,
            array: t.array,
            rows,
            notes,
        });
    }
    FileReference {
        title,
        tables,
        unmatched: checks.into_keys().collect(),
    }
}

/// A leaf of the schema: a key whose value is not a table.
struct Leaf {
    path: String,
    ty: String,
    default: Option<Value>,
    required: bool,
    nullable: bool,
    description: String,
}

/// A table met while walking the schema.
struct TableAcc {
    /// The path records name it by (`operator.intent[]` for an array of tables).
    key: String,
    /// Its dotted path.
    path: String,
    array: bool,
    leaves: Vec<Leaf>,
}

/// A walk of a schema's tables and keys, in the order of the type's fields.
struct Walk<'a> {
    root: &'a Value,
    tables: Vec<TableAcc>,
}

/// Deepest nesting of tables walked (the configuration types are not recursive).
const DEPTH_MAX: usize = 32;

impl<'a> Walk<'a> {
    /// The index of the table `key`, added if new.
    fn table(&mut self, key: &str, path: &str, array: bool) -> usize {
        if let Some(i) = self.tables.iter().position(|t| t.key == key) {
            return i;
        }
        self.tables.push(TableAcc {
            key: key.to_string(),
            path: path.to_string(),
            array,
            leaves: Vec::new(),
        });
        self.tables.len() - 1
    }

    /// Walks the object schema `obj` at `path`; `inherited` is the default of the whole
    /// table as the enclosing table's default gives it.
    fn object(
        &mut self,
        obj: &'a Value,
        path: &str,
        array: bool,
        inherited: Option<&'a Value>,
        depth: usize,
    ) {
        let key = if array {
            format!("{path}[]")
        } else {
            path.to_string()
        };
        let t = self.table(&key, path, array);
        if depth > DEPTH_MAX {
            return;
        }
        let Some(props) = obj.get("properties").and_then(Value::as_object) else {
            return;
        };
        let required: Vec<&str> = obj
            .get("required")
            .and_then(Value::as_array)
            .map(|a| a.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        for (name, prop) in props {
            let child = if key.is_empty() {
                name.clone()
            } else {
                format!("{key}.{name}")
            };
            let resolved = resolve(self.root, prop);
            let default = prop
                .get("default")
                .or_else(|| inherited.and_then(|d| d.get(name)));
            let child_default = default.filter(|d| d.is_object());
            let description = prop
                .get("description")
                .or_else(|| resolved.get("description"))
                .and_then(Value::as_str)
                .unwrap_or("")
                .to_string();
            let (alts, nullable) = alternatives(self.root, prop, 0);
            let objects: Vec<&'a Value> =
                alts.iter().copied().filter(|a| has_properties(a)).collect();
            if !objects.is_empty() && objects.len() == alts.len() {
                // A table, or an optional one.
                for o in objects {
                    self.object(o, &child, false, child_default, depth + 1);
                }
                continue;
            }
            if let [only] = alts.as_slice()
                && let Some(items) = table_items(self.root, only)
            {
                // An array of tables.
                self.object(items, &child, true, None, depth + 1);
                continue;
            }
            self.tables[t].leaves.push(Leaf {
                path: child.clone(),
                ty: type_name(self.root, prop, 0),
                default: default.cloned(),
                required: required.contains(&name.as_str()),
                nullable,
                description,
            });
            // A value that may also be a table (`geometry = "alt"` or its parameters).
            for o in objects {
                self.object(o, &child, false, child_default, depth + 1);
            }
        }
    }
}

/// The schema `s` refers to (`$ref` into `$defs`, or `#` for the root), or `s`.
fn resolve<'a>(root: &'a Value, s: &'a Value) -> &'a Value {
    let mut cur = s;
    for _ in 0..DEPTH_MAX {
        let Some(reference) = cur.get("$ref").and_then(Value::as_str) else {
            return cur;
        };
        let target = if reference == "#" {
            Some(root)
        } else {
            reference
                .strip_prefix("#/$defs/")
                .and_then(|name| root.get("$defs")?.get(name))
        };
        match target {
            Some(t) => cur = t,
            None => return cur,
        }
    }
    cur
}

/// The schemas `s` may be, `$ref`s resolved and nested `anyOf`/`oneOf` flattened, without
/// `null`; and whether `null` is one of them (an `Option`).
fn alternatives<'a>(root: &'a Value, s: &'a Value, depth: usize) -> (Vec<&'a Value>, bool) {
    let s = resolve(root, s);
    if depth <= DEPTH_MAX {
        for key in ["anyOf", "oneOf"] {
            if let Some(list) = s.get(key).and_then(Value::as_array) {
                let mut out = Vec::new();
                let mut nullable = false;
                for v in list {
                    let (inner, n) = alternatives(root, v, depth + 1);
                    nullable |= n;
                    out.extend(inner);
                }
                return (out, nullable);
            }
        }
    }
    let types = types_of(s);
    if types == ["null"] || s.get("const").is_some_and(Value::is_null) {
        return (Vec::new(), true);
    }
    let nullable = types.contains(&"null")
        || s.get("enum")
            .and_then(Value::as_array)
            .is_some_and(|e| e.iter().any(Value::is_null));
    (vec![s], nullable)
}

/// The `type` keyword as a list (`"number"`, `["array", "null"]`).
fn types_of(s: &Value) -> Vec<&str> {
    match s.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(list)) => list.iter().filter_map(Value::as_str).collect(),
        _ => Vec::new(),
    }
}

/// An object schema with fields: a table.
fn has_properties(s: &Value) -> bool {
    s.get("properties").is_some_and(Value::is_object)
}

/// The table schema of an array of tables (`[[operator.intent]]`).
fn table_items<'a>(root: &'a Value, s: &'a Value) -> Option<&'a Value> {
    if !types_of(s).contains(&"array") {
        return None;
    }
    let items = resolve(root, s.get("items")?);
    has_properties(items).then_some(items)
}

/// The type of a key as the reference writes it.
fn type_name(root: &Value, s: &Value, depth: usize) -> String {
    let (alts, nullable) = alternatives(root, s, depth);
    let mut names: Vec<String> = Vec::new();
    for a in alts {
        let name = single_type_name(root, a, depth + 1);
        if !names.contains(&name) {
            names.push(name);
        }
    }
    let mut out = if names.is_empty() {
        "value".to_string()
    } else {
        names.join(", ")
    };
    if nullable {
        out.push_str(" (optional)");
    }
    out
}

/// The type of one alternative (no `anyOf`/`oneOf` left).
fn single_type_name(root: &Value, s: &Value, depth: usize) -> String {
    if let Some(c) = s.get("const") {
        return format!("`{}`", toml_text(c));
    }
    if let Some(list) = s.get("enum").and_then(Value::as_array) {
        return list
            .iter()
            .filter(|v| !v.is_null())
            .map(|v| format!("`{}`", toml_text(v)))
            .collect::<Vec<_>>()
            .join(", ");
    }
    if has_properties(s) {
        return "table".to_string();
    }
    let types = types_of(s);
    let Some(first) = types.into_iter().find(|t| *t != "null") else {
        return "value".to_string();
    };
    match first {
        "number" => "float".to_string(),
        "integer" => "integer".to_string(),
        "boolean" => "bool".to_string(),
        "string" => "string".to_string(),
        "object" => "table".to_string(),
        "array" => {
            let item = match s.get("items") {
                Some(items) if depth <= DEPTH_MAX => type_name(root, items, depth + 1),
                _ => "value".to_string(),
            };
            let min = s.get("minItems").and_then(Value::as_u64);
            let max = s.get("maxItems").and_then(Value::as_u64);
            match (min, max) {
                (Some(n), Some(m)) if n == m => format!("[{item}; {n}]"),
                _ => format!("array of {item}"),
            }
        }
        other => other.to_string(),
    }
}

/// The unit and range cells of a key's checks.
fn describe_checks(records: &[RangeRecord]) -> (String, String) {
    let split: Vec<(&str, Option<&str>, Option<&str>, &Allowed)> = records
        .iter()
        .map(|r| {
            let (unit, unit_note) = split_note(&r.unit);
            (unit, unit_note, r.field_note(), &r.allowed)
        })
        .collect();
    let unit = split
        .iter()
        .find(|(u, _, _, a)| !u.is_empty() && matches!(a, Allowed::Range { .. }))
        .map_or("", |(u, _, _, _)| *u);
    let mut entries: Vec<String> = Vec::new();
    for (u, unit_note, field_note, allowed) in &split {
        let mut text = match allowed {
            Allowed::Range { min, max } => format!("{} – {}", number(*min), number(*max)),
            Allowed::Rule(rule) => rule.clone(),
        };
        if !u.is_empty() && *u != unit {
            text.push(' ');
            text.push_str(u);
        }
        let notes: Vec<&str> = [*field_note, *unit_note].into_iter().flatten().collect();
        if !notes.is_empty() {
            text.push_str(&format!(" ({})", notes.join("; ")));
        }
        if !entries.contains(&text) {
            entries.push(text);
        }
    }
    let unit = if unit.is_empty() { "—" } else { unit };
    let range = if entries.is_empty() {
        "—".to_string()
    } else {
        entries.join("; ")
    };
    (unit.to_string(), range)
}

/// A check's unit and the note after it in parentheses: `mm (≥ the minimum)` → (`mm`,
/// `≥ the minimum`); `(probability)` → (``, `probability`); `N/(mm·s)` has no note.
fn split_note(unit: &str) -> (&str, Option<&str>) {
    let unit = unit.trim();
    let (main, note) = if let Some(rest) = unit.strip_prefix('(') {
        ("", rest)
    } else if let Some((main, rest)) = unit.split_once(" (") {
        (main.trim(), rest)
    } else {
        return (unit, None);
    };
    let note = note.strip_suffix(')').unwrap_or(note).trim();
    (main, (!note.is_empty()).then_some(note))
}

/// A number as the reference writes it: plain between 1e-4 and 1e5, else with an exponent
/// (`1e6`, `3.6e6`, `1e-6`).
fn number(v: f64) -> String {
    if v == 0.0 {
        return "0".to_string();
    }
    let a = v.abs();
    if (1e-4..1e5).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// The default cell of a key.
fn describe_default(leaf: &Leaf) -> String {
    match &leaf.default {
        Some(Value::Null) => "none".to_string(),
        Some(v) => format!("`{}`", toml_text(v)),
        None if leaf.required => "required".to_string(),
        None if leaf.nullable => "none".to_string(),
        None => "—".to_string(),
    }
}

/// A JSON value as TOML writes it (`"resin"`, `[0, 0, -250]`, `{ a = 1 }`).
fn toml_text(v: &Value) -> String {
    match v {
        Value::Null => "none".to_string(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.to_string()
            } else if let Some(u) = n.as_u64() {
                u.to_string()
            } else {
                n.as_f64().map_or_else(|| n.to_string(), number)
            }
        }
        Value::String(s) => format!("\"{s}\""),
        Value::Array(items) => format!(
            "[{}]",
            items.iter().map(toml_text).collect::<Vec<_>>().join(", ")
        ),
        Value::Object(map) => {
            if map.is_empty() {
                return "{}".to_string();
            }
            let fields: Vec<String> = map
                .iter()
                .map(|(k, v)| format!("{k} = {}", toml_text(v)))
                .collect();
            format!("{{ {} }}", fields.join(", "))
        }
    }
}

/// The first sentence of a doc comment: up to the first full stop followed by a space (or
/// the end) outside parentheses, brackets and code, not ending an `e.g.`; rustdoc's link
/// brackets around code (`` [`AdcAperture`] ``) dropped.
pub fn first_sentence(text: &str) -> String {
    let flat = text
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace("[`", "`")
        .replace("`]", "`");
    let chars: Vec<char> = flat.chars().collect();
    let mut depth = 0usize;
    let mut code = false;
    for (i, &c) in chars.iter().enumerate() {
        match c {
            '`' => code = !code,
            '(' | '[' if !code => depth += 1,
            ')' | ']' if !code => depth = depth.saturating_sub(1),
            '.' if !code && depth == 0 => {
                let ends = chars.get(i + 1).is_none_or(|n| n.is_whitespace());
                if ends && !abbreviation(&chars[..i]) {
                    return chars[..=i].iter().collect();
                }
            }
            _ => {}
        }
    }
    flat
}

/// Whether the word before a full stop is an abbreviation (`e.g`, `i.e`, `cf`, `vs`).
fn abbreviation(before: &[char]) -> bool {
    let word: String = before
        .iter()
        .rev()
        .take_while(|c| !c.is_whitespace() && **c != '(')
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    matches!(word.as_str(), "e.g" | "i.e" | "cf" | "vs" | "etc")
}

/// Text for a markdown table cell: no line breaks, `|` escaped.
fn cell(text: &str) -> String {
    text.replace('\n', " ").replace('|', "\\|")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sentences_end_at_the_first_full_stop_outside_brackets() {
        assert_eq!(first_sentence("One. Two."), "One.");
        assert_eq!(
            first_sentence("Servo rate, Hz (1000 to 100000; the paper's ran 20 kHz. Yes).\nMore."),
            "Servo rate, Hz (1000 to 100000; the paper's ran 20 kHz. Yes)."
        );
        assert_eq!(
            first_sentence("A value, e.g. 1.5 mm. Next."),
            "A value, e.g. 1.5 mm."
        );
        assert_eq!(first_sentence("See `a.b`. Next."), "See `a.b`.");
        assert_eq!(first_sentence("No stop"), "No stop");
        assert_eq!(
            first_sentence("Reads ([`AdcAperture`])."),
            "Reads (`AdcAperture`)."
        );
    }

    #[test]
    fn numbers_and_notes_are_written_plainly() {
        assert_eq!(number(1e4), "10000");
        assert_eq!(number(1e6), "1e6");
        assert_eq!(number(3.6e6), "3.6e6");
        assert_eq!(number(-0.5), "-0.5");
        assert_eq!(number(1e-6), "1e-6");
        assert_eq!(
            split_note("mm (≥ the minimum)"),
            ("mm", Some("≥ the minimum"))
        );
        assert_eq!(split_note("(probability)"), ("", Some("probability")));
        assert_eq!(split_note("N/(mm·s)"), ("N/(mm·s)", None));
        assert_eq!(split_note(""), ("", None));
    }

    #[test]
    fn every_check_names_a_key_and_every_key_has_a_sentence() {
        let files = reference().unwrap();
        assert_eq!(files.len(), 3);
        for f in &files {
            assert!(f.unmatched.is_empty(), "{}: {:?}", f.title, f.unmatched);
            for row in f.rows() {
                assert!(!row.sentence.trim().is_empty(), "{}: {}", f.title, row.path);
            }
        }
    }
}
