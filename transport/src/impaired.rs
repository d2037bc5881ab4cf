//! The simulation's impairment layer ([`crate::impair`]) on a real process's link:
//! `--impair delay_ms=…,jitter_ms=…,loss=…,blackout_ms=…,blackout_every_ms=…,seed=…` on
//! `h4-slave run`, `h4-master run` and `h4-master loopback`, on any transport.
//!
//! Each process impairs what it *publishes* (the slave its feedback, the master its commands)
//! with [`Impaired`] on the monotonic clock, unchanged: the same delay, jitter, loss and
//! blackout semantics and random draws as in `h4-master sim`. A round trip of R ms with both
//! processes impaired is `delay_ms = R/2` on each. Each direction draws from its own stream of
//! `seed` ([`Direction`]), so the two sides' losses are independent with one seed. Held
//! messages are released whenever the loop publishes or receives, i.e. every cycle.

use std::fmt;
use std::str::FromStr;

use h4_shared::clock::MonotonicClock;
use h4_shared::config::Validate;
use h4_shared::rng::Rng;
use h4_shared::wire::WireMessage;

use crate::impair::{Impaired, ImpairmentConfig, ImpairmentCounters};
use crate::{Link, LinkError};

/// The period the in-flight buffer is sized for (1 kHz loops), ns.
const LOOP_PERIOD_NS: u64 = 1_000_000;

/// `--impair KEY=VALUE,…`: an [`ImpairmentConfig`] written as comma-separated `key=value`
/// pairs. Keys are the fields of `ImpairmentConfig` (the `[link]` keys of a session file):
/// `delay_ms`, `jitter_ms`, `loss`, `burst_loss_enter`, `burst_loss_exit`,
/// `burst_loss_in_bad`, `duplicate`, `reorder`, `reorder_extra_ms`, `blackout_ms`,
/// `blackout_every_ms`, `seed`; unnamed keys keep their defaults (no impairment).
/// (Boxed: it sits in the commands' argument structs, which clap keeps by value.)
#[derive(Clone, Debug, PartialEq)]
pub struct ImpairSpec(pub Box<ImpairmentConfig>);

/// Why an `--impair` value was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ImpairSpecError {
    /// A pair without `=`.
    #[error("`{0}`: expected KEY=VALUE (e.g. delay_ms=25,loss=0.05,seed=3)")]
    NotAPair(String),
    /// A key that is not a field of the impairment.
    #[error(
        "unknown key `{0}` (known: delay_ms, jitter_ms, loss, burst_loss_enter, burst_loss_exit, burst_loss_in_bad, duplicate, reorder, reorder_extra_ms, blackout_ms, blackout_every_ms, seed)"
    )]
    UnknownKey(String),
    /// A value that is not a number of the right kind.
    #[error("{key}: `{value}` is not a {kind}")]
    BadValue {
        /// The key.
        key: String,
        /// The value given.
        value: String,
        /// What was expected.
        kind: &'static str,
    },
    /// The same key twice.
    #[error("{0} given twice")]
    Repeated(String),
    /// Out of range (the same checks as a session file's `[link]`).
    #[error("{0}")]
    Invalid(String),
}

impl FromStr for ImpairSpec {
    type Err = ImpairSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut cfg = ImpairmentConfig::default();
        let mut seen: Vec<&str> = Vec::new();
        for pair in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = pair
                .split_once('=')
                .ok_or_else(|| ImpairSpecError::NotAPair(pair.to_string()))?;
            let (key, value) = (key.trim(), value.trim());
            if seen.contains(&key) {
                return Err(ImpairSpecError::Repeated(key.to_string()));
            }
            seen.push(key);
            if key == "seed" {
                cfg.seed = value.parse().map_err(|_| ImpairSpecError::BadValue {
                    key: key.into(),
                    value: value.into(),
                    kind: "non-negative integer",
                })?;
                continue;
            }
            let slot = field_mut(&mut cfg, key)
                .ok_or_else(|| ImpairSpecError::UnknownKey(key.to_string()))?;
            let x: f64 = value.parse().map_err(|_| ImpairSpecError::BadValue {
                key: key.into(),
                value: value.into(),
                kind: "number",
            })?;
            if !x.is_finite() {
                return Err(ImpairSpecError::BadValue {
                    key: key.into(),
                    value: value.into(),
                    kind: "finite number",
                });
            }
            *slot = x;
        }
        cfg.validate()
            .map_err(|e| ImpairSpecError::Invalid(e.to_string()))?;
        Ok(ImpairSpec(Box::new(cfg)))
    }
}

