//! `h4-master run --device crtk`: the master over a haptic device reached through ROS 2
//! (docs/ros2.md "A ROS 2 haptic device"). The flags, the device's node and the wait for the
//! device's first pose; the loop is the product's (`h4_master::server::run_then`).

use std::sync::Arc;
use std::time::{Duration, Instant};

use h4_master::crtk::{CrtkDevice, CrtkDeviceConfig, DeviceWorkspace};
use h4_master::server::{MasterRunOptions, MasterRunSummary};
use h4_master::teleop::MasterTeleop;
use h4_master_sim::server::RunOutputs;
use h4_master_sim::session::SessionConfig;
use h4_shared::wire::{Command, Feedback};
use h4_transport::Link;
use h4_transport::ros2::Ros2Names;
use h4_transport::ros2::device::{DeviceCells, DeviceProfile, DeviceTopics};
use h4_transport::ros2::device_io::{DeviceIo, DeviceIoConfig};
use h4_transport::ros2::node::Ros2Args;

/// The flags of a ROS 2 haptic device (`--device crtk`). The node's domain, endpoint and
/// key format are `--ros2-domain`, `--ros2-connect` and `--ros2-distro` (with or without
/// `--ros2`).
#[derive(Clone, Debug, clap::Args)]
pub struct CrtkDeviceArgs {
    /// The device's topics: `crtk` (`<ns>/measured_cp`, `measured_cv`, `clutch` in,
    /// `servo_cf` out) or `force-dimension` (forcedimension_ros2: `<ns>/ee_pose` in,
    /// `<ns>/fd_controller/commands` out).
    #[arg(long, value_enum, default_value_t = DeviceProfile::Crtk)]
    pub device_profile: DeviceProfile,
    /// The device's namespace (default: `/h4_device` for `crtk`, `/fd` for
    /// `force-dimension`).
    #[arg(long, value_name = "NS")]
    pub device_ns: Option<String>,
    /// A device with no fresh pose for this long is silent: the rendered force fades to
    /// zero until it answers again, ms.
    #[arg(long, default_value_t = 20.0, value_name = "MS")]
    pub device_timeout_ms: f64,
    /// How often the newest force command is published to the device, Hz (1 to 10000).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    pub device_rate_hz: f64,
    /// Centre of the mapped workspace in the device's frame, `X_MM,Y_MM,Z_MM,THETA_RAD`
    /// (default: the session's master home pose).
    #[arg(long, value_name = "X,Y,Z,THETA", value_parser = parse4)]
    pub device_workspace_centre: Option<Vec4>,
    /// Half extents of the mapped workspace, `X_MM,Y_MM,Z_MM,THETA_RAD`: poses outside the
    /// box are clamped onto it and counted.
    #[arg(long, value_name = "X,Y,Z,THETA", value_parser = parse4, default_value = "80,80,80,1")]
    pub device_workspace_half: Vec4,
    /// The handle's effective mass, kg (0: unknown; bounds the coupling's damping steps).
    #[arg(long, default_value_t = 0.0, value_name = "KG")]
    pub device_mass_kg: f64,
    /// Wait this long for the device's first pose before the loop starts, s.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    pub wait_for_device_s: f64,
}

/// Four numbers (`X,Y,Z,THETA`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vec4(pub [f64; 4]);

/// Parses `a,b,c,d` into four finite numbers.
pub fn parse4(s: &str) -> Result<Vec4, String> {
    let v: Result<Vec<f64>, _> = s.split(',').map(|p| p.trim().parse::<f64>()).collect();
    let v = v.map_err(|e| format!("{s:?}: {e}"))?;
    match <[f64; 4]>::try_from(v) {
        Ok(a) if a.iter().all(|x| x.is_finite()) => Ok(Vec4(a)),
        _ => Err(format!("{s:?}: four finite numbers X,Y,Z,THETA expected")),
    }
}

impl Default for CrtkDeviceArgs {
    /// The flags' defaults (from their clap declarations: one source).
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            args: CrtkDeviceArgs,
        }
        <Defaults as clap::Parser>::parse_from(["h4-master"]).args
    }
}

