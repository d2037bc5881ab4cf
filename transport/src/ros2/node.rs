//! A ROS 2 node over Zenoh, as rmw_zenoh speaks it (feature `zenoh`; issue 35, publishing).
//!
//! [`Ros2Node::open`] opens the node's own Zenoh session (separate from the teleoperation
//! link): a peer, as rmw_zenoh's nodes are, that connects to `--ros2-connect` (default
//! `tcp/localhost:7447`, the router `ros2 run rmw_zenoh_cpp rmw_zenohd` listens on) and
//! listens on a loopback ephemeral port only; multicast scouting off. It declares the node's
//! liveliness token and, per publisher, the publisher's token (`MP`, [`super::keys`]), so
//! `ros2 node list` / `ros2 topic list` see them. Each publication is a `put` of the CDR
//! payload on the topic's key expression with the 33-byte attachment (sequence number from
//! 1, source timestamp, the publisher's GID).
//!
//! [`spawn_publisher`] starts the decimating thread: every `1/rate_hz` it takes the newest
//! sample the loop left in a [`LatestCell`] and, if it is new, publishes it on each of the
//! sample's topics. The 1 kHz loop only writes the cell; everything Zenoh does (and
//! allocates) happens on this thread.
//!
//! The GID: rmw_zenoh hashes the endpoint's liveliness token with XXH3-128; we take the first
//! 16 bytes of its SHA-256 (unique per endpoint just the same; subscribers only compare GIDs).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ::zenoh::Wait;
use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::{Publisher, Subscriber};
use ::zenoh::qos::CongestionControl;
use ::zenoh::sample::Sample;
use ::zenoh::{Config, Session};
use serde::Serialize;
use sha2::{Digest, Sha256};

use super::keys::{Attachment, Distro, EntityKind, GID_LEN, KeyError, NodeInfo, Qos, TopicInfo};
use super::telemetry::{LatestCell, Ros2Recording, TelemetrySample, base_frame_id};
use super::{CrtkTopic, Ros2Names};

/// Which ROS 2 distribution's key format (`--ros2-distro`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DistroArg {
    /// Jazzy, Kilted, Rolling: RIHS01 type hashes in the keys.
    #[default]
    Jazzy,
    /// Humble: `TypeHashNotSupported` in the keys.
    Humble,
}

impl From<DistroArg> for Distro {
    fn from(d: DistroArg) -> Distro {
        match d {
            DistroArg::Jazzy => Distro::Jazzy,
            DistroArg::Humble => Distro::Humble,
        }
    }
}

/// The ROS 2 flags of `h4-slave run`, `h4-master run` and `h4-master loopback`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct Ros2Args {
    /// Also publish this side's CRTK topics to ROS 2 over rmw_zenoh's wire format (its own
    /// Zenoh session, separate from the teleoperation link; docs/ros2.md).
    #[arg(long)]
    pub ros2: bool,
    /// ROS_DOMAIN_ID of the topics (0 to 232).
    #[arg(long, default_value_t = 0, value_name = "ID")]
    pub ros2_domain: u32,
    /// The Zenoh endpoint to connect to: the rmw_zenoh router (`rmw_zenohd`) or a peer.
    #[arg(long, default_value = "tcp/localhost:7447", value_name = "ENDPOINT")]
    pub ros2_connect: String,
    /// The namespace of the topics (default: `/h4` on the slave, `/h4_master` on the master;
    /// on `loopback`: the slave's, the master keeps `/h4_master`).
    #[arg(long, value_name = "NS")]
    pub ros2_ns: Option<String>,
    /// How often the publishing thread publishes the newest cycle, Hz (1 to 1000).
    #[arg(long, default_value_t = 100.0, value_name = "HZ")]
    pub ros2_rate_hz: f64,
    /// The key format's distribution.
    #[arg(long, value_enum, default_value_t = DistroArg::Jazzy)]
    pub ros2_distro: DistroArg,
    /// With `--record`: also record this side's CRTK topics as ROS 2 messages (CDR, `ros2msg`
    /// schemas, under the `--ros2-ns` namespace, at `--ros2-rate-hz`), so ROS 2 bag tools and
    /// Foxglove open them as ROS 2 messages; works with or without `--ros2` (docs/ros2.md).
    #[arg(long)]
    pub record_ros2: bool,
}

/// The cell a run's loop writes and what `--record-ros2` records
/// ([`Ros2Args::cell_and_recording`]).
pub type CellAndRecording<T> = (Option<Arc<LatestCell<T>>>, Option<Ros2Recording>);

