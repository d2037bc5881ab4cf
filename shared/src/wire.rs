//! Master ↔ slave messages.
//!
//! Both messages are `#[repr(C)]`, `Copy` and fixed-size with no implicit padding, so the
//! shared-memory path sends them as they are (from `session_id` on). The network path uses
//! the checked little-endian encoding of [`Command::encode`] / [`Command::decode`]: a
//! 16-byte header (magic `b"H4"`, protocol version, message kind, reserved byte, body
//! length, the sender's session id) and the fields in order. Decoding rejects, in this
//! order, a wrong magic, version or kind, a non-zero reserved byte, a header body length
//! that does not match the kind, a payload whose size is not the kind's, then in the body
//! another version, an unknown mode or state, a reserved byte, unknown flag bits and every
//! non-finite number, each with its own [`WireError`] (the first failure is the error), and
//! every error belongs to one [`RejectReason`] (the receivers' counters). The byte layout,
//! for clients in other languages, is in docs/wire.md with test vectors in
//! tests/data/wire_vectors.json.

use crate::kinematics::{Pose, Workspace};

/// Version of the message layout and encoding. Bump on any change to either.
/// Version 2 added the session id to the header and the rejection report to the feedback;
/// version 3 the command's echo of the newest feedback (the slave measures its round trip)
/// and the feedback's surface estimate (contact point, normal, stiffness, contact state).
pub const PROTOCOL_VERSION: u16 = 3;

const MAGIC: [u8; 2] = *b"H4";
/// Bytes before the message's `session_id`: magic, version, kind, reserved, body length.
const PREFIX_LEN: usize = 8;
/// The whole header: the prefix and the session id.
pub const HEADER_LEN: usize = PREFIX_LEN + 8;
const KIND_COMMAND: u8 = 1;
const KIND_FEEDBACK: u8 = 2;

/// Why received bytes or a received message were rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// The buffer does not have the size of the message.
    #[error("wrong message size: expected {expected} bytes, got {got}")]
    WrongSize {
        /// Size of an encoded message of this kind.
        expected: usize,
        /// Size received.
        got: usize,
    },
    /// The buffer does not start with the h4-teleop magic bytes.
    #[error("not an h4-teleop message (bad magic)")]
    BadMagic,
    /// Another message kind than the one expected.
    #[error("wrong message kind: expected {expected}, got {got}")]
    WrongKind {
        /// Kind expected (1 command, 2 feedback).
        expected: u8,
        /// Kind received.
        got: u8,
    },
    /// The peer speaks another protocol version.
    #[error("protocol version mismatch: ours is {ours}, the message has {theirs}")]
    WrongVersion {
        /// [`PROTOCOL_VERSION`].
        ours: u16,
        /// The version in the message.
        theirs: u16,
    },
    /// A number in the message is NaN or infinite.
    #[error("field {field} is not a finite number")]
    NonFinite {
        /// Name of the field.
        field: &'static str,
    },
    /// The mode byte names no [`Mode`].
    #[error("unknown mode {0}")]
    BadMode(u8),
    /// The status byte names no [`SlaveState`].
    #[error("unknown slave state {0}")]
    BadState(u8),
    /// Flag bits that this version does not define are set.
    #[error("unknown flag bits {0:#x}")]
    BadFlags(u16),
    /// A reserved byte is not zero.
    #[error("reserved byte {field} is {value}, must be 0")]
    ReservedSet {
        /// Which reserved byte (`header.reserved` or `reserved`).
        field: &'static str,
        /// Its value.
        value: u8,
    },
    /// The feedback's contact-state byte names no [`ContactState`].
    #[error("unknown contact state {0}")]
    BadContactState(u8),
    /// A field of the feedback's surface estimate is finite but outside its range (a
    /// contact point beyond [`SURFACE_POINT_LIMIT_MM`], a normal neither unit nor zero, or
    /// not unit in contact, a stiffness outside [0, [`SURFACE_STIFFNESS_MAX_N_PER_MM`]]).
    #[error("surface estimate: {field} out of range")]
    SurfaceOutOfRange {
        /// The field.
        field: &'static str,
    },
    /// Bits of the feedback's `rejected_reasons` that this version does not define are set.
    #[error("unknown rejection-reason bits {0:#x}")]
    BadReasonBits(u32),
    /// The header's body-length field disagrees with the message kind's body size.
    #[error("header body length {declared} does not match the {expected}-byte body of this kind")]
    LengthMismatch {
        /// The body length the header declares.
        declared: u16,
        /// The body size of the kind.
        expected: u16,
    },
}

