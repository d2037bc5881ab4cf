//! Every shipped arm configuration under `config/` parses and validates, and bad files and
//! keys give errors that name them.
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
