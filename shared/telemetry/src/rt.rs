//! Real-time loop support for the 1 kHz processes: a pacer on absolute deadlines (sleep to
//! shortly before the deadline, then spin), lateness statistics without allocation, a
//! deadline-miss counter, optional `SCHED_FIFO` and memory locking, and [`RtLoop`], the
//! loop shell both processes run their cycle in.
//!
//! Measured on the project's 2-vCPU VMs (see `docs/realtime.md`): sleeping to the deadline is
//! late by ~90 µs at p50 and by milliseconds at p99.9; sleeping to ~200 µs before it and then
//! spinning gives sub-microsecond p99. A thread that spins all the time under `SCHED_FIFO` is
//! frozen 50 ms every second by RT throttling, so the pacer spins only the last margin.
#![allow(unsafe_code)]

use std::time::{Duration, Instant};

const SUB_BITS: u32 = 7;
const SUB: usize = 1 << SUB_BITS;
const BUCKETS: usize = (64 - SUB_BITS as usize + 1) * SUB;

/// A log-linear histogram of nanosecond values (≤ 0.8 % relative bucket width: 128 linear
/// buckets per power of two, ≈ 8 µs at 1 ms, ≈ 0.2 µs at 20 µs), fixed size (58 KiB),
/// no allocation after construction.
#[derive(Clone)]
pub struct Histogram {
    counts: Box<[u64; BUCKETS]>,
    count: u64,
    max: u64,
    sum: u128,
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Histogram")
            .field("count", &self.count)
            .field("max", &self.max)
            .finish()
    }
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

fn bucket_of(v: u64) -> usize {
    if v < SUB as u64 {
        v as usize
    } else {
        let e = 63 - v.leading_zeros(); // ≥ SUB_BITS
        let sub = ((v >> (e - SUB_BITS)) as usize) & (SUB - 1);
        ((e - SUB_BITS + 1) as usize) * SUB + sub
    }
}

fn bucket_upper(i: usize) -> u64 {
    if i < SUB {
        i as u64
    } else {
        let e = (i / SUB) as u32 + SUB_BITS - 1;
        let sub = (i % SUB) as u64;
        let base = 1u64 << e;
        let width = 1u64 << (e - SUB_BITS);
        (base - 1) + (sub + 1) * width
    }
}

impl Histogram {
    /// An empty histogram.
    pub fn new() -> Self {
        Histogram {
            counts: Box::new([0; BUCKETS]),
            count: 0,
            max: 0,
            sum: 0,
        }
    }

    /// Records one value.
    pub fn record(&mut self, v: u64) {
        let i = bucket_of(v).min(BUCKETS - 1);
        self.counts[i] += 1;
        self.count += 1;
        self.max = self.max.max(v);
        self.sum += u128::from(v);
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Largest value recorded.
    pub fn max(&self) -> u64 {
        self.max
    }

    /// Mean of the values, or 0.
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum as f64 / self.count as f64
        }
    }

    /// The value below which a fraction `q` (0–1) of the values lie (bucket upper bound,
    /// capped at the maximum); 0 when empty.
    pub fn quantile(&self, q: f64) -> u64 {
        if self.count == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return bucket_upper(i).min(self.max);
            }
        }
        self.max
    }

    /// Forgets every value.
    pub fn reset(&mut self) {
        self.counts.fill(0);
        self.count = 0;
        self.max = 0;
        self.sum = 0;
    }
}

/// What one wait of the pacer observed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Cycle number, from 0.
    pub cycle: u64,
    /// How late the loop woke after the deadline, ns.
    pub lateness_ns: u64,
    /// Deadlines skipped because the loop was later than a whole period.
    pub missed: u64,
    /// The cycle was started by the peer's message ([`Pacer::wait_or_wake`]), not by the
    /// loop's own deadline.
    pub woken: bool,
}

/// Paces a loop on absolute deadlines `start + n · period`.
#[derive(Debug)]
pub struct Pacer {
    period: Duration,
    spin: Duration,
    next: Instant,
    cycle: u64,
    /// Lateness of every cycle, ns.
    pub lateness: Histogram,
    /// Deadlines missed in total.
    pub misses: u64,
    /// Deadlines missed after a cycle whose body used at least a whole period of the loop
    /// thread's CPU time: the loop's own work alone overran. The other misses happened while
    /// the thread was not running (the host or the scheduler stalled it): had it run, its work
    /// would have fitted in the period.
    pub misses_outside_stalls: u64,
    /// Largest CPU time of the loop thread in one cycle's body, ns.
    pub max_body_cpu_ns: u64,
    /// The loop thread's CPU time at the last wake-up, ns.
    woke_cpu_ns: u64,
    /// When each of the first [`MISS_SPANS_MAX`] misses happened, on `CLOCK_MONOTONIC`:
    /// `[deadline_ns, woke_ns]` (the stretch the loop should have run but did not), so that
    /// an outside witness of host stalls can be matched against them.
    miss_spans_ns: [[u64; 2]; MISS_SPANS_MAX],
    miss_spans_len: usize,
    /// `CLOCK_MONOTONIC` at `origin`, ns: turns an `Instant` into a system-wide time.
    origin_mono_ns: u64,
    origin: Instant,
    /// When the last cycle started (woke).
    last_start: Instant,
    /// The last cycle was started by a message ([`Pacer::wait_or_wake`]).
    locked: bool,
    /// Cycles started by a message.
    pub woken_cycles: u64,
}

