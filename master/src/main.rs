//! `h4-master`: the master side of h4-teleop. Dispatch only; each subcommand lives in its
//! own module under `cli/`.

use clap::{Parser, Subcommand};

mod cli;

/// The h4-teleop master.
#[derive(Parser)]
#[command(name = "h4-master", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a whole session (operator, master, impaired link, slave) on the simulated clock.
    Sim(cli::sim::SimArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Sim(args) => args.run(),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("h4-master: {e}");
            std::process::ExitCode::from(2)
        }
    }
}
