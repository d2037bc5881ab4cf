//! The check in front of every control loop, and the one receive path of both endpoints
//! ([`Gate::drain`]): every received message is judged once, and acted on only if it is
//! well-formed, of our protocol version, for our arm, from the paired session, newer than the
//! last one accepted but not wildly ahead of it, inside the receiver's limits and with
//! plausible energy fields. Everything else is rejected and counted by [`RejectReason`]
//! (payloads the link could not decode are counted by the link and folded in by the drain).
//!
//! **Sessions pair the two sides, not sequence numbers.** Every message carries its sender's
//! session id (a random id a process picks when it starts). The first acceptable message
//! pairs the gate with its session; a message of another session is refused
//! ([`RejectReason::WrongSession`]) while the paired session is alive, and pairs the gate
//! with the new session once the paired one has been silent for the restart window (a
//! restarted peer announces itself with a new id). A session the gate left is never taken
//! back. Inside a session the sequence number must grow (else [`RejectReason::Stale`]) by no
//! more than the sender can have sent since its last accepted message
//! ([`SEQ_SLACK`] + the silence at one message per [`SEQ_MIN_PERIOD_NS`], else
//! [`RejectReason::WildSeq`]): a wild number is rejected, never adopted.
//!
//! **Pairing events** are visible to the endpoint: [`Drained::paired`] (this drain paired the
//! gate with a new session), [`Gate::paired_session`], [`GateCounters::pairings`] and the
//! energies the pairing message carried ([`Gate::pairing_energies_j`], the baseline of
//! [`Gate::energy_since_pairing_j`]): a passivity ledger is reset there.
//!
//! **Energy plausibility** ([`EnergyBound`]): the cumulative energy fields may not decrease
//! within a session, and each may grow by no more than a token bucket allows, refilled at
//! `max_power_w` (the receiver's bound on the power the link can carry) and holding at most
//! `reserve_j`. The first message of a session sets the baseline (any finite energy ≥ 0).

use h4_shared::wire::{RejectReason, WireError, WireMessage};

use crate::{DecodeRejects, Link};

/// Sequence numbers a sender may run ahead of the last accepted one beyond its rate.
pub const SEQ_SLACK: u64 = 1000;
/// Shortest period a sender is assumed to send at (10 kHz, ten times the processes' rate).
pub const SEQ_MIN_PERIOD_NS: u64 = 100_000;

/// Why a received message was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum Rejection {
    /// The message did not pass the wire checks (version, size, reserved bits, enums,
    /// finiteness); [`WireError::reason`] says under which counter.
    #[error("{0}")]
    Wire(WireError),
    /// The message is for another arm.
    #[error("message for arm {got}, this is arm {expected}")]
    WrongArm {
        /// Our arm id.
        expected: u16,
        /// The message's arm id.
        got: u16,
    },
    /// From another session than the paired one, which is alive (or a retired session).
    #[error("message of session {got:#x}, paired with {paired:#x}")]
    WrongSession {
        /// The paired session.
        paired: u64,
        /// The message's session.
        got: u64,
    },
    /// A duplicate, or older than a message already accepted (reordered or replayed).
    #[error("stale message: seq {got} after {last}")]
    Stale {
        /// Last accepted sequence number.
        last: u64,
        /// The message's sequence number.
        got: u64,
    },
    /// Further ahead of the last accepted sequence number than the sender can have sent.
    #[error("wild sequence number {got} after {last} (at most {allowed} ahead)")]
    WildSeq {
        /// Last accepted sequence number.
        last: u64,
        /// The message's sequence number.
        got: u64,
        /// The largest step allowed at that moment.
        allowed: u64,
    },
    /// Outside the receiver's limits (a reason code).
    #[error("out of range: {0}")]
    OutOfRange(&'static str),
    /// Energy fields that cannot have been exchanged since the last message.
    #[error("implausible energy: {field} changed by {change_j} J (at most {allowed_j} J)")]
    ImplausibleEnergy {
        /// `energy_in_j` or `energy_out_j`.
        field: &'static str,
        /// Change since the last accepted message, J.
        change_j: f64,
        /// Largest change allowed then, J.
        allowed_j: f64,
    },
}

