//! `h4-slave kin [--params prototype|alt|R,E,C,D] [--stiffness K]`: JSON lines in, JSON lines out.

use std::io::{BufReader, BufWriter};
use std::process::ExitCode;

use h4_shared::{ActuatorStiffness, H4Params, WorkspaceLimits};

/// The kinematics tool's options.
#[derive(Debug, clap::Args)]
pub struct KinArgs {
    /// Geometry: `prototype`, `alt`, or R,E,C,D in mm (E = a − b).
    #[arg(long, default_value = "prototype", value_parser = h4_slave_sim::kin_tool::parse_params)]
    params: H4Params,
    /// Axial stiffness of every actuator, N/mm, for the compliance and stiffness matrices.
    #[arg(long = "stiffness", value_name = "K_N_PER_MM", default_value_t = 1.0)]
    stiffness_n_per_mm: f64,
    /// Answer poses outside the nominal workspace too (|θ| ≤ 60°, ≥ 10 mm from the singular
    /// line, rail clearance ≥ 20 mm, actuators within ±650 mm): the bare kinematics.
    #[arg(long)]
    no_workspace_check: bool,
}

impl KinArgs {
    /// Answers every line of standard input on standard output.
    pub fn run(self) -> Result<ExitCode, String> {
        let k = ActuatorStiffness::uniform(self.stiffness_n_per_mm)
            .map_err(|e| format!("--stiffness: {e}"))?;
        let stdin = std::io::stdin();
        let stdout = std::io::stdout();
        h4_slave_sim::kin_tool::run(
            BufReader::new(stdin.lock()),
            BufWriter::new(stdout.lock()),
            &self.params,
            &k,
            (!self.no_workspace_check)
                .then(WorkspaceLimits::default)
                .as_ref(),
        )
        .map_err(|e| format!("kin: {e}"))?;
        Ok(ExitCode::SUCCESS)
    }
}