fn field_mut<'a>(cfg: &'a mut ImpairmentConfig, key: &str) -> Option<&'a mut f64> {
    Some(match key {
        "delay_ms" => &mut cfg.delay_ms,
        "jitter_ms" => &mut cfg.jitter_ms,
        "loss" => &mut cfg.loss,
        "burst_loss_enter" => &mut cfg.burst_loss_enter,
        "burst_loss_exit" => &mut cfg.burst_loss_exit,
        "burst_loss_in_bad" => &mut cfg.burst_loss_in_bad,
        "duplicate" => &mut cfg.duplicate,
        "reorder" => &mut cfg.reorder,
        "reorder_extra_ms" => &mut cfg.reorder_extra_ms,
        "blackout_ms" => &mut cfg.blackout_ms,
        "blackout_every_ms" => &mut cfg.blackout_every_ms,
        _ => return None,
    })
}

impl fmt::Display for ImpairSpec {
    /// The `--impair` value that parses back to this impairment (every key written).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.0;
        write!(
            f,
            "delay_ms={},jitter_ms={},loss={},burst_loss_enter={},burst_loss_exit={},burst_loss_in_bad={},duplicate={},reorder={},reorder_extra_ms={},blackout_ms={},blackout_every_ms={},seed={}",
            c.delay_ms,
            c.jitter_ms,
            c.loss,
            c.burst_loss_enter,
            c.burst_loss_exit,
            c.burst_loss_in_bad,
            c.duplicate,
            c.reorder,
            c.reorder_extra_ms,
            c.blackout_ms,
            c.blackout_every_ms,
            c.seed
        )
    }
}

/// The `--impair` option, flattened into the `run` and `loopback` commands.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ImpairArgs {
    /// Impair what this process sends, with the simulation's impairment layer:
    /// KEY=VALUE,… with keys delay_ms, jitter_ms, loss, blackout_ms, blackout_every_ms, seed
    /// (and the other `[link]` keys of a session file). Round trip R ms: delay_ms=R/2 on
    /// both processes. Any transport.
    #[arg(long, value_name = "KEY=VALUE,...")]
    pub impair: Option<ImpairSpec>,
}

impl ImpairArgs {
    /// The arguments that reproduce this option on another command line.
    pub fn to_args(&self) -> Vec<String> {
        match &self.impair {
            Some(spec) => vec!["--impair".into(), spec.to_string()],
            None => vec![],
        }
    }
}

/// Which way a process's messages go: each direction draws from its own random stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Master → slave.
    Commands = 1,
    /// Slave → master.
    Feedback = 2,
}

/// A process's link with its outgoing messages impaired; reports its counters on stderr
/// when dropped (at the end of the run).
pub struct ImpairedLink<Out: WireMessage, In: WireMessage> {
    inner: Impaired<Box<dyn Link<Out, In>>, MonotonicClock, Out, In>,
    direction: Direction,
}

impl<Out: WireMessage, In: WireMessage> ImpairedLink<Out, In> {
    /// Wraps `link`; the impairment's clock starts now (blackouts count from here).
    pub fn new(
        link: Box<dyn Link<Out, In>>,
        spec: &ImpairSpec,
        direction: Direction,
    ) -> Result<Self, ImpairSpecError> {
        let mut cfg = *spec.0;
        cfg.seed = Rng::fork(spec.0.seed, direction as u64).next_u64();
        let inner = Impaired::new(link, MonotonicClock::new(), cfg, LOOP_PERIOD_NS)
            .map_err(|e| ImpairSpecError::Invalid(e.to_string()))?;
        Ok(ImpairedLink { inner, direction })
    }

    /// What happened to the messages so far.
    pub fn counters(&self) -> ImpairmentCounters {
        self.inner.counters
    }
}

impl<Out: WireMessage, In: WireMessage> Link<Out, In> for ImpairedLink<Out, In> {
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        self.inner.publish(msg)
    }
    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        self.inner.try_recv()
    }
    fn undecodable(&self) -> u64 {
        self.inner.undecodable()
    }
}

