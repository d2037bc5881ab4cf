//! The playout (jitter) buffer on a simulated clock, behind the impairment layer: a link
//! with ±J of jitter comes out in order and evenly spaced (what the receive gate then accepts
//! has no gap near 2J), the playout delay settles near the configured quantile of the
//! lateness, nothing is lost, a late message goes on at once, a new sender's messages follow
//! the old one's, and without the buffer (the control) the same link leaves the gate gaps of
//! tens of milliseconds.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::alloc_count::{CountingAllocator, allocations_in};
use h4_shared::clock::{Clock, SimClock};
use h4_shared::wire::{Command, Feedback, PROTOCOL_VERSION};
use h4_transport::Link;
use h4_transport::gate::Gate;
use h4_transport::impair::{Impaired, ImpairmentConfig};
use h4_transport::inproc::{self, InprocEnd};
use h4_transport::playout::{Playout, PlayoutConfig};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

const PERIOD_NS: u64 = 1_000_000;

fn command(session_id: u64, seq: u64, send_time_ns: u64) -> Command {
    Command {
        session_id,
        seq,
        send_time_ns,
        protocol_version: PROTOCOL_VERSION,
        arm_id: 0,
        ..Command::default()
    }
}

struct Trace {
    /// (seq, time accepted by the gate, ns).
    accepted: Vec<(u64, u64)>,
    /// Messages the receiver got from the link (accepted or not).
    received: u64,
    delay_ms: f64,
}

/// A 1 kHz sender for `n` ms through `impair`, a receiver polling once per ms through the
/// playout buffer (`playout`, None: without it) and a gate.
fn run(impair: ImpairmentConfig, playout: Option<PlayoutConfig>, n: u64) -> Trace {
    let clock = SimClock::new();
    let (master, slave): (InprocEnd<Command, Feedback>, _) = inproc::pair(100_000);
    let mut master = Impaired::new(master, clock.clone(), impair, PERIOD_NS).unwrap();
    let cfg = playout.unwrap_or_default();
    let mut slave = Playout::new(slave, clock.clone(), cfg);
    let mut gate = Gate::<Command>::new(0, u64::MAX);
    let mut t = Trace {
        accepted: Vec::new(),
        received: 0,
        delay_ms: 0.0,
    };
    for k in 0..n + 2000 {
        let now = clock.now_ns();
        if k < n {
            master.publish(&command(7, k + 1, now)).unwrap();
        } else {
            master.pump().unwrap();
        }
        while let Some(c) = slave.try_recv().unwrap() {
            t.received += 1;
            if gate.accept(&c, now).is_ok() {
                t.accepted.push((c.seq, now));
            }
        }
        clock.advance_ns(PERIOD_NS);
    }
    t.delay_ms = slave.counters.delay_ms;
    t
}

fn largest_gap_ms(t: &Trace, from_ns: u64) -> f64 {
    t.accepted
        .windows(2)
        .filter(|w| w[0].1 >= from_ns)
        .map(|w| (w[1].1 - w[0].1) as f64 / 1e6)
        .fold(0.0, f64::max)
}

fn jittery(delay_ms: f64, jitter_ms: f64, seed: u64) -> ImpairmentConfig {
    ImpairmentConfig {
        delay_ms,
        jitter_ms,
        seed,
        ..Default::default()
    }
}

fn on() -> PlayoutConfig {
    PlayoutConfig {
        enabled: true,
        ..PlayoutConfig::default()
    }
}

/// ±50 ms of jitter on 250 ms: with the buffer the gate accepts nearly every message (after
/// the first window of learning) with gaps of a few ms; without it the gaps reach tens of ms
/// and most messages are stale on arrival.
#[test]
fn a_jittery_link_comes_out_in_order_and_evenly_spaced() {
    for seed in [1, 2, 3] {
        let n = 10_000;
        let with = run(jittery(250.0, 50.0, seed), Some(on()), n);
        let without = run(jittery(250.0, 50.0, seed), None, n);
        assert_eq!(with.received, n, "seed {seed}: every message handed on");
        assert_eq!(without.received, n);
        // After two windows (4 s) of learning.
        let settled = 4_500_000_000;
        let gap_with = largest_gap_ms(&with, settled);
        let gap_without = largest_gap_ms(&without, settled);
        assert!(
            gap_with <= 12.0,
            "seed {seed}: gap {gap_with} ms with the buffer"
        );
        assert!(
            gap_without >= 25.0,
            "seed {seed}: gap {gap_without} ms without the buffer"
        );
        let tail = |t: &Trace| t.accepted.iter().filter(|a| a.1 >= settled).count() as f64;
        assert!(
            tail(&with) >= 0.9 * (n as f64 - 4_500.0 + 250.0),
            "seed {seed}: accepted {}",
            tail(&with)
        );
        assert!(tail(&without) < 0.5 * tail(&with));
        // Uniform lateness over 100 ms: its 95th percentile near 95 ms.
        assert!(
            (85.0..=100.0).contains(&with.delay_ms),
            "seed {seed}: playout delay {} ms",
            with.delay_ms
        );
    }
}

