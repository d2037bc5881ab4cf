//! An outside client of the slave, written from docs/wire.md alone: it encodes commands and
//! decodes feedback byte by byte (little-endian, offsets of the doc's tables), without the
//! project's encoder or decoder, as a client in another language would.

#![allow(dead_code)]

/// A command's fields, and the header fields a client could get wrong.
#[derive(Clone, Copy, Debug)]
pub struct Cmd {
    /// Header offset 2.
    pub header_version: u16,
    /// Header offset 4.
    pub kind: u8,
    /// Header offset 5.
    pub header_reserved: u8,
    /// Header offset 6.
    pub body_len: u16,
    /// Header offset 8.
    pub session_id: u64,
    pub seq: u64,
    pub send_time_ns: u64,
    pub pose: [f64; 4],
    pub velocity: [f64; 4],
    pub force_setpoint_n: f64,
    pub energy_in_j: f64,
    pub energy_out_j: f64,
    pub protocol_version: u16,
    pub arm_id: u16,
    pub mode: u8,
    pub reserved: u8,
    pub flags: u16,
    /// Protocol 3: the newest feedback's `seq` and `send_time_ns` (0 before the first).
    pub echo_seq: u64,
    pub echo_send_time_ns: u64,
}

/// docs/wire.md: protocol version 3, command 144 bytes (body 128), feedback 232 (body 216).
pub const VERSION: u16 = 3;
pub const COMMAND_LEN: usize = 144;
pub const FEEDBACK_LEN: usize = 232;

/// Reason bits of the feedback's `rejected_reasons` (docs/wire.md, "What the receiver checks").
pub const BIT_UNDECODABLE: u32 = 1 << 0;
pub const BIT_WRONG_VERSION: u32 = 1 << 1;
pub const BIT_WRONG_ARM: u32 = 1 << 2;
pub const BIT_STALE: u32 = 1 << 3;
pub const BIT_OUT_OF_RANGE: u32 = 1 << 4;
pub const BIT_IMPLAUSIBLE_ENERGY: u32 = 1 << 5;
pub const BIT_RESERVED_BITS: u32 = 1 << 6;
pub const BIT_LENGTH_MISMATCH: u32 = 1 << 7;
pub const BIT_WILD_SEQ: u32 = 1 << 8;
pub const BIT_WRONG_SESSION: u32 = 1 << 9;

impl Cmd {
    /// A position command (mode 1) to `pose` for arm 0.
    pub fn position(session_id: u64, seq: u64, pose: [f64; 4]) -> Self {
        Cmd {
            header_version: VERSION,
            kind: 1,
            header_reserved: 0,
            body_len: 128,
            session_id,
            seq,
            send_time_ns: seq * 1_000_000,
            pose,
            velocity: [0.0; 4],
            force_setpoint_n: 0.0,
            energy_in_j: 0.0,
            energy_out_j: 0.0,
            protocol_version: VERSION,
            arm_id: 0,
            mode: 1,
            reserved: 0,
            flags: 0,
            echo_seq: 0,
            echo_send_time_ns: 0,
        }
    }

    /// The bytes, laid out as docs/wire.md's tables say.
    pub fn bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(COMMAND_LEN);
        b.extend_from_slice(b"H4");
        b.extend_from_slice(&self.header_version.to_le_bytes());
        b.push(self.kind);
        b.push(self.header_reserved);
        b.extend_from_slice(&self.body_len.to_le_bytes());
        b.extend_from_slice(&self.session_id.to_le_bytes());
        b.extend_from_slice(&self.seq.to_le_bytes());
        b.extend_from_slice(&self.send_time_ns.to_le_bytes());
        for x in self.pose.iter().chain(self.velocity.iter()) {
            b.extend_from_slice(&x.to_le_bytes());
        }
        for x in [self.force_setpoint_n, self.energy_in_j, self.energy_out_j] {
            b.extend_from_slice(&x.to_le_bytes());
        }
        b.extend_from_slice(&self.protocol_version.to_le_bytes());
        b.extend_from_slice(&self.arm_id.to_le_bytes());
        b.push(self.mode);
        b.push(self.reserved);
        b.extend_from_slice(&self.flags.to_le_bytes());
        b.extend_from_slice(&self.echo_seq.to_le_bytes());
        b.extend_from_slice(&self.echo_send_time_ns.to_le_bytes());
        assert_eq!(b.len(), COMMAND_LEN);
        b
    }
}