impl Ros2Args {
    /// The node these flags describe, for a side whose default namespace is `default_ns`
    /// and whose node is called `node_name`; None without `--ros2`.
    pub fn node_config(
        &self,
        default_ns: &str,
        node_name: &str,
    ) -> Result<Option<NodeConfig>, Ros2Error> {
        if !self.ros2 {
            return Ok(None);
        }
        if self.ros2_domain > 232 {
            return Err(Ros2Error::Flag(format!(
                "--ros2-domain {} is out of range: allowed 0 to 232",
                self.ros2_domain
            )));
        }
        let names = self.checked_names(default_ns)?;
        Ok(Some(NodeConfig {
            domain_id: self.ros2_domain,
            connect: self.ros2_connect.clone(),
            names,
            node_name: node_name.to_owned(),
            distro: self.ros2_distro.into(),
            rate_hz: self.ros2_rate_hz,
            listen: None,
        }))
    }

    /// The node of a device-side endpoint of this process (a ROS 2 device or arm, or a
    /// stand-in for one): named `node_name` in `namespace`, on these flags' domain, endpoint
    /// and key format, with or without `--ros2`.
    pub fn endpoint_node(&self, namespace: &str, node_name: &str) -> Result<NodeConfig, String> {
        if self.ros2_domain > 232 {
            return Err(format!(
                "--ros2-domain {} is out of range: allowed 0 to 232",
                self.ros2_domain
            ));
        }
        Ok(NodeConfig {
            domain_id: self.ros2_domain,
            connect: self.ros2_connect.clone(),
            names: Ros2Names::new(namespace).map_err(|e| format!("{namespace}: {e}"))?,
            node_name: node_name.to_owned(),
            distro: self.ros2_distro.into(),
            rate_hz: 100.0,
            listen: None,
        })
    }

    /// The namespace's names after checking `--ros2-rate-hz` and `--ros2-ns` (shared by
    /// `--ros2` and `--record-ros2`).
    fn checked_names(&self, default_ns: &str) -> Result<Ros2Names, Ros2Error> {
        if !(self.ros2_rate_hz.is_finite() && (1.0..=1000.0).contains(&self.ros2_rate_hz)) {
            return Err(Ros2Error::Flag(format!(
                "--ros2-rate-hz {} is out of range: allowed 1 to 1000",
                self.ros2_rate_hz
            )));
        }
        let ns = self.ros2_ns.as_deref().unwrap_or(default_ns);
        Ros2Names::new(ns).map_err(|e| Ros2Error::Flag(format!("--ros2-ns {ns}: {e}")))
    }

    /// What `--record-ros2` records for a side whose default namespace is `default_ns`;
    /// None without it. The namespace and rate are checked as for `--ros2`.
    pub fn recording(&self, default_ns: &str) -> Result<Option<Ros2Recording>, Ros2Error> {
        if !self.record_ros2 {
            return Ok(None);
        }
        let names = self.checked_names(default_ns)?;
        Ok(Some(Ros2Recording {
            names,
            rate_hz: self.ros2_rate_hz,
        }))
    }

    /// The cell a run's loop writes and what `--record-ros2` records (for a side whose
    /// default namespace is `default_ns`): the publishing's cell with `--ros2`, a cell of
    /// its own for the recording with `--record-ros2` alone, none without either.
    /// `--record-ros2` needs `--record` (`recording`: whether the run records).
    pub fn cell_and_recording<T: TelemetrySample>(
        &self,
        publishing: Option<&Ros2Publishing<T>>,
        default_ns: &str,
        recording: bool,
    ) -> Result<CellAndRecording<T>, String> {
        let rec = self.recording(default_ns).map_err(|e| e.to_string())?;
        if rec.is_some() && !recording {
            return Err("--record-ros2 needs --record FILE".to_string());
        }
        let cell = match (publishing, &rec) {
            (Some(p), _) => Some(Arc::clone(&p.cell)),
            (None, Some(_)) => Some(Arc::new(LatestCell::new())),
            (None, None) => None,
        };
        Ok((cell, rec))
    }

