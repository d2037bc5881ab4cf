//! An arm reached over ROS 2 (`h4-slave run --arm crtk`; issue 35): its topics by profile,
//! and what its subscriptions hand the 1 kHz loop. Pure: the Zenoh side is
//! `arm_io::ArmIo` (feature `zenoh`); the `ArmDriver` over these cells is
//! `h4_slave::crtk::CrtkArm`.
//!
//! Profiles ([`ArmProfile`]):
//!
//! * `crtk` (CRTK names, dVRK PSM / sawRobot style), under the arm namespace (`--arm-ns`,
//!   default `/arm`): `measured_cp` (geometry_msgs/PoseStamped, the platform's pose in the
//!   arm's base frame) and `measured_cf` (WrenchStamped, the force/torque sensor's wrench on
//!   the tool in the base frame) in, `servo_cp` (PoseStamped, the pose to go to) out;
//! * `cartesian-controllers` (FZI cartesian_controllers on ros2_control), under `--arm-ns`
//!   (default `/cartesian_compliance_controller`): `current_pose` (PoseStamped) and
//!   `ft_sensor_wrench` (WrenchStamped) in, `target_frame` (PoseStamped) out.
//!
//! Every value the loop gets is in project units (mm, rad, N, N·mm), converted here by
//! [`super::units`]; every subscription's rejected samples are counted by reason
//! ([`super::subscriber::RejectCounters`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

use super::device::StandinSample;
use super::keys::KeyError;
use super::msgs::{Header, PoseStamped, Ros2Message, Time, WrenchStamped};
use super::subscriber::{RejectCounters, Ros2Rejected};
use super::telemetry::LatestCell;
use super::{Ros2Names, units};

/// Which topics a ROS 2 arm speaks (`--arm-profile`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ArmProfile {
    /// CRTK: `measured_cp`, `measured_cf` in; `servo_cp` out.
    #[default]
    Crtk,
    /// FZI cartesian_controllers: `current_pose`, `ft_sensor_wrench` in; `target_frame` out.
    CartesianControllers,
}

impl ArmProfile {
    /// The default arm namespace of the profile.
    pub fn default_namespace(self) -> &'static str {
        match self {
            ArmProfile::Crtk => "/arm",
            ArmProfile::CartesianControllers => "/cartesian_compliance_controller",
        }
    }
}

/// The fully qualified topic names of one arm.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ArmTopics {
    /// The arm's namespace.
    pub namespace: String,
    /// The measured pose in (geometry_msgs/PoseStamped).
    pub pose: String,
    /// The measured wrench in (geometry_msgs/WrenchStamped).
    pub wrench: String,
    /// The pose command out (geometry_msgs/PoseStamped).
    pub command: String,
}

impl ArmTopics {
    /// The arm's measured velocity (geometry_msgs/TwistStamped), beside its pose:
    /// `<ns>/measured_cv` (a stand-in publishes it; the slave does not read it).
    pub fn twist(&self) -> String {
        match self.pose.rsplit_once('/') {
            Some((ns, _)) => format!("{ns}/measured_cv"),
            None => "measured_cv".to_owned(),
        }
    }

    /// The topics of `profile` under `namespace` (None: the profile's default).
    pub fn new(profile: ArmProfile, namespace: Option<&str>) -> Result<Self, KeyError> {
        let names = Ros2Names::new(namespace.unwrap_or(profile.default_namespace()))?;
        let ns = names.namespace().to_owned();
        let t = |leaf: &str| {
            if ns == "/" {
                format!("/{leaf}")
            } else {
                format!("{ns}/{leaf}")
            }
        };
        let (pose, wrench, command) = match profile {
            ArmProfile::Crtk => ("measured_cp", "measured_cf", "servo_cp"),
            ArmProfile::CartesianControllers => {
                ("current_pose", "ft_sensor_wrench", "target_frame")
            }
        };
        Ok(ArmTopics {
            pose: t(pose),
            wrench: t(wrench),
            command: t(command),
            namespace: ns,
        })
    }
}

/// A wrench the arm's sensor published, in project units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WrenchReading {
    /// `[Fx_n, Fy_n, Fz_n, My_n_mm]`, the arm's base frame.
    pub wrench_n_nmm: [f64; 4],
    /// The message's `header.stamp`, ns since the epoch.
    pub stamp_ns: i64,
}

impl WrenchReading {
    /// From an accepted message (N, N·m → N, N·mm).
    pub fn from_msg(m: &WrenchStamped) -> Self {
        WrenchReading {
            wrench_n_nmm: units::wrench_from_ros(&m.wrench),
            stamp_ns: m.header.stamp.to_ns(),
        }
    }
}

/// A pose command for the arm, written by the loop.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseCommand {
    /// The platform pose to go to, `[x_mm, y_mm, z_mm, theta_rad]`, the arm's base frame.
    pub pose_mm_rad: [f64; 4],
}

