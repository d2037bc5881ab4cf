//! `tests/data/wire_vectors.json`: encoded bytes ↔ decoded fields for both messages, checked both
//! ways (decode the bytes and compare the fields; encode the fields and compare the bytes), and
//! invalid encodings with the error each must give and the receiver's counter it is counted
//! under (`counter`, `gate.<counter>` in the summaries; `tests/wire_vectors_at_the_slave.rs`
//! sends each through the slave). docs/wire.md describes the layout; these
//! vectors are what a client in another language tests against.
//!
//! `H4_BLESS=1 cargo test --release -p h4-tests --test wire_vectors` rewrites the file from the
//! cases below (only for an intended change of the wire format, with `PROTOCOL_VERSION` bumped).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_shared::wire::{
    CMD_FLAG_CLUTCH, Command, ContactState, FAULT_CONTACT_LOST, FAULT_FORCE_LIMIT, Feedback, Mode,
    PROTOCOL_VERSION, RejectReason, SlaveState, WireError,
};
use serde_json::{Value, json};

fn path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/wire_vectors.json")
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn command_fields(c: &Command) -> Value {
    json!({
        "session_id": c.session_id, "seq": c.seq, "send_time_ns": c.send_time_ns, "pose": c.pose, "velocity": c.velocity,
        "force_setpoint_n": c.force_setpoint_n, "energy_in_j": c.energy_in_j,
        "energy_out_j": c.energy_out_j, "protocol_version": c.protocol_version,
        "arm_id": c.arm_id, "mode": c.mode, "reserved": c.reserved, "flags": c.flags,
        "echo_seq": c.echo_seq, "echo_send_time_ns": c.echo_send_time_ns,
    })
}

fn feedback_fields(f: &Feedback) -> Value {
    json!({
        "session_id": f.session_id, "seq": f.seq, "send_time_ns": f.send_time_ns,
        "echo_seq": f.echo_seq,
        "echo_send_time_ns": f.echo_send_time_ns, "pose": f.pose,
        "wrench_measured": f.wrench_measured, "wrench_desired": f.wrench_desired,
        "energy_in_j": f.energy_in_j, "energy_out_j": f.energy_out_j,
        "protocol_version": f.protocol_version, "arm_id": f.arm_id, "state": f.state,
        "contact_state": f.contact_state, "fault_flags": f.fault_flags,
        "rejected_reasons": f.rejected_reasons, "rejected_count": f.rejected_count,
        "contact_point_mm": f.contact_point_mm, "contact_normal": f.contact_normal,
        "contact_stiffness_n_per_mm": f.contact_stiffness_n_per_mm,
    })
}

fn f4(v: &Value) -> [f64; 4] {
    let a = v.as_array().unwrap();
    [0, 1, 2, 3].map(|i| a[i].as_f64().unwrap())
}

fn f3(v: &Value) -> [f64; 3] {
    let a = v.as_array().unwrap();
    [0, 1, 2].map(|i| a[i].as_f64().unwrap())
}

fn command_from(v: &Value) -> Command {
    Command {
        session_id: v["session_id"].as_u64().unwrap(),
        seq: v["seq"].as_u64().unwrap(),
        send_time_ns: v["send_time_ns"].as_u64().unwrap(),
        pose: f4(&v["pose"]),
        velocity: f4(&v["velocity"]),
        force_setpoint_n: v["force_setpoint_n"].as_f64().unwrap(),
        energy_in_j: v["energy_in_j"].as_f64().unwrap(),
        energy_out_j: v["energy_out_j"].as_f64().unwrap(),
        protocol_version: v["protocol_version"].as_u64().unwrap() as u16,
        arm_id: v["arm_id"].as_u64().unwrap() as u16,
        mode: v["mode"].as_u64().unwrap() as u8,
        reserved: v["reserved"].as_u64().unwrap() as u8,
        flags: v["flags"].as_u64().unwrap() as u16,
        echo_seq: v["echo_seq"].as_u64().unwrap(),
        echo_send_time_ns: v["echo_send_time_ns"].as_u64().unwrap(),
    }
}

