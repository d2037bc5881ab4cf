//! Running the real processes (`h4-slave run`, `h4-master run`) from tests: the binaries of
//! this build, a scratch directory, children killed on drop, optionally on one of the
//! [`crate::netns::TwoHosts`], and the verdict on two run summaries.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use crate::netns::{Host, TwoHosts};
use crate::relay::Relay;
use h4_master::server::MasterRunSummary;
use h4_slave_sim::server::SimRunSummary;

/// The observers' floor of the criteria (and the simulated matrix's): a passivity
/// observer below −1 mJ means the link generated energy.
pub const ENERGY_FLOOR_J: f64 = -1e-3;

/// The workspace's root directory.
pub fn workspace() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().unwrap_or(here).to_path_buf()
}

/// `target/<profile>/` of the running test binary (`target/<profile>/deps/<test>-…`).
fn profile_dir() -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    exe.parent()
        .and_then(Path::parent)
        .map(Path::to_path_buf)
        .ok_or_else(|| format!("{}: no profile directory", exe.display()))
}

/// The h4-master and h4-slave binaries of this build, built (or confirmed up to date) once
/// with the cargo that runs the tests, in the same profile and target directory.
pub fn binaries() -> Result<&'static (PathBuf, PathBuf), String> {
    static BINS: OnceLock<Result<(PathBuf, PathBuf), String>> = OnceLock::new();
    BINS.get_or_init(|| {
        let dir = profile_dir()?;
        if let Some(cargo) = std::env::var_os("CARGO") {
            let profile = dir.file_name().and_then(|s| s.to_str()).unwrap_or("debug");
            let profile = if profile == "debug" { "dev" } else { profile };
            let mut build = Command::new(cargo);
            h4_telemetry::process::without_cargo_run_env(&mut build);
            let target = dir.parent().ok_or("no target directory")?;
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
                .arg(target)
                .output()
                .map_err(|e| format!("cargo build: {e}"))?;
            if !out.status.success() {
                return Err(format!(
                    "cargo build of h4-master and h4-slave failed:\n{}",
                    String::from_utf8_lossy(&out.stderr)
                ));
            }
        }
        let exe = std::env::consts::EXE_SUFFIX;
        let bins = (
            dir.join(format!("h4-master{exe}")),
            dir.join(format!("h4-slave{exe}")),
        );
        for b in [&bins.0, &bins.1] {
            if !b.is_file() {
                return Err(format!("{} missing", b.display()));
            }
        }
        Ok(bins)
    })
    .as_ref()
    .map_err(Clone::clone)
}

/// A scratch directory (removed on drop unless the test is failing) and an iceoryx2 prefix
/// unique to it.
#[derive(Debug)]
pub struct Scratch {
    dir: PathBuf,
    /// An iceoryx2 service prefix of this scratch.
    pub prefix: String,
}

impl Scratch {
    /// `$TMP/h4-test-<pid>-<name>`, emptied.
    pub fn new(name: &str) -> Result<Self, String> {
        let tag = format!("h4-test-{}-{name}", std::process::id());
        let dir = std::env::temp_dir().join(&tag);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        Ok(Scratch { dir, prefix: tag })
    }

    /// A path inside.
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

/// A child process, killed when dropped (a failing test leaves nothing running); its stderr
/// goes to a log file.
#[derive(Debug)]
pub struct Running {
    name: String,
    child: Option<Child>,
    log: PathBuf,
}

impl Running {
    /// Starts `cmd` (stdin and stdout null, stderr to `<scratch>/<name>.log`) in the workspace.
    pub fn spawn(name: &str, mut cmd: Command, scratch: &Scratch) -> Result<Self, String> {
        let log = scratch.path(&format!("{name}.log"));
        let file = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
        let child = cmd
            .current_dir(workspace())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(file)
            .spawn()
            .map_err(|e| format!("cannot start {name}: {e}"))?;
        Ok(Running {
            name: name.to_string(),
            child: Some(child),
            log,
        })
    }

