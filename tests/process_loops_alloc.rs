//! The 1 kHz loops of `h4-master run` and `h4-slave run` allocate nothing per cycle: each
//! loop runs twice on its own thread, for 300 and for 900 real 1 ms cycles, against the other
//! side's loop on a helper thread over an in-process link; a counting global allocator
//! (per thread) must see the same number of allocations on the measured thread both times
//! (set-up and summary allocate, the cycles do not).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use h4_master::server::MasterRunOptions;
use h4_master_sim::session::{self, SessionConfig};
use h4_shared::alloc_count::{CountingAllocator, count_allocations};
use h4_slave::server::RunOptions;
use h4_slave_sim::experiment::ExperimentConfig;
use h4_telemetry::progress::{Mode, ProgressConfig};
use h4_transport::inproc;

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

fn config_path(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn session() -> SessionConfig {
    session::load(&config_path("config/sessions/wall-push.toml"), &[]).unwrap()
}

fn world() -> ExperimentConfig {
    h4_shared::config::load(&config_path("config/slave/sim-resin.toml"), &[]).unwrap()
}

/// Plain progress lines every 50 ms: the status text is formatted and handed to the
/// reporter many times in each measured run.
fn progress(label: &str) -> ProgressConfig {
    ProgressConfig {
        mode: Mode::Plain,
        plain_interval_s: 0.05,
        label: label.into(),
    }
}

fn master_opts(duration_s: f64) -> MasterRunOptions {
    MasterRunOptions {
        duration_s: Some(duration_s),
        wait_for_slave_s: 0.0,
        progress: progress("alloc test, master"),
        ..MasterRunOptions::default()
    }
}

fn slave_opts(duration_s: f64) -> RunOptions {
    RunOptions {
        duration_s: Some(duration_s),
        progress: progress("alloc test, slave"),
        ..RunOptions::default()
    }
}

/// The live view on: its per-cycle hand-off is on the measured thread too; so is the
/// `--ros2` hand-off (the cycle written into the publishing thread's cell).
fn live_master() -> h4_master_sim::server::RunOutputs {
    h4_master_sim::server::RunOutputs {
        foxglove_ws: Some("127.0.0.1:0".into()),
        ros2: Some(std::sync::Arc::new(
            h4_transport::ros2::telemetry::LatestCell::new(),
        )),
        ..Default::default()
    }
}

/// The live view and the `--ros2` hand-off on (the slave's).
fn live_slave() -> h4_slave_sim::server::RunOutputs {
    h4_slave_sim::server::RunOutputs {
        foxglove_ws: Some("127.0.0.1:0".into()),
        ros2: Some(std::sync::Arc::new(
            h4_transport::ros2::telemetry::LatestCell::new(),
        )),
        ..Default::default()
    }
}

/// The master loop on this thread for `duration_s`, a slave loop on a helper thread.
fn master_run(duration_s: f64) -> (u64, u64) {
    let (m, mut s) = inproc::pair(64);
    let cfg = session();
    let w = world();
    let helper = std::thread::spawn(move || {
        h4_slave_sim::server::run(&w, &slave_opts(duration_s + 0.5), &live_slave(), &mut s).unwrap()
    });
    let (n, summary) = count_allocations(|| {
        h4_master_sim::server::run(&cfg, &master_opts(duration_s), &live_master(), m).unwrap()
    });
    helper.join().unwrap();
    (n, summary.run.cycles)
}

/// The slave loop on this thread for `duration_s`, a master loop on a helper thread.
fn slave_run(duration_s: f64) -> (u64, u64) {
    let (m, mut s) = inproc::pair(64);
    let cfg = session();
    let w = world();
    let helper = std::thread::spawn(move || {
        h4_master_sim::server::run(&cfg, &master_opts(duration_s + 0.5), &live_master(), m).unwrap()
    });
    let (n, summary) = count_allocations(|| {
        h4_slave_sim::server::run(&w, &slave_opts(duration_s), &live_slave(), &mut s).unwrap()
    });
    helper.join().unwrap();
    (n, summary.run.cycles)
}

/// A run of 0.9 s allocates exactly as much as one of 0.3 s (set-up only), over at least
/// 300 more cycles. `run(duration_s)` returns (allocations, cycles).
fn assert_allocates_nothing_per_cycle(run: fn(f64) -> (u64, u64)) {
    let (short, short_cycles) = run(0.3);
    let (long, long_cycles) = run(0.9);
    assert!(
        long_cycles > short_cycles + 300,
        "{short_cycles} vs {long_cycles} cycles"
    );
    assert_eq!(
        long, short,
        "{long} allocations in {long_cycles} cycles vs {short} in {short_cycles}"
    );
}

#[test]
fn master_loop_allocates_nothing_per_cycle() {
    assert_allocates_nothing_per_cycle(master_run);
}

#[test]
fn slave_loop_allocates_nothing_per_cycle() {
    assert_allocates_nothing_per_cycle(slave_run);
}
