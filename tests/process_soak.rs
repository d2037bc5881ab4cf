//! Soak (issue 14): `h4-master loopback` at 1 kHz for 60 s (`H4_SOAK_S` overrides: the
//! documented 10-minute run is `H4_SOAK_S=600`), recording. Sampled once a second from
//! outside, for both processes: resident memory flat (≤ 1 MiB growth after the first 10 s),
//! open file descriptors and shared-memory mappings constant after the first 10 s; deadline
//! misses of both loops inside host stalls but for at most 1 in 1 000 cycles, or 20 % of the
//! misses on a host that stalls often (`deadline_misses_outside_stalls`: a miss after a cycle
//! that used a whole period of the loop thread's CPU; see the test for why not 0 on this VM). `H4_SOAK_WITNESS_US=1000` also runs
//! an outside witness of host stalls (`h4_tests::stalls`) and reports which misses it explains.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use h4_tests::procs::*;
use h4_tests::stalls::StallWitness;

/// Growth of resident memory allowed after the warm-up, KiB.
const MAX_RSS_GROWTH_KIB: u64 = 1024;
/// Deadline misses counted as the loop's own allowed per cycle (see the test).
const MAX_OWN_MISS_RATE: f64 = 1e-3;
/// Or, on a host that stalls often, the share of all misses that may be counted as the
/// loop's own (see the test).
const MAX_OWN_MISS_SHARE: f64 = 0.2;
/// The warm-up the memory criterion starts after, s.
const WARM_UP_S: f64 = 10.0;

#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    t_s: f64,
    rss_kib: u64,
    fds: usize,
    shm_maps: usize,
}

fn sample(pid: i32, t_s: f64) -> Option<Sample> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss_kib = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count();
    let maps = std::fs::read_to_string(format!("/proc/{pid}/maps")).ok()?;
    let mut shm: Vec<&str> = maps
        .lines()
        .filter_map(|l| l.split_whitespace().nth(5))
        .filter(|p| p.starts_with("/dev/shm/"))
        .collect();
    shm.sort_unstable();
    shm.dedup();
    Some(Sample {
        t_s,
        rss_kib,
        fds,
        shm_maps: shm.len(),
    })
}

fn judge(who: &str, samples: &[Sample]) {
    let after: Vec<&Sample> = samples.iter().filter(|s| s.t_s >= WARM_UP_S).collect();
    assert!(
        after.len() >= 20,
        "{who}: too few samples after the warm-up: {samples:?}"
    );
    let base = after[0];
    let max_rss = after.iter().map(|s| s.rss_kib).max().unwrap_or(0);
    let (fd_min, fd_max) = (
        after.iter().map(|s| s.fds).min().unwrap_or(0),
        after.iter().map(|s| s.fds).max().unwrap_or(0),
    );
    let (shm_min, shm_max) = (
        after.iter().map(|s| s.shm_maps).min().unwrap_or(0),
        after.iter().map(|s| s.shm_maps).max().unwrap_or(0),
    );
    let last = after[after.len() - 1];
    eprintln!(
        "soak {who}: RSS {} KiB at {:.0} s, max {} KiB after it, {} KiB at the end ({:.0} s); fds {fd_min}–{fd_max}; /dev/shm mappings {shm_min}–{shm_max}",
        base.rss_kib, base.t_s, max_rss, last.rss_kib, last.t_s
    );
    assert!(
        max_rss <= base.rss_kib + MAX_RSS_GROWTH_KIB,
        "{who}: resident memory grew {} KiB after {WARM_UP_S} s",
        max_rss - base.rss_kib
    );
    assert_eq!(
        fd_min, fd_max,
        "{who}: open file descriptors changed: {samples:?}"
    );
    assert_eq!(
        shm_min, shm_max,
        "{who}: shared-memory mappings changed: {samples:?}"
    );
    assert!(shm_min > 0, "{who}: no iceoryx2 shared memory mapped?");
}