impl CrtkDeviceArgs {
    /// Checks the flags; the device's topics.
    pub fn topics(&self) -> Result<DeviceTopics, String> {
        if !(self.device_timeout_ms.is_finite()
            && (1.0..=10_000.0).contains(&self.device_timeout_ms))
        {
            return Err(format!(
                "--device-timeout-ms {} is out of range: allowed 1 to 10000 ms",
                self.device_timeout_ms
            ));
        }
        if !(self.device_rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.device_rate_hz)) {
            return Err(format!(
                "--device-rate-hz {} is out of range: allowed 1 to 10000 Hz",
                self.device_rate_hz
            ));
        }
        if !(self.device_mass_kg.is_finite() && (0.0..=100.0).contains(&self.device_mass_kg)) {
            return Err(format!(
                "--device-mass-kg {} is out of range: allowed 0 to 100 kg",
                self.device_mass_kg
            ));
        }
        DeviceTopics::new(self.device_profile, self.device_ns.as_deref())
            .map_err(|e| format!("--device-ns: {e}"))
    }

    /// The device's configuration for a session whose master arm's home pose is `home`.
    pub fn device_config(&self, home: [f64; 4]) -> CrtkDeviceConfig {
        CrtkDeviceConfig {
            timeout_ns: (self.device_timeout_ms * 1e6) as u64,
            workspace: DeviceWorkspace::around(
                self.device_workspace_centre.map_or(home, |c| c.0),
                self.device_workspace_half.0,
            ),
            mass_kg: self.device_mass_kg,
        }
    }
}

/// Waits for `cells`' first accepted pose (at most `wait_s`, or until a stop request).
fn wait_for_first_pose(cells: &DeviceCells, topic: &str, wait_s: f64) -> Result<(), String> {
    let start = Instant::now();
    while cells.pose_counts.accepted() == 0 {
        if h4_telemetry::process::stop_requested() {
            return Ok(());
        }
        if start.elapsed().as_secs_f64() > wait_s {
            let r = cells.rejected();
            return Err(format!(
                "no pose from the device on {topic} within {wait_s} s ({} samples refused: {r:?}): \
                 is it publishing, on the same domain and Zenoh endpoint (--ros2-connect)?",
                r.total()
            ));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

/// Runs the master on the ROS 2 device of `args` (see the module doc).
#[allow(clippy::too_many_arguments)]
pub fn run_then<L: Link<Command, Feedback>>(
    args: &CrtkDeviceArgs,
    ros2: &Ros2Args,
    label: &str,
    cfg: &SessionConfig,
    opts: &MasterRunOptions,
    out: &RunOutputs,
    link: L,
    at_loop_end: impl FnOnce(),
) -> Result<MasterRunSummary, String> {
    let topics = args.topics()?;
    let node = ros2.endpoint_node(
        ros2.ros2_ns
            .as_deref()
            .unwrap_or(Ros2Names::MASTER_NAMESPACE),
        "h4_master_device",
    )?;
    let cells = DeviceCells::shared();
    let io_cfg = DeviceIoConfig {
        node,
        topics: topics.clone(),
        owner_timeout_ns: (args.device_timeout_ms * 1e6) as u64,
        command_rate_hz: args.device_rate_hz,
        label: label.to_owned(),
        timeout_ms: args.device_timeout_ms,
    };
    let io =
        DeviceIo::open(&io_cfg, Arc::clone(&cells)).map_err(|e| format!("--device crtk: {e}"))?;
    wait_for_first_pose(&cells, &topics.pose, args.wait_for_device_s)?;
    let device = CrtkDevice::new(
        Arc::clone(&cells),
        args.device_config(cfg.master.home_pose),
        cfg.master.home_pose,
    );
    let mut side = MasterTeleop::new(&cfg.master_teleop(opts.arm_id), device);
    let sink = h4_master::ros2::Ros2Tee::new(
        h4_master_sim::server::outputs(out, opts).map_err(|e| e.to_string())?,
        out.ros2.clone(),
    );
    let summary = h4_master::server::run_then(&mut side, sink, opts, link, at_loop_end);
    let report = io.stop();
    let mut summary = summary.map_err(|e| e.to_string())?;
    let device = cells.report();
    summary.ros2_rejected = device.rejected;
    summary.ros2_device = Some(device);
    eprintln!(
        "{label}: ROS 2 device on {}: {} poses accepted, {} refused, silent {} times, {} poses clamped, {} commands sent ({} errors)",
        topics.namespace,
        device.poses_accepted,
        device.rejected.total(),
        device.silences,
        device.clamped_poses,
        report.commands,
        report.errors
    );
    Ok(summary)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn defaults_are_the_documented_ones() {
        let d = CrtkDeviceArgs::default();
        assert_eq!(d.device_profile, DeviceProfile::Crtk);
        assert_eq!(d.device_timeout_ms, 20.0);
        assert_eq!(d.device_workspace_half, Vec4([80.0, 80.0, 80.0, 1.0]));
        assert_eq!(d.topics().unwrap().pose, "/h4_device/measured_cp");
        let bad = CrtkDeviceArgs {
            device_timeout_ms: 0.0,
            ..d
        };
        assert!(bad.topics().is_err());
    }

    #[test]
    fn four_numbers_are_parsed_and_checked() {
        assert_eq!(parse4("1, 2,3,-0.5").unwrap(), Vec4([1.0, 2.0, 3.0, -0.5]));
        for bad in ["1,2,3", "1,2,3,4,5", "a,b,c,d", "1,2,3,NaN"] {
            assert!(parse4(bad).is_err(), "{bad}");
        }
    }
}
