//! A user-space relay between the two hosts ([`crate::netns`]): a small UDP or TCP forwarder
//! (std threads) that delays, jitters, drops, stalls and cuts the traffic, seeded.
//!
//! It runs inside the master's namespace, listens on the master host's address and forwards
//! across the veth pair to the slave's endpoint, so the master connects to the relay and
//! everything it says crosses the real network. Each direction has its own random stream.
//! What it does to the traffic is an [`ImpairmentConfig`] (the simulation's keys:
//! `delay_ms`, `jitter_ms`, `loss`, `blackout_ms`, `blackout_every_ms`, `seed`) plus a
//! manual cut ([`Relay::cut`]), both changeable while it runs ([`Relay::set`]).
//!
//! * **UDP** (per datagram): delay and jitter per datagram; loss, a blackout and a cut drop
//!   it. Datagrams leave in order (a network queue: a datagram is never sent before the one
//!   ahead of it).
//! * **TCP** (per chunk read): delay and jitter per chunk, in order; a stream cannot lose
//!   bytes, so loss is ignored and a blackout or cut *holds* the bytes until it ends (what TCP
//!   does over a pulled cable: retransmission, then everything at once). The connection stays
//!   open.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use h4_shared::rng::Rng;
use h4_transport::impair::ImpairmentConfig;

use crate::netns::{Host, TwoHosts};

/// What the relay counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RelayCounters {
    /// Datagrams / chunks received from either side.
    pub received: u64,
    /// Forwarded.
    pub forwarded: u64,
    /// Dropped (UDP: loss, blackout, cut).
    pub dropped: u64,
}

#[derive(Debug)]
struct Shared {
    cfg: ImpairmentConfig,
    cut: bool,
    counters: RelayCounters,
}

/// The relay's state shared by its threads.
#[derive(Debug)]
struct Control {
    shared: Mutex<Shared>,
    stop: AtomicBool,
    start: Instant,
}

impl Control {
    fn lock(&self) -> std::sync::MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn now_ns(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }
}

/// What happens to one datagram or chunk.
enum Fate {
    /// Deliver at this time (ns since the relay started).
    At(u64),
    /// Drop it (UDP only).
    Drop,
    /// Hold it until the cut or blackout ends, then deliver (TCP).
    Hold,
}

/// One direction's scheduler: decides each packet's fate and keeps them in order.
struct Lane {
    control: Arc<Control>,
    rng: Rng,
    stream: bool,
    queue: VecDeque<(u64, Vec<u8>)>,
    held: Vec<Vec<u8>>,
    last_due_ns: u64,
}

impl Lane {
    fn new(control: Arc<Control>, seed_stream: u64, stream: bool) -> Self {
        let seed = control.lock().cfg.seed;
        Lane {
            control,
            rng: Rng::fork(seed, seed_stream),
            stream,
            queue: VecDeque::new(),
            held: Vec::new(),
            last_due_ns: 0,
        }
    }

    fn fate(&mut self, now: u64) -> Fate {
        let mut s = self.control.lock();
        s.counters.received += 1;
        let cfg = s.cfg;
        let lost = self.rng.bernoulli(cfg.loss);
        let jitter = if cfg.jitter_ms > 0.0 {
            self.rng.uniform_in(-cfg.jitter_ms, cfg.jitter_ms)
        } else {
            0.0
        };
        let blocked = s.cut || cfg.in_blackout(now);
        if self.stream && blocked {
            return Fate::Hold;
        }
        if blocked || (lost && !self.stream) {
            s.counters.dropped += 1;
            return Fate::Drop;
        }
        let delay_ns = ((cfg.delay_ms + jitter).max(0.0) * 1e6) as u64;
        Fate::At(now.saturating_add(delay_ns))
    }

    /// Takes in one packet.
    fn push(&mut self, bytes: Vec<u8>) {
        let now = self.control.now_ns();
        match self.fate(now) {
            Fate::Drop => {}
            Fate::Hold => self.held.push(bytes),
            Fate::At(due) => {
                self.release_held(now);
                let due = due.max(self.last_due_ns);
                self.last_due_ns = due;
                self.queue.push_back((due, bytes));
            }
        }
    }

    /// A stream's bytes held by a cut go out first once it has ended.
    fn release_held(&mut self, now: u64) {
        if self.held.is_empty() {
            return;
        }
        let blocked = {
            let s = self.control.lock();
            s.cut || s.cfg.in_blackout(now)
        };
        if !blocked {
            for b in self.held.drain(..) {
                self.queue.push_back((now.max(self.last_due_ns), b));
            }
        }
    }

