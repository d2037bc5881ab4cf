//! The iceoryx2 link: shared-memory publish-subscribe on one host. The `#[repr(C)]`
//! [`Command`] and [`Feedback`] are written straight into shared memory (zero-copy, no
//! encoding); the receiver still validates every message through its [`crate::gate::Gate`].
//!
//! Services are `<prefix>/<arm_id>/command` and `<prefix>/<arm_id>/feedback` (prefix `h4`),
//! so several arms share a host. Receiving is a non-blocking poll ([`Link::try_recv`]); a
//! receiver that waits for its peer ([`Link::wait_message`]: the phase-locked slave, the
//! master waiting for its cycle's feedback) blocks on the event service
//! `<prefix>/<arm_id>/<topic>/event`, which the publisher notifies after every sample: it
//! sleeps in the kernel (no core spinning on the link) and pays one wake-up (35–110 µs across
//! vCPUs on the project's VMs). The round-trip bench measures it against a busy-poll
//! (`docs/processes.md`, "Event wake-up or polling").
//!
//! Resources left by a killed process are removed when the next node is created (iceoryx2
//! cleans up dead nodes on creation), and services are opened with `open_or_create`, so a
//! restarted process re-pairs by itself.
#![allow(unsafe_code)]

use std::sync::Once;

use ::iceoryx2::port::listener::Listener;
use ::iceoryx2::port::notifier::Notifier;
use ::iceoryx2::port::publisher::Publisher;
use ::iceoryx2::port::subscriber::Subscriber;
use ::iceoryx2::prelude::*;
use ::iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use h4_shared::wire::{Command, Feedback, WireMessage};

use crate::{Link, LinkError};

/// The shortest wait handed to the event listener: its timeout counts whole microseconds and
/// zero would block for ever (see [`Link::wait_message`] for [`Iceoryx2Link`]).
const MIN_LISTENER_TIMEOUT: std::time::Duration = std::time::Duration::from_micros(1);

/// A message as it lies in shared memory: the wire struct itself.
#[derive(Clone, Copy, Debug)]
#[repr(transparent)]
pub struct Shm<M>(pub M);

// SAFETY: `Command` and `Feedback` are `#[repr(C)]`, `Copy`, hold only integers and floats
// (no pointers, no heap, no `Drop`), and have no implicit padding (checked at compile time in
// `h4_shared::wire`). The type names carry the protocol version so processes built with
// another layout cannot open the same service.
unsafe impl ZeroCopySend for Shm<Command> {
    unsafe fn type_name() -> &'static str {
        "h4_teleop::wire::Command.v1"
    }
}

// SAFETY: as for `Shm<Command>`.
unsafe impl ZeroCopySend for Shm<Feedback> {
    unsafe fn type_name() -> &'static str {
        "h4_teleop::wire::Feedback.v1"
    }
}

/// Why the iceoryx2 link could not be opened.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: {what}: {detail}")]
pub struct Iceoryx2Error {
    /// The step that failed.
    pub what: &'static str,
    /// iceoryx2's message.
    pub detail: String,
}

fn err(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> Iceoryx2Error {
    move |e| Iceoryx2Error {
        what,
        detail: format!("{e:?}"),
    }
}

/// Where the link lives.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Iceoryx2Options {
    /// Service name prefix (default `h4`).
    pub prefix: String,
    /// Arm id, part of the service names.
    pub arm_id: u16,
    /// Messages a subscriber buffers before the oldest are overwritten.
    pub buffer: usize,
}

impl Iceoryx2Options {
    /// Defaults for `arm_id`.
    pub fn new(arm_id: u16) -> Self {
        Iceoryx2Options {
            prefix: "h4".to_string(),
            arm_id,
            buffer: 16,
        }
    }
}

