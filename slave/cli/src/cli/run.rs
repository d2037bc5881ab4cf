//! `h4-slave run [--arm sim|replay|crtk] [--config world.toml] [--transport iceoryx2|zenoh] [--arm-id N] ...`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_shared::clock::MonotonicClock;
use h4_shared::passivity::PassivityParams;
use h4_slave::server::{self, NoDiagnostics, RunOptions};
use h4_slave::teleop::{ContactHandover, SlaveTeleop};
use h4_slave_sim::experiment::ExperimentConfig;
use h4_slave_sim::replay::ReplayArm;
use h4_slave_sim::server::{RunOutputs, SimRunSummary};
use h4_telemetry::rt::LoopArgs;
use h4_telemetry::sink::Outputs;
use h4_transport::impaired::{self, Direction, ImpairArgs};
use h4_transport::open::TransportArgs;
use h4_transport::playout::{Playout, PlayoutConfig};
use h4_transport::ros2::node::{Ros2Args, Ros2Publishing};

/// The arm driver `h4-slave run` runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ArmKind {
    /// The simulated arm of the world file (`--config`).
    Sim,
    /// A recorded arm played back from an MCAP file (`--replay FILE`, a `h4-slave run
    /// --record` recording): the controller of the world file runs on what that arm read;
    /// the commands move nothing (docs/drivers.md).
    Replay,
    /// An arm reached over ROS 2 (rmw_zenoh): `measured_cp`/`measured_cf` in, `servo_cp` out,
    /// or FZI cartesian_controllers' topics (`--arm-profile`, `--arm-ns`; docs/ros2.md). The
    /// world file gives the arm's geometry and the controller.
    Crtk,
}