fn feedback_from(v: &Value) -> Feedback {
    Feedback {
        session_id: v["session_id"].as_u64().unwrap(),
        seq: v["seq"].as_u64().unwrap(),
        send_time_ns: v["send_time_ns"].as_u64().unwrap(),
        echo_seq: v["echo_seq"].as_u64().unwrap(),
        echo_send_time_ns: v["echo_send_time_ns"].as_u64().unwrap(),
        pose: f4(&v["pose"]),
        wrench_measured: f4(&v["wrench_measured"]),
        wrench_desired: f4(&v["wrench_desired"]),
        energy_in_j: v["energy_in_j"].as_f64().unwrap(),
        energy_out_j: v["energy_out_j"].as_f64().unwrap(),
        protocol_version: v["protocol_version"].as_u64().unwrap() as u16,
        arm_id: v["arm_id"].as_u64().unwrap() as u16,
        state: v["state"].as_u64().unwrap() as u8,
        contact_state: v["contact_state"].as_u64().unwrap() as u8,
        fault_flags: v["fault_flags"].as_u64().unwrap() as u16,
        rejected_reasons: v["rejected_reasons"].as_u64().unwrap() as u32,
        rejected_count: v["rejected_count"].as_u64().unwrap() as u32,
        contact_point_mm: f3(&v["contact_point_mm"]),
        contact_normal: f3(&v["contact_normal"]),
        contact_stiffness_n_per_mm: v["contact_stiffness_n_per_mm"].as_f64().unwrap(),
    }
}

fn encode_command(c: &Command) -> Vec<u8> {
    let mut b = [0u8; Command::WIRE_SIZE];
    c.encode(&mut b);
    b.to_vec()
}

fn encode_feedback(f: &Feedback) -> Vec<u8> {
    let mut b = [0u8; Feedback::WIRE_SIZE];
    f.encode(&mut b);
    b.to_vec()
}