impl Rejection {
    /// The counter it is counted under.
    pub fn reason(&self) -> RejectReason {
        match self {
            Rejection::Wire(e) => e.reason(),
            Rejection::WrongArm { .. } => RejectReason::WrongArm,
            Rejection::WrongSession { .. } => RejectReason::WrongSession,
            Rejection::Stale { .. } => RejectReason::Stale,
            Rejection::WildSeq { .. } => RejectReason::WildSeq,
            Rejection::OutOfRange(_) => RejectReason::OutOfRange,
            Rejection::ImplausibleEnergy { .. } => RejectReason::ImplausibleEnergy,
        }
    }
}

/// What the gate has seen: one counter per rejection reason (docs/processes.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct GateCounters {
    /// Messages accepted.
    pub accepted: u64,
    /// Not a message: wrong payload size, magic or kind, a non-finite number, an unknown mode
    /// or state (counted by the link for payloads it could not decode, by the gate for typed
    /// messages).
    pub undecodable: u64,
    /// Messages with another protocol version.
    pub wrong_version: u64,
    /// Messages for another arm.
    pub wrong_arm: u64,
    /// Duplicates and messages older than the last accepted one of the session.
    pub stale: u64,
    /// Commands outside the receiver's limits (workspace, set-point, speed).
    pub out_of_range: u64,
    /// Energy fields more than the sender can have exchanged since its last message.
    pub implausible_energy: u64,
    /// A reserved byte or an undefined flag bit set.
    pub reserved_bits: u64,
    /// A header body length other than the kind's.
    pub length_mismatch: u64,
    /// Sequence numbers wildly ahead of the session's.
    pub wild_seq: u64,
    /// Messages of another session than the paired, living one.
    pub wrong_session: u64,
    /// Times the gate paired with a session (the first included).
    pub pairings: u64,
    /// Times the gate paired with a new session after another one (a restarted peer).
    pub repaired: u64,
}

impl GateCounters {
    /// All rejections.
    pub fn rejected(&self) -> u64 {
        RejectReason::ALL.iter().map(|r| self.of(*r)).sum()
    }

    /// The counter of `reason`.
    pub fn of(&self, reason: RejectReason) -> u64 {
        match reason {
            RejectReason::Undecodable => self.undecodable,
            RejectReason::WrongVersion => self.wrong_version,
            RejectReason::WrongArm => self.wrong_arm,
            RejectReason::Stale => self.stale,
            RejectReason::OutOfRange => self.out_of_range,
            RejectReason::ImplausibleEnergy => self.implausible_energy,
            RejectReason::ReservedBits => self.reserved_bits,
            RejectReason::LengthMismatch => self.length_mismatch,
            RejectReason::WildSeq => self.wild_seq,
            RejectReason::WrongSession => self.wrong_session,
        }
    }

    fn count(&mut self, reason: RejectReason, n: u64) {
        let c = match reason {
            RejectReason::Undecodable => &mut self.undecodable,
            RejectReason::WrongVersion => &mut self.wrong_version,
            RejectReason::WrongArm => &mut self.wrong_arm,
            RejectReason::Stale => &mut self.stale,
            RejectReason::OutOfRange => &mut self.out_of_range,
            RejectReason::ImplausibleEnergy => &mut self.implausible_energy,
            RejectReason::ReservedBits => &mut self.reserved_bits,
            RejectReason::LengthMismatch => &mut self.length_mismatch,
            RejectReason::WildSeq => &mut self.wild_seq,
            RejectReason::WrongSession => &mut self.wrong_session,
        };
        *c += n;
    }
}

/// The energy plausibility bound of one receiver (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnergyBound {
    /// Largest power the sender's energy fields may grow at, W.
    pub max_power_w: f64,
    /// Largest burst, J (the bucket's size; full at pairing).
    pub reserve_j: f64,
}

impl EnergyBound {
    /// The bound of a link whose side can push at most `force_limit_n` at `max_speed_mm_per_s`:
    /// that power times `margin`, with a reserve of 1 J.
    pub fn from_limits(force_limit_n: f64, max_speed_mm_per_s: f64, margin: f64) -> Self {
        EnergyBound {
            max_power_w: margin * force_limit_n * max_speed_mm_per_s * 1e-3,
            reserve_j: 1.0,
        }
    }
}

