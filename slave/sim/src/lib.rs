//! The h4-teleop slave's simulator, apart from the product (`h4-slave`): everything here
//! stands in for the world a real arm lives in, or studies a run after the fact.
//!
//! * [`plant`]: [`plant::SimArm`], the simulated prototype behind the
//!   [`h4_slave::arm::ArmDriver`] interface (20 kHz servos, finite stiffness, contact,
//!   force sensor, cutting stock, turntable).
//! * [`world`]: [`world::SlaveWorld`], the slave-side configuration sections (arm,
//!   surface, sensor, plant, controller) and the one place that builds the simulated arm
//!   and its controller from them.
//! * [`cut`]: the cut as the simulated arm knows it (the endpoint's cut evidence, `/slave/cut`).
//! * [`server`]: `h4-slave run --arm sim`: the product's server over the simulated arm, with
//!   its diagnostics (true force, the cut).
//! * [`replay`]: `h4-slave run --arm replay`: an arm driver playing a recorded arm back.
//! * [`experiment`]: autonomous force-tracking experiments on the simulated clock.
//! * [`identify`]: the tool's identification on the simulated arm.
//! * [`report`]: PNG figures, metrics and an HTML page from a recording.
//! * [`kin_tool`]: `h4-slave kin`, the kinematics as JSON lines.

pub mod cut;
pub mod experiment;
pub mod fault;
pub mod identify;
pub mod kin_tool;
pub mod plant;
pub mod replay;
pub mod report;
pub mod server;
pub mod world;
