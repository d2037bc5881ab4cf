//! Process helpers for the outside-client tests (the same as tests/processes.rs's): the
//! binaries of this build, a scratch directory, children killed when dropped.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command as Proc, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use serde_json::Value;

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
            let mut build = Proc::new(cargo);
            h4_shared::process::without_cargo_run_env(&mut build);
            let out = build
                .args(["build", "-p", "h4-master", "-p", "h4-slave", "--profile"])
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

/// A scratch directory and iceoryx2 prefix of this test.
pub struct Scratch {
    pub dir: PathBuf,
    pub prefix: String,
}

impl Scratch {
    pub fn new(name: &str) -> Self {
        let tag = format!("h4-test-{}-{name}", std::process::id());
        let dir = std::env::temp_dir().join(&tag);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch dir");
        Scratch { dir, prefix: tag }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// A child process killed when dropped (a failing test leaves nothing running).
pub struct Running {
    name: &'static str,
    child: Option<Child>,
    log: PathBuf,
}

impl Running {
    pub fn spawn(name: &'static str, bin: &Path, args: &[String], scratch: &Scratch) -> Self {
        let log = scratch.path(&format!("{name}.log"));
        let child = Proc::new(bin)
            .args(args)
            .current_dir(workspace())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).expect("log file"))
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        Running {
            name,
            child: Some(child),
            log,
        }
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn pid(&self) -> i32 {
        self.child.as_ref().map_or(0, |c| c.id() as i32)
    }

    pub fn signal(&self, sig: i32) {
        // SAFETY: plain syscall on our own, not yet reaped child.
        unsafe {
            libc::kill(self.pid(), sig);
        }
    }

    pub fn sigkill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Waits for the exit (watchdog: `limit_s`, then the child is killed and the test
    /// fails); returns whether it exited successfully.
    pub fn wait(&mut self, limit_s: f64) -> bool {
        let mut child = self.child.take().expect("child already reaped");
        let t = Instant::now();
        loop {
            if let Some(status) = child.try_wait().expect("try_wait") {
                return status.success();
            }
            if t.elapsed().as_secs_f64() > limit_s {
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "watchdog: {} did not finish within {limit_s} s; its log:\n{}",
                    self.name,
                    self.log()
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// SIGTERM, then an orderly exit within the watchdog.
    pub fn stop(&mut self) {
        self.signal(libc::SIGTERM);
        let ok = self.wait(20.0);
        assert!(ok, "{} failed; its log:\n{}", self.name, self.log());
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.sigkill();
    }
}

pub fn read_json(path: &Path) -> Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("summary {}: {e}", path.display()));
    serde_json::from_str(&text).expect("summary JSON")
}
