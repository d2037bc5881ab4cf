//! The Zenoh side of a ROS 2 arm (feature `zenoh`; `h4-slave run --arm crtk`): a node with
//! a subscription for the arm's measured pose and one for its measured wrench
//! ([`super::arm::ArmTopics`]), and a thread that publishes the newest pose command.
//!
//! Each subscription's callback checks every sample ([`super::subscriber::Intake`]: type on
//! the key, attachment, one owner GID, CDR, finiteness), counts the rejected ones by reason
//! and writes the accepted ones, in project units, into the arm's cells
//! ([`super::arm::ArmCells`]); the 1 kHz loop reads them without waiting. The command
//! thread wakes at `rate_hz`, takes the newest command the loop left in its cell, stamps it
//! with the time it sends it and puts it on the command topic; it also says on stderr when
//! the loop found the arm stale and when it answers again (the loop itself never prints).
//!
//! [`ArmStandinIo`] is the other side, a stand-in arm (`h4-slave ros2-standin`): it
//! subscribes to the command topic and publishes the arm's pose, velocity and wrench.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde::Serialize;

use super::arm::{ArmCells, ArmStandinCells, ArmTopics, PoseCommand, WrenchReading};
use super::device::PoseReading;
use super::device_io::{StandinIoReport, publish_newest, subscribe};
use super::msgs::{PoseStamped, Ros2Message, TwistStamped, WrenchStamped};
use super::node::{Cadence, NodeConfig, RawPublisher, Ros2Error, Ros2Node, StoppableThread};

/// How the arm's node runs.
#[derive(Clone, Debug)]
pub struct ArmIoConfig {
    /// The node (domain, endpoint, distribution; its name and namespace).
    pub node: NodeConfig,
    /// The arm's topics.
    pub topics: ArmTopics,
    /// The commands' `header.frame_id`.
    pub frame_id: String,
    /// A topic's owner (the first publisher's GID) is released after this much silence, ns.
    pub owner_timeout_ns: u64,
    /// How often the newest command is published, Hz.
    pub command_rate_hz: f64,
    /// How the stderr lines start (`h4-slave run`).
    pub label: String,
    /// The staleness timeout, ms (for the stderr line).
    pub timeout_ms: f64,
}

/// What the command thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ArmIoReport {
    /// Commands published.
    pub commands: u64,
    /// Commands Zenoh refused or that could not be encoded.
    pub errors: u64,
}

/// The arm's node and command thread; [`ArmIo::stop`] ends them.
pub struct ArmIo {
    thread: StoppableThread<ArmIoReport>,
}

impl ArmIo {
    /// Opens the node, subscribes to the arm's pose and wrench (writing into `cells`) and
    /// starts the command thread (reading `cells.command`).
    pub fn open(cfg: &ArmIoConfig, cells: Arc<ArmCells>) -> Result<Self, Ros2Error> {
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
        subscribe::<_, WrenchStamped, _>(
            &mut node,
            &t.wrench,
            cfg.owner_timeout_ns,
            epoch,
            &cells,
            |c| (&c.wrench, &c.wrench_counts),
            WrenchReading::from_msg,
        )?;
        let (publisher, _key) = node.declare_raw_publisher(&t.command, PoseStamped::TYPE_NAME)?;
        let period = Duration::from_secs_f64(1.0 / cfg.command_rate_hz.clamp(1.0, 10_000.0));
        let cfg = cfg.clone();
        let thread = StoppableThread::spawn("h4-ros2-arm", move |stop| {
            command_loop(node, publisher, &cfg, &cells, period, stop)
        })?;
        Ok(ArmIo { thread })
    }

