//! When the lockstep session's slave takes the master's command (`slave.timing`): in the
//! period the master sent it (phase-locked, as `h4-slave run` does since issue 33) or in the
//! next (a slave on its own clock that polls once per period).
//!
//! A lockstep cycle steps the master (it reads the feedback that has arrived and publishes
//! its command), then the slave. Phase-locked, the slave's step reads the command of this
//! period and its feedback answers it; the master reads that feedback at its next step: the
//! loop carries one period. On its own clock the slave polls before the master's command
//! has arrived, so it takes that command one period later and its feedback echoes the
//! command of the previous period: the loop carries two periods, as the processes' did when
//! the slave answered in its next cycle (issue 33: round trip p50 1003 µs over the
//! transport's 3.5 µs).

use std::collections::VecDeque;

use h4_shared::wire::{Command, Feedback};
use h4_transport::{DecodeRejects, Link, LinkError};
use serde::{Deserialize, Serialize};

/// When the slave's cycle takes the master's command (`slave.timing`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum SlaveTiming {
    /// The slave's cycle runs when the master's command arrives: its feedback answers the
    /// command of the same period, which the master reads at its next step (what
    /// `h4-slave run` does with a link that can wake it).
    #[default]
    PhaseLocked,
    /// The slave runs on its own clock and polls before the master's command arrives: it
    /// takes each command one period late, its feedback echoes the previous period's command.
    OwnClock,
}

/// Commands an own-clock slave's poll takes at most (the in-process link's capacity).
const HELD_CAPACITY: usize = 1024;

/// The slave's side of the link with [`SlaveTiming`] applied. Phase-locked it passes
/// everything through. On its own clock the slave's poll is [`SlaveInbox::poll`], called
/// at the end of each lockstep cycle (before the master's next step): what has arrived by
/// then is held, and the slave's next step takes only that (the master's command of that
/// period waits for the next poll). Allocated once; nothing is dropped (a full hold leaves
/// the rest in the link).
pub struct SlaveInbox<L> {
    inner: L,
    timing: SlaveTiming,
    held: VecDeque<Command>,
}

impl<L: Link<Feedback, Command>> SlaveInbox<L> {
    /// Wraps the slave's end `inner`.
    pub fn new(inner: L, timing: SlaveTiming) -> Self {
        let capacity = match timing {
            SlaveTiming::PhaseLocked => 0,
            SlaveTiming::OwnClock => HELD_CAPACITY,
        };
        SlaveInbox {
            inner,
            timing,
            held: VecDeque::with_capacity(capacity),
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

    /// An own-clock slave's poll for its next step, made before the master's step of that
    /// period: holds what has arrived so far. Does nothing phase-locked.
    pub fn poll(&mut self) -> Result<(), LinkError> {
        if self.timing == SlaveTiming::OwnClock {
            while self.held.len() < HELD_CAPACITY {
                match self.inner.try_recv()? {
                    Some(c) => self.held.push_back(c),
                    None => break,
                }
            }
        }
        Ok(())
    }
}

impl<L: Link<Feedback, Command>> Link<Feedback, Command> for SlaveInbox<L> {
    fn publish(&mut self, msg: &Feedback) -> Result<(), LinkError> {
        self.inner.publish(msg)
    }

    fn try_recv(&mut self) -> Result<Option<Command>, LinkError> {
        match self.timing {
            SlaveTiming::PhaseLocked => self.inner.try_recv(),
            SlaveTiming::OwnClock => Ok(self.held.pop_front()),
        }
    }

    fn decode_rejects(&self) -> DecodeRejects {
        self.inner.decode_rejects()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn cmd(seq: u64) -> Command {
        Command {
            seq,
            ..Command::default()
        }
    }

    /// Own-clock, a command sent after the poll waits for the next poll; phase-locked it is
    /// taken at once (negative control).
    #[test]
    fn an_own_clock_slave_takes_a_command_at_its_next_poll() {
        for (timing, at_once) in [
            (SlaveTiming::PhaseLocked, true),
            (SlaveTiming::OwnClock, false),
        ] {
            let (mut m, s) = h4_transport::inproc::pair(16);
            let mut s = SlaveInbox::new(s, timing);
            s.poll().unwrap();
            m.publish(&cmd(1)).unwrap();
            let first = s.try_recv().unwrap().map(|c| c.seq);
            assert_eq!(first.is_some(), at_once, "{timing:?}");
            s.poll().unwrap();
            m.publish(&cmd(2)).unwrap();
            let mut got = Vec::new();
            while let Some(c) = s.try_recv().unwrap() {
                got.push(c.seq);
            }
            let want = if at_once { vec![2] } else { vec![1] };
            assert_eq!(got, want, "{timing:?}");
        }
    }
}
