//! The subcommands.

pub mod bench;
pub mod config_reference;
pub mod crtk;
pub mod loopback;
pub mod matrix;
pub mod plausible;
pub mod run;
pub mod sim;
pub mod standin;

/// The default session file of `run`, `loopback` and `matrix`, relative to the repository
/// (found by `h4_shared::paths::default_config`).
pub const SESSION: &str = "config/sessions/wall-push.toml";
