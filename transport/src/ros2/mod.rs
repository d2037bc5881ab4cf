//! ROS 2 over rmw_zenoh, without a ROS installation: the wire format and publishing (issue 35).
//!
//! A ROS 2 node using `rmw_zenoh_cpp` publishes each message as a Zenoh `put` of its CDR
//! encoding on a key expression made of the domain, topic, DDS type name and type hash, with a
//! 33-byte attachment (sequence number, timestamp, publisher GID); it announces itself and
//! its endpoints with liveliness tokens under `@ros2_lv`. This module has everything needed
//! to speak that format, as pure functions with no Zenoh session:
//!
//! * [`cdr`]: little-endian plain CDR writer and reader (the reader never panics);
//! * [`msgs`]: the messages (builtin_interfaces, std_msgs, geometry_msgs, sensor_msgs/Joy,
//!   crtk_msgs/OperatingState) and the [`msgs::Ros2Message`] trait: encode, decode, finiteness;
//! * [`type_hash`]: REP 2011 type descriptions and their RIHS01 hashes;
//! * [`keys`]: topic key expressions (Jazzy form with the hash, Humble form with
//!   `TypeHashNotSupported`), liveliness tokens, the QoS chunk and the attachment;
//! * [`units`]: mm/N·mm/θ-about-y ↔ m/N·m/quaternion (REP 103);
//! * [`Ros2Names`]: the CRTK topic names under a namespace.
//!
//! `transport/tests/ros2_*.rs` check it, against byte strings and hashes produced by rosbags
//! (`tests/data/make_ros2_vectors.py`) and the examples in rmw_zenoh's `docs/design.md`.
//! Publishing: [`telemetry`] (the samples the 1 kHz loop leaves in a [`telemetry::LatestCell`]
//! and their messages, pure) and `node` (feature `zenoh`: the node's session, tokens,
//! publishers and the decimating publishing thread, with the `--ros2` flags).

pub mod arm;
#[cfg(feature = "zenoh")]
pub mod arm_io;
pub mod cdr;
pub mod device;
#[cfg(feature = "zenoh")]
pub mod device_io;
pub mod keys;
pub mod msgs;
#[cfg(feature = "zenoh")]
pub mod node;
pub mod subscriber;
pub mod telemetry;
pub mod type_hash;
pub mod units;

use keys::KeyError;
use msgs::{OperatingState, PoseStamped, Ros2Message, TwistStamped, WrenchStamped};

/// The CRTK topics h4-teleop publishes or subscribes to (CRTK naming: `measured_*` what the
/// device measures, `setpoint_*` what its controller aims at, `servo_*` a stream of commands).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CrtkTopic {
    /// `measured_cp`: measured Cartesian pose, `geometry_msgs/PoseStamped`.
    MeasuredCp,
    /// `measured_cv`: measured Cartesian velocity, `geometry_msgs/TwistStamped`.
    MeasuredCv,
    /// `measured_cf`: measured Cartesian force (wrench), `geometry_msgs/WrenchStamped`.
    MeasuredCf,
    /// `setpoint_cf`: the wrench the controller aims at, `geometry_msgs/WrenchStamped`.
    SetpointCf,
    /// `operating_state`: `crtk_msgs/OperatingState`.
    OperatingState,
    /// `servo_cf`: the wrench to render, `geometry_msgs/WrenchStamped`.
    ServoCf,
}

impl CrtkTopic {
    /// The slave's (the arm's) topics.
    pub const SLAVE: [CrtkTopic; 5] = [
        CrtkTopic::MeasuredCp,
        CrtkTopic::MeasuredCv,
        CrtkTopic::MeasuredCf,
        CrtkTopic::SetpointCf,
        CrtkTopic::OperatingState,
    ];

    /// The master's (the haptic device's) topics.
    pub const MASTER: [CrtkTopic; 2] = [CrtkTopic::MeasuredCp, CrtkTopic::ServoCf];