impl<Out: WireMessage, In: WireMessage> Drop for ImpairedLink<Out, In> {
    fn drop(&mut self) {
        let c = self.inner.counters;
        eprintln!(
            "impair ({}): sent {}, delivered {}, lost {}, blacked out {}, duplicated {}, overflowed {}, still in flight {}",
            match self.direction {
                Direction::Commands => "commands",
                Direction::Feedback => "feedback",
            },
            c.sent,
            c.delivered,
            c.lost,
            c.blacked_out,
            c.duplicated,
            c.overflowed,
            self.inner.in_flight()
        );
    }
}

/// `link` as it is, or impaired by `spec` (outgoing messages, `direction`).
pub fn wrap<Out: WireMessage + 'static, In: WireMessage + 'static>(
    link: Box<dyn Link<Out, In>>,
    spec: Option<&ImpairSpec>,
    direction: Direction,
) -> Result<Box<dyn Link<Out, In>>, ImpairSpecError> {
    match spec {
        None => Ok(link),
        Some(s) => Ok(Box::new(ImpairedLink::new(link, s, direction)?)),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn parses_the_issue_keys_and_round_trips_through_display() {
        let s: ImpairSpec =
            "delay_ms=25,jitter_ms=5,loss=0.05,blackout_ms=200,blackout_every_ms=2000,seed=7"
                .parse()
                .unwrap();
        assert_eq!(s.0.delay_ms, 25.0);
        assert_eq!(s.0.jitter_ms, 5.0);
        assert_eq!(s.0.loss, 0.05);
        assert_eq!(s.0.blackout_ms, 200.0);
        assert_eq!(s.0.blackout_every_ms, 2000.0);
        assert_eq!(s.0.seed, 7);
        assert_eq!(s.0.duplicate, 0.0, "unnamed keys keep their defaults");
        let back: ImpairSpec = s.to_string().parse().unwrap();
        assert_eq!(back, s);
        assert_eq!(
            *"".parse::<ImpairSpec>().unwrap().0,
            ImpairmentConfig::default()
        );
    }

    #[test]
    fn refuses_bad_specs_with_a_reason() {
        for (bad, needle) in [
            ("delay_ms", "KEY=VALUE"),
            ("delay=3", "unknown key"),
            ("loss=x", "not a number"),
            ("loss=NaN", "finite"),
            ("loss=1.5", "loss"),
            ("delay_ms=-1", "delay_ms"),
            ("seed=-1", "integer"),
            ("loss=0.1,loss=0.2", "twice"),
            ("blackout_ms=300,blackout_every_ms=200", "blackout_ms"),
        ] {
            let e = bad.parse::<ImpairSpec>().unwrap_err().to_string();
            assert!(e.contains(needle), "{bad}: {e}");
        }
    }

    #[test]
    fn the_wrapper_drops_and_delays_on_the_real_clock() {
        use h4_shared::wire::{Command, Feedback};
        let cmd = |seq| Command {
            seq,
            ..Command::default()
        };
        // loss = 1: nothing arrives.
        let (m, mut s) = crate::inproc::pair(64);
        let m: Box<dyn Link<Command, Feedback>> = Box::new(m);
        let spec: ImpairSpec = "loss=1".parse().unwrap();
        let mut m = wrap(m, Some(&spec), Direction::Commands).unwrap();
        for seq in 1..=20 {
            m.publish(&cmd(seq)).unwrap();
        }
        assert!(s.try_recv().unwrap().is_none());
        // delay 30 ms: not there at once (load only makes the check later, never earlier than
        // the publish), there once 30 ms have passed and the sender's loop pumped.
        let (m, mut s) = crate::inproc::pair(64);
        let spec: ImpairSpec = "delay_ms=30".parse().unwrap();
        let mut m = ImpairedLink::new(Box::new(m), &spec, Direction::Commands).unwrap();
        let sent = std::time::Instant::now();
        m.publish(&cmd(1)).unwrap();
        let early = s.try_recv().unwrap();
        assert!(
            early.is_none() || sent.elapsed().as_millis() >= 30,
            "delivered before its delay"
        );
        std::thread::sleep(std::time::Duration::from_millis(40));
        let _ = m.try_recv().unwrap();
        assert_eq!(s.try_recv().unwrap().map(|c| c.seq), Some(1));
        assert_eq!(m.counters().delivered, 1);
    }
}
