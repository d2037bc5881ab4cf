//! `h4_transport::ros2` against rosbags, an outside implementation of CDR and of RIHS01:
//! `tests/data/ros2_vectors.json`, written by `tests/data/make_ros2_vectors.py` (see its
//! docstring to regenerate), holds for every type we describe rosbags' type hash, the JSON text
//! it hashed, and its CDR bytes of one fixed instance. `instances` below builds the same
//! instances field for field.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fmt::Debug;

use h4_transport::ros2::cdr::HEADER_LEN;
use h4_transport::ros2::msgs::{
    Float64MultiArray, Header, Joy, MultiArrayDimension, MultiArrayLayout, OperatingState, Point,
    Pose, PoseStamped, Quaternion, Ros2Message, StringMsg, Time, Twist, TwistStamped, Vector3,
    Wrench, WrenchStamped,
};
use h4_transport::ros2::type_hash::{self, TypeHash};
use serde::Deserialize;

#[derive(Deserialize)]
struct Vectors {
    rosbags_version: String,
    messages: Vec<Vector>,
}

#[derive(Deserialize)]
struct Vector {
    type_name: String,
    rihs01: String,
    hashed_json: String,
    cdr_hex: String,
}

fn vectors() -> Vectors {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/ros2_vectors.json");
    let text = std::fs::read_to_string(path).expect("tests/data/ros2_vectors.json");
    serde_json::from_str(&text).expect("ros2_vectors.json parses")
}

fn from_hex(text: &str) -> Vec<u8> {
    assert!(text.len().is_multiple_of(2), "odd hex length");
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).expect("hex"))
        .collect()
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn described_type_names() -> Vec<&'static str> {
    let mut names: Vec<&str> = type_hash::DESCRIPTIONS
        .iter()
        .map(|d| d.type_name)
        .collect();
    names.sort_unstable();
    names
}

#[test]
fn the_vectors_cover_every_described_type() {
    let v = vectors();
    assert!(!v.rosbags_version.is_empty());
    let mut theirs: Vec<&str> = v.messages.iter().map(|m| m.type_name.as_str()).collect();
    theirs.sort_unstable();
    assert_eq!(theirs, described_type_names());
}

#[test]
fn canonical_json_and_rihs01_match_rosbags() {
    for m in &vectors().messages {
        let d = type_hash::describe(&m.type_name).unwrap();
        assert_eq!(d.canonical_json(), m.hashed_json, "{}", m.type_name);
        assert_eq!(d.rihs01().to_string(), m.rihs01, "{}", m.type_name);
        assert_eq!(TypeHash::parse(&m.rihs01).unwrap(), d.rihs01());
    }
}

/// Encodes `msg` and compares with rosbags' bytes; decodes rosbags' bytes and compares with
/// `msg`; then checks that no truncation is accepted and that corruptions never panic.
fn check<M: Ros2Message + PartialEq + Debug>(v: &Vectors, msg: &M) -> &'static str {
    let name = M::TYPE_NAME;
    let vector = v
        .messages
        .iter()
        .find(|m| m.type_name == name)
        .unwrap_or_else(|| panic!("no vector for {name}"));
    let theirs = from_hex(&vector.cdr_hex);

    assert_eq!(
        to_hex(&msg.encode().unwrap()),
        vector.cdr_hex,
        "{name}: our bytes"
    );
    assert_eq!(&M::decode(&theirs).unwrap(), msg, "{name}: their bytes");
    assert!(M::decode_finite(&theirs).is_ok(), "{name}: finite");
    assert_eq!(M::type_hash().unwrap().to_string(), vector.rihs01, "{name}");

    for cut in 0..theirs.len() {
        assert!(
            M::decode(&theirs[..cut]).is_err(),
            "{name}: cut at {cut} accepted"
        );
    }
    // Padding the body to a multiple of 4 (as Fast-CDR may) is accepted; a 4th byte is not.
    let body_len = theirs.len() - HEADER_LEN;
    let mut padded = theirs.clone();
    padded.resize(theirs.len() + (4 - body_len % 4) % 4, 0);
    assert_eq!(&M::decode(&padded).unwrap(), msg, "{name}: padded");
    padded.extend_from_slice(&[0, 0, 0, 0]);
    assert!(
        M::decode(&padded).is_err(),
        "{name}: 4 trailing bytes accepted"
    );
    // Every single-byte corruption decodes or is refused, never panics.
    for i in 0..theirs.len() {
        for flip in [0x01u8, 0x80, 0xff] {
            let mut bad = theirs.clone();
            bad[i] ^= flip;
            let _ = M::decode(&bad);
        }
    }
    name
}

