//! A slow, not dead, link against the real processes (issue 16): between two hosts (network
//! namespaces) over Zenoh/TCP through the relay, every message is held 300 ms for 5 s in the
//! middle of a contact, then the link is normal again. No safe-state flapping, no energy
//! generated. Skipped with a printed `SKIPPED` line where namespaces cannot be made.
//!
//! When every message becomes 300 ms late at once, nothing arrives for 300 ms: the slave's
//! 20 ms watchdog trips once (a real outage) and re-pairs when the late commands arrive; it
//! must then stay paired through the slow stretch (late but steady commands) and through the
//! return to normal (the relay keeps order: no gap there). Flapping would be a trip every
//! time the late stream hiccups. Allowed: that one trip at the onset plus one more; the trip
//! when the run ends, the episodes of a loaded start-up before the slow stretch (CI,
//! 2026-12-03: the first commands stalled 0.6 s twice in three runs) and the episodes a host
//! stall explains are not counted. This VM stalls for 3–66 ms a few times a minute, and on a
//! noisy day (2026-12-03: 200–650 missed deadlines a minute) one in the 5 s stretch is
//! likely: a stall of ≥ [`STALL_MS`] seen by an outside witness (`h4_tests::stalls`, one
//! SCHED_FIFO 99 sentinel per CPU, every 2 ms) or by either loop's own missed deadlines
//! explains an episode that begins within [`STALL_REACH_MS`] of its end (the stretch's
//! 300 ms delay, the 20 ms watchdog, margin). Every episode, explained or not, is printed.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::SocketAddr;
use std::time::Duration;

use h4_telemetry::rt::monotonic_ns;
use h4_tests::netns::{Host, TwoHosts};
use h4_tests::record::{self, SafeEpisode};
use h4_tests::relay::{Proto, Relay};
use h4_tests::remote_procs::{self, Pair, PairSpec, Scratch};
use h4_tests::stalls::{StallWitness, explains_trip, long_stalls};

/// At most this many re-paired episodes in the slow stretch may be excused by host stalls.
const MAX_EXCUSED: usize = 2;
use h4_transport::impair::ImpairmentConfig;

const SESSION: &str = "config/sessions/wall-push.toml";
/// A stall at least this long can silence the link for the watchdog's 20 ms, ms.
const STALL_MS: f64 = 8.0;
/// How long after a stall's end a trip can still be its consequence, ms.
const STALL_REACH_MS: f64 = 400.0;

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
    let witness = StallWitness::start(Duration::from_millis(2));
    let mut pair = Pair::start_on(&hosts, &spec, &scratch).unwrap();
    std::thread::sleep(Duration::from_millis(2000));
    // When the slow stretch starts, on the host's monotonic clock (the slave's recording is
    // placed on it by its loop's `clock_origin_monotonic_ns`): a re-paired episode that
    // began before it is the start-up's, not the slow link's.
    let slow_from_ns = monotonic_ns();
    relay.set(ImpairmentConfig {
        delay_ms: 300.0,
        ..ImpairmentConfig::default()
    });
    std::thread::sleep(Duration::from_millis(5000));
    relay.set(ImpairmentConfig::default());
    let (m, s) = pair.finish().unwrap();
    let seen = witness.stop();
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
    let stalls = long_stalls(Some(&seen), &[&m.run, &s.run], STALL_MS);
    let entry_ns = |e: &SafeEpisode| s.run.clock_origin_monotonic_ns + (e.entry_s * 1e9) as u64;
    let (explained, during): (Vec<&&SafeEpisode>, Vec<_>) = repaired
        .iter()
        .filter(|e| entry_ns(e) >= slow_from_ns)
        .partition(|e| explains_trip(&stalls, entry_ns(e), STALL_REACH_MS));
    println!(
        "safe stops {}, repairs {}, re-paired episodes in the stretch no stall explains: {during:#?}\n\
         explained by the stalls {stalls:?} (witness trustworthy: {}, longest {:.1} ms): {explained:#?}\n\
         all: {episodes:#?}\nmaster: {m:#?}",
        s.safe_stops,
        s.repairs,
        seen.trustworthy(),
        seen.longest_ms()
    );
    assert!(
        during.len() <= 2,
        "the safe state flapped: {} episodes\n{during:#?}",
        during.len()
    );
    println!(
        "re-paired episodes excused by host stalls: {} (at most {MAX_EXCUSED})",
        explained.len()
    );
    assert!(
        explained.len() <= MAX_EXCUSED,
        "{} episodes excused by host stalls, more than {MAX_EXCUSED}: {explained:#?}",
        explained.len()
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
