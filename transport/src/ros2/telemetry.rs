//! What the 1 kHz loop hands the ROS 2 publishing thread, and how each sample becomes the
//! CRTK messages (issue 35, publishing). Pure: no Zenoh session here ([`super::node`] has it).
//!
//! The loop writes its newest sample into a [`LatestCell`] every cycle; the publishing
//! thread wakes at its own rate (`--ros2-rate-hz`, default 100 Hz), takes the newest sample
//! if there is one it has not published, and publishes it on every topic. The loop never
//! waits: [`LatestCell::offer`] is a `try_lock`; in the rare cycle the thread holds the cell
//! (copying one `Copy` value out) the loop's write is skipped and counted
//! ([`LatestCell::skipped`]), and the next cycle's write lands. Nothing is allocated per
//! write; samples are plain `Copy` values in project units (mm, rad, N, N·mm), converted to
//! SI by [`super::units`] on the publishing thread.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::cdr::CdrError;
use super::msgs::{
    Header, OperatingState, PoseStamped, Ros2Message, Time, TwistStamped, WrenchStamped,
};
use super::type_hash::TypeHashError;
use super::units;
use super::{CrtkTopic, Ros2Names};

/// A single-slot cell holding the newest value a writer offered, for one reader that
/// samples it at its own rate. Writing never blocks and never allocates.
#[derive(Debug, Default)]
pub struct LatestCell<T: Copy> {
    slot: Mutex<Slot<T>>,
    skipped: AtomicU64,
}

#[derive(Debug, Default, Clone, Copy)]
struct Slot<T: Copy> {
    /// Writes that landed so far (0: none yet).
    version: u64,
    value: Option<T>,
}

impl<T: Copy> LatestCell<T> {
    /// An empty cell.
    pub fn new() -> Self {
        LatestCell {
            slot: Mutex::new(Slot {
                version: 0,
                value: None,
            }),
            skipped: AtomicU64::new(0),
        }
    }

    /// Replaces the value without waiting: when the reader holds the cell at this instant
    /// the write is skipped and counted. Returns whether it landed.
    pub fn offer(&self, value: T) -> bool {
        match self.slot.try_lock() {
            Ok(mut s) => {
                s.version += 1;
                s.value = Some(value);
                true
            }
            Err(std::sync::TryLockError::Poisoned(p)) => {
                let mut s = p.into_inner();
                s.version += 1;
                s.value = Some(value);
                true
            }
            Err(std::sync::TryLockError::WouldBlock) => {
                self.skipped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// The newest value and its version, if it is newer than `seen` (a version this
    /// reader took before; 0 at first).
    pub fn newer_than(&self, seen: u64) -> Option<(u64, T)> {
        let s = match self.slot.lock() {
            Ok(s) => *s,
            Err(p) => *p.into_inner(),
        };
        match s.value {
            Some(v) if s.version > seen => Some((s.version, v)),
            _ => None,
        }
    }

    /// Replaces the value, waiting for the cell if a reader holds it (for a writer off the
    /// 1 kHz path, e.g. a subscriber's callback; the loop reads with
    /// [`LatestCell::try_newer_than`], which never waits).
    pub fn put(&self, value: T) {
        let mut s = match self.slot.lock() {
            Ok(s) => s,
            Err(p) => p.into_inner(),
        };
        s.version += 1;
        s.value = Some(value);
    }

    /// [`LatestCell::newer_than`] without waiting, for the 1 kHz loop: None also when the
    /// writer holds the cell at this instant (counted in [`LatestCell::skipped`]); the value
    /// is there at the next cycle's read. No allocation.
    pub fn try_newer_than(&self, seen: u64) -> Option<(u64, T)> {
        let s = match self.slot.try_lock() {
            Ok(s) => *s,
            Err(std::sync::TryLockError::Poisoned(p)) => *p.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => {
                self.skipped.fetch_add(1, Ordering::Relaxed);
                return None;
            }
        };
        match s.value {
            Some(v) if s.version > seen => Some((s.version, v)),
            _ => None,
        }
    }

    /// Writes (or, for [`LatestCell::try_newer_than`], reads) skipped because the other
    /// side held the cell.
    pub fn skipped(&self) -> u64 {
        self.skipped.load(Ordering::Relaxed)
    }
}

/// A sample the publishing thread turns into one message per topic of its side.
pub trait TelemetrySample: Copy + Send + 'static {
    /// The topics a sample is published on, in order.
    const TOPICS: &'static [CrtkTopic];

    /// The CDR payload of `topic` (one of [`TelemetrySample::TOPICS`]) for this sample, with
    /// `frame_id` in its header, reusing `buf`'s allocation.
    fn encode(&self, topic: CrtkTopic, frame_id: &str, buf: Vec<u8>) -> Result<Vec<u8>, CdrError>;

    /// The sample's source time, ns since the UNIX epoch.
    fn stamp_unix_ns(&self) -> u64;
}

/// The slave's operating state as CRTK says it (`crtk_msgs/OperatingState.state`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CrtkState {
    /// `ENABLED`, not busy: powered, waiting for a master (the endpoint's `Idle`).
    #[default]
    Ready,
    /// `ENABLED`, busy: following a master (`Active`).
    Following,
    /// `PAUSED`: the safe stop (force ramped to zero, retract, hold) after a silent link or
    /// driver (`SafeStop`).
    Paused,
    /// `FAULT`: motion stopped until reset (`Fault`).
    Fault,
}

impl CrtkState {
    /// The `state` string.
    pub fn as_str(self) -> &'static str {
        match self {
            CrtkState::Ready | CrtkState::Following => "ENABLED",
            CrtkState::Paused => "PAUSED",
            CrtkState::Fault => "FAULT",
        }
    }
}

