//! The Zenoh side of a ROS 2 haptic device (feature `zenoh`; `h4-master run --device crtk`):
//! a node with a subscription per input topic of the device ([`super::device::DeviceTopics`])
//! and a thread that publishes the newest force command.
//!
//! Each subscription's callback checks every sample ([`super::subscriber::Intake`]: type on
//! the key, attachment, one owner GID, CDR, finiteness), counts the rejected ones by reason
//! and writes the accepted ones, in project units, into the device's cells
//! ([`super::device::DeviceCells`]); the 1 kHz loop reads them without waiting. The command
//! thread wakes at `rate_hz`, takes the newest command the loop left in its cell and puts it
//! on the command topic; it also says on stderr when the loop found the device silent and
//! when it answers again (the loop itself never prints).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::cdr::CdrError;
use super::device::{
    ButtonsReading, CommandKind, DeviceCells, DeviceTopics, PoseReading, StandinCells,
    TwistReading, command_from_wrench,
};
use super::msgs::{Joy, PoseStamped, Ros2Message, TwistStamped, WrenchStamped};
use super::node::{Cadence, NodeConfig, RawPublisher, Ros2Error, Ros2Node, StoppableThread};
use super::subscriber::{Intake, RejectCounters};
use super::telemetry::{LatestCell, base_frame_id};

/// How the device's node runs.
#[derive(Clone, Debug)]
pub struct DeviceIoConfig {
    /// The node (domain, endpoint, distribution; its name and namespace).
    pub node: NodeConfig,
    /// The device's topics.
    pub topics: DeviceTopics,
    /// A topic's owner (the first publisher's GID) is released after this much silence, ns.
    pub owner_timeout_ns: u64,
    /// How often the newest command is published, Hz.
    pub command_rate_hz: f64,
    /// How the stderr lines start (`h4-master run`).
    pub label: String,
    /// The silence timeout, ms (for the stderr line).
    pub timeout_ms: f64,
}

/// What the command thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct DeviceIoReport {
    /// Commands published.
    pub commands: u64,
    /// Commands Zenoh refused or that could not be encoded.
    pub errors: u64,
}

/// The device's node and command thread; [`DeviceIo::stop`] ends them.
pub struct DeviceIo {
    thread: StoppableThread<DeviceIoReport>,
}

