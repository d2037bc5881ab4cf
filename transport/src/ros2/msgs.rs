//! The ROS 2 messages h4-teleop speaks, with their CDR encoding and decoding.
//!
//! Field names and order are the `.msg` files' (the wire is positional, so the order is the
//! format). Values are in ROS units (REP 103: m, rad, s, N, N·m); [`super::units`] converts from
//! and to the project's mm, N·mm. Decoding accepts any float bit pattern, as ROS does; call
//! [`Ros2Message::finite`] (or decode with [`Ros2Message::decode_finite`]) where a NaN or an
//! infinity must not get further, e.g. a pose or wrench that will drive an arm.

use super::cdr::{CdrError, CdrReader, CdrWriter};
use super::keys::{self, KeyError};
use super::type_hash::{self, TypeDescription, TypeHash, TypeHashError};

/// A value that is NaN or infinite, found by [`Ros2Message::finite`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{field} is not finite")]
pub struct NonFinite {
    /// Path of the value in the message, e.g. `pose.position.x` or `axes[2]`.
    pub field: String,
}

impl NonFinite {
    fn within(self, parent: &str) -> Self {
        NonFinite {
            field: format!("{parent}.{}", self.field),
        }
    }
}

fn finite_f64(field: &str, value: f64) -> Result<(), NonFinite> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(NonFinite {
            field: field.to_owned(),
        })
    }
}

/// Why a payload was refused by [`Ros2Message::decode_finite`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Not a valid CDR encoding of the type.
    #[error(transparent)]
    Cdr(#[from] CdrError),
    /// Valid, but a value is NaN or infinite.
    #[error(transparent)]
    NonFinite(#[from] NonFinite),
}

/// A ROS 2 message type: its name, CDR encoding and type hash.
pub trait Ros2Message: Sized {
    /// The ROS type name, `pkg/msg/Name`.
    const TYPE_NAME: &'static str;

    /// Writes the fields (no encapsulation header: [`Ros2Message::encode`] adds it).
    fn write_cdr(&self, w: &mut CdrWriter);

    /// Reads the fields (the header has been checked by the reader's constructor).
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError>;

    /// `Ok` if every floating-point value is finite; otherwise the first that is not.
    fn finite(&self) -> Result<(), NonFinite> {
        Ok(())
    }

    /// The complete payload: header and body.
    fn encode(&self) -> Result<Vec<u8>, CdrError> {
        self.encode_reusing(Vec::new())
    }

    /// Like [`Ros2Message::encode`], reusing `buf`'s allocation.
    fn encode_reusing(&self, buf: Vec<u8>) -> Result<Vec<u8>, CdrError> {
        let mut w = CdrWriter::reusing(buf);
        self.write_cdr(&mut w);
        w.finish()
    }

    /// Decodes a complete payload; bytes left over (beyond padding) are an error.
    fn decode(payload: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(payload)?;
        let msg = Self::read_cdr(&mut r)?;
        r.finish()?;
        Ok(msg)
    }

    /// [`Ros2Message::decode`], then [`Ros2Message::finite`].
    fn decode_finite(payload: &[u8]) -> Result<Self, DecodeError> {
        let msg = Self::decode(payload)?;
        msg.finite()?;
        Ok(msg)
    }

    /// The type's full description (REP 2011).
    fn type_description() -> Result<TypeDescription, TypeHashError> {
        type_hash::describe(Self::TYPE_NAME)
    }

    /// The type's RIHS01 hash.
    fn type_hash() -> Result<TypeHash, TypeHashError> {
        type_hash::rihs01(Self::TYPE_NAME)
    }

    /// The DDS type name, e.g. `geometry_msgs::msg::dds_::PoseStamped_`.
    fn dds_type_name() -> Result<String, KeyError> {
        keys::dds_type_name(Self::TYPE_NAME)
    }
}

/// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the epoch of the clock.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Time {
    /// Whole seconds, s.
    pub sec: i32,
    /// Nanoseconds within the second (0 to 999 999 999 for a normalised time), ns.
    pub nanosec: u32,
}

