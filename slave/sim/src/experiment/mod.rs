//! Autonomous force-tracking experiments on the simulated clock: approach from free space,
//! contact, track along the surface, optional set-point steps; a summary of how well the
//! force was held, and optionally an MCAP recording of every 1 ms cycle.
//!
//! Every field of an experiment file is documented in `docs/slave-experiments.md`.
//!
//! * [`config`]: the experiment file, [`ExperimentConfig`], and its sections;
//! * [`run()`]: the 1 ms loop of the simulated arm and its controller, and its recording;
//! * [`metrics`]: the [`Summary`] of a run.

pub mod config;
pub mod metrics;
mod record;
mod run;

pub use crate::plant::{Axis, ShapeKind, SurfaceConfig};
pub use config::{
    ApproachConfig, ExperimentConfig, ForceConfig, ForceStep, SummaryConfig, TargetsConfig,
    TrackConfig,
};
pub use metrics::{EventSummary, Summary, Verdict};
pub use run::{run, run_with};

use h4_shared::config::ConfigError;
use h4_telemetry::recording::RecordingError;

use crate::plant::SimError;

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The simulation could not be built.
    #[error("simulation: {0}")]
    Sim(#[from] SimError),
    /// The recording failed.
    #[error("{0}")]
    Recording(#[from] RecordingError),
    /// The configuration is not usable.
    #[error("{0}")]
    Config(#[from] ConfigError),
}