    /// What it wrote on stderr so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Its pid (0 once reaped).
    pub fn pid(&self) -> i32 {
        self.child
            .as_ref()
            .and_then(|c| i32::try_from(c.id()).ok())
            .unwrap_or(0)
    }

    /// Sends `sig` (if still running).
    pub fn signal(&self, sig: i32) {
        let pid = self.pid();
        if pid > 0 {
            // SAFETY: plain syscall on our own, not yet reaped child.
            unsafe {
                libc::kill(pid, sig);
            }
        }
    }

    /// Kills and reaps it.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Whether it has exited (reaps it then).
    pub fn exited(&mut self) -> bool {
        matches!(
            self.child.as_mut().map(Child::try_wait),
            Some(Ok(Some(_))) | None
        )
    }

    /// Waits for the exit, at most `limit_s` (then it is killed: an error with its log);
    /// returns whether it exited successfully.
    pub fn wait(&mut self, limit_s: f64) -> Result<bool, String> {
        let Some(mut child) = self.child.take() else {
            return Err(format!("{} already reaped", self.name));
        };
        let t = Instant::now();
        loop {
            if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
                return Ok(status.success());
            }
            if t.elapsed().as_secs_f64() > limit_s {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!(
                    "watchdog: {} did not finish within {limit_s} s; its log:\n{}",
                    self.name,
                    self.log()
                ));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// SIGTERM, then an orderly exit within 20 s (an error with its log otherwise).
    pub fn stop(&mut self) -> Result<(), String> {
        self.signal(libc::SIGTERM);
        match self.wait(20.0)? {
            true => Ok(()),
            false => Err(format!("{} failed; its log:\n{}", self.name, self.log())),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Reads a JSON summary.
pub fn read_summary<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// Whether `overrides` turn a safety layer off (a negative control): the processes then run
/// with `--unsafe-test-override`.
pub fn is_control(overrides: &[String]) -> bool {
    overrides.iter().any(|o| {
        o == "passivity.enabled=false"
            || o == "slave.controller.spindle_stall_safe_stop=false"
            || o == "slave.safety_monitor=false"
    })
}

/// The slave's world and passivity files of `session` with `overrides`
/// (`h4-master slave-config`), for `h4-slave run --config W --passivity-config P`.
pub fn slave_config(
    scratch: &Scratch,
    tag: &str,
    session: &str,
    overrides: &[String],
) -> Result<(PathBuf, PathBuf), String> {
    let (master, _) = binaries()?;
    let world = scratch.path(&format!("{tag}-world.toml"));
    let passivity = scratch.path(&format!("{tag}-passivity.toml"));
    let mut cmd = Command::new(master);
    cmd.arg("slave-config").arg(session);
    if is_control(overrides) {
        cmd.arg("--unsafe-test-override");
    }
    for o in overrides {
        cmd.arg("--set").arg(o);
    }
    let out = cmd
        .arg("--world")
        .arg(&world)
        .arg("--passivity")
        .arg(&passivity)
        .current_dir(workspace())
        .output()
        .map_err(|e| format!("h4-master slave-config: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "slave-config: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok((world, passivity))
}

/// The true contact force a run may reach, as a share of the slave's force limit (issue 31:
/// 84 N at 80 N).
pub const TRUE_FORCE_SHARE: f64 = 1.05;

/// The criteria for one real-process run — the simulated matrix's
/// (`tests/delay_matrix.rs`, the session's `[coupling]` section) — on physical evidence from
/// both summaries: every force finite; the slave's true contact force within
/// [`TRUE_FORCE_SHARE`] × the slave's own force limit (its summary's `force_limit_n`, 80 N
/// on the prototype: 84 N); the rendered force within `coupling.force_limit_n`; both
/// passivity observers ≥ [`ENERGY_FLOOR_J`] (NaN fails); round trips completed. Returns the reasons it fails (empty: stable).
pub fn judge(
    master: &MasterRunSummary,
    slave: &SimRunSummary,
    session: &h4_master_sim::session::SessionConfig,
) -> Vec<String> {
    let coupling_limit_n = session.coupling.force_limit_n;
    let force_limit_n = TRUE_FORCE_SHARE * slave.force_limit_n;
    let mut why = Vec::new();
    if !slave.max_force_n.is_finite() || !master.max_rendered_force_n.is_finite() {
        why.push("a force is not finite".to_string());
    }
    if slave.force_limit_n.is_nan() || slave.force_limit_n <= 0.0 {
        why.push(format!(
            "the slave's summary has no force limit ({})",
            slave.force_limit_n
        ));
    }
    if slave.max_force_n > force_limit_n {
        why.push(format!(
            "true contact force {:.2} N > {TRUE_FORCE_SHARE} × the slave's {} N limit",
            slave.max_force_n, slave.force_limit_n
        ));
    }
    if master.max_rendered_force_n > coupling_limit_n + 1e-9 {
        why.push(format!(
            "rendered force {:.1} N > {coupling_limit_n} N",
            master.max_rendered_force_n
        ));
    }
    for (who, e) in [
        ("master", master.energy_min_j),
        ("slave", slave.energy_min_j),
    ] {
        // NaN fails too.
        if e.is_nan() || e < ENERGY_FLOOR_J {
            why.push(format!(
                "the {who}'s observer reached {:.3} mJ < {:.1} mJ",
                e * 1e3,
                ENERGY_FLOOR_J * 1e3
            ));
        }
    }
    if master.round_trip_samples == 0 {
        why.push("no round trip completed".to_string());
    }
    why
}

/// A slave and a master process running one session (the slave's world derived from the
/// same session file and overrides).
#[derive(Debug)]
pub struct Pair {
    /// The slave process.
    pub slave: Running,
    /// The master process.
    pub master: Running,
    slave_summary: PathBuf,
    master_summary: PathBuf,
    /// The slave's recording (`--record`).
    pub slave_record: PathBuf,
    duration_s: f64,
}

/// What a [`Pair`] runs.
#[derive(Clone, Debug)]
pub struct PairSpec<'a> {
    /// A name for files and logs.
    pub tag: &'a str,
    /// The session file (relative to the workspace).
    pub session: &'a str,
    /// `--set` overrides for both sides.
    pub overrides: Vec<String>,
    /// The master's `--duration-s`.
    pub duration_s: f64,
    /// Extra arguments of `h4-slave run` (transport, impairment).
    pub slave_args: Vec<String>,
    /// Extra arguments of `h4-master run`.
    pub master_args: Vec<String>,
}

impl Pair {
    /// Starts the pair across the two hosts: the slave in [`Host::Slave`]'s namespace, the
    /// master in [`Host::Master`]'s.
    pub fn start_on(
        hosts: &TwoHosts,
        spec: &PairSpec<'_>,
        scratch: &Scratch,
    ) -> Result<Self, String> {
        Self::start(spec, scratch, |slave, bin| {
            hosts.command(if slave { Host::Slave } else { Host::Master }, bin)
        })
    }

    /// Starts the slave (recording itself), then the master, both under `--fifo-priority 10`
    /// (refused without the permission: a warning, normal scheduling); `wrap` makes each command
    /// (e.g. to run it on one of two hosts).
    pub fn start(
        spec: &PairSpec<'_>,
        scratch: &Scratch,
        mut wrap: impl FnMut(bool, &Path) -> Command,
    ) -> Result<Self, String> {
        let (master_bin, slave_bin) = binaries()?;
        let tag = spec.tag;
        let (world, passivity) = slave_config(scratch, tag, spec.session, &spec.overrides)?;
        let slave_summary = scratch.path(&format!("{tag}-slave.json"));
        let master_summary = scratch.path(&format!("{tag}-master.json"));
        let slave_record = scratch.path(&format!("{tag}-slave.mcap"));
        let mut sc = wrap(true, slave_bin);
        sc.arg("run")
            .arg("--config")
            .arg(&world)
            .arg("--passivity-config")
            .arg(&passivity)
            .arg("--summary")
            .arg(&slave_summary)
            .arg("--record")
            .arg(&slave_record)
            .args(["--fifo-priority", "10"])
            .args(&spec.slave_args);

        let mut mc = wrap(false, master_bin);
        mc.arg("run").arg("--config").arg(spec.session);
        if is_control(&spec.overrides) {
            sc.arg("--unsafe-test-override");
            mc.arg("--unsafe-test-override");
        }
        for o in &spec.overrides {
            mc.arg("--set").arg(o);
        }
        mc.args(["--duration-s", &spec.duration_s.to_string()])
            .args(["--wait-for-slave-s", "30"])
            .arg("--summary")
            .arg(&master_summary)
            .args(["--fifo-priority", "10"])
            .args(&spec.master_args);
        let slave = Running::spawn(&format!("{tag}-slave"), sc, scratch)?;
        let master = Running::spawn(&format!("{tag}-master"), mc, scratch)?;
        Ok(Pair {
            slave,
            master,
            slave_summary,
            master_summary,
            slave_record,
            duration_s: spec.duration_s,
        })
    }

    /// Waits for the master's end, stops the slave, reads both summaries.
    pub fn finish(&mut self) -> Result<(MasterRunSummary, SimRunSummary), String> {
        let ok = self.master.wait(self.duration_s + 60.0)?;
        self.slave.stop()?;
        if !ok {
            return Err(format!(
                "the master failed:\n{}\nslave:\n{}",
                self.master.log(),
                self.slave.log()
            ));
        }
        Ok((
            read_summary(&self.master_summary)?,
            read_summary(&self.slave_summary)?,
        ))
    }
}

/// A loop that missed more than this share of its deadlines did not run in real time (the
/// threshold of `h4-master loopback`'s `realtime_ok`).
pub const MAX_MISSED_SHARE: f64 = 0.01;

/// Whether either loop of a run was starved by the host (missed more than
/// [`MAX_MISSED_SHARE`] of its deadlines): its physics then describe the host, not the link.
pub fn starved(master: &MasterRunSummary, slave: &SimRunSummary) -> bool {
    [
        (master.run.cycles, master.run.deadline_misses),
        (slave.run.cycles, slave.run.deadline_misses),
    ]
    .iter()
    .any(|&(c, m)| m as f64 > MAX_MISSED_SHARE * (c + m).max(1) as f64)
}

/// The session file `session` (relative to the workspace) with `overrides`, as the master
/// process reads it.
pub fn session(
    session: &str,
    overrides: &[String],
) -> Result<h4_master_sim::session::SessionConfig, String> {
    h4_master_sim::session::load_with(&workspace().join(session), overrides, is_control(overrides))
        .map_err(|e| e.to_string())
}

/// The arguments of one side of a Zenoh link between the two hosts: `--transport zenoh`
/// and `flag` (`--zenoh-listen` for the slave, `--zenoh-connect` for the master) `endpoint`.
pub fn zenoh_args(flag: &str, endpoint: &str) -> Vec<String> {
    ["--transport", "zenoh", flag, endpoint]
        .iter()
        .map(|s| s.to_string())
        .collect()
}

/// The Zenoh arguments of a pair across `relay`: the slave listens on `target` (its host's
/// address), the master connects to the relay. `(slave_args, master_args)`.
pub fn zenoh_across(target: SocketAddr, relay: &Relay) -> (Vec<String>, Vec<String>) {
    (
        zenoh_args("--zenoh-listen", &format!("tcp/{target}")),
        zenoh_args("--zenoh-connect", &format!("tcp/{}", relay.listen_addr())),
    )
}
