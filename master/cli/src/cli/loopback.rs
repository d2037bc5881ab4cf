//! `h4-master loopback [--duration-s N] [--summary out.json] [--record out.mcap]
//! [--transport iceoryx2|zenoh]`: the slave (`h4-slave run`, a child process) and the master
//! (this process) as two OS processes connected by iceoryx2 (or Zenoh peers over TCP on
//! 127.0.0.1), with the simulated arms, the simulated surface and the scripted
//! operator of a session file. Stops by itself and prints a summary.

use std::path::{Path, PathBuf};
use std::process::{Child, ExitCode, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use h4_master::server::MasterRunSummary;
use h4_master_sim::session::{self, SessionConfig};
use h4_slave_sim::experiment::{
    ApproachConfig, ExperimentConfig, ForceConfig, SummaryConfig, TrackConfig,
};
use h4_slave_sim::server::SimRunSummary;
use h4_telemetry::process::ExitStatus;
use h4_telemetry::progress::{grouped, verdict_line};
use h4_telemetry::rt::LoopArgs;
use h4_telemetry::rt::RealtimeMode;
use h4_transport::impaired::ImpairArgs;
use h4_transport::open::{TransportArgs, TransportKind};
use serde::Serialize;

/// Run the slave and the master as two processes over iceoryx2 for a fixed time and print a
/// summary (fields in docs/processes.md).
#[derive(Clone, Debug, clap::Args)]
pub struct LoopbackArgs {
    /// How long the master runs, s, a positive finite number (default: the session's
    /// duration_s).
    #[arg(long, value_parser = h4_telemetry::process::positive_seconds)]
    pub duration_s: Option<f64>,
    /// Write the summary as JSON here (it is also printed on stdout).
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Record every cycle of both processes here, one MCAP file: topics `/master/cycle` and
    /// `/slave/cycle` on one timeline (Unix time). Each process writes its part next to it
    /// while running (`<name>.master.part.mcap`, `<name>.slave.part.mcap`); they are merged
    /// and removed at the end.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// The session file: operator script, master arm, coupling, and the slave's world
    /// (environment and slave sections); default: config/sessions/wall-push.toml of the
    /// repository (found from the binary, not the working directory).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a field of the session file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Arm id.
    #[arg(long, default_value_t = 0)]
    pub arm_id: u16,
    /// The link between the two processes: `iceoryx2` (services under a prefix of the run's
    /// own) or `zenoh` (peers over TCP on 127.0.0.1, the slave listening on a free port, the
    /// master connecting to it).
    #[arg(long, value_enum, default_value_t = TransportKind::Iceoryx2)]
    pub transport: TransportKind,
    /// The h4-slave binary (default: next to this executable; under `cargo run` it is built
    /// there first if missing).
    #[arg(long)]
    pub slave_bin: Option<PathBuf>,
    /// The slave's command watchdog, ms.
    #[arg(long, default_value_t = 20.0)]
    pub watchdog_ms: f64,
    /// In a cutting session: the slave writes the machined part into DIR at the end
    /// (`height.png`, `part.stl`, `deviation.png` against the session's `cut_target`;
    /// `h4-slave run --out`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Real time for both loops: `try` (default: SCHED_FIFO and locked memory where
    /// permitted, a one-line note otherwise), `enforce` (not permitted: exit 2), `off`.
    #[arg(long, value_enum, default_value_t = RealtimeMode::Try)]
    pub realtime: RealtimeMode,
    /// The SCHED_FIFO priority of both loops under `--realtime try|enforce` (1–99; default
    /// 80).
    #[arg(long)]
    pub fifo_priority: Option<i32>,
    /// Link impairment, passed to both processes (each impairs what it sends: round trip
    /// R ms is delay_ms=R/2).
    #[command(flatten)]
    pub impair: ImpairArgs,
    /// The live view: the master serves at HOST:PORT, the slave at HOST:PORT+1 (with port 0,
    /// each picks a free port; both are printed on stderr).
    #[command(flatten)]
    pub live: h4_telemetry::live::LiveArgs,
    /// Accept a safety layer turned off (`passivity.enabled=false`,
    /// `slave.controller.spindle_stall_safe_stop=false`, `slave.safety_monitor=false`) and
    /// controller gains beyond the arm's stable range: for negative controls only. The
    /// summary says so (`unsafe_test_override`). No rating of the arm can be raised.
    #[arg(long)]
    pub unsafe_test_override: bool,
    /// ROS 2: both processes publish their CRTK topics (`--ros2-ns` names the slave's
    /// namespace; the master keeps `/h4_master`; docs/ros2.md).
    #[command(flatten)]
    pub ros2: h4_transport::ros2::node::Ros2Args,
}

/// What `loopback` prints.
#[derive(Clone, Debug, Serialize)]
pub struct LoopbackSummary {
    /// The session's name.
    pub name: String,
    /// The verdict on the physics: every force finite, the slave's true contact force within
    /// the slave controller's force limit, the rendered force within coupling.force_limit_n,
    /// both passivity observers above −detector.energy_tolerance_j, and a round trip
    /// completed.
    pub stable: bool,
    /// Why not stable (empty when stable).
    pub unstable_reasons: Vec<String>,
    /// Both loops ran in real time: each missed at most 1 % of its deadlines and the master
    /// ran at least 90 % of the requested cycles. False ⇒ the figures describe a starved run
    /// (exit code 1 as for an unstable one).
    pub realtime_ok: bool,
    /// Fault events that are not instability: the slave's watchdog tripped (safe state),
    /// commands the controller rejected, messages the gates rejected, feedback losses.
    pub faults: Vec<String>,
    /// Master loop cycles.
    pub cycles: u64,
    /// Deadline misses, both loops.
    pub deadline_misses: u64,
    /// Worse of the two loops' p99 wake-up lateness, µs.
    pub lateness_p99_us: f64,
    /// Round trip master → slave → master, p50, µs (includes both loops' phase).
    pub round_trip_p50_us: f64,
    /// Round trip p99, µs.
    pub round_trip_p99_us: f64,
    /// Largest true contact force at the slave, N.
    pub max_force_n: f64,
    /// Force limit the verdict uses (the slave controller's, `slave.controller.force_limit_n`
    /// of the session), N.
    pub force_limit_n: f64,
    /// Largest force rendered to the operator, N.
    pub max_master_force_n: f64,
    /// Lowest value of the two passivity observers, J.
    pub energy_min_j: f64,
    /// Force transparency in contact, %: see `master.force_transparency_err_pct`.
    pub force_transparency_err_pct: f64,
    /// Time in contact seen by the master, s.
    pub contact_time_s: f64,
    /// Both processes ran to the end and reported (false: the slave process died; its
    /// summary fields are then zero and `faults` says how it ended).
    pub complete: bool,
    /// SIGINT, SIGTERM or SIGHUP stopped the run before its end (exit 130): the figures
    /// cover the cycles run, and the cycles not run are not a real-time failure.
    pub interrupted: bool,
    /// With `--record`: what was merged and what was lost.
    pub recording: Option<RecordingReport>,
    /// In a cutting session: the cut and the part as the slave judged them against the
    /// session's `cut_target` (`removed_volume_mm3`, `surface_error_p99_mm`,
    /// `gouge_max_mm`, `cutting_force_dev_p99_pct`, `removal_rate_mm3_per_s`, …: the
    /// simulation's fields, at the top level as there; also in `slave`).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub cutting: Option<h4_slave_sim::plant::cutting::judge::CutSummary>,
    /// The master process's own summary.
    pub master: MasterRunSummary,
    /// The slave process's own summary.
    pub slave: SimRunSummary,
}

impl LoopbackArgs {
    /// Runs the two processes; exit code 0 if stable and in real time, 1 if not (or if the
    /// slave process died), 130 if a signal stopped it early.
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        h4_telemetry::rt::realtime_preflight(self.realtime, self.fifo_priority, false, LABEL)?;
        let config =
            h4_shared::paths::default_config(self.config.as_deref(), super::SESSION, "--config")?;
        let cfg = session::load_with(&config, &self.set, self.unsafe_test_override)
            .map_err(|e| format!("{}: {e}", config.display()))?;
        super::plausible::check_session(&cfg, LABEL)?;
        let parts = self.record.as_deref().map(RecordingParts::next_to);
        self.check_outputs(parts.as_ref())?;
        let slave_bin = find_slave_binary(self.slave_bin.as_deref())?;
        let (slave_transport, transport) = self.links()?;
        let slave = SlaveChild::spawn(&self, &cfg, &slave_bin, &slave_transport, parts.as_ref())?;
        let slave_pid = slave.pid;
        let duration_s = self.duration_s.unwrap_or(cfg.duration_s);
        let master_args = super::run::RunArgs {
            device: super::run::DeviceKind::Sim,
            config: Some(config),
            set: self.set.clone(),
            transport,
            impair: self.impair.clone(),
            run: LoopArgs {
                duration_s: Some(duration_s),
                summary: None,
                record: parts.as_ref().map(|p| p.master.clone()),
                realtime: self.realtime,
                fifo_priority: self.fifo_priority,
                lock_memory: false,
            },
            wait_for_slave_s: 20.0,
            live: self.live.clone(),
            ros2: h4_transport::ros2::node::Ros2Args {
                ros2_ns: None,
                ..self.ros2.clone()
            },
            crtk: super::crtk::CrtkDeviceArgs::default(),
            prechecked: true,
            unsafe_test_override: self.unsafe_test_override,
        };
        // The slave is told to stop the moment the master's loop ends, before its watchdog
        // sees the master's silence.
        let master = master_args.run_summary_then(LABEL, || {
            // SAFETY: plain syscall; the slave is our child, reaped only in `SlaveChild::stop`.
            unsafe {
                libc::kill(slave_pid, libc::SIGTERM);
            }
        });
        let ended = slave.stop();
        let master = master.map_err(|e| with_log(format!("master: {e}"), &ended.log))?;
        if !ended.log.trim().is_empty() {
            eprintln!("h4-slave said:\n{}", ended.log.trim_end());
        }
        let (slave, slave_fault) = match &ended.outcome {
            Ok(()) => (
                serde_json::from_str::<SimRunSummary>(&ended.stdout)
                    .map_err(|e| format!("slave summary: {e}"))?,
                None,
            ),
            Err(e) => (SimRunSummary::default(), Some(e.clone())),
        };
        let recording = match (&self.record, &parts) {
            (Some(out), Some(p)) => Some(p.merge_into(out, ended.died_unix_ns)?),
            _ => None,
        };
        let interrupted = h4_telemetry::process::signal_received();
        let mut summary = combine(&cfg, duration_s, interrupted, master, slave);
        if let Some(e) = &slave_fault {
            summary.complete = false;
            summary.faults.push(format!("slave process: {e}"));
        }
        if let Some(r) = &recording {
            for lost in &r.lost {
                eprintln!("h4-master: recording: {lost}");
            }
        }
        summary.recording = recording;
        h4_telemetry::process::emit_summary(&summary, self.summary.as_deref())?;
        verdict_line(LABEL, &summary.in_words(duration_s));
        Ok(if interrupted {
            ExitStatus::Interrupted.into()
        } else if summary.stable && summary.realtime_ok && summary.complete {
            ExitCode::SUCCESS
        } else {
            ExitStatus::VerdictFailed.into()
        })
    }

    /// The slave's and the master's link options. iceoryx2: a prefix of our own, so runs side
    /// by side never share services. Zenoh: the slave listens on a free loopback port.
    fn links(&self) -> Result<(TransportArgs, TransportArgs), String> {
        let pid = std::process::id();
        let iceoryx2 = TransportArgs::iceoryx2(self.arm_id, format!("h4-loopback-{pid}"));
        match self.transport {
            TransportKind::Iceoryx2 => Ok((iceoryx2.clone(), iceoryx2)),
            TransportKind::Zenoh => {
                let port = std::net::TcpListener::bind("127.0.0.1:0")
                    .and_then(|l| l.local_addr())
                    .map_err(|e| format!("a free TCP port for Zenoh: {e}"))?
                    .port();
                let endpoint = format!("tcp/127.0.0.1:{port}");
                let slave = TransportArgs {
                    transport: TransportKind::Zenoh,
                    zenoh_listen: vec![endpoint.clone()],
                    ..iceoryx2.clone()
                };
                let master = TransportArgs {
                    transport: TransportKind::Zenoh,
                    zenoh_connect: vec![endpoint],
                    ..iceoryx2
                };
                Ok((slave, master))
            }
        }
    }

    /// `--summary`, `--record` and the recording's parts must be writable before the run.
    fn check_outputs(&self, parts: Option<&RecordingParts>) -> Result<(), String> {
        use h4_telemetry::process::check_writable;
        if let Some(p) = &self.summary {
            check_writable("--summary", p)?;
        }
        if let Some(p) = &self.record {
            check_writable("--record", p)?;
        }
        if let Some(p) = parts {
            check_writable("--record (its master part)", &p.master)?;
            check_writable("--record (its slave part)", &p.slave)?;
        }
        Ok(())
    }
}

