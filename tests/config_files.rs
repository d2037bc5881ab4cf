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
        let in_session = session::load(&session_file, &[format!("slave.{key}={value}")]);
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