    /// The flags again, for a child process (`loopback`'s slave).
    pub fn to_args(&self) -> Vec<String> {
        if !self.ros2 {
            let mut a = Vec::new();
            if self.record_ros2 {
                a.push("--record-ros2".to_owned());
                a.push("--ros2-rate-hz".to_owned());
                a.push(self.ros2_rate_hz.to_string());
                if let Some(ns) = &self.ros2_ns {
                    a.push("--ros2-ns".to_owned());
                    a.push(ns.clone());
                }
            }
            return a;
        }
        let mut a = vec![
            "--ros2".to_owned(),
            "--ros2-domain".to_owned(),
            self.ros2_domain.to_string(),
            "--ros2-connect".to_owned(),
            self.ros2_connect.clone(),
            "--ros2-rate-hz".to_owned(),
            self.ros2_rate_hz.to_string(),
            "--ros2-distro".to_owned(),
            match self.ros2_distro {
                DistroArg::Jazzy => "jazzy",
                DistroArg::Humble => "humble",
            }
            .to_owned(),
        ];
        if let Some(ns) = &self.ros2_ns {
            a.push("--ros2-ns".to_owned());
            a.push(ns.clone());
        }
        if self.record_ros2 {
            a.push("--record-ros2".to_owned());
        }
        a
    }
}

/// A node's settings.
#[derive(Clone, Debug)]
pub struct NodeConfig {
    /// ROS_DOMAIN_ID.
    pub domain_id: u32,
    /// The Zenoh endpoint to connect to.
    pub connect: String,
    /// The topics' namespace.
    pub names: Ros2Names,
    /// The node's name (`h4_slave`, `h4_master`).
    pub node_name: String,
    /// Key format.
    pub distro: Distro,
    /// Publishing rate, Hz.
    pub rate_hz: f64,
    /// The endpoint the node listens on (None: a loopback ephemeral port).
    pub listen: Option<String>,
}

/// Why the ROS 2 node could not start.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// A flag is unusable.
    #[error("{0}")]
    Flag(String),
    /// A name or key could not be formed.
    #[error("ros2 key: {0}")]
    Key(#[from] KeyError),
    /// Zenoh refused a setting or a declaration, or the session did not open.
    #[error("ros2 zenoh: {0}")]
    Zenoh(String),
}

fn zerr(e: impl std::fmt::Display) -> Ros2Error {
    Ros2Error::Zenoh(e.to_string())
}

/// One publisher of the node: its key, GID and sequence number.
pub struct RawPublisher {
    publisher: Publisher<'static>,
    gid: [u8; GID_LEN],
    sequence_number: i64,
    _token: LivelinessToken,
}

impl RawPublisher {
    /// Puts `payload` with the next sequence number and `stamp_unix_ns` in the attachment.
    pub fn put(&mut self, payload: Vec<u8>, stamp_unix_ns: i64) -> Result<(), Ros2Error> {
        self.sequence_number += 1;
        let att = Attachment {
            sequence_number: self.sequence_number,
            source_timestamp_ns: stamp_unix_ns,
            gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(att.to_zbytes())
            .wait()
            .map_err(zerr)
    }

    /// The publisher's GID.
    pub fn gid(&self) -> [u8; GID_LEN] {
        self.gid
    }
}

/// One CRTK publisher of the node.
struct Ros2Publisher {
    topic: CrtkTopic,
    raw: RawPublisher,
}

/// One subscription of the node (its Zenoh subscriber and token, kept alive).
struct Ros2Subscription {
    _subscriber: Subscriber<()>,
    _token: LivelinessToken,
}

/// The node: its session, its liveliness token, its publishers and subscriptions.
pub struct Ros2Node {
    cfg: NodeConfig,
    info: NodeInfo,
    next_entity_id: u64,
    publishers: Vec<Ros2Publisher>,
    subscriptions: Vec<Ros2Subscription>,
    _node_token: LivelinessToken,
    // Declared last: dropped after the tokens and publishers.
    session: Session,
}

/// The GID of the endpoint whose liveliness token is `token`.
pub fn gid_of(token: &str) -> [u8; GID_LEN] {
    let digest = Sha256::digest(token.as_bytes());
    let mut gid = [0u8; GID_LEN];
    gid.copy_from_slice(&digest[..GID_LEN]);
    gid
}

impl Ros2Node {
    /// Opens the node's session and declares its token.
    pub fn open(cfg: &NodeConfig) -> Result<Self, Ros2Error> {
        let mut config = Config::default();
        let set = |c: &mut Config, k: &str, v: &str| c.insert_json5(k, v).map_err(zerr);
        set(&mut config, "mode", "\"peer\"")?;
        set(
            &mut config,
            "connect/endpoints",
            &format!("[{:?}]", cfg.connect),
        )?;
        let listen = cfg.listen.as_deref().unwrap_or("tcp/127.0.0.1:0");
        set(&mut config, "listen/endpoints", &format!("[{listen:?}]"))?;
        set(&mut config, "scouting/multicast/enabled", "false")?;
        let session = ::zenoh::open(config).wait().map_err(zerr)?;
        let info = NodeInfo::new(
            cfg.domain_id,
            &session.zid().to_string(),
            0,
            cfg.names.namespace(),
            &cfg.node_name,
        )?;
        let node_token = session
            .liveliness()
            .declare_token(info.node_token())
            .wait()
            .map_err(zerr)?;
        Ok(Ros2Node {
            cfg: cfg.clone(),
            info,
            next_entity_id: 1,
            publishers: Vec::new(),
            subscriptions: Vec::new(),
            _node_token: node_token,
            session,
        })
    }

