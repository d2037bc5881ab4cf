//! The h4-teleop slave: the H-4 arm's force loop, its simulated plant, and the tools of
//! the `h4-slave` command.
//!
//! * [`arm`]: the driver boundary, the [`arm::ArmDriver`] interface a real robot driver
//!   implements.
//! * [`plant`]: [`plant::SimArm`], the simulated prototype behind that interface (20 kHz
//!   servos, finite stiffness, contact, force sensor).
//! * [`controller`]: [`controller::SlaveController`], the pure 1 kHz step (position mode,
//!   implicit force control with online environment-stiffness estimation, safe stop).
//! * [`experiment`]: autonomous force-tracking experiments on the simulated clock.
//! * [`teleop`]: [`teleop::SlaveTeleop`], the slave's per-cycle teleoperation endpoint
//!   (gate, watchdog and safe stop, passivity port, controller, feedback).
//! * [`report`]: PNG figures, metrics and an HTML page from a recording.
//! * [`world`]: [`world::SlaveWorld`], the slave-side configuration sections (arm,
//!   surface, sensor, plant, controller) and the one place that builds the simulated arm
//!   and its controller from them.
//! * [`server`]: `h4-slave run`, the slave as a real-time process on a link.

pub mod arm;
pub mod controller;
pub mod experiment;
pub mod filter;
pub mod identify;
pub mod kin_tool;
pub mod plant;
pub mod report;
pub mod server;
pub mod teleop;
pub mod world;
