//! Link impairment: a decorator over any [`Link`] that delays, jitters, loses (Bernoulli and
//! bursty Gilbert–Elliott), duplicates, reorders and blacks out the messages an end
//! *publishes*. Wrap both ends to impair both directions. Seeded; runs on any [`Clock`]:
//! a `SimClock` for the lockstep simulation, the monotonic clock for real processes (held
//! messages are released whenever the owner publishes, receives or calls [`Impaired::pump`],
//! i.e. every cycle).
//!
//! The in-flight buffer is allocated once; impairing a message allocates nothing.

use std::collections::VecDeque;
use std::marker::PhantomData;

use h4_shared::clock::Clock;
use h4_shared::config::{ConfigError, Validate, check_range};
use h4_shared::rng::Rng;
use h4_shared::wire::WireMessage;
use serde::{Deserialize, Serialize};

use crate::{Link, LinkError};

const NS_PER_MS: f64 = 1e6;

/// What to do to the messages of one direction of a link.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ImpairmentConfig {
    /// Constant one-way delay, ms (0 to 10 000).
    pub delay_ms: f64,
    /// Bounded jitter, ms (0 to 10 000): each message's delay is uniform in
    /// `[delay_ms − jitter_ms, delay_ms + jitter_ms]`, never below 0. Messages may overtake.
    pub jitter_ms: f64,
    /// Independent (Bernoulli) loss probability per message (0 to 1).
    pub loss: f64,
    /// Gilbert–Elliott: probability per message of going from the good to the bad state (0 to 1; 0 disables bursts).
    pub burst_loss_enter: f64,
    /// Gilbert–Elliott: probability per message of leaving the bad state (0 to 1); mean burst length is 1/this.
    pub burst_loss_exit: f64,
    /// Gilbert–Elliott: loss probability while in the bad state (0 to 1).
    pub burst_loss_in_bad: f64,
    /// Probability that a message is delivered twice (0 to 1).
    pub duplicate: f64,
    /// Probability that a message is held back by an extra `reorder_extra_ms` (0 to 1).
    pub reorder: f64,
    /// Extra delay of a reordered message, ms (0 to 10 000).
    pub reorder_extra_ms: f64,
    /// Length of each blackout (everything published in it is lost), ms (0 to 3 600 000; 0 = none).
    pub blackout_ms: f64,
    /// A blackout starts every this many ms, the first one after one period (0 = none).
    pub blackout_every_ms: f64,
    /// Seed of the impairment's random draws.
    pub seed: u64,
}

impl Default for ImpairmentConfig {
    fn default() -> Self {
        ImpairmentConfig {
            delay_ms: 0.0,
            jitter_ms: 0.0,
            loss: 0.0,
            burst_loss_enter: 0.0,
            burst_loss_exit: 0.5,
            burst_loss_in_bad: 1.0,
            duplicate: 0.0,
            reorder: 0.0,
            reorder_extra_ms: 3.0,
            blackout_ms: 0.0,
            blackout_every_ms: 0.0,
            seed: 1,
        }
    }
}

impl ImpairmentConfig {
    /// Validates, naming fields under `prefix` (e.g. `"link."`).
    pub fn validate_at(&self, prefix: &str) -> Result<(), ConfigError> {
        let f = |name: &str| format!("{prefix}{name}");
        check_range(&f("delay_ms"), self.delay_ms, 0.0, 10_000.0, "ms")?;
        check_range(&f("jitter_ms"), self.jitter_ms, 0.0, 10_000.0, "ms")?;
        for (name, p) in [
            ("loss", self.loss),
            ("burst_loss_enter", self.burst_loss_enter),
            ("burst_loss_exit", self.burst_loss_exit),
            ("burst_loss_in_bad", self.burst_loss_in_bad),
            ("duplicate", self.duplicate),
            ("reorder", self.reorder),
        ] {
            check_range(&f(name), p, 0.0, 1.0, "(probability)")?;
        }
        check_range(
            &f("reorder_extra_ms"),
            self.reorder_extra_ms,
            0.0,
            10_000.0,
            "ms",
        )?;
        check_range(&f("blackout_ms"), self.blackout_ms, 0.0, 3_600_000.0, "ms")?;
        check_range(
            &f("blackout_every_ms"),
            self.blackout_every_ms,
            0.0,
            3_600_000.0,
            "ms",
        )?;
        if h4_shared::config::recording() {
            h4_shared::config::record_rule(
                &f("blackout_ms"),
                "less than blackout_every_ms when both are set",
            );
        }
        if self.blackout_ms > 0.0
            && self.blackout_every_ms > 0.0
            && self.blackout_ms >= self.blackout_every_ms
        {
            return Err(ConfigError::OutOfRange {
                field: f("blackout_ms"),
                value: self.blackout_ms.to_string(),
                allowed: format!(
                    "less than {}blackout_every_ms ({} ms)",
                    prefix, self.blackout_every_ms
                ),
            });
        }
        Ok(())
    }

