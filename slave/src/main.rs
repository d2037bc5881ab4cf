//! `h4-slave`: the slave side of h4-teleop.

use std::io::{BufReader, BufWriter};
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use h4_shared::recording::Recorder;
use h4_shared::{ActuatorStiffness, H4Params};

/// The h4-teleop slave: the H-4 arm's force loop and its tools.
#[derive(Debug, Parser)]
#[command(name = "h4-slave", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Kinematics tool: JSON lines on stdin ({"pose":[x,y,z,theta]} or {"l":[l1,l2,l3,l4]},
    /// mm and rad), one JSON answer per line on stdout.
    Kin(KinArgs),
    /// Runs one autonomous force-tracking experiment on the simulated clock and prints its
    /// summary as JSON (fields in docs/slave-experiments.md).
    Experiment(ExperimentArgs),
    /// Runs the slave process: the 1 kHz force loop on the simulated arm, commanded by a
    /// master over iceoryx2 or Zenoh, until SIGINT/SIGTERM (or --duration-s).
    Run(h4_slave::server::cli::RunArgs),
    /// Draws a recording (MCAP): PNG figures (force against the set-point and its tolerance
    /// band, force along the path, tracking errors; for sessions the rendered force, the
    /// passivity observers and the link), metrics.json and index.html.
    Report(h4_slave::report::ReportArgs),
}

#[derive(Debug, Args)]
struct ExperimentArgs {
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
    fn run(self) -> Result<(), String> {
        let cfg: h4_slave::experiment::ExperimentConfig =
            h4_shared::config::load(&self.file, &self.set).map_err(|e| e.to_string())?;
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
        Ok(())
    }
}

#[derive(Debug, Args)]
struct KinArgs {
    /// Geometry: `prototype`, `alt`, or R,E,C,D in mm (E = a − b).
    #[arg(long, default_value = "prototype", value_parser = h4_slave::kin_tool::parse_params)]
    params: H4Params,
    /// Axial stiffness of every actuator, N/mm, for the compliance and stiffness matrices.
    #[arg(long = "stiffness", value_name = "K_N_PER_MM", default_value_t = 1.0)]
    stiffness_n_per_mm: f64,
}

impl KinArgs {
    fn run(self) -> Result<(), String> {
        let k = ActuatorStiffness::uniform(self.stiffness_n_per_mm)
            .map_err(|e| format!("--stiffness: {e}"))?;
        let stdin = std::io::stdin();
        let stdout = std::io::stdout();
        h4_slave::kin_tool::run(
            BufReader::new(stdin.lock()),
            BufWriter::new(stdout.lock()),
            &self.params,
            &k,
        )
        .map_err(|e| format!("kin: {e}"))
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Kin(args) => args.run(),
        Command::Experiment(args) => args.run(),
        Command::Run(args) => args.run(),
        Command::Report(args) => args.run().map(|_| ()).map_err(|e| e.to_string()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("h4-slave: {message}");
            ExitCode::FAILURE
        }
    }
}
