//! `h4-master sim <session.toml> [--set key=value]... [--summary out.json] [--record out.mcap]
//! [--out DIR]`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_master_sim::session;
use h4_telemetry::process::ExitStatus;
use h4_telemetry::progress::{Progress, interrupted_simulated_line, verdict_line};
use h4_telemetry::recording::Recorder;

const LABEL: &str = "h4-master sim";

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
    /// A cutting session writes the part here: `height.png`, `part.stl`, `deviation.png`,
    /// `cut.json` (the cutting fields; `report --part DIR` shows them).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Accept a safety layer turned off (`passivity.enabled=false`,
    /// `slave.controller.spindle_stall_safe_stop=false`, `slave.safety_monitor=false`) and
    /// controller gains beyond the arm's stable range: for negative controls only. The
    /// summary says so (`unsafe_test_override`). No rating of the arm can be raised.
    #[arg(long)]
    pub unsafe_test_override: bool,
}

impl SimArgs {
    /// Runs the session with progress on stderr; prints the summary (stdout) and the verdict
    /// line (stderr); exit code 0 if the detector says stable, 1 if not, 130 if SIGINT cut
    /// it short (the summary then covers the cycles run, and there is no verdict).
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        let cfg = session::load_with(&self.session, &self.set, self.unsafe_test_override)
            .map_err(|e| e.to_string())?;
        super::plausible::check_session(&cfg, LABEL)?;
        if let Some(p) = &self.summary {
            h4_telemetry::process::check_writable("--summary", p)?;
        }
        let mut recorder = match &self.record {
            Some(p) => Some(Recorder::create(p).map_err(|e| e.to_string())?),
            None => None,
        };
        let planned = (cfg.duration_s * 1000.0).round() as u64;
        let progress = Progress::simulated(LABEL, cfg.duration_s);
        let handle = progress.handle();
        let result = session::Session::new(&cfg).and_then(|s| {
            s.run_with(recorder.as_mut(), self.out.as_deref(), &mut |k| {
                handle.set(k);
                !h4_telemetry::process::stop_requested()
            })
        });
        progress.finish();
        let summary = result.map_err(|e| e.to_string())?;
        if let Some(r) = recorder {
            r.finish().map_err(|e| e.to_string())?;
        }
        h4_telemetry::process::emit_summary(&summary, self.summary.as_deref())?;
        if summary.cycles < planned {
            interrupted_simulated_line(LABEL, summary.sim_time_s, cfg.duration_s);
            return Ok(ExitStatus::Interrupted.into());
        }
        verdict_line(LABEL, &summary.in_words());
        Ok(if summary.stable {
            ExitStatus::Ok.into()
        } else {
            ExitStatus::VerdictFailed.into()
        })
    }
}