impl PoseCommand {
    /// The command as a message stamped `stamp_unix_ns`, with `frame_id` (mm → m, θ → a
    /// quaternion about y).
    pub fn msg(&self, stamp_unix_ns: u64, frame_id: &str) -> PoseStamped {
        PoseStamped {
            header: Header {
                stamp: Time::from_ns(i64::try_from(stamp_unix_ns).unwrap_or(i64::MAX))
                    .unwrap_or_default(),
                frame_id: frame_id.to_owned(),
            },
            pose: units::pose_to_ros(&self.pose_mm_rad),
        }
    }

    /// The command's payload, reusing `buf`.
    pub fn encode(
        &self,
        stamp_unix_ns: u64,
        frame_id: &str,
        buf: Vec<u8>,
    ) -> Result<Vec<u8>, super::cdr::CdrError> {
        self.msg(stamp_unix_ns, frame_id).encode_reusing(buf)
    }

    /// A command as an arm reads it from `servo_cp` (m → mm).
    pub fn from_msg(m: &PoseStamped) -> Self {
        PoseCommand {
            pose_mm_rad: units::pose_from_ros(&m.pose),
        }
    }
}

/// The arm's state as the loop sees it, for the thread that says so on stderr and for the
/// summary.
#[derive(Debug, Default)]
pub struct ArmStatus {
    stale: AtomicBool,
    stale_events: AtomicU64,
    unreachable: AtomicU64,
    refused_commands: AtomicU64,
}

impl ArmStatus {
    /// The loop found the arm stale (true) or answering (false); counts each time it goes
    /// stale.
    pub fn set_stale(&self, stale: bool) {
        if stale && !self.stale.swap(true, Ordering::Relaxed) {
            self.stale_events.fetch_add(1, Ordering::Relaxed);
        } else if !stale {
            self.stale.store(false, Ordering::Relaxed);
        }
    }

    /// The arm is stale now.
    pub fn stale(&self) -> bool {
        self.stale.load(Ordering::Relaxed)
    }

    /// Times the arm went stale.
    pub fn stale_events(&self) -> u64 {
        self.stale_events.load(Ordering::Relaxed)
    }

    /// Counts a measured pose the inverse kinematics could not map to actuator positions.
    pub fn unreachable(&self) {
        self.unreachable.fetch_add(1, Ordering::Relaxed);
    }

    /// Measured poses not mapped so far.
    pub fn unreachable_poses(&self) -> u64 {
        self.unreachable.load(Ordering::Relaxed)
    }

    /// Counts an actuator set-point not sent (non-finite, or no forward kinematics).
    pub fn refused_command(&self) {
        self.refused_commands.fetch_add(1, Ordering::Relaxed);
    }

    /// Set-points not sent so far.
    pub fn refused_commands(&self) -> u64 {
        self.refused_commands.load(Ordering::Relaxed)
    }
}

/// What the arm's subscriptions, its command thread and the loop share.
#[derive(Debug, Default)]
pub struct ArmCells {
    /// Newest accepted measured pose (mm, rad).
    pub pose: LatestCell<super::device::PoseReading>,
    /// Newest accepted measured wrench (N, N·mm).
    pub wrench: LatestCell<WrenchReading>,
    /// Newest pose command.
    pub command: LatestCell<PoseCommand>,
    /// The pose subscription's counts.
    pub pose_counts: RejectCounters,
    /// The wrench subscription's counts.
    pub wrench_counts: RejectCounters,
    /// Staleness, unreachable poses, refused set-points, as the loop found them.
    pub status: ArmStatus,
}

impl ArmCells {
    /// Empty cells, shared.
    pub fn shared() -> Arc<Self> {
        Arc::new(ArmCells::default())
    }

    /// The rejected samples of both the arm's subscriptions.
    pub fn rejected(&self) -> Ros2Rejected {
        self.pose_counts
            .rejected()
            .plus(&self.wrench_counts.rejected())
    }

    /// The arm's figures for the summary (`commands_sent`: the command thread's count).
    pub fn report(&self, commands_sent: u64) -> ArmReport {
        ArmReport {
            poses_accepted: self.pose_counts.accepted(),
            wrenches_accepted: self.wrench_counts.accepted(),
            rejected: self.rejected(),
            stale_events: self.status.stale_events(),
            unreachable_poses: self.status.unreachable_poses(),
            refused_commands: self.status.refused_commands(),
            commands_sent,
        }
    }
}

/// One cycle of a stand-in arm (`h4-slave ros2-standin`) for its publishing thread, in
/// project units: what the arm publishes on `measured_cp`, `measured_cv`, `measured_cf`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ArmStandinSample {
    /// The stamp, the platform's pose and velocity (the stand-in device's sample with the
    /// clutch never held).
    pub motion: StandinSample,
    /// The force/torque sensor's reading `[Fx_n, Fy_n, Fz_n, My_n_mm]`.
    pub wrench_n_nmm: [f64; 4],
}

impl ArmStandinSample {
    /// The `measured_cf` message.
    pub fn wrench_msg(&self, frame_id: &str) -> WrenchStamped {
        WrenchStamped {
            header: self.motion.header(frame_id),
            wrench: units::wrench_to_ros(&self.wrench_n_nmm),
        }
    }
}