/// One end of the iceoryx2 link.
pub struct Iceoryx2Link<Out, In>
where
    Shm<Out>: ZeroCopySend,
    Shm<In>: ZeroCopySend,
    Out: std::fmt::Debug + 'static,
    In: std::fmt::Debug + 'static,
{
    publisher: Publisher<ipc::Service, Shm<Out>, ()>,
    subscriber: Subscriber<ipc::Service, Shm<In>, ()>,
    /// Notifies the peer's listener after each published sample (`<…>/<out topic>/event`).
    notifier: Notifier<ipc::Service>,
    /// Woken by the peer's notifier (`<…>/<in topic>/event`): [`Link::wait_message`].
    listener: Listener<ipc::Service>,
    // Dropped last: ports belong to the node.
    _node: Node<ipc::Service>,
}

impl<Out, In> std::fmt::Debug for Iceoryx2Link<Out, In>
where
    Shm<Out>: ZeroCopySend,
    Shm<In>: ZeroCopySend,
    Out: std::fmt::Debug + 'static,
    In: std::fmt::Debug + 'static,
{
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Iceoryx2Link").finish_non_exhaustive()
    }
}

/// Opens (or creates) the publish-subscribe service `<prefix>/<arm_id>/<topic>` of `Shm<M>`.
fn service<M>(
    node: &Node<ipc::Service>,
    opts: &Iceoryx2Options,
    topic: &str,
) -> Result<PortFactory<ipc::Service, Shm<M>, ()>, String>
where
    Shm<M>: ZeroCopySend,
    M: std::fmt::Debug + 'static,
{
    let name = format!("{}/{}/{}", opts.prefix, opts.arm_id, topic);
    let name = ServiceName::new(&name).map_err(|e| format!("service name {name}: {e:?}"))?;
    node.service_builder(&name)
        .publish_subscribe::<Shm<M>>()
        .history_size(1)
        .subscriber_max_buffer_size(opts.buffer.max(1))
        .enable_safe_overflow(true)
        .max_publishers(MAX_PUBLISHERS)
        .max_subscribers(4)
        .max_nodes(8)
        .open_or_create()
        .map_err(|e| format!("{e:?}"))
}

/// Opens (or creates) the event service `<prefix>/<arm_id>/<topic>/event`: the publisher of
/// `<topic>` notifies it after every sample, the subscriber's side listens on it.
fn event_service(
    node: &Node<ipc::Service>,
    opts: &Iceoryx2Options,
    topic: &str,
) -> Result<::iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, String> {
    let name = format!("{}/{}/{}/event", opts.prefix, opts.arm_id, topic);
    let name = ServiceName::new(&name).map_err(|e| format!("service name {name}: {e:?}"))?;
    node.service_builder(&name)
        .event()
        .max_notifiers(4)
        .max_listeners(4)
        .max_nodes(8)
        .open_or_create()
        .map_err(|e| format!("{e:?}"))
}

/// Publishers per service: one master publishes commands, one slave feedback. A second
/// process of the same kind on the same prefix and arm is refused when it creates its
/// publisher (monitors only subscribe: [`feedback_monitor`]).
pub const MAX_PUBLISHERS: usize = 1;

static QUIET: Once = Once::new();

/// A node named `<prefix>/<arm_id>/<role>` (so [`resources`] can tell ours apart).
fn node(opts: &Iceoryx2Options, role: &str) -> Result<Node<ipc::Service>, Iceoryx2Error> {
    let name = format!("{}/{}/{role}", opts.prefix, opts.arm_id);
    let name = NodeName::new(&name).map_err(|e| err("node name")(&e))?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| err("node")(&e))
}

