//! The h4-teleop slave, the product: the H-4 arm's 1 kHz force loop on any arm driver.
//!
//! * [`arm`]: the driver boundary, the [`arm::ArmDriver`] interface a robot driver
//!   implements (the simulated arm and the replay driver are in `h4-slave-sim`;
//!   docs/drivers.md).
//! * [`crtk`]: [`crtk::CrtkArm`], an arm reached over ROS 2 (CRTK or cartesian_controllers
//!   topics; `h4-slave run --arm crtk`).
//! * [`controller`]: [`controller::SlaveController`], the pure 1 kHz step (position mode,
//!   implicit force control with online environment-stiffness estimation, safe stop).
//! * [`filter`]: the low-pass filters the controller (and the simulated sensor) use.
//! * [`round_trip`]: [`round_trip::RoundTripEstimator`], the slave's own round trip from
//!   the commands' echo of its feedback (protocol 3).
//! * [`safety`]: [`safety::SafetyMonitor`], the arm's ratings enforced between the
//!   controller and the driver every cycle.
//! * [`teleop`]: [`teleop::SlaveTeleop`], the slave's per-cycle teleoperation endpoint
//!   (gate, watchdog and safe stop, passivity port, controller, feedback).
//! * [`server`]: the slave as a real-time process on a link (`h4-slave run`), generic over
//!   the driver, its diagnostics and the outputs.
//!
//! This crate builds without the simulator, plotters, mcap, foxglove or indicatif
//! (`tests/layout.rs`).

pub mod arm;
pub mod controller;
pub mod crtk;
pub mod filter;
pub mod ros2;
pub mod round_trip;
pub mod safety;
pub mod server;
pub mod teleop;
