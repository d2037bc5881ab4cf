//! A haptic device reached over ROS 2 (`h4-master run --device crtk`; issue 35): its topics
//! by profile, and what its subscriptions hand the 1 kHz loop. Pure: the Zenoh side is
//! `node::DeviceIo` (feature `zenoh`); the `HapticDevice` over these cells is
//! `h4_master::crtk::CrtkDevice`.
//!
//! Profiles ([`DeviceProfile`]):
//!
//! * `crtk` (CRTK names, sawForceDimensionSDK / sawSensablePhantom / dVRK style), under the
//!   device namespace (`--device-ns`, default `/h4_device`): `measured_cp`
//!   (geometry_msgs/PoseStamped) and `measured_cv` (TwistStamped) in, `clutch`
//!   (sensor_msgs/Joy, `buttons[0]` non-zero while held) in, `servo_cf` (WrenchStamped) out;
//! * `force-dimension` (forcedimension_ros2), under `--device-ns` (default `/fd`):
//!   `ee_pose` (PoseStamped) in, `fd_controller/commands` (std_msgs/Float64MultiArray,
//!   `data = [Fx, Fy, Fz]`, N) out; no twist and no clutch topic (the velocity is the poses'
//!   finite difference, the clutch is never held).
//!
//! Every value the loop gets is in project units (mm, rad, N, N·mm), converted here by
//! [`super::units`]; every subscription's rejected samples are counted by reason
//! ([`super::subscriber::RejectCounters`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

use super::keys::KeyError;
use super::msgs::{
    Float64MultiArray, Header, Joy, PoseStamped, Ros2Message, Time, TwistStamped, WrenchStamped,
};
use super::subscriber::{RejectCounters, Ros2Rejected};
use super::telemetry::LatestCell;
use super::{Ros2Names, units};

/// Which topics a ROS 2 haptic device speaks (`--device-profile`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DeviceProfile {
    /// CRTK: `measured_cp`, `measured_cv`, `clutch` (Joy) in; `servo_cf` out.
    #[default]
    Crtk,
    /// forcedimension_ros2: `ee_pose` in; `fd_controller/commands` (Float64MultiArray) out.
    ForceDimension,
}

impl DeviceProfile {
    /// The default device namespace of the profile.
    pub fn default_namespace(self) -> &'static str {
        match self {
            DeviceProfile::Crtk => "/h4_device",
            DeviceProfile::ForceDimension => "/fd",
        }
    }
}

/// How the force command is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandKind {
    /// geometry_msgs/WrenchStamped (N, N·m).
    WrenchStamped,
    /// std_msgs/Float64MultiArray, `data = [Fx, Fy, Fz]` (N).
    ForceArray,
}

impl CommandKind {
    /// The ROS type name.
    pub fn type_name(self) -> &'static str {
        match self {
            CommandKind::WrenchStamped => WrenchStamped::TYPE_NAME,
            CommandKind::ForceArray => Float64MultiArray::TYPE_NAME,
        }
    }
}

/// The fully qualified topic names of one device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceTopics {
    /// The device's namespace.
    pub namespace: String,
    /// The pose in (geometry_msgs/PoseStamped).
    pub pose: String,
    /// The velocity in (geometry_msgs/TwistStamped), if the profile has one.
    pub twist: Option<String>,
    /// The buttons in (sensor_msgs/Joy, `buttons[0]`: the clutch), if the profile has them.
    pub clutch: Option<String>,
    /// The force command out.
    pub command: String,
    /// Its type.
    pub command_kind: CommandKind,
}