    /// Largest one-way delay a message can get, ms.
    pub fn max_delay_ms(&self) -> f64 {
        self.delay_ms
            + self.jitter_ms
            + if self.reorder > 0.0 {
                self.reorder_extra_ms
            } else {
                0.0
            }
    }

    /// Whether time `t_ns` (since the clock's origin) lies in a blackout.
    pub fn in_blackout(&self, t_ns: u64) -> bool {
        if self.blackout_ms <= 0.0 || self.blackout_every_ms <= 0.0 {
            return false;
        }
        let every_ns = (self.blackout_every_ms * NS_PER_MS) as u64;
        let len_ns = (self.blackout_ms * NS_PER_MS) as u64;
        every_ns > 0 && t_ns >= every_ns && t_ns % every_ns < len_ns
    }
}

impl Validate for ImpairmentConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        self.validate_at("")
    }
}

/// What happened to the messages of one impaired direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ImpairmentCounters {
    /// Messages published into the impairment.
    pub sent: u64,
    /// Messages (including duplicates) handed to the underlying link.
    pub delivered: u64,
    /// Messages lost to Bernoulli or burst loss.
    pub lost: u64,
    /// Messages lost in a blackout.
    pub blacked_out: u64,
    /// Extra copies made.
    pub duplicated: u64,
    /// Messages delivered after a message with a higher sequence number.
    pub reordered: u64,
    /// Messages dropped because the in-flight buffer was full.
    pub overflowed: u64,
}

impl ImpairmentCounters {
    /// Every message that never arrived (loss, blackout, overflow).
    pub fn dropped(&self) -> u64 {
        self.lost + self.blacked_out + self.overflowed
    }
}

/// An event of the impairment, for recordings: what happened to which message when.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LinkEventKind {
    /// Lost (random or burst).
    Lost,
    /// Lost in a blackout.
    BlackedOut,
    /// Duplicated.
    Duplicated,
    /// Dropped: buffer full.
    Overflowed,
}

/// One impairment event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, schemars::JsonSchema)]
pub struct LinkEvent {
    /// When, ns on the impairment's clock.
    pub time_ns: u64,
    /// Sequence number of the message.
    pub seq: u64,
    /// What happened.
    pub kind: LinkEventKind,
}

#[derive(Clone, Copy, Debug)]
struct InFlight<M> {
    deliver_at_ns: u64,
    msg: M,
}

/// A link whose outgoing messages are impaired.
#[derive(Debug)]
pub struct Impaired<L, C, Out, In> {
    inner: L,
    clock: C,
    cfg: ImpairmentConfig,
    rng: Rng,
    burst_bad: bool,
    in_flight: VecDeque<InFlight<Out>>,
    max_seq_delivered: Option<u64>,
    events: VecDeque<LinkEvent>,
    /// Counters.
    pub counters: ImpairmentCounters,
    _marker: PhantomData<In>,
}

/// Events kept for [`Impaired::drain_events`] before the oldest are dropped.
const EVENT_CAPACITY: usize = 4096;

