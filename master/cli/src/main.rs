//! `h4-master`: the master side of h4-teleop. Dispatch only; each subcommand lives in its
//! own module under `cli/`.

use clap::{Parser, Subcommand};

mod cli;

/// The h4-teleop master.
#[derive(Parser)]
#[command(name = "h4-master", version, about, after_help = h4_telemetry::process::EXIT_CODES_HELP)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a whole session (operator, master, impaired link, slave) on the simulated clock.
    Sim(cli::sim::SimArgs),
    /// Run the master process: simulated master arm and scripted operator at 1 kHz against a
    /// slave process over iceoryx2 or Zenoh, until SIGINT/SIGTERM (or --duration-s).
    Run(Box<cli::run::RunArgs>),
    /// Start the slave and the master as two processes connected by iceoryx2 (or Zenoh with
    /// --transport zenoh), run the session for a while, stop, and print a summary (JSON).
    Loopback(cli::loopback::LoopbackArgs),
    /// Run the delay matrix: a session over wall × round trip × jitter × loss × force scale
    /// on the simulated clock, with progress; writes the per-cell table (CSV, JSON,
    /// markdown) and a heat map per wall (PNG).
    Matrix(cli::matrix::MatrixArgs),
    /// Run a stand-in haptic device that speaks only ROS 2: the simulated master arm and
    /// scripted operator of a session file behind CRTK topics (publishes measured_cp,
    /// measured_cv, clutch; renders servo_cf), for `h4-master run --device crtk`.
    Ros2Standin(cli::standin::StandinArgs),
    /// Write the slave's world, passivity and contact hand-over files of a session, for
    /// `h4-slave run --config WORLD --passivity-config PASSIVITY --contact-config CONTACT`.
    SlaveConfig(cli::loopback::SlaveConfigArgs),
    /// Draws a recording (MCAP) of a session, the processes or an experiment: PNG figures
    /// (rendered vs slave force, passivity observers, the link's round trip and losses; force
    /// against the set-point band), metrics.json and index.html.
    Report(h4_slave_sim::report::ReportArgs),
    /// Measure on this host, in one run: round trips of the bare links against the processes
    /// (iceoryx2 and Zenoh, idle and with both cores loaded), 1 kHz loop lateness, simulation
    /// speed per session kind and the matrix; prints a table, --json writes it.
    Bench(cli::bench::BenchArgs),
    /// Write the configuration reference (docs/configuration.md): every field of the arm,
    /// experiment and session files with its type, unit, range, default and description,
    /// from the code's schemas and checks; `--check FILE` exits 1 if FILE is stale.
    ConfigReference(cli::config_reference::ConfigReferenceArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    h4_transport::zenoh::init_log_from_env();
    let result = match cli.command {
        Command::Sim(args) => args.run(),
        Command::Run(args) => args.run(),
        Command::Loopback(args) => args.run(),
        Command::Matrix(args) => args.run(),
        Command::SlaveConfig(args) => args.run(),
        Command::Ros2Standin(args) => args.run(),
        Command::ConfigReference(args) => args.run(),
        Command::Bench(args) => args.run(),
        Command::Report(args) => args
            .run()
            .map(|_| std::process::ExitCode::SUCCESS)
            .map_err(|e| e.to_string()),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("h4-master: {e}");
            h4_telemetry::process::ExitStatus::Error.into()
        }
    }
}
