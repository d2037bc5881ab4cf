//! `h4-master run [--config session.toml] [--transport iceoryx2|zenoh] [--arm-id N] ...`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_master::server::{self, MasterRunOptions, MasterRunSummary};
use h4_master::session;
use h4_shared::process::LoopArgs;
use h4_transport::open::TransportArgs;

/// Run the master process: the simulated master arm and the scripted operator of a session
/// file, at 1 kHz, against a slave process (`h4-slave run`) over iceoryx2 or Zenoh.
#[derive(Clone, Debug, clap::Args)]
pub struct RunArgs {
    /// The session file: master arm, operator script, coupling, scaling, passivity
    /// (docs/sessions.md; the link and slave sections are not used by a real process).
    #[arg(long, default_value = "config/sessions/wall-push.toml")]
    pub config: PathBuf,
    /// Override a field of the session file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Transport.
    #[command(flatten)]
    pub transport: TransportArgs,
    /// Duration, summary, recording, real-time settings.
    #[command(flatten)]
    pub run: LoopArgs,
    /// The live view.
    #[command(flatten)]
    pub live: h4_shared::live::LiveArgs,
    /// Wait this long for the slave's first feedback before the operator's script starts, s.
    #[arg(long, default_value_t = 10.0)]
    pub wait_for_slave_s: f64,
}

impl RunArgs {
    /// Runs the master until stopped and returns its summary.
    pub fn run_summary(&self) -> Result<MasterRunSummary, String> {
        self.run_summary_then(|| {})
    }

    /// [`RunArgs::run_summary`], calling `at_loop_end` as soon as the loop has stopped.
    pub fn run_summary_then(&self, at_loop_end: impl FnOnce()) -> Result<MasterRunSummary, String> {
        h4_shared::process::install_stop_handlers().map_err(|e| format!("signal handlers: {e}"))?;
        let cfg = session::load(&self.config, &self.set)
            .map_err(|e| format!("{}: {e}", self.config.display()))?;
        let link = self.transport.open_master().map_err(|e| e.to_string())?;
        let opts = MasterRunOptions {
            arm_id: self.transport.arm_id,
            fifo_priority: self.run.fifo_priority,
            lock_memory: self.run.lock_memory,
            duration_s: self.run.duration_s,
            wait_for_slave_s: self.wait_for_slave_s,
            record: self.run.record.clone(),
            foxglove_ws: self.live.foxglove_ws.clone(),
            ..MasterRunOptions::default()
        };
        server::run_then(&cfg, &opts, link, at_loop_end).map_err(|e| e.to_string())
    }

    /// Runs the master process; prints and writes the summary.
    pub fn run(self) -> Result<ExitCode, String> {
        let summary = self.run_summary()?;
        h4_shared::process::emit_summary(&summary, self.run.summary.as_deref())?;
        Ok(h4_shared::process::exit_after_run(
            self.run.duration_s.is_some(),
        ))
    }
}
