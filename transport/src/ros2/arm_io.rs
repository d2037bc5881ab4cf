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

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde::Serialize;

use super::arm::{ArmCells, ArmTopics, WrenchReading};
use super::device::PoseReading;
use super::device_io::subscribe;
use super::msgs::{PoseStamped, Ros2Message, WrenchStamped};
use super::node::{NodeConfig, RawPublisher, Ros2Error, Ros2Node, StoppableThread};

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
    let mut next = Instant::now();
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
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    drop(node);
    report
}