impl WireError {
    /// The counter this error is counted under.
    pub fn reason(&self) -> RejectReason {
        match self {
            WireError::WrongVersion { .. } => RejectReason::WrongVersion,
            WireError::ReservedSet { .. }
            | WireError::BadFlags(_)
            | WireError::BadReasonBits(_) => RejectReason::ReservedBits,
            WireError::LengthMismatch { .. } => RejectReason::LengthMismatch,
            WireError::SurfaceOutOfRange { .. } => RejectReason::OutOfRange,
            WireError::WrongSize { .. }
            | WireError::BadMagic
            | WireError::WrongKind { .. }
            | WireError::NonFinite { .. }
            | WireError::BadMode(_)
            | WireError::BadState(_)
            | WireError::BadContactState(_) => RejectReason::Undecodable,
        }
    }
}

/// Why a receiver refused a message: one counter per reason in both processes' summaries
/// (`h4_transport::gate::GateCounters`) and one bit per reason (`1 << reason as u32`) in the
/// feedback's [`Feedback::rejected_reasons`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RejectReason {
    /// Not a message: wrong payload size, magic or kind, a non-finite number, an unknown
    /// mode or state.
    Undecodable = 0,
    /// Another protocol version (header or body field).
    WrongVersion = 1,
    /// For another arm.
    WrongArm = 2,
    /// Sequence number not above the last accepted one of the session (duplicate, reordered,
    /// replayed).
    Stale = 3,
    /// Finite but outside the receiver's limits: a target outside the workspace, a force
    /// set-point outside [0, force limit], a speed above the speed limit.
    OutOfRange = 4,
    /// Energy fields the sender cannot have exchanged since its last message (more than the
    /// power bound times the elapsed time plus a small reserve, or decreasing).
    ImplausibleEnergy = 5,
    /// A reserved byte or an undefined flag bit is set.
    ReservedBits = 6,
    /// The header's body length is not the kind's body size.
    LengthMismatch = 7,
    /// Sequence number far ahead of the session's (more than the sender can have sent since
    /// its last accepted message): rejected, not adopted.
    WildSeq = 8,
    /// From another session than the paired one while the paired one is alive (a second
    /// sender, or a retired session).
    WrongSession = 9,
}

impl RejectReason {
    /// Every reason, in bit order.
    pub const ALL: [RejectReason; 10] = [
        RejectReason::Undecodable,
        RejectReason::WrongVersion,
        RejectReason::WrongArm,
        RejectReason::Stale,
        RejectReason::OutOfRange,
        RejectReason::ImplausibleEnergy,
        RejectReason::ReservedBits,
        RejectReason::LengthMismatch,
        RejectReason::WildSeq,
        RejectReason::WrongSession,
    ];

    /// Its bit in [`Feedback::rejected_reasons`].
    pub fn bit(self) -> u32 {
        1 << (self as u32)
    }

    /// The summary counter's name.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Undecodable => "undecodable",
            RejectReason::WrongVersion => "wrong_version",
            RejectReason::WrongArm => "wrong_arm",
            RejectReason::Stale => "stale",
            RejectReason::OutOfRange => "out_of_range",
            RejectReason::ImplausibleEnergy => "implausible_energy",
            RejectReason::ReservedBits => "reserved_bits",
            RejectReason::LengthMismatch => "length_mismatch",
            RejectReason::WildSeq => "wild_seq",
            RejectReason::WrongSession => "wrong_session",
        }
    }
}

/// All bits [`Feedback::rejected_reasons`] defines in this version.
pub const REJECT_REASONS_KNOWN: u32 = (1 << RejectReason::ALL.len()) - 1;

/// A fresh session id: random (the OS's hash seed, the clock and the process id mixed), so a
/// restarted process announces itself with a new one.
pub fn new_session_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    h.write_u128(now);
    h.write_u32(std::process::id());
    h.finish()
}

/// What the master asks the slave to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Mode {
    /// Hold the current pose; no contact force control.
    Hold = 0,
    /// Follow the commanded pose (position–force coupling).
    Position = 1,
    /// Follow the commanded motion along the surface while the slave's implicit force loop
    /// holds the commanded contact force (force-guided cutting).
    ForceGuided = 2,
}

impl Mode {
    /// Mode from its wire byte.
    pub fn from_u8(b: u8) -> Result<Self, WireError> {
        match b {
            0 => Ok(Mode::Hold),
            1 => Ok(Mode::Position),
            2 => Ok(Mode::ForceGuided),
            other => Err(WireError::BadMode(other)),
        }
    }
}

/// The slave's state as reported in feedback.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum SlaveState {
    /// Started, waiting for a valid command.
    Idle = 0,
    /// Following commands.
    Active = 1,
    /// Commands stopped or became invalid: force ramped to zero, retracting, holding.
    SafeStop = 2,
    /// A fault stops motion until reset.
    Fault = 3,
}

impl SlaveState {
    /// State from its wire byte.
    pub fn from_u8(b: u8) -> Result<Self, WireError> {
        match b {
            0 => Ok(SlaveState::Idle),
            1 => Ok(SlaveState::Active),
            2 => Ok(SlaveState::SafeStop),
            3 => Ok(SlaveState::Fault),
            other => Err(WireError::BadState(other)),
        }
    }
}