impl DeviceTopics {
    /// The topics of `profile` under `namespace` (None: the profile's default).
    pub fn new(profile: DeviceProfile, namespace: Option<&str>) -> Result<Self, KeyError> {
        let names = Ros2Names::new(namespace.unwrap_or(profile.default_namespace()))?;
        let ns = names.namespace().to_owned();
        let t = |leaf: &str| {
            if ns == "/" {
                format!("/{leaf}")
            } else {
                format!("{ns}/{leaf}")
            }
        };
        Ok(match profile {
            DeviceProfile::Crtk => DeviceTopics {
                pose: t("measured_cp"),
                twist: Some(t("measured_cv")),
                clutch: Some(t("clutch")),
                command: t("servo_cf"),
                command_kind: CommandKind::WrenchStamped,
                namespace: ns,
            },
            DeviceProfile::ForceDimension => DeviceTopics {
                pose: t("ee_pose"),
                twist: None,
                clutch: None,
                command: t("fd_controller/commands"),
                command_kind: CommandKind::ForceArray,
                namespace: ns,
            },
        })
    }
}

/// A pose the device published, in project units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseReading {
    /// `[x_mm, y_mm, z_mm, theta_rad]`, the device's frame.
    pub pose_mm_rad: [f64; 4],
    /// The message's `header.stamp`, ns since the epoch.
    pub stamp_ns: i64,
}

/// A velocity the device published, in project units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TwistReading {
    /// `[mm/s ×3, rad/s]`, the device's frame.
    pub velocity_mm_rad_per_s: [f64; 4],
}

/// The device's buttons.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ButtonsReading {
    /// The clutch (`buttons[0]` non-zero).
    pub clutch: bool,
}

/// A force command for the device, written by the loop.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WrenchCommand {
    /// When the loop wrote it, ns since the epoch.
    pub stamp_unix_ns: u64,
    /// `[Fx_n, Fy_n, Fz_n, My_n_mm]`, the device's frame.
    pub wrench_n_nmm: [f64; 4],
}

impl PoseReading {
    /// From an accepted message.
    pub fn from_msg(m: &PoseStamped) -> Self {
        PoseReading {
            pose_mm_rad: units::pose_from_ros(&m.pose),
            stamp_ns: m.header.stamp.to_ns(),
        }
    }
}

impl TwistReading {
    /// From an accepted message.
    pub fn from_msg(m: &TwistStamped) -> Self {
        TwistReading {
            velocity_mm_rad_per_s: units::velocity_from_ros(&m.twist),
        }
    }
}

impl ButtonsReading {
    /// From an accepted message: no buttons, not held.
    pub fn from_msg(m: &Joy) -> Self {
        ButtonsReading {
            clutch: m.buttons.first().is_some_and(|&b| b != 0),
        }
    }
}

impl WrenchCommand {
    /// The command's payload, `kind`, with `frame_id`, reusing `buf`.
    pub fn encode(
        &self,
        kind: CommandKind,
        frame_id: &str,
        buf: Vec<u8>,
    ) -> Result<Vec<u8>, super::cdr::CdrError> {
        match kind {
            CommandKind::WrenchStamped => WrenchStamped {
                header: Header {
                    stamp: Time::from_ns(i64::try_from(self.stamp_unix_ns).unwrap_or(i64::MAX))
                        .unwrap_or_default(),
                    frame_id: frame_id.to_owned(),
                },
                wrench: units::wrench_to_ros(&self.wrench_n_nmm),
            }
            .encode_reusing(buf),
            CommandKind::ForceArray => Float64MultiArray {
                data: self.wrench_n_nmm[..3].to_vec(),
                ..Float64MultiArray::default()
            }
            .encode_reusing(buf),
        }
    }
}

/// The device's state as the loop sees it, for the thread that says so on stderr.
#[derive(Debug, Default)]
pub struct DeviceStatus {
    silent: AtomicBool,
    silences: AtomicU64,
    clamped: AtomicU64,
}

impl DeviceStatus {
    /// The loop found the device silent (true) or answering (false); counts each silence.
    pub fn set_silent(&self, silent: bool) {
        if silent && !self.silent.swap(true, Ordering::Relaxed) {
            self.silences.fetch_add(1, Ordering::Relaxed);
        } else if !silent {
            self.silent.store(false, Ordering::Relaxed);
        }
    }

