//! The link conformance suite (`tests/common`) over Zenoh (peer mode, TCP loopback, a free port
//! per test; and again with both ends clients of a router), plus what only the byte path has: raw payloads that do not decode are counted and never
//! delivered, and a client-mode end works like a peer.
#![cfg(feature = "zenoh")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[macro_use]
mod common;

use std::time::{Duration, Instant};

use ::zenoh::Wait;
use common::suite::{Transport, WATCHDOG, command, connect, deliver, deliver_to};
use h4_shared::wire::{Command, WireMessage};
use h4_transport::Link;
use h4_transport::zenoh::{MasterZenohLink, SlaveZenohLink, ZenohConfig, ZenohMode, key_expr};

/// Zenoh peers: the first slave listens on a fresh loopback port, every other end connects
/// to it (one Zenoh network per test, all arms on it).
struct ZenohPeers;

impl Transport for ZenohPeers {
    type Master = MasterZenohLink;
    type Slave = SlaveZenohLink;

    fn open(arms: &[u16]) -> Vec<(MasterZenohLink, SlaveZenohLink)> {
        let port = common::free_port();
        let mut pairs = Vec::new();
        for (i, &arm) in arms.iter().enumerate() {
            let slave_cfg = if i == 0 {
                ZenohConfig::listen_on_loopback(port)
            } else {
                ZenohConfig::connect_to_loopback(port)
            };
            let slave = SlaveZenohLink::open(arm, &slave_cfg).expect("slave end");
            let master = MasterZenohLink::open(arm, &ZenohConfig::connect_to_loopback(port))
                .expect("master end");
            pairs.push((master, slave));
        }
        pairs
    }
}

conformance_suite!(ZenohPeers);

/// The deployment across hosts: a Zenoh router (started here, in this process, as a session in
/// router mode on a fresh loopback port) and every end a client of it, as `h4-slave run
/// --zenoh-mode client --zenoh-connect …` and `h4-master run` would be with `zenohd`.
mod via_router {
    use super::*;

    /// Clients of one router per test.
    struct ZenohRouterClients;

    /// A router on `tcp/127.0.0.1:<port>`; it lives until the test process ends.
    fn router(port: u16) {
        let mut config = ::zenoh::Config::default();
        config.insert_json5("mode", "\"router\"").unwrap();
        config
            .insert_json5("listen/endpoints", &format!("[\"tcp/127.0.0.1:{port}\"]"))
            .unwrap();
        config
            .insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        let session = ::zenoh::open(config).wait().expect("router");
        std::mem::forget(session);
    }

    fn client(port: u16) -> ZenohConfig {
        ZenohConfig {
            mode: ZenohMode::Client,
            ..ZenohConfig::connect_to_loopback(port)
        }
    }

    impl Transport for ZenohRouterClients {
        type Master = MasterZenohLink;
        type Slave = SlaveZenohLink;

        fn open(arms: &[u16]) -> Vec<(MasterZenohLink, SlaveZenohLink)> {
            let port = common::free_port();
            router(port);
            arms.iter()
                .map(|&arm| {
                    let slave = SlaveZenohLink::open(arm, &client(port)).expect("slave end");
                    let master = MasterZenohLink::open(arm, &client(port)).expect("master end");
                    (master, slave)
                })
                .collect()
        }
    }

    conformance_suite!(ZenohRouterClients);
}