/// Without jitter the buffer holds nothing: the playout delay is 0 and the message times
/// are the link's.
#[test]
fn a_steady_link_goes_through_unchanged() {
    let with = run(jittery(30.0, 0.0, 1), Some(on()), 3000);
    let without = run(jittery(30.0, 0.0, 1), None, 3000);
    assert_eq!(with.accepted, without.accepted);
    assert_eq!(with.delay_ms, 0.0);
}

/// A message later than its playout time goes on at once; the longest hold is `max_ms`.
#[test]
fn late_messages_go_on_at_once_and_no_hold_exceeds_max_ms() {
    let clock = SimClock::new();
    let (mut tx, rx): (InprocEnd<Command, Feedback>, _) = inproc::pair(64);
    let mut rx = Playout::new(
        rx,
        clock.clone(),
        PlayoutConfig {
            enabled: true,
            quantile: 0.95,
            max_ms: 20.0,
        },
    );
    // Teach it a lateness spread of 0..60 ms: the quantile is ~57 ms, capped at 20.
    for k in 0..2000u64 {
        let now = clock.now_ns();
        let lateness = (k * 7919 % 61) * PERIOD_NS;
        tx.publish(&command(1, k + 1, now.saturating_sub(lateness)))
            .unwrap();
        while rx.try_recv().unwrap().is_some() {}
        clock.advance_ns(PERIOD_NS);
    }
    while rx.held() > 0 {
        while rx.try_recv().unwrap().is_some() {}
        clock.advance_ns(PERIOD_NS);
    }
    assert_eq!(rx.counters.delay_ms, 20.0);
    // The fastest path: held the full 20 ms, not more.
    let now = clock.now_ns();
    tx.publish(&command(1, 5000, now)).unwrap();
    assert!(rx.try_recv().unwrap().is_none());
    clock.advance_ns(19 * PERIOD_NS);
    assert!(rx.try_recv().unwrap().is_none());
    clock.advance_ns(PERIOD_NS);
    assert_eq!(rx.try_recv().unwrap().map(|c| c.seq), Some(5000));
    // A very late one (sent 100 ms ago): at once.
    let now = clock.now_ns();
    tx.publish(&command(1, 5001, now - 100 * PERIOD_NS))
        .unwrap();
    assert_eq!(rx.try_recv().unwrap().map(|c| c.seq), Some(5001));
    assert!(rx.counters.late >= 1);
}

/// A restarted sender (a new session id, its clock elsewhere): what is held from the old
/// one goes first, then the new one's, which is not held for the old clock's sake.
#[test]
fn a_new_sender_follows_the_old_one() {
    let clock = SimClock::new();
    let (mut tx, rx): (InprocEnd<Command, Feedback>, _) = inproc::pair(64);
    let mut rx = Playout::new(rx, clock.clone(), on());
    // Old sender: lateness alternating 0 and 30 ms, so messages are held ~30 ms.
    for k in 0..500u64 {
        let now = clock.now_ns();
        let lateness = if k % 2 == 0 { 0 } else { 30 * PERIOD_NS };
        tx.publish(&command(1, k + 1, now.saturating_sub(lateness)))
            .unwrap();
        while rx.try_recv().unwrap().is_some() {}
        clock.advance_ns(PERIOD_NS);
    }
    tx.publish(&command(1, 501, clock.now_ns())).unwrap();
    while rx.try_recv().unwrap().is_some() {}
    assert!(rx.held() > 0, "the fastest message is held ~30 ms");
    // The new sender's clock starts near 0.
    tx.publish(&command(2, 1, 1_000)).unwrap();
    let mut got = Vec::new();
    while let Some(c) = rx.try_recv().unwrap() {
        got.push((c.session_id, c.seq));
    }
    assert_eq!(got.last(), Some(&(2, 1)), "{got:?}");
    assert!(got.iter().filter(|g| g.0 == 1).count() >= 1);
    assert_eq!(rx.held(), 0);
}

/// Receiving through the buffer allocates nothing per message.
#[test]
fn the_playout_buffer_allocates_nothing_per_message() {
    let clock = SimClock::new();
    let (master, slave): (InprocEnd<Command, Feedback>, _) = inproc::pair(100_000);
    let mut master =
        Impaired::new(master, clock.clone(), jittery(50.0, 20.0, 3), PERIOD_NS).unwrap();
    let mut slave = Playout::new(slave, clock.clone(), on());
    let mut step = |k: u64| {
        master.publish(&command(1, k + 1, clock.now_ns())).unwrap();
        while slave.try_recv().unwrap().is_some() {}
        clock.advance_ns(PERIOD_NS);
    };
    for k in 0..3000 {
        step(k);
    }
    let n = allocations_in(|| {
        for k in 3000..8000 {
            step(k);
        }
    });
    assert_eq!(n, 0);
}