    /// The device is silent now.
    pub fn silent(&self) -> bool {
        self.silent.load(Ordering::Relaxed)
    }

    /// Times the device fell silent.
    pub fn silences(&self) -> u64 {
        self.silences.load(Ordering::Relaxed)
    }

    /// Counts a pose clamped into the workspace.
    pub fn clamped(&self) {
        self.clamped.fetch_add(1, Ordering::Relaxed);
    }

    /// Poses clamped so far.
    pub fn clamped_poses(&self) -> u64 {
        self.clamped.load(Ordering::Relaxed)
    }
}

/// What the device's subscriptions and the loop share: one cell per input, the command
/// cell, the counters.
#[derive(Debug, Default)]
pub struct DeviceCells {
    /// Newest accepted pose.
    pub pose: LatestCell<PoseReading>,
    /// Newest accepted velocity.
    pub twist: LatestCell<TwistReading>,
    /// Newest accepted buttons.
    pub buttons: LatestCell<ButtonsReading>,
    /// Newest force command.
    pub command: LatestCell<WrenchCommand>,
    /// The pose subscription's counts.
    pub pose_counts: RejectCounters,
    /// The velocity subscription's counts.
    pub twist_counts: RejectCounters,
    /// The buttons subscription's counts.
    pub buttons_counts: RejectCounters,
    /// Silence and clamping, as the loop found them.
    pub status: DeviceStatus,
}

impl DeviceCells {
    /// Empty cells, shared.
    pub fn shared() -> Arc<Self> {
        Arc::new(DeviceCells::default())
    }

    /// The rejected samples of all the device's subscriptions.
    pub fn rejected(&self) -> Ros2Rejected {
        self.pose_counts
            .rejected()
            .plus(&self.twist_counts.rejected())
            .plus(&self.buttons_counts.rejected())
    }

    /// The device's figures for the summary.
    pub fn report(&self) -> DeviceReport {
        DeviceReport {
            poses_accepted: self.pose_counts.accepted(),
            twists_accepted: self.twist_counts.accepted(),
            buttons_accepted: self.buttons_counts.accepted(),
            rejected: self.rejected(),
            silences: self.status.silences(),
            clamped_poses: self.status.clamped_poses(),
        }
    }
}

/// A ROS 2 device's figures at the end of a run.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(default)]
pub struct DeviceReport {
    /// Poses accepted.
    pub poses_accepted: u64,
    /// Velocities accepted.
    pub twists_accepted: u64,
    /// Button messages accepted.
    pub buttons_accepted: u64,
    /// Samples rejected on the device's topics, by reason.
    pub rejected: Ros2Rejected,
    /// Times the device fell silent (no fresh pose within the timeout).
    pub silences: u64,
    /// Poses outside the workspace, clamped.
    pub clamped_poses: u64,
}

/// One cycle of a stand-in device (`h4-master ros2-standin`), as it publishes it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StandinSample {
    /// When the cycle ran, ns since the epoch.
    pub stamp_unix_ns: u64,
    /// Handle pose `[x_mm, y_mm, z_mm, theta_rad]`, the device's frame.
    pub pose_mm_rad: [f64; 4],
    /// Handle velocity `[mm/s ×3, rad/s]`.
    pub velocity_mm_rad_per_s: [f64; 4],
    /// The clutch is held.
    pub clutch: bool,
}

impl StandinSample {
    /// The messages' header: the cycle's stamp, `frame_id`.
    pub(super) fn header(&self, frame_id: &str) -> Header {
        Header {
            stamp: Time::from_ns(i64::try_from(self.stamp_unix_ns).unwrap_or(i64::MAX))
                .unwrap_or_default(),
            frame_id: frame_id.to_owned(),
        }
    }

    /// The pose message.
    pub fn pose_msg(&self, frame_id: &str) -> PoseStamped {
        PoseStamped {
            header: self.header(frame_id),
            pose: units::pose_to_ros(&self.pose_mm_rad),
        }
    }