/// What the slave knows of the surface under its tool (feedback `contact_state`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum ContactState {
    /// The slave does not say (idle, safe stop): the surface fields carry nothing to render.
    #[default]
    Unknown = 0,
    /// In free space; the surface fields are the last surface touched (all zero before the
    /// first touch).
    Free = 1,
    /// Touching: the surface fields are the current contact's.
    Contact = 2,
}

impl ContactState {
    /// Contact state from its wire byte.
    pub fn from_u8(b: u8) -> Result<Self, WireError> {
        match b {
            0 => Ok(ContactState::Unknown),
            1 => Ok(ContactState::Free),
            2 => Ok(ContactState::Contact),
            other => Err(WireError::BadContactState(other)),
        }
    }
}

/// Largest magnitude of a coordinate of the feedback's `contact_point_mm`, mm (10 m: far
/// beyond any H-4 workspace, so only a corrupt figure is refused).
pub const SURFACE_POINT_LIMIT_MM: f64 = 1e4;
/// Largest stiffness of the feedback's surface estimate, N/mm (0 means not estimated).
pub const SURFACE_STIFFNESS_MAX_N_PER_MM: f64 = 1e6;
/// How far from 1 the length of a unit normal may be.
pub const SURFACE_NORMAL_TOLERANCE: f64 = 1e-6;

/// Command flag: the operator holds the clutch (the slave holds still; re-anchor on release).
pub const CMD_FLAG_CLUTCH: u16 = 1 << 0;
/// Command flag: the master has seen the slave's safe stop, faded its rendering out and
/// started a new energy ledger; a slave in `SafeStop` re-engages only on a command that
/// carries it.
pub const CMD_FLAG_ACK_SAFE_STOP: u16 = 1 << 1;
/// All command flags this version defines.
pub const CMD_FLAGS_KNOWN: u16 = CMD_FLAG_CLUTCH | CMD_FLAG_ACK_SAFE_STOP;

/// Fault flag: no valid command within the watchdog period.
pub const FAULT_COMMAND_TIMEOUT: u16 = 1 << 0;
/// Fault flag: a command was rejected (outside the workspace or the limits).
pub const FAULT_COMMAND_REJECTED: u16 = 1 << 1;
/// Fault flag: the force limit was reached.
pub const FAULT_FORCE_LIMIT: u16 = 1 << 2;
/// Fault flag: contact was lost during force control.
pub const FAULT_CONTACT_LOST: u16 = 1 << 3;
/// Fault flag: the force sensor reading is invalid.
pub const FAULT_SENSOR: u16 = 1 << 4;
/// Fault flag: the control loop missed deadlines.
pub const FAULT_DEADLINE_MISS: u16 = 1 << 5;
/// Fault flag: the safety monitor tripped the arm into its safe stop (latched until the master
/// re-arms it; the reason is in the slave's summary, `safety_trips`).
pub const FAULT_SAFETY_TRIP: u16 = 1 << 6;
/// Every fault flag this protocol defines.
pub const FAULT_FLAGS_KNOWN: u16 = (1 << 7) - 1;

/// Master → slave, once per master cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Command {
    /// The sender's session: a random id a master picks when it starts (header offset 8).
    pub session_id: u64,
    /// Sequence number, +1 per message sent.
    pub seq: u64,
    /// Sender's clock when sent, ns.
    pub send_time_ns: u64,
    /// Desired slave pose `[x_mm, y_mm, z_mm, theta_rad]`, slave frame.
    pub pose: [f64; 4],
    /// Desired slave velocity `[mm/s, mm/s, mm/s, rad/s]`, slave frame.
    pub velocity: [f64; 4],
    /// Desired normal contact force, N (force-guided mode).
    pub force_setpoint_n: f64,
    /// Passivity: energy that has entered the link at the master port so far, J.
    pub energy_in_j: f64,
    /// Passivity: energy that has left the link at the master port so far, J.
    pub energy_out_j: f64,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u16,
    /// Arm this command is for.
    pub arm_id: u16,
    /// [`Mode`] as a byte.
    pub mode: u8,
    /// Reserved, zero.
    pub reserved: u8,
    /// `CMD_FLAG_*` bits.
    pub flags: u16,
    /// `seq` of the newest feedback the master accepted (0 before the first).
    pub echo_seq: u64,
    /// That feedback's `send_time_ns`, on the slave's clock (0 before the first): the slave's
    /// round trip is its own clock now minus this.
    pub echo_send_time_ns: u64,
}

