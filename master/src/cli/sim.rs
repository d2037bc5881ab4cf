//! `h4-master sim <session.toml> [--set key=value]... [--summary out.json] [--record out.mcap]
//! [--out DIR]`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_master::session;
use h4_shared::recording::Recorder;

/// Simulate a whole teleoperation session on the simulated clock.
#[derive(clap::Args)]
pub struct SimArgs {
    /// The session file (TOML; fields in docs/sessions.md).
    session: PathBuf,
    /// Override a field: `--set link.delay_ms=50` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Write the summary (JSON) here; it is always printed on stdout.
    #[arg(long, value_name = "FILE")]
    summary: Option<PathBuf>,
    /// Record every cycle of both sides and the link's events (MCAP).
    #[arg(long, value_name = "FILE")]
    record: Option<PathBuf>,
    /// A cutting session writes the part here: `height.png`, `part.stl`, `deviation.png`.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

impl SimArgs {
    /// Runs the session; exit code 0 if the detector says stable, 1 if not.
    pub fn run(self) -> Result<ExitCode, String> {
        let cfg = session::load(&self.session, &self.set).map_err(|e| e.to_string())?;
        if let Some(p) = &self.summary {
            h4_shared::process::check_writable("--summary", p)?;
        }
        let mut recorder = match &self.record {
            Some(p) => Some(Recorder::create(p).map_err(|e| e.to_string())?),
            None => None,
        };
        let summary = session::run_with_outputs(&cfg, recorder.as_mut(), self.out.as_deref())
            .map_err(|e| e.to_string())?;
        if let Some(r) = recorder {
            r.finish().map_err(|e| e.to_string())?;
        }
        h4_shared::process::emit_summary(&summary, self.summary.as_deref())?;
        Ok(if summary.stable {
            ExitCode::SUCCESS
        } else {
            h4_shared::process::ExitStatus::VerdictFailed.into()
        })
    }
}
