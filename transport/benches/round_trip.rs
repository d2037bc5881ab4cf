//! Round-trip latency at 1 kHz pacing, master → slave → master, through our [`Link`] types
//! and, in the same run, bare library ping-pongs and a plain UDP loopback baseline.
//!
//! Ping (the master) runs on the main thread, paced at 1 kHz by `h4_telemetry::rt::Pacer`; after
//! each publish it waits for the reply. Pong (the slave) runs on its own thread or process and
//! answers each message at once. Both wait by busy-polling, except on the "event wake-up"
//! paths, where every send notifies an iceoryx2 event and the receiver blocks on its listener
//! (iceoryx2's own wake-up). Figures are µs; processes' CPU is % of one core.
//!
//! ```text
//! CARGO_TARGET_DIR=/work/target-transport cargo bench -p h4-transport --bench round_trip
//! H4_BENCH_CYCLES=10000 cargo bench -p h4-transport --bench round_trip -- zenoh udp
//! ```
//! Zenoh settings under test: `H4_BENCH_ZENOH_CONFIG=config/zenoh/low-latency.json5` (a json5
//! file every Zenoh end of the run loads), `H4_BENCH_ZENOH_PROTO=udp|unixsock-stream` (the
//! link), `ZENOH_RUNTIME` (Zenoh's own thread pools); docs/remote.md, "Zenoh at 1 kHz".
//! Arguments select paths by substring (default: all). `H4_BENCH_CYCLES` sets the measured
//! round trips per path (default 5000, after 200 warm-up ones).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::spin_loop;
use std::io::{BufRead, BufReader, Write};
use std::net::UdpSocket;
use std::process::{Command as Process, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use h4_shared::wire::{Command, Feedback, PROTOCOL_VERSION, WireMessage};
use h4_telemetry::rt::{Histogram, Pacer};
use h4_transport::Link;

const PERIOD: Duration = Duration::from_millis(1);
const SPIN: Duration = Duration::from_micros(200);
const WARM_UP: u64 = 200;
/// A reply slower than this is counted lost and the cycle moves on.
const REPLY_TIMEOUT: Duration = Duration::from_millis(100);

/// What one path measured.
struct Outcome {
    name: &'static str,
    rtt_ns: Histogram,
    lost: u64,
    late_cycles: u64,
    /// CPU of the ping process and of the pong process over the measured cycles, % of one
    /// core (processes only).
    cpu_pct: Option<(f64, f64)>,
}

/// One side of a ping-pong: send a 64-bit sequence number with a payload, poll for one.
trait Endpoint {
    fn send(&mut self, seq: u64);
    fn poll(&mut self) -> Option<u64>;
    /// Waits until something may have arrived, at most `timeout`: busy-polling endpoints
    /// return at once (the caller polls again), event-driven ones block on their event.
    fn wait(&mut self, _timeout: Duration) {
        spin_loop();
    }
}

/// How a receiving end of one of our links waits for the next message between polls:
/// busy-polling (spinning) unless the link can block.
trait WaitFor {
    fn wait_for(&self, _timeout: Duration) {
        spin_loop();
    }
}

#[cfg(feature = "iceoryx2")]
impl WaitFor for h4_transport::iceoryx2::Iceoryx2Link<Command, Feedback> {}
#[cfg(feature = "iceoryx2")]
impl WaitFor for h4_transport::iceoryx2::Iceoryx2Link<Feedback, Command> {}

/// Zenoh's receive path runs on its own threads: a receiver spinning on two vCPUs starves
/// them (the round trip's tail becomes the scheduler's time slice), so Zenoh ends block until
/// a message is there, unless `H4_BENCH_ZENOH_WAIT=spin` (how the figures before 2026-12-02
/// were taken).
#[cfg(feature = "zenoh")]
fn zenoh_blocks() -> bool {
    static BLOCKS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *BLOCKS.get_or_init(|| std::env::var("H4_BENCH_ZENOH_WAIT").map_or(true, |w| w != "spin"))
}

#[cfg(feature = "zenoh")]
impl<O: WireMessage, I: WireMessage> WaitFor for h4_transport::zenoh::ZenohLink<O, I> {
    fn wait_for(&self, timeout: Duration) {
        if zenoh_blocks() {
            self.wait_for_message(timeout);
        } else {
            spin_loop();
        }
    }
}

fn command(seq: u64) -> Command {
    Command {
        session_id: 1,
        seq,
        send_time_ns: seq,
        pose: [1.0, 2.0, 3.0, 0.1],
        velocity: [0.0; 4],
        force_setpoint_n: 2.0,
        energy_in_j: 0.0,
        energy_out_j: 0.0,
        protocol_version: PROTOCOL_VERSION,
        arm_id: 1,
        mode: 1,
        reserved: 0,
        flags: 0,
        echo_seq: 0,
        echo_send_time_ns: 0,
    }
}

fn feedback(echo_seq: u64) -> Feedback {
    Feedback {
        session_id: 2,
        seq: echo_seq,
        send_time_ns: 0,
        echo_seq,
        echo_send_time_ns: echo_seq,
        pose: [1.0, 2.0, 3.0, 0.1],
        wrench_measured: [0.0, 0.0, 2.0, 0.0],
        wrench_desired: [0.0, 0.0, 2.0, 0.0],
        energy_in_j: 0.0,
        energy_out_j: 0.0,
        protocol_version: PROTOCOL_VERSION,
        arm_id: 1,
        state: 1,
        contact_state: 0,
        fault_flags: 0,
        rejected_reasons: 0,
        rejected_count: 0,
        contact_point_mm: [0.0; 3],
        contact_normal: [0.0; 3],
        contact_stiffness_n_per_mm: 0.0,
    }
}

/// Our master end as a ping endpoint.
struct MasterEnd<L>(L);
impl<L: Link<Command, Feedback> + WaitFor> Endpoint for MasterEnd<L> {
    fn send(&mut self, seq: u64) {
        self.0.publish(&command(seq)).expect("publish");
    }
    fn poll(&mut self) -> Option<u64> {
        self.0.try_recv().expect("recv").map(|f| f.echo_seq)
    }
    fn wait(&mut self, timeout: Duration) {
        self.0.wait_for(timeout);
    }
}

/// Our slave end as a pong endpoint.
struct SlaveEnd<L>(L);
impl<L: Link<Feedback, Command> + WaitFor> Endpoint for SlaveEnd<L> {
    fn send(&mut self, seq: u64) {
        self.0.publish(&feedback(seq)).expect("publish");
    }
    fn poll(&mut self) -> Option<u64> {
        self.0.try_recv().expect("recv").map(|c| c.seq)
    }
    fn wait(&mut self, timeout: Duration) {
        self.0.wait_for(timeout);
    }
}

/// Answers every received sequence number until `stop` is set.
fn serve(pong: &mut dyn Endpoint, stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        while let Some(seq) = pong.poll() {
            pong.send(seq);
        }
        pong.wait(Duration::from_millis(10));
    }
}

