//! The core of h4-teleop, with no I/O stack: H-4 family kinematics and compliance, the
//! master ↔ slave wire types and their checked byte encoding, time-domain passivity, clocks,
//! a deterministic random source and the TOML configuration helpers. Recording, the live
//! view, progress and the real-time process plumbing are in `h4-telemetry`, beside it.
#![deny(unsafe_code)]

pub mod alloc_count;
pub mod clock;
pub mod config;
pub mod kinematics;
pub mod passivity;
pub mod paths;
pub mod rng;
pub mod vec3;
pub mod watchdog;
pub mod wire;

pub use kinematics::{
    ActuatorStiffness, Actuators, H4Params, KinError, Pose, Workspace, WorkspaceLimits, Wrench,
};