/// Run the slave process: the 1 kHz force loop on an arm driver, commanded by a master
/// over iceoryx2 or Zenoh.
#[derive(Clone, Debug, clap::Args)]
pub struct RunArgs {
    /// The arm driver.
    #[arg(long, value_enum, default_value_t = ArmKind::Sim)]
    pub arm: ArmKind,
    /// With `--arm replay`: the recording to play back (MCAP, `/slave/cycle` of `h4-slave run
    /// --record`).
    #[arg(long, value_name = "FILE", required_if_eq("arm", "replay"))]
    pub replay: Option<PathBuf>,
    /// The simulated world (arm, surface, sensor, plant, controller): an experiment file,
    /// e.g. config/experiments/fig6b.toml (its force and track sections are not used: the
    /// master commands the motion).
    /// Default: config/slave/sim-resin.toml of the repository (found from the binary, not
    /// the working directory).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override any field of the config file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Transport.
    #[command(flatten)]
    pub transport: TransportArgs,
    /// Link impairment of the feedback this process sends (`--impair`).
    #[command(flatten)]
    pub impair: ImpairArgs,
    /// Duration, summary, recording, real-time settings.
    #[command(flatten)]
    pub run: LoopArgs,
    /// The live view.
    #[command(flatten)]
    pub live: h4_telemetry::live::LiveArgs,
    /// Accept a safety layer turned off (the world's `controller.spindle_stall_safe_stop =
    /// false`, `enabled = false` in the passivity file, `--no-safety-monitor`) and controller
    /// gains beyond the arm's stable range: for negative controls only. The summary says so
    /// (`unsafe_test_override`). No rating of the arm can be raised.
    #[arg(long)]
    pub unsafe_test_override: bool,
    /// Run without the safety monitor (only with `--unsafe-test-override`).
    #[arg(long)]
    pub no_safety_monitor: bool,
    /// Make the simulated arm fail on purpose, `KIND@START_S+DURATION_S` on the arm's clock
    /// (from the loop's first cycle): `sensor-freeze` (the force reading stops updating),
    /// `sensor-saturate` (the normal force reads the sensor's full range, the arm file's
    /// `ratings.sensor_range_n`), `driver-silent` (stale readings, commands not taken). The
    /// summary's `fault_injection` says how the slave answered (docs/safety.md). `--arm sim`
    /// only.
    #[arg(long, value_name = "KIND@START+DURATION")]
    pub inject_fault: Option<h4_slave_sim::fault::FaultPlan>,
    /// ROS 2 (`--ros2`, docs/ros2.md).
    #[command(flatten)]
    pub ros2: Ros2Args,
    /// The ROS 2 arm (`--arm crtk`).
    #[command(flatten)]
    pub crtk: super::crtk::CrtkArmArgs,
    /// No valid command for this long puts the arm in its safe state, ms.
    #[arg(long, default_value_t = 20.0)]
    pub watchdog_ms: f64,
    /// Hold commands in a playout (jitter) buffer: each is followed at its send time + the
    /// link's fastest delay + the 95th percentile of the recent lateness (at most
    /// --playout-max-ms), in order and evenly spaced: for a jittery network link
    /// (docs/remote.md). Default off.
    #[arg(long)]
    pub playout: bool,
    /// The longest the playout buffer holds a command, ms (0 to 1000).
    #[arg(long, default_value_t = 200.0, value_name = "MS")]
    pub playout_max_ms: f64,
    /// The share of recent commands the playout delay waits for (0.5 to 1).
    #[arg(long, default_value_t = 0.95, value_name = "SHARE")]
    pub playout_quantile: f64,
    /// The slave's passivity settings: a TOML file with the keys of a session file's
    /// `[passivity]` section (docs/sessions.md); default: the defaults there.
    #[arg(long, value_name = "FILE")]
    pub passivity_config: Option<PathBuf>,
    /// The contact hand-over's settings: a TOML file with the keys of a session file's
    /// `[slave.contact]` section (docs/sessions.md); default: the defaults there.
    #[arg(long, value_name = "FILE")]
    pub contact_config: Option<PathBuf>,
    /// The link's round trip, ms, as the deployment knows it (the master's measured round
    /// trip, `round_trip_p50_us` in its summary): the hand-over's spring softens over it
    /// (`slave.contact.round_trip_ms`, docs/sessions.md); overrides the contact file's.
    #[arg(long, value_name = "MS")]
    pub round_trip_ms: Option<f64>,
    /// When the arm cuts (a world with `[cutting]`): write the machined part into DIR at the
    /// end, `height.png` (height map), `part.stl` (binary STL) and, with a `cut_target`,
    /// `deviation.png`, as `h4-master sim --out` does (docs/cutting.md). Created if missing; refused before the run if it cannot be.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Stop (safe state, summary) when process PID, this process's parent, dies: set by
    /// `h4-master loopback` for the slave it starts (parent-death signal plus a watch on the
    /// parent).
    #[arg(long, value_name = "PID")]
    pub parent_pid: Option<u32>,
}

/// A `--contact-config` file: the keys of a session's `[slave.contact]` section.
#[derive(serde::Deserialize)]
#[serde(transparent)]
struct ContactFile(ContactHandover);

impl h4_shared::config::Validate for ContactFile {
    fn validate(&self) -> Result<(), h4_shared::config::ConfigError> {
        self.0.validate_at("")
    }
}

/// A `--passivity-config` file: the keys of a session's `[passivity]` section.
#[derive(serde::Deserialize)]
#[serde(transparent)]
struct PassivityFile(PassivityParams);

impl h4_shared::config::Validate for PassivityFile {
    fn validate(&self) -> Result<(), h4_shared::config::ConfigError> {
        self.0.validate_at("")
    }
}

