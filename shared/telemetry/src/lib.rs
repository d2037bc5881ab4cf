//! The telemetry and process plumbing of h4-teleop, beside the core (`h4-shared`): MCAP
//! recording ([`recording`]), the Foxglove live view ([`live`]), progress on a terminal
//! ([`progress`]), the real-time loop ([`rt`]) and process plumbing: signals, stop requests,
//! exit codes ([`process`]). The core builds without any of these crates (mcap, foxglove,
//! indicatif, clap); the 1 kHz loops use [`rt`] only for pacing and statistics.
//!
//! Features (all on by default): `mcap` ([`recording`]), `live` ([`live`], needs `mcap`),
//! `bars` (progress bars drawn by indicatif; without it progress is plain lines). The
//! product crates (h4-slave, h4-master) use this crate with none of them: the real-time
//! servers hand their records to sinks the command-line crates build from [`recording`]
//! and [`live`].

#[cfg(feature = "live")]
pub mod live;
pub mod process;
pub mod progress;
#[cfg(feature = "mcap")]
pub mod recording;
pub mod rt;
pub mod sink;