/// The slave child: stdout (its summary) and stderr (its log) read by two threads, a watcher
/// that stops the master when the slave exits. No temporary files: the slave's world,
/// passivity and contact files are handed over as memory files.
struct SlaveChild {
    pid: i32,
    child: Arc<Mutex<Child>>,
    done: Arc<AtomicBool>,
    died_unix_ns: Arc<std::sync::atomic::AtomicU64>,
    watcher: std::thread::JoinHandle<()>,
    stdout: std::thread::JoinHandle<String>,
    stderr: std::thread::JoinHandle<String>,
}

/// What the slave left when it ended.
struct SlaveEnded {
    /// Its orderly stop, or why not (killed by a signal, failed).
    outcome: Result<(), String>,
    /// Its standard output: the summary JSON.
    stdout: String,
    /// Its standard error.
    log: String,
    /// Unix time the master saw it exit by itself (0: it did not, it was stopped), ns.
    died_unix_ns: u64,
}

/// The session's `slave.playout` as `h4-slave run` options (none when it is off).
fn playout_args(p: &h4_transport::playout::PlayoutConfig) -> Vec<String> {
    if !p.enabled {
        return Vec::new();
    }
    vec![
        "--playout".to_string(),
        "--playout-max-ms".to_string(),
        p.max_ms.to_string(),
        "--playout-quantile".to_string(),
        p.quantile.to_string(),
    ]
}

