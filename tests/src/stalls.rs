//! An outside witness of host stalls for the real-process tests.
//!
//! The host stalls this VM for milliseconds a few times a minute, and its hypervisor does not
//! report steal time: inside the guest a stalled thread looks as if it ran. A process's loop
//! cannot tell a stall from its own overrun, so the witness is a separate one: one sentinel
//! thread per CPU, pinned to it, under `SCHED_FIFO` at priority 99 (above every loop of the
//! project, which run at ≤ 80), waking every period on `CLOCK_MONOTONIC`. Nothing
//! in the guest keeps such a thread from running for a millisecond but the host (or the
//! kernel's own non-preemptible work), so a gap between two of its wake-ups is a stall of
//! that CPU. A loop's deadline miss (the processes report each one's `[deadline, woke]` on
//! the same clock, `deadline_miss_spans_ns`) is explained by a stall when a sentinel's gap
//! covers it.
//!
//! Measured with it (docs/processes.md, "Soak", "An outside witness of the stalls"): it is
//! not free. Woken every 250 µs the sentinels multiplied the loops' misses by ~18; every
//! millisecond they see the stalls of ≥ 1.5 ms only, and 20 % of the loops' misses (mostly
//! 1.0–1.5 ms late) fall outside those. So `tests/process_soak.rs` runs it only on request
//! (`H4_SOAK_WITNESS_US`) and reports, never judges, with it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use h4_telemetry::rt::{LoopReport, monotonic_ns};

/// A gap between two wake-ups longer than the sentinel's period plus this is recorded as a
/// stall, ns.
pub const STALL_EXTRA_NS: u64 = 500_000;
/// How far a stall's recorded edges may be from a miss's edges and still explain it: a
/// sentinel sees a stall's start up to a period late and its end within its wake-up
/// latency; the loop's deadline may fall a little before the stall when its last cycle's
/// work ran into it, ns.
pub const EDGE_TOLERANCE_NS: u64 = 500_000;

/// The sentinels, running until [`StallWitness::stop`].
pub struct StallWitness {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<Sentinel>>,
}

/// What one sentinel saw.
#[derive(Clone, Debug, Default)]
pub struct Sentinel {
    /// The CPU it was pinned to.
    pub cpu: usize,
    /// Whether it ran under `SCHED_FIFO` 99 and pinned (without, its gaps prove nothing).
    pub privileged: bool,
    /// Its gaps longer than its period + [`STALL_EXTRA_NS`], `[from_ns, to_ns]` on `CLOCK_MONOTONIC`.
    pub gaps_ns: Vec<[u64; 2]>,
}

/// What the witness saw, per CPU.
#[derive(Clone, Debug, Default)]
pub struct Stalls {
    /// One per CPU.
    pub sentinels: Vec<Sentinel>,
}

impl Stalls {
    /// Whether every sentinel ran pinned under `SCHED_FIFO` 99.
    pub fn trustworthy(&self) -> bool {
        !self.sentinels.is_empty() && self.sentinels.iter().all(|s| s.privileged)
    }

    /// Whether a stall seen by any sentinel covers the miss `[deadline_ns, woke_ns]` (within
    /// [`EDGE_TOLERANCE_NS`] at either edge).
    pub fn explains(&self, miss: [u64; 2]) -> bool {
        self.sentinels.iter().flat_map(|s| &s.gaps_ns).any(|g| {
            g[0] <= miss[0].saturating_add(EDGE_TOLERANCE_NS)
                && g[1].saturating_add(EDGE_TOLERANCE_NS) >= miss[1]
        })
    }

    /// The misses no stall explains.
    pub fn unexplained(&self, misses: &[[u64; 2]]) -> Vec<[u64; 2]> {
        misses
            .iter()
            .copied()
            .filter(|m| !self.explains(*m))
            .collect()
    }

    /// Stalls seen, over all CPUs.
    pub fn count(&self) -> usize {
        self.sentinels.iter().map(|s| s.gaps_ns.len()).sum()
    }

    /// The longest stall seen, ms.
    pub fn longest_ms(&self) -> f64 {
        self.sentinels
            .iter()
            .flat_map(|s| &s.gaps_ns)
            .map(|g| (g[1] - g[0]) as f64 / 1e6)
            .fold(0.0, f64::max)
    }
}

impl StallWitness {
    /// One sentinel per online CPU waking every `period`, started now.
    pub fn start(period: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = (0..cpus)
            .map(|cpu| {
                let stop = Arc::clone(&stop);
                std::thread::spawn(move || sentinel(cpu, period, &stop))
            })
            .collect();
        StallWitness { stop, threads }
    }

    /// Stops the sentinels and returns what they saw.
    pub fn stop(self) -> Stalls {
        self.stop.store(true, Ordering::Relaxed);
        Stalls {
            sentinels: self
                .threads
                .into_iter()
                .map(|t| t.join().unwrap_or_default())
                .collect(),
        }
    }
}

#[allow(unsafe_code)]
fn pin_and_raise(cpu: usize) -> bool {
    // SAFETY: a zeroed cpu_set_t is a valid empty set; the calls get valid pointers to live
    // values and act on the calling thread (pid 0).
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        let pinned = libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0;
        let param = libc::sched_param { sched_priority: 99 };
        let fifo = libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0;
        pinned && fifo
    }
}