/// How many retired sessions the gate remembers (never re-paired with).
const RETIRED: usize = 4;

/// The state of the paired session.
#[derive(Clone, Copy, Debug)]
struct Session {
    id: u64,
    last_seq: u64,
    /// Energies of the last accepted message, J.
    energy_j: (f64, f64),
    /// Energies of the pairing message, J.
    baseline_j: (f64, f64),
    /// Token buckets of the energy fields, J.
    budget_j: (f64, f64),
}

/// The receive gate for messages of type `M`.
#[derive(Clone, Debug)]
pub struct Gate<M: WireMessage> {
    arm_id: u16,
    restart_silence_ns: u64,
    limits: Option<M::Limits>,
    energy: Option<EnergyBound>,
    session: Option<Session>,
    retired: [Option<u64>; RETIRED],
    last_accept_ns: Option<u64>,
    latest: Option<M>,
    link_seen: DecodeRejects,
    reasons: u32,
    last_rejection: Option<Rejection>,
    peer_ledger_may_restart: bool,
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
    /// The gate paired with a new session in this drain ([`Gate::paired_session`] is it).
    pub paired: bool,
    /// The link failed while receiving (the drain stopped there).
    pub link_error: bool,
}

impl<M: WireMessage> Gate<M> {
    /// A gate for `arm_id`, without limits or energy bound. After `restart_silence_ns`
    /// without an accepted message, a message of a new session pairs the gate with it.
    pub fn new(arm_id: u16, restart_silence_ns: u64) -> Self {
        Gate {
            arm_id,
            restart_silence_ns,
            limits: None,
            energy: None,
            session: None,
            retired: [None; RETIRED],
            last_accept_ns: None,
            latest: None,
            link_seen: DecodeRejects::default(),
            reasons: 0,
            last_rejection: None,
            peer_ledger_may_restart: false,
            counters: GateCounters::default(),
        }
    }

    /// While `on`, the peer may start a new energy ledger inside the session without flagging
    /// it: a message whose energies fall is taken as a new ledger (within the reserve), not as
    /// implausible. The master sets it while it acknowledges the slave's safe stop: the slave
    /// starts its new ledger on that acknowledgement, and its feedback says so only by its
    /// energies.
    pub fn set_peer_ledger_may_restart(&mut self, on: bool) {
        self.peer_ledger_may_restart = on;
    }

    /// With limits on the messages' values (out-of-range messages are rejected).
    pub fn with_limits(mut self, limits: M::Limits) -> Self {
        self.limits = Some(limits);
        self
    }

    /// With an energy plausibility bound.
    pub fn with_energy_bound(mut self, bound: EnergyBound) -> Self {
        self.energy = Some(bound);
        self
    }

    fn reject(&mut self, r: Rejection) -> Rejection {
        let reason = r.reason();
        self.counters.count(reason, 1);
        self.reasons |= reason.bit();
        self.last_rejection = Some(r);
        r
    }

    /// Checks one received message at local time `now_ns`.
    pub fn accept(&mut self, msg: &M, now_ns: u64) -> Result<M, Rejection> {
        match self.judge(msg, now_ns) {
            Ok(next) => {
                self.commit(msg, next, now_ns);
                Ok(*msg)
            }
            Err(r) => Err(self.reject(r)),
        }
    }