/// Connects (repeats seq 0 until it comes back: asynchronous discovery loses early
/// messages), then runs `cycles` paced round trips.
fn measure(name: &'static str, cycles: u64, ping: &mut dyn Endpoint) -> Outcome {
    let deadline = Instant::now() + Duration::from_secs(20);
    'connect: loop {
        assert!(Instant::now() < deadline, "{name}: no reply within 20 s");
        ping.send(0);
        let t = Instant::now();
        while t.elapsed() < Duration::from_millis(10) {
            if ping.poll() == Some(0) {
                break 'connect;
            }
        }
    }
    thread::sleep(Duration::from_millis(50));
    while ping.poll().is_some() {}

    let mut pacer = Pacer::new(PERIOD, SPIN);
    let mut rtt_ns = Histogram::new();
    let (mut lost, mut late_cycles) = (0, 0);
    for seq in 1..=WARM_UP + cycles {
        let tick = pacer.wait();
        let t0 = Instant::now();
        ping.send(seq);
        let rtt = loop {
            if let Some(echo) = ping.poll()
                && echo == seq
            {
                break Some(t0.elapsed());
            }
            let waited = t0.elapsed();
            if waited > REPLY_TIMEOUT {
                break None;
            }
            ping.wait(REPLY_TIMEOUT - waited);
        };
        if seq > WARM_UP {
            late_cycles += tick.missed;
            match rtt {
                Some(d) => rtt_ns.record(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
                None => lost += 1,
            }
        }
    }
    Outcome {
        name,
        rtt_ns,
        lost,
        late_cycles,
        cpu_pct: None,
    }
}

