//! `h4-slave`: the slave side of h4-teleop.

use std::io::{BufReader, BufWriter};
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
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
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("h4-slave: {message}");
            ExitCode::FAILURE
        }
    }
}