/// The cases the file is made from.
fn make_vectors() -> Value {
    let cmd = Command {
        session_id: 0x1122_3344_5566_7788,
        seq: 42,
        send_time_ns: 1_764_620_000_123_456_789,
        pose: [10.0, -5.5, -250.0, 0.349],
        velocity: [3.5, 0.0, -1.25, 0.0],
        force_setpoint_n: 20.0,
        energy_in_j: 0.012_5,
        energy_out_j: 0.003,
        arm_id: 3,
        mode: Mode::ForceGuided as u8,
        flags: CMD_FLAG_CLUTCH,
        echo_seq: 6,
        echo_send_time_ns: 1_764_620_000_119_000_000,
        ..Command::default()
    };
    let hold = Command {
        session_id: 1,
        seq: 1,
        send_time_ns: 1_000_000,
        pose: [0.0, 0.0, -250.0, 0.0],
        ..Command::default()
    };
    let fb = Feedback {
        session_id: 0xA1B2_C3D4_E5F6_0718,
        seq: 7,
        send_time_ns: 1_764_620_000_124_000_000,
        echo_seq: 42,
        echo_send_time_ns: 1_764_620_000_123_456_789,
        pose: [10.01, -5.49, -250.2, 0.3488],
        wrench_measured: [0.4, -0.2, 19.8, -12.5],
        wrench_desired: [0.0, 0.0, 20.0, 0.0],
        energy_in_j: 0.004,
        energy_out_j: 0.011,
        arm_id: 3,
        state: SlaveState::Active as u8,
        fault_flags: FAULT_FORCE_LIMIT | FAULT_CONTACT_LOST,
        rejected_reasons: RejectReason::OutOfRange.bit() | RejectReason::Stale.bit(),
        rejected_count: 17,
        contact_state: ContactState::Contact as u8,
        contact_point_mm: [10.01, -5.49, -253.0],
        contact_normal: [0.0, 0.6, 0.8],
        contact_stiffness_n_per_mm: 1000.0,
        ..Feedback::default()
    };
    let free = Feedback {
        session_id: 0xA1B2_C3D4_E5F6_0718,
        seq: 1,
        send_time_ns: 5_000_000,
        state: SlaveState::Idle as u8,
        contact_state: ContactState::Free as u8,
        ..Feedback::default()
    };
    let good = encode_command(&cmd);
    let mut invalid = Vec::new();
    let mut bad = |name: &str, bytes: Vec<u8>, error: WireError| {
        invalid.push(json!({
            "name": name, "kind": "command", "bytes": hex(&bytes), "error": format!("{error:?}"),
            "counter": error.reason().name(),
        }));
    };
    let mut b = good.clone();
    b[2] = 4;
    bad(
        "protocol version 4 in the header",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 4,
        },
    );
    // A protocol-2 master's command (128 bytes, body 112, version 2 in header and body): the
    // layout without the echo, refused as another version.
    let mut b = good[..128].to_vec();
    b[2] = 2;
    b[6..8].copy_from_slice(&112u16.to_le_bytes());
    b[120] = 2;
    bad(
        "a protocol version 2 command",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 2,
        },
    );
    // A version-1 command (8-byte header, 120 bytes): refused as another version.
    let mut b = good[..120].to_vec();
    b[2] = 1;
    bad(
        "a protocol version 1 command",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 1,
        },
    );
    let mut b = good.clone();
    b[5] = 1;
    bad(
        "header reserved byte set",
        b,
        WireError::ReservedSet {
            field: "header.reserved",
            value: 1,
        },
    );
    let mut b = good.clone();
    b[6] = 127;
    bad(
        "header body length 127",
        b,
        WireError::LengthMismatch {
            declared: 127,
            expected: 128,
        },
    );
    let mut b = good.clone();
    b[125] = 4;
    bad(
        "body reserved byte set",
        b,
        WireError::ReservedSet {
            field: "reserved",
            value: 4,
        },
    );
    let mut b = good.clone();
    b[124] = 9;
    bad("mode 9", b, WireError::BadMode(9));
    let mut b = good.clone();
    b[126] = 0x04;
    bad("unknown flag bit 2", b, WireError::BadFlags(0x04));
    let mut b = good.clone();
    b[32..40].copy_from_slice(&f64::NAN.to_le_bytes());
    bad("NaN in pose[0]", b, WireError::NonFinite { field: "pose" });
    bad(
        "one byte short",
        good[..good.len() - 1].to_vec(),
        WireError::WrongSize {
            expected: Command::WIRE_SIZE,
            got: Command::WIRE_SIZE - 1,
        },
    );
    let mut b = good.clone();
    b[0] = b'X';
    bad("bad magic", b, WireError::BadMagic);
    let fb_bytes = encode_feedback(&fb);
    let mut b = fb_bytes[..Command::WIRE_SIZE].to_vec();
    b[6..8].copy_from_slice(&128u16.to_le_bytes());
    bad(
        "feedback kind on the command key",
        b,
        WireError::WrongKind {
            expected: 1,
            got: 2,
        },
    );
    // Shorter than a message: under the 8-byte prefix, the prefix alone, the prefix and part
    // of the session id, the whole header without a body. With a valid prefix the size is
    // judged after the header's fields, so each of these is `WrongSize`.
    for len in [7, 8, 15, 16] {
        bad(
            match len {
                7 => "7 bytes: shorter than the prefix",
                8 => "8 bytes: the prefix alone",
                15 => "15 bytes: the prefix and 7 bytes of the session id",
                _ => "16 bytes: the header without a body",
            },
            good[..len].to_vec(),
            WireError::WrongSize {
                expected: Command::WIRE_SIZE,
                got: len,
            },
        );
    }
    // Two faults at once: the first check in docs/wire.md's order names the error.
    let mut b = good[..12].to_vec();
    b[2] = 1;
    bad(
        "version 1 and 12 bytes: the version before the size",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 1,
        },
    );
    let mut b = good[..7].to_vec();
    b[2] = 1;
    bad(
        "version 1 and 7 bytes: under 8 bytes nothing is read",
        b,
        WireError::WrongSize {
            expected: Command::WIRE_SIZE,
            got: 7,
        },
    );
    let mut b = good.clone();
    b[0] = b'X';
    b[2] = 1;
    bad(
        "bad magic and version 1: the magic first",
        b,
        WireError::BadMagic,
    );
    let mut b = good.clone();
    b[2] = 4;
    b[4] = 2;
    bad(
        "version 4 and the feedback kind: the version before the kind",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 4,
        },
    );
    let mut b = good.clone();
    b[4] = 2;
    b[5] = 1;
    bad(
        "feedback kind and header reserved byte set: the kind first",
        b,
        WireError::WrongKind {
            expected: 1,
            got: 2,
        },
    );
    let mut b = good.clone();
    b[5] = 1;
    b[6] = 127;
    bad(
        "header reserved byte and body length 127: the reserved byte first",
        b,
        WireError::ReservedSet {
            field: "header.reserved",
            value: 1,
        },
    );
    let mut b = good[..good.len() - 1].to_vec();
    b[6] = 127;
    bad(
        "body length 127 and one byte short: the body length before the size",
        b,
        WireError::LengthMismatch {
            declared: 127,
            expected: 128,
        },
    );
    let mut b = good.clone();
    b[120] = 4;
    bad(
        "version 4 in the body only",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 4,
        },
    );
    let mut b = good.clone();
    b[120] = 4;
    b[32..40].copy_from_slice(&f64::NAN.to_le_bytes());
    bad(
        "body version 4 and NaN in pose[0]: the body version first",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 4,
        },
    );
    let mut b = good.clone();
    b[124] = 9;
    b[125] = 4;
    bad(
        "mode 9 and body reserved byte set: the mode first",
        b,
        WireError::BadMode(9),
    );
    let mut b = good.clone();
    b[125] = 4;
    b[126] = 0x04;
    bad(
        "body reserved byte and unknown flag bit: the reserved byte first",
        b,
        WireError::ReservedSet {
            field: "reserved",
            value: 4,
        },
    );
    let mut b = good.clone();
    b[126] = 0x04;
    b[104..112].copy_from_slice(&f64::INFINITY.to_le_bytes());
    bad(
        "unknown flag bit and energy_in_j infinite: the flags before the numbers",
        b,
        WireError::BadFlags(0x04),
    );
    let mut b = good.clone();
    b[64..72].copy_from_slice(&f64::NAN.to_le_bytes());
    b[104..112].copy_from_slice(&f64::INFINITY.to_le_bytes());
    bad(
        "NaN in velocity[0] and energy_in_j infinite: the first field in wire order",
        b,
        WireError::NonFinite { field: "velocity" },
    );
    let invalid_feedback = invalid_feedback_vectors(&fb_bytes);
    invalid.extend(invalid_feedback);
    json!({
        "protocol_version": PROTOCOL_VERSION,
        "command_size": Command::WIRE_SIZE,
        "feedback_size": Feedback::WIRE_SIZE,
        "valid": [
            {"name": "force-guided command with clutch", "kind": "command",
             "bytes": hex(&good), "fields": command_fields(&cmd)},
            {"name": "hold command", "kind": "command",
             "bytes": hex(&encode_command(&hold)), "fields": command_fields(&hold)},
            {"name": "active feedback with faults, in contact", "kind": "feedback",
             "bytes": hex(&fb_bytes), "fields": feedback_fields(&fb)},
            {"name": "idle feedback in free space, no surface known", "kind": "feedback",
             "bytes": hex(&encode_feedback(&free)), "fields": feedback_fields(&free)},
        ],
        "invalid": invalid,
    })
}

