//! The project's binaries for the tests that run them as processes.
//!
//! Test support: a missing binary or a failed build is a test failure, so `expect` is the point.
#![allow(clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The workspace root.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace root")
        .to_path_buf()
}

/// `target/<profile>/` of this test binary (`target/<profile>/deps/processes-…`).
pub fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable");
    let deps = exe.parent().expect("deps dir");
    deps.parent().expect("profile dir").to_path_buf()
}

/// The h4-master and h4-slave binaries of this build, built (or brought up to date) once
/// with the cargo that runs the tests, in the same profile and target directory.
pub fn binaries() -> &'static (PathBuf, PathBuf) {
    static BINS: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    BINS.get_or_init(|| {
        let dir = profile_dir();
        if let Some(cargo) = std::env::var_os("CARGO") {
            let profile = dir.file_name().and_then(|s| s.to_str()).unwrap_or("debug");
            let profile = if profile == "debug" { "dev" } else { profile };
            let mut build = Command::new(cargo);
            h4_telemetry::process::without_cargo_run_env(&mut build);
            let out = build
                .args([
                    "build",
                    "-p",
                    "h4-master-cli",
                    "-p",
                    "h4-slave-cli",
                    "--profile",
                ])
                .arg(profile)
                .arg("--manifest-path")
                .arg(workspace().join("Cargo.toml"))
                .arg("--target-dir")
                .arg(dir.parent().expect("target dir"))
                .output()
                .expect("run cargo build");
            assert!(
                out.status.success(),
                "cargo build of h4-master and h4-slave failed:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        let exe = std::env::consts::EXE_SUFFIX;
        let master = dir.join(format!("h4-master{exe}"));
        let slave = dir.join(format!("h4-slave{exe}"));
        assert!(master.is_file(), "{} missing", master.display());
        assert!(slave.is_file(), "{} missing", slave.display());
        (master, slave)
    })
}