/// How long after its period a phase-locked loop still waits for the peer's message before it
/// runs on its own clock, as a share of the period: the peer's own lateness (a master's p99
/// under load is ~1 ms at 1 kHz, `docs/processes.md`) up to half a period does not split a
/// cycle in two.
pub const LOCK_MARGIN_PERIODS: f64 = 0.5;

/// The shortest time between the starts of two cycles when the second is woken by a
/// message: a quarter period, at most this (a peer sending faster than its period, a burst
/// after a stall, cannot drive the loop faster than four times its rate), ns.
pub const MIN_WOKEN_SPACING_MAX_NS: u64 = 250_000;

/// Misses whose times a [`Pacer`] keeps (the later ones are only counted).
pub const MISS_SPANS_MAX: usize = 256;

pub use crate::progress::set_normal_scheduling;
pub use h4_shared::clock::{monotonic_ns, thread_cpu_ns};

impl Pacer {
    /// A pacer whose first deadline is one period from now; `spin` is how long before each
    /// deadline it stops sleeping and spins (200 µs suits the project's VMs). Call it on the
    /// loop's thread: it sets that thread's timer slack to [`LOOP_TIMER_SLACK_NS`] (Linux
    /// lets a normal thread's sleep end up to 50 µs late by default, to batch wake-ups).
    pub fn new(period: Duration, spin: Duration) -> Self {
        // Best effort: a refusal leaves the default slack, which the spin margin covers.
        let _ = set_timer_slack_ns(LOOP_TIMER_SLACK_NS);
        Pacer {
            period,
            spin,
            next: Instant::now() + period,
            cycle: 0,
            lateness: Histogram::new(),
            misses: 0,
            misses_outside_stalls: 0,
            max_body_cpu_ns: 0,
            woke_cpu_ns: thread_cpu_ns(),
            miss_spans_ns: [[0; 2]; MISS_SPANS_MAX],
            miss_spans_len: 0,
            origin_mono_ns: monotonic_ns(),
            origin: Instant::now(),
            last_start: Instant::now(),
            locked: false,
            woken_cycles: 0,
        }
    }

    /// When the next cycle is due on the loop's own clock (the next deadline).
    pub fn next_deadline(&self) -> Instant {
        self.next
    }

    /// How long before each deadline the pacer stops sleeping and spins.
    pub fn spin(&self) -> Duration {
        self.spin
    }

    /// The phase-locked wait: the next cycle starts when the peer's message arrives
    /// (`wake(until)` blocks until a message is waiting, true, or until `until`, false;
    /// a link's `wait_message`) or, without one, at the loop's own
    /// deadline, whichever comes first. The own deadline after a woken cycle is its start
    /// plus `1 + LOCK_MARGIN_PERIODS` periods, after an own-clock cycle the next deadline of
    /// the grid (anchored at the last woken cycle's start). A woken cycle starts no sooner than
    /// a quarter period (at most [`MIN_WOKEN_SPACING_MAX_NS`]) after the last one. Its
    /// lateness is 0 (the loop ran when its input came); `missed` counts the whole periods
    /// beyond the first since the last cycle (a stalled host). A `wake` that cannot block
    /// (returns false at once) makes this [`Pacer::wait`].
    pub fn wait_or_wake(&mut self, mut wake: impl FnMut(Instant) -> bool) -> Tick {
        let body_cpu_ns = thread_cpu_ns().saturating_sub(self.woke_cpu_ns);
        let period_ns = u64::try_from(self.period.as_nanos())
            .unwrap_or(u64::MAX)
            .max(1);
        let own = if self.locked {
            self.last_start + self.period.mul_f64(1.0 + LOCK_MARGIN_PERIODS)
        } else {
            self.next
        };
        let earliest =
            self.last_start + Duration::from_nanos((period_ns / 4).min(MIN_WOKEN_SPACING_MAX_NS));
        if let Some(pause) = earliest.checked_duration_since(Instant::now()) {
            std::thread::sleep(pause);
        }
        let until = own.checked_sub(self.spin).unwrap_or(own);
        if Instant::now() < until && wake(until) {
            let woke = Instant::now();
            let gap_ns =
                u64::try_from(woke.duration_since(self.last_start).as_nanos()).unwrap_or(u64::MAX);
            let missed = (gap_ns / period_ns).saturating_sub(1);
            self.book_miss(
                missed,
                body_cpu_ns,
                period_ns,
                self.last_start + self.period,
                woke,
            );
            self.max_body_cpu_ns = self.max_body_cpu_ns.max(body_cpu_ns);
            self.woke_cpu_ns = thread_cpu_ns();
            self.lateness.record(0);
            self.next = woke + self.period;
            self.last_start = woke;
            self.locked = true;
            self.woken_cycles += 1;
            let tick = Tick {
                cycle: self.cycle,
                lateness_ns: 0,
                missed,
                woken: true,
            };
            self.cycle += 1 + missed;
            return tick;
        }
        self.next = own;
        self.locked = false;
        self.wait()
    }

