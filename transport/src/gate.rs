//! The check in front of every control loop: a received message is acted on only if it is
//! well-formed, of our protocol version, for our arm, and newer than the last one accepted.
//! Everything else is rejected and counted. The gate also tells liveness (time since the
//! last accepted message) and re-pairs with a peer that restarted (its sequence numbers
//! start again from the beginning after a silence).

use h4_shared::wire::{WireError, WireMessage};

use crate::Link;

/// Why a received message was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Rejection {
    /// The peer speaks another protocol version.
    #[error("wrong protocol version {theirs} (ours {ours})")]
    WrongVersion {
        /// Our version.
        ours: u16,
        /// The message's version.
        theirs: u16,
    },
    /// Non-finite numbers, unknown enum values or flag bits.
    #[error("malformed message: {0}")]
    Malformed(WireError),
    /// The message is for another arm.
    #[error("message for arm {got}, this is arm {expected}")]
    WrongArm {
        /// Our arm id.
        expected: u16,
        /// The message's arm id.
        got: u16,
    },
    /// A duplicate, or older than a message already accepted (reordered or replayed).
    #[error("stale message: seq {got} after {last}")]
    Stale {
        /// Last accepted sequence number.
        last: u64,
        /// The message's sequence number.
        got: u64,
    },
}

/// What the gate has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct GateCounters {
    /// Messages accepted.
    pub accepted: u64,
    /// Messages with another protocol version.
    pub wrong_version: u64,
    /// Malformed messages (non-finite, bad enums or flags).
    pub malformed: u64,
    /// Messages for another arm.
    pub wrong_arm: u64,
    /// Duplicates and messages older than the last accepted one.
    pub stale: u64,
    /// Times the peer restarted and the gate paired with its new session.
    pub repaired: u64,
    /// Payloads the link dropped before the gate because they did not decode (wrong size,
    /// version or content): the link's own count ([`crate::Link::undecodable`]), handed over by
    /// [`Gate::note_undecodable`].
    pub undecodable: u64,
}

impl GateCounters {
    /// All rejections.
    pub fn rejected(&self) -> u64 {
        self.wrong_version + self.malformed + self.wrong_arm + self.stale + self.undecodable
    }
}

/// The receive gate for messages of type `M`.
#[derive(Clone, Debug)]
pub struct Gate<M> {
    arm_id: u16,
    restart_silence_ns: u64,
    last_seq: Option<u64>,
    last_accept_ns: Option<u64>,
    latest: Option<M>,
    /// Counters.
    pub counters: GateCounters,
}

/// What one [`Gate::drain`] saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Drained {
    /// Messages the link delivered.
    pub received: u64,
    /// Of those, accepted by the gate.
    pub accepted: u64,
    /// The link failed while receiving (the drain stopped there).
    pub link_error: bool,
}

impl<M: WireMessage> Gate<M> {
    /// A gate for `arm_id`. After `restart_silence_ns` without an accepted message, a
    /// message whose sequence number went backwards is taken as a restarted peer.
    pub fn new(arm_id: u16, restart_silence_ns: u64) -> Self {
        Gate {
            arm_id,
            restart_silence_ns,
            last_seq: None,
            last_accept_ns: None,
            latest: None,
            counters: GateCounters::default(),
        }
    }

    /// Checks one received message at local time `now_ns`.
    pub fn accept(&mut self, msg: &M, now_ns: u64) -> Result<M, Rejection> {
        if let Err(e) = msg.validate() {
            return Err(match e {
                WireError::WrongVersion { ours, theirs } => {
                    self.counters.wrong_version += 1;
                    Rejection::WrongVersion { ours, theirs }
                }
                other => {
                    self.counters.malformed += 1;
                    Rejection::Malformed(other)
                }
            });
        }
        if msg.arm_id() != self.arm_id {
            self.counters.wrong_arm += 1;
            return Err(Rejection::WrongArm {
                expected: self.arm_id,
                got: msg.arm_id(),
            });
        }
        if let Some(last) = self.last_seq
            && msg.seq() <= last
        {
            {
                let silent = self
                    .silence_ns(now_ns)
                    .is_some_and(|s| s > self.restart_silence_ns);
                if silent && msg.seq() < last {
                    self.counters.repaired += 1;
                } else {
                    self.counters.stale += 1;
                    return Err(Rejection::Stale {
                        last,
                        got: msg.seq(),
                    });
                }
            }
        }
        self.last_seq = Some(msg.seq());
        self.last_accept_ns = Some(now_ns);
        self.latest = Some(*msg);
        self.counters.accepted += 1;
        Ok(*msg)
    }

