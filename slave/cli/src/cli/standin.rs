//! `h4-slave ros2-standin`: an arm that speaks only ROS 2. The simulated arm of a world file
//! (the plant `h4-slave run --arm sim` drives: `h4_slave_sim::server::sim_parts`) behind the
//! CRTK topics of an arm (the `crtk` profile of `h4-slave run --arm crtk`): it publishes
//! `measured_cp`, `measured_cv` and `measured_cf` under `--arm-ns` and follows the newest
//! `servo_cp` it accepts, so `h4-slave run --arm crtk` can be tested with every arm-side byte
//! in rmw_zenoh's format (docs/ros2.md).
//!
//! The loop runs at 1 kHz: the arm's encoders and force/torque sensor are read (the pose is
//! the forward kinematics of the encoders, as a real arm's `measured_cp`; the wrench is the
//! sensor's reading as `--arm sim` hands it to the controller) and the cycle goes to the
//! publishing thread; the newest accepted `servo_cp` goes through the inverse kinematics to
//! the actuators' set-points (a position-servoed arm holds its last set-point when no new
//! command comes); the plant's physics advances.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use h4_slave::arm::ArmDriver;
use h4_slave::crtk::{actuators_of, pose_of};
use h4_slave_sim::experiment::ExperimentConfig;
use h4_telemetry::rt::{LoopReport, RtLoop};
use h4_transport::ros2::arm::{ArmProfile, ArmStandinCells, ArmStandinSample, ArmTopics};
use h4_transport::ros2::arm_io::{ArmStandinIo, ArmStandinIoConfig};
use h4_transport::ros2::device::StandinSample;
use h4_transport::ros2::node::Ros2Args;
use h4_transport::ros2::subscriber::Ros2Rejected;
use h4_transport::ros2::telemetry::base_frame_id;
use serde::Serialize;

/// Run a stand-in arm that speaks only ROS 2 (CRTK topics): the simulated arm of a world
/// file.
#[derive(Clone, Debug, clap::Args)]
pub struct StandinArgs {
    /// The world file (as `h4-slave run --config`; default: config/slave/sim-resin.toml of
    /// the repository).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a field of the world file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// The arm's namespace (the one `h4-slave run --arm crtk` speaks to by default).
    #[arg(long, default_value = "/arm", value_name = "NS")]
    pub arm_ns: String,
    /// How often the newest cycle is published, Hz (1 to 10000).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    pub rate_hz: f64,
    /// A `servo_cp` older than this is not fresh (counted in `command_stale_cycles`; the
    /// arm holds its last set-point), and the topic's owner is released after this much
    /// silence, ms.
    #[arg(long, default_value_t = 20.0, value_name = "MS")]
    pub command_timeout_ms: f64,
    /// Run the loop under SCHED_FIFO at this priority where permitted (a refusal is one line
    /// on stderr; default: normal scheduling).
    #[arg(long, value_name = "PRIORITY")]
    pub fifo_priority: Option<i32>,
    /// Stop by itself after this many seconds of the loop (default: until SIGINT/SIGTERM).
    #[arg(long, value_parser = h4_telemetry::process::positive_seconds)]
    pub duration_s: Option<f64>,
    /// Write the summary as JSON here (it is also printed on stdout).
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Also listen for Zenoh peers on this endpoint (e.g. `tcp/127.0.0.1:7451`), so a
    /// slave can `--ros2-connect` to the stand-in without a router.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Option<String>,
    /// ROS 2: `--ros2-domain`, `--ros2-connect`, `--ros2-distro` (the others are not used).
    #[command(flatten)]
    pub ros2: Ros2Args,
}

/// What the stand-in reports when it stops.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StandinSummary {
    /// The loop (flattened).
    #[serde(flatten)]
    pub run: LoopReport,
    /// `servo_cp` messages accepted.
    pub commands_accepted: u64,
    /// `servo_cp` samples refused, by reason.
    pub ros2_rejected: Ros2Rejected,
    /// Accepted commands the inverse kinematics could not map (not followed).
    pub unreachable_commands: u64,
    /// Cycles without a fresh command (the arm held its last set-point).
    pub command_stale_cycles: u64,
    /// Largest true contact force of the simulated arm (the plant's, not the sensor's), N.
    pub max_true_force_n: f64,
    /// Largest force the sensor read (its force axes), N.
    pub max_measured_force_n: f64,
    /// The platform's pose in the last cycle `[x_mm, y_mm, z_mm, theta_rad]`.
    pub final_pose: [f64; 4],
    /// Cycles published (each on `measured_cp`, `measured_cv`, `measured_cf`).
    pub samples_published: u64,
    /// Messages Zenoh refused.
    pub publish_errors: u64,
}

const LABEL: &str = "h4-slave ros2-standin";

