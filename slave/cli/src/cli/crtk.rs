//! `h4-slave run --arm crtk`: the slave over an arm reached through ROS 2 (docs/ros2.md "A
//! ROS 2 arm"). The flags, the arm's node and the wait for the arm's first pose and wrench;
//! the loop is the product's (`h4_slave::server::run`).

use std::sync::Arc;
use std::time::{Duration, Instant};

use h4_shared::wire::{Command, Feedback};
use h4_slave::crtk::{CrtkArm, CrtkArmConfig};
use h4_slave::server::{self, NoDiagnostics, RunOptions};
use h4_slave::teleop::SlaveTeleop;
use h4_slave_sim::experiment::ExperimentConfig;
use h4_slave_sim::server::{RunOutputs, SimRunSummary};
use h4_telemetry::sink::Outputs;
use h4_transport::Link;
use h4_transport::ros2::Ros2Names;
use h4_transport::ros2::arm::{ArmCells, ArmProfile, ArmTopics};
use h4_transport::ros2::arm_io::{ArmIo, ArmIoConfig};
use h4_transport::ros2::node::Ros2Args;
use h4_transport::ros2::telemetry::base_frame_id;

/// The flags of a ROS 2 arm (`--arm crtk`). The node's domain, endpoint and key format are
/// `--ros2-domain`, `--ros2-connect` and `--ros2-distro` (with or without `--ros2`).
#[derive(Clone, Debug, clap::Args)]
pub struct CrtkArmArgs {
    /// The arm's topics: `crtk` (`<ns>/measured_cp`, `measured_cf` in, `servo_cp` out) or
    /// `cartesian-controllers` (FZI cartesian_controllers: `<ns>/current_pose`,
    /// `<ns>/ft_sensor_wrench` in, `<ns>/target_frame` out).
    #[arg(long, value_enum, default_value_t = ArmProfile::Crtk)]
    pub arm_profile: ArmProfile,
    /// The arm's namespace (default: `/arm` for `crtk`, `/cartesian_compliance_controller`
    /// for `cartesian-controllers`).
    #[arg(long, value_name = "NS")]
    pub arm_ns: Option<String>,
    /// The commands' `header.frame_id` (default: the namespace's last name + `_base`,
    /// `/arm` → `arm_base`).
    #[arg(long, value_name = "FRAME")]
    pub arm_frame_id: Option<String>,
    /// An arm with no fresh pose or no fresh wrench for this long is stale: the slave
    /// safe-stops, as for any driver that stops answering, ms.
    #[arg(long, default_value_t = 20.0, value_name = "MS")]
    pub arm_timeout_ms: f64,
    /// How often the newest pose command is published to the arm, Hz (1 to 10000).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    pub arm_rate_hz: f64,
    /// Wait this long for the arm's first pose and wrench before the loop starts, s.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    pub wait_for_arm_s: f64,
}

impl Default for CrtkArmArgs {
    /// The flags' defaults (from their clap declarations: one source).
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Defaults {
            #[command(flatten)]
            args: CrtkArmArgs,
        }
        <Defaults as clap::Parser>::parse_from(["h4-slave"]).args
    }
}

impl CrtkArmArgs {
    /// Checks the flags; the arm's topics.
    pub fn topics(&self) -> Result<ArmTopics, String> {
        if !(self.arm_timeout_ms.is_finite() && (1.0..=10_000.0).contains(&self.arm_timeout_ms)) {
            return Err(format!(
                "--arm-timeout-ms {} is out of range: allowed 1 to 10000 ms",
                self.arm_timeout_ms
            ));
        }
        if !(self.arm_rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.arm_rate_hz)) {
            return Err(format!(
                "--arm-rate-hz {} is out of range: allowed 1 to 10000 Hz",
                self.arm_rate_hz
            ));
        }
        if !(self.wait_for_arm_s.is_finite() && (0.0..=3600.0).contains(&self.wait_for_arm_s)) {
            return Err(format!(
                "--wait-for-arm-s {} is out of range: allowed 0 to 3600 s",
                self.wait_for_arm_s
            ));
        }
        if let Some(f) = &self.arm_frame_id
            && (f.is_empty() || f.chars().any(|c| c.is_whitespace() || c.is_control()))
        {
            return Err(format!(
                "--arm-frame-id {f:?}: a frame name without spaces expected"
            ));
        }
        ArmTopics::new(self.arm_profile, self.arm_ns.as_deref())
            .map_err(|e| format!("--arm-ns: {e}"))
    }

    /// The commands' frame for `topics`.
    pub fn frame_id(&self, topics: &ArmTopics) -> String {
        self.arm_frame_id
            .clone()
            .unwrap_or_else(|| base_frame_id(&topics.namespace))
    }
}

