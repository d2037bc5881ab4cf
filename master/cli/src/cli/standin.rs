//! `h4-master ros2-standin`: a haptic device that speaks only ROS 2. The simulated master arm
//! with the scripted operator's hand of a session file (the device `h4-master run --device
//! sim` uses), behind the CRTK topics of a device: it publishes `measured_cp`, `measured_cv`
//! and `clutch` (sensor_msgs/Joy) under `--device-ns` and renders the newest `servo_cf` it
//! accepts, so `h4-master run --device crtk` can be tested with every device-side byte in
//! rmw_zenoh's format (docs/ros2.md).
//!
//! The loop runs at 1 kHz: take the newest accepted command (none fresh for
//! `--command-timeout-ms`: zero force, as a device's driver does), the hand acts, the arm
//! renders the command, its physics advances, the cycle goes to the publishing thread.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use h4_master::device::HapticDevice;
use h4_master_sim::session;
use h4_shared::vec3::norm3;
use h4_telemetry::rt::{LoopReport, RtLoop};
use h4_transport::ros2::device::{DeviceProfile, DeviceTopics, StandinCells, StandinSample};
use h4_transport::ros2::device_io::{StandinIo, StandinIoConfig, StandinIoReport};
use h4_transport::ros2::node::Ros2Args;
use h4_transport::ros2::subscriber::Ros2Rejected;
use serde::Serialize;

/// Run a stand-in haptic device that speaks only ROS 2 (CRTK topics): the simulated master
/// arm and scripted operator of a session file.
#[derive(Clone, Debug, clap::Args)]
pub struct StandinArgs {
    /// The session file: its master arm and operator script (default:
    /// config/sessions/wall-push.toml of the repository).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a field of the session file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// The device's namespace.
    #[arg(long, default_value = "/h4_device", value_name = "NS")]
    pub device_ns: String,
    /// How often the newest cycle is published, Hz (1 to 10000).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    pub rate_hz: f64,
    /// No fresh `servo_cf` for this long: the arm renders zero force, ms.
    #[arg(long, default_value_t = 20.0, value_name = "MS")]
    pub command_timeout_ms: f64,
    /// Wait this long for the first `servo_cf` before the operator's script starts (the
    /// home pose is published meanwhile), s (0: start at once).
    #[arg(long, default_value_t = 20.0, value_name = "S")]
    pub wait_for_master_s: f64,
    /// Stop publishing this many seconds into the loop (the device falls silent; for tests).
    #[arg(long, value_name = "S")]
    pub silent_from_s: Option<f64>,
    /// Stop by itself after this many seconds of the loop (default: until SIGINT/SIGTERM).
    #[arg(long, value_parser = h4_telemetry::process::positive_seconds)]
    pub duration_s: Option<f64>,
    /// Write the summary as JSON here (it is also printed on stdout).
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Also listen for Zenoh peers on this endpoint (e.g. `tcp/127.0.0.1:7450`), so a
    /// master can `--ros2-connect` to the stand-in without a router.
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
    /// Time spent waiting for the first `servo_cf`, s.
    pub waited_for_master_s: f64,
    /// `servo_cf` messages accepted.
    pub commands_accepted: u64,
    /// `servo_cf` samples refused, by reason.
    pub ros2_rejected: Ros2Rejected,
    /// Cycles without a fresh command (zero force rendered).
    pub command_stale_cycles: u64,
    /// Largest force the arm rendered (the commands, after its motor limits), N.
    pub max_rendered_force_n: f64,
    /// Largest force of the operator's hand on the handle, N.
    pub max_hand_force_n: f64,
    /// The handle's pose in the last cycle `[x_mm, y_mm, z_mm, theta_rad]`.
    pub final_pose: [f64; 4],
    /// Cycles published (each on `measured_cp`, `measured_cv`, `clutch`).
    pub samples_published: u64,
    /// Messages Zenoh refused.
    pub publish_errors: u64,
    /// Cycles not published because of `--silent-from-s`.
    pub silent_cycles: u64,
}

