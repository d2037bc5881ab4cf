//! Every shipped arm configuration under `config/` parses and validates, bad files and keys
//! give errors that name them, and the session files wall-push and cut-pocket set only what
//! differs from the defaults.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_shared::config::{self, ArmConfig, ConfigError};

fn config_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../config"))
}

#[test]
fn shipped_arm_configs_parse() {
    let mut n = 0;
    for entry in std::fs::read_dir(config_dir().join("arms")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let cfg: ArmConfig = config::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
            cfg.stiffness().unwrap();
            n += 1;
        }
    }
    assert!(n >= 2, "expected the shipped arm configs");
}

#[test]
fn bad_arm_configs_are_named() {
    let path = config_dir().join("arms/prototype.toml");
    let err = config::load::<ArmConfig>(&path, &["workspace.theta_max_rad=2".into()]).unwrap_err();
    assert!(
        matches!(err, ConfigError::OutOfRange { ref field, .. } if field == "workspace.theta_max_rad"),
        "{err}"
    );
    let err = config::load::<ArmConfig>(&path, &["workspace.bogus=1".into()]).unwrap_err();
    assert!(err.to_string().contains("bogus"), "{err}");
    let err = config::load::<ArmConfig>(&config_dir().join("arms/missing.toml"), &[]).unwrap_err();
    assert!(err.to_string().contains("missing.toml"), "{err}");
    let err = config::parse::<ArmConfig>("geometry = 5", "inline.toml", &[]).unwrap_err();
    assert!(err.to_string().contains("inline.toml"), "{err}");
}

/// One value, one verdict: a slave section's field is judged the same in a session file
/// (`slave.<section>.<field>`) as in an experiment file (`<section>.<field>`), and the session's
/// environment takes the experiment's surface ranges.
#[test]
fn a_value_gets_the_same_verdict_in_every_file() {
    use h4_master_sim::session;
    use h4_slave_sim::experiment::ExperimentConfig;
    let session_file = config_dir().join("sessions/wall-push.toml");
    let experiment_file = config_dir().join("experiments/fig6b.toml");
    let verdict = |e: Result<(), ConfigError>| match e {
        Ok(()) => "accepted".to_string(),
        Err(ConfigError::OutOfRange { value, allowed, .. }) => format!("{value}: {allowed}"),
        Err(other) => panic!("not a range verdict: {other}"),
    };
    let cases = [
        ("controller.kp", "-5"),
        ("controller.kp", "5"),
        ("controller.tool_mass_kg", "0"),
        ("controller.max_speed_mm_per_s", "0.5"),
        ("plant.stiffness_scale", "20"),
        ("plant.servo_rate_hz", "500"),
        ("sensor.noise_std_n", "11"),
        ("sensor.filter_cutoff_hz", "0.5"),
    ];
    for (key, value) in cases {
        // The ranges alone (the override lifts only the arm's stable-gain check, below).
        let in_session = session::load_with(&session_file, &[format!("slave.{key}={value}")], true);
        let in_experiment =
            config::load::<ExperimentConfig>(&experiment_file, &[format!("{key}={value}")]);
        let s = verdict(in_session.map(|_| ()).map_err(|e| match e {
            session::SessionError::Config(c) => c,
            other => panic!("{other}"),
        }));
        let x = verdict(in_experiment.map(|_| ()));
        assert_eq!(s, x, "{key}={value}: session {s}, experiment {x}");
        if value == "-5" {
            assert_ne!(s, "accepted", "slave.controller.kp=-5 must be refused");
        }
    }
    // Within the field's range, beyond the arm's stable range: a session refuses it with
    // its reason unless overridden (the slave's endpoint refuses the same when built).
    let hot = session::load(&session_file, &["slave.controller.kp=5".to_string()])
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        hot.contains("kp_max") && hot.contains("--unsafe-test-override"),
        "{hot}"
    );
    for (env_key, surface_key, value) in [
        ("tilt_deg", "tilt_deg", "50"),
        ("tilt_deg", "tilt_deg", "61"),
        ("stiffness_n_per_mm", "stiffness_n_per_mm", "500000"),
        ("stiffness_n_per_mm", "stiffness_n_per_mm", "2000000"),
    ] {
        let s = session::load(&session_file, &[format!("environment.{env_key}={value}")]);
        let x = config::load::<ExperimentConfig>(
            &experiment_file,
            &[format!("surface.{surface_key}={value}")],
        );
        assert_eq!(s.is_ok(), x.is_ok(), "{env_key}={value}");
    }
}

/// Where a leaf key sits in a TOML document: each step a key, with the index of the table
/// when the key holds an array of tables (`operator.intent[3].at_s`).
type KeyPath = Vec<(String, Option<usize>)>;

/// Every leaf key of a TOML table (a value that is not a table): tables and arrays of tables
/// are walked, an array of values is one key.
fn leaf_keys(table: &toml::Table, at: &KeyPath, out: &mut Vec<KeyPath>) {
    for (key, value) in table {
        let mut here = at.clone();
        match value {
            toml::Value::Table(inner) => {
                here.push((key.clone(), None));
                leaf_keys(inner, &here, out);
            }
            toml::Value::Array(items)
                if !items.is_empty() && items.iter().all(|i| i.is_table()) =>
            {
                for (i, item) in items.iter().enumerate() {
                    if let toml::Value::Table(inner) = item {
                        let mut each = at.clone();
                        each.push((key.clone(), Some(i)));
                        leaf_keys(inner, &each, out);
                    }
                }
            }
            _ => {
                here.push((key.clone(), None));
                out.push(here);
            }
        }
    }
}

