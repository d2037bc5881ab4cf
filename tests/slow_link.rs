//! A slow, not dead, link against the real processes (issue 16): between two hosts (network
//! namespaces) over Zenoh/TCP through the relay, every message is held 300 ms for 5 s in the
//! middle of a contact, then the link is normal again. No safe-state flapping, no energy
//! generated. Skipped with a printed `SKIPPED` line where namespaces cannot be made.
//!
//! When every message becomes 300 ms late at once, nothing arrives for 300 ms: the slave's
//! 20 ms watchdog trips once (a real outage) and re-pairs when the late commands arrive; it
//! must then stay paired through the slow stretch (late but steady commands) and through the
//! return to normal (the relay keeps order: no gap there). Flapping would be a trip every
//! time the late stream hiccups. Allowed: that one trip at the onset plus one for a host
//! stall (this VM stalls for 3–66 ms a few times a minute); the trip when the run ends and
//! the episodes of a loaded start-up before the slow stretch (CI, 2026-12-03: the first
//! commands stalled 0.6 s twice in three runs) are not counted.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::SocketAddr;
use std::time::Duration;

use h4_tests::netns::{Host, TwoHosts};
use h4_tests::record;
use h4_tests::relay::{Proto, Relay};
use h4_tests::remote_procs::{self, Pair, PairSpec, Scratch};
use h4_transport::impair::ImpairmentConfig;

const SESSION: &str = "config/sessions/wall-push.toml";

#[test]
fn a_link_300_ms_late_for_5_s_neither_flaps_nor_generates_energy() {
    let Some(hosts) = TwoHosts::new_or_skip("slow_link") else {
        return;
    };
    let scratch = Scratch::new("slow-link").unwrap();
    let target = SocketAddr::new(hosts.ip(Host::Slave).into(), 7447);
    let relay = Relay::start(&hosts, Proto::Tcp, target, ImpairmentConfig::default()).unwrap();
    let (slave_args, master_args) = remote_procs::zenoh_across(target, &relay);
    let spec = PairSpec {
        tag: "slow",
        session: SESSION,
        overrides: vec![
            "environment.stiffness_n_per_mm=0".into(),
            "duration_s=9.5".into(),
        ],
        duration_s: 9.5,
        slave_args,
        master_args,
    };
    let mut pair = Pair::start_on(&hosts, &spec, &scratch).unwrap();
    let started = std::time::Instant::now();
    std::thread::sleep(Duration::from_millis(2000));
    // When the slow stretch starts on the slave's clock, at the latest (the slave's clock
    // started before `start_on` returned): a re-paired episode that began before it is the
    // start-up's, not the slow link's.
    let slow_from_s = started.elapsed().as_secs_f64() - 0.2;
    relay.set(ImpairmentConfig {
        delay_ms: 300.0,
        ..ImpairmentConfig::default()
    });
    std::thread::sleep(Duration::from_millis(5000));
    relay.set(ImpairmentConfig::default());
    let (m, s) = pair.finish().unwrap();
    // No energy generated, forces within limits.
    let why = remote_procs::judge(
        &m,
        &s,
        &remote_procs::session(SESSION, &spec.overrides).unwrap(),
    );
    assert!(why.is_empty(), "{why:?}\n{m:#?}\n{s:#?}");
    // The slow stretch really was slow.
    assert!(m.round_trip_max_us >= 600_000.0, "{m:#?}");
    let cycles = record::slave_cycles(&pair.slave_record).unwrap();
    let episodes = record::safe_episodes(&cycles);
    let repaired: Vec<_> = episodes.iter().filter(|e| e.repaired_s.is_some()).collect();
    let during: Vec<_> = repaired
        .iter()
        .filter(|e| e.entry_s >= slow_from_s)
        .collect();
    println!(
        "safe stops {}, repairs {}, safe-state episodes that re-paired: {during:#?}\nall: {episodes:#?}\nmaster: {m:#?}",
        s.safe_stops, s.repairs
    );
    assert!(
        during.len() <= 2,
        "the safe state flapped: {} episodes\n{during:#?}",
        during.len()
    );
    // The master fades out for each of the slave's safe stops it sees, and may time out
    // once more on its own (the onset's 300 ms of silence can reach it before the slave's
    // safe stop does). CI, 2026-12-03: a loaded start-up stalled the first commands for
    // 0.6 s (a safe stop before the slow stretch, re-paired at once), the onset tripped
    // once, and the master counted 3 fade-outs against the former fixed bound of 2.
    assert!(
        m.feedback_losses <= repaired.len() as u64 + 1,
        "{} fade-outs for {} safe-state episodes: {m:#?}",
        m.feedback_losses,
        repaired.len()
    );
}