    /// The verdict on `msg`, and the session state accepting it would leave.
    fn judge(&self, msg: &M, now_ns: u64) -> Result<Session, Rejection> {
        msg.validate().map_err(Rejection::Wire)?;
        if msg.arm_id() != self.arm_id {
            return Err(Rejection::WrongArm {
                expected: self.arm_id,
                got: msg.arm_id(),
            });
        }
        let sid = msg.session_id();
        let silence = self.silence_ns(now_ns);
        let current = match self.session {
            Some(s) if s.id == sid => Some(s),
            Some(s) => {
                let silent = silence.is_some_and(|t| t > self.restart_silence_ns);
                if !silent || self.retired.contains(&Some(sid)) {
                    return Err(Rejection::WrongSession {
                        paired: s.id,
                        got: sid,
                    });
                }
                None
            }
            None if self.retired.contains(&Some(sid)) => {
                return Err(Rejection::WrongSession {
                    paired: 0,
                    got: sid,
                });
            }
            None => None,
        };
        if let Some(s) = &current {
            if msg.seq() <= s.last_seq {
                return Err(Rejection::Stale {
                    last: s.last_seq,
                    got: msg.seq(),
                });
            }
            let allowed = SEQ_SLACK.saturating_add(silence.unwrap_or(0) / SEQ_MIN_PERIOD_NS);
            if msg.seq() - s.last_seq > allowed {
                return Err(Rejection::WildSeq {
                    last: s.last_seq,
                    got: msg.seq(),
                    allowed,
                });
            }
        }
        if let Some(l) = &self.limits
            && let Some(code) = msg.out_of_range(l)
        {
            return Err(Rejection::OutOfRange(code));
        }
        let energy_j = msg.energies_j();
        let restarts = msg.starts_new_ledger()
            || (self.peer_ledger_may_restart
                && current.is_some_and(|s| energy_j.0 < s.energy_j.0 || energy_j.1 < s.energy_j.1));
        let next = match current {
            Some(s) if !restarts => self.energy_step(&s, energy_j, silence.unwrap_or(0)),
            _ => {
                // A new session, or a new ledger inside one (the safe-stop acknowledgement):
                // energies ≥ 0, and a new ledger starts within the reserve.
                let cap = match (current.is_some(), self.energy) {
                    (true, Some(b)) => b.reserve_j,
                    _ => f64::INFINITY,
                };
                for (field, e) in [("energy_in_j", energy_j.0), ("energy_out_j", energy_j.1)] {
                    if self.energy.is_some() && !(0.0..=cap).contains(&e) {
                        return Err(Rejection::ImplausibleEnergy {
                            field,
                            change_j: e,
                            allowed_j: cap,
                        });
                    }
                }
                let full = self.energy.map_or(0.0, |b| b.reserve_j);
                Ok(Session {
                    id: sid,
                    last_seq: current.map_or(msg.seq(), |s| s.last_seq),
                    energy_j,
                    baseline_j: energy_j,
                    budget_j: (full, full),
                })
            }
        };
        next.map(|mut s| {
            s.last_seq = msg.seq();
            s
        })
    }

    /// The energy check inside session `s`, `dt_ns` after its last accepted message.
    fn energy_step(&self, s: &Session, e: (f64, f64), dt_ns: u64) -> Result<Session, Rejection> {
        let mut next = *s;
        next.energy_j = e;
        let Some(bound) = self.energy else {
            return Ok(next);
        };
        let refill = bound.max_power_w * dt_ns as f64 * 1e-9;
        let fields = [
            ("energy_in_j", s.energy_j.0, e.0, s.budget_j.0),
            ("energy_out_j", s.energy_j.1, e.1, s.budget_j.1),
        ];
        let mut budgets = [0.0; 2];
        for (i, (field, last, now, budget)) in fields.into_iter().enumerate() {
            let change_j = now - last;
            let allowed_j = (budget + refill).min(bound.reserve_j);
            let tolerance = 1e-9 * last.abs().max(1.0);
            if change_j < -tolerance || change_j > allowed_j {
                return Err(Rejection::ImplausibleEnergy {
                    field,
                    change_j,
                    allowed_j,
                });
            }
            budgets[i] = allowed_j - change_j.max(0.0);
        }
        next.budget_j = (budgets[0], budgets[1]);
        Ok(next)
    }

    fn commit(&mut self, msg: &M, next: Session, now_ns: u64) {
        let new = self.session.is_none_or(|s| s.id != next.id);
        if new {
            if let Some(old) = self.session {
                self.retired.rotate_right(1);
                self.retired[0] = Some(old.id);
                self.counters.repaired += 1;
            }
            self.counters.pairings += 1;
        }
        self.session = Some(next);
        self.last_accept_ns = Some(now_ns);
        self.latest = Some(*msg);
        self.counters.accepted += 1;
    }

