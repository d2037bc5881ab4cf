//! Zenoh link (feature `zenoh`): master and slave on different hosts, or on one host over TCP
//! loopback.
//!
//! Each end opens its own Zenoh session (synchronous API), declares one publisher for the
//! messages it sends and one subscriber for the messages it receives, on key expressions that
//! carry the arm id: `h4/<arm_id>/command` and `h4/<arm_id>/feedback`. Messages travel in the
//! checked byte encoding of [`WireMessage::encode_into`]; the subscriber callback (a Zenoh
//! thread) decodes each payload and pushes it into a bounded queue preallocated at
//! construction (drop-oldest when full), which [`Link::try_recv`] drains without blocking.
//! Payloads that do not decode (wrong size, magic, kind or version, a non-finite number, an
//! unknown enum or flag) are counted by reason in [`Link::decode_rejects`] and never delivered;
//! a payload of any size is judged as [`decode_payload`] says (its header before its size).
//!
//! Publications are `express` (not batched), [`Priority::RealTime`] and
//! [`CongestionControl::Drop`]: a late message is worth less than the next one.
//!
//! Endpoints are explicit and loopback by default: one side listens (`tcp/127.0.0.1:<port>`),
//! the other connects; multicast scouting is off. A user-supplied json5 file
//! ([`ZenohConfig::config_file`]) is loaded first and our settings are applied over it.
//!
//! Our code allocates nothing per message (fixed stack buffers, a preallocated queue); Zenoh
//! itself allocates per publication and per received sample (its buffers and task queues).

use std::marker::PhantomData;
use std::sync::{Arc, Mutex};

use ::zenoh::Wait;
use ::zenoh::bytes::ZBytes;
use ::zenoh::pubsub::{Publisher, Subscriber};
use ::zenoh::qos::{CongestionControl, Priority};
use ::zenoh::sample::Sample;
use ::zenoh::{Config, Session};
use h4_shared::wire::{Command, Feedback, WireError, WireMessage};
use serde::{Deserialize, Serialize};

use crate::inproc::Ring;
use crate::{DecodeRejects, Link, LinkError, decode_payload};

const TRANSPORT: &str = "zenoh";

/// Largest encoded message the link handles, bytes (stack buffers are this long).
pub const MAX_WIRE_SIZE: usize = 512;

/// How a Zenoh session joins the network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZenohMode {
    /// Peer: talks directly to the peers it listens for or connects to.
    #[default]
    Peer,
    /// Client: connects to one peer or router, which routes for it; never listens.
    Client,
}

impl ZenohMode {
    fn as_json5(self) -> &'static str {
        match self {
            ZenohMode::Peer => "\"peer\"",
            ZenohMode::Client => "\"client\"",
        }
    }
}

/// Settings of one Zenoh link end. In TOML:
///
/// ```toml
/// [zenoh]
/// mode = "peer"
/// listen = ["tcp/127.0.0.1:7447"]   # the slave, say
/// connect = []                      # the master: connect = ["tcp/127.0.0.1:7447"]
/// ```
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Peer or client.
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `"tcp/127.0.0.1:7447"`. Empty in peer mode: listen on
    /// `tcp/127.0.0.1:0` (loopback, any free port), never on every interface. Ignored in
    /// client mode (clients do not listen).
    pub listen: Vec<String>,
    /// Endpoints to connect to, e.g. `"tcp/127.0.0.1:7447"` (required in client mode).
    pub connect: Vec<String>,
    /// Optional Zenoh json5 configuration file (TLS, authentication, access control, tuning).
    /// It is loaded first; `mode`, `listen`, `connect` and the scouting and latency settings
    /// below are applied over it.
    pub config_file: Option<String>,
    /// Zenoh's low-latency transport (`transport/unicast/lowlatency`, which also needs
    /// `transport/unicast/qos/enabled = false`, so priorities are ignored). Both ends must agree.
    pub low_latency: bool,
    /// Received messages buffered until `try_recv` takes them (1 to 65 536); when full, the
    /// oldest is dropped.
    pub queue_capacity: usize,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        ZenohConfig {
            mode: ZenohMode::Peer,
            listen: Vec::new(),
            connect: Vec::new(),
            config_file: None,
            low_latency: false,
            queue_capacity: 64,
        }
    }
}

