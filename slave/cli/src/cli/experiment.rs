//! `h4-slave experiment <file.toml> [--set key=value]... [--summary out.json] [--record out.mcap]`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_slave_sim::experiment::Summary;
use h4_telemetry::process::ExitStatus;
use h4_telemetry::progress::{Progress, grouped, interrupted_simulated_line, verdict_line};
use h4_telemetry::recording::Recorder;

const LABEL: &str = "h4-slave experiment";

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
    /// Runs the experiment with progress on stderr, prints its summary (stdout) and its
    /// verdict line (stderr): exit 0 when the file's targets are met, 1 when not, 130 when
    /// SIGINT cut it short (the summary then covers the cycles run, no verdict).
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        let cfg: h4_slave_sim::experiment::ExperimentConfig =
            h4_shared::config::load(&self.file, &self.set).map_err(|e| e.to_string())?;
        if let Some(p) = &self.summary {
            h4_telemetry::process::check_writable("--summary", p)?;
        }
        let mut recorder = match &self.record {
            Some(path) => Some(Recorder::create(path).map_err(|e| e.to_string())?),
            None => None,
        };
        let planned = (cfg.duration_s * 1000.0).round() as u64;
        let progress = Progress::simulated(LABEL, cfg.duration_s);
        let handle = progress.handle();
        let result = h4_slave_sim::experiment::run_with(&cfg, recorder.as_mut(), &mut |k| {
            handle.set(k);
            !h4_telemetry::process::stop_requested()
        });
        progress.finish();
        let summary = result.map_err(|e| format!("{}: {e}", self.file.display()))?;
        if let Some(rec) = recorder {
            rec.finish().map_err(|e| e.to_string())?;
        }
        h4_telemetry::process::emit_summary(&summary, self.summary.as_deref())?;
        if summary.cycles < planned {
            interrupted_simulated_line(LABEL, summary.sim_time_s, cfg.duration_s);
            return Ok(ExitStatus::Interrupted.into());
        }
        verdict_line(LABEL, &in_words(&summary));
        Ok(if summary.verdict.passed {
            ExitStatus::Ok.into()
        } else {
            ExitStatus::VerdictFailed.into()
        })
    }
}

/// The experiment's line: `targets met, …` or `TARGETS MISSED: …`, then its figures.
fn in_words(s: &Summary) -> String {
    let figures = format!(
        "{} cycles ({:.1} s simulated), force error p99 {:.2} N (whole contact {:.2} N, max \
         {:.2} N), overshoot {:.1} %, settling {:.0} ms, max force {:.1} N",
        grouped(s.cycles),
        s.sim_time_s,
        s.force_error_p99_n,
        s.force_error_p99_contact_n,
        s.force_error_max_n,
        s.overshoot_pct,
        s.settling_ms,
        s.max_force_n
    );
    if s.verdict.passed {
        format!("targets met, {figures}")
    } else {
        format!(
            "TARGETS MISSED: {}; {figures}",
            s.verdict.failures.join("; ")
        )
    }
}
