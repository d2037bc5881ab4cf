//! The subcommands.

pub mod loopback;
pub mod run;
pub mod sim;