impl ZenohConfig {
    /// A peer that listens on `tcp/127.0.0.1:<port>`.
    pub fn listen_on_loopback(port: u16) -> Self {
        ZenohConfig {
            listen: vec![format!("tcp/127.0.0.1:{port}")],
            ..Self::default()
        }
    }

    /// A peer that connects to `tcp/127.0.0.1:<port>` (and listens on a loopback ephemeral
    /// port only).
    pub fn connect_to_loopback(port: u16) -> Self {
        ZenohConfig {
            connect: vec![format!("tcp/127.0.0.1:{port}")],
            ..Self::default()
        }
    }

    /// The Zenoh configuration these settings describe.
    pub fn to_zenoh(&self) -> Result<Config, ZenohError> {
        if self.queue_capacity == 0 || self.queue_capacity > 65_536 {
            return Err(ZenohError::Config {
                key: "queue_capacity".into(),
                message: format!(
                    "{} is out of range: allowed 1 to 65536",
                    self.queue_capacity
                ),
            });
        }
        if self.mode == ZenohMode::Client && self.connect.is_empty() {
            return Err(ZenohError::Config {
                key: "connect".into(),
                message: "a client needs at least one endpoint to connect to".into(),
            });
        }
        let mut config = match &self.config_file {
            Some(path) => Config::from_file(path).map_err(|e| ZenohError::ConfigFile {
                path: path.clone(),
                message: e.to_string(),
            })?,
            None => Config::default(),
        };
        let listen: Vec<String> = match self.mode {
            ZenohMode::Client => Vec::new(),
            ZenohMode::Peer if self.listen.is_empty() => vec!["tcp/127.0.0.1:0".into()],
            ZenohMode::Peer => self.listen.clone(),
        };
        set(&mut config, "mode", self.mode.as_json5())?;
        set(&mut config, "listen/endpoints", &json_list(&listen))?;
        set(&mut config, "connect/endpoints", &json_list(&self.connect))?;
        set(&mut config, "scouting/multicast/enabled", "false")?;
        if self.low_latency {
            set(&mut config, "transport/unicast/lowlatency", "true")?;
            set(&mut config, "transport/unicast/qos/enabled", "false")?;
        }
        Ok(config)
    }
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("{s:?}")).collect();
    format!("[{}]", quoted.join(","))
}

fn set(config: &mut Config, key: &str, value: &str) -> Result<(), ZenohError> {
    config
        .insert_json5(key, value)
        .map_err(|e| ZenohError::Config {
            key: key.into(),
            message: e.to_string(),
        })
}

/// Why a Zenoh link could not be set up (construction only; the hot path uses [`LinkError`]).
#[derive(Debug, thiserror::Error)]
pub enum ZenohError {
    /// A setting was refused (by us or by Zenoh).
    #[error("zenoh setting {key}: {message}")]
    Config {
        /// The setting, as a Zenoh configuration path or our field name.
        key: String,
        /// Why.
        message: String,
    },
    /// The json5 configuration file could not be read or parsed.
    #[error("zenoh configuration file {path}: {message}")]
    ConfigFile {
        /// The file.
        path: String,
        /// Zenoh's message.
        message: String,
    },
    /// The session could not be opened (e.g. the listen endpoint is taken).
    #[error("cannot open the zenoh session: {0}")]
    Open(String),
    /// The publisher or subscriber could not be declared.
    #[error("cannot declare the zenoh {what} on {key}: {message}")]
    Declare {
        /// "publisher" or "subscriber".
        what: &'static str,
        /// The key expression.
        key: String,
        /// Zenoh's message.
        message: String,
    },
    /// Another process already holds this role on this arm (its liveliness token is alive).
    #[error(
        "refused: another {role} already serves arm {arm_id} (its liveliness token {key} is alive on the Zenoh network): one master and one slave per arm"
    )]
    RoleTaken {
        /// "master" or "slave".
        role: String,
        /// The arm.
        arm_id: u16,
        /// The liveliness key expression.
        key: String,
    },
    /// The message type encodes to more than [`MAX_WIRE_SIZE`] bytes.
    #[error("{name} encodes to {size} bytes, more than the {max} this link supports")]
    MessageTooLarge {
        /// Message name.
        name: &'static str,
        /// Its encoded size.
        size: usize,
        /// [`MAX_WIRE_SIZE`].
        max: usize,
    },
}

