//! The impairment decorator, on a simulated clock: exact constant delay, bounded jitter,
//! loss rates, Gilbert–Elliott burstiness, blackout windows, duplication and reordering, and
//! the same seed giving the same delivery trace.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::clock::{Clock, SimClock};
use h4_shared::wire::{Command, Feedback};
use h4_transport::Link;
use h4_transport::impair::{Impaired, ImpairmentConfig};
use h4_transport::inproc::{self, InprocEnd};

const PERIOD_NS: u64 = 1_000_000;

/// Publishes one command per ms for `n` ms; returns (seq, arrival time) of every delivery.
fn run(
    cfg: ImpairmentConfig,
    n: u64,
) -> (Vec<(u64, u64)>, h4_transport::impair::ImpairmentCounters) {
    let clock = SimClock::new();
    let (master, mut slave): (InprocEnd<Command, Feedback>, _) = inproc::pair(100_000);
    let mut master = Impaired::new(master, clock.clone(), cfg, PERIOD_NS).unwrap();
    let mut arrivals = Vec::new();
    for seq in 1..=n + 5000 {
        if seq <= n {
            master
                .publish(&Command {
                    seq,
                    ..Command::default()
                })
                .unwrap();
        } else {
            master.pump().unwrap();
        }
        while let Some(c) = slave.try_recv().unwrap() {
            arrivals.push((c.seq, clock.now_ns()));
        }
        clock.advance_ns(PERIOD_NS);
    }
    (arrivals, master.counters)
}

fn sent_at(seq: u64) -> u64 {
    (seq - 1) * PERIOD_NS
}

#[test]
fn constant_delay_is_exact() {
    let cfg = ImpairmentConfig {
        delay_ms: 50.0,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 1000);
    assert_eq!(arrivals.len(), 1000);
    for (seq, at) in &arrivals {
        assert_eq!(at - sent_at(*seq), 50_000_000, "seq {seq}");
    }
    assert_eq!(counters.delivered, 1000);
    assert_eq!(counters.reordered, 0);
}

#[test]
fn jitter_is_bounded_and_reorders() {
    let cfg = ImpairmentConfig {
        delay_ms: 100.0,
        jitter_ms: 20.0,
        seed: 3,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 5000);
    assert_eq!(arrivals.len(), 5000);
    let delays: Vec<u64> = arrivals.iter().map(|(s, at)| at - sent_at(*s)).collect();
    // Arrival is observed on the 1 ms grid: within [80, 121) ms.
    assert!(
        delays.iter().all(|d| (80_000_000..121_000_000).contains(d)),
        "{:?}",
        delays.iter().max()
    );
    let spread = delays.iter().max().unwrap() - delays.iter().min().unwrap();
    assert!(
        spread > 30_000_000,
        "jitter actually varies the delay: {spread}"
    );
    assert!(counters.reordered > 100, "{counters:?}");
}

#[test]
fn bernoulli_loss_rate_matches() {
    let cfg = ImpairmentConfig {
        loss: 0.2,
        seed: 11,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 20_000);
    let rate = counters.lost as f64 / 20_000.0;
    assert!((rate - 0.2).abs() < 0.015, "{rate}");
    assert_eq!(arrivals.len() as u64 + counters.lost, 20_000);
}

fn mean_burst_length(arrivals: &[(u64, u64)], n: u64) -> f64 {
    let got: std::collections::HashSet<u64> = arrivals.iter().map(|a| a.0).collect();
    let (mut bursts, mut lost, mut in_burst) = (0u64, 0u64, false);
    for seq in 1..=n {
        if got.contains(&seq) {
            in_burst = false;
        } else {
            lost += 1;
            if !in_burst {
                bursts += 1;
                in_burst = true;
            }
        }
    }
    lost as f64 / bursts.max(1) as f64
}

#[test]
fn gilbert_elliott_loss_comes_in_bursts() {
    // Stationary loss ≈ enter / (enter + exit) = 0.05, mean burst ≈ 1/exit = 10.
    let ge = ImpairmentConfig {
        burst_loss_enter: 0.005,
        burst_loss_exit: 0.1,
        seed: 5,
        ..Default::default()
    };
    let (ge_arrivals, ge_counters) = run(ge, 50_000);
    let bern = ImpairmentConfig {
        loss: 0.05,
        seed: 5,
        ..Default::default()
    };
    let (b_arrivals, _) = run(bern, 50_000);
    let ge_burst = mean_burst_length(&ge_arrivals, 50_000);
    let b_burst = mean_burst_length(&b_arrivals, 50_000);
    let ge_rate = ge_counters.lost as f64 / 50_000.0;
    assert!((0.02..0.09).contains(&ge_rate), "{ge_rate}");
    assert!(
        ge_burst > 5.0 && b_burst < 1.2,
        "GE {ge_burst} vs Bernoulli {b_burst}"
    );
}

