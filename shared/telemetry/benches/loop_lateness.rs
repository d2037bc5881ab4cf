//! 1 kHz loop lateness of the `rt::Pacer` (sleep to 200 µs before the deadline, then spin),
//! against plain `thread::sleep` to the deadline, the pacer with Linux's default timer slack
//! and with a wider spin margin, idle and with the other cores busy.
//! `cargo bench -p h4-shared --bench loop_lateness [-- SECONDS]` (default 10 s per case).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use h4_telemetry::rt::{Histogram, Pacer, set_fifo_priority, set_timer_slack_ns};

fn report(name: &str, h: &Histogram, misses: u64) {
    println!(
        "{name:<44} n={:>6} p50={:>7.1}us p99={:>7.1}us p99.9={:>8.1}us max={:>8.1}us misses={misses}",
        h.count(),
        h.quantile(0.5) as f64 / 1e3,
        h.quantile(0.99) as f64 / 1e3,
        h.quantile(0.999) as f64 / 1e3,
        h.max() as f64 / 1e3
    );
}

/// How a pacer case is set up.
#[derive(Clone, Copy)]
struct Setup {
    fifo: bool,
    spin_us: u64,
    /// Put the timer slack back to Linux's default for a normal thread (50 µs) after the
    /// pacer set its own, to show what the pacer's slack setting buys.
    default_slack: bool,
}

const PACER: Setup = Setup {
    fifo: false,
    spin_us: 200,
    default_slack: false,
};

fn pacer_case(name: &str, seconds: u64, setup: Setup) {
    let handle = std::thread::spawn(move || {
        let fifo_ok = setup.fifo && set_fifo_priority(80).is_ok();
        let mut p = Pacer::new(
            Duration::from_millis(1),
            Duration::from_micros(setup.spin_us),
        );
        if setup.default_slack {
            let _ = set_timer_slack_ns(50_000);
        }
        for _ in 0..seconds * 1000 {
            p.wait();
        }
        (p.lateness, p.misses, fifo_ok)
    });
    if let Ok((h, misses, fifo_ok)) = handle.join() {
        let label = if setup.fifo && !fifo_ok {
            format!("{name} (FIFO refused)")
        } else {
            name.to_string()
        };
        report(&label, &h, misses);
    }
}

fn sleep_case(name: &str, seconds: u64) {
    let mut h = Histogram::new();
    let start = Instant::now();
    let mut misses = 0;
    for n in 1..=seconds * 1000 {
        let deadline = start + Duration::from_millis(n);
        if let Some(d) = deadline.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let late = Instant::now().duration_since(deadline).as_nanos() as u64;
        misses += late / 1_000_000;
        h.record(late);
    }
    report(name, &h, misses);
}

fn main() {
    let seconds: u64 = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(10);
    sleep_case("thread::sleep to deadline, idle", seconds);
    pacer_case(
        "pacer, default 50us timer slack, idle",
        seconds,
        Setup {
            default_slack: true,
            ..PACER
        },
    );
    pacer_case(
        "pacer (sleep + 200us spin, 1us slack), idle",
        seconds,
        PACER,
    );
    pacer_case(
        "pacer, 300us spin, idle",
        seconds,
        Setup {
            spin_us: 300,
            ..PACER
        },
    );
    pacer_case(
        "pacer, SCHED_FIFO 80, idle",
        seconds,
        Setup {
            fifo: true,
            ..PACER
        },
    );
    let stop = Arc::new(AtomicBool::new(false));
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let burners: Vec<_> = (0..cores)
        .map(|_| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                }
                x
            })
        })
        .collect();
    pacer_case("pacer, all cores busy", seconds, PACER);
    pacer_case(
        "pacer, SCHED_FIFO 80, all cores busy",
        seconds,
        Setup {
            fifo: true,
            ..PACER
        },
    );
    stop.store(true, Ordering::Relaxed);
    for b in burners {
        let _ = b.join();
    }
}