impl Time {
    const NS_PER_S: i64 = 1_000_000_000;

    /// The time `stamp_ns` nanoseconds after the epoch (normalised: `nanosec` < 10⁹, negative
    /// times count seconds down); `None` if the seconds do not fit an `i32` (after 2038).
    pub fn from_ns(stamp_ns: i64) -> Option<Time> {
        let sec = i32::try_from(stamp_ns.div_euclid(Self::NS_PER_S)).ok()?;
        let nanosec = u32::try_from(stamp_ns.rem_euclid(Self::NS_PER_S)).ok()?;
        Some(Time { sec, nanosec })
    }

    /// Nanoseconds after the epoch (exact for any field values).
    pub fn to_ns(self) -> i64 {
        i64::from(self.sec) * Self::NS_PER_S + i64::from(self.nanosec)
    }
}

impl Ros2Message for Time {
    const TYPE_NAME: &'static str = "builtin_interfaces/msg/Time";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_i32(self.sec);
        w.write_u32(self.nanosec);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Time {
            sec: r.read_i32()?,
            nanosec: r.read_u32()?,
        })
    }
}

/// `std_msgs/msg/Header`: when and in which frame.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Header {
    /// Acquisition time.
    pub stamp: Time,
    /// Coordinate frame (tf2 frame id).
    pub frame_id: String,
}

impl Ros2Message for Header {
    const TYPE_NAME: &'static str = "std_msgs/msg/Header";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.stamp.write_cdr(w);
        w.write_string(&self.frame_id);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Header {
            stamp: Time::read_cdr(r)?,
            frame_id: r.read_string()?,
        })
    }
}

/// `std_msgs/msg/String` (for tests against rmw_zenoh's `chatter` examples).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StringMsg {
    /// The text.
    pub data: String,
}

impl Ros2Message for StringMsg {
    const TYPE_NAME: &'static str = "std_msgs/msg/String";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_string(&self.data);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(StringMsg {
            data: r.read_string()?,
        })
    }
}

/// `geometry_msgs/msg/Point`, m.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Point {
    /// m.
    pub x: f64,
    /// m.
    pub y: f64,
    /// m.
    pub z: f64,
}

impl Ros2Message for Point {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Point";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_f64(self.x);
        w.write_f64(self.y);
        w.write_f64(self.z);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Point {
            x: r.read_f64()?,
            y: r.read_f64()?,
            z: r.read_f64()?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        finite_f64("x", self.x)?;
        finite_f64("y", self.y)?;
        finite_f64("z", self.z)
    }
}

/// `geometry_msgs/msg/Quaternion` (x, y, z, w); the default is the identity, as in the `.msg`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quaternion {
    /// Vector part, x.
    pub x: f64,
    /// Vector part, y.
    pub y: f64,
    /// Vector part, z.
    pub z: f64,
    /// Scalar part.
    pub w: f64,
}

impl Quaternion {
    /// No rotation.
    pub const IDENTITY: Quaternion = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    };
}