    /// The last token of the topic name.
    pub fn leaf(self) -> &'static str {
        match self {
            CrtkTopic::MeasuredCp => "measured_cp",
            CrtkTopic::MeasuredCv => "measured_cv",
            CrtkTopic::MeasuredCf => "measured_cf",
            CrtkTopic::SetpointCf => "setpoint_cf",
            CrtkTopic::OperatingState => "operating_state",
            CrtkTopic::ServoCf => "servo_cf",
        }
    }

    /// The ROS type name of its messages.
    pub fn type_name(self) -> &'static str {
        match self {
            CrtkTopic::MeasuredCp => PoseStamped::TYPE_NAME,
            CrtkTopic::MeasuredCv => TwistStamped::TYPE_NAME,
            CrtkTopic::MeasuredCf | CrtkTopic::SetpointCf | CrtkTopic::ServoCf => {
                WrenchStamped::TYPE_NAME
            }
            CrtkTopic::OperatingState => OperatingState::TYPE_NAME,
        }
    }
}

/// CRTK topic names under one namespace: `<namespace>/<leaf>`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Ros2Names {
    namespace: String,
}

impl Ros2Names {
    /// The slave's default namespace.
    pub const SLAVE_NAMESPACE: &'static str = "/h4";
    /// The master's default namespace.
    pub const MASTER_NAMESPACE: &'static str = "/h4_master";

    /// Names under `namespace`: a fully qualified namespace such as `/h4` or `/lab/h4_2`
    /// (a missing leading `/` is added; `/` is the root namespace).
    pub fn new(namespace: &str) -> Result<Self, KeyError> {
        let namespace = if namespace.starts_with('/') {
            namespace.to_owned()
        } else {
            format!("/{namespace}")
        };
        keys::validate_fully_qualified_name(&namespace, true)?;
        Ok(Ros2Names { namespace })
    }

    /// The slave's names, under [`Ros2Names::SLAVE_NAMESPACE`].
    pub fn slave_default() -> Self {
        Ros2Names {
            namespace: Self::SLAVE_NAMESPACE.to_owned(),
        }
    }

    /// The master's names, under [`Ros2Names::MASTER_NAMESPACE`].
    pub fn master_default() -> Self {
        Ros2Names {
            namespace: Self::MASTER_NAMESPACE.to_owned(),
        }
    }

    /// The namespace.
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    /// The fully qualified name of `topic`, e.g. `/h4/measured_cp`.
    pub fn topic(&self, topic: CrtkTopic) -> String {
        if self.namespace == "/" {
            format!("/{}", topic.leaf())
        } else {
            format!("{}/{}", self.namespace, topic.leaf())
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn default_names() {
        let slave = Ros2Names::slave_default();
        let names: Vec<String> = CrtkTopic::SLAVE.iter().map(|&t| slave.topic(t)).collect();
        assert_eq!(
            names,
            [
                "/h4/measured_cp",
                "/h4/measured_cv",
                "/h4/measured_cf",
                "/h4/setpoint_cf",
                "/h4/operating_state",
            ]
        );
        let master = Ros2Names::master_default();
        assert_eq!(
            master.topic(CrtkTopic::MeasuredCp),
            "/h4_master/measured_cp"
        );
        assert_eq!(master.topic(CrtkTopic::ServoCf), "/h4_master/servo_cf");
        assert_eq!(Ros2Names::new(Ros2Names::SLAVE_NAMESPACE).unwrap(), slave);
    }

    #[test]
    fn namespaces_are_normalised_and_checked() {
        assert_eq!(Ros2Names::new("lab/h4_2").unwrap().namespace(), "/lab/h4_2");
        assert_eq!(
            Ros2Names::new("/").unwrap().topic(CrtkTopic::MeasuredCp),
            "/measured_cp"
        );
        for bad in ["/h4/", "/h 4", "/9h4", "//h4"] {
            assert!(Ros2Names::new(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn every_topic_type_has_a_description() {
        for t in CrtkTopic::SLAVE.iter().chain(CrtkTopic::MASTER.iter()) {
            assert!(type_hash::rihs01(t.type_name()).is_ok(), "{t:?}");
        }
    }
}
