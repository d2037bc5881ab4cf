//! `h4-master run --device sim`: the product's real-time server
//! ([`h4_master::server::run_then`]) over the simulated device of a session file (the
//! simulated master arm with the scripted operator's hand on it, [`SimHandDevice`]), with
//! the recording and the live view.

use std::path::PathBuf;

use h4_master::server::{CycleRecord, MasterRunError, MasterRunOptions, MasterRunSummary};
use h4_master::teleop::MasterTeleop;
use h4_shared::wire::{Command, Feedback};
use h4_telemetry::sink::Outputs;
use h4_transport::Link;
use h4_transport::ros2::telemetry::MasterSample;

use crate::hand::SimHandDevice;
use crate::session::SessionConfig;

/// Where a run's outputs go.
#[derive(Clone, Debug, Default)]
pub struct RunOutputs {
    /// Write an MCAP recording here (`--record`).
    pub record: Option<PathBuf>,
    /// Serve the live view here (`--foxglove-ws HOST:PORT`).
    pub foxglove_ws: Option<String>,
    /// With `--ros2`: the cell the ROS 2 publishing thread reads (each cycle is written
    /// into it, `h4_master::ros2::Ros2Tee`).
    pub ros2: Option<std::sync::Arc<h4_transport::ros2::telemetry::LatestCell<MasterSample>>>,
    /// With `--record-ros2`: the CRTK topics the recording also holds, sampled from `ros2`
    /// (which must then be set; [`h4_slave_sim::server::ros2_polled`]).
    pub ros2_record: Option<h4_transport::ros2::telemetry::Ros2Recording>,
}

/// The master's endpoint of a session file, for `arm_id` (the master's sections only: no
/// simulated slave is built), over the session's simulated device.
pub fn master_teleop(
    cfg: &SessionConfig,
    arm_id: u16,
) -> Result<MasterTeleop<SimHandDevice>, MasterRunError> {
    let device = cfg
        .sim_device()
        .map_err(|e| MasterRunError::Device(e.to_string()))?;
    Ok(MasterTeleop::new(&cfg.master_teleop(arm_id), device))
}

/// The recording and live view of the master process (`/master/cycle`,
/// `h4.MasterProcessCycle`).
pub fn outputs(
    out: &RunOutputs,
    opts: &MasterRunOptions,
) -> Result<Outputs<CycleRecord>, MasterRunError> {
    let polled = h4_slave_sim::server::ros2_polled(out.ros2_record.as_ref(), out.ros2.as_ref())
        .map_err(|e| MasterRunError::Outputs(e.to_string()))?;
    Outputs::start_polled(
        out.record.as_deref(),
        out.foxglove_ws.as_deref(),
        "h4-master",
        ("/master/cycle", "h4.MasterProcessCycle"),
        None,
        1e9 / opts.period_ns.max(1) as f64,
        polled,
    )
    .map_err(|e| MasterRunError::Outputs(e.to_string()))
}

/// Runs the master on the session's simulated device until stopped (SIGINT/SIGTERM or the
/// duration), on `link`.
pub fn run<L: Link<Command, Feedback>>(
    cfg: &SessionConfig,
    opts: &MasterRunOptions,
    out: &RunOutputs,
    link: L,
) -> Result<MasterRunSummary, MasterRunError> {
    run_then(cfg, opts, out, link, || {})
}

/// [`run`], calling `at_loop_end` as soon as the loop has stopped (before the summary and
/// the recording are finished): `loopback` stops the slave there, before its watchdog
/// would notice the silence.
pub fn run_then<L: Link<Command, Feedback>>(
    cfg: &SessionConfig,
    opts: &MasterRunOptions,
    out: &RunOutputs,
    link: L,
    at_loop_end: impl FnOnce(),
) -> Result<MasterRunSummary, MasterRunError> {
    let mut side = master_teleop(cfg, opts.arm_id)?;
    let sink = h4_master::ros2::Ros2Tee::new(outputs(out, opts)?, out.ros2.clone());
    h4_master::server::run_then(&mut side, sink, opts, link, at_loop_end)
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_transport::inproc;

    fn wall_push() -> SessionConfig {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/sessions/wall-push.toml"
        );
        crate::session::load(std::path::Path::new(path), &[]).expect("wall-push loads")
    }

    /// The endpoint of a session file speaks for the process's arm.
    #[test]
    fn master_teleop_speaks_for_its_arm() {
        let cfg = wall_push();
        let mut side = master_teleop(&cfg, 3).expect("master endpoint");
        let (mut master_end, mut slave_end) = inproc::pair(16);
        side.step(&mut master_end, 1_000_000, 1e-3);
        let cmd = slave_end.recv_latest().expect("link").expect("a command");
        assert_eq!(cmd.arm_id, 3);
    }
}