/// Slave → master, once per slave cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Feedback {
    /// The sender's session: a random id a slave picks when it starts (header offset 8).
    pub session_id: u64,
    /// Sequence number, +1 per message sent.
    pub seq: u64,
    /// Sender's clock when sent, ns.
    pub send_time_ns: u64,
    /// Sequence number of the last command the slave accepted.
    pub echo_seq: u64,
    /// `send_time_ns` of that command (the master computes round-trip time from it).
    pub echo_send_time_ns: u64,
    /// Measured pose `[x_mm, y_mm, z_mm, theta_rad]` (forward kinematics of the actuators).
    pub pose: [f64; 4],
    /// Measured contact wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]` at the tool, slave frame.
    pub wrench_measured: [f64; 4],
    /// Desired contact wrench, same units.
    pub wrench_desired: [f64; 4],
    /// Passivity: energy that has entered the link at the slave port so far, J.
    pub energy_in_j: f64,
    /// Passivity: energy that has left the link at the slave port so far, J.
    pub energy_out_j: f64,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u16,
    /// Arm this feedback comes from.
    pub arm_id: u16,
    /// [`SlaveState`] as a byte.
    pub state: u8,
    /// [`ContactState`] as a byte (protocol 2's reserved byte).
    pub contact_state: u8,
    /// `FAULT_*` bits.
    pub fault_flags: u16,
    /// Why commands were rejected since the previous feedback: one bit per [`RejectReason`]
    /// (`1 << reason`), 0 when every command judged was accepted.
    pub rejected_reasons: u32,
    /// Commands rejected since the slave started, all reasons (saturating).
    pub rejected_count: u32,
    /// The surface estimate: the contact point `[x_mm, y_mm, z_mm]`, slave frame.
    pub contact_point_mm: [f64; 3],
    /// The surface's outward unit normal, slave frame (zero when none is known).
    pub contact_normal: [f64; 3],
    /// The surface's stiffness as the slave's force controller estimates it, N/mm (0: none).
    pub contact_stiffness_n_per_mm: f64,
}

impl Default for Command {
    fn default() -> Self {
        Command {
            session_id: 0,
            seq: 0,
            send_time_ns: 0,
            pose: [0.0; 4],
            velocity: [0.0; 4],
            force_setpoint_n: 0.0,
            energy_in_j: 0.0,
            energy_out_j: 0.0,
            protocol_version: PROTOCOL_VERSION,
            arm_id: 0,
            mode: Mode::Hold as u8,
            reserved: 0,
            flags: 0,
            echo_seq: 0,
            echo_send_time_ns: 0,
        }
    }
}

impl Default for Feedback {
    fn default() -> Self {
        Feedback {
            session_id: 0,
            seq: 0,
            send_time_ns: 0,
            echo_seq: 0,
            echo_send_time_ns: 0,
            pose: [0.0; 4],
            wrench_measured: [0.0; 4],
            wrench_desired: [0.0; 4],
            energy_in_j: 0.0,
            energy_out_j: 0.0,
            protocol_version: PROTOCOL_VERSION,
            arm_id: 0,
            state: SlaveState::Idle as u8,
            contact_state: ContactState::Unknown as u8,
            fault_flags: 0,
            rejected_reasons: 0,
            rejected_count: 0,
            contact_point_mm: [0.0; 3],
            contact_normal: [0.0; 3],
            contact_stiffness_n_per_mm: 0.0,
        }
    }
}

struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        // Sizes are fixed at compile time and checked by the round-trip tests.
        if let Some(dst) = self.buf.get_mut(self.at..self.at + b.len()) {
            dst.copy_from_slice(b);
        }
        self.at += b.len();
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64s<const N: usize>(&mut self, v: &[f64; N]) {
        for x in v {
            self.f64(*x);
        }
    }
    fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn u8(&mut self, v: u8) {
        self.bytes(&[v]);
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.buf.get(self.at..self.at + N) {
            out.copy_from_slice(src);
        }
        self.at += N;
        out
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn f64s<const N: usize>(&mut self) -> [f64; N] {
        let mut out = [0.0; N];
        for x in out.iter_mut() {
            *x = self.f64();
        }
        out
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
}

fn write_header(w: &mut Writer<'_>, kind: u8, body_len: usize, session_id: u64) {
    w.bytes(&MAGIC);
    w.u16(PROTOCOL_VERSION);
    w.u8(kind);
    w.u8(0);
    w.u16(body_len as u16);
    w.u64(session_id);
}

/// Checks the header and the size; returns a reader at the session id. The order (magic,
/// version, kind, reserved byte, body length, then the payload's size) lets a message of
/// another version be reported as such whatever its size.
fn read_header<'a>(bytes: &'a [u8], kind: u8, body_len: usize) -> Result<Reader<'a>, WireError> {
    let expected = HEADER_LEN + body_len;
    let wrong_size = WireError::WrongSize {
        expected,
        got: bytes.len(),
    };
    if bytes.len() < PREFIX_LEN {
        return Err(wrong_size);
    }
    let mut r = Reader { buf: bytes, at: 0 };
    if r.take::<2>() != MAGIC {
        return Err(WireError::BadMagic);
    }
    let theirs = r.u16();
    if theirs != PROTOCOL_VERSION {
        return Err(WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs,
        });
    }
    let got = r.u8();
    if got != kind {
        return Err(WireError::WrongKind {
            expected: kind,
            got,
        });
    }
    let reserved = r.u8();
    if reserved != 0 {
        return Err(WireError::ReservedSet {
            field: "header.reserved",
            value: reserved,
        });
    }
    let declared = r.u16();
    if usize::from(declared) != body_len {
        return Err(WireError::LengthMismatch {
            declared,
            expected: body_len as u16,
        });
    }
    if bytes.len() != expected {
        return Err(wrong_size);
    }
    Ok(r)
}

