//! Master ↔ slave links for h4-teleop.
//!
//! One interface, [`Link`], with several implementations: [`inproc`] (two ends in one
//! process, for tests and the lockstep simulation), `iceoryx2` (shared memory on one host)
//! and `zenoh` (between hosts). [`impair::Impaired`] wraps any link and injects delay,
//! jitter, loss, duplication, reordering and blackouts ([`impaired`]: the same on a real process's
//! link, `--impair`); [`gate::Gate`] is the check every
//! receiver puts in front of its control loop. `open` (with both middleware features) opens
//! a process's end from its command-line options. [`ros2`] is the ROS 2 wire format over
//! rmw_zenoh (CDR, type hashes, key expressions; pure, no session).
//!
//! Publishing and receiving never block and allocate nothing per message; a receiver that
//! has nothing else to do until its peer's message may block in [`Link::wait_message`].

pub mod gate;
#[cfg(feature = "iceoryx2")]
pub mod iceoryx2;
pub mod impair;
pub mod impaired;
pub mod inproc;
#[cfg(all(feature = "iceoryx2", feature = "zenoh"))]
pub mod open;
pub mod playout;
pub mod ros2;
#[cfg(feature = "zenoh")]
pub mod zenoh;

use h4_shared::wire::{RejectReason, WireError, WireMessage};

/// Decodes a received payload of `len` bytes, of which `head` holds the first (all of them, or
/// the first bytes of a payload longer than the receiver's buffer). Whatever its size, a
/// payload is judged by its header first (magic, version, kind, reserved byte, body length),
/// then by its size, then by its body, as [`WireMessage::decode_from`] does: a message of
/// another protocol version is [`WireError::WrongVersion`] (counted `wrong_version`) whatever
/// its size, never `undecodable` for its size alone.
pub fn decode_payload<In: WireMessage>(head: &[u8], len: usize) -> Result<In, WireError> {
    let judged = In::decode_from(head);
    if head.len() == len {
        return judged;
    }
    // A truncated view of a longer payload: only its header can be judged, its size is `len`.
    match judged {
        Err(WireError::WrongSize { .. }) | Ok(_) => Err(WireError::WrongSize {
            expected: In::WIRE_SIZE,
            got: len,
        }),
        Err(e) => Err(e),
    }
}

/// Payloads a link end dropped because they did not decode, by reason (totals since it was
/// opened; see [`WireError::reason`]). The gate folds them into its counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecodeRejects {
    /// Wrong size, magic or kind, non-finite numbers, unknown enums.
    pub undecodable: u64,
    /// Another protocol version.
    pub wrong_version: u64,
    /// Reserved bytes or undefined flag bits set.
    pub reserved_bits: u64,
    /// A header body length other than the kind's.
    pub length_mismatch: u64,
    /// Finite but out of range: a feedback's surface estimate (protocol 3).
    pub out_of_range: u64,
}

impl DecodeRejects {
    /// Counts one payload refused with `e`.
    pub fn count(&mut self, e: &WireError) {
        match e.reason() {
            RejectReason::WrongVersion => self.wrong_version += 1,
            RejectReason::ReservedBits => self.reserved_bits += 1,
            RejectReason::LengthMismatch => self.length_mismatch += 1,
            RejectReason::OutOfRange => self.out_of_range += 1,
            _ => self.undecodable += 1,
        }
    }

    /// All of them.
    pub fn total(&self) -> u64 {
        self.undecodable
            + self.wrong_version
            + self.reserved_bits
            + self.length_mismatch
            + self.out_of_range
    }
}

/// Why a link operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LinkError {
    /// The other end is gone for good (in-process link dropped).
    #[error("the link is closed")]
    Closed,
    /// The transport refused the message or failed to deliver it to the wire.
    #[error("{transport}: send failed")]
    SendFailed {
        /// Which transport.
        transport: &'static str,
    },
    /// The transport failed while receiving.
    #[error("{transport}: receive failed")]
    ReceiveFailed {
        /// Which transport.
        transport: &'static str,
    },
}