/// The key expression of messages named `name` ([`WireMessage::NAME`]) for `arm_id`:
/// `h4/<arm_id>/<name>`.
pub fn key_expr(arm_id: u16, name: &str) -> String {
    format!("h4/{arm_id}/{name}")
}

/// How long [`ZenohLink::claim_role`] lets the new session meet the network (peers learn of
/// each other by gossip through the peer they connect to) before it asks who is alive.
pub const ROLE_SETTLE: std::time::Duration = std::time::Duration::from_millis(1000);

/// What the subscriber callback shares with the link end.
struct Inbox<In> {
    queue: Mutex<Ring<In>>,
    /// Signalled after a message is queued while a thread waits in
    /// [`ZenohLink::wait_for_message`] (and so [`Link::wait_message`]: the phase-locked slave
    /// between its cycles, the master for the feedback of its cycle); `waiters` keeps the
    /// callback from paying a wake-up syscall when nobody waits.
    arrived: std::sync::Condvar,
    waiters: std::sync::atomic::AtomicUsize,
    rejects: Mutex<DecodeRejects>,
    last_decode_error: Mutex<Option<WireError>>,
}

impl<In: WireMessage> Inbox<In> {
    fn on_sample(&self, sample: &Sample) {
        let payload = sample.payload();
        let mut buf = [0u8; MAX_WIRE_SIZE];
        // The whole payload, or the first MAX_WIRE_SIZE bytes of a longer one: a payload of
        // another size is judged by its header first (docs/wire.md, "Checks in order"), so a
        // message of another version is counted as such whatever its size.
        let mut at = 0;
        for slice in payload.slices() {
            let n = slice.len().min(MAX_WIRE_SIZE - at);
            if let (Some(dst), Some(src)) = (buf.get_mut(at..at + n), slice.get(..n)) {
                dst.copy_from_slice(src);
            }
            at += n;
            if at == MAX_WIRE_SIZE {
                break;
            }
        }
        let decoded = decode_payload::<In>(buf.get(..at).unwrap_or(&[]), payload.len());
        match decoded {
            Ok(msg) => {
                if let Ok(mut q) = self.queue.lock() {
                    q.push(msg);
                }
                if self.waiters.load(std::sync::atomic::Ordering::Acquire) > 0 {
                    self.arrived.notify_all();
                }
            }
            Err(e) => {
                if let Ok(mut r) = self.rejects.lock() {
                    r.count(&e);
                }
                if let Ok(mut last) = self.last_decode_error.lock() {
                    *last = Some(e);
                }
            }
        }
    }
}

/// One end of a Zenoh link: publishes `Out` on `h4/<arm_id>/<Out::NAME>`, receives `In` from
/// `h4/<arm_id>/<In::NAME>`.
pub struct ZenohLink<Out: WireMessage, In: WireMessage> {
    publisher: Publisher<'static>,
    // Kept alive: dropping it undeclares the subscription.
    _subscriber: Subscriber<()>,
    inbox: Arc<Inbox<In>>,
    publish_errors: u64,
    // The role this end claimed ([`ZenohLink::claim_role`]); undeclared when dropped.
    _role_token: Option<::zenoh::liveliness::LivelinessToken>,
    session: Session,
    arm_id: u16,
    _marker: PhantomData<fn(Out)>,
}

/// The master's end over Zenoh.
pub type MasterZenohLink = ZenohLink<Command, Feedback>;
/// The slave's end over Zenoh.
pub type SlaveZenohLink = ZenohLink<Feedback, Command>;

impl<Out: WireMessage, In: WireMessage> std::fmt::Debug for ZenohLink<Out, In> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZenohLink")
            .field("arm_id", &self.arm_id)
            .field("publishes", &Out::NAME)
            .field("receives", &In::NAME)
            .field("zid", &self.session.zid())
            .finish()
    }
}