    /// Hands every packet that is due to `send`.
    fn flush(&mut self, mut send: impl FnMut(&[u8]) -> std::io::Result<()>) -> std::io::Result<()> {
        let now = self.control.now_ns();
        self.release_held(now);
        while self.queue.front().is_some_and(|(due, _)| *due <= now) {
            if let Some((_, b)) = self.queue.pop_front() {
                send(&b)?;
                self.control.lock().counters.forwarded += 1;
            }
        }
        Ok(())
    }
}

/// Transport of the relay.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Proto {
    /// Datagrams (Zenoh `udp/…`).
    Udp,
    /// A byte stream (Zenoh `tcp/…`).
    Tcp,
}

/// A running relay; stopped and joined when dropped.
#[derive(Debug)]
pub struct Relay {
    control: Arc<Control>,
    listen: SocketAddr,
    threads: Vec<JoinHandle<()>>,
}

/// How long a relay thread waits for traffic before it looks at its queue and the stop flag.
const POLL: Duration = Duration::from_micros(500);

impl Relay {
    /// Starts a relay of `proto` in the master's namespace of `hosts`, listening on the master
    /// host's address (a free port), forwarding to `target` (the slave's endpoint).
    pub fn start(
        hosts: &TwoHosts,
        proto: Proto,
        target: SocketAddr,
        cfg: ImpairmentConfig,
    ) -> Result<Self, String> {
        let control = Arc::new(Control {
            shared: Mutex::new(Shared {
                cfg,
                cut: false,
                counters: RelayCounters::default(),
            }),
            stop: AtomicBool::new(false),
            start: Instant::now(),
        });
        let ns = hosts.namespace(Host::Master).to_string();
        let bind = SocketAddr::new(hosts.ip(Host::Master).into(), 0);
        let (tx, rx) = std::sync::mpsc::channel::<Result<SocketAddr, String>>();
        let c = Arc::clone(&control);
        let main = std::thread::spawn(move || {
            let run = || -> Result<(), String> {
                crate::netns::enter_namespace(&ns)?;
                match proto {
                    Proto::Udp => udp_relay(c, bind, target, &tx),
                    Proto::Tcp => tcp_relay(c, bind, target, &tx),
                }
            };
            if let Err(e) = run() {
                let _ = tx.send(Err(e));
            }
        });
        let listen = rx
            .recv_timeout(Duration::from_secs(10))
            .map_err(|e| format!("relay did not start: {e}"))??;
        Ok(Relay {
            control,
            listen,
            threads: vec![main],
        })
    }

    /// Where the master connects (on the master host).
    pub fn listen_addr(&self) -> SocketAddr {
        self.listen
    }

    /// Replaces the impairment (the random streams go on).
    pub fn set(&self, cfg: ImpairmentConfig) {
        self.control.lock().cfg = cfg;
    }

    /// Cuts the link (`true`) or restores it.
    pub fn cut(&self, cut: bool) {
        self.control.lock().cut = cut;
    }