/// Subscribes to `topic` as message type `M`: each sample is checked by an [`Intake`],
/// counted in the counters `pick` gives (rejected by reason, or accepted) and, accepted,
/// converted and written into `pick`'s cell of `cells` (shared with `h4-slave`'s arm,
/// [`super::arm_io`]).
pub(super) fn subscribe<C, M, T>(
    node: &mut Ros2Node,
    topic: &str,
    owner_timeout_ns: u64,
    epoch: Instant,
    cells: &Arc<C>,
    pick: fn(&C) -> (&LatestCell<T>, &RejectCounters),
    convert: fn(&M) -> T,
) -> Result<(), Ros2Error>
where
    C: Send + Sync + 'static,
    M: Ros2Message + 'static,
    T: Copy + Send + 'static,
{
    let intake = Mutex::new(Intake::new(
        M::TYPE_NAME,
        node.config().distro,
        owner_timeout_ns,
    )?);
    let cells = Arc::clone(cells);
    node.declare_subscription(topic, M::TYPE_NAME, move |key, payload, attachment| {
        let now_ns = u64::try_from(epoch.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let (cell, counts) = pick(&cells);
        let msg = match intake.lock() {
            Ok(mut i) => i.take::<M>(counts, key, payload, attachment, now_ns),
            Err(p) => p
                .into_inner()
                .take::<M>(counts, key, payload, attachment, now_ns),
        };
        if let Some(m) = msg {
            cell.put(convert(&m));
        }
    })?;
    Ok(())
}

impl DeviceIo {
    /// Opens the node, subscribes to the device's inputs (writing into `cells`) and starts
    /// the command thread (reading `cells.command`).
    pub fn open(cfg: &DeviceIoConfig, cells: Arc<DeviceCells>) -> Result<Self, Ros2Error> {
        let mut node = Ros2Node::open(&cfg.node)?;
        let epoch = Instant::now();
        let t = &cfg.topics;
        subscribe::<_, PoseStamped, _>(
            &mut node,
            &t.pose,
            cfg.owner_timeout_ns,
            epoch,
            &cells,
            |c| (&c.pose, &c.pose_counts),
            PoseReading::from_msg,
        )?;
        if let Some(twist) = &t.twist {
            subscribe::<_, TwistStamped, _>(
                &mut node,
                twist,
                cfg.owner_timeout_ns,
                epoch,
                &cells,
                |c| (&c.twist, &c.twist_counts),
                TwistReading::from_msg,
            )?;
        }
        if let Some(clutch) = &t.clutch {
            subscribe::<_, Joy, _>(
                &mut node,
                clutch,
                cfg.owner_timeout_ns,
                epoch,
                &cells,
                |c| (&c.buttons, &c.buttons_counts),
                ButtonsReading::from_msg,
            )?;
        }
        let (publisher, _key) =
            node.declare_raw_publisher(&t.command, t.command_kind.type_name())?;
        let period = Duration::from_secs_f64(1.0 / cfg.command_rate_hz.clamp(1.0, 10_000.0));
        let cfg = cfg.clone();
        let thread = StoppableThread::spawn("h4-ros2-dev", move |stop| {
            command_loop(node, publisher, &cfg, &cells, period, stop)
        })?;
        Ok(DeviceIo { thread })
    }

    /// Stops the command thread and closes the node; what the thread did.
    pub fn stop(self) -> DeviceIoReport {
        self.thread.stop()
    }
}

fn command_loop(
    node: Ros2Node,
    mut publisher: RawPublisher,
    cfg: &DeviceIoConfig,
    cells: &DeviceCells,
    period: Duration,
    stop: &AtomicBool,
) -> DeviceIoReport {
    let frame_id = base_frame_id(&cfg.topics.namespace);
    let mut report = DeviceIoReport::default();
    let mut seen = 0;
    let mut said_silent = false;
    let mut cadence = Cadence::new(period);
    while !stop.load(Ordering::Relaxed) {
        if let Some((version, cmd)) = cells.command.newer_than(seen) {
            seen = version;
            let stamp = i64::try_from(cmd.stamp_unix_ns).unwrap_or(i64::MAX);
            match cmd
                .encode(cfg.topics.command_kind, &frame_id, Vec::with_capacity(128))
                .map_err(|e| Ros2Error::Zenoh(e.to_string()))
                .and_then(|p| publisher.put(p, stamp))
            {
                Ok(()) => report.commands += 1,
                Err(_) => report.errors += 1,
            }
        }
        let silent = cells.status.silent();
        if silent != said_silent {
            said_silent = silent;
            if silent {
                eprintln!(
                    "{}: device silent: no fresh pose on {} within {} ms; the rendered force fades to zero",
                    cfg.label, cfg.topics.pose, cfg.timeout_ms
                );
            } else {
                eprintln!(
                    "{}: device answers again on {}; the rendered force fades back in",
                    cfg.label, cfg.topics.pose
                );
            }
        }
        cadence.wait();
    }
    drop(node);
    report
}

/// How a stand-in device's node runs (`h4-master ros2-standin`).
#[derive(Clone, Debug)]
pub struct StandinIoConfig {
    /// The node.
    pub node: NodeConfig,
    /// The device's topics (the `crtk` profile: the stand-in publishes what a device does).
    pub topics: DeviceTopics,
    /// A command topic's owner is released after this much silence, ns.
    pub owner_timeout_ns: u64,
    /// How often the newest cycle is published, Hz.
    pub rate_hz: f64,
}

/// What a stand-in's publishing thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct StandinIoReport {
    /// Cycles published (each on the pose, velocity and clutch topics).
    pub samples: u64,
    /// Messages Zenoh refused or that could not be encoded.
    pub errors: u64,
}

/// A stand-in device's node and publishing thread; [`StandinIo::stop`] ends them.
pub struct StandinIo {
    thread: StoppableThread<StandinIoReport>,
}