/// Ping on this thread, pong on another; `make_pong` runs inside the pong thread (iceoryx2
/// ports are not `Send`).
fn in_threads<P: Endpoint, Q: Endpoint>(
    name: &'static str,
    cycles: u64,
    make_ping: impl FnOnce() -> P,
    make_pong: impl FnOnce() -> Q + Send + 'static,
) -> Outcome {
    let stop = Arc::new(AtomicBool::new(false));
    let ready = Arc::new(AtomicBool::new(false));
    let pong = {
        let (stop, ready) = (Arc::clone(&stop), Arc::clone(&ready));
        thread::spawn(move || {
            let mut pong = make_pong();
            ready.store(true, Ordering::Release);
            serve(&mut pong, &stop);
        })
    };
    let mut ping = make_ping();
    while !ready.load(Ordering::Acquire) {
        thread::sleep(Duration::from_millis(1));
    }
    let outcome = measure(name, cycles, &mut ping);
    stop.store(true, Ordering::Relaxed);
    pong.join().expect("pong thread");
    outcome
}

/// Ping in this process, pong in a child process (this executable with `--pong <args>`); the
/// child prints one `ready <info>` line, which `make_ping` receives.
fn in_processes<P: Endpoint>(
    name: &'static str,
    cycles: u64,
    pong_args: &[String],
    make_ping: impl FnOnce(&str) -> P,
) -> Outcome {
    let mut child = Process::new(std::env::current_exe().expect("current exe"))
        .arg("--pong")
        .args(pong_args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn pong process");
    let mut line = String::new();
    let mut from_child = BufReader::new(child.stdout.take().expect("child stdout"));
    from_child.read_line(&mut line).expect("pong ready line");
    let info = line
        .trim()
        .strip_prefix("ready")
        .expect("ready line")
        .trim()
        .to_string();
    let mut ping = make_ping(&info);
    // CPU over the whole measurement (connect, warm-up and measured cycles): the child
    // reports its own at the start of the run and when it stops.
    let wall = Instant::now();
    let ping_cpu = h4_telemetry::process::cpu_time_s();
    writeln!(child.stdin.as_mut().expect("child stdin"), "cpu?").expect("ask the pong");
    let pong_cpu = read_cpu(&mut from_child);
    let mut outcome = measure(name, cycles, &mut ping);
    let ping_cpu = h4_telemetry::process::cpu_time_s() - ping_cpu;
    drop(child.stdin.take()); // EOF: the child reports its CPU, stops serving and exits
    let pong_cpu = read_cpu(&mut from_child) - pong_cpu;
    let wall = wall.elapsed().as_secs_f64();
    let _ = child.wait();
    outcome.cpu_pct = Some((100.0 * ping_cpu / wall, 100.0 * pong_cpu / wall));
    outcome
}

/// Reads a `cpu <seconds>` line from the pong process.
fn read_cpu(from_child: &mut impl BufRead) -> f64 {
    let mut line = String::new();
    from_child.read_line(&mut line).expect("pong cpu line");
    line.trim()
        .strip_prefix("cpu")
        .and_then(|v| v.trim().parse().ok())
        .expect("cpu line")
}

/// The child side of [`in_processes`].
fn pong_main(args: &[String]) {
    let arg = |i: usize| args.get(i).cloned().expect("pong argument");
    let mut info = String::new();
    let mut pong: Box<dyn Endpoint> = match arg(0).as_str() {
        "udp" => {
            let udp = Udp::connected_to(arg(1).parse().expect("port"));
            info = udp.socket.local_addr().expect("addr").port().to_string();
            Box::new(udp)
        }
        #[cfg(feature = "iceoryx2")]
        "iceoryx2-bare" => Box::new(bare_iceoryx2::End::new(&arg(1), &arg(2))),
        #[cfg(feature = "iceoryx2")]
        "iceoryx2-event" => Box::new(bare_iceoryx2::EventEnd::new(&arg(1), &arg(2))),
        #[cfg(feature = "iceoryx2")]
        "iceoryx2-link" => Box::new(SlaveEnd(
            h4_transport::iceoryx2::slave(&iox_options(arg(1))).expect("slave"),
        )),
        #[cfg(feature = "zenoh")]
        "zenoh-bare" => Box::new(bare_zenoh::End::new(
            zenoh_listen(arg(1).parse().expect("port")),
            &arg(2),
            &arg(3),
        )),
        #[cfg(feature = "zenoh")]
        "zenoh-link" => Box::new(SlaveEnd(
            h4_transport::zenoh::SlaveZenohLink::open(
                1,
                &zenoh_settings(h4_transport::zenoh::ZenohConfig::listen_on_loopback(
                    arg(1).parse().expect("port"),
                )),
            )
            .expect("slave"),
        )),
        other => panic!("unknown pong kind {other}"),
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        thread::spawn(move || {
            // Each line asks for the CPU used so far; EOF asks for it and stops.
            let mut sink = String::new();
            while std::io::stdin().read_line(&mut sink).is_ok_and(|n| n > 0) {
                println!("cpu {}", h4_telemetry::process::cpu_time_s());
                std::io::stdout().flush().expect("flush");
            }
            stop.store(true, Ordering::Relaxed);
        });
    }
    println!("ready {info}");
    std::io::stdout().flush().expect("flush");
    serve(pong.as_mut(), &stop);
    println!("cpu {}", h4_telemetry::process::cpu_time_s());
    std::io::stdout().flush().expect("flush");
}

// ---- plain UDP loopback ----

struct Udp {
    socket: UdpSocket,
    buf: [u8; 256],
}
impl Udp {
    fn pair() -> (Udp, Udp) {
        let a = UdpSocket::bind("127.0.0.1:0").expect("bind");
        let b = UdpSocket::bind("127.0.0.1:0").expect("bind");
        a.connect(b.local_addr().expect("addr")).expect("connect");
        b.connect(a.local_addr().expect("addr")).expect("connect");
        a.set_nonblocking(true).expect("nonblocking");
        b.set_nonblocking(true).expect("nonblocking");
        let udp = |socket| Udp {
            socket,
            buf: [0; 256],
        };
        (udp(a), udp(b))
    }
}
impl Udp {
    /// A socket on 127.0.0.1 connected to `port` on 127.0.0.1.
    fn connected_to(port: u16) -> Udp {
        let socket = UdpSocket::bind("127.0.0.1:0").expect("bind");
        socket.connect(("127.0.0.1", port)).expect("connect");
        socket.set_nonblocking(true).expect("nonblocking");
        Udp {
            socket,
            buf: [0; 256],
        }
    }
}
impl Endpoint for Udp {
    fn send(&mut self, seq: u64) {
        let mut bytes = [0u8; Command::WIRE_SIZE];
        command(seq).encode_into(&mut bytes).expect("encode");
        let _ = self.socket.send(&bytes);
    }
    fn poll(&mut self) -> Option<u64> {
        let n = self.socket.recv(&mut self.buf).ok()?;
        Command::decode_from(self.buf.get(..n)?).ok().map(|c| c.seq)
    }
}

// ---- bare iceoryx2 ----

#[cfg(feature = "iceoryx2")]
mod bare_iceoryx2 {
    use iceoryx2::port::listener::Listener;
    use iceoryx2::port::notifier::Notifier;
    use iceoryx2::port::publisher::Publisher;
    use iceoryx2::port::subscriber::Subscriber;
    use iceoryx2::prelude::*;

    /// 128 bytes, like our messages.
    pub type Payload = [u64; 16];

    pub struct End {
        _node: Node<ipc::Service>,
        publisher: Publisher<ipc::Service, Payload, ()>,
        subscriber: Subscriber<ipc::Service, Payload, ()>,
    }

    impl End {
        pub fn new(out: &str, inp: &str) -> End {
            // An explicit configuration: no config-file lookup, no "No config file" warning.
            let node = NodeBuilder::new()
                .config(&Config::default())
                .create::<ipc::Service>()
                .expect("iceoryx2 node");
            let service = |name: &str| {
                node.service_builder(&name.try_into().expect("service name"))
                    .publish_subscribe::<Payload>()
                    .subscriber_max_buffer_size(16)
                    .history_size(0)
                    .enable_safe_overflow(true)
                    .open_or_create()
                    .expect("iceoryx2 service")
            };
            let out_service = service(out);
            let in_service = service(inp);
            End {
                publisher: out_service.publisher_builder().create().expect("publisher"),
                subscriber: in_service
                    .subscriber_builder()
                    .create()
                    .expect("subscriber"),
                _node: node,
            }
        }
    }

    impl super::Endpoint for End {
        fn send(&mut self, seq: u64) {
            let mut payload = [7u64; 16];
            payload[0] = seq;
            self.publisher.send_copy(payload).expect("send");
        }
        fn poll(&mut self) -> Option<u64> {
            self.subscriber
                .receive()
                .expect("receive")
                .map(|sample| sample.payload()[0])
        }
    }

    /// The same publish-subscribe pair plus an event service per direction: every send
    /// notifies, and waiting blocks on the listener (iceoryx2's wake-up path) instead of
    /// busy-polling.
    pub struct EventEnd {
        end: End,
        notifier: Notifier<ipc::Service>,
        listener: Listener<ipc::Service>,
    }

    impl EventEnd {
        pub fn new(out: &str, inp: &str) -> EventEnd {
            let end = End::new(out, inp);
            let event = |name: &str| {
                end._node
                    .service_builder(&format!("{name}/event").as_str().try_into().expect("name"))
                    .event()
                    .open_or_create()
                    .expect("iceoryx2 event service")
            };
            let notifier = event(out).notifier_builder().create().expect("notifier");
            let listener = event(inp).listener_builder().create().expect("listener");
            EventEnd {
                end,
                notifier,
                listener,
            }
        }
    }

    /// Service names of a bare ping-pong: `(ping's out, pong's out)`, unique per process and tag.
    fn names(tag: &str) -> (String, String) {
        let pid = std::process::id();
        (
            format!("h4bench/{pid}/{tag}/ping"),
            format!("h4bench/{pid}/{tag}/pong"),
        )
    }

    /// A bare ping-pong of `E`s in two threads.
    pub fn in_threads<E: super::Endpoint + 'static>(
        name: &'static str,
        cycles: u64,
        tag: &str,
        make: fn(&str, &str) -> E,
    ) -> super::Outcome {
        let (a, b) = names(tag);
        let (a2, b2) = (a.clone(), b.clone());
        super::in_threads(name, cycles, move || make(&a, &b), move || make(&b2, &a2))
    }

    /// A bare ping-pong of `E`s in two processes; `kind` names the pong's `E` for the child.
    pub fn in_processes<E: super::Endpoint>(
        name: &'static str,
        cycles: u64,
        kind: &str,
        make: fn(&str, &str) -> E,
    ) -> super::Outcome {
        let (a, b) = names(kind);
        let pong_args = [kind.to_string(), b.clone(), a.clone()];
        super::in_processes(name, cycles, &pong_args, move |_| make(&a, &b))
    }

    impl super::Endpoint for EventEnd {
        fn send(&mut self, seq: u64) {
            self.end.send(seq);
            self.notifier.notify().expect("notify");
        }
        fn poll(&mut self) -> Option<u64> {
            self.end.poll()
        }
        fn wait(&mut self, timeout: core::time::Duration) {
            self.listener.timed_wait(|_| {}, timeout).expect("wait");
        }
    }
}

