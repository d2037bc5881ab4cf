//! Every shipped experiment parses, every key the issue names can be overridden, and bad
//! files and keys give errors that name them (library and command line), never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use h4_shared::config::{self, ConfigError};
use h4_slave_sim::experiment::{ExperimentConfig, ShapeKind};
use h4_slave_sim::plant::MaterialPreset;

fn dir() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/experiments"
    ))
}

fn load(name: &str, overrides: &[&str]) -> Result<ExperimentConfig, ConfigError> {
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    config::load(&dir().join(name), &overrides)
}

#[test]
fn every_shipped_experiment_parses() {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let cfg: ExperimentConfig = config::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
            assert!(cfg.sensor.noise_std_n > 0.0);
            names.push(path.file_name().unwrap().to_string_lossy().to_string());
        }
    }
    names.sort();
    assert_eq!(
        names,
        [
            "fig6b.toml",
            "fig6c.toml",
            "fig6d.toml",
            "fig7b.toml",
            "fig7c.toml",
            "fig7d.toml"
        ]
    );
}

#[test]
fn the_issue_keys_can_be_set() {
    let cfg = load(
        "fig6b.toml",
        &[
            "seed=7",
            "surface.shape=cylinder",
            "surface.material=steel",
            "surface.tilt_deg=12.5",
            "surface.radius_mm=150",
            "surface.stiffness_n_per_mm=750",
            "force.setpoint_n=22",
            "track.speed_mm_per_s=4.5",
            "sensor.noise_std_n=0.2",
            "plant.stiffness_scale=0.7",
            "controller.compliance_model=false",
        ],
    )
    .unwrap();
    assert_eq!(cfg.seed, 7);
    assert_eq!(cfg.surface.shape, ShapeKind::Cylinder);
    assert_eq!(cfg.surface.material, MaterialPreset::Steel);
    assert_eq!(cfg.surface.tilt_deg, 12.5);
    assert_eq!(cfg.surface.radius_mm, 150.0);
    assert_eq!(cfg.surface().material.stiffness_n_per_mm, 750.0);
    assert_eq!(cfg.force.setpoint_n, 22.0);
    assert_eq!(cfg.track.speed_mm_per_s, 4.5);
    assert_eq!(cfg.sensor.noise_std_n, 0.2);
    assert_eq!(cfg.plant.stiffness_scale, 0.7);
    assert!(!cfg.controller.compliance_model);
    // Without the override the material's own stiffness applies.
    let cfg = load("fig7b.toml", &[]).unwrap();
    assert_eq!(cfg.surface().material, MaterialPreset::Steel.material());
}

fn err(name: &str, overrides: &[&str]) -> String {
    load(name, overrides).unwrap_err().to_string()
}

#[test]
fn bad_keys_and_values_are_named() {
    let e = err("fig6b.toml", &["surface.colour=red"]);
    assert!(e.contains("colour"), "{e}");
    let e = err("fig6b.toml", &["surface.shape=cube"]);
    assert!(e.contains("cube") || e.contains("shape"), "{e}");
    let e = err("fig6b.toml", &["surface.material=wood"]);
    assert!(e.contains("wood") || e.contains("material"), "{e}");
    let e = err("fig6b.toml", &["force.setpoint_n=5000"]);
    assert!(e.contains("force.setpoint_n"), "{e}");
    let e = err("fig6b.toml", &["plant.stiffness_scale=0"]);
    assert!(e.contains("plant.stiffness_scale"), "{e}");
    let e = err("fig6b.toml", &["surface.tilt_deg=nan"]);
    assert!(e.contains("surface.tilt_deg"), "{e}");
    let e = err("fig6b.toml", &["track.speed_mm_per_s=-1"]);
    assert!(e.contains("track.speed_mm_per_s"), "{e}");
    let e = err("fig6b.toml", &["controller.compliance_model=maybe"]);
    assert!(e.contains("compliance_model") || e.contains("maybe"), "{e}");
    let e = err("fig6b.toml", &["seed"]);
    assert!(e.contains("seed"), "{e}");
    let e = err("fig6b.toml", &["track.direction=[0, 0, 0]"]);
    assert!(e.contains("track.direction"), "{e}");
    let e = config::load::<ExperimentConfig>(Path::new("/nonexistent/exp.toml"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/exp.toml"), "{e}");
    let e = config::parse::<ExperimentConfig>("seed = 1\nduration_s = [", "broken.toml", &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("broken.toml"), "{e}");
    let e = config::parse::<ExperimentConfig>("seed = 1\n", "short.toml", &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("duration_s") || e.contains("missing"), "{e}");
}

#[test]
fn the_command_line_reports_bad_input_and_runs_good_input() {
    let exe = env!("CARGO_BIN_EXE_h4-slave");
    let file = dir().join("fig7b.toml");
    let out = Command::new(exe)
        .args(["experiment"])
        .arg(&file)
        .args(["--set", "surface.colour=red"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("colour"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    let out = Command::new(exe)
        .args(["experiment", "/nonexistent.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent.toml"));

    let tmp = std::env::temp_dir().join(format!("h4-slave-cli-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let summary = tmp.join("summary.json");
    let record = tmp.join("run.mcap");
    let out = Command::new(exe)
        .args(["experiment"])
        .arg(&file)
        .args(["--set", "duration_s=2", "--summary"])
        .arg(&summary)
        .arg("--record")
        .arg(&record)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let printed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    assert_eq!(printed, written);
    for key in [
        "force_error_rms_n",
        "force_error_p99_n",
        "overshoot_pct",
        "settling_ms",
        "max_force_n",
        "contact_lost_ms",
        "tracked_distance_mm",
        "cycles",
        "sim_time_s",
        "wall_time_s",
    ] {
        assert!(printed.get(key).is_some(), "{key} missing");
    }
    assert_eq!(printed["cycles"], 2000);
    let bytes = std::fs::read(&record).unwrap();
    assert!(bytes.starts_with(b"\x89MCAP0\r\n"));
    let _ = std::fs::remove_dir_all(&tmp);
}