    /// What it counted so far.
    pub fn counters(&self) -> RelayCounters {
        self.control.lock().counters
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.control.stop.store(true, Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// UDP: one flow per client address, as a NAT keeps one mapping per source port: each flow
/// has its own socket towards the slave (a new port there), so a client's new socket (Zenoh
/// retrying a connection whose handshake lost a datagram) is a new peer for the slave, not
/// the old, failed one's address (with one shared socket the slave's Zenoh never accepted
/// the retries and a session lossy from its first datagram never came up).
fn udp_relay(
    control: Arc<Control>,
    bind: SocketAddr,
    target: SocketAddr,
    ready: &std::sync::mpsc::Sender<Result<SocketAddr, String>>,
) -> Result<(), String> {
    let front = UdpSocket::bind(bind).map_err(|e| format!("relay bind {bind}: {e}"))?;
    front
        .set_read_timeout(Some(POLL))
        .map_err(|e| e.to_string())?;
    let listen = front.local_addr().map_err(|e| e.to_string())?;
    let _ = ready.send(Ok(listen));
    // Up (master → slave) lanes on this thread; down (slave → master) a thread per flow.
    let mut flows: Vec<(SocketAddr, UdpSocket, Lane)> = Vec::new();
    let mut downs = Vec::new();
    let mut buf = vec![0u8; 65_536];
    while !control.stop.load(Ordering::SeqCst) {
        if let Ok((n, from)) = front.recv_from(&mut buf) {
            let flow = match flows.iter().position(|f| f.0 == from) {
                Some(i) => Some(i),
                None => {
                    let stream = 2 * flows.len() as u64 + 1;
                    match udp_flow(&control, &front, bind, target, from, stream + 1) {
                        Ok((back, down)) => {
                            downs.push(down);
                            flows.push((
                                from,
                                back,
                                Lane::new(Arc::clone(&control), stream, false),
                            ));
                            Some(flows.len() - 1)
                        }
                        Err(_) => None,
                    }
                }
            };
            if let Some((_, _, lane)) = flow.and_then(|i| flows.get_mut(i)) {
                lane.push(buf[..n].to_vec());
            }
        }
        for (_, back, lane) in flows.iter_mut() {
            // A refused send (the slave not listening yet) is the network's loss.
            let _ = lane.flush(|b| back.send(b).map(|_| ()));
        }
    }
    for d in downs {
        let _ = d.join();
    }
    Ok(())
}

/// A new flow's socket towards the slave and its down thread (slave → `client`).
fn udp_flow(
    control: &Arc<Control>,
    front: &UdpSocket,
    bind: SocketAddr,
    target: SocketAddr,
    client: SocketAddr,
    down_stream: u64,
) -> Result<(UdpSocket, std::thread::JoinHandle<()>), String> {
    let back = UdpSocket::bind(SocketAddr::new(bind.ip(), 0)).map_err(|e| e.to_string())?;
    back.connect(target).map_err(|e| e.to_string())?;
    back.set_read_timeout(Some(POLL))
        .map_err(|e| e.to_string())?;
    let control = Arc::clone(control);
    let front = front.try_clone().map_err(|e| e.to_string())?;
    let from_slave = back.try_clone().map_err(|e| e.to_string())?;
    let down = std::thread::spawn(move || {
        let mut lane = Lane::new(Arc::clone(&control), down_stream, false);
        let mut buf = vec![0u8; 65_536];
        while !control.stop.load(Ordering::SeqCst) {
            if let Ok(n) = from_slave.recv(&mut buf) {
                lane.push(buf[..n].to_vec());
            }
            let _ = lane.flush(|b| front.send_to(b, client).map(|_| ()));
        }
    });
    Ok((back, down))
}

fn tcp_relay(
    control: Arc<Control>,
    bind: SocketAddr,
    target: SocketAddr,
    ready: &std::sync::mpsc::Sender<Result<SocketAddr, String>>,
) -> Result<(), String> {
    let listener = TcpListener::bind(bind).map_err(|e| format!("relay bind {bind}: {e}"))?;
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    let listen = listener.local_addr().map_err(|e| e.to_string())?;
    let _ = ready.send(Ok(listen));
    let mut pumps = Vec::new();
    let mut conn = 0u64;
    while !control.stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((client, _)) => {
                // The slave side refusing (not up yet, restarting): drop the client; it retries.
                let Ok(server) = TcpStream::connect_timeout(&target, Duration::from_secs(2)) else {
                    continue;
                };
                conn += 1;
                for (from, to, stream) in [
                    (client.try_clone(), server.try_clone(), 2 * conn + 1),
                    (server.try_clone(), client.try_clone(), 2 * conn + 2),
                ] {
                    let (Ok(from), Ok(to)) = (from, to) else {
                        continue;
                    };
                    let lane = Lane::new(Arc::clone(&control), stream, true);
                    let control = Arc::clone(&control);
                    pumps.push(std::thread::spawn(move || pump(control, lane, from, to)));
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(2))
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
    }
    for p in pumps {
        let _ = p.join();
    }
    Ok(())
}

/// One direction of one TCP connection; ends when either side closes or the relay stops
/// (and then closes both, so the peers notice).
fn pump(control: Arc<Control>, mut lane: Lane, mut from: TcpStream, mut to: TcpStream) {
    let _ = from.set_read_timeout(Some(POLL));
    let _ = to.set_nodelay(true);
    let _ = to.set_write_timeout(Some(Duration::from_secs(5)));
    let mut buf = vec![0u8; 65_536];
    while !control.stop.load(Ordering::SeqCst) {
        match from.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => lane.push(buf[..n].to_vec()),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(_) => break,
        }
        if lane.flush(|b| to.write_all(b)).is_err() {
            break;
        }
    }
    let _ = from.shutdown(std::net::Shutdown::Both);
    let _ = to.shutdown(std::net::Shutdown::Both);
}