impl SlaveChild {
    fn spawn(
        args: &LoopbackArgs,
        cfg: &SessionConfig,
        slave_bin: &Path,
        transport: &TransportArgs,
        parts: Option<&RecordingParts>,
    ) -> Result<Self, String> {
        let world = memory_file(
            "slave-world.toml",
            &toml::to_string(&slave_world(cfg)).map_err(|e| e.to_string())?,
        )?;
        let passivity = memory_file(
            "passivity.toml",
            &toml::to_string(&cfg.passivity).map_err(|e| e.to_string())?,
        )?;
        let contact = memory_file(
            "contact.toml",
            &toml::to_string(&cfg.slave.contact).map_err(|e| e.to_string())?,
        )?;
        let mut cmd = std::process::Command::new(slave_bin);
        cmd.arg("run")
            .arg("--config")
            .arg(fd_path(&world))
            .args(transport.to_args())
            .args(args.impair.to_args())
            .arg("--passivity-config")
            .arg(fd_path(&passivity))
            .arg("--contact-config")
            .arg(fd_path(&contact))
            .arg("--watchdog-ms")
            .arg(args.watchdog_ms.to_string())
            .args(playout_args(&cfg.slave.playout))
            .args(args.ros2.to_args())
            .arg("--parent-pid")
            .arg(std::process::id().to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if let Some(p) = parts {
            cmd.arg("--record").arg(&p.slave);
        }
        if args.unsafe_test_override {
            cmd.arg("--unsafe-test-override");
        }
        if !cfg.slave.safety_monitor {
            cmd.arg("--no-safety-monitor");
        }
        if let Some(d) = &args.out {
            cmd.arg("--out").arg(d);
        }
        cmd.arg("--realtime").arg(match args.realtime {
            RealtimeMode::Try => "try",
            RealtimeMode::Enforce => "enforce",
            RealtimeMode::Off => "off",
        });
        if let Some(p) = args.fifo_priority {
            cmd.arg("--fifo-priority").arg(p.to_string());
        }
        // The master shows the run's progress; the slave's log is printed only at the end.
        cmd.env("H4_PROGRESS", "off");
        if let Some(addr) = args.live.slave_address() {
            if !addr.ends_with(":0") {
                eprintln!("h4-master loopback: the slave's live view at ws://{addr}");
            }
            cmd.arg("--foxglove-ws").arg(addr);
        }
        let mut child = cmd
            .spawn()
            .map_err(|e| format!("cannot start {}: {e}", slave_bin.display()))?;
        drop((world, passivity, contact));
        let pid = i32::try_from(child.id()).map_err(|e| e.to_string())?;
        let stdout = read_all(child.stdout.take());
        let stderr = read_all(child.stderr.take());
        // If the slave dies, the master stops too (instead of waiting for its feedback).
        let child = Arc::new(Mutex::new(child));
        let done = Arc::new(AtomicBool::new(false));
        let died_unix_ns = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let watcher = {
            let (child, done, died) = (
                Arc::clone(&child),
                Arc::clone(&done),
                Arc::clone(&died_unix_ns),
            );
            std::thread::spawn(move || {
                while !done.load(Ordering::SeqCst) {
                    let exited = child
                        .lock()
                        .map(|mut c| matches!(c.try_wait(), Ok(Some(_))))
                        .unwrap_or(true);
                    if exited {
                        died.store(unix_now_ns(), Ordering::SeqCst);
                        h4_telemetry::process::request_stop();
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            })
        };
        Ok(SlaveChild {
            pid,
            child,
            done,
            died_unix_ns,
            watcher,
            stdout,
            stderr,
        })
    }

    /// Stops the slave (SIGTERM, then SIGKILL after 10 s) and collects what it left.
    fn stop(self) -> SlaveEnded {
        self.done.store(true, Ordering::SeqCst);
        let _ = self.watcher.join();
        let outcome = match self.child.lock() {
            Ok(mut child) => stop_child(&mut child),
            Err(_) => Err("slave process handle poisoned".to_string()),
        };
        SlaveEnded {
            outcome,
            stdout: self.stdout.join().unwrap_or_default(),
            log: self.stderr.join().unwrap_or_default(),
            died_unix_ns: self.died_unix_ns.load(Ordering::SeqCst),
        }
    }
}

fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// A thread reading `pipe` to its end.
fn read_all(pipe: Option<impl std::io::Read + Send + 'static>) -> std::thread::JoinHandle<String> {
    std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut p) = pipe {
            let _ = p.read_to_string(&mut text);
        }
        text
    })
}

