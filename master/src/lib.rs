//! The h4-teleop master: the operator's haptic arm, the bilateral coupling with
//! time-domain passivity control, and the whole-session simulation.
//!
//! * [`device`]: [`device::HapticDevice`] (what a real driver implements) and
//!   [`device::SimMasterArm`], a simulated H-4 family master arm.
//! * [`operator`]: the simulated hand following a scripted intent, or replaying a trajectory.
//! * [`coupling`]: [`coupling::MasterCoupling`], the master's pure 1 kHz step
//!   (position–force and force-guided coupling, scaling, clutch, workspace mapping,
//!   saturation, feedback-loss fade).
//! * [`contact_model`]: [`contact_model::ContactModel`], the master's local model of the
//!   slave's contact (model-mediated rendering).
//! * [`link_stats`]: the link as the operator sees it in `h4-master run` (feedback loss,
//!   link state).
//! * [`teleop`]: [`teleop::MasterTeleop`], the master's per-cycle endpoint (device,
//!   operator, receive gate, coupling, round trip), stepped by the simulation and the
//!   process alike.
//! * passivity: `h4_shared::passivity` (both sides use it).
//! * [`session`]: the lockstep whole-session simulation, its summary and stability detector.
//! * [`plausible`]: settings the coupling cannot render stably (`scale.force` against the
//!   force limit and the master's passive stiffness), refused before a run.
//! * [`matrix`]: the delay matrix, sessions over wall × round trip × jitter × loss × force
//!   scale, and its verdicts (`h4-master matrix`, `tests/delay_matrix.rs`).

pub mod contact_model;
pub mod coupling;
pub mod device;
pub mod link_stats;
pub mod matrix;
pub mod operator;
pub mod plausible;
pub mod server;
pub mod session;
pub mod teleop;