/// Zenoh's own log (the `tracing` of its transport: links, handshakes, dropped frames) on
/// stdout, filtered by `RUST_LOG` (e.g. `RUST_LOG=zenoh_transport=debug`); nothing when
/// `RUST_LOG` is unset. Call once, first thing in `main`.
pub fn init_log_from_env() {
    ::zenoh::try_init_log_from_env();
}

impl<Out: WireMessage, In: WireMessage> ZenohLink<Out, In> {
    /// Opens a session with `config` and declares the publisher and subscriber of `arm_id`.
    /// Blocks while Zenoh starts (tens of ms); call it before the control loop.
    pub fn open(arm_id: u16, config: &ZenohConfig) -> Result<Self, ZenohError> {
        for (name, size) in [(Out::NAME, Out::WIRE_SIZE), (In::NAME, In::WIRE_SIZE)] {
            if size > MAX_WIRE_SIZE {
                return Err(ZenohError::MessageTooLarge {
                    name,
                    size,
                    max: MAX_WIRE_SIZE,
                });
            }
        }
        let zconfig = config.to_zenoh()?;
        let session = ::zenoh::open(zconfig)
            .wait()
            .map_err(|e| ZenohError::Open(e.to_string()))?;
        let out_key = key_expr(arm_id, Out::NAME);
        let in_key = key_expr(arm_id, In::NAME);
        let publisher = session
            .declare_publisher(out_key.clone())
            .express(true)
            .priority(Priority::RealTime)
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| ZenohError::Declare {
                what: "publisher",
                key: out_key,
                message: e.to_string(),
            })?;
        let inbox = Arc::new(Inbox {
            queue: Mutex::new(Ring::new(config.queue_capacity)),
            arrived: std::sync::Condvar::new(),
            waiters: std::sync::atomic::AtomicUsize::new(0),
            rejects: Mutex::new(DecodeRejects::default()),
            last_decode_error: Mutex::new(None),
        });
        let cb_inbox = Arc::clone(&inbox);
        let subscriber = session
            .declare_subscriber(in_key.clone())
            .callback(move |sample: Sample| cb_inbox.on_sample(&sample))
            .wait()
            .map_err(|e| ZenohError::Declare {
                what: "subscriber",
                key: in_key,
                message: e.to_string(),
            })?;
        Ok(ZenohLink {
            publisher,
            _subscriber: subscriber,
            inbox,
            publish_errors: 0,
            _role_token: None,
            session,
            arm_id,
            _marker: PhantomData,
        })
    }

    /// Blocks until a message is waiting for [`Link::try_recv`] or `timeout` passes; true if
    /// one is waiting. For a receiver that has nothing else to do until the message (a tool,
    /// the round-trip bench, a phase-locked loop through [`Link::wait_message`]). Waiting this way leaves the
    /// CPU to Zenoh's own threads, which deliver the message; spinning on `try_recv` on a
    /// 2-core machine competes with them.
    pub fn wait_for_message(&self, timeout: std::time::Duration) -> bool {
        use std::sync::atomic::Ordering;
        let Ok(queue) = self.inbox.queue.lock() else {
            return false;
        };
        if !queue.is_empty() {
            return true;
        }
        self.inbox.waiters.fetch_add(1, Ordering::AcqRel);
        let waited = self
            .inbox
            .arrived
            .wait_timeout_while(queue, timeout, |q| q.is_empty());
        self.inbox.waiters.fetch_sub(1, Ordering::AcqRel);
        waited.is_ok_and(|(q, _)| !q.is_empty())
    }

    /// Claims `role` ("master" or "slave") for this arm on the Zenoh network: refused
    /// ([`ZenohError::RoleTaken`]) if another session holds the liveliness token
    /// `h4/<arm_id>/<role>` (asked with a liveliness query, answered by the sessions this one
    /// is connected to, waiting at most `timeout`), otherwise the token is declared and kept
    /// while this end lives (a killed process's token vanishes with its session).
    pub fn claim_role(
        &mut self,
        role: &str,
        timeout: std::time::Duration,
    ) -> Result<(), ZenohError> {
        let key = key_expr(self.arm_id, role);
        let declare = |message: String| ZenohError::Declare {
            what: "liveliness token",
            key: key.clone(),
            message,
        };
        std::thread::sleep(ROLE_SETTLE);
        let replies = self
            .session
            .liveliness()
            .get(key.as_str())
            .timeout(timeout)
            .wait()
            .map_err(|e| declare(e.to_string()))?;
        while let Ok(reply) = replies.recv() {
            if reply.result().is_ok() {
                return Err(ZenohError::RoleTaken {
                    role: role.to_string(),
                    arm_id: self.arm_id,
                    key,
                });
            }
        }
        let token = self
            .session
            .liveliness()
            .declare_token(key.as_str())
            .wait()
            .map_err(|e| declare(e.to_string()))?;
        self._role_token = Some(token);
        Ok(())
    }

    /// The arm this end serves.
    pub fn arm_id(&self) -> u16 {
        self.arm_id
    }

    /// Why the last undecodable payload was refused.
    pub fn last_decode_error(&self) -> Option<WireError> {
        self.inbox.last_decode_error.lock().ok().and_then(|e| *e)
    }

    /// Received messages dropped because `try_recv` did not take them in time.
    pub fn dropped_incoming(&self) -> u64 {
        self.inbox.queue.lock().map_or(0, |q| q.dropped())
    }

    /// Publications Zenoh refused.
    pub fn publish_errors(&self) -> u64 {
        self.publish_errors
    }

    /// The Zenoh session (e.g. to read its id or the connected peers).
    pub fn session(&self) -> &Session {
        &self.session
    }
}

