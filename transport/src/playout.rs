//! A playout (jitter) buffer in front of a receiver: [`Playout`] wraps any [`Link`] and hands
//! each arrived message on at its sender's send time plus the link's *fastest* delay plus a
//! playout delay, so a jittery link's messages come out in order and evenly spaced instead of
//! in bursts with gaps.
//!
//! Why: the receive gate follows only messages newer than the newest it has seen. On a link
//! whose delay varies by ±J (a network's jitter), a message that happens to be fast makes the
//! slower ones sent before it stale, and the next newer message may be up to 2J away: with
//! 25 ms of jitter and more the slave's 20 ms watchdog trips again and again and the command
//! it follows jumps. Delaying every message to the same age (its send time + the fastest
//! delay + the playout delay) restores the sender's spacing; a message that arrives later
//! than that goes on at once (late), so no message waits longer than `max_ms`.
//!
//! * **Clock offset**: the sender's clock is not the receiver's; `arrival − send_time` is the
//!   offset plus the one-way delay. Its minimum over the last two windows of
//!   [`WINDOW_MESSAGES`] messages is the fastest path (`base`); a message's *lateness* is
//!   `arrival − send_time − base` (0 for the fastest).
//! * **Playout delay**: the `quantile` of the lateness over the recent messages (a histogram
//!   of 1 ms bins, halved every [`WINDOW_MESSAGES`] messages), at most `max_ms`; without
//!   jitter it is 0 and the layer changes nothing but order.
//! * **Nothing is lost or judged here**: every message is handed on (held ones in order of
//!   their playout time); a message from another session, or one whose send time makes no
//!   sense, goes on at once; the gate behind still judges each one (a duplicate or an old
//!   one is rejected and counted there, as without the buffer). A full buffer hands on its
//!   oldest message at once. Fixed size, nothing allocated per message.
//!
//! Used on the slave's command link (`slave.playout`, docs/sessions.md): off by default.

use core::marker::PhantomData;

use h4_shared::clock::Clock;
use h4_shared::config::{ConfigError, Section, check_range};
use h4_shared::wire::WireMessage;
use serde::{Deserialize, Serialize};

use crate::{DecodeRejects, Link, LinkError};

/// Messages held at most (1 s of a 1 kHz sender).
pub const PLAYOUT_CAPACITY: usize = 1024;
/// Messages per window of the fastest-delay minimum and of the lateness histogram's halving.
pub const WINDOW_MESSAGES: u32 = 2000;
/// Lateness histogram bins (1 ms each; the last holds everything later).
const BINS: usize = 1024;
const NS_PER_MS: f64 = 1e6;

/// The playout buffer's settings (`slave.playout`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlayoutConfig {
    /// Hold messages to even out the link's jitter (false: hand each on as it arrives).
    pub enabled: bool,
    /// The share of recent messages the playout delay waits for (0.5 to 1; 0.95).
    pub quantile: f64,
    /// The longest playout delay, and the longest any message is held, ms (0 to 1000; 200).
    pub max_ms: f64,
}

impl Default for PlayoutConfig {
    fn default() -> Self {
        PlayoutConfig {
            enabled: false,
            quantile: 0.95,
            max_ms: 200.0,
        }
    }
}

impl Section for PlayoutConfig {
    fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        check_range(&format!("{prefix}quantile"), self.quantile, 0.5, 1.0, "")?;
        check_range(&format!("{prefix}max_ms"), self.max_ms, 0.0, 1000.0, "ms")
    }
}

/// What the playout buffer did (totals).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlayoutCounters {
    /// Messages handed on after being held.
    pub held: u64,
    /// Messages that arrived after their playout time (handed on at once).
    pub late: u64,
    /// Messages handed on at once because the buffer was full.
    pub overflow: u64,
    /// The playout delay now, ms.
    pub delay_ms: f64,
}

#[derive(Clone, Copy)]
struct Held<M> {
    release_ns: u64,
    msg: M,
}

