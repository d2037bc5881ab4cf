//! The h4-teleop master, the product: the bilateral coupling with time-domain passivity
//! control over any haptic device.
//!
//! * [`device`]: [`device::HapticDevice`], what a device's driver implements (the simulated
//!   master arm and operator are in `h4-master-sim`; docs/drivers.md).
//! * [`coupling`]: [`coupling::MasterCoupling`], the master's pure 1 kHz step
//!   (position–force and force-guided coupling, scaling, clutch, workspace mapping,
//!   saturation, feedback-loss fade).
//! * [`crtk`]: [`crtk::CrtkDevice`], a haptic device reached over ROS 2 (`--device crtk`,
//!   docs/ros2.md), over the cells its subscriptions fill.
//! * [`contact_model`]: [`contact_model::ContactModel`], the master's local model of the
//!   slave's contact (model-mediated rendering).
//! * [`link_stats`]: the link as the operator sees it in `h4-master run` (feedback loss,
//!   link state).
//! * [`teleop`]: [`teleop::MasterTeleop`], the master's per-cycle endpoint (device, receive
//!   gate, coupling, round trip), stepped by the simulation and the process alike.
//! * [`server`]: the master as a real-time process on a link (`h4-master run`), generic over
//!   the device and the outputs.
//! * passivity: `h4_shared::passivity` (both sides use it).
//!
//! This crate builds without the simulator, the slave, plotters, mcap, foxglove or
//! indicatif (`tests/layout.rs`).

pub mod contact_model;
pub mod coupling;
pub mod crtk;
pub mod device;
pub mod link_stats;
pub mod ros2;
pub mod server;
pub mod teleop;