fn open<Out, In>(
    opts: &Iceoryx2Options,
    out_topic: &str,
    in_topic: &str,
) -> Result<Iceoryx2Link<Out, In>, Iceoryx2Error>
where
    Shm<Out>: ZeroCopySend,
    Shm<In>: ZeroCopySend,
    Out: std::fmt::Debug + 'static,
    In: std::fmt::Debug + 'static,
{
    // iceoryx2 warns on every start that no config file was loaded; keep errors only
    // unless the user asks for more with IOX2_LOG_LEVEL.
    QUIET.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let node = node(opts, out_topic)?;
    let out_service = service::<Out>(&node, opts, out_topic).map_err(|detail| Iceoryx2Error {
        what: "open or create the outgoing service",
        detail,
    })?;
    let in_service = service::<In>(&node, opts, in_topic).map_err(|detail| Iceoryx2Error {
        what: "open or create the incoming service",
        detail,
    })?;
    let publisher = out_service.publisher_builder().create().map_err(|e| {
        if matches!(
            e,
            ::iceoryx2::port::publisher::PublisherCreateError::ExceedsMaxSupportedPublishers
        ) {
            Iceoryx2Error {
                what: "refused",
                detail: format!(
                    "another process already publishes on the service {}/{}/{out_topic}: one master and one slave per arm and prefix",
                    opts.prefix, opts.arm_id
                ),
            }
        } else {
            err("publisher")(&e)
        }
    })?;
    let subscriber = in_service
        .subscriber_builder()
        .buffer_size(opts.buffer.max(1))
        .create()
        .map_err(|e| err("subscriber")(&e))?;
    let notifier = event_service(&node, opts, out_topic)
        .map_err(|detail| Iceoryx2Error {
            what: "open or create the outgoing event service",
            detail,
        })?
        .notifier_builder()
        .create()
        .map_err(|e| err("notifier")(&e))?;
    let listener = event_service(&node, opts, in_topic)
        .map_err(|detail| Iceoryx2Error {
            what: "open or create the incoming event service",
            detail,
        })?
        .listener_builder()
        .create()
        .map_err(|e| err("listener")(&e))?;
    Ok(Iceoryx2Link {
        publisher,
        subscriber,
        notifier,
        listener,
        _node: node,
    })
}

/// Removes the shared-memory segments and files of dead nodes (processes that were killed
/// without cleaning up) and returns how many dead nodes were found. Creating a node does
/// the same by default; calling this first lets a process report it.
pub fn remove_stale_nodes() -> Result<usize, Iceoryx2Error> {
    QUIET.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let mut dead = 0;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            dead += 1;
            // Another process may be removing the same node: not an error.
            let _ = view.try_remove_stale_resources();
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("list nodes")(&e))?;
    Ok(dead)
}

/// A receive-only end on `<prefix>/<arm_id>/<topic>` (a monitor: it takes no publisher slot,
/// so it never keeps the master or the slave out).
pub struct Iceoryx2Monitor<In>
where
    Shm<In>: ZeroCopySend,
    In: std::fmt::Debug + 'static,
{
    subscriber: Subscriber<ipc::Service, Shm<In>, ()>,
    _node: Node<ipc::Service>,
}

impl<In> std::fmt::Debug for Iceoryx2Monitor<In>
where
    Shm<In>: ZeroCopySend,
    In: std::fmt::Debug + 'static,
{
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Iceoryx2Monitor").finish_non_exhaustive()
    }
}

impl<In> Iceoryx2Monitor<In>
where
    Shm<In>: ZeroCopySend,
    In: Copy + std::fmt::Debug + 'static,
{
    /// The next message, if any (non-blocking).
    pub fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(sample.payload().0)),
            Ok(None) => Ok(None),
            Err(_) => Err(LinkError::ReceiveFailed {
                transport: "iceoryx2",
            }),
        }
    }
}

/// A monitor of the slave's feedback on `opts` (receive only).
pub fn feedback_monitor(
    opts: &Iceoryx2Options,
) -> Result<Iceoryx2Monitor<Feedback>, Iceoryx2Error> {
    QUIET.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let node = node(opts, "monitor")?;
    let service = service::<Feedback>(&node, opts, "feedback").map_err(|detail| Iceoryx2Error {
        what: "open or create the feedback service",
        detail,
    })?;
    let subscriber = service
        .subscriber_builder()
        .buffer_size(opts.buffer.max(1))
        .create()
        .map_err(|e| err("subscriber")(&e))?;
    Ok(Iceoryx2Monitor {
        subscriber,
        _node: node,
    })
}

/// What iceoryx2 holds on this host under one prefix ([`resources`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Resources {
    /// Nodes of live processes named under the prefix.
    pub alive_nodes: usize,
    /// Nodes of dead processes named under the prefix whose resources were not removed yet.
    pub dead_nodes: usize,
    /// Nodes iceoryx2 cannot inspect (no permission, being created or removed), any name.
    pub other_nodes: usize,
    /// Services whose name starts with the prefix.
    pub services: Vec<String>,
}