impl Default for Quaternion {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Ros2Message for Quaternion {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Quaternion";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_f64(self.x);
        w.write_f64(self.y);
        w.write_f64(self.z);
        w.write_f64(self.w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Quaternion {
            x: r.read_f64()?,
            y: r.read_f64()?,
            z: r.read_f64()?,
            w: r.read_f64()?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        finite_f64("x", self.x)?;
        finite_f64("y", self.y)?;
        finite_f64("z", self.z)?;
        finite_f64("w", self.w)
    }
}

/// `geometry_msgs/msg/Pose`: position (m) and orientation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    /// m.
    pub position: Point,
    /// Unit quaternion.
    pub orientation: Quaternion,
}

impl Ros2Message for Pose {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Pose";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.position.write_cdr(w);
        self.orientation.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Pose {
            position: Point::read_cdr(r)?,
            orientation: Quaternion::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.position.finite().map_err(|e| e.within("position"))?;
        self.orientation
            .finite()
            .map_err(|e| e.within("orientation"))
    }
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseStamped {
    /// Time and frame.
    pub header: Header,
    /// The pose.
    pub pose: Pose,
}

impl Ros2Message for PoseStamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/PoseStamped";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.header.write_cdr(w);
        self.pose.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(PoseStamped {
            header: Header::read_cdr(r)?,
            pose: Pose::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.pose.finite().map_err(|e| e.within("pose"))
    }
}

/// `geometry_msgs/msg/Vector3` (its unit is the user's: m/s, rad/s, N, N·m, ...).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vector3 {
    /// x component.
    pub x: f64,
    /// y component.
    pub y: f64,
    /// z component.
    pub z: f64,
}

impl Ros2Message for Vector3 {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Vector3";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_f64(self.x);
        w.write_f64(self.y);
        w.write_f64(self.z);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Vector3 {
            x: r.read_f64()?,
            y: r.read_f64()?,
            z: r.read_f64()?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        finite_f64("x", self.x)?;
        finite_f64("y", self.y)?;
        finite_f64("z", self.z)
    }
}

/// `geometry_msgs/msg/Twist`: linear (m/s) and angular (rad/s) velocity.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Twist {
    /// m/s.
    pub linear: Vector3,
    /// rad/s.
    pub angular: Vector3,
}

impl Ros2Message for Twist {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Twist";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.linear.write_cdr(w);
        self.angular.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Twist {
            linear: Vector3::read_cdr(r)?,
            angular: Vector3::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.linear.finite().map_err(|e| e.within("linear"))?;
        self.angular.finite().map_err(|e| e.within("angular"))
    }
}

/// `geometry_msgs/msg/TwistStamped`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TwistStamped {
    /// Time and frame.
    pub header: Header,
    /// The velocity.
    pub twist: Twist,
}

impl Ros2Message for TwistStamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/TwistStamped";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.header.write_cdr(w);
        self.twist.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(TwistStamped {
            header: Header::read_cdr(r)?,
            twist: Twist::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.twist.finite().map_err(|e| e.within("twist"))
    }
}

/// `geometry_msgs/msg/Wrench`: force (N) and torque (N·m).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Wrench {
    /// N.
    pub force: Vector3,
    /// N·m.
    pub torque: Vector3,
}

impl Ros2Message for Wrench {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/Wrench";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.force.write_cdr(w);
        self.torque.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Wrench {
            force: Vector3::read_cdr(r)?,
            torque: Vector3::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.force.finite().map_err(|e| e.within("force"))?;
        self.torque.finite().map_err(|e| e.within("torque"))
    }
}

/// `geometry_msgs/msg/WrenchStamped`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WrenchStamped {
    /// Time and frame.
    pub header: Header,
    /// The wrench.
    pub wrench: Wrench,
}

impl Ros2Message for WrenchStamped {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/WrenchStamped";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.header.write_cdr(w);
        self.wrench.write_cdr(w);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(WrenchStamped {
            header: Header::read_cdr(r)?,
            wrench: Wrench::read_cdr(r)?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        self.wrench.finite().map_err(|e| e.within("wrench"))
    }
}

/// `sensor_msgs/msg/Joy`: axes and buttons of a joystick or similar input device.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Joy {
    /// Time and frame.
    pub header: Header,
    /// Axis positions, usually −1 to 1.
    pub axes: Vec<f32>,
    /// Button states, usually 0 or 1.
    pub buttons: Vec<i32>,
}

