//! The outside client of `wire_outside_client_inproc.rs` (bytes by hand from docs/wire.md)
//! against the real `h4-slave run` process over Zenoh, with its own Zenoh session (the
//! `zenoh` crate directly, raw payloads on `h4/0/command`, feedback read from `h4/0/feedback`
//! and parsed by hand). A correct command is accepted (echoed); each bad message of issue
//! 14's list is rejected, counted under its reason in the process's summary (`gate.<reason>`),
//! flagged in the feedback's `rejected_reasons`, and never acted on (the arm, 5 mm above a
//! resin plane, neither moves nor presses: from the feedback's measured pose and force). And
//! protocol 3's echo: a client that echoes the newest feedback gives the process a measured
//! round trip, an impossible echo is refused and counted.

#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "common/outside_client.rs"]
mod outside_client;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use h4_tests::procs::{Running, Scratch, binaries, read_json};
use outside_client::{Cmd, Fb, bad_messages};
use zenoh::Wait;

struct Client {
    session: zenoh::Session,
    publisher: zenoh::pubsub::Publisher<'static>,
    inbox: Arc<Mutex<Vec<Vec<u8>>>>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
}

impl Client {
    fn connect(endpoint: &str) -> Self {
        let mut config = zenoh::Config::default();
        config.insert_json5("mode", "\"client\"").unwrap();
        config
            .insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
            .unwrap();
        config
            .insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        // The slave may still be starting: retry (watchdog 30 s).
        let t = Instant::now();
        let session = loop {
            match zenoh::open(config.clone()).wait() {
                Ok(s) => break s,
                Err(e) => {
                    assert!(t.elapsed() < Duration::from_secs(30), "zenoh session: {e}");
                    std::thread::sleep(Duration::from_millis(200));
                }
            }
        };
        let inbox = Arc::new(Mutex::new(Vec::new()));
        let q = Arc::clone(&inbox);
        let subscriber = session
            .declare_subscriber("h4/0/feedback")
            .callback(move |s| q.lock().unwrap().push(s.payload().to_bytes().to_vec()))
            .wait()
            .expect("subscriber");
        let publisher = session
            .declare_publisher("h4/0/command")
            .wait()
            .expect("publisher");
        Client {
            session,
            publisher,
            inbox,
            _subscriber: subscriber,
        }
    }

    fn send(&self, bytes: &[u8]) {
        self.publisher.put(bytes.to_vec()).wait().expect("put");
    }

    fn feedback(&self) -> Vec<Fb> {
        let all = std::mem::take(&mut *self.inbox.lock().unwrap());
        all.iter()
            .map(|b| Fb::parse(b).expect("feedback as docs/wire.md describes it"))
            .collect()
    }
}