/// What a stand-in arm's loop and its node share.
#[derive(Debug, Default)]
pub struct ArmStandinCells {
    /// The newest cycle, for the publishing thread.
    pub state: LatestCell<ArmStandinSample>,
    /// The newest accepted pose command (`servo_cp`).
    pub command: LatestCell<PoseCommand>,
    /// The command subscription's counts.
    pub command_counts: RejectCounters,
}

/// A ROS 2 arm's figures at the end of a run (`ros2_arm` in the slave's summary).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(default)]
pub struct ArmReport {
    /// Measured poses accepted.
    pub poses_accepted: u64,
    /// Measured wrenches accepted.
    pub wrenches_accepted: u64,
    /// Samples rejected on the arm's topics, by reason.
    pub rejected: Ros2Rejected,
    /// Times the arm went stale (no fresh pose or wrench within `--arm-timeout-ms`).
    pub stale_events: u64,
    /// Measured poses the inverse kinematics could not map (out of reach, wrong assembly
    /// mode): not used.
    pub unreachable_poses: u64,
    /// Actuator set-points not sent (non-finite, or no forward kinematics).
    pub refused_commands: u64,
    /// Pose commands published.
    pub commands_sent: u64,
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn topics_by_profile() {
        let c = ArmTopics::new(ArmProfile::Crtk, None).unwrap();
        assert_eq!(c.pose, "/arm/measured_cp");
        assert_eq!(c.wrench, "/arm/measured_cf");
        assert_eq!(c.command, "/arm/servo_cp");
        let f = ArmTopics::new(ArmProfile::CartesianControllers, None).unwrap();
        assert_eq!(f.pose, "/cartesian_compliance_controller/current_pose");
        assert_eq!(
            f.wrench,
            "/cartesian_compliance_controller/ft_sensor_wrench"
        );
        assert_eq!(f.command, "/cartesian_compliance_controller/target_frame");
        let p = ArmTopics::new(ArmProfile::Crtk, Some("PSM1")).unwrap();
        assert_eq!(p.command, "/PSM1/servo_cp");
        assert!(ArmTopics::new(ArmProfile::Crtk, Some("/bad/")).is_err());
    }

    /// The command goes out in metres with a quaternion about y; read back it is the same
    /// pose in mm (the round trip through CDR).
    #[test]
    fn commands_encode_in_si_and_round_trip() {
        let c = PoseCommand {
            pose_mm_rad: [12.5, -3.0, -245.0, 0.1],
        };
        let m =
            PoseStamped::decode(&c.encode(2_500_000_000, "arm_base", Vec::new()).unwrap()).unwrap();
        assert_eq!(m.header.frame_id, "arm_base");
        assert_eq!(
            (m.header.stamp.sec, m.header.stamp.nanosec),
            (2, 500_000_000)
        );
        assert!((m.pose.position.z + 0.245).abs() < 1e-15);
        assert!((m.pose.position.x - 0.0125).abs() < 1e-15);
        assert!((m.pose.orientation.y - 0.05f64.sin()).abs() < 1e-15);
        let back = PoseCommand::from_msg(&m).pose_mm_rad;
        for (a, b) in back.iter().zip(c.pose_mm_rad.iter()) {
            assert!((a - b).abs() < 1e-12, "{back:?}");
        }
    }

    #[test]
    fn wrenches_are_read_in_n_and_n_mm() {
        let mut m = WrenchStamped::default();
        m.wrench.force.z = 4.0;
        m.wrench.torque.y = 0.25;
        m.wrench.torque.x = 9.0;
        let r = WrenchReading::from_msg(&m);
        assert_eq!(r.wrench_n_nmm, [0.0, 0.0, 4.0, 250.0]);
    }

    /// The stand-in's `measured_cf` goes out in N and N·m, stamped and framed as its pose.
    #[test]
    fn a_standin_wrench_goes_out_in_si() {
        let s = ArmStandinSample {
            motion: StandinSample {
                stamp_unix_ns: 3_000_000_001,
                ..StandinSample::default()
            },
            wrench_n_nmm: [1.0, -2.0, 5.5, 250.0],
        };
        let m = WrenchStamped::decode(&s.wrench_msg("arm_base").encode().unwrap()).unwrap();
        assert_eq!(m.header.frame_id, "arm_base");
        assert_eq!((m.header.stamp.sec, m.header.stamp.nanosec), (3, 1));
        assert_eq!(m.wrench.force.z, 5.5);
        assert_eq!(m.wrench.torque.y, 0.25);
        assert_eq!(WrenchReading::from_msg(&m).wrench_n_nmm, s.wrench_n_nmm);
    }

    #[test]
    fn stale_events_are_counted_once_each() {
        let s = ArmStatus::default();
        for stale in [false, true, true, false, true, true] {
            s.set_stale(stale);
        }
        assert!(s.stale());
        assert_eq!(s.stale_events(), 2);
    }
}