impl Command {
    /// Size of the encoded command, bytes.
    pub const WIRE_SIZE: usize = HEADER_LEN + 8 * 2 + 8 * 4 * 2 + 8 * 3 + 2 + 2 + 1 + 1 + 2 + 8 * 2;
    /// Size of the body after the header, bytes (the header's body length).
    pub const BODY_LEN: usize = Self::WIRE_SIZE - HEADER_LEN;

    /// Checks a command's body, received over any transport, in this order (the first failure
    /// is the error): body version, mode, reserved byte, flag bits, then every number finite
    /// (fields in wire order). The byte path ([`Command::decode`]) checks the header and the
    /// size first.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.protocol_version != PROTOCOL_VERSION {
            return Err(WireError::WrongVersion {
                ours: PROTOCOL_VERSION,
                theirs: self.protocol_version,
            });
        }
        Mode::from_u8(self.mode)?;
        if self.reserved != 0 {
            return Err(WireError::ReservedSet {
                field: "reserved",
                value: self.reserved,
            });
        }
        if self.flags & !CMD_FLAGS_KNOWN != 0 {
            return Err(WireError::BadFlags(self.flags & !CMD_FLAGS_KNOWN));
        }
        let fields: [(&'static str, &[f64]); 5] = [
            ("pose", &self.pose),
            ("velocity", &self.velocity),
            (
                "force_setpoint_n",
                core::slice::from_ref(&self.force_setpoint_n),
            ),
            ("energy_in_j", core::slice::from_ref(&self.energy_in_j)),
            ("energy_out_j", core::slice::from_ref(&self.energy_out_j)),
        ];
        check_all_finite(&fields)
    }

    /// The mode, checked.
    pub fn mode(&self) -> Result<Mode, WireError> {
        Mode::from_u8(self.mode)
    }

    /// Whether the operator holds the clutch.
    pub fn clutch(&self) -> bool {
        self.flags & CMD_FLAG_CLUTCH != 0
    }

    /// Encodes into `out` (little-endian, with header).
    pub fn encode(&self, out: &mut [u8; Self::WIRE_SIZE]) {
        let mut w = Writer { buf: out, at: 0 };
        write_header(&mut w, KIND_COMMAND, Self::BODY_LEN, self.session_id);
        w.u64(self.seq);
        w.u64(self.send_time_ns);
        w.f64s(&self.pose);
        w.f64s(&self.velocity);
        w.f64(self.force_setpoint_n);
        w.f64(self.energy_in_j);
        w.f64(self.energy_out_j);
        w.u16(self.protocol_version);
        w.u16(self.arm_id);
        w.u8(self.mode);
        w.u8(self.reserved);
        w.u16(self.flags);
        w.u64(self.echo_seq);
        w.u64(self.echo_send_time_ns);
    }

    /// Decodes and validates a command: the header (magic, version, kind, reserved byte, body
    /// length), then the payload's size, then the body ([`Command::validate`]'s order), so every transport judges a body alike.
    pub fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        let mut r = read_header(bytes, KIND_COMMAND, Self::BODY_LEN)?;
        let cmd = Command {
            session_id: r.u64(),
            seq: r.u64(),
            send_time_ns: r.u64(),
            pose: r.f64s(),
            velocity: r.f64s(),
            force_setpoint_n: r.f64(),
            energy_in_j: r.f64(),
            energy_out_j: r.f64(),
            protocol_version: r.u16(),
            arm_id: r.u16(),
            mode: r.u8(),
            reserved: r.u8(),
            flags: r.u16(),
            echo_seq: r.u64(),
            echo_send_time_ns: r.u64(),
        };
        cmd.validate()?;
        Ok(cmd)
    }
}

impl Feedback {
    /// Size of the encoded feedback, bytes.
    pub const WIRE_SIZE: usize =
        HEADER_LEN + 8 * 4 + 8 * 4 * 3 + 8 * 2 + 2 + 2 + 1 + 1 + 2 + 4 + 4 + 8 * 7;
    /// Size of the body after the header, bytes (the header's body length).
    pub const BODY_LEN: usize = Self::WIRE_SIZE - HEADER_LEN;

