//! `h4-slave experiment <file.toml> [--set key=value]... [--summary out.json] [--record out.mcap]`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_shared::process::ExitStatus;
use h4_shared::recording::Recorder;

/// Run one autonomous force-tracking experiment on the simulated clock.
#[derive(Debug, clap::Args)]
pub struct ExperimentArgs {
    /// The experiment file (TOML), e.g. config/experiments/fig6b.toml.
    file: PathBuf,
    /// Override any field: `--set surface.material=steel` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Also write the summary JSON to this file.
    #[arg(long)]
    summary: Option<PathBuf>,
    /// Record every 1 ms cycle to this MCAP file (Foxglove opens it).
    #[arg(long)]
    record: Option<PathBuf>,
}

impl ExperimentArgs {
    /// Runs the experiment and prints its summary.
    pub fn run(self) -> Result<ExitCode, String> {
        let cfg: h4_slave::experiment::ExperimentConfig =
            h4_shared::config::load(&self.file, &self.set).map_err(|e| e.to_string())?;
        if let Some(p) = &self.summary {
            h4_shared::process::check_writable("--summary", p)?;
        }
        let mut recorder = match &self.record {
            Some(path) => Some(Recorder::create(path).map_err(|e| e.to_string())?),
            None => None,
        };
        let summary = h4_slave::experiment::run(&cfg, recorder.as_mut())
            .map_err(|e| format!("{}: {e}", self.file.display()))?;
        if let Some(rec) = recorder {
            rec.finish().map_err(|e| e.to_string())?;
        }
        h4_shared::process::emit_summary(&summary, self.summary.as_deref())?;
        if summary.verdict.passed {
            Ok(ExitStatus::Ok.into())
        } else {
            for why in &summary.verdict.failures {
                eprintln!("h4-slave experiment: {}: {why}", self.file.display());
            }
            Ok(ExitStatus::VerdictFailed.into())
        }
    }
}