/// One cycle of the slave, as published on its CRTK topics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SlaveSample {
    /// When the cycle ran, ns since the UNIX epoch.
    pub stamp_unix_ns: u64,
    /// Measured tool pose `[x_mm, y_mm, z_mm, theta_rad]`, base frame (`measured_cp`).
    pub pose_mm_rad: [f64; 4],
    /// Measured tool velocity `[mm/s ×3, rad/s]`, base frame (`measured_cv`).
    pub velocity_mm_rad_per_s: [f64; 4],
    /// The force sensor's wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]`, base frame (`measured_cf`).
    pub wrench_sensor_n_nmm: [f64; 4],
    /// The force the controller aims at, `[Fx_n, Fy_n, Fz_n, My_n_mm]` (`setpoint_cf`).
    pub wrench_setpoint_n_nmm: [f64; 4],
    /// The endpoint's state (`operating_state`).
    pub state: CrtkState,
}

fn header(stamp_unix_ns: u64, frame_id: &str) -> Header {
    Header {
        stamp: Time::from_ns(i64::try_from(stamp_unix_ns).unwrap_or(i64::MAX)).unwrap_or_default(),
        frame_id: frame_id.to_owned(),
    }
}

fn wrench_msg(stamp_unix_ns: u64, frame_id: &str, w: &[f64; 4]) -> WrenchStamped {
    WrenchStamped {
        header: header(stamp_unix_ns, frame_id),
        wrench: units::wrench_to_ros(w),
    }
}

fn pose_msg(stamp_unix_ns: u64, frame_id: &str, p: &[f64; 4]) -> PoseStamped {
    PoseStamped {
        header: header(stamp_unix_ns, frame_id),
        pose: units::pose_to_ros(p),
    }
}

impl TelemetrySample for SlaveSample {
    const TOPICS: &'static [CrtkTopic] = &CrtkTopic::SLAVE;