    /// Checks a feedback body, received over any transport, in this order (the first failure
    /// is the error): body version, state, contact state, fault flag bits, reason bits, every
    /// number finite (fields in wire order), then the surface estimate's ranges (point,
    /// normal, stiffness). The byte path ([`Feedback::decode`]) checks the header and the
    /// size first.
    pub fn validate(&self) -> Result<(), WireError> {
        if self.protocol_version != PROTOCOL_VERSION {
            return Err(WireError::WrongVersion {
                ours: PROTOCOL_VERSION,
                theirs: self.protocol_version,
            });
        }
        SlaveState::from_u8(self.state)?;
        let contact = ContactState::from_u8(self.contact_state)?;
        if self.fault_flags & !FAULT_FLAGS_KNOWN != 0 {
            return Err(WireError::BadFlags(self.fault_flags & !FAULT_FLAGS_KNOWN));
        }
        if self.rejected_reasons & !REJECT_REASONS_KNOWN != 0 {
            return Err(WireError::BadReasonBits(
                self.rejected_reasons & !REJECT_REASONS_KNOWN,
            ));
        }
        let fields: [(&'static str, &[f64]); 8] = [
            ("pose", &self.pose),
            ("wrench_measured", &self.wrench_measured),
            ("wrench_desired", &self.wrench_desired),
            ("energy_in_j", core::slice::from_ref(&self.energy_in_j)),
            ("energy_out_j", core::slice::from_ref(&self.energy_out_j)),
            ("contact_point_mm", &self.contact_point_mm),
            ("contact_normal", &self.contact_normal),
            (
                "contact_stiffness_n_per_mm",
                core::slice::from_ref(&self.contact_stiffness_n_per_mm),
            ),
        ];
        check_all_finite(&fields)?;
        self.check_surface(contact)
    }

    /// The surface estimate's ranges: every coordinate of the point within
    /// ±[`SURFACE_POINT_LIMIT_MM`]; the normal of unit length (within
    /// [`SURFACE_NORMAL_TOLERANCE`]) or, out of contact, all zero; the stiffness within
    /// [0, [`SURFACE_STIFFNESS_MAX_N_PER_MM`]].
    fn check_surface(&self, contact: ContactState) -> Result<(), WireError> {
        let out = |field| Err(WireError::SurfaceOutOfRange { field });
        if self
            .contact_point_mm
            .iter()
            .any(|x| x.abs() > SURFACE_POINT_LIMIT_MM)
        {
            return out("contact_point_mm");
        }
        let n = &self.contact_normal;
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let unit = (len - 1.0).abs() <= SURFACE_NORMAL_TOLERANCE;
        let zero = len == 0.0 && contact != ContactState::Contact;
        if !unit && !zero {
            return out("contact_normal");
        }
        if !(0.0..=SURFACE_STIFFNESS_MAX_N_PER_MM).contains(&self.contact_stiffness_n_per_mm) {
            return out("contact_stiffness_n_per_mm");
        }
        Ok(())
    }

    /// The contact state, checked.
    pub fn contact_state(&self) -> Result<ContactState, WireError> {
        ContactState::from_u8(self.contact_state)
    }

    /// The slave state, checked.
    pub fn state(&self) -> Result<SlaveState, WireError> {
        SlaveState::from_u8(self.state)
    }

    /// Encodes into `out` (little-endian, with header).
    pub fn encode(&self, out: &mut [u8; Self::WIRE_SIZE]) {
        let mut w = Writer { buf: out, at: 0 };
        write_header(&mut w, KIND_FEEDBACK, Self::BODY_LEN, self.session_id);
        w.u64(self.seq);
        w.u64(self.send_time_ns);
        w.u64(self.echo_seq);
        w.u64(self.echo_send_time_ns);
        w.f64s(&self.pose);
        w.f64s(&self.wrench_measured);
        w.f64s(&self.wrench_desired);
        w.f64(self.energy_in_j);
        w.f64(self.energy_out_j);
        w.u16(self.protocol_version);
        w.u16(self.arm_id);
        w.u8(self.state);
        w.u8(self.contact_state);
        w.u16(self.fault_flags);
        w.u32(self.rejected_reasons);
        w.u32(self.rejected_count);
        w.f64s(&self.contact_point_mm);
        w.f64s(&self.contact_normal);
        w.f64(self.contact_stiffness_n_per_mm);
    }

    /// Decodes and validates feedback: the header (magic, version, kind, reserved byte, body
    /// length), then the payload's size, then the body
    /// ([`Feedback::validate`]'s order).
    pub fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        let mut r = read_header(bytes, KIND_FEEDBACK, Self::BODY_LEN)?;
        let fb = Feedback {
            session_id: r.u64(),
            seq: r.u64(),
            send_time_ns: r.u64(),
            echo_seq: r.u64(),
            echo_send_time_ns: r.u64(),
            pose: r.f64s(),
            wrench_measured: r.f64s(),
            wrench_desired: r.f64s(),
            energy_in_j: r.f64(),
            energy_out_j: r.f64(),
            protocol_version: r.u16(),
            arm_id: r.u16(),
            state: r.u8(),
            contact_state: r.u8(),
            fault_flags: r.u16(),
            rejected_reasons: r.u32(),
            rejected_count: r.u32(),
            contact_point_mm: r.f64s(),
            contact_normal: r.f64s(),
            contact_stiffness_n_per_mm: r.f64(),
        };
        fb.validate()?;
        Ok(fb)
    }
}

