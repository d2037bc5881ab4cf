//! Time, injected: the control code reads a [`Clock`], never the system time, so the same
//! code runs on the monotonic clock in a process and on a simulated clock in tests.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// A source of monotonic time in nanoseconds since an arbitrary origin.
pub trait Clock {
    /// Now, ns since the clock's origin. Never decreases.
    fn now_ns(&self) -> u64;
}

/// The operating system's monotonic clock, with its origin at construction.
#[derive(Clone, Copy, Debug)]
pub struct MonotonicClock {
    origin: Instant,
    origin_unix_ns: u64,
    origin_monotonic_ns: u64,
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> Self {
        let origin_unix_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
        let origin = Instant::now();
        // `Instant` reads CLOCK_MONOTONIC on Linux: the read right after it is the same
        // origin within the call's cost.
        MonotonicClock {
            origin,
            origin_unix_ns,
            origin_monotonic_ns: monotonic_ns(),
        }
    }

    /// The Unix time (ns since 1970, as the system clock read it at the origin) of the clock's
    /// `ns`: a time base that processes on one host share, for recordings that are merged.
    /// Later steps of the system clock do not affect it.
    pub fn unix_ns(&self, ns: u64) -> u64 {
        self.origin_unix_ns.saturating_add(ns)
    }

    /// The origin on the host's `CLOCK_MONOTONIC`, ns: the clock every process of the host
    /// shares, so this clock's times can be matched with another process's.
    pub fn origin_monotonic_ns(&self) -> u64 {
        self.origin_monotonic_ns
    }

    /// The instant that is `ns` after the origin.
    pub fn instant_at(&self, ns: u64) -> Instant {
        self.origin + std::time::Duration::from_nanos(ns)
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }
}

/// A simulated clock that only moves when told to. Clones share the same time, so a test
/// keeps one handle to advance and gives the others to the code under test.
#[derive(Clone, Debug, Default)]
pub struct SimClock {
    now_ns: Arc<AtomicU64>,
}

impl SimClock {
    /// A simulated clock at time zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves time forward by `dt_ns`.
    pub fn advance_ns(&self, dt_ns: u64) {
        self.now_ns.fetch_add(dt_ns, Ordering::Relaxed);
    }

    /// Sets the time; ignored if it would move time backwards.
    pub fn set_ns(&self, t_ns: u64) {
        self.now_ns.fetch_max(t_ns, Ordering::Relaxed);
    }
}

impl Clock for SimClock {
    fn now_ns(&self) -> u64 {
        self.now_ns.load(Ordering::Relaxed)
    }
}

/// `CLOCK_MONOTONIC` now, ns: the same clock in every process of the host (what `Instant`
/// reads on Linux), so times from two processes and a test can be compared.
pub fn monotonic_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// CPU time the calling thread has used, ns (0 if unknown).
pub fn thread_cpu_ns() -> u64 {
    clock_ns(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// The clock `id` now, ns (0 if unknown).
#[allow(unsafe_code)]
fn clock_ns(id: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer to a live timespec; `id` is one of libc's clock constants.
    if unsafe { libc::clock_gettime(id, &mut ts) } != 0 {
        return 0;
    }
    u64::try_from(ts.tv_sec).unwrap_or(0) * 1_000_000_000 + u64::try_from(ts.tv_nsec).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_clock_moves_only_forward_and_is_shared() {
        let clock = SimClock::new();
        let view = clock.clone();
        clock.advance_ns(1_000_000);
        assert_eq!(view.now_ns(), 1_000_000);
        clock.set_ns(10);
        assert_eq!(view.now_ns(), 1_000_000);
    }

    #[test]
    fn monotonic_clock_does_not_go_back() {
        let clock = MonotonicClock::new();
        let a = clock.now_ns();
        let b = clock.now_ns();
        assert!(b >= a);
    }
}