/// Invalid feedback (what the master refuses): a protocol-2 slave's feedback, the contact
/// state, the surface estimate's ranges.
fn invalid_feedback_vectors(good: &[u8]) -> Vec<Value> {
    let mut invalid = Vec::new();
    let mut bad = |name: &str, bytes: Vec<u8>, error: WireError| {
        invalid.push(json!({
            "name": name, "kind": "feedback", "bytes": hex(&bytes), "error": format!("{error:?}"),
            "counter": error.reason().name(),
        }));
    };
    // A protocol-2 slave's feedback (176 bytes, body 160, version 2 in header and body).
    // Byte 165 was protocol 2's reserved byte (0), now the contact state.
    let mut b = good[..176].to_vec();
    b[2] = 2;
    b[6..8].copy_from_slice(&160u16.to_le_bytes());
    b[160] = 2;
    b[165] = 0;
    bad(
        "a protocol version 2 feedback",
        b,
        WireError::WrongVersion {
            ours: PROTOCOL_VERSION,
            theirs: 2,
        },
    );
    let mut b = good.to_vec();
    b[165] = 3;
    bad("contact state 3", b, WireError::BadContactState(3));
    let mut b = good.to_vec();
    b[200..208].copy_from_slice(&0.5f64.to_le_bytes());
    bad(
        "contact normal not unit",
        b,
        WireError::SurfaceOutOfRange {
            field: "contact_normal",
        },
    );
    let mut b = good.to_vec();
    b[224..232].copy_from_slice(&(-1.0f64).to_le_bytes());
    bad(
        "negative contact stiffness",
        b,
        WireError::SurfaceOutOfRange {
            field: "contact_stiffness_n_per_mm",
        },
    );
    let mut b = good.to_vec();
    b[176..184].copy_from_slice(&2e4f64.to_le_bytes());
    bad(
        "contact point 20 m away",
        b,
        WireError::SurfaceOutOfRange {
            field: "contact_point_mm",
        },
    );
    let mut b = good.to_vec();
    b[184..192].copy_from_slice(&f64::NAN.to_le_bytes());
    bad(
        "NaN in contact_point_mm[1]",
        b,
        WireError::NonFinite {
            field: "contact_point_mm",
        },
    );
    invalid
}