/// The receiver's limits on a command's values (finite values outside them are rejected as
/// [`RejectReason::OutOfRange`] before anything acts on them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandLimits {
    /// The slave arm's workspace: the pose of a position or force-guided command must be in it.
    pub workspace: Workspace,
    /// Largest commanded translational speed, mm/s.
    pub max_speed_mm_per_s: f64,
    /// Largest force set-point, N (the smallest is 0).
    pub force_limit_n: f64,
}

impl CommandLimits {
    /// Why `cmd` is outside these limits (a reason code: the kinematics' workspace codes,
    /// `speed_above_limit`, `setpoint_out_of_range`), or `None`. The pose is checked in
    /// position and force-guided mode (hold mode ignores it); the set-point and the speed in
    /// every mode.
    pub fn check(&self, cmd: &Command) -> Option<&'static str> {
        let v = &cmd.velocity;
        let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if speed.is_nan() || speed > self.max_speed_mm_per_s * (1.0 + 1e-9) {
            return Some("speed_above_limit");
        }
        let sp = cmd.force_setpoint_n;
        if !(0.0..=self.force_limit_n).contains(&sp) {
            return Some("setpoint_out_of_range");
        }
        let moves = cmd.mode == Mode::Position as u8 || cmd.mode == Mode::ForceGuided as u8;
        if moves && let Err(e) = self.workspace.ik(&Pose::from(cmd.pose)) {
            return Some(e.reason_code());
        }
        None
    }
}

/// What every transport needs of a message: its session, sequence number and send time,
/// its energy fields, a check of its contents and the checked byte encoding of the network
/// path.
pub trait WireMessage: Copy + Send + 'static {
    /// The receiver's limits on this message's values ([`CommandLimits`] for a command, none
    /// for feedback).
    type Limits: Copy + core::fmt::Debug;
    /// Size of the encoded message, bytes.
    const WIRE_SIZE: usize;
    /// Short name for logs and errors ("command", "feedback").
    const NAME: &'static str;
    /// The sender's session id.
    fn session_id(&self) -> u64;
    /// Sequence number.
    fn seq(&self) -> u64;
    /// The passivity energy fields `(energy_in_j, energy_out_j)`, cumulative, J.
    fn energies_j(&self) -> (f64, f64);
    /// Whether the sender started a new energy ledger with this message (a command carrying
    /// [`CMD_FLAG_ACK_SAFE_STOP`]): its energy fields start again near 0.
    fn starts_new_ledger(&self) -> bool;
    /// Why the message is outside `limits` (a reason code), or `None`.
    fn out_of_range(&self, limits: &Self::Limits) -> Option<&'static str>;
    /// Sender's clock when sent, ns.
    fn send_time_ns(&self) -> u64;
    /// Arm the message belongs to.
    fn arm_id(&self) -> u16;
    /// Checks version, enums, flags and finiteness.
    fn validate(&self) -> Result<(), WireError>;
    /// Encodes into `out`, which must be `WIRE_SIZE` bytes long (checked: a wrong size is an error).
    fn encode_into(&self, out: &mut [u8]) -> Result<(), WireError>;
    /// Decodes and validates.
    fn decode_from(bytes: &[u8]) -> Result<Self, WireError>;
}

macro_rules! impl_wire_message {
    ($ty:ty, $name:literal, $limits:ty, $check:expr, $ledger:expr) => {
        impl WireMessage for $ty {
            type Limits = $limits;
            const WIRE_SIZE: usize = <$ty>::WIRE_SIZE;
            const NAME: &'static str = $name;
            fn session_id(&self) -> u64 {
                self.session_id
            }
            fn seq(&self) -> u64 {
                self.seq
            }
            fn energies_j(&self) -> (f64, f64) {
                (self.energy_in_j, self.energy_out_j)
            }
            fn starts_new_ledger(&self) -> bool {
                let ledger: fn(&Self) -> bool = $ledger;
                ledger(self)
            }
            fn out_of_range(&self, limits: &Self::Limits) -> Option<&'static str> {
                let check: fn(&Self, &$limits) -> Option<&'static str> = $check;
                check(self, limits)
            }
            fn send_time_ns(&self) -> u64 {
                self.send_time_ns
            }
            fn arm_id(&self) -> u16 {
                self.arm_id
            }
            fn validate(&self) -> Result<(), WireError> {
                <$ty>::validate(self)
            }
            fn encode_into(&self, out: &mut [u8]) -> Result<(), WireError> {
                let got = out.len();
                let buf: &mut [u8; <$ty>::WIRE_SIZE] =
                    out.try_into().map_err(|_| WireError::WrongSize {
                        expected: <$ty>::WIRE_SIZE,
                        got,
                    })?;
                self.encode(buf);
                Ok(())
            }
            fn decode_from(bytes: &[u8]) -> Result<Self, WireError> {
                <$ty>::decode(bytes)
            }
        }
    };
}