impl Ros2Message for Joy {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/Joy";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.header.write_cdr(w);
        w.write_f32_sequence(&self.axes);
        w.write_i32_sequence(&self.buttons);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Joy {
            header: Header::read_cdr(r)?,
            axes: r.read_f32_sequence()?,
            buttons: r.read_i32_sequence()?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        match self.axes.iter().position(|a| !a.is_finite()) {
            Some(i) => Err(NonFinite {
                field: format!("axes[{i}]"),
            }),
            None => Ok(()),
        }
    }
}

/// `std_msgs/msg/MultiArrayDimension`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MultiArrayDimension {
    /// Name of the dimension.
    pub label: String,
    /// Number of elements along it.
    pub size: u32,
    /// Elements spanned by one step along it (including the dimensions after it).
    pub stride: u32,
}

impl Ros2Message for MultiArrayDimension {
    const TYPE_NAME: &'static str = "std_msgs/msg/MultiArrayDimension";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_string(&self.label);
        w.write_u32(self.size);
        w.write_u32(self.stride);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(MultiArrayDimension {
            label: r.read_string()?,
            size: r.read_u32()?,
            stride: r.read_u32()?,
        })
    }
}

/// Smallest encoding of one [`MultiArrayDimension`]: label length and NUL, size, stride.
const MULTI_ARRAY_DIMENSION_MIN_BYTES: usize = 4 + 1 + 4 + 4;

/// `std_msgs/msg/MultiArrayLayout`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MultiArrayLayout {
    /// The dimensions, outermost first.
    pub dim: Vec<MultiArrayDimension>,
    /// Elements before the first one in `data`.
    pub data_offset: u32,
}

impl Ros2Message for MultiArrayLayout {
    const TYPE_NAME: &'static str = "std_msgs/msg/MultiArrayLayout";
    fn write_cdr(&self, w: &mut CdrWriter) {
        w.write_sequence_len(self.dim.len());
        for d in &self.dim {
            d.write_cdr(w);
        }
        w.write_u32(self.data_offset);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        let n = r.read_sequence_len(MULTI_ARRAY_DIMENSION_MIN_BYTES)?;
        let mut dim = Vec::with_capacity(n);
        for _ in 0..n {
            dim.push(MultiArrayDimension::read_cdr(r)?);
        }
        Ok(MultiArrayLayout {
            dim,
            data_offset: r.read_u32()?,
        })
    }
}

/// `std_msgs/msg/Float64MultiArray`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Float64MultiArray {
    /// How `data` is laid out.
    pub layout: MultiArrayLayout,
    /// The values.
    pub data: Vec<f64>,
}

impl Ros2Message for Float64MultiArray {
    const TYPE_NAME: &'static str = "std_msgs/msg/Float64MultiArray";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.layout.write_cdr(w);
        w.write_f64_sequence(&self.data);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Float64MultiArray {
            layout: MultiArrayLayout::read_cdr(r)?,
            data: r.read_f64_sequence()?,
        })
    }
    fn finite(&self) -> Result<(), NonFinite> {
        match self.data.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(NonFinite {
                field: format!("data[{i}]"),
            }),
            None => Ok(()),
        }
    }
}

/// `crtk_msgs/msg/OperatingState` (crtk_msgs 1.3.0): the CRTK operating state of a device.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OperatingState {
    /// Time and frame.
    pub header: Header,
    /// One of [`OperatingState::DISABLED`], [`OperatingState::ENABLED`],
    /// [`OperatingState::PAUSED`], [`OperatingState::FAULT`].
    pub state: String,
    /// The device knows where it is (homed).
    pub is_homed: bool,
    /// The device is carrying out a command (e.g. a trajectory or homing).
    pub is_busy: bool,
}

impl OperatingState {
    /// CRTK state: not powered or not accepting commands.
    pub const DISABLED: &'static str = "DISABLED";
    /// CRTK state: powered and accepting commands.
    pub const ENABLED: &'static str = "ENABLED";
    /// CRTK state: powered, commands suspended.
    pub const PAUSED: &'static str = "PAUSED";
    /// CRTK state: stopped by a fault.
    pub const FAULT: &'static str = "FAULT";
}