    /// Takes the link's count of payloads it dropped undecoded ([`crate::Link::undecodable`],
    /// a total since the link was opened) into [`GateCounters::undecodable`]: a receiver calls
    /// it after draining the link, so every message that arrived, decodable or not, is counted
    /// by the gate.
    pub fn note_undecodable(&mut self, link_total: u64) {
        self.counters.undecodable = link_total;
    }

    /// Drains `link` at `now_ns`: at most `max` messages, each through [`Gate::accept`], every
    /// accepted one handed to `on_accept`; then the payloads the link dropped undecoded are
    /// noted ([`Gate::note_undecodable`]). The one receive path of both endpoints.
    pub fn drain<Out: WireMessage, L: Link<Out, M> + ?Sized>(
        &mut self,
        link: &mut L,
        now_ns: u64,
        max: usize,
        mut on_accept: impl FnMut(&M),
    ) -> Drained {
        let mut d = Drained::default();
        for _ in 0..max {
            match link.try_recv() {
                Ok(Some(msg)) => {
                    d.received += 1;
                    if let Ok(m) = self.accept(&msg, now_ns) {
                        d.accepted += 1;
                        on_accept(&m);
                    }
                }
                Ok(None) => break,
                Err(_) => {
                    d.link_error = true;
                    break;
                }
            }
        }
        self.note_undecodable(link.undecodable());
        d
    }

    /// The newest accepted message.
    pub fn latest(&self) -> Option<&M> {
        self.latest.as_ref()
    }

    /// Time since the last accepted message, or `None` before the first.
    pub fn silence_ns(&self, now_ns: u64) -> Option<u64> {
        self.last_accept_ns.map(|t| now_ns.saturating_sub(t))
    }

    /// Whether a message was accepted within `timeout_ns` before `now_ns`.
    pub fn alive(&self, now_ns: u64, timeout_ns: u64) -> bool {
        self.silence_ns(now_ns).is_some_and(|s| s <= timeout_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_shared::wire::{Command, PROTOCOL_VERSION};

    fn cmd(seq: u64) -> Command {
        Command {
            seq,
            arm_id: 4,
            ..Command::default()
        }
    }

    #[test]
    fn rejects_and_counts_every_kind() {
        let mut g = Gate::<Command>::new(4, 50_000_000);
        assert!(g.accept(&cmd(1), 0).is_ok());
        assert_eq!(
            g.accept(&cmd(1), 1),
            Err(Rejection::Stale { last: 1, got: 1 })
        );
        assert!(g.accept(&cmd(3), 2).is_ok());
        assert_eq!(
            g.accept(&cmd(2), 3),
            Err(Rejection::Stale { last: 3, got: 2 })
        );
        let mut other_arm = cmd(9);
        other_arm.arm_id = 5;
        assert!(matches!(
            g.accept(&other_arm, 4),
            Err(Rejection::WrongArm { .. })
        ));
        let mut nan = cmd(10);
        nan.pose[1] = f64::NAN;
        assert!(matches!(g.accept(&nan, 5), Err(Rejection::Malformed(_))));
        let mut v = cmd(11);
        v.protocol_version = PROTOCOL_VERSION + 1;
        assert!(matches!(
            g.accept(&v, 6),
            Err(Rejection::WrongVersion { .. })
        ));
        let c = g.counters;
        assert_eq!(
            (
                c.accepted,
                c.stale,
                c.wrong_arm,
                c.malformed,
                c.wrong_version
            ),
            (2, 2, 1, 1, 1)
        );
        assert_eq!(g.latest().map(|m| m.seq), Some(3));
    }

    #[test]
    fn restarted_peer_is_repaired_only_after_silence() {
        let mut g = Gate::<Command>::new(4, 50_000_000);
        assert!(g.accept(&cmd(1000), 0).is_ok());
        assert!(
            g.accept(&cmd(1), 10_000_000).is_err(),
            "too soon: a replay, not a restart"
        );
        assert!(g.accept(&cmd(1), 100_000_000).is_ok());
        assert_eq!(g.counters.repaired, 1);
        assert!(g.alive(110_000_000, 20_000_000));
        assert!(!g.alive(130_000_001, 20_000_000));
    }
}