/// A [`Link`] whose received messages are held until their playout time (see the module).
pub struct Playout<L, C, Out, In: Copy> {
    inner: L,
    clock: C,
    cfg: PlayoutConfig,
    /// Held messages sorted by release time: a ring, `len` of them from `head`.
    buf: Box<[Option<Held<In>>]>,
    head: usize,
    len: usize,
    /// The playout delay as of this receive, ns.
    delay_cache_ns: u64,
    /// The session the offsets belong to.
    session: Option<u64>,
    /// Minimum of `arrival − send` in this window and the last, ns (signed: clocks differ).
    min_cur: Option<i128>,
    min_prev: Option<i128>,
    in_window: u32,
    hist: Box<[u32; BINS]>,
    hist_total: u64,
    /// Counters.
    pub counters: PlayoutCounters,
    _marker: PhantomData<Out>,
}

impl<L, C, Out, In: Copy> Playout<L, C, Out, In> {
    /// Wraps `inner`'s receive side; `clock` is the receiver's.
    pub fn new(inner: L, clock: C, cfg: PlayoutConfig) -> Self {
        Playout {
            inner,
            clock,
            cfg,
            buf: vec![None; PLAYOUT_CAPACITY].into_boxed_slice(),
            head: 0,
            len: 0,
            delay_cache_ns: 0,
            session: None,
            min_cur: None,
            min_prev: None,
            in_window: 0,
            hist: Box::new([0; BINS]),
            hist_total: 0,
            counters: PlayoutCounters::default(),
            _marker: PhantomData,
        }
    }

    /// The wrapped link.
    pub fn inner(&self) -> &L {
        &self.inner
    }

    /// The wrapped link, mutably.
    pub fn inner_mut(&mut self) -> &mut L {
        &mut self.inner
    }

    /// Messages held now.
    pub fn held(&self) -> usize {
        self.len
    }

