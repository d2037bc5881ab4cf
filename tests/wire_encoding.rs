//! The checked byte encoding round-trips every valid message and rejects wrong sizes,
//! wrong versions, wrong kinds, unknown enums and flags, and non-finite numbers.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::wire::{
    CMD_FLAG_CLUTCH, Command, ContactState, FAULT_FLAGS_KNOWN, Feedback, Mode, PROTOCOL_VERSION,
    SlaveState, WireError, WireMessage,
};
use proptest::prelude::*;

fn finite() -> impl Strategy<Value = f64> {
    -1e9..1e9f64
}

fn arr4() -> impl Strategy<Value = [f64; 4]> {
    proptest::array::uniform4(finite())
}

prop_compose! {
    fn command()(seq in any::<u64>(), t in any::<u64>(), pose in arr4(), vel in arr4(),
                 f in finite(), ein in finite(), eout in finite(), arm in any::<u16>(),
                 mode in 0u8..3, clutch in any::<bool>(), echo in any::<u64>(),
                 echo_t in any::<u64>()) -> Command {
        Command {
            seq, send_time_ns: t, pose, velocity: vel, force_setpoint_n: f,
            energy_in_j: ein, energy_out_j: eout, arm_id: arm, mode,
            flags: if clutch { CMD_FLAG_CLUTCH } else { 0 },
            echo_seq: echo, echo_send_time_ns: echo_t,
            ..Command::default()
        }
    }
}

prop_compose! {
    fn feedback()(seq in any::<u64>(), t in any::<u64>(), echo in any::<u64>(), echo_t in any::<u64>(),
                  pose in arr4(), wm in arr4(), wd in arr4(), ein in finite(), eout in finite(),
                  arm in any::<u16>(), state in 0u8..4, faults in 0..=FAULT_FLAGS_KNOWN,
                  contact in 0u8..3, point in proptest::array::uniform3(-1e4..1e4f64),
                  dir in proptest::array::uniform3(-1.0..1.0f64), k in 0.0..1e6f64) -> Feedback {
        // A unit normal (or, out of contact and for a too-short draw, none).
        let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        let normal = if len > 0.1 { dir.map(|x| x / len) } else { [0.0, 0.0, 1.0] };
        let normal = if contact == 1 && len <= 0.1 { [0.0; 3] } else { normal };
        Feedback {
            seq, send_time_ns: t, echo_seq: echo, echo_send_time_ns: echo_t, pose,
            wrench_measured: wm, wrench_desired: wd, energy_in_j: ein, energy_out_j: eout,
            arm_id: arm, state, fault_flags: faults, contact_state: contact,
            contact_point_mm: point, contact_normal: normal, contact_stiffness_n_per_mm: k,
            ..Feedback::default()
        }
    }
}

fn encode<M: WireMessage>(m: &M) -> Vec<u8> {
    let mut buf = vec![0u8; M::WIRE_SIZE];
    m.encode_into(&mut buf).unwrap();
    buf
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn command_round_trips(cmd in command()) {
        prop_assert_eq!(Command::decode_from(&encode(&cmd)), Ok(cmd));
    }

    #[test]
    fn feedback_round_trips(fb in feedback()) {
        prop_assert_eq!(Feedback::decode_from(&encode(&fb)), Ok(fb));
    }

    #[test]
    fn any_size_but_the_right_one_is_rejected(cmd in command(), len in 0usize..400) {
        prop_assume!(len != Command::WIRE_SIZE);
        let mut bytes = encode(&cmd);
        bytes.resize(len, 0);
        prop_assert_eq!(
            Command::decode_from(&bytes),
            Err(WireError::WrongSize { expected: Command::WIRE_SIZE, got: len })
        );
    }

    #[test]
    fn non_finite_numbers_are_rejected(fb in feedback(), slot in 0usize..21, which in 0usize..3) {
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][which];
        let mut bytes = encode(&fb);
        // f64 fields start after the 16-byte header and the four u64 fields (14 of them),
        // and the surface estimate's 7 after the 16 bytes of integers at 160.
        let at = if slot < 14 { 16 + 32 + 8 * slot } else { 176 + 8 * (slot - 14) };
        bytes[at..at + 8].copy_from_slice(&bad.to_le_bytes());
        let ok = matches!(Feedback::decode_from(&bytes), Err(WireError::NonFinite { .. }));
        prop_assert!(ok, "slot {}", slot);
        let mut direct = fb;
        direct.wrench_measured[slot % 4] = bad;
        prop_assert_eq!(direct.validate(), Err(WireError::NonFinite { field: "wrench_measured" }));
    }

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = Command::decode_from(&bytes);
        let _ = Feedback::decode_from(&bytes);
    }

    #[test]
    fn wrong_version_kind_mode_and_flags_are_named(cmd in command(), v in any::<u16>()) {
        prop_assume!(v != PROTOCOL_VERSION);
        let good = encode(&cmd);
        let mut bytes = good.clone();
        bytes[2..4].copy_from_slice(&v.to_le_bytes());
        prop_assert_eq!(Command::decode_from(&bytes), Err(WireError::WrongVersion { ours: PROTOCOL_VERSION, theirs: v }));
        // The header is judged before the size: a command on the feedback key is the wrong kind.
        prop_assert_eq!(Feedback::decode_from(&good), Err(WireError::WrongKind { expected: 2, got: 1 }));
        let mut bytes = good.clone();
        bytes[4] = 2;
        prop_assert_eq!(Command::decode_from(&bytes), Err(WireError::WrongKind { expected: 1, got: 2 }));
        let mut bytes = good.clone();
        bytes[0] = b'X';
        prop_assert_eq!(Command::decode_from(&bytes), Err(WireError::BadMagic));
        let mut bad_mode = cmd;
        bad_mode.mode = 7;
        prop_assert_eq!(Command::decode_from(&encode(&bad_mode)), Err(WireError::BadMode(7)));
        let mut bad_flags = cmd;
        bad_flags.flags |= 0x80;
        prop_assert_eq!(Command::decode_from(&encode(&bad_flags)), Err(WireError::BadFlags(0x80)));
    }
}

#[test]
fn enums_cover_their_bytes() {
    assert_eq!(Mode::from_u8(2), Ok(Mode::ForceGuided));
    assert_eq!(SlaveState::from_u8(2), Ok(SlaveState::SafeStop));
    assert_eq!(SlaveState::from_u8(4), Err(WireError::BadState(4)));
    assert_eq!(ContactState::from_u8(2), Ok(ContactState::Contact));
    assert_eq!(ContactState::from_u8(3), Err(WireError::BadContactState(3)));
    let mut buf = [0u8; 3];
    assert!(Command::default().encode_into(&mut buf).is_err());
}