    fn book_miss(
        &mut self,
        missed: u64,
        body_cpu_ns: u64,
        period_ns: u64,
        due: Instant,
        woke: Instant,
    ) {
        self.misses += missed;
        if missed > 0 && body_cpu_ns >= period_ns {
            self.misses_outside_stalls += missed;
        }
        if missed > 0 && self.miss_spans_len < MISS_SPANS_MAX {
            self.miss_spans_ns[self.miss_spans_len] = [self.mono_ns(due), self.mono_ns(woke)];
            self.miss_spans_len += 1;
        }
    }

    /// `t` on `CLOCK_MONOTONIC`, ns.
    fn mono_ns(&self, t: Instant) -> u64 {
        let since = t.saturating_duration_since(self.origin).as_nanos();
        self.origin_mono_ns
            .saturating_add(u64::try_from(since).unwrap_or(u64::MAX))
    }

    /// The times of the first [`MISS_SPANS_MAX`] misses, `[deadline_ns, woke_ns]` on
    /// `CLOCK_MONOTONIC` ([`monotonic_ns`]).
    pub fn miss_spans_ns(&self) -> &[[u64; 2]] {
        &self.miss_spans_ns[..self.miss_spans_len]
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Waits for the next deadline. If the loop overran by whole periods, those deadlines are
    /// counted as missed and skipped (no burst of catch-up cycles).
    pub fn wait(&mut self) -> Tick {
        let deadline = self.next;
        let body_cpu_ns = thread_cpu_ns().saturating_sub(self.woke_cpu_ns);
        let now = Instant::now();
        if let Some(until_spin) = deadline.checked_duration_since(now + self.spin) {
            std::thread::sleep(until_spin);
        }
        let mut woke = Instant::now();
        while woke < deadline {
            std::hint::spin_loop();
            woke = Instant::now();
        }
        let late = woke.duration_since(deadline);
        let late_ns = u64::try_from(late.as_nanos()).unwrap_or(u64::MAX);
        let period_ns = u64::try_from(self.period.as_nanos())
            .unwrap_or(u64::MAX)
            .max(1);
        let missed = late_ns / period_ns;
        self.book_miss(missed, body_cpu_ns, period_ns, deadline, woke);
        self.last_start = woke;
        self.max_body_cpu_ns = self.max_body_cpu_ns.max(body_cpu_ns);
        self.woke_cpu_ns = thread_cpu_ns();
        self.lateness.record(late_ns);
        let skip = u32::try_from(missed + 1).unwrap_or(u32::MAX);
        self.next = deadline + self.period * skip;
        let tick = Tick {
            cycle: self.cycle,
            lateness_ns: late_ns,
            missed,
            woken: false,
        };
        self.cycle += 1 + missed;
        tick
    }
}

/// What a process's 1 kHz loop reports when it stops: its timing and its cost. Both process
/// summaries (`h4-slave run`, `h4-master run`) carry it flattened, so the JSON fields are the
/// same in both.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LoopReport {
    /// Loop cycles run.
    pub cycles: u64,
    /// Deadlines missed (the loop woke more than a whole period late).
    pub deadline_misses: u64,
    /// Of those, the ones after a cycle whose body used at least a whole period of the loop
    /// thread's CPU time (the loop's own work alone overran); the rest happened while the host
    /// or the scheduler did not run the loop thread (its work would have fitted).
    pub deadline_misses_outside_stalls: u64,
    /// When the misses happened (the first 256): `[deadline_ns, woke_ns]` on the host's
    /// `CLOCK_MONOTONIC`, the stretch the loop should have run and did not; an outside
    /// witness of host stalls (a test's high-priority sentinel threads) is matched against it.
    pub deadline_miss_spans_ns: Vec<[u64; 2]>,
    /// The loop clock's zero (the process's recordings' `time_ns` 0) on the host's
    /// `CLOCK_MONOTONIC`, ns: a recorded cycle's time plus this is comparable with the spans
    /// above and with the other process's.
    pub clock_origin_monotonic_ns: u64,
    /// Cycles the peer's message started (a phase-locked loop: the slave's woken by the
    /// master's command); the other cycles ran on the loop's own clock.
    pub phase_locked_cycles: u64,
    /// Largest CPU time of the loop thread in one cycle's body (the per-cycle work, without
    /// the pacer's wait), µs.
    pub max_cycle_cpu_us: f64,
    /// Lateness of the loop's wake-up, p50, µs.
    pub lateness_p50_us: f64,
    /// p99 lateness, µs.
    pub lateness_p99_us: f64,
    /// p99.9 lateness, µs.
    pub lateness_p999_us: f64,
    /// Largest lateness, µs.
    pub lateness_max_us: f64,
    /// CPU time the whole process used (all threads, start-up included), s.
    pub cpu_time_s: f64,
    /// `cpu_time_s` over `run_time_s`, % of one core.
    pub cpu_percent: f64,
    /// Seconds run, by the loop's clock.
    pub run_time_s: f64,
}