impl<L, C, Out, In> Impaired<L, C, Out, In>
where
    L: Link<Out, In>,
    C: Clock,
    Out: WireMessage,
    In: WireMessage,
{
    /// Wraps `inner`; the in-flight buffer holds what `period_ns`-spaced messages need at
    /// the configured maximum delay (with duplicates), plus margin.
    pub fn new(
        inner: L,
        clock: C,
        cfg: ImpairmentConfig,
        period_ns: u64,
    ) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let period_ms = (period_ns.max(1) as f64) / NS_PER_MS;
        let capacity = (2.0 * (cfg.max_delay_ms() / period_ms + 16.0)).ceil() as usize;
        Ok(Impaired {
            inner,
            clock,
            rng: Rng::new(cfg.seed),
            cfg,
            burst_bad: false,
            in_flight: VecDeque::with_capacity(capacity),
            max_seq_delivered: None,
            events: VecDeque::with_capacity(EVENT_CAPACITY),
            counters: ImpairmentCounters::default(),
            _marker: PhantomData,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ImpairmentConfig {
        &self.cfg
    }

    /// The wrapped link.
    pub fn inner(&self) -> &L {
        &self.inner
    }

    /// The wrapped link, mutably.
    pub fn inner_mut(&mut self) -> &mut L {
        &mut self.inner
    }

    /// Messages in flight.
    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Hands every message whose delivery time has come to the underlying link.
    pub fn pump(&mut self) -> Result<(), LinkError> {
        let now = self.clock.now_ns();
        while self
            .in_flight
            .front()
            .is_some_and(|m| m.deliver_at_ns <= now)
        {
            let Some(m) = self.in_flight.pop_front() else {
                break;
            };
            let seq = m.msg.seq();
            match self.max_seq_delivered {
                Some(max) if seq < max => self.counters.reordered += 1,
                _ => self.max_seq_delivered = Some(seq),
            }
            self.counters.delivered += 1;
            self.inner.publish(&m.msg)?;
        }
        Ok(())
    }

    /// Takes the events recorded since the last call (oldest first) and hands each to `f`.
    pub fn drain_events(&mut self, mut f: impl FnMut(&LinkEvent)) {
        while let Some(e) = self.events.pop_front() {
            f(&e);
        }
    }

    fn event(&mut self, time_ns: u64, seq: u64, kind: LinkEventKind) {
        if self.events.len() == EVENT_CAPACITY {
            self.events.pop_front();
        }
        self.events.push_back(LinkEvent { time_ns, seq, kind });
    }

    fn schedule(&mut self, msg: Out, deliver_at_ns: u64) {
        if self.in_flight.len() == self.in_flight.capacity() {
            self.counters.overflowed += 1;
            self.event(self.clock.now_ns(), msg.seq(), LinkEventKind::Overflowed);
            return;
        }
        let at = self
            .in_flight
            .partition_point(|m| m.deliver_at_ns <= deliver_at_ns);
        self.in_flight.insert(at, InFlight { deliver_at_ns, msg });
    }

    fn delay_ns(&mut self) -> u64 {
        let mut ms = self.cfg.delay_ms;
        if self.cfg.jitter_ms > 0.0 {
            ms += self.rng.uniform_in(-self.cfg.jitter_ms, self.cfg.jitter_ms);
        }
        if self.cfg.reorder > 0.0 && self.rng.bernoulli(self.cfg.reorder) {
            ms += self.cfg.reorder_extra_ms;
        }
        (ms.max(0.0) * NS_PER_MS) as u64
    }
}

impl<L, C, Out, In> Link<Out, In> for Impaired<L, C, Out, In>
where
    L: Link<Out, In>,
    C: Clock,
    Out: WireMessage,
    In: WireMessage,
{
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        let now = self.clock.now_ns();
        self.counters.sent += 1;
        // Every draw happens for every message, so one setting does not shift another's numbers.
        let bernoulli_lost = self.rng.bernoulli(self.cfg.loss);
        let u_burst = self.rng.uniform();
        let u_bad_loss = self.rng.uniform();
        let duplicate = self.rng.bernoulli(self.cfg.duplicate);
        if self.burst_bad {
            if u_burst < self.cfg.burst_loss_exit {
                self.burst_bad = false;
            }
        } else if u_burst < self.cfg.burst_loss_enter {
            self.burst_bad = true;
        }
        let burst_lost = self.burst_bad && u_bad_loss < self.cfg.burst_loss_in_bad;
        if self.cfg.in_blackout(now) {
            self.counters.blacked_out += 1;
            self.event(now, msg.seq(), LinkEventKind::BlackedOut);
        } else if bernoulli_lost || burst_lost {
            self.counters.lost += 1;
            self.event(now, msg.seq(), LinkEventKind::Lost);
        } else {
            let d = self.delay_ns();
            self.schedule(*msg, now.saturating_add(d));
            if duplicate {
                self.counters.duplicated += 1;
                self.event(now, msg.seq(), LinkEventKind::Duplicated);
                let d2 = self.delay_ns();
                self.schedule(*msg, now.saturating_add(d2));
            }
        }
        self.pump()
    }

    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        self.pump()?;
        self.inner.try_recv()
    }

    fn decode_rejects(&self) -> crate::DecodeRejects {
        self.inner.decode_rejects()
    }
}