    /// The node's liveliness token.
    pub fn node_token(&self) -> String {
        self.info.node_token()
    }

    /// Declares a publisher on `topic` (its token too); returns its key expression.
    pub fn declare_publisher(&mut self, topic: CrtkTopic) -> Result<String, Ros2Error> {
        let (raw, key) =
            self.declare_raw_publisher(&self.cfg.names.topic(topic), topic.type_name())?;
        self.publishers.push(Ros2Publisher { topic, raw });
        Ok(key)
    }

    fn entity_id(&mut self) -> u64 {
        let id = self.next_entity_id;
        self.next_entity_id += 1;
        id
    }

    /// Declares a publisher of `type_name` on the fully qualified topic `fq_topic` (its
    /// `MP` token too), owned by the caller; returns it and its key expression.
    pub fn declare_raw_publisher(
        &mut self,
        fq_topic: &str,
        type_name: &str,
    ) -> Result<(RawPublisher, String), Ros2Error> {
        let t = TopicInfo::new(fq_topic, type_name, self.cfg.distro, Qos::keep_last(1))?;
        let entity_id = self.entity_id();
        let token_key = self
            .info
            .endpoint_token(entity_id, EntityKind::Publisher, &t);
        let key = t.key_expr(self.cfg.domain_id);
        let publisher = self
            .session
            .declare_publisher(key.clone())
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(zerr)?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(zerr)?;
        Ok((
            RawPublisher {
                publisher,
                gid: gid_of(&token_key),
                sequence_number: 0,
                _token: token,
            },
            key,
        ))
    }

    /// Declares a subscription to `fq_topic` for messages of `type_name` (its `MS` token
    /// too). It listens to every type on the topic (`<domain>/<topic>/*/*`), so that a
    /// publication of another type reaches `on_sample` and can be refused and counted
    /// ([`super::subscriber::Intake`]). `on_sample(key, payload, attachment)` runs on
    /// Zenoh's thread. Returns the key expression subscribed to.
    pub fn declare_subscription(
        &mut self,
        fq_topic: &str,
        type_name: &str,
        on_sample: impl Fn(&str, &[u8], Option<&[u8]>) + Send + Sync + 'static,
    ) -> Result<String, Ros2Error> {
        let t = TopicInfo::new(fq_topic, type_name, self.cfg.distro, Qos::keep_last(1))?;
        let entity_id = self.entity_id();
        let token_key = self
            .info
            .endpoint_token(entity_id, EntityKind::Subscription, &t);
        let name = fq_topic.strip_prefix('/').unwrap_or(fq_topic);
        let key = format!("{}/{name}/*/*", self.cfg.domain_id);
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            .callback(move |sample: Sample| {
                let payload = sample.payload().to_bytes();
                let attachment = sample.attachment().map(|a| a.to_bytes());
                on_sample(sample.key_expr().as_str(), &payload, attachment.as_deref());
            })
            .wait()
            .map_err(zerr)?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key)
            .wait()
            .map_err(zerr)?;
        self.subscriptions.push(Ros2Subscription {
            _subscriber: subscriber,
            _token: token,
        });
        Ok(key)
    }

    /// The node's configuration.
    pub fn config(&self) -> &NodeConfig {
        &self.cfg
    }
}

/// What the publishing thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PublishReport {
    /// Samples taken from the loop and published (each on every topic).
    pub samples: u64,
    /// Messages put.
    pub messages: u64,
    /// Messages Zenoh refused to put, or that could not be encoded.
    pub errors: u64,
    /// The loop's writes skipped because the thread held the cell at that instant.
    pub loop_writes_skipped: u64,
}