/// Lists, with iceoryx2's own node and service listing, the nodes (alive and dead) and the
/// services on this host whose names start with `prefix` (our nodes are named
/// `<prefix>/<arm_id>/<role>`).
pub fn resources(prefix: &str) -> Result<Resources, Iceoryx2Error> {
    QUIET.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let mut r = Resources::default();
    use ::iceoryx2::node::NodeView;
    let ours = |d: Option<&::iceoryx2::node::NodeDetails>| {
        d.is_some_and(|d| d.name().as_str().starts_with(prefix))
    };
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        match &state {
            NodeState::<ipc::Service>::Alive(v) if ours(v.details().as_ref()) => {
                r.alive_nodes += 1;
            }
            NodeState::<ipc::Service>::Dead(v) if ours(v.details().as_ref()) => {
                r.dead_nodes += 1;
            }
            NodeState::<ipc::Service>::Alive(_) | NodeState::<ipc::Service>::Dead(_) => {}
            _ => r.other_nodes += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("list nodes")(&e))?;
    ipc::Service::list(Config::global_config(), |service| {
        let name = service.static_details.name().to_string();
        if name.starts_with(prefix) {
            r.services.push(name);
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("list services")(&e))?;
    r.services.sort();
    Ok(r)
}

/// The master's end: publishes commands, receives feedback.
pub fn master(opts: &Iceoryx2Options) -> Result<Iceoryx2Link<Command, Feedback>, Iceoryx2Error> {
    open(opts, "command", "feedback")
}

/// The slave's end: publishes feedback, receives commands.
pub fn slave(opts: &Iceoryx2Options) -> Result<Iceoryx2Link<Feedback, Command>, Iceoryx2Error> {
    open(opts, "feedback", "command")
}

impl<Out, In> Link<Out, In> for Iceoryx2Link<Out, In>
where
    Out: WireMessage + std::fmt::Debug,
    In: WireMessage + std::fmt::Debug,
    Shm<Out>: ZeroCopySend,
    Shm<In>: ZeroCopySend,
{
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        let failed = LinkError::SendFailed {
            transport: "iceoryx2",
        };
        let sample = self.publisher.loan_uninit().map_err(|_| failed)?;
        let sample = sample.write_payload(Shm(*msg));
        sample.send().map_err(|_| failed)?;
        // The sample is delivered whatever the notification does: a lost wake-up leaves a
        // waiting peer to its own clock for one cycle, so a failure is not the link's.
        let _ = self.notifier.notify();
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(sample.payload().0)),
            Ok(None) => Ok(None),
            Err(_) => Err(LinkError::ReceiveFailed {
                transport: "iceoryx2",
            }),
        }
    }

    /// Blocks on the event service's listener, which the peer's publisher notifies after
    /// every sample; a notification for a sample already taken (the listener collects them
    /// all) is slept through again until the deadline.
    ///
    /// A deadline less than a microsecond away is reached without blocking: iceoryx2 0.10's
    /// listener turns its timeout into a `timeval` by whole microseconds, and a zero
    /// `SO_RCVTIMEO` means "no timeout", so a sub-microsecond wait on a silent peer never
    /// returned (the restarted slave of `tests/processes.rs` froze its loop that way).
    fn wait_message(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        let failed = LinkError::ReceiveFailed {
            transport: "iceoryx2",
        };
        loop {
            if self.subscriber.has_samples().map_err(|_| failed)? {
                // Forget the notifications of what is waiting: the next wait sleeps.
                self.listener.try_wait(|_| {}).map_err(|_| failed)?;
                return Ok(true);
            }
            let timeout = deadline.saturating_duration_since(std::time::Instant::now());
            if timeout < MIN_LISTENER_TIMEOUT {
                return Ok(false);
            }
            self.listener
                .timed_wait(|_| {}, timeout)
                .map_err(|_| failed)?;
        }
    }

    fn can_wake(&self) -> bool {
        true
    }
}
