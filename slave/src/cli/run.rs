//! `h4-slave run [--config world.toml] [--transport iceoryx2|zenoh] [--arm-id N] ...`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_shared::passivity::PassivityParams;
use h4_shared::process::LoopArgs;
use h4_slave::experiment::ExperimentConfig;
use h4_slave::server::{self, RunOptions};
use h4_transport::open::TransportArgs;

/// Run the slave process: the 1 kHz force loop on the simulated arm, commanded by a master
/// over iceoryx2 or Zenoh.
#[derive(Clone, Debug, clap::Args)]
pub struct RunArgs {
    /// The simulated world (arm, surface, sensor, plant, controller): an experiment file,
    /// e.g. config/experiments/fig6b.toml (its force and track sections are not used: the
    /// master commands the motion).
    #[arg(long, default_value = "config/slave/sim-resin.toml")]
    pub config: PathBuf,
    /// Override any field of the config file (repeatable).
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
    /// No valid command for this long puts the arm in its safe state, ms.
    #[arg(long, default_value_t = 20.0)]
    pub watchdog_ms: f64,
    /// The slave's passivity settings: a TOML file with the keys of a session file's
    /// `[passivity]` section (docs/sessions.md); default: the defaults there.
    #[arg(long, value_name = "FILE")]
    pub passivity_config: Option<PathBuf>,
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
        h4_shared::process::install_stop_handlers().map_err(|e| format!("signal handlers: {e}"))?;
        let cfg: ExperimentConfig =
            h4_shared::config::load(&self.config, &self.set).map_err(|e| e.to_string())?;
        let passivity = match &self.passivity_config {
            Some(p) => {
                h4_shared::config::load::<PassivityFile>(p, &[])
                    .map_err(|e| e.to_string())?
                    .0
            }
            None => PassivityParams::default(),
        };
        let mut link = self.transport.open_slave().map_err(|e| e.to_string())?;
        let opts = RunOptions {
            passivity,
            arm_id: self.transport.arm_id,
            watchdog_ms: self.watchdog_ms,
            fifo_priority: self.run.fifo_priority,
            lock_memory: self.run.lock_memory,
            duration_s: self.run.duration_s,
            record: self.run.record.clone(),
            foxglove_ws: self.live.foxglove_ws.clone(),
            ..RunOptions::default()
        };
        let summary = server::run(&cfg, &opts, &mut link).map_err(|e| e.to_string())?;
        h4_shared::process::emit_summary(&summary, self.run.summary.as_deref())?;
        Ok(h4_shared::process::exit_after_run(
            self.run.duration_s.is_some(),
        ))
    }
}
