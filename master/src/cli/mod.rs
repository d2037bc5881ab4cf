//! The subcommands.

pub mod sim;