/// One end of a master ↔ slave link: it publishes `Out` and receives `In`.
pub trait Link<Out: WireMessage, In: WireMessage> {
    /// Publishes a message; never blocks (a full queue drops the oldest message).
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError>;

    /// The next message that has arrived, or `None`; never blocks.
    fn try_recv(&mut self) -> Result<Option<In>, LinkError>;

    /// Drains everything that has arrived and returns the newest, or `None`.
    fn recv_latest(&mut self) -> Result<Option<In>, LinkError> {
        let mut latest = None;
        while let Some(msg) = self.try_recv()? {
            latest = Some(msg);
        }
        Ok(latest)
    }

    /// Received payloads this end dropped because they did not decode, by reason, in total
    /// since it was opened: they are never delivered, so the gate's drain folds these counts
    /// into its own ([`gate::Gate::note_decode_rejects`]). 0 for links that carry typed
    /// messages and decode nothing (in-process, iceoryx2: their gate judges every message).
    fn decode_rejects(&self) -> DecodeRejects {
        DecodeRejects::default()
    }

    /// All payloads this end dropped undecoded ([`Link::decode_rejects`]'s total).
    fn undecodable(&self) -> u64 {
        self.decode_rejects().total()
    }

    /// Blocks until a message has arrived for [`Link::try_recv`] or until `deadline`,
    /// whichever comes first; true if one is waiting (at once when one already is). It
    /// sleeps in the kernel (a condition variable, an iceoryx2 event, the Zenoh subscriber's
    /// signal), never spins, and allocates nothing. A phase-locked loop waits here for its
    /// peer's message and runs its cycle when it arrives ([`Link::can_wake`]).
    ///
    /// The default, for a link that cannot be woken (an impaired link, whose messages are
    /// released by the clock): returns `Ok(false)` at once, and the caller runs on its own
    /// clock.
    fn wait_message(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        let _ = deadline;
        Ok(false)
    }

    /// True if [`Link::wait_message`] wakes on an arrival (false: it returns at once).
    fn can_wake(&self) -> bool {
        false
    }
}

impl<Out: WireMessage, In: WireMessage, L: Link<Out, In> + ?Sized> Link<Out, In> for Box<L> {
    fn publish(&mut self, msg: &Out) -> Result<(), LinkError> {
        (**self).publish(msg)
    }
    fn try_recv(&mut self) -> Result<Option<In>, LinkError> {
        (**self).try_recv()
    }
    fn decode_rejects(&self) -> DecodeRejects {
        (**self).decode_rejects()
    }
    fn wait_message(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        (**self).wait_message(deadline)
    }
    fn can_wake(&self) -> bool {
        (**self).can_wake()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use h4_shared::wire::{Command, PROTOCOL_VERSION};

    fn command_bytes() -> [u8; Command::WIRE_SIZE] {
        let mut b = [0u8; Command::WIRE_SIZE];
        Command::default().encode(&mut b);
        b
    }

    /// A version-1 command (120 bytes) is another version, not an undecodable size, whether
    /// the receiver holds all of it or only the first bytes of a longer payload.
    #[test]
    fn another_version_is_named_whatever_the_payload_size() {
        let mut v1 = command_bytes()[..120].to_vec();
        v1[2] = 1;
        let wrong_version = Err(WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 1,
        });
        assert_eq!(decode_payload::<Command>(&v1, v1.len()), wrong_version);
        assert_eq!(decode_payload::<Command>(&v1, 4000), wrong_version);
        // Control: the same payload with our version is judged by its size.
        let ours = &command_bytes()[..120];
        assert_eq!(
            decode_payload::<Command>(ours, 120),
            Err(WireError::WrongSize {
                expected: Command::WIRE_SIZE,
                got: 120
            })
        );
        assert_eq!(
            decode_payload::<Command>(&command_bytes(), 4000),
            Err(WireError::WrongSize {
                expected: Command::WIRE_SIZE,
                got: 4000
            })
        );
        assert_eq!(
            decode_payload::<Command>(&command_bytes(), Command::WIRE_SIZE),
            Ok(Command::default())
        );
    }
}