impl RunArgs {
    /// Runs the slave process until stopped; prints and writes the summary.
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        if let Some(pid) = self.parent_pid {
            h4_telemetry::process::stop_with_parent(pid)
                .map_err(|e| format!("--parent-pid {pid}: {e}"))?;
        }
        self.run.check_outputs()?;
        if let Some(d) = &self.out {
            std::fs::create_dir_all(d).map_err(|e| format!("--out {}: {e}", d.display()))?;
        }
        let realtime = self.run.realtime_preflight(LABEL)?;
        let path = h4_shared::paths::default_config(
            self.config.as_deref(),
            "config/slave/sim-resin.toml",
            "--config",
        )?;
        let mut cfg: ExperimentConfig =
            h4_shared::config::load(&path, &self.set).map_err(|e| e.to_string())?;
        // A part from a mesh: read, checked and its distance grid built before the run.
        h4_slave_sim::plant::cutting::judge::load_mesh_target(
            cfg.cut_target.as_mut(),
            &mut cfg.fixtures,
            cfg.cutting.as_ref(),
            path.parent().unwrap_or(std::path::Path::new(".")),
        )
        .map_err(|e| e.to_string())?;
        let passivity = match &self.passivity_config {
            Some(p) => {
                h4_shared::config::load::<PassivityFile>(p, &[])
                    .map_err(|e| e.to_string())?
                    .0
            }
            None => PassivityParams::default(),
        };
        let playout = PlayoutConfig {
            enabled: self.playout,
            max_ms: self.playout_max_ms,
            quantile: self.playout_quantile,
        };
        h4_shared::config::check_range("--playout-max-ms", playout.max_ms, 0.0, 1000.0, "ms")
            .and_then(|()| {
                h4_shared::config::check_range("--playout-quantile", playout.quantile, 0.5, 1.0, "")
            })
            .map_err(|e| e.to_string())?;
        let link = self.transport.open_slave().map_err(|e| e.to_string())?;
        let link = impaired::wrap(link, self.impair.impair.as_ref(), Direction::Feedback)
            .map_err(|e| e.to_string())?;
        let mut link = Playout::new(link, MonotonicClock::new(), playout);
        let mut contact = match &self.contact_config {
            Some(p) => {
                h4_shared::config::load::<ContactFile>(p, &[])
                    .map_err(|e| e.to_string())?
                    .0
            }
            None => ContactHandover::default(),
        };
        if let Some(ms) = self.round_trip_ms {
            h4_shared::config::check_range("--round-trip-ms", ms, 0.0, 60_000.0, "ms")
                .map_err(|e| e.to_string())?;
            contact.round_trip_ms = ms;
        }
        let opts = RunOptions {
            passivity,
            contact,
            arm_id: self.transport.arm_id,
            watchdog_ms: self.watchdog_ms,
            realtime,
            progress: h4_telemetry::progress::ProgressConfig::from_env(LABEL),
            duration_s: self.run.duration_s,
            safety: h4_slave::teleop::SafetyParams {
                ratings: cfg.arm.ratings,
                monitor: !self.no_safety_monitor,
                unsafe_test_override: self.unsafe_test_override,
            },
            ..RunOptions::default()
        };
        let publishing = Ros2Publishing::start(
            &self.ros2,
            h4_transport::ros2::Ros2Names::SLAVE_NAMESPACE,
            "h4_slave",
        )?;
        let (ros2, ros2_record) = self.ros2.cell_and_recording(
            publishing.as_ref(),
            h4_transport::ros2::Ros2Names::SLAVE_NAMESPACE,
            self.run.record.is_some(),
        )?;
        let outputs = RunOutputs {
            record: self.run.record.clone(),
            foxglove_ws: self.live.foxglove_ws.clone(),
            out_dir: self.out.clone(),
            ros2,
            ros2_record,
        };
        let summary = match (self.arm, &self.replay) {
            (ArmKind::Sim, None) => h4_slave_sim::server::run_with_fault(
                &cfg,
                &opts,
                &outputs,
                self.inject_fault,
                &mut link,
            )
            .map_err(|e| e.to_string())?,
            (ArmKind::Replay, Some(_)) if self.inject_fault.is_some() => {
                return Err("--inject-fault needs --arm sim (the simulated arm)".to_string());
            }
            (ArmKind::Replay, Some(file)) => run_replay(&cfg, file, &opts, &outputs, &mut link)?,
            (ArmKind::Crtk, None) if self.inject_fault.is_some() => {
                return Err("--inject-fault needs --arm sim (the simulated arm)".to_string());
            }
            (ArmKind::Crtk, None) => super::crtk::run(
                &self.crtk, &self.ros2, LABEL, &cfg, &opts, &outputs, &mut link,
            )?,
            (ArmKind::Sim | ArmKind::Crtk, Some(_)) => {
                return Err("--replay needs --arm replay".to_string());
            }
            (ArmKind::Replay, None) => return Err("--arm replay needs --replay FILE".to_string()),
        };
        if let Some(p) = publishing {
            eprintln!("{}", p.stop_line(LABEL));
        }
        h4_telemetry::process::emit_summary(&summary, self.run.summary.as_deref())?;
        let interrupted = self.run.duration_s.is_some() && h4_telemetry::process::signal_received();
        h4_telemetry::progress::verdict_line(LABEL, &in_words(&summary, interrupted));
        Ok(h4_telemetry::process::exit_after_run(
            self.run.duration_s.is_some(),
        ))
    }
}