impl_wire_message!(Command, "command", CommandLimits, |c, l| l.check(c), |c| c
    .flags
    & CMD_FLAG_ACK_SAFE_STOP
    != 0);
impl_wire_message!(Feedback, "feedback", (), |_, _| None, |_| false);

fn check_all_finite(fields: &[(&'static str, &[f64])]) -> Result<(), WireError> {
    for (field, values) in fields {
        if values.iter().any(|v| !v.is_finite()) {
            return Err(WireError::NonFinite { field });
        }
    }
    Ok(())
}

// The in-memory layout has no implicit padding: the shared-memory path copies it as is. It
// is the encoding from the session id on.
const _: () = assert!(core::mem::size_of::<Command>() == Command::WIRE_SIZE - PREFIX_LEN);
const _: () = assert!(core::mem::size_of::<Feedback>() == Feedback::WIRE_SIZE - PREFIX_LEN);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_round_trips() {
        let cmd = Command {
            seq: 7,
            send_time_ns: 123_456,
            pose: [1.0, -2.0, -300.0, 0.1],
            velocity: [3.5, 0.0, 0.0, 0.0],
            force_setpoint_n: 20.0,
            energy_in_j: 0.5,
            energy_out_j: 0.25,
            arm_id: 3,
            mode: Mode::ForceGuided as u8,
            flags: CMD_FLAG_CLUTCH,
            echo_seq: 41,
            echo_send_time_ns: 99_000_000,
            ..Command::default()
        };
        let mut buf = [0u8; Command::WIRE_SIZE];
        cmd.encode(&mut buf);
        assert_eq!(Command::decode(&buf), Ok(cmd));
    }

    /// The surface estimate: a unit normal in contact, a zero one allowed out of contact, a
    /// point and a stiffness in range; each bound refused just past it, as `out_of_range`.
    #[test]
    fn the_surface_estimate_is_checked() {
        let ok = Feedback {
            contact_state: ContactState::Contact as u8,
            contact_point_mm: [1.0, -2.0, -253.0],
            contact_normal: [0.0, 0.6, 0.8],
            contact_stiffness_n_per_mm: 2000.0,
            ..Feedback::default()
        };
        let mut buf = [0u8; Feedback::WIRE_SIZE];
        ok.encode(&mut buf);
        assert_eq!(Feedback::decode(&buf), Ok(ok));
        let free_unknown_normal = Feedback {
            contact_state: ContactState::Free as u8,
            contact_normal: [0.0; 3],
            ..ok
        };
        assert_eq!(free_unknown_normal.validate(), Ok(()));
        let refused = |f: Feedback, field| {
            let e = f.validate().unwrap_err();
            assert_eq!(e, WireError::SurfaceOutOfRange { field });
            assert_eq!(e.reason(), RejectReason::OutOfRange);
        };
        refused(
            Feedback {
                contact_normal: [0.0; 3],
                ..ok
            },
            "contact_normal",
        );
        refused(
            Feedback {
                contact_normal: [0.0, 0.0, 1.0 + 2e-6],
                ..ok
            },
            "contact_normal",
        );
        refused(
            Feedback {
                contact_point_mm: [0.0, 0.0, -1.0001e4],
                ..ok
            },
            "contact_point_mm",
        );
        refused(
            Feedback {
                contact_stiffness_n_per_mm: -0.001,
                ..ok
            },
            "contact_stiffness_n_per_mm",
        );
        refused(
            Feedback {
                contact_stiffness_n_per_mm: 1.000001e6,
                ..ok
            },
            "contact_stiffness_n_per_mm",
        );
        assert_eq!(
            Feedback {
                contact_state: 3,
                ..ok
            }
            .validate(),
            Err(WireError::BadContactState(3))
        );
        assert_eq!(
            Feedback {
                contact_normal: [f64::NAN, 0.0, 1.0],
                ..ok
            }
            .validate(),
            Err(WireError::NonFinite {
                field: "contact_normal"
            })
        );
    }

    #[test]
    fn wrong_version_is_named() {
        let mut buf = [0u8; Feedback::WIRE_SIZE];
        Feedback::default().encode(&mut buf);
        buf[2] = 9;
        assert_eq!(
            Feedback::decode(&buf),
            Err(WireError::WrongVersion {
                ours: PROTOCOL_VERSION,
                theirs: 9
            })
        );
    }
}