fn sentinel(cpu: usize, period: Duration, stop: &AtomicBool) -> Sentinel {
    let privileged = pin_and_raise(cpu);
    let mut gaps_ns = Vec::new();
    let stall_min_ns = u64::try_from(period.as_nanos())
        .unwrap_or(u64::MAX)
        .saturating_add(STALL_EXTRA_NS);
    let mut last = monotonic_ns();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(period);
        let now = monotonic_ns();
        if now.saturating_sub(last) > stall_min_ns {
            gaps_ns.push([last, now]);
        }
        last = now;
    }
    Sentinel {
        cpu,
        privileged,
        gaps_ns,
    }
}

/// The stalls at least `min_ms` long, `[from_ns, to_ns]` on `CLOCK_MONOTONIC`: the witness's
/// gaps (any CPU; none without a witness) and the loops' own missed-deadline spans (a loop
/// that did not run for that long is stalled, whoever froze it).
pub fn long_stalls(witness: Option<&Stalls>, loops: &[&LoopReport], min_ms: f64) -> Vec<[u64; 2]> {
    let min_ns = (min_ms * 1e6) as u64;
    witness
        .into_iter()
        .flat_map(|w| w.sentinels.iter().flat_map(|s| s.gaps_ns.iter()))
        .chain(loops.iter().flat_map(|l| l.deadline_miss_spans_ns.iter()))
        .filter(|g| g[1].saturating_sub(g[0]) >= min_ns)
        .copied()
        .collect()
}

/// Whether a trip at `t_ns` (`CLOCK_MONOTONIC`) can be one of `stalls`' consequences: a stall
/// began at or before it and ended at most `reach_ms` before it (the time a stall's silence
/// takes to reach the tripping side: the link's delay and the watchdog).
pub fn explains_trip(stalls: &[[u64; 2]], t_ns: u64, reach_ms: f64) -> bool {
    let reach_ns = (reach_ms * 1e6) as u64;
    stalls
        .iter()
        .any(|g| g[0] <= t_ns && t_ns <= g[1].saturating_add(reach_ns))
}

/// A loopback summary's (`h4-master loopback --summary`) slave safe stops that no stall of
/// either loop explains: the stalls at least `min_ms` long in the `master` and `slave`
/// `deadline_miss_spans_ns`, each reaching `reach_ms` past its end
/// ([`explains_trip`]); the slave's `safe_stop_times_ns` (`CLOCK_MONOTONIC`).
///
/// # Panics
/// When the summary has not one trip time per safe stop (a test helper).
pub fn trips_outside_stalls(v: &serde_json::Value, min_ms: f64, reach_ms: f64) -> Vec<u64> {
    // A summary without the fields explains nothing (and fails the count below).
    let report =
        |side: &str| serde_json::from_value::<LoopReport>(v[side].clone()).unwrap_or_default();
    let (m, s) = (report("master"), report("slave"));
    let stalls = long_stalls(None, &[&m, &s], min_ms);
    let times: Vec<u64> = v["slave"]["safe_stop_times_ns"]
        .as_array()
        .map(|a| a.iter().filter_map(serde_json::Value::as_u64).collect())
        .unwrap_or_default();
    assert_eq!(
        Some(times.len() as u64),
        v["slave"]["safe_stops"].as_u64(),
        "a trip time per safe stop: {v:#}"
    );
    times
        .into_iter()
        .filter(|&t| !explains_trip(&stalls, t, reach_ms))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stalls(gaps: &[[u64; 2]]) -> Stalls {
        Stalls {
            sentinels: vec![Sentinel {
                cpu: 0,
                privileged: true,
                gaps_ns: gaps.to_vec(),
            }],
        }
    }

    #[test]
    fn a_miss_inside_a_stall_is_explained_one_outside_is_not() {
        let ms = 1_000_000;
        let s = stalls(&[[100 * ms, 110 * ms]]);
        // Deadline inside the stall, woke at its end.
        assert!(s.explains([101 * ms, 110 * ms + 50_000]));
        // The last cycle's work ran into the stall: deadline a little after its start.
        assert!(s.explains([100 * ms + 300_000, 110 * ms]));
        // Woke long after the stall ended: the loop's own lateness.
        assert!(!s.explains([101 * ms, 113 * ms]));
        // No stall at that time.
        assert!(!s.explains([200 * ms, 202 * ms]));
        assert_eq!(s.unexplained(&[[200 * ms, 202 * ms]]).len(), 1);
        assert!((s.longest_ms() - 10.0).abs() < 1e-9);
    }

    #[test]
    fn long_stalls_join_witness_and_loops_and_reach_a_later_trip() {
        let ms = 1_000_000;
        let w = stalls(&[[100 * ms, 103 * ms], [200 * ms, 212 * ms]]);
        let l = LoopReport {
            deadline_miss_spans_ns: vec![[300 * ms, 309 * ms], [400 * ms, 401 * ms]],
            ..LoopReport::default()
        };
        let long = long_stalls(Some(&w), &[&l], 8.0);
        assert_eq!(long, vec![[200 * ms, 212 * ms], [300 * ms, 309 * ms]]);
        assert_eq!(long_stalls(None, &[&l], 8.0), vec![[300 * ms, 309 * ms]]);
        // A trip during a stall or within the reach after it; not before it, not later.
        assert!(explains_trip(&long, 205 * ms, 50.0));
        assert!(explains_trip(&long, 262 * ms, 50.0));
        assert!(!explains_trip(&long, 263 * ms, 50.0));
        assert!(!explains_trip(&long, 199 * ms, 50.0));
        // The short stall at 100 ms explains nothing.
        assert!(!explains_trip(&long, 101 * ms, 50.0));
    }
}