/// Waits for `cells`' first accepted pose and wrench (at most `wait_s`, or until a stop
/// request).
fn wait_for_arm(cells: &ArmCells, topics: &ArmTopics, wait_s: f64) -> Result<(), String> {
    let start = Instant::now();
    while cells.pose_counts.accepted() == 0 || cells.wrench_counts.accepted() == 0 {
        if h4_telemetry::process::stop_requested() {
            return Ok(());
        }
        if start.elapsed().as_secs_f64() > wait_s {
            let r = cells.rejected();
            return Err(format!(
                "no pose on {} and wrench on {} from the arm within {wait_s} s ({} poses and {} \
                 wrenches accepted, {} samples refused: {r:?}): is it publishing, on the same \
                 domain and Zenoh endpoint (--ros2-connect)?",
                topics.pose,
                topics.wrench,
                cells.pose_counts.accepted(),
                cells.wrench_counts.accepted(),
                r.total()
            ));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(())
}

/// Runs the slave on the ROS 2 arm of `args`: the world file's controller (its arm
/// geometry, tool, limits) over [`CrtkArm`], no diagnostics (the true force is the measured
/// one's), the recording and live view as for the simulated arm.
pub fn run<L: Link<Feedback, Command>>(
    args: &CrtkArmArgs,
    ros2: &Ros2Args,
    label: &str,
    cfg: &ExperimentConfig,
    opts: &RunOptions,
    outputs: &RunOutputs,
    link: &mut L,
) -> Result<SimRunSummary, String> {
    use h4_shared::config::Validate;
    if outputs.out_dir.is_some() {
        return Err("--out: a ROS 2 arm's cut is not simulated".to_string());
    }
    cfg.validate().map_err(|e| format!("configuration: {e}"))?;
    let topics = args.topics()?;
    let (_, ctrl) = h4_slave_sim::server::sim_parts(cfg).map_err(|e| format!("controller: {e}"))?;
    let params = cfg.arm.geometry.params();
    let node = ros2.endpoint_node(
        ros2.ros2_ns
            .as_deref()
            .unwrap_or(Ros2Names::SLAVE_NAMESPACE),
        "h4_slave_arm",
    )?;
    let cells = ArmCells::shared();
    let io_cfg = ArmIoConfig {
        node,
        frame_id: args.frame_id(&topics),
        topics: topics.clone(),
        owner_timeout_ns: (args.arm_timeout_ms * 1e6) as u64,
        command_rate_hz: args.arm_rate_hz,
        label: label.to_owned(),
        timeout_ms: args.arm_timeout_ms,
    };
    let io = ArmIo::open(&io_cfg, Arc::clone(&cells)).map_err(|e| format!("--arm crtk: {e}"))?;
    wait_for_arm(&cells, &topics, args.wait_for_arm_s)?;
    // Until the loop's first read the actuators read those of the arm's first pose.
    let first = cells.pose.newer_than(0).map(|(_, p)| p.pose_mm_rad);
    let initial = first
        .and_then(|p| h4_slave::crtk::actuators_of(&params, &p))
        .ok_or_else(|| {
            format!(
                "--arm crtk: the arm's first pose on {} ({first:?} mm, rad) has no actuator \
                 positions in the world file's geometry (out of reach, or the other assembly \
                 mode): is the arm's base frame the H-4's?",
                topics.pose
            )
        })?;
    let arm = CrtkArm::new(
        Arc::clone(&cells),
        CrtkArmConfig {
            timeout_ns: (args.arm_timeout_ms * 1e6) as u64,
            params,
        },
        initial,
    );
    let period_ns = opts.period_ns.max(1);
    let mut teleop =
        SlaveTeleop::new(opts.teleop_params(), ctrl, arm, period_ns).map_err(|e| e.to_string())?;
    let sink = Outputs::<server::CycleRecord>::start_polled(
        outputs.record.as_deref(),
        outputs.foxglove_ws.as_deref(),
        "h4-slave",
        ("/slave/cycle", "h4.SlaveProcessCycle"),
        None,
        1e9 / period_ns as f64,
        outputs.ros2_polled().map_err(|e| e.to_string())?,
    )
    .map_err(|e| e.to_string())?;
    let sink = h4_slave::ros2::Ros2Tee::new(sink, outputs.ros2.clone());
    let slave = server::run(&mut teleop, &mut NoDiagnostics, sink, opts, link);
    let report = io.stop();
    let mut slave = slave.map_err(|e| e.to_string())?;
    let arm = cells.report(report.commands);
    slave.ros2_rejected = arm.rejected;
    slave.ros2_arm = Some(arm);
    eprintln!(
        "{label}: ROS 2 arm on {}: {} poses and {} wrenches accepted, {} refused, stale {} times, \
         {} poses unreachable, {} set-points refused, {} commands sent ({} errors)",
        topics.namespace,
        arm.poses_accepted,
        arm.wrenches_accepted,
        arm.rejected.total(),
        arm.stale_events,
        arm.unreachable_poses,
        arm.refused_commands,
        report.commands,
        report.errors
    );
    Ok(SimRunSummary {
        slave,
        cutting: None,
        fault_injection: None,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn defaults_are_the_documented_ones() {
        let d = CrtkArmArgs::default();
        assert_eq!(d.arm_profile, ArmProfile::Crtk);
        assert_eq!(d.arm_timeout_ms, 20.0);
        assert_eq!(d.wait_for_arm_s, 10.0);
        let t = d.topics().unwrap();
        assert_eq!(t.command, "/arm/servo_cp");
        assert_eq!(d.frame_id(&t), "arm_base");
        for bad in [
            CrtkArmArgs {
                arm_timeout_ms: 0.0,
                ..d.clone()
            },
            CrtkArmArgs {
                arm_rate_hz: f64::NAN,
                ..d.clone()
            },
            CrtkArmArgs {
                arm_frame_id: Some("a b".into()),
                ..d.clone()
            },
            CrtkArmArgs {
                arm_ns: Some("/bad/".into()),
                ..d.clone()
            },
        ] {
            assert!(bad.topics().is_err(), "{bad:?}");
        }
    }
}