    /// Folds the link's totals of payloads it could not decode (since it was opened) into the
    /// counters and the reasons ([`Link::decode_rejects`]); [`Gate::drain`] calls it.
    pub fn note_decode_rejects(&mut self, total: DecodeRejects) {
        let seen = self.link_seen;
        for (reason, now, before) in [
            (
                RejectReason::Undecodable,
                total.undecodable,
                seen.undecodable,
            ),
            (
                RejectReason::WrongVersion,
                total.wrong_version,
                seen.wrong_version,
            ),
            (
                RejectReason::ReservedBits,
                total.reserved_bits,
                seen.reserved_bits,
            ),
            (
                RejectReason::LengthMismatch,
                total.length_mismatch,
                seen.length_mismatch,
            ),
            (
                RejectReason::OutOfRange,
                total.out_of_range,
                seen.out_of_range,
            ),
        ] {
            let n = now.saturating_sub(before);
            if n > 0 {
                self.counters.count(reason, n);
                self.reasons |= reason.bit();
            }
        }
        self.link_seen = total;
    }

    /// Drains `link` at `now_ns`: at most `max` messages, each judged once by
    /// [`Gate::accept`], every accepted one handed to `on_accept`; then the payloads the link
    /// could not decode are counted ([`Gate::note_decode_rejects`]). The one receive path of
    /// both endpoints.
    pub fn drain<Out: WireMessage, L: Link<Out, M> + ?Sized>(
        &mut self,
        link: &mut L,
        now_ns: u64,
        max: usize,
        mut on_accept: impl FnMut(&M),
    ) -> Drained {
        let mut d = Drained::default();
        let pairings = self.counters.pairings;
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
        self.note_decode_rejects(link.decode_rejects());
        d.paired = self.counters.pairings != pairings;
        d
    }

    /// The reasons (bits of [`RejectReason::bit`]) of the rejections since the last call, and
    /// clears them: the slave reports them in its next feedback.
    pub fn take_reasons(&mut self) -> u32 {
        std::mem::take(&mut self.reasons)
    }

    /// The link's totals of payloads it could not decode, as last folded in.
    pub fn link_decode_rejects(&self) -> DecodeRejects {
        self.link_seen
    }

    /// The last rejection, for diagnostics.
    pub fn last_rejection(&self) -> Option<Rejection> {
        self.last_rejection
    }

    /// The session the gate is paired with, or `None` before the first accepted message.
    pub fn paired_session(&self) -> Option<u64> {
        self.session.map(|s| s.id)
    }

    /// The energy fields `(in, out)` of the message that paired the gate with its session, J.
    pub fn pairing_energies_j(&self) -> Option<(f64, f64)> {
        self.session.map(|s| s.baseline_j)
    }

    /// `msg`'s energy fields minus those of the pairing message (energy exchanged since the
    /// pairing), J; the fields themselves before a pairing.
    pub fn energy_since_pairing_j(&self, msg: &M) -> (f64, f64) {
        let (i, o) = msg.energies_j();
        self.session
            .map_or((i, o), |s| (i - s.baseline_j.0, o - s.baseline_j.1))
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
            session_id: 77,
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
        assert_eq!(
            g.accept(&nan, 5).map_err(|r| r.reason()),
            Err(RejectReason::Undecodable)
        );
        let mut v = cmd(11);
        v.protocol_version = PROTOCOL_VERSION + 1;
        assert_eq!(
            g.accept(&v, 6).map_err(|r| r.reason()),
            Err(RejectReason::WrongVersion)
        );
        let mut r = cmd(12);
        r.reserved = 1;
        assert_eq!(
            g.accept(&r, 7).map_err(|r| r.reason()),
            Err(RejectReason::ReservedBits)
        );
        let c = g.counters;
        assert_eq!(
            (
                c.accepted,
                c.stale,
                c.wrong_arm,
                c.undecodable,
                c.wrong_version,
                c.reserved_bits
            ),
            (2, 2, 1, 1, 1, 1)
        );
        assert_eq!(c.rejected(), 6);
        assert_eq!(g.latest().map(|m| m.seq), Some(3));
        let bits = g.take_reasons();
        assert_eq!(
            bits,
            RejectReason::Stale.bit()
                | RejectReason::WrongArm.bit()
                | RejectReason::Undecodable.bit()
                | RejectReason::WrongVersion.bit()
                | RejectReason::ReservedBits.bit()
        );
        assert_eq!(g.take_reasons(), 0);
    }

