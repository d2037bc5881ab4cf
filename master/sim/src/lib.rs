//! The h4-teleop master's simulator, apart from the product (`h4-master`).
//!
//! * [`arm`]: [`arm::SimMasterArm`], a simulated H-4 family master arm.
//! * [`operator`]: the simulated hand following a scripted intent, or replaying a trajectory.
//! * [`hand`]: [`hand::SimHandDevice`], the arm with the hand on it: the product's
//!   [`h4_master::device::HapticDevice`] for `h4-master sim` and `h4-master run --device sim`.
//! * [`server`]: `h4-master run --device sim`, the product's server over that device.
//! * [`session`]: the lockstep whole-session simulation, its summary and stability detector.
//! * [`plausible`]: settings the coupling cannot render stably (`scale.force` against the
//!   force limit and the master's passive stiffness), refused before a run.
//! * [`config_reference`]: `docs/configuration.md`, every configuration field with its unit,
//!   range, default and sentence, from the types' schemas and checks (`h4-master
//!   config-reference`).
//! * [`matrix`]: the delay matrix, sessions over wall × round trip × jitter × loss × force
//!   scale, and its verdicts (`h4-master matrix`, `tests/delay_matrix.rs`).

pub mod arm;
pub mod config_reference;
pub mod hand;
pub mod matrix;
pub mod operator;
pub mod plausible;
pub mod server;
pub mod session;