// ---- bare Zenoh ----

#[cfg(feature = "zenoh")]
mod bare_zenoh {
    use zenoh::Wait;
    use zenoh::handlers::FifoChannelHandler;
    use zenoh::pubsub::{Publisher, Subscriber};
    use zenoh::qos::{CongestionControl, Priority};
    use zenoh::sample::Sample;

    pub struct End {
        _session: zenoh::Session,
        publisher: Publisher<'static>,
        subscriber: Subscriber<FifoChannelHandler<Sample>>,
        /// A sample a blocking wait received, for the next poll.
        pending: Option<Sample>,
    }

    impl End {
        pub fn new(config: zenoh::Config, out: &str, inp: &str) -> End {
            let session = zenoh::open(config).wait().expect("zenoh session");
            let publisher = session
                .declare_publisher(out.to_string())
                .express(true)
                .priority(Priority::RealTime)
                .congestion_control(CongestionControl::Drop)
                .wait()
                .expect("publisher");
            let subscriber = session
                .declare_subscriber(inp.to_string())
                .wait()
                .expect("subscriber");
            End {
                _session: session,
                publisher,
                subscriber,
                pending: None,
            }
        }
    }

    impl super::Endpoint for End {
        fn send(&mut self, seq: u64) {
            let mut payload = [7u8; 128];
            payload[..8].copy_from_slice(&seq.to_le_bytes());
            self.publisher.put(payload).wait().expect("put");
        }
        fn poll(&mut self) -> Option<u64> {
            let sample = match self.pending.take() {
                Some(s) => s,
                None => self.subscriber.try_recv().ok()??,
            };
            let bytes = sample.payload().to_bytes();
            let seq: [u8; 8] = bytes.get(..8)?.try_into().ok()?;
            Some(u64::from_le_bytes(seq))
        }
        fn wait(&mut self, timeout: core::time::Duration) {
            if !super::zenoh_blocks() {
                std::hint::spin_loop();
            } else if self.pending.is_none() {
                self.pending = self.subscriber.recv_timeout(timeout).ok().flatten();
            }
        }
    }
}