impl StandinIo {
    /// Opens the node, subscribes to the command topic (into `cells.command`) and starts
    /// the thread publishing `cells.state`.
    pub fn open(cfg: &StandinIoConfig, cells: Arc<StandinCells>) -> Result<Self, Ros2Error> {
        let t = &cfg.topics;
        if t.command_kind != CommandKind::WrenchStamped {
            return Err(Ros2Error::Flag(
                "the stand-in speaks the crtk profile only (servo_cf as WrenchStamped)".into(),
            ));
        }
        let mut node = Ros2Node::open(&cfg.node)?;
        let epoch = Instant::now();
        let intake = Mutex::new(Intake::new(
            WrenchStamped::TYPE_NAME,
            cfg.node.distro,
            cfg.owner_timeout_ns,
        )?);
        let cb_cells = Arc::clone(&cells);
        node.declare_subscription(
            &t.command,
            WrenchStamped::TYPE_NAME,
            move |key, payload, attachment| {
                let now_ns = u64::try_from(epoch.elapsed().as_nanos()).unwrap_or(u64::MAX);
                let counts = &cb_cells.command_counts;
                let msg = match intake.lock() {
                    Ok(mut i) => i.take::<WrenchStamped>(counts, key, payload, attachment, now_ns),
                    Err(p) => p
                        .into_inner()
                        .take::<WrenchStamped>(counts, key, payload, attachment, now_ns),
                };
                if let Some(m) = msg {
                    cb_cells.command.put(command_from_wrench(&m));
                }
            },
        )?;
        let (pose, _) = node.declare_raw_publisher(&t.pose, PoseStamped::TYPE_NAME)?;
        let twist = match &t.twist {
            Some(topic) => Some(
                node.declare_raw_publisher(topic, TwistStamped::TYPE_NAME)?
                    .0,
            ),
            None => None,
        };
        let joy = match &t.clutch {
            Some(topic) => Some(node.declare_raw_publisher(topic, Joy::TYPE_NAME)?.0),
            None => None,
        };
        let period = Duration::from_secs_f64(1.0 / cfg.rate_hz.clamp(1.0, 10_000.0));
        let frame_id = base_frame_id(&t.namespace);
        let thread = StoppableThread::spawn("h4-ros2-standin", move |stop| {
            let mut pubs = StandinPublishers { pose, twist, joy };
            let report = standin_loop(&mut pubs, &frame_id, &cells, period, stop);
            drop(pubs);
            drop(node);
            report
        })?;
        Ok(StandinIo { thread })
    }

    /// Stops the thread and closes the node; what the thread did.
    pub fn stop(self) -> StandinIoReport {
        self.thread.stop()
    }
}

struct StandinPublishers {
    pose: RawPublisher,
    twist: Option<RawPublisher>,
    joy: Option<RawPublisher>,
}

fn standin_loop(
    pubs: &mut StandinPublishers,
    frame_id: &str,
    cells: &StandinCells,
    period: Duration,
    stop: &AtomicBool,
) -> StandinIoReport {
    publish_newest(&cells.state, period, stop, |s, put| {
        let stamp = i64::try_from(s.stamp_unix_ns).unwrap_or(i64::MAX);
        put(&mut pubs.pose, s.pose_msg(frame_id).encode(), stamp);
        if let Some(p) = &mut pubs.twist {
            put(p, s.twist_msg(frame_id).encode(), stamp);
        }
        if let Some(p) = &mut pubs.joy {
            put(p, s.joy_msg(frame_id).encode(), stamp);
        }
    })
}

/// A stand-in's publishing: every `period` (until `stop`) the newest sample of `cell`, if
/// it is new, goes to `publish`, which puts its messages with the `put` it is given (an
/// encoding or Zenoh error counts); what went out. Shared by the stand-in device and the
/// stand-in arm ([`super::arm_io::ArmStandinIo`]).
pub(super) fn publish_newest<T: Copy>(
    cell: &LatestCell<T>,
    period: Duration,
    stop: &AtomicBool,
    mut publish: impl FnMut(&T, &mut dyn FnMut(&mut RawPublisher, Result<Vec<u8>, CdrError>, i64)),
) -> StandinIoReport {
    let mut report = StandinIoReport::default();
    let mut seen = 0;
    let mut cadence = Cadence::new(period);
    while !stop.load(Ordering::Relaxed) {
        if let Some((version, s)) = cell.newer_than(seen) {
            seen = version;
            report.samples += 1;
            let mut put = |p: &mut RawPublisher, bytes: Result<Vec<u8>, CdrError>, stamp: i64| {
                let ok = bytes
                    .map_err(|e| Ros2Error::Zenoh(e.to_string()))
                    .and_then(|b| p.put(b, stamp));
                if ok.is_err() {
                    report.errors += 1;
                }
            };
            publish(&s, &mut put);
        }
        cadence.wait();
    }
    report
}
