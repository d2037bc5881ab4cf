//! A whole teleoperation session on the simulated clock: the operator's hand, the master arm
//! and its coupling, an impaired in-process link in each direction, the slave's passivity
//! port, the slave controller and the simulated H-4 arm, stepped in lockstep at 1 kHz. The
//! two sides share nothing but the link. A summary judges the run (with the stability
//! detector), and an MCAP recording can hold every cycle of both sides and the link's events.
//!
//! * `config`: the session file ([`load`], [`SessionConfig`]), its sections and their checks;
//! * `run`: [`Session`], both endpoints and the link in lockstep;
//! * `timing`: when the slave takes the master's command ([`SlaveTiming`], `slave.timing`);
//! * `record`: the recording's channels and messages;
//! * `detector`: the stability detector and the [`Summary`];
//! * [`cutting`]: a cutting session's target shape, its judgement and the part's files.
//!
//! Every field of a session file is documented in `docs/sessions.md`.

use h4_shared::config::ConfigError;
use h4_slave::teleop::TeleopError;
use h4_slave_sim::plant::SimError;
use h4_telemetry::recording::RecordingError;

use crate::operator::IntentError;

mod config;
pub use h4_slave_sim::plant::cutting::judge as cutting;
mod detector;
mod record;
mod run;
mod timing;

pub use h4_master::coupling::{CouplingConfig, ScaleConfig};
pub use h4_master::teleop::MasterCycle;

/// One master cycle of the session: the endpoint's cycle (its fields read through) and the
/// simulated operator's hand in it.
#[derive(Clone, Copy, Debug)]
pub struct SimMasterCycle {
    /// The endpoint's cycle.
    pub cycle: MasterCycle,
    /// The hand.
    pub hand: crate::operator::HandOutput,
}

impl std::ops::Deref for SimMasterCycle {
    type Target = MasterCycle;
    fn deref(&self) -> &MasterCycle {
        &self.cycle
    }
}
pub use config::{
    EnvironmentConfig, HostConfig, OperatorConfig, PassivityConfig, SessionConfig, SlaveConfig,
    StallSide, load, load_with,
};
pub use detector::{DetectorConfig, HF_CUTOFF_HZ, Summary, high_frequency_rms};
pub use run::{Session, run, run_with_outputs};
pub use timing::{SlaveInbox, SlaveTiming};

/// Period of the lockstep cycle, ns.
const CYCLE_NS: u64 = 1_000_000;
/// Period of the lockstep cycle, s.
const DT_S: f64 = 1e-3;

/// Why a session could not run.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The configuration is not usable.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// The operator's script or replay file.
    #[error("{0}")]
    Intent(#[from] IntentError),
    /// The simulated slave could not be built.
    #[error("slave simulation: {0}")]
    Sim(#[from] SimError),
    /// The master arm could not be built.
    #[error("master arm: {0}")]
    Master(h4_shared::KinError),
    /// The recording failed.
    #[error("{0}")]
    Recording(#[from] RecordingError),
    /// The slave's endpoint could not be built.
    #[error("{0}")]
    Teleop(#[from] TeleopError),
    /// The link failed.
    #[error("link: {0}")]
    Link(#[from] h4_transport::LinkError),
    /// A mesh target's part was refused (or a mesh fixture has no part).
    #[error("{0}")]
    Mesh(#[from] h4_slave_sim::plant::cutting::judge::MeshTargetError),
    /// The part's files could not be written.
    #[error("--out: {0}")]
    Export(#[from] h4_slave_sim::plant::cutting::export::ExportError),
}
