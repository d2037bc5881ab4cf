//! The subcommands of `h4-slave`, one module each.

pub mod crtk;
pub mod experiment;
pub mod identify;
pub mod kin;
pub mod run;
pub mod standin;