    fn encode(&self, topic: CrtkTopic, frame_id: &str, buf: Vec<u8>) -> Result<Vec<u8>, CdrError> {
        let t = self.stamp_unix_ns;
        match topic {
            CrtkTopic::MeasuredCp => pose_msg(t, frame_id, &self.pose_mm_rad).encode_reusing(buf),
            CrtkTopic::MeasuredCv => TwistStamped {
                header: header(t, frame_id),
                twist: units::velocity_to_ros(&self.velocity_mm_rad_per_s),
            }
            .encode_reusing(buf),
            CrtkTopic::MeasuredCf => {
                wrench_msg(t, frame_id, &self.wrench_sensor_n_nmm).encode_reusing(buf)
            }
            CrtkTopic::SetpointCf | CrtkTopic::ServoCf => {
                wrench_msg(t, frame_id, &self.wrench_setpoint_n_nmm).encode_reusing(buf)
            }
            CrtkTopic::OperatingState => OperatingState {
                header: header(t, frame_id),
                state: self.state.as_str().to_owned(),
                is_homed: true,
                is_busy: self.state == CrtkState::Following,
            }
            .encode_reusing(buf),
        }
    }

    fn stamp_unix_ns(&self) -> u64 {
        self.stamp_unix_ns
    }
}

/// One cycle of the master (the haptic device), as published on its CRTK topics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MasterSample {
    /// When the cycle ran, ns since the UNIX epoch.
    pub stamp_unix_ns: u64,
    /// Handle pose `[x_mm, y_mm, z_mm, theta_rad]`, the device's base frame (`measured_cp`).
    pub pose_mm_rad: [f64; 4],
    /// The wrench rendered to the operator `[Fx_n, Fy_n, Fz_n, My_n_mm]` (`servo_cf`).
    pub wrench_rendered_n_nmm: [f64; 4],
}

impl TelemetrySample for MasterSample {
    const TOPICS: &'static [CrtkTopic] = &CrtkTopic::MASTER;

    fn encode(&self, topic: CrtkTopic, frame_id: &str, buf: Vec<u8>) -> Result<Vec<u8>, CdrError> {
        let t = self.stamp_unix_ns;
        match topic {
            CrtkTopic::MeasuredCp => pose_msg(t, frame_id, &self.pose_mm_rad).encode_reusing(buf),
            _ => wrench_msg(t, frame_id, &self.wrench_rendered_n_nmm).encode_reusing(buf),
        }
    }

    fn stamp_unix_ns(&self) -> u64 {
        self.stamp_unix_ns
    }
}

/// The `header.frame_id` of a side's messages: its namespace's last name + `_base`
/// (`/h4` → `h4_base`, `/h4_master` → `h4_master_base`; the root namespace → `base`).
pub fn base_frame_id(namespace: &str) -> String {
    match namespace.rsplit('/').next() {
        Some(leaf) if !leaf.is_empty() => format!("{leaf}_base"),
        _ => "base".to_owned(),
    }
}

/// What `--record-ros2` adds to a recording: a side's CRTK topics under its names, as ROS 2
/// messages (CDR, `ros2msg` schemas), sampled from the loop's [`LatestCell`] at `rate_hz` by
/// the recording thread ([`CellPoller`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Ros2Recording {
    /// The topic names (`/h4/measured_cp`, ...).
    pub names: Ros2Names,
    /// How often the cell is sampled, Hz (`--ros2-rate-hz`).
    pub rate_hz: f64,
}

/// One recorded ROS 2 topic: its name, its type (the MCAP schema's name,
/// `geometry_msgs/msg/PoseStamped`) and the type's complete `ros2msg` definition
/// ([`super::type_hash::ros2msg_definition`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RecordedTopic {
    /// The fully qualified topic name.
    pub topic: String,
    /// `pkg/msg/Name`.
    pub type_name: &'static str,
    /// The `.msg` text with its dependencies.
    pub definition: String,
}

impl Ros2Recording {
    /// The topics of `T`'s side, in [`TelemetrySample::TOPICS`] order.
    pub fn topics<T: TelemetrySample>(&self) -> Result<Vec<RecordedTopic>, TypeHashError> {
        T::TOPICS
            .iter()
            .map(|&t| {
                Ok(RecordedTopic {
                    topic: self.names.topic(t),
                    type_name: t.type_name(),
                    definition: super::type_hash::ros2msg_definition(t.type_name())?,
                })
            })
            .collect()
    }