    fn base_ns(&self) -> Option<i128> {
        match (self.min_cur, self.min_prev) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The playout delay: the configured quantile of the recent lateness, at most `max_ms`.
    fn delay_ns(&self) -> u64 {
        if self.hist_total == 0 {
            return 0;
        }
        let want = (self.cfg.quantile * self.hist_total as f64).ceil() as u64;
        let mut acc = 0u64;
        let mut ms = BINS - 1;
        for (i, c) in self.hist.iter().enumerate() {
            acc += u64::from(*c);
            if acc >= want {
                ms = i;
                break;
            }
        }
        let ms = (ms as f64).min(self.cfg.max_ms);
        (ms * NS_PER_MS) as u64
    }

    /// Learns from one arrival (`d` = arrival − send, ns) and returns its lateness, ns.
    fn learn(&mut self, d: i128) -> i128 {
        self.min_cur = Some(self.min_cur.map_or(d, |m| m.min(d)));
        self.in_window += 1;
        if self.in_window >= WINDOW_MESSAGES {
            self.min_prev = self.min_cur;
            self.min_cur = None;
            self.in_window = 0;
            self.hist_total = 0;
            for c in self.hist.iter_mut() {
                *c /= 2;
                self.hist_total += u64::from(*c);
            }
        }
        let late = d - self.base_ns().unwrap_or(d);
        let bin = ((late.max(0) as f64 / NS_PER_MS) as usize).min(BINS - 1);
        self.hist[bin] = self.hist[bin].saturating_add(1);
        self.hist_total += 1;
        late
    }

    /// The `i`-th held message's slot.
    fn slot(&self, i: usize) -> usize {
        (self.head + i) % PLAYOUT_CAPACITY
    }

    /// Inserts `h` keeping the buffer sorted by release time (a message with the same time
    /// goes after those already there); arrivals come mostly in order, so the search from
    /// the back is short. The buffer must have room.
    fn insert(&mut self, h: Held<In>) {
        let mut i = self.len;
        while i > 0 {
            let prev = self.buf[self.slot(i - 1)];
            match prev {
                Some(p) if p.release_ns > h.release_ns => {
                    let to = self.slot(i);
                    self.buf[to] = Some(p);
                    i -= 1;
                }
                _ => break,
            }
        }
        let at = self.slot(i);
        self.buf[at] = Some(h);
        self.len += 1;
    }

    /// Takes the first held message if its time has come.
    fn pop_due(&mut self, now_ns: u64) -> Option<In> {
        if self.len == 0 {
            return None;
        }
        let first = self.buf[self.head]?;
        if first.release_ns > now_ns {
            return None;
        }
        self.buf[self.head] = None;
        self.head = (self.head + 1) % PLAYOUT_CAPACITY;
        self.len -= 1;
        self.counters.held += 1;
        Some(first.msg)
    }

    /// Makes every held message due now (in its order): a new sender's messages follow.
    fn release_all(&mut self) {
        for i in 0..self.len {
            let at = self.slot(i);
            if let Some(h) = self.buf[at].as_mut() {
                h.release_ns = 0;
            }
        }
    }
}

impl<L, C, Out, In> Playout<L, C, Out, In>
where
    L: Link<Out, In>,
    C: Clock,
    Out: WireMessage,
    In: WireMessage,
{
    /// Handles one message that has just arrived: `Some` to hand on at once, or held.
    fn arrive(&mut self, msg: In, now_ns: u64) -> Option<In> {
        if self.session != Some(msg.session_id()) {
            // Another sender: its clock and delays are new. What is held goes first (the
            // caller drains it), the new one after.
            self.session = Some(msg.session_id());
            self.min_cur = None;
            self.min_prev = None;
            self.in_window = 0;
            self.hist.iter_mut().for_each(|c| *c = 0);
            self.hist_total = 0;
            self.delay_cache_ns = 0;
        }
        let d = i128::from(now_ns) - i128::from(msg.send_time_ns());
        let late = self.learn(d);
        let delay = i128::from(self.delay_cache_ns);
        let wait = delay - late;
        let max_ns = (self.cfg.max_ms * NS_PER_MS) as i128;
        if wait <= 0 {
            self.counters.late += u64::from(wait < 0);
            return Some(msg);
        }
        let wait = wait.min(max_ns);
        if self.len == PLAYOUT_CAPACITY {
            self.counters.overflow += 1;
            return Some(msg);
        }
        let release_ns = now_ns.saturating_add(u64::try_from(wait).unwrap_or(0));
        self.insert(Held { release_ns, msg });
        None
    }
}

impl<L, C, Out, In> Link<Out, In> for Playout<L, C, Out, In>
where
    L: Link<Out, In>,
    C: Clock,
    Out: WireMessage,
    In: WireMessage,
{
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        self.inner.publish(msg)
    }

    /// The next message due: held ones first (in order of their playout time), then
    /// arrivals, each either handed on at once (late, another session, a full buffer) or
    /// held. Disabled, the inner link's next message.
    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        if !self.cfg.enabled {
            return self.inner.try_recv();
        }
        let now = self.clock.now_ns();
        self.delay_cache_ns = self.delay_ns();
        self.counters.delay_ms = self.delay_cache_ns as f64 / NS_PER_MS;
        loop {
            if let Some(m) = self.pop_due(now) {
                return Ok(Some(m));
            }
            let Some(msg) = self.inner.try_recv()? else {
                return Ok(None);
            };
            if self.session.is_some_and(|s| s != msg.session_id()) {
                // A new sender: everything held from the old one goes first.
                self.release_all();
            }
            if let Some(m) = self.arrive(msg, now) {
                if self.len == 0 || self.len == PLAYOUT_CAPACITY {
                    return Ok(Some(m));
                }
                // Due now: after what is already due, before what is still held.
                self.insert(Held {
                    release_ns: now,
                    msg: m,
                });
            }
        }
    }

    /// Disabled, the inner link's wake-up (the slave phase-locks through it); enabled, the
    /// buffer releases by its clock and cannot be woken by an arrival.
    fn wait_message(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        if self.cfg.enabled {
            Ok(false)
        } else {
            self.inner.wait_message(deadline)
        }
    }

    fn can_wake(&self) -> bool {
        !self.cfg.enabled && self.inner.can_wake()
    }

    fn decode_rejects(&self) -> DecodeRejects {
        self.inner.decode_rejects()
    }
}
