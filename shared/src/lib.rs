//! Shared foundation of h4-teleop: H-4 family kinematics and compliance, the master ↔ slave
//! wire types and their checked byte encoding, clocks, a deterministic random source and
//! TOML configuration helpers.
#![deny(unsafe_code)]

pub mod alloc_count;
pub mod clock;
pub mod config;
pub mod kinematics;
pub mod live;
pub mod passivity;
pub mod paths;
pub mod process;
pub mod progress;
pub mod recording;
pub mod rng;
pub mod rt;
pub mod vec3;
pub mod wire;

pub use kinematics::{
    ActuatorStiffness, Actuators, H4Params, KinError, Pose, Workspace, WorkspaceLimits, Wrench,
};
