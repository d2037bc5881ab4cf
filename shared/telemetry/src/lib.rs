//! The telemetry and process plumbing of h4-teleop, beside the core (`h4-shared`): MCAP
//! recording ([`recording`]), the Foxglove live view ([`live`]), progress on a terminal
//! ([`progress`]), the real-time loop ([`rt`]) and process plumbing: signals, stop requests,
//! exit codes ([`process`]). The core builds without any of these crates (mcap, foxglove,
//! indicatif, clap); the 1 kHz loops use [`rt`] only for pacing and statistics.

pub mod live;
pub mod process;
pub mod progress;
pub mod recording;
pub mod rt;