    /// Stops the command thread and closes the node; what the thread did.
    pub fn stop(self) -> ArmIoReport {
        self.thread.stop()
    }
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

fn command_loop(
    node: Ros2Node,
    mut publisher: RawPublisher,
    cfg: &ArmIoConfig,
    cells: &ArmCells,
    period: Duration,
    stop: &AtomicBool,
) -> ArmIoReport {
    let mut report = ArmIoReport::default();
    let mut seen = 0;
    let mut said_stale = false;
    let mut cadence = Cadence::new(period);
    while !stop.load(Ordering::Relaxed) {
        if let Some((version, cmd)) = cells.command.newer_than(seen) {
            seen = version;
            let stamp_ns = unix_now_ns();
            match cmd
                .encode(stamp_ns, &cfg.frame_id, Vec::with_capacity(128))
                .map_err(|e| Ros2Error::Zenoh(e.to_string()))
                .and_then(|p| publisher.put(p, i64::try_from(stamp_ns).unwrap_or(i64::MAX)))
            {
                Ok(()) => report.commands += 1,
                Err(_) => report.errors += 1,
            }
        }
        let stale = cells.status.stale();
        if stale != said_stale {
            said_stale = stale;
            if stale {
                eprintln!(
                    "{}: arm stale: no fresh pose on {} or wrench on {} within {} ms; the slave safe-stops",
                    cfg.label, cfg.topics.pose, cfg.topics.wrench, cfg.timeout_ms
                );
            } else {
                eprintln!(
                    "{}: arm answers again on {} and {}",
                    cfg.label, cfg.topics.pose, cfg.topics.wrench
                );
            }
        }
        cadence.wait();
    }
    drop(node);
    report
}

/// How a stand-in arm's node runs (`h4-slave ros2-standin`).
#[derive(Clone, Debug)]
pub struct ArmStandinIoConfig {
    /// The node.
    pub node: NodeConfig,
    /// The arm's topics (the stand-in publishes what an arm does, subscribes to its
    /// command).
    pub topics: ArmTopics,
    /// The messages' `header.frame_id`.
    pub frame_id: String,
    /// The command topic's owner is released after this much silence, ns.
    pub owner_timeout_ns: u64,
    /// How often the newest cycle is published, Hz.
    pub rate_hz: f64,
}

/// A stand-in arm's node and publishing thread; [`ArmStandinIo::stop`] ends them.
pub struct ArmStandinIo {
    thread: StoppableThread<StandinIoReport>,
}

impl ArmStandinIo {
    /// Opens the node, subscribes to the command topic (into `cells.command`, checked as
    /// every subscription is) and starts the thread publishing `cells.state` on the pose,
    /// velocity (`<ns>/measured_cv`) and wrench topics.
    pub fn open(cfg: &ArmStandinIoConfig, cells: Arc<ArmStandinCells>) -> Result<Self, Ros2Error> {
        let t = &cfg.topics;
        let mut node = Ros2Node::open(&cfg.node)?;
        subscribe::<_, PoseStamped, _>(
            &mut node,
            &t.command,
            cfg.owner_timeout_ns,
            Instant::now(),
            &cells,
            |c| (&c.command, &c.command_counts),
            PoseCommand::from_msg,
        )?;
        let (mut pose, _) = node.declare_raw_publisher(&t.pose, PoseStamped::TYPE_NAME)?;
        let (mut twist, _) = node.declare_raw_publisher(&t.twist(), TwistStamped::TYPE_NAME)?;
        let (mut wrench, _) = node.declare_raw_publisher(&t.wrench, WrenchStamped::TYPE_NAME)?;
        let period = Duration::from_secs_f64(1.0 / cfg.rate_hz.clamp(1.0, 10_000.0));
        let frame_id = cfg.frame_id.clone();
        let thread = StoppableThread::spawn("h4-ros2-arm-standin", move |stop| {
            let report = publish_newest(&cells.state, period, stop, |s, put| {
                let stamp = i64::try_from(s.motion.stamp_unix_ns).unwrap_or(i64::MAX);
                put(&mut pose, s.motion.pose_msg(&frame_id).encode(), stamp);
                put(&mut twist, s.motion.twist_msg(&frame_id).encode(), stamp);
                put(&mut wrench, s.wrench_msg(&frame_id).encode(), stamp);
            });
            drop((pose, twist, wrench));
            drop(node);
            report
        })?;
        Ok(ArmStandinIo { thread })
    }

    /// Stops the thread and closes the node; what the thread did.
    pub fn stop(self) -> StandinIoReport {
        self.thread.stop()
    }
}