#[test]
fn vectors_decode_to_their_fields_and_fields_encode_to_their_bytes() {
    let made = make_vectors();
    if std::env::var_os("H4_BLESS").is_some() {
        let text = serde_json::to_string_pretty(&made).unwrap() + "\n";
        std::fs::write(path(), text).unwrap();
    }
    let text = std::fs::read_to_string(path()).unwrap();
    let file: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        file, made,
        "the file and the encoder disagree: the wire format changed (bump PROTOCOL_VERSION, bless)"
    );
    assert_eq!(file["protocol_version"], PROTOCOL_VERSION);
    let mut checked = 0;
    for v in file["valid"].as_array().unwrap() {
        let bytes = unhex(v["bytes"].as_str().unwrap());
        match v["kind"].as_str().unwrap() {
            "command" => {
                let decoded = Command::decode(&bytes).unwrap();
                assert_eq!(command_fields(&decoded), v["fields"]);
                assert_eq!(encode_command(&command_from(&v["fields"])), bytes);
            }
            _ => {
                let decoded = Feedback::decode(&bytes).unwrap();
                assert_eq!(feedback_fields(&decoded), v["fields"]);
                assert_eq!(encode_feedback(&feedback_from(&v["fields"])), bytes);
            }
        }
        checked += 1;
    }
    for v in file["invalid"].as_array().unwrap() {
        let bytes = unhex(v["bytes"].as_str().unwrap());
        let err = match v["kind"].as_str().unwrap() {
            "command" => Command::decode(&bytes).unwrap_err(),
            _ => Feedback::decode(&bytes).unwrap_err(),
        };
        assert_eq!(
            format!("{err:?}"),
            v["error"].as_str().unwrap(),
            "{}",
            v["name"]
        );
        assert_eq!(err.reason().name(), v["counter"], "{}", v["name"]);
        checked += 1;
    }
    assert_eq!(checked, 4 + 12 + 17 + 6);
}