fn stamp() -> Time {
    Time {
        sec: 1_700_000_000,
        nanosec: 123_456_789,
    }
}

fn header(frame_id: &str) -> Header {
    Header {
        stamp: stamp(),
        frame_id: frame_id.to_owned(),
    }
}

fn pose() -> Pose {
    Pose {
        position: Point {
            x: 0.1,
            y: -0.2,
            z: 0.3,
        },
        orientation: Quaternion {
            x: 0.0,
            y: 0.6,
            z: 0.0,
            w: 0.8,
        },
    }
}

fn twist() -> Twist {
    Twist {
        linear: Vector3 {
            x: 0.01,
            y: 0.02,
            z: -0.03,
        },
        angular: Vector3 {
            x: 0.0,
            y: 0.5,
            z: 0.0,
        },
    }
}

fn wrench() -> Wrench {
    Wrench {
        force: Vector3 {
            x: 1.5,
            y: -2.5,
            z: 9.81,
        },
        torque: Vector3 {
            x: 0.0,
            y: -0.125,
            z: 0.0,
        },
    }
}

fn layout() -> MultiArrayLayout {
    MultiArrayLayout {
        dim: vec![
            MultiArrayDimension {
                label: "rows".into(),
                size: 2,
                stride: 6,
            },
            MultiArrayDimension {
                label: "cols".into(),
                size: 3,
                stride: 3,
            },
        ],
        data_offset: 0,
    }
}

#[test]
fn our_bytes_are_rosbags_bytes_and_we_read_theirs() {
    let v = vectors();
    let mut checked = vec![
        check(&v, &stamp()),
        check(&v, &header("h4_base")),
        check(
            &v,
            &StringMsg {
                data: "hello".into(),
            },
        ),
        check(
            &v,
            &MultiArrayDimension {
                label: "rows".into(),
                size: 2,
                stride: 6,
            },
        ),
        check(&v, &layout()),
        check(
            &v,
            &Float64MultiArray {
                layout: layout(),
                data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5],
            },
        ),
        check(
            &v,
            &Point {
                x: 0.125,
                y: -0.25,
                z: 0.5,
            },
        ),
        check(
            &v,
            &Quaternion {
                x: 0.0,
                y: 0.6,
                z: 0.0,
                w: 0.8,
            },
        ),
        check(&v, &pose()),
        check(
            &v,
            &PoseStamped {
                header: header("world"),
                pose: pose(),
            },
        ),
        check(
            &v,
            &Vector3 {
                x: 1.0,
                y: -2.0,
                z: 3.5,
            },
        ),
        check(&v, &twist()),
        check(
            &v,
            &TwistStamped {
                header: header("h4_tool"),
                twist: twist(),
            },
        ),
        check(&v, &wrench()),
        check(
            &v,
            &WrenchStamped {
                header: header("tool0"),
                wrench: wrench(),
            },
        ),
        check(
            &v,
            &Joy {
                header: header("joy"),
                axes: vec![0.5, -1.0, 0.25],
                buttons: vec![1, 0, 1, 1],
            },
        ),
        check(
            &v,
            &OperatingState {
                header: header("h4"),
                state: OperatingState::ENABLED.into(),
                is_homed: true,
                is_busy: false,
            },
        ),
    ];
    checked.sort_unstable();
    assert_eq!(checked, described_type_names());
}

#[test]
fn a_nan_in_rosbags_bytes_is_caught_by_decode_finite() {
    let v = vectors();
    let vector = v
        .messages
        .iter()
        .find(|m| m.type_name == PoseStamped::TYPE_NAME)
        .unwrap();
    let mut bytes = from_hex(&vector.cdr_hex);
    // The last 8 bytes are pose.orientation.w.
    let at = bytes.len() - 8;
    bytes[at..].copy_from_slice(&f64::NAN.to_le_bytes());
    assert!(PoseStamped::decode(&bytes).is_ok());
    let err = PoseStamped::decode_finite(&bytes).unwrap_err();
    assert_eq!(err.to_string(), "pose.orientation.w is not finite");
}