fn count_leaf_keys(text: &str) -> usize {
    let table: toml::Table = toml::from_str(text).unwrap();
    let mut out = Vec::new();
    leaf_keys(&table, &Vec::new(), &mut out);
    out.len()
}

/// Removes the leaf at `path` from `table`.
fn remove_leaf(table: &mut toml::Table, path: &[(String, Option<usize>)]) {
    let Some(((key, index), rest)) = path.split_first() else {
        return;
    };
    if rest.is_empty() {
        table.remove(key);
        return;
    }
    let next = match (table.get_mut(key), index) {
        (Some(toml::Value::Table(inner)), None) => inner,
        (Some(toml::Value::Array(items)), Some(i)) => match items.get_mut(*i) {
            Some(toml::Value::Table(inner)) => inner,
            _ => return,
        },
        _ => return,
    };
    remove_leaf(next, rest);
}

fn path_text(path: &[(String, Option<usize>)]) -> String {
    path.iter()
        .map(|(k, i)| match i {
            Some(i) => format!("{k}[{i}]"),
            None => k.clone(),
        })
        .collect::<Vec<_>>()
        .join(".")
}

/// The keys of a session file that change nothing: without each one alone the file reads as
/// the same session (its value is the field's default).
fn keys_at_their_default(table: &toml::Table, name: &str) -> Vec<String> {
    use h4_master_sim::session::SessionConfig;
    let text = toml::to_string(table).unwrap();
    let whole: SessionConfig = config::parse(&text, name, &[]).unwrap_or_else(|e| panic!("{e}"));
    let mut paths = Vec::new();
    leaf_keys(table, &Vec::new(), &mut paths);
    let mut redundant = Vec::new();
    for path in paths {
        let mut without = table.clone();
        remove_leaf(&mut without, &path);
        let text = toml::to_string(&without).unwrap();
        if let Ok(cfg) = config::parse::<SessionConfig>(&text, name, &[])
            && cfg == whole
        {
            redundant.push(path_text(&path));
        }
    }
    redundant.sort();
    redundant
}

/// The keys the trimmed session files keep (issue 30 asks for at most 25 and 60): each file
/// sets only what differs from the defaults, so these are what is left. wall-push: name,
/// seed, duration_s, environment.stiffness_n_per_mm and gap_mm, coupling.model and
/// contact_damping_n_s_per_mm, slave.controller.max_accel_mm_per_s2 and the five intent
/// segments' 19 keys (at_s and target_mm are required). cut-pocket: 19 keys besides its 28
/// intent segments' 109 (each at least at_s and target_mm; the raster's moves and pushes are
/// not the defaults).
const KEYS_MAX: [(&str, usize); 2] = [("wall-push.toml", 27), ("cut-pocket.toml", 128)];

/// Issue 30's targets for the same files.
const KEYS_TARGET: [(&str, usize); 2] = [("wall-push.toml", 25), ("cut-pocket.toml", 60)];

#[test]
fn session_files_set_only_what_differs_from_the_defaults() {
    // Negative control of the count: a, b (one array), c.d, c.e.f, and g's two tables'
    // h, i and h: 7.
    let control = "a = 1\nb = [1, 2]\n[c]\nd = true\n[c.e]\nf = \"x\"\n\
                   [[g]]\nh = 1\ni = 2\n[[g]]\nh = 3\n";
    assert_eq!(count_leaf_keys(control), 7);
    assert_eq!(count_leaf_keys(""), 0);
    for (file, max) in KEYS_MAX {
        let path = config_dir().join("sessions").join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let n = count_leaf_keys(&text);
        assert!(n <= max, "{file}: {n} keys, at most {max}");
        let table: toml::Table = toml::from_str(&text).unwrap();
        let redundant = keys_at_their_default(&table, file);
        assert!(
            redundant.is_empty(),
            "{file}: keys set to their default: {redundant:?}"
        );
    }
    // Negative control of the default check: a key added at its default is found.
    let path = config_dir().join("sessions/wall-push.toml");
    let mut table: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    config::apply_override(&mut table, "passivity.enabled=true").unwrap();
    config::apply_override(&mut table, "link.delay_ms=0.0").unwrap();
    let redundant = keys_at_their_default(&table, "wall-push.toml");
    assert_eq!(
        redundant,
        ["link.delay_ms", "passivity.enabled"],
        "{redundant:?}"
    );
}

/// Issue 30's key targets, not met without changing defaults: the intent segments' required
/// keys alone exceed them (see [`KEYS_MAX`]).
#[test]
#[ignore = "issue 30's targets (25, 60) need fewer intent keys than the scripts have"]
fn session_files_meet_the_issue_targets() {
    for (file, max) in KEYS_TARGET {
        let text = std::fs::read_to_string(config_dir().join("sessions").join(file)).unwrap();
        let n = count_leaf_keys(&text);
        assert!(n <= max, "{file}: {n} keys, target {max}");
    }
}
