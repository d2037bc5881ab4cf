//! Support for the real-process tests (`tests/process*.rs`): the binaries of this build,
//! scratch directories, child processes killed when dropped, summaries, the shared session
//! arguments and iceoryx2 monitors of the slave's feedback.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command as Proc, Stdio};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use h4_shared::wire::{Command, Feedback};
use h4_transport::Link;
use h4_transport::iceoryx2::{self as iox, Iceoryx2Link, Iceoryx2Monitor, Iceoryx2Options};
use serde_json::Value;

/// One process test at a time: each runs two 1 kHz loops, and the machine has two cores.
pub static SERIAL: Mutex<()> = Mutex::new(());

pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

pub use crate::bins::{binaries, profile_dir, workspace};

/// A scratch directory and iceoryx2 prefix of this test.
pub struct Scratch {
    /// The directory.
    pub dir: PathBuf,
    /// The iceoryx2 prefix.
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
        Self::spawn_in(name, bin, args, scratch, &workspace(), &[])
    }

    /// [`Running::spawn`] in the working directory `cwd` with the extra environment `env`;
    /// standard output goes to `<name>.out` in the scratch directory ([`Running::stdout`]).
    pub fn spawn_in(
        name: &'static str,
        bin: &Path,
        args: &[String],
        scratch: &Scratch,
        cwd: &Path,
        env: &[(&str, &str)],
    ) -> Self {
        let log = scratch.path(&format!("{name}.log"));
        let out = scratch.path(&format!("{name}.out"));
        let child = Proc::new(bin)
            .args(args)
            .current_dir(cwd)
            .envs(env.iter().copied())
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&out).expect("stdout file"))
            .stderr(std::fs::File::create(&log).expect("log file"))
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        Running {
            name,
            child: Some(child),
            log,
        }
    }

    /// What the process wrote on standard output (`<name>.out`, see [`Running::spawn_in`]).
    pub fn stdout(&self) -> String {
        std::fs::read_to_string(self.log.with_extension("out")).unwrap_or_default()
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
        self.wait_status(limit_s).success()
    }

    /// Waits for the exit (watchdog as [`Running::wait`]); returns the exit status.
    pub fn wait_status(&mut self, limit_s: f64) -> std::process::ExitStatus {
        let mut child = self.child.take().expect("child already reaped");
        let t = Instant::now();
        loop {
            if let Some(status) = child.try_wait().expect("try_wait") {
                return status;
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

/// A free TCP port on 127.0.0.1 (for a peer's Zenoh listen endpoint).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("bind a free port")
        .local_addr()
        .expect("its address")
        .port()
}

/// Waits (watchdog `limit_s`) until `run`'s log contains `what`.
pub fn wait_for_log(run: &Running, what: &str, limit_s: f64) {
    let t = Instant::now();
    while !run.log().contains(what) {
        assert!(
            t.elapsed() < Duration::from_secs_f64(limit_s),
            "no {what:?} within {limit_s} s; log:\n{}",
            run.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

pub fn read_json(path: &Path) -> Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("summary {}: {e}", path.display()));
    serde_json::from_str(&text).expect("summary JSON")
}

pub fn f(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing in {v}"))
}

pub fn u(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} missing in {v}"))
}

pub fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

/// The scripted contact used here: the wall-push session on a 20 N/mm wall, so the slave's
/// position-mode contact stays below its force limit (80 N). Both processes get the same
/// session: the master reads it, the slave the files `h4-master slave-config` derives.
pub const SESSION: &str = "config/sessions/wall-push.toml";
pub const WALL_N_PER_MM: &str = "20";

/// `h4-slave run` arguments for the slave side of the session (world and passivity files
/// written by `h4-master slave-config`).
pub fn slave_args(scratch: &Scratch, extra: &[&str]) -> Vec<String> {
    let (master, _) = binaries();
    let world = scratch.path("world.toml");
    let passivity = scratch.path("passivity.toml");
    let mut cfg = s(&["slave-config", SESSION, "--set"]);
    cfg.push(format!("environment.stiffness_n_per_mm={WALL_N_PER_MM}"));
    cfg.extend(["--world".into(), world.display().to_string()]);
    cfg.extend(["--passivity".into(), passivity.display().to_string()]);
    let out = Proc::new(master)
        .args(&cfg)
        .current_dir(workspace())
        .output()
        .expect("h4-master slave-config");
    assert!(
        out.status.success(),
        "slave-config: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut a = s(&["run", "--config"]);
    a.push(world.display().to_string());
    a.push("--passivity-config".into());
    a.push(passivity.display().to_string());
    a.extend(s(&["--fifo-priority", "10", "--iceoryx2-prefix"]));
    a.push(scratch.prefix.clone());
    a.extend(s(extra));
    a
}

pub fn master_args(scratch: &Scratch, extra: &[&str]) -> Vec<String> {
    let mut a = s(&["run", "--config", SESSION, "--set"]);
    a.push(format!("environment.stiffness_n_per_mm={WALL_N_PER_MM}"));
    a.extend(s(&["--fifo-priority", "10", "--iceoryx2-prefix"]));
    a.push(scratch.prefix.clone());
    a.extend(s(extra));
    a
}

/// A third iceoryx2 node on the test's services that watches the slave's feedback.
pub fn spy(scratch: &Scratch) -> Iceoryx2Monitor<Feedback> {
    monitor(&scratch.prefix)
}

/// A receive-only iceoryx2 node on the feedback of `prefix` (arm 0).
pub fn monitor(prefix: &str) -> Iceoryx2Monitor<Feedback> {
    iox::feedback_monitor(&Iceoryx2Options {
        prefix: prefix.to_string(),
        ..Iceoryx2Options::new(0)
    })
    .expect("open the test's iceoryx2 monitor")
}

/// The test as the master on the test's services (publishes commands).
pub fn master_end(scratch: &Scratch) -> Iceoryx2Link<Command, Feedback> {
    iox::master(&Iceoryx2Options {
        prefix: scratch.prefix.clone(),
        ..Iceoryx2Options::new(0)
    })
    .expect("open the test's iceoryx2 end")
}

/// Something feedback can be read from without blocking.
pub trait FeedbackSource {
    /// The next feedback message, if any.
    fn next_feedback(&mut self) -> Option<Feedback>;
}

impl FeedbackSource for Iceoryx2Monitor<Feedback> {
    fn next_feedback(&mut self) -> Option<Feedback> {
        self.try_recv().expect("receive")
    }
}

impl FeedbackSource for Iceoryx2Link<Command, Feedback> {
    fn next_feedback(&mut self) -> Option<Feedback> {
        self.try_recv().expect("receive")
    }
}

/// Reads feedback until `pred` holds (watchdog `limit_s`); returns the matching message.
pub fn watch_until(
    link: &mut impl FeedbackSource,
    limit_s: f64,
    what: &str,
    mut pred: impl FnMut(&Feedback) -> bool,
) -> Feedback {
    let t = Instant::now();
    loop {
        while let Some(fb) = link.next_feedback() {
            if pred(&fb) {
                return fb;
            }
        }
        assert!(
            t.elapsed().as_secs_f64() < limit_s,
            "watchdog: {what} not seen within {limit_s} s"
        );
        std::thread::sleep(Duration::from_micros(500));
    }
}

pub fn force(fb: &Feedback) -> f64 {
    let w = fb.wrench_measured;
    (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt()
}

/// `h4-master loopback` arguments: the test session on the 20 N/mm wall for `duration_s`,
/// both loops under SCHED_FIFO 10 where allowed, plus `extra`.
pub fn loopback_args(duration_s: &str, extra: &[&str]) -> Vec<String> {
    let mut a = s(&["loopback", "--config", SESSION, "--duration-s", duration_s]);
    a.extend(s(&["--fifo-priority", "10", "--set"]));
    a.push(format!("environment.stiffness_n_per_mm={WALL_N_PER_MM}"));
    a.extend(s(extra));
    a
}

/// Runs `h4-master loopback` with `args` (the subcommand itself, its `--summary` and
/// `--fifo-priority 10` added here) in a scratch directory named `tag`, waits at most
/// `limit_s` (the exit code is not judged: a loaded host can spoil `realtime_ok`), and
/// returns its summary and log.
pub fn loopback_summary(tag: &str, args: &[String], limit_s: f64) -> (Value, String) {
    let (master, _) = binaries();
    let scratch = Scratch::new(tag);
    let summary = scratch.path("loopback.json");
    let mut a = s(&["loopback", "--fifo-priority", "10", "--summary"]);
    a.push(summary.display().to_string());
    a.extend(args.iter().cloned());
    let mut run = Running::spawn("loopback", master, &a, &scratch);
    let _ = run.wait(limit_s);
    (read_json(&summary), run.log())
}

/// Whether process `pid` exists and is not a zombie.
pub fn alive(pid: i32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the parenthesised command name.
        Ok(stat) => stat
            .rsplit_once(')')
            .is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z')),
        Err(_) => false,
    }
}

/// Waits (at most `limit_s`) until `pid` is gone; returns whether it went.
pub fn wait_gone(pid: i32, limit_s: f64) -> bool {
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < limit_s {
        if !alive(pid) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    !alive(pid)
}

/// The first child process of `pid` (waits at most `limit_s` for one to appear).
pub fn child_of(pid: i32, limit_s: f64) -> i32 {
    let t = Instant::now();
    loop {
        let children =
            std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children")).unwrap_or_default();
        if let Some(c) = children.split_whitespace().next() {
            return c.parse().expect("child pid");
        }
        assert!(
            t.elapsed().as_secs_f64() < limit_s,
            "watchdog: process {pid} started no child within {limit_s} s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Kills `pid` (SIGKILL) when dropped if it is still alive: a process the test did not start
/// itself (e.g. the slave of a loopback) never outlives a failing test.
pub struct KillOnDrop(pub i32);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if self.0 > 0 && alive(self.0) {
            // SAFETY: plain syscall; a stale pid at worst gets a signal it ignores or ESRCH.
            unsafe {
                libc::kill(self.0, libc::SIGKILL);
            }
        }
    }
}

/// Unix time now, ns.
pub fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// A Python interpreter that imports the public MCAP reader: `H4_TEST_PYTHON` if set, else
/// `python3` when it has `mcap`, else a virtual environment in `target/` made once with
/// `tests/python-requirements.txt` (pinned versions, from PyPI), so the test command works on a
/// fresh machine. A Python that cannot be had is a test failure that says why.
pub fn python_with_mcap() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_venv(
            "python-mcap",
            "python-requirements.txt",
            "import mcap.reader, zstandard, lz4",
            Some("H4_TEST_PYTHON"),
        )
    })
}

/// A Python interpreter that imports Python eclipse-zenoh and rosbags (the outside ROS 2 peer
/// of `tests/ros2_peer.rs`): `H4_TEST_PYTHON_ROS2` if set, else `python3` when it has both,
/// else a virtual environment in `target/` made once with
/// `tests/python-ros2-requirements.txt` (pinned, from PyPI).
pub fn python_with_zenoh_rosbags() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_venv(
            "python-ros2",
            "python-ros2-requirements.txt",
            "import zenoh, rosbags.typesys, mcap.reader, mcap_ros2.decoder, zstandard",
            Some("H4_TEST_PYTHON_ROS2"),
        )
    })
}