impl StandinArgs {
    /// Runs the stand-in; prints and writes the summary.
    pub fn run(self) -> Result<ExitCode, String> {
        h4_telemetry::process::install_stop_handlers()
            .map_err(|e| format!("signal handlers: {e}"))?;
        if !(self.rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.rate_hz)) {
            return Err(format!(
                "--rate-hz {} is out of range: allowed 1 to 10000 Hz",
                self.rate_hz
            ));
        }
        if !(self.command_timeout_ms.is_finite() && self.command_timeout_ms >= 1.0) {
            return Err(format!(
                "--command-timeout-ms {} is out of range: at least 1 ms",
                self.command_timeout_ms
            ));
        }
        let path = h4_shared::paths::default_config(
            self.config.as_deref(),
            "config/slave/sim-resin.toml",
            "--config",
        )?;
        let cfg: ExperimentConfig =
            h4_shared::config::load(&path, &self.set).map_err(|e| e.to_string())?;
        {
            use h4_shared::config::Validate;
            cfg.validate().map_err(|e| format!("configuration: {e}"))?;
        }
        let (mut arm, _) =
            h4_slave_sim::server::sim_parts(&cfg).map_err(|e| format!("the arm: {e}"))?;
        let params = cfg.arm.geometry.params();
        let topics = ArmTopics::new(ArmProfile::Crtk, Some(&self.arm_ns))
            .map_err(|e| format!("--arm-ns: {e}"))?;
        let mut node = self
            .ros2
            .endpoint_node(&topics.namespace, "h4_arm_standin")?;
        node.listen = self.listen.clone();
        let cells = Arc::new(ArmStandinCells::default());
        let timeout_ns = (self.command_timeout_ms * 1e6) as u64;
        let io_cfg = ArmStandinIoConfig {
            node,
            frame_id: base_frame_id(&topics.namespace),
            topics: topics.clone(),
            owner_timeout_ns: timeout_ns,
            rate_hz: self.rate_hz,
        };
        let io = ArmStandinIo::open(&io_cfg, Arc::clone(&cells)).map_err(|e| e.to_string())?;
        if let Some(p) = self.fifo_priority
            && let Err(e) = h4_telemetry::rt::set_fifo_priority(p)
        {
            eprintln!("{LABEL}: real time: --fifo-priority {p} refused ({e}); normal scheduling");
        }
        eprintln!(
            "{LABEL}: publishing on {} (domain {}), listening on {}, following servo_cp",
            topics.namespace,
            self.ros2.ros2_domain,
            self.listen
                .as_deref()
                .unwrap_or("a loopback ephemeral port")
        );
        let mut s = StandinSummary::default();
        let period_ns = 1_000_000u64;
        let dt_s = period_ns as f64 * 1e-9;
        let mut seen = 0;
        let mut command_ns: Option<u64> = None;
        let mut last_pose: Option<[f64; 4]> = None;
        let mut rt = RtLoop::new(period_ns, 200_000, self.duration_s);
        rt.run(|cx| {
            let now = cx.now_ns;
            // Simulated physics keeps real time through deadlines the loop missed.
            arm.advance(period_ns * cx.tick.missed);
            let r = arm.read();
            let pose = pose_of(&params, &r.actuators_mm)
                .or(last_pose)
                .unwrap_or_default();
            let velocity = last_pose.map_or([0.0; 4], |p| {
                std::array::from_fn(|i| (pose[i] - p[i]) / dt_s)
            });
            last_pose = Some(pose);
            cells.state.offer(ArmStandinSample {
                motion: StandinSample {
                    stamp_unix_ns: cx.unix_ns,
                    pose_mm_rad: pose,
                    velocity_mm_rad_per_s: velocity,
                    clutch: false,
                },
                wrench_n_nmm: r.wrench,
            });
            if let Some((v, c)) = cells.command.try_newer_than(seen) {
                seen = v;
                command_ns = Some(now);
                match actuators_of(&params, &c.pose_mm_rad) {
                    Some(l) => arm.command(&l),
                    None => s.unreachable_commands += 1,
                }
            }
            if command_ns.is_none_or(|t| now.saturating_sub(t) > timeout_ns) {
                s.command_stale_cycles += 1;
            }
            let f = arm.true_contact_wrench();
            s.max_true_force_n = s.max_true_force_n.max(f.fixed_rows::<3>(0).norm());
            s.max_measured_force_n = s
                .max_measured_force_n
                .max(h4_shared::vec3::norm3(&r.wrench));
            s.final_pose = pose;
            arm.advance(period_ns);
            Ok::<(), String>(())
        })?;
        s.run = rt.report();
        let report = io.stop();
        s.samples_published = report.samples;
        s.publish_errors = report.errors;
        s.commands_accepted = cells.command_counts.accepted();
        s.ros2_rejected = cells.command_counts.rejected();
        eprintln!(
            "{LABEL}: {} cycles on {} (domain {}, via {}), {} commands accepted, {} refused, {} samples published, max true force {:.2} N",
            s.run.cycles,
            topics.namespace,
            self.ros2.ros2_domain,
            self.ros2.ros2_connect,
            s.commands_accepted,
            s.ros2_rejected.total(),
            s.samples_published,
            s.max_true_force_n
        );
        h4_telemetry::process::emit_summary(&s, self.summary.as_deref())?;
        Ok(h4_telemetry::process::exit_after_run(
            self.duration_s.is_some(),
        ))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// The stand-in's default namespace and topics are the ones `--arm crtk` speaks to by
    /// default, so the two meet without flags.
    #[test]
    fn the_default_namespace_is_the_arms() {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: StandinArgs,
        }
        let args = <Cli as clap::Parser>::parse_from(["h4-slave"]).args;
        let ours = ArmTopics::new(ArmProfile::Crtk, Some(&args.arm_ns)).unwrap();
        let theirs = super::super::crtk::CrtkArmArgs::default().topics().unwrap();
        assert_eq!(ours, theirs);
        assert_eq!(ours.twist(), "/arm/measured_cv");
        assert_eq!(base_frame_id(&ours.namespace), "arm_base");
    }
}