impl LoopReport {
    /// The report of a loop that ran `cycles` cycles paced by `pacer` for `run_time_s`; reads
    /// the process's CPU time now.
    pub fn new(cycles: u64, pacer: &Pacer, run_time_s: f64) -> Self {
        let us = |ns: u64| ns as f64 / 1e3;
        let h = &pacer.lateness;
        let cpu_time_s = crate::process::cpu_time_s();
        LoopReport {
            cycles,
            deadline_misses: pacer.misses,
            deadline_misses_outside_stalls: pacer.misses_outside_stalls,
            deadline_miss_spans_ns: {
                // Always the whole capacity: the report allocates the same with or without
                // misses (the allocation tests compare runs by their count).
                let mut spans = Vec::with_capacity(MISS_SPANS_MAX);
                spans.extend_from_slice(pacer.miss_spans_ns());
                spans
            },
            // The pacer has no clock origin: `RtLoop::report` sets it.
            clock_origin_monotonic_ns: 0,
            phase_locked_cycles: pacer.woken_cycles,
            max_cycle_cpu_us: us(pacer.max_body_cpu_ns),
            lateness_p50_us: us(h.quantile(0.5)),
            lateness_p99_us: us(h.quantile(0.99)),
            lateness_p999_us: us(h.quantile(0.999)),
            lateness_max_us: us(h.max()),
            cpu_time_s,
            cpu_percent: if run_time_s > 0.0 {
                100.0 * cpu_time_s / run_time_s
            } else {
                0.0
            },
            run_time_s,
        }
    }
}

/// A status line due in this cycle: the per-cycle body writes it into `text` (cleared, with
/// room for a line: no allocation), and [`RtLoop`] shows it after the body returns.
#[derive(Debug)]
pub struct StatusDue<'a> {
    /// Where the body writes the line.
    pub text: &'a mut String,
    /// The loop's p99 wake-up lateness so far, µs.
    pub lateness_p99_us: f64,
    /// Deadlines missed so far.
    pub misses: u64,
}

/// One cycle of an [`RtLoop`], as its body sees it.
#[derive(Debug)]
pub struct CycleCtx<'a> {
    /// The loop's monotonic clock at this cycle, ns since the loop started.
    pub now_ns: u64,
    /// The same instant as Unix time, ns (the log time of recordings, so the recordings of
    /// two processes on one host share a timeline).
    pub unix_ns: u64,
    /// What the pacer's wait observed: lateness, skipped deadlines.
    pub tick: Tick,
    /// Cycles run, this one included.
    pub cycles: u64,
    /// `Some` when the progress reporter wants the status text (a few times a second for a
    /// bar, once per plain line): the text to write.
    pub status: Option<StatusDue<'a>>,
    /// The loop's clock (to read the time again inside the body).
    pub clock: &'a h4_shared::clock::MonotonicClock,
    /// The latest instant the body may block until (waiting for the peer's message) without
    /// delaying the next cycle: the next deadline less the pacer's spin margin.
    pub idle_until: Instant,
}

impl CycleCtx<'_> {
    /// The loop's clock now, ns since the loop started (later than `now_ns` by the body's
    /// time so far).
    pub fn clock_ns(&self) -> u64 {
        use h4_shared::clock::Clock;
        self.clock.now_ns()
    }
}

/// The real-time shell both processes (`h4-slave run`, `h4-master run`) run their 1 kHz
/// cycle in: a [`Pacer`] on absolute deadlines, the monotonic clock, the stop request
/// (SIGINT/SIGTERM or [`crate::process::request_stop`]) and the fixed duration, the lateness
/// histogram and deadline misses, and the progress it hands to a [`crate::progress`]
/// reporter (position every cycle, the status text when due). The per-cycle body is a
/// closure; the shell allocates nothing per cycle.
#[derive(Debug)]
pub struct RtLoop {
    pacer: Pacer,
    clock: h4_shared::clock::MonotonicClock,
    progress: crate::progress::ProgressHandle,
    next_status_ns: u64,
    text: String,
    end_ns: Option<u64>,
    cycles: u64,
}

impl RtLoop {
    /// A loop of period `period_ns` (at least 1 ns) that spins the last `spin_ns` before each
    /// deadline and stops by itself after `duration_s` (None: only on a stop request). Its
    /// clock starts now; create it on the loop's thread (see [`Pacer::new`]).
    pub fn new(period_ns: u64, spin_ns: u64, duration_s: Option<f64>) -> Self {
        let pacer = Pacer::new(
            Duration::from_nanos(period_ns.max(1)),
            Duration::from_nanos(spin_ns),
        );
        RtLoop {
            pacer,
            clock: h4_shared::clock::MonotonicClock::new(),
            progress: crate::progress::ProgressHandle::off(),
            next_status_ns: 0,
            text: String::with_capacity(512),
            end_ns: duration_s.map(|s| (s * 1e9) as u64),
            cycles: 0,
        }
    }