const LABEL: &str = "h4-slave run";

/// The slave on a replayed arm: the world file's controller over [`ReplayArm`], no
/// diagnostics (the recording's true force is not played back: `max_force_n` is the
/// measured force's), the recording and live view as for the simulated arm.
fn run_replay<L: h4_transport::Link<h4_shared::wire::Feedback, h4_shared::wire::Command>>(
    cfg: &ExperimentConfig,
    file: &std::path::Path,
    opts: &RunOptions,
    outputs: &RunOutputs,
    link: &mut L,
) -> Result<SimRunSummary, String> {
    use h4_shared::config::Validate;
    if outputs.out_dir.is_some() {
        return Err("--out: a replayed arm cuts nothing".to_string());
    }
    cfg.validate().map_err(|e| format!("configuration: {e}"))?;
    let arm = ReplayArm::open(file).map_err(|e| format!("--replay {e}"))?;
    // The controller of the world file (its arm, tool, limits and fixtures); the simulated
    // arm built beside it is not used.
    let (_, ctrl) = h4_slave_sim::server::sim_parts(cfg).map_err(|e| format!("controller: {e}"))?;
    let period_ns = opts.period_ns.max(1);
    let mut teleop =
        SlaveTeleop::new(opts.teleop_params(), ctrl, arm, period_ns).map_err(|e| e.to_string())?;
    let sink = Outputs::<server::CycleRecord>::start_polled(
        outputs.record.as_deref(),
        outputs.foxglove_ws.as_deref(),
        "h4-slave",
        ("/slave/cycle", "h4.SlaveProcessCycle"),
        None,
        1e9 / period_ns as f64,
        outputs.ros2_polled().map_err(|e| e.to_string())?,
    )
    .map_err(|e| e.to_string())?;
    let sink = h4_slave::ros2::Ros2Tee::new(sink, outputs.ros2.clone());
    let slave = server::run(&mut teleop, &mut NoDiagnostics, sink, opts, link)
        .map_err(|e| e.to_string())?;
    Ok(SimRunSummary {
        slave,
        cutting: None,
        fault_injection: None,
    })
}

/// The slave run's line: how it ended, then its figures.
fn in_words(s: &SimRunSummary, interrupted: bool) -> String {
    format!(
        "{} after {} cycles ({:.1} s), max force {:.1} N (true; limit {} N), {} safe stop(s), \
         {} command(s) rejected, observer min {:.2} mJ, loop lateness p99 {:.0} µs, {} deadline \
         misses, ended {}",
        if interrupted {
            "interrupted"
        } else {
            "stopped"
        },
        h4_telemetry::progress::grouped(s.run.cycles),
        s.run.run_time_s,
        s.max_force_n,
        s.force_limit_n,
        s.safe_stops,
        s.gate.rejected(),
        s.energy_min_j * 1e3,
        s.run.lateness_p99_us,
        s.run.deadline_misses,
        s.final_state
    )
}