    /// The velocity message.
    pub fn twist_msg(&self, frame_id: &str) -> TwistStamped {
        TwistStamped {
            header: self.header(frame_id),
            twist: units::velocity_to_ros(&self.velocity_mm_rad_per_s),
        }
    }

    /// The buttons message: one button, the clutch.
    pub fn joy_msg(&self, frame_id: &str) -> Joy {
        Joy {
            header: self.header(frame_id),
            axes: Vec::new(),
            buttons: vec![i32::from(self.clutch)],
        }
    }
}

/// A force command as a CRTK device reads it from `servo_cf` (N, N·m → N, N·mm).
pub fn command_from_wrench(m: &WrenchStamped) -> WrenchCommand {
    WrenchCommand {
        stamp_unix_ns: u64::try_from(m.header.stamp.to_ns()).unwrap_or(0),
        wrench_n_nmm: units::wrench_from_ros(&m.wrench),
    }
}

/// What a stand-in device's loop and its node share.
#[derive(Debug, Default)]
pub struct StandinCells {
    /// The newest cycle, for the publishing thread.
    pub state: LatestCell<StandinSample>,
    /// The newest accepted command.
    pub command: LatestCell<WrenchCommand>,
    /// The command subscription's counts.
    pub command_counts: RejectCounters,
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn topics_by_profile() {
        let c = DeviceTopics::new(DeviceProfile::Crtk, None).unwrap();
        assert_eq!(c.pose, "/h4_device/measured_cp");
        assert_eq!(c.twist.as_deref(), Some("/h4_device/measured_cv"));
        assert_eq!(c.clutch.as_deref(), Some("/h4_device/clutch"));
        assert_eq!(c.command, "/h4_device/servo_cf");
        let f = DeviceTopics::new(DeviceProfile::ForceDimension, None).unwrap();
        assert_eq!(f.pose, "/fd/ee_pose");
        assert_eq!(f.command, "/fd/fd_controller/commands");
        assert_eq!(f.command_kind.type_name(), "std_msgs/msg/Float64MultiArray");
        let m = DeviceTopics::new(DeviceProfile::Crtk, Some("MTMR")).unwrap();
        assert_eq!(m.pose, "/MTMR/measured_cp");
        assert!(DeviceTopics::new(DeviceProfile::Crtk, Some("/bad/")).is_err());
    }

    #[test]
    fn commands_encode_in_si() {
        let c = WrenchCommand {
            stamp_unix_ns: 1_500_000_000,
            wrench_n_nmm: [1.0, -2.0, 3.0, 500.0],
        };
        let w = WrenchStamped::decode(
            &c.encode(CommandKind::WrenchStamped, "dev_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert_eq!(w.header.stamp.sec, 1);
        assert_eq!(w.wrench.force.y, -2.0);
        assert!((w.wrench.torque.y - 0.5).abs() < 1e-12);
        let a =
            Float64MultiArray::decode(&c.encode(CommandKind::ForceArray, "", Vec::new()).unwrap())
                .unwrap();
        assert_eq!(a.data, vec![1.0, -2.0, 3.0]);
    }

    #[test]
    fn silences_are_counted_once_each() {
        let s = DeviceStatus::default();
        for silent in [false, true, true, false, true] {
            s.set_silent(silent);
        }
        assert!(s.silent());
        assert_eq!(s.silences(), 2);
    }

    #[test]
    fn the_clutch_is_the_first_button() {
        let joy = |b: Vec<i32>| Joy {
            buttons: b,
            ..Joy::default()
        };
        assert!(ButtonsReading::from_msg(&joy(vec![1, 0])).clutch);
        assert!(!ButtonsReading::from_msg(&joy(vec![0, 1])).clutch);
        assert!(!ButtonsReading::from_msg(&joy(vec![])).clutch);
    }
}
