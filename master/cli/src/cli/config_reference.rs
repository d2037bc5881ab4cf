//! `h4-master config-reference [--out FILE] [--check FILE]`: the configuration reference
//! (`docs/configuration.md`), generated from the configuration types' schemas and checks
//! ([`h4_master_sim::config_reference`]).

use std::path::PathBuf;
use std::process::ExitCode;

use h4_master_sim::config_reference;
use h4_telemetry::process::ExitStatus;

/// Write the configuration reference: every field of the arm, experiment and session files
/// with its type, unit, range, default and description.
#[derive(clap::Args)]
pub struct ConfigReferenceArgs {
    /// Write the reference to this file (default: print it on stdout).
    #[arg(long, value_name = "FILE", conflicts_with = "check")]
    out: Option<PathBuf>,
    /// Compare FILE with the reference instead: exit 1 with a one-line message if it differs
    /// (stale), 0 if it is the same.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
}

impl ConfigReferenceArgs {
    /// Renders the reference, then prints, writes or compares it.
    pub fn run(self) -> Result<ExitCode, String> {
        let text = config_reference::render()?;
        if let Some(path) = &self.check {
            let current = std::fs::read_to_string(path)
                .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
            if current == text {
                return Ok(ExitStatus::Ok.into());
            }
            eprintln!(
                "h4-master config-reference: {0} is stale: run `h4-master config-reference --out {0}`",
                path.display()
            );
            return Ok(ExitStatus::VerdictFailed.into());
        }
        match &self.out {
            Some(path) => std::fs::write(path, &text)
                .map_err(|e| format!("cannot write {}: {e}", path.display()))?,
            None => print!("{text}"),
        }
        Ok(ExitStatus::Ok.into())
    }
}