/// Reads feedback until `pred` holds (watchdog 20 s); `each` sees every message.
fn until(c: &Client, mut each: impl FnMut(&Fb), mut pred: impl FnMut(&Fb) -> bool) -> Fb {
    let t = Instant::now();
    loop {
        for fb in c.feedback() {
            each(&fb);
            if pred(&fb) {
                return fb;
            }
        }
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "watchdog: no such feedback"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn the_slave_process_rejects_counts_and_flags_every_bad_message_from_an_outside_client() {
    let (_, slave) = binaries();
    let scratch = Scratch::new("outside-zenoh");
    let endpoint = format!("tcp/127.0.0.1:{}", 21000 + std::process::id() % 20000);
    let summary = scratch.path("slave.json").display().to_string();
    let args: Vec<String> = [
        "run",
        "--transport",
        "zenoh",
        "--zenoh-listen",
        &endpoint,
        "--watchdog-ms",
        "10000",
        "--summary",
        &summary,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut sl = Running::spawn("slave", slave, &args, &scratch);
    let client = Client::connect(&endpoint);
    let _ = &client.session;
    let first = until(&client, |_| {}, |_| true);
    let home = first.pose;
    let session = 0xC0FF_EE00_0000_0042u64;
    // A correct hand-encoded command is accepted: the slave echoes it and becomes active.
    let mut seq = 0u64;
    for _ in 0..50 {
        seq += 1;
        client.send(&Cmd::position(session, seq, home).bytes());
        std::thread::sleep(Duration::from_millis(2));
    }
    let want = seq;
    let fb = until(&client, |_| {}, |fb| fb.echo_seq >= want && fb.state == 1);
    assert_eq!(fb.echo_seq, want, "{}", sl.log());
    let (mut max_dev_mm, mut max_force_n, mut reasons) = (0.0f64, 0.0f64, 0u32);
    let rng = 0xDEAD_BEEF_1234_5678u64;
    let bad_at =
        |seq: u64| bad_messages(&Cmd::position(session, seq + 500, home), &mut rng.clone());
    let bad = bad_at(seq);
    const SENT: u64 = 20;
    for i in 0..bad.len() {
        let b = &bad_at(seq)[i];
        for _ in 0..SENT {
            client.send(&b.bytes);
            std::thread::sleep(Duration::from_millis(2));
        }
        // A valid hold after each batch; its echo means the batch was judged.
        seq += 1;
        client.send(&Cmd::position(session, seq, home).bytes());
        let want = seq;
        let mut seen = 0u32;
        until(
            &client,
            |fb| {
                max_dev_mm = max_dev_mm.max(fb.distance_mm(&home));
                max_force_n = max_force_n.max(fb.force_n());
                seen |= fb.rejected_reasons;
            },
            |fb| fb.echo_seq >= want,
        );
        assert!(
            seen & b.bit != 0,
            "{}: flag {:#x} not in the feedback ({seen:#x})",
            b.name,
            b.bit
        );
        reasons |= seen;
    }
    sl.stop();
    let v = read_json(&scratch.path("slave.json"));
    let g = &v["gate"];
    let mut expected = std::collections::BTreeMap::<&str, u64>::new();
    for b in &bad {
        *expected.entry(b.counter).or_default() += SENT;
    }
    for (name, n) in &expected {
        assert_eq!(g[name].as_u64(), Some(*n), "{name}: {g:#}");
    }
    let total: u64 = expected.values().sum();
    let rejected: u64 = expected.keys().map(|k| g[k].as_u64().unwrap()).sum::<u64>();
    assert_eq!(rejected, total, "{g:#}");
    assert_eq!(g["accepted"].as_u64(), Some(50 + bad.len() as u64), "{g:#}");
    assert_eq!(g["pairings"].as_u64(), Some(1), "{g:#}");
    assert_eq!(
        v["commands_rejected_by_controller"].as_u64(),
        Some(0),
        "{v:#}"
    );
    assert!(max_dev_mm < 0.5, "the arm moved {max_dev_mm} mm");
    assert!(max_force_n < 1.0, "the arm pressed {max_force_n} N");
    assert!(reasons != 0);
    // The control of the round-trip test below: this client echoes nothing (0 and 0), so the
    // slave has no sample and no refusal.
    assert_eq!(v["round_trip_samples"].as_u64(), Some(0), "{v:#}");
    assert!(v["rtt_measured_p50_ms"].is_null(), "{v:#}");
    assert_eq!(v["round_trip_echoes_refused"].as_u64(), Some(0), "{v:#}");
}

/// Protocol 3 against the process (docs/wire.md, "The command's echo"): an outside client
/// that echoes the newest feedback it has in every command gives `h4-slave run` a measured
/// round trip (`rtt_measured_p50_ms`, `round_trip_samples` in its summary); one command echoing
/// a feedback the slave has not sent is accepted and followed like any other, its echo refused
/// and counted (`round_trip_echoes_refused`). Control: the test above, whose client echoes
/// nothing.
#[test]
fn the_slave_process_measures_the_round_trip_an_outside_client_echoes() {
    let (_, slave) = binaries();
    let scratch = Scratch::new("outside-zenoh-rtt");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let summary = scratch.path("slave.json").display().to_string();
    let args: Vec<String> = [
        "run",
        "--transport",
        "zenoh",
        "--zenoh-listen",
        &endpoint,
        "--watchdog-ms",
        "10000",
        "--summary",
        &summary,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut sl = Running::spawn("slave", slave, &args, &scratch);
    let client = Client::connect(&endpoint);
    let mut newest = until(&client, |_| {}, |_| true);
    let home = newest.pose;
    let session = 0xC0FF_EE00_0000_0043u64;
    const COMMANDS: u64 = 300;
    for seq in 1..=COMMANDS {
        for fb in client.feedback() {
            if fb.seq > newest.seq {
                newest = fb;
            }
        }
        let mut c = Cmd::position(session, seq, home);
        (c.echo_seq, c.echo_send_time_ns) = (newest.seq, newest.send_time_ns);
        client.send(&c.bytes());
        std::thread::sleep(Duration::from_millis(2));
    }
    // An echo of a feedback the slave has not sent (its sequence number far ahead).
    let mut c = Cmd::position(session, COMMANDS + 1, home);
    (c.echo_seq, c.echo_send_time_ns) = (1 << 62, newest.send_time_ns);
    client.send(&c.bytes());
    let fb = until(&client, |_| {}, |fb| fb.echo_seq > COMMANDS);
    assert_eq!(
        fb.echo_seq,
        COMMANDS + 1,
        "taken and followed: {}",
        sl.log()
    );
    assert_eq!(fb.state, 1);
    sl.stop();
    let v = read_json(&scratch.path("slave.json"));
    assert_eq!(v["gate"]["accepted"].as_u64(), Some(COMMANDS + 1), "{v:#}");
    assert_eq!(v["round_trip_echoes_refused"].as_u64(), Some(1), "{v:#}");
    let samples = v["round_trip_samples"].as_u64().unwrap();
    assert!(samples >= COMMANDS / 2, "{samples} of {COMMANDS}: {v:#}");
    let p50 = v["rtt_measured_p50_ms"]
        .as_f64()
        .expect("a measured round trip");
    let p99 = v["rtt_measured_p99_ms"].as_f64().unwrap();
    assert!(p50 > 0.0 && p99 >= p50, "{v:#}");
    assert!(v["rtt_jitter_ms"].as_f64().unwrap() >= 0.0, "{v:#}");
}