/// The feedback fields the tests read.
#[derive(Clone, Copy, Debug)]
pub struct Fb {
    pub session_id: u64,
    pub seq: u64,
    pub send_time_ns: u64,
    pub echo_seq: u64,
    pub pose: [f64; 4],
    pub wrench_measured: [f64; 4],
    pub state: u8,
    pub fault_flags: u16,
    pub rejected_reasons: u32,
    pub rejected_count: u32,
    /// Protocol 3's surface estimate: 0 unknown, 1 free, 2 contact.
    pub contact_state: u8,
    pub contact_point_mm: [f64; 3],
    pub contact_normal: [f64; 3],
    pub contact_stiffness_n_per_mm: f64,
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}
fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}
fn f64s_at(b: &[u8], at: usize) -> [f64; 4] {
    [0, 1, 2, 3].map(|i| f64::from_le_bytes(b[at + 8 * i..at + 8 * i + 8].try_into().unwrap()))
}

impl Fb {
    /// Parses feedback bytes by docs/wire.md's table (checks magic, version, kind, length).
    pub fn parse(b: &[u8]) -> Option<Fb> {
        if b.len() != FEEDBACK_LEN
            || &b[0..2] != b"H4"
            || u16_at(b, 2) != VERSION
            || b[4] != 2
            || u16_at(b, 6) != 216
        {
            return None;
        }
        Some(Fb {
            session_id: u64_at(b, 8),
            seq: u64_at(b, 16),
            send_time_ns: u64_at(b, 24),
            echo_seq: u64_at(b, 32),
            pose: f64s_at(b, 48),
            wrench_measured: f64s_at(b, 80),
            state: b[164],
            fault_flags: u16_at(b, 166),
            rejected_reasons: u32_at(b, 168),
            rejected_count: u32_at(b, 172),
            contact_state: b[165],
            contact_point_mm: [0, 1, 2].map(|i| f64_at(b, 176 + 8 * i)),
            contact_normal: [0, 1, 2].map(|i| f64_at(b, 200 + 8 * i)),
            contact_stiffness_n_per_mm: f64_at(b, 224),
        })
    }