#[test]
fn undecodable_payloads_are_counted_never_delivered() {
    let port = common::free_port();
    let mut slave = SlaveZenohLink::open(3, &ZenohConfig::listen_on_loopback(port)).unwrap();
    let raw = ::zenoh::open(ZenohConfig::connect_to_loopback(port).to_zenoh().unwrap())
        .wait()
        .unwrap();
    let publisher = raw
        .declare_publisher(key_expr(3, Command::NAME))
        .wait()
        .unwrap();

    let encode = |c: &Command| {
        let mut bytes = vec![0u8; Command::WIRE_SIZE];
        c.encode_into(&mut bytes).unwrap();
        bytes
    };
    // Wait until the raw publisher reaches the slave.
    let deadline = Instant::now() + WATCHDOG;
    loop {
        publisher.put(encode(&command(3, 1))).wait().unwrap();
        std::thread::sleep(Duration::from_millis(2));
        if slave.recv_latest().unwrap().is_some() {
            break;
        }
        assert!(Instant::now() < deadline, "watchdog: never connected");
    }
    std::thread::sleep(Duration::from_millis(20));
    while slave.try_recv().unwrap().is_some() {}
    assert_eq!(slave.undecodable(), 0);

    let good = encode(&command(3, 50));
    // A NaN in pose[0]: the body starts after the 16-byte header with seq and send time.
    let mut nan = good.clone();
    nan[32..40].copy_from_slice(&f64::NAN.to_le_bytes());
    // Another protocol version in the header (bytes 2..4).
    let mut version = good.clone();
    version[2..4].copy_from_slice(&99u16.to_le_bytes());
    let short = good[..good.len() - 1].to_vec();
    let garbage = vec![0xA5u8; Command::WIRE_SIZE];
    // One at a time, each refused before the next (see `deliver`).
    for bad in [nan, version, short, garbage] {
        let before = slave.undecodable();
        deliver(
            "a bad payload",
            || publisher.put(bad.clone()).wait().unwrap(),
            || {
                assert_eq!(slave.try_recv().unwrap(), None, "a bad payload delivered");
                slave.undecodable() > before
            },
        );
    }
    let got = deliver_to(
        "the valid command",
        || publisher.put(good.clone()).wait().unwrap(),
        &mut slave,
        |c| c.seq == 50,
    );
    assert_eq!(got, command(3, 50));
    assert_eq!(slave.undecodable(), 4);
    let by_reason = slave.decode_rejects();
    assert_eq!((by_reason.undecodable, by_reason.wrong_version), (3, 1));
    assert!(slave.last_decode_error().is_some());
    assert_eq!(slave.try_recv().unwrap(), None);
}

#[test]
fn client_mode_end_talks_to_a_listening_peer() {
    let port = common::free_port();
    let mut slave = SlaveZenohLink::open(5, &ZenohConfig::listen_on_loopback(port)).unwrap();
    let client = ZenohConfig {
        mode: ZenohMode::Client,
        ..ZenohConfig::connect_to_loopback(port)
    };
    let mut master = MasterZenohLink::open(5, &client).unwrap();
    connect(&mut master, &mut slave, 5);
    let got = deliver_to(
        "command 77",
        || master.publish(&command(5, 77)).unwrap(),
        &mut slave,
        |c| c.seq == 77,
    );
    assert_eq!(got, command(5, 77));
}

#[test]
fn second_listener_on_a_taken_port_is_an_error() {
    let port = common::free_port();
    let _first = SlaveZenohLink::open(1, &ZenohConfig::listen_on_loopback(port)).unwrap();
    assert!(SlaveZenohLink::open(1, &ZenohConfig::listen_on_loopback(port)).is_err());
}

#[test]
fn a_waiting_receiver_wakes_for_a_message_and_times_out_without_one() {
    let port = common::free_port();
    let mut slave = SlaveZenohLink::open(6, &ZenohConfig::listen_on_loopback(port)).unwrap();
    let mut master = MasterZenohLink::open(6, &ZenohConfig::connect_to_loopback(port)).unwrap();
    connect(&mut master, &mut slave, 6);
    // The connection's own messages may still be on their way: let them land, then drop them.
    std::thread::sleep(Duration::from_millis(200));
    while slave.try_recv().unwrap().is_some() {}
    // Nothing sent: the wait ends at its timeout, with nothing waiting.
    assert!(!slave.wait_for_message(Duration::from_millis(20)));
    assert_eq!(slave.try_recv().unwrap(), None);
    // Sent from another thread while this one waits: the wait ends with it waiting. Zenoh
    // publishes with congestion control `Drop`, so the sender repeats until it is seen.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sender = {
        let stop = std::sync::Arc::clone(&stop);
        std::thread::spawn(move || {
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(5));
                master.publish(&command(6, 91)).unwrap();
            }
        })
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    let got = loop {
        assert!(Instant::now() < deadline, "no message woke the receiver");
        if slave.wait_for_message(Duration::from_secs(1)) {
            break slave.try_recv().unwrap();
        }
    };
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    sender.join().unwrap();
    assert_eq!(got, Some(command(6, 91)));
}