/// The publishing thread; [`PublishingThread::stop`] ends it.
pub struct PublishingThread {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<PublishReport>>,
}

impl PublishingThread {
    /// Stops the thread (after its current round) and returns what it did.
    pub fn stop(mut self) -> PublishReport {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default()
    }
}

impl Drop for PublishingThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// A run's ROS 2 publishing (`--ros2`): the node's configuration, the cell the loop writes
/// its samples into and the thread that publishes them.
pub struct Ros2Publishing<T: TelemetrySample> {
    /// The node.
    pub cfg: NodeConfig,
    /// The cell the loop writes (hand it to the server's outputs).
    pub cell: Arc<LatestCell<T>>,
    thread: PublishingThread,
}

impl<T: TelemetrySample> Ros2Publishing<T> {
    /// The publishing of the node `args` describe ([`Ros2Args::node_config`]), started;
    /// None without `--ros2`. Errors are worded for the command line (`--ros2: ...`).
    pub fn start(
        args: &Ros2Args,
        default_ns: &str,
        node_name: &str,
    ) -> Result<Option<Self>, String> {
        let Some(cfg) = args
            .node_config(default_ns, node_name)
            .map_err(|e| e.to_string())?
        else {
            return Ok(None);
        };
        let cell = Arc::new(LatestCell::new());
        let thread =
            spawn_publisher(&cfg, Arc::clone(&cell)).map_err(|e| format!("--ros2: {e}"))?;
        Ok(Some(Ros2Publishing { cfg, cell, thread }))
    }

    /// Stops the thread; the line a run prints on stderr: what it published.
    pub fn stop_line(self, label: &str) -> String {
        let r = self.thread.stop();
        let c = &self.cfg;
        format!(
            "{label}: ROS 2: {} samples, {} messages on {} (domain {}, via {}), {} errors, {} loop writes skipped",
            r.samples,
            r.messages,
            c.names.namespace(),
            c.domain_id,
            c.connect,
            r.errors,
            r.loop_writes_skipped
        )
    }
}

/// Opens the node of `cfg`, declares a publisher per topic of `T`, and starts the thread
/// that publishes the newest sample of `cell` at `cfg.rate_hz`.
pub fn spawn_publisher<T: TelemetrySample>(
    cfg: &NodeConfig,
    cell: Arc<LatestCell<T>>,
) -> Result<PublishingThread, Ros2Error> {
    let mut node = Ros2Node::open(cfg)?;
    for &topic in T::TOPICS {
        node.declare_publisher(topic)?;
    }
    let stop = Arc::new(AtomicBool::new(false));
    let stop_thread = Arc::clone(&stop);
    let period = Duration::from_secs_f64(1.0 / cfg.rate_hz);
    let handle = std::thread::Builder::new()
        .name("h4-ros2-pub".into())
        .spawn(move || publish_loop(node, cell, period, &stop_thread))
        .map_err(|e| Ros2Error::Zenoh(format!("publishing thread: {e}")))?;
    Ok(PublishingThread {
        stop,
        handle: Some(handle),
    })
}

fn publish_loop<T: TelemetrySample>(
    mut node: Ros2Node,
    cell: Arc<LatestCell<T>>,
    period: Duration,
    stop: &AtomicBool,
) -> PublishReport {
    let frame_id = base_frame_id(node.cfg.names.namespace());
    let mut report = PublishReport::default();
    let mut seen = 0;
    let mut cadence = Cadence::new(period);
    // One last round after the stop, so the final state goes out.
    let mut last_round = false;
    loop {
        if let Some((version, sample)) = cell.newer_than(seen) {
            seen = version;
            report.samples += 1;
            let stamp = i64::try_from(sample.stamp_unix_ns()).unwrap_or(i64::MAX);
            for p in &mut node.publishers {
                // Zenoh takes the payload by value: one allocation per message, on this thread.
                let payload = match sample.encode(p.topic, &frame_id, Vec::with_capacity(256)) {
                    Ok(b) => b,
                    Err(_) => {
                        report.errors += 1;
                        continue;
                    }
                };
                match p.raw.put(payload, stamp) {
                    Ok(()) => report.messages += 1,
                    Err(_) => report.errors += 1,
                }
            }
        }
        if last_round {
            break;
        }
        if stop.load(Ordering::Relaxed) {
            last_round = true;
            continue;
        }
        cadence.wait();
    }
    report.loop_writes_skipped = cell.skipped();
    report
}