impl Ros2Message for OperatingState {
    const TYPE_NAME: &'static str = "crtk_msgs/msg/OperatingState";
    fn write_cdr(&self, w: &mut CdrWriter) {
        self.header.write_cdr(w);
        w.write_string(&self.state);
        w.write_bool(self.is_homed);
        w.write_bool(self.is_busy);
    }
    fn read_cdr(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(OperatingState {
            header: Header::read_cdr(r)?,
            state: r.read_string()?,
            is_homed: r.read_bool()?,
            is_busy: r.read_bool()?,
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn time_from_and_to_ns() {
        let t = Time::from_ns(1_700_000_000_123_456_789).unwrap();
        assert_eq!(
            t,
            Time {
                sec: 1_700_000_000,
                nanosec: 123_456_789
            }
        );
        assert_eq!(t.to_ns(), 1_700_000_000_123_456_789);
        assert_eq!(
            Time::from_ns(-1).unwrap(),
            Time {
                sec: -1,
                nanosec: 999_999_999
            }
        );
        assert_eq!(Time::from_ns(i64::MAX), None);
    }

    #[test]
    fn nan_poses_are_rejected_with_their_path() {
        let orientation = Quaternion {
            y: f64::NAN,
            ..Quaternion::IDENTITY
        };
        let m = PoseStamped {
            pose: Pose {
                orientation,
                ..Pose::default()
            },
            ..PoseStamped::default()
        };
        let bytes = m.encode().unwrap();
        assert!(PoseStamped::decode(&bytes).is_ok());
        assert_eq!(
            PoseStamped::decode_finite(&bytes),
            Err(DecodeError::NonFinite(NonFinite {
                field: "pose.orientation.y".into()
            }))
        );
    }

    #[test]
    fn every_float_is_checked() {
        let torque = Vector3 {
            z: f64::INFINITY,
            ..Vector3::default()
        };
        let w = WrenchStamped {
            wrench: Wrench {
                torque,
                ..Wrench::default()
            },
            ..WrenchStamped::default()
        };
        assert_eq!(w.finite().unwrap_err().field, "wrench.torque.z");
        let linear = Vector3 {
            x: f64::NEG_INFINITY,
            ..Vector3::default()
        };
        let t = TwistStamped {
            twist: Twist {
                linear,
                ..Twist::default()
            },
            ..TwistStamped::default()
        };
        assert_eq!(t.finite().unwrap_err().field, "twist.linear.x");
        let j = Joy {
            axes: vec![0.0, f32::NAN],
            ..Joy::default()
        };
        assert_eq!(j.finite().unwrap_err().field, "axes[1]");
        let a = Float64MultiArray {
            data: vec![f64::NAN],
            ..Float64MultiArray::default()
        };
        assert_eq!(a.finite().unwrap_err().field, "data[0]");
        assert!(PoseStamped::default().finite().is_ok());
    }

    #[test]
    fn truncated_messages_are_errors_not_panics() {
        let m = OperatingState {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "h4".into(),
            },
            state: OperatingState::ENABLED.into(),
            is_homed: true,
            is_busy: false,
        };
        let bytes = m.encode().unwrap();
        assert_eq!(OperatingState::decode(&bytes).unwrap(), m);
        for cut in 0..bytes.len() {
            assert!(OperatingState::decode(&bytes[..cut]).is_err(), "cut {cut}");
        }
    }

    #[test]
    fn a_huge_dimension_count_does_not_allocate() {
        let mut payload = super::super::cdr::CDR_LE_HEADER.to_vec();
        payload.extend_from_slice(&0x1000_0000u32.to_le_bytes());
        assert!(matches!(
            Float64MultiArray::decode(&payload),
            Err(CdrError::SequenceTooLong { .. })
        ));
    }
}