    /// Reports to `progress`: the cycles run, every cycle; the body's status text (asked for
    /// through [`CycleCtx::status`]) as often as the reporter shows it.
    pub fn with_progress(mut self, progress: crate::progress::ProgressHandle) -> Self {
        self.progress = progress;
        self
    }

    /// Runs `body` once per period until a stop is requested or the duration is over (the
    /// check comes after each wait, before the body), or until `body` fails (its error is
    /// returned at once).
    pub fn run<E>(
        &mut self,
        mut body: impl FnMut(&mut CycleCtx<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        let end_ns = self.end_ns;
        self.cycle_until(
            &mut (),
            |p, _| p.wait(),
            |cx, _| body(cx),
            |now_ns| crate::process::stop_requested() || end_ns.is_some_and(|e| now_ns >= e),
        )
    }

    /// [`RtLoop::run`], phase-locked ([`Pacer::wait_or_wake`]): each cycle starts when
    /// `wake(state, until)` reports the peer's message (it blocks until one is waiting or
    /// until `until`), or at the loop's own deadline without one. `state` (the link) is lent
    /// to `wake` between cycles and to `body` in them.
    pub fn run_phase_locked<T, E>(
        &mut self,
        state: &mut T,
        mut wake: impl FnMut(&mut T, Instant) -> bool,
        body: impl FnMut(&mut CycleCtx<'_>, &mut T) -> Result<(), E>,
    ) -> Result<(), E> {
        let end_ns = self.end_ns;
        self.cycle_until(
            state,
            |p, st| p.wait_or_wake(|until| wake(st, until)),
            body,
            |now_ns| crate::process::stop_requested() || end_ns.is_some_and(|e| now_ns >= e),
        )
    }

    /// After [`RtLoop::run`] stopped: runs `body` on the same pacer, clock and statistics for
    /// at most `limit_s` more, whatever the stop request says, until `body` returns false
    /// (e.g. the slave bringing its arm to its safe state before the process exits).
    pub fn run_after_stop(
        &mut self,
        limit_s: f64,
        mut body: impl FnMut(&mut CycleCtx<'_>) -> bool,
    ) {
        use h4_shared::clock::Clock;
        let end_ns = self.clock.now_ns() + (limit_s.max(0.0) * 1e9) as u64;
        let done = std::cell::Cell::new(false);
        let Ok(()) = self.cycle_until(
            &mut (),
            |p, _| p.wait(),
            |cx, _| {
                done.set(!body(cx));
                Ok::<(), std::convert::Infallible>(())
            },
            |now_ns| done.get() || now_ns >= end_ns,
        );
    }

    fn cycle_until<T, E>(
        &mut self,
        state: &mut T,
        mut wait: impl FnMut(&mut Pacer, &mut T) -> Tick,
        mut body: impl FnMut(&mut CycleCtx<'_>, &mut T) -> Result<(), E>,
        mut stop: impl FnMut(u64) -> bool,
    ) -> Result<(), E> {
        use h4_shared::clock::Clock;
        loop {
            let tick = wait(&mut self.pacer, state);
            let now_ns = self.clock.now_ns();
            if stop(now_ns) {
                break;
            }
            self.cycles += 1;
            self.progress.set(self.cycles);
            let due = self
                .progress
                .detail_interval_ns()
                .is_some_and(|every| now_ns >= self.next_status_ns && every > 0);
            if due {
                let every = self.progress.detail_interval_ns().unwrap_or(u64::MAX);
                self.next_status_ns = now_ns.saturating_add(every);
            }
            let status = if due {
                self.text.clear();
                Some(StatusDue {
                    text: &mut self.text,
                    lateness_p99_us: self.pacer.lateness.quantile(0.99) as f64 / 1e3,
                    misses: self.pacer.misses,
                })
            } else {
                None
            };
            let next = self.pacer.next_deadline();
            let mut ctx = CycleCtx {
                now_ns,
                unix_ns: self.clock.unix_ns(now_ns),
                tick,
                cycles: self.cycles,
                status,
                clock: &self.clock,
                idle_until: next.checked_sub(self.pacer.spin()).unwrap_or(next),
            };
            body(&mut ctx, state)?;
            if due {
                self.progress.set_detail(&self.text);
            }
        }
        Ok(())
    }

    /// Cycles run so far.
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// The loop's report now: cycles, misses, lateness, CPU and run time.
    pub fn report(&self) -> LoopReport {
        use h4_shared::clock::Clock;
        LoopReport {
            clock_origin_monotonic_ns: self.clock.origin_monotonic_ns(),
            ..LoopReport::new(self.cycles, &self.pacer, self.clock.now_ns() as f64 / 1e9)
        }
    }
}

/// Why a real-time setting could not be applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RtError {
    /// The process lacks the privilege (CAP_SYS_NICE / CAP_IPC_LOCK or an rlimit).
    #[error(
        "{what} not permitted (errno {errno}): run as root, grant CAP_SYS_NICE/CAP_IPC_LOCK, or raise the rtprio/memlock limits"
    )]
    NotPermitted {
        /// The setting.
        what: &'static str,
        /// errno.
        errno: i32,
    },
    /// Any other failure.
    #[error("{what} failed (errno {errno})")]
    Failed {
        /// The setting.
        what: &'static str,
        /// errno.
        errno: i32,
    },
}

fn last_errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

fn rt_error(what: &'static str) -> RtError {
    let errno = last_errno();
    if errno == libc::EPERM || errno == libc::EACCES || errno == libc::ENOMEM {
        RtError::NotPermitted { what, errno }
    } else {
        RtError::Failed { what, errno }
    }
}

/// The timer slack [`Pacer::new`] gives its thread, ns.
pub const LOOP_TIMER_SLACK_NS: u64 = 1_000;

/// Sets the calling thread's timer slack (how late the kernel may end its sleeps to group
/// wake-ups; 50 µs by default for a normal thread, ignored under `SCHED_FIFO`).
pub fn set_timer_slack_ns(ns: u64) -> Result<(), RtError> {
    let slack = libc::c_ulong::try_from(ns.max(1)).unwrap_or(libc::c_ulong::MAX);
    // SAFETY: plain prctl on the calling thread with an integer argument.
    let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, slack, 0, 0, 0) };
    if rc == 0 {
        Ok(())
    } else {
        Err(rt_error("PR_SET_TIMERSLACK"))
    }
}