    #[test]
    fn a_wild_sequence_number_is_rejected_not_adopted() {
        let mut g = Gate::<Command>::new(4, 50_000_000);
        assert!(g.accept(&cmd(1), 0).is_ok());
        assert!(matches!(
            g.accept(&cmd(u64::MAX), 1_000_000),
            Err(Rejection::WildSeq { .. })
        ));
        assert!(g.accept(&cmd(2), 2_000_000).is_ok(), "not locked out");
        // After a 1 s gap, 1 s worth of messages ahead is fine.
        assert!(g.accept(&cmd(1500), 1_002_000_000).is_ok());
        assert_eq!(g.counters.wild_seq, 1);
    }

    #[test]
    fn a_new_session_pairs_only_after_the_paired_one_went_silent() {
        let mut g = Gate::<Command>::new(4, 50_000_000);
        assert!(g.accept(&cmd(1000), 0).is_ok());
        assert_eq!(g.paired_session(), Some(77));
        let mut other = cmd(1);
        other.session_id = 78;
        assert!(
            matches!(
                g.accept(&other, 10_000_000),
                Err(Rejection::WrongSession { .. })
            ),
            "the paired session is alive"
        );
        // The same session's lower seq after a silence is stale, not a restart.
        assert!(g.accept(&cmd(1), 100_000_000).is_err());
        assert!(g.accept(&other, 100_000_000).is_ok());
        assert_eq!(g.paired_session(), Some(78));
        assert_eq!((g.counters.pairings, g.counters.repaired), (2, 1));
        // The retired session is never taken back.
        assert!(g.accept(&cmd(2000), 300_000_000).is_err());
        assert!(g.alive(110_000_000, 20_000_000));
        assert!(!g.alive(130_000_001, 20_000_000));
    }

    #[test]
    fn energy_is_bounded_by_power_and_never_decreases() {
        let bound = EnergyBound {
            max_power_w: 10.0,
            reserve_j: 1.0,
        };
        let mut g = Gate::<Command>::new(4, 50_000_000).with_energy_bound(bound);
        let with = |seq, e| Command {
            energy_in_j: e,
            ..cmd(seq)
        };
        assert!(g.accept(&with(1, 5.0), 0).is_ok(), "the baseline");
        assert_eq!(g.pairing_energies_j(), Some((5.0, 0.0)));
        assert!(g.accept(&with(2, 5.9), 1_000_000).is_ok(), "the reserve");
        assert!(g.accept(&with(3, 6.5), 2_000_000).is_err(), "reserve spent");
        assert!(g.accept(&with(4, 6.0), 12_000_000).is_ok(), "refilled");
        assert!(g.accept(&with(5, 5.0), 13_000_000).is_err(), "decreasing");
        assert!(g.accept(&with(6, 1e6), 14_000_000).is_err());
        assert_eq!(g.counters.implausible_energy, 3);
        assert_eq!(g.energy_since_pairing_j(&with(7, 6.5)), (1.5, 0.0));
    }

    #[test]
    fn a_peer_ledger_restart_is_taken_only_while_expected_and_within_the_reserve() {
        let bound = EnergyBound {
            max_power_w: 10.0,
            reserve_j: 1.0,
        };
        let mut g = Gate::<Command>::new(4, 50_000_000).with_energy_bound(bound);
        let with = |seq, e| Command {
            energy_in_j: e,
            ..cmd(seq)
        };
        assert!(g.accept(&with(1, 5.0), 0).is_ok());
        assert!(g.accept(&with(2, 0.1), 1_000_000).is_err(), "not expected");
        g.set_peer_ledger_may_restart(true);
        assert!(
            g.accept(&with(3, 5.1), 2_000_000).is_ok(),
            "the old ledger goes on"
        );
        assert!(
            g.accept(&with(4, 2.0), 3_000_000).is_err(),
            "beyond the reserve"
        );
        assert!(g.accept(&with(5, 0.2), 4_000_000).is_ok(), "a new ledger");
        g.set_peer_ledger_may_restart(false);
        assert!(
            g.accept(&with(6, 0.1), 5_000_000).is_err(),
            "decreasing again"
        );
        assert!(g.accept(&with(7, 0.25), 6_000_000).is_ok());
        assert_eq!(g.counters.implausible_energy, 3);
    }
}