fn free_port() -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    listener.local_addr().expect("addr").port()
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1000.0
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(at) = args.iter().position(|a| a == "--pong") {
        pong_main(&args[at + 1..]);
        return;
    }
    let cycles: u64 = std::env::var("H4_BENCH_CYCLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5000);
    let mode = std::env::var("H4_BENCH_MODE").unwrap_or_else(|_| "both".into());
    let filters: Vec<&String> = args.iter().filter(|a| !a.starts_with('-')).collect();
    let wanted = |name: &str| filters.is_empty() || filters.iter().any(|f| name.contains(*f));
    let pid = std::process::id();
    let mut outcomes = Vec::new();
    let mut run = |name: &'static str, f: &dyn Fn(&'static str) -> Outcome| {
        if wanted(name) {
            let o = f(name);
            eprintln!("{name}: p50 {:.1} µs", us(o.rtt_ns.quantile(0.5)));
            outcomes.push(o);
        }
    };

    if mode == "both" || mode == "threads" {
        run("threads: udp loopback (baseline)", &|name| {
            let (ping, pong) = Udp::pair();
            in_threads(name, cycles, || ping, || pong)
        });
        #[cfg(feature = "iceoryx2")]
        {
            run("threads: iceoryx2 bare", &|name| {
                bare_iceoryx2::in_threads(name, cycles, "t", bare_iceoryx2::End::new)
            });
            run("threads: iceoryx2 bare, event wake-up", &|name| {
                bare_iceoryx2::in_threads(name, cycles, "te", bare_iceoryx2::EventEnd::new)
            });
            run("threads: iceoryx2 link (Iceoryx2Link)", &|name| {
                let opts = iox_options(format!("h4bench-{pid}-t"));
                let opts2 = opts.clone();
                in_threads(
                    name,
                    cycles,
                    move || MasterEnd(h4_transport::iceoryx2::master(&opts).expect("master")),
                    move || SlaveEnd(h4_transport::iceoryx2::slave(&opts2).expect("slave")),
                )
            });
        }
        #[cfg(feature = "zenoh")]
        {
            run("threads: zenoh bare (peer, express)", &|name| {
                let port = free_port();
                let (a, b) = (
                    format!("h4bench/{pid}/t/ping"),
                    format!("h4bench/{pid}/t/pong"),
                );
                let (a2, b2) = (a.clone(), b.clone());
                in_threads(
                    name,
                    cycles,
                    move || bare_zenoh::End::new(zenoh_connect(port), &a, &b),
                    move || bare_zenoh::End::new(zenoh_listen(port), &b2, &a2),
                )
            });
            run("threads: zenoh link (ZenohLink, peer)", &|name| {
                use h4_transport::zenoh::{MasterZenohLink, SlaveZenohLink, ZenohConfig};
                let port = free_port();
                in_threads(
                    name,
                    cycles,
                    move || {
                        MasterEnd(
                            MasterZenohLink::open(
                                1,
                                &zenoh_settings(ZenohConfig::connect_to_loopback(port)),
                            )
                            .expect("master"),
                        )
                    },
                    move || {
                        SlaveEnd(
                            SlaveZenohLink::open(
                                1,
                                &zenoh_settings(ZenohConfig::listen_on_loopback(port)),
                            )
                            .expect("slave"),
                        )
                    },
                )
            });
        }
    }

    if mode == "both" || mode == "processes" {
        run("processes: udp loopback (baseline)", &|name| {
            let socket = UdpSocket::bind("127.0.0.1:0").expect("bind");
            let port = socket.local_addr().expect("addr").port().to_string();
            in_processes(name, cycles, &["udp".into(), port], move |pong_port| {
                socket
                    .connect(("127.0.0.1", pong_port.parse::<u16>().expect("port")))
                    .expect("connect");
                socket.set_nonblocking(true).expect("nonblocking");
                Udp {
                    socket,
                    buf: [0; 256],
                }
            })
        });
        #[cfg(feature = "iceoryx2")]
        {
            run("processes: iceoryx2 bare", &|name| {
                bare_iceoryx2::in_processes(name, cycles, "iceoryx2-bare", bare_iceoryx2::End::new)
            });
            run("processes: iceoryx2 bare, event wake-up", &|name| {
                bare_iceoryx2::in_processes(
                    name,
                    cycles,
                    "iceoryx2-event",
                    bare_iceoryx2::EventEnd::new,
                )
            });
            run("processes: iceoryx2 link (Iceoryx2Link)", &|name| {
                let prefix = format!("h4bench-{pid}-p");
                let pong_args = ["iceoryx2-link".into(), prefix.clone()];
                in_processes(name, cycles, &pong_args, move |_| {
                    MasterEnd(h4_transport::iceoryx2::master(&iox_options(prefix)).expect("master"))
                })
            });
        }
        #[cfg(feature = "zenoh")]
        {
            run("processes: zenoh bare (peer, express)", &|name| {
                let port = free_port();
                let (a, b) = (
                    format!("h4bench/{pid}/p/ping"),
                    format!("h4bench/{pid}/p/pong"),
                );
                let pong_args = ["zenoh-bare".into(), port.to_string(), b.clone(), a.clone()];
                in_processes(name, cycles, &pong_args, move |_| {
                    bare_zenoh::End::new(zenoh_connect(port), &a, &b)
                })
            });
            run("processes: zenoh link (ZenohLink, peer)", &|name| {
                use h4_transport::zenoh::{MasterZenohLink, ZenohConfig};
                let port = free_port();
                let pong_args = ["zenoh-link".into(), port.to_string()];
                in_processes(name, cycles, &pong_args, move |_| {
                    MasterEnd(
                        MasterZenohLink::open(
                            1,
                            &zenoh_settings(ZenohConfig::connect_to_loopback(port)),
                        )
                        .expect("master"),
                    )
                })
            });
        }
    }

    println!(
        "\n{cycles} round trips per path at 1 kHz, µs; {} vCPU",
        thread::available_parallelism().map_or(0, |n| n.get())
    );
    println!("| path | p50 | p99 | p99.9 | max | lost | late cycles | CPU ping / pong, % |");
    println!("|---|---|---|---|---|---|---|---|");
    for o in &outcomes {
        let h = &o.rtt_ns;
        let cpu = o
            .cpu_pct
            .map_or_else(|| "–".to_string(), |(a, b)| format!("{a:.0} / {b:.0}"));
        println!(
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {} | {cpu} |",
            o.name,
            us(h.quantile(0.5)),
            us(h.quantile(0.99)),
            us(h.quantile(0.999)),
            us(h.max()),
            o.lost,
            o.late_cycles
        );
    }
}