impl<Out: WireMessage, In: WireMessage> Link<Out, In> for ZenohLink<Out, In> {
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        let mut buf = [0u8; MAX_WIRE_SIZE];
        let bytes = buf.get_mut(..Out::WIRE_SIZE).ok_or(LinkError::SendFailed {
            transport: TRANSPORT,
        })?;
        msg.encode_into(bytes).map_err(|_| LinkError::SendFailed {
            transport: TRANSPORT,
        })?;
        let payload = ZBytes::from(&*bytes);
        self.publisher.put(payload).wait().map_err(|_| {
            self.publish_errors += 1;
            LinkError::SendFailed {
                transport: TRANSPORT,
            }
        })
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        let mut q = self
            .inbox
            .queue
            .lock()
            .map_err(|_| LinkError::ReceiveFailed {
                transport: TRANSPORT,
            })?;
        Ok(q.pop())
    }

    fn decode_rejects(&self) -> DecodeRejects {
        self.inbox
            .rejects
            .lock()
            .map_or(DecodeRejects::default(), |r| *r)
    }

    /// Sleeps on the subscriber callback's signal ([`ZenohLink::wait_for_message`]).
    fn wait_message(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        let timeout = deadline.saturating_duration_since(std::time::Instant::now());
        Ok(self.wait_for_message(timeout))
    }

    fn can_wake(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_become_zenoh_config() {
        let cfg = ZenohConfig::listen_on_loopback(7999);
        let z = cfg.to_zenoh().unwrap();
        let json = format!("{z}");
        assert!(json.contains("tcp/127.0.0.1:7999"), "{json}");
        let client = ZenohConfig {
            mode: ZenohMode::Client,
            ..ZenohConfig::default()
        };
        assert!(matches!(
            client.to_zenoh(),
            Err(ZenohError::Config { ref key, .. }) if key == "connect"
        ));
        let bad = ZenohConfig {
            queue_capacity: 0,
            ..ZenohConfig::default()
        };
        assert!(bad.to_zenoh().is_err());
    }

    #[test]
    fn config_parses_from_toml_and_rejects_unknown_keys() {
        let cfg: ZenohConfig =
            toml::from_str("mode = \"client\"\nconnect = [\"tcp/10.0.0.2:7447\"]\n").unwrap();
        assert_eq!(cfg.mode, ZenohMode::Client);
        assert!(toml::from_str::<ZenohConfig>("lisen = []\n").is_err());
    }

    #[test]
    fn missing_config_file_is_reported() {
        let cfg = ZenohConfig {
            config_file: Some("/nonexistent/zenoh.json5".into()),
            ..ZenohConfig::default()
        };
        assert!(matches!(cfg.to_zenoh(), Err(ZenohError::ConfigFile { .. })));
    }
}