    /// |measured force|, N.
    pub fn force_n(&self) -> f64 {
        let w = self.wrench_measured;
        (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt()
    }

    /// Distance of the measured position from `p`, mm.
    pub fn distance_mm(&self, p: &[f64; 4]) -> f64 {
        (0..3)
            .map(|i| (self.pose[i] - p[i]).powi(2))
            .sum::<f64>()
            .sqrt()
    }
}

/// One bad message of the test list: what it is, its bytes and the counter it must land in.
pub struct Bad {
    pub name: &'static str,
    pub bytes: Vec<u8>,
    pub counter: &'static str,
    pub bit: u32,
}

/// Deterministic bytes (xorshift), for the random-bytes case.
pub fn random_bytes(state: &mut u64, len: usize) -> Vec<u8> {
    (0..len)
        .map(|_| {
            *state ^= *state << 13;
            *state ^= *state >> 7;
            *state ^= *state << 17;
            (*state >> 24) as u8
        })
        .collect()
}

/// The bad messages of issue 14, built by hand around a valid command `ok` (session and pose
/// of the paired master, a sequence number above every one the test sends meanwhile, within
/// the gate's window); each is sent in place of a command, so only the named fault can
/// reject it.
pub fn bad_messages(ok: &Cmd, rng: &mut u64) -> Vec<Bad> {
    let next = |c: &Cmd| *c;
    let mut out = Vec::new();
    let mut push = |name, bytes, counter, bit| {
        out.push(Bad {
            name,
            bytes,
            counter,
            bit,
        })
    };
    let len = (*rng % 300) as usize;
    push(
        "random bytes",
        random_bytes(rng, len),
        "undecodable",
        BIT_UNDECODABLE,
    );
    push(
        "random bytes of the command's size",
        random_bytes(rng, COMMAND_LEN),
        "undecodable",
        BIT_UNDECODABLE,
    );
    push(
        "truncated (60 of 144 bytes)",
        next(ok).bytes()[..60].to_vec(),
        "undecodable",
        BIT_UNDECODABLE,
    );
    push(
        "wrong version (1)",
        Cmd {
            header_version: 1,
            protocol_version: 1,
            ..next(ok)
        }
        .bytes(),
        "wrong_version",
        BIT_WRONG_VERSION,
    );
    // Version 1's layout: the same fields after an 8-byte header without the session id
    // (120 bytes); refused as another version, whatever its size.
    let mut v1 = Cmd {
        header_version: 1,
        protocol_version: 1,
        ..next(ok)
    }
    .bytes();
    v1.drain(8..16);
    push(
        "a protocol-1 command (120 bytes)",
        v1,
        "wrong_version",
        BIT_WRONG_VERSION,
    );
    // Protocol 2's layout: 128 bytes (body 112), without the echo; refused as another version.
    let mut v2 = Cmd {
        header_version: 2,
        protocol_version: 2,
        body_len: 112,
        ..next(ok)
    }
    .bytes();
    v2.truncate(128);
    push(
        "a protocol-2 command (128 bytes)",
        v2,
        "wrong_version",
        BIT_WRONG_VERSION,
    );
    push(
        "version 4 in the body only",
        Cmd {
            protocol_version: 4,
            ..next(ok)
        }
        .bytes(),
        "wrong_version",
        BIT_WRONG_VERSION,
    );
    push(
        "header reserved byte set",
        Cmd {
            header_reserved: 1,
            ..next(ok)
        }
        .bytes(),
        "reserved_bits",
        BIT_RESERVED_BITS,
    );
    push(
        "body reserved byte set",
        Cmd {
            reserved: 0x80,
            ..next(ok)
        }
        .bytes(),
        "reserved_bits",
        BIT_RESERVED_BITS,
    );
    push(
        "undefined flag bit",
        Cmd {
            flags: 0x8000,
            ..next(ok)
        }
        .bytes(),
        "reserved_bits",
        BIT_RESERVED_BITS,
    );
    push(
        "header body length 127",
        Cmd {
            body_len: 127,
            ..next(ok)
        }
        .bytes(),
        "length_mismatch",
        BIT_LENGTH_MISMATCH,
    );
    let mut x = next(ok);
    x.pose[0] = 1e6;
    push(
        "target x = 1e6 mm",
        x.bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    let mut z = next(ok);
    z.pose[2] = -1e6;
    push(
        "target z = -1e6 mm",
        z.bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    let mut zf = next(ok);
    zf.pose[2] = -1e6;
    zf.mode = 2;
    zf.force_setpoint_n = 20.0;
    push(
        "force-guided target z = -1e6 mm",
        zf.bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    push(
        "set-point 1e6 N (force-guided)",
        Cmd {
            mode: 2,
            force_setpoint_n: 1e6,
            ..next(ok)
        }
        .bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    push(
        "set-point -5 N",
        Cmd {
            mode: 2,
            force_setpoint_n: -5.0,
            ..next(ok)
        }
        .bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    push(
        "speed 1e4 mm/s",
        Cmd {
            velocity: [1e4, 0.0, 0.0, 0.0],
            ..next(ok)
        }
        .bytes(),
        "out_of_range",
        BIT_OUT_OF_RANGE,
    );
    push(
        "energy_in_j = 1e6",
        Cmd {
            energy_in_j: 1e6,
            ..next(ok)
        }
        .bytes(),
        "implausible_energy",
        BIT_IMPLAUSIBLE_ENERGY,
    );
    push(
        "seq 2^64-1",
        Cmd {
            seq: u64::MAX,
            ..*ok
        }
        .bytes(),
        "wild_seq",
        BIT_WILD_SEQ,
    );
    push(
        "another arm",
        Cmd {
            arm_id: 7,
            ..next(ok)
        }
        .bytes(),
        "wrong_arm",
        BIT_WRONG_ARM,
    );
    push(
        "duplicate",
        Cmd { seq: 1, ..*ok }.bytes(),
        "stale",
        BIT_STALE,
    );
    push(
        "a second master",
        Cmd {
            session_id: ok.session_id ^ 0xFFFF,
            ..next(ok)
        }
        .bytes(),
        "wrong_session",
        BIT_WRONG_SESSION,
    );
    out
}