    /// The poller of `cell` for these topics.
    pub fn poller<T: TelemetrySample>(&self, cell: Arc<LatestCell<T>>) -> CellPoller<T> {
        CellPoller {
            cell,
            seen: 0,
            frame_id: base_frame_id(self.names.namespace()),
            buf: Vec::with_capacity(256),
            errors: 0,
        }
    }
}

/// Samples a [`LatestCell`] for a recording thread: each call hands out the newest sample
/// not seen before, encoded on each topic of its side (the same messages `--ros2`
/// publishes), into one reused buffer.
#[derive(Debug)]
pub struct CellPoller<T: TelemetrySample> {
    cell: Arc<LatestCell<T>>,
    seen: u64,
    frame_id: String,
    buf: Vec<u8>,
    errors: u64,
}

impl<T: TelemetrySample> CellPoller<T> {
    /// Hands `write(topic index, stamp ns, CDR payload)` the newest sample on every topic
    /// (nothing if the loop wrote none since the last call); returns the number of samples
    /// taken (0 or 1).
    pub fn poll(&mut self, write: &mut dyn FnMut(usize, u64, &[u8])) -> u64 {
        let Some((version, sample)) = self.cell.newer_than(self.seen) else {
            return 0;
        };
        self.seen = version;
        let stamp = sample.stamp_unix_ns();
        for (i, &topic) in T::TOPICS.iter().enumerate() {
            let buf = std::mem::take(&mut self.buf);
            match sample.encode(topic, &self.frame_id, buf) {
                Ok(b) => {
                    write(i, stamp, &b);
                    self.buf = b;
                }
                Err(_) => self.errors += 1,
            }
        }
        1
    }