#[test]
fn blackouts_drop_everything_inside_the_window() {
    let cfg = ImpairmentConfig {
        blackout_ms: 200.0,
        blackout_every_ms: 1000.0,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 3500);
    let got: std::collections::HashSet<u64> = arrivals.iter().map(|a| a.0).collect();
    for seq in 1..=3500u64 {
        let t_ms = sent_at(seq) / 1_000_000;
        let inside = t_ms >= 1000 && t_ms % 1000 < 200;
        assert_eq!(!got.contains(&seq), inside, "seq {seq} at {t_ms} ms");
    }
    assert_eq!(counters.blacked_out, 3 * 200);
}

#[test]
fn duplicates_arrive_twice() {
    let cfg = ImpairmentConfig {
        duplicate: 0.1,
        delay_ms: 5.0,
        seed: 9,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 10_000);
    assert_eq!(arrivals.len() as u64, 10_000 + counters.duplicated);
    assert!((800..1200).contains(&counters.duplicated), "{counters:?}");
}

#[test]
fn same_seed_same_trace_other_seed_other_trace() {
    let cfg = ImpairmentConfig {
        delay_ms: 20.0,
        jitter_ms: 4.0,
        loss: 0.05,
        duplicate: 0.01,
        reorder: 0.02,
        seed: 77,
        ..Default::default()
    };
    let a = run(cfg, 5000);
    let b = run(cfg, 5000);
    assert_eq!(a.0, b.0);
    let c = run(ImpairmentConfig { seed: 78, ..cfg }, 5000);
    assert_ne!(a.0, c.0);
}

#[test]
fn bad_configs_name_the_field() {
    let bad = ImpairmentConfig {
        loss: 1.5,
        ..Default::default()
    };
    let err = Impaired::<_, _, Command, Feedback>::new(
        inproc::pair(4).0,
        SimClock::new(),
        bad,
        PERIOD_NS,
    )
    .unwrap_err();
    assert!(err.to_string().contains("loss"), "{err}");
    let bad = ImpairmentConfig {
        blackout_ms: 300.0,
        blackout_every_ms: 200.0,
        ..Default::default()
    };
    let err = bad.validate_at("link.").unwrap_err();
    assert!(err.to_string().contains("link.blackout_ms"), "{err}");
    let clock = SimClock::new();
    assert_eq!(clock.now_ns(), 0);
}

/// On the wall clock (the processes' `MonotonicClock`): a 20 ms delay with jitter holds
/// every message back at least its delay, and delivers every one. (Only the lower bound is
/// asserted: how late a message comes depends on how this machine schedules the test.)
#[test]
fn delay_holds_messages_back_on_the_wall_clock() {
    use h4_shared::clock::MonotonicClock;
    let clock = MonotonicClock::new();
    let cfg = ImpairmentConfig {
        delay_ms: 20.0,
        jitter_ms: 5.0,
        reorder: 0.0,
        ..Default::default()
    };
    let (master, mut slave): (InprocEnd<Command, Feedback>, _) = inproc::pair(1024);
    let mut master = Impaired::new(master, clock, cfg, PERIOD_NS).unwrap();
    let mut sent = Vec::new();
    let mut arrivals = Vec::new();
    // Bounded: 50 messages 1 ms apart, then at most 2 s of pumping.
    for seq in 1..=50u64 {
        sent.push(clock.now_ns());
        master
            .publish(&Command {
                seq,
                ..Command::default()
            })
            .unwrap();
        while let Some(c) = slave.try_recv().unwrap() {
            arrivals.push((c.seq, clock.now_ns()));
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    let deadline = clock.now_ns() + 2_000_000_000;
    while arrivals.len() < 50 && clock.now_ns() < deadline {
        master.pump().unwrap();
        while let Some(c) = slave.try_recv().unwrap() {
            arrivals.push((c.seq, clock.now_ns()));
        }
        std::thread::sleep(std::time::Duration::from_micros(200));
    }
    assert_eq!(arrivals.len(), 50, "{:?}", master.counters);
    for (seq, at) in &arrivals {
        let held = at - sent[(*seq - 1) as usize];
        assert!(held >= 15_000_000, "seq {seq} delivered after {held} ns");
    }
}

/// Reordering: a share of the messages is held back by exactly the extra delay, so later
/// ones overtake them; every message still arrives.
#[test]
fn reorder_holds_back_a_share_by_the_extra_delay() {
    let cfg = ImpairmentConfig {
        delay_ms: 10.0,
        reorder: 0.2,
        reorder_extra_ms: 5.0,
        ..Default::default()
    };
    let (arrivals, counters) = run(cfg, 2000);
    assert_eq!(arrivals.len(), 2000);
    let mut held = 0;
    for (seq, at) in &arrivals {
        let d = at - sent_at(*seq);
        assert!(d == 10_000_000 || d == 15_000_000, "seq {seq}: {d} ns");
        if d == 15_000_000 {
            held += 1;
        }
    }
    assert!((300..500).contains(&held), "{held} of 2000 held back");
    assert_eq!(counters.reordered, held);
    let overtaken = arrivals.windows(2).filter(|w| w[1].0 < w[0].0).count();
    assert!(overtaken > 100, "{overtaken}");
}