#[test]
fn documented_offsets_match_the_encoding() {
    // docs/wire.md's offset tables, checked against the encoder: a field written at another
    // offset fails here.
    let cmd = Command {
        session_id: 0x1122_3344_5566_7788,
        seq: 0x0102_0304_0506_0708,
        force_setpoint_n: 20.0,
        energy_in_j: 0.25,
        arm_id: 0xBEEF,
        mode: 2,
        flags: 1,
        echo_seq: 0x1112_1314_1516_1718,
        echo_send_time_ns: 77,
        ..Command::default()
    };
    let b = encode_command(&cmd);
    assert_eq!(&b[0..2], b"H4");
    assert_eq!(u16::from_le_bytes([b[2], b[3]]), PROTOCOL_VERSION);
    assert_eq!((b[4], b[5]), (1, 0));
    assert_eq!(u16::from_le_bytes([b[6], b[7]]), 128);
    assert_eq!(
        u64::from_le_bytes(b[8..16].try_into().unwrap()),
        cmd.session_id
    );
    assert_eq!(b[16], 0x08);
    assert_eq!(&b[96..104], &20.0f64.to_le_bytes());
    assert_eq!(&b[104..112], &0.25f64.to_le_bytes());
    assert_eq!(u16::from_le_bytes([b[120], b[121]]), PROTOCOL_VERSION);
    assert_eq!(u16::from_le_bytes([b[122], b[123]]), 0xBEEF);
    assert_eq!((b[124], b[125], b[126], b[127]), (2, 0, 1, 0));
    assert_eq!(b[128], 0x18);
    assert_eq!(u64::from_le_bytes(b[136..144].try_into().unwrap()), 77);
    assert_eq!(b.len(), 144);
    let fb = Feedback {
        session_id: 5,
        echo_send_time_ns: 99,
        energy_out_j: 1.5,
        fault_flags: FAULT_FORCE_LIMIT,
        rejected_reasons: 0x210,
        rejected_count: 0x0A0B_0C0D,
        contact_state: ContactState::Contact as u8,
        contact_point_mm: [1.0, 2.0, 3.0],
        contact_normal: [0.0, 0.0, 1.0],
        contact_stiffness_n_per_mm: 250.0,
        ..Feedback::default()
    };
    let b = encode_feedback(&fb);
    assert_eq!((b[4], u16::from_le_bytes([b[6], b[7]])), (2, 216));
    assert_eq!(b[165], 2);
    assert_eq!(&b[176..184], &1.0f64.to_le_bytes());
    assert_eq!(&b[192..200], &3.0f64.to_le_bytes());
    assert_eq!(&b[216..224], &1.0f64.to_le_bytes());
    assert_eq!(&b[224..232], &250.0f64.to_le_bytes());
    assert_eq!(u64::from_le_bytes(b[8..16].try_into().unwrap()), 5);
    assert_eq!(u64::from_le_bytes(b[40..48].try_into().unwrap()), 99);
    assert_eq!(&b[152..160], &1.5f64.to_le_bytes());
    assert_eq!(u16::from_le_bytes([b[166], b[167]]), FAULT_FORCE_LIMIT);
    assert_eq!(u32::from_le_bytes(b[168..172].try_into().unwrap()), 0x210);
    assert_eq!(
        u32::from_le_bytes(b[172..176].try_into().unwrap()),
        0x0A0B_0C0D
    );
    assert_eq!(b.len(), 232);
}

/// Protocol 3's new fields in the file's valid vectors, against bytes computed by hand (not by
/// the encoder): little-endian u64 and IEEE 754 binary64 at docs/wire.md's offsets.
#[test]
fn the_new_fields_of_protocol_3_have_their_hand_computed_bytes_in_the_vectors() {
    let text = std::fs::read_to_string(path()).unwrap();
    let file: Value = serde_json::from_str(&text).unwrap();
    let valid = |name: &str| {
        let v = file["valid"]
            .as_array()
            .unwrap()
            .iter()
            .find(|v| v["name"] == name)
            .unwrap_or_else(|| panic!("no vector {name}"));
        v["bytes"].as_str().unwrap().to_string()
    };
    let cmd = valid("force-guided command with clutch");
    assert_eq!(cmd.len(), 2 * 144);
    // Header: version 3, kind 1, body length 128 = 0x0080.
    assert_eq!(&cmd[4..16], "030001008000");
    // echo_seq = 6 @128, echo_send_time_ns = 1 764 620 000 119 000 000 = 0x187D308A6EA48BC0
    // @136.
    assert_eq!(&cmd[2 * 128..], "0600000000000000c08ba46e8a307d18");
    let hold = valid("hold command");
    assert_eq!(&hold[2 * 128..], "00000000000000000000000000000000");
    let fb = valid("active feedback with faults, in contact");
    assert_eq!(fb.len(), 2 * 232);
    // Header: version 3, kind 2, body length 216 = 0x00D8; contact_state 2 @165.
    assert_eq!(&fb[4..16], "03000200d800");
    assert_eq!(&fb[2 * 165..2 * 166], "02");
    // contact_point_mm [10.01, -5.49, -253.0] @176 (-253 = -1.9765625 x 2^7: 0xC06FA000...),
    // contact_normal [0, 0.6, 0.8] @200 (0.6 = 0x3FE3333333333333, 0.8 = 0x3FE999999999999A),
    // contact_stiffness_n_per_mm 1000 = 1.953125 x 2^9 = 0x408F400000000000 @224.
    assert_eq!(
        &fb[2 * 176..],
        concat!(
            "85eb51b81e052440",
            "f6285c8fc2f515c0",
            "0000000000a06fc0",
            "0000000000000000",
            "333333333333e33f",
            "9a9999999999e93f",
            "0000000000408f40"
        )
    );
    let free = valid("idle feedback in free space, no surface known");
    assert_eq!(&free[2 * 165..2 * 166], "01");
    assert_eq!(&free[2 * 176..], "0".repeat(2 * 56));
}