    /// Samples that could not be encoded (one per topic).
    pub fn errors(&self) -> u64 {
        self.errors
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn the_reader_sees_only_the_newest_value_once() {
        let cell = LatestCell::<u32>::new();
        assert_eq!(cell.newer_than(0), None);
        assert!(cell.offer(1));
        assert!(cell.offer(2));
        let (v, x) = cell.newer_than(0).unwrap();
        assert_eq!(x, 2);
        assert_eq!(cell.newer_than(v), None);
        assert!(cell.offer(3));
        assert_eq!(cell.newer_than(v).map(|(_, x)| x), Some(3));
        assert_eq!(cell.skipped(), 0);
    }

    /// Negative control of "never waits": while the reader holds the cell a write is
    /// skipped and counted, not queued behind the lock.
    #[test]
    fn a_write_while_the_reader_holds_the_cell_is_skipped_and_counted() {
        let cell = LatestCell::<u32>::new();
        let guard = cell.slot.lock().unwrap();
        assert!(!cell.offer(7));
        drop(guard);
        assert_eq!(cell.skipped(), 1);
        assert_eq!(cell.newer_than(0), None);
    }

    /// The loop's read never waits: while the writer holds the cell it returns None and
    /// counts it, and the value is read once the writer is done. Control: without the
    /// writer holding it the same read sees the value at once.
    #[test]
    fn the_loops_read_does_not_wait_for_the_writer() {
        let cell = LatestCell::<u32>::new();
        cell.put(5);
        let guard = cell.slot.lock().unwrap();
        assert_eq!(cell.try_newer_than(0), None);
        drop(guard);
        assert_eq!(cell.skipped(), 1);
        let (v, x) = cell.try_newer_than(0).unwrap();
        assert_eq!(x, 5);
        assert_eq!(cell.try_newer_than(v), None);
        cell.put(6);
        assert_eq!(cell.try_newer_than(v).map(|(_, x)| x), Some(6));
    }

    #[test]
    fn samples_decode_back_in_si_units() {
        let s = SlaveSample {
            stamp_unix_ns: 1_700_000_000_123_456_789,
            pose_mm_rad: [10.0, -20.0, 300.0, 0.1],
            velocity_mm_rad_per_s: [5.0, 0.0, -1.0, 0.2],
            wrench_sensor_n_nmm: [0.5, 0.0, -4.0, 250.0],
            wrench_setpoint_n_nmm: [0.0, 0.0, -5.0, 0.0],
            state: CrtkState::Following,
        };
        let p = PoseStamped::decode(
            &s.encode(CrtkTopic::MeasuredCp, "h4_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert_eq!(p.header.frame_id, "h4_base");
        assert_eq!(p.header.stamp.sec, 1_700_000_000);
        assert_eq!(p.header.stamp.nanosec, 123_456_789);
        assert!((p.pose.position.z - 0.3).abs() < 1e-12);
        let w = WrenchStamped::decode(
            &s.encode(CrtkTopic::MeasuredCf, "h4_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert!((w.wrench.torque.y - 0.25).abs() < 1e-12);
        assert_eq!(w.wrench.force.z, -4.0);
        let sp = WrenchStamped::decode(
            &s.encode(CrtkTopic::SetpointCf, "h4_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert_eq!(sp.wrench.force.z, -5.0);
        let v = TwistStamped::decode(
            &s.encode(CrtkTopic::MeasuredCv, "h4_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert!((v.twist.linear.x - 0.005).abs() < 1e-12);
        let o = OperatingState::decode(
            &s.encode(CrtkTopic::OperatingState, "h4_base", Vec::new())
                .unwrap(),
        )
        .unwrap();
        assert_eq!((o.state.as_str(), o.is_busy), ("ENABLED", true));
    }

    #[test]
    fn frame_ids_follow_the_namespace() {
        assert_eq!(base_frame_id("/h4"), "h4_base");
        assert_eq!(base_frame_id("/lab/h4_master"), "h4_master_base");
        assert_eq!(base_frame_id("/"), "base");
    }

    #[test]
    fn the_poller_records_each_new_sample_once_on_every_topic() {
        let rec = Ros2Recording {
            names: Ros2Names::slave_default(),
            rate_hz: 100.0,
        };
        let topics = rec.topics::<SlaveSample>().unwrap();
        let names: Vec<&str> = topics.iter().map(|t| t.topic.as_str()).collect();
        assert_eq!(names[0], "/h4/measured_cp");
        assert_eq!(names[4], "/h4/operating_state");
        assert_eq!(topics[4].type_name, "crtk_msgs/msg/OperatingState");
        assert!(topics[0].definition.starts_with("std_msgs/Header header\n"));
        let cell = Arc::new(LatestCell::new());
        let mut poller = rec.poller(Arc::clone(&cell));
        let mut got: Vec<(usize, u64, Vec<u8>)> = Vec::new();
        assert_eq!(poller.poll(&mut |i, t, b| got.push((i, t, b.to_vec()))), 0);
        let s = SlaveSample {
            stamp_unix_ns: 42,
            pose_mm_rad: [1.0, 2.0, 300.0, 0.0],
            ..SlaveSample::default()
        };
        cell.offer(s);
        assert_eq!(poller.poll(&mut |i, t, b| got.push((i, t, b.to_vec()))), 1);
        assert_eq!(poller.poll(&mut |i, t, b| got.push((i, t, b.to_vec()))), 0);
        assert_eq!(got.len(), 5);
        assert_eq!(got.iter().map(|g| g.0).collect::<Vec<_>>(), [0, 1, 2, 3, 4]);
        assert!(got.iter().all(|g| g.1 == 42));
        let p = PoseStamped::decode(&got[0].2).unwrap();
        assert_eq!(p.header.frame_id, "h4_base");
        assert!((p.pose.position.z - 0.3).abs() < 1e-12);
        assert_eq!(
            got[4].2,
            s.encode(CrtkTopic::OperatingState, "h4_base", Vec::new())
                .unwrap()
        );
        assert_eq!(poller.errors(), 0);
    }
}