/// Paces a thread on absolute deadlines `start + n · period`; a round that ends after its
/// deadline starts the count again from now (no burst of catch-up rounds). The publishing,
/// command and stand-in threads of the ROS 2 side.
#[derive(Debug)]
pub struct Cadence {
    period: Duration,
    next: Instant,
}

impl Cadence {
    /// A cadence of `period` from now.
    pub fn new(period: Duration) -> Self {
        Cadence {
            period,
            next: Instant::now(),
        }
    }

    /// A cadence of `rate_hz` (clamped to 1 to 10 000 Hz).
    pub fn at_hz(rate_hz: f64) -> Self {
        Self::new(Duration::from_secs_f64(1.0 / rate_hz.clamp(1.0, 10_000.0)))
    }

    /// Sleeps until the next deadline.
    pub fn wait(&mut self) {
        self.next += self.period;
        let now = Instant::now();
        if self.next > now {
            std::thread::sleep(self.next - now);
        } else {
            self.next = now;
        }
    }
}

/// A named background thread that runs until asked to stop: [`StoppableThread::stop`] sets
/// its flag, joins it and returns its report (the default if it panicked); dropping it stops
/// and joins it too. The ROS 2 device's, arm's and stand-in's command threads.
pub struct StoppableThread<R: Default> {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<R>>,
}

impl<R: Default + Send + 'static> StoppableThread<R> {
    /// Starts `body` on a thread called `name`; `body` returns when the flag it is given is
    /// set.
    pub fn spawn(
        name: &str,
        body: impl FnOnce(&AtomicBool) -> R + Send + 'static,
    ) -> Result<Self, Ros2Error> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let handle = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || body(&flag))
            .map_err(|e| Ros2Error::Zenoh(format!("{name} thread: {e}")))?;
        Ok(StoppableThread {
            stop,
            handle: Some(handle),
        })
    }
}

impl<R: Default> StoppableThread<R> {
    /// Stops the thread (after its current round) and returns what it did.
    pub fn stop(mut self) -> R {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default()
    }
}

impl<R: Default> Drop for StoppableThread<R> {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn flags_are_checked_and_passed_on() {
        let off = Ros2Args::default();
        assert!(off.node_config("/h4", "h4_slave").unwrap().is_none());
        assert!(off.to_args().is_empty());
        let on = Ros2Args {
            ros2: true,
            ros2_domain: 3,
            ros2_connect: "tcp/127.0.0.1:7447".into(),
            ros2_ns: None,
            ros2_rate_hz: 100.0,
            ros2_distro: DistroArg::Humble,
            record_ros2: false,
        };
        assert!(on.recording("/h4").unwrap().is_none());
        let rec_only = Ros2Args {
            ros2: false,
            record_ros2: true,
            ros2_ns: Some("/psm1".into()),
            ..on.clone()
        };
        let r = rec_only.recording("/h4").unwrap().unwrap();
        assert_eq!(r.names.namespace(), "/psm1");
        assert!(rec_only.node_config("/h4", "h4_slave").unwrap().is_none());
        assert_eq!(
            rec_only.to_args(),
            [
                "--record-ros2",
                "--ros2-rate-hz",
                "100",
                "--ros2-ns",
                "/psm1"
            ]
        );
        assert!(
            Ros2Args {
                ros2_rate_hz: 0.0,
                ..rec_only.clone()
            }
            .recording("/h4")
            .is_err()
        );
        let cfg = on.node_config("/h4", "h4_slave").unwrap().unwrap();
        assert_eq!(cfg.names.namespace(), "/h4");
        assert_eq!(cfg.distro, Distro::Humble);
        assert!(on.to_args().contains(&"humble".to_owned()));
        for bad in [
            Ros2Args {
                ros2_domain: 233,
                ..on.clone()
            },
            Ros2Args {
                ros2_rate_hz: 0.5,
                ..on.clone()
            },
            Ros2Args {
                ros2_rate_hz: f64::NAN,
                ..on.clone()
            },
            Ros2Args {
                ros2_ns: Some("/h4/".into()),
                ..on.clone()
            },
        ] {
            assert!(bad.node_config("/h4", "h4_slave").is_err(), "{bad:?}");
        }
    }

    #[test]
    fn gids_differ_per_endpoint() {
        assert_ne!(gid_of("a"), gid_of("b"));
        assert_eq!(gid_of("a"), gid_of("a"));
    }
}