/// `env` if set, else `python3` if it runs `imports`, else the virtual environment
/// `target/<venv_name>` made (once) with `tests/<requirements>`.
fn python_venv(venv_name: &str, requirements: &str, imports: &str, env: Option<&str>) -> PathBuf {
    let runs_imports = |python: &Path| {
        Proc::new(python)
            .args(["-c", imports])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if let Some(python) = env.and_then(std::env::var_os) {
        return PathBuf::from(python);
    }
    let system = PathBuf::from("python3");
    if runs_imports(&system) {
        return system;
    }
    let venv = profile_dir().parent().expect("target dir").join(venv_name);
    let python = venv.join("bin").join("python3");
    if !runs_imports(&python) {
        let _ = std::fs::remove_dir_all(&venv);
        // A step of making the environment: run it, fail the test with its stderr.
        let step = |cmd: &mut Proc, what: &str| {
            let out = cmd.output().expect(what);
            assert!(
                out.status.success(),
                "{what} into {} failed (PyPI reachable?):\n{}",
                venv.display(),
                String::from_utf8_lossy(&out.stderr)
            );
        };
        step(
            Proc::new("python3").args(["-m", "venv"]).arg(&venv),
            "python3 -m venv",
        );
        step(
            Proc::new(&python)
                .args([
                    "-m",
                    "pip",
                    "install",
                    "--quiet",
                    "--disable-pip-version-check",
                ])
                .arg("-r")
                .arg(workspace().join("tests").join(requirements)),
            "installing the Python requirements",
        );
        assert!(
            runs_imports(&python),
            "{} cannot run {imports:?}",
            python.display()
        );
    }
    python
}

/// Opens MCAP files with the public Python reader (`mcap` package, `make_reader`) and returns,
/// per path, `{messages, last_log_time_ns: {topic: ns}}`; panics with the reader's error if a
/// file does not open or read to its end.
pub fn read_with_python_mcap(paths: &[&Path]) -> Value {
    const SCRIPT: &str = r#"
import json, sys
from mcap.reader import make_reader
out = {}
for path in sys.argv[1:]:
    with open(path, "rb") as f:
        n, last = 0, {}
        for schema, channel, message in make_reader(f).iter_messages():
            n += 1
            last[channel.topic] = max(last.get(channel.topic, 0), message.log_time)
    out[path] = {"messages": n, "last_log_time_ns": last}
print(json.dumps(out))
"#;
    let out = Proc::new(python_with_mcap())
        .arg("-c")
        .arg(SCRIPT)
        .args(paths)
        .output()
        .expect("python3");
    assert!(
        out.status.success(),
        "the Python MCAP reader failed on {paths:?}:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("reader output")
}
