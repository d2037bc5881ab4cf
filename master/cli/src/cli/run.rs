//! `h4-master run [--device sim] [--config session.toml] [--transport iceoryx2|zenoh] [--arm-id N] ...`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_master::server::{MasterRunOptions, MasterRunSummary};
use h4_master_sim::server::RunOutputs;
use h4_master_sim::session;
use h4_telemetry::progress::{ProgressConfig, grouped, verdict_line};
use h4_telemetry::rt::LoopArgs;
use h4_telemetry::rt::RealtimePlan;
use h4_transport::impaired::{self, Direction, ImpairArgs};
use h4_transport::open::TransportArgs;
use h4_transport::ros2::node::{Ros2Args, Ros2Publishing};

/// The haptic device `h4-master run` renders on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceKind {
    /// The simulated master arm with the scripted operator's hand of the session file.
    Sim,
    /// A haptic device reached over ROS 2 (rmw_zenoh): CRTK topics or forcedimension_ros2's
    /// (`--device-profile`, `--device-ns`; docs/ros2.md).
    Crtk,
}

/// Run the master process: a haptic device (the simulated master arm and the scripted
/// operator of a session file), at 1 kHz, against a slave process (`h4-slave run`) over
/// iceoryx2 or Zenoh.
#[derive(Clone, Debug, clap::Args)]
pub struct RunArgs {
    /// The haptic device driver (docs/drivers.md).
    #[arg(long, value_enum, default_value_t = DeviceKind::Sim)]
    pub device: DeviceKind,
    /// The session file: master arm, operator script, coupling, scaling, passivity
    /// (docs/sessions.md; the link and slave sections are not used by a real process);
    /// default: config/sessions/wall-push.toml of the repository (found from the binary,
    /// not the working directory).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a field of the session file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Transport.
    #[command(flatten)]
    pub transport: TransportArgs,
    /// Link impairment of the commands this process sends (`--impair`).
    #[command(flatten)]
    pub impair: ImpairArgs,
    /// Duration, summary, recording, real-time settings.
    #[command(flatten)]
    pub run: LoopArgs,
    /// The live view.
    #[command(flatten)]
    pub live: h4_telemetry::live::LiveArgs,
    /// ROS 2 (`--ros2`, docs/ros2.md).
    #[command(flatten)]
    pub ros2: Ros2Args,
    /// The ROS 2 device (`--device crtk`).
    #[command(flatten)]
    pub crtk: super::crtk::CrtkDeviceArgs,
    /// Wait this long for the slave's first feedback before the operator's script starts, s.
    #[arg(long, default_value_t = 10.0)]
    pub wait_for_slave_s: f64,
    /// Set by `loopback`, which did the checks before the run itself (the real-time
    /// preflight, the plausibility of the session): they are not repeated.
    #[arg(skip)]
    pub prechecked: bool,
    /// Accept a safety layer turned off (`passivity.enabled=false`,
    /// `slave.controller.spindle_stall_safe_stop=false`, `slave.safety_monitor=false`) and
    /// controller gains beyond the arm's stable range: for negative controls only. The
    /// summary says so (`unsafe_test_override`). No rating of the arm can be raised.
    #[arg(long)]
    pub unsafe_test_override: bool,
}

impl RunArgs {
    /// Runs the master until stopped and returns its summary.
    pub fn run_summary(&self, label: &str) -> Result<MasterRunSummary, String> {
        self.run_summary_then(label, || {})
    }

    /// [`RunArgs::run_summary`], calling `at_loop_end` as soon as the loop has stopped;
    /// `label` starts the progress lines and notes (`h4-master run`, `h4-master loopback`).
    pub fn run_summary_then(
        &self,
        label: &str,
        at_loop_end: impl FnOnce(),
    ) -> Result<MasterRunSummary, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        self.run.check_outputs()?;
        let realtime = if self.prechecked {
            RealtimePlan::from_flags(
                self.run.realtime,
                self.run.fifo_priority,
                self.run.lock_memory,
            )?
        } else {
            self.run.realtime_preflight(label)?
        };
        let path =
            h4_shared::paths::default_config(self.config.as_deref(), super::SESSION, "--config")?;
        let cfg = session::load_with(&path, &self.set, self.unsafe_test_override)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        if !self.prechecked {
            super::plausible::check_session(&cfg, label)?;
        }
        let link = self.transport.open_master().map_err(|e| e.to_string())?;
        let link = impaired::wrap(link, self.impair.impair.as_ref(), Direction::Commands)
            .map_err(|e| e.to_string())?;
        let opts = MasterRunOptions {
            arm_id: self.transport.arm_id,
            realtime,
            progress: ProgressConfig::from_env(label),
            duration_s: self.run.duration_s,
            wait_for_slave_s: self.wait_for_slave_s,
            ..MasterRunOptions::default()
        };
        let publishing = Ros2Publishing::start(
            &self.ros2,
            h4_transport::ros2::Ros2Names::MASTER_NAMESPACE,
            "h4_master",
        )?;
        let (ros2, ros2_record) = self.ros2.cell_and_recording(
            publishing.as_ref(),
            h4_transport::ros2::Ros2Names::MASTER_NAMESPACE,
            self.run.record.is_some(),
        )?;
        let out = RunOutputs {
            record: self.run.record.clone(),
            foxglove_ws: self.live.foxglove_ws.clone(),
            ros2,
            ros2_record,
        };
        let summary = match self.device {
            DeviceKind::Sim => {
                h4_master_sim::server::run_then(&cfg, &opts, &out, link, at_loop_end)
                    .map_err(|e| e.to_string())
            }
            DeviceKind::Crtk => super::crtk::run_then(
                &self.crtk,
                &self.ros2,
                label,
                &cfg,
                &opts,
                &out,
                link,
                at_loop_end,
            ),
        };
        if let Some(p) = publishing {
            eprintln!("{}", p.stop_line(label));
        }
        summary
    }

    /// Runs the master process; prints and writes the summary, then its verdict line.
    pub fn run(self) -> Result<ExitCode, String> {
        let summary = self.run_summary(LABEL)?;
        h4_telemetry::process::emit_summary(&summary, self.run.summary.as_deref())?;
        let code = h4_telemetry::process::exit_after_run(self.run.duration_s.is_some());
        let interrupted = self.run.duration_s.is_some() && h4_telemetry::process::signal_received();
        verdict_line(LABEL, &in_words(&summary, interrupted));
        Ok(code)
    }
}

const LABEL: &str = "h4-master run";

/// The master run's line: how it ended, then its figures.
pub fn in_words(s: &MasterRunSummary, interrupted: bool) -> String {
    let r = &s.run;
    format!(
        "{} after {} cycles ({:.1} s), round trip p99 {:.2} ms, rendered force max {:.1} N, \
         slave force max {:.1} N (reported), observer min {:.2} mJ, feedback lost {:.1} %, \
         loop lateness p99 {:.0} µs, {} deadline misses",
        if interrupted {
            "interrupted"
        } else {
            "stopped"
        },
        grouped(r.cycles),
        r.run_time_s,
        s.round_trip_p99_us / 1e3,
        s.max_rendered_force_n,
        s.max_slave_force_n,
        s.energy_min_j * 1e3,
        s.feedback_loss_pct,
        r.lateness_p99_us,
        r.deadline_misses
    )
}