/// An anonymous memory file holding `text`, inherited by child processes (no close-on-exec),
/// which open it as `/proc/self/fd/N` ([`fd_path`]): nothing on disk to leave behind.
fn memory_file(name: &str, text: &str) -> Result<std::fs::File, String> {
    use std::io::Write;
    use std::os::fd::FromRawFd;
    let cname = std::ffi::CString::new(name).map_err(|e| e.to_string())?;
    // SAFETY: a valid NUL-terminated name; flags 0 (inheritable). The fd is owned by the File.
    let fd = unsafe { libc::memfd_create(cname.as_ptr(), 0) };
    if fd < 0 {
        return Err(format!(
            "memory file {name}: {}",
            std::io::Error::last_os_error()
        ));
    }
    // SAFETY: `fd` was just created and is owned by nothing else.
    let mut file = unsafe { std::fs::File::from_raw_fd(fd) };
    file.write_all(text.as_bytes())
        .map_err(|e| format!("memory file {name}: {e}"))?;
    Ok(file)
}

/// The path under which a child process opens an inherited file.
fn fd_path(file: &std::fs::File) -> String {
    use std::os::fd::AsRawFd;
    format!("/proc/self/fd/{}", file.as_raw_fd())
}

fn with_log(msg: String, log: &str) -> String {
    if log.trim().is_empty() {
        msg
    } else {
        format!("{msg}\nh4-slave said:\n{}", log.trim_end())
    }
}

