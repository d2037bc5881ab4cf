//! `h4-slave identify [--world world.toml] [--arm arm.toml] [--set key=value]... [--write]
//! [--summary out.json]`

use std::path::PathBuf;
use std::process::ExitCode;

use h4_shared::config::ArmConfig;
use h4_shared::kinematics::Pose;
use h4_slave_sim::experiment::ExperimentConfig;
use h4_slave_sim::identify::{identify, write_tool_section};
use serde::Serialize;

/// Identify the tool beyond the force sensor (mass, centre of mass, sensor bias) on the
/// simulated arm, from a few poses in free space; with --write, into the arm file.
#[derive(Debug, clap::Args)]
pub struct IdentifyArgs {
    /// The simulated world (sensor, plant; an experiment file): the poses are held 30 mm
    /// above its surface's contact point plus its approach gap.
    #[arg(long, default_value = "config/slave/sim-resin.toml")]
    world: PathBuf,
    /// The arm file whose geometry the routine uses and whose `[tool]` --write replaces.
    #[arg(long, default_value = "config/arms/prototype.toml")]
    arm: PathBuf,
    /// Override any field of the world file (repeatable), e.g. --set plant.payload_mass_kg=1.2.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Write the identified `[tool]` into the arm file.
    #[arg(long)]
    write: bool,
    /// Also write the result JSON to this file.
    #[arg(long)]
    summary: Option<PathBuf>,
}

/// What `identify` prints.
#[derive(Serialize)]
struct IdentifySummary {
    identified: h4_slave_sim::identify::Identified,
    /// The simulation's true payload, for comparison only (a real arm has none).
    sim_truth_mass_kg: f64,
    sim_truth_com_mm: [f64; 3],
    arm_file_written: bool,
}

impl IdentifyArgs {
    /// Runs the routine and prints its result.
    pub fn run(self) -> Result<ExitCode, String> {
        let arm: ArmConfig = h4_shared::config::load(&self.arm, &[]).map_err(|e| e.to_string())?;
        let mut cfg: ExperimentConfig =
            h4_shared::config::load(&self.world, &self.set).map_err(|e| e.to_string())?;
        cfg.arm = arm;
        let p = cfg.surface.contact_point_mm;
        let start = Pose::new(p[0], p[1], p[2] + cfg.approach.gap_mm + 30.0, 0.0);
        let (mut sim, _) = cfg
            .world()
            .build(start, cfg.seed)
            .map_err(|e| e.to_string())?;
        let ws = cfg.arm.workspace();
        let g = cfg.controller.gravity_mm_per_s2;
        let result = identify(&mut sim, &ws, start, g, 1e-3, |a| a.advance(1_000_000))
            .map_err(|e| e.to_string())?;
        if self.write {
            let text = std::fs::read_to_string(&self.arm)
                .map_err(|e| format!("{}: {e}", self.arm.display()))?;
            let note = format!(
                "written by h4-slave identify ({} poses, residual {:.3} N)",
                result.poses, result.residual_n
            );
            let new = write_tool_section(&text, &result.tool, &note);
            let tmp = self.arm.with_extension("toml.tmp");
            std::fs::write(&tmp, new).map_err(|e| format!("{}: {e}", tmp.display()))?;
            std::fs::rename(&tmp, &self.arm).map_err(|e| format!("{}: {e}", self.arm.display()))?;
        }
        let summary = IdentifySummary {
            identified: result,
            sim_truth_mass_kg: cfg.plant.payload_mass_kg,
            sim_truth_com_mm: cfg.plant.payload_com_mm,
            arm_file_written: self.write,
        };
        h4_telemetry::process::emit_summary(&summary, self.summary.as_deref())?;
        Ok(ExitCode::SUCCESS)
    }
}