#[test]
fn a_long_loopback_keeps_memory_descriptors_and_deadlines() {
    let _g = serial();
    let (master, _) = binaries();
    let soak_s: f64 = std::env::var("H4_SOAK_S")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60.0);
    let scratch = Scratch::new("soak");
    let summary = scratch.path("summary.json");
    let rec = scratch.path("soak.mcap");
    let (sp, rp) = (summary.display().to_string(), rec.display().to_string());
    let args = loopback_args(&soak_s.to_string(), &["--summary", &sp, "--record", &rp]);
    // The stall witness only on request: it costs the loops deadlines (tests/src/stalls.rs).
    let witness = std::env::var("H4_SOAK_WITNESS_US")
        .ok()
        .and_then(|us| us.parse().ok())
        .map(|us| StallWitness::start(Duration::from_micros(us)));
    let mut lb = Running::spawn("loopback", master, &args, &scratch);
    let slave = KillOnDrop(child_of(lb.pid(), 30.0));
    let start = Instant::now();
    let (mut ms, mut ss) = (Vec::new(), Vec::new());
    loop {
        let t = start.elapsed().as_secs_f64();
        match (sample(lb.pid(), t), sample(slave.0, t)) {
            (Some(m), Some(s)) => {
                ms.push(m);
                ss.push(s);
            }
            _ => break,
        }
        assert!(t < soak_s + 120.0, "watchdog: the loopback did not end");
        std::thread::sleep(Duration::from_secs(1));
    }
    let _ = lb.wait_status(120.0);
    let stalls = witness.map(StallWitness::stop);
    // The last second may catch the stop (recording merged, summaries written).
    ms.pop();
    ss.pop();
    judge("master", &ms);
    judge("slave", &ss);
    let v = read_json(&summary);
    eprintln!(
        "soak loopback: stable {} realtime_ok {} cycles {} misses {} (master {} / slave {} outside stalls), lateness p99 {} us, round trip p99 {} us, max force {:.1} N",
        v["stable"],
        v["realtime_ok"],
        v["cycles"],
        v["deadline_misses"],
        v["master"]["deadline_misses_outside_stalls"],
        v["slave"]["deadline_misses_outside_stalls"],
        v["lateness_p99_us"],
        v["round_trip_p99_us"],
        f(&v, "max_force_n")
    );
    assert_eq!(v["stable"], true, "{v:#}");
    assert_eq!(v["complete"], true, "{v:#}");
    // A miss after a cycle that used a whole period of the loop thread's CPU is counted as
    // the loop's own. This VM's hypervisor does not report steal time, so a stall inside a
    // cycle is charged to the thread as CPU (single cycles of 4–6 ms "CPU" seen under load,
    // against tens of µs of work): the criterion cannot clear those, and the bound is a rate
    // (1 in 1000: 9 such misses in 60 000 cycles were measured with nothing else running on
    // 2026-12-02; a loop that overran its period by itself would miss every cycle). On a host
    // that stalls often the stalls land inside a cycle's body about as often as the body's
    // share of the period (the thread's CPU is ~20 % of a core, most of it the pacer's spin):
    // CI's host on 2026-12-03 missed 2 902 / 2 990 of 57 098 deadlines, 95 / 28 of them
    // charged as own (3.3 % / 0.9 %). So either bound clears a loop: the rate, or a share of
    // all misses ≤ 20 %; a loop whose own work overran would have nearly all its misses
    // outside stalls, and fails both.
    for who in ["master", "slave"] {
        let own = u(&v[who], "deadline_misses_outside_stalls") as f64;
        let misses = u(&v[who], "deadline_misses") as f64;
        assert!(
            own <= MAX_OWN_MISS_RATE * u(&v[who], "cycles") as f64
                || own <= MAX_OWN_MISS_SHARE * misses,
            "{who}: {own} of {misses} deadline misses not explained by a host stall: {v:#}"
        );
    }
    assert!(u(&v, "cycles") as f64 > 0.9 * soak_s * 1000.0, "{v:#}");
    for who in ["master", "slave"] {
        let spans = miss_spans(&v[who]);
        assert!(
            spans.len() as u64 <= u(&v[who], "deadline_misses"),
            "{who}: more miss spans than misses: {v:#}"
        );
        assert!(
            spans.iter().all(|s| s[1] >= s[0] + 1_000_000),
            "{who}: a miss span shorter than a period: {spans:?}"
        );
        let Some(stalls) = &stalls else { continue };
        let unexplained = stalls.unexplained(&spans);
        eprintln!(
            "soak {who}: {} misses, {} unexplained by the {} stalls the witness saw (longest {:.1} ms, trustworthy {}): {unexplained:?}",
            spans.len(),
            unexplained.len(),
            stalls.count(),
            stalls.longest_ms(),
            stalls.trustworthy()
        );
    }
}

/// A process summary's `deadline_miss_spans_ns`.
fn miss_spans(v: &serde_json::Value) -> Vec<[u64; 2]> {
    v["deadline_miss_spans_ns"]
        .as_array()
        .expect("deadline_miss_spans_ns")
        .iter()
        .map(|p| [p[0].as_u64().expect("ns"), p[1].as_u64().expect("ns")])
        .collect()
}