/// The calling thread's timer slack, ns.
pub fn timer_slack_ns() -> Result<u64, RtError> {
    // SAFETY: plain prctl on the calling thread; returns the slack.
    let rc = unsafe { libc::prctl(libc::PR_GET_TIMERSLACK, 0, 0, 0, 0) };
    u64::try_from(rc).map_err(|_| rt_error("PR_GET_TIMERSLACK"))
}

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1–99).
pub fn set_fifo_priority(priority: i32) -> Result<(), RtError> {
    let param = libc::sched_param {
        sched_priority: priority.clamp(1, 99),
    };
    // SAFETY: plain syscall on the calling thread with a valid, initialised parameter.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(rt_error("SCHED_FIFO"))
    }
}

/// Locks current and future memory so the loop never page-faults.
pub fn lock_memory() -> Result<(), RtError> {
    // SAFETY: plain syscall with constant flags.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc == 0 {
        Ok(())
    } else {
        Err(rt_error("mlockall"))
    }
}

/// Applies a process's real-time options: locks memory if `lock`, then puts the calling
/// thread under `SCHED_FIFO` at `fifo_priority`. A refused setting is not an error: a warning
/// on stderr says which and why, and the loop runs without it.
pub fn apply_realtime(fifo_priority: Option<i32>, lock: bool) {
    if lock && let Err(e) = lock_memory() {
        eprintln!("warning: {e}; continuing without it");
    }
    if let Some(p) = fifo_priority
        && let Err(e) = set_fifo_priority(p)
    {
        eprintln!("warning: {e}; continuing without it");
    }
}

/// `--realtime`: what a process asks of the scheduler and the memory manager.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum RealtimeMode {
    /// SCHED_FIFO for the 1 kHz loop and all memory locked where permitted; a one-line note
    /// for what is not, and the run goes on without it.
    #[default]
    Try,
    /// The same, but a setting that is not permitted is an error (exit 2) before the run.
    Enforce,
    /// Normal scheduling, memory not locked.
    Off,
}

/// The SCHED_FIFO priority `--realtime try|enforce` uses when `--fifo-priority` does not
/// name one (the priority README's measurements were taken at; below the kernel's own
/// threaded interrupts at 50 only on a PREEMPT_RT kernel, where those matter less than 1 ms).
pub const DEFAULT_FIFO_PRIORITY: i32 = 80;

/// The real-time settings a process resolved from its flags (`--realtime`,
/// `--fifo-priority`, `--lock-memory`): [`RealtimePlan::prepare`] applies the process-wide
/// part before the run, [`RealtimePlan::enter`] the loop thread's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RealtimePlan {
    /// The mode.
    pub mode: RealtimeMode,
    /// SCHED_FIFO at this priority for the loop thread (None: normal scheduling).
    pub fifo_priority: Option<i32>,
    /// Lock all memory (mlockall).
    pub lock_memory: bool,
}

/// What a process got of its [`RealtimePlan`] (both process summaries carry it as
/// `realtime`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct RealtimeStatus {
    /// `try`, `enforce` or `off`.
    pub mode: RealtimeMode,
    /// The loop ran under SCHED_FIFO at this priority (None: normal scheduling).
    pub sched_fifo_priority: Option<i32>,
    /// All memory was locked.
    pub memory_locked: bool,
    /// What was asked for and not permitted (under `try`), one sentence each.
    pub not_permitted: Vec<String>,
}

impl RealtimePlan {
    /// Nothing asked.
    pub fn off() -> Self {
        RealtimePlan {
            mode: RealtimeMode::Off,
            fifo_priority: None,
            lock_memory: false,
        }
    }