/// The two processes' recordings while they run, next to the final file.
struct RecordingParts {
    master: PathBuf,
    slave: PathBuf,
}

impl RecordingParts {
    /// `out.mcap` → `out.master.part.mcap`, `out.slave.part.mcap`.
    fn next_to(out: &Path) -> Self {
        let stem = out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "recording".into());
        RecordingParts {
            master: out.with_file_name(format!("{stem}.master.part.mcap")),
            slave: out.with_file_name(format!("{stem}.slave.part.mcap")),
        }
    }

    /// Merges both parts into `out` and removes them; on failure they stay, and the error
    /// names them. A part that did not end properly (its process was killed) is merged up to
    /// its last checkpoint and the report says what was lost.
    fn merge_into(&self, out: &Path, slave_died_unix_ns: u64) -> Result<RecordingReport, String> {
        let stats =
            h4_telemetry::recording::merge(&[&self.master, &self.slave], out).map_err(|e| {
                format!(
                    "{e} (the parts {} and {} are kept)",
                    self.master.display(),
                    self.slave.display()
                )
            })?;
        let _ = std::fs::remove_file(&self.master);
        let _ = std::fs::remove_file(&self.slave);
        let mut report = RecordingReport {
            master_messages: stats.messages_by_input.first().copied().unwrap_or(0),
            slave_messages: stats.messages_by_input.get(1).copied().unwrap_or(0),
            master_complete: stats.complete.first().copied().unwrap_or(false),
            slave_complete: stats.complete.get(1).copied().unwrap_or(false),
            lost: Vec::new(),
        };
        for (i, who) in ["master", "slave"].into_iter().enumerate() {
            if stats.complete.get(i).copied().unwrap_or(false) {
                continue;
            }
            let last = stats.last_log_time_ns.get(i).copied().unwrap_or(0);
            let torn = if stats.unreadable_tail.get(i).copied().unwrap_or(false) {
                " (its last write was torn and skipped)"
            } else {
                ""
            };
            let gap = if who == "slave" && slave_died_unix_ns > last && last > 0 {
                format!(
                    "; the slave was seen dead {:.3} s after its last recorded cycle: at most that much is lost",
                    (slave_died_unix_ns - last) as f64 / 1e9
                )
            } else {
                String::new()
            };
            report.lost.push(format!(
                "the {who} process did not finish its part: {} messages recovered up to its last checkpoint{torn}{gap}",
                stats.messages_by_input.get(i).copied().unwrap_or(0)
            ));
        }
        Ok(report)
    }
}

/// What `loopback --record` merged.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RecordingReport {
    /// Messages from the master's part.
    pub master_messages: u64,
    /// Messages from the slave's part.
    pub slave_messages: u64,
    /// The master's part ended properly.
    pub master_complete: bool,
    /// The slave's part ended properly (false: the slave was killed; its part is merged up
    /// to its last checkpoint, at most 0.5 s before the end).
    pub slave_complete: bool,
    /// What was lost, one sentence per incomplete part (empty: nothing).
    pub lost: Vec<String>,
}