const LABEL: &str = "h4-master ros2-standin";

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
        let path =
            h4_shared::paths::default_config(self.config.as_deref(), super::SESSION, "--config")?;
        let cfg = session::load_with(&path, &self.set, false)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let mut device = cfg.sim_device().map_err(|e| e.to_string())?;
        let topics = DeviceTopics::new(DeviceProfile::Crtk, Some(&self.device_ns))
            .map_err(|e| format!("--device-ns: {e}"))?;
        let mut node = self
            .ros2
            .endpoint_node(topics.namespace.as_str(), "h4_standin")?;
        node.listen = self.listen.clone();
        let cells = Arc::new(StandinCells::default());
        let io_cfg = StandinIoConfig {
            node,
            topics: topics.clone(),
            owner_timeout_ns: (self.command_timeout_ms * 1e6) as u64,
            rate_hz: self.rate_hz,
        };
        let io = StandinIo::open(&io_cfg, Arc::clone(&cells)).map_err(|e| e.to_string())?;
        eprintln!(
            "{LABEL}: publishing on {} (domain {}), listening on {}, waiting for servo_cf",
            topics.namespace,
            self.ros2.ros2_domain,
            self.listen
                .as_deref()
                .unwrap_or("a loopback ephemeral port")
        );
        let mut s = StandinSummary {
            waited_for_master_s: wait_for_master(&mut device, &cells, self.wait_for_master_s)?,
            ..StandinSummary::default()
        };
        let period_ns = 1_000_000u64;
        let dt_s = period_ns as f64 * 1e-9;
        let timeout_ns = (self.command_timeout_ms * 1e6) as u64;
        let silent_from_ns = self.silent_from_s.map(|x| (x.max(0.0) * 1e9) as u64);
        let mut seen = 0;
        let mut wrench = [0.0; 4];
        let mut command_ns: Option<u64> = None;
        let mut rt = RtLoop::new(period_ns, 200_000, self.duration_s);
        rt.run(|cx| {
            let now = cx.now_ns;
            if let Some((v, c)) = cells.command.try_newer_than(seen) {
                seen = v;
                wrench = c.wrench_n_nmm;
                command_ns = Some(now);
            }
            if command_ns.is_none_or(|t| now.saturating_sub(t) > timeout_ns) {
                wrench = [0.0; 4];
                s.command_stale_cycles += 1;
            }
            device.stalled(now, period_ns, cx.tick.missed);
            device.begin_cycle(now, dt_s);
            let st = device.read();
            let rendered = device.write_wrench(&wrench);
            device.advance(period_ns);
            s.max_rendered_force_n = s.max_rendered_force_n.max(norm3(&rendered));
            if let Some(h) = device.hand_wrench() {
                s.max_hand_force_n = s.max_hand_force_n.max(norm3(&h));
            }
            s.final_pose = st.pose;
            if silent_from_ns.is_some_and(|t| now >= t) {
                s.silent_cycles += 1;
            } else {
                cells.state.offer(StandinSample {
                    stamp_unix_ns: cx.unix_ns,
                    pose_mm_rad: st.pose,
                    velocity_mm_rad_per_s: st.velocity,
                    clutch: st.clutch,
                });
            }
            Ok::<(), String>(())
        })?;
        s.run = rt.report();
        let report: StandinIoReport = io.stop();
        s.samples_published = report.samples;
        s.publish_errors = report.errors;
        s.commands_accepted = cells.command_counts.accepted();
        s.ros2_rejected = cells.command_counts.rejected();
        eprintln!(
            "{LABEL}: {} cycles on {} (domain {}, via {}), {} commands accepted, {} refused, {} samples published",
            s.run.cycles,
            topics.namespace,
            self.ros2.ros2_domain,
            self.ros2.ros2_connect,
            s.commands_accepted,
            s.ros2_rejected.total(),
            s.samples_published
        );
        h4_telemetry::process::emit_summary(&s, self.summary.as_deref())?;
        Ok(h4_telemetry::process::exit_after_run(
            self.duration_s.is_some(),
        ))
    }
}

/// Publishes the handle at rest until the first command arrives (at most `wait_s`; 0: not
/// at all); how long it waited, s.
fn wait_for_master(
    device: &mut h4_master_sim::hand::SimHandDevice,
    cells: &StandinCells,
    wait_s: f64,
) -> Result<f64, String> {
    let start = Instant::now();
    if wait_s <= 0.0 {
        return Ok(0.0);
    }
    let rest = device.read();
    while cells.command_counts.accepted() == 0 && !h4_telemetry::process::stop_requested() {
        if start.elapsed().as_secs_f64() > wait_s {
            return Err(format!(
                "no servo_cf from a master within {wait_s} s: is `h4-master run --device crtk` running on the same domain and Zenoh endpoint?"
            ));
        }
        cells.state.offer(StandinSample {
            stamp_unix_ns: unix_now_ns(),
            pose_mm_rad: rest.pose,
            velocity_mm_rad_per_s: [0.0; 4],
            clutch: false,
        });
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(start.elapsed().as_secs_f64())
}

fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// The stand-in's default namespace is the one `--device crtk` listens on by default, so
    /// the two meet without flags.
    #[test]
    fn the_default_namespace_is_the_devices() {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: StandinArgs,
        }
        let args = <Cli as clap::Parser>::parse_from(["h4-master"]).args;
        assert_eq!(args.device_ns, DeviceProfile::Crtk.default_namespace());
        assert_eq!(
            super::super::crtk::CrtkDeviceArgs::default()
                .topics()
                .unwrap()
                .command,
            DeviceTopics::new(DeviceProfile::Crtk, Some(&args.device_ns))
                .unwrap()
                .command
        );
    }
}