    /// From the flags: `try` and `enforce` ask for SCHED_FIFO at `fifo_priority` (default
    /// [`DEFAULT_FIFO_PRIORITY`]) and locked memory; `off` asks for nothing, and naming a
    /// priority or `--lock-memory` with it is a usage error. A priority outside 1–99 is one
    /// too.
    pub fn from_flags(
        mode: RealtimeMode,
        fifo_priority: Option<i32>,
        lock_memory: bool,
    ) -> Result<Self, String> {
        if let Some(p) = fifo_priority
            && !(1..=99).contains(&p)
        {
            return Err(format!(
                "--fifo-priority {p}: a SCHED_FIFO priority is 1 to 99"
            ));
        }
        match mode {
            RealtimeMode::Off if fifo_priority.is_some() || lock_memory => Err(
                "--realtime off asks for normal scheduling: drop --fifo-priority/--lock-memory, \
                 or use --realtime try|enforce"
                    .into(),
            ),
            RealtimeMode::Off => Ok(Self::off()),
            RealtimeMode::Try | RealtimeMode::Enforce => Ok(RealtimePlan {
                mode,
                fifo_priority: Some(fifo_priority.unwrap_or(DEFAULT_FIFO_PRIORITY)),
                lock_memory: true,
            }),
        }
    }

    /// Before the run (before any link or helper thread exists): locks all memory, and
    /// tries SCHED_FIFO on a short-lived thread (the loop thread gets it in
    /// [`RealtimePlan::enter`]). Under `enforce` the first refusal is the error; under `try`
    /// each refusal is a sentence in [`RealtimeStatus::not_permitted`] and the run goes on.
    pub fn prepare(&self) -> Result<RealtimeStatus, RtError> {
        let mut st = RealtimeStatus {
            mode: self.mode,
            ..RealtimeStatus::default()
        };
        let refused = |e: RtError, st: &mut RealtimeStatus| {
            if self.mode == RealtimeMode::Enforce {
                Err(e)
            } else {
                st.not_permitted.push(e.to_string());
                Ok(())
            }
        };
        if self.lock_memory {
            match lock_memory() {
                Ok(()) => st.memory_locked = true,
                Err(e) => refused(e, &mut st)?,
            }
        }
        if let Some(p) = self.fifo_priority {
            let probe = std::thread::spawn(move || set_fifo_priority(p))
                .join()
                .unwrap_or(Err(RtError::Failed {
                    what: "SCHED_FIFO",
                    errno: 0,
                }));
            match probe {
                Ok(()) => st.sched_fifo_priority = Some(p),
                Err(e) => refused(e, &mut st)?,
            }
        }
        Ok(st)
    }

    /// On the loop thread, after [`RealtimePlan::prepare`]: SCHED_FIFO if the probe got it.
    /// A refusal now (the permission changed in between) is an error under `enforce`, a
    /// sentence in `status` under `try`.
    pub fn enter(&self, status: &mut RealtimeStatus) -> Result<(), RtError> {
        if let Some(p) = status.sched_fifo_priority
            && let Err(e) = set_fifo_priority(p)
        {
            status.sched_fifo_priority = None;
            if self.mode == RealtimeMode::Enforce {
                return Err(e);
            }
            status.not_permitted.push(e.to_string());
        }
        Ok(())
    }
}

impl LoopArgs {
    /// [`check_writable`](crate::process::check_writable) on `--summary` and `--record`: an unwritable path is an error
    /// before the run starts.
    pub fn check_outputs(&self) -> Result<(), String> {
        if let Some(p) = &self.summary {
            crate::process::check_writable("--summary", p)?;
        }
        if let Some(p) = &self.record {
            crate::process::check_writable("--record", p)?;
        }
        Ok(())
    }
}

/// What both `run` commands (`h4-slave run`, `h4-master run`) take about their loop: how
/// long, where the summary and the recording go, real-time settings (flattened into their
/// clap arguments).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct LoopArgs {
    /// Stop by itself after this many seconds, a positive finite number (default: until
    /// SIGINT/SIGTERM).
    #[arg(long, value_parser = crate::process::positive_seconds)]
    pub duration_s: Option<f64>,
    /// Write the summary as JSON here (it is also printed on stdout).
    #[arg(long)]
    pub summary: Option<std::path::PathBuf>,
    /// Write an MCAP recording of every cycle here.
    #[arg(long)]
    pub record: Option<std::path::PathBuf>,
    /// Real time: `try` (default) runs the loop under SCHED_FIFO and locks all memory where
    /// permitted, with a one-line note for what is not; `enforce` makes a refusal an error
    /// (exit 2) before the run; `off` asks for neither.
    #[arg(long, value_enum, default_value_t = RealtimeMode::Try)]
    pub realtime: RealtimeMode,
    /// The SCHED_FIFO priority `--realtime try|enforce` uses (1–99; default 80).
    #[arg(long)]
    pub fifo_priority: Option<i32>,
    /// Lock all memory (mlockall): implied by `--realtime try|enforce`, kept for scripts.
    #[arg(long)]
    pub lock_memory: bool,
}