/// SIGTERM, then up to 10 s for an orderly stop; SIGKILL after that (an error).
fn stop_child(child: &mut Child) -> Result<(), String> {
    let pid = i32::try_from(child.id()).map_err(|e| e.to_string())?;
    // SAFETY: plain syscall; `pid` is our own child, not yet reaped.
    unsafe {
        libc::kill(pid, libc::SIGTERM);
    }
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(10) {
        match child.try_wait() {
            Ok(Some(status)) if status.success() => return Ok(()),
            Ok(Some(status)) => return Err(format!("the slave process failed: {status}")),
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return Err(e.to_string()),
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    Err("the slave process did not stop within 10 s of SIGTERM; killed".into())
}

/// Writes the files `h4-slave run --config WORLD --passivity-config PASSIVITY
/// [--contact-config CONTACT]` needs to simulate the slave side of a session.
pub fn write_slave_config(
    cfg: &SessionConfig,
    world: &Path,
    passivity: &Path,
    contact: Option<&Path>,
) -> Result<(), String> {
    let write = |path: &Path, text: Result<String, toml::ser::Error>| {
        let text = text.map_err(|e| e.to_string())?;
        std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
    };
    write(world, toml::to_string(&slave_world(cfg)))?;
    write(passivity, toml::to_string(&cfg.passivity))?;
    match contact {
        Some(c) => write(c, toml::to_string(&cfg.slave.contact)),
        None => Ok(()),
    }
}

/// Write the slave's world, passivity and contact hand-over files of a session, for
/// `h4-slave run`.
#[derive(Clone, Debug, clap::Args)]
pub struct SlaveConfigArgs {
    /// The session file.
    pub session: PathBuf,
    /// Override a field of the session file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Where to write the world (for `h4-slave run --config`).
    #[arg(long, default_value = "slave-world.toml")]
    pub world: PathBuf,
    /// Where to write the passivity settings (for `h4-slave run --passivity-config`).
    #[arg(long, default_value = "slave-passivity.toml")]
    pub passivity: PathBuf,
    /// Where to write the contact hand-over's settings (for `h4-slave run
    /// --contact-config`; none without it).
    #[arg(long)]
    pub contact: Option<PathBuf>,
    /// Accept a session that turns a safety layer off (for negative controls: the slave
    /// must then run with `--unsafe-test-override` too).
    #[arg(long)]
    pub unsafe_test_override: bool,
}

impl SlaveConfigArgs {
    /// Writes both files.
    pub fn run(self) -> Result<ExitCode, String> {
        let cfg = session::load_with(&self.session, &self.set, self.unsafe_test_override)
            .map_err(|e| format!("{}: {e}", self.session.display()))?;
        write_slave_config(&cfg, &self.world, &self.passivity, self.contact.as_deref())?;
        Ok(ExitCode::SUCCESS)
    }
}

/// The slave's world (arm, plant, sensor, controller, surface, start) from a session file,
/// in the format `h4-slave run --config` reads.
pub fn slave_world(cfg: &SessionConfig) -> ExperimentConfig {
    let env = &cfg.environment;
    ExperimentConfig {
        name: format!("{}: slave world", cfg.name),
        seed: cfg.seed,
        duration_s: cfg.duration_s.max(0.01),
        arm: cfg.slave.arm,
        surface: env.surface_config(),
        // Not used by `h4-slave run` (the master commands set-points), but must validate.
        force: ForceConfig {
            setpoint_n: 5.0,
            steps: vec![],
        },
        track: TrackConfig {
            speed_mm_per_s: 0.0,
            direction: [1.0, 0.0, 0.0],
            start_delay_s: 0.0,
        },
        approach: ApproachConfig {
            gap_mm: env.gap_mm,
            ..ApproachConfig::default()
        },
        sensor: cfg.slave.sensor,
        plant: cfg.slave.plant,
        controller: cfg.slave.controller,
        summary: SummaryConfig::default(),
        targets: Default::default(),
        cutting: cfg.cutting,
        fixtures: cfg.fixtures.clone(),
        cut_target: cfg.cut_target.clone(),
    }
}

const LABEL: &str = "h4-master loopback";

impl LoopbackSummary {
    /// The verdict in one line of words (`stable, 14 000 cycles, round trip p99 1.06 ms, max
    /// force 13.9 N, …` / `UNSTABLE: …` / `interrupted after …`), for a run planned for
    /// `duration_s`.
    pub fn in_words(&self, duration_s: f64) -> String {
        let figures = format!(
            "round trip p99 {:.2} ms, max force {:.1} N (true, at the slave; limit {} N), \
             rendered {:.1} N, observer min {:.2} mJ, loop lateness p99 {:.0} µs, {} deadline misses",
            self.round_trip_p99_us / 1e3,
            self.max_force_n,
            self.force_limit_n,
            self.max_master_force_n,
            self.energy_min_j * 1e3,
            self.lateness_p99_us,
            self.deadline_misses
        );
        let cycles = grouped(self.cycles);
        if self.interrupted {
            let so_far = if self.stable {
                "stable so far".to_string()
            } else {
                format!("UNSTABLE so far: {}", self.unstable_reasons.join("; "))
            };
            return format!(
                "interrupted after {cycles} of {} cycles: {so_far}; {figures}",
                grouped((duration_s * 1000.0).round() as u64)
            );
        }
        let mut head = if self.stable {
            "stable".to_string()
        } else {
            format!("UNSTABLE: {}", self.unstable_reasons.join("; "))
        };
        if !self.complete {
            head = format!("INCOMPLETE (the slave process ended early), {head}");
        }
        if !self.realtime_ok {
            let rt: Vec<&str> = self
                .faults
                .iter()
                .filter(|f| f.starts_with("real time"))
                .map(String::as_str)
                .collect();
            head = format!("{head}, but real time missed ({})", rt.join("; "));
        }
        format!("{head}, {cycles} cycles, {figures}")
    }
}

/// A loop that missed more than this share of its deadlines did not run in real time.
const MAX_MISSED_SHARE: f64 = 0.01;
/// The master must have run at least this share of the requested cycles.
const MIN_CYCLE_SHARE: f64 = 0.9;

fn combine(
    cfg: &SessionConfig,
    duration_s: f64,
    interrupted: bool,
    m: MasterRunSummary,
    s: SimRunSummary,
) -> LoopbackSummary {
    // The slave's own force limit (its controller's): the arm must never exceed it.
    let limit = s.force_limit_n;
    let mut reasons = Vec::new();
    if !s.max_force_n.is_finite() || !m.max_rendered_force_n.is_finite() {
        reasons.push("diverged: a force is not finite".to_string());
    }
    if s.max_force_n > limit {
        reasons.push(format!(
            "force: contact force {:.1} N > {limit} N",
            s.max_force_n
        ));
    }
    // NaN-safe: a NaN observer (`f64::min` would drop it) is a divergence.
    let energy_min_j = if m.energy_min_j.is_nan() || s.energy_min_j.is_nan() {
        f64::NAN
    } else {
        m.energy_min_j.min(s.energy_min_j)
    };
    if energy_min_j.is_nan() {
        reasons.push("diverged: a passivity observer is not finite".to_string());
    } else if energy_min_j < -cfg.detector.energy_tolerance_j {
        reasons.push(format!(
            "energy: a passivity observer reached {energy_min_j:.4} J < -{} J (the link generated energy)",
            cfg.detector.energy_tolerance_j
        ));
    }
    if m.max_rendered_force_n > cfg.coupling.force_limit_n + 1e-9 {
        reasons.push(format!(
            "master force: {:.1} N > {} N",
            m.max_rendered_force_n, cfg.coupling.force_limit_n
        ));
    }
    let mut faults = Vec::new();
    if s.safe_stops > 0 {
        faults.push(format!(
            "watchdog: the slave entered its safe state {} time(s)",
            s.safe_stops
        ));
    }
    if s.commands_rejected_by_controller > 0 {
        faults.push(format!(
            "controller: {} command(s) rejected",
            s.commands_rejected_by_controller
        ));
    }
    if s.gate.rejected() > 0 || m.feedback_invalid > 0 {
        faults.push(format!(
            "messages: {} command(s) and {} feedback message(s) rejected",
            s.gate.rejected(),
            m.feedback_invalid
        ));
    }
    let mut realtime_ok = true;
    for (who, cycles, misses) in [
        ("master", m.run.cycles, m.run.deadline_misses),
        ("slave", s.run.cycles, s.run.deadline_misses),
    ] {
        let share = misses as f64 / (cycles + misses).max(1) as f64;
        if share > MAX_MISSED_SHARE {
            realtime_ok = false;
            faults.push(format!(
                "real time: the {who} loop missed {misses} deadlines ({:.1} % > {:.0} %)",
                100.0 * share,
                100.0 * MAX_MISSED_SHARE
            ));
        }
    }
    let expected = (duration_s * 1000.0).round() as u64;
    if !interrupted && (m.run.cycles as f64) < MIN_CYCLE_SHARE * expected as f64 {
        realtime_ok = false;
        faults.push(format!(
            "real time: the master ran {} of {expected} cycles (< {:.0} %)",
            m.run.cycles,
            100.0 * MIN_CYCLE_SHARE
        ));
    }
    if m.feedback_losses > 0 {
        faults.push(format!(
            "feedback: lost {} time(s), restored {} time(s)",
            m.feedback_losses, m.feedback_restored
        ));
    }
    if m.round_trip_samples == 0 {
        reasons.push("link: no round trip completed".to_string());
    }
    LoopbackSummary {
        name: cfg.name.clone(),
        stable: reasons.is_empty(),
        unstable_reasons: reasons,
        realtime_ok,
        faults,
        cycles: m.run.cycles,
        deadline_misses: m.run.deadline_misses + s.run.deadline_misses,
        lateness_p99_us: m.run.lateness_p99_us.max(s.run.lateness_p99_us),
        round_trip_p50_us: m.round_trip_p50_us,
        round_trip_p99_us: m.round_trip_p99_us,
        max_force_n: s.max_force_n,
        force_limit_n: limit,
        max_master_force_n: m.max_rendered_force_n,
        energy_min_j,
        force_transparency_err_pct: m.force_transparency_err_pct,
        contact_time_s: m.contact_cycles as f64 * 1e-3,
        complete: true,
        interrupted,
        recording: None,
        cutting: s.cutting.clone(),
        master: m,
        slave: s,
    }
}

/// The h4-slave binary: `explicit`, else next to this executable; under `cargo run`
/// (`CARGO` set) a missing one is built first with the same profile and target directory.
pub fn find_slave_binary(explicit: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(p) = explicit {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(format!("--slave-bin {}: no such file", p.display()))
        };
    }
    let exe = std::env::current_exe().map_err(|e| format!("current executable: {e}"))?;
    let name = format!("h4-slave{}", std::env::consts::EXE_SUFFIX);
    let sibling = exe.with_file_name(&name);
    if sibling.is_file() {
        return Ok(sibling);
    }
    let hint = format!(
        "{} not found next to {}: build both binaries with `cargo build --release -p h4-slave-cli -p h4-master-cli`, or pass --slave-bin",
        name,
        exe.display()
    );
    let (Some(cargo), Some(profile_dir)) = (std::env::var_os("CARGO"), exe.parent()) else {
        return Err(hint);
    };
    let (Some(profile), Some(target_dir)) = (
        profile_dir.file_name().and_then(|s| s.to_str()),
        profile_dir.parent(),
    ) else {
        return Err(hint);
    };
    let profile = if profile == "debug" { "dev" } else { profile };
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../Cargo.toml");
    eprintln!(
        "h4-master: building h4-slave ({profile} profile) next to {}",
        exe.display()
    );
    let mut build = std::process::Command::new(cargo);
    h4_telemetry::process::without_cargo_run_env(&mut build);
    let status = build
        .args([
            "build",
            "-p",
            "h4-slave-cli",
            "--bin",
            "h4-slave",
            "--profile",
            profile,
        ])
        .arg("--manifest-path")
        .arg(&manifest)
        .arg("--target-dir")
        .arg(target_dir)
        .status()
        .map_err(|e| format!("{hint} (cargo: {e})"))?;
    if status.success() && sibling.is_file() {
        Ok(sibling)
    } else {
        Err(hint)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_telemetry::rt::LoopReport;

    fn summaries(misses: u64, cycles: u64) -> (MasterRunSummary, SimRunSummary) {
        let m = MasterRunSummary {
            run: LoopReport {
                cycles,
                deadline_misses: misses,
                ..LoopReport::default()
            },
            round_trip_samples: 100,
            ..MasterRunSummary::default()
        };
        let s = SimRunSummary {
            slave: h4_slave::server::SlaveRunSummary {
                run: LoopReport {
                    cycles,
                    ..LoopReport::default()
                },
                force_limit_n: 80.0,
                max_force_n: 10.0,
                ..Default::default()
            },
            cutting: None,
            fault_injection: None,
        };
        (m, s)
    }

    /// A NaN anywhere in the evidence fails the verdict; the same summaries without it pass.
    #[test]
    fn a_nan_force_or_observer_fails_the_verdict() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sessions/wall-push.toml");
        let cfg = session::load(&path, &[]).expect("wall-push session");
        let (m, s) = summaries(0, 2000);
        assert!(combine(&cfg, 2.0, false, m, s).stable, "control");
        type Spoil = fn(&mut MasterRunSummary, &mut SimRunSummary);
        let spoils: [(&str, Spoil); 4] = [
            ("true force", |_, s| s.slave.max_force_n = f64::NAN),
            ("rendered force", |m, _| m.max_rendered_force_n = f64::NAN),
            ("master observer", |m, _| m.energy_min_j = f64::NAN),
            ("slave observer", |_, s| s.slave.energy_min_j = f64::NAN),
        ];
        for (what, spoil) in spoils {
            let (mut m, mut s) = summaries(0, 2000);
            spoil(&mut m, &mut s);
            let v = combine(&cfg, 2.0, false, m, s);
            assert!(!v.stable, "{what} NaN: {v:?}");
        }
    }

    #[test]
    fn verdict_flags_starved_loops_and_the_slaves_force_limit() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sessions/wall-push.toml");
        let cfg = session::load(&path, &[]).expect("wall-push session");
        let (m, s) = summaries(5, 2000);
        let ok = combine(&cfg, 2.0, false, m, s);
        assert!(ok.stable && ok.realtime_ok, "{ok:?}");
        let (m, s) = summaries(100, 1900);
        let missed = combine(&cfg, 2.0, false, m, s);
        assert!(missed.stable && !missed.realtime_ok, "{missed:?}");
        assert!(missed.faults.iter().any(|f| f.contains("missed")));
        let (m, s) = summaries(0, 1500);
        let short = combine(&cfg, 2.0, false, m, s);
        assert!(!short.realtime_ok, "{short:?}");
        assert!(
            short.in_words(2.0).contains("but real time missed"),
            "{short:?}"
        );
        // Cut short by a signal: not a real-time failure, and it says so.
        let (m, s) = summaries(0, 1500);
        let cut = combine(&cfg, 2.0, true, m, s);
        assert!(cut.realtime_ok && cut.interrupted, "{cut:?}");
        let words = cut.in_words(2.0);
        assert!(
            words.starts_with("interrupted after 1 500 of 2 000 cycles: stable so far"),
            "{words}"
        );
        let (m, mut s) = summaries(0, 2000);
        s.max_force_n = 81.0;
        let over = combine(&cfg, 2.0, false, m, s);
        assert!(!over.stable && over.force_limit_n == 80.0, "{over:?}");
    }
}