#[cfg(feature = "iceoryx2")]
fn iox_options(prefix: String) -> h4_transport::iceoryx2::Iceoryx2Options {
    h4_transport::iceoryx2::Iceoryx2Options {
        prefix,
        ..h4_transport::iceoryx2::Iceoryx2Options::new(1)
    }
}

/// `H4_BENCH_ZENOH_CONFIG=FILE.json5`: a Zenoh configuration file every Zenoh path of the
/// run (bare and ours, ping and pong) loads first, e.g. `config/zenoh/low-latency.json5`;
/// `H4_BENCH_ZENOH_PROTO=udp|tcp|unixsock-stream` (default tcp) picks the link.
#[cfg(feature = "zenoh")]
fn zenoh_settings(mut c: h4_transport::zenoh::ZenohConfig) -> h4_transport::zenoh::ZenohConfig {
    c.config_file = std::env::var("H4_BENCH_ZENOH_CONFIG").ok();
    if let Ok(proto) = std::env::var("H4_BENCH_ZENOH_PROTO") {
        let swap = |e: &String| {
            if proto == "unixsock-stream" {
                let port = e.rsplit(':').next().unwrap_or("0");
                format!("unixsock-stream//tmp/h4bench-{port}.sock")
            } else {
                e.replacen("tcp/", &format!("{proto}/"), 1)
            }
        };
        c.listen = c.listen.iter().map(swap).collect();
        c.connect = c.connect.iter().map(swap).collect();
    }
    c
}

#[cfg(feature = "zenoh")]
fn zenoh_listen(port: u16) -> zenoh::Config {
    zenoh_settings(h4_transport::zenoh::ZenohConfig::listen_on_loopback(port))
        .to_zenoh()
        .expect("config")
}

#[cfg(feature = "zenoh")]
fn zenoh_connect(port: u16) -> zenoh::Config {
    zenoh_settings(h4_transport::zenoh::ZenohConfig::connect_to_loopback(port))
        .to_zenoh()
        .expect("config")
}