impl LoopArgs {
    /// The real-time plan of the flags, prepared before the run ([`realtime_preflight`]).
    pub fn realtime_preflight(&self, label: &str) -> Result<RealtimePlan, String> {
        realtime_preflight(self.realtime, self.fifo_priority, self.lock_memory, label)
    }
}

/// Resolves `--realtime`, `--fifo-priority` and `--lock-memory` into a plan and prepares it
/// before anything else runs: under `enforce` a setting that is not permitted is an error
/// (exit 2); under `try` each refusal is one line on stderr (`LABEL: real time: …`) and the
/// run goes on without it.
pub fn realtime_preflight(
    mode: RealtimeMode,
    fifo_priority: Option<i32>,
    lock_memory: bool,
    label: &str,
) -> Result<RealtimePlan, String> {
    let plan = RealtimePlan::from_flags(mode, fifo_priority, lock_memory)?;
    let status = plan
        .prepare()
        .map_err(|e| format!("--realtime enforce: {e}"))?;
    for why in &status.not_permitted {
        crate::progress::verdict_line(
            label,
            &format!(
                "real time: {why}; running without it (--realtime enforce makes this an error, --realtime off silences it)"
            ),
        );
    }
    Ok(plan)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_flags_resolve_and_conflicts_are_usage_errors() {
        let p = RealtimePlan::from_flags(RealtimeMode::Try, None, false).unwrap();
        assert_eq!(p.fifo_priority, Some(DEFAULT_FIFO_PRIORITY));
        assert!(p.lock_memory);
        let p = RealtimePlan::from_flags(RealtimeMode::Enforce, Some(10), false).unwrap();
        assert_eq!(p.fifo_priority, Some(10));
        assert_eq!(
            RealtimePlan::from_flags(RealtimeMode::Off, None, false).unwrap(),
            RealtimePlan::off()
        );
        assert!(RealtimePlan::from_flags(RealtimeMode::Off, Some(10), false).is_err());
        assert!(RealtimePlan::from_flags(RealtimeMode::Off, None, true).is_err());
        assert!(RealtimePlan::from_flags(RealtimeMode::Try, Some(0), false).is_err());
        assert!(RealtimePlan::from_flags(RealtimeMode::Try, Some(100), false).is_err());
        // Off asks nothing and gets nothing.
        let st = RealtimePlan::off().prepare().unwrap();
        assert!(st.sched_fifo_priority.is_none() && !st.memory_locked);
    }

    #[test]
    fn quantiles_are_within_bucket_width() {
        let mut h = Histogram::new();
        for v in 1..=100_000u64 {
            h.record(v);
        }
        for (q, want) in [(0.5, 50_000.0), (0.99, 99_000.0), (0.999, 99_900.0)] {
            let got = h.quantile(q) as f64;
            assert!((got - want).abs() / want < 0.008, "q{q}: {got} vs {want}");
        }
        assert_eq!(h.max(), 100_000);
        assert_eq!(h.quantile(1.0), 100_000);
        for v in [0u64, 1, 127, 128, 129, 1000, 1 << 40, u64::MAX] {
            let b = bucket_of(v).min(BUCKETS - 1);
            assert!(bucket_upper(b) >= v.min(bucket_upper(BUCKETS - 1)), "{v}");
        }
    }

    #[test]
    fn pacer_sets_its_threads_timer_slack() {
        std::thread::spawn(|| {
            set_timer_slack_ns(50_000).unwrap();
            assert_eq!(timer_slack_ns().unwrap(), 50_000);
            let _p = Pacer::new(Duration::from_millis(1), Duration::from_micros(200));
            assert_eq!(timer_slack_ns().unwrap(), LOOP_TIMER_SLACK_NS);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn pacer_counts_skipped_deadlines() {
        let mut p = Pacer::new(Duration::from_millis(1), Duration::from_micros(200));
        let first = p.wait();
        assert_eq!(first.cycle, 0);
        std::thread::sleep(Duration::from_millis(5));
        let late = p.wait();
        // At least 3 whole periods were overslept (5 ms sleep against 1 ms deadlines).
        assert!(late.missed >= 3, "{late:?}");
        assert_eq!(p.misses, late.missed + first.missed);
        let next = p.wait();
        assert_eq!(next.cycle, late.cycle + late.missed + 1);
        // Each miss's span is on the host's monotonic clock, a whole period or more long,
        // and inside the time the test ran.
        let before = monotonic_ns();
        let spans = p.miss_spans_ns().to_vec();
        assert_eq!(
            spans.len() as u64,
            u64::from(first.missed > 0) + 1 + u64::from(next.missed > 0)
        );
        let span = spans[usize::from(first.missed > 0)];
        assert!(span[1] >= span[0] + late.missed * 1_000_000, "{spans:?}");
        assert!(
            span[1] <= before && span[0] + 10_000_000_000 > before,
            "{spans:?} at {before}"
        );
        let report = LoopReport::new(3, &p, 0.01);
        assert_eq!(report.deadline_miss_spans_ns, spans);
    }
}
