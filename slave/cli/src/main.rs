//! `h4-slave`: the slave side of h4-teleop. Dispatch only; each subcommand lives in its own
//! module under `cli/`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use h4_telemetry::process::{EXIT_CODES_HELP, ExitStatus};

mod cli;

/// The h4-teleop slave: the H-4 arm's force loop and its tools.
#[derive(Debug, Parser)]
#[command(name = "h4-slave", version, about, after_help = EXIT_CODES_HELP)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Kinematics tool: JSON lines on stdin ({"pose":[x,y,z,theta]} or {"l":[l1,l2,l3,l4]},
    /// mm and rad), one JSON answer per line on stdout.
    Kin(cli::kin::KinArgs),
    /// Runs one autonomous force-tracking experiment on the simulated clock and prints its
    /// summary as JSON (fields in docs/slave-experiments.md).
    Experiment(cli::experiment::ExperimentArgs),
    /// Identifies the tool beyond the force sensor (mass, centre of mass, sensor bias) from
    /// a few poses in free space on the simulated arm; --write puts it into the arm file.
    Identify(cli::identify::IdentifyArgs),
    /// Runs the slave process: the 1 kHz force loop on an arm (`--arm sim`, the simulated
    /// arm, or `--arm replay --replay FILE`, a recorded one), commanded by a master over
    /// iceoryx2 or Zenoh, until SIGINT/SIGTERM (or --duration-s).
    Run(Box<cli::run::RunArgs>),
    /// Runs a stand-in arm that speaks only ROS 2: the simulated arm of a world file behind
    /// CRTK topics (publishes measured_cp, measured_cv, measured_cf; follows servo_cp), for
    /// `h4-slave run --arm crtk` (docs/ros2.md).
    #[command(name = "ros2-standin")]
    Ros2Standin(Box<cli::standin::StandinArgs>),
    /// Draws a recording (MCAP): PNG figures (force against the set-point and its tolerance
    /// band, force along the path, tracking errors; for sessions the rendered force, the
    /// passivity observers and the link), metrics.json and index.html.
    Report(h4_slave_sim::report::ReportArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    h4_transport::zenoh::init_log_from_env();
    let result = match cli.command {
        Command::Kin(args) => args.run(),
        Command::Experiment(args) => args.run(),
        Command::Identify(args) => args.run(),
        Command::Run(args) => args.run(),
        Command::Ros2Standin(args) => args.run(),
        Command::Report(args) => args
            .run()
            .map(|_| ExitStatus::Ok.into())
            .map_err(|e| e.to_string()),
    };
    match result {
        Ok(code) => code,
        Err(message) => {
            eprintln!("h4-slave: {message}");
            ExitStatus::Error.into()
        }
    }
}
